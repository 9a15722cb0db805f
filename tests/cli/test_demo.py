import re

import numpy as np

import facestats
from facestats.core.published import SIGMA_TR_AVG
from tests.helpers import run_cli


def test_version_and_help():
    r = run_cli("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"facestats {facestats.__version__}"
    r = run_cli("--help")
    assert r.returncode == 0 and "demo" in r.stdout


def _row(text, name):
    line = next(l for l in text.splitlines() if l.startswith(name))
    return np.array([float(x) for x in re.findall(r"-?\d+\.\d+", line[len(name) :])][:3])


def test_demo_prints_consistent_parameters_and_writes_plot(tmp_path):
    out = tmp_path / "profiles.png"
    r = run_cli("demo", "--albedo", "0.5", "0.3", "0.2", "--plot", out)
    assert r.returncode == 0, r.stderr
    np.testing.assert_allclose(_row(r.stdout, "σtr"), SIGMA_TR_AVG, atol=1e-5)
    np.testing.assert_allclose(_row(r.stdout, "total diffuse reflectance"), [0.5, 0.3, 0.2], atol=1e-5)
    s, a = _row(r.stdout, "σ's"), _row(r.stdout, "σa")
    np.testing.assert_allclose(np.sqrt(3 * a * (a + s)), SIGMA_TR_AVG, rtol=2e-4)
    assert out.exists() and out.stat().st_size > 10_000


def test_demo_rejects_bad_albedo():
    r = run_cli("demo", "--albedo", "1.5", "0.3", "0.2", "--plot", "")
    assert r.returncode == 2
    assert "albedo must lie in (0, 1), got 1.5" in r.stderr  # named as the argument it came from
