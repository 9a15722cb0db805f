"""A request/reply link to a device over pyserial: timeouts on every read, bounded retries, reconnection.

:class:`SerialLink` sends a request of :mod:`facestats.acquire.devices.protocol`
and returns the device's reply frame, enforcing the protocol's rules: garbled
and truncated frames, timeouts and the retryable errors (E02 bad checksum, E05
not ready) make it send the request again with the same id, after a backoff that
doubles from ``backoff`` up to ``max_backoff`` seconds, at most ``retries``
times; late (out-of-order) and duplicated frames are discarded; a reboot of the
device (a ``BOOT`` frame, or sequence numbers that start again) increments
:attr:`SerialLink.epoch`, which the drivers watch to restore the device's state.
A port that fails (cable pulled, emulator gone) is reopened until
``reconnect_timeout`` seconds have passed.  Every event is counted in
:class:`LinkStats` and reported through ``log``.

``port`` is a device path (``/dev/ttyUSB0``, a pty such as ``/dev/pts/7``, ``COM3``)
or any pyserial URL (``loop://``, ``socket://host:port``, ``rfc2217://host:port``).
Request ids start at a random value for every link, so a device's stored answer
to an earlier program's request can never be mistaken for a new one.
"""

from __future__ import annotations

import collections
import errno
import os
import time
from dataclasses import dataclass, fields

from facestats.acquire.devices.protocol import BAUDRATE, ERRORS, RETRYABLE, FrameError, FrameReader, Request, quoted
from facestats.core.validate import as_finite, check_choice, check_integer
from facestats.errors import DeviceError, DeviceReplyError, DeviceTimeout

__all__ = ["SerialLink", "LinkStats", "open_port"]

#: Seconds one pyserial read waits before the link checks its deadline again.
POLL_S = 0.05


