"""Capture sessions: run a plan on a device and its cameras, journal each completed step, resume after anything.

A capture directory holds what the photograph ingest reads (``docs/photographs.md``)
and the session's bookkeeping::

    manifest.json              dome session complete: facestats.capture-folder/1 (written last, atomically)
    dome.json                  the calibration the dome plan was made from (a copy)
    cam00/led000_e0.png …      dome frames
    sensor.json                sensor session complete: facestats.sensor-profiles/1 (written last, atomically)
    sensor-calibration.json    the sensor calibration (a copy)
    sensor/cheek_e00.png …     sensor frames (the raw bracket)
    session/dome.plan.json     the plan; its SHA-256 identifies it
    session/dome.journal       one JSON line per completed step
    session/sensor.plan.json, session/sensor.journal
    session/log.txt            what happened: runs, retries, reboots, reconnections, retakes

**Journal.** A step is committed once its frames are stored under their final
names (moved out of the hot folder or written, then fsync'ed) and verified — the
SHA-256 of the stored file (:func:`facestats.acquire.photographs.frame_entry`)
must equal the checksum the cameras delivered — by appending its line and
fsync'ing the journal.  On ``resume`` a line cut short by a crash is removed, a
step whose frames are missing is taken again (with ``verify``: also one whose
frames differ from their SHA-256), and steps without a line are taken (their
leftover files overwritten); this holds for a finished session too (each
frame it lists is looked up; its product is removed and written again once
every step is back).  On completion the journal is rewritten in step order and
the product (manifest or sensor file) is written atomically, so a session is
marked complete only when every frame is stored, and a completed session is the
same, byte for byte, however often it was interrupted (only
``session/log.txt`` tells the story).  Every frame is taken under a state the
device itself reports in its trigger reply (:meth:`DomePlan.matches`); a frame
taken under another state (a reboot lost the LED) is discarded and the step
taken again.

**Refusals** (:class:`facestats.errors.SessionError`, raised before anything is
written): a capture directory whose plan names another subject; a journal made
from another plan; an unfinished session without ``resume``; ``resume`` with
nothing to resume; a directory holding files of something else.
"""

from __future__ import annotations

import collections
import hashlib
import json
import os
import pathlib
import time
from dataclasses import dataclass, field

from facestats.core.conventions import SITES
from facestats.core.progress import progress_bar
from facestats.errors import DeviceError, SessionError
from facestats.io.layout import read_regular_file

__all__ = ["run_session", "SessionReport", "SessionLog", "session_state", "missing_steps"]

SESSION_DIR = "session"
#: Files and directories a capture directory may hold besides the frames' camera folders.
KNOWN = {SESSION_DIR, "manifest.json", "dome.json", "sensor.json", "sensor-calibration.json", "sensor"}
PRODUCT = {"dome": "manifest.json", "sensor": "sensor.json"}
CALIBRATION = {"dome": "dome.json", "sensor": "sensor-calibration.json"}


class SessionLog:
    """Timestamped lines into ``session/log.txt``, held in memory until the session directory exists.

    Parameters
    ----------
    echo : callable, optional
        Also receives each line (without its time stamp), e.g. to print it.
    """

    def __init__(self, echo=None):
        self.path, self.lines, self.echo = None, [], echo

    def __call__(self, line: str):
        """Log ``line`` with a time stamp: to the log file once attached, else kept until then."""
        text = f"{time.strftime('%Y-%m-%d %H:%M:%S')} {line}"
        if self.echo is not None:
            self.echo(line)
        if self.path is None:
            self.lines.append(text)
            return
        with open(self.path, "a") as f:
            f.write(text + "\n")

    def attach(self, path):
        """Write the lines kept so far to ``path`` and log there from now on.

        Parameters
        ----------
        path : str or path-like
            The log file (appended to).
        """
        self.path = pathlib.Path(path)
        with open(self.path, "a") as f:
            f.writelines(t + "\n" for t in self.lines)
        self.lines = []


