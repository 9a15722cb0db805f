"""Capture sessions against the emulated devices over a real pty: full sequences, faults, resume, refusals."""

import json
import os
import pathlib
import shutil
import time

import numpy as np
import pytest

from facestats.acquire.devices.cameras import EmulatedCameras, HotFolderCameras, Trigger
from facestats.acquire.devices.capture import capture, dome_plan
from facestats.acquire.devices.emulator import Faults
from facestats.acquire.devices.lab import emulated_dome, emulated_sensor
from facestats.acquire.devices.plans import DomePlan, SensorPlan
from facestats.acquire.photographs import open_folder
from facestats.errors import DeviceError, FormatError, SessionError
from tests.acquire.devices.helpers import record, run_capture, tree


@pytest.fixture(scope="module")
def full(tmp_path_factory):
    """The full dome sequence (150 LEDs × 16 cameras × 2 exposures) at 24² pixels, captured once without faults."""
    root = tmp_path_factory.mktemp("full")
    server = emulated_dome("S001", root / "hot", root / "lab", resolution=24)
    try:
        report = run_capture(server, root / "lab", root / "hot", root / "clean")
    finally:
        server.stop()
    return root, server.scene, report


@pytest.mark.slow
def test_the_full_dome_sequence_writes_the_capture_folder_the_ingest_reads(full):
    root, scene, report = full
    assert report.complete and (report.steps_taken, report.frames, report.retakes) == (300, 4800, 0)
    folder = open_folder(root / "clean")
    assert (folder.n_cameras, folder.n_leds, folder.n_exposures) == (16, 150, 2)
    assert folder.subject() == record(root / "lab") and folder.bits == 12
    assert (root / "clean" / "dome.json").read_bytes() == (root / "lab" / "dome.json").read_bytes()
    journal = (root / "clean" / "session" / "dome.journal").read_text().splitlines()
    assert [json.loads(line)["step"] for line in journal] == list(range(300))
    cams = EmulatedCameras(scene)
    for camera, led, exposure in ((0, 0, 0), (7, 75, 1), (15, 149, 1), (3, 12, 0)):  # each file is its own frame
        stored = (root / "clean" / folder.files[0, camera, led, exposure]).read_bytes()
        assert stored == cams.frame(camera, Trigger(0, led, exposure)).data
    codes = folder.read_codes(7, 75, 1, size=(24, 24))  # checksum, size and EXIF exposure time checked
    assert codes.shape == (24, 24, 3) and codes.max() > 100


@pytest.mark.slow
def test_garbled_replies_a_disconnect_and_a_reboot_leave_the_session_identical(full, tmp_path):
    root, scene, _ = full
    faults = Faults(garble=0.01, disconnect_after=(200,), reboot_after=(400,), seed=7)
    server = emulated_dome(
        "S001", tmp_path / "hot", tmp_path / "lab", scene=scene, faults=faults, link=tmp_path / "tty"
    )
    try:
        report = run_capture(server, tmp_path / "lab", tmp_path / "hot", tmp_path / "faulty")
    finally:
        server.stop()
    assert server.injected["garble"] >= 3 and server.injected["disconnect"] == 1 and server.injected["reboot"] == 1
    link = report.link
    assert link["garbled"] == server.injected["garble"] and link["reboots"] == 1 and link["reconnects"] == 1
    assert tree(tmp_path / "faulty") == tree(root / "clean")  # byte for byte, journal included
    log = (tmp_path / "faulty" / "session" / "log.txt").read_text()
    assert "rebooted" in log and "reconnecting" in log and "garbled reply frame" in log


