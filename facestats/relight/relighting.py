"""Relighting a reflectance field: the weighted sum of its images (Debevec et al. 2000 eq. 3-4).

L̂(x, y) = Σ_{θ,φ} R_xy(θ, φ) L(θ, φ) δA(θ, φ)          (eq. 4)

per colour channel, in linear radiometry: ``lighting`` holds L·δA per light
(:func:`facestats.relight.lighting.resample_probe`), the field R the image per
unit L·δA (:mod:`facestats.relight.field`).  The product is one float32 BLAS
matrix product over the lights for each image tile; fields on disk (or larger
than memory) are relit tile by tile from their zarr chunks.  :func:`relight_frames` relights one field under
many lightings (a turntable's frames) in the same single pass over its tiles.

The clothing term of §3.4 (Fig. 7) is :func:`tint_indirect`: with the subject
recorded in white and in black clothing, the difference is the light the
clothing reflects onto the face, which can be tinted and added back.  All of it
is linear in the lighting, so it applies to fields and to relit images alike.
"""

from __future__ import annotations

import math

import numpy as np

from facestats.core.progress import progress_bar
from facestats.core.validate import as_finite, as_float, check_shape
from facestats.errors import ValidationError
from facestats.relight.field import as_field, image_tiles, light_dims, light_table
from facestats.relight.lighting import resample_probe

__all__ = ["lighting_for", "relight", "relight_frames", "relight_block", "tint_indirect", "indirect_field"]


def lighting_for(field, probe, *, layout: str = "latlong", rotate: float = 0.0, supersample: int = 4):
    """L·δA of a light probe for the lights of ``field``, shape (light dims..., 3).

    A lat-long light-stage field gets the exact cell integrals; any other light
    set the spherical-Voronoi integrals (:func:`facestats.relight.lighting.resample_probe`).
    ``rotate`` rotates the environment about +y first (radians).  The field's own
    ``solid_angle`` is not used: the probe's integral over each light's cell already
    is L·δA (with ``solid_angles`` given to :func:`~facestats.relight.field.make_field`,
    e.g. a rig's calibration, pass ``lighting=`` computed from them instead).

    Parameters
    ----------
    field : xarray.Dataset
        A reflectance field; only its ``direction`` coordinate is read.
    probe : array_like, shape (H, W, 3)
        Linear radiance in ``layout`` (:func:`facestats.model.sphere.check_probe`).
    layout : {"latlong", "angular"}
    rotate : float
        Rotation of the environment about +y, radians (right-handed).
    supersample : int
        Sub-cells per probe pixel side for the Voronoi integration (and angular probes), 1-16.

    Returns
    -------
    numpy.ndarray of float64, shape (light dims..., 3)
        ∫_cell L dΩ per light and channel, in the probe's unit × sr.

    Raises
    ------
    ValidationError
        For a field that is not a reflectance field, or an invalid probe, layout, rotation or supersampling.
    """
    f = as_field(field)
    d = np.asarray(f["direction"].values, np.float64)
    return resample_probe(probe, d, layout=layout, rotate=rotate, supersample=supersample)


def _weights(field, lighting):
    """Lighting as a float32 (L, 3) matrix matching the field's lights (grey (L,) allowed)."""
    f = as_field(field)
    lshape = tuple(f.sizes[d] for d in light_dims(f))
    w = as_finite(lighting, "lighting", 0, None, dtype=np.float64)  # L·δA >= 0: subtract two relit images instead
    if w.shape in (lshape, (int(np.prod(lshape)),)):
        w = np.repeat(w.reshape(-1, 1), 3, axis=1)
    elif w.shape in (lshape + (3,), (int(np.prod(lshape)), 3)):
        w = w.reshape(-1, 3)
    else:
        raise ValidationError(
            f"lighting must hold L·δA per light of the field, shape {lshape + (3,)} or {lshape} (grey), "
            f"got {w.shape}; resample a probe with facestats.relight.lighting_for(field, probe)"
        )
    return as_float(w, "lighting", np.float32)


