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
"""

from __future__ import annotations

import json
import pathlib
import shutil

import numpy as np

from facestats.acquire.devices.cameras import EmulatedCameras, HotFolderWriter
from facestats.acquire.devices.emulator import DomeDevice, Faults, PtyServer, SensorDevice
from facestats.acquire.devices.scene import DomeScene, SensorScene, subject_truth
from facestats.acquire.devices.sensor import save_sensor_calibration
from facestats.acquire.dome import default_dome
from facestats.core.validate import check_integer
from facestats.errors import DeviceError

__all__ = ["emulated_rig", "emulated_dome", "emulated_sensor"]


def emulated_rig(resolution: int | None = None, leds: int | None = None, cameras: int | None = None):
    """The simulator's dome (:func:`facestats.acquire.dome.default_dome`), optionally smaller for quick runs.

    ``leds`` and ``cameras`` keep that many, evenly spread over the rig's
    indices; ``resolution`` resamples every camera to ``resolution``² pixels
    (default: the rig's 1024²).
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


def _write_subject(lab: pathlib.Path, truth):
    (lab / "subject.json").write_text(json.dumps(truth.metadata(), indent=1))


def emulated_dome(
    subject_id: str,
    hot_folder,
    lab,
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

    ``store``: None for the synthetic population (at ``map_size``), a store path
    or ``"default"`` for a store subject.  ``wired_leds`` makes a mis-wired
    controller (it reports and drives that many LEDs).  ``cache``: where the
    cameras' pixel maps are kept between runs.  ``scene``: a scene built before
    (``server.scene`` of an earlier emulator), reused instead of the subject and rig arguments.
    """
    lab = _directory(lab, "lab directory")
    _directory(hot_folder, "hot folder")
    if scene is None:
        truth = subject_truth(subject_id, store=store, map_size=map_size)
        scene = DomeScene(
            truth, emulated_rig(resolution, leds, cameras), lab, seed=seed, progress=progress, cache=cache
        )
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
    server = PtyServer(device, faults, link=link, realtime=realtime, log=log)
    server.closers.append(writer.close)
    server.scene, server.writer = scene, writer
    return server.start()


def emulated_sensor(
    subject_id: str,
    hot_folder,
    lab,
    *,
    store=None,
    map_size: int = 16,
    faults: Faults = Faults(),
    link=None,
    realtime: bool = False,
    seed: int = 0,
    log=None,
) -> PtyServer:
    """Build and start the emulated contact sensor on ``subject_id``'s three sites; returns the running server."""

    lab = _directory(lab, "lab directory")
    _directory(hot_folder, "hot folder")
    truth = subject_truth(subject_id, store=store, map_size=map_size)
    scene = SensorScene.of(truth, seed=seed)
    save_sensor_calibration(lab / "sensor-calibration.json", scene.sensor, scene.layout)
    _write_subject(lab, truth)
    writer = HotFolderWriter(EmulatedCameras(scene, workers=1, model="emulated sensor camera"), hot_folder, log=log)
    device = SensorDevice(
        scene.sensor.n_fibers, scene.sensor.exposure_times, scene.layout.size, on_trigger=writer.submit
    )
    server = PtyServer(device, faults, link=link, realtime=realtime, log=log)
    server.closers.append(writer.close)
    server.scene, server.writer = scene, writer
    return server.start()
