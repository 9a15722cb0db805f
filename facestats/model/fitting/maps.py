"""Stage 5 of the fit: lumitexel results to UV maps, with push-pull hole filling (Weyrich et al. 2006 §4, §5.3).

§4: "The data is densely interpolated using push-pull interpolation into texture
maps"; §5.3: "The data for lumitexels with a badly conditioned fit is
interpolated during creation of the BRDF coefficient texture."

* :func:`scatter_to_map` averages the values of the lumitexels that fall into
  each texel of a UV map.
* :func:`push_pull` fills holes (Gortler et al. 1996, "The Lumigraph", §3.2):
  *pull* builds a pyramid of weighted averages, halving the resolution until no
  cell is empty; *push* walks back up and gives every empty cell the value of its
  coarser parent (bilinearly interpolated from the parent level), so holes receive
  smooth data from their neighbourhood.  Known values are never changed.
* :func:`fill_flagged` treats flagged texels as holes (their values are replaced,
  their flags keep a record).
"""

from __future__ import annotations

import numpy as np

from facestats.core.validate import as_float, check_integer, check_shape
from facestats.errors import ValidationError

__all__ = ["scatter_to_map", "push_pull", "fill_flagged"]


def scatter_to_map(values, texel, size):
    """Average per-lumitexel values into a ``size``² map.

    Parameters
    ----------
    values : ndarray, shape (N, ...)
        Values per lumitexel (trailing dims kept, e.g. channels); NaN ignored.
    texel : ndarray of int, shape (N, 2)
        ``(v, u)`` texel of each lumitexel, in [0, size).
    size : int
        Side of the square map (≥ 1).

    Returns
    -------
    mean : ndarray, shape (size, size, ...)
        NaN where no lumitexel landed (float32 for float32 input, else float64;
        sums are accumulated in float64).
    count : ndarray of int, shape (size, size)
    """
    size = check_integer(size, "size", 1)
    v = as_float(values, "values")
    t = check_shape(np.asarray(texel), "texel", (v.shape[0] if v.ndim else None, 2))
    if t.dtype.kind not in "iu":
        raise ValidationError(f"texel must hold integer (v, u) indices, got dtype {t.dtype}")
    if t.size and (t.min() < 0 or t.max() >= size):
        raise ValidationError(f"texel must lie in [0, {size}), got indices {int(t.min())}..{int(t.max())}")
    flat = t[:, 0].astype(np.int64) * size + t[:, 1]
    trail = v.shape[1:]
    vv = v.reshape(v.shape[0], -1)
    dtype = np.float32 if vv.dtype == np.float32 else np.float64
    # Group the lumitexels by texel once; per component, sums over the groups (float64).
    where, group = np.unique(flat, return_inverse=True)
    sizes = np.bincount(group, minlength=where.size)
    mean = np.full((vv.shape[1], size * size), np.nan, dtype)
    for j in range(vv.shape[1]):  # loop over trailing components (channels), vectorised over lumitexels
        col = np.ascontiguousarray(vv[:, j])
        ok = np.isfinite(col)
        if ok.all():
            sums, cnts = np.bincount(group, weights=col, minlength=where.size), sizes
        else:
            sums = np.bincount(group, weights=np.where(ok, col, 0), minlength=where.size)
            cnts = np.bincount(group, weights=ok, minlength=where.size)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean[j, where] = sums / cnts
    count = np.zeros(size * size, np.int64)
    count[where] = sizes
    # (K, size²) -> (size, size, K): a transposed view, no copy.
    return mean.T.reshape((size, size) + trail), count.reshape(size, size)


