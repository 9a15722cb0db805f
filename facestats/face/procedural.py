"""A procedural head: an ellipsoidal cap with the 10 regions of Fig. 15 (the default face is ICT-FaceKit's).

The procedural face is an ellipsoidal cap with Gaussian features (nose ridge,
eye sockets, brow ridge, cheekbones, lips, mouth line, chin).  Its 10 regions
follow Weyrich et al. 2006 Fig. 15: forehead (2) above the eyebrows (3),
eyelids (4) below them, region 5 (not named in the paper; placed as the
under-eye band between eyelids and cheeks), nose (6) down the midline, cheeks
(7), mustache (1) between nose and upper lip, lips (8), chin (9) below the lips
and beard (10) along the jaw.  Frame and UV conventions: :mod:`facestats.face.geometry`.
"""

from __future__ import annotations

import numpy as np

from facestats.errors import ValidationError
from facestats.face.geometry import FaceGeometry, grid_triangles

__all__ = ["procedural_face", "face_window", "face_uv", "SITE_CENTRES"]


#: Face coordinates (x, y) in mm of the contact-sensor sites on the procedural face: the cheek on the
#: cheekbone (region 7), the forehead on the midline above the brows (region 2).  (The neck is not modelled.)
SITE_CENTRES = {"cheek": (46.0, 2.0), "forehead": (0.0, 80.0)}

# -- the procedural head --------------------------------------------------------------
#: Half-axes of the ellipsoidal cap (mm): width, height, depth.
_HALF_WIDTH, _HALF_HEIGHT, _DEPTH = 80.0, 115.0, 75.0
#: Size of the UV domain in mm (the cap plus a margin).
_UV_WIDTH, _UV_HEIGHT = 2 * _HALF_WIDTH, 2 * _HALF_HEIGHT


def _gauss(x, y, x0, y0, sx, sy):
    return np.exp(-0.5 * (((x - x0) / sx) ** 2 + ((y - y0) / sy) ** 2))


def _height(x, y):
    """Depth z(x, y) of the procedural face, mm (features documented in the module docstring)."""
    q = 1 - (x / _HALF_WIDTH) ** 2 - (y / _HALF_HEIGHT) ** 2
    z = _DEPTH * np.sqrt(np.maximum(q, 0.0))
    # Nose: a ridge from the bridge (y = 35) to the tip (y = -25), higher and wider towards the tip.
    t = np.clip((35 - y) / 60, 0, 1)
    ridge = (
        (8 + 20 * t**1.5)
        * np.exp(-0.5 * (x / (6 + 6 * t)) ** 2)
        * np.where(y < -25, np.exp(-0.5 * ((y + 25) / 6) ** 2), 1)
    )
    z = z + ridge * (y < 40) + ridge * (y >= 40) * np.exp(-0.5 * ((y - 40) / 4) ** 2)
    for sx_ in (-1, 1):
        z = z - 9 * _gauss(x, y, sx_ * 32, 28, 14, 10)  # eye sockets
        z = z + 4 * _gauss(x, y, sx_ * 32, 46, 18, 6)  # brow ridge
        z = z + 5 * _gauss(x, y, sx_ * 46, 2, 18, 15)  # cheekbones
    z = z + 6 * _gauss(x, y, 0, -57, 22, 8)  # lips
    z = z - 2.5 * _gauss(x, y, 0, -57, 20, 1.5)  # mouth line
    z = z + 6 * _gauss(x, y, 0, -92, 18, 12)  # chin
    return z


def _inside(x, y, x0, y0, ax, ay):
    return ((x - x0) / ax) ** 2 + ((y - y0) / ay) ** 2 <= 1


def _regions(x, y):
    """Region labels (Weyrich Fig. 15 numbering) of points with face coordinates x, y (mm)."""
    face = ((x / (0.93 * _HALF_WIDTH)) ** 2 + (y / (0.93 * _HALF_HEIGHT)) ** 2) <= 1
    reg = np.full(x.shape, 7, np.uint8)  # cheeks by default
    reg[y > 52] = 2  # forehead
    jaw = (y < -38) & (np.abs(x) > 24)
    reg[jaw] = 10  # beard along the jaw
    reg[(y < -68)] = 10
    reg[_inside(x, y, 0, -90, 24, 20) & (y < -66)] = 9  # chin
    for s in (-1, 1):
        reg[_inside(x, y, s * 32, 45, 21, 6.5)] = 3  # eyebrows
        reg[_inside(x, y, s * 32, 29, 16, 9)] = 4  # eyelids
        reg[_inside(x, y, s * 32, 14, 17, 6)] = 5  # under-eye (region 5)
    nose = (y > -32) & (y < 38) & (np.abs(x) < 6 + 0.13 * (38 - y))
    reg[nose] = 6
    reg[(y <= -32) & (y > -48) & (np.abs(x) < 22)] = 1  # mustache
    reg[_inside(x, y, 0, -57, 25, 9.5)] = 8  # lips
    reg[~face] = 0
    return reg


def face_uv(x, y):
    """Texture coordinates (u, v) in [0, 1] of face coordinates x, y (mm): the inverse of the UV → surface map.

    Parameters
    ----------
    x, y : array_like
        Face coordinates of the procedural head, mm (x right, y up).

    Returns
    -------
    u, v : ndarray
        Texture coordinates (v down), clipped to [0, 1].
    """
    return np.clip(np.asarray(x) / _UV_WIDTH + 0.5, 0, 1), np.clip(0.5 - np.asarray(y) / _UV_HEIGHT, 0, 1)


def _surface(u, v):
    x = (u - 0.5) * _UV_WIDTH
    y = (0.5 - v) * _UV_HEIGHT
    return x, y, _height(x, y)


