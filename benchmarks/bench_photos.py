"""Real photographs in (issue 16): HDR merge and response recovery against OpenCV, and a whole-capture ingest.

* ``merge``: Debevec-Malik merge of a 1-megapixel 3-exposure 8-bit stack
  (:func:`facestats.acquire.hdr.merge_photographs`) against OpenCV's
  ``MergeDebevec`` on the same images and response (target ≤ 0.2 s and no slower
  than OpenCV); agreement as the median relative difference of the merged
  radiance after a global scale, with OpenCV's response (same g) and with each
  library's own recovered response, and against colour-hdri's merge.
* ``recover``: response recovery on the same stack (target ≤ 1 s) beside
  OpenCV's ``CalibrateDebevec``, and on a 12-bit stack; error of g against the
  simulated camera's true curve.
* ``real_bracket``: the same on a real bracket, the three CC0 Olympus JPEGs of
  ``tests/data/unis-bracket`` (1024 × 768, exposure times from EXIF): recovery and
  merge times beside OpenCV's, merge agreement with OpenCV (same g, own g) and
  colour-hdri, and each curve's :func:`facestats.acquire.response.exposure_agreement`
  (there is no true curve for real photographs).
* ``ingest``: a whole simulated capture of the default subject (16 cameras ×
  150 LEDs × 2 exposures, 1024² 12-bit PNG, calibration with small errors) made
  once by :func:`facestats.acquire.synthetic.photographs.write_capture_photographs`
  (kept by :func:`inputs.cached_input`), then ingested and fitted in a
  subprocess (peak resident memory of that process; target ≤ 5 minutes for the
  ingest), with the albedo, ρs and m errors against the truth beside those of
  the in-memory path on the same subject, and the frames flagged for head motion
  (``motion_flagged``: camera, LED, score) beside the moved frames.
* ``led_calibration``: the photometric LED calibration on the set-up of
  ``tests/acquire/test_calibration.py`` (8 LEDs, 3 cameras, 4 target poses, 128²
  12-bit frames): intensity, E⊥ over the face and over shells up to 150 mm from
  the head centre, linear and quadratic beam coefficients against the truth,
  residuals, and the beams' standard errors relative to the residual.
* ``led_sparse``: a sparse target (the first 40 LEDs, 2 poses, grid 8): LEDs not
  calibrated, beams flagged ``poorly_determined`` and how wrong they are on the
  target, the others' errors, and the standard error over each LED's own points.
* ``led_underexposed``: the tests' 4-LED target at 100 %, 1 % and 0.3 % of the
  full scale: residuals, intensity errors, LEDs named ``noisy``.
* ``tiff``: 16-bit TIFF decoding by libtiff against OpenCV: the codes each
  returns from a planar file, and decode times for LZW and uncompressed frames.
* ``frobisher``: the real bracket ``frobisher_001`` of colour-hdri-tests-datasets
  from ``$FACESTATS_COLOUR_HDRI_DATASETS`` (not in the repository; ``skipped``
  without it): merge agreement with OpenCV and colour-hdri, same g and own g
  (histogram and stratified samples).
* ``motion_brackets``: the head-motion statistic on those real brackets (UNIS
  always, ``frobisher_001`` when present), each pair of frames whole: their shift by
  phase correlation and the score with 0-8 pixels around clipped pixels left out.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:  # inputs.py, however this module is loaded (run.py, the tests, the ingest subprocess)
    sys.path.insert(0, HERE)
from inputs import (  # noqa: E402
    beam_error_on,
    cached_input,
    colour_hdri_merge,
    e_perp_error,
    fit_errors,
    phase_shift_px,
    scaled_difference,
    target_pose,
    target_rig,
    unknown_leds,
)

TARGET_MERGE_S = 0.2
TARGET_RECOVER_S = 1.0
TARGET_INGEST_S = 300.0
TIMES = np.array([1 / 60, 1 / 15, 1 / 4])


def _stack(side, bits=8, seed=0):
    """A ``side``² scene over four decades photographed by the BT.709 camera at three exposures."""
    from facestats.acquire.response import ResponseCurve

    cam = ResponseCurve(bits=bits)
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:side, 0:side] / side
    rate = np.exp(np.log(3e3) + 8 * xx + 0.7 * np.sin(9 * yy))[..., None] * np.array([1.0, 0.8, 0.6])
    rate *= 1 + 0.2 * rng.random((side, side, 1))
    return cam, rate, [cam.encode(rate * t, rng) for t in TIMES]


def _best(fn, repeat=3):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def bench_merge(side=1024, repeat=3):
    import cv2

    from facestats.acquire.hdr import merge_photographs, recover_response

    _, rate, imgs = _stack(side)
    bgr = [np.ascontiguousarray(i[..., ::-1]) for i in imgs]
    t32 = TIMES.astype(np.float32)
    resp = cv2.createCalibrateDebevec().process(bgr, t32)
    g_cv = np.log(resp[:, 0, ::-1].astype(np.float64))
    t_ours, e_ours = _best(lambda: merge_photographs(imgs, TIMES, g_cv), repeat)
    merger = cv2.createMergeDebevec()
    t_cv, e_cv = _best(lambda: merger.process(bgr, t32, resp), repeat)
    e_cv = e_cv[..., ::-1]
    own = merge_photographs(imgs, TIMES, recover_response(imgs, TIMES))
    out = {
        "ours_s": t_ours,
        "opencv_s": t_cv,
        "opencv_over_ours": t_cv / t_ours,
        "target_s": TARGET_MERGE_S,
        "agreement_same_g": scaled_difference(e_ours, e_cv),
        "agreement_own_g": scaled_difference(own, e_cv),
        "ours_vs_truth": scaled_difference(own, rate),
        "opencv_vs_truth": scaled_difference(e_cv, rate),
        "megapixels": side * side / 1e6,
    }
    try:
        out["agreement_colour_hdri"] = scaled_difference(own, colour_hdri_merge(imgs, TIMES))
    except ImportError:  # colour-hdri is a test extra
        pass
    return out


def bench_recover(side=1024, repeat=2):
    import cv2

    from facestats.acquire.hdr import recover_response

    cam, _, imgs = _stack(side)
    t_ours, g = _best(lambda: recover_response(imgs, TIMES), repeat)
    bgr = [np.ascontiguousarray(i[..., ::-1]) for i in imgs]
    t_cv, resp = _best(lambda: cv2.createCalibrateDebevec().process(bgr, TIMES.astype(np.float32)), repeat)
    true = cam.log_exposure() - cam.log_exposure()[128]
    g_cv = np.log(resp[:, 0, ::-1].astype(np.float64))
    z = np.arange(20, 251)
    cam12, _, imgs12 = _stack(side // 2, bits=12)
    t12, g12 = _best(lambda: recover_response(imgs12, TIMES, bits=12), 1)
    true12 = cam12.log_exposure() - cam12.log_exposure()[2048]
    z12 = np.arange(300, 4000)
    return {
        "ours_s": t_ours,
        "opencv_s": t_cv,
        "target_s": TARGET_RECOVER_S,
        "g_max_err_ours": float(np.abs(g[z] - true[z, None]).max()),
        "g_max_err_opencv": float(np.abs(g_cv[z] - g_cv[128] - true[z, None]).max()),
        "ours_12bit_s": t12,
        "g_max_err_12bit": float(np.abs(g12[z12] - true12[z12, None]).max()),
    }


def bench_real_bracket(side=None, repeat=3):
    """Our response recovery and merge against OpenCV's on the real CC0 bracket (module docstring).

    ``side`` crops the frames to their central ``side``² pixels (the smoke test); None keeps 1024 × 768.
    """
    import cv2

    from facestats.acquire.response import exposure_agreement, merge_photographs, recover_response

    folder = os.path.join(HERE, os.pardir, "tests", "data", "unis-bracket")
    imgs, times = _bracket([os.path.join(folder, f"UNIS_EV{ev}.jpg") for ev in ("-2", "0", "2")], side)
    bgr = [np.ascontiguousarray(i[..., ::-1]) for i in imgs]
    t32 = times.astype(np.float32)
    t_rec, g = _best(lambda: recover_response(imgs, times), repeat)
    t_rec_cv, resp = _best(lambda: cv2.createCalibrateDebevec().process(bgr, t32), repeat)
    g_cv = np.log(resp[:, 0, ::-1].astype(np.float64))
    t_merge, e_same = _best(lambda: merge_photographs(imgs, times, g_cv), repeat)
    merger = cv2.createMergeDebevec()
    t_merge_cv, e_cv = _best(lambda: merger.process(bgr, t32, resp), repeat)
    e_cv = e_cv[..., ::-1]
    own = merge_photographs(imgs, times, g)
    agree, agree_cv = exposure_agreement(imgs, times, g), exposure_agreement(imgs, times, g_cv)
    out = {
        "merge_ours_s": t_merge,
        "merge_opencv_s": t_merge_cv,
        "merge_opencv_over_ours": t_merge_cv / t_merge,
        "recover_ours_s": t_rec,
        "recover_opencv_s": t_rec_cv,
        "agreement_same_g": scaled_difference(e_same, e_cv),
        "agreement_own_g": scaled_difference(own, e_cv),
        "exposure_disagreement_median_ours": agree[:, 0].tolist(),
        "exposure_disagreement_median_opencv": agree_cv[:, 0].tolist(),
        "megapixels": imgs[0].shape[0] * imgs[0].shape[1] / 1e6,
        "exposure_times_s": times.tolist(),
    }
    return {**out, **_against_colour_hdri(imgs, times, own, e_cv)}


def bench_motion_brackets(radii=(0, 2, 4, 8), side=None):
    """The head-motion statistic on real brackets, whole frames (module docstring, ``motion_brackets``).

    For each pair of frames: the shift between them by phase correlation (:func:`inputs.phase_shift_px`), and
    :func:`facestats.acquire.photographs.exposure_consistency`'s score (%) with each ``clip_radius`` in ``radii``;
    the response recovered from the pair's bracket. UNIS always; ``frobisher_001`` when
    ``$FACESTATS_COLOUR_HDRI_DATASETS`` holds it. ``side`` crops the frames to their central ``side``² pixels.
    """
    from facestats.acquire.photographs import exposure_consistency
    from facestats.acquire.response import recover_response

    brackets = {"unis": [os.path.join(HERE, os.pardir, "tests", "data", "unis-bracket", f"UNIS_EV{ev}.jpg")
                         for ev in ("-2", "0", "2")]}  # fmt: skip
    root = os.environ.get(COLOUR_HDRI_DATASETS)
    if root and os.path.isfile(os.path.join(root, "frobisher_001", "IMG_2600.jpg")):
        brackets["frobisher"] = [os.path.join(root, "frobisher_001", f"IMG_260{k}.jpg") for k in (0, 1, 2)]
    out = {}
    for name, files in brackets.items():
        imgs, times = _bracket(files, side)
        g = recover_response(imgs, times)
        box = (0, 0, imgs[0].shape[1], imgs[0].shape[0])
        for a, b in ((0, 1), (1, 2)):
            pair, pair_t = (imgs[a], imgs[b]), times[[a, b]]
            out[f"{name}_{a}{b}"] = {
                "times_s": pair_t.tolist(),
                "shift_px": round(phase_shift_px(pair, pair_t, g), 3),
                "score_pct": {
                    r: round(100 * exposure_consistency(pair, pair_t, g, box, clip_radius=r)[0], 4) for r in radii
                },  # fmt: skip
            }
    return out


def _bracket(files, side):
    """``(images, exposure times from EXIF)`` of a bracket's files (:func:`facestats.acquire.bracket.read_bracket`),
    cropped to their central ``side``² pixels."""
    from facestats.acquire.bracket import read_bracket

    imgs, times, _ = read_bracket(files)
    if side is not None:
        h, w = imgs[0].shape[:2]
        y0, x0 = (h - side) // 2, (w - side) // 2
        imgs = [np.ascontiguousarray(i[y0 : y0 + side, x0 : x0 + side]) for i in imgs]
    return imgs, times


def _against_colour_hdri(imgs, times, own, e_cv):
    """colour-hdri's merge of the bracket against ours and OpenCV's (empty without colour-hdri, a test extra)."""
    try:
        e_ch = colour_hdri_merge(imgs, times)
    except ImportError:
        return {}
    return {
        "agreement_colour_hdri_ours": scaled_difference(own, e_ch),
        "agreement_colour_hdri_opencv": scaled_difference(e_cv, e_ch),
    }


_INGEST = r"""
import json, sys, time
sys.path.insert(0, sys.argv[5])
from inputs import fit_errors
from facestats.acquire.dome import Dome
from facestats.acquire.ingest import ingest_photographs, open_ingested
from facestats.face.named import face_geometry
from facestats.acquire.synthetic.population import synthesize_population
from facestats.io.mesh import load_face_mesh
from facestats.pipeline import fit_subject
folder, out = sys.argv[1], sys.argv[2]
t0 = time.perf_counter()
geometry = load_face_mesh(folder + "/face.obj", folder + "/face.regions.png")
ingest_photographs(folder, geometry, Dome.load(folder + "/dome.json"), out, workers=int(sys.argv[3]),
                   min_footprint_px=float(sys.argv[6]))
