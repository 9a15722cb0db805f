"""Camera exposure, noise and high-dynamic-range merging.

Both devices of Weyrich et al. 2006 record HDR data from bracketed exposures: the
dome repeats its light sequence with two exposure settings (§5) and the contact
sensor takes 23 images 2/3 stop apart (§5.4).  This module holds the one camera
model both use:

* signal: the expected photo-electron count is ``rate × t`` for an exposure time
  ``t`` (``rate`` in electrons per unit time);
* noise: shot noise (variance = mean electrons, Gaussian approximation of the
  Poisson distribution, good above ~20 e⁻) plus Gaussian read noise and the
  quantisation noise of one DN, the linear camera model of the EMVA Standard 1288
  (Release 3.1, §2: σ_y² = K²σ_d² + σ_q² + K(μ_y − μ_y,dark), σ_q² = 1/12 DN²),
  written here in electrons: Var = e + σ_read² + g²/12 with g = 1/K electrons per DN;
* response: linear, quantised by an ``adc_bits`` converter whose full scale is
  the full-well capacity, with a black level (pedestal) of ``black_level`` DN so
  that noise below zero signal is recorded rather than clipped (merges subtract
  it, leaving dark readings unbiased); values at or above ``saturation`` of full
  scale are clipped and unusable;
* merge: each unclipped exposure gives an independent estimate (DN − black)·g/t
  of the rate, of variance Var_j/t_j²; they are combined with inverse-variance
  weights t_j²/Var_j, the minimum-variance unbiased combination of a linear camera's
  exposures (Granados et al. 2010, "Optimal HDR reconstruction with linear digital
  cameras", CVPR; Debevec & Malik 1997's hat weights, eq. 6, are for an unknown
  non-linear response and serve :mod:`facestats.acquire.response`).  The weights are
  evaluated at a first estimate Σ_j (DN_j − black)·g / Σ_j t_j (total electrons over
  total time: the maximum-likelihood rate of Poisson counts), so that they do not
  depend on the noise of each value.

Photographs from cameras with an unknown or non-linear response (8-bit JPEG/PNG,
16-bit PNG/TIFF) go through Debevec & Malik's response recovery and weighted
radiance merge instead: :func:`recover_response` and :func:`merge_photographs`,
implemented in :mod:`facestats.acquire.response` and exposed here beside the
linear-raw merge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.acquire.response import merge_photographs, recover_response
from facestats.core.compiled import resolve_backend
from facestats.core.validate import as_finite
from facestats.errors import ValidationError

__all__ = ["CameraResponse", "expose", "merge_exposures", "merged_std", "recover_response", "merge_photographs"]


@dataclass(frozen=True)
class CameraResponse:
    """Linear camera with shot and read noise and a quantising ADC.

    Parameters
    ----------
    full_well : float
        Full-well capacity in electrons (mapped to the ADC's full scale).
    read_noise : float
        Read noise in electrons (rms).
    adc_bits : int
        ADC resolution.
    saturation : float
        Fraction of full scale above which a value counts as clipped.
    black_level : float
        Pedestal added to every reading, DN.
    """

    full_well: float = 20000.0
    read_noise: float = 5.0
    adc_bits: int = 12
    saturation: float = 0.95
    black_level: float = 64.0

    def __post_init__(self):
        if not (
            self.full_well > 0
            and self.read_noise >= 0
            and 1 <= self.adc_bits <= 24
            and 0 < self.saturation <= 1
            and 0 <= self.black_level < 2**self.adc_bits - 1
        ):
            raise ValidationError(
                "CameraResponse needs full_well > 0, read_noise >= 0, adc_bits in [1, 24], saturation in (0, 1] "
                f"and black_level in [0, 2**adc_bits - 1), got {self!r}"
            )

    @property
    def max_dn(self) -> int:
        """Largest digital number."""
        return 2**self.adc_bits - 1

    @property
    def gain(self) -> float:
        """Electrons per digital number."""
        return self.full_well / self.max_dn

    def variance(self, electrons):
        """Variance (e⁻²) of a reading with ``electrons`` expected: shot + read + quantisation.

        max(e, 0) + σ_read² + g²/12 (Poisson shot noise, Gaussian read noise and the
        uniform quantisation error of one DN of g electrons: EMVA 1288 Release 3.1 §2,
        in electrons instead of DN); float input keeps its dtype.

        Parameters
        ----------
        electrons : array_like
            Expected signal in electrons, any shape; negative values count as 0 in the shot noise.

        Returns
        -------
        ndarray
            Variance in e⁻², the shape of ``electrons``; its dtype if float, else float64.
        """
        e = np.asarray(electrons)
        if e.dtype.kind == "f":
            return np.maximum(e, 0) + e.dtype.type(self.read_noise**2 + self.gain**2 / 12)
        return np.maximum(e, 0) + self.read_noise**2 + self.gain**2 / 12


def expose(rate, times, response: CameraResponse, rng: np.random.Generator, dtype=np.float32, backend: str = "auto"):
    """Simulate readings (digital numbers) of a signal for each exposure time.

    DN = clip(rint((e + √(e + σ_read²) z)/g + black), 0, max_dn) with e = rate·t and z
    standard normal: the noise model of :meth:`CameraResponse.variance` (shot noise in
    its Gaussian approximation, read noise), quantised by the ADC's rounding, which adds
    the g²/12 term.

    Parameters
    ----------
    rate : array_like
        Expected electrons per unit exposure time, ≥ 0, any shape.
    times : array_like, shape (E,)
        Exposure times (same time unit as ``rate``).
    response : CameraResponse
    rng : numpy.random.Generator
        Source of the noise (seed it for reproducible captures).
    dtype : {numpy.float32, numpy.float64}
        Computation and output dtype (float32 draws float32 normals).
    backend : {"auto", "numba", "numpy"}
        Where the readings are formed from the normal draws: one compiled sweep
        (:func:`facestats.acquire.hdr_numba.expose_pass`) or whole-array passes; the draws
        and the bits of the readings are the same either way.

    Returns
    -------
    ndarray, shape ``rate.shape + (E,)``
        Quantised readings in DN, clipped to [0, max_dn], as ``dtype``.
    """
    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise ValidationError(f"dtype must be float32 or float64, got {dtype}")
    r = np.asarray(rate, dtype=dtype)
    if r.size and not (np.min(r) >= 0 and np.isfinite(np.max(r))):  # reductions only: no temporaries
        raise ValidationError(
            f"rate must be finite and >= 0 electrons per unit time, got values in [{np.min(r)!r}, {np.max(r)!r}]"
        )
    as_finite(times, "times", 0, None, low_inclusive=False)
    t = np.asarray(times, dtype=np.float64)
    out = np.empty((t.size,) + r.shape, dtype)
    read2 = dtype.type(response.read_noise**2)
    inv_gain = dtype.type(1 / response.gain)
    black = dtype.type(response.black_level)
    compiled = resolve_backend(backend) == "numba"
    if compiled:
        from facestats.acquire.hdr_numba import expose_pass  # imports numba: only when a capture is exposed
    for j, tj in enumerate(t):  # loop over exposures, vectorised over samples
        e = rng.standard_normal(r.shape, dtype=np.float32 if dtype == np.float32 else np.float64)
        if compiled:
            expose_pass(
                r.ravel(),
                dtype.type(tj),
                e.ravel(),
                read2,
                inv_gain,
                black,
                dtype.type(response.max_dn),
                out[j].reshape(-1),
            )
            continue
        mean = r * dtype.type(tj)
        e *= np.sqrt(mean + read2)
        e += mean
        e *= inv_gain
        e += black
        np.rint(e, out=e)
        np.clip(e, 0, response.max_dn, out=out[j])
    return np.moveaxis(out, 0, -1)


def merge_exposures(dn, times, response: CameraResponse, backend: str = "auto"):
    """Merge bracketed readings into an HDR rate estimate with its noise.

    rate = Σ_j w_j (DN_j − black)·g/t_j / Σ_j w_j and std = 1/√(Σ_j w_j) over the
    unclipped exposures (DN_j < ``saturation`` × max_dn), with the inverse-variance weights
    w_j = t_j²/Var(rate₀·t_j) of Granados et al. 2010 evaluated at the
    time-weighted first estimate rate₀ = Σ_j (DN_j − black)·g / Σ_j t_j (module docstring).
    Units: ``rate`` in electrons per unit of ``times``.

    Parameters
    ----------
    dn : array_like, shape (..., E)
        Readings in DN for E exposures (:func:`expose`).
    times : array_like, shape (E,)
        Exposure times.
    response : CameraResponse
    backend : {"auto", "numba", "numpy"}
        ``"numba"`` (:mod:`facestats.acquire.hdr_numba`): one sweep over the readings, about
        five times faster; ``"numpy"``: whole-array passes.  Both give the same bits
        (the same float operations in the same order); ``"auto"`` takes numba where it imports.

    Returns
    -------
    rate : ndarray, shape (...)
        Estimated electrons per unit time; NaN where every exposure is clipped.
    std : ndarray, shape (...)
        Its standard deviation under the noise model.
    n_used : ndarray of int, shape (...)
        Number of unclipped exposures that contributed.
    """
    d = np.asarray(dn)
    t = as_finite(times, "times", 0, None, low_inclusive=False)
    if t.ndim != 1:
        raise ValidationError(f"times must be a 1-D array of exposure times, got shape {t.shape}")
    if d.ndim < 1 or d.shape[-1] != t.shape[0]:
        raise ValidationError(f"dn must have {t.shape[0]} exposures on its last axis, got shape {d.shape}")
    dtype = d.dtype if d.dtype in (np.float32, np.float64) else np.dtype(np.float64)
    d = np.moveaxis(d, -1, 0)  # (E, ...): each exposure's slice is a whole array
    sat = response.saturation * response.max_dn
    if resolve_backend(backend) == "numba":
        from facestats.acquire.hdr_numba import merge_pass  # imports numba: only when a merge runs

        flat = np.ascontiguousarray(d, dtype).reshape(t.size, -1)
        rate, std = np.empty(flat.shape[1], dtype), np.empty(flat.shape[1], dtype)
        n_used = np.empty(flat.shape[1], np.int16)
        var0 = response.variance(np.zeros((), dtype))  # σ_read² + g²/12 in the readings' dtype
        merge_pass(
            flat,
            t.astype(dtype),
            dtype.type(sat),
            dtype.type(response.gain),
            dtype.type(response.black_level),
            var0,
            rate,
            std,
            n_used,
        )
        shape = d.shape[1:]
        return rate.reshape(shape), std.reshape(shape), n_used.reshape(shape)
    return _merge_numpy(d, t, response, dtype, sat)


def _merge_numpy(d, t, response, dtype, sat):
    """The numpy twin of :func:`facestats.acquire.hdr_numba.merge_pass` for readings ``d`` of shape (E, ...)."""
    gain = dtype.type(response.gain)
    black = dtype.type(response.black_level)
    shape = d.shape[1:]
    # First pass: time-weighted mean of the unclipped estimates (weights ∝ t: total electrons over total time).
    num = np.zeros(shape, dtype)
    den = np.zeros(shape, dtype)
    n_used = np.zeros(shape, np.int16)
    for j, tj in enumerate(t):
        ok = d[j] < sat
        n_used += ok
        num += np.where(ok, (d[j] - black) * gain, 0)  # t·((DN − black)·g/t)
        den += np.where(ok, dtype.type(tj), 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rate0 = np.maximum(num / den, 0)
    # Second pass: inverse-variance weights from the first estimate.
    num[...] = 0
    wsum = np.zeros(shape, dtype)
    for j, tj in enumerate(t):
        ok = d[j] < sat
        tj = dtype.type(tj)
        w = np.where(ok, tj * tj / response.variance(rate0 * tj).astype(dtype, copy=False), 0)
        num += w * ((d[j] - black) * gain / tj)
        wsum += w
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = num / wsum
        std = 1 / np.sqrt(wsum)
    none = n_used == 0
    rate[none] = np.nan
    std[none] = np.nan
    return rate, std, n_used


def merged_std(rate, times, response: CameraResponse):
    """Expected standard deviation of :func:`merge_exposures` for a true ``rate``.

    1/sqrt(Σ_j t_j²/Var_j) over the exposures that do not clip at the expected
    signal, Var_j = rate·t_j + σ_read² + g²/12: the standard deviation of the
    inverse-variance mean of independent estimates (Granados et al. 2010), with the
    weights at the true rate instead of the merge's first estimate.  This is the noise model the
    translucency fit and the Bayesian posterior use.  An exposure clips as the
    merge decides it: a reading black + e/g at or above ``saturation`` × the full
    scale, i.e. e ≥ (saturation · max_dn − black_level) · g electrons (18,687 e⁻
    for the default camera).  Before 2026-12-06 the test was e ≥ saturation ×
    full_well (19,000 e⁻), which counted exposures the merge drops: fibres whose
    signal fell between the two were 1.06-1.28 × noisier than modelled (an audit).

    Parameters
    ----------
    rate : array_like, shape (...)
        True rate in electrons per unit of ``times`` (negative values count as 0).
    times : array_like, shape (E,)
        Exposure times.
    response : CameraResponse

    Returns
    -------
    ndarray of float64, shape (...)
        Standard deviation of the merged rate (electrons per unit time); inf where every exposure clips.
    """
    r = np.asarray(rate, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    mean = np.maximum(r, 0)[..., None] * t
    ok = mean < (response.saturation * response.max_dn - response.black_level) * response.gain
    w = np.where(ok, t * t / response.variance(mean), 0)
    with np.errstate(divide="ignore"):
        return 1 / np.sqrt(np.sum(w, axis=-1))