@dataclass
class SessionReport:
    """What a run of :func:`run_session` did.

    Attributes
    ----------
    kind : str
        ``"dome"`` or ``"sensor"``.
    subject_id : str
    out : pathlib.Path
        The capture directory.
    steps_total : int
        Steps of the plan.
    steps_before : int
        Steps committed by earlier runs.
    steps_taken : int
        Steps committed by this run.
    frames : int
        Frames stored by this run.
    retakes : int
        Steps taken again (state not reached, frame not delivered).
    elapsed_s : float
        Duration of this run's capture, s.
    link : dict
        The link's counters (:meth:`~facestats.acquire.devices.serial_link.LinkStats.as_dict`).
    complete : bool
        The session's product (manifest or sensor file) is written.
    stray_frames : list of str
        Frame files left in the hot folder at the end of the run, of triggers no run collected
        (:meth:`~facestats.acquire.devices.cameras.HotFolderCameras.stray_frames`); the session does not use them.
    """

    kind: str
    subject_id: str
    out: pathlib.Path
    steps_total: int
    steps_before: int
    steps_taken: int = 0
    frames: int = 0
    retakes: int = 0
    elapsed_s: float = 0.0
    link: dict = field(default_factory=dict)
    complete: bool = False
    stray_frames: list = field(default_factory=list)

    def to_text(self) -> str:
        """What the session did, for the operator."""
        head = f"{self.kind} session of {self.subject_id} in {self.out}: "
        if self.complete and not self.steps_taken:
            return head + f"complete ({self.steps_total} steps), nothing to do"
        lines = [
            head
            + ("complete" if self.complete else "interrupted")
            + f": {self.steps_before + self.steps_taken}/{self.steps_total} steps"
            + (f" ({self.steps_before} from an earlier run)" if self.steps_before else ""),
            f"this run: {self.steps_taken} steps, {self.frames} frames in {self.elapsed_s:.1f} s, "
            f"{self.retakes} step(s) taken again",
        ]
        if self.link:
            shown = {k: v for k, v in self.link.items() if v and k != "bytes_received"}
            lines.append("link: " + ", ".join(f"{k} {v}" for k, v in shown.items()))
        if self.stray_frames:
            lines.append(
                f"hot folder: {len(self.stray_frames)} frame file(s) of triggers no run collected (an interrupted "
                f"run's, or triggered by hand) are left there, e.g. {self.stray_frames[0]}; this session does not "
                "use them: delete them"
            )
        return "\n".join(lines)


def _read_json(path, what):
    try:
        return json.loads(read_regular_file(path))
    except (OSError, ValueError, RecursionError) as exc:  # ValueError: not JSON, or not UTF-8
        raise SessionError(
            f"{what} {path} cannot be read ({exc}): delete the session directory to start over"
        ) from None


def missing_steps(out, plan, log=None, *, verify: bool = True) -> int:
    """Steps of a session in ``out`` whose frames are missing (or, with ``verify``, differ from their SHA-256).

    Without ``verify`` every committed frame is only looked up (a stat each: cheap); with it every frame is read
    and hashed.  Only a journal line cut short by an interruption is changed (removed, as on resume: its step
    counts as missing).

    Parameters
    ----------
    out : str or path-like
        The capture directory.
    plan : DomePlan or SensorPlan
        The plan whose journal (``session/<kind>.journal``) is read.
    log : callable, optional
        Receives the lines about removed or missing entries (default a :class:`SessionLog` that keeps them).
    verify : bool
        Hash every committed frame against its SHA-256.

    Returns
    -------
    int
        Number of the plan's steps without a committed, present frame set (all of them without a journal).

    Raises
    ------
    SessionError
        A corrupt journal line, or one naming a step outside the plan.
    """
    return plan.n_steps - len(_Journal(pathlib.Path(out), plan, log or SessionLog()).load(verify))


