"""The emulated lab: a subject's scene, the dome or sensor controller on a pty, its cameras, and the lab's files.

:func:`emulated_dome` and :func:`emulated_sensor` assemble what ``facestats emulate``
serves: the scene (:mod:`facestats.acquire.devices.scene`), the emulated cameras
writing each trigger's frames into a hot folder
(:class:`~facestats.acquire.devices.cameras.HotFolderWriter`), the controller's
firmware (:mod:`facestats.acquire.devices.emulator`) and its pty.  They also
write the files a lab keeps beside the devices into ``lab``: the calibration
(``dome.json`` — the true rig with the cameras' true response — or
``sensor-calibration.json``), the face scanner's mesh (``face.obj`` with
``face.regions.npy``) and the subject's record (``subject.json``: id, person,
age, gender, skin type, condition).

A failed start leaves no side effects: every argument is checked first (numbers
and seeds in their domains, the folders writable or creatable, the link a path
for a symlink), then the subject's truth is drawn, and only then are the
folders created; if building the scene or starting the server fails after that,
the folders the call created are removed again.  A hot folder or lab of None is
put in a new temporary directory (``facestats-emulate-<device>-*``).
"""

from __future__ import annotations

import contextlib
import json
import os
import pathlib
import shutil
import tempfile

import numpy as np

from facestats.acquire.devices.cameras import EmulatedCameras, HotFolderWriter
from facestats.acquire.devices.emulator import DomeDevice, Faults, PtyServer, SensorDevice
from facestats.acquire.devices.scene import DomeScene, SensorScene, subject_truth
from facestats.acquire.devices.sensor import save_sensor_calibration
from facestats.acquire.dome import default_dome
from facestats.core.conventions import DEFAULT_EMULATED_SUBJECT
from facestats.core.outputs import check_output_dir
from facestats.core.validate import check_integer
from facestats.errors import DeviceError, ValidationError

__all__ = ["emulated_rig", "emulated_dome", "emulated_sensor"]


def emulated_rig(resolution: int | None = None, leds: int | None = None, cameras: int | None = None):
    """The simulator's dome (:func:`facestats.acquire.dome.default_dome`), optionally smaller for quick runs.

    Parameters
    ----------
    resolution : int, optional
        Resample every camera to ``resolution``² pixels, 8 to 8192 (default: the rig's 1024²).
    leds, cameras : int, optional
        Keep that many LEDs or cameras, evenly spread over the rig's indices (1 to the rig's count; default all).

    Returns
    -------
    Dome

    Raises
    ------
    ValidationError
        A count or resolution out of range.
    """

    dome = default_dome()
    pick = {}
    for name, n, total in (("leds", leds, dome.n_leds), ("cameras", cameras, dome.n_cameras)):
        if n is not None:
            check_integer(n, name, 1, total)
            pick[name] = np.unique(np.round(np.linspace(0, total - 1, n)).astype(int))
    if pick:
        dome = dome.select(**pick)
    if resolution is not None:
        check_integer(resolution, "resolution", 8, 8192)
        dome = dome.resized(resolution, resolution)
    return dome


def _directory(path, what) -> pathlib.Path:
    """``path`` created if needed; a :class:`DeviceError` naming ``what`` if it cannot be."""
    p = pathlib.Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DeviceError(f"cannot create the {what} {p}: {exc.strerror}") from None
    return p


def _check_link(link) -> None:
    """``link`` must be None or a path where the pty's symlink can be kept (absent, or a symlink already)."""
    if link is None:
        return
    if not isinstance(link, (str, os.PathLike)) or not os.fspath(link).strip():
        raise ValidationError(f"link must be a path for the pty's symlink, got {link!r}")
    p = pathlib.Path(os.fspath(link))
    if os.path.lexists(p) and not p.is_symlink():
        raise ValidationError(f"link must be absent or a symlink (it is replaced), got {str(p)!r}, which is neither")
    parent = p.absolute().parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise ValidationError(f"link must be a path in a writable directory, got {str(p)!r}")


