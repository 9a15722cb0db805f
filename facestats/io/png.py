"""PNG encoding fast enough for a dome's frame rate: 8/16-bit grey or RGB(A), rows unfiltered.

A dome session writes 4,800 frames of 1024² × 3 16-bit samples (6 MB each);
encoding them dominates the cost of an emulated session.  OpenCV's PNG writer
(libpng + zlib) takes 50-70 ms per frame even with Huffman-only deflate; this
writer builds the rows with filter type 0 (the noisy 12-bit codes gain nothing
from prediction) and deflates them with one of two compressors:

* ``"huffman"``: :func:`facestats.io.deflate.deflate_rows`, a Huffman
  code of the frame's bytes and no string matching, about 11 ms a frame
  (compiled), files about 5 % smaller than libdeflate level 1's on noisy frames;
* ``"libdeflate"``: libdeflate at ``level`` (``imagecodecs.deflate_encode``,
  zlib container), 27-33 ms at level 1; smaller files on smooth images;
* ``"auto"`` (default): Huffman-only from :data:`HUFFMAN_MIN_SAMPLES` samples on, libdeflate level
  ``level`` below, where building the Huffman code (about 0.35 ms) costs more than libdeflate's
  search (measured on read-noise frames: libdeflate faster up to 128² × 3 samples, Huffman-only from
  192² × 3 on; ``benchmarks/bench_devices.py``).

Format (PNG specification, ISO/IEC 15948, §5 and §11): signature, ``IHDR``
(width, height, bit depth 8 or 16, colour type 0 grey / 2 RGB / 6 RGBA,
compression 0, filter 0, interlace 0), the ancillary chunks given, one
``IDAT`` holding the zlib stream of the rows (each a filter byte 0 followed by
the samples, 16-bit samples big-endian), ``IEND``.  Every chunk carries its
CRC-32 over type and data.  Any PNG decoder reads the result (tested against
OpenCV's).
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from facestats.core.validate import check_choice, check_integer
from facestats.errors import ValidationError

__all__ = ["COMPRESSIONS", "HUFFMAN_MIN_SAMPLES", "encode_png", "png_chunk", "PNG_SIGNATURE"]

#: The eight bytes every PNG file starts with.
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

#: PNG colour type by number of channels: grey, RGB, RGBA.
_COLOUR_TYPE = {1: 0, 3: 2, 4: 6}


def png_chunk(tag: bytes, data: bytes) -> bytes:
    """One PNG chunk: length (4 bytes, big-endian), type, data, CRC-32 of type and data.

    Parameters
    ----------
    tag : bytes
        The chunk type, 4 bytes (e.g. ``b"IDAT"``).
    data : bytes
        The chunk data.

    Returns
    -------
    bytes

    Raises
    ------
    ValidationError
        ``tag`` is not 4 bytes.
    """
    if not isinstance(tag, bytes) or len(tag) != 4:
        raise ValidationError(f"a PNG chunk type has 4 bytes, got {tag!r}")
    body = tag + data
    return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)


#: Values of :func:`encode_png`'s ``compression``.
COMPRESSIONS = ("auto", "huffman", "libdeflate")

#: Samples (pixels × channels) from which ``compression="auto"`` deflates with the Huffman-only encoder.
HUFFMAN_MIN_SAMPLES = 65536


def encode_png(image, *, compression: str = "auto", level: int = 1, chunks=(), backend: str = "auto") -> bytes:
    """The bytes of a PNG file holding ``image``.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C), C in {1, 3, 4}
        uint8 or uint16 samples, channels in RGB(A) order.
    compression : {"auto", "huffman", "libdeflate"}
        The rows' compressor (module docstring).
    level : int
        libdeflate compression level, 1 (fastest) to 12 (``compression="libdeflate"`` only).
    chunks : iterable of (bytes, bytes)
        Ancillary chunks ``(type, data)`` written after ``IHDR`` (e.g. ``(b"eXIf", payload)``).
    backend : {"auto", "numba", "numpy"}
        The Huffman compressor compiled or with numpy (the same bytes).

    Returns
    -------
    bytes
    """
    from facestats.io.deflate import deflate_rows, prefixed_rows

    a = np.asarray(image)
    if a.dtype.kind != "u" or a.dtype.itemsize not in (1, 2):
        raise ValidationError(f"image must hold uint8 or uint16 samples, got dtype {a.dtype}")
    a = a.astype(a.dtype.newbyteorder("="), copy=False)  # big-endian uint16 (">u2") holds the same codes
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in _COLOUR_TYPE or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValidationError(f"image must have shape (H, W) or (H, W, 1|3|4), got {np.shape(image)}")
    check_choice(compression, "compression", COMPRESSIONS)
    check_integer(level, "level", 1, 12)
    h, w, c = a.shape
    bits = 8 * a.itemsize
    if compression == "auto":
        compression = "huffman" if a.size >= HUFFMAN_MIN_SAMPLES else "libdeflate"
    if compression == "huffman":
        idat = deflate_rows(a.reshape(h, w * c), prefix=0, backend=backend)  # filter type 0 (None) on every row
    else:
        import imagecodecs

        idat = imagecodecs.deflate_encode(prefixed_rows(a.reshape(h, w * c), 0), level=int(level))
    ihdr = struct.pack(">IIBBBBB", w, h, bits, _COLOUR_TYPE[c], 0, 0, 0)
    out = [PNG_SIGNATURE, png_chunk(b"IHDR", ihdr)]
    out += [png_chunk(tag, data) for tag, data in chunks]
    out.append(png_chunk(b"IDAT", idat))
    out.append(png_chunk(b"IEND", b""))
    return b"".join(out)
