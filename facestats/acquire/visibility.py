"""Visibility of surface points from lights and cameras by shadow mapping.

Weyrich et al. 2006 §5: "We use shadow mapping to determine the visibility of
lumitexel samples for each light source and camera."  For each viewpoint the
triangle mesh is rasterised into a depth buffer (perspective projection towards
the mesh centre, z-buffer of the distance along the view axis); a point is
visible when it faces the viewpoint and its own depth is not behind the buffer by
more than a bias of ``bias_px`` pixel footprints (slope-scaled), which absorbs the
discretisation of the buffer.

The triangles are rasterised by :func:`facestats.core.raster.triangle_coverage`
(vectorised over triangles, grouped by the size of their pixel bounding box) and
the nearest depth per pixel is kept with ``numpy.minimum.at``.  The loop runs over
viewpoints and size groups, never over triangles or points.  :func:`rasterize`
(:func:`nearest_triangle` for vertices already projected) keeps the nearest triangle per pixel instead, to render
a camera view of a mesh.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.acquire.camera import look_at
from facestats.core.compiled import resolve_backend
from facestats.core.raster import triangle_coverage
from facestats.core.validate import check_integer
from facestats.errors import ValidationError

__all__ = [
    "DISTANT_LIGHT_MM",
    "shadow_map",
    "rasterize",
    "nearest_triangle",
    "ShadowMaps",
    "visible_from",
    "SampleVisibility",
    "sample_visibility",
    "dome_shadow_maps",
]

#: Distance (mm) from the face of the viewpoint of a distant light's shadow map.  At 10⁵ mm the rays to a face
#: 200 mm across diverge by at most 0.06°: the map is orthographic for the face.  At 2 m (what
#: :func:`facestats.pipeline.validation.render_probe` used until 2026-12-07) they diverge by up to 2.9°, and a light
#: 75° above the frontal axis lit 4.6 % less of the default S001's face than from afar.
DISTANT_LIGHT_MM = 1e5


def _project(points, eye, rot, focal, res):
    cam = (points - eye) @ rot.T
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = focal * cam[:, 0] / z + res / 2
        y = focal * cam[:, 1] / z + res / 2
    return x, y, z


def _front_triangles(x, y, z, faces):
    """Which triangles lie in front of the camera with finite projections, and their vertex depths (T, 3)."""
    tz = z[faces]
    good = np.all(np.isfinite(x[faces]) & np.isfinite(y[faces]) & (tz > 0), axis=1)
    return good, tz[good]


def _fragments(x, y, z, faces, width, height, triangles=False):
    """Covered pixel centres of a projected mesh, one batch at a time.

    ``x``, ``y`` are the vertices' image coordinates in pixels (column, row; pixel centres at +0.5) and ``z``
    their depths along the view axis.  Yields ``(pixel, depth, triangle)`` arrays for every (triangle, pixel)
    pair whose pixel centre the triangle covers: the flat pixel index (row · width + column), the depth
    interpolated with screen-space barycentrics, and the index of the triangle (None unless ``triangles``).
    Triangles behind the viewpoint or with a non-finite projection cover nothing.  Shared by
    :func:`shadow_map` (nearest depth) and :func:`nearest_triangle` (nearest triangle).
    """
    good, tz = _front_triangles(x, y, z, faces)
    tri_index = np.nonzero(good)[0]
    for tri, py, px, l0, l1, l2 in triangle_coverage(x, y, faces[good], width, height):
        t = tz[tri]
        depth = l0 * t[:, 0] + l1 * t[:, 1] + l2 * t[:, 2]
        yield py * width + px, depth, (tri_index[tri] if triangles else None)


def shadow_map(vertices, faces, eye, target, radius, resolution, *, backend="auto"):
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
    backend : {"auto", "numba", "numpy"}
        The compiled depth buffer (:mod:`facestats.core.raster_numba`, default where numba is
        installed) or the numpy one; both give the same buffer, bit for bit.

    Returns
    -------
    depth : ndarray, shape (resolution, resolution)
        Nearest depth along the view axis per pixel (inf where empty).
    camera : tuple
        ``(eye, rot, focal, resolution)`` to project points into the buffer.
    """
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise ValidationError(
            f"faces must be an (F, 3) array of integer vertex indices, got shape {faces.shape} of {faces.dtype}"
        )
    eye = np.asarray(eye, float)
    rot = look_at(eye, target)
    dist = np.linalg.norm(np.asarray(target, float) - eye)
    half = np.arcsin(min(radius / dist, 0.99))
    focal = (resolution / 2) / np.tan(half)
    depth = np.full(resolution * resolution, np.inf)
    if resolve_backend(backend) == "numba":
        from facestats.core.raster_numba import nearest_depth  # imports numba: only when a map is drawn

        faces = faces.astype(np.int64)
        n = len(vertices)
        if faces.size and (faces.min() < -n or faces.max() >= n):  # as numpy's indexing would refuse them
            raise IndexError(f"faces index vertices outside [-{n}, {n})")
        x, y, z = _project(vertices, eye, rot, focal, resolution)
        nearest_depth(x, y, z, np.ascontiguousarray(faces % n if n else faces), resolution, depth)
    else:
        x, y, z = _project(vertices, eye, rot, focal, resolution)
        for pix, zz, _ in _fragments(x, y, z, faces, resolution, resolution):
            np.minimum.at(depth, pix, zz)
    return depth.reshape(resolution, resolution), (eye, rot, focal, resolution)


