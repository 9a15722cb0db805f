"""Emulated dome and contact-sensor controllers on a pseudo-terminal, with fault injection.

:class:`DomeDevice` and :class:`SensorDevice` are the controllers' firmware as
state machines: they parse request lines, answer with frames
(:mod:`facestats.acquire.devices.protocol`; commands in
:mod:`facestats.acquire.devices.dome` and :mod:`facestats.acquire.devices.sensor`),
answer a repeated request id from their stored frame, and on ``tr`` hand a
:class:`~facestats.acquire.devices.cameras.Trigger` to their camera system (the
emulated cameras writing into a hot folder).

:class:`PtyServer` connects a device to a pseudo-terminal (``os.openpty``): the
client opens the slave's path (``/dev/pts/N``, or a stable symlink ``link`` that
follows reconnections) with pyserial like any serial port.  It injects the faults
of :class:`Faults`, drawn from a seeded generator so a faulty run can be repeated:

* ``drop``, ``garble``, ``truncate``, ``duplicate``: fractions of the reply frames
  that are not sent, sent with one byte changed, sent cut short, or sent twice;
* ``stall``: fraction of the commands before which the device freezes for
  ``stall_s`` seconds (requests queue up; the host's retries then meet late and
  duplicated answers);
* ``disconnect_after``: command counts after which the line drops (the pty is
  closed and a new one opened ``reconnect_delay`` s later; the device keeps its state);
* ``reboot_after``: command counts at which the device reboots instead of
  answering: the command is lost, the state reset, the sequence numbers restart
  and a ``BOOT`` frame is sent.

A watchdog switches the lights off after ``watchdog_s`` seconds without a command
(a crashed or killed host leaves no LED burning).  With ``realtime`` the device
answers a trigger only after the exposure time.
"""

from __future__ import annotations

import abc
import os
import re
import select
import threading
import time
import tty
from dataclasses import dataclass

import numpy as np

from facestats.acquire.devices.cameras import Trigger
from facestats.acquire.devices.protocol import MAX_LINE, TERMINATOR, ProtocolViolation, Reply, parse_request, quoted
from facestats.core.validate import as_finite, check_integer
from facestats.errors import DeviceError, ValidationError

__all__ = ["EmulatedDevice", "DomeDevice", "SensorDevice", "Faults", "PtyServer"]

VERSION = "1.0"


class _Refused(Exception):
    def __init__(self, code, message):
        super().__init__(message)
        self.code = code


def _clean(text: str) -> str:
    """Text fit for a frame's payload: printable ASCII without '@' or '*'."""
    return re.sub(r"[^ -)+-?A-~]", "_", text)


def _request_id(line: bytes) -> int:
    m = re.search(rb" #(\d{1,10})", line)
    return int(m.group(1)) % 2**31 if m else 0