@pytest.mark.slow
def test_the_full_sensor_sequence_measures_the_profiles_within_their_noise(full, tmp_path):
    root, _, _ = full
    out = tmp_path / "capture"
    shutil.copytree(root / "clean", out)  # the sensor session joins the dome session's folder
    server = emulated_sensor("S001", tmp_path / "hot", tmp_path / "lab")
    try:
        report = run_capture(server, tmp_path / "lab", tmp_path / "hot", out, kind="sensor", on_site=print)
    finally:
        server.stop()
    assert report.complete and report.frames == 69
    sensor, profile, std = open_folder(out).sensor()
    truth = server.scene.profile
    z = (profile - truth) / std
    assert np.all(np.abs(z) < 5) and 0.8 < np.std(z) < 1.2  # the merged profile and its noise model agree
    strong = truth > 1e-4
    assert np.abs(profile[strong] / truth[strong] - 1).max() < 0.01  # the paper's dynamic range: 1 % where it matters
    entries = json.loads((out / "sensor.json").read_text())["frames"]
    assert [e["file"] for e in entries[:2]] == ["sensor/cheek_e00.png", "sensor/cheek_e01.png"] and len(entries) == 69
    assert tree(root / "clean").items() <= tree(out).items()  # the dome session is untouched


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A smaller rig (10 LEDs, 4 cameras, 24²) and its clean session, for the resume and refusal tests."""
    root = tmp_path_factory.mktemp("small")
    server = emulated_dome("S002", root / "hot", root / "lab", resolution=24, leds=10, cameras=4)
    try:
        run_capture(server, root / "lab", root / "hot", root / "clean", durable=True)
    finally:
        server.stop()
    return root, server.scene


def _serve(small, tmp_path, **kw):
    _, scene = small
    return emulated_dome("S002", tmp_path / "hot", tmp_path / "lab", scene=scene, **kw)


class _Crash(HotFolderCameras):
    """Cameras of a process that dies (KeyboardInterrupt) while collecting its ``at``-th trigger."""

    def __init__(self, *a, at, **kw):
        super().__init__(*a, **kw)
        self.at, self.calls = at, 0

    def collect(self, trigger, timeout):
        self.calls += 1
        if self.calls == self.at:
            raise KeyboardInterrupt("power cut")
        return super().collect(trigger, timeout)


def test_an_interrupted_session_resumes_to_the_identical_folder(small, tmp_path):
    root, _ = small
    server = _serve(small, tmp_path)
    out = tmp_path / "out"
    try:
        plan, calibration = dome_plan(tmp_path / "lab" / "dome.json", record(tmp_path / "lab"))
        from facestats.acquire.devices.dome import DomeController

        with DomeController(server.port) as c:
            from facestats.acquire.devices.session import run_session

            cams = _Crash(tmp_path / "hot", range(4), at=8)
            with pytest.raises(KeyboardInterrupt):
                run_session(plan, c, cams, out, calibration=calibration, progress=False)
        assert server.device.led == -1  # the driver switched the LEDs off on the way out
        assert not (out / "manifest.json").exists()  # an interrupted session is never marked complete
        journal = out / "session" / "dome.journal"
        assert len(journal.read_text().splitlines()) == 7  # steps 0-6 committed; step 7 triggered, never collected
        with open(journal, "ab") as f:  # a line cut short by the crash
            f.write(b'{"frames":[{"cam')
        (out / "cam02" / "led003_e0.png").unlink()  # a committed frame lost afterwards
        with pytest.raises(SessionError, match="pass --resume to continue it"):
            run_capture(server, tmp_path / "lab", tmp_path / "hot", out)
        report = run_capture(server, tmp_path / "lab", tmp_path / "hot", out, resume=True)
        assert report.complete and report.steps_before == 6 and report.steps_taken == 14
        assert tree(out) == tree(root / "clean")
        # the crashed run triggered steps 7 and 8 (one trigger of look-ahead) and collected neither: their 4 + 4
        # frames stay in the hot folder, and the resumed run says so
        assert len(report.stray_frames) == 8 and all(pathlib.Path(f).is_file() for f in report.stray_frames)
        assert len({pathlib.Path(f).name for f in report.stray_frames}) == 2  # two frame ids, four cameras each
        assert "hot folder: 8 frame file(s) of triggers no run collected" in report.to_text()
        log = (out / "session" / "log.txt").read_text()
        assert "removed a line cut short" in log and "step 3 has missing or altered frames" in log
        # A finished session loses a frame: --resume --verify reopens it and retakes that step only.
        (out / "cam01" / "led005_e1.png").unlink()
        fixed = run_capture(server, tmp_path / "lab", tmp_path / "hot", out, resume=True, verify=True)
        assert fixed.complete and fixed.steps_taken == 1 and tree(out) == tree(root / "clean")
    finally:
        server.stop()
    again = run_capture(server, tmp_path / "lab", tmp_path / "hot", out, resume=True)
    assert again.complete and again.steps_taken == 0 and "nothing to do" in again.to_text()


def test_plain_resume_retakes_the_frames_deleted_from_a_finished_session(small, tmp_path):
    """Plain --resume on a finished session said "nothing to do" with frames gone; it now looks each frame up."""
    root, _ = small
    out = tmp_path / "out"
    shutil.copytree(root / "clean", out)
    (out / "cam02" / "led007_e0.png").unlink()
    altered = out / "cam00" / "led001_e1.png"
    altered.write_bytes(altered.read_bytes()[:-1] + b"\0")  # content: only --verify reads it
    server = _serve(small, tmp_path)
    try:
        fixed = run_capture(server, tmp_path / "lab", tmp_path / "hot", out, resume=True)
        assert fixed.complete and (fixed.steps_before, fixed.steps_taken) == (19, 1)
        log = (out / "session" / "log.txt").read_text()
        assert "resume: 1 completed step(s) have missing frames; the session is reopened" in log
        assert "step 7 has missing or altered frames" in log
        clean = tree(root / "clean")
        assert {k: v for k, v in tree(out).items() if k != altered.relative_to(out).as_posix()} == {
            k: v for k, v in clean.items() if k != altered.relative_to(out).as_posix()
        }
        verified = run_capture(server, tmp_path / "lab", tmp_path / "hot", out, resume=True, verify=True)
        assert verified.complete and verified.steps_taken == 1 and tree(out) == clean
    finally:
        server.stop()
    again = run_capture(server, tmp_path / "lab", tmp_path / "hot", out, resume=True)  # no port: nothing missing
    assert again.complete and again.steps_taken == 0 and "nothing to do" in again.to_text()


class _BadChecksum(HotFolderCameras):
    """A transfer that corrupts one frame's checksum file once."""

    done = False

    def collect(self, trigger, timeout):
        if not self.done:
            side = self.path(1, trigger.frame).with_name(self.path(1, trigger.frame).name + ".sha256")
            # wait for the camera's whole checksum line: overwriting a file it is still writing could be undone
            while not (side.exists() and side.read_text().endswith("\n")):
                time.sleep(0.001)
            side.write_text("0" * 64 + " 1\n")
            self.done = True
        return super().collect(trigger, timeout)


