"""``facestats emulate`` and ``facestats capture`` through the console script; SIGKILL of the capture and --resume."""

import json
import os
import pty
import signal
import subprocess
import time

import numpy as np
import pytest

from facestats.acquire.devices.lab import emulated_dome
from facestats.acquire.photographs import open_folder
from tests.acquire.devices.helpers import run_capture, tree
from tests.helpers import facestats_exe, run_cli, run_main


@pytest.fixture(scope="module")
def emulator(tmp_path_factory):
    """``facestats emulate dome`` in a subprocess (6 LEDs, 2 cameras, 24² frames); yields (port, root)."""
    root = tmp_path_factory.mktemp("cli")
    args = ["emulate", "dome", "--leds", "6", "--cameras", "2", "--resolution", "24", "--subject", "S003"]
    args += ["--hot-folder", root / "hot", "--lab", root / "lab", "--link", root / "dome.tty", "--quiet"]
    proc = subprocess.Popen(
        facestats_exe() + [str(a) for a in args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONWARNINGS="ignore"),
    )
    lines = []
    while not lines or lines[-1] != "ready (Ctrl-C to stop)":
        line = proc.stdout.readline()
        assert line, proc.stderr.read()
        lines.append(line.rstrip("\n"))
    yield root, lines
    proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0 and "stopped after" in out


def _capture(root, *extra, out="cap", subject="S003"):
    return run_cli(
        "capture",
        "dome",
        "--port",
        root / "dome.tty",
        "--subject",
        subject,
        "--out",
        root / out,
        "--calibration",
        root / "lab" / "dome.json",
        "--hot-folder",
        root / "hot",
        "--metadata",
        root / "lab" / "subject.json",
        "--timeout",
        "0.3",
        *extra,
    )


def test_emulate_prints_its_port_and_capture_runs_the_plan(emulator):
    root, lines = emulator
    assert lines[0] == "dome emulator for S003: 6 LEDs, 2 cameras, 24×24 px frames"
    assert lines[1].startswith("port: /dev/pts/") and os.path.realpath(root / "dome.tty") == lines[1][6:]
    dry = _capture(root, "--dry-run")
    assert dry.returncode == 0 and "12 triggers × 2 cameras = 24 frames" in dry.stdout
    assert "estimated duration on the hardware: 1.2 s" in dry.stdout and not (root / "cap").exists()
    r = _capture(root)
    assert r.returncode == 0, r.stderr
    assert "dome session of S003 in" in r.stdout and "complete: 12/12 steps" in r.stdout
    assert "capture dome S003" in r.stderr and "step/s]" in r.stderr  # the progress bar, with its ETA
    assert open_folder(root / "cap").subject()["subject_id"] == "S003"
    again = _capture(root, "--resume")
    assert again.returncode == 0 and "nothing to do" in again.stdout