class EmulatedDevice(abc.ABC):
    """Firmware shared by the emulated controllers: framing, the request-id cache, ``? ver st x reboot``.

    A device (:class:`DomeDevice`, :class:`SensorDevice`) supplies :meth:`status` and :meth:`_off`.

    Parameters
    ----------
    on_trigger : callable, optional
        Receives the :class:`~facestats.acquire.devices.cameras.Trigger` of each ``tr`` command (the camera
        system).
    """

    kind = ""

    def __init__(self, *, on_trigger=None):
        self.on_trigger = on_trigger
        self.commands = {
            "?": (self._help, (0,), "list the commands"),
            "ver": (lambda: self.identity, (0,), "identity and protocol version"),
            "st": (self.status, (0,), "status as key=value words"),
            "x": (self._off, (0,), "every light off"),
            "reboot": (self._reboot, (0,), "restart (state lost, BOOT frame follows)"),
        }
        self.commands.update(self.own_commands())
        self.busy_s = 0.0
        self.boot()

    @property
    def identity(self) -> str:
        return f"facestats-{self.kind} emulator {VERSION} protocol=1"

    def own_commands(self) -> dict:
        """The device's commands beyond the common ones: name → (handler, argument counts, help)."""
        return {}

    def reset(self):
        """Power-up state."""

    def idle(self):
        """What the watchdog does after a long silence: lights off."""
        self._off()

    @abc.abstractmethod
    def status(self) -> str:
        """The ``st`` reply: the device's state as ``key=value`` words."""

    def boot(self) -> bytes:
        """Power up: state reset, sequence numbers restart, the ``BOOT`` frame."""
        self.seq, self._last_id, self._last_frame = 0, 0, b""
        self.reboot_requested = False
        self.reset()
        return self._frame(0, "BOOT", self.identity)

    def _frame(self, rid, status, payload="") -> bytes:
        self.seq += 1
        return Reply(self.seq, rid, status, _clean(payload)).encode()

    def handle(self, line: bytes):
        """The frame answering one request line (None for an empty line).

        Parameters
        ----------
        line : bytes
            One request line without its LF (:func:`~facestats.acquire.devices.protocol.parse_request`).

        Returns
        -------
        bytes or None
            The encoded reply frame: ``OK`` with the command's payload, or ``Enn`` with the refusal; for a
            repeated request id the stored frame of its first execution.
        """
        if not line.strip():
            return None
        self.busy_s = 0.0
        try:
            req = parse_request(line)
        except ProtocolViolation as exc:
            return self._frame(_request_id(line), f"E{exc.code:02d}", str(exc))
        if req.id and req.id == self._last_id:
            return self._last_frame
        entry = self.commands.get(req.name)
        if entry is None:
            frame = self._frame(req.id, "E01", f"unknown command {req.name} (? lists the commands)")
        elif len(req.args) not in entry[1]:
            frame = self._frame(req.id, "E03", f"{req.name} takes {entry[1]} argument(s), got {len(req.args)}")
        else:
            try:
                frame = self._frame(req.id, "OK", entry[0](*req.args) or "")
            except _Refused as exc:
                frame = self._frame(req.id, f"E{exc.code:02d}", str(exc))
        if req.id:
            self._last_id, self._last_frame = req.id, frame
        return frame

    def _help(self):
        return " ".join(sorted(self.commands))

    @abc.abstractmethod
    def _off(self):
        """The ``x`` command: every light off."""

    def _reboot(self):
        self.reboot_requested = True
        return "rebooting"

    @staticmethod
    def _index(value, n, what):
        if not 0 <= value < n:
            raise _Refused(4, f"{what} {value} out of range 0..{n - 1}")
        return value


class DomeDevice(EmulatedDevice):
    """The dome controller's firmware (commands: :mod:`facestats.acquire.devices.dome`).

    Parameters
    ----------
    n_leds, n_cameras : int
    exposure_s : sequence of float
        The cameras' exposure settings, s.
    bits : int
        Code depth of the cameras' frames.
    frame_interval_s : float
        Shortest time between triggers (the cameras' frame rate; Weyrich §5: 25 s for 300 triggers).
    wired_leds : int, optional
        The LED count the controller reports and drives (a mis-wired controller); default ``n_leds``.
    on_trigger : callable, optional
        Receives each :class:`Trigger` (the camera system).
    """

    kind = "dome"

    def __init__(
        self, n_leds, n_cameras, exposure_s, *, bits=12, frame_interval_s=1 / 12, wired_leds=None, on_trigger=None
    ):
        self.n_leds = check_integer(n_leds, "n_leds", 1)
        self.n_cameras = check_integer(n_cameras, "n_cameras", 1)
        self.exposure_s = tuple(float(t) for t in as_finite(exposure_s, "exposure_s", 0, None, low_inclusive=False))
        self.bits = check_integer(bits, "bits", 8, 16)
        self.frame_interval_s = float(frame_interval_s)
        self.wired = self.n_leds if wired_leds is None else check_integer(wired_leds, "wired_leds", 1)
        super().__init__(on_trigger=on_trigger)

    def own_commands(self):
        """The dome's commands: name → (handler, argument counts, help)."""
        return {
            "l": (self._light, (1,), "light LED i alone"),
            "sb": (self._brightness, (1,), "brightness 0-255"),
            "sc": (self._colour, (3,), "colour r.g.b 0-255"),
            "se": (self._exposure, (1,), "exposure setting k"),
            "tm": (self._mask, (1,), "trigger lines to pulse: bit c for camera c"),
            "tr": (self._trigger, (1,), "pulse the trigger lines: frame id"),
        }

    def reset(self):
        self.led, self.exposure, self.brightness, self.colour = -1, 0, 255, (255, 255, 255)
        self.lines = (1 << self.n_cameras) - 1

    def status(self):
        us = ",".join(str(round(t * 1e6)) for t in self.exposure_s)
        return (
            f"leds={self.wired} cameras={self.n_cameras} exposures={len(self.exposure_s)} exposure_us={us} "
            f"bits={self.bits} frame_us={round(self.frame_interval_s * 1e6)} led={self.led} exposure={self.exposure} "
            f"brightness={self.brightness} colour={','.join(map(str, self.colour))} lines={self.lines}"
        )

    def _off(self):
        self.led = -1

    def _light(self, i):
        self.led = self._index(i, self.wired, "LED")
        return f"led={i}"

    def _brightness(self, v):
        self.brightness = self._index(v, 256, "brightness")
        return f"brightness={v}"

    def _colour(self, r, g, b):
        self.colour = tuple(self._index(v, 256, "colour") for v in (r, g, b))
        return f"colour={r},{g},{b}"

    def _exposure(self, k):
        self.exposure = self._index(k, len(self.exposure_s), "exposure setting")
        return f"exposure={k}"

    def _mask(self, mask):
        self.lines = self._index(mask, 1 << self.n_cameras, "trigger mask")
        return f"lines={mask}"

    def _trigger(self, frame):
        trig = Trigger(frame, self.led, self.exposure, self.brightness, self.colour, lines=self.lines)
        if self.on_trigger is not None:
            self.on_trigger(trig)
        self.busy_s = max(self.exposure_s[self.exposure], self.frame_interval_s)
        return (
            f"frame={frame} led={self.led} exposure={self.exposure} brightness={self.brightness} "
            f"colour={','.join(map(str, self.colour))} lines={self.lines}"
        )


