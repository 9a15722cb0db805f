"""EXIF exposure metadata of photographs: a small reader (JPEG, TIFF, PNG) and writer, in pure Python.

EXIF (JEITA CP-3451 / CIPA DC-008) stores its tags as a TIFF structure (TIFF 6.0
§2: byte-order mark ``II`` or ``MM``, magic 42, offset of the first image file
directory; each IFD a count and 12-byte entries tag, type, count, value/offset).
The capture tags live in the Exif sub-IFD that tag 0x8769 of IFD0 points to.
This module reads that structure from

* JPEG: the APP1 segment starting ``Exif\\0\\0``;
* TIFF: the file itself (its IFD0 is the EXIF IFD0);
* PNG: the ``eXIf`` chunk (PNG 1.5 extension, the TIFF structure without the
  ``Exif\\0\\0`` prefix),

and returns the exposure tags: ``ExposureTime`` (0x829A, seconds), ``FNumber``
(0x829D), ``ISOSpeedRatings`` (0x8827), ``Make`` (0x010F), ``Model`` (0x0110).
Nothing else is interpreted; no external program is run.  :func:`exif_payload`
and :func:`embed_exif` write the same structure (used by the simulator to tag its
photographs like a camera does).
"""

from __future__ import annotations

import os
import struct
from fractions import Fraction

from facestats.errors import FormatError
from facestats.io.png import PNG_SIGNATURE, png_chunk

__all__ = ["read_exif", "parse_exif", "read_exposure_time", "exif_payload", "embed_exif", "EXIF_TAGS"]

#: Tags read, by number.
EXIF_TAGS = {
    0x010F: "Make",
    0x0110: "Model",
    0x829A: "ExposureTime",
    0x829D: "FNumber",
    0x8827: "ISOSpeedRatings",
}
_EXIF_IFD = 0x8769
#: TIFF field types: (struct code, size in bytes).
_TYPES = {1: ("B", 1), 2: ("s", 1), 3: ("H", 2), 4: ("I", 4), 5: ("II", 8), 7: ("B", 1), 9: ("i", 4), 10: ("ii", 8)}


def _value(data, order, typ, count, field, base):
    """Value of one IFD entry (``field``: its 4-byte value/offset field)."""
    code, size = _TYPES[typ]
    n = size * count
    raw = field[:n] if n <= 4 else data[base + struct.unpack(order + "I", field)[0] :][:n]
    if len(raw) < n:
        raise FormatError("EXIF entry points beyond the end of its data")
    if typ == 2:
        return raw.split(b"\0", 1)[0].decode("latin-1").strip()
    if typ in (5, 10):
        vals = struct.unpack(order + code[0] * (2 * count), raw)
        out = [float(Fraction(a, b)) if b else float("nan") for a, b in zip(vals[::2], vals[1::2])]
    else:
        out = list(struct.unpack(order + code * count, raw))
    return out[0] if count == 1 else out


def _ifd(data, order, offset, base):
    """``{tag: value}`` of the IFD at ``offset`` (relative to ``base``)."""
    pos = base + offset
    if pos + 2 > len(data):
        raise FormatError(f"EXIF IFD offset {offset} lies beyond the end of the data")
    (count,) = struct.unpack(order + "H", data[pos : pos + 2])
    out = {}
    for k in range(count):  # loop over the IFD's entries (a few dozen at most)
        entry = data[pos + 2 + 12 * k : pos + 14 + 12 * k]
        if len(entry) < 12:
            raise FormatError("EXIF IFD is truncated")
        tag, typ, n = struct.unpack(order + "HHI", entry[:8])
        if typ in _TYPES and (tag in EXIF_TAGS or tag == _EXIF_IFD):
            out[tag] = _value(data, order, typ, n, entry[8:12], base)
    return out


def _parse_tiff(data, base=0):
    """The exposure tags of a TIFF structure starting at ``base``."""
    head = data[base : base + 8]
    if head[:4] not in (b"II*\0", b"MM\0*"):
        raise FormatError("EXIF data does not start with a TIFF header (II*\\0 or MM\\0*)")
    order = "<" if head[:2] == b"II" else ">"
    ifd0 = _ifd(data, order, struct.unpack(order + "I", head[4:8])[0], base)
    tags = {EXIF_TAGS[t]: v for t, v in ifd0.items() if t in EXIF_TAGS}
    if _EXIF_IFD in ifd0:
        sub = _ifd(data, order, int(ifd0[_EXIF_IFD]), base)
        tags.update({EXIF_TAGS[t]: v for t, v in sub.items() if t in EXIF_TAGS})
    return tags


def _jpeg_app1(data):
    """Offset of the TIFF structure inside a JPEG's Exif APP1 segment, or None."""
    pos = 2
    while pos + 4 <= len(data) and data[pos] == 0xFF:  # loop over marker segments up to the image data
        marker = data[pos + 1]
        if marker in (0xD9, 0xDA):  # end of image, start of scan
            return None
        (length,) = struct.unpack(">H", data[pos + 2 : pos + 4])
        if marker == 0xE1 and data[pos + 4 : pos + 10] == b"Exif\0\0":
            return pos + 10
        pos += 2 + length
    return None