def test_bad_input_gets_a_message_and_no_traceback(emulator, tmp_path):
    root, _ = emulator
    if not (root / "cap" / "manifest.json").exists():  # the session refused below, made by the test above when it
        assert _capture(root).returncode == 0  # ran first on this pytest-xdist worker
    master, slave = pty.openpty()  # a device that never answers
    try:
        silent = run_cli("capture", "dome", "--port", os.ttyname(slave), "--subject", "S003", "--out", tmp_path / "a",
                         "--calibration", root / "lab" / "dome.json", "--hot-folder", root / "hot", "--metadata",
                         root / "lab" / "subject.json", "--timeout", "0.1", "--retries", "1")  # fmt: skip
    finally:
        os.close(master)
        os.close(slave)
    cases = [
        (silent, "did not answer 'ver' after 2 attempt(s)"),
        (_capture_port(root, "/dev/ttyNOPE"), "no such device"),
        (_capture_port(root, "loop://"), "it speaks another protocol"),
        (_capture(root, out="cap", subject="S004"), "belongs to subject S003"),
        (_capture(root, "--brightness", "200", "--resume"), "different dome plan (differs in: brightness)"),
    ]
    for r, message in cases:
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert message in r.stderr, r.stderr
    assert not (tmp_path / "a").exists() and not (root / "b").exists()
    # Bad values are refused before the port is opened and before anything is written (a port that does not
    # exist would otherwise be the first error).
    for extra, message in [
        (("--brightness", "300"), "--brightness must be an integer in [0, 255], got 300"),  # the options' names
        (("--brightness", "300", "--dry-run"), "--brightness must be an integer in [0, 255]"),
        (("--colour", "1,2"), "--colour must be three LED drive values"),
        (("--colour", "1,2,999"), "--colour must be an integer in [0, 255], got 999"),
        (("--frame-interval", "nan"), "--frame-interval must be finite"),  # was frame_interval_s
        (("--frame-interval", "-1"), "--frame-interval must lie in"),
        (("--frame-timeout", "nan"), "--frame-timeout must be finite"),
        (("--frame-timeout", "-1"), "--frame-timeout must lie in (0, inf], got -1.0"),
        (("--timeout", "0"), "--timeout must lie in (0, inf] s, got 0.0"),
        (("--baudrate", "0"), "--baudrate must be an integer in [50, 4000000], got 0"),
        (("--retries", "-1"), "--retries must be an integer in [0, 100], got -1"),
        (("--pattern", "foo"), "must name each frame's file apart: it lacks {frame}"),
        (("--pattern", "{frame}{ext}"), "it lacks {camera}"),
        (("--pattern", "../x{camera}{frame}.png"), "must name a file inside the hot folder"),
    ]:
        r = run_main("capture", "dome", "--port", "/dev/ttyNOPE", "--subject", "S003", "--out", tmp_path / "d",
                     "--calibration", root / "lab" / "dome.json", "--hot-folder", root / "hot", "--metadata",
                     root / "lab" / "subject.json", *extra)  # fmt: skip
        assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, (extra, r.stderr)
        assert not (tmp_path / "d").exists(), extra
    for extra, message in [  # the subject record from options, named by them (from --metadata: by its JSON keys)
        (("--subject", ""), "--subject must be 1-64 characters of letters"),
        (("--age", "-1"), "--age must be an integer in [0, 150], got -1"),
        (("--skin-type", "9"), "--skin-type must be an integer in [1, 6], got 9"),
        (("--condition", "wet"), "--condition must be one of ['cold', 'hot', "),
    ]:
        subject = () if "--subject" in extra else ("--subject", "S003")
        record = dict(zip(("--age", "--gender", "--skin-type"), ("30", "M", "3")), **dict(zip(extra[::2], extra[1::2])))
        r = run_main("capture", "dome", "--port", "/dev/ttyNOPE", *subject, "--out", tmp_path / "d", "--calibration",
                     root / "lab" / "dome.json", "--hot-folder", root / "hot", *sum(record.items(), ()))  # fmt: skip
        assert r.returncode == 2 and f"facestats: error: {message}" in r.stderr, (extra, r.stderr)
        assert not (tmp_path / "d").exists(), extra
    (tmp_path / "record.json").write_text(json.dumps({"age": 30, "gender": "M", "skin_type": 9}))
    r = run_main("capture", "dome", "--port", "/dev/ttyNOPE", "--subject", "S003", "--out", tmp_path / "d",
                 "--calibration", root / "lab" / "dome.json", "--hot-folder", root / "hot",
                 "--metadata", tmp_path / "record.json")  # fmt: skip
    assert "facestats: error: skin_type must be an integer in [1, 6], got 9" in r.stderr  # the file's key, not typed
    missing = run_main("capture", "dome", "--port", "x", "--subject", "S9", "--out", tmp_path / "c", "--calibration",
                       root / "lab" / "dome.json", "--hot-folder", root / "hot", "--dry-run")  # fmt: skip
    assert missing.returncode == 2 and "needs the subject's age, gender, skin_type" in missing.stderr


def test_sensor_dry_run_prints_the_bracket_and_its_duration(tmp_path):
    from facestats.acquire.devices.sensor import FiberLayout, save_sensor_calibration
    from facestats.acquire.sensor import ContactSensor

    save_sensor_calibration(tmp_path / "sensor.json", ContactSensor(), FiberLayout())
    r = run_cli("capture", "sensor", "--port", "/dev/null", "--subject", "S001", "--out", tmp_path / "cap",
                "--calibration", tmp_path / "sensor.json", "--hot-folder", tmp_path, "--age", "31", "--gender", "F",
                "--skin-type", "3", "--dry-run")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "3 sites (cheek, forehead, neck) × 23 exposures = 69 frames" in r.stdout
    assert "89 s per site" in r.stdout and not (tmp_path / "cap").exists()
    for readout in ("nan", "-1"):
        bad = run_main("capture", "sensor", "--port", "/dev/null", "--subject", "S001", "--out", tmp_path / "cap",
                       "--calibration", tmp_path / "sensor.json", "--hot-folder", tmp_path, "--age", "31", "--gender",
                       "F", "--skin-type", "3", "--readout", readout, "--dry-run")  # fmt: skip
        assert bad.returncode == 2 and "facestats: error: --readout must" in bad.stderr, bad.stderr  # not readout_s


