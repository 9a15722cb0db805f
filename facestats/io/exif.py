"""EXIF exposure metadata of photographs: a small reader (JPEG, TIFF, PNG) and writer, in pure Python.

EXIF (JEITA CP-3451 / CIPA DC-008) stores its tags as a TIFF structure (TIFF 6.0
§2: byte-order mark ``II`` or ``MM``, magic 42, offset of the first image file
directory; each IFD a count and 12-byte entries tag, type, count, value/offset;
BigTIFF: magic 43, 8-byte offsets and counts, 20-byte entries).  The capture
tags live in the Exif sub-IFD that tag 0x8769 of IFD0 points to.  This module
reads that structure from

* JPEG: the APP1 segment starting ``Exif\\0\\0``;
* TIFF: the file itself (its IFD0 is the EXIF IFD0; its IFDs may lie anywhere
  in it, libtiff writes them after the image data: they are read by seeking);
* PNG: the ``eXIf`` chunk (PNG 1.5 extension, the TIFF structure without the
  ``Exif\\0\\0`` prefix),

and returns the exposure tags: ``ExposureTime`` (0x829A, seconds), ``FNumber``
(0x829D), ``ISOSpeedRatings`` (0x8827), ``Make`` (0x010F), ``Model`` (0x0110).
Nothing else is interpreted; no external program is run.  :func:`exif_payload`
and :func:`embed_exif` write the same structure (used by the simulator to tag its
photographs like a camera does).  :func:`read_tiff_tags` reads other tags of the
first IFD of a TIFF file with the same parser (the image decoder of
:mod:`facestats.io.images` checks a TIFF's layout with it).
"""

from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass
from fractions import Fraction

from facestats.errors import FormatError
from facestats.io.layout import open_regular_file
from facestats.io.png import PNG_SIGNATURE, png_chunk

__all__ = [
    "read_exif",
    "parse_exif",
    "read_exposure_time",
    "read_tiff_tags",
    "exif_payload",
    "embed_exif",
    "EXIF_TAGS",
]

#: Tags read, by number.
EXIF_TAGS = {
    0x010F: "Make",
    0x0110: "Model",
    0x829A: "ExposureTime",
    0x829D: "FNumber",
    0x8827: "ISOSpeedRatings",
}
#: Tags whose value is one positive number (ExposureTime is refused otherwise; the others are dropped).
_NUMERIC = ("ExposureTime", "FNumber", "ISOSpeedRatings")
_EXIF_IFD = 0x8769
#: TIFF field types: (struct code, size in bytes); 13 is IFD (TIFF 6.0 supplement), 16-18 are BigTIFF's 8-byte types.
_TYPES = {
    1: ("B", 1),
    2: ("s", 1),
    3: ("H", 2),
    4: ("I", 4),
    5: ("II", 8),
    6: ("b", 1),
    7: ("B", 1),
    8: ("h", 2),
    9: ("i", 4),
    10: ("ii", 8),
    11: ("f", 4),
    12: ("d", 8),
    13: ("I", 4),
    16: ("Q", 8),
    17: ("q", 8),
    18: ("Q", 8),
}
#: Byte-order marks and magic numbers (TIFF 6.0 §2; BigTIFF: 43, then offset size 8 and a reserved 0).
_CLASSIC_HEADERS = (b"II*\0", b"MM\0*")
_BIG_HEADERS = (b"II+\0", b"MM\0+")
#: Bytes of a file :func:`read_exif` reads first: a JPEG's or PNG's EXIF block precedes its image data, within them.
_HEAD = 1 << 20
#: Most bytes :func:`read_exif` reads at once past those of a TIFF file (one IFD, or one value of a tag): the
#: values read are a few bytes and an IFD at most 65535 entries, but a corrupt entry can claim gigabytes.
_MAX_READ = 1 << 24


class _FileData:
    """A TIFF file's bytes sliced like :class:`bytes` (``data[a:b]``, ``len(data)``), but read on demand.

    A TIFF file's IFDs and the values they point to may lie anywhere in it
    (libtiff, hence OpenCV, writes IFD0 after the image data): they are read by
    seeking, never the whole file.  ``head`` is the file's first bytes, already read.
    """

    def __init__(self, fh, head: bytes):
        self._fh, self._head = fh, head
        self._size = os.fstat(fh.fileno()).st_size

    def __len__(self) -> int:
        return self._size

    def __getitem__(self, key: slice) -> bytes:
        start, stop, step = key.indices(self._size)
        if step != 1:
            raise TypeError("a TIFF file is read in contiguous slices only")
        if stop <= len(self._head):
            return self._head[start:stop]
        n = max(stop - start, 0)
        if n > _MAX_READ:
            raise FormatError(f"TIFF field of {n} bytes at offset {start} is too large to read (at most {_MAX_READ})")
        self._fh.seek(start)
        return self._fh.read(n)


