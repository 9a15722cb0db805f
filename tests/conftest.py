import os
import sys

# Two test workers (``-n 2``) already fill two cores: one BLAS thread per process. The variables reach every
# process the tests start (xdist workers, console scripts, notebook kernels, build workers) before it loads
# OpenBLAS; this process may have loaded it already (zarr's pytest plugin imports numpy), so it is also limited
# here. numba's ``prange`` kernels keep their own thread count (its OpenMP layer does not read OMP_NUM_THREADS).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
# numba's OpenMP threads spin-wait between parallel regions by default (GNU OpenMP), burning the core the other
# worker needs: tests/model/microstructure + tests/relight took 36-43 s of CPU with it, 27-29 s passive (same
# results: only how idle threads wait changes). Read when libgomp loads, so set before any kernel runs.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
# The processes the tests start import the checkout's sources: let them keep its bytecode in __pycache__
# (git ignores it; numba's kernel caches live there already). Where PYTHONDONTWRITEBYTECODE is set, as in
# this workplace, every console script, notebook kernel and worker compiled facestats afresh: about 0.2-0.3 s
# each, hundreds of times a run.
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
sys.dont_write_bytecode = False

import matplotlib  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

threadpool_limits(int(os.environ["OPENBLAS_NUM_THREADS"]), user_api="blas")
matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


#: Folders whose tests are end-to-end by nature (a notebook run, a console script in a subprocess, the
#: hostile-input corpus against both, a headless browser): all ``slow``, so ``-m "not slow"`` keeps
#: the everyday loop to the library's own tests.  CI runs everything.
END_TO_END = ("tests/notebooks/", "tests/cli/", "tests/reliability/", "tests/web/test_browser.py")


#: Modules with a test of 20 s or more: run first, so that under ``-n 2`` the other worker's queue fills
#: the time instead of the suite waiting for a long test that started last (order within a module kept).
LONG_FIRST = (
    "tests/pipeline/test_default_store.py",
    "tests/reliability/test_build_workers.py",
    "tests/model/fitting/test_engines.py",
    "tests/notebooks/test_microstructure.py",
)


def pytest_collection_modifyitems(config, items):
    root = str(config.rootpath) + os.sep
    rank = {}
    for item in items:
        rel = str(item.path).removeprefix(root).replace(os.sep, "/")
        if rel.startswith(END_TO_END):
            item.add_marker(pytest.mark.slow)
        rank[item.nodeid] = 0 if rel in LONG_FIRST else 1
    items.sort(key=lambda item: rank[item.nodeid])  # stable: the order within each group is kept


#: The checkout under test, first on the path of every process the tests start (console scripts,
#: notebook kernels, build workers): they then run the same files as the tests themselves, and share
#: their numba cache (kept beside the sources), instead of compiling every kernel a second time for the
#: copy that ``pip install .`` put in site-packages (the console scripts stay the installed ones; that
#: the installed package holds every file of the checkout is tests/test_packaging.py's job).
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (REPO, os.environ.get("PYTHONPATH")) if p)


def pytest_configure(config):
    """Under ``-n N`` (N > 1), compile the numba kernels once before the workers start.

    numba compiles a kernel on its first call and caches it on disk; on a fresh install the workers and
    the processes they start (the default-store regeneration's two build workers, the build-worker
    test's builds of three processes each, console scripts, the microstructure notebook's kernel) would
    otherwise all compile the same kernels at the same time, some 20 CPU-seconds a family each.  The
    fit's kernels compile here while the microstructure's compile in a second process, on the other
    core (about 25 s with an empty cache, 3 s with a warm one).
    """
    if hasattr(config, "workerinput") or (config.getoption("numprocesses", default=None) or 0) in (0, 1):
        return  # an xdist worker, or a run in one process: nothing to share
    import subprocess

    from tests import warmup

    other = subprocess.Popen([sys.executable, "-m", "tests.warmup", "microstructure"], cwd=REPO)
    try:
        warmup.fit_kernels()
    finally:
        if other.wait() != 0:  # the tests that need these kernels will fail and say why
            print("tests.warmup microstructure failed: the workers compile these kernels themselves", file=sys.stderr)
