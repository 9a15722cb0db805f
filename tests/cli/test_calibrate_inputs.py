"""``facestats calibrate``: outputs never replace the inputs; options are range-checked before any work.

Found by a red-team review: ``--output`` or ``--plot`` naming one of the bracket's photographs replaced it with JSON
or a plot (exit 0), and ``calibrate leds --output TARGET/manifest.json`` replaced the target's manifest.

Refusals and repeated runs call :func:`facestats.cli.main` in the test's process (:func:`tests.helpers.run_main`, or
``main`` itself), which the console script runs; the tests that ran the console script still run it.
"""

import hashlib
import json
import pathlib
import re
import shutil
from dataclasses import replace

import numpy as np
import pytest

from tests.helpers import TEST_DATA, run_cli, run_main

UNIS = sorted((TEST_DATA / "unis-bracket").glob("*.jpg"))


def _digests(paths):
    return {str(p): hashlib.sha256(pathlib.Path(p).read_bytes()).hexdigest() for p in paths}


@pytest.fixture
def bracket(tmp_path):
    """The three UNIS JPEGs (EXIF times), copied: outputs may be pointed at them."""
    out = []
    for f in UNIS:
        shutil.copy(f, tmp_path / f.name)
        out.append(tmp_path / f.name)
    return out


def _bracket_12_bit(folder, black=0, white=4095):
    """Four 16-bit PNGs holding 12-bit codes of a linear sensor on a pedestal of ``black`` DN that clips at ``white``
    DN (EXIF times)."""
    from facestats.acquire.synthetic.photographs import encode_frame

    rng = np.random.default_rng(3)
    rate = np.exp(rng.uniform(np.log(10), np.log(1e5), (96, 128, 3)))  # electrons/s
    paths = []
    for k, t in enumerate([1 / 60, 1 / 10, 1 / 4, 1.0]):
        e = rate * t
        e = e + rng.standard_normal(e.shape) * np.sqrt(e + 25.0)
        z = np.clip(np.rint(e / 20000 * (4095 - black) + black), 0, white).astype(np.uint16)
        paths.append(folder / f"h{k}.png")
        paths[-1].write_bytes(encode_frame(z, t, ".png"))
    return paths


@pytest.fixture(scope="module")
def target(tmp_path_factory):
    """A small target folder (2 cameras, 3 LEDs, one pose, 96² 12-bit frames) with its dome.json."""
    from facestats.acquire.dome import default_dome
    from facestats.acquire.response import ResponseCurve
    from facestats.acquire.synthetic.photographs import TargetPose, write_target_photographs

    camera = ResponseCurve(12)
    dome = default_dome().select(leds=[0, 41, 101]).resized(96, 96)
    dome = replace(dome, camera_log_response=np.repeat(camera.log_exposure()[:, None], 3, axis=1))
    root = tmp_path_factory.mktemp("target")
    poses = [TargetPose((0.0, 0.0, 40.0), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0))]
    write_target_photographs(root / "target", dome, poses, cameras=[4, 11], camera=camera)
    dome.save(root / "target" / "dome.json")
    return root / "target"


def test_response_outputs_that_are_inputs_are_refused_before_the_fit(tmp_path):
    from facestats.acquire.dome import default_dome

    bracket = _bracket_12_bit(tmp_path)
    dome = tmp_path / "dome.json"
    default_dome().save(dome)
    before = _digests(bracket + [dome])
    link = tmp_path / "link"
    link.symlink_to(tmp_path, target_is_directory=True)
    cases = [
        (("--output", bracket[0]), f"--output must not be one of the inputs, got '{bracket[0]}', which is IMAGE"),
        (("--plot", bracket[2]), f"--plot must not be one of the inputs, got '{bracket[2]}', which is IMAGE"),
        (("--output", link / bracket[1].name), "--output must not be one of the inputs"),  # another spelling
        (("--output", f"{tmp_path}/./{bracket[1].name}"), "--output must not be one of the inputs"),
        (("--calibration", dome, "--write-calibration", dome),
         f"--write-calibration must not be one of the inputs, got '{dome}', which is --calibration '{dome}'"),
        (("--calibration", dome, "--write-calibration", bracket[1]), "--write-calibration must not be one of the"),
    ]  # fmt: skip
    for extra, message in cases:
        r = run_main("calibrate", "response", *bracket, "--bits", "12", *extra)
        assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, (extra, r.stderr)
        assert "exposure agreement" not in r.stdout  # refused before the fit
    assert _digests(bracket + [dome]) == before
    ok = run_cli("calibrate", "response", *bracket, "--bits", "12", "--output", tmp_path / "g.json")
    assert ok.returncode == 0, ok.stderr


