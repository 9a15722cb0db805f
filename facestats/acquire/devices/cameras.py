"""Cameras behind one small interface: emulated cameras, and a hot folder that vendor software fills.

A :class:`CameraBackend` delivers the frames of one trigger (:class:`Trigger`, the
device's report of the light state the cameras exposed under) as :class:`Frame`
objects: the encoded file's bytes and their SHA-256.  Two backends:

* :class:`EmulatedCameras` renders the frames from a scene
  (:mod:`facestats.acquire.devices.scene`) for the LED, exposure and drive the
  trigger reports, encoded as the simulator encodes photographs
  (:func:`facestats.acquire.synthetic.photographs.encode_frame`: 16-bit PNG with the
  exposure time in EXIF).
* :class:`HotFolderCameras` waits for the files that a camera vendor's software
  drops into a directory, one per camera and trigger, named by ``pattern``
  (default ``cam{camera:02d}/{frame:012d}.png``): each file is awaited with a
  timeout, then checked against its sidecar ``<file>.sha256`` (``"<hex digest>
  <size in bytes>"``) when there is one, or else read once its size has stopped
  changing, and a PNG's header is checked against the calibration's image size.
  Files are removed once the session has stored them (:meth:`CameraBackend.release`).

:class:`HotFolderWriter` is the other side of a hot folder: it writes an
emulated camera system's frames the way vendor software would (sidecar first,
then the image by an atomic rename), on a pool of threads so that frames are
encoded while the device goes on with the sequence.
"""

from __future__ import annotations

import hashlib
import os
import pathlib
import re
import stat
import struct
import threading
import time
from abc import ABC, abstractmethod
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

from facestats.errors import DeviceError, DeviceTimeout

__all__ = ["Trigger", "Frame", "CameraBackend", "EmulatedCameras", "HotFolderCameras", "HotFolderWriter"]

DEFAULT_PATTERN = "cam{camera:02d}/{frame:012d}{ext}"


#: A field value of a device reply: a plain decimal integer.
_DECIMAL = re.compile(r"-?[0-9]{1,18}")


@dataclass(frozen=True)
class Trigger:
    """A device's report of one trigger: the frame id and the state the cameras exposed under.

    Dome triggers use ``led``, ``exposure``, ``brightness``, ``colour`` and ``lines``; sensor triggers use
    ``exposure``, ``lamp``, ``shutter`` and ``site``.

    Attributes
    ----------
    frame : int
        The frame id the host sent with ``tr``.
    led : int
        Dome: the LED lit (−1: none lit).
    exposure : int
        Dome: index of the calibration's exposure times; sensor: index in the bracket.
    brightness : int
        Dome: LED brightness, 0-255.
    colour : tuple of int
        Dome: LED colour (R, G, B), each 0-255.
    lamp, shutter : int
        Sensor: source lamp on (1) or off (0), shutter open (1) or closed (0).
    site : int
        Sensor: index of :data:`facestats.core.conventions.SITES`.
    lines : int
        Dome: bit c set: camera c's trigger line pulsed; −1: every line.
    """

    frame: int
    led: int = -1
    exposure: int = 0
    brightness: int = 255
    colour: tuple = (255, 255, 255)
    lamp: int = 0
    shutter: int = 0
    site: int = 0
    lines: int = -1

    def fires(self, camera: int) -> bool:
        """True if ``camera``'s trigger line was pulsed.

        Parameters
        ----------
        camera : int
            0-based camera index (bit of ``lines``).

        Returns
        -------
        bool
            True also when ``lines`` is negative (every line pulsed).
        """
        return self.lines < 0 or bool(self.lines >> int(camera) & 1)

    @classmethod
    def from_fields(cls, fields: dict, required=("frame",), frame: int | None = None) -> "Trigger":
        """The trigger of a ``tr`` reply's payload (``frame=… led=… exposure=…``).

        Parameters
        ----------
        fields : dict
            The reply's ``key=value`` fields (:meth:`~facestats.acquire.devices.protocol.Reply.fields`).
        required : sequence of str
            Fields the device must report (a missing one would take its default here, and a plan's state check
            would compare against the default, not against what the device did).
        frame : int, optional
            The frame id the host asked for: a reply naming another (firmware with a stale frame register) would
            file this exposure's pictures under another trigger's id.

        Returns
        -------
        Trigger
            The trigger the payload names.

        Raises
        ------
        DeviceError
            A required field missing, a value that is not a plain decimal integer (``int`` also takes ``0_2``
            and `` 2``), or another frame id.
        """
        missing = [k for k in required if k not in fields]
        if missing:
            raise DeviceError(f"trigger reply without the field(s) {missing}: {fields!r:.160}")
        kw = {}
        for k in ("frame", "led", "exposure", "brightness", "lamp", "shutter", "site", "lines", "colour"):
            if k not in fields:
                continue
            parts = fields[k].split(",") if k == "colour" else [fields[k]]
            if not all(_DECIMAL.fullmatch(v) for v in parts) or (k == "colour") != (len(parts) == 3):
                raise DeviceError(f"trigger reply with a malformed field {k}={fields[k]!r}: {fields!r:.160}")
            kw[k] = tuple(int(v) for v in parts) if k == "colour" else int(parts[0])
        if frame is not None and kw["frame"] != frame:
            raise DeviceError(
                f"trigger reply for frame {kw['frame']}, the host asked for frame {frame}: its pictures would be "
                "filed under another trigger"
            )
        return cls(**kw)