def session_state(out, plan, *, resume: bool) -> str:
    """``"new"``, ``"resume"`` or ``"complete"`` for ``plan`` in ``out``; :class:`SessionError` for every refusal.

    Reads only: nothing is created or changed.

    Parameters
    ----------
    out : str or path-like
        The capture directory.
    plan : DomePlan or SensorPlan
        The plan to run there.
    resume : bool
        Whether the caller means to continue an unfinished session.

    Returns
    -------
    str
        ``"complete"`` if the plan's product (manifest or sensor file) exists, ``"resume"`` for an unfinished
        session with ``resume``, ``"new"`` for a directory without a session of this kind.

    Raises
    ------
    SessionError
        Every refusal of the module docstring: another subject's directory, a journal of another plan, an
        unfinished session without ``resume``, ``resume`` with nothing to resume, a directory of other files.
    """
    out = pathlib.Path(out)
    sdir = out / SESSION_DIR
    mine = sdir / f"{plan.kind}.plan.json"
    _check_owner(out, sdir, plan)
    if mine.exists():
        doc = _read_json(mine, "capture plan")
        if doc != json.loads(json.dumps(plan.to_dict())):
            diff = ", ".join(plan.differences(doc)) or "content"
            raise SessionError(
                f"the journal in {sdir} was written for a different {plan.kind} plan (differs in: {diff}); "
                "capture into a new --out, or delete that session directory to start over"
            )
        if (out / PRODUCT[plan.kind]).exists():
            return "complete"
        if not resume:
            raise SessionError(
                f"{out} holds an unfinished {plan.kind} session of {plan.subject_id}: pass --resume to continue it "
                "(or choose another --out)"
            )
        return "resume"
    if resume:
        raise SessionError(
            f"nothing to resume in {out}: it has no {plan.kind} session ({mine} is missing); run without --resume"
        )
    _check_empty(out)
    return "new"


def _check_owner(out, sdir, plan):
    """Raise if a session in ``out`` (of either kind) belongs to another subject."""
    for other in sorted(sdir.glob("*.plan.json")) if sdir.is_dir() else []:
        sid = (_read_json(other, "capture plan").get("subject") or {}).get("subject_id")
        if sid != plan.subject_id:
            raise SessionError(
                f"capture directory {out} belongs to subject {sid} (its {other.name}), not {plan.subject_id}: "
                "choose another --out for this subject"
            )


def _check_empty(out):
    """Raise unless ``out`` is absent, empty, or holds only capture-session files."""
    if not out.exists():
        return
    if not out.is_dir():
        raise SessionError(f"--out {out} is a file, not a directory")
    strangers = sorted(p.name for p in out.iterdir() if p.name not in KNOWN and not p.name.startswith("cam"))
    if strangers:
        raise SessionError(
            f"{out} is not empty and holds no capture session ({', '.join(strangers[:3])} …): choose an empty "
            "or new directory for --out"
        )


