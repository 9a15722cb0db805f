"""The facestats device protocol: line-based ASCII requests and CRC-checked, numbered reply frames.

Modelled on open LED-array controllers (``zfphil/illuminate``: ``l.37`` lights LED 37,
``x`` clears the array, ``sb``/``sc`` set brightness and colour, ``ver``, ``?``; every
reply ends with the marker ``-==-``), with the framing a lab needs to trust a long,
unattended sequence: request ids, device sequence numbers and a CRC.

**Port.** 115200 baud, 8 data bits, no parity, 1 stop bit (8N1) by default
(:data:`BAUDRATE`; the drivers take other settings).  ASCII only.

**Requests** (host → device), one line ending in LF (a CR before it is ignored)::

    BODY                   typed by a person at a terminal:  l.37
    BODY #ID*CRC           sent by facestats:                l.37 #1048577*1B09

BODY is a command name (lower-case letters or ``?``) and its integer arguments
joined by dots (``l.37``, ``sc.255.200.180``); ID is the host's request id
(1 … 2³¹ − 1); CRC is :func:`crc16` of every byte before the ``*``, as four
upper-case hex digits.  A line longer than :data:`MAX_LINE` bytes is refused.

**Replies** (device → host): exactly one frame per request, then the marker line::

    @SEQ ID STATUS[ PAYLOAD]*CRC
    -==-

SEQ counts the frames the device has sent since power-up (1 for the first);
ID echoes the request's id (0 for plain requests and unsolicited frames);
STATUS is ``OK``, ``Enn`` (a numbered error of :data:`ERRORS`, PAYLOAD the
message) or ``BOOT`` (sent once at power-up, SEQ 1, PAYLOAD the identity);
PAYLOAD is printable ASCII without ``@``, ``*`` or line breaks, values as
``key=value`` words; CRC is :func:`crc16` of the bytes from ``@`` up to ``*``.

**Rules** (the host side is :class:`facestats.acquire.devices.serial_link.SerialLink`):

* a frame whose CRC or syntax is wrong is *garbled*; a frame whose marker has not
  arrived when the read times out is *truncated*: both are dropped and the request
  is sent again with the same id;
* the device executes a request id once: a repeated id is answered with the
  stored frame of its first execution (same SEQ), so a retried trigger never takes
  a second picture;
* a frame carrying another id is a late answer to an earlier request
  (*out of order*) and a frame equal to the last accepted one is a *duplicate*:
  both are discarded;
* a ``BOOT`` frame, or an answer to the current id whose SEQ is below the last
  accepted one, means the device *rebooted* and lost its state (sequence numbers
  restart): the host counts the reboot and the driver restores the state.
"""

from __future__ import annotations

import binascii
import re
from dataclasses import dataclass

from facestats.errors import DeviceError

__all__ = [
    "BAUDRATE",
    "MARKER",
    "TERMINATOR",
    "MAX_LINE",
    "ERRORS",
    "RETRYABLE",
    "crc16",
    "Request",
    "Reply",
    "FrameError",
    "ProtocolViolation",
    "parse_request",
    "parse_reply",
    "FrameReader",
    "quoted",
]

#: Default line settings: 115200 baud, 8N1.
BAUDRATE = 115200
#: The line that ends every reply frame.
MARKER = b"-==-"
#: Bytes that end a reply frame: its LF and the marker line.
TERMINATOR = b"\n" + MARKER + b"\n"
#: Longest request line a device accepts, bytes (without the LF).
MAX_LINE = 200
#: Bytes a :class:`FrameReader` keeps while it waits for a frame's end (a reply frame is far shorter).
MAX_PENDING = 1 << 16
#: Numbered errors of ``Enn`` replies.
ERRORS = {
    1: "unknown command",
    2: "bad checksum",
    3: "wrong number of arguments",
    4: "argument out of range",
    5: "not ready",
    6: "hardware fault",
    7: "malformed request",
}
#: Errors after which the host sends the same request again (the request was garbled, or the device was busy).
RETRYABLE = frozenset({2, 5})