def test_led_outputs_that_are_inputs_are_refused_before_the_fit(target, tmp_path):
    work = tmp_path / "target"
    shutil.copytree(target, work)
    frame = work / json.loads((work / "manifest.json").read_text())["frames"][3]["file"]
    inputs = [work / "manifest.json", work / "dome.json", frame]
    before = _digests(inputs)
    cases = [
        (("--output", work / "manifest.json"), "--output must not be one of the inputs, got '"),
        (("--output", work / "manifest.json"), "which is the target folder's manifest"),
        (("--write-calibration", frame), f"which is the target photograph '{frame}'"),
        (("--write-calibration", work / "dome.json"), f"which is --calibration '{work / 'dome.json'}'"),
        (("--calibration", work / "dome.json", "--output", work / "dome.json"), "--output must not be one of"),
    ]
    for extra, message in cases:
        r = run_main("calibrate", "leds", work, *extra)
        assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, (extra, r.stderr)
        assert "camera gains" not in r.stdout
    assert _digests(inputs) == before
    r = run_cli("calibrate", "leds", work, "--output", work / "leds.json")  # beside the inputs is fine
    assert r.returncode == 0 and (work / "leds.json").is_file(), r.stderr


def test_out_of_range_options_are_refused_before_any_work(bracket, tmp_path):
    """--smoothness 1e300 ended in "response must be finite"; --grid 100000 in "out of memory (74.5 GiB)"."""
    r = run_cli("calibrate", "response", *bracket, "--smoothness", "1e300")
    assert r.returncode == 2 and "--smoothness must lie in [0, 1e+06], got 1e+300" in r.stderr, r.stderr
    r = run_main("calibrate", "leds", tmp_path / "absent", "--grid", "100000")  # checked before the folder is read
    assert r.returncode == 2 and "--grid must be an integer in [2, 100], got 100000" in r.stderr, r.stderr
    r = run_main("calibrate", "response", *bracket, "--black-level", "-3")
    assert r.returncode == 2 and "--black-level must be an integer in [0, inf], got -3" in r.stderr, r.stderr
    r = run_main("calibrate", "response", *bracket, "--samples", "foo")  # the message names every accepted form
    assert r.returncode == 2 and "--samples: must be histogram, stratified or a number of samples" in r.stderr
    # checks the API makes are named by the options too (they named exposure_times, bits, samples: a red team)
    for argv, said in ((["--times", "1", "2"], "--times must hold one time per photograph (3), got 2"),
                       (["--bits", "12"], "--bits must be at most 8 for these 8-bit files, got 12"),
                       (["--samples", "1"], "--samples must be an integer in [2, "),
                       (["--times", "1e-320", "2e-320", "4e-320"], "--times must lie in [1e-12, inf] s")):  # fmt: skip
        r = run_main("calibrate", "response", *bracket, *argv)
        assert r.returncode == 2 and said in r.stderr, (argv, r.stderr)