class _Journal:
    """The plan, journal and product of one session in a capture directory (module docstring)."""

    def __init__(self, out, plan, log):
        self.out, self.plan, self.log = pathlib.Path(out), plan, log
        self.sdir = self.out / SESSION_DIR
        self.path = self.sdir / f"{plan.kind}.journal"
        self.done: dict = {}

    def create(self, calibration: bytes):
        self.sdir.mkdir(parents=True, exist_ok=True)
        _atomic_write(self.out / CALIBRATION[self.plan.kind], calibration)
        _atomic_write(self.path, b"")
        _atomic_write(self.sdir / f"{self.plan.kind}.plan.json", json.dumps(self.plan.to_dict(), indent=1).encode())

    def load(self, verify: bool = False):
        """The committed steps; a line cut short by a crash is removed, steps with missing frames dropped."""
        data = self.path.read_bytes() if self.path.exists() else b""
        end = data.rfind(b"\n") + 1
        if end < len(data):
            self.log(f"journal: removed a line cut short ({len(data) - end} bytes) by an interruption")
            with open(self.path, "r+b") as f:
                f.truncate(end)
                os.fsync(f.fileno())
        for n, line in enumerate(data[:end].splitlines(), 1):
            try:
                rec = json.loads(line)
                step, entries = int(rec["step"]), rec["frames"]
            except (ValueError, KeyError, TypeError):
                raise SessionError(
                    f"journal {self.path} line {n} is corrupt: delete {self.sdir} and the frames to start over"
                ) from None
            if not 0 <= step < self.plan.n_steps:
                raise SessionError(f"journal {self.path} line {n} names step {step} outside the plan")
            if self._present(entries, verify):
                self.done[step] = entries
            else:
                self.log(f"journal: step {step} has missing or altered frames; it will be taken again")
        return self.done

    def _present(self, entries, verify):
        for e in entries:
            p = self.out / e["file"]
            if not p.is_file() or (verify and hashlib.sha256(p.read_bytes()).hexdigest() != e["sha256"]):
                return False
        return True

    def commit(self, step: int, entries: list, durable: bool):
        line = json.dumps({"step": step, "frames": entries}, sort_keys=True, separators=(",", ":")).encode() + b"\n"
        with open(self.path, "ab") as f:
            f.write(line)
            f.flush()
            if durable:
                os.fsync(f.fileno())
        self.done[step] = json.loads(line)["frames"]  # as a resumed run reads it: the product is the same

    def finish(self):
        """Rewrite the journal in step order (every run of the plan ends with the same journal)."""
        lines = [
            json.dumps({"step": s, "frames": self.done[s]}, sort_keys=True, separators=(",", ":")) + "\n"
            for s in range(self.plan.n_steps)
        ]
        _atomic_write(self.path, "".join(lines).encode())


