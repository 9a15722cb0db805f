import os

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def random_hemisphere(rng, n, normal=(0.0, 0.0, 1.0), min_cos=0.05):
    """Uniform random unit vectors with N·ω ≥ min_cos around ``normal``."""
    normal = np.asarray(normal, float)
    normal = normal / np.linalg.norm(normal)
    out = np.empty((0, 3))
    while len(out) < n:
        v = rng.normal(size=(4 * n, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        out = np.concatenate([out, v[v @ normal >= min_cos]])
    return out[:n]