def rasterize(vertices, faces, eye, rot, focal, resolution):
    """Nearest triangle and its depth at every pixel centre of a square pinhole image.

    The camera is the one :func:`shadow_map` returns: centre ``eye``, world-to-camera
    rotation ``rot`` (rows x right, y down, z forward, :func:`facestats.acquire.camera.look_at`),
    focal length ``focal`` in pixels and the principal point at the image centre.
    Depths are compared in float32 (as the shadow maps store them); ties go to
    the smaller triangle index.

    Parameters
    ----------
    vertices : array_like, shape (V, 3)
        Mesh vertices, mm.
    faces : array_like of int, shape (F, 3)
        Triangles.
    eye : array_like, shape (3,)
        Camera centre, mm.
    rot : ndarray, shape (3, 3)
        World-to-camera rotation.
    focal : float
        Focal length in pixels.
    resolution : int
        Image side in pixels.

    Returns
    -------
    triangle : ndarray of int64, shape (resolution, resolution)
        Index into ``faces`` of the visible triangle, −1 where the pixel sees no triangle.
    depth : ndarray of float32, shape (resolution, resolution)
        Its depth along the view axis (inf where empty).
    """
    res = int(resolution)
    x, y, z = _project(np.asarray(vertices, float), np.asarray(eye, float), rot, focal, res)
    return nearest_triangle(x, y, z, faces, res, res)