def test_a_corrupted_transfer_is_taken_again(small, tmp_path):
    root, _ = small
    from facestats.acquire.devices.dome import DomeController
    from facestats.acquire.devices.session import run_session

    server = _serve(small, tmp_path)
    try:
        plan, calibration = dome_plan(tmp_path / "lab" / "dome.json", record(tmp_path / "lab"))
        with DomeController(server.port) as c:
            cams = _BadChecksum(tmp_path / "hot", range(4), sizes={i: (24, 24) for i in range(4)})
            report = run_session(plan, c, cams, tmp_path / "out", calibration=calibration, progress=False)
    finally:
        server.stop()
    assert report.retakes == 1 and tree(tmp_path / "out") == tree(root / "clean")
    assert "does not match its checksum file" in (tmp_path / "out" / "session" / "log.txt").read_text()


def test_a_miswired_dome_is_refused_before_anything_is_written(small, tmp_path):
    server = _serve(small, tmp_path, wired_leds=9)
    try:
        with pytest.raises(DeviceError, match="reports 9 LEDs, the calibration has 10.*no picture was taken"):
            run_capture(server, tmp_path / "lab", tmp_path / "hot", tmp_path / "out")
    finally:
        server.stop()
    assert not (tmp_path / "out").exists() and server.writer.written == 0
    assert server.device.led == -1


