"""The fibre-optic contact sensor of Weyrich et al. 2006 §5.4: layout, capture and noise model.

A sensor head holds one source fibre (lit by a white LED) and 28 detector fibres
in a line.  A cooled camera images the detector fibres; 23 images bracketed by
2/3 f-stop give an HDR reading per fibre, which the device's calibration turns
into the diffuse reflectance profile R(r) in mm⁻² (exitance per unit incident
flux), the quantity the dipole model predicts (:func:`facestats.model.dipole.dipole_profile`).

Documented choices (the paper does not publish them):

* **Layout.** Detectors on one side of the source at r_k = 0.50 + 0.35 k mm,
  k = 0..27 (0.50-9.95 mm): a linear array of 250 µm fibres at 350 µm pitch.
  It spans 0.3-5 ℓd in red (ℓd ≈ 1.8 mm) and beyond 10 ℓd in blue; fibres are
  treated as points (the 0.25 mm core is small against ℓd).
* **Photometry.** ``scale`` electrons per second of exposure per mm⁻² of R; with
  the default, R = 0.6 mm⁻² just saturates the shortest exposure, and the longest
  exposure (2^(22·2/3) ≈ 26,000 × longer) resolves R ≈ 2·10⁻⁸ mm⁻² at read-noise
  level.
* **Noise.** The camera model of :mod:`facestats.acquire.hdr` (shot, read,
  quantisation; cooled sensor: 3 e⁻ read noise), merged with inverse-variance
  weights; :meth:`ContactSensor.profile_std` gives the noise model used by the
  fit and the posterior.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facestats.acquire.hdr import CameraResponse, expose, merge_exposures, merged_std
from facestats.core.published import N_FIBERS, SENSOR_BRACKET_IMAGES, SENSOR_BRACKET_STOP
from facestats.core.validate import as_finite, check_range, check_shape
from facestats.errors import FormatError, ValidationError

__all__ = ["ContactSensor", "default_fiber_distances"]


def default_fiber_distances() -> np.ndarray:
    """Detector distances from the source fibre, mm: 0.50 + 0.35 k for k = 0..27."""
    return 0.50 + 0.35 * np.arange(N_FIBERS)


@dataclass(frozen=True)
class ContactSensor:
    """Layout and photometry of the contact sensor.

    Parameters
    ----------
    fiber_distance : ndarray, shape (F,)
        Detector distances from the source fibre in mm, increasing.
    n_exposures : int
        Number of bracketed images (23 in §5.4).
    stop : float
        Bracket step in f-stops (2/3 in §5.4).
    shortest_exposure : float
        Shortest exposure time in s.
    scale : float
        Electrons per second of exposure per mm⁻² of R(r) (source power × fibre
        throughput × quantum efficiency, as calibrated).
    camera : CameraResponse
        The sensor camera (cooled: low read noise).
    """

    fiber_distance: np.ndarray = field(default_factory=default_fiber_distances)
    n_exposures: int = SENSOR_BRACKET_IMAGES
    stop: float = SENSOR_BRACKET_STOP
    shortest_exposure: float = 1e-3
    scale: float = 3.2e7
    camera: CameraResponse = field(
        default_factory=lambda: CameraResponse(full_well=20000.0, read_noise=3.0, adc_bits=12)
    )

    def __post_init__(self):
        d = as_finite(self.fiber_distance, "fiber_distance")
        check_shape(d, "fiber_distance", (None,))
        check_range(d, "fiber_distance", 0, None, low_inclusive=False, unit="mm")
        if np.any(np.diff(d) <= 0):
            raise ValidationError("fiber_distance must be strictly increasing, got a non-increasing sequence")
        object.__setattr__(self, "fiber_distance", d.astype(np.float64))
        if self.n_exposures < 1 or self.stop <= 0 or self.shortest_exposure <= 0 or self.scale <= 0:
            raise ValidationError(
                f"ContactSensor needs n_exposures >= 1, stop > 0, shortest_exposure > 0 and scale > 0, got "
                f"{self.n_exposures}, {self.stop}, {self.shortest_exposure}, {self.scale}"
            )

    @property
    def n_fibers(self) -> int:
        return int(self.fiber_distance.shape[0])

    @property
    def exposure_times(self) -> np.ndarray:
        """Bracketed exposure times t_j = t_0 · 2^(stop · j), s."""
        return self.shortest_exposure * 2.0 ** (self.stop * np.arange(self.n_exposures))

    def capture(self, profile, rng: np.random.Generator):
        """Simulate the HDR bracket of a true profile and merge it.

        Parameters
        ----------
        profile : array_like, shape (..., F, 3)
            True R(r) at the fibre distances, mm⁻², per channel.
        rng : numpy.random.Generator

        Returns
        -------
        measured, std : ndarray, shape of ``profile``
            The HDR-merged R(r) and its standard deviation under the noise model,
            mm⁻² (NaN where every exposure clipped).
        """
        p = as_finite(profile, "profile", 0, None, unit="mm^-2", dtype=np.float64)
        if p.ndim < 2 or p.shape[-2] != self.n_fibers:
            raise ValidationError(f"profile must have shape (..., {self.n_fibers}, 3), got {p.shape}")
        dn = expose(p * self.scale, self.exposure_times, self.camera, rng, dtype=np.float64)
        rate, std, _ = merge_exposures(dn, self.exposure_times, self.camera)
        return rate / self.scale, std / self.scale

    def profile_std(self, profile):
        """Noise model: standard deviation of a measured R(r) whose true value is ``profile`` (mm⁻²).

        :func:`facestats.acquire.hdr.merged_std` of the expected electron rate
        ``profile × scale`` over the bracket, divided by ``scale``; inf where every
        exposure would clip.

        Parameters
        ----------
        profile : array_like
            True R(r), mm⁻², any shape (e.g. (..., F, 3)); negative values count as 0.

        Returns
        -------
        ndarray of float64, shape of ``profile``
            Standard deviation, mm⁻².
        """
        p = np.asarray(profile, dtype=np.float64)
        return merged_std(p * self.scale, self.exposure_times, self.camera) / self.scale

    def to_attrs(self) -> dict:
        """JSON-serialisable description (stored as provenance of sensor data)."""
        return {
            "fiber_distance_mm": self.fiber_distance.tolist(),
            "n_exposures": self.n_exposures,
            "stop": self.stop,
            "shortest_exposure_s": self.shortest_exposure,
            "scale_e_per_s_per_mm-2": self.scale,
            "camera": {
                "full_well": self.camera.full_well,
                "read_noise": self.camera.read_noise,
                "adc_bits": self.camera.adc_bits,
                "saturation": self.camera.saturation,
                "black_level": self.camera.black_level,
            },
        }

    @classmethod
    def from_attrs(cls, attrs: dict) -> "ContactSensor":
        """Inverse of :meth:`to_attrs`.

        Parameters
        ----------
        attrs : dict
            As :meth:`to_attrs` writes it; ``camera`` may be absent (the default :class:`CameraResponse`), the
            other keys are required.

        Returns
        -------
        ContactSensor

        Raises
        ------
        FormatError
            ``attrs`` not a dict, a required key missing (named), or a field of the wrong type.
        ValidationError
            A value out of its domain (the constructor's and :class:`CameraResponse`'s checks).
        """
        if not isinstance(attrs, dict):
            raise FormatError(f"contact sensor description must be a JSON object, got {type(attrs).__name__}")
        try:
            cam = attrs.get("camera", {})
            return cls(
                fiber_distance=np.asarray(attrs["fiber_distance_mm"], float),
                n_exposures=int(attrs["n_exposures"]),
                stop=float(attrs["stop"]),
                shortest_exposure=float(attrs["shortest_exposure_s"]),
                scale=float(attrs["scale_e_per_s_per_mm-2"]),
                camera=CameraResponse(**cam) if cam else CameraResponse(),
            )
        except KeyError as exc:
            raise FormatError(f"contact sensor description is missing the key {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ValidationError):
                raise
            raise FormatError(f"contact sensor description has a malformed field: {exc}") from None