@dataclass
class LinkStats:
    """Counters of a link's traffic and of every irregularity it met.

    Attributes
    ----------
    requests : int
        Requests made (:meth:`SerialLink.request` calls).
    sent : int
        Request lines written, retries included.
    retries : int
        Attempts after the first.
    garbled, truncated : int
        Reply frames dropped for a wrong CRC or syntax, or cut short.
    timeouts : int
        Attempts without a reply within the timeout.
    out_of_order, duplicates : int
        Late frames answering other requests, and repeated frames, discarded.
    device_errors : int
        ``Enn`` replies.
    reboots : int
        Reboots of the device seen.
    reconnects : int
        Times the port was reopened.
    bytes_received : int
        Bytes read from the port.
    """

    requests: int = 0
    sent: int = 0
    retries: int = 0
    garbled: int = 0
    truncated: int = 0
    timeouts: int = 0
    out_of_order: int = 0
    duplicates: int = 0
    device_errors: int = 0
    reboots: int = 0
    reconnects: int = 0
    bytes_received: int = 0

    def as_dict(self) -> dict:
        """The counters as a dict."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def to_text(self) -> str:
        """The counters that are not zero (and always requests and retries), on one line."""
        return ", ".join(f"{k} {v}" for k, v in self.as_dict().items() if v or k in ("requests", "retries"))


def open_port(port: str, *, baudrate: int = BAUDRATE, bytesize: int = 8, parity: str = "N", stopbits: float = 1):
    """Open a pyserial port or URL with the given line settings; a :class:`DeviceError` says what to do if it fails.

    Parameters
    ----------
    port : str
        A device path or a pyserial URL (module docstring); a device path is opened exclusively.
    baudrate : int
        Line speed in baud, 50 to 4,000,000 (default the protocol's :data:`BAUDRATE`).
    bytesize : {5, 6, 7, 8}
        Data bits.
    parity : {"N", "E", "O", "M", "S"}
        Parity.
    stopbits : {1, 1.5, 2}
        Stop bits.

    Returns
    -------
    serial.SerialBase
        The open port (a :class:`serial.Serial` for a device path): reads time out after :data:`POLL_S` s,
        writes after 5 s; its input buffer emptied.

    Raises
    ------
    ValidationError
        A line setting out of range or not among the choices.
    DeviceError
        ``port`` is not a non-empty string, or pyserial cannot open it (the message advises).
    """
    import serial

    check_integer(baudrate, "baudrate", 50, 4_000_000)
    check_choice(bytesize, "bytesize", (5, 6, 7, 8))
    check_choice(parity, "parity", ("N", "E", "O", "M", "S"))
    check_choice(stopbits, "stopbits", (1, 1.5, 2))
    if not isinstance(port, str) or not port:
        raise DeviceError(f"port must be a device path or a pyserial URL, got {port!r}")
    try:
        ser = serial.serial_for_url(
            port,
            baudrate=baudrate,
            bytesize=bytesize,
            parity=parity,
            stopbits=stopbits,
            timeout=POLL_S,
            write_timeout=5.0,
            exclusive="://" not in port or None,
        )
    except (serial.SerialException, OSError, ValueError) as exc:
        raise DeviceError(_open_advice(port, exc)) from None
    ser.reset_input_buffer()
    return ser


def _open_advice(port, exc) -> str:
    """The message for a port that cannot be opened: what failed and what to do next."""
    code = getattr(exc, "errno", None)
    text = str(exc)
    if code == errno.ENOENT or "No such file" in text:
        return (
            f"cannot open serial port {port}: no such device. Check the cable and the name "
            "(`python -m serial.tools.list_ports` lists the ports), or use the path `facestats emulate` printed"
        )
    if code == errno.EACCES or "Permission denied" in text:
        return (
            f"cannot open serial port {port}: permission denied. Add your user to the group owning the port "
            "(usually 'dialout': sudo usermod -aG dialout $USER, then log in again)"
        )
    if code in (errno.EBUSY, errno.EAGAIN) or "lock" in text.lower():
        return f"cannot open serial port {port}: it is in use by another program (close it, or stop the other capture)"
    if "Inappropriate ioctl" in text or "configure port" in text:
        return f"cannot open {port}: it is not a serial port (a regular file or another kind of device)"
    if "://" in port:
        return f"cannot open {port}: {text} (check the URL; pyserial supports loop://, socket://, rfc2217://)"
    return f"cannot open serial port {port}: {text}"


class SerialLink:
    """Requests and replies over one serial port (module docstring).

    Parameters
    ----------
    port : str
        Device path or pyserial URL.
    baudrate, bytesize, parity, stopbits
        Line settings (default 115200 8N1).
    timeout : float
        Seconds to wait for a reply to one request, > 0 (per attempt).
    retries : int
        Attempts after the first, ≥ 0.
    backoff, max_backoff : float
        First and largest pause between attempts, s.
    reconnect_timeout : float
        How long a failed port is retried before the link gives up, s.
    log : callable, optional
        Receives one line of text per irregular event.
    """

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = BAUDRATE,
        bytesize: int = 8,
        parity: str = "N",
        stopbits: float = 1,
        timeout: float = 1.0,
        retries: int = 5,
        backoff: float = 0.02,
        max_backoff: float = 0.5,
        reconnect_timeout: float = 10.0,
        log=None,
    ):
        as_finite(timeout, "timeout", 0, None, low_inclusive=False, unit="s")
        check_integer(retries, "retries", 0, 100)
        as_finite(backoff, "backoff", 0, None, unit="s")
        as_finite(max_backoff, "max_backoff", 0, None, unit="s")
        as_finite(reconnect_timeout, "reconnect_timeout", 0, None, unit="s")
        self.port = port
        self.settings = dict(baudrate=baudrate, bytesize=bytesize, parity=parity, stopbits=stopbits)
        self.timeout, self.retries = float(timeout), int(retries)
        self.backoff, self.max_backoff = float(backoff), float(max_backoff)
        self.reconnect_timeout = float(reconnect_timeout)
        self.log = log or (lambda line: None)
        self.stats = LinkStats()
        self.epoch = 0  # reboots of the device seen by this link
        self._next_id = 1 + int.from_bytes(os.urandom(4), "big") % (2**30)
        self._last = None  # (seq, id) of the last accepted frame
        self._noted = 0  # discarded items logged during the current request (at most MAX_NOTES)
        self._unlogged = 0  # ... and those beyond it
        self._reader = FrameReader()
        self._backlog = collections.deque()  # frames read but not yet examined
        self._ser = open_port(port, **self.settings)

    # -- life cycle ----------------------------------------------------------------------------
    def close(self):
        """Close the port (once; a port that failed is let go)."""
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:  # closing a port that failed: nothing left to release
                pass
            self._ser = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def is_open(self) -> bool:
        return self._ser is not None

    def _reconnect(self, why):
        """Reopen the port until it works or ``reconnect_timeout`` has passed."""
        self.log(f"port {self.port} failed ({why}); reconnecting")
        self.close()
        deadline = time.monotonic() + self.reconnect_timeout
        pause = self.backoff or 0.01
        while True:
            try:
                self._ser = open_port(self.port, **self.settings)
            except DeviceError as exc:
                if time.monotonic() + pause > deadline:
                    raise DeviceTimeout(
                        f"device on {self.port} disconnected and did not come back within {self.reconnect_timeout:g} s "
                        f"({exc}); reconnect it and rerun the command (a capture session continues with --resume)"
                    ) from None
                time.sleep(pause)
                pause = min(2 * pause, max(self.max_backoff, 0.05))
                continue
            self._reader = FrameReader()
            self._backlog.clear()
            self.stats.reconnects += 1
            self.log(f"port {self.port} reopened")
            return

    # -- requests --------------------------------------------------------------------------------
    def request(self, name: str, *args: int, timeout: float | None = None):
        """Send ``name.args`` and return the device's OK :class:`~facestats.acquire.devices.protocol.Reply`.

        Parameters
        ----------
        name : str
            The command name.
        *args : int
            Its integer arguments.
        timeout : float, optional
            Seconds to wait for the reply to each attempt; default the link's ``timeout``.

        Returns
        -------
        Reply
            The ``OK`` frame answering the request.

        Raises
        ------
        DeviceReplyError
            The device answered with a numbered error that is not retryable.
        DeviceTimeout
            Every attempt failed, or the port did not come back within ``reconnect_timeout``.
        DeviceError
            The port dropped the connection more than ``retries + 1`` times during the request.
        """
        rid = self._next_id
        self._next_id = self._next_id % (2**31 - 1) + 1
        req = Request(name, tuple(int(a) for a in args), rid)
        wait = self.timeout if timeout is None else float(timeout)
        self.stats.requests += 1
        try:
            return self._request(req, wait)
        finally:
            self._end_notes(req)

    def _request(self, req, wait):
        """:meth:`request`'s attempts for ``req`` (its id is ``req.id``)."""
        rid, line = req.id, req.encode()
        failures = []
        attempt = drops = 0
        while attempt <= self.retries:
            if attempt:
                self.stats.retries += 1
                time.sleep(min(self.max_backoff, self.backoff * 2 ** (attempt - 1)))
            try:
                reply = self._exchange(line, rid, wait)
            except _Disconnected as exc:
                drops += 1
                if drops > self.retries + 1:  # a port that opens and fails at once would loop here for ever
                    raise DeviceError(
                        f"{self.port} dropped the connection {drops} times while {req.body!r} was sent ({exc}); "
                        "check the cable and the device, then rerun (a capture session continues with --resume)"
                    ) from None
                self._reconnect(exc)
                continue  # a failed port is not the device's answer: retry without counting an attempt
            attempt += 1
            if reply is None:
                failures.append("no reply")
                continue
            if isinstance(reply, str):  # a reboot interrupted the request: send it again at once
                failures.append(reply)
                continue
            if reply.ok:
                return reply
            self.stats.device_errors += 1
            code = reply.error_code
            message = (
                f"{self.port} answered {req.body!r} with error {code} ({ERRORS.get(code, 'unknown')}): {reply.payload}"
            )
            if code not in RETRYABLE:
                raise DeviceReplyError(message, code)
            failures.append(f"error {code}")
            self.log(message)
        raise DeviceTimeout(self._give_up(req, failures))

    def _give_up(self, req, failures) -> str:
        s = self.stats
        if s.out_of_order and not (s.requests > 1 or self._last):  # valid frames, none answering this request
            return (
                f"the device on {self.port} answered {req.body!r} only with {s.out_of_order} frames for other "
                "requests: another program is using the device, or its firmware numbers its replies wrongly"
            )
        if s.bytes_received and not (s.requests > 1 or self._last):
            return (
                f"the device on {self.port} answered {req.body!r} with bytes that are not facestats protocol frames "
                f"({s.garbled} garbled, {s.truncated} truncated): it speaks another protocol or another line setting "
                f"(check --port and --baudrate, {self.settings['baudrate']} now)"
            )
        return (
            f"the device on {self.port} did not answer {req.body!r} after {len(failures)} attempt(s) "
            f"({', '.join(sorted(set(failures)))}; {s.bytes_received} bytes received in all): check its power, "
            "cable and --baudrate, then rerun (a capture session continues with --resume)"
        )

    def _exchange(self, line: bytes, rid: int, wait: float):
        """Write ``line`` and read until the reply to ``rid``: a Reply, None (timeout, garbled) or "reboot"."""
        while self._backlog:  # frames that came after an earlier reply: late, duplicated, or a BOOT
            self._accept(self._backlog.popleft(), None)
        try:
            self._ser.write(line)
            self._ser.flush()
        except Exception as exc:  # pyserial raises SerialException, SerialTimeoutException or OSError
            raise _Disconnected(exc) from None
        self.stats.sent += 1
        deadline = time.monotonic() + wait
        while True:
            self._backlog.extend(self._read(deadline))
            garbled = False
            while self._backlog:
                outcome = self._accept(self._backlog.popleft(), rid)
                if outcome is None:  # a garbled frame: the reply may still be among what arrived with it
                    garbled = True
                elif outcome is not _SKIP:
                    return outcome
            if garbled:
                return None
            if time.monotonic() >= deadline:
                rest = self._reader.flush()
                if rest is not None:
                    self.stats.truncated += 1
                    self.log(f"truncated reply to request {rid}: {quoted(rest.raw[-40:])}")
                else:
                    self.stats.timeouts += 1
                    self.log(f"no reply to request {rid} within {wait:g} s")
                return None

    def _read(self, deadline):
        """The frames (and frame errors) that arrive before ``deadline``, waiting at most until then."""
        try:
            data = self._ser.read(max(1, self._ser.in_waiting))
            if data:
                more = self._ser.in_waiting
                if more:
                    data += self._ser.read(more)
        except Exception as exc:  # SerialException (device gone) or OSError
            raise _Disconnected(exc) from None
        if not data:
            return []
        self.stats.bytes_received += len(data)
        return self._reader.feed(data)

    def _accept(self, item, rid):
        """What one incoming item means for the request ``rid`` (None: no request waiting; protocol docstring)."""
        if isinstance(item, FrameError):
            if item.kind == "garbled":
                self.stats.garbled += 1
            else:
                self.stats.truncated += 1
            self._note(f"{item.kind} reply frame while waiting for request {rid}: {quoted(item.raw[-40:])}")
            return None if item.kind == "garbled" else _SKIP
        if item.status == "BOOT":
            self._reboot(f"boot frame {item.payload!r}")
            self._last = (item.seq, item.id)
            return "reboot"
        key = (item.seq, item.id)
        if key == self._last:
            self.stats.duplicates += 1
            self._note(f"duplicate frame @{item.seq} (request {item.id}) discarded")
            return _SKIP
        if item.id != rid:
            self.stats.out_of_order += 1
            self._note(f"late frame @{item.seq} answering request {item.id} discarded (waiting for {rid})")
            return _SKIP
        if self._last is not None and item.seq < self._last[0]:
            self._reboot(f"sequence number {item.seq} after {self._last[0]}")
        self._last = key
        return item

    def _note(self, line):
        """Log a discarded item: the first :data:`MAX_NOTES` of a request one line each, then only count them."""
        if self._noted < MAX_NOTES:
            self._noted += 1
            self.log(line)
        else:
            self._unlogged += 1

    def _end_notes(self, req):
        """One line for the discarded items of ``req`` that were not logged; reset the counts for the next request."""
        if self._unlogged:
            self.log(f"... and {self._unlogged} more frames discarded while waiting for {req.body!r} (not logged)")
        self._noted = self._unlogged = 0

    def _reboot(self, why):
        self.epoch += 1
        self.stats.reboots += 1
        self.log(f"device on {self.port} rebooted ({why}); its state is lost")


#: Discarded frames logged one line each per request; the rest are counted in one line (a flood of stray frames
#: wrote a line for each before, megabytes of log a second; a red team).
MAX_NOTES = 20


class _Disconnected(Exception):
    """The port failed under the link (internal: turned into a reconnection)."""


_SKIP = object()