def test_sessions_that_do_not_fit_are_refused_and_nothing_changes(small, tmp_path):
    root, _ = small
    lab = root / "lab"
    done = tmp_path / "done"
    shutil.copytree(root / "clean", done)
    before = tree(done, skip=())
    plan, calibration = dome_plan(lab / "dome.json", record(lab))
    other = DomePlan(**{**plan.__dict__, "subject": {**plan.subject, "subject_id": "S999", "person_id": "S999"}})
    dimmer = DomePlan(**{**plan.__dict__, "brightness": 200})
    cases = [
        (other, {}, "belongs to subject S002 .*not S999: choose another --out"),
        (dimmer, {"resume": True}, r"written for a different dome plan \(differs in: brightness\)"),
    ]
    for p, kw, message in cases:
        with pytest.raises(SessionError, match=message):
            capture(p, calibration, "/dev/null", done, root / "hot", **kw)
    assert tree(done, skip=()) == before
    report = capture(plan, calibration, "/nonexistent", done, root / "hot")  # complete: the port is not even opened
    assert report.complete and "nothing to do" in report.to_text()
    with pytest.raises(SessionError, match="nothing to resume in .*run without --resume"):
        capture(plan, calibration, "/dev/null", tmp_path / "new", root / "hot", resume=True)
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("…")
    with pytest.raises(SessionError, match="not empty and holds no capture session"):
        capture(plan, calibration, "/dev/null", foreign, root / "hot")
    with pytest.raises(DeviceError, match="hot folder .* does not exist"):
        capture(plan, calibration, "/dev/null", tmp_path / "new", tmp_path / "nowhere")
    with pytest.raises(DeviceError, match="cannot open serial port /dev/ttyNOPE: no such device"):
        capture(plan, calibration, "/dev/ttyNOPE", tmp_path / "new", root / "hot")
    assert not (tmp_path / "new").exists()


def test_dry_run_durations_follow_the_paper():
    from facestats.acquire.devices.sensor import FiberLayout
    from facestats.acquire.dome import default_dome
    from facestats.acquire.sensor import ContactSensor

    subject = {
        "subject_id": "S001",
        "person_id": "S001",
        "age": 30,
        "gender": "F",
        "skin_type": 3,
        "condition": "normal",
    }
    dome = DomePlan.from_calibration(default_dome(), b"{}", subject)
    assert (dome.n_steps, dome.frames_per_step) == (300, 16)
    assert dome.duration_s() == pytest.approx(150 * (1 / 12) + 150 * (1 / 8))  # frame interval, then the 1/8 s pass
    assert "300 triggers × 16 cameras = 4800 frames" in dome.describe() and "31.2 s" in dome.describe()
    assert [dome.step(s) for s in (0, 149, 150, 299)] == [
        {"exposure": 0, "led": 0},
        {"exposure": 0, "led": 149},
        {"exposure": 1, "led": 0},
        {"exposure": 1, "led": 149},
    ]  # two passes through the LEDs (Weyrich §5)
    sensor = SensorPlan.from_calibration(ContactSensor(), FiberLayout(), b"{}", subject)
    exposure = 1e-3 * (2 ** (2 / 3 * 23) - 1) / (2 ** (2 / 3) - 1)  # geometric bracket, 23 images at 2/3 stop
    assert sensor.duration_s() / 3 == pytest.approx(exposure + 23 * 0.8)
    assert 85 < sensor.duration_s() / 3 < 91  # Weyrich §5.4: "about 88 seconds"
    assert sensor.file(68) == "sensor/neck_e22.png" and sensor.n_steps == 69


