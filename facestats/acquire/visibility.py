"""Visibility of surface points from lights and cameras by shadow mapping.

Weyrich et al. 2006 §5: "We use shadow mapping to determine the visibility of
lumitexel samples for each light source and camera."  For each viewpoint the
triangle mesh is rasterised into a depth buffer (perspective projection towards
the mesh centre, z-buffer of the distance along the view axis); a point is
visible when it faces the viewpoint and its own depth is not behind the buffer by
more than a bias of ``bias_px`` pixel footprints (slope-scaled), which absorbs the
discretisation of the buffer.

The rasteriser is vectorised over triangles: triangles are grouped by the size of
their pixel bounding box, each group tests all its candidate pixels at once, and
the nearest depth per pixel is kept with ``numpy.minimum.at``.  The loop runs over
viewpoints and size groups, never over triangles or points.  :func:`rasterize`
keeps the nearest triangle per pixel instead, to render a camera view of a mesh.
"""

from __future__ import annotations

import numpy as np

from facestats.acquire.dome import look_at

__all__ = ["shadow_map", "rasterize", "ShadowMaps", "visible_from"]


def _project(points, eye, rot, focal, res):
    cam = (points - eye) @ rot.T
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = focal * cam[:, 0] / z + res / 2
        y = focal * cam[:, 1] / z + res / 2
    return x, y, z