class SensorDevice(EmulatedDevice):
    """The contact sensor's firmware (commands: :mod:`facestats.acquire.devices.sensor`).

    Parameters
    ----------
    n_fibers : int
    exposure_s : sequence of float
        The bracket's exposure times, s.
    image_size : (int, int)
        The sensor camera's frame (width, height).
    readout_s : float
        Time to read a frame out after its exposure (0.8 s makes the 23-image bracket take the paper's ~88 s).
    on_trigger : callable, optional
    """

    kind = "sensor"

    def __init__(self, n_fibers, exposure_s, image_size, *, readout_s=0.8, on_trigger=None):
        self.n_fibers = check_integer(n_fibers, "n_fibers", 1)
        self.exposure_s = tuple(float(t) for t in as_finite(exposure_s, "exposure_s", 0, None, low_inclusive=False))
        self.image_size = tuple(int(v) for v in image_size)
        self.readout_s = float(readout_s)
        super().__init__(on_trigger=on_trigger)

    def own_commands(self):
        """The contact sensor's commands: name → (handler, argument counts, help)."""
        return {
            "lamp": (self._lamp, (1,), "source lamp 0/1"),
            "sh": (self._shutter, (1,), "shutter 0/1"),
            "se": (self._exposure, (1,), "bracket exposure j"),
            "pos": (self._site, (1,), "placement label: 0 cheek, 1 forehead, 2 neck"),
            "tr": (self._trigger, (1,), "take a picture: frame id"),
        }

    def reset(self):
        self.lamp, self.shutter, self.exposure, self.site = 0, 0, 0, 0

    def status(self):
        us = ",".join(str(round(t * 1e6)) for t in self.exposure_s)
        return (
            f"fibers={self.n_fibers} exposures={len(self.exposure_s)} exposure_us={us} "
            f"image={self.image_size[0]}x{self.image_size[1]} lamp={self.lamp} shutter={self.shutter} "
            f"exposure={self.exposure} site={self.site}"
        )

    def _off(self):
        self.lamp, self.shutter = 0, 0

    def _lamp(self, v):
        self.lamp = self._index(v, 2, "lamp")
        return f"lamp={v}"

    def _shutter(self, v):
        self.shutter = self._index(v, 2, "shutter")
        return f"shutter={v}"

    def _exposure(self, j):
        self.exposure = self._index(j, len(self.exposure_s), "exposure")
        return f"exposure={j}"

    def _site(self, s):
        self.site = self._index(s, 3, "site")
        return f"site={s}"

    def _trigger(self, frame):
        trig = Trigger(frame, exposure=self.exposure, lamp=self.lamp, shutter=self.shutter, site=self.site)
        if self.on_trigger is not None:
            self.on_trigger(trig)
        self.busy_s = self.exposure_s[self.exposure] + self.readout_s
        return f"frame={frame} exposure={self.exposure} lamp={self.lamp} shutter={self.shutter} site={self.site}"


