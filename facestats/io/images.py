"""Image files: high-dynamic-range (OpenEXR, Radiance RGBE, PFM) and integer (PNG, JPEG, TIFF) readers and writers.

Every reader returns an array indexed ``[row, column, channel]`` with row 0 the
top of the image (the PFM format stores rows bottom-up; the reader flips them).
High-dynamic-range data are returned as stored, in linear radiometry, as
float32: they are never normalised.  Integer images are returned either raw
(:func:`read_integer_image`, for camera-response work) or scaled to [0, 1] by
the largest code value of their bit depth, optionally decoded from sRGB to
linear (:func:`read_image` with ``srgb=True``; the sRGB transfer function of
IEC 61966-2-1).

Formats, by extension:

* ``.exr`` — OpenEXR through the OpenEXR package: half or float channels,
  ``R, G, B[, A]`` read as one image; other channel sets through
  :func:`read_exr` / :func:`write_exr`, which also carry string header attributes
  (units, colour space);
* ``.hdr``, ``.pic`` — Radiance RGBE (Ward 1991): flat and run-length-encoded
  scanlines; a pixel (r, g, b, e) is ((r, g, b) + 0.5) · 2^(e − 136) as in
  Radiance's ``colr_color`` (e = 0 is black); only the ``-Y H +X W`` orientation
  (the standard one) is accepted; written as flat scanlines.  The header's
  ``EXPOSURE=`` and ``COLORCORR=`` lines record multipliers already applied to
  the pixels, cumulatively (Radiance's file-format notes): the reader divides by
  their product, so values come back in the units before any exposure (each must
  be finite and > 0); the writer writes none (multiplier 1);
* ``.pfm`` — Portable Float Map, grey (``Pf``) or colour (``PF``), either byte order;
* ``.png``, ``.jpg``, ``.jpeg`` — through OpenCV (8- and 16-bit, grey or RGB(A);
  Pillow, under imageio, reads 16-bit RGB PNG as 8-bit); an EXIF ``Orientation``
  is not applied: pixels are read in the sensor's layout, the one a camera
  calibration (intrinsics, image size) describes;
* ``.tif``, ``.tiff`` — the first image of the file through libtiff
  (``imagecodecs.tiff_decode``), which reads every layout TIFF 6.0 and BigTIFF
  allow: strips or tiles, contiguous or planar samples (PlanarConfiguration 1
  or 2), either byte order, uncompressed, LZW, deflate, PackBits, JPEG (decoded
  to 8-bit RGB), with or without a horizontal predictor, and packed bit depths
  9-15 (returned in uint16 with their own ``bits``).  Before decoding, the
  first image file directory is checked (:func:`facestats.io.exif.read_tiff_tags`):
  unsigned integer samples (SampleFormat 1) of 8 to 16 bits, grey
  (MinIsBlack, one sample), RGB with optional extra samples, or YCbCr, and not
  a reduced-resolution or mask image (NewSubfileType); anything else (float,
  signed, palette, MinIsWhite, CMYK, CFA raw mosaics, 1-bit, ...) is an
  :class:`ImageFormatError` naming the file, the tag and its value.  OpenCV is
  not used for TIFF: it decodes 16-bit planar files to wrong codes.
"""

from __future__ import annotations

import io
import math
import os
import pathlib
import re
import struct
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from facestats.core.blocked import blockwise
from facestats.core.validate import as_float
from facestats.errors import DependencyError, FormatError, ValidationError
from facestats.io.layout import read_regular_file
from facestats.io.png import PNG_SIGNATURE

__all__ = [
    "HDR_EXTENSIONS",
    "INTEGER_EXTENSIONS",
    "stride_step",
    "read_image",
    "read_integer_image",
    "decode_integer_image",
    "write_image",
    "read_exr",
    "read_exr_attributes",
    "write_exr",
    "read_rgbe",
    "write_rgbe",
    "read_pfm",
    "write_pfm",
    "srgb_to_linear",
    "linear_to_srgb",
    "MAX_IMAGE_PIXELS",
    "read_npy",
    "check_image_size",
    "require_openexr",
]

HDR_EXTENSIONS = (".exr", ".hdr", ".pic", ".pfm")
INTEGER_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


#: Most pixels an image file may declare (16384², the side of the largest maps facestats makes).  A header is
#: checked against it before any decoding, so a file of a few bytes cannot ask for gigabytes.
MAX_IMAGE_PIXELS = 1 << 28


class ImageFormatError(ValidationError):
    """A file is not a valid image of the format its extension names."""


def check_image_size(height, width, name) -> None:
    """Raise :class:`ImageFormatError` unless a file's declared ``height`` × ``width`` is at most
    :data:`MAX_IMAGE_PIXELS`.

    Parameters
    ----------
    height, width : int
        The size the file's header declares, pixels.
    name : str
        The file, for the message.
    """
    if int(height) * int(width) > MAX_IMAGE_PIXELS:
        raise ImageFormatError(
            f"image file {name!r} declares {int(width)} x {int(height)} pixels, more than the {MAX_IMAGE_PIXELS} "
            "(16384 x 16384) facestats reads"
        )


def _path(path, *, must_exist=True) -> pathlib.Path:
    p = pathlib.Path(os.fspath(path))
    if must_exist and not p.is_file():
        raise ValidationError(f"path must name an existing image file, got {str(p)!r}")
    return p


def _extension(p: pathlib.Path) -> str:
    ext = p.suffix.lower()
    if ext not in HDR_EXTENSIONS + INTEGER_EXTENSIONS:
        known = ", ".join(HDR_EXTENSIONS + INTEGER_EXTENSIONS)
        raise ValidationError(f"image file {str(p)!r} has an unknown extension {ext!r} (expected one of {known})")
    return ext


