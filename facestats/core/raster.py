"""Which pixel centres each triangle of a 2-D triangle soup covers, with barycentric coordinates.

The one rasteriser of facestats, shared by the shadow maps of
:mod:`facestats.acquire.visibility` (depth buffers from viewpoints) and the
texture-space rasterisation of :mod:`facestats.model.strain` (per-vertex
quantities interpolated into UV texels).

Pixel ``(row, col)`` has its centre at ``(x, y) = (col + 0.5, row + 0.5)``; a
centre is covered when its three barycentric coordinates are ≥ −1e-6 (shared
edges are covered by both triangles).  Triangles are grouped by the power-of-two
size of their pixel bounding box; each group tests all its candidate pixels at
once, in chunks of at most ``max_candidates`` pixels.  The loops run over size
groups and chunks, never over triangles or pixels.
"""

from __future__ import annotations

import numpy as np

__all__ = ["triangle_coverage", "triangle_setup"]

#: Barycentric tolerance of the inside test.
EDGE_EPS = -1e-6


def triangle_coverage(x, y, triangles, width, height, *, max_candidates=2_000_000):
    """Yield the covered pixel centres of every triangle, group by group.

    Parameters
    ----------
    x, y : ndarray, shape (V,)
        Vertex positions in pixel units (x along columns, y along rows).
    triangles : ndarray of int, shape (F, 3)
        Vertex indices.  Triangles with a non-finite vertex or a (near) zero
        pixel area (|2A| ≤ 1e-12) cover nothing.
    width, height : int
        Size of the pixel grid; pixels outside it are never reported.
    max_candidates : int
        Largest number of candidate pixels tested at once (memory bound).

    Yields
    ------
    tri : ndarray of int, shape (K,)
        Index into ``triangles`` of each covered pixel's triangle.
    row, col : ndarray of int, shape (K,)
        The covered pixel.
    l0, l1, l2 : ndarray of float, shape (K,)
        Barycentric coordinates of the pixel centre (weights of the triangle's
        first, second and third vertex; they sum to 1).
    """
    triangles = np.asarray(triangles, np.int64)
    ax, ay, bx, by, cx, cy, den, x0, y0, classes, usable = triangle_setup(x, y, triangles, width, height)
    for s in np.unique(classes[usable]):
        sel = np.nonzero((classes == s) & usable)[0]
        step = max(1, int(max_candidates) // int(s * s))
        oy, ox = np.mgrid[0:s, 0:s]
        for start in range(0, sel.size, step):
            t = sel[start : start + step]
            px = x0[t, None, None] + ox[None]  # pixel indices
            py = y0[t, None, None] + oy[None]
            cxp, cyp = px + 0.5, py + 0.5  # pixel centres
            d = den[t, None, None]
            l0 = (
                (by[t, None, None] - cy[t, None, None]) * (cxp - cx[t, None, None])
                + (cx[t, None, None] - bx[t, None, None]) * (cyp - cy[t, None, None])
            ) / d
            l1 = (
                (cy[t, None, None] - ay[t, None, None]) * (cxp - cx[t, None, None])
                + (ax[t, None, None] - cx[t, None, None]) * (cyp - cy[t, None, None])
            ) / d
            l2 = 1 - l0 - l1
            inside = (
                (l0 >= EDGE_EPS)
                & (l1 >= EDGE_EPS)
                & (l2 >= EDGE_EPS)
                & (px >= 0)
                & (py >= 0)
                & (px < width)
                & (py < height)
            )
            if not inside.any():
                continue
            tri = np.broadcast_to(t[:, None, None], inside.shape)[inside]
            yield tri, py[inside], px[inside], l0[inside], l1[inside], l2[inside]


def triangle_setup(x, y, triangles, width, height):
    """Per-triangle set-up of :func:`triangle_coverage`: vertices, edge-function denominator, candidate box.

    The compiled depth buffer (:mod:`facestats.core.raster_numba`) tests the same candidates with the same
    arithmetic.

    Parameters
    ----------
    x, y : array_like, shape (V,)
        Vertex positions in pixel units (x along columns, y along rows).
    triangles : array_like of int, shape (F, 3)
        Vertex indices.
    width, height : int
        Size of the pixel grid.

    Returns
    -------
    tuple of ndarray
        ``(ax, ay, bx, by, cx, cy, den, x0, y0, size, usable)``, each of shape (F,): the three
        vertices in pixel units (float64; a triangle with a non-finite vertex has all three replaced by 0),
        den = (by − cy)(ax − cx) + (cx − bx)(ay − cy) (twice the signed area), the first candidate column and
        row (int64), the side of the square candidate box (int64, the power of two at or above the bounding
        box's larger side) and whether the triangle can cover anything (bool: finite, |den| > 1e-12, its box
        on the grid).
    """
    triangles = np.asarray(triangles, np.int64)
    tx, ty = np.asarray(x, float)[triangles], np.asarray(y, float)[triangles]  # (F, 3)
    finite = np.all(np.isfinite(tx) & np.isfinite(ty), axis=1)
    tx, ty = np.where(finite[:, None], tx, 0.0), np.where(finite[:, None], ty, 0.0)
    x0 = np.floor(tx.min(1) - 0.5).astype(np.int64)
    y0 = np.floor(ty.min(1) - 0.5).astype(np.int64)
    w = np.ceil(tx.max(1) - 0.5).astype(np.int64) - x0 + 1
    h = np.ceil(ty.max(1) - 0.5).astype(np.int64) - y0 + 1
    size = np.maximum(w, h)
    # Barycentric set-up (edge functions) of every triangle.
    ax, ay, bx, by, cx, cy = tx[:, 0], ty[:, 0], tx[:, 1], ty[:, 1], tx[:, 2], ty[:, 2]
    den = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
    # Triangles entirely off the grid cover nothing.
    on_grid = (x0 + w > 0) & (y0 + h > 0) & (x0 < width) & (y0 < height)
    usable = finite & (np.abs(den) > 1e-12) & on_grid
    classes = 2 ** np.ceil(np.log2(np.maximum(size, 1))).astype(np.int64)
    return ax, ay, bx, by, cx, cy, den, x0, y0, classes, usable
