"""Simulator speed (issue: embedded default).

One default subject, the whole default population, a full-resolution subject.

Figures:

* ``one_subject``: seconds to simulate one default subject (48² lumitexel grid,
  ~1,560 lumitexels × ~940 samples), geometry and shadow maps cached as in a
  population build (target: well under 1 s).
* ``population``: wall time of simulating the whole default population (155
  captures) on this machine's cores (target: under a minute).
* ``full_resolution``: a subject at the paper's full resolution (lumitexel grid
  1,152², about 900,000 lumitexels, 2,048² maps, finer than the grid) streamed
  block by block into a zarr capture kept in ``FACESTATS_BENCH_DIR``
  (:mod:`inputs`: the fit benchmark reuses it while the code is unchanged), with
  the peak resident memory of the process (it runs in a subprocess so the peak
  is its own).
* ``valid_samples``: valid samples per lumitexel (16 cameras × 150 LEDs = 2,400
  (camera, LED) pairs; a sample is valid when the fit may use it:
  :attr:`facestats.acquire.capture.Lumitexels.valid`) over every lumitexel of the
  default population (seed 2006, 48² grid, the 155 records of the embedded
  default) simulated on the ICT face, as ``facestats build --default`` simulates
  it, and on the procedural head (``--face procedural``): median, 5th and 95th
  percentile, mean, minimum and maximum (the README's figures; the paper: about
  900, up to 1,200).
* ``albedo_resolution``: the face-mean albedo of the default population's truth
  (seed 2006, ICT face) drawn at 24², 48² and 96²: equal across sizes since the
  synthetic texture's sub-texel spots keep their physical integral.

Every benchmark takes its sizes as arguments; ``SMOKE`` gives tiny ones that the
test suite runs (``tests/test_benchmarks.py``) so that no benchmark can rot.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from inputs import cached_input  # noqa: E402


def bench_one_subject(grid=48, repeats=5):
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator
    from facestats.face.procedural import procedural_face

    pop = synthesize_population(map_size=grid, geometry=procedural_face(grid))
    t0 = time.perf_counter()
    sim = DomeSimulator(procedural_face(grid))
    sim.simulate(pop[0])  # builds the geometry cache
    setup = time.perf_counter() - t0
    times = []
    for i in range(1, repeats + 1):
        t0 = time.perf_counter()
        cap = sim.simulate(pop[i])
        times.append(time.perf_counter() - t0)
    n = int(np.isfinite(cap.array("radiance")[..., 0]).sum())
    return {
        "seconds_per_subject": float(np.median(times)),
        "setup_s": setup,
        "lumitexels": cap.n_lumitexels,
        "samples": n,
    }


def _simulate_many(ids, grid):
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator
    from facestats.face.procedural import procedural_face

    pop = synthesize_population(map_size=grid, geometry=procedural_face(grid))
    sim = DomeSimulator(procedural_face(grid))
    for sid in ids:
        sim.simulate(pop[sid])
    return len(ids)


def bench_population(grid=48, n_subjects=None):
    from concurrent.futures import ProcessPoolExecutor

    from facestats.acquire.synthetic.population import synthesize_population

    ids = [s.subject_id for s in synthesize_population(map_size=grid).subjects][:n_subjects]
    workers = os.cpu_count() or 1
    chunks = [ids[k::workers] for k in range(workers)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(workers) as ex:
        done = sum(ex.map(_simulate_many, chunks, [grid] * workers))
    return {"seconds": time.perf_counter() - t0, "subjects": done, "workers": workers}


_FULL = r"""
import json, resource, sys, time
from facestats.face.procedural import procedural_face
from facestats.acquire.synthetic.population import synthesize_population
from facestats.acquire.synthetic.simulate import DomeSimulator
t0 = time.perf_counter()
grid, size = int(sys.argv[2]), int(sys.argv[3])
geom = procedural_face(grid, map_size=size)
pop = synthesize_population(map_size=size, geometry=geom, conditions=False, seed=11, subjects=["S001"])
t1 = time.perf_counter()
sim = DomeSimulator(geom, block=8192)
sim.simulate_to_zarr(pop[0], sys.argv[1])
t2 = time.perf_counter()
print(json.dumps({"lumitexels": geom.n_points, "setup_s": t1 - t0, "simulate_s": t2 - t1,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


#: The paper's full resolution: a 1,152² lumitexel grid (about 900,000 lumitexels) and 2,048² maps.
FULL_GRID, FULL_MAP_SIZE = 1152, 2048


def full_resolution_capture(grid=FULL_GRID, map_size=FULL_MAP_SIZE, *, rebuild=False):
    """The full-resolution capture (path) and, when it was simulated now, the simulator's figures.

    Kept in the benchmark directory and reused while the facestats source and the
    sizes are unchanged (:func:`inputs.cached_input`); simulated in a subprocess.
    """

    def make(path):
        out = subprocess.run(
            [sys.executable, "-c", _FULL, path, str(grid), str(map_size)], capture_output=True, text=True, check=True
        )
        return json.loads(out.stdout.strip().splitlines()[-1])

    name = f"capture_{grid}_{map_size}.zarr"
    return cached_input(name, {"grid": grid, "map_size": map_size, "seed": 11}, make, rebuild=rebuild)


def bench_full_resolution(grid=FULL_GRID, map_size=FULL_MAP_SIZE):
    path, fig = full_resolution_capture(grid, map_size, rebuild=True)
    size = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(path) for f in fs)
    fig["capture_gb"] = size / 1e9
    return fig


def bench_valid_samples(grid=48, faces=("ict", "procedural"), n_subjects=None):
    """Valid samples per lumitexel of the default population simulated on each face (module docstring)."""
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator
    from facestats.core.conventions import DEFAULT_SEED
    from facestats.face.named import face_geometry

    out = {}
    for face in faces:
        t0 = time.perf_counter()
        geometry = face_geometry(face, grid)
        pop = synthesize_population(seed=DEFAULT_SEED, map_size=grid, geometry=geometry)
        sim = DomeSimulator(geometry)  # the build's simulator: default dome, noise, Torrance-Sparrow highlights
        truths = pop.subjects[:n_subjects]
        counts = np.concatenate([sim.simulate(t).lumitexels().valid.sum(axis=(1, 2)) for t in truths])
        p5, median, p95 = np.percentile(counts, [5, 50, 95])
        out.update({
            f"{face}_median": float(median),
            f"{face}_p5": float(p5),
            f"{face}_p95": float(p95),
            f"{face}_mean": float(counts.mean()),
            f"{face}_min": int(counts.min()),
            f"{face}_max": int(counts.max()),
            f"{face}_subjects": len(truths),
            f"{face}_lumitexels": geometry.n_points,
            f"{face}_s": time.perf_counter() - t0,
        })  # fmt: skip
    return out


def bench_albedo_resolution(sizes=(24, 48, 96), face="ict"):
    """Face-mean albedo of the default population's truth at several map sizes (module docstring).

    The normal-condition subjects of seed 2006 on ``face``, drawn at each size: the mean over subjects of each
    subject's face-mean albedo (R, G, B).  Spots narrower than a texel keep their physical integral since
    2026-12-07 (:mod:`facestats.acquire.synthetic.texture`), so the means agree across sizes; before, the
    coarser maps were darker (0.357 / 0.394 / 0.404 in R at 24² / 48² / 96², the same computation at 99896b1).
    """
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.core.conventions import DEFAULT_SEED
    from facestats.face.named import face_geometry

    out = {}
    for size in sizes:
        pop = synthesize_population(
            seed=DEFAULT_SEED, map_size=size, geometry=face_geometry(face, size), conditions=False
        )
        means = np.array([s.albedo[s.region_map > 0].mean(0) for s in pop.subjects])
        out[f"{face}_{size}_albedo_mean_rgb"] = [round(float(v), 4) for v in means.mean(0)]
    return out


BENCHMARKS = [
    ("one_subject", bench_one_subject),
    ("population", bench_population),
    ("full_resolution", bench_full_resolution),
    ("valid_samples", bench_valid_samples),
    ("albedo_resolution", bench_albedo_resolution),
]

#: Tiny sizes for the test suite (the full-resolution case keeps its maps finer than its grid).
SMOKE = {
    "one_subject": {"grid": 16, "repeats": 1},
    "population": {"grid": 16, "n_subjects": 4},
    "full_resolution": {"grid": 24, "map_size": 64},
    "valid_samples": {"grid": 16, "n_subjects": 2},
    "albedo_resolution": {"sizes": (16,)},
}