@dataclass(frozen=True)
class Faults:
    """Faults a :class:`PtyServer` injects (module docstring); fractions in [0, 1], counts of commands ≥ 1, seed ≥ 0.

    Attributes
    ----------
    drop, garble, truncate, duplicate : float
        Fractions of the reply frames not sent, sent with one byte changed, sent cut short, or sent twice; their
        sum at most 1.
    stall : float
        Fraction of the commands before which the device freezes.
    stall_s : float
        Length of a stall, s (≥ 0).
    disconnect_after : tuple of int
        Command counts after which the line drops.
    reboot_after : tuple of int
        Command counts at which the device reboots instead of answering.
    seed : int
        Seed of the generator that draws the faults.
    """

    drop: float = 0.0
    garble: float = 0.0
    truncate: float = 0.0
    duplicate: float = 0.0
    stall: float = 0.0
    stall_s: float = 1.5
    disconnect_after: tuple = ()
    reboot_after: tuple = ()
    seed: int = 0

    def __post_init__(self):
        for name in ("drop", "garble", "truncate", "duplicate", "stall"):
            as_finite(getattr(self, name), name, 0, 1)
        if self.drop + self.garble + self.truncate + self.duplicate > 1:
            raise ValidationError("drop + garble + truncate + duplicate must not exceed 1 (fractions of the replies)")
        as_finite(self.stall_s, "stall_s", 0, None, unit="s")
        for name in ("disconnect_after", "reboot_after"):
            for k in getattr(self, name):
                check_integer(k, name, 1)
        check_integer(self.seed, "seed", 0)  # of numpy.random.default_rng: a negative seed fails there

    @property
    def any(self) -> bool:
        return bool(self.drop or self.garble or self.truncate or self.duplicate or self.stall) or bool(
            self.disconnect_after or self.reboot_after
        )


