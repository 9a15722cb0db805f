import os

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


#: Folders whose tests are end-to-end by nature (a notebook run, a console script in a subprocess, the
#: hostile-input corpus against both, a headless browser): all ``slow``, so ``-m "not slow"`` keeps
#: the everyday loop to the library's own tests.  CI runs everything.
END_TO_END = ("tests/notebooks/", "tests/cli/", "tests/reliability/", "tests/web/test_browser.py")


#: Modules with one test of minutes: run first, so that under ``-n 2`` the other worker's queue fills
#: the time instead of the suite waiting for a long test that started last (order within a module kept).
LONG_FIRST = ("tests/pipeline/test_default_store.py", "tests/reliability/test_build_workers.py")


def pytest_collection_modifyitems(config, items):
    root = str(config.rootpath) + os.sep
    rank = {}
    for item in items:
        rel = str(item.path).removeprefix(root).replace(os.sep, "/")
        if rel.startswith(END_TO_END):
            item.add_marker(pytest.mark.slow)
        rank[item.nodeid] = 0 if rel in LONG_FIRST else 1
    items.sort(key=lambda item: rank[item.nodeid])  # stable: the order within each group is kept
