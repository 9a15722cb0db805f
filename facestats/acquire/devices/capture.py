"""Capture from the lab's devices: calibration → plan → controller and hot-folder cameras → session.

:func:`dome_plan` and :func:`sensor_plan` make the plan of a calibration file and
a subject record (no device needed: the dry run prints it); :func:`capture` opens
the controller on ``port`` (a device path or pyserial URL), checks it against
the plan, waits for the cameras' frames in the hot folder and runs the session
(:func:`facestats.acquire.devices.session.run_session`).  Everything that can be
refused without the device (a directory of another subject, a journal of another
plan, a missing hot folder) is refused before the port is opened.
"""

from __future__ import annotations

import json
import pathlib

from facestats.acquire.devices.cameras import DEFAULT_PATTERN, HotFolderCameras
from facestats.acquire.devices.dome import DomeController
from facestats.acquire.devices.plans import DomePlan, SensorPlan
from facestats.acquire.devices.sensor import SensorController, load_sensor_calibration
from facestats.acquire.devices.session import SessionLog, SessionReport, missing_steps, run_session, session_state
from facestats.acquire.dome import Dome
from facestats.core.validate import as_finite
from facestats.errors import FormatError
from facestats.io.layout import read_regular_file

__all__ = ["dome_plan", "sensor_plan", "capture", "read_subject_record"]


def _read(path) -> bytes:
    try:
        return read_regular_file(path)
    except OSError as exc:
        raise FormatError(f"cannot read calibration {path}: {exc.strerror}") from None


def read_subject_record(path) -> dict:
    """The subject record of a JSON file (fields of :func:`~facestats.acquire.devices.plans.subject_record`).

    Parameters
    ----------
    path : str or path-like
        A JSON file holding one object.

    Returns
    -------
    dict
        The object as read; its fields are not checked here.

    Raises
    ------
    FormatError
        The file cannot be read, is not valid JSON, or is not an object.
    """
    try:
        doc = json.loads(read_regular_file(path))
    except (OSError, ValueError, RecursionError) as exc:  # ValueError: not JSON, or not UTF-8
        raise FormatError(f"cannot read the subject record {path}: {exc}") from None
    if not isinstance(doc, dict):
        raise FormatError(f"subject record {path} must be a JSON object, got {type(doc).__name__}")
    return doc


def dome_plan(calibration, subject: dict, **options) -> tuple:
    """``(DomePlan, calibration bytes)`` of a dome calibration file (:meth:`facestats.acquire.dome.Dome.load`).

    Parameters
    ----------
    calibration : str or path-like
        The dome calibration (JSON).
    subject : dict
        The subject record (:func:`~facestats.acquire.devices.plans.subject_record`).
    **options
        Fields of :class:`~facestats.acquire.devices.plans.DomePlan` (``bits``, ``brightness``, ``colour``,
        ``frame_interval_s``, ``extension``); ``bits`` (8 to 16) defaults to that of the calibration's camera response,
        else 12.

    Returns
    -------
    plan : DomePlan
    data : bytes
        The calibration file's bytes (the plan holds their SHA-256).

    Raises
    ------
    FormatError
        The file cannot be read, is not valid JSON, or lacks a field or has a malformed one.
    ValidationError
        A calibration value out of its domain, or a bad plan option.
    """

    data = _read(calibration)
    try:
        doc = json.loads(data)
    except (ValueError, RecursionError) as exc:  # ValueError: not JSON, or not UTF-8
        raise FormatError(f"dome calibration {calibration} is not valid JSON: {exc}") from None
    return DomePlan.from_calibration(Dome.from_dict(doc), data, subject, **options), data


