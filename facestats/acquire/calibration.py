"""Calibration files of a dome and the photometric calibration of its LEDs from photographs of a diffuse target.

**Camera files** in the layout OpenCV writes (``cv2.FileStorage``, YAML or JSON
by extension): ``K`` (3 × 3), ``dist`` (1 × 4|5|8), ``R`` (3 × 3, world to
camera), ``t`` (3 × 1, mm), ``image_width``, ``image_height``; the names
``camera_matrix`` and ``distortion_coefficients`` of OpenCV's calibration sample
are read too.  :func:`write_opencv_camera` / :func:`read_opencv_camera` move one
camera between such a file and a :class:`facestats.acquire.dome.Dome`, whose own
JSON (:meth:`Dome.save`) holds the same fields per camera.

**LED files** (``facestats.led-calibration/1``, JSON): per LED its position (mm),
beam axis, RGB intensity I₀ and beam polynomial c₀..c₅ (module docstring of
:mod:`facestats.acquire.dome`), the RMS relative residual and number of
observations of its fit, and the cameras' radiometric gains.

**Photometric LED calibration** (Weyrich et al. 2006 §5: the radiance of each
light source is calibrated "using a white ideal diffuse reflector (Fluorilon)",
the beam spread modelled "by a bi-variate 2nd degree polynomial"): a planar
Lambertian target of albedo ρ (per channel) is photographed at known poses under
every LED.  A target point x with normal n seen by camera c under LED l has
radiance (Lambert's law with the point-source irradiance of the dome model)

    V = G_c · (ρ/π) · I₀ · P(s, t) · max(n·ωi, 0) / r²,

with G_c the camera's gain relative to the reference camera (G = 1 there).
For fixed G this is linear in the six products a_k = I₀ c_k, so each LED is a
linear least-squares fit per channel of y = V r² π / (G ρ max(n·ωi, 0)) on the
monomials (1, s, t, s², s t, t²); the beam shape is shared by the channels
(c = Σ_ch a_ch / Σ_ch a_ch,0, so c₀ = 1) and each channel's I₀ is then the
least-squares scale of that shape.  The gains G_c are the median ratio of a
camera's observations to the model, starting from the reference camera alone;
the fit alternates LEDs and gains (:data:`ITERATIONS` rounds).  Target values
come from the HDR merge of the target's frames (:mod:`facestats.acquire.photographs`),
so I₀ is in the units of the cameras' merged values per ``camera_scale``.
"""

from __future__ import annotations

import json
import os
import pathlib
from dataclasses import dataclass, replace

import numpy as np

from facestats.acquire.dome import Dome, beam_terms
from facestats.acquire.photographs import (
    CaptureFolder,
    bilinear_taps,
    check_exposures,
    check_response,
    merge_at,
    open_folder,
    prefetch,
)
from facestats.acquire.response import check_black_level, check_white_level
from facestats.core.validate import check_integer, json_numbers
from facestats.errors import FormatError, ValidationError
from facestats.io.layout import read_regular_file

__all__ = [
    "read_opencv_camera",
    "write_opencv_camera",
    "LedCalibration",
    "read_led_calibration",
    "target_observations",
    "fit_leds",
    "calibrate_leds",
    "target_hits",
    "LED_FORMAT",
    "ITERATIONS",
    "MAX_GRID",
    "MIN_OBSERVATIONS",
    "NOISY_RESIDUAL",
]

LED_FORMAT = "facestats.led-calibration/1"
#: Rounds of the alternating LED / camera-gain fit.
ITERATIONS = 3
#: Most target points per side of a pose (:func:`target_observations`).  Each (point, camera, LED) observation
#: holds about 130 bytes: the default 24 on the full rig (150 LEDs, 4 poses each seen by about 8 cameras) keeps
#: some 0.4 GB, 100 some 6 GB (on a 6-LED, 3-camera rig 100 takes 2 s and 0.28 GB, 1000 took 4.5 min and 9.3 GB);
#: six beam coefficients per LED need nowhere near 10,000 points per pose.
MAX_GRID = 100
#: Fewest usable observations (lit from the front, seen unsaturated) of an LED for its fit: twice the six
#: coefficients of the beam polynomial.  An LED with fewer is not calibrated (NaN; :meth:`LedCalibration.apply`
#: keeps its previous photometry).
MIN_OBSERVATIONS = 12
#: RMS relative residual of one observation above which a fitted LED is named :attr:`LedCalibration.noisy`: a
#: well-exposed target leaves about 1 %; the tests' 4-LED target at 1 % of the full scale 7.343-11.48 %, with
#: intensities up to 1.549 % high (observations near the noise floor read high;
#: ``benchmarks/bench_photos.py``'s ``bench_led_underexposed``).
NOISY_RESIDUAL = 0.10