def relight_block(values, weights) -> np.ndarray:
    """Σ_l R[l, ..., c] W[l, c] for an array of light-major values (L, ..., 3) and weights (L, 3) or (F, L, 3).

    One float32 matrix product W.T (3F × L) @ R (L × P·3) that reads the block once; the F frames' three channel
    products are the diagonal blocks of its result (the off-diagonal ones are computed and dropped: cheaper, here,
    than copying each channel's strided values out for a product of its own).  Nothing is checked (overflow is
    left to :func:`check_relit`).

    Parameters
    ----------
    values : array_like, shape (L, ..., 3)
        Reflectance per light (light dims flattened into the first axis), read as float32.
    weights : numpy.ndarray, shape (L, 3) or (F, L, 3)
        L·δA per light and channel: one lighting, or F of them.

    Returns
    -------
    numpy.ndarray of float32, shape values.shape[1:] or (F,) + values.shape[1:]
        The relit values, one image per lighting.
    """
    r = np.asarray(values, np.float32)
    w = np.asarray(weights, np.float32)
    frames = w[None] if w.ndim == 2 else w
    n, f = r.shape[0], frames.shape[0]
    flat = r.reshape(n, -1)
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported by check_relit
        prod = np.swapaxes(frames, 1, 2).reshape(3 * f, n) @ flat  # (F·3, P·3)
    p3 = prod.reshape(f, 3, -1, 3)
    out = np.stack([p3[:, c, :, c] for c in range(3)], axis=-1).reshape((f,) + r.shape[1:])
    return out[0] if w.ndim == 2 else out


def relight(field, lighting=None, *, probe=None, layout: str = "latlong", rotate: float = 0.0, indirect=None,
            progress: bool = False):  # fmt: skip
    """Relight a reflectance field: L̂(x, y) = Σ R_xy(θ, φ) L(θ, φ) δA(θ, φ) (Debevec et al. 2000 eq. 4).

    Parameters
    ----------
    field : xarray.Dataset
        A reflectance field, in memory or opened from zarr (:func:`facestats.relight.field.open_field`):
        then it is read one chunk tile at a time.
    lighting : array_like, optional
        L·δA per light: shape (light dims..., 3), (L, 3), or grey (light dims...) / (L,).
    probe : array_like, optional
        Instead of ``lighting``: a light probe (H, W, 3), resampled to the field's
        lights (:func:`lighting_for` with ``layout`` and ``rotate``).
    layout : {"latlong", "angular"}
    rotate : float
        Rotation of the probe about +y, radians (only with ``probe``).
    indirect : tuple (field, tint), optional
        The clothing term of §3.4: an indirect-light field (:func:`indirect_field`)
        relit with the same lighting, times the RGB ``tint``, is added.
    progress : bool
        Progress bar over tiles (fields on disk).

    Returns
    -------
    ndarray of float32, shape (y, x, 3)
        Linear radiance in the unit of the lighting (per sr).
    """
    f = as_field(field)
    if (lighting is None) == (probe is None):
        raise ValidationError("pass exactly one of lighting (L·δA per light) and probe (an environment image)")
    if probe is not None:
        lighting = lighting_for(f, probe, layout=layout, rotate=rotate)
    elif rotate:
        raise ValidationError("rotate applies to a probe; rotate per-light lighting with the probe before resampling")
    w = _weights(f, lighting)
    ind = tint = None
    if indirect is not None:  # checked before the relight, which may take long
        if not isinstance(indirect, tuple) or len(indirect) != 2:
            got = f"a tuple of {len(indirect)}" if isinstance(indirect, tuple) else type(indirect).__name__
            raise ValidationError(f"indirect must be a tuple of two, (field, tint), got {got}")
        ind = as_field(indirect[0])
        if (ind.sizes["y"], ind.sizes["x"]) != (f.sizes["y"], f.sizes["x"]):
            raise ValidationError(
                f"indirect field must have the field's image size {f.sizes['y']} x {f.sizes['x']}, got "
                f"{ind.sizes['y']} x {ind.sizes['x']}"
            )
        tint = check_shape(as_finite(indirect[1], "tint", 0, None, dtype=np.float32), "tint", (3,))
    out = _relight_weights(f, w[None], progress)[0]
    if ind is not None:
        out = out + tint * _relight_weights(ind, _weights(ind, lighting)[None], progress)[0]
    return check_relit(out, "relight")


