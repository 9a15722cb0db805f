"""Displacement (height) maps as files: user-supplied neutral microstructure maps and rendered frames.

Nagano et al. 2015 §5: the neutral microstructure map "can come from any
source".  :func:`read_displacement` reads one through :mod:`facestats.io.images`:

* float files (``.exr``, ``.pfm``, ``.hdr``): heights as stored, in µm, unless
  an EXR carries a ``units`` attribute of ``mm`` or ``m`` (converted);
* floating-point TIFF (``.tif``/``.tiff`` with SampleFormat IEEE float, read by
  ``tifffile``): heights as stored, in µm;
* integer files (16-bit ``.png``, ``.tif``/``.tiff``; 8-bit accepted with a
  :class:`~facestats.errors.QuantisationWarning`: 256 levels quantise a height
  map coarsely): codes scaled to [0, 1] by :func:`facestats.io.images.read_image`,
  then mapped to ``(value − midpoint) · height_range_um`` — the range must be
  given, an integer image carries no unit.

A map must have one channel (or identical R, G, B); it is returned as float32
``[v, u]`` (row 0 at the top, the image convention facestats' UV maps share).
:func:`write_displacement` writes a map to EXR with ``units = um``.
"""

from __future__ import annotations

import io
import os
import pathlib
import warnings

import numpy as np

from facestats.errors import FormatError, QuantisationWarning, ValidationError
from facestats.io.images import INTEGER_EXTENSIONS, read_exr, read_image, read_integer_image, write_exr
from facestats.io.layout import read_regular_file

__all__ = ["read_displacement", "write_displacement"]

_UNITS_TO_UM = {"um": 1.0, "µm": 1.0, "micron": 1.0, "mm": 1000.0, "m": 1e6}


def _tiff_page(data: bytes, path):
    """``(dtype, axes, shape)`` of the first image of a TIFF file's bytes, or :class:`FormatError` naming the file."""
    import tifffile

    try:
        with tifffile.TiffFile(io.BytesIO(data)) as tif:
            page = tif.pages.first
            dtype, axes, shape = page.dtype, page.axes, page.shape
    except Exception as exc:  # tifffile raises many types for a damaged header
        raise FormatError(f"displacement map {str(path)!r} is not a readable TIFF file: {exc}") from None
    if dtype is None:  # no sample format or no strips: nothing to decode
        raise FormatError(f"displacement map {str(path)!r} is not a readable TIFF file: its first image has no data")
    return np.dtype(dtype), axes, shape


def _float_tiff(path):
    """``(bytes, axes, shape)`` of a TIFF file whose first image holds floating-point samples, else None."""
    try:
        data = read_regular_file(path)  # a FIFO or a device is refused, never read
    except OSError as exc:
        raise FormatError(f"cannot read the displacement map {str(path)!r}: {exc}") from None
    dtype, axes, shape = _tiff_page(data, path)
    return (data, axes, shape) if dtype.kind == "f" else None


def _read_float_tiff(data: bytes, axes: str, shape, path):
    """The first page of a float TIFF as (H, W, C) float32: samples last, also for planar files ('SYX')."""
    import tifffile

    from facestats.io.images import check_image_size

    if set(axes) - set("YXS") or not {"Y", "X"} <= set(axes):
        raise FormatError(f"displacement map {str(path)!r} must be one 2-D image, got TIFF axes {axes!r} {shape}")
    check_image_size(shape[axes.index("Y")], shape[axes.index("X")], str(path))
    try:
        img = tifffile.imread(io.BytesIO(data), key=0)
    except Exception as exc:  # tifffile and imagecodecs raise many types for damaged data
        raise FormatError(f"displacement map {str(path)!r} could not be decoded: {exc}") from None
    order = [axes.index(a) for a in "YXS" if a in axes]
    img = np.asarray(np.transpose(img, order), np.float32)
    return img[..., None] if img.ndim == 2 else img


