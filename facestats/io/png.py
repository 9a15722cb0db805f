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

__all__ = [
    "COMPRESSIONS",
    "HUFFMAN_MIN_SAMPLES",
    "encode_png",
    "png_chunk",
    "PNG_SIGNATURE",
    "text_chunks",
    "add_chunks",
]

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


def text_chunks(text) -> list:
    """PNG text chunks ``(type, data)`` of a mapping of keywords to values (PNG specification §11.3.4).

    A value in Latin-1 is a ``tEXt`` chunk (keyword, NUL, value); any other is an uncompressed ``iTXt`` chunk
    (keyword, NUL, compression flag 0, method 0, empty language tag and translated keyword, each NUL-terminated,
    then the UTF-8 value), which PNG readers decode alike (e.g. Pillow's ``Image.text``; matplotlib's
    ``imsave(metadata=...)`` writes the same two kinds).

    Parameters
    ----------
    text : mapping of str to str
        Keywords of 1-79 Latin-1 characters without leading, trailing or double spaces; values without NUL.

    Returns
    -------
    list of (bytes, bytes)
        For :func:`encode_png`'s ``chunks`` or :func:`add_chunks`.

    Raises
    ------
    ValidationError
        A keyword or value the format cannot hold, named.
    """
    out = []
    for key, value in text.items():
        key, value = str(key), str(value)
        try:
            k = key.encode("latin-1")
        except UnicodeEncodeError:
            k = b""
        if not 1 <= len(k) <= 79 or key != key.strip() or "  " in key or "\0" in key:
            raise ValidationError(
                f"a PNG text keyword has 1-79 Latin-1 characters, no outer or double spaces, got {key!r}"
            )
        if "\0" in value:
            raise ValidationError(f"a PNG text value holds no NUL character, got one in {key!r}")
        try:
            out.append((b"tEXt", k + b"\0" + value.encode("latin-1")))
        except UnicodeEncodeError:
            out.append((b"iTXt", k + b"\0\0\0\0\0" + value.encode("utf-8")))
    return out


def add_chunks(png: bytes, chunks) -> bytes:
    """A PNG file with ancillary chunks inserted after its ``IHDR`` (e.g. :func:`text_chunks` into a file another
    encoder wrote).

    Parameters
    ----------
    png : bytes
        A PNG file (signature, then ``IHDR``, which the specification puts first).
    chunks : iterable of (bytes, bytes)
        Chunks ``(type, data)``.

    Returns
    -------
    bytes

    Raises
    ------
    ValidationError
        ``png`` does not start with the PNG signature and an ``IHDR`` chunk.
    """
    end = len(PNG_SIGNATURE) + 8 + 13 + 4  # IHDR: length, type, 13 bytes of data, CRC
    if not png.startswith(PNG_SIGNATURE) or png[len(PNG_SIGNATURE) + 4 : len(PNG_SIGNATURE) + 8] != b"IHDR":
        raise ValidationError("png must be a PNG file starting with its signature and IHDR chunk")
    return png[:end] + b"".join(png_chunk(tag, data) for tag, data in chunks) + png[end:]


#: PNG text keys of a map's image (:func:`map_scale_text`: ``facestats edit``'s and the web app's images): the
#: variable, its units (``facestats.io.schema.VARIABLES``'s, "1" dimensionless), the colour map (:data:`COLORMAPS`:
#: "viridis", or "sRGB" for the albedo: each channel's linear value sRGB-encoded, 0 black and 1 white), the values
#: drawn at its low and high ends (``repr`` of a float; values beyond are clipped to them), and the pixels a side
#: of one texel.  ``Description`` says the same in words.
SCALE_KEYS = (
    "facestats:variable",
    "facestats:units",
    "facestats:colormap",
    "facestats:vmin",
    "facestats:vmax",
    "facestats:texel_pixels",
)


#: Colour maps :func:`map_scale_text` describes.
COLORMAPS = ("viridis", "sRGB", "(n + 1) / 2", "tab10")


def map_scale_text(var, colormap, lo, hi, texel_pixels, *, units=None, long_name=None, note=""):
    """``(PNG text chunks, one line in words)``: the scale of a map's image drawn with ``colormap`` from ``lo`` to
    ``hi`` (:data:`SCALE_KEYS` and ``Description``).

    Colour maps (:data:`COLORMAPS`): ``viridis`` (a scalar from ``lo`` to ``hi``), ``sRGB`` (each channel's
    linear value from ``lo`` black to ``hi`` white, sRGB-encoded), ``(n + 1) / 2`` (each component of a unit vector
    from ``lo`` = −1 to ``hi`` = 1 as 8-bit codes 0-255 per channel, x red, y green, z blue) and ``tab10`` (integer
    labels ``lo`` to ``hi``, label k in tab10's colour (k − 1) mod 10).  Used by the ``edit`` images
    (:func:`facestats.edit.plots.stage_edit_images`) and the web app's map images (:func:`facestats.web.data.map_png`),
    so both carry one scale format; :func:`text_chunks` writes the text into a PNG.

    Parameters
    ----------
    var : str
        The map's variable.
    colormap : str
        One of :data:`COLORMAPS`.
    lo, hi : float
        The values drawn at the colour map's two ends (values beyond are clipped to them).
    texel_pixels : int
        Pixels a side of one texel.
    units, long_name : str, optional
        Default: the schema's (:data:`facestats.io.schema.VARIABLES`); "1" is dimensionless.
    note : str
        Words appended to the description (e.g. "; the before and after images share it").

    Returns
    -------
    text : dict of str to str
    words : str
        The scale in one line (without the map's name).

    Raises
    ------
    ValidationError
        An unknown ``colormap``, or a ``var`` the schema does not know without ``units`` and ``long_name``.
    """
    from facestats.io.schema import VARIABLES  # local: keeps the schema out of this module's import

    check_choice(colormap, "colormap", COLORMAPS)
    if (units is None or long_name is None) and var not in VARIABLES:
        raise ValidationError(f"map {var!r} is not a variable of the schema: give its units and long_name")
    units = VARIABLES[var][1] if units is None else units
    long_name = VARIABLES[var][2] if long_name is None else long_name
    unit_words = "dimensionless" if units == "1" else f"in {units}"
    if colormap == "sRGB":
        words = f"linear {lo:g} (black) to {hi:g} (white) per channel, sRGB-encoded, {unit_words}"
    elif colormap == "(n + 1) / 2":
        words = (
            f"components {lo:g} to {hi:g} as (n + 1) / 2 in 8-bit codes 0-255 (x red, y green, z blue), {unit_words}"
        )
    elif colormap == "tab10":
        words = f"labels {lo:g} to {hi:g}, label k in matplotlib's tab10 colour (k - 1) mod 10, {unit_words}"
    else:
        words = f"{colormap} from {lo:.4g} (dark purple) to {hi:.4g} (yellow), {unit_words}"
    text = {
        "facestats:variable": var,
        "facestats:units": units,
        "facestats:colormap": colormap,
        "facestats:vmin": repr(float(lo)),
        "facestats:vmax": repr(float(hi)),
        "facestats:texel_pixels": str(int(texel_pixels)),
        "Description": f"{var} ({long_name}): {words}; values beyond clipped{note}; one texel is {int(texel_pixels)} x "
        f"{int(texel_pixels)} pixels",
    }
    return text, words


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