# -- OpenCV camera files ---------------------------------------------------------------------------------------
def write_opencv_camera(path, dome: Dome, camera: int):
    """Write camera ``camera`` of ``dome`` as an OpenCV FileStorage file (.yml, .yaml or .json).

    Parameters
    ----------
    path : str or path-like
        The file to write; OpenCV picks YAML or JSON by its extension.
    dome : Dome
        The calibration holding the camera.
    camera : int
        0-based camera index in ``dome``.

    Returns
    -------
    str
        ``path`` as a string.

    Raises
    ------
    FormatError
        OpenCV cannot open ``path`` for writing.
    """
    import cv2

    p = os.fspath(path)
    d = dome.camera_dict(camera)
    fs = cv2.FileStorage(p, cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise FormatError(f"cannot write the camera file {p}")
    try:
        fs.write("image_width", d["image_width"])
        fs.write("image_height", d["image_height"])
        fs.write("K", np.asarray(d["K"], np.float64))
        fs.write("dist", np.asarray(d["dist"], np.float64).reshape(1, -1))
        fs.write("R", np.asarray(d["R"], np.float64))
        fs.write("t", np.asarray(d["t"], np.float64).reshape(3, 1))
    finally:
        fs.release()
    return p


def read_opencv_camera(path) -> dict:
    """One camera from an OpenCV FileStorage file: the ``camera_dict`` fields of :class:`Dome` (K, dist, R, t, size).

    Parameters
    ----------
    path : str or path-like
        A YAML or JSON FileStorage file (module docstring; ``camera_matrix``, ``distortion_coefficients`` and ``T``
        are read as ``K``, ``dist`` and ``t``).

    Returns
    -------
    dict
        ``K`` (3 × 3 nested list), ``dist`` (list), ``R`` (3 × 3 nested list, world to camera), ``t`` (3 floats,
        mm), ``image_width`` and ``image_height`` (int); no ``gain``.

    Raises
    ------
    FormatError
        The file does not exist, cannot be parsed or lacks a field (the message names both), a field is not a
        matrix, or K, R or t has the wrong shape.
    """
    import cv2

    p = os.fspath(path)
    if not pathlib.Path(p).is_file():
        raise FormatError(f"camera file {p} does not exist")
    try:
        fs = cv2.FileStorage(p, cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise FormatError(f"camera file {p} cannot be parsed: {exc.err}") from None

    def mat(*names):
        for name in names:
            node = fs.getNode(name)
            if not node.empty():
                m = node.mat()
                if m is None:
                    raise FormatError(f"camera file {p} field {name!r} is not an OpenCV matrix")
                return m
        raise FormatError(f"camera file {p} is missing the field {names[0]!r}")

    def num(name):
        node = fs.getNode(name)
        if node.empty():
            raise FormatError(f"camera file {p} is missing the field {name!r}")
        return int(node.real())

    try:
        out = {
            "K": np.asarray(mat("K", "camera_matrix"), np.float64).tolist(),
            "dist": np.asarray(mat("dist", "distortion_coefficients"), np.float64).reshape(-1).tolist(),
            "R": np.asarray(mat("R"), np.float64).tolist(),
            "t": np.asarray(mat("t", "T"), np.float64).reshape(-1).tolist(),
            "image_width": num("image_width"),
            "image_height": num("image_height"),
        }
    finally:
        fs.release()
    if np.shape(out["K"]) != (3, 3) or np.shape(out["R"]) != (3, 3) or len(out["t"]) != 3:
        raise FormatError(f"camera file {p}: K and R must be 3×3 and t 3×1, got {np.shape(out['K'])}, ...")
    return out


# -- LED calibration ---------------------------------------------------------------------------------------------
@dataclass
class LedCalibration:
    """Result of :func:`fit_leds`: per-LED intensity and beam, camera gains, residuals.

    Attributes
    ----------
    intensity : ndarray, shape (L, 3)
        On-axis RGB intensity I₀ (dome units · mm²); NaN for LEDs without observations.
    beam : ndarray, shape (L, 6)
        Beam polynomial c₀..c₅ with c₀ = 1.
    camera_gain : ndarray, shape (C, 3)
        Gain of each camera relative to ``reference_camera`` (NaN for cameras without observations).
    rms_residual : ndarray, shape (L,)
        RMS relative residual of each LED's observations.
    n_observations : ndarray of int, shape (L,)
        Usable observations of each LED (fewer than :data:`MIN_OBSERVATIONS`: not calibrated).
    reference_camera : int
    beam_stderr : ndarray, shape (L, 6), optional
        Standard errors of the beam coefficients c₀..c₅ (c₀ ≡ 1: 0), from the residuals of the fit
        (inf where the observations do not determine the polynomial at all).
    beam_error : ndarray, shape (L,), optional
        Largest relative standard error of the fitted beam P(s, t) over the target's points in front of
        the LED (every pose, every camera: where the calibration is used).  At its own observations a
        least-squares fit is never less certain than one observation (their leverage is at most 1), so a
        ``beam_error`` above ``rms_residual`` means the beam is extrapolated beyond the LED's observations
        (:attr:`poorly_determined`).
    """

    intensity: np.ndarray
    beam: np.ndarray
    camera_gain: np.ndarray
    rms_residual: np.ndarray
    n_observations: np.ndarray
    reference_camera: int
    beam_stderr: np.ndarray | None = None
    beam_error: np.ndarray | None = None

    @property
    def uncalibrated(self) -> np.ndarray:
        """Indices of the LEDs without a fit (fewer than :data:`MIN_OBSERVATIONS` usable observations)."""
        return np.nonzero(~np.isfinite(self.intensity).all(1))[0]

    @property
    def poorly_determined(self) -> np.ndarray:
        """Indices of the fitted LEDs whose :attr:`beam_error` exceeds their ``rms_residual`` (class docstring)."""
        if self.beam_error is None:
            return np.zeros(0, np.int64)
        fitted = np.isfinite(self.intensity).all(1)
        with np.errstate(invalid="ignore"):
            return np.nonzero(fitted & ~(self.beam_error <= self.rms_residual))[0]

    @property
    def noisy(self) -> np.ndarray:
        """Indices of the fitted LEDs whose ``rms_residual`` exceeds :data:`NOISY_RESIDUAL`."""
        with np.errstate(invalid="ignore"):
            return np.nonzero(np.isfinite(self.intensity).all(1) & (self.rms_residual > NOISY_RESIDUAL))[0]

    def noisy_text(self) -> str:
        """One line naming the :attr:`noisy` LEDs and their residuals, or '' if there is none."""
        bad = self.noisy
        if bad.size == 0:
            return ""
        r = self.rms_residual[bad]
        return (
            f"LED{'s' if bad.size > 1 else ''} {', '.join(map(str, bad))}: RMS residual of one observation "
            f"{r.min():.0%}-{r.max():.0%} (over {NOISY_RESIDUAL:.0%}; a well-exposed target leaves about 1 %): the "
            "target is underexposed under these LEDs (observations near the noise floor read high, and so do the "
            "intensities), or the target moved; lengthen the exposures"
        )

    def uncalibrated_text(self) -> str:
        """One line naming the LEDs without a fit and why, or '' if every LED was fitted."""
        bad = self.uncalibrated
        if bad.size == 0:
            return ""
        return (
            f"{bad.size} of {len(self.intensity)} LEDs not calibrated (fewer than {MIN_OBSERVATIONS} usable "
            f"observations of the target, lit from the front and seen unsaturated): "
            f"LED{'s' if bad.size > 1 else ''} {', '.join(map(str, bad))}"
        )

    def poorly_determined_text(self) -> list[str]:
        """One line per LED of :attr:`poorly_determined`: its beam error, residual and curvature terms."""
        lines = []
        for i in self.poorly_determined:
            b, se = self.beam[i], (self.beam_stderr[i] if self.beam_stderr is not None else np.full(6, np.nan))
            lines.append(
                f"LED {i}: beam poorly determined, extrapolated beyond its {self.n_observations[i]} observations: "
                f"its standard error on the target reaches {self.beam_error[i]:.1%}, above the "
                f"{self.rms_residual[i]:.2%} RMS residual of one observation (c3 {b[3]:.3f} ± {se[3]:.3f}, "
                f"c5 {b[5]:.3f} ± {se[5]:.3f})"
            )
        return lines

    def apply(self, dome: Dome) -> Dome:
        """``dome`` with these LED intensities, beams and camera gains (LEDs or cameras without data keep theirs).

        Parameters
        ----------
        dome : Dome
            The calibration the fit was made with (the same L LEDs and C cameras); it is not modified.

        Returns
        -------
        Dome
            A copy with ``led_intensity``, ``led_beam`` and ``camera_gain`` replaced where they are finite here.
        """
        ok = np.isfinite(self.intensity).all(1)
        gain_ok = np.isfinite(self.camera_gain).all(1)
        return replace(
            dome,
            led_intensity=np.where(ok[:, None], self.intensity, dome.led_intensity),
            led_beam=np.where(ok[:, None], self.beam, dome.led_beam),
            camera_gain=np.where(gain_ok[:, None], self.camera_gain, dome.camera_gain),
        )

    def to_dict(self, dome: Dome) -> dict:
        """The LED file (``facestats.led-calibration/1``) with ``dome``'s LED positions and axes.

        Parameters
        ----------
        dome : Dome
            The calibration whose LEDs (at least L of them, in the same order) give each LED's position (mm)
            and axis.

        Returns
        -------
        dict
            JSON-ready: ``format``, ``reference_camera``, ``camera_gain`` and one entry per LED in ``leds`` (with
            ``beam_stderr`` and ``beam_error`` when set, each on its own); NaN values are null.
        """
        leds = [
            {
                "index": i,
                "position_mm": dome.led_position[i].tolist(),
                "axis": dome.led_axis[i].tolist(),
                "intensity": _list(self.intensity[i]),
                "beam_polynomial": _list(self.beam[i]),
                "rms_residual": _num(self.rms_residual[i]),
                "n_observations": int(self.n_observations[i]),
            }
            | ({} if self.beam_stderr is None else {"beam_stderr": _list(self.beam_stderr[i])})
            | ({} if self.beam_error is None else {"beam_error": _num(self.beam_error[i])})
            for i in range(len(self.intensity))
        ]
        return {
            "format": LED_FORMAT,
            "reference_camera": int(self.reference_camera),
            "camera_gain": [_list(g) for g in self.camera_gain],
            "leds": leds,
        }

    def save(self, path, dome: Dome):
        """Write :meth:`to_dict` as JSON.

        Parameters
        ----------
        path : str or path-like
            The file to write (replaced if it exists); :func:`read_led_calibration` reads it.
        dome : Dome
            As :meth:`to_dict`.
        """
        pathlib.Path(path).write_text(json.dumps(self.to_dict(dome), indent=1))

    def to_text(self) -> str:
        """One line per LED: intensity, beam curvature, residual and observations; the camera gains."""
        lines = [f"{'LED':>4} {'I0 R':>10} {'I0 G':>10} {'I0 B':>10} {'c3':>7} {'c5':>7} {'rms res':>8} {'n':>6}"]
        for i, (it, b, r, n) in enumerate(zip(self.intensity, self.beam, self.rms_residual, self.n_observations)):
            if not np.all(np.isfinite(it)):
                lines.append(f"{i:4d}   not calibrated: {n} usable observations, {MIN_OBSERVATIONS} needed")
                continue
            lines.append(f"{i:4d} {it[0]:10.4g} {it[1]:10.4g} {it[2]:10.4g} {b[3]:7.3f} {b[5]:7.3f} {r:8.2%} {n:6d}")
        lines.append(f"camera gains relative to camera {self.reference_camera}:")
        for c, g in enumerate(self.camera_gain):
            if np.all(np.isfinite(g)):
                lines.append(f"  camera {c:2d}: {g[0]:.4f} {g[1]:.4f} {g[2]:.4f}")
        return "\n".join(lines)


def _list(a):
    return [_num(x) for x in np.asarray(a).reshape(-1)]


def _num(x):
    return None if not np.isfinite(x) else float(x)


def read_led_calibration(path) -> dict:
    """Arrays of an LED file: ``position``, ``axis``, ``intensity``, ``beam`` (L, ·), ``camera_gain`` (C, 3).

    Parameters
    ----------
    path : str or path-like
        A ``facestats.led-calibration/1`` file (:meth:`LedCalibration.save`).

    Returns
    -------
    dict of ndarray of float
        ``position`` (L, 3, mm), ``axis`` (L, 3), ``intensity`` (L, 3), ``beam`` (L, 6) and ``camera_gain``
        (C, 3); values stored as null are NaN.

    Raises
    ------
    FormatError
        The file cannot be read or is not JSON, its ``format`` is not ``facestats.led-calibration/1``, or a field
        is missing or malformed.
    """
    p = pathlib.Path(path)
    try:
        doc = json.loads(read_regular_file(p))
    except (OSError, ValueError, RecursionError) as exc:  # ValueError: not JSON, or not UTF-8
        raise FormatError(f"cannot read the LED calibration {p}: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != LED_FORMAT:
        raise FormatError(f"{p} field 'format' must be {LED_FORMAT!r}")
    try:
        leds = doc["leds"]

        def col(key):
            return np.asarray([[np.nan if v is None else v for v in np.atleast_1d(led[key])] for led in leds], float)

        return {
            "position": col("position_mm"),
            "axis": col("axis"),
            "intensity": col("intensity"),
            "beam": col("beam_polynomial"),
            "camera_gain": np.asarray([[np.nan if v is None else v for v in g] for g in doc["camera_gain"]], float),
        }
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(f"{p} has a missing or malformed field: {exc}") from None


# -- observations of the target ----------------------------------------------------------------------------------
def _target(folder: CaptureFolder):
    """Albedo (3,) and poses (centre, unit normal, unit u axis in the plane, size) of a target folder's manifest."""
    t = folder.manifest.get("target")
    where = f"{folder.path / 'manifest.json'} field 'target'"
    if not isinstance(t, dict) or not isinstance(t.get("poses"), list):
        raise FormatError(f"{where} must be an object with 'albedo' and a list 'poses', got {t!r:.80}")
    rho = json_numbers(t.get("albedo"), f"{where} 'albedo'", 3)
    if np.any(rho <= 0):
        raise FormatError(f"{where} 'albedo' must be 3 numbers > 0, got {t['albedo']!r}")
    if len(t["poses"]) != folder.n_poses:
        raise FormatError(f"{where} needs {folder.n_poses} pose(s) (one per frame pose), got {len(t['poses'])}")
    poses = []
    for k, p in enumerate(t["poses"]):  # loop over the few poses
        name = f"{where} poses[{k}]"
        if not isinstance(p, dict):
            raise FormatError(f"{name} must be an object, got {p!r:.60}")
        centre = json_numbers(p.get("centre_mm"), f"{name} 'centre_mm'", 3)
        normal = json_numbers(p.get("normal"), f"{name} 'normal'", 3)
        u_axis = json_numbers(p.get("u_axis"), f"{name} 'u_axis'", 3)
        size = json_numbers(p.get("size_mm"), f"{name} 'size_mm'", 2)
        if np.linalg.norm(normal) < 1e-9 or np.linalg.norm(u_axis) < 1e-9 or np.any(size <= 0):
            raise FormatError(f"{name} needs a non-zero 'normal' and 'u_axis' and 'size_mm' > 0, got {p!r:.120}")
        normal = normal / np.linalg.norm(normal)
        u_axis = u_axis / np.linalg.norm(u_axis)
        if abs(normal @ u_axis) > 1e-3:
            raise FormatError(
                f"{name} 'u_axis' must lie in the target's plane (perpendicular to 'normal'), got cosine "
                f"{normal @ u_axis:.4g} between them"
            )
        poses.append((centre, normal, u_axis, size))
    return rho, poses


def target_observations(
    folder,
    dome: Dome,
    *,
    grid: int = 24,
    cameras=None,
    workers: int = 2,
    black_level: int | None = None,
    white_level: int | None = None,
) -> dict:
    """HDR values of a target folder at a grid of points on each pose, for every camera and LED.

    Points: a ``grid`` × ``grid`` lattice over the central 90 % of each target;
    each camera keeps those in frame, on the side of the target it faces, and
    whose four bilinear taps all see the target (near an edge seen at a grazing
    angle a pixel's footprint reaches past the target: its value mixes in the
    background, 15-18 % low in the simulated set-up of the tests, and such points
    biased the beam's quadratic terms by up to 2);
    values are the HDR merge (:func:`facestats.acquire.photographs.merge_at`, with the
    cameras' pedestal ``black_level`` in DN, default the calibration's ``camera_black_level``, and
    the code ``white_level`` in DN at and above which they clip, default the calibration's
    ``camera_white_level`` (None there: the top code); Z_min and Z_max of the hat weights of
    Debevec & Malik 1997 eq. 4) divided by ``camera_scale``; saturated or unlit observations are
    dropped.  ``grid`` is in [2, :data:`MAX_GRID`].

    Parameters
    ----------
    folder : str, path-like or CaptureFolder
        A capture folder of ``kind`` ``"target"`` (:mod:`facestats.acquire.photographs`).
    dome : Dome
        The calibration: geometry, camera responses and exposure times of the rig.
    grid : int
        Points per side of each pose's lattice, in [2, :data:`MAX_GRID`].
    cameras : sequence of int, optional
        The cameras to read (default the folder's ``cameras``).
    workers : int
        Threads decoding frames (:func:`facestats.acquire.photographs.prefetch`).
    black_level, white_level : int, optional
        Pedestal and clipping code in DN (above); default the calibration's.

    Returns
    -------
    dict
        ``point`` (M, 3), ``normal`` (M, 3), ``camera`` (M,), ``led`` (M,), ``value`` (M, 3), ``albedo`` (3,),
        and ``target_points`` (K, 3): the points each camera sees on each pose, whatever the LED (where the
        fitted beams are checked, :attr:`LedCalibration.beam_error`).
    """
    folder = folder if isinstance(folder, CaptureFolder) else open_folder(folder)
    if folder.kind != "target":
        raise FormatError(f"manifest.json field 'kind' must be 'target' for an LED calibration, got {folder.kind!r}")
    if folder.n_cameras != dome.n_cameras or folder.n_leds != dome.n_leds:
        raise FormatError(
            f"manifest.json fields 'n_cameras', 'n_leds' are {folder.n_cameras}, {folder.n_leds}; the calibration "
            f"has {dome.n_cameras} cameras and {dome.n_leds} LEDs"
        )
    check_response(folder, dome)  # to merge the target's photographs
    check_exposures(folder, dome)  # with the times they were taken with
    rho, poses = _target(folder)
    check_integer(grid, "grid", 2, MAX_GRID)
    black_level = check_black_level(dome.camera_black_level if black_level is None else black_level, 2**folder.bits)
    white_level = check_white_level(
        dome.camera_white_level if white_level is None else white_level, 2**folder.bits, black_level
    )
    cams = folder.cameras if cameras is None else [int(c) for c in cameras]
    out = {k: [] for k in ("point", "normal", "camera", "led", "value", "target_points")}
    f = (np.arange(grid) + 0.5) / grid * 0.9 - 0.45
    for p, (centre, normal, u_axis, size) in enumerate(poses):  # loop over poses and cameras; arrays inside
        a, b = np.meshgrid(f * size[0], f * size[1])
        pts = centre + a.reshape(-1, 1) * u_axis + b.reshape(-1, 1) * np.cross(normal, u_axis)
        for cam in cams:
            if (dome.camera_position[cam] - centre) @ normal > 0:  # the camera faces the target's front
                _observe(folder, dome, p, cam, pts, poses[p], workers, out, black_level, white_level)
    if not out["point"]:
        raise FormatError("no camera sees a target pose: check the poses and the camera calibration")
    res = {k: np.concatenate(v) for k, v in out.items()}
    res["albedo"] = rho
    return res


def target_hits(dome: Dome, camera: int, pixels, geometry):
    """Where the rays of ``pixels`` (N, 2; centres at integers) of ``camera`` meet a planar target.

    Parameters
    ----------
    dome : Dome
    camera : int
        0-based camera index.
    pixels : array_like, shape (N, 2)
        (u, v) pixel positions, OpenCV convention.
    geometry : tuple
        ``(centre, normal, u_axis, size)`` of the target (mm, unit vectors, (width, height) mm).

    Returns
    -------
    points : ndarray of float64, shape (N, 3)
        The world points where the rays meet the target's plane, mm (non-finite for a ray parallel to it).
    inside : ndarray of bool, shape (N,)
        The point lies in front of the camera and inside the target's rectangle.
    """
    centre, normal, u_axis, size = (np.asarray(x, np.float64) for x in geometry)
    rays = dome.pixel_rays(camera, pixels)
    origin = dome.camera_position[camera]
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = ((centre - origin) @ normal) / (rays @ normal)
    pts = origin + dist[:, None] * rays
    d = pts - centre
    inside = (dist > 0) & (np.abs(d @ u_axis) <= size[0] / 2) & (np.abs(d @ np.cross(normal, u_axis)) <= size[1] / 2)
    return pts, inside


def _taps_on_target(dome, cam, index, geometry) -> np.ndarray:
    """Whether every tap pixel (N, 4 flat indices) of ``cam`` looks at the target ``geometry`` (N,) bool."""
    w = int(dome.image_size[cam][0])
    flat = index.reshape(-1)
    _, inside = target_hits(dome, cam, np.stack([flat % w, flat // w], 1).astype(np.float64), geometry)
    return inside.reshape(index.shape).all(axis=1)


def _observe(folder, dome, pose, cam, pts, geometry, workers, out, black_level=0, white_level=None):
    """Append the observations of target points ``pts`` in camera ``cam`` under every LED to ``out``."""
    normal = geometry[1]
    _, in_frame, pix = dome.view(pts, [cam])
    keep = np.nonzero(in_frame[:, 0])[0]
    if keep.size == 0:
        return
    index, weight = bilinear_taps(pix[keep, 0], dome.image_size[cam])
    on = _taps_on_target(dome, cam, index, geometry)
    keep, index, weight = keep[on], index[on], weight[on]
    if keep.size == 0:
        return
    out["target_points"].append(pts[keep])
    g = dome.camera_log_response[cam]

    def read(led):
        return led, folder.read_stack(cam, led, pose=pose, size=dome.image_size[cam])

    for led, (stack, times) in prefetch(read, range(dome.n_leds), workers):  # loop over LEDs; arrays inside
        val = merge_at(stack, times, g, index, weight, black_level=black_level, white_level=white_level,
                       measured_only=True)  # fmt: skip  # a dark tap's floor is a bound, not an observation
        val /= dome.camera_scale
        ok = np.all(np.isfinite(val) & (val > 0), axis=1)
        out["point"].append(pts[keep[ok]])
        out["normal"].append(np.broadcast_to(normal, (int(ok.sum()), 3)))
        out["camera"].append(np.full(ok.sum(), cam))
        out["led"].append(np.full(ok.sum(), led))
        out["value"].append(val[ok])


# -- the fit ------------------------------------------------------------------------------------------------------
def _led_fit(dome, obs, rows, led, gain, region):
    """Intensity (3,), beam (6,), residual, observations, beam standard errors (6,) and beam error of one LED.

    From its observation rows (module docstring); the last two are those of :class:`LedCalibration`, the beam
    error over the target points ``region`` (K, 3).
    """
    wi, r2, s, t, front = dome.beam_coordinates(obs["point"][rows], [led])
    cos = np.einsum("nk,nk->n", wi[:, 0], obs["normal"][rows])
    use = front[:, 0] & (cos > 0.05)
    if use.sum() < MIN_OBSERVATIONS:
        return np.full(3, np.nan), np.full(6, np.nan), np.nan, int(use.sum()), np.full(6, np.nan), np.nan
    geo = (obs["albedo"] / np.pi) * (cos[use] / r2[use, 0])[:, None] * gain[obs["camera"][rows][use]]
    y = obs["value"][rows][use] / geo  # I₀ P(s, t) per channel
    x = beam_terms(s[use, 0], t[use, 0])
    a = np.linalg.lstsq(x, y, rcond=None)[0]  # (6, 3)
    beam = a.sum(1) / a[0].sum()
    shape = x @ beam
    intensity = (shape @ y) / (shape @ shape)
    model = shape[:, None] * intensity
    rms = float(np.sqrt(np.mean((y / model - 1) ** 2)))
    stderr, error = _beam_uncertainty(dome, led, x, y.sum(1), a.sum(1), region)
    return intensity, beam, rms, int(use.sum()), stderr, error


def _beam_uncertainty(dome, led, x, total, coef, region):
    """Standard errors of the beam c = A / A₀ (6,) and its largest relative standard error over ``region``.

    ``coef`` A (6,) is the least-squares fit of the channels' sum ``total`` (N,) on the monomials ``x`` (N, 6)
    (the sum of the channels' fits, from which the beam is formed); its covariance is σ² (XᵀX)⁻¹ with σ² the
    residual variance on N − 6 degrees of freedom, propagated to c and to P(s, t) = m(s, t)·c to first order.
    A design of lower numerical rank (numpy's ``matrix_rank`` tolerance) leaves the beam undetermined: inf.
    """
    _, sv, vt = np.linalg.svd(x, full_matrices=False)
    if sv[-1] <= sv[0] * max(x.shape) * np.finfo(np.float64).eps:
        return np.r_[0.0, np.full(5, np.inf)], np.inf
    resid = total - x @ coef
    cov = (resid @ resid) / (len(total) - 6) * (vt.T / sv**2) @ vt  # covariance of A
    beam = coef / coef[0]
    jac = (np.eye(6) - np.outer(beam, np.eye(6)[0])) / coef[0]  # ∂c/∂A
    stderr = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", jac, cov, jac), 0))
    _, _, s, t, front = dome.beam_coordinates(region, [led])
    m = beam_terms(s[front[:, 0], 0], t[front[:, 0], 0])
    if len(m) == 0:
        return stderr, np.nan
    grad = m @ jac  # ∂P/∂A at each point
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.sqrt(np.maximum(np.einsum("nj,jk,nk->n", grad, cov, grad), 0)) / np.abs(m @ beam)
    return stderr, float(np.max(np.where(np.isnan(rel), np.inf, rel)))


def _gains(dome, obs, intensity, beam, reference):
    """Median ratio of each camera's observations to the gain-free model, relative to ``reference`` (C, 3)."""
    gains = np.full((dome.n_cameras, 3), np.nan)
    for cam in np.unique(obs["camera"]):  # loop over cameras, vectorised over observations
        rows = np.nonzero(obs["camera"] == cam)[0]
        leds = obs["led"][rows]
        ratios = []
        for led in np.unique(leds):
            if not np.all(np.isfinite(intensity[led])):
                continue
            r = rows[leds == led]
            wi, r2, s, t, front = dome.beam_coordinates(obs["point"][r], [led])
            cos = np.maximum(np.einsum("nk,nk->n", wi[:, 0], obs["normal"][r]), 0)
            model = (obs["albedo"] / np.pi) * ((beam_terms(s, t)[:, 0] @ beam[led]) * cos / r2[:, 0])[:, None]
            ok = front[:, 0] & (cos > 0.05)
            ratios.append(obs["value"][r][ok] / (model[ok] * intensity[led]))
        if ratios:
            gains[cam] = np.median(np.concatenate(ratios), axis=0)
    return gains / gains[reference]


def fit_leds(dome: Dome, obs: dict, *, reference_camera: int | None = None) -> LedCalibration:
    """The photometric LED calibration (module docstring) from :func:`target_observations`.

    Parameters
    ----------
    dome : Dome
        The calibration whose LED and camera geometry the fit uses.
    obs : dict
        :func:`target_observations`'s result.
    reference_camera : int, optional
        The camera of gain 1 that starts the fit; default the camera with the most observations.

    Returns
    -------
    LedCalibration

    Raises
    ------
    ValidationError
        ``reference_camera`` is not a camera of ``dome`` with observations.
    """
    counts = np.bincount(obs["camera"], minlength=dome.n_cameras)
    ref = int(np.argmax(counts)) if reference_camera is None else check_integer(reference_camera, "reference_camera")
    if not 0 <= ref < dome.n_cameras or counts[ref] == 0:
        raise ValidationError(f"reference_camera must be a camera that sees the target, got {reference_camera!r}")
    n_led = dome.n_leds
    by_led = [np.nonzero(obs["led"] == led)[0] for led in range(n_led)]
    ref_only = [r[obs["camera"][r] == ref] for r in by_led]
    region = obs["target_points"] if "target_points" in obs else np.unique(obs["point"], axis=0)
    gain = np.ones((dome.n_cameras, 3))
    intensity, beam = np.full((n_led, 3), np.nan), np.full((n_led, 6), np.nan)
    rms, nobs = np.full(n_led, np.nan), np.zeros(n_led, np.int64)
    stderr, error = np.full((n_led, 6), np.nan), np.full(n_led, np.nan)
    for it in range(ITERATIONS):  # alternate LEDs (linear) and camera gains (medians)
        rows = ref_only if it == 0 else by_led
        for led in range(n_led):  # loop over LEDs: one small linear fit each
            intensity[led], beam[led], rms[led], nobs[led], stderr[led], error[led] = _led_fit(
                dome, obs, rows[led], led, np.nan_to_num(gain), region
            )
        gain = _gains(dome, obs, intensity, beam, ref)
    return LedCalibration(intensity, beam, gain, rms, nobs, ref, stderr, error)


def calibrate_leds(
    folder,
    dome: Dome,
    *,
    grid: int = 24,
    reference_camera: int | None = None,
    workers: int = 2,
    black_level: int | None = None,
    white_level: int | None = None,
):
    """Fit every LED's intensity and beam polynomial, and the camera gains, from a target folder (module docstring).

    Parameters
    ----------
    folder : str, path-like or CaptureFolder
        A capture folder of ``kind`` ``"target"`` (:mod:`facestats.acquire.photographs`).
    dome : Dome
        The calibration: geometry, camera responses and exposure times of the rig.
    grid : int
        As :func:`target_observations`.
    reference_camera : int, optional
        As :func:`fit_leds`.
    workers, black_level, white_level
        As :func:`target_observations` (``black_level`` and ``white_level`` in DN; Z_min and Z_max of the hat
        weights of Debevec & Malik 1997 eq. 4, default the calibration's).

    Returns
    -------
    LedCalibration

    Raises
    ------
    FormatError
        The folder is not a target capture, its ``target`` description is malformed, it does not match ``dome``
        (cameras, LEDs, response levels, exposure times), or no camera sees a target pose.
    ValidationError
        A bad ``grid``, ``black_level``, ``white_level`` or ``reference_camera``.
    """
    obs = target_observations(
        folder, dome, grid=grid, workers=workers, black_level=black_level, white_level=white_level
    )
    return fit_leds(dome, obs, reference_camera=reference_camera)