def _one_channel(img, path):
    if img.ndim == 3 and img.shape[2] > 1:
        if not np.allclose(img[..., 1:3], img[..., :1]):
            raise FormatError(f"displacement map {path} must have one channel (or equal R, G, B), got {img.shape[2]}")
    return img[..., 0] if img.ndim == 3 else img


def read_displacement(path, *, height_range_um=None, midpoint=0.5) -> np.ndarray:
    """A displacement map in µm from an EXR/PFM/HDR, float TIFF or 8/16-bit PNG/TIFF file (module docstring).

    Parameters
    ----------
    path : path-like
    height_range_um : float, optional
        Integer files: µm spanned by the code range 0 … max (required for them; refused for float files,
        which are in µm already: a range given for one would be silently ignored).
    midpoint : float
        Integer files: the code fraction that means height 0.

    Returns
    -------
    ndarray of float32, shape (H, W)
    """
    p = pathlib.Path(os.fspath(path))
    ext = p.suffix.lower()
    float_tiff = _float_tiff(p) if ext in (".tif", ".tiff") else None
    if (float_tiff or ext not in INTEGER_EXTENSIONS) and height_range_um is not None:
        raise ValidationError(
            f"height_range_um applies to integer images only: {str(p)!r} holds floating-point heights in um "
            f"already, got {height_range_um!r}"
        )
    if float_tiff:
        h = _one_channel(_read_float_tiff(*float_tiff, p), p)
    elif ext in INTEGER_EXTENSIONS:
        if height_range_um is None:
            raise ValidationError(
                f"height_range_um must be given for the integer image {str(p)!r} (its codes carry no unit), got None"
            )
        rng = float(height_range_um)
        if not (np.isfinite(rng) and rng > 0):
            raise ValidationError(f"height_range_um must be > 0, got {height_range_um!r}")
        _, bits = read_integer_image(p)
        if bits <= 8:
            warnings.warn(
                f"displacement map {str(p)!r} has {bits}-bit codes: {2**bits} height levels over "
                f"{rng:g} um ({rng / (2**bits - 1):.3g} um per level); a 16-bit or float file keeps the fine relief",
                QuantisationWarning,
                stacklevel=2,
            )
        h = (_one_channel(read_image(p), p) - np.float32(midpoint)) * np.float32(rng)
    else:
        factor = 1.0
        if ext == ".exr":
            _, attrs = read_exr(p)
            unit = attrs.get("units", "um").strip().lower()
            if unit not in _UNITS_TO_UM:
                raise FormatError(
                    f"displacement map {str(p)!r} has units {unit!r}; expected one of {sorted(_UNITS_TO_UM)}"
                )
            factor = _UNITS_TO_UM[unit]
        h = _one_channel(read_image(p), p) * np.float32(factor)
    if not np.all(np.isfinite(h)):
        raise FormatError(
            f"displacement map {str(p)!r} must be finite, got {int(np.sum(~np.isfinite(h)))} NaN/inf texels"
        )
    return np.ascontiguousarray(h, np.float32)


def write_displacement(path, displacement, *, attributes=None):
    """Write a displacement map (µm) to an EXR file (single channel ``Y``, ``units = um``).

    Parameters
    ----------
    path : str or path-like
        The file to write; must end in ``.exr``.
    displacement : array_like, shape (H, W)
        Heights in µm, row 0 at the top; stored as float32 (must be finite: :func:`facestats.io.images.write_exr`).
    attributes : dict, optional
        Further string header attributes (values converted with ``str``); a ``units`` entry here replaces ``um``.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    ValidationError
        ``path`` does not end in ``.exr``, or ``displacement`` is not 2-D (or not finite).
    """
    p = pathlib.Path(os.fspath(path))
    if p.suffix.lower() != ".exr":
        raise ValidationError(f"path must end in .exr, got {str(p)!r}")
    d = np.asarray(displacement, np.float32)
    if d.ndim != 2:
        raise ValidationError(f"displacement must be a 2-D map, got shape {d.shape}")
    return write_exr(p, {"Y": d}, attributes={"units": "um", **(attributes or {})})