@dataclass(frozen=True)
class Frame:
    """One camera's picture of a trigger: file bytes, their SHA-256, the exposure time (s), the file's extension.

    Attributes
    ----------
    camera : int
        0-based camera index.
    data : bytes
        The encoded file's bytes.
    sha256 : str
        Hex SHA-256 of ``data``.
    exposure_s : float
        Exposure time, s (NaN for a hot folder's frame: the backend does not know it).
    extension : str
        The file's extension with its dot.
    path : pathlib.Path or None
        The file the bytes were read from (a hot folder's), if any.
    """

    camera: int
    data: bytes
    sha256: str
    exposure_s: float
    extension: str = ".png"
    path: pathlib.Path | None = None


class CameraBackend(ABC):
    """The frames of each trigger, from real or emulated cameras (module docstring)."""

    cameras: tuple = ()

    def prepare(self):
        """Get ready for a session (called once before the first trigger)."""

    @abstractmethod
    def collect(self, trigger: Trigger, timeout: float) -> list:
        """The :class:`Frame` of every camera for ``trigger``, waiting at most ``timeout`` s per frame.

        Parameters
        ----------
        trigger : Trigger
            The device's report of the trigger; only the cameras it fires (:meth:`Trigger.fires`) deliver.
        timeout : float
            Seconds to wait for each frame.

        Returns
        -------
        list of Frame
            One per camera of :attr:`cameras` that ``trigger`` fires, in the order of :attr:`cameras`.
        """

    def release(self, trigger: Trigger):
        """Forget the frames of ``trigger`` (stored, or taken under a wrong state).

        Parameters
        ----------
        trigger : Trigger
            The trigger whose frames to forget (a no-op here; a hot folder removes its files).
        """

    def close(self):
        """Release the backend's resources."""


class EmulatedCameras(CameraBackend):
    """Frames rendered from a scene (``scene.render(camera, trigger) -> (codes, exposure_s)``, ``scene.cameras``).

    Parameters
    ----------
    scene : DomeScene or SensorScene
        What the cameras see (:mod:`facestats.acquire.devices.scene`); its ``cameras`` are the cameras.
    extension : str
        File type of the encoded frames (:func:`~facestats.acquire.synthetic.photographs.encode_frame`).
    workers : int
        Threads that encode the cameras' frames of a trigger in parallel (noise generation and PNG encoding
        release the GIL); at least 1.
    model : str
        EXIF ``Model`` of the frames.
    """

    def __init__(self, scene, *, extension: str = ".png", workers: int = 2, model: str = "emulated camera"):
        self.scene, self.extension, self.model = scene, extension, model
        self.cameras = tuple(scene.cameras)
        self.workers = max(1, int(workers))
        self._pool = ThreadPoolExecutor(self.workers)

    def frame(self, camera: int, trigger: Trigger) -> Frame:
        """The encoded frame ``camera`` takes for ``trigger``, rendered from the emulated scene.

        Parameters
        ----------
        camera : int
            0-based camera index.
        trigger : Trigger
            The state the frame is taken under.

        Returns
        -------
        Frame
            The encoded bytes, their SHA-256 and the exposure time the scene reports (no ``path``).
        """
        # local import: keeps numpy out of this module's import
        from facestats.acquire.synthetic.photographs import encode_frame

        codes, t = self.scene.render(camera, trigger)
        data = encode_frame(codes, t, self.extension, model=self.model)
        return Frame(camera, data, hashlib.sha256(data).hexdigest(), t, self.extension)

    def collect(self, trigger: Trigger, timeout: float = 0.0) -> list:
        """The rendered :class:`Frame` of every camera ``trigger`` fires, encoded on the thread pool.

        Parameters
        ----------
        trigger : Trigger
            The state the frames are taken under.
        timeout : float
            Unused: rendered frames do not wait.

        Returns
        -------
        list of Frame
            In the order of :attr:`cameras`.
        """
        return list(self._pool.map(lambda c: self.frame(c, trigger), [c for c in self.cameras if trigger.fires(c)]))

    def close(self):
        self._pool.shutdown()