def sensor_plan(calibration, subject: dict, **options) -> tuple:
    """``(SensorPlan, calibration bytes)`` of a sensor calibration file (``facestats.sensor-calibration/1``).

    Parameters
    ----------
    calibration : str or path-like
        The sensor calibration (:func:`~facestats.acquire.devices.sensor.load_sensor_calibration`).
    subject : dict
        The subject record (:func:`~facestats.acquire.devices.plans.subject_record`).
    **options
        Fields of :class:`~facestats.acquire.devices.plans.SensorPlan` (``readout_s``, ``sites``, ``extension``).

    Returns
    -------
    plan : SensorPlan
    data : bytes
        The calibration file's bytes (the plan holds their SHA-256).

    Raises
    ------
    FormatError
        The file cannot be read or is not a valid sensor calibration.
    ValidationError
        A bad plan option.
    """

    data = _read(calibration)
    sensor, layout = load_sensor_calibration(calibration)
    return SensorPlan.from_calibration(sensor, layout, data, subject, **options), data


def capture(
    plan,
    calibration: bytes,
    port: str,
    out,
    hot_folder,
    *,
    resume: bool = False,
    link_options: dict | None = None,
    pattern: str = DEFAULT_PATTERN,
    frame_timeout: float = 60.0,
    durable: bool = True,
    verify: bool = False,
    progress: bool = True,
    on_site=None,
    echo=None,
) -> SessionReport:
    """Run ``plan`` on the device at ``port`` with the frames of ``hot_folder`` into ``out`` (module docstring).

    Every argument is checked before the port is opened or anything is written.  A session already complete
    (and, with ``resume``, missing no frame) returns at once without opening the port.

    Parameters
    ----------
    plan : DomePlan or SensorPlan
        From :func:`dome_plan` or :func:`sensor_plan`.
    calibration : bytes
        The calibration file the plan was made from (copied into ``out``).
    port : str
        The controller's device path or pyserial URL.
    out : str or path-like
        The capture directory.
    hot_folder : str or path-like
        Where the cameras deliver their frames
        (:class:`~facestats.acquire.devices.cameras.HotFolderCameras`).
    resume : bool
        Continue the unfinished session in ``out`` (:func:`~facestats.acquire.devices.session.run_session`).
    link_options : dict, optional
        Keyword arguments of :class:`~facestats.acquire.devices.serial_link.SerialLink` (baudrate, bytesize,
        parity, stopbits, timeout, retries).
    pattern : str
        A frame's file name relative to ``hot_folder``, with ``{camera}``, ``{frame}`` and ``{ext}``.
    frame_timeout, durable, verify, progress, on_site
        As :func:`~facestats.acquire.devices.session.run_session` (``frame_timeout`` in s, > 0).
    echo : callable, optional
        Receives the session's log lines as they happen.

    Returns
    -------
    SessionReport
        With ``stray_frames``: frame files left in the hot folder after the run (frames no run collected).
    """
    as_finite(frame_timeout, "frame_timeout", 0, None, low_inclusive=False)
    finished = session_state(out, plan, resume=resume) == "complete"
    if finished and not (resume and missing_steps(out, plan, verify=verify)):  # nothing to do: no port opened
        return SessionReport(plan.kind, plan.subject_id, pathlib.Path(out), plan.n_steps, plan.n_steps, complete=True)
    if plan.kind == "dome":
        cams, sizes, controller = range(plan.n_cameras), dict(enumerate(plan.image_size)), DomeController
    else:
        cams, sizes, controller = (0,), {0: plan.image_size}, SensorController
    cameras = HotFolderCameras(hot_folder, cams, pattern=pattern, extension=plan.extension, sizes=sizes)
    cameras.prepare()
    log = SessionLog(echo)
    with controller(port, log=log, **(link_options or {})) as device:
        report = run_session(
            plan,
            device,
            cameras,
            out,
            calibration=calibration,
            resume=resume,
            progress=progress,
            frame_timeout=frame_timeout,
            durable=durable,
            verify=verify,
            log=log,
            on_site=on_site,
        )
    report.stray_frames = [str(p) for p in cameras.stray_frames()]
    return report