def test_12_bit_codes_in_16_bit_files_need_bits_and_a_black_level_is_recorded(tmp_path):
    frames = _bracket_12_bit(tmp_path, black=128)
    r = run_cli("calibrate", "response", *frames, "--output", tmp_path / "g.json")
    assert r.returncode == 2 and not (tmp_path / "g.json").exists()
    assert "highest code is 4095, below a quarter of the full scale 65535" in r.stderr and "--bits 12" in r.stderr
    g_json = tmp_path / "g.json"
    r = run_main("calibrate", "response", *frames, "--bits", "12", "--black-level", "128", "--output", g_json)
    assert r.returncode == 0, r.stderr
    assert "4 photographs, 12-bit codes, black level 128:" in r.stdout
    doc = json.loads((tmp_path / "g.json").read_text())
    assert doc["black_level"] == 128 and len(doc["log_response"][0]) == 4096
    g = np.array(doc["log_response"][1][208:4000], float)
    d = g - np.log(np.arange(208, 4000) - 128.0)
    assert np.abs(d - np.median(d)).max() < 0.02  # ln(z − 128) from 2 % of the range above the pedestal
    from facestats.acquire.dome import default_dome

    default_dome().save(tmp_path / "dome.json")
    r = run_main("calibrate", "response", *frames, "--bits", "12", "--black-level", "128",
                 "--calibration", tmp_path / "dome.json", "--write-calibration", tmp_path / "new.json")  # fmt: skip
    assert r.returncode == 0, r.stderr  # the calibration records the pedestal the ingest then merges with
    assert json.loads((tmp_path / "new.json").read_text())["camera_black_level"] == 128


def test_response_options_for_the_calibration_are_checked_before_the_fit(target, tmp_path):
    """--cameras without --write-calibration was ignored (exit 0), and --cameras 9 of a calibration without camera 9
    was refused only after the fit had run and printed; so were a subset of a calibration without responses, another
    black level for some cameras and a --bits whose levels differ from the calibration's responses."""
    frames = _bracket_12_bit(tmp_path)
    plain = tmp_path / "plain.json"  # 16 cameras, no responses yet
    from facestats.acquire.dome import default_dome

    default_dome().save(plain)
    with_g = target / "dome.json"  # 16 cameras with 12-bit responses, black level 0
    new = ("--write-calibration", tmp_path / "new.json")
    cases = [
        (("--cameras", "0"), "--cameras needs --write-calibration (--cameras names the cameras that get this "
         "response in the written calibration)"),
        (("--calibration", plain), "--calibration needs --write-calibration (--calibration names the calibration "
         "the response is put into)"),
        (("--calibration", plain, "--cameras", "9", "16", *new),
         "--cameras must be in [0, 16), got [16]: --calibration has 16 cameras"),
        (("--calibration", plain, "--cameras", "2", *new),
         "--cameras must be every camera (0-15): --calibration has no camera responses yet, got [2]"),
        (("--calibration", with_g, "--cameras", "2", "--black-level", "5", *new),
         "--black-level must be the calibration's camera_black_level (0) when only --cameras 2 take this response "
         "(the cameras share one), got 5"),
        (("--calibration", with_g, "--bits", "10", *new),
         "--bits must be 12 to match the calibration's responses (4096 levels), got 10"),
    ]  # fmt: skip
    for extra, message in cases:
        bits = () if "--bits" in extra else ("--bits", "12")  # an option given twice is refused (cli.options.Parser)
        r = run_main("calibrate", "response", *frames, *bits, *extra)
        assert r.returncode == 2 and r.stderr == f"facestats: error: {message}\n", (extra, r.stderr)
        assert r.stdout == "" and not (tmp_path / "new.json").exists()  # before the fit
    r = run_cli("calibrate", "response", *frames, "--bits", "12", "--calibration", with_g, "--cameras", "2", *new)
    assert r.returncode == 0 and "calibration with this response for camera(s) 2 written to" in r.stdout, r.stderr


@pytest.fixture(scope="module")
def sparse_target(tmp_path_factory):
    """Two poses that leave LED 1 unlit from the front and light LEDs 2 and 3 only over a strip (3 cameras, 96²)."""
    from facestats.acquire.dome import default_dome
    from facestats.acquire.response import ResponseCurve
    from facestats.acquire.synthetic.photographs import TargetPose, write_target_photographs

    camera = ResponseCurve(12, 20000.0, 5.0)
    dome = default_dome().select(leds=[0, 3, 33, 81]).resized(96, 96)
    dome = replace(dome, camera_log_response=np.repeat(camera.log_exposure()[:, None], 3, axis=1))
    poses = []
    for normal in ((0.0, 0.0, 1.0), (3.7, 0.0, 1.0)):
        n = np.asarray(normal) / np.linalg.norm(normal)
        u = np.cross([0.0, 1.0, 0.0], n)
        poses.append(TargetPose((0.0, 0.0, 40.0), tuple(n), tuple(u / np.linalg.norm(u)), (300.0, 300.0)))
    root = tmp_path_factory.mktemp("sparse") / "target"
    write_target_photographs(root, dome, poses, cameras=[3, 4, 11], camera=camera)
    dome.save(root / "dome.json")
    return root


