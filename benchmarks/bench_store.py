"""Parameter store: end-to-end ``facestats query`` time, write and read throughput (issue: store).

Requirement: ``facestats query --skin-type IV`` finishes in at most 1 s end to
end.  Measured as the wall time of the installed console script in a fresh
subprocess (interpreter start-up included), median of several runs, on a zip
store of 160 factory subjects (the size of the paper's population, 149, plus
margin) packed like the embedded default.  Baseline: ``facestats --version``,
the start-up cost of the interpreter and the CLI without any store work.

``subject_io_2048`` writes and reads back (a full, verified and validated
read) the representative 2048² subject with a 16-camera micro-normal map
(``bench_export.representative_subject``): seconds and traced peak memory of
each, against the subject's own size in memory, which a full read must hold
anyway.  Before 2026-12-07 the map's 25 MB Zarr chunks of all cameras, about ten
of them decoded at once, and the validation's copy of its face texels held some
800 MB more at a read.

``validate_2048`` validates a store holding that subject in a fresh process (``Store.validate``: every checksum,
the schema, the index row recomputed) and reports its peak RSS and seconds, with the interpreter's own RSS after
importing what validation imports (the floor), beside :data:`VALIDATE_BASELINE`, the same benchmark run with the
code of commit a1bce51, which loaded every variable of a subject before checking it (``bench_validate(code=...)``
runs it with any checkout's code).
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

N_SUBJECTS = 160
MAP_SIZE = 32
RUNS = 7


def _exe():
    exe = pathlib.Path(sys.executable).parent / "facestats"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "facestats"]


def _wall(args, runs=RUNS) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        r = subprocess.run(_exe() + [str(a) for a in args], capture_output=True, text=True, stdin=subprocess.DEVNULL)
        times.append(time.perf_counter() - t0)
        if r.returncode not in (0, 1):
            raise RuntimeError(f"facestats {' '.join(map(str, args))} failed: {r.stderr}")
    return statistics.median(times)


def _population(n_subjects=N_SUBJECTS):
    from tests.helpers import make_map_subject

    types = [2] * 14 + [3] * 67 + [4] * 48 + [5] * 15 + [6] * 5  # Weyrich Table 2 proportions
    types += [4] * (n_subjects - len(types))
    for k in range(n_subjects):
        yield make_map_subject(
            f"S{k:03d}", size=MAP_SIZE, skin_type=types[k], gender="MF"[k % 4 == 0], age=20 + (k * 7) % 45, seed=k
        )


def bench_query_cli(n_subjects=N_SUBJECTS, runs=RUNS):
    from facestats.io import open_store, pack_store

    tmp = pathlib.Path(tempfile.mkdtemp(prefix="facestats-bench-"))
    try:
        store = tmp / "pop.zarr"
        t0 = time.perf_counter()
        with open_store(store, mode="a") as st:
            batch = []
            for ds in _population(n_subjects):
                batch.append(ds)
                if len(batch) == 20:
                    st.write_subjects(batch)
                    batch = []
            if batch:  # the last, partial batch
                st.write_subjects(batch)
        write_s = time.perf_counter() - t0
        zp = pack_store(store, tmp / "pop.zip")
        q = _wall(["query", "--skin-type", "IV", "--store", zp], runs)
        qj = _wall(["query", "--skin-type", "IV", "--store", zp, "--format", "json"], runs)
        qd = _wall(["query", "--skin-type", "IV", "--store", store], runs)
        base = _wall(["--version"], runs)
        with open_store(zp) as st:
            t0 = time.perf_counter()
            ids = st.ids()[:20]
            for sid in ids:
                st.subject(sid)
            read_ms = (time.perf_counter() - t0) / len(ids) * 1e3
            t0 = time.perf_counter()
            st.query(skin_type="IV")
            api_ms = (time.perf_counter() - t0) * 1e3
        return {
            "query_cli_zip_s": q,
            "limit_s": 1.0,
            "query_cli_json_s": qj,
            "query_cli_directory_s": qd,
            "cli_startup_s": base,
            "query_api_ms": api_ms,
            "subjects": n_subjects,
            "write_subjects_per_s": n_subjects / write_s,
            "read_subject_ms": read_ms,
            "zip_MB": zp.stat().st_size / 1e6,
            "index_kB": (store / "index.json").stat().st_size / 1e3,
        }
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def bench_subject_io(size=2048, cameras=16):
    """Seconds and traced peak MB of writing and of fully reading one size² subject with ``cameras`` micro-normals."""
    import tracemalloc

    from bench_export import representative_subject

    from facestats.io import open_store

    ds = representative_subject(size, cameras=cameras)
    subject_mb = sum(v.nbytes for v in ds.variables.values()) / 2**20
    figures = {}
    with tempfile.TemporaryDirectory() as d, open_store(f"{d}/s.zarr", mode="a") as st:
        for step in ("write", "read"):
            tracemalloc.start()
            t = time.perf_counter()
            back = st.write_subject(ds) if step == "write" else st.subject("S001")
            figures[f"{step}_s"] = time.perf_counter() - t
            figures[f"{step}_peak_MB"] = tracemalloc.get_traced_memory()[1] / 2**20
            tracemalloc.stop()
            if step == "write":
                del ds  # the read starts with nothing held
    return {
        "read_peak_over_subject": figures["read_peak_MB"] / subject_mb,
        **figures,
        "subject_MB": subject_mb,
        "subject_id": back.attrs["subject_id"],
    }


#: ``bench_validate()`` run with the code of commit a1bce51 (every variable of a subject loaded, then checked):
#: peak RSS (MiB) and seconds, medians of 3 runs, 2026-12-07, in 2 batches alternating with this version on a
#: shared 2-core machine (1,323 and 1,328 MiB, 3.14 s both times; this version 345 and 353 MiB, 3.92 and 3.93 s,
#: with a floor of 90 MiB: its large maps were read twice, for their checksums and again for the schema).  Since
#: 68d1132 each band is read once (2026-12-08, alternating with a59b93e, one child each: 371-380 MiB and 4.0-5.0 s
#: against 361-363 MiB and 5.4-9.0 s; docs/store.md).
VALIDATE_BASELINE = {"peak_rss_MB": 1325.0, "s": 3.14}

#: What the child of :func:`bench_validate` runs: validate the store ``argv[1]``, print JSON figures.
#: The peak is the process's VmHWM (Linux): ru_maxrss would carry the parent's peak over the fork.
_VALIDATE_CHILD = """
import json, re, sys, time
import xarray, zarr
from facestats.io import open_store
def hwm():
    with open("/proc/self/status") as f:
        return int(re.search(r"VmHWM:\\s*(\\d+) kB", f.read()).group(1)) / 1024