# -- colour transfer ------------------------------------------------------------------------
#: IEC 61966-2-1:1999 (sRGB), §5.2: the encoded value below which the decoding is linear, the linear value below
#: which the encoding is, the slope of that segment, and the power segment's offset and exponent.  The two
#: thresholds are the standard's rounded ones (0.04045 = 12.92 · 0.0031308 to 5 digits); colour-science's
#: ``eotf_sRGB`` uses 12.92 · 0.0031308 = 0.040449936 exactly, so the two decodings differ only for encoded
#: values in (0.040449936, 0.04045], by under 3e-9 (tests/io/test_images.py compares them).
SRGB_DECODE_KNEE = 0.04045
SRGB_ENCODE_KNEE = 0.0031308
SRGB_SLOPE = 12.92
SRGB_OFFSET = 0.055
SRGB_GAMMA = 2.4


def _decode_srgb(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 §5.2 decoding (``v`` float64, any sign): v / 12.92 to 0.04045, ((v + 0.055) / 1.055)^2.4 above."""
    power = ((np.maximum(v, SRGB_DECODE_KNEE) + SRGB_OFFSET) / (1 + SRGB_OFFSET)) ** SRGB_GAMMA
    return np.where(v <= SRGB_DECODE_KNEE, v / SRGB_SLOPE, power)


def _encode_srgb(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 §5.2 encoding of ``v`` clipped to [0, 1]: 12.92 v to 0.0031308, 1.055 v^(1/2.4) − 0.055 above."""
    v = np.clip(v, 0, 1)
    power = (1 + SRGB_OFFSET) * np.maximum(v, SRGB_ENCODE_KNEE) ** (1 / SRGB_GAMMA) - SRGB_OFFSET
    return np.where(v <= SRGB_ENCODE_KNEE, SRGB_SLOPE * v, power)


def srgb_to_linear(values) -> np.ndarray:
    """Linear values from sRGB-encoded values (IEC 61966-2-1:1999 §5.2), float32.

    Computed block by block in float64 (:func:`facestats.core.blocked.blockwise`), so a large map takes
    block-sized temporaries only.  The formula is written out here rather than taken from colour-science,
    whose import costs about a second of every command that reads or writes an sRGB image; the two agree
    to float32 precision (tests/io/test_images.py).

    Parameters
    ----------
    values : array_like
        sRGB-encoded values, any shape, nominally in [0, 1] (not clipped: values below 0.04045, negative ones
        included, take the linear segment; values above 1 the power segment).

    Returns
    -------
    ndarray of float32
        Linear values, the shape of ``values``.
    """
    return blockwise(_decode_srgb, [values], np.float64, block=SRGB_BLOCK, out_dtype=np.float32)


def linear_to_srgb(values) -> np.ndarray:
    """sRGB-encoded values in [0, 1] from linear values (clipped to [0, 1] first; IEC 61966-2-1:1999 §5.2), float32.

    Block by block in float64 (:func:`facestats.core.blocked.blockwise`): a 4096² RGB map at once took about
    1.2 GB of temporaries.  Written out as :func:`srgb_to_linear` is, and checked against colour-science's
    ``cctf_encoding`` in the tests.

    Parameters
    ----------
    values : array_like
        Linear values, any shape.

    Returns
    -------
    ndarray of float32
        sRGB-encoded values in [0, 1], the shape of ``values``.
    """
    return blockwise(_encode_srgb, [values], np.float64, block=SRGB_BLOCK, out_dtype=np.float32)


#: Values :func:`srgb_to_linear` and :func:`linear_to_srgb` transfer at a time (bounds their float64 temporaries).
SRGB_BLOCK = 1 << 18


def stride_step(height: int, width: int, max_side: int) -> int:
    """The smallest step k (≥ 1) for which every k-th pixel of a ``height`` × ``width`` image is at most
    ``max_side`` pixels a side: what a preview of a large map strides by.

    Parameters
    ----------
    height, width : int
        The image's size, pixels.
    max_side : int
        Longest side wanted, pixels (≥ 1; not checked).

    Returns
    -------
    int
        ⌈max(height, width) / max_side⌉, at least 1.
    """
    return max(1, -(-max(int(height), int(width)) // int(max_side)))


# -- public entry points --------------------------------------------------------------------
def read_image(path, *, srgb: bool = False) -> np.ndarray:
    """An image as float32 ``(H, W, C)``, row 0 at the top.

    Parameters
    ----------
    path : str or path-like
        An ``.exr``, ``.hdr``/``.pic``, ``.pfm``, ``.png``, ``.jpg``/``.jpeg`` or ``.tif``/``.tiff`` file.
    srgb : bool
        For integer images: decode the sRGB transfer function to linear values.
        Must be False for high-dynamic-range files (they are linear already).

    Returns
    -------
    ndarray of float32, shape (H, W, C)
        HDR files as stored (never normalised); integer files divided by the
        largest code of their bit depth (255 or 65535).
    """
    p = _path(path)
    ext = _extension(p)
    if ext in HDR_EXTENSIONS:
        if srgb:
            raise ValidationError(f"srgb must be False for a high-dynamic-range file ({str(p)!r} is linear), got True")
        if ext == ".exr":
            channels, _ = read_exr(p)
            return _stack_rgb(channels, p)
        return read_pfm(p) if ext == ".pfm" else read_rgbe(p)
    raw, bits = read_integer_image(p)
    out = raw.astype(np.float32) / np.float32(2**bits - 1)
    return srgb_to_linear(out) if srgb else out


def read_integer_image(path):
    """An integer image as stored in a PNG, JPEG or TIFF file, for camera-response work.

    Parameters
    ----------
    path : str or path-like
        A ``.png``, ``.jpg``/``.jpeg`` or ``.tif``/``.tiff`` file.

    Returns
    -------
    codes : ndarray of uint8 or uint16, shape (H, W, C), C-contiguous
        The codes as stored (no scaling, no EXIF rotation), row 0 at the top;
        C = 1 for grey, else channels in RGB order followed by any extra
        samples (C = 4: RGBA).  uint8 for 8-bit files, uint16 for 9- to 16-bit
        ones.
    bits : int
        Bits per sample of the file: 8 or 16 (PNG, JPEG, TIFF), or 9-15 for a
        TIFF with packed samples; codes lie in [0, 2**bits − 1].

    Raises
    ------
    ValidationError
        ``path`` is missing or not an integer image extension.
    ImageFormatError
        The file cannot be decoded, or holds samples that are not 8- to 16-bit
        unsigned integers in grey or RGB(A) (module docstring); the message
        names the file and, for TIFF, the tag and value.
    """
    p = _path(path)
    if _extension(p) not in INTEGER_EXTENSIONS:
        raise ValidationError(f"path must name an integer image ({', '.join(INTEGER_EXTENSIONS)}), got {str(p)!r}")
    return decode_integer_image(p.read_bytes(), str(p))


def decode_integer_image(data: bytes, name: str = "<bytes>"):
    """:func:`read_integer_image` of a file's bytes (read once, e.g. to check a checksum first); ``name`` for errors.

    The format is told by the data's signature, not by ``name``: TIFF (classic or
    BigTIFF) through libtiff, anything else through OpenCV (module docstring).

    Parameters
    ----------
    data : bytes
        The whole file.
    name : str
        The file's name, for messages.

    Returns
    -------
    codes : ndarray of uint8 or uint16, shape (H, W, C), C-contiguous
        As :func:`read_integer_image`.
    bits : int
        8 or 16, or 9-15 for a TIFF with packed samples.

    Raises
    ------
    ImageFormatError
        Empty or undecodable data, a PNG/JPEG/TIFF header declaring more than :data:`MAX_IMAGE_PIXELS` pixels,
        samples that are not 8- or 16-bit integers, or an unsupported TIFF layout (module docstring).
    """
    if len(data) == 0:  # OpenCV would fail an internal assertion
        raise ImageFormatError(f"image file {name!r} is empty (0 bytes)")
    if bytes(data[:4]) in _TIFF_SIGNATURES:
        return _decode_tiff(data, name)
    size = _declared_size(data)
    if size is not None:  # before OpenCV allocates what the header asks for
        check_image_size(*size, name)
    import cv2

    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)  # no EXIF rotation, no depth change
    except cv2.error:
        img = None
    if img is None:
        raise ImageFormatError(f"image file {name!r} could not be decoded (not a valid PNG, JPEG or TIFF file)")
    if img.dtype == np.uint8:
        bits = 8
    elif img.dtype == np.uint16:
        bits = 16
    else:
        raise ImageFormatError(f"image file {name!r} must hold 8- or 16-bit integer samples, got dtype {img.dtype}")
    if img.ndim == 2:
        return img[..., None], bits
    if img.shape[2] in (3, 4):  # OpenCV stores BGR(A); cvtColor swaps in one SIMD pass (fancy indexing: 10× slower)
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB if img.shape[2] == 3 else cv2.COLOR_BGRA2RGBA), bits
    return np.ascontiguousarray(img), bits


# -- TIFF ------------------------------------------------------------------------------------
#: Classic TIFF and BigTIFF signatures (byte order, magic 42 or 43).
_TIFF_SIGNATURES = (b"II*\0", b"MM\0*", b"II+\0", b"MM\0+")
#: JPEG start-of-frame markers (ITU T.81 Table B.1: SOF0-SOF15 but DHT C4, JPG C8 and DAC CC).
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def _declared_size(data: bytes):
    """``(height, width)`` a PNG (IHDR, PNG spec §11.2.2) or JPEG (the first SOFn frame header, ITU T.81 §B.2.2)
    declares, or None when the data is neither or the header cannot be found (the decoder then reports it)."""
    if data[:8] == PNG_SIGNATURE and len(data) >= 24 and data[12:16] == b"IHDR":
        width, height = struct.unpack(">II", data[16:24])
        return height, width
    if data[:2] != b"\xff\xd8":
        return None
    pos = 2
    while pos + 4 <= len(data):  # loop over the marker segments before the frame header (a few)
        if data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker == 0xFF:  # a fill byte
            pos += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):  # TEM, RSTn: no length
            pos += 2
            continue
        length = struct.unpack(">H", data[pos + 2 : pos + 4])[0]
        if marker in _JPEG_SOF:
            if pos + 9 > len(data):
                return None
            height, width = struct.unpack(">HH", data[pos + 5 : pos + 9])
            return height, width
        if marker in (0xD9, 0xDA) or length < 2:  # end of image or start of scan before any frame header
            return None
        pos += 2 + length
    return None


