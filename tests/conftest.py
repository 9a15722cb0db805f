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


def pytest_collection_modifyitems(config, items):
    root = str(config.rootpath) + os.sep
    for item in items:
        rel = str(item.path).removeprefix(root).replace(os.sep, "/")
        if rel.startswith(END_TO_END):
            item.add_marker(pytest.mark.slow)
