"""Relighting a reflectance field: the weighted sum of its images (Debevec et al. 2000 eq. 3-4).

L̂(x, y) = Σ_{θ,φ} R_xy(θ, φ) L(θ, φ) δA(θ, φ)          (eq. 4)

per colour channel, in linear radiometry: ``lighting`` holds L·δA per light
(:func:`facestats.relight.lighting.resample_probe`), the field R the image per
unit L·δA (:mod:`facestats.relight.field`).  The product is one float32 BLAS
matrix product over the lights for each image tile; fields on disk (or larger
than memory) are relit tile by tile from their zarr chunks.

The clothing term of §3.4 (Fig. 7) is :func:`tint_indirect`: with the subject
recorded in white and in black clothing, the difference is the light the
clothing reflects onto the face, which can be tinted and added back.  All of it
is linear in the lighting, so it applies to fields and to relit images alike.
"""

from __future__ import annotations

import numpy as np

from facestats.core.progress import progress_bar
from facestats.core.validate import as_finite, as_float, check_shape
from facestats.errors import ValidationError
from facestats.relight.field import as_field, image_tiles, light_dims, light_table
from facestats.relight.lighting import resample_probe

__all__ = ["lighting_for", "relight", "relight_block", "tint_indirect", "indirect_field"]


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
    """Σ_l R[l, ..., c] W[l, c] for an array of light-major values (L, ..., 3) and weights (L, 3).

    One float32 matrix product W.T (3 × L) @ R (L × P·3) that reads the block once;
    the three channel products are the diagonal blocks of its result.  Nothing is checked (overflow is left to
    :func:`check_relit`).

    Parameters
    ----------
    values : array_like, shape (L, ..., 3)
        Reflectance per light (light dims flattened into the first axis), read as float32.
    weights : numpy.ndarray, shape (L, 3)
        L·δA per light and channel.

    Returns
    -------
    numpy.ndarray of float32, shape (...) + (3,)
        The relit values, ``values.shape[1:]``.
    """
    r = np.asarray(values, np.float32)
    n = r.shape[0]
    flat = r.reshape(n, -1)
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported by check_relit
        prod = weights.T.astype(np.float32) @ flat  # (3, P·3)
    p3 = prod.reshape(3, -1, 3)
    return np.stack([p3[c, :, c] for c in range(3)], axis=-1).reshape(r.shape[1:])


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
    out = _relight_weights(f, w, progress)
    if ind is not None:
        out = out + tint * _relight_weights(ind, _weights(ind, lighting), progress)
    return check_relit(out, "relight")


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


def _relight_weights(f, w, progress):
    """Relit image of a validated field with (L, 3) float32 weights, by tiles when the field is chunked."""
    refl = f["reflectance"]
    nl = len(light_dims(f))
    n = int(np.prod(refl.shape[:nl]))
    if refl.chunks is None:  # in memory
        vals = np.asarray(refl.values).reshape((n,) + refl.shape[nl:])
        return relight_block(vals, w)
    out = np.zeros((f.sizes["y"], f.sizes["x"], 3), np.float32)
    for ys, xs in progress_bar(image_tiles(f), desc="relight tiles", enabled=progress, leave=False):
        block = np.asarray(refl.isel(y=ys, x=xs).values, np.float32)
        out[ys, xs] = relight_block(block.reshape((n,) + block.shape[nl:]), w)
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