#: Tags of the first IFD the decoder checks (TIFF 6.0 numbers).
_TIFF_TAGS = {
    254: "NewSubfileType",
    256: "ImageWidth",
    257: "ImageLength",
    258: "BitsPerSample",
    259: "Compression",
    262: "PhotometricInterpretation",
    277: "SamplesPerPixel",
    284: "PlanarConfiguration",
    339: "SampleFormat",
}
#: PhotometricInterpretation values (TIFF 6.0, TIFF/EP, DNG) named in messages.
_PHOTOMETRIC = {
    0: "MinIsWhite",
    1: "MinIsBlack",
    2: "RGB",
    3: "Palette",
    4: "TransparencyMask",
    5: "Separated (CMYK)",
    6: "YCbCr",
    8: "CIELab",
    9: "ICCLab",
    10: "ITULab",
    32803: "CFA (a raw colour-filter mosaic: demosaic it first)",
    32844: "LogL",
    32845: "LogLuv",
    34892: "LinearRaw",
}
_MIN_IS_BLACK, _RGB, _YCBCR = 1, 2, 6
#: Compression values libtiff decodes to 8-bit RGB(A) itself (JPEG, old-style JPEG): already interleaved.
_JPEG_COMPRESSION = (6, 7)


@dataclass(frozen=True)
class _TiffLayout:
    """The checked layout of a TIFF's first image: pixels, samples, bit depth, planar storage."""

    height: int
    width: int
    samples: int
    bits: int
    planar: bool  # samples stored plane by plane (PlanarConfiguration 2) *and* returned so by libtiff