def procedural_face(
    lumitexel_grid: int = 48, map_size: int | None = None, mesh_grid: int | None = None
) -> FaceGeometry:
    """A parametric head (ellipsoidal cap with a nose) with the 10 regions of Weyrich Fig. 15.

    Parameters
    ----------
    lumitexel_grid : int
        Lumitexels are the face points of a ``lumitexel_grid``² grid in UV (48 by
        default: about 1,560 lumitexels 3.3 × 4.8 mm apart, which keeps the whole
        default population fast; 1,152 gives about 900,000, the paper's full
        resolution of 700,000-900,000 vertices).
    map_size : int, optional
        Side of the output UV maps; default ``lumitexel_grid``.
    mesh_grid : int, optional
        Grid of the shadowing mesh; default ``min(lumitexel_grid, 192)`` (shadows
        need geometry, not texture resolution).

    Returns
    -------
    FaceGeometry
    """
    n = int(lumitexel_grid)
    if n < 8:
        raise ValidationError(f"lumitexel_grid must be >= 8, got {lumitexel_grid!r}")
    map_size = n if map_size is None else int(map_size)
    mesh_n = min(n, 192) if mesh_grid is None else int(mesh_grid)
    c = (np.arange(n) + 0.5) / n
    uu, vv = np.meshgrid(c, c)  # [v, u]
    x, y, z = _surface(uu, vv)
    reg = _regions(x, y)
    # Partial derivatives by central differences of the analytic surface, in mm per UV unit.
    h = 1e-4
    xu1, yu1, zu1 = _surface(uu + h, vv)
    xu0, yu0, zu0 = _surface(uu - h, vv)
    xv1, yv1, zv1 = _surface(uu, vv + h)
    xv0, yv0, zv0 = _surface(uu, vv - h)
    pu = np.stack([xu1 - xu0, yu1 - yu0, zu1 - zu0], -1) / (2 * h)
    pv = np.stack([xv1 - xv0, yv1 - yv0, zv1 - zv0], -1) / (2 * h)
    cross = np.cross(pv, pu)  # v grows downwards: pv × pu points out of the face (+z)
    dA = np.linalg.norm(cross, axis=-1)
    normal = cross / dA[..., None]
    area = dA / (n * n)
    face = reg > 0
    vi, ui = np.nonzero(face)
    # Shadowing mesh over the whole cap (including non-face margin that can cast shadows).
    mc = (np.arange(mesh_n) + 0.5) / mesh_n
    mu, mv = np.meshgrid(mc, mc)
    mx, my, mz = _surface(mu, mv)
    q = 1 - (mx / _HALF_WIDTH) ** 2 - (my / _HALF_HEIGHT) ** 2
    verts = np.stack([mx, my, mz], -1).reshape(-1, 3)
    faces = grid_triangles(q > 0.02)
    # Region label image at map resolution.
    mc2 = (np.arange(map_size) + 0.5) / map_size
    ru, rv = np.meshgrid(mc2, mc2)
    rx, ry, _ = _surface(ru, rv)
    return FaceGeometry(
        position=np.stack([x, y, z], -1)[face],
        normal=normal[face],
        area=area[face],
        uv=np.stack([uu[face], vv[face]], -1),
        region=reg[face],
        map_size=map_size,
        mesh_vertices=verts,
        mesh_faces=faces,
        grid_index=np.stack([vi, ui], -1),
        region_map=_regions(rx, ry),
        name=f"procedural-{n}",
        meta={"kind": "procedural", "lumitexel_grid": n, "mesh_grid": mesh_n},
        mesh_uv=np.stack([mu.ravel(), mv.ravel()], 1),
    )


def face_window(site, *, half_width=9.0, spacing=0.3):
    """A square window of the procedural face's surface around a sensor site, as a triangle mesh.

    The window is the height field z(x, y) of the procedural head over
    |x − x₀|, |y − y₀| ≤ ``half_width`` around the site (:data:`SITE_CENTRES`),
    sampled every ``spacing`` mm, two triangles per grid cell, normals towards +z.

    Parameters
    ----------
    site : str
        A key of :data:`SITE_CENTRES`.
    half_width : float
        Half the window's side, mm (> 0).
    spacing : float
        Grid step, mm (> 0; at most 4000 samples a side).

    Returns
    -------
    vertices : ndarray, shape (V, 3)
    faces : ndarray of int, shape (F, 3)
    centre : ndarray, shape (3,)
        The site's surface point, mm.
    normal : ndarray, shape (3,)
        The unit surface normal there.
    """
    if site not in SITE_CENTRES:
        raise ValidationError(f"site must be one of {sorted(SITE_CENTRES)}, got {site!r}")
    hw, h = float(half_width), float(spacing)
    if not (hw > 0 and h > 0 and hw / h <= 2000):
        raise ValidationError(f"half_width and spacing must be > 0 with at most 4000 samples a side, got {hw}, {h}")
    x0, y0 = SITE_CENTRES[site]
    n = int(np.ceil(2 * hw / h)) + 1
    xs = x0 + np.linspace(-hw, hw, n)
    ys = y0 + np.linspace(hw, -hw, n)  # rows go down in y, like v, so grid_triangles faces +z
    xx, yy = np.meshgrid(xs, ys)
    verts = np.stack([xx, yy, _height(xx, yy)], -1).reshape(-1, 3)
    faces = grid_triangles(np.ones((n, n), bool))
    e = 1e-4
    gx = (_height(x0 + e, y0) - _height(x0 - e, y0)) / (2 * e)
    gy = (_height(x0, y0 + e) - _height(x0, y0 - e)) / (2 * e)
    normal = np.array([-gx, -gy, 1.0]) / np.sqrt(gx * gx + gy * gy + 1)
    return verts, faces, np.array([x0, y0, float(_height(x0, y0))]), normal