def test_capture_refuses_empty_values_and_a_file_for_the_hot_folder_by_name(tmp_path):
    """``--person ''`` and ``--metadata ''`` were "not given", ``--out ''`` the current folder (". is not empty"),
    ``--port ''`` a DeviceError naming the API's ``port``, and a file given as ``--hot-folder`` "does not exist"
    (a red team): each is refused naming the option and the value, before anything is written."""
    from facestats.acquire.devices.sensor import FiberLayout, save_sensor_calibration
    from facestats.acquire.sensor import ContactSensor

    save_sensor_calibration(tmp_path / "sensor.json", ContactSensor(), FiberLayout())
    (tmp_path / "hot").write_text("a file, not the camera software's folder")
    given = {"--port": "/dev/null", "--subject": "S001", "--out": tmp_path / "cap",
             "--calibration": tmp_path / "sensor.json", "--hot-folder": tmp_path, "--age": "31", "--gender": "F",
             "--skin-type": "3"}  # fmt: skip
    for option in ("--port", "--out", "--hot-folder", "--person", "--metadata"):
        argv = {**given, option: ""}
        r = run_main("capture", "sensor", *sum(argv.items(), ()), "--quiet", cwd=tmp_path)
        assert r.returncode == 2 and f"argument {option}: must not be empty, got ''" in r.stderr, (option, r.stderr)
    r = run_main("capture", "sensor", *sum({**given, "--hot-folder": tmp_path / "hot"}.items(), ()), "--quiet")
    assert r.returncode == 2, r.stderr
    assert f"facestats: error: hot folder {tmp_path / 'hot'} is not a folder: point --hot-folder at" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hot", "sensor.json"]  # no capture folder, no journal


def test_emulate_errors_name_the_options_not_the_api_parameters(tmp_path):
    for sub, extra, message in [
        ("dome", ("--map-size", "0"), "--map-size must be an integer in [8, inf], got 0"),  # was map_size
        ("sensor", ("--map-size", "4"), "--map-size must be an integer in [8, inf], got 4"),
        ("dome", ("--seed", "-1"), "--seed must be an integer in [0, inf], got -1"),
        ("dome", ("--resolution", "0"), "--resolution must be an integer in [8, 8192], got 0"),
        ("dome", ("--leds", "0"), "--leds must be an integer in [1, 150], got 0"),
        ("dome", ("--cameras", "99"), "--cameras must be an integer in [1, 16], got 99"),
        ("dome", ("--wired-leds", "-1"), "--wired-leds must be an integer in [1, inf], got -1"),
        ("dome", ("--workers", "0"), "--workers must be an integer in [1, inf], got 0"),
        # one id, named in the singular with its value (was "must be ids ..., got unknown ['S999']")
        (
            "dome",
            ("--subject", "S999"),
            "--subject must be an id of the population (S001-S149, S008-<condition>), got 'S999'",
        ),
        (
            "sensor",
            ("--subject", ""),
            "--subject must be an id of the population (S001-S149, S008-<condition>), got ''",
        ),
        ("dome", ("--cache", tmp_path / "afile"), f"--cache must be a directory, got '{tmp_path / 'afile'}'"),
    ]:
        (tmp_path / "afile").write_text("x")
        r = run_main("emulate", sub, *extra, "--hot-folder", tmp_path / "hot", "--lab", tmp_path / "lab", "--quiet")
        assert r.returncode == 2 and f"facestats: error: {message}" in r.stderr, (extra, r.stderr)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"], extra  # no folder left behind


def test_emulate_fault_percentages_that_exceed_the_replies_name_the_options(tmp_path):
    """--drop 60 --garble 60 said "must not exceed 1 (fractions of the replies)": neither the options nor per cent."""
    for sub in ("dome", "sensor"):
        r = run_cli("emulate", sub, "--drop", "60", "--garble", "60", "--hot-folder", tmp_path / "hot",
                    "--lab", tmp_path / "lab", "--quiet")  # fmt: skip
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert (
            "--drop + --garble + --truncate + --duplicate must not exceed 100 % (per cent of the replies), "
            "got 60 + 60 + 0 + 0 = 120 %" in r.stderr
        ), r.stderr
        assert not (tmp_path / "hot").exists() and not (tmp_path / "lab").exists()


