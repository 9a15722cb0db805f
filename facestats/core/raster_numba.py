"""The depth buffer of :func:`facestats.acquire.visibility.shadow_map`, compiled with numba.

Imported only when a shadow map is drawn with ``backend="numba"``: importing numba costs about a
second.  One loop over triangles: each is culled as :func:`facestats.acquire.visibility.shadow_map`'s
numpy path culls it (a non-finite projection or a vertex at or behind the eye), set up as
:func:`facestats.core.raster.triangle_setup` sets it up (bounding box, the power-of-two square box of
candidate pixels, twice the signed area), and its candidate pixel centres are tested with the same
float64 arithmetic in the same order as :func:`facestats.core.raster.triangle_coverage` (barycentrics
l0, l1 divided by the same denominator, l2 = 1 − l0 − l1, depth l0 z0 + l1 z1 + l2 z2), keeping the
nearest depth per pixel.  So the buffer equals the numpy path's bit for bit
(``tests/acquire/test_shadow_maps.py``).  Compiled without ``fastmath``: no reassociation or fused
multiply-add changes a result.  The box is kept in float64 and clipped to the grid before any
conversion to an integer, so a triangle that projects absurdly far (a vertex just in front of the eye,
even beyond 2⁶³ pixels) costs no more than the grid, converts no out-of-range float and still occludes
what it covers; the numpy path cannot draw such a triangle (its candidate box would not fit in memory).
One difference is left, on absurd input only: a vertex whose depth overflows to inf while its projection
stays finite gives NaN in the numpy path (0 · inf) and inf here.
"""

from __future__ import annotations

import numba
import numpy as np

from facestats.core.raster import EDGE_EPS

__all__ = ["nearest_depth"]


@numba.njit(cache=True, nogil=True)
def nearest_depth(x, y, z, faces, resolution, depth):
    """Lower ``depth`` (flat, resolution², float64) to the nearest covering triangle's depth, per pixel.

    Parameters
    ----------
    x, y, z : ndarray of float64, shape (V,)
        Vertices in the buffer's camera: pixel column, pixel row and depth along the view axis.
    faces : ndarray of int64, shape (F, 3)
        Vertex indices, each in [0, V).
    resolution : int
        Buffer side in pixels.
    depth : ndarray of float64, shape (resolution², )
        Lowered in place and returned.

    Returns
    -------
    ndarray
        ``depth``, lowered in place.
    """
    for t in range(faces.shape[0]):
        i, j, k = faces[t, 0], faces[t, 1], faces[t, 2]
        ax, ay, bx, by, cx, cy = x[i], y[i], x[j], y[j], x[k], y[k]
        z0, z1, z2 = z[i], z[j], z[k]
        finite = np.isfinite(ax) and np.isfinite(ay) and np.isfinite(bx) and np.isfinite(by)
        if not (finite and np.isfinite(cx) and np.isfinite(cy) and z0 > 0 and z1 > 0 and z2 > 0):
            continue
        d = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
        if not abs(d) > 1e-12:
            continue
        x0 = np.floor(min(ax, bx, cx) - 0.5)  # numpy's floor and ceil keep float64 (math's return int64)
        y0 = np.floor(min(ay, by, cy) - 0.5)
        x1 = np.ceil(max(ax, bx, cx) - 0.5)
        y1 = np.ceil(max(ay, by, cy) - 0.5)
        if x1 + 1 <= 0 or y1 + 1 <= 0 or x0 >= resolution or y0 >= resolution:
            continue  # the bounding box is off the grid
        side = max(x1 - x0 + 1, y1 - y0 + 1)
        box = 1.0
        while box < side:  # the power of two at or above the larger side
            box *= 2.0
        for py in range(int(max(y0, 0.0)), int(min(y0 + box, resolution))):
            cyp = py + 0.5
            for px in range(int(max(x0, 0.0)), int(min(x0 + box, resolution))):
                cxp = px + 0.5
                l0 = ((by - cy) * (cxp - cx) + (cx - bx) * (cyp - cy)) / d
                l1 = ((cy - ay) * (cxp - cx) + (ax - cx) * (cyp - cy)) / d
                l2 = 1 - l0 - l1
                if l0 >= EDGE_EPS and l1 >= EDGE_EPS and l2 >= EDGE_EPS:
                    zz = l0 * z0 + l1 * z1 + l2 * z2
                    q = py * resolution + px
                    if zz < depth[q]:
                        depth[q] = zz
    return depth