def _check_common(hot_folder, lab, map_size, faults, link, seed, cache=None) -> None:
    """The arguments :func:`emulated_dome` and :func:`emulated_sensor` share, checked before any work."""
    if hot_folder is not None:
        check_output_dir(hot_folder, "hot_folder")
    if lab is not None:
        check_output_dir(lab, "lab")
    if cache is not None:
        check_output_dir(cache, "cache")
    check_integer(map_size, "map_size", 8)  # the synthetic faces need a lumitexel grid of 8 or more
    if not isinstance(faults, Faults):
        raise ValidationError(f"faults must be a Faults, got {type(faults).__name__}")
    _check_link(link)
    check_integer(seed, "seed", 0)


@contextlib.contextmanager
def _folders(kind, hot_folder, lab):
    """(hot folder, lab) created, with a temporary directory for either that is None; removed again on an error.

    Only folders this block created are removed (with what was written into them), never one that existed.
    """
    created = []  # the outermost folder of each path that did not exist before
    for path in (hot_folder, lab):
        if path is None:
            continue
        p, top = pathlib.Path(os.fspath(path)).absolute(), None
        while not os.path.lexists(p) and p != p.parent:
            top, p = p, p.parent
        if top is not None:
            created.append(top)
    try:
        if hot_folder is None or lab is None:
            base = pathlib.Path(tempfile.mkdtemp(prefix=f"facestats-emulate-{kind}-"))
            created.append(base)
            hot_folder = base / "hot" if hot_folder is None else hot_folder
            lab = base / "lab" if lab is None else lab
        yield _directory(hot_folder, "hot folder"), _directory(lab, "lab directory")
    except BaseException:  # an error or an interruption while starting: nothing to keep
        for top in created:
            if top.is_dir() and not top.is_symlink():
                shutil.rmtree(top, ignore_errors=True)
        raise


def _write_subject(lab: pathlib.Path, truth):
    (lab / "subject.json").write_text(json.dumps(truth.metadata(), indent=1))