def test_a_dome_plan_takes_its_bits_as_given_and_checks_them():
    """``bits=0`` fell back to the response's depth through ``or``; any value was accepted (a reviewer)."""
    from dataclasses import replace

    from facestats.acquire.dome import default_dome
    from facestats.acquire.response import ResponseCurve
    from facestats.errors import ValidationError

    subject = {"subject_id": "S001", "person_id": "S001", "age": 30, "gender": "F", "skin_type": 3}
    dome = default_dome()
    g = np.repeat(ResponseCurve(bits=10).log_exposure()[:, None], 3, axis=1)
    assert DomePlan.from_calibration(dome, b"{}", subject).bits == 12  # no response
    assert DomePlan.from_calibration(replace(dome, camera_log_response=g), b"{}", subject).bits == 10
    assert DomePlan.from_calibration(dome, b"{}", subject, bits=None).bits == 12
    plan = DomePlan.from_calibration(dome, b"{}", subject, bits=np.int64(14))
    assert plan.bits == 14 and type(plan.bits) is int and plan.fingerprint()  # JSON-ready
    for bits in (0, 7, 17, 12.0, True):
        with pytest.raises(ValidationError, match=f"bits must be an integer( in \\[8, 16\\])?, got {bits!r}"):
            DomePlan.from_calibration(dome, b"{}", subject, bits=bits)


@pytest.mark.slow
def test_a_disconnect_that_outlasts_the_link_ends_the_run_and_resume_completes(small, tmp_path):
    root, _ = small
    server = _serve(small, tmp_path, faults=Faults(disconnect_after=(20,)), link=tmp_path / "tty")
    server.reconnect_delay = 3.0  # the cable stays out longer than the link waits
    try:
        with pytest.raises(DeviceError, match="disconnected and did not come back.*continues with --resume"):
            run_capture(server, tmp_path / "lab", tmp_path / "hot", tmp_path / "out",
                        link_options={"reconnect_timeout": 0.5})  # fmt: skip
        assert not (tmp_path / "out" / "manifest.json").exists()
        # While the cable is out the link is gone: its old pty name may already belong to another process's pty.
        assert not os.path.lexists(tmp_path / "tty")
        for _ in range(1000):  # the cable is plugged back in
            if (tmp_path / "tty").exists():
                break
            time.sleep(0.01)
        report = run_capture(server, tmp_path / "lab", tmp_path / "hot", tmp_path / "out", resume=True)
    finally:
        server.stop()
    assert report.complete and 0 < report.steps_before < 20
    assert tree(tmp_path / "out") == tree(root / "clean")


def test_trigger_lines_choose_the_cameras_that_take_a_picture(small, tmp_path):
    from facestats.acquire.devices.dome import DomeController

    server = _serve(small, tmp_path)
    try:
        with DomeController(server.port) as c:
            assert c.n_cameras == 4
            c.ensure(3, 1, cameras=[0, 2])
            trig = c.trigger(77)
            cams = HotFolderCameras(tmp_path / "hot", range(4))
            frames = cams.collect(trig, 30)
            c.ensure(3, 1)  # every line again
            assert c.trigger(78).lines == 15
    finally:
        server.stop()
    assert trig.lines == 5 and [f.camera for f in frames] == [0, 2]
    assert not cams.path(1, 77).exists()  # camera 1 took no picture
    plan, _ = dome_plan(tmp_path / "lab" / "dome.json", record(tmp_path / "lab"))
    assert not plan.matches(13, trig) and plan.matches(13, Trigger(77, 3, 1, lines=15))  # a session needs every camera


def test_the_sensor_driver_runs_a_bracket(tmp_path):
    from facestats.acquire.devices.sensor import SensorController

    server = emulated_sensor("S001", tmp_path / "hot", tmp_path / "lab")
    try:
        with SensorController(server.port) as c:
            triggers = list(c.bracket(1, range(23), range(500, 523)))
            assert server.device.lamp == 1 and server.device.shutter == 1
        assert server.device.lamp == 0 and server.device.shutter == 0  # lamp off, shutter closed on leaving
    finally:
        server.stop()
    assert [(t.site, t.exposure, t.lamp, t.shutter) for t in triggers] == [(1, j, 1, 1) for j in range(23)]