_NAME = re.compile(r"[a-z?]{1,8}")
_REQUEST = re.compile(rb"^([a-z?]{1,8})((?:\.-?\d{1,12})*)(?: #(\d{1,10}))?(?:\*([0-9A-F]{4}))?\Z")
_FRAME = re.compile(rb"^@(\d{1,12}) (\d{1,10}) (OK|E\d\d|BOOT)(?: ([ -)+-?A-~]*))?\*([0-9A-F]{4})\Z")


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of ``data``: polynomial 0x1021, initial value 0xFFFF, no reflection, no final XOR.

    The check value of the CRC catalogue (Williams, *A painless guide to CRC error
    detection algorithms*, 1993, parameter model "CRC-16/CCITT-FALSE", since
    renamed CRC-16/IBM-3740) is ``crc16(b"123456789") == 0x29B1``; computed by the
    C implementation of :func:`binascii.crc_hqx`.

    Parameters
    ----------
    data : bytes-like

    Returns
    -------
    int
        The CRC, in [0, 0xFFFF].
    """
    return binascii.crc_hqx(data, 0xFFFF)


class FrameError(DeviceError):
    """A reply frame that is garbled (``kind="garbled"``) or truncated (``kind="truncated"``)."""

    def __init__(self, message: str, kind: str, raw: bytes = b""):
        super().__init__(message)
        self.kind = kind
        self.raw = raw


class ProtocolViolation(DeviceError):
    """A request a device refuses (``code``: the number of :data:`ERRORS` it answers with)."""

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = int(code)


@dataclass(frozen=True)
class Request:
    """A command with integer arguments and the host's request id (0: a plain, unframed request).

    Attributes
    ----------
    name : str
        Command name: 1-8 lower-case letters or ``?``.
    args : tuple of int
        Integer arguments (not bool).
    id : int
        Request id, in [0, 2³¹); 0 for a plain request.
    """

    name: str
    args: tuple = ()
    id: int = 0

    def __post_init__(self):
        if not _NAME.fullmatch(self.name):
            raise DeviceError(f"command name must be 1-8 lower-case letters or '?', got {self.name!r}")
        if any(isinstance(a, bool) or not isinstance(a, int) for a in self.args):
            raise DeviceError(f"command arguments must be integers, got {self.args!r}")
        if not 0 <= int(self.id) < 2**31:
            raise DeviceError(f"request id must lie in [0, 2^31), got {self.id!r}")

    @property
    def body(self) -> str:
        """``name.arg.arg``: the command as a person would type it."""
        return ".".join([self.name, *map(str, self.args)])

    def encode(self) -> bytes:
        """The request line: framed (``BODY #ID*CRC``) when ``id`` > 0, else plain."""
        if not self.id:
            return self.body.encode("ascii") + b"\n"
        head = f"{self.body} #{self.id}".encode("ascii")
        return head + b"*%04X\n" % crc16(head)


@dataclass(frozen=True)
class Reply:
    """A reply frame (module docstring).

    Attributes
    ----------
    seq : int
        The device's frame count since power-up (1 for the first).
    id : int
        The request id answered (0 for plain requests and unsolicited frames).
    status : str
        ``"OK"``, ``"Enn"`` (error number nn of :data:`ERRORS`) or ``"BOOT"``.
    payload : str
        Printable ASCII without ``@``, ``*`` or line breaks: ``key=value`` words, or an error message.
    """

    seq: int
    id: int
    status: str
    payload: str = ""

    @property
    def ok(self) -> bool:
        return self.status == "OK"

    @property
    def error_code(self) -> int:
        """The error number of an ``Enn`` reply, 0 otherwise."""
        return int(self.status[1:]) if self.status.startswith("E") else 0

    def fields(self) -> dict:
        """The ``key=value`` words of the payload (words without ``=`` map to ``""``).

        Raises
        ------
        DeviceError
            A key given twice (``led=0 led=2``: which one the device meant is unknown).
        """
        out = {}
        for word in self.payload.split():
            key, _, value = word.partition("=")
            if key in out:
                raise DeviceError(f"reply names the field {key!r} twice: {self.payload[:120]!r}")
            out[key] = value
        return out

    def encode(self) -> bytes:
        """The frame's bytes including the marker line."""
        head = f"@{self.seq} {self.id} {self.status}" + (f" {self.payload}" if self.payload else "")
        data = head.encode("ascii")
        return data + b"*%04X" % crc16(data) + TERMINATOR


def quoted(data: bytes) -> str:
    """Bytes of the link quoted for a message: ASCII as text, other bytes and control characters escaped.

    Parameters
    ----------
    data : bytes

    Returns
    -------
    str
        A Python string literal of ``data`` read as Latin-1 (quotes included, ``\\xNN`` escapes).
    """
    return ascii(data.decode("latin-1"))


def parse_request(line: bytes) -> Request:
    """The request of one line (without its LF); raises :class:`ProtocolViolation` with the device's error number.

    Parameters
    ----------
    line : bytes
        One request line; a trailing CR is ignored.

    Returns
    -------
    Request
        Its name, integer arguments and id (0 for a plain request).

    Raises
    ------
    ProtocolViolation
        Code 7 for a line over :data:`MAX_LINE` bytes, a malformed request or an id ≥ 2³¹; code 2 for a bad
        checksum.
    """
    line = line.rstrip(b"\r")
    if len(line) > MAX_LINE:
        raise ProtocolViolation(f"line of {len(line)} bytes exceeds {MAX_LINE}", 7)
    m = _REQUEST.match(line)
    if m is None:
        name = re.match(rb"[a-z?]{1,8}", line)
        if name is None or line[name.end() : name.end() + 1] not in (b"", b".", b" ", b"*"):
            raise ProtocolViolation(f"malformed request {quoted(line[:40])}", 7)
        raise ProtocolViolation(f"malformed arguments in {quoted(line[:40])} (integers joined by dots)", 7)
    name, args, rid, crc = m.groups()
    if crc is not None and int(crc, 16) != crc16(line[: line.rindex(b"*")]):
        raise ProtocolViolation(f"bad checksum {crc.decode()} of {quoted(line[:40])}", 2)
    if rid and int(rid) >= 2**31:  # ten digits reach past the ids a host may use (Request)
        raise ProtocolViolation(f"request id must lie in [0, 2^31), got {int(rid)}", 7)
    values = tuple(int(a) for a in args.split(b".")[1:]) if args else ()
    return Request(name.decode(), values, int(rid) if rid else 0)


def parse_reply(chunk: bytes) -> Reply:
    """The reply frame in ``chunk`` (bytes before a :data:`TERMINATOR`); raises :class:`FrameError`.

    Bytes before the frame's last ``@`` (the remains of a truncated frame) are
    ignored here; :class:`FrameReader` reports them.

    Parameters
    ----------
    chunk : bytes
        The bytes read up to the terminator (excluded).

    Returns
    -------
    Reply

    Raises
    ------
    FrameError
        ``kind="garbled"``: no ``@``, a frame of wrong syntax, or a wrong CRC.
    """
    start = chunk.rfind(b"@")
    m = _FRAME.match(chunk[start:]) if start >= 0 else None
    if m is None:
        raise FrameError(f"garbled reply frame {quoted(chunk[-60:])}", "garbled", chunk)
    seq, rid, status, payload, crc = m.groups()
    if int(crc, 16) != crc16(chunk[start : chunk.rindex(b"*")]):
        raise FrameError(f"reply frame with a wrong CRC {quoted(chunk[-60:])}", "garbled", chunk)
    return Reply(int(seq), int(rid), status.decode(), (payload or b"").decode("ascii"))


class FrameReader:
    """Split a byte stream into reply frames: :meth:`feed` returns :class:`Reply` and :class:`FrameError` items.

    Bytes before a complete frame that do not form one themselves are reported
    as a truncated frame; :attr:`pending` holds the bytes of the frame still
    arriving, at most :data:`MAX_PENDING` (a device sending megabytes without a
    frame end made every read search them all again: quadratic time, unbounded
    memory; a red team); beyond it the older bytes are dropped, reported as a truncated frame.
    """

    def __init__(self):
        self.pending = b""

    def feed(self, data: bytes) -> list:
        """Add received bytes; return the complete replies they finish, in order.

        Parameters
        ----------
        data : bytes
            Bytes read from the link.

        Returns
        -------
        list of Reply or FrameError
            The frames completed by ``data``, and a :class:`FrameError` for each garbled or truncated one (and
            for pending bytes dropped beyond :data:`MAX_PENDING`).
        """
        buf = self.pending + data
        items = []
        start = max(0, len(self.pending) - len(TERMINATOR) + 1)  # the pending bytes hold no terminator
        while True:
            end = buf.find(TERMINATOR, start)
            start = 0
            if end < 0:
                break
            chunk, buf = buf[:end], buf[end + len(TERMINATOR) :]
            at = chunk.rfind(b"@")  # not ``start``: the next search runs from the start of the rest of ``buf``
            if at > 0 and chunk[:at].strip():
                head = chunk[:at]
                items.append(FrameError(f"truncated reply frame {quoted(head[-60:])}", "truncated", head))
            try:
                items.append(parse_reply(chunk))
            except FrameError as exc:
                items.append(exc)
        if len(buf) > MAX_PENDING:
            dropped, buf = buf[:-MAX_PENDING], buf[-MAX_PENDING:]
            # as bytes before a frame: a frame may still follow (1 MB of boot noise, then the reply)
            items.append(FrameError(f"{len(dropped)} bytes without a frame end dropped", "truncated", dropped[-60:]))
        self.pending = buf
        return items

    def flush(self):
        """Drop the pending bytes; a :class:`FrameError` ("truncated") if they held anything but whitespace."""
        rest, self.pending = self.pending, b""
        return FrameError(f"truncated reply frame {quoted(rest[-60:])}", "truncated", rest) if rest.strip() else None