def relight_frames(field, lightings, *, progress: bool = False) -> np.ndarray:
    """Relit images of one field under F lightings, in one pass over its tiles (Debevec et al. 2000 eq. 4).

    Image k equals :func:`relight` ``(field, lightings[k])`` (up to float32 summation order): the frames of a
    turntable, or several probes, at the cost of reading the field once.  Reading its tiles dominates a relight of a
    field on disk: on a 256² stage field of 2,048 lights (float32 zarr, 165 MB) one frame took 3.0 s and 36 frames
    5.0 s (one-offs on a shared machine, 2026-12-08).  Memory: the F images (F × y × x × 3 float32) besides one tile's
    values; pass the lightings in batches to bound it.

    Parameters
    ----------
    field : xarray.Dataset
        A reflectance field, in memory or opened from zarr (:func:`facestats.relight.field.open_field`).
    lightings : array_like, shape (F, light dims..., 3), (F, L, 3), or grey (F, light dims...) / (F, L)
        L·δA per light of each frame (:func:`lighting_for`), ≥ 0; F ≥ 1.
    progress : bool
        Progress bar over tiles (fields on disk).

    Returns
    -------
    ndarray of float32, shape (F, y, x, 3)
        Linear radiance in the unit of the lightings (per sr).

    Raises
    ------
    ValidationError
        A field that is not a reflectance field, no lighting, a lighting of another shape or negative, or a relit
        value that is not finite (:func:`check_relit`, naming the frame).
    """
    f = as_field(field)
    w = np.stack([_weights(f, x) for x in _frames_of(lightings)])  # each checked as relight checks its lighting
    out = _relight_weights(f, w, progress)
    for k in range(out.shape[0]):
        check_relit(out[k], f"relight, frame {k}")
    return out


def _frames_of(lightings):
    """The lightings as a non-empty list of per-frame arrays (an array's first axis, or a sequence)."""
    if isinstance(lightings, np.ndarray) or not isinstance(lightings, (list, tuple)):
        a = np.asarray(lightings)
        if a.ndim < 2:
            raise ValidationError(
                f"lightings must hold one lighting per frame, shape (F, L, 3) or (F, light dims..., 3), got {a.shape}"
            )
        lightings = list(a)
    if not lightings:
        raise ValidationError("lightings must hold at least one lighting, got none")
    return lightings


def check_relit(image, what: str) -> np.ndarray:
    """``image`` (y, x, 3) if every value is finite; else a :class:`ValidationError` naming the first pixel.

    A relit value is not finite when the field holds NaN or inf at that pixel (under a light with L·δA ≠ 0),
    or when finite values overflow float32 (lighting brighter than about 1e38 / the reflectance).
    """
    bad = ~np.isfinite(image)
    if bad.any():
        y, x, c = (int(v) for v in np.argwhere(bad)[0])
        raise ValidationError(
            f"{what}: the relit value at pixel (y={y}, x={x}), channel {c} is {float(image[y, x, c])!r} "
            f"({int(bad.sum())} non-finite value(s)): the field holds NaN or inf there, or the lighting times the "
            "reflectance exceeds the float32 range"
        )
    return image


#: Bytes of the product of one block of :func:`relight_block` (F·3 × P·3 float32) that :func:`_relight_weights`
#: allows an in-memory field's frames before it cuts the image into tiles.
_PRODUCT_BYTES = 1 << 26