@dataclass(frozen=True)
class _Layout:
    """Where a TIFF structure's IFD fields are: byte order, offset size (4 classic, 8 BigTIFF)."""

    order: str
    offset_size: int

    @property
    def offset_code(self) -> str:
        return "I" if self.offset_size == 4 else "Q"

    @property
    def entry_size(self) -> int:
        return 12 if self.offset_size == 4 else 20

    @property
    def count_code(self) -> str:
        """Struct code of an IFD's entry count (2 bytes classic, 8 BigTIFF)."""
        return "H" if self.offset_size == 4 else "Q"


def _value(data, layout, typ, count, field, base):
    """Value of one IFD entry (``field``: its value/offset field, 4 or 8 bytes)."""
    code, size = _TYPES[typ]
    n = size * count
    if n <= len(field):  # the value fits in the entry
        raw = field[:n]
    else:
        start = base + struct.unpack(layout.order + layout.offset_code, field)[0]
        raw = b"" if start + n > len(data) else data[start : start + n]
    if len(raw) < n:
        raise FormatError("TIFF entry points beyond the end of its data")
    if typ == 2:
        return raw.split(b"\0", 1)[0].decode("latin-1").strip()
    if typ in (5, 10):
        vals = struct.unpack(layout.order + code[0] * (2 * count), raw)
        out = [float(Fraction(a, b)) if b else float("nan") for a, b in zip(vals[::2], vals[1::2])]
    else:
        out = list(struct.unpack(layout.order + code * count, raw))
    return out[0] if count == 1 else out


def _ifd(data, layout, offset, base, wanted):
    """``{tag: value}`` of the tags in ``wanted`` of the IFD at ``offset`` (relative to ``base``)."""
    pos = base + offset
    count_size = struct.calcsize(layout.count_code)
    if offset < 0:  # a signed (SLONG) pointer: Python's slices would read from the end of the data
        raise FormatError(f"TIFF IFD offset must be >= 0, got {offset}")
    if pos + count_size > len(data):
        raise FormatError(f"TIFF IFD offset {offset} lies beyond the end of the data")
    (count,) = struct.unpack(layout.order + layout.count_code, data[pos : pos + count_size])
    head = layout.order + "HH" + layout.offset_code  # tag, type, count
    out = {}
    first, size = pos + count_size, layout.entry_size
    if first + size * count > len(data):
        raise FormatError("TIFF IFD is truncated")
    entries = data[first : first + size * count]  # one read of the whole IFD
    if len(entries) < size * count:
        raise FormatError("TIFF IFD is truncated")
    for k in range(count):  # loop over the IFD's entries (a few dozen at most)
        entry = entries[size * k : size * (k + 1)]
        tag, typ, n = struct.unpack(head, entry[: 4 + layout.offset_size])
        if typ in _TYPES and tag in wanted:
            out[tag] = _value(data, layout, typ, n, entry[4 + layout.offset_size :], base)
    return out


def _header(data, base):
    """The :class:`_Layout` and IFD0 offset of the TIFF structure starting at ``base`` (classic or BigTIFF)."""
    head = data[base : base + 16]
    order = "<" if head[:2] == b"II" else ">"
    if head[:4] in _CLASSIC_HEADERS:
        return _Layout(order, 4), struct.unpack(order + "I", head[4:8])[0]
    if head[:4] in _BIG_HEADERS and struct.unpack(order + "HH", head[4:8]) == (8, 0):
        return _Layout(order, 8), struct.unpack(order + "Q", head[8:16])[0]
    raise FormatError("data does not start with a TIFF header (II*\\0, MM\\0*, or BigTIFF II+\\0, MM\\0+)")


def _parse_tiff(data, base=0):
    """The exposure tags of a TIFF structure starting at ``base``."""
    layout, offset0 = _header(data, base)
    ifd0 = _ifd(data, layout, offset0, base, EXIF_TAGS.keys() | {_EXIF_IFD})
    tags = {EXIF_TAGS[t]: v for t, v in ifd0.items() if t in EXIF_TAGS}
    if _EXIF_IFD in ifd0:
        pointer = ifd0[_EXIF_IFD]
        if isinstance(pointer, (list, str, float)):
            raise FormatError(f"the Exif IFD pointer must be one integer offset, got {pointer!r:.40}")
        sub = _ifd(data, layout, int(pointer), base, EXIF_TAGS.keys())
        tags.update({EXIF_TAGS[t]: v for t, v in sub.items() if t in EXIF_TAGS})
    for name in _NUMERIC:
        v = tags.get(name)
        if v is not None and (isinstance(v, (str, list)) or not math.isfinite(v) or v <= 0):
            if name == "ExposureTime":  # it would reach the HDR merge as a time: refuse the file
                raise FormatError(f"EXIF ExposureTime must be one positive number, got {v!r:.40}")
            del tags[name]  # informative only (a manual lens writes FNumber 0; ISO may hold several values)
    return tags