def _tiff_tag(tags, tag, default, name):
    """One value of ``tag`` (its TIFF 6.0 default when absent); per-sample lists must agree."""
    v = tags.get(tag, default)
    values = v if isinstance(v, list) else [v]
    if v is not default and not (values and all(isinstance(x, int) and x >= 0 for x in values)):
        raise ImageFormatError(
            f"TIFF file {name!r} must hold a non-negative integer {_TIFF_TAGS[tag]} (tag {tag}), got {v!r}"
        )
    if len(set(values)) != 1:
        raise ImageFormatError(
            f"TIFF file {name!r} must have one {_TIFF_TAGS[tag]} (tag {tag}) for all samples, got {values}"
        )
    return values[0]


def _tiff_error(name, tag, value, expected) -> ImageFormatError:
    """The error of a TIFF whose tag ``tag`` has an unsupported ``value``."""
    return ImageFormatError(f"TIFF file {name!r} must hold {expected}, got {_TIFF_TAGS[tag]} (tag {tag}) = {value!r}")


def _tiff_bits(tags, name) -> int:
    """Bits per sample of a full-resolution image of unsigned 8- to 16-bit samples (else the error)."""
    subfile = _tiff_tag(tags, 254, 0, name)
    if subfile & 5:  # bit 0: reduced-resolution version of another image; bit 2: a transparency mask
        raise _tiff_error(name, 254, subfile, "a full-resolution image first (NewSubfileType without bits 0 and 2)")
    fmt = _tiff_tag(tags, 339, 1, name)
    if fmt != 1:
        kind = {2: "signed integer", 3: "floating point", 4: "undefined"}.get(fmt, "unknown")
        raise _tiff_error(name, 339, f"{fmt} ({kind})", "unsigned integer samples (SampleFormat 1)")
    bits = _tiff_tag(tags, 258, 1, name)
    if not 8 <= bits <= 16:
        raise _tiff_error(name, 258, bits, "8 to 16 bits per sample")
    return int(bits)


def _tiff_colour(tags, bits, name):
    """``(samples per pixel, decoded through libtiff's RGBA interface)`` of a grey, RGB(A) or YCbCr image."""
    photometric = _tiff_tag(tags, 262, None, name)
    samples = _tiff_tag(tags, 277, 1, name)
    shown = f"{photometric} ({_PHOTOMETRIC.get(photometric, 'unknown')})"
    if photometric not in (_MIN_IS_BLACK, _RGB, _YCBCR):
        raise _tiff_error(name, 262, shown, "a grey (1 MinIsBlack), RGB (2) or YCbCr (6) image")
    if photometric == _MIN_IS_BLACK and samples != 1:
        raise _tiff_error(name, 277, samples, "one sample per pixel for a grey (MinIsBlack) image")
    if photometric != _MIN_IS_BLACK and samples < 3:
        raise _tiff_error(name, 277, samples, f"at least 3 samples per pixel for PhotometricInterpretation {shown}")
    # libtiff returns JPEG-compressed and YCbCr images through its RGBA interface: 8-bit RGB, interleaved.
    via_rgba = _tiff_tag(tags, 259, 1, name) in _JPEG_COMPRESSION or photometric == _YCBCR
    if via_rgba and bits != 8:
        raise _tiff_error(name, 258, bits, "8 bits per sample for a JPEG-compressed or YCbCr image")
    return int(samples), via_rgba


def _tiff_layout(data, name) -> _TiffLayout:
    """The layout of the first image of a TIFF file, or :class:`ImageFormatError` naming what is unsupported."""
    from facestats.io.exif import read_tiff_tags

    try:
        tags = read_tiff_tags(data, _TIFF_TAGS, name)
    except FormatError as exc:
        raise ImageFormatError(f"TIFF file {name!r} could not be decoded: {exc}") from None
    for tag in (256, 257, 262):
        if tag not in tags:
            raise ImageFormatError(f"TIFF file {name!r} has no {_TIFF_TAGS[tag]} (tag {tag}), which TIFF 6.0 requires")
    width, height = _tiff_tag(tags, 256, None, name), _tiff_tag(tags, 257, None, name)
    bits = _tiff_bits(tags, name)
    samples, via_rgba = _tiff_colour(tags, bits, name)
    check_image_size(height, width, name)
    planar = _tiff_tag(tags, 284, 1, name)
    if planar not in (1, 2):
        raise _tiff_error(name, 284, planar, "contiguous (1) or planar (2) samples")
    return _TiffLayout(int(height), int(width), samples, bits, planar == 2 and samples > 1 and not via_rgba)


def _decode_tiff(data, name):
    """``(codes (H, W, C), bits)`` of the first image of a TIFF file (module docstring)."""
    import imagecodecs

    layout = _tiff_layout(data, name)
    try:
        img = imagecodecs.tiff_decode(data)  # the first IFD, samples as stored, native byte order
    except (RuntimeError, ValueError, IndexError, MemoryError) as exc:  # imagecodecs.TiffError is a RuntimeError
        raise ImageFormatError(f"TIFF file {name!r} could not be decoded by libtiff: {exc}") from None
    if img.ndim == 2:
        img = img[..., None]
    elif layout.planar:  # (samples, H, W) -> (H, W, samples)
        img = np.moveaxis(img, 0, -1)
    want = (layout.height, layout.width, layout.samples)
    dtype = np.uint8 if layout.bits == 8 else np.uint16
    if img.shape != want or img.dtype != dtype:
        raise ImageFormatError(
            f"TIFF file {name!r} decoded to shape {img.shape} and dtype {img.dtype}, its tags say {want} and "
            f"{layout.bits} bits per sample ({np.dtype(dtype).name}): unsupported layout"
        )
    return np.ascontiguousarray(img), layout.bits


