"""Simulator speed (issue: embedded default).

One default subject, the whole default population, a full-resolution subject.

Figures:

* ``one_subject``: seconds to simulate one default subject (48² lumitexel grid,
  ~1,560 lumitexels × ~940 samples), geometry and shadow maps cached as in a
  population build (target: well under 1 s).
* ``population``: wall time of simulating the whole default population (156
  captures) on this machine's cores (target: under a minute).
* ``full_resolution``: a subject at the paper's full resolution (lumitexel grid
  1,152², about 900,000 lumitexels, 2,048² maps) streamed block by block into a
  zarr capture in ``FACESTATS_BENCH_DIR`` (default: a temporary directory, removed
  afterwards unless the variable is set), with the peak resident memory of the
  process (it runs in a subprocess so the peak is its own).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np


def bench_one_subject():
    from facestats.acquire.synthetic.face import procedural_face
    from facestats.acquire.synthetic.population import default_population
    from facestats.acquire.synthetic.simulate import DomeSimulator

    pop = default_population()
    t0 = time.perf_counter()
    sim = DomeSimulator(procedural_face(48))
    sim.simulate(pop[0])  # builds the geometry cache
    setup = time.perf_counter() - t0
    times = []
    for i in range(1, 6):
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


def _simulate_many(ids):
    from facestats.acquire.synthetic.face import procedural_face
    from facestats.acquire.synthetic.population import default_population
    from facestats.acquire.synthetic.simulate import DomeSimulator

    pop = default_population()
    sim = DomeSimulator(procedural_face(48))
    for sid in ids:
        sim.simulate(pop[sid])
    return len(ids)


def bench_population():
    from concurrent.futures import ProcessPoolExecutor

    from facestats.acquire.synthetic.population import default_population

    ids = [s.subject_id for s in default_population().subjects]
    workers = os.cpu_count() or 1
    chunks = [ids[k::workers] for k in range(workers)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(workers) as ex:
        done = sum(ex.map(_simulate_many, chunks))
    return {"seconds": time.perf_counter() - t0, "subjects": done, "workers": workers}


_FULL = r"""
import json, resource, sys, time
from facestats.acquire.synthetic.face import procedural_face
from facestats.acquire.synthetic.population import synthesize_population
from facestats.acquire.synthetic.simulate import DomeSimulator
t0 = time.perf_counter()
geom = procedural_face(1152, map_size=2048)
pop = synthesize_population(map_size=2048, geometry=geom, conditions=False, seed=11, subjects=["S001"])
t1 = time.perf_counter()
sim = DomeSimulator(geom, block=8192)
sim.simulate_to_zarr(pop[0], sys.argv[1])
t2 = time.perf_counter()
print(json.dumps({"lumitexels": geom.n_points, "setup_s": t1 - t0, "simulate_s": t2 - t1,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def full_resolution_capture(path):
    """Simulate the full-resolution capture into ``path`` (subprocess); return its figures."""
    out = subprocess.run([sys.executable, "-c", _FULL, str(path)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_full_resolution():
    keep = os.environ.get("FACESTATS_BENCH_DIR")
    root = keep or tempfile.mkdtemp(prefix="facestats-bench-")
    path = os.path.join(root, "full_resolution.zarr")
    try:
        fig = full_resolution_capture(path)
        size = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(path) for f in fs)
        fig["capture_gb"] = size / 1e9
        return fig
    finally:
        if not keep:
            import shutil

            shutil.rmtree(root, ignore_errors=True)


BENCHMARKS = [
    ("one_subject", bench_one_subject),
    ("population", bench_population),
    ("full_resolution", bench_full_resolution),
]