def _atomic_write(path, data: bytes):
    tmp = pathlib.Path(f"{path}.part")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _store(frame, dest: pathlib.Path, durable: bool):
    """Put a frame's file at ``dest``: moved out of the hot folder when possible, else written."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    moved = False
    if frame.path is not None:
        try:
            os.replace(frame.path, dest)
            moved = True
        except OSError:  # another file system, or gone: write the bytes received
            moved = False
    if not moved:
        tmp = dest.with_name(dest.name + ".part")
        tmp.write_bytes(frame.data)
        os.replace(tmp, dest)
    if durable:
        fd = os.open(dest, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


class _Runner:
    """One run of a session: takes the pending steps with one trigger of look-ahead, commits them in order."""

    def __init__(self, plan, controller, cameras, journal, *, frame_timeout, attempts, durable, log, on_site, bar):
        self.plan, self.controller, self.cameras, self.journal = plan, controller, cameras, journal
        self.frame_timeout, self.attempts, self.durable = frame_timeout, attempts, durable
        self.log, self.on_site, self.bar = log, on_site, bar
        self.next_frame = 1 + int.from_bytes(os.urandom(5), "big") % 10**11  # ids never repeat across runs
        self.retakes = self.taken = self.frames = 0

    def run(self, pending):
        inflight = collections.deque()
        site = None
        for s in pending:
            step = self.plan.step(s)
            if "site" in step and step["site"] != site:
                while inflight:
                    self._commit(*inflight.popleft())
                site = step["site"]
                self.controller.all_off()
                if self.on_site is not None:
                    self.on_site(SITES[site])
            inflight.append((s, self._take(s)))
            while len(inflight) > 1:
                self._commit(*inflight.popleft())
        while inflight:
            self._commit(*inflight.popleft())

    def _take(self, s):
        trig = None
        for _ in range(self.attempts):
            self.plan.ensure(self.controller, s)
            frame, self.next_frame = self.next_frame, self.next_frame + 1
            trig = self.controller.trigger(frame, self.plan.trigger_timeout(s, self.controller.link.timeout))
            if self.plan.matches(s, trig):
                return trig
            self.retakes += 1
            self.log(f"step {s} {self.plan.step(s)}: the device took frame {frame} under {trig}; taking it again")
            self.cameras.release(trig)
            self.controller.forget()  # e.g. its watchdog switched the light off: set everything again
        raise SessionError(
            f"step {s} {self.plan.step(s)}: the device did not reach the planned state in {self.attempts} triggers "
            f"(last report: {trig}); check the controller, then rerun with --resume"
        )

    def _commit(self, s, trig):
        for attempt in range(self.attempts):
            try:
                frames = self.cameras.collect(trig, self.frame_timeout)
                break
            except DeviceError as exc:
                self.cameras.release(trig)
                if attempt == self.attempts - 1:
                    raise
                self.retakes += 1
                self.log(f"step {s}: {exc}; taking it again")
                trig = self._take(s)
        entries = [self._entry(s, fr) for fr in sorted(frames, key=lambda f: f.camera)]
        self.journal.commit(s, entries, self.durable)
        self.cameras.release(trig)
        self.taken += 1
        self.frames += len(entries)
        self.bar.update(1)

    def _entry(self, s, frame):
        # local import: keeps numpy out of this module's import
        from facestats.acquire.photographs import frame_entry

        out, plan = self.journal.out, self.plan
        rel = plan.file(s, frame.camera)
        _store(frame, out / rel, self.durable)
        st = plan.step(s)
        t = plan.exposure_s[st["exposure"]]
        if plan.kind == "dome":
            entry = frame_entry(out, rel, frame.camera, st["led"], st["exposure"], t)
        else:
            sha = hashlib.sha256((out / rel).read_bytes()).hexdigest()
            entry = {"site": SITES[st["site"]], "exposure": st["exposure"], "exposure_s": t, "file": rel, "sha256": sha}
        if entry["sha256"] != frame.sha256:
            raise SessionError(
                f"stored frame {out / rel} differs from the frame the camera delivered (disk error?); "
                "rerun with --resume to take it again"
            )
        return entry


def run_session(
    plan,
    controller,
    cameras,
    out,
    *,
    calibration: bytes,
    resume: bool = False,
    progress: bool = True,
    frame_timeout: float = 60.0,
    attempts: int = 4,
    durable: bool = True,
    verify: bool = False,
    log=None,
    on_site=None,
) -> SessionReport:
    """Run ``plan`` (:mod:`facestats.acquire.devices.plans`) into the capture directory ``out`` (module docstring).

    Parameters
    ----------
    plan : DomePlan or SensorPlan
    controller : DomeController or SensorController
        Open, and checked here against the plan before anything is written.
    cameras : CameraBackend
    out : path-like
    calibration : bytes
        The calibration file the plan was made from (copied into ``out``).
    resume : bool
        Continue the unfinished session in ``out``.
    progress : bool
        Show a progress bar over the plan's steps.
    frame_timeout : float
        Seconds to wait for a camera's frame of a trigger.
    attempts : int
        Triggers per step before the run gives up (state not reached, frame not delivered).
    durable : bool
        fsync every frame and journal line (a power cut loses nothing committed).
    verify : bool
        On resume, check the SHA-256 of every committed frame (without it, only that each file exists), also of
        a finished session.
    log : callable, optional
        Receives the session's log lines (a :class:`SessionLog` writes them to ``session/log.txt``).
    on_site : callable, optional
        Sensor plans: called with the site's name before its bracket (prompt the operator).

    Returns
    -------
    SessionReport
    """
    log = log or SessionLog()
    out = pathlib.Path(out)
    state = session_state(out, plan, resume=resume)
    report = SessionReport(plan.kind, plan.subject_id, out, plan.n_steps, 0)
    # A finished session is checked too on resume: the steps whose frames are gone (with verify: or altered) are
    # retaken.
    missing = missing_steps(out, plan, log, verify=verify) if state == "complete" and resume else 0
    if state == "complete" and not missing:
        report.steps_before, report.complete = plan.n_steps, True
        return report
    plan.check_device(controller)  # a mis-wired device stops the session before anything is written
    cameras.prepare()
    if missing:
        found = "missing or altered" if verify else "missing"
        log(f"resume: {missing} completed step(s) have {found} frames; the session is reopened")
        os.remove(out / PRODUCT[plan.kind])  # written again when every step is back
        state = "resume"
    journal = _Journal(out, plan, log)
    if state == "new":
        try:
            journal.create(calibration)
        except OSError as exc:
            raise SessionError(f"cannot create the capture directory {out}: {exc.strerror or exc}") from None
    if isinstance(log, SessionLog):
        log.attach(journal.sdir / "log.txt")
    log(f"{state} {plan.kind} session of {plan.subject_id} (pid {os.getpid()}, device {controller.identity!r})")
    done = journal.load(verify)
    report.steps_before = len(done)
    pending = [s for s in range(plan.n_steps) if s not in done]
    bar = progress_bar(
        total=plan.n_steps,
        initial=len(done),
        desc=f"capture {plan.kind} {plan.subject_id}",
        unit="step",
        enabled=progress,
    )
    runner = _Runner(
        plan,
        controller,
        cameras,
        journal,
        frame_timeout=frame_timeout,
        attempts=attempts,
        durable=durable,
        log=log,
        on_site=on_site,
        bar=bar,
    )
    t0 = time.perf_counter()
    try:
        runner.run(pending)
    except OSError as exc:  # the capture directory failed under the session (disk full, removed, read-only)
        raise SessionError(
            f"cannot write the capture into {out}: {exc.strerror or exc} ({exc.filename or ''}); fix it, then rerun "
            "with --resume (completed steps are kept)"
        ) from None
    finally:
        bar.close()
        report.steps_taken, report.frames, report.retakes = runner.taken, runner.frames, runner.retakes
        report.elapsed_s = time.perf_counter() - t0
        report.link = controller.link.stats.as_dict()
        log(f"run ended: {report.steps_before + report.steps_taken}/{plan.n_steps} steps; link {report.link}")
    journal.finish()
    _finish(plan, out, journal.done)
    report.complete = True
    log(f"{plan.kind} session complete: {PRODUCT[plan.kind]} written")
    return report


def _finish(plan, out, done):
    """Write the session's product atomically: the manifest (dome) or the merged sensor file (sensor)."""
    entries = [e for s in range(plan.n_steps) for e in done[s]]
    if plan.kind == "dome":
        # local import: keeps numpy out of this module's import
        from facestats.acquire.photographs import write_manifest

        write_manifest(
            out,
            entries,
            kind="face",
            bits=plan.bits,
            n_cameras=plan.n_cameras,
            n_leds=plan.n_leds,
            subject=plan.subject,
            sensor="sensor.json",
        )
        return
    import numpy as np

    # local import: keeps numpy out of this module's import
    from facestats.acquire.devices.sensor import FiberLayout, merge_bracket
    from facestats.acquire.photographs import write_sensor_file
    from facestats.acquire.sensor import ContactSensor
    from facestats.io.images import decode_integer_image

    sensor, layout = ContactSensor.from_attrs(plan.sensor), FiberLayout(**plan.layout)
    n_exp = len(plan.exposure_s)
    profile = np.full((len(SITES), plan.n_fibers, 3), np.nan)
    std = np.full_like(profile, np.nan)
    for k, site in enumerate(plan.sites):
        site_entries = entries[k * n_exp : (k + 1) * n_exp]
        stack = [decode_integer_image((out / e["file"]).read_bytes(), e["file"])[0] for e in site_entries]
        profile[site], std[site] = merge_bracket(np.stack(stack), plan.exposure_s, sensor, layout)
    tmp = out / "sensor.json.part"
    # the layout goes with the frames: read_bracket finds the fibre spots where this merge found them
    write_sensor_file(tmp, sensor, profile, std, frames=entries, subject=plan.subject, fiber_layout=layout.to_dict())
    os.replace(tmp, out / "sensor.json")