def emulated_dome(
    subject_id: str = DEFAULT_EMULATED_SUBJECT,
    hot_folder=None,
    lab=None,
    *,
    store=None,
    map_size: int = 16,
    resolution: int | None = None,
    leds: int | None = None,
    cameras: int | None = None,
    faults: Faults = Faults(),
    link=None,
    wired_leds: int | None = None,
    realtime: bool = False,
    seed: int = 0,
    workers: int = 2,
    cache=None,
    progress: bool = False,
    log=None,
    scene: DomeScene | None = None,
) -> PtyServer:
    """Build and start the emulated dome of ``subject_id`` (module docstring); returns the running server.

    Parameters
    ----------
    subject_id : str
        The subject: of the synthetic population, or of ``store`` (default
        :data:`facestats.core.conventions.DEFAULT_EMULATED_SUBJECT`, ``"S001"``, as ``facestats emulate``).
    hot_folder, lab : path-like, optional
        Where the cameras drop frames and where the lab's files are written (created;
        None: in a new temporary directory).  The server's ``hot_folder`` and ``lab`` say where.
    store : str or path-like, optional
        None for the synthetic population (at ``map_size``), a store path or ``"default"`` for a store subject.
    map_size : int
        Map side of a synthetic subject (>= 8).
    resolution, leds, cameras : int, optional
        A smaller rig (:func:`emulated_rig`).
    faults : Faults
        Faults injected into the replies.
    link : path-like, optional
        A symlink kept pointing at the pty (absent, or a symlink: it is replaced).
    wired_leds : int, optional
        A mis-wired controller: it reports and drives that many LEDs (>= 1).
    realtime : bool
        Answer triggers only after the exposure time.
    seed : int
        Seed of the frames' noise (>= 0).
    workers : int
        Threads rendering frames (>= 1).
    cache : path-like, optional
        Where the cameras' pixel maps are kept between runs.
    progress : bool
        Progress bars while the scene is built.
    log : callable, optional
        Receives one line per fault and event.
    scene : DomeScene, optional
        A scene built before (``server.scene`` of an earlier emulator), reused instead of the subject and rig
        arguments.

    Returns
    -------
    PtyServer
        Started; ``stop()`` ends it.

    Raises
    ------
    ValidationError
        An argument out of its domain (before anything is created).
    """
    _check_common(hot_folder, lab, map_size, faults, link, seed, cache)
    if wired_leds is not None:
        check_integer(wired_leds, "wired_leds", 1)
    workers = check_integer(workers, "workers", 1)
    rig = emulated_rig(resolution, leds, cameras) if scene is None else None  # cheap: a copy of the default dome
    truth = subject_truth(subject_id, store=store, map_size=map_size) if scene is None else None
    with _folders("dome", hot_folder, lab) as (hot_folder, lab):
        if scene is None:
            scene = DomeScene(truth, rig, lab, seed=seed, progress=progress, cache=cache)
        dome = scene.dome
        for f in (scene.mesh, scene.regions):  # the scanner's mesh, when the scene was made in another lab
            if f.parent.resolve() != lab.resolve():
                shutil.copyfile(f, lab / f.name)
        scene.calibration().save(lab / "dome.json")
        _write_subject(lab, scene.truth)
        writer = HotFolderWriter(EmulatedCameras(scene, workers=workers), hot_folder, log=log)
        device = DomeDevice(
            dome.n_leds,
            dome.n_cameras,
            dome.exposure_times,
            bits=scene.camera.bits,
            wired_leds=wired_leds,
            on_trigger=writer.submit,
        )
        return _start(PtyServer(device, faults, link=link, realtime=realtime, log=log), scene, writer, hot_folder, lab)


def _start(server, scene, writer, hot_folder, lab) -> PtyServer:
    """``server`` started with its scene, writer and folders as attributes; the writer closed if it cannot start."""
    server.closers.append(writer.close)
    server.scene, server.writer, server.hot_folder, server.lab = scene, writer, hot_folder, lab
    try:
        return server.start()
    except BaseException:
        writer.close()
        raise


def emulated_sensor(
    subject_id: str = DEFAULT_EMULATED_SUBJECT,
    hot_folder=None,
    lab=None,
    *,
    store=None,
    map_size: int = 16,
    faults: Faults = Faults(),
    link=None,
    realtime: bool = False,
    seed: int = 0,
    log=None,
) -> PtyServer:
    """Build and start the emulated contact sensor on ``subject_id``'s three sites; returns the running server.

    The arguments are checked before any work (module docstring).  Writes ``sensor-calibration.json`` and
    ``subject.json`` into ``lab``.

    Parameters
    ----------
    subject_id, hot_folder, lab, store, map_size, faults, link, realtime, seed, log
        As :func:`emulated_dome`.

    Returns
    -------
    PtyServer
        Started; ``stop()`` ends it.

    Raises
    ------
    ValidationError
        An argument out of its domain (before anything is created).
    """

    _check_common(hot_folder, lab, map_size, faults, link, seed)
    truth = subject_truth(subject_id, store=store, map_size=map_size)
    with _folders("sensor", hot_folder, lab) as (hot_folder, lab):
        scene = SensorScene.of(truth, seed=seed)
        save_sensor_calibration(lab / "sensor-calibration.json", scene.sensor, scene.layout)
        _write_subject(lab, truth)
        writer = HotFolderWriter(EmulatedCameras(scene, workers=1, model="emulated sensor camera"), hot_folder, log=log)
        device = SensorDevice(
            scene.sensor.n_fibers, scene.sensor.exposure_times, scene.layout.size, on_trigger=writer.submit
        )
        return _start(PtyServer(device, faults, link=link, realtime=realtime, log=log), scene, writer, hot_folder, lab)