def _capture_port(root, port):
    lab = root / "lab"
    return run_cli("capture", "dome", "--port", port, "--subject", "S003", "--out", root / "b", "--calibration",
                   lab / "dome.json", "--hot-folder", root / "hot", "--metadata", lab / "subject.json",
                   "--timeout", "0.1", "--retries", "1")  # fmt: skip


@pytest.mark.slow
def test_sigkill_at_ten_random_points_then_resume_loses_and_duplicates_nothing(tmp_path):
    """The capture process is killed ten times (at random committed-step counts plus a random delay)."""
    server = emulated_dome("S005", tmp_path / "hot", tmp_path / "lab", resolution=24, leds=12, cameras=3)
    try:
        run_capture(server, tmp_path / "lab", tmp_path / "hot", tmp_path / "clean")
        rng = np.random.default_rng(2006)
        targets = np.sort(rng.choice(np.arange(1, 20), 10, replace=False))  # at least 4 steps left after a kill
        journal = tmp_path / "out" / "session" / "dome.journal"
        args = ["capture", "dome", "--port", server.port, "--subject", "S005", "--out", tmp_path / "out",
                "--calibration", tmp_path / "lab" / "dome.json", "--hot-folder", tmp_path / "hot", "--metadata",
                tmp_path / "lab" / "subject.json", "--timeout", "0.3", "--quiet"]  # fmt: skip
        killed_at = []
        for k, target in enumerate(targets):
            proc = subprocess.Popen(facestats_exe() + [str(a) for a in args + (["--resume"] if k else [])],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
            while proc.poll() is None and _lines(journal) < target:
                time.sleep(0.002)
            time.sleep(rng.uniform(0, 0.004))  # somewhere inside the next step (a step of this small dome takes ms)
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            assert proc.returncode == -signal.SIGKILL, proc.stderr.read()
            killed_at.append(_lines(journal))
            assert not (tmp_path / "out" / "manifest.json").exists(), (k, killed_at, proc.stderr.read()[-2000:])
        final = run_cli(*args, "--resume")
        assert final.returncode == 0 and "complete: 24/24 steps" in final.stdout, final.stderr
    finally:
        server.stop()
    assert len(set(killed_at)) >= 5  # the kills landed at different points of the sequence
    assert tree(tmp_path / "out") == tree(tmp_path / "clean")  # nothing lost, nothing twice, byte for byte
    folder = open_folder(tmp_path / "out")
    assert folder.files.size == 3 * 12 * 2 and len(set(folder.files.ravel())) == 72


def _lines(path):
    try:
        return path.read_bytes().count(b"\n")
    except FileNotFoundError:
        return 0


def test_an_emulator_in_temporary_folders_says_where_it_leaves_them(tmp_path):
    args = ["emulate", "sensor", "--subject", "S003", "--duration", "0.2", "--quiet", "--lab", tmp_path / "lab"]
    r = run_cli(*args, env={"TMPDIR": str(tmp_path)})
    assert r.returncode == 0, r.stderr
    (hot,) = [p for p in tmp_path.iterdir() if p.name.startswith("facestats-emulate-sensor-")]
    assert f"kept in a temporary folder (remove it when done): {hot / 'hot'}" in r.stdout
    assert str(tmp_path / "lab") not in r.stdout.split("kept in")[1]  # a folder the user named is not temporary


@pytest.mark.slow
def test_emulate_killed_while_it_builds_leaves_no_temporary_folder(tmp_path):
    """SIGTERM during the minutes of start-up did what Ctrl-C does only since 2026-12-06: before, the default
    disposition killed the process and left a half-built ``facestats-emulate-dome-*`` folder (a red team)."""
    env = dict(os.environ, TMPDIR=str(tmp_path), PYTHONWARNINGS="ignore")
    proc = subprocess.Popen(
        facestats_exe() + ["emulate", "dome", "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=env,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob("facestats-emulate-dome-*")) and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(0.05)
        assert list(tmp_path.glob("facestats-emulate-dome-*")), "the emulator made no temporary folder"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130 and "facestats: interrupted" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []
