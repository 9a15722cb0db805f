"""Inputs the benchmarks build once and reuse, rebuilt when absent or stale.

A benchmark input (e.g. the full-resolution capture, ~10 min to simulate) lives
in ``FACESTATS_BENCH_DIR`` (default: ``facestats-bench`` in the system's temporary
directory) next to a key file recording the facestats source it was made with
(a SHA-256 of every ``facestats/**/*.py``) and the parameters it was made from.
An input whose key differs from the current one is deleted and rebuilt, so a
benchmark can never measure data that an older version of the code produced.

Two processes asking for one input at once build it once: the check and the
build hold an exclusive lock (``<name>.lock``, POSIX ``flock``).  Do not run
benchmarks of *different* code versions against one ``FACESTATS_BENCH_DIR`` at
the same time: the newer one deletes and rebuilds an input the other may be
reading, and zarr reads the chunks that vanished as zeros.

Set-ups and measures that benchmarks and tests share live here too (tests import
this module as ``benchmarks.inputs``; benchmarks never import from ``tests/``,
which is not installed): colour-hdri's merge, the median relative difference
after a global scale, a fit's errors against the truth, and the LED-calibration
target rig with its error measures.
"""

from __future__ import annotations

import fcntl
import json
import os
import pathlib
import shutil
import tempfile

import numpy as np

from facestats.core.version import source_fingerprint

__all__ = [
    "beam_error_on",
    "bench_dir",
    "cached_input",
    "colour_hdri_merge",
    "e_perp_error",
    "fit_errors",
    "scaled_difference",
    "target_pose",
    "target_rig",
    "unknown_leds",
]


def bench_dir() -> pathlib.Path:
    """Where benchmark inputs live: ``$FACESTATS_BENCH_DIR`` or ``<tmp>/facestats-bench`` (created)."""
    root = pathlib.Path(
        os.environ.get("FACESTATS_BENCH_DIR") or pathlib.Path(tempfile.gettempdir()) / "facestats-bench"
    )
    root.mkdir(parents=True, exist_ok=True)
    return root


def cached_input(name: str, params: dict, make, *, rebuild: bool = False):
    """The path of input ``name``, made by ``make(path)`` unless a current copy exists.

    Parameters
    ----------
    name : str
        File or directory name of the input inside :func:`bench_dir`.
    params : dict
        JSON-serialisable parameters the input is made from (part of its key).
    make : callable
        ``make(path)`` writes the input at ``path`` and may return a dict of figures.
    rebuild : bool
        Rebuild even if a current copy exists (a benchmark that measures the making).

    Returns
    -------
    path : str
    figures : dict
        What ``make`` returned, or ``{}`` when a current copy was reused.
    """
    root = bench_dir()
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        return _current_or_built(root, name, params, make, rebuild)


def _current_or_built(root, name, params, make, rebuild):
    path, key_file = root / name, root / f"{name}.key.json"
    key = {"code": source_fingerprint(), "params": params}
    if not rebuild and path.exists() and key_file.exists():
        try:
            if json.loads(key_file.read_text()) == key:
                return str(path), {}
        except ValueError:
            pass
    key_file.unlink(missing_ok=True)
    shutil.rmtree(path, ignore_errors=True)
    figures = make(str(path)) or {}
    key_file.write_text(json.dumps(key))
    return str(path), figures


# -- shared by benchmarks and tests ----------------------------------------------------------------------------------
def scaled_difference(a, b) -> float:
    """Median relative difference of two radiance images after the best global scale.

    With r = a / b over the pixels where r is finite and positive, the value is median |r / median(r) − 1|: two
    merges that differ only by a global factor (an HDR merge's radiance is known up to one) give 0.

    Parameters
    ----------
    a, b : array_like
        Images of one shape.

    Returns
    -------
    float
    """
    r = np.asarray(a, np.float64) / np.asarray(b, np.float64)
    ok = np.isfinite(r) & (r > 0)
    return float(np.median(np.abs(r[ok] / np.median(r[ok]) - 1)))


def phase_shift_px(imgs, times, response):
    """How far apart two frames of a bracket are, px: OpenCV's phase correlation of their log radiance
    (Debevec & Malik 1997 eq. 2, mean over channels), over the pixels well exposed (hat weight ≥ 0.2 of its peak)
    in both, the others filled with the mean; an estimate of camera or scene motion independent of
    :func:`facestats.acquire.photographs.exposure_consistency`.

    Parameters
    ----------
    imgs : (ndarray, ndarray) of uint8, each (H, W, 3)
        The two frames' codes.
    times : ndarray, shape (2,)
        Their exposure times, s.
    response : ndarray, shape (256, 3)
        g(Z) = ln exposure per code and channel.
    """
    import cv2

    from facestats.acquire.response import hat_weights

    w = hat_weights(256)
    ok = np.all((w[imgs[0]] >= 0.2 * w.max()) & (w[imgs[1]] >= 0.2 * w.max()), axis=-1)
    logs = [(response[im, np.arange(3)] - np.log(t)).mean(-1) for im, t in zip(imgs, times)]
    a, b = (np.where(ok, x, x[ok].mean()).astype(np.float32) for x in logs)
    (dx, dy), _ = cv2.phaseCorrelate(a, b, cv2.createHanningWindow(a.shape[::-1], cv2.CV_32F))
    return float(np.hypot(dx, dy))


def colour_hdri_merge(imgs, times):
    """colour-hdri's Debevec 1997 response and HDRI merge of 8-bit images (values scaled to [0, 1]).

    Parameters
    ----------
    imgs : sequence of ndarray of uint8, each (H, W, 3)
        The bracket.
    times : sequence of float
        Exposure times, seconds, one per image.

    Returns
    -------
    ndarray, shape (H, W, 3)
        The merged radiance, up to a global scale.

    Raises
    ------
    ImportError
        Without colour-hdri (a test extra).
    """
    from colour_hdri import Image, ImageStack, camera_response_functions_Debevec1997, image_stack_to_HDRI
    from colour_hdri.utilities.image import Metadata

    stack = ImageStack()
    for img, t in zip(imgs, times):
        im = Image()
        im.data = img.astype(np.float64) / 255
        im.metadata = Metadata(8.0, float(t), 100.0)
        stack.append(im)
    crfs = camera_response_functions_Debevec1997(stack, sampling_function_kwargs={"samples": 200})
    return image_stack_to_HDRI(stack, camera_response_functions=crfs)


def fit_errors(ds, truth) -> dict:
    """Relative errors |fit / truth − 1| of a fitted subject's albedo, ρs and m: median and 90th percentile.

    The albedo over the face texels (``region_map > 0``), ρs and m over those the fit did not flag (``ts_flag`` 0).

    Parameters
    ----------
    ds : xarray.Dataset
        The fitted subject (``albedo``, ``ts_rho_s``, ``ts_m``, ``ts_flag``).
    truth : SubjectTruth
        Its synthetic truth.

    Returns
    -------
    dict
        ``{"albedo" | "ts_rho_s" | "ts_m": (median, p90)}``.
    """
    face = truth.region_map > 0
    ok = face & (ds.ts_flag.values == 0)
    out = {}
    for name, mask in (("albedo", face), ("ts_rho_s", ok), ("ts_m", ok)):
        e = np.abs(ds[name].values[mask] / getattr(truth, name)[mask] - 1)
        out[name] = (float(np.median(e)), float(np.percentile(e, 90)))
    return out


def target_pose(normal, centre=(0.0, 0.0, 40.0)):
    """A 300 mm square calibration target at ``centre`` (mm) facing ``normal``.

    Its in-plane axis u is ŷ × n̂, normalised (``normal`` must not be parallel to y).

    Returns
    -------
    facestats.acquire.synthetic.photographs.TargetPose
    """
    from facestats.acquire.synthetic.photographs import TargetPose

    n = np.asarray(normal, float) / np.linalg.norm(normal)
    u = np.cross([0.0, 1.0, 0.0], n)
    return TargetPose(centre, tuple(n), tuple(u / np.linalg.norm(u)), (300.0, 300.0))


def target_rig(leds, side, exposure=1.0):
    """The LED-calibration tests' rig: the default dome restricted to ``leds``, ``side``² frames.

    The camera is 12-bit (full well 20,000 e⁻, read noise 5 e⁻); its log exposure per code is the dome's
    ``camera_log_response`` in every channel.  ``exposure`` scales ``camera_scale`` (0.01: the target at 1 % of the
    full scale).

    Returns
    -------
    camera : facestats.acquire.response.ResponseCurve
    dome : facestats.acquire.dome.Dome
    """
    from dataclasses import replace

    from facestats.acquire.dome import default_dome
    from facestats.acquire.response import ResponseCurve

    camera = ResponseCurve(12, 20000.0, 5.0)
    dome = default_dome().select(leds=leds).resized(side, side)
    g = np.repeat(camera.log_exposure()[:, None], 3, axis=1)
    return camera, replace(dome, camera_log_response=g, camera_scale=dome.camera_scale * exposure)


def unknown_leds(dome):
    """``dome`` with its LED photometry forgotten: intensity 1 in every channel, a flat beam (c = (1, 0, …, 0))."""
    from dataclasses import replace

    flat = np.tile([1.0, 0, 0, 0, 0, 0], (dome.n_leds, 1))
    return replace(dome, led_intensity=np.ones((dome.n_leds, 3)), led_beam=flat)


def beam_error_on(dome, fitted_beam, led, points) -> float:
    """Largest |P_fit / P_true − 1| of ``led``'s beam over the ``points`` (K, 3) in front of it.

    P(s, t) = m(s, t)·c with m the beam monomials (1, s, t, s², st, t²) of :func:`facestats.acquire.dome.beam_terms`
    and c the fitted or the true (``dome.led_beam[led]``) coefficients.
    """
    from facestats.acquire.dome import beam_terms

    _, _, s, t, front = dome.beam_coordinates(points, [led])
    m = beam_terms(s[front[:, 0], 0], t[front[:, 0], 0])
    return float(np.max(np.abs(m @ fitted_beam / (m @ dome.led_beam[led]) - 1)))


def e_perp_error(truth, fitted, points) -> float:
    """Largest relative error |E⊥_fit / E⊥_true − 1| of a fitted rig over ``points`` where E⊥_true > 1e-3.

    E⊥ = I(d) / r² is the irradiance on a plane facing each LED (:meth:`facestats.acquire.dome.Dome.incident`), per
    point, LED and channel.
    """
    e_true, e_fit = truth.incident(points)[1], fitted.incident(points)[1]
    lit = e_true > 1e-3
    return float(np.max(np.abs(e_fit[lit] / e_true[lit] - 1)))
