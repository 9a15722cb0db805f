"""``facestats ingest`` and ``facestats calibrate leds`` end to end through the console script."""

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest

from tests.cli_helpers import run_cli


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """A 16-grid subject photographed by 16 cameras under 15 LEDs at 80² pixels."""
    from facestats.acquire.dome import default_dome
    from facestats.acquire.synthetic.face import procedural_face
    from facestats.acquire.synthetic.photographs import write_capture_photographs
    from facestats.acquire.synthetic.population import synthesize_population

    truth = synthesize_population(map_size=16, subjects=["S001"])["S001"]
    dome = default_dome().select(leds=np.arange(0, 150, 10)).resized(80, 80)
    root = tmp_path_factory.mktemp("cli")
    write_capture_photographs(truth, root / "photos", geometry=procedural_face(16), dome=dome, seed=3)
    return root / "photos"


@pytest.mark.slow
def test_ingest_command_writes_the_subject_and_rerunning_does_nothing(capture, tmp_path):
    store = tmp_path / "s.zarr"
    args = ["ingest", capture, "--mesh", capture / "face.obj", "--calibration", capture / "dome.json"]
    args += ["--store", store, "--subject", "PH002", "--min-footprint", "1"]
    r = run_cli(*args)
    assert r.returncode == 0, r.stderr
    assert "ingested PH002 into" in r.stdout and "frames flagged for head motion: 0" in r.stdout
    assert "ingest photos" in r.stderr  # the progress bar
    from facestats.io import open_store

    with open_store(store) as st:
        assert st.ids() == ["PH002"]
        assert json.loads(st.subject("PH002").attrs["provenance"])["capture_provenance"]["source"] == "photographs"
    again = run_cli(*args)
    assert again.returncode == 0 and "already in" in again.stdout


def test_ingest_command_reports_bad_input_without_a_traceback(capture, tmp_path):
    bad = tmp_path / "photos"
    shutil.copytree(capture, bad)
    (bad / "cam05" / "led003_e1.png").unlink()
    r = run_cli(
        "ingest",
        bad,
        "--mesh",
        bad / "face.obj",
        "--calibration",
        bad / "dome.json",
        "--store",
        tmp_path / "s.zarr",
        "--subject",
        "PH003",
        "--quiet",
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "frame cam05/led003_e1.png listed in manifest.json is missing" in r.stderr
    assert not (tmp_path / "s.zarr.ingest").exists() or not any((tmp_path / "s.zarr.ingest").rglob("zarr.json"))


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
