"""Calibration of a face-scanning dome: LEDs, their beam spread, and cameras.

Weyrich et al. 2006 §5: 16 cameras and 150 LEDs on a geodesic dome; each LED's
radiance is calibrated against a white diffuse reflector and its beam spread is
modelled "by a bi-variate 2nd degree polynomial".  A :class:`Dome` holds such a
calibration; real rigs are described with the same object (:meth:`Dome.from_dict`
/ :meth:`Dome.load` of a JSON file), the simulator's default rig with
:func:`default_dome`.

Conventions: world frame of :mod:`facestats.face.geometry` (mm, +y up, +z towards
the frontal camera).  Irradiance is in *dome units*: the calibrated LEDs give
E⊥ ≈ 1 at the head on their axis; radiance is in dome units per sr.  Only
ratios L/E enter the model, so the unit needs no physical scale.

LED beam model: an LED at p with unit axis a emits towards direction d (unit,
from the LED) the radiant intensity

    I(d) = I₀ · P(s, t),  P = c₀ + c₁ s + c₂ t + c₃ s² + c₄ s t + c₅ t²,

where (s, t) = (d·e₁, d·e₂)/(d·a) are the beam-plane (tangent) coordinates of d
in an orthonormal frame (e₁, e₂, a) of the LED, and I₀ is the RGB intensity.
The irradiance on a surface with normal N at distance r is E = I(d) (N·ωi)/r²
(point source, inverse-square law); E⊥ = I(d)/r² is the irradiance normal to
the beam.

Camera model: OpenCV's pinhole camera with Brown-Conrady distortion (the layout
and equations of OpenCV's ``calib3d`` module, so calibrations made with
``cv2.calibrateCamera`` load unchanged).  A world point X (mm) has camera
coordinates x_c = R X + t with R the world-to-camera rotation (rows: camera x
right, y down, z forward) and t = −R C for the camera centre C; its normalised
coordinates (x_c/z_c, y_c/z_c) are distorted to (x'', y'') by
:func:`facestats.acquire.lens.distort_normalised` with ``dist`` =
(k₁, k₂, p₁, p₂[, k₃[, k₄, k₅, k₆]]), and the pixel is (u, v) = K (x'', y'', 1)
(pixel centres at integer coordinates, as in OpenCV).  ``camera_gain`` (C, 3)
converts a camera's merged photograph values to the reference camera's units
(1 for the reference; :mod:`facestats.acquire.calibration` fits it), and
``camera_log_response`` holds the Debevec-Malik response g of the cameras'
photographs (:mod:`facestats.acquire.response`), when they are not linear raw,
and ``camera_black_level`` the pedestal (DN) it was recovered above: codes at
and below it get no weight when the photographs are merged (0: none);
``camera_white_level`` the code (DN) at which the cameras clip, that it was
recovered below: codes at and above it get no weight (None: the top code).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace

import numpy as np

from facestats.acquire.camera import look_at
from facestats.acquire.geodesic import farthest_point_subset, geodesic_points
from facestats.acquire.hdr import CameraResponse
from facestats.acquire.lens import distort_normalised, undistort_normalised
from facestats.acquire.response import check_rising
from facestats.core.compiled import resolve_backend
from facestats.core.published import N_CAMERAS, N_LEDS
from facestats.core.validate import (
    as_finite,
    as_float,
    check_integer,
    check_range,
    check_shape,
    check_unit_vectors,
)
from facestats.errors import FormatError, ValidationError

__all__ = ["Dome", "default_dome", "beam_terms"]


def beam_terms(s, t) -> np.ndarray:
    """The monomials (1, s, t, s², s t, t²) of the LED beam polynomial (module docstring), last axis of length 6.

    Parameters
    ----------
    s, t : ndarray, same shape (...)
        Beam-plane (tangent) coordinates of directions from the LED.

    Returns
    -------
    ndarray, shape (..., 6)
    """
    return np.stack([np.ones_like(s), s, t, s * s, s * t, t * t], axis=-1)


def _tangent_frames(axis):
    """Orthonormal (e1, e2) perpendicular to each unit axis."""
    ref = np.where(np.abs(axis[:, 1:2]) < 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(ref, axis)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(axis, e1)
    return e1, e2


@dataclass
class Dome:
    """Calibration of the LEDs and cameras of a dome.

    Attributes
    ----------
    led_position : ndarray, shape (L, 3)
        LED positions, mm.
    led_axis : ndarray, shape (L, 3)
        Unit beam axes.
    led_intensity : ndarray, shape (L, 3)
        On-axis RGB radiant intensity I₀ (dome units · mm²).
    led_beam : ndarray, shape (L, 6)
        Beam-spread polynomial coefficients c₀..c₅ (module docstring).
    camera_position : ndarray, shape (C, 3)
        Camera centres, mm.
    camera_rotation : ndarray, shape (C, 3, 3)
        World-to-camera rotations (rows x right, y down, z forward).
    camera_matrix : ndarray, shape (C, 3, 3)
        Pinhole intrinsics K (pixels).
    image_size : ndarray of int, shape (C, 2)
        Width, height in pixels.
    exposure_times : ndarray, shape (E,)
        HDR exposure times (s) of the two passes (§5).
    camera_scale : float
        Electrons per second of exposure per (dome unit / sr) of radiance; for
        photographs, merged value exp(g)/s per dome unit of the reference camera.
    response : CameraResponse
        Camera noise and ADC model.
    camera_distortion : ndarray, shape (C, 8), optional
        OpenCV distortion (k₁, k₂, p₁, p₂, k₃, k₄, k₅, k₆) (module docstring);
        default none.  4 or 5 coefficients are padded with zeros.
    camera_gain : ndarray, shape (C, 3), optional
        Radiometric gain of each camera and channel relative to the reference
        camera (default 1).
    camera_log_response : ndarray, shape (C, levels, 3), optional
        Debevec-Malik g = ln f⁻¹ of each camera's photographs (levels = 2^bits).
    camera_black_level : int
        The photographs' pedestal in DN, shared by the cameras, that ``camera_log_response`` was
        recovered above (:func:`facestats.acquire.response.recover_response`, ``black_level``);
        0 ≤ it < levels / 2.  JSON field ``camera_black_level`` (absent: 0).
    camera_white_level : int or None
        The code in DN, shared by the cameras, at and above which their photographs clip (Z_max of the hat
        weights of Debevec & Malik 1997 eq. 4) and below which ``camera_log_response`` was recovered
        (:func:`facestats.acquire.response.recover_response`, ``white_level``); levels / 2 < it ≤ levels − 1,
        or None for the top code levels − 1.  JSON field ``camera_white_level`` (absent: None).
    """

    led_position: np.ndarray
    led_axis: np.ndarray
    led_intensity: np.ndarray
    led_beam: np.ndarray
    camera_position: np.ndarray
    camera_rotation: np.ndarray
    camera_matrix: np.ndarray
    image_size: np.ndarray
    exposure_times: np.ndarray
    camera_scale: float
    response: CameraResponse = CameraResponse()
    camera_distortion: np.ndarray | None = None
    camera_gain: np.ndarray | None = None
    camera_log_response: np.ndarray | None = None
    camera_black_level: int = 0
    camera_white_level: int | None = None

    def __post_init__(self):
        def array(name, shape):
            return check_shape(as_finite(getattr(self, name), name, dtype=np.float64), name, shape)

        lp = array("led_position", (None, 3))
        n_led = lp.shape[0]
        la = array("led_axis", (n_led, 3))
        li = check_range(array("led_intensity", (n_led, 3)), "led_intensity", 0, None)
        lb = array("led_beam", (n_led, 6))
        cp = array("camera_position", (None, 3))
        n_cam = cp.shape[0]
        cr = array("camera_rotation", (n_cam, 3, 3))
        ck = array("camera_matrix", (n_cam, 3, 3))
        im = np.asarray(self.image_size, dtype=np.int64)
        if im.shape != (n_cam, 2) or np.any(im <= 0):
            raise ValidationError(f"image_size must be ({n_cam}, 2) positive integers, got shape {im.shape}")
        et = as_float(self.exposure_times, "exposure_times", np.float64)
        if et.ndim != 1 or et.size < 1 or not np.all(et > 0):
            raise ValidationError(f"exposure_times must be a 1-D array of positive times, got {et!r}")
        check_unit_vectors(la, "led_axis", 1e-6)
        rrt = cr @ np.swapaxes(cr, 1, 2)
        if not np.allclose(rrt, np.eye(3), atol=1e-6):
            err = np.abs(rrt - np.eye(3)).max(axis=(1, 2))
            raise ValidationError(
                f"camera_rotation must hold rotation matrices (R Rᵀ = I), got camera {int(np.argmax(err))} "
                f"with |R Rᵀ − I| = {err.max():.3g}"
            )
        if not float(self.camera_scale) > 0:
            raise ValidationError(f"camera_scale must be > 0, got {self.camera_scale!r}")
        self.led_position, self.led_axis, self.led_intensity, self.led_beam = lp, la, li, lb
        self.camera_position, self.camera_rotation, self.camera_matrix = cp, cr, ck
        self.image_size, self.exposure_times = im, et
        self.camera_scale = float(self.camera_scale)
        self._check_camera_extras(n_cam)

    def _check_camera_extras(self, n_cam):
        """Validate and normalise ``camera_distortion``, ``camera_gain``, ``camera_log_response``, its black and
        white levels."""
        if self.camera_distortion is None:
            dist = np.zeros((n_cam, 8))
        else:
            dist = as_finite(self.camera_distortion, "camera_distortion", dtype=np.float64)
            if dist.ndim != 2 or dist.shape[0] != n_cam or dist.shape[1] not in (4, 5, 8):
                raise ValidationError(
                    f"camera_distortion must have shape ({n_cam}, 4|5|8) (OpenCV k1, k2, p1, p2[, k3[, k4, k5, k6]]), "
                    f"got shape {dist.shape}"
                )
            dist = np.pad(dist, ((0, 0), (0, 8 - dist.shape[1])))
        gain = np.ones((n_cam, 3)) if self.camera_gain is None else np.asarray(self.camera_gain, np.float64)
        check_shape(gain, "camera_gain", (n_cam, 3))
        check_range(as_finite(gain, "camera_gain"), "camera_gain", 0, None, low_inclusive=False)
        resp = self.camera_log_response
        if resp is not None:
            resp = np.asarray(resp, np.float64)
            if resp.ndim == 2:
                resp = np.broadcast_to(resp, (n_cam,) + resp.shape)
            levels = resp.shape[1] if resp.ndim == 3 else 0
            if resp.ndim != 3 or resp.shape[0] != n_cam or resp.shape[2] != 3 or levels < 2 or levels & (levels - 1):
                raise ValidationError(
                    f"camera_log_response must have shape ({n_cam}, levels, 3) with levels = 2^bits, "
                    f"got shape {np.shape(self.camera_log_response)}"
                )
            if not np.all(np.isfinite(resp)):
                raise ValidationError("camera_log_response must be finite, got NaN or inf")
            for cam in range(n_cam):  # a handful of cameras, each checked vectorised
                check_rising(resp[cam], 0, f"camera_log_response of camera {cam}")
        levels = None if resp is None else resp.shape[1]
        self.camera_black_level = check_integer(
            self.camera_black_level, "camera_black_level", 0, None if levels is None else levels // 2 - 1
        )
        if self.camera_white_level is not None:  # above levels / 2 (where g is pinned), at most the top code
            low = self.camera_black_level + 1 if levels is None else levels // 2 + 1
            self.camera_white_level = check_integer(
                self.camera_white_level, "camera_white_level", low, None if levels is None else levels - 1
            )
        self.camera_distortion, self.camera_gain, self.camera_log_response = dist, gain, resp

    @property
    def n_leds(self) -> int:
        return int(self.led_position.shape[0])

    @property
    def n_cameras(self) -> int:
        return int(self.camera_position.shape[0])

    # -- photometry -------------------------------------------------------------
    def beam_coordinates(self, points, leds=None):
        """Where ``points`` lie in the LEDs' beams (module docstring).

        Parameters
        ----------
        points : ndarray, shape (N, 3)
            Surface points, mm.
        leds : array_like of int, optional
            Subset of LEDs (default all); L is its length.

        Returns
        -------
        wi : ndarray, shape (N, L, 3)
            Unit directions from the points towards the LEDs.
        r2 : ndarray, shape (N, L)
            Squared distances, mm².
        s, t : ndarray, shape (N, L)
            Beam-plane coordinates (d·e₁, d·e₂)/(d·a) of the direction d from the LED.
        front : ndarray of bool, shape (N, L)
            The point lies in front of the LED (d·a > 0).
        """
        sel = slice(None) if leds is None else np.asarray(leds)
        la = self.led_axis[sel]
        wi, r2, _ = self._towards(self.led_position[sel], points)
        d_unit = -wi  # LED -> point
        e1, e2 = _tangent_frames(la)
        ca = np.einsum("nlk,lk->nl", d_unit, la)
        front = ca > 1e-6
        ca_s = np.where(front, ca, 1.0)
        s = np.einsum("nlk,lk->nl", d_unit, e1) / ca_s
        t = np.einsum("nlk,lk->nl", d_unit, e2) / ca_s
        return wi, r2, s, t, front

    def incident(self, points, leds=None):
        """Directions towards the LEDs and the beam-normal irradiance E⊥ = I(d)/r² at ``points``.

        Parameters
        ----------
        points : ndarray, shape (N, 3)
            Surface points, mm.
        leds : array_like of int, optional
            Subset of LEDs (default all).

        Returns
        -------
        wi : ndarray, shape (N, L, 3)
            Unit directions from the points towards the LEDs.
        e_perp : ndarray, shape (N, L, 3)
            RGB irradiance on a plane facing the LED (dome units); 0 where the
            point lies behind the LED's emitting hemisphere.
        """
        sel = slice(None) if leds is None else np.asarray(leds)
        wi, r2, s, t, front = self.beam_coordinates(points, leds)
        poly = np.einsum("nlk,lk->nl", beam_terms(s, t), self.led_beam[sel])
        gain = np.where(front, np.maximum(poly, 0), 0) / r2
        return wi, gain[..., None] * self.led_intensity[sel][None, :, :]

    def select(self, leds=None, cameras=None) -> "Dome":
        """The rig restricted to some LEDs and/or cameras (indices; default all).

        Parameters
        ----------
        leds : array_like of int, optional
            Indices of the LEDs to keep, in that order (default all).
        cameras : array_like of int, optional
            Indices of the cameras to keep, in that order (default all); their distortion, gain and response go
            with them.

        Returns
        -------
        Dome
            A new calibration; this one is not modified.
        """

        lsel = slice(None) if leds is None else np.asarray(leds)
        csel = slice(None) if cameras is None else np.asarray(cameras)
        return replace(
            self,
            led_position=self.led_position[lsel],
            led_axis=self.led_axis[lsel],
            led_intensity=self.led_intensity[lsel],
            led_beam=self.led_beam[lsel],
            camera_position=self.camera_position[csel],
            camera_rotation=self.camera_rotation[csel],
            camera_matrix=self.camera_matrix[csel],
            image_size=self.image_size[csel],
            camera_distortion=self.camera_distortion[csel],
            camera_gain=self.camera_gain[csel],
            camera_log_response=None if self.camera_log_response is None else self.camera_log_response[csel],
        )

    @staticmethod
    def _towards(targets, points):
        """Unit directions (N, T, 3) from ``points`` (N, 3) towards ``targets`` (T, 3).

        Also returns the squared distances (N, T) and the offsets (N, T, 3).
        """
        d = targets[None, :, :] - np.asarray(points, np.float64)[:, None, :]
        r2 = np.einsum("ntk,ntk->nt", d, d)
        return d / np.sqrt(r2)[..., None], r2, d

    def light_directions(self, points):
        """Unit directions (N, L, 3) from ``points`` (N, 3, mm) towards every LED (the ``wi`` of :meth:`incident`).

        Parameters
        ----------
        points : array_like, shape (N, 3)
            World points, mm.

        Returns
        -------
        ndarray of float64, shape (N, L, 3)
        """
        return self._towards(self.led_position, points)[0]

    def view_directions(self, points):
        """Unit directions (N, C, 3) from ``points`` (N, 3, mm) towards every camera centre (``wo`` of :meth:`view`).

        Parameters
        ----------
        points : array_like, shape (N, 3)
            World points, mm.

        Returns
        -------
        ndarray of float64, shape (N, C, 3)
        """
        return self._towards(self.camera_position, points)[0]

    def directions32(self, points, backend="auto"):
        """(ωi (N, L, 3), ωo (N, C, 3)) from ``points`` (N, 3, mm): :meth:`light_directions` and
        :meth:`view_directions` rounded to float32 (as the fit stores them).

        Parameters
        ----------
        points : array_like, shape (N, 3)
            World points, mm.
        backend : {"auto", "numba", "numpy"}
            :data:`facestats.core.compiled.BACKENDS`: ``"numba"`` computes them in one compiled
            pass (:func:`facestats.acquire.dome_numba.unit_directions32`, the same float64 arithmetic, so the
            same bits) without the float64 (N, T, 3) temporaries; ``"auto"`` uses it when numba imports (the fit's
            engine setting does not choose here: both give the same bits).

        Returns
        -------
        wi : ndarray of float32, shape (N, L, 3)
        wo : ndarray of float32, shape (N, C, 3)

        Raises
        ------
        ValidationError
            ``points`` not of shape (N, 3), an unknown ``backend``, or ``"numba"`` when numba cannot be used.
        """
        pts = np.ascontiguousarray(points, np.float64)
        check_shape(pts, "points", (None, 3))
        if resolve_backend(backend) == "numba":
            from facestats.acquire.dome_numba import unit_directions32  # imports numba: only when used

            led, cam = (np.ascontiguousarray(x, np.float64) for x in (self.led_position, self.camera_position))
            return unit_directions32(led, pts), unit_directions32(cam, pts)
        return self.light_directions(pts).astype(np.float32), self.view_directions(pts).astype(np.float32)

    def resized(self, width: int, height: int) -> "Dome":
        """The same rig with every camera's image resampled to ``width`` × ``height`` pixels (K scaled, pixel
        centres at integers: u' = (u + ½)·s − ½).

        Parameters
        ----------
        width, height : int
            The new image size in pixels, the same for every camera; s is its ratio to each camera's old size.

        Returns
        -------
        Dome
            A new calibration with ``camera_matrix`` and ``image_size`` changed.
        """

        sx = int(width) / self.image_size[:, 0]
        sy = int(height) / self.image_size[:, 1]
        k = self.camera_matrix.copy()
        k[:, 0, :] *= sx[:, None]
        k[:, 1, :] *= sy[:, None]
        k[:, 0, 2] += 0.5 * sx - 0.5
        k[:, 1, 2] += 0.5 * sy - 0.5
        size = np.tile([int(width), int(height)], (self.n_cameras, 1))
        return replace(self, camera_matrix=k, image_size=size)

    @property
    def camera_translation(self) -> np.ndarray:
        """OpenCV extrinsic translations t = −R C, shape (C, 3), mm."""
        return -np.einsum("cij,cj->ci", self.camera_rotation, self.camera_position)

    def project(self, points, cameras=None):
        """Pixel coordinates of world points in the cameras, with lens distortion (module docstring).

        Parameters
        ----------
        points : ndarray, shape (N, 3)
            World points, mm.
        cameras : array_like of int, optional
            Subset of cameras (default all).

        Returns
        -------
        pixel : ndarray, shape (N, C, 2)
            (u, v) in pixels, OpenCV convention (pixel centres at integers); NaN
            behind the camera.
        depth : ndarray, shape (N, C)
            z in camera coordinates, mm (≤ 0 behind the camera).
        """
        sel = slice(None) if cameras is None else np.asarray(cameras)
        rot, pos = self.camera_rotation[sel], self.camera_position[sel]
        k, dist = self.camera_matrix[sel], self.camera_distortion[sel]
        cam = np.einsum("cij,ncj->nci", rot, np.asarray(points, np.float64)[:, None, :] - pos[None])
        z = cam[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xd, yd = distort_normalised(cam[..., 0] / z, cam[..., 1] / z, dist[None])
        u = k[None, :, 0, 0] * xd + k[None, :, 0, 1] * yd + k[None, :, 0, 2]
        v = k[None, :, 1, 1] * yd + k[None, :, 1, 2]
        pix = np.stack([u, v], -1)
        pix[z <= 0] = np.nan
        return pix, z

    def view(self, points, cameras=None):
        """Unit directions from ``points`` towards the camera centres and whether each point is in frame.

        Parameters
        ----------
        points : ndarray, shape (N, 3)
            World points, mm.
        cameras : array_like of int, optional
            Subset of cameras (default all); C is its length.

        Returns
        -------
        wo : ndarray, shape (N, C, 3)
        in_frame : ndarray of bool, shape (N, C)
            In front of the camera and inside its image (pixel centres at integer
            coordinates: the image spans [−½, W − ½) × [−½, H − ½)).
        pixel : ndarray, shape (N, C, 2)
            Image coordinates (u, v) in pixels (:meth:`project`).
        """
        sel = slice(None) if cameras is None else np.asarray(cameras)
        wo, _, _ = self._towards(self.camera_position[sel], points)
        pix, z = self.project(points, cameras)
        im = self.image_size[sel]
        with np.errstate(invalid="ignore"):
            in_frame = (
                (z > 0)
                & (pix[..., 0] >= -0.5)
                & (pix[..., 1] >= -0.5)
                & (pix[..., 0] < im[None, :, 0] - 0.5)
                & (pix[..., 1] < im[None, :, 1] - 0.5)
            )
        return wo, in_frame, pix

    def pixel_rays(self, camera: int, pixels) -> np.ndarray:
        """Unit world directions (N, 3) of the rays through ``pixels`` (N, 2) of one camera (distortion undone).

        Parameters
        ----------
        camera : int
            Index of the camera.
        pixels : array_like, shape (N, 2)
            Image coordinates (u, v) in pixels, OpenCV convention (pixel centres at integers).

        Returns
        -------
        ndarray of float64, shape (N, 3)
            Unit directions in the world frame, from the camera centre into the scene.
        """
        k = self.camera_matrix[camera]
        px = np.asarray(pixels, np.float64)
        yd = (px[:, 1] - k[1, 2]) / k[1, 1]
        xd = (px[:, 0] - k[0, 2] - k[0, 1] * yd) / k[0, 0]
        x, y = undistort_normalised(xd, yd, self.camera_distortion[camera])
        d = np.stack([x, y, np.ones_like(x)], -1) @ self.camera_rotation[camera]  # Rᵀ (x, y, 1)
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    # -- serialisation ------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-serialisable calibration; cameras in OpenCV's layout (``K``, ``dist``, ``R``, ``t``)."""
        r = self.response
        out = {
            "led_position_mm": self.led_position.tolist(),
            "led_axis": self.led_axis.tolist(),
            "led_intensity": self.led_intensity.tolist(),
            "led_beam_polynomial": self.led_beam.tolist(),
            "cameras": [self.camera_dict(c) for c in range(self.n_cameras)],
            "exposure_times_s": self.exposure_times.tolist(),
            "camera_scale": self.camera_scale,
            "response": {
                "full_well": r.full_well,
                "read_noise": r.read_noise,
                "adc_bits": r.adc_bits,
                "saturation": r.saturation,
                "black_level": r.black_level,
            },
        }
        if self.camera_log_response is not None:
            g = self.camera_log_response
            shared = bool(np.all(g == g[:1]))
            out["camera_log_response"] = (g[0] if shared else g).tolist()
        if self.camera_black_level:
            out["camera_black_level"] = self.camera_black_level
        if self.camera_white_level is not None:
            out["camera_white_level"] = self.camera_white_level
        return out

    def camera_dict(self, c: int) -> dict:
        """Camera ``c`` as OpenCV names it: ``K``, ``dist`` (5 or 8), ``R``, ``t`` (mm), image size, gain.

        Parameters
        ----------
        c : int
            Index of the camera.

        Returns
        -------
        dict
            JSON-ready: ``K``, ``dist``, ``R``, ``t``, ``image_width``, ``image_height`` and ``gain`` (RGB).
        """
        dist = self.camera_distortion[c]
        return {
            "K": self.camera_matrix[c].tolist(),
            "dist": (dist if np.any(dist[5:]) else dist[:5]).tolist(),
            "R": self.camera_rotation[c].tolist(),
            "t": self.camera_translation[c].tolist(),
            "image_width": int(self.image_size[c, 0]),
            "image_height": int(self.image_size[c, 1]),
            "gain": self.camera_gain[c].tolist(),
        }

    @staticmethod
    def _cameras_from_dict(d: dict) -> dict:
        """Camera arrays from the OpenCV layout (``cameras``) or the legacy arrays of facestats < 0.5."""
        if "cameras" not in d:
            return {
                "camera_position": np.asarray(d["camera_position_mm"], float),
                "camera_rotation": np.asarray(d["camera_rotation"], float),
                "camera_matrix": np.asarray(d["camera_matrix"], float),
                "image_size": np.asarray(d["image_size"], int),
            }
        cams = d["cameras"]
        if not isinstance(cams, list) or not cams:
            raise FormatError(f"dome calibration field 'cameras' must be a non-empty list, got {cams!r:.60}")
        for i, c in enumerate(cams):
            missing = [k for k in ("K", "R", "t", "image_width", "image_height") if k not in c]
            if missing:
                raise FormatError(f"dome calibration camera {i} is missing the field(s) {missing}")
        rot = np.asarray([c["R"] for c in cams], float)
        t = np.asarray([c["t"] for c in cams], float)
        dists = [np.asarray(c.get("dist", np.zeros(5)), float).reshape(-1) for c in cams]
        bad = [i for i, x in enumerate(dists) if x.size not in (4, 5, 8)]
        if bad:
            raise FormatError(f"dome calibration camera {bad[0]} field 'dist' must hold 4, 5 or 8 coefficients")
        return {
            "camera_position": -np.einsum("cji,cj->ci", rot, t),  # C = −Rᵀ t
            "camera_rotation": rot,
            "camera_matrix": np.asarray([c["K"] for c in cams], float),
            "image_size": np.asarray([[c["image_width"], c["image_height"]] for c in cams], int),
            "camera_distortion": np.asarray([np.pad(x, (0, 8 - x.size)) for x in dists]),
            "camera_gain": np.asarray([c.get("gain", [1.0, 1.0, 1.0]) for c in cams], float),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Dome":
        """Inverse of :meth:`to_dict` (e.g. a real rig's calibration file; legacy camera arrays accepted).

        Parameters
        ----------
        d : dict
            A decoded calibration document as :meth:`to_dict` writes it.

        Returns
        -------
        Dome

        Raises
        ------
        FormatError
            A required key is missing or a field is malformed (the wrong type or shape to read).
        ValidationError
            A field is out of its domain (the checks of the constructor).
        """
        try:
            resp = d.get("camera_log_response")
            return cls(
                led_position=np.asarray(d["led_position_mm"], float),
                led_axis=np.asarray(d["led_axis"], float),
                led_intensity=np.asarray(d["led_intensity"], float),
                led_beam=np.asarray(d["led_beam_polynomial"], float),
                exposure_times=np.asarray(d["exposure_times_s"], float),
                camera_scale=float(d["camera_scale"]),
                response=CameraResponse(**d.get("response", {})),
                camera_log_response=None if resp is None else np.asarray(resp, float),
                camera_black_level=d.get("camera_black_level", 0),
                camera_white_level=d.get("camera_white_level"),
                **cls._cameras_from_dict(d),
            )
        except KeyError as exc:
            raise FormatError(f"dome calibration is missing the key {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ValidationError):
                raise
            raise FormatError(f"dome calibration has a malformed field: {exc}") from None

    def save(self, path):
        """Write the calibration as JSON.

        Parameters
        ----------
        path : str or os.PathLike
            The file to write (replaced if it exists); :meth:`load` reads it.
        """
        with open(path, "w") as f:
            json.dump(self.to_dict(), f)

    @classmethod
    def load(cls, path) -> "Dome":
        """Read a calibration written by :meth:`save` (or by hand for a real rig).

        Parameters
        ----------
        path : str or os.PathLike
            The calibration JSON file.

        Returns
        -------
        Dome

        Raises
        ------
        FormatError
            ``path`` is missing, unreadable, not a regular file (a directory, a FIFO
            or a device, refused without blocking on it), not a JSON object, or
            lacks a field; the message names the file.
        ValidationError
            A field of the calibration is out of its domain (:meth:`from_dict`); the message names the file.
        """
        # local import: keeps facestats.io (the store, 20-odd modules) out of this module's import
        from facestats.io.layout import read_regular_file

        if not isinstance(path, (str, os.PathLike)) or not os.fspath(path):
            raise ValidationError(f"calibration must be the path of a dome calibration file, got {path!r}")
        try:
            doc = json.loads(read_regular_file(path))
        except OSError as exc:
            raise FormatError(f"cannot read dome calibration {os.fspath(path)}: {exc.strerror or exc}") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise FormatError(f"cannot read dome calibration {os.fspath(path)}: not valid JSON ({exc})") from None
        if not isinstance(doc, dict):
            raise FormatError(f"dome calibration {os.fspath(path)} must hold a JSON object, got {type(doc).__name__}")
        try:
            return cls.from_dict(doc)
        except (FormatError, ValidationError) as exc:  # name the file
            raise type(exc)(f"{exc} (in {os.fspath(path)})") from None


def default_dome(seed: int = 2006) -> Dome:
    """The simulator's dome: 150 LEDs and 16 cameras (Weyrich §5), documented choices.

    * **LEDs.** 150 vertices of a frequency-8 geodesic sphere of radius 1000 mm around
      the head, chosen by farthest-point sampling among the directions the dome
      covers (elevation ≥ -40°, below which the chair stands, and z ≥ -0.8: the
      dome wraps around the head), all aimed at the head centre.  A frontal
      lumitexel then sees about 76 LEDs and 12 cameras, about 900 samples, the
      paper's figure (§5: ~900, up to 1,200).  White LEDs with a slightly warm RGB intensity [1.00, 0.97,
      0.92] × 10⁶ dome units·mm² (E⊥ ≈ 1 at 1 m) and beam polynomials with a
      fall-off of 30 % per unit tan² off-axis and 2 % random tilt and curvature terms;
      ``seed`` fixes the draw.
    * **Cameras.** 16 cameras at 1200 mm in two rows (elevation −12° and +18°) of 8,
      azimuths −84°..84° (the upper row turned a further 12°), looking at the face centre (0, 0, 50) mm; 1024 × 1024
      pixels with a 17° field of view, enough to frame the face.
    * **Exposures.** Two passes (§5, HDR from two exposures) of 1/60 s and 1/8 s; with
      ``camera_scale`` chosen so that diffuse skin reads about a third of the full
      well in the long pass, highlights clip there and are read from the short one.

    Parameters
    ----------
    seed : int
        Seed of the random draw of the LED intensities and beam terms.

    Returns
    -------
    Dome
    """
    rng = np.random.default_rng(seed)
    sphere = geodesic_points(8)
    ok = (sphere[:, 1] >= np.sin(np.radians(-40))) & (sphere[:, 2] >= -0.8)
    cand = sphere[ok]
    start = int(np.argmax(cand[:, 2]))
    dirs = cand[farthest_point_subset(cand, N_LEDS, start)]
    centre = np.array([0.0, 0.0, 40.0])
    led_pos = centre + 1000.0 * dirs
    axis = centre - led_pos
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    intensity = np.outer(np.ones(N_LEDS), [1.0, 0.97, 0.92]) * 1e6 * (1 + 0.02 * rng.standard_normal((N_LEDS, 1)))
    beam = np.column_stack(
        [
            np.ones(N_LEDS),
            0.02 * rng.standard_normal(N_LEDS),
            0.02 * rng.standard_normal(N_LEDS),
            -0.3 + 0.02 * rng.standard_normal(N_LEDS),
            0.01 * rng.standard_normal(N_LEDS),
            -0.3 + 0.02 * rng.standard_normal(N_LEDS),
        ]
    )
    el = np.radians(np.repeat([-12.0, 18.0], N_CAMERAS // 2))
    az = np.radians(np.tile(np.linspace(-84, 84, N_CAMERAS // 2), 2) + np.repeat([0.0, 12.0], N_CAMERAS // 2))
    target = np.array([0.0, 0.0, 50.0])
    cam_dir = np.stack([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)], 1)
    cam_pos = target + 1200.0 * cam_dir
    rot = look_at(cam_pos, target)
    f = 512 / np.tan(np.radians(17.0) / 2)
    k = np.tile(np.array([[f, 0, 512.0], [0, f, 512.0], [0, 0, 1.0]]), (N_CAMERAS, 1, 1))
    return Dome(
        led_position=led_pos,
        led_axis=axis,
        led_intensity=intensity,
        led_beam=beam,
        camera_position=cam_pos,
        camera_rotation=rot,
        camera_matrix=k,
        image_size=np.full((N_CAMERAS, 2), 1024),
        exposure_times=np.array([1 / 60, 1 / 8]),
        camera_scale=4.0e5,
        response=CameraResponse(full_well=20000.0, read_noise=5.0, adc_bits=12),
    )