def _fragments(vertices, faces, eye, rot, focal, resolution, triangles=False):
    """Covered pixel centres of a mesh seen through a pinhole camera, one batch at a time.

    Yields ``(pixel, depth, triangle)`` arrays for every (triangle, pixel) pair
    whose pixel centre the triangle covers: the flat pixel index
    (row · resolution + column), the depth along the view axis interpolated with
    screen-space barycentrics, and the index of the triangle (None unless
    ``triangles``).  Shared by :func:`shadow_map` (nearest depth) and
    :func:`rasterize` (nearest triangle).
    """
    x, y, z = _project(vertices, eye, rot, focal, resolution)
    tx, ty, tz = x[faces], y[faces], z[faces]  # (F, 3)
    good = np.all(np.isfinite(tx) & np.isfinite(ty) & (tz > 0), axis=1)
    tri_index = np.nonzero(good)[0]
    tx, ty, tz = tx[good], ty[good], tz[good]
    x0 = np.floor(tx.min(1) - 0.5).astype(np.int64)
    y0 = np.floor(ty.min(1) - 0.5).astype(np.int64)
    w = np.ceil(tx.max(1) - 0.5).astype(np.int64) - x0 + 1
    h = np.ceil(ty.max(1) - 0.5).astype(np.int64) - y0 + 1
    size = np.maximum(w, h)
    # Barycentric set-up (edge functions) of every triangle.
    ax, ay, bx, by, cx, cy = tx[:, 0], ty[:, 0], tx[:, 1], ty[:, 1], tx[:, 2], ty[:, 2]
    den = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
    nondeg = np.abs(den) > 1e-12
    classes = 2 ** np.ceil(np.log2(np.maximum(size, 1))).astype(np.int64)
    for s in np.unique(classes[nondeg]):
        sel = np.nonzero((classes == s) & nondeg)[0]
        # Bound the candidates per pass to keep memory small.
        step = max(1, 2_000_000 // int(s * s))
        for start in range(0, sel.size, step):
            t = sel[start : start + step]
            oy, ox = np.mgrid[0:s, 0:s]
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
            eps = -1e-6
            inside = (
                (l0 >= eps) & (l1 >= eps) & (l2 >= eps) & (px >= 0) & (py >= 0) & (px < resolution) & (py < resolution)
            )
            zz = l0 * tz[t, 0, None, None] + l1 * tz[t, 1, None, None] + l2 * tz[t, 2, None, None]
            tri = np.broadcast_to(tri_index[t, None, None], inside.shape)[inside] if triangles else None
            yield (py * resolution + px)[inside], zz[inside], tri


def shadow_map(vertices, faces, eye, target, radius, resolution):
    """Depth buffer of a mesh seen from ``eye`` looking at ``target``.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    faces : ndarray of int, shape (F, 3)
    eye, target : array_like, shape (3,)
        Viewpoint and the point it looks at, mm.
    radius : float
        Radius (mm) around ``target`` the buffer must cover.
    resolution : int
        Buffer side in pixels.

    Returns
    -------
    depth : ndarray, shape (resolution, resolution)
        Nearest depth along the view axis per pixel (inf where empty).
    camera : tuple
        ``(eye, rot, focal, resolution)`` to project points into the buffer.
    """
    eye = np.asarray(eye, float)
    rot = look_at(eye, target)
    dist = np.linalg.norm(np.asarray(target, float) - eye)
    half = np.arcsin(min(radius / dist, 0.99))
    focal = (resolution / 2) / np.tan(half)
    depth = np.full(resolution * resolution, np.inf)
    for pix, zz, _ in _fragments(vertices, faces, eye, rot, focal, resolution):
        np.minimum.at(depth, pix, zz)
    return depth.reshape(resolution, resolution), (eye, rot, focal, resolution)


def rasterize(vertices, faces, eye, rot, focal, resolution):
    """Nearest triangle and its depth at every pixel centre of a square pinhole image.

    The camera is the one :func:`shadow_map` returns: centre ``eye``, world-to-camera
    rotation ``rot`` (rows x right, y down, z forward, :func:`facestats.acquire.dome.look_at`),
    focal length ``focal`` in pixels and the principal point at the image centre.
    Depths are compared in float32 (as the shadow maps store them); ties go to
    the smaller triangle index.

    Returns
    -------
    triangle : ndarray of int64, shape (resolution, resolution)
        Index into ``faces`` of the visible triangle, −1 where the pixel sees no triangle.
    depth : ndarray of float32, shape (resolution, resolution)
        Its depth along the view axis (inf where empty).
    """
    res = int(resolution)
    n = res * res
    empty = np.iinfo(np.int64).max
    key = np.full(n, empty, np.int64)
    eye = np.asarray(eye, float)
    frags = _fragments(np.asarray(vertices, float), np.asarray(faces), eye, rot, focal, res, triangles=True)
    for pix, zz, tri in frags:
        # Positive float32 bit patterns order like the floats: (depth bits, triangle) in one int64 key.
        bits = zz.astype(np.float32).view(np.int32).astype(np.int64)
        np.minimum.at(key, pix, (bits << 32) | tri.astype(np.int64))
    hit = key != empty
    triangle = np.where(hit, key & 0xFFFFFFFF, -1)
    depth = np.full(n, np.inf, np.float32)
    depth[hit] = (key[hit] >> 32).astype(np.int32).view(np.float32)
    return triangle.reshape(res, res), depth.reshape(res, res)


class ShadowMaps:
    """Depth buffers of a mesh from a set of viewpoints, to test many points against in blocks.

    Parameters
    ----------
    vertices, faces : ndarray
        Occluding triangle mesh (mm).
    eyes : ndarray, shape (K, 3)
        Viewpoints (LED or camera positions), mm.
    target : array_like, optional
        Point the buffers look at; default the centre of the mesh's bounding box.
    resolution : int
        Buffer side in pixels; choose it so a pixel is about the mesh's edge length.
    bias_px : float
        Depth tolerance in pixel footprints (slope-scaled).
    """

    def __init__(self, vertices, faces, eyes, *, target=None, resolution=256, bias_px=1.5):
        verts = np.asarray(vertices, float)
        if target is None:
            target = 0.5 * (verts.min(0) + verts.max(0))
        self.target = np.asarray(target, float)
        radius = 1.05 * np.max(np.linalg.norm(verts - self.target, axis=1))
        self.bias_px = float(bias_px)
        self.maps = []
        for eye in np.asarray(eyes, float):  # loop over viewpoints
            depth, cam = shadow_map(verts, faces, eye, self.target, radius, int(resolution))
            self.maps.append((depth.astype(np.float32), cam))

    def __len__(self):
        return len(self.maps)

    def visible(self, points, normals) -> np.ndarray:
        """(N, K) bool: each point faces viewpoint k and is not occluded."""
        pts = np.asarray(points, float)
        nrm = np.asarray(normals, float)
        out = np.zeros((pts.shape[0], len(self.maps)), bool)
        for k, (depth, (e, rot, focal, res)) in enumerate(self.maps):  # loop over viewpoints
            x, y, z = _project(pts, e, rot, focal, res)
            to_eye = e - pts
            cos = np.einsum("nk,nk->n", nrm, to_eye) / np.linalg.norm(to_eye, axis=1)
            with np.errstate(invalid="ignore"):
                ix = np.floor(x).astype(np.int64)
                iy = np.floor(y).astype(np.int64)
            inb = (ix >= 0) & (iy >= 0) & (ix < res) & (iy < res) & (z > 0)
            buf = np.full(pts.shape[0], np.inf)
            buf[inb] = depth[iy[inb], ix[inb]]
            tol = (
                self.bias_px * (z / focal) / np.maximum(cos, 0.2)
            )  # pixel footprint at the point's depth, slope-scaled
            out[:, k] = (cos > 0) & inb & (z <= buf + tol)
        return out


def visible_from(points, normals, vertices, faces, eyes, *, target=None, resolution=256, bias_px=1.5):
    """Which points each viewpoint sees (front-facing and not occluded by the mesh): (N, K) bool.

    Convenience for :class:`ShadowMaps` (see there for the parameters).
    """
    return ShadowMaps(vertices, faces, eyes, target=target, resolution=resolution, bias_px=bias_px).visible(
        points, normals
    )