def test_leds_left_uncalibrated_or_poorly_determined_are_named(sparse_target, tmp_path):
    """Found by a red team: `calibrate leds --grid 8 --write-calibration` listed 9 of 40 LEDs as `nan … 0`, kept their
    old photometry in the calibration and wrote null for them with --output, exit 0 and no word; it also accepted
    beams such as c3 = 12.772 (truth about -0.3) without comment."""
    from facestats.acquire.dome import Dome

    old = Dome.load(sparse_target / "dome.json")
    r = run_cli("calibrate", "leds", sparse_target, "--grid", "8",
                "--write-calibration", tmp_path / "d.json", "--output", tmp_path / "o.json")  # fmt: skip
    assert r.returncode == 1, r.stderr  # a calibration was written with an LED left at its previous photometry
    assert "   1   not calibrated: 0 usable observations, 12 needed\n" in r.stdout and "nan" not in r.stdout
    lines = r.stderr.splitlines()
    assert lines[0] == (
        "facestats: warning: 1 of 4 LEDs not calibrated (fewer than 12 usable observations of the target, lit from "
        "the front and seen unsaturated): LED 1; --write-calibration keeps their previous intensity and beam, "
        "--output records null for them"
    )
    poor = re.compile(
        r"facestats: warning: LED (\d): beam poorly determined, extrapolated beyond its \d+ observations: its "
        r"standard error on the target reaches (\d+\.\d)%, above the (\d\.\d\d)% RMS residual of one observation "
        r"\(c3 -?\d+\.\d{3} ± \d+\.\d{3}, c5 -?\d+\.\d{3} ± \d+\.\d{3}\)"
    )
    matches = [poor.fullmatch(line) for line in lines[1:]]
    assert len(lines) == 3 and all(matches), r.stderr
    assert [m.group(1) for m in matches] == ["2", "3"]
    assert all(float(m.group(2)) > 5 * float(m.group(3)) for m in matches)  # measured 8.8x and 32x
    written = Dome.load(tmp_path / "d.json")
    np.testing.assert_array_equal(written.led_intensity[1], old.led_intensity[1])
    np.testing.assert_array_equal(written.led_beam[1], old.led_beam[1])
    led1 = json.loads((tmp_path / "o.json").read_text())["leds"][1]
    assert led1["intensity"] == [None] * 3 and led1["n_observations"] == 0 and led1["beam_error"] is None
    r = run_main("calibrate", "leds", sparse_target, "--grid", "8", "--output", tmp_path / "o2.json")
    assert r.returncode == 0, r.stderr  # nothing kept from before: the LED file says null
    assert r.stderr.splitlines()[0].endswith("LED 1; --output records null for them")


def test_white_level_is_range_checked_before_the_fit_naming_the_option(target, tmp_path, capsys):
    """--white-level DN (Debevec & Malik 1997 eq. 4's Z_max): above mid-range and at most the top code, refused
    naming the option once the bits are known (--bits, the calibration's responses, the target folder's manifest),
    and the same for every camera when only some take the response."""
    from facestats.cli import main

    frames = _bracket_12_bit(tmp_path)
    new = ("--write-calibration", tmp_path / "new.json")
    cases = [
        (("response", *frames, "--bits", "12", "--white-level", "2048"),
         "--white-level must be an integer in [2049, 4095], got 2048"),
        (("response", *frames, "--bits", "12", "--white-level", "4096"),
         "--white-level must be an integer in [2049, 4095], got 4096"),
        (("response", *frames, "--white-level", "70000"), "--white-level must be an integer in [2, 65535], got 70000"),
        (("response", *frames, "--calibration", target / "dome.json", "--white-level", "1000", *new),
         "--white-level must be an integer in [2049, 4095], got 1000"),  # the calibration's 12-bit responses
        (("response", *frames, "--bits", "12", "--calibration", target / "dome.json", "--cameras", "2",
          "--white-level", "3000", *new),
         "--white-level must be the calibration's camera_white_level (4095) when only --cameras 2 take this response "
         "(the cameras share one), got 3000"),
        (("leds", target, "--white-level", "100000"), "--white-level must be an integer in [2, 65535], got 100000"),
        (("leds", target, "--white-level", "2048"), "--white-level must be an integer in [2049, 4095], got 2048"),
    ]  # fmt: skip
    for args, message in cases:
        assert main(["calibrate", *map(str, args)]) == 2, args
        out, err = capsys.readouterr()
        assert err == f"facestats: error: {message}\n" and out == "", (args, err)
    assert not (tmp_path / "new.json").exists()
    with pytest.raises(SystemExit):
        main(["calibrate", "response", *map(str, frames), "--white-level", "4000.5"])
    assert "argument --white-level: must be an integer (ASCII digits 0-9), got '4000.5'" in capsys.readouterr().err