def nearest_triangle(x, y, z, faces, width, height):
    """Nearest triangle and its depth at every pixel centre of an image, from the vertices' projections.

    Depths are compared in float32 (as the shadow maps store them); ties go to the smaller triangle index.
    Triangles with a vertex behind the viewpoint (z ≤ 0) or a non-finite projection cover nothing.

    Parameters
    ----------
    x, y : array_like, shape (V,)
        The vertices' image coordinates in pixels: x along columns, y along rows, pixel (row, col) centred at
        (col + 0.5, row + 0.5) (:func:`facestats.core.raster.triangle_coverage`).
    z : array_like, shape (V,)
        Their depths along the view axis, mm (> 0 in front of the viewpoint).
    faces : array_like of int, shape (F, 3)
        Triangles.
    width, height : int
        Image size in pixels.

    Returns
    -------
    triangle : ndarray of int64, shape (height, width)
        Index into ``faces`` of the visible triangle, −1 where the pixel sees no triangle.
    depth : ndarray of float32, shape (height, width)
        Its depth along the view axis (inf where empty).
    """
    n = int(width) * int(height)
    empty = np.iinfo(np.int64).max
    key = np.full(n, empty, np.int64)
    x, y, z = (np.asarray(a, float) for a in (x, y, z))
    for pix, zz, tri in _fragments(x, y, z, np.asarray(faces), int(width), int(height), triangles=True):
        # Positive float32 bit patterns order like the floats: (depth bits, triangle) in one int64 key.
        bits = zz.astype(np.float32).view(np.int32).astype(np.int64)
        np.minimum.at(key, pix, (bits << 32) | tri.astype(np.int64))
    hit = key != empty
    triangle = np.where(hit, key & 0xFFFFFFFF, -1)
    depth = np.full(n, np.inf, np.float32)
    depth[hit] = (key[hit] >> 32).astype(np.int32).view(np.float32)
    return triangle.reshape(int(height), int(width)), depth.reshape(int(height), int(width))


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
    resolution : int or sequence of int
        Buffer side in pixels, one for all viewpoints or one per viewpoint; choose it
        so a pixel is about the mesh's edge length (LEDs), or the camera's own pixel
        (cameras whose images are finer than the mesh).
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
        eyes = np.asarray(eyes, float)
        res = np.broadcast_to(np.asarray(resolution, np.int64), (len(eyes),))
        for eye, r in zip(eyes, res):  # loop over viewpoints
            depth, cam = shadow_map(verts, faces, eye, self.target, radius, int(r))
            self.maps.append((depth.astype(np.float32), cam))

    def __len__(self):
        return len(self.maps)

    def visible(self, points, normals) -> np.ndarray:
        """(N, K) bool: each point faces viewpoint k and is not occluded.

        Parameters
        ----------
        points : array_like, shape (N, 3)
            Points, mm.
        normals : array_like, shape (N, 3)
            Their unit normals (the depth tolerance is scaled by the cosine to each viewpoint).

        Returns
        -------
        ndarray of bool, shape (N, K)
            True where N·ω > 0, the point projects inside viewpoint k's buffer, in front of it, and its depth is
            within ``bias_px`` pixel footprints of the buffer's.
        """
        pts = np.asarray(points, float)
        nrm = np.asarray(normals, float)
        out = np.zeros((pts.shape[0], len(self.maps)), bool)
        for k in range(len(self.maps)):  # loop over viewpoints
            z, buf, tol, cos, inb = self._depth_test(pts, nrm, k)
            out[:, k] = (cos > 0) & inb & (z <= buf + tol)
        return out

    def on_surface(self, points, normals, viewpoint: int) -> np.ndarray:
        """(N,) bool: viewpoint ``viewpoint``'s ray through each point meets the mesh there, neither in front of it
        (occluded) nor nowhere (the point lies beyond the mesh's silhouette, where the buffer holds no surface).

        :meth:`visible` counts a point off the mesh as unoccluded; this test is for points that stand for what a
        camera pixel sees, e.g. where a pixel's ray meets a surface point's tangent plane
        (:func:`facestats.acquire.ingest.taps_on_surface`).

        Parameters
        ----------
        points : array_like, shape (N, 3)
            Points, mm.
        normals : array_like, shape (N, 3)
            Unit normals of the surface the points stand for (the depth tolerance is scaled by the cosine).
        viewpoint : int
            Index of the viewpoint, in [0, len(self)).

        Returns
        -------
        ndarray of bool, shape (N,)
            True where N·ω > 0, the point projects inside the buffer onto a surface (a finite depth), and it lies
            no more than ``bias_px`` pixel footprints behind that surface (as :meth:`visible`).
        """
        k = check_integer(viewpoint, "viewpoint", 0, len(self.maps) - 1)
        z, buf, tol, cos, inb = self._depth_test(np.asarray(points, float), np.asarray(normals, float), k)
        return (cos > 0) & inb & np.isfinite(buf) & (z <= buf + tol)

    def _depth_test(self, pts, nrm, k):
        """Depth z of the points in viewpoint k's buffer, the buffer's depth there (inf outside it or where it
        holds no surface), the slope-scaled tolerance, the cosine to the viewpoint and the in-buffer mask."""
        depth, (e, rot, focal, res) = self.maps[k]
        x, y, z = _project(pts, e, rot, focal, res)
        to_eye = e - pts
        cos = np.einsum("nk,nk->n", nrm, to_eye) / np.linalg.norm(to_eye, axis=1)
        with np.errstate(invalid="ignore"):
            ix = np.floor(x).astype(np.int64)
            iy = np.floor(y).astype(np.int64)
        inb = (ix >= 0) & (iy >= 0) & (ix < res) & (iy < res) & (z > 0)
        buf = np.full(pts.shape[0], np.inf)
        buf[inb] = depth[iy[inb], ix[inb]]
        tol = self.bias_px * (z / focal) / np.maximum(cos, 0.2)  # pixel footprint at the point's depth, slope-scaled
        return z, buf, tol, cos, inb


def visible_from(points, normals, vertices, faces, eyes, *, target=None, resolution=256, bias_px=1.5):
    """Which points each viewpoint sees (front-facing and not occluded by the mesh): (N, K) bool.

    Convenience for :class:`ShadowMaps`.

    Parameters
    ----------
    points, normals : array_like, shape (N, 3)
        Points (mm) and their normals.
    vertices, faces, eyes, target, resolution, bias_px
        As :class:`ShadowMaps` (``eyes`` (K, 3), mm).

    Returns
    -------
    ndarray of bool, shape (N, K)
    """
    return ShadowMaps(vertices, faces, eyes, target=target, resolution=resolution, bias_px=bias_px).visible(
        points, normals
    )