def _size(path):
    """The size of ``path`` in bytes, None while it does not exist.

    Raises :class:`DeviceError` for anything but a regular file (a link, which could lead out of the hot folder or
    to ``/dev/zero``; a FIFO, which would block the read; a folder): camera software writes files.
    """
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return None
    if not stat.S_ISREG(st.st_mode):
        raise DeviceError(
            f"frame {path} in the hot folder is not a regular file (a link, FIFO, device or folder): camera software "
            "writes plain files; remove it and rerun with --resume"
        )
    return st.st_size


#: The first 8 bytes of every PNG file (PNG spec §5.2).
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: The last 12 bytes of every complete PNG file: the IEND chunk (PNG spec §11.2.5) with its CRC.
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def _complete(data: bytes) -> bool:
    """False for a PNG without its IEND chunk at the end (still being written).

    Only PNG is judged: a JPEG may carry data after its EOI marker (phones append trailers and motion clips) and holds
    EOI markers inside (its EXIF thumbnail), so its end says nothing; other formats need a sidecar to be safe.
    """
    return data.endswith(_PNG_END) if data[:8] == _PNG_SIGNATURE else True


def _png_size(data: bytes):
    """(width, height) from a PNG's IHDR chunk, or None for other formats."""
    if data[:8] == _PNG_SIGNATURE and data[12:16] == b"IHDR":
        return struct.unpack(">II", data[16:24])
    return None


