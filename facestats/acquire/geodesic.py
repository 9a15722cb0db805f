"""Points on the sphere for dome layouts: geodesic (subdivided icosahedron) vertices and farthest-point subsets."""

from __future__ import annotations

import numpy as np

__all__ = ["geodesic_points", "farthest_point_subset"]


def geodesic_points(frequency: int = 4) -> np.ndarray:
    """Vertices of a geodesic sphere: an icosahedron, each edge split ``frequency`` times, on the unit sphere.

    Parameters
    ----------
    frequency : int
        Segments per icosahedron edge, ≥ 1.

    Returns
    -------
    ndarray of float64, shape (10·frequency² + 2, 3)
        Unit vectors, each vertex once (in the order first met over the faces).
    """
    t = (1 + 5**0.5) / 2
    v = np.array(
        [
            [-1, t, 0],
            [1, t, 0],
            [-1, -t, 0],
            [1, -t, 0],
            [0, -1, t],
            [0, 1, t],
            [0, -1, -t],
            [0, 1, -t],
            [t, 0, -1],
            [t, 0, 1],
            [-t, 0, -1],
            [-t, 0, 1],
        ],
        float,
    )
    faces = np.array(
        [
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ]
    )
    f = int(frequency)
    i, j = np.meshgrid(np.arange(f + 1), np.arange(f + 1), indexing="ij")
    keep = (i + j) <= f
    a, b = i[keep] / f, j[keep] / f
    pts = (
        v[faces[:, 0]][:, None] * (1 - a - b)[None, :, None]
        + v[faces[:, 1]][:, None] * a[None, :, None]
        + v[faces[:, 2]][:, None] * b[None, :, None]
    )
    pts = pts.reshape(-1, 3)
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    _, idx = np.unique(np.round(pts, 9), axis=0, return_index=True)
    return pts[np.sort(idx)]


def farthest_point_subset(points, k, start):
    """Deterministic farthest-point sampling of ``k`` points (loop over the k picks).

    Each pick is the point farthest (Euclidean) from those already chosen; ties go to the lowest index.

    Parameters
    ----------
    points : ndarray, shape (M, D)
        Candidate points.
    k : int
        Number of points to pick, ≥ 1 (at most M for distinct picks).
    start : int
        Index of the first pick.

    Returns
    -------
    ndarray of int, shape (k,)
        Indices into ``points`` in the order picked, ``start`` first.
    """
    chosen = [start]
    d = np.linalg.norm(points - points[start], axis=1)
    for _ in range(k - 1):
        nxt = int(np.argmax(d))
        chosen.append(nxt)
        d = np.minimum(d, np.linalg.norm(points - points[nxt], axis=1))
    return np.array(chosen)
