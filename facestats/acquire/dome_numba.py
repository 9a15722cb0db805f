"""The compiled twin of :meth:`facestats.acquire.dome.Dome.directions32` (which documents it and keeps the
numpy path).  Imported only when directions are computed with numba: importing numba costs about a second."""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["unit_directions32"]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def unit_directions32(targets, points):
    """Unit vectors (N, T, 3) from ``points`` (N, 3) towards ``targets`` (T, 3), float32.

    Computed in float64 as :meth:`facestats.acquire.dome.Dome.light_directions` computes them (offset,
    squared length summed x, y, z in that order, division by its square root; NaN for a point at a
    target), then rounded: the same bits.
    """
    n, m = points.shape[0], targets.shape[0]
    out = np.empty((n, m, 3), np.float32)
    for i in range(n):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        for j in range(m):
            dx, dy, dz = targets[j, 0] - px, targets[j, 1] - py, targets[j, 2] - pz
            r = np.sqrt(dx * dx + dy * dy + dz * dz)
            out[i, j, 0] = dx / r
            out[i, j, 1] = dy / r
            out[i, j, 2] = dz / r
    return out