def _png_exif(data):
    """Offset of the TIFF structure of a PNG's eXIf chunk, or None."""
    pos = 8
    while pos + 8 <= len(data):  # loop over chunks up to the image data
        length, kind = struct.unpack(">I4s", data[pos : pos + 8])
        if kind == b"eXIf":
            return pos + 8
        if kind in (b"IDAT", b"IEND"):
            return None
        pos += 12 + length
    return None


def read_exif(path) -> dict:
    """The exposure tags (module docstring) of a JPEG, TIFF or PNG file; ``{}`` when it has no EXIF data.

    Raises
    ------
    FormatError
        The file is not a JPEG, TIFF or PNG, or its EXIF structure is corrupt (the
        message names the file).
    """
    p = os.fspath(path)
    try:
        with open(p, "rb") as f:
            data = f.read(1 << 20)  # EXIF blocks precede the image data: the first MiB holds them
    except OSError as exc:
        raise FormatError(f"cannot read EXIF data of {p}: {exc}") from None
    return parse_exif(data, p)


def parse_exif(data: bytes, name: str = "<bytes>") -> dict:
    """:func:`read_exif` of the bytes of a file (``name`` for messages)."""
    try:
        if data[:2] == b"\xff\xd8":
            base = _jpeg_app1(data)
        elif data[:4] in (b"II*\0", b"MM\0*"):
            base = 0
        elif data[:8] == PNG_SIGNATURE:
            base = _png_exif(data)
        else:
            raise FormatError(f"{name} is not a JPEG, TIFF or PNG file (no EXIF reader for it)")
        return {} if base is None else _parse_tiff(data, base)
    except (struct.error, FormatError, ValueError, ZeroDivisionError) as exc:
        if isinstance(exc, FormatError) and str(exc).startswith(name):
            raise
        raise FormatError(f"EXIF data of {name} is corrupt: {exc}") from None


def read_exposure_time(path) -> float | None:
    """EXIF ``ExposureTime`` of a photograph in seconds, or None when the file does not record it."""
    t = read_exif(path).get("ExposureTime")
    return None if t is None else float(t)


def exif_payload(exposure_time: float, *, f_number: float | None = None, iso: int | None = None, make="", model=""):
    """A little-endian TIFF structure (no ``Exif\\0\\0`` prefix) with IFD0 (Make, Model) and an Exif IFD.

    ``exposure_time`` (s) is written as the rational closest to it with a
    denominator ≤ 10⁶.
    """
    blobs = []
    for tag, text in ((0x010F, make), (0x0110, model)):
        if text:
            blobs.append((tag, 2, text.encode("latin-1") + b"\0"))
    exif = []
    t = Fraction(float(exposure_time)).limit_denominator(1_000_000)
    exif.append((0x829A, 5, struct.pack("<II", t.numerator, t.denominator)))
    if f_number is not None:
        fn = Fraction(float(f_number)).limit_denominator(1000)
        exif.append((0x829D, 5, struct.pack("<II", fn.numerator, fn.denominator)))
    if iso is not None:
        exif.append((0x8827, 3, struct.pack("<H", int(iso))))
    entries0 = blobs + [(_EXIF_IFD, 4, b"")]

    def ifd_size(n):
        return 2 + 12 * n + 4

    off0 = 8
    off_exif = off0 + ifd_size(len(entries0))
    data_start = off_exif + ifd_size(len(exif))
    out_data = bytearray()

    def pack_ifd(entries, pointer_value):
        nonlocal out_data
        b = struct.pack("<H", len(entries))
        for tag, typ, payload in entries:
            if tag == _EXIF_IFD:
                b += struct.pack("<HHII", tag, 4, 1, pointer_value)
                continue
            size = _TYPES[typ][1]
            count = len(payload) // size
            if len(payload) <= 4:
                b += struct.pack("<HHI", tag, typ, count) + payload.ljust(4, b"\0")
            else:
                b += struct.pack("<HHII", tag, typ, count, data_start + len(out_data))
                out_data += payload + (b"\0" if len(payload) % 2 else b"")
        return b + struct.pack("<I", 0)

    ifd0 = pack_ifd(entries0, off_exif)
    ifd_exif = pack_ifd(exif, 0)
    return b"II*\0" + struct.pack("<I", off0) + ifd0 + ifd_exif + bytes(out_data)


def embed_exif(encoded: bytes, payload: bytes) -> bytes:
    """An encoded PNG or JPEG file (bytes) with the EXIF ``payload`` of :func:`exif_payload` inserted.

    PNG: an ``eXIf`` chunk after ``IHDR``; JPEG: an APP1 ``Exif`` segment after SOI.
    """
    if encoded[:8] == PNG_SIGNATURE:
        (ihdr_len,) = struct.unpack(">I", encoded[8:12])
        cut = 8 + 12 + ihdr_len
        return encoded[:cut] + png_chunk(b"eXIf", payload) + encoded[cut:]
    if encoded[:2] == b"\xff\xd8":
        body = b"Exif\0\0" + payload
        return encoded[:2] + b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body + encoded[2:]
    raise FormatError("embed_exif needs an encoded PNG or JPEG file, got other bytes")
