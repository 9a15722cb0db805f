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


def test_demo_keeps_an_existing_plot_file_unless_told_to_replace_it(tmp_path):
    """`demo --plot keep.png` replaced the user's file silently (a fresh-user red team), where relight, export and
    the other writers refuse without --overwrite."""
    keep = tmp_path / "keep.png"
    keep.write_bytes(b"mine")
    r = run_cli("demo", "--plot", keep)
    assert r.returncode == 2 and "keep.png' exists (pass --overwrite to replace it)" in r.stderr
    assert keep.read_bytes() == b"mine"
    r = run_cli("demo", "--plot", keep, "--overwrite")
    assert r.returncode == 0, r.stderr
    assert keep.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_demo_rejects_bad_albedo():
    r = run_cli("demo", "--albedo", "1.5", "0.3", "0.2")
    assert r.returncode == 2
    assert "--albedo must lie in [1e-10, 1), got 1.5" in r.stderr  # named as the argument it came from


def test_demo_messages_name_the_option_its_true_domain_and_the_value_given(tmp_path):
    """Found by a red team: --albedo 1e-300 (legal by the help) ended in "sigma_s_prime must lie in [0, inf] mm^-1,
    got -7.06e-17", --sigma-tr 1e-300 in "sigma_tr must lie in (0, inf] mm^-1, got 0.0", --eta -1 in "eta must lie
    in (0, inf]" (the range is [1, 3]) and --sigma-tr inf was refused by a message whose interval included inf."""
    cases = [
        (("--albedo", "1e-300", "0.3", "0.2"), "--albedo must lie in [1e-10, 1), got 1e-300"),
        (("--albedo", "0.5", "1", "0.2"), "--albedo must lie in [1e-10, 1), got 1.0"),
        (("--albedo", "0.5", "nan", "0.2"), "--albedo must be finite, got 1 non-finite value(s) (first: nan)"),
        (("--sigma-tr", "1e-300", "1", "1"), "--sigma-tr must lie in [1e-100, 1e+80] mm^-1, got 1e-300"),
        (("--sigma-tr", "inf", "1", "1"), "--sigma-tr must be finite, got 1 non-finite value(s) (first: inf)"),
        (("--sigma-tr", "1", "0", "1"), "--sigma-tr must lie in [1e-100, 1e+80] mm^-1, got 0.0"),
        (("--eta", "-1"), "--eta must lie in [1, 3], got -1.0"),
        (("--eta", "3.5"), "--eta must lie in [1, 3], got 3.5"),
    ]
    for extra, message in cases:
        r = run_cli("demo", *extra, "--plot", tmp_path / "p.png")
        assert r.returncode == 2 and f"facestats: error: {message}\n" == r.stderr, (extra, r.stderr)
        assert r.stdout == "" and not (tmp_path / "p.png").exists()  # refused before any work
    # the ends of the domains work, with the plot (the dipole profile stays in the float range)
    r = run_cli("demo", "--albedo", "1e-10", "0.5", "0.9999999999999999", "--sigma-tr", "1e-100", "1", "1e80",
                "--eta", "3", "--plot", tmp_path / "p.png")  # fmt: skip
    assert r.returncode == 0 and r.stderr == "", r.stderr
    np.testing.assert_allclose(_row(r.stdout, "total diffuse reflectance")[1], 0.5, atol=1e-5)
    assert (tmp_path / "p.png").stat().st_size > 10_000


def test_demo_plots_only_when_asked_and_checks_plot_as_the_other_commands(tmp_path):
    """demo wrote dipole_profiles.png into the current folder unless told not to (its help did not say so); its
    --plot was checked as "plot" with every suffix matplotlib writes (translucency and calibrate response: --plot,
    .png/.svg/.pdf, no plot unless given)."""
    r = run_cli("demo", cwd=tmp_path)
    assert r.returncode == 0 and "wrote" not in r.stdout and list(tmp_path.iterdir()) == [], r.stderr
    for plot, message in [
        ("x.xyz", "--plot must end in one of ['.pdf', '.png', '.svg'], got 'x.xyz'"),
        ("x.eps", "--plot must end in one of ['.pdf', '.png', '.svg'], got 'x.eps'"),
        ("/dev/null/x.png", "--plot must be a path that can be created, got '/dev/null/x.png' (/dev/null is not a"),
    ]:
        r = run_cli("demo", "--plot", plot, cwd=tmp_path)
        assert r.returncode == 2 and message in r.stderr and r.stdout == "", (plot, r.stderr)
    # as every output of the CLI (facestats.core.outputs.OutputSet), missing folders of --plot are created
    r = run_cli("demo", "--plot", tmp_path / "new" / "d.svg")
    assert r.returncode == 0 and f"wrote {tmp_path / 'new' / 'd.svg'}" in r.stdout, r.stderr
    assert (tmp_path / "new" / "d.svg").is_file()
    help_text = " ".join(run_cli("demo", "--help").stdout.split())  # as argparse wraps it
    assert "(.png, .svg or .pdf); default: no plot" in help_text and "in [1e-10, 1)" in help_text
    assert "in [1e-100, 1e80]" in help_text and "in [1, 3]" in help_text


def test_an_empty_plot_is_refused_by_name_not_taken_for_no_plot(tmp_path):
    """``--plot ''`` printed the demo and exited 0 without a plot (a red team): argparse refuses it, naming it."""
    from tests.helpers import run_main

    r = run_main("demo", "--plot", "", cwd=tmp_path)
    assert r.returncode == 2 and "argument --plot: must not be empty, got ''" in r.stderr, r.stderr
    assert r.stdout == "" and list(tmp_path.iterdir()) == []  # no report, nothing written
