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
  the in-memory path on the same subject.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
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


def _scaled_rel(a, b):
    r = np.asarray(a, np.float64) / np.asarray(b, np.float64)
    ok = np.isfinite(r) & (r > 0)
    return float(np.median(np.abs(r[ok] / np.median(r[ok]) - 1)))


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
        "agreement_same_g": _scaled_rel(e_ours, e_cv),
        "agreement_own_g": _scaled_rel(own, e_cv),
        "ours_vs_truth": _scaled_rel(own, rate),
        "opencv_vs_truth": _scaled_rel(e_cv, rate),
        "megapixels": side * side / 1e6,
    }
    try:
        from tests.helpers import colour_hdri_merge

        out["agreement_colour_hdri"] = _scaled_rel(own, colour_hdri_merge(imgs, TIMES))
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
    from facestats.io.exif import read_exposure_time
    from facestats.io.images import read_integer_image

    folder = os.path.join(HERE, os.pardir, "tests", "data", "unis-bracket")
    files = [os.path.join(folder, f"UNIS_EV{ev}.jpg") for ev in ("-2", "0", "2")]
    times = np.array([read_exposure_time(f) for f in files])
    imgs = [read_integer_image(f)[0] for f in files]
    if side is not None:
        h, w = imgs[0].shape[:2]
        y0, x0 = (h - side) // 2, (w - side) // 2
        imgs = [np.ascontiguousarray(i[y0 : y0 + side, x0 : x0 + side]) for i in imgs]
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
        "agreement_same_g": _scaled_rel(e_same, e_cv),
        "agreement_own_g": _scaled_rel(own, e_cv),
        "exposure_disagreement_median_ours": agree[:, 0].tolist(),
        "exposure_disagreement_median_opencv": agree_cv[:, 0].tolist(),
        "megapixels": imgs[0].shape[0] * imgs[0].shape[1] / 1e6,
        "exposure_times_s": times.tolist(),
    }
    try:
        from tests.helpers import colour_hdri_merge

        e_ch = colour_hdri_merge(imgs, times)
        out["agreement_colour_hdri_ours"] = _scaled_rel(own, e_ch)
        out["agreement_colour_hdri_opencv"] = _scaled_rel(e_cv, e_ch)
    except ImportError:  # colour-hdri is a test extra
        pass
    return out


_INGEST = r"""
import json, sys, time
sys.path.insert(0, sys.argv[5])
from bench_photos import _errors
from facestats.acquire.dome import Dome
from facestats.acquire.ingest import ingest_photographs, open_ingested
from facestats.acquire.synthetic.faces import face_geometry
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
print(json.dumps({"ingest_s": t1 - t0, "fit_s": time.perf_counter() - t1, "peak_rss_ingest_mb": peak,
                  "motion_flags": len(cap.provenance.get("motion_flags", [])), **_errors(ds, truth)}))
"""


def _errors(ds, truth):
    face = truth.region_map > 0
    ok = face & (ds.ts_flag.values == 0)
    out = {}
    for name, mask in (("albedo", face), ("ts_rho_s", ok), ("ts_m", ok)):
        e = np.abs(ds[name].values[mask] / getattr(truth, name)[mask] - 1)
        out[f"{name}_median"], out[f"{name}_p90"] = float(np.median(e)), float(np.percentile(e, 90))
    return out


def bench_ingest(grid=48, side=1024, leds=None, workers=2, min_footprint_px=2.0):
    """Whole-capture ingest and fit of the default subject S001 (module docstring)."""
    import shutil

    sys.path.insert(0, HERE)
    from inputs import cached_input

    from facestats.acquire.dome import default_dome
    from facestats.acquire.synthetic.face import procedural_face
    from facestats.acquire.synthetic.photographs import write_capture_photographs
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator
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
    figures = {k: result.pop(k) for k in ("ingest_s", "peak_rss_ingest_mb", "fit_s", "motion_flags")}
    figures.update({f"simulate_{k}": v for k, v in made.items()})
    figures.update(frames=2 * dome.n_cameras * dome.n_leds, target_s=TARGET_INGEST_S, moved_frames=len(moved))
    memory = _errors(fit_subject(DomeSimulator(geometry, dome).simulate(truth)), truth)
    for k in result:
        figures[f"photo_{k}"] = result[k]
        figures[f"memory_{k}"] = memory[k]
    for k in ("albedo", "ts_rho_s", "ts_m"):
        figures[f"{k}_median_ratio_photo_over_memory"] = result[f"{k}_median"] / memory[f"{k}_median"]
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


BENCHMARKS = [
    ("merge", bench_merge),
    ("agreement_memory", bench_agreement_memory),
    ("recover", bench_recover),
    ("real_bracket", bench_real_bracket),
    ("ingest", bench_ingest),
]

#: Tiny sizes for the test suite (tests/test_benchmarks.py).
SMOKE = {
    "merge": {"side": 64, "repeat": 1},
    "agreement_memory": {"side": 64},
    "recover": {"side": 64, "repeat": 1},
    "real_bracket": {"side": 128, "repeat": 1},
    "ingest": {"grid": 16, "side": 64, "leds": 8, "workers": 1, "min_footprint_px": 0.5},
}
