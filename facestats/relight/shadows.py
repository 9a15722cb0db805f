"""Shadow maps of reflectance functions by brightness thresholding (Debevec et al. 2000 §4.4, Fig. 13).

"since the geometry is incomplete we instead compute the shadow map using
brightness thresholding on the original reflectance function": a light is
*lit* for a pixel when the function's luminance (here the plain sum R + G + B of the
linear values, not a photometric Y) there exceeds ``threshold``
times the function's maximum (a per-pixel relative threshold, so dark skin and
bright skin are treated alike).  On a lat-long light grid the binary map is
then cleaned morphologically — an opening removes isolated lit samples
(noise, interreflection speckle) and a closing fills isolated dark ones
(specular-free holes) — with a 3 × 3 neighbourhood that wraps around in
azimuth.  The result is compared with the geometric visibility of the virtual
light stage by :func:`shadow_agreement`, which ignores a band of ``band``
cells around the geometric boundary (the terminator and cast-shadow edges,
where the 64 × 32 sampling and the cos θ fall-off make any threshold
ambiguous).
"""

from __future__ import annotations

import numpy as np

from facestats.core.validate import as_scalar, check_finite, check_integer
from facestats.errors import ValidationError
from facestats.relight.field import as_field, is_grid

__all__ = ["threshold_shadow_maps", "shadow_agreement"]


def _wrap_morphology(lit, op, iterations):
    """Binary opening/closing on (n_phi, n_theta, ...) with a 3 × 3 element over the first two axes, θ wrapping.

    An opening or closing of ``iterations`` = c steps reads up to 2c cells away (c erosions, then c dilations), so
    2c + 1 cells are padded on each side; c + 1 left the seam's result depending on where the map starts in
    azimuth for c ≥ 2 (an audit).
    """

    pad = 2 * iterations + 1
    n_rows, n_cols = lit.shape[:2]
    # Columns wrap (modulo, so any pad fits any width); rows do not: beyond-pole cells repeat the nearest row
    # (no false edges).
    x = np.take(lit, np.arange(-pad, n_cols + pad) % n_cols, axis=1)
    x = np.take(x, np.clip(np.arange(-pad, n_rows + pad), 0, n_rows - 1), axis=0)
    struct = np.zeros((3, 3) + (1,) * (lit.ndim - 2), bool)
    struct[:, :, ...] = True
    y = op(x, structure=struct, iterations=iterations)
    return y[pad:-pad, pad:-pad]


def threshold_shadow_maps(field, threshold: float = 0.02, *, clean: int = 1):
    """Lit/shadowed map of every reflectance function: luminance > ``threshold`` × its maximum, cleaned.

    Parameters
    ----------
    field : xarray.Dataset or array_like
        A reflectance field, or an array (light dims..., y, x, 3) of its values.
    threshold : float
        Relative threshold in (0, 1).
    clean : int
        Iterations of the 3 × 3 opening and closing on a lat-long light grid (0: none;
        list fields are never cleaned, their lights have no grid neighbours).

    Returns
    -------
    ndarray of bool, shape (light dims..., y, x)
        True where the light reaches the pixel.
    """

    grid = True
    if hasattr(field, "data_vars") or hasattr(field, "dims"):
        f = as_field(field)
        grid = is_grid(f)
        vals = np.asarray(f["reflectance"].values, np.float32)
    else:
        vals = np.asarray(field, np.float32)
        grid = vals.ndim == 5
    t = as_scalar(threshold, "threshold", 0, 1, low_inclusive=False, high_inclusive=False)
    c = check_integer(clean, "clean", 0, 8)
    if vals.ndim not in (4, 5) or vals.shape[-1] != 3:
        raise ValidationError(
            f"field values must have shape (light dims..., y, x, 3) with one or two light dims, got {vals.shape}"
        )
    check_finite(vals, "field values")  # a NaN would compare as shadowed
    lum = vals.sum(-1)
    nl = 2 if grid else 1
    peak = lum.max(axis=tuple(range(nl)), keepdims=True)
    lit = (lum > t * peak) & (peak > 0)
    if grid and c:
        from scipy import ndimage

        lit = _wrap_morphology(lit, ndimage.binary_opening, c)
        lit = _wrap_morphology(lit, ndimage.binary_closing, c)
    return lit


def shadow_agreement(lit, visible, band: int = 1, mask=None) -> dict:
    """Agreement of a thresholded shadow map with geometric visibility, away from the boundaries.

    Parameters
    ----------
    lit, visible : array_like of bool, shape (n_phi, n_theta, y, x)
        Thresholded map and geometric visibility (light reaches the front side
        unoccluded) on a lat-long light grid.
    band : int
        Cells within ``band`` (3 × 3 steps, θ wrapping) of a change of ``visible``
        are excluded.
    mask : array_like of bool, shape (y, x), optional
        Pixels to compare (default all).

    Returns
    -------
    dict
        ``agreement`` (fraction of compared samples equal), ``compared``,
        ``false_lit`` and ``false_shadow`` counts, ``excluded`` (boundary samples).
    """
    from scipy import ndimage

    a = np.asarray(lit, bool)
    v = np.asarray(visible, bool)
    if a.shape != v.shape or a.ndim != 4:
        raise ValidationError(
            f"lit and visible must have the same shape (n_phi, n_theta, y, x), got {a.shape}, {v.shape}"
        )
    b = check_integer(band, "band", 0, 16)
    near = np.zeros_like(v)
    if b:
        grown = _wrap_morphology(v, ndimage.binary_dilation, b)
        shrunk = _wrap_morphology(v, ndimage.binary_erosion, b)
        near = grown & ~shrunk
    use = ~near
    if mask is not None:
        use &= np.asarray(mask, bool)[None, None]
    n = int(use.sum())
    if n == 0:
        raise ValidationError("no sample is left to compare (empty mask or band too wide)")
    return {
        "agreement": float((a == v)[use].mean()),
        "compared": n,
        "false_lit": int((a & ~v)[use].sum()),
        "false_shadow": int((~a & v)[use].sum()),
        "excluded": int((near & (np.ones_like(v) if mask is None else np.asarray(mask, bool)[None, None])).sum()),
    }
