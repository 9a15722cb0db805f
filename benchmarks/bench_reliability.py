"""The cost of the store's safety (issue #12): verified reads, the checked index, repair planning.

Each benchmark puts the safe path beside the baseline it replaced, on the same data:

* ``lazy_band_read`` — one 64-row band of a 2048² map read lazily, every chunk checked against its
  CRC-32 (:mod:`facestats.io.integrity`), against the same band through ``xarray.open_zarr`` with
  no check (what a lazy read did before); also the whole map read both ways.
* ``index_parse`` — the population index of a 160-subject store parsed and every entry checked
  (:func:`facestats.io.index.parse_index`) against ``json.loads`` alone.
* ``repair_plan`` — :meth:`Store.plan_repair` of a store (every subject opened and checksummed,
  the layout surveyed) against reading every subject once with :meth:`Store.subject` (the checksum
  work alone): the ratio is what planning adds.

Run ``python benchmarks/run.py reliability``.  Inputs are built once under ``FACESTATS_BENCH_DIR``
(:func:`inputs.cached_input`).
"""

from __future__ import annotations

import json
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
for p in (ROOT, pathlib.Path(__file__).resolve().parent):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from inputs import cached_input  # noqa: E402


def _best(fn, repeat):
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _store(name, n_subjects, size):
    from facestats.io import open_store
    from tests.helpers import make_map_subject

    def make(path):
        with open_store(path, mode="a") as st:
            for k in range(n_subjects):
                st.write_subject(make_map_subject(f"B{k:03d}", size=size, seed=k, skin_type=2 + k % 5))

    return cached_input(name, {"n": n_subjects, "size": size}, make)[0]


def bench_lazy_band_read(size=2048, repeat=5):
    import xarray as xr

    from facestats.io import open_store

    path = _store(f"reliability-band-{size}", 1, size)
    with open_store(path) as st:
        group = f"{path}/subjects/B000/{st.index_entries()['B000']['generation']}"

        def read(verified, band):
            ds = st.subject("B000", lazy=True) if verified else xr.open_zarr(group, consolidated=False, chunks=None)
            var = ds["albedo"]
            return (var.isel(v=slice(64, 128)) if band else var).values

        tb, pb = (_best(lambda v=v: read(v, True), repeat) for v in (True, False))
        ta, pa = (_best(lambda v=v: read(v, False), max(1, repeat // 2)) for v in (True, False))
    return {
        "verified_band_ms": tb * 1e3,
        "unverified_band_ms": pb * 1e3,
        "band_ratio": tb / pb,
        "verified_map_ms": ta * 1e3,
        "unverified_map_ms": pa * 1e3,
        "map_ratio": ta / pa,
        "map_size": size,
    }


def bench_index_parse(n_subjects=160, size=16, repeat=20):
    from facestats.io.index import parse_index

    path = _store(f"reliability-index-{n_subjects}", n_subjects, size)
    data = (pathlib.Path(path) / "index.json").read_bytes()
    checked = _best(lambda: parse_index(data), repeat)
    plain = _best(lambda: json.loads(data), repeat)
    return {"checked_ms": checked * 1e3, "json_loads_ms": plain * 1e3, "ratio": checked / plain, "subjects": n_subjects}


def bench_repair_plan(n_subjects=40, size=64, repeat=3):
    from facestats.io import open_store

    path = _store(f"reliability-plan-{n_subjects}-{size}", n_subjects, size)
    with open_store(path) as st:
        ids = st.ids()
        plan = _best(lambda: st.plan_repair(), repeat)
        reads = _best(lambda: [st.subject(s) for s in ids], repeat)
    return {"plan_s": plan, "read_every_subject_s": reads, "ratio": plan / reads, "subjects": n_subjects}


BENCHMARKS = [
    ("lazy_band_read", bench_lazy_band_read),
    ("index_parse", bench_index_parse),
    ("repair_plan", bench_repair_plan),
]

#: Tiny sizes for the test suite (tests/test_benchmarks.py).
SMOKE = {
    "lazy_band_read": {"size": 130, "repeat": 1},
    "index_parse": {"n_subjects": 4, "size": 8, "repeat": 1},
    "repair_plan": {"n_subjects": 2, "size": 8, "repeat": 1},
}