floor = hwm()
t = time.perf_counter()
with open_store(sys.argv[1]) as st:
    report = st.validate()
seconds = time.perf_counter() - t
print(json.dumps({"peak_rss_MB": hwm(), "s": seconds, "floor_rss_MB": floor, "problems": report.problems}))
"""


def bench_validate(size=2048, cameras=16, runs=3, code=None):
    """Peak RSS (MiB) and seconds of ``Store.validate`` on a store of one representative size² subject.

    Each run is a fresh ``python -c`` (the peak RSS of that process, VmHWM: the interpreter and its imports included,
    given apart as ``floor_rss_MB``); medians of ``runs``.  ``code``: the checkout whose ``facestats`` the child imports
    (default this one), to measure a baseline such as :data:`VALIDATE_BASELINE` with the same store and method.
    """
    from bench_export import representative_subject

    from facestats.io import open_store

    ds = representative_subject(size, cameras=cameras)
    subject_mb = sum(v.nbytes for v in ds.variables.values()) / 2**20
    env = {**os.environ, "PYTHONPATH": str(code or ROOT)}
    with tempfile.TemporaryDirectory() as d:
        with open_store(f"{d}/s.zarr", mode="a") as st:
            st.write_subject(ds)
        del ds
        out = []
        for _ in range(runs):
            r = subprocess.run(
                [sys.executable, "-c", _VALIDATE_CHILD, f"{d}/s.zarr"], capture_output=True, text=True, env=env
            )
            if r.returncode != 0:
                raise RuntimeError(f"validate failed: {r.stderr}")
            out.append(json.loads(r.stdout.strip().splitlines()[-1]))
    if any(o["problems"] for o in out):
        raise RuntimeError(f"the store is not valid: {out[0]['problems']}")
    figures = {k: statistics.median(o[k] for o in out) for k in ("peak_rss_MB", "s", "floor_rss_MB")}
    base = VALIDATE_BASELINE if (size, cameras) == (2048, 16) else {}
    return {
        "peak_rss_MB": figures["peak_rss_MB"],
        "baseline_a1bce51_peak_rss_MB": base.get("peak_rss_MB"),
        "s": figures["s"],
        "baseline_a1bce51_s": base.get("s"),
        "floor_rss_MB": figures["floor_rss_MB"],
        "subject_MB": subject_mb,
    }


BENCHMARKS = [
    ("query_cli", bench_query_cli),
    ("subject_io_2048", bench_subject_io),
    ("validate_2048", bench_validate),
]

#: Tiny sizes for the test suite (tests/test_benchmarks.py).
SMOKE = {
    "query_cli": {"n_subjects": 4, "runs": 1},
    "subject_io_2048": {"size": 64, "cameras": 2},
    "validate_2048": {"size": 64, "cameras": 2, "runs": 1},
}

if __name__ == "__main__":
    for name, fn in BENCHMARKS:
        print(name, fn())
