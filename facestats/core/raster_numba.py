"""The depth buffer of :func:`facestats.acquire.visibility.shadow_map`, compiled with numba.

Imported only when a shadow map is drawn with ``backend="numba"``: importing numba costs about a
second.  One loop over triangles, each testing the same square box of candidate pixel centres as
:func:`facestats.core.raster.triangle_coverage` with the same float64 arithmetic in the same order
(barycentrics l0, l1 divided by the same denominator, l2 = 1 − l0 − l1, depth l0 z0 + l1 z1 + l2 z2)
and keeping the nearest depth per pixel, so the buffer equals the numpy path's bit for bit
(``tests/acquire/test_shadow_maps.py``).  Compiled without ``fastmath``: no reassociation or fused
multiply-add changes a result.
"""

from __future__ import annotations

import numba

from facestats.core.raster import EDGE_EPS

__all__ = ["nearest_depth"]


@numba.njit(cache=True, nogil=True)
def nearest_depth(ax, ay, bx, by, cx, cy, den, x0, y0, size, usable, z0, z1, z2, resolution, depth):
    """Lower ``depth`` (flat, resolution², float64) to the nearest covering triangle's depth, per pixel.

    Arguments as :func:`facestats.core.raster.triangle_setup` returns them, plus each triangle's three
    vertex depths ``z0, z1, z2``.
    """
    for t in range(ax.size):
        if not usable[t]:
            continue
        d = den[t]
        for oy in range(size[t]):
            py = y0[t] + oy
            if py < 0 or py >= resolution:
                continue
            cyp = py + 0.5
            for ox in range(size[t]):
                px = x0[t] + ox
                if px < 0 or px >= resolution:
                    continue
                cxp = px + 0.5
                l0 = ((by[t] - cy[t]) * (cxp - cx[t]) + (cx[t] - bx[t]) * (cyp - cy[t])) / d
                l1 = ((cy[t] - ay[t]) * (cxp - cx[t]) + (ax[t] - cx[t]) * (cyp - cy[t])) / d
                l2 = 1 - l0 - l1
                if l0 >= EDGE_EPS and l1 >= EDGE_EPS and l2 >= EDGE_EPS:
                    z = l0 * z0[t] + l1 * z1[t] + l2 * z2[t]
                    k = py * resolution + px
                    if z < depth[k]:
                        depth[k] = z
    return depth