def test_a_lamp_switched_off_behind_the_drivers_back_is_noticed_and_set_again(tmp_path):
    """The sensor's watchdog (or an operator) turns the lamp off mid-bracket: the trigger's report shows it, the
    step is taken again with the lamp set again, and the session is the same as an undisturbed one."""
    from facestats.acquire.devices.sensor import SensorController
    from facestats.acquire.devices.session import run_session

    server = emulated_sensor("S001", tmp_path / "hot", tmp_path / "lab")
    lab = tmp_path / "lab"

    class Watchdog(HotFolderCameras):
        def collect(self, trigger, timeout):
            if (trigger.site, trigger.exposure) == (1, 5):
                server.device.idle()  # lamp off, shutter closed, without a word to the host
            return super().collect(trigger, timeout)

    try:
        run_capture(server, lab, tmp_path / "hot", tmp_path / "clean", kind="sensor")
        from facestats.acquire.devices.capture import sensor_plan

        plan, calibration = sensor_plan(lab / "sensor-calibration.json", record(lab))
        with SensorController(server.port) as c:
            report = run_session(plan, c, Watchdog(tmp_path / "hot", [0]), tmp_path / "out",
                                 calibration=calibration, progress=False, durable=False)  # fmt: skip
    finally:
        server.stop()
    assert report.retakes == 1 and report.complete
    assert tree(tmp_path / "out") == tree(tmp_path / "clean")
    assert "lamp=0" in (tmp_path / "out" / "session" / "log.txt").read_text()


def _sensor_session(tmp_path, layout, sites, sensor=None, subject_id="S001"):
    """A sensor session captured from an emulated sensor whose camera images its fibres with ``layout``."""
    from facestats.acquire.devices.cameras import EmulatedCameras, HotFolderWriter
    from facestats.acquire.devices.capture import sensor_plan
    from facestats.acquire.devices.emulator import PtyServer, SensorDevice
    from facestats.acquire.devices.scene import SensorScene
    from facestats.acquire.devices.sensor import save_sensor_calibration

    sp = np.array([[1.0, 1.2, 1.5], [2.0, 2.4, 3.0], [0.6, 0.7, 0.9]])  # the three sites differ
    sa = np.array([[0.03, 0.08, 0.2], [0.01, 0.02, 0.05], [0.1, 0.2, 0.4]])
    scene = SensorScene(sp, sa, sensor=sensor, layout=layout, seed=4)
    save_sensor_calibration(tmp_path / "sensor-calibration.json", scene.sensor, layout)
    writer = HotFolderWriter(EmulatedCameras(scene, workers=1), tmp_path / "hot")
    device = SensorDevice(scene.sensor.n_fibers, scene.sensor.exposure_times, layout.size, on_trigger=writer.submit)
    server = PtyServer(device)
    server.closers.append(writer.close)
    server.start()
    subject = {"subject_id": subject_id, "person_id": subject_id, "age": 30, "gender": "F", "skin_type": 3}
    try:
        plan, calibration = sensor_plan(tmp_path / "sensor-calibration.json", {**subject, "condition": "normal"},
                                        sites=sites)  # fmt: skip
        report = capture(plan, calibration, server.port, tmp_path / "out", tmp_path / "hot", durable=False,
                         progress=False, link_options={"timeout": 0.3, "backoff": 0.005})  # fmt: skip
    finally:
        server.stop()
    assert report.complete
    return tmp_path / "out", scene