def read_tiff_tags(data: bytes, tags, name: str = "<bytes>") -> dict:
    """Values of some tags of the first image file directory (IFD0) of a TIFF file's bytes.

    Parameters
    ----------
    data : bytes
        The whole file (classic TIFF or BigTIFF, either byte order).
    tags : iterable of int
        Tag numbers (TIFF 6.0, e.g. 262 PhotometricInterpretation).
    name : str
        The file's name, for messages.

    Returns
    -------
    dict of int to value
        The tags present: a single value as int, float or str, several as a list
        (e.g. BitsPerSample of an RGB image: ``[16, 16, 16]``).  Absent tags are
        left out (their TIFF defaults are the caller's business).

    Raises
    ------
    FormatError
        The data is not a TIFF file or its IFD0 is corrupt (the message names ``name``).
    """
    try:
        layout, offset0 = _header(data, 0)
        return _ifd(data, layout, offset0, 0, frozenset(tags))
    except (struct.error, FormatError, ValueError, ZeroDivisionError) as exc:
        raise FormatError(f"TIFF structure of {name} is corrupt: {exc}") from None


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

    Parameters
    ----------
    path : str or path-like
        The file.  Of a JPEG or PNG file only the first MiB is read (EXIF blocks precede the image data); of a
        TIFF file the header, the first IFD, the Exif IFD and the values of the tags read, wherever they are
        (libtiff writes the first IFD after the image data), never the whole file.

    Returns
    -------
    dict
        The tags found among ``Make``, ``Model`` (str), ``ExposureTime`` (s), ``FNumber`` and ``ISOSpeedRatings``
        (numbers); ``FNumber`` and ``ISOSpeedRatings`` are left out unless they are one positive number.

    Raises
    ------
    FormatError
        The file cannot be read (a FIFO or a device is refused, never read), is not a JPEG, TIFF or PNG, or its
        EXIF structure is corrupt (the message names the file).
    """
    p = os.fspath(path)
    try:
        with open_regular_file(p) as fh:  # a FIFO or a device is refused, never read
            head = fh.read(_HEAD)
            tiff = head[:4] in _CLASSIC_HEADERS + _BIG_HEADERS
            return _parse(_FileData(fh, head) if tiff else head, p)
    except OSError as exc:
        raise FormatError(f"cannot read EXIF data of {p}: {exc}") from None


def parse_exif(data: bytes, name: str = "<bytes>") -> dict:
    """:func:`read_exif` of the bytes of a file (``name`` for messages).

    Parameters
    ----------
    data : bytes
        The file's bytes (or their first part holding the EXIF block).
    name : str
        The file's name, for messages.

    Returns
    -------
    dict
        As :func:`read_exif`; ``{}`` when the file has no EXIF data.

    Raises
    ------
    FormatError
        ``data`` is not a JPEG, TIFF or PNG file, its EXIF structure is corrupt, or its ``ExposureTime`` is not one
        positive number.
    """
    return _parse(data, name)


def _parse(data, name):
    """:func:`parse_exif` of ``data``: bytes, or a TIFF file's :class:`_FileData`."""
    try:
        if data[:2] == b"\xff\xd8":
            base = _jpeg_app1(data)
        elif data[:4] in _CLASSIC_HEADERS + _BIG_HEADERS:
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
    """EXIF ``ExposureTime`` of a photograph in seconds, or None when the file does not record it.

    Parameters
    ----------
    path : str or path-like
        A JPEG, TIFF or PNG file.

    Returns
    -------
    float or None
        Seconds.

    Raises
    ------
    FormatError
        As :func:`read_exif` (including an ``ExposureTime`` that is not one positive number).
    """
    t = read_exif(path).get("ExposureTime")
    return None if t is None else float(t)


def exif_payload(exposure_time: float, *, f_number: float | None = None, iso: int | None = None, make="", model=""):
    """A little-endian TIFF structure (no ``Exif\\0\\0`` prefix) with IFD0 (Make, Model) and an Exif IFD.

    ``exposure_time`` (s) is written as the rational closest to it with a
    denominator ≤ 10⁶.

    Parameters
    ----------
    exposure_time : float
        ``ExposureTime`` in seconds (not checked; it must be ≥ 0 to be packed).
    f_number : float, optional
        ``FNumber``, written as the closest rational with a denominator ≤ 1000; omitted when None.
    iso : int, optional
        ``ISOSpeedRatings`` (one unsigned 16-bit value); omitted when None.
    make, model : str
        ``Make`` and ``Model`` (latin-1 text) in IFD0; omitted when empty.

    Returns
    -------
    bytes
        The TIFF structure, ready for :func:`embed_exif`.
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

    Parameters
    ----------
    encoded : bytes
        A whole PNG or JPEG file.
    payload : bytes
        The TIFF structure (:func:`exif_payload`).

    Returns
    -------
    bytes
        The file with the EXIF block added (an existing one is not removed).

    Raises
    ------
    FormatError
        ``encoded`` starts with neither the PNG signature nor a JPEG SOI marker.
    """
    if encoded[:8] == PNG_SIGNATURE:
        (ihdr_len,) = struct.unpack(">I", encoded[8:12])
        cut = 8 + 12 + ihdr_len
        return encoded[:cut] + png_chunk(b"eXIf", payload) + encoded[cut:]
    if encoded[:2] == b"\xff\xd8":
        body = b"Exif\0\0" + payload
        return encoded[:2] + b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body + encoded[2:]
    raise FormatError("embed_exif needs an encoded PNG or JPEG file, got other bytes")