class PtyServer:
    """A device on a pseudo-terminal (module docstring); ``start()`` serves it on a thread, ``stop()`` ends it.

    Parameters
    ----------
    device : EmulatedDevice
    faults : Faults
    link : path-like, optional
        A symlink kept pointing at the current pty (clients reconnect through it).
    realtime : bool
        Answer triggers only after the exposure (and frame interval / readout).
    reconnect_delay : float
        Seconds the line stays down after an injected disconnect.
    watchdog_s : float or None
        Lights off after this many seconds without a command.
    log : callable, optional
    """

    def __init__(
        self, device, faults=Faults(), *, link=None, realtime=False, reconnect_delay=0.3, watchdog_s=10.0, log=None
    ):
        self.device, self.faults = device, faults
        self.link = None if link is None else os.fspath(link)
        self.realtime, self.reconnect_delay, self.watchdog_s = bool(realtime), float(reconnect_delay), watchdog_s
        self.log = log or (lambda line: None)
        self.rng = np.random.default_rng(faults.seed)
        self.commands = 0
        self.injected = {
            "drop": 0,
            "garble": 0,
            "truncate": 0,
            "duplicate": 0,
            "stall": 0,
            "disconnect": 0,
            "reboot": 0,
        }
        self.closers = []
        self._stop = threading.Event()
        self._thread = None
        self._fds = None
        self._last_command = time.monotonic()

    # -- the pty ----------------------------------------------------------------------------------
    @property
    def port(self) -> str:
        """The path clients open: the link if there is one, else the current slave."""
        return self.link or self.slave_name

    def _open(self):
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._fds = (master, slave)
        self.slave_name = os.ttyname(slave)
        if self.link:
            tmp = f"{self.link}.{os.getpid()}.tmp"
            try:
                if os.path.lexists(tmp):
                    os.unlink(tmp)
                os.symlink(self.slave_name, tmp)
                os.replace(tmp, self.link)
            except OSError as exc:
                self._close()
                raise DeviceError(f"cannot create the link {self.link} to the pty: {exc.strerror}") from None

    def _close(self):
        if self._fds:
            for fd in self._fds:
                try:
                    os.close(fd)
                except OSError:
                    pass
            self._fds = None

    def start(self) -> "PtyServer":
        """Open the pseudo-terminal, send the boot banner and serve requests in a thread; return self."""
        self._open()
        self._send(self.device.boot())
        self._thread = threading.Thread(target=self._serve, name=f"facestats-{self.device.kind}-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self):
        """Stop serving, close the pseudo-terminal and remove its link."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        self._close()
        if self.link and os.path.islink(self.link):
            os.unlink(self.link)
        for close in self.closers:
            close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    # -- serving -----------------------------------------------------------------------------------
    def _serve(self):
        buf = b""
        while not self._stop.is_set():
            if self._fds is None:
                break
            master = self._fds[0]
            ready, _, _ = select.select([master], [], [], 0.05)
            if not ready:
                self._watchdog()
                continue
            try:
                data = os.read(master, 65536)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:  # no slave open at the moment
                time.sleep(0.01)
                continue
            buf += data
            while b"\n" in buf:
                line, _, buf = buf.partition(b"\n")
                self._on_line(line)
            if len(buf) > 4 * MAX_LINE:
                self._send(self.device.handle(buf[: MAX_LINE + 1]))
                buf = b""

    def _watchdog(self):
        if self.watchdog_s is not None and time.monotonic() - self._last_command > self.watchdog_s:
            self.device.idle()
            self._last_command = time.monotonic()

    def _on_line(self, line):
        if not line.strip():
            return
        self._last_command = time.monotonic()
        self.commands += 1
        n = self.commands
        if n in self.faults.reboot_after:
            self.injected["reboot"] += 1
            self.log(f"fault: reboot at command {n} ({quoted(line[:30])} lost)")
            self._send(self.device.boot())
            return
        if self.faults.stall and self.rng.random() < self.faults.stall:
            self.injected["stall"] += 1
            self.log(f"fault: stall of {self.faults.stall_s:g} s before command {n}")
            time.sleep(self.faults.stall_s)
        frame = self.device.handle(line)
        if frame is not None:
            if self.realtime and self.device.busy_s:
                time.sleep(self.device.busy_s)
            self._send_faulty(frame)
        if self.device.reboot_requested:
            self._send(self.device.boot())
        if n in self.faults.disconnect_after:
            self._disconnect(n)

    def _send_faulty(self, frame):
        f = self.faults
        u = self.rng.random()
        body = len(frame) - len(TERMINATOR)
        if u < f.drop:
            self.injected["drop"] += 1
            return
        u -= f.drop
        if u < f.garble:
            self.injected["garble"] += 1
            i = int(self.rng.integers(0, body))
            frame = frame[:i] + bytes([frame[i] ^ 0x01 if frame[i] != ord("\n") ^ 0x01 else 0x30]) + frame[i + 1 :]
        elif u < f.garble + f.truncate:
            self.injected["truncate"] += 1
            frame = frame[: int(self.rng.integers(1, body))]
        elif u < f.garble + f.truncate + f.duplicate:
            self.injected["duplicate"] += 1
            frame = frame + frame
        self._send(frame)

    def _send(self, data):
        if not data or self._fds is None:
            return
        master = self._fds[0]
        view = memoryview(data)
        deadline = time.monotonic() + 1.0
        while view:
            try:
                view = view[os.write(master, view) :]
            except BlockingIOError:
                if time.monotonic() > deadline:  # nobody reads: the line is dead, the frame is lost
                    return
                select.select([], [master], [], 0.05)
            except OSError:
                return

    def _disconnect(self, n):
        self.injected["disconnect"] += 1
        self.log(f"fault: line dropped after command {n}; back in {self.reconnect_delay:g} s")
        # The cable is out: the link goes first, or a client could open the closed pty's name after the
        # kernel has handed it to another process's pty.
        if self.link and os.path.islink(self.link):
            os.unlink(self.link)
        self._close()
        time.sleep(self.reconnect_delay)
        if not self._stop.is_set():
            self._open()