def test_read_bracket_finds_the_spots_of_the_sessions_layout_and_names_each_profile_by_its_site(tmp_path):
    """read_bracket located the spots with the default layout (a calibration with another pitch failed) and named
    the sites in capture order while the profiles are stored in SITES order (a reviewer)."""
    from facestats.acquire.devices.sensor import FiberLayout, merge_bracket, read_bracket
    from facestats.core.conventions import SITES
    from facestats.io.images import decode_integer_image

    layout = FiberLayout(pitch_px=10, radius_px=3.5, margin_px=5)
    out, scene = _sensor_session(tmp_path, layout, sites=(2, 0, 1))  # neck first
    doc = json.loads((out / "sensor.json").read_text())
    assert doc["fiber_layout"] == layout.to_dict() and doc["frames"][0]["site"] == "neck"
    bracket = read_bracket(out)
    assert bracket.sites == SITES
    labels = layout.labels()
    times = scene.sensor.exposure_times
    for k, site in enumerate(bracket.sites):
        stack = np.stack(
            [decode_integer_image((out / f"sensor/{site}_e{j:02d}.png").read_bytes())[0] for j in range(len(times))]
        )
        profile, std = merge_bracket(stack, times, scene.sensor, layout)
        np.testing.assert_array_equal(bracket.profile[k], profile)  # row k is the profile of site k
        np.testing.assert_array_equal(bracket.profile_std[k], std)
        spot = stack[7][labels == 3].astype(np.float64)  # fibre 3 in exposure 7: the mean code of its spot
        np.testing.assert_allclose(bracket.readings[k, 7, 3], spot.mean(axis=0))
    assert not np.allclose(bracket.profile[0], bracket.profile[2])
    # a fibre without a reading (null in both fields) reads back as NaN; null in one field only is refused
    doc["profile"][1][4][2] = doc["profile_std"][1][4][2] = None
    (out / "sensor.json").write_text(json.dumps(doc))
    assert np.isnan(read_bracket(out).profile[1, 4, 2]) and np.isnan(read_bracket(out).profile_std[1, 4, 2])
    doc["profile_std"][1][4][2] = 0.5
    (out / "sensor.json").write_text(json.dumps(doc))
    with pytest.raises(FormatError, match=r"must both be null where a fibre has no reading, got nan and 0\.5"):
        read_bracket(out)


def test_a_session_whose_nearest_fibres_clip_in_every_exposure_is_read_for_the_ingest_and_fitted(small, tmp_path):
    """merge_bracket gives NaN for a fibre that clipped in every exposure; CaptureFolder.sensor (the ingest) refused
    such a session while read_bracket accepted it. The fibre is now a missing reading the fit leaves out."""
    from facestats.acquire.devices.sensor import FiberLayout
    from facestats.acquire.sensor import ContactSensor
    from facestats.model.fitting import fit_translucency

    root, _ = small
    shutil.copytree(root / "clean", tmp_path / "out")  # the sensor session joins a dome session's folder
    sensor = ContactSensor(shortest_exposure=0.03, n_exposures=8)  # 30 ms first: the nearest fibres clip throughout
    out, scene = _sensor_session(tmp_path, FiberLayout(), sites=(0, 1, 2), sensor=sensor, subject_id="S002")
    _, profile, std = open_folder(out).sensor()
    clipped = np.isnan(profile)
    assert clipped[:, 0].all() and clipped[0, 1].all() and not clipped[:, 4:].any()  # the near fibres, not the far
    assert np.array_equal(clipped, np.isnan(std))
    fit = fit_translucency(sensor.fiber_distance, np.moveaxis(profile, 1, 2), np.moveaxis(std, 1, 2))
    sp = np.array([[1.0, 1.2, 1.5], [2.0, 2.4, 3.0], [0.6, 0.7, 0.9]])  # _sensor_session's scene
    sa = np.array([[0.03, 0.08, 0.2], [0.01, 0.02, 0.05], [0.1, 0.2, 0.4]])
    assert clipped.sum(1).tolist() == [[3, 2, 2], [3, 3, 3], [1, 1, 1]]  # fibres without a reading, (site, channel)
    np.testing.assert_allclose(fit.sigma_s_prime, sp, rtol=0.015)  # measured: within 0.53 %
    np.testing.assert_allclose(fit.sigma_a, sa, rtol=0.015)  # within 0.31 %


