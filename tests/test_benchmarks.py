"""Every benchmark runs at a tiny size, so that none can rot unnoticed.

Each ``benchmarks/bench_*.py`` lists its benchmarks in ``BENCHMARKS`` and tiny
arguments for each in ``SMOKE``; this runs every one with its smoke arguments
(inputs rebuilt in a temporary ``FACESTATS_BENCH_DIR``: the test's own, or one
folder per session for the benchmarks of ``SHARED_INPUTS``) and checks the
figures it returns.  Timings are not asserted: they belong to the benchmarks.
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import math
import pathlib
import sys

import pytest

BENCH = pathlib.Path(__file__).resolve().parents[1] / "benchmarks"
MODULES = sorted(BENCH.glob("bench_*.py"))
#: Benchmarks whose inputs are built once per session (in one ``FACESTATS_BENCH_DIR`` shared by the xdist
#: workers, ``inputs.cached_input`` locking each build): they ask for the same input with the same arguments
#: (the 24² full-resolution capture, simulated in a subprocess) and never rebuild or delete one.  The first to
#: run builds it, the other reuses it.  (``simulate.full_resolution`` rebuilds that capture: it keeps its own folder.)
SHARED_INPUTS = {"scale.full_resolution", "scale.fit_stages"}


def _distributed_speedup(figures):
    """``fit.dask_scaling`` at its smoke size runs clusters of 1 and 2 workers: its speedup is their rates' ratio."""
    one, two = (figures[f"subjects_per_min_distributed_{w}_workers"] for w in (1, 2))
    assert one > 0 and two > 0
    assert figures["speedup_distributed"] == pytest.approx(two / one) and figures["speedup_distributed"] > 0


#: What particular figures must be, beyond finite: a check per benchmark (its ``group.name``), given its figures.
CHECKS = {"fit.dask_scaling": _distributed_speedup}


@functools.cache
def _load(path):
    """Import a benchmark script once, under its own name (process pools pickle its functions by name)."""
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = module
    spec.loader.exec_module(module)
    return module


def _cases():
    for path in MODULES:
        module = _load(path)
        for name, fn in module.BENCHMARKS:
            yield pytest.param(module, name, fn, id=f"{path.stem[len('bench_') :]}.{name}")


def test_every_benchmark_has_smoke_arguments():
    assert MODULES
    for path in MODULES:
        module = _load(path)
        missing = [name for name, _ in module.BENCHMARKS if name not in getattr(module, "SMOKE", {})]
        assert not missing, f"{path.name}: no SMOKE arguments for {missing}"


@pytest.mark.slow
@pytest.mark.parametrize("module, name, fn", list(_cases()))
def test_benchmark_runs_at_a_tiny_size(module, name, fn, tmp_path, tmp_path_factory, monkeypatch):
    from tests.helpers import once_per_session

    shared = f"{module.__name__[len('bench_') :]}.{name}" in SHARED_INPUTS
    folder = once_per_session("benchmark-inputs", tmp_path_factory, lambda folder: None) if shared else tmp_path
    monkeypatch.setenv("FACESTATS_BENCH_DIR", str(folder))
    monkeypatch.syspath_prepend(str(BENCH))
    figures = fn(**module.SMOKE[name])
    assert isinstance(figures, dict) and figures
    for key, value in figures.items():
        assert isinstance(key, str)
        if isinstance(value, (int, float)):
            assert math.isfinite(value), (key, value)
    check = CHECKS.get(f"{module.__name__[len('bench_') :]}.{name}")
    if check is not None:
        check(figures)


def test_an_input_asked_for_twice_at_once_is_built_once(tmp_path, monkeypatch):
    import threading
    import time

    monkeypatch.setenv("FACESTATS_BENCH_DIR", str(tmp_path))
    monkeypatch.syspath_prepend(str(BENCH))
    inputs = importlib.import_module("inputs")
    built = []

    def make(path):
        built.append(path)
        time.sleep(0.3)  # long enough for the other caller to arrive while this one builds
        pathlib.Path(path).write_text("data")
        return {"made": 1}

    results = []
    callers = [threading.Thread(target=lambda: results.append(inputs.cached_input("x", {"a": 1}, make))) for _ in "ab"]
    for t in callers:
        t.start()
    for t in callers:
        t.join()
    assert len(built) == 1 and sorted(len(r[1]) for r in results) == [0, 1]  # one built, the other reused
    assert inputs.cached_input("x", {"a": 2}, make)[1] == {"made": 1} and len(built) == 2  # other parameters: rebuilt


def test_run_refuses_an_unknown_group(capsys):
    spec = importlib.util.spec_from_file_location("bench_run", BENCH / "run.py")
    run = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(run)
    assert run.main(["relight", "nosuch"]) == 2  # before running anything
    assert "unknown group(s) nosuch; the groups are analysis," in capsys.readouterr().err


def test_validation_images_empty_share_counts_a_face_that_touches_the_border():
    """bench_export's empty share: a face filling the image but for one empty pixel has 1 % empty.  A red team:
    the closing eroded the silhouette where the face touches the image's border (as the baseline's does), and
    the finite pixels cut off still counted, so this image's share was negative and the baseline's 3-4 points low."""
    import numpy as np

    bench_export = _load(BENCH / "bench_export.py")
    img = np.ones((10, 10, 3))
    img[5, 5] = np.nan
    assert bench_export._empty_share(img) == (pytest.approx(0.01), 100)


def test_default_store_accuracy_region_means_are_those_the_cca_reads():
    """bench_analysis's region-mean errors: a subject's region means are the store index's (flagged texels left
    out, :func:`facestats.io.summary.region_samples`), which the CCA reads.  A red team: flagged texels (filled
    from neighbours) counted, so a flagged texel far off moved the error of its region's mean."""
    from types import SimpleNamespace

    import numpy as np
    import xarray as xr

    bench_analysis = _load(BENCH / "bench_analysis.py")
    region = np.repeat(np.arange(1, 11), 4).reshape(5, 8)
    maps = {v: np.full((5, 8), 0.3) for v in ("ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent")}
    truth = SimpleNamespace(albedo=np.full((5, 8, 3), 0.5), **{v: m.copy() for v, m in maps.items()})
    flag = np.zeros((5, 8), np.uint8)
    flag[0, 0] = 1
    maps["ts_rho_s"][0, 0] = 3.0  # flagged: not a measurement
    ds = xr.Dataset(
        {
            "region": (("v", "u"), region),
            "albedo": (("v", "u", "c"), truth.albedo),
            "ts_flag": (("v", "u"), flag),
            "bp_flag": (("v", "u"), flag),
            **{v: (("v", "u"), m) for v, m in maps.items()},
        }
    )
    assert np.abs(bench_analysis._fit_against_truth(ds, truth)["region_mean"]).max() < 1e-12