def write_image(path, image, *, half: bool = False, bits: int = 8, srgb: bool = False, attributes=None):
    """Write ``image`` (H, W[, C]) in the format of the extension of ``path``.

    Parameters
    ----------
    path : str or path-like
    image : array_like, shape (H, W) or (H, W, C)
        Row 0 at the top.  HDR formats take any finite float values; integer
        formats take values in [0, 1] (clipped), quantised to ``bits``.
    half : bool
        EXR only: store half floats instead of float32.
    bits : {8, 16}
        PNG/TIFF bit depth (JPEG is always 8).
    srgb : bool
        Integer formats: encode linear values with the sRGB transfer function.
    attributes : dict of str, optional
        EXR only: string header attributes (e.g. units, colour space).

    Returns
    -------
    pathlib.Path
    """
    p = _path(path, must_exist=False)
    ext = _extension(p)
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[0] < 1 or img.shape[1] < 1:
        raise ValidationError(f"image must have shape (H, W) or (H, W, C), got {np.shape(image)}")
    if ext == ".exr":
        names = "RGBA"[: img.shape[2]] if img.shape[2] in (3, 4) else ("Y",) if img.shape[2] == 1 else None
        if names is None:
            raise ValidationError(f"image for EXR must have 1, 3 or 4 channels, got {img.shape[2]} (use write_exr)")
        write_exr(p, {n: img[..., i] for i, n in enumerate(names)}, half=half, attributes=attributes)
    elif ext == ".pfm":
        write_pfm(p, img)
    elif ext in (".hdr", ".pic"):
        write_rgbe(p, img)
    else:
        _write_integer(p, img, bits=bits, srgb=srgb)
    return p


def _write_integer(p, img, *, bits, srgb):
    import cv2

    if bits not in (8, 16) or (bits == 16 and p.suffix.lower() in (".jpg", ".jpeg")):
        raise ValidationError(f"bits must be 8 or 16 (8 for JPEG), got {bits!r} for {str(p)!r}")
    if img.shape[2] not in (1, 3, 4):
        raise ValidationError(f"image for {p.suffix} must have 1, 3 or 4 channels, got {img.shape[2]}")
    top = 2**bits - 1

    def codes(v):  # one block, float64: its codes (an image's float64 copies were four times its size)
        if not np.all(np.isfinite(v)):
            raise ValidationError(f"image must be finite to write {str(p)!r}, got NaN or inf")
        return np.round((linear_to_srgb(v) if srgb else np.clip(v, 0, 1)) * top)

    q = blockwise(codes, [img], np.float64, block=SRGB_BLOCK, out_dtype=np.uint8 if bits == 8 else np.uint16)
    q = q[..., 0] if q.shape[2] == 1 else q[..., [2, 1, 0, 3][: q.shape[2]]]  # OpenCV writes BGR(A)
    if not cv2.imwrite(str(p), q):
        raise ValidationError(f"path must be a writable {p.suffix} file, could not write {str(p)!r}")


def _stack_rgb(channels, p):
    """(H, W, C) float32 from the channels of an EXR: R, G, B[, A] or a single channel."""
    if all(c in channels for c in "RGB"):
        names = ["R", "G", "B"] + (["A"] if "A" in channels else [])
    elif len(channels) == 1:
        names = list(channels)
    else:
        raise ImageFormatError(
            f"EXR file {str(p)!r} must hold R, G, B channels or a single channel to read as an image, "
            f"got channels {sorted(channels)} (use read_exr)"
        )
    return np.stack([channels[n] for n in names], axis=-1).astype(np.float32)


# -- OpenEXR ---------------------------------------------------------------------------------
def require_openexr():
    """The OpenEXR module, or :class:`DependencyError` saying how to install it (a broken environment)."""
    try:
        import OpenEXR
    except ImportError as exc:
        raise DependencyError(
            f"the OpenEXR package is not installed (needed to read and write .exr files): pip install OpenEXR ({exc})"
        ) from None
    return OpenEXR


def read_exr(path):
    """All channels of an EXR file and its string header attributes.

    Parameters
    ----------
    path : str or path-like
        An existing EXR file.

    Returns
    -------
    channels : dict of str to ndarray (H, W)
        As stored (float16 or float32; uint32 channels as uint32).  Subsampled
        channels (x or y sampling other than 1, as in luminance/chroma files) are refused.
    attributes : dict of str to str
        Header attributes whose values are strings.
    """
    OpenEXR = require_openexr()

    p = _path(path)
    try:
        with OpenEXR.File(str(p), separate_channels=True) as f:
            stored = f.channels()
            sub = {n: (c.xSampling, c.ySampling) for n, c in stored.items() if (c.xSampling, c.ySampling) != (1, 1)}
            channels = {} if sub else {name: np.array(ch.pixels) for name, ch in stored.items()}
            attrs = {k: v for k, v in f.header().items() if isinstance(v, str)}  # the header empties on close
    except Exception as exc:  # the bindings raise RuntimeError and others for bad files
        raise ImageFormatError(f"EXR file {str(p)!r} could not be read: {exc}") from exc
    if sub:  # a subsampled channel holds fewer pixels than the data window: it is no map of its texels
        raise ImageFormatError(f"EXR file {str(p)!r} must hold full-resolution channels, got (x, y) sampling {sub}")
    return channels, attrs


def read_exr_attributes(path) -> dict:
    """The string header attributes of an EXR file, without reading its pixels (see :func:`read_exr`).

    Parameters
    ----------
    path : str or path-like
        An existing EXR file.

    Returns
    -------
    dict of str to str
        Header attributes whose values are strings.

    Raises
    ------
    ValidationError
        ``path`` is not an existing file.
    ImageFormatError
        The file cannot be read as EXR.
    DependencyError
        The OpenEXR package is not installed.
    """
    OpenEXR = require_openexr()

    p = _path(path)
    try:
        with OpenEXR.File(str(p), header_only=True) as f:
            return {k: v for k, v in f.header().items() if isinstance(v, str)}
    except Exception as exc:  # the bindings raise RuntimeError and others for bad files
        raise ImageFormatError(f"EXR file {str(p)!r} could not be read: {exc}") from exc