def test_a_white_level_is_recovered_below_and_recorded(tmp_path):
    """A 12-bit linear bracket clipping at 3,800 DN: `calibrate response --white-level 3800` recovers g = ln z below
    it, writes it into the response file and the dome calibration (camera_white_level), which the ingest merges with."""
    from facestats.acquire.dome import default_dome

    frames = _bracket_12_bit(tmp_path, white=3800)
    default_dome().save(tmp_path / "dome.json")
    r = run_cli("calibrate", "response", *frames, "--bits", "12", "--white-level", "3800", "--output",
                tmp_path / "g.json", "--calibration", tmp_path / "dome.json", "--write-calibration",
                tmp_path / "new.json")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "4 photographs, 12-bit codes, white level 3800:" in r.stdout
    doc = json.loads((tmp_path / "g.json").read_text())
    assert doc["white_level"] == 3800 and doc["black_level"] == 0
    g = np.array(doc["log_response"], float)
    d = g[:, 80:3801] - np.log(np.arange(80, 3801.0))
    assert np.abs(d - np.median(d, axis=1, keepdims=True)).max() < 0.03  # ln z up to it: measured 0.008 (0.79 without)
    assert np.all(g[:, 3800:] == g[:, 3800:3801])  # above it: g(3800)
    assert json.loads((tmp_path / "new.json").read_text())["camera_white_level"] == 3800
    # Without --bits the 16-bit files set the levels: the refusal names the option and the way out (it named the
    # API's white_level, and said nothing of --bits; a red team).
    r = run_main("calibrate", "response", *frames, "--white-level", "3800")
    assert r.returncode == 2 and "--white-level must be an integer in [32769, 65535], got 3800" in r.stderr
    assert "pass --bits N for N-bit codes" in r.stderr


def test_calibrate_leds_merges_with_the_white_level(target, tmp_path, capsys):
    """The LED calibration's merge takes --white-level, default the calibration's camera_white_level."""
    from facestats.acquire.calibration import target_observations
    from facestats.acquire.dome import Dome
    from facestats.cli import main

    dome = Dome.load(target / "dome.json")
    plain = target_observations(target, dome, grid=6)["value"]
    given = target_observations(target, dome, grid=6, white_level=3000)["value"]
    recorded = target_observations(target, replace(dome, camera_white_level=3000), grid=6)["value"]
    np.testing.assert_array_equal(given, recorded)
    assert given.shape == plain.shape and not np.array_equal(given, plain)  # the hat ends at 3000 (codes to 3706)
    assert main(["calibrate", "leds", str(target), "--grid", "6", "--white-level", "3000"]) == 0
    assert "camera gains" in capsys.readouterr().out


def test_an_empty_calibration_is_refused_by_name_not_taken_for_the_default(target, bracket, tmp_path):
    """``calibrate leds T --calibration ''`` read T/dome.json as if it were not given, and ``calibrate response ...
    --calibration ''`` was ignored (a red team): argparse refuses both, naming the option, before any work."""
    before = sorted(p.name for p in tmp_path.iterdir())
    for argv in (("leds", target), ("response", *bracket, "--write-calibration", tmp_path / "dome.json")):
        r = run_main("calibrate", *argv, "--calibration", "", cwd=tmp_path)
        assert r.returncode == 2 and "argument --calibration: must not be empty, got ''" in r.stderr, r.stderr
        assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written
