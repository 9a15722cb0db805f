"""Face geometry: lumitexel points with UV coordinates, normals, areas and face regions.

A :class:`FaceGeometry` is what the dome simulator and the fit pipeline need of a
face: for every lumitexel (a surface point where BRDF samples are gathered,
Weyrich et al. 2006 §5) its 3D position (mm), its scanned normal, the surface
area it represents (mm²), its UV texture coordinates, its face region
(Weyrich Fig. 15), and a triangle mesh for shadow mapping.  It comes from

* :func:`procedural_face` — the embedded default: a parametric head whose
  lumitexels sit on a regular UV grid, or
* :func:`facestats.io.mesh.load_face_mesh` — a real scan (OBJ/PLY with UVs and a
  region label image).

World frame (right-handed, mm): +y up, +z out of the face towards the frontal
camera, +x to the subject's left; the origin is near the centre of the head.
UV: ``u`` grows with x, ``v`` grows downwards (v = 0 at the top of the forehead),
so a map indexed ``[v, u]`` shows the face upright as an image.

The procedural face is an ellipsoidal cap with Gaussian features (nose ridge,
eye sockets, brow ridge, cheekbones, lips, mouth line, chin).  Its 10 regions
follow Fig. 15: forehead (2) above the eyebrows (3), eyelids (4) below them,
region 5 (not named in the paper; placed as the under-eye band between eyelids
and cheeks), nose (6) down the midline, cheeks (7), mustache (1) between nose
and upper lip, lips (8), chin (9) below the lips and beard (10) along the jaw.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._validate import as_finite, check_range, check_shape
from ..errors import ValidationError

__all__ = ["FaceGeometry", "procedural_face", "grid_triangles", "uv_to_texel"]


def uv_to_texel(uv, size: int) -> np.ndarray:
    """The ``(v, u)`` texel of a ``size``² map that contains each UV coordinate, shape (N, 2).

    Texel (i, j) covers v ∈ [i/size, (i+1)/size) and u ∈ [j/size, (j+1)/size)
    (module docstring: ``v`` grows downwards, maps are indexed ``[v, u]``);
    u or v = 1 falls into the last texel.

    Parameters
    ----------
    uv : ndarray, shape (N, 2)
        Texture coordinates (u, v) in [0, 1].
    size : int
        Side of the map.
    """
    return np.clip((np.asarray(uv)[:, ::-1] * size).astype(np.int64), 0, size - 1)


@dataclass
class FaceGeometry:
    """Lumitexel points of a face and the mesh that shadows them.

    Attributes
    ----------
    position : ndarray, shape (N, 3)
        Lumitexel positions in mm (world frame of the module docstring).
    normal : ndarray, shape (N, 3)
        Unit normals of the scanned geometry (the fit re-estimates normals by
        photometric stereo; this is the scanner's coarse normal).
    area : ndarray, shape (N,)
        Surface area each lumitexel represents, mm².
    uv : ndarray, shape (N, 2)
        Texture coordinates in [0, 1]² (u right, v down).
    region : ndarray of uint8, shape (N,)
        Face region 1-10 (Fig. 15); lumitexels are face points, so never 0.
    map_size : int
        Side of the square UV maps the pipeline produces (Weyrich §4: 2048).
    mesh_vertices, mesh_faces : ndarray
        Triangle mesh (mm; int indices) used for shadow mapping.
    grid_index : ndarray of int, shape (N, 2), optional
        ``(v, u)`` texel of each lumitexel when lumitexels lie on the UV grid.
    region_map : ndarray of uint8, shape (map_size, map_size), optional
        Region label image in UV (0 = not face).
    """

    position: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    uv: np.ndarray
    region: np.ndarray
    map_size: int
    mesh_vertices: np.ndarray
    mesh_faces: np.ndarray
    grid_index: np.ndarray | None = None
    region_map: np.ndarray | None = None
    name: str = "face"
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        p = check_shape(as_finite(self.position, "position", dtype=np.float64), "position", (None, 3))
        n = check_shape(as_finite(self.normal, "normal", dtype=np.float64), "normal", (p.shape[0], 3))
        norm = np.linalg.norm(n, axis=1)
        if np.any(np.abs(norm - 1) > 1e-3):
            bad = norm[np.abs(norm - 1) > 1e-3][0]
            raise ValidationError(f"normal must hold unit vectors (norm 1 ± 1e-3), got a vector of norm {bad:.6g}")
        a = check_shape(as_finite(self.area, "area", dtype=np.float64), "area", (p.shape[0],))
        check_range(a, "area", 0, None, low_inclusive=False, unit="mm^2")
        uv = check_shape(as_finite(self.uv, "uv", dtype=np.float64), "uv", (p.shape[0], 2))
        check_range(uv, "uv", 0, 1)
        reg = np.asarray(self.region)
        if reg.shape != (p.shape[0],) or reg.min(initial=1) < 1 or reg.max(initial=1) > 10:
            raise ValidationError(
                f"region must hold one label 1-10 per lumitexel, shape ({p.shape[0]},), got shape {reg.shape} "
                f"with labels {reg.min(initial=0)}..{reg.max(initial=0)}"
            )
        if int(self.map_size) < 2:
            raise ValidationError(f"map_size must be >= 2, got {self.map_size!r}")
        self.position, self.normal, self.area, self.uv = p, n, a, uv
        self.region = reg.astype(np.uint8)
        self.map_size = int(self.map_size)
        self.mesh_vertices = np.asarray(self.mesh_vertices, np.float64)
        self.mesh_faces = np.asarray(self.mesh_faces, np.int64)

    @property
    def n_points(self) -> int:
        return int(self.position.shape[0])

    def texel_index(self, size: int | None = None) -> np.ndarray:
        """Nearest ``(v, u)`` texel of each lumitexel in a ``size``² map (default ``map_size``)."""
        s = self.map_size if size is None else int(size)
        return uv_to_texel(self.uv, s)

    def face_texel_index(self) -> np.ndarray:
        """The ``(v, u)`` texel of each lumitexel in the ``map_size``² maps, on the face, shape (N, 2).

        A lumitexel's own texel (:meth:`texel_index`) can lie just off the face of
        ``region_map`` when the maps are finer than the lumitexel spacing: the
        lumitexel's region is that of its centre, the texel's that of the texel
        centre, and near the face border the two differ.  Such lumitexels take the
        nearest face texel (Euclidean distance in texels; ties by
        :func:`scipy.ndimage.distance_transform_edt`), so maps that hold values
        only on the face (the population's truth, fitted maps) are defined at every
        lumitexel.  Without a ``region_map`` this is :meth:`texel_index`.
        """
        tex = self.texel_index()
        if self.region_map is None:
            return tex
        off = np.asarray(self.region_map)[tex[:, 0], tex[:, 1]] == 0
        if np.any(off):
            from scipy.ndimage import distance_transform_edt

            _, (iv, iu) = distance_transform_edt(np.asarray(self.region_map) == 0, return_indices=True)
            tex = tex.copy()
            tex[off] = np.stack([iv[tex[off, 0], tex[off, 1]], iu[tex[off, 0], tex[off, 1]]], -1)
        return tex

    def subset(self, index) -> "FaceGeometry":
        """The geometry restricted to some lumitexels (the mesh is kept whole for shadowing)."""
        idx = np.asarray(index)
        return FaceGeometry(
            position=self.position[idx], normal=self.normal[idx], area=self.area[idx], uv=self.uv[idx],
            region=self.region[idx], map_size=self.map_size, mesh_vertices=self.mesh_vertices,
            mesh_faces=self.mesh_faces, grid_index=None if self.grid_index is None else self.grid_index[idx],
            region_map=self.region_map, name=self.name, meta=dict(self.meta),
        )


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
    ridge = (8 + 20 * t**1.5) * np.exp(-0.5 * (x / (6 + 6 * t)) ** 2) * np.where(y < -25, np.exp(-0.5 * ((y + 25) / 6) ** 2), 1)
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


def _surface(u, v):
    x = (u - 0.5) * _UV_WIDTH
    y = (0.5 - v) * _UV_HEIGHT
    return x, y, _height(x, y)


def grid_triangles(valid: np.ndarray) -> np.ndarray:
    """Triangles (two per quad) of a grid of vertices, using only quads whose 4 corners are valid.

    ``valid`` is a (rows, cols) bool array; vertex ``(i, j)`` has index ``i*cols + j``.
    """
    rows, cols = valid.shape
    i, j = np.mgrid[0 : rows - 1, 0 : cols - 1]
    q = valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:] & valid[1:, 1:]
    a = (i * cols + j)[q]
    b, c, d = a + 1, a + cols, a + cols + 1
    return np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])


def procedural_face(lumitexel_grid: int = 48, map_size: int | None = None, mesh_grid: int | None = None) -> FaceGeometry:
    """The embedded default face: a parametric head with the 10 regions of Weyrich Fig. 15.

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
    )