def dome_shadow_maps(geometry, dome, resolution: int | None = None, *, camera_pixels: bool = False) -> ShadowMaps:
    """Shadow maps of a face geometry's mesh from every LED, then every camera, of a dome.

    ``resolution`` defaults to twice the mesh grid (``geometry.meta["mesh_grid"]``,
    128 if unknown): about one buffer pixel per half triangle edge.  With
    ``camera_pixels`` the cameras' buffers have the cameras' own resolution over
    the mesh (capped at 2,048): photographs show occlusion edges at image
    resolution, and a lumitexel next to an edge must be tested at that scale.

    Parameters
    ----------
    geometry : FaceGeometry
        Its mesh occludes.
    dome : Dome
    resolution : int, optional
        Buffer side in pixels (default above); with ``camera_pixels`` the cameras' minimum.
    camera_pixels : bool
        Cameras' buffers at their own resolution over the mesh.

    Returns
    -------
    ShadowMaps
        L + C viewpoints: the LEDs, then the cameras.
    """
    res = int(resolution or 2 * int(geometry.meta.get("mesh_grid", 128)))
    eyes = np.concatenate([dome.led_position, dome.camera_position])
    per_eye = np.full(len(eyes), res)
    if camera_pixels:
        verts = np.asarray(geometry.mesh_vertices, float)
        centre = 0.5 * (verts.min(0) + verts.max(0))
        radius = 1.05 * np.max(np.linalg.norm(verts - centre, axis=1))
        dist = np.linalg.norm(dome.camera_position - centre, axis=1)
        across = 2 * dome.camera_matrix[:, 0, 0] * np.tan(np.arcsin(np.minimum(radius / dist, 0.99)))
        per_eye[dome.n_leds :] = np.clip(np.ceil(across), res, 2048)
    return ShadowMaps(geometry.mesh_vertices, geometry.mesh_faces, eyes, resolution=per_eye)


@dataclass
class SampleVisibility:
    """Which (light, camera) samples of surface points are valid, with the directions and irradiance.

    Attributes
    ----------
    wi, e_perp : ndarray, shape (N, L, 3)
        Directions towards the LEDs and beam-normal irradiance (:meth:`Dome.incident`).
    cos_i : ndarray, shape (N, L)
        N·ωi.
    lit : ndarray of bool, shape (N, L)
        The LED's shadow map sees the point, it faces the LED and the LED's beam reaches it.
    wo : ndarray, shape (N, C, 3)
        Directions towards the cameras.
    cos_o : ndarray, shape (N, C)
        N·ωo.
    seen : ndarray of bool, shape (N, C)
        The camera's shadow map sees the point, it faces the camera and projects inside the image.
    pixel : ndarray, shape (N, C, 2)
        Image coordinates (:meth:`Dome.project`).
    """

    wi: np.ndarray
    e_perp: np.ndarray
    cos_i: np.ndarray
    lit: np.ndarray
    wo: np.ndarray
    cos_o: np.ndarray
    seen: np.ndarray
    pixel: np.ndarray


def sample_visibility(dome, shadows: ShadowMaps, points, normals) -> SampleVisibility:
    """Valid samples of points with ``normals`` (Weyrich et al. 2006 §5: shadow maps per light and camera).

    The simulator renders exactly these samples and the photograph ingest keeps
    exactly these, so both paths agree on what a valid sample is.

    Parameters
    ----------
    dome : Dome
    shadows : ShadowMaps
        The maps of the LEDs then the cameras (:func:`dome_shadow_maps`).
    points, normals : array_like, shape (N, 3)
        Surface points (mm) and their unit normals.

    Returns
    -------
    SampleVisibility
    """
    pts, nrm = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    n_led = dome.n_leds
    vis = shadows.visible(pts, nrm)
    wi, e_perp = dome.incident(pts)
    wo, in_frame, pix = dome.view(pts)
    cos_i = np.einsum("nk,nlk->nl", nrm, wi)
    cos_o = np.einsum("nk,nck->nc", nrm, wo)
    lit = vis[:, :n_led] & (cos_i > 0) & np.all(e_perp > 0, axis=-1)
    seen = vis[:, n_led:] & in_frame & (cos_o > 0)
    return SampleVisibility(wi, e_perp, cos_i, lit, wo, cos_o, seen, pix)
