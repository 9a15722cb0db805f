"""``facestats calibrate leds`` and ``calibrate response`` through the console script.

``facestats ingest`` end to end: tests/pipeline/test_photographs.py; its --regions help here.
"""

import json
import os
import pathlib
from dataclasses import replace

import numpy as np
import pytest

from tests.helpers import run_cli


@pytest.mark.slow
def test_calibrate_leds_prints_the_fitted_leds(tmp_path):
    from facestats.acquire.dome import default_dome
    from facestats.acquire.response import ResponseCurve
    from facestats.acquire.synthetic.photographs import TargetPose, write_target_photographs

    camera = ResponseCurve(12)
    dome = default_dome().select(leds=[0, 41, 101]).resized(96, 96)
    dome = replace(dome, camera_log_response=np.repeat(camera.log_exposure()[:, None], 3, axis=1))
    poses = [
        TargetPose((0.0, 0.0, 40.0), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)),
        TargetPose((0.0, 0.0, 40.0), (0.6, 0.0, 0.8), (0.8, 0.0, -0.6)),
    ]
    write_target_photographs(tmp_path / "target", dome, poses, cameras=[4, 11], camera=camera)
    dome.save(tmp_path / "target" / "dome.json")
    r = run_cli("calibrate", "leds", tmp_path / "target", "--output", tmp_path / "leds.json")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].split() == ["LED", "I0", "R", "I0", "G", "I0", "B", "c3", "c5", "rms", "res", "n"]
    rows = [line.split() for line in lines[1:4]]
    np.testing.assert_allclose([float(x[1]) for x in rows], dome.led_intensity[:, 0], rtol=0.01)
    assert all(x[6].endswith("%") for x in rows)
    assert json.loads((tmp_path / "leds.json").read_text())["format"] == "facestats.led-calibration/1"


def test_calibrate_response_from_the_real_bracket_into_a_dome(tmp_path):
    from facestats.acquire.bracket import read_response
    from facestats.acquire.dome import Dome, default_dome

    frames = sorted((pathlib.Path(__file__).resolve().parents[1] / "data" / "unis-bracket").glob("*.jpg"))
    default_dome().save(tmp_path / "dome.json")
    r = run_cli(
        "calibrate", "response", *frames, "--output", tmp_path / "g.json", "--plot", tmp_path / "g.png",
        "--calibration", tmp_path / "dome.json", "--write-calibration", tmp_path / "dome-g.json",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "1/1250 s -> 1/320 s: 3.3" in r.stdout and "written to" in r.stdout
    g = read_response(tmp_path / "g.json")
    np.testing.assert_array_equal(Dome.load(tmp_path / "dome-g.json").camera_log_response[7, 1:], g[1:])
    assert (tmp_path / "g.png").stat().st_size > 10_000
    before = sorted(p.name for p in tmp_path.iterdir())
    r = run_cli("calibrate", "response", *frames, "--write-calibration", tmp_path / "x.json")
    assert r.returncode == 2 and "--write-calibration needs --calibration" in r.stderr
    r = run_cli("calibrate", "response", *frames, "--plot", tmp_path / "g.gif")
    assert r.returncode == 2 and "--plot" in r.stderr
    r = run_cli("calibrate", "response", frames[0], frames[1], "--times", "0.1")
    assert r.returncode == 2 and "one time per photograph (2), got 1" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # failed commands write nothing
    (tmp_path / "g.json").write_text("OLD")  # a fit that cannot be applied replaces no output
    r = run_cli("calibrate", "response", *frames, "--output", tmp_path / "g.json")
    assert r.returncode == 2 and "g.json' exists (pass --overwrite to replace it)" in r.stderr
    r = run_cli("calibrate", "response", *frames, "--output", tmp_path / "g.json", "--plot", tmp_path / "new.png",
                "--calibration", tmp_path / "dome.json", "--write-calibration", tmp_path / "n.json",
                "--cameras", "99", "--overwrite")  # fmt: skip
    assert r.returncode == 2 and "cameras must be in [0, 16), got [99]" in r.stderr
    assert (tmp_path / "g.json").read_text() == "OLD" and not (tmp_path / "new.png").exists()
    r = run_cli("calibrate", "response", *frames, "--bits", "12")  # 8-bit JPEGs
    assert r.returncode == 2 and "bits must be at most 8 for these 8-bit files, got 12" in r.stderr
    r = run_cli("calibrate", "response", *frames, "--samples", "100000000")
    assert r.returncode == 2 and "samples must be" in r.stderr


def test_ingest_errors_name_the_options_not_the_api_parameters(tmp_path, capsys):
    from facestats.cli import main

    base = ["ingest", str(tmp_path), "--mesh", str(tmp_path / "m.obj"), "--calibration", str(tmp_path / "c.json")]
    base += ["--store", str(tmp_path / "s.zarr")]
    for extra, message in [
        (["--subject", ""], "--subject must be 1-64 characters of letters"),  # was subject_id
        (["--subject", "S1", "--workers", "0"], "--workers must be an integer in [1, inf], got 0"),
        (["--subject", "S1", "--motion-tolerance", "-1"], "--motion-tolerance must lie in (0, inf], got -1.0"),
        (["--subject", "S1", "--min-footprint", "-1"], "--min-footprint must lie in [0, inf], got -1.0"),
    ]:
        assert main(base + extra) == 2, extra
        assert f"facestats: error: {message}" in capsys.readouterr().err, extra
    assert os.listdir(tmp_path) == []


def test_ingest_regions_help_names_every_file_the_default_looks_for(tmp_path, capsys):
    """``--regions`` said ``.png|.npy`` while :func:`find_region_image` also takes ``<stem>.regions.tif``."""
    from facestats.cli import main
    from facestats.errors import FormatError
    from facestats.pipeline.photographs import find_region_image

    with pytest.raises(FormatError) as exc:
        find_region_image(tmp_path / "face.obj")
    looked_for = str(exc.value).split("looked for ")[1].split(")")[0].split(", ")  # face.regions.png, ...
    with pytest.raises(SystemExit):
        main(["ingest", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    default = help_text.split("default: <mesh stem>.regions")[1].split(" next to the mesh")[0]  # .png|.npy|...
    assert [f"face.regions{ext}" for ext in default.split("|")] == looked_for