def _relight_weights(f, w, progress):
    """Relit images (F, y, x, 3) of a validated field with (F, L, 3) float32 weights, by tiles when the field is
    chunked (or the F frames' product over the whole image would exceed :data:`_PRODUCT_BYTES`)."""
    refl = f["reflectance"]
    nl = len(light_dims(f))
    n = int(np.prod(refl.shape[:nl]))
    h, wd = f.sizes["y"], f.sizes["x"]
    frames = w.shape[0]
    per_pixel = 36 * frames  # bytes of relight_block's product per pixel: (F·3 × 3) float32
    if refl.chunks is None and (frames == 1 or per_pixel * h * wd <= _PRODUCT_BYTES):  # in memory: one product
        vals = np.asarray(refl.values).reshape((n,) + refl.shape[nl:])
        return relight_block(vals, w)
    tile = None if refl.chunks is not None else max(1, math.isqrt(_PRODUCT_BYTES // per_pixel))
    out = np.zeros((frames, h, wd, 3), np.float32)
    for ys, xs in progress_bar(image_tiles(f, tile), desc="relight tiles", enabled=progress, leave=False):
        block = np.asarray(refl.isel(y=ys, x=xs).values, np.float32)
        out[:, ys, xs] = relight_block(block.reshape((n,) + block.shape[nl:]), w)
    return out


def indirect_field(white, black):
    """The light reflected onto the face by white clothing: field(white) − field(black) (§3.4, Fig. 7).

    Both fields must share their lights and image size (captured with the same
    stage and camera).  Negative differences (noise) are kept: the sum
    black + tint · difference reproduces the white capture exactly at tint 1.

    Parameters
    ----------
    white, black : xarray.Dataset
        Reflectance fields of the subject in white and in black clothing.

    Returns
    -------
    xarray.Dataset
        A copy of ``black`` with ``reflectance`` = white − black (lazy if the inputs are) and the attributes
        ``source`` and ``signed`` = True.

    Raises
    ------
    ValidationError
        If either is not a reflectance field, their ``reflectance`` shapes differ, or their light directions do
        not match (:func:`numpy.allclose`).
    """
    w, b = as_field(white), as_field(black)
    if w["reflectance"].shape != b["reflectance"].shape:
        raise ValidationError(
            "white and black fields must have the same shape, got "
            f"{w['reflectance'].shape} and {b['reflectance'].shape}"
        )
    if not np.allclose(light_table(w)[0], light_table(b)[0]):
        raise ValidationError("white and black fields must share their light directions")
    out = b.copy()
    out["reflectance"] = w["reflectance"] - b["reflectance"]
    out["reflectance"].attrs.update(b["reflectance"].attrs)
    out.attrs["source"] = "indirect light from clothing (white - black), Debevec et al. 2000 §3.4"
    out.attrs["signed"] = True  # differences: relights may be negative (CompressedField.nonnegative)
    return out


def tint_indirect(black, white, tint):
    """Debevec et al. 2000 §3.4 (Fig. 7): black + tint · (white − black), for images or arrays of the same shape.

    ``tint`` is an RGB reflectance of the new clothing relative to the white
    one (1, 1, 1 gives the white capture; 0 the black one).  Linear, so it
    commutes with relighting: tinting relit images equals relighting tinted
    fields.

    Parameters
    ----------
    black, white : array_like, shape (..., 3)
        Images (or field values) under black and white clothing, finite, the same shape.
    tint : array_like, shape (3,)
        RGB tint, finite and ≥ 0.

    Returns
    -------
    numpy.ndarray of float32, shape of ``black``

    Raises
    ------
    ValidationError
        For non-finite inputs, mismatched shapes, a last axis other than 3, or a negative tint.
    """
    b = as_finite(black, "black", dtype=np.float32)
    w = as_finite(white, "white", dtype=np.float32)
    if b.shape != w.shape or b.shape[-1:] != (3,):
        raise ValidationError(f"black and white must have the same shape (..., 3), got {b.shape} and {w.shape}")
    t = check_shape(as_finite(tint, "tint", 0, None, dtype=np.float32), "tint", (3,))
    return b + t * (w - b)