class HotFolderCameras(CameraBackend):
    """Frames that vendor software writes into ``folder`` (module docstring).

    Parameters
    ----------
    folder : path-like
        The hot folder (must exist).
    cameras : sequence of int
        The cameras to expect a file from on every trigger.
    pattern : str
        File name of a frame relative to ``folder``, with ``{camera}``, ``{frame}`` and ``{ext}``.
    extension : str
        ``{ext}`` of the pattern.
    sizes : dict, optional
        Expected (width, height) of each camera's frames (checked for PNG files).
    settle : float
        Without a sidecar, a file is read when its size has not changed for this long, s.
    require_checksum : bool
        Wait for every frame's sidecar (vendor software that always writes one);
        otherwise a frame without a sidecar is read once its size has settled.
    """

    def __init__(
        self,
        folder,
        cameras,
        *,
        pattern=DEFAULT_PATTERN,
        extension=".png",
        sizes=None,
        settle=0.05,
        require_checksum=False,
    ):
        self.folder = pathlib.Path(folder)
        self.cameras = tuple(int(c) for c in cameras)
        self.pattern, self.extension = pattern, extension
        self.sizes = dict(sizes or {})
        self.settle = float(settle)
        self.require_checksum = bool(require_checksum)
        try:
            first = pattern.format(camera=0, frame=0, ext=extension)
            same_frame = first == pattern.format(camera=0, frame=1, ext=extension)
            same_camera = len(self.cameras) > 1 and first == pattern.format(camera=1, frame=0, ext=extension)
        except (KeyError, IndexError, ValueError, AttributeError) as exc:
            raise DeviceError(f"hot-folder pattern {pattern!r} is invalid ({exc}); use {{camera}}, {{frame}}, {{ext}}")
        if same_frame or same_camera:  # every frame would be looked for under one name
            missing = "{frame}" if same_frame else "{camera}"
            raise DeviceError(f"hot-folder pattern {pattern!r} must name each frame's file apart: it lacks {missing}")
        # local import: keeps numpy out of this module's import
        from facestats.acquire.photographs import relative_inside

        if not relative_inside(first):  # frames are taken (and released: deleted) only inside the hot folder
            raise DeviceError(
                f"hot-folder pattern {pattern!r} must name a file inside the hot folder (a relative path without "
                f"'..', as in a manifest), got {first!r}"
            )

    def path(self, camera: int, frame: int) -> pathlib.Path:
        """The file the camera writes for ``frame``, by the folder's name pattern.

        Parameters
        ----------
        camera : int
            0-based camera index.
        frame : int
            The trigger's frame id.

        Returns
        -------
        pathlib.Path
            ``folder`` joined with ``pattern`` formatted with ``camera``, ``frame`` and the extension.
        """
        return self.folder / self.pattern.format(camera=camera, frame=frame, ext=self.extension)

    def stray_frames(self) -> list:
        """Frame files in the hot folder that the pattern names, of any camera and frame id, sorted.

        Every frame a run collects is moved out of the hot folder (:meth:`release` removes what is left of a
        step), and frame ids never repeat across runs, so after a run these are frames of triggers that no run
        collected: those an interrupted run triggered and then stopped waiting for (they arrive after it).
        """
        import glob
        import string

        parts = []
        for literal, field, _, _ in string.Formatter().parse(self.pattern):
            parts.append(glob.escape(literal))
            if field == "ext":
                parts.append(glob.escape(self.extension))
            elif field is not None:
                parts.append("*")
        return sorted(p for p in self.folder.glob("".join(parts)) if p.is_file())

    def prepare(self):
        if not self.folder.is_dir():
            what = "is not a folder" if self.folder.exists() else "does not exist"  # a file given for the folder
            raise DeviceError(
                f"hot folder {self.folder} {what}: point --hot-folder at the directory the camera software "
                "(or `facestats emulate`) writes frames into"
            )

    def collect(self, trigger: Trigger, timeout: float) -> list:
        """Wait for and read the frame file of every camera ``trigger`` fires (module docstring).

        Parameters
        ----------
        trigger : Trigger
            The trigger whose frames (by its frame id) to collect.
        timeout : float
            Seconds to wait for each camera's file.

        Returns
        -------
        list of Frame
            In the order of :attr:`cameras`; each with its ``path`` and ``exposure_s`` NaN.

        Raises
        ------
        DeviceTimeout
            A file did not arrive within ``timeout``.
        DeviceError
            A file that is not a regular file, cannot be read, disagrees with its sidecar, or (PNG) has another
            size than the calibration's.
        """
        return [self._wait(c, trigger.frame, timeout) for c in self.cameras if trigger.fires(c)]

    def _wait(self, camera, frame, timeout):
        p = self.path(camera, frame)
        side = p.with_name(p.name + ".sha256")
        deadline = time.monotonic() + timeout
        pause, last = 0.001, None
        while True:
            size = _size(p)
            try:
                if size is not None and side.exists():
                    return self._checked(camera, p, side)
                if size is not None and size == last and not self.require_checksum:
                    frame = self._checked(camera, p, None)
                    if frame is not None:
                        return frame
            except (OSError, ValueError) as exc:  # the file went away or its sidecar is unreadable
                raise DeviceError(f"frame {p} could not be read from the hot folder: {exc}") from None
            if time.monotonic() > deadline:
                raise DeviceTimeout(
                    f"camera {camera} delivered no frame {p.name} into {p.parent} within {timeout:g} s: check that "
                    "the camera software is running and writing there (--hot-folder), or raise --frame-timeout"
                )
            last = size
            time.sleep(pause if size is None else max(pause, self.settle))
            pause = min(2 * pause, 0.02)

    def _checked(self, camera, p, side):
        """The frame in ``p`` after its checks; None if it has no sidecar and is still being written."""
        # local import: keeps numpy (facestats.io) out of this module's import
        from facestats.io.layout import read_regular_file

        data = read_regular_file(p, follow_links=False)  # checked by _size; a link put in its place is refused
        if side is None and not _complete(data):  # a writer that paused longer than ``settle``
            return None
        digest = hashlib.sha256(data).hexdigest()
        if side is not None:
            want = side.read_text().split()
            if len(want) != 2 or want[0] != digest or int(want[1]) != len(data):
                raise DeviceError(
                    f"frame {p} does not match its checksum file {side.name} ({len(data)} bytes, sha256 "
                    f"{digest[:12]}…, expected {' '.join(want)[:40]}): the transfer was corrupted; rerun with --resume "
                    "to take it again"
                )
        size = _png_size(data)
        want_size = self.sizes.get(camera)
        if size is not None and want_size is not None and tuple(size) != tuple(want_size):
            raise DeviceError(
                f"frame {p} is {size[0]}×{size[1]} pixels, the calibration's camera {camera} is "
                f"{want_size[0]}×{want_size[1]}: is the camera software set to the calibrated resolution?"
            )
        return Frame(camera, data, digest, float("nan"), p.suffix, p)

    def release(self, trigger: Trigger):
        """Remove the frame files of ``trigger`` and their sidecars from the hot folder (those still there).

        Parameters
        ----------
        trigger : Trigger
            The trigger whose files (by its frame id, every camera) to remove.
        """
        for c in self.cameras:
            p = self.path(c, trigger.frame)
            for q in (p.with_name(p.name + ".sha256"), p):
                try:
                    q.unlink()
                except FileNotFoundError:
                    pass