def test_read_bracket_names_the_file_and_the_field_of_a_bad_sensor_file(tmp_path):
    from facestats.acquire.devices.sensor import FiberLayout, read_bracket

    out, _ = _sensor_session(tmp_path, FiberLayout(), sites=(0, 1, 2))
    good = json.loads((out / "sensor.json").read_text())
    old = {k: v for k, v in good.items() if k != "fiber_layout"}  # written before the layout was stored: the default
    (out / "sensor.json").write_text(json.dumps(old))
    np.testing.assert_array_equal(read_bracket(out).profile, np.asarray(good["profile"]))
    cases = [
        ({k: v for k, v in good.items() if k != "sensor"}, r"sensor\.json has a missing or malformed field: 'sensor'"),
        ({k: v for k, v in good.items() if k != "frames"}, r"sensor\.json holds no frames"),
        ({**good, "profile_std": good["profile"][:2]}, r"'profile_std' must be \(site 3, fiber 28, channel 3\)"),
        ({**good, "fiber_layout": {**good["fiber_layout"], "pitch_px": 9}}, r"sensor/cheek_e00\.png has shape"),
        ({**good, "fiber_layout": {"n_fibers": 5}}, "'fiber_layout' has 5 fibres, its sensor 28"),
        ({**good, "frames": [{**good["frames"][0], "site": "chin"}]}, "a frame with a missing or malformed field"),
    ]
    for doc, message in cases:
        (out / "sensor.json").write_text(json.dumps(doc))
        with pytest.raises(FormatError, match=message):
            read_bracket(out)
    (out / "sensor.json").write_bytes(b"\xff\xfe{")
    with pytest.raises(FormatError, match=r"sensor file .*sensor\.json cannot be read"):
        read_bracket(out)
    (out / "sensor.json").unlink()
    with pytest.raises(FormatError, match=r"holds no completed sensor session \(no sensor\.json\)"):
        read_bracket(out)


def test_files_that_are_not_utf8_are_format_errors(tmp_path):
    """A calibration, subject record or plan that is not UTF-8 raised UnicodeDecodeError (a reviewer)."""
    from facestats.acquire.devices.capture import read_subject_record, sensor_plan
    from facestats.acquire.devices.sensor import load_sensor_calibration

    bad = tmp_path / "bad.json"
    bad.write_bytes(b'{"format": "\xff\xfe"}')
    for read, message in (
        (read_subject_record, "cannot read the subject record"),
        (lambda p: dome_plan(p, {}), "dome calibration .* is not valid JSON"),
        (lambda p: sensor_plan(p, {}), "cannot read sensor calibration"),
        (load_sensor_calibration, "cannot read sensor calibration"),
    ):
        with pytest.raises(FormatError, match=message):
            read(bad)


def test_a_session_plan_that_is_not_utf8_is_a_session_error(small, tmp_path):
    root, _ = small
    plan, calibration = dome_plan(root / "lab" / "dome.json", record(root / "lab"))
    out = tmp_path / "out"
    shutil.copytree(root / "clean", out)
    (out / "session" / "dome.plan.json").write_bytes(b'{"kind": "\xff"}')
    with pytest.raises(SessionError, match="capture plan .*dome.plan.json cannot be read"):
        capture(plan, calibration, "/dev/null", out, root / "hot")


def test_the_api_emulates_the_command_lines_default_subject(tmp_path):
    """``emulated_dome()`` required a subject where ``facestats emulate`` defaults to S001 (a walkthrough): both
    take one constant."""
    import inspect

    from facestats.cli import build_parser
    from facestats.core.conventions import DEFAULT_EMULATED_SUBJECT

    for kind, fn in (("dome", emulated_dome), ("sensor", emulated_sensor)):
        args = build_parser().parse_args(["emulate", kind])
        assert args.subject == inspect.signature(fn).parameters["subject_id"].default == DEFAULT_EMULATED_SUBJECT
    server = emulated_sensor(hot_folder=tmp_path / "hot", lab=tmp_path / "lab")  # no subject given
    try:
        record = json.loads((tmp_path / "lab" / "subject.json").read_text())
    finally:
        server.stop()
    assert record["subject_id"] == DEFAULT_EMULATED_SUBJECT == "S001"