#: Largest value of an integer EXR channel (stored as uint32).
_UINT32_MAX = 2**32 - 1


def write_exr(path, channels: dict, *, half: bool = False, attributes=None):
    """Write named 2-D channels (same shape) to an EXR file, ZIP-compressed.

    Parameters
    ----------
    path : str or path-like
        The file to write (its extension is not checked here).
    channels : dict of str to array_like, shape (H, W)
        At least one channel, named by a non-empty string.  Float channels must be finite; integer (and bool)
        channels are stored as uint32 and must hold values in [0, 4294967295].  An image array (H, W[, C]) is
        refused (its channels have no names here): write it with :func:`write_image`, which names 1, 3 or 4
        channels Y or R, G, B[, A].
    half : bool
        Store float channels as half floats instead of float32.
    attributes : dict, optional
        String header attributes (keys and values converted with ``str``).

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    ValidationError
        ``channels`` not a dict of named channels (an array, a list), no channel, a name that is not a non-empty
        string, channels that are not 2-D of one shape, a float channel with NaN or inf, a finite value
        beyond the range of the stored float type, or an integer channel with a value outside [0, 4294967295]
        (the message names the channel and the value).
    DependencyError
        The OpenEXR package is not installed.
    """
    if not isinstance(channels, Mapping):  # an ndarray raised numpy's "truth value ... is ambiguous"
        shape = f" of shape {np.shape(channels)}" if isinstance(channels, np.ndarray) else ""
        raise ValidationError(
            f"channels must be a dict of channel name to (H, W) array, e.g. {{'R': r, 'G': g, 'B': b}}, got "
            f"{type(channels).__name__}{shape}; write an (H, W[, C]) image with write_image"
        )
    bad = [k for k in channels if not isinstance(k, str) or not k]
    if bad:
        raise ValidationError(f"channels must be named by non-empty strings, got {bad[0]!r}")
    OpenEXR = require_openexr()

    p = _path(path, must_exist=False)
    if not channels:
        raise ValidationError("channels must name at least one channel, got none")
    shapes = {np.shape(v) for v in channels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValidationError(f"channels must be 2-D arrays of one shape, got shapes {sorted(shapes)}")
    data = {}
    for name, v in channels.items():
        a = np.asarray(v)
        if a.dtype.kind in "iub":
            lo, hi = (int(a.min()), int(a.max())) if a.size else (0, 0)
            if lo < 0 or hi > _UINT32_MAX:  # the cast would wrap: -1 stored as 4294967295, 2**33 as 0
                raise ValidationError(
                    f"channel {name!r} for {str(p)!r} must hold integers in [0, {_UINT32_MAX}] (stored as uint32), "
                    f"got {lo if lo < 0 else hi}"
                )
            data[name] = np.ascontiguousarray(a.astype(np.uint32))
        else:
            if not np.all(np.isfinite(a)):
                raise ValidationError(f"channel {name!r} must be finite to write {str(p)!r}, got NaN or inf")
            stored = np.float16 if half else np.float32
            data[name] = np.ascontiguousarray(as_float(a, f"channel {name!r} for {str(p)!r}", stored))
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for key, value in (attributes or {}).items():
        header[str(key)] = str(value)
    with OpenEXR.File(header, data) as f:
        f.write(str(p))
    return p


# -- Radiance RGBE ---------------------------------------------------------------------------
#: Radiance RGBE holds values below 2^127 (exponent byte 255): the largest a file can store.
_RGBE_LIMIT = 2.0**127

_RGBE_SIZE = re.compile(rb"^-Y (\d+) \+X (\d+)$")


def _rgbe_multipliers(line: bytes, key: bytes, count: int, p) -> np.ndarray:
    """The ``count`` multipliers of a header line ``KEY= v ...`` (finite, > 0)."""
    text = line[len(key) :].decode("ascii", "replace")
    try:
        values = np.array([float(v) for v in text.split()], np.float64)
    except ValueError:
        values = np.zeros(0)
    if values.size != count or not np.all(np.isfinite(values)) or np.any(values <= 0):
        raise ImageFormatError(
            f"Radiance file {str(p)!r} header {key.decode()} must hold {count} finite value(s) > 0, "
            f"got {text.strip()!r}"
        )
    return values


#: Longest header (bytes) a Radiance file may have before its empty line.
_RGBE_MAX_HEADER = 1 << 20


def _rgbe_header_lines(data: bytes, p):
    """The header lines of a Radiance file's bytes (without line ends) and the offset after its empty line; CRLF
    line ends are accepted (files written on Windows: "no end of header" before)."""
    header, pos = [], 0
    while True:
        nl = data.find(b"\n", pos, _RGBE_MAX_HEADER)
        if nl < 0:
            raise ImageFormatError(
                f"Radiance file {str(p)!r} has no end of header (an empty line) within its first "
                f"{_RGBE_MAX_HEADER // 1024} KiB"
            )
        line = data[pos:nl].rstrip(b"\r")
        pos = nl + 1
        if not line:
            return header, pos
        header.append(line)


def _rgbe_header(data: bytes, p):
    """(height, width, offset of the pixel data, the RGB multipliers applied to the pixels: the product of the
    ``EXPOSURE=`` and ``COLORCORR=`` lines) of a Radiance file's bytes."""
    if not (data.startswith(b"#?RADIANCE") or data.startswith(b"#?RGBE")):
        raise ImageFormatError(f"Radiance file {str(p)!r} must start with '#?RADIANCE' or '#?RGBE'")
    header, pos = _rgbe_header_lines(data, p)
    applied = np.ones(3)
    for line in header:
        if line.startswith(b"FORMAT=") and line.strip() != b"FORMAT=32-bit_rle_rgbe":
            shown = line.decode("ascii", "backslashreplace")[:60]
            raise ImageFormatError(f"Radiance file {str(p)!r} must be FORMAT=32-bit_rle_rgbe, got {shown!r}")
        if line.startswith(b"EXPOSURE="):
            applied *= _rgbe_multipliers(line, b"EXPOSURE=", 1, p)
        elif line.startswith(b"COLORCORR="):
            applied *= _rgbe_multipliers(line, b"COLORCORR=", 3, p)
    nl = data.find(b"\n", pos)
    size_line = data[pos : nl if nl >= 0 else len(data)].strip()
    m = _RGBE_SIZE.match(size_line) if len(size_line) <= 40 else None  # Python refuses ints of > 4300 digits
    if not m:
        raise ImageFormatError(
            f"Radiance file {str(p)!r} must have the resolution line '-Y H +X W', got {size_line[:40]!r}"
        )
    height, width = int(m.group(1)), int(m.group(2))
    if height < 1 or width < 1:
        raise ImageFormatError(f"Radiance file {str(p)!r} must have at least one pixel, got '-Y {height} +X {width}'")
    check_image_size(height, width, str(p))
    # Before allocating: each scanline takes at least 4 + 8 ceil(W / 127) bytes (run-length encoded, only for
    # 8 <= W < 32768: read_rgbe) or 4 W (flat).
    rle = 8 <= width < 32768
    least = height * (min(4 * width, 4 + 8 * -(-width // 127)) if rle else 4 * width)
    if nl < 0 or len(data) - (nl + 1) < least:
        raise ImageFormatError(
            f"Radiance file {str(p)!r} is truncated: '-Y {height} +X {width}' needs at least {least} bytes of "
            f"pixel data, the file holds {max(len(data) - (nl + 1), 0) if nl >= 0 else 0}"
        )
    return height, width, nl + 1, applied


def _rle_scanline(buf, pos, width, p, row):
    """Decode one new-style run-length-encoded scanline at ``pos``: (width, 4) uint8 and the next position."""
    out = np.empty((4, width), np.uint8)
    for c in range(4):  # four components, each run-length encoded on its own
        x = 0
        while x < width:  # loop over runs (not pixels): a run fills many pixels at once
            if pos >= len(buf):
                raise ImageFormatError(f"Radiance file {str(p)!r} is truncated in scanline {row}")
            count = buf[pos]
            if count > 128:  # a run of one value
                n = count - 128
                if x + n > width or pos + 1 >= len(buf):
                    raise ImageFormatError(f"Radiance file {str(p)!r} has a bad run in scanline {row}")
                out[c, x : x + n] = buf[pos + 1]
                pos += 2
            else:  # a literal stretch
                n = count
                if n == 0 or x + n > width or pos + 1 + n > len(buf):
                    raise ImageFormatError(f"Radiance file {str(p)!r} has a bad literal run in scanline {row}")
                out[c, x : x + n] = np.frombuffer(buf, np.uint8, n, pos + 1)
                pos += 1 + n
            x += n
    return out.T, pos


def read_rgbe(path) -> np.ndarray:
    """A Radiance RGBE file as float32 (H, W, 3) (module docstring for the decoding).

    Parameters
    ----------
    path : str or path-like
        An existing Radiance RGBE file (``.hdr``, ``.pic``).

    Returns
    -------
    ndarray of float32, shape (H, W, 3)
        Linear values, row 0 at the top, divided by the header's ``EXPOSURE`` × ``COLORCORR``.

    Raises
    ------
    ValidationError
        ``path`` is not an existing file.
    ImageFormatError
        A bad or oversized header (more than :data:`MAX_IMAGE_PIXELS`), a truncated file, an invalid run, or
        old-style run-length encoding.
    """
    p = _path(path)
    data = p.read_bytes()
    height, width, pos, applied = _rgbe_header(data, p)
    rgbe = np.empty((height, width, 4), np.uint8)
    rle = 8 <= width < 32768
    for row in range(height):  # loop over scanlines; each is decoded with array operations per run
        if rle and pos + 4 <= len(data) and data[pos : pos + 2] == b"\x02\x02" and not data[pos + 2] & 0x80:
            if (data[pos + 2] << 8 | data[pos + 3]) != width:
                raise ImageFormatError(f"Radiance file {str(p)!r} has a scanline of the wrong width at row {row}")
            rgbe[row], pos = _rle_scanline(data, pos + 4, width, p, row)
        else:  # flat scanline
            if pos + 4 * width > len(data):
                raise ImageFormatError(f"Radiance file {str(p)!r} is truncated in scanline {row}")
            flat = np.frombuffer(data, np.uint8, 4 * width, pos).reshape(width, 4)
            if np.any((flat[:, 0] == 1) & (flat[:, 1] == 1) & (flat[:, 2] == 1)):
                raise ImageFormatError(f"Radiance file {str(p)!r} uses old-style run-length encoding (unsupported)")
            rgbe[row] = flat
            pos += 4 * width
    e = rgbe[..., 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(np.float32(1), e - 136), 0).astype(np.float32)
    out = (rgbe[..., :3].astype(np.float32) + np.float32(0.5)) * scale[..., None]
    if np.any(applied != 1):  # the pixels before EXPOSURE / COLORCORR
        out = as_float(out / applied, f"Radiance file {str(p)!r} pixels divided by EXPOSURE × COLORCORR", np.float32)
    return out


def write_rgbe(path, image):
    """Write a float (H, W, 3) image (finite, ≥ 0) as a Radiance RGBE file with flat scanlines.

    Parameters
    ----------
    path : str or path-like
        The file to write (its extension is not checked here).
    image : array_like, shape (H, W, 3)
        Linear values, finite, ≥ 0 and below 2^127; a pixel whose largest component is below 1e-32 is written black.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    ValidationError
        ``image`` of another shape, with NaN, inf or negative values, or a value ≥ 2^127.
    """
    p = _path(path, must_exist=False)
    img = np.asarray(image, np.float64)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValidationError(f"image for a Radiance file must have shape (H, W, 3), got {img.shape}")
    if not np.all(np.isfinite(img)) or np.any(img < 0):
        raise ValidationError(f"image for a Radiance file must be finite and >= 0 ({str(p)!r})")
    v = img.max(axis=-1)
    if v.max(initial=0.0) >= _RGBE_LIMIT:
        i = np.unravel_index(int(np.argmax(v)), v.shape)
        raise ValidationError(
            f"image for a Radiance file must be below 2^127 (about 1.7e38, the largest RGBE value), got "
            f"{float(v[i])!r} at row {i[0]}, column {i[1]} ({str(p)!r})"
        )
    mant, exp = np.frexp(v)  # v = mant · 2^exp, mant in [0.5, 1)
    ok = v >= 1e-32
    scale = np.where(ok, mant * 256.0 / np.where(ok, v, 1), 0)
    rgbe = np.zeros(img.shape[:2] + (4,), np.uint8)
    rgbe[..., :3] = np.clip(np.floor(img * scale[..., None]), 0, 255).astype(np.uint8)
    rgbe[..., 3] = np.where(ok, exp + 128, 0).astype(np.uint8)
    header = f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {img.shape[0]} +X {img.shape[1]}\n".encode()
    p.write_bytes(header + rgbe.tobytes())
    return p


# -- PFM -------------------------------------------------------------------------------------
_PFM_HEADER = re.compile(rb"(P[Ff])\s+(\d+)\s+(\d+)\s+(\S+)\s")


def read_npy(path, what: str = "array") -> np.ndarray:
    """A numeric array from a ``.npy`` file (never a pickle), read once as a regular file.

    The header's shape and dtype are checked against the file's size before the
    array is built, so a damaged header cannot ask for more memory than the file
    holds; a FIFO or a device is refused, never read.

    Parameters
    ----------
    path : str or path-like
    what : str
        The array's name in messages (e.g. ``"region image"``).

    Returns
    -------
    ndarray
        The array.

    Raises
    ------
    FormatError
        The file cannot be read, is not a ``.npy`` file, or holds no numeric
        (bool, integer or float) array; the message names ``what`` and the file.
    """
    p = os.fspath(path)
    try:
        data = read_regular_file(p)
        f = io.BytesIO(data)
        version = np.lib.format.read_magic(f)
        header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, _, dtype = header(f)
        if dtype.hasobject or dtype.kind not in "biuf":
            raise FormatError(f"{what} {p} must hold a numeric .npy array, got dtype {dtype}")
        if math.prod(shape) * dtype.itemsize > len(data) - f.tell():
            raise FormatError(f"{what} {p} is truncated: its header declares shape {shape} of {dtype}")
        f.seek(0)
        return np.load(f, allow_pickle=False)
    except FormatError:
        raise
    except Exception as exc:  # numpy raises many types for a damaged file (ValueError, EOFError, SyntaxError, ...)
        raise FormatError(f"cannot read the {what} {p} as a .npy array: {exc}") from None


def read_pfm(path) -> np.ndarray:
    """A Portable Float Map as float32 (H, W, C), row 0 at the top (PFM stores rows bottom-up).

    Parameters
    ----------
    path : str or path-like
        An existing PFM file.

    Returns
    -------
    ndarray of float32, shape (H, W, C)
        C = 3 for ``PF``, 1 for ``Pf``; values as stored: the sign of the header's scale gives the byte order, its
        magnitude is not applied.

    Raises
    ------
    ValidationError
        ``path`` is not an existing file.
    ImageFormatError
        A bad header (width or height < 1, scale 0 or not finite) or a truncated file.
    """
    p = _path(path)
    data = p.read_bytes()
    m = _PFM_HEADER.match(data)
    if not m:
        raise ImageFormatError(f"PFM file {str(p)!r} must start with 'PF' or 'Pf', width, height and scale")
    try:
        width, height, scale = int(m.group(2)), int(m.group(3)), float(m.group(4))
    except ValueError as exc:
        raise ImageFormatError(f"PFM file {str(p)!r} has a bad header: {exc}") from exc
    if width < 1 or height < 1 or scale == 0 or not math.isfinite(scale):
        raise ImageFormatError(f"PFM file {str(p)!r} has a bad header: width {width}, height {height}, scale {scale}")
    n_ch = 3 if m.group(1) == b"PF" else 1
    offset = m.end()  # the header ends with exactly one whitespace byte after the scale
    count = width * height * n_ch
    if len(data) - offset < 4 * count:
        raise ImageFormatError(f"PFM file {str(p)!r} is truncated: {count} samples expected")
    arr = np.frombuffer(data, "<f4" if scale < 0 else ">f4", count, offset).astype(np.float32)
    return arr.reshape(height, width, n_ch)[::-1].copy()


def write_pfm(path, image):
    """Write a float (H, W, 1|3) image as a little-endian PFM file (rows stored bottom-up).

    Parameters
    ----------
    path : str or path-like
        The file to write (its extension is not checked here).
    image : array_like, shape (H, W), (H, W, 1) or (H, W, 3)
        Numeric values, stored as float32 (NaN and inf are written as they are).

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    ValidationError
        ``image`` of another shape, not numeric, or with a finite value beyond the float32 range.
    """
    p = _path(path, must_exist=False)
    img = as_float(image, f"image for {str(p)!r}", np.float32)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[2] not in (1, 3):
        raise ValidationError(f"image for PFM must have shape (H, W), (H, W, 1) or (H, W, 3), got {img.shape}")
    kind = b"PF" if img.shape[2] == 3 else b"Pf"
    header = kind + f"\n{img.shape[1]} {img.shape[0]}\n-1.0\n".encode()
    p.write_bytes(header + np.ascontiguousarray(img[::-1]).astype("<f4").tobytes())
    return p