class HotFolderWriter:
    """Vendor software for emulated cameras: writes each trigger's frames into a hot folder (module docstring).

    ``submit`` returns at once; every frame is rendered, encoded and written by one
    task on a pool of ``workers`` threads (frames of consecutive triggers overlap).
    At most ``depth`` triggers are in progress; beyond that ``submit`` waits, as a
    camera that is not ready yet.

    Parameters
    ----------
    cameras : EmulatedCameras
        Renders the frames; its ``workers`` size the writing pool.
    folder : path-like
        The hot folder (created).
    pattern : str
        File name of a frame relative to ``folder``, with ``{camera}``, ``{frame}`` and ``{ext}``.
    depth : int
        Triggers in progress at most (at least 1).
    log : callable, optional
        Receives one line per frame that failed (which is then not written).
    """

    def __init__(self, cameras: EmulatedCameras, folder, *, pattern=DEFAULT_PATTERN, depth: int = 2, log=None):
        self.cameras, self.pattern = cameras, pattern
        self.folder = pathlib.Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self._slots = threading.BoundedSemaphore(max(1, int(depth)))
        self._pool = ThreadPoolExecutor(cameras.workers)
        self._lock = threading.Lock()
        self._left = {}
        self.log = log or (lambda line: None)
        self.written = 0

    def submit(self, trigger: Trigger):
        """Write the frames of the cameras ``trigger`` fires into the hot folder (in the background).

        Parameters
        ----------
        trigger : Trigger
            The state to render the frames under; its frame id names the files.
        """
        cams = [c for c in self.cameras.cameras if trigger.fires(c)]
        if not cams:
            return
        self._slots.acquire()
        with self._lock:
            self._left[trigger.frame] = len(cams)
        for c in cams:
            self._pool.submit(self._write, trigger, c)

    def _write(self, trigger, camera):
        try:
            frame = self.cameras.frame(camera, trigger)
            p = self.folder / self.pattern.format(camera=camera, frame=trigger.frame, ext=frame.extension)
            p.parent.mkdir(parents=True, exist_ok=True)
            side = p.with_name(p.name + ".sha256")
            tmp = p.with_name(p.name + ".part")
            side.write_text(f"{frame.sha256} {len(frame.data)}\n")
            tmp.write_bytes(frame.data)
            os.replace(tmp, p)
            with self._lock:
                self.written += 1
        except Exception as exc:  # a camera system that fails writes nothing; the host times out and says so
            self.log(f"camera {camera} failed on frame {trigger.frame}: {exc}")
        finally:
            with self._lock:
                self._left[trigger.frame] -= 1
                done = not self._left[trigger.frame]
                if done:
                    del self._left[trigger.frame]
            if done:
                self._slots.release()

    def close(self):
        """Wait for the frames being written, then close the cameras."""
        self._pool.shutdown(wait=True)
        self.cameras.close()