def _pull(val, w):
    """One coarser level: weighted 2×2 averages (odd sizes padded with zero weight)."""
    h, wd = w.shape
    ph, pw = h % 2, wd % 2
    if ph or pw:
        val = np.pad(val, ((0, ph), (0, pw)) + ((0, 0),) * (val.ndim - 2))
        w = np.pad(w, ((0, ph), (0, pw)))
    ws = w.reshape(w.shape[0] // 2, 2, w.shape[1] // 2, 2)
    vs = (val * w[..., None]).reshape(ws.shape + val.shape[2:])
    wsum = ws.sum(axis=(1, 3))
    vsum = vs.sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        out = vsum / wsum[..., None]
    return np.where(wsum[..., None] > 0, out, 0), np.minimum(wsum, 1.0)


def _upsample(coarse, shape):
    """Bilinear upsampling by 2 of a coarse level (h, w, K), cropped to ``shape`` (cell-centred grids).

    Fine cell i lies at coarse coordinate i/2 − 1/4: along each axis an even
    cell takes 3/4 of its parent and 1/4 of the parent's previous neighbour, an
    odd cell 3/4 and 1/4 of the next one (edges clamped).  The pull step pads
    odd sizes at the end, so parent j always covers fine cells 2j and 2j + 1.
    Rows are interpolated on the edge-padded coarse grid, then each of the four
    (row, column) parities is written in one pass.
    """
    p = np.pad(coarse, ((1, 1), (1, 1), (0, 0)), mode="edge")
    h, w = coarse.shape[:2]
    fine = np.empty((2 * h, 2 * w) + coarse.shape[2:], coarse.dtype)
    for parity, rows in ((0, p[:-2]), (1, p[2:])):  # previous / next coarse row
        r = 0.75 * p[1:-1] + 0.25 * rows  # (h, w + 2, K)
        centre = 0.75 * r[:, 1:-1]
        np.add(centre, 0.25 * r[:, :-2], out=fine[parity::2, 0::2])
        np.add(centre, 0.25 * r[:, 2:], out=fine[parity::2, 1::2])
    return fine[: shape[0], : shape[1]]


def push_pull(image, known, fill=None):
    """Fill the unknown texels of an image by push-pull interpolation (module docstring).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, K)
        Values, finite where ``known``; entries where ``known`` is False are ignored.
    known : ndarray of bool, shape (H, W)
        Texels holding data.
    fill : ndarray of bool, shape (H, W), optional
        Texels to fill (default: all unknown ones).  Others keep ``image``'s value.

    Returns
    -------
    ndarray, shape of ``image``
    """
    dtype = np.float32 if np.asarray(image).dtype == np.float32 else np.float64  # float32 maps stay float32
    img = np.asarray(image, dtype)
    if img.ndim not in (2, 3):
        raise ValidationError(f"image must have shape (H, W) or (H, W, K), got shape {img.shape}")
    k = np.asarray(known, bool)
    if k.shape != img.shape[:2]:
        raise ValidationError(f"known must have shape {img.shape[:2]}, got {k.shape}")
    if not k.any():
        raise ValidationError("known must mark at least one texel with data, got none")
    finite = np.isfinite(img).all(-1) if img.ndim == 3 else np.isfinite(img)
    if not finite[k].all():  # a NaN among the known texels spread into every texel filled from it
        y, x = (int(v) for v in np.argwhere(k & ~finite)[0])
        raise ValidationError(
            f"image must be finite at the known texels, got {int((k & ~finite).sum())} non-finite (first at y={y}, "
            f"x={x}); mark them unknown (known=False) to have them filled"
        )
    squeeze = img.ndim == 2
    val = np.where(k[..., None] if not squeeze else k, img, 0)
    if squeeze:
        val = val[..., None]
    levels = [(val, k.astype(dtype))]
    while levels[-1][1].min() < 1 and max(levels[-1][1].shape) > 1:  # a 1 x N level still halves along N
        levels.append(_pull(*levels[-1]))
    # Push: from the coarsest level down, fill every empty cell from the parent.
    cur = levels[-1][0]
    for val_l, w_l in reversed(levels[:-1]):
        cur = _upsample(cur, w_l.shape)
        cur += w_l[..., None] * (val_l - cur)  # w val + (1 − w) parent
    out = cur[..., 0] if squeeze else cur
    if fill is not None and np.shape(fill) != k.shape:
        raise ValidationError(f"fill must have shape {k.shape}, got {np.shape(fill)}")
    target = ~k if fill is None else (np.asarray(fill, bool) & ~k)
    res = np.array(img, copy=True)
    res[target] = out[target]
    return res.astype(np.asarray(image).dtype if np.asarray(image).dtype.kind == "f" else np.float64, copy=False)


def fill_flagged(image, flagged, face):
    """Replace flagged face texels by push-pull interpolation of the unflagged face texels (§5.3).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, K)
    flagged, face : ndarray of bool, shape (H, W)
        Texels whose fit was flagged; texels that belong to the face.  Non-finite
        face texels are filled too.

    Returns
    -------
    ndarray, shape of ``image``
        Face texels that are flagged or non-finite replaced; others unchanged.
    """
    face = np.asarray(face, bool)
    flagged = np.asarray(flagged, bool)
    if flagged.shape != face.shape or np.shape(image)[:2] != face.shape:
        raise ValidationError(
            f"image, flagged and face must share (H, W), got shapes {np.shape(image)}, {flagged.shape} and {face.shape}"
        )
    known = face & ~flagged & np.all(np.isfinite(np.asarray(image).reshape(face.shape + (-1,))), axis=-1)
    return push_pull(image, known, fill=face & ~known)