t1 = time.perf_counter()
# VmHWM: this process's own peak (ru_maxrss would carry the parent's peak over fork and exec)
peak = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM")) / 1024
cap = open_ingested(out)
ds = fit_subject(cap)
grid = int(sys.argv[4])
truth = synthesize_population(map_size=grid, geometry=face_geometry("procedural", grid), subjects=["S001"])["S001"]
flags = cap.provenance.get("motion_flags", [])
print(json.dumps({"ingest_s": t1 - t0, "fit_s": time.perf_counter() - t1, "peak_rss_ingest_mb": peak,
                  "motion_flags": len(flags), "motion_flagged": [[f["camera"], f["led"], f["score"]] for f in flags],
                  "errors": fit_errors(ds, truth)}))
"""


def bench_ingest(grid=48, side=1024, leds=None, workers=2, min_footprint_px=2.0):
    """Whole-capture ingest and fit of the default subject S001 (module docstring)."""
    import shutil

    from facestats.acquire.dome import default_dome
    from facestats.acquire.synthetic.photographs import write_capture_photographs
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator
    from facestats.face.procedural import procedural_face
    from facestats.pipeline import fit_subject

    geometry = procedural_face(grid)
    truth = synthesize_population(map_size=grid, geometry=geometry, subjects=["S001"])["S001"]
    dome = default_dome().resized(side, side)
    if leds is not None:
        dome = dome.select(leds=np.arange(leds))
    # two frames whose LED lights the face in that camera (LED 1 lit nothing well exposed in camera 4: a moved
    # frame without evidence, which no statistic can flag)
    moved = [(4, 10), (11, 70)] if dome.n_leds > 70 else [(4, 10), (11, 15)] if dome.n_leds > 15 else [(4, 1)]

    def make(path):
        t0 = time.perf_counter()
        write_capture_photographs(truth, path, geometry=geometry, dome=dome, moved_frames=moved, progress=True)
        return {"write_s": time.perf_counter() - t0}

    folder, made = cached_input("photos-S001", {"grid": grid, "side": side, "leds": leds}, make)
    out_path = os.path.join(os.path.dirname(folder), "photos-S001-capture.zarr")
    shutil.rmtree(out_path, ignore_errors=True)
    run = subprocess.run(
        [sys.executable, "-c", _INGEST, folder, out_path, str(workers), str(grid), HERE, str(min_footprint_px)],
        capture_output=True,
        text=True,
        check=True,
    )
    shutil.rmtree(out_path, ignore_errors=True)
    result = json.loads(run.stdout.strip().splitlines()[-1])
    figures = {k: result.pop(k) for k in ("ingest_s", "peak_rss_ingest_mb", "fit_s", "motion_flags", "motion_flagged")}
    figures.update({f"simulate_{k}": v for k, v in made.items()})
    figures.update(frames=2 * dome.n_cameras * dome.n_leds, target_s=TARGET_INGEST_S, moved_frames=len(moved))
    figures["moved"] = moved
    photo, memory = result["errors"], fit_errors(fit_subject(DomeSimulator(geometry, dome).simulate(truth)), truth)
    for k in photo:
        for j, stat in enumerate(("median", "p90")):
            figures[f"photo_{k}_{stat}"] = photo[k][j]
            figures[f"memory_{k}_{stat}"] = memory[k][j]
    for k in photo:
        figures[f"{k}_median_ratio_photo_over_memory"] = photo[k][0] / memory[k][0]
    return figures


def bench_agreement_memory(side=4096):
    """Peak memory of the agreement diagnostic and the merge of a ``side``² three-exposure 8-bit bracket.

    The baseline is the codes themselves: before 2026-12-06 :func:`exposure_agreement` made int64 copies of whole
    frames, masks and gathers, 37 bytes a sample (a red team: 2.7 GB beside a 24-megapixel bracket); it now reads
    at most ``AGREEMENT_SAMPLES`` samples on a grid of pixels.
    """
    import tracemalloc

    from facestats.acquire.hdr import merge_photographs
    from facestats.acquire.response import exposure_agreement

    cam, _, imgs = _stack(side)
    g = cam.log_exposure() - cam.log_exposure()[128]
    codes = sum(a.nbytes for a in imgs)
    out = {"megapixels": side * side / 1e6, "codes_mb": codes / 1e6}
    for name, fn in (("agreement", lambda: exposure_agreement(imgs, TIMES, g)),
                     ("merge", lambda: merge_photographs(imgs, TIMES, g))):  # fmt: skip
        tracemalloc.start()
        t0 = time.perf_counter()
        fn()
        out[f"{name}_s"] = time.perf_counter() - t0
        out[f"{name}_peak_mb"] = tracemalloc.get_traced_memory()[1] / 1e6
        tracemalloc.stop()
        out[f"{name}_bytes_per_sample"] = out[f"{name}_peak_mb"] * 1e6 / imgs[0].size
    return out


# -- LED calibration from a simulated target (tests/acquire/test_calibration.py's set-ups) ---------------------------
def bench_led_calibration(side=128, grid=24, face_grid=24, shell_points=1000):
    """The photometric LED calibration on the set-up of ``tests/acquire/test_calibration.py`` (8 LEDs spread over
    the dome, 3 cameras, 4 poses of a Fluorilon target of albedo 0.99, ``side``² 12-bit frames): the fitted
    intensities, E⊥ over the face and over shells of radius 50, 100 and 150 mm around the head centre, the beam
    coefficients against the simulator's truth, the residuals and the beams' standard errors."""
    import tempfile

    from facestats.acquire.calibration import calibrate_leds
    from facestats.acquire.synthetic.photographs import write_target_photographs
    from facestats.face.procedural import procedural_face

    camera, truth = target_rig([0, 20, 41, 60, 83, 101, 122, 147], side)
    poses = [target_pose((0, 0, 1)), target_pose((3.7, 0, 1)), target_pose((-3.7, 0, 1)), target_pose((0, 0.9, 1))]
    with tempfile.TemporaryDirectory() as folder:
        write_target_photographs(folder, truth, poses, cameras=[3, 4, 11], camera=camera)
        t0 = time.perf_counter()
        res = calibrate_leds(folder, unknown_leds(truth), grid=grid)
        fit_s = time.perf_counter() - t0
    fitted = res.apply(truth)
    d = np.random.default_rng(1).standard_normal((3 * shell_points, 3))
    radius = np.repeat([50.0, 100.0, 150.0], shell_points)[:, None]
    shells = np.array([0.0, 0.0, 40.0]) + d / np.linalg.norm(d, axis=1, keepdims=True) * radius
    beam_err = np.abs(res.beam - truth.led_beam)
    return {
        "intensity_max_rel_err": float(np.max(np.abs(res.intensity / truth.led_intensity - 1))),
        "e_perp_face_max_rel_err": e_perp_error(truth, fitted, procedural_face(face_grid).position),
        "e_perp_shells_max_rel_err": e_perp_error(truth, fitted, shells),
        "rms_residual_min": float(np.min(res.rms_residual)),
        "rms_residual_max": float(np.max(res.rms_residual)),
        "beam_linear_max_abs_err": float(beam_err[:, 1:3].max()),  # c1, c2: s, t
        "beam_quadratic_max_abs_err": float(beam_err[:, 3:].max()),  # c3..c5: s², st, t²
        "beam_error_over_residual_max": float(np.max(res.beam_error / res.rms_residual)),
        "poorly_determined": int(res.poorly_determined.size),
        "camera_gain_max_abs_err": float(np.max(np.abs(res.camera_gain[[3, 4, 11]] - 1))),
        "observations_min": int(res.n_observations.min()),
        "calibrate_s": fit_s,
    }


def bench_led_sparse(leds=40, side=96, grid=8):
    """``calibrate leds --grid 8`` on a sparse target: the first ``leds`` LEDs of the dome, 3 cameras, 2 poses
    (facing the dome's axis and tilted by 75° about y; the set-up of the tests' ``sparse_target`` with more LEDs).

    Prints how many LEDs are not calibrated and flagged (``poorly_determined``), how wrong the flagged and the other
    beams are on the target (largest |P_fit / P_true − 1| over the target points in front of the LED), the flagged
    LED with the largest such error (its c₃ ± standard error and the truth), the others' standard errors relative to
    their residual, and the same ratio over only the points each LED was fitted from (lit from the front at more
    than 0.05 in cosine, the fit's own rule: a least-squares fit is never less certain there than one observation,
    leverage at most 1).
    """
    import tempfile

    from facestats.acquire.calibration import fit_leds, target_observations
    from facestats.acquire.synthetic.photographs import write_target_photographs

    camera, truth = target_rig(np.arange(leds), side)
    with tempfile.TemporaryDirectory() as folder:
        write_target_photographs(
            folder, truth, [target_pose((0, 0, 1)), target_pose((3.7, 0, 1))], cameras=[3, 4, 11], camera=camera
        )
        obs = target_observations(folder, truth, grid=grid)
    res = fit_leds(truth, obs)
    fitted = np.nonzero(np.isfinite(res.intensity).all(1))[0]
    flagged = res.poorly_determined
    good = np.setdiff1d(fitted, flagged)
    err = {int(i): beam_error_on(truth, res.beam[i], i, obs["target_points"]) for i in fitted}
    own = []  # beam_error over the points each LED was fitted from (lit from the front at cosine > 0.05)
    for i in fitted:  # one small fit per LED
        pts, normal = obs["point"][obs["led"] == i], obs["normal"][obs["led"] == i]
        wi, _, _, _, front = truth.beam_coordinates(pts, [i])
        used = front[:, 0] & (np.einsum("nk,nk->n", wi[:, 0], normal) > 0.05)
        mine = fit_leds(truth, dict(obs, target_points=pts[used]))
        own.append(mine.beam_error[i] / mine.rms_residual[i])
    out = {
        "leds": leds,
        "uncalibrated": int(res.uncalibrated.size),
        "poorly_determined": int(flagged.size),
        "well_determined": int(good.size),
    }
    if flagged.size:
        worst = max(flagged, key=lambda i: err[int(i)])
        out.update(
            flagged_leds=flagged.tolist(),
            flagged_beam_err=[err[int(i)] for i in flagged],
            flagged_beam_err_min=min(err[int(i)] for i in flagged),
            flagged_beam_err_max=err[int(worst)],
            worst_flagged_led=int(worst),
            worst_flagged_c3=float(res.beam[worst, 3]),
            worst_flagged_c3_stderr=float(res.beam_stderr[worst, 3]),
            worst_flagged_c3_true=float(truth.led_beam[worst, 3]),
        )
    if good.size:
        out.update(
            others_beam_err_max=max(err[int(i)] for i in good),
            others_beam_error_over_residual_max=float(np.max(res.beam_error[good] / res.rms_residual[good])),
        )
    out["own_points_beam_error_over_residual_max"] = float(np.max(own))
    return out


def _worst_intensity(res, truth, skip=()):
    """The signed relative intensity error of largest magnitude over the fitted LEDs not in ``skip``."""
    ratio = res.intensity / truth.led_intensity - 1
    ratio[np.asarray(skip, dtype=np.int64)] = np.nan
    return float(ratio.flat[np.nanargmax(np.abs(ratio))]) if np.isfinite(ratio).any() else float("nan")


def bench_led_underexposed(side=64, grid=24, exposures=(1.0, 0.01, 0.003), leds=(0, 20, 41, 60)):
    """The LED calibration of a target photographed at a fraction of the full scale: the set-up of the tests'
    underexposed target (``leds``, default 0, 20, 41 and 60; cameras 3 and 4, 2 poses, ``side``² 12-bit frames),
    ``camera_scale`` times each of ``exposures``.

    For each exposure: the residuals (min-max), the LEDs named ``noisy``, and the largest intensity error (signed:
    observations near the noise floor read high) over the fitted LEDs and over those whose beam is not
    ``poorly_determined`` (an extrapolated beam has its own error)."""
    import tempfile

    from facestats.acquire.calibration import calibrate_leds
    from facestats.acquire.synthetic.photographs import write_target_photographs

    out = {}
    for exposure in exposures:  # one small target each
        camera, truth = target_rig(list(leds), side, exposure)
        key = f"x{exposure:g}"
        with tempfile.TemporaryDirectory() as folder:
            write_target_photographs(
                folder, truth, [target_pose((0, 0, 1)), target_pose((3.7, 0, 1))], cameras=[3, 4], camera=camera
            )
            res = calibrate_leds(folder, unknown_leds(truth), grid=grid)
        out[f"{key}_rms_residual_min"] = float(np.nanmin(res.rms_residual))
        out[f"{key}_rms_residual_max"] = float(np.nanmax(res.rms_residual))
        out[f"{key}_noisy"] = int(res.noisy.size)
        out[f"{key}_poorly_determined"] = int(res.poorly_determined.size)
        out[f"{key}_intensity_err_max"] = _worst_intensity(res, truth)
        out[f"{key}_intensity_err_max_well_determined"] = _worst_intensity(res, truth, res.poorly_determined)
    return out


# -- 16-bit TIFF frames ---------------------------------------------------------------------------------------------
def bench_tiff(side=1024, repeat=5):
    """16-bit RGB TIFF frames: libtiff (:func:`facestats.io.images.decode_integer_image`) against OpenCV.

    A planar (PlanarConfiguration 2) TIFF of random codes with a constant blue channel of 30000 (the tests' layout,
    ``side``²): the fraction of codes each decoder returns exactly, and the first blue codes OpenCV returns.
    A contiguous TIFF of a simulated 12-bit photograph (the middle exposure of the ``recover`` scene), LZW and
    uncompressed: decode time (best of ``repeat``) of ours and of ``cv2.imdecode`` (BGR, as OpenCV returns it).
    """
    import io

    import cv2
    import tifffile

    from facestats.io.images import decode_integer_image

    rgb = np.random.default_rng(16).integers(0, 65536, (side, side, 3), dtype=np.uint16)
    rgb[..., 2] = 30000
    buf = io.BytesIO()
    tifffile.imwrite(buf, np.ascontiguousarray(np.moveaxis(rgb, -1, 0)), photometric="rgb", planarconfig="separate")
    planar = buf.getvalue()
    cv = cv2.imdecode(np.frombuffer(planar, np.uint8), cv2.IMREAD_UNCHANGED)[..., ::-1]
    out = {
        "planar_ours_matching": float(np.mean(decode_integer_image(planar, "planar.tif")[0] == rgb)),
        "planar_opencv_matching": float(np.mean(cv == rgb)),
        "planar_opencv_blue_first_codes": cv[0, :4, 2].tolist(),
        "megapixels": side * side / 1e6,
    }
    frame = np.ascontiguousarray(_stack(side, bits=12)[2][1])
    for compression in ("lzw", None):
        buf = io.BytesIO()
        tifffile.imwrite(buf, frame, photometric="rgb", compression=compression)
        data = buf.getvalue()
        name = compression or "uncompressed"
        t_ours, ours = _best(lambda: decode_integer_image(data, "frame.tif"), repeat)
        t_cv, cv = _best(lambda: cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED), repeat)
        assert np.array_equal(ours[0], frame) and np.array_equal(cv[..., ::-1], frame)
        out[f"{name}_ours_ms"], out[f"{name}_opencv_ms"] = 1e3 * t_ours, 1e3 * t_cv
    return out


# -- a real bracket outside the repository ---------------------------------------------------------------------------
COLOUR_HDRI_DATASETS = "FACESTATS_COLOUR_HDRI_DATASETS"


def bench_frobisher(side=None):
    """``frobisher_001`` of colour-science/colour-hdri-tests-datasets (three Canon EOS 5D Mark II JPEGs, 1/8, 1 and
    8 s from EXIF), read from ``$FACESTATS_COLOUR_HDRI_DATASETS/frobisher_001`` as ``tests/acquire/test_response.py``
    does (not in the repository: the JPEGs carry no licence file of their own). Without it the benchmark returns
    only ``skipped``, saying why.

    Median relative differences after a global scale (as ``real_bracket``): our merge with OpenCV's recovered g
    against OpenCV's merge; each library's own recovered g (ours from histogram and from stratified samples)
    against OpenCV's merge and colour-hdri's; and each curve's median exposure disagreement. ``side`` crops the
    frames to their central ``side``² pixels.
    """
    import cv2

    from facestats.acquire.response import exposure_agreement, merge_photographs, recover_response

    root = os.environ.get(COLOUR_HDRI_DATASETS)
    folder = os.path.join(root, "frobisher_001") if root else None
    if folder is None or not os.path.isfile(os.path.join(folder, "IMG_2600.jpg")):
        return {
            "skipped": f"real bracket absent: set {COLOUR_HDRI_DATASETS} to a checkout of "
            "colour-science/colour-hdri-tests-datasets (frobisher_001: three Canon JPEGs, 1/8, 1 and 8 s)"
            + (f"; {root}/frobisher_001/IMG_2600.jpg not found" if root else "")
        }
    imgs, times = _bracket([os.path.join(folder, f"IMG_260{k}.jpg") for k in (0, 1, 2)], side)
    bgr = [np.ascontiguousarray(i[..., ::-1]) for i in imgs]
    t32 = times.astype(np.float32)
    resp = cv2.createCalibrateDebevec().process(bgr, t32)
    e_cv = cv2.createMergeDebevec().process(bgr, t32, resp)[..., ::-1]
    g_cv = np.log(resp[:, 0, ::-1].astype(np.float64))
    g_hist, g_strat = recover_response(imgs, times), recover_response(imgs, times, samples="stratified")
    own, strat = merge_photographs(imgs, times, g_hist), merge_photographs(imgs, times, g_strat)
    out = {
        "exposure_times_s": times.tolist(),
        "agreement_same_g": scaled_difference(merge_photographs(imgs, times, g_cv), e_cv),
        "agreement_own_g_histogram": scaled_difference(own, e_cv),
        "agreement_own_g_stratified": scaled_difference(strat, e_cv),
        "exposure_disagreement_median_ours": exposure_agreement(imgs, times, g_hist)[:, 0].tolist(),
        "exposure_disagreement_median_opencv": exposure_agreement(imgs, times, g_cv)[:, 0].tolist(),
    }
    return {**out, **_against_colour_hdri(imgs, times, own, e_cv)}


BENCHMARKS = [
    ("merge", bench_merge),
    ("agreement_memory", bench_agreement_memory),
    ("recover", bench_recover),
    ("real_bracket", bench_real_bracket),
    ("ingest", bench_ingest),
    ("led_calibration", bench_led_calibration),
    ("led_sparse", bench_led_sparse),
    ("led_underexposed", bench_led_underexposed),
    ("tiff", bench_tiff),
    ("frobisher", bench_frobisher),
    ("motion_brackets", bench_motion_brackets),
]

#: Tiny sizes for the test suite (tests/test_benchmarks.py).
SMOKE = {
    "merge": {"side": 64, "repeat": 1},
    "agreement_memory": {"side": 64},
    "recover": {"side": 64, "repeat": 1},
    "real_bracket": {"side": 128, "repeat": 1},
    "ingest": {"grid": 16, "side": 64, "leds": 8, "workers": 1, "min_footprint_px": 0.5},
    "led_calibration": {"side": 48, "grid": 6, "face_grid": 8, "shell_points": 20},
    "led_sparse": {"leds": 6, "side": 48, "grid": 4},
    "led_underexposed": {"side": 32, "grid": 4, "exposures": (1.0, 0.003)},
    "tiff": {"side": 32, "repeat": 1},
    "frobisher": {"side": 64},
    "motion_brackets": {"radii": (0, 4), "side": 128},
}
