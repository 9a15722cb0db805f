"""Face geometry: lumitexel points with UV coordinates, normals, areas and face regions.

A :class:`FaceGeometry` is what the dome simulator and the fit pipeline need of a
face: for every lumitexel (a surface point where BRDF samples are gathered,
Weyrich et al. 2006 §5) its 3D position (mm), its scanned normal, the surface
area it represents (mm²), its UV texture coordinates, its face region
(Weyrich Fig. 15), and a triangle mesh for shadow mapping.  It comes from

* :func:`facestats.face.procedural.procedural_face` — the embedded
  default: a parametric head whose lumitexels sit on a regular UV grid, or
* :func:`facestats.io.mesh.load_face_mesh` — a real scan (OBJ/PLY with UVs and a
  region label image).

World frame (right-handed, mm): +y up, +z out of the face towards the frontal
camera, +x to the subject's left; the origin is near the centre of the head.
UV: ``u`` grows with x, ``v`` grows downwards (v = 0 at the top of the forehead),
so a map indexed ``[v, u]`` shows the face upright as an image.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facestats.core.validate import as_finite, check_range, check_shape, check_unit_vectors
from facestats.errors import ValidationError


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
    mesh_uv : ndarray, shape (V, 2), optional
        UV (u right, v down) of every mesh vertex, when the mesh has them.
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
    mesh_uv: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        p = check_shape(as_finite(self.position, "position", dtype=np.float64), "position", (None, 3))
        n = check_shape(as_finite(self.normal, "normal", dtype=np.float64), "normal", (p.shape[0], 3))
        check_unit_vectors(n, "normal", 1e-3)
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
        if self.mesh_uv is not None:
            self.mesh_uv = check_shape(np.asarray(self.mesh_uv, np.float64), "mesh_uv", (len(self.mesh_vertices), 2))

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
            position=self.position[idx],
            normal=self.normal[idx],
            area=self.area[idx],
            uv=self.uv[idx],
            region=self.region[idx],
            map_size=self.map_size,
            mesh_vertices=self.mesh_vertices,
            mesh_faces=self.mesh_faces,
            grid_index=None if self.grid_index is None else self.grid_index[idx],
            region_map=self.region_map,
            name=self.name,
            meta=dict(self.meta),
            mesh_uv=self.mesh_uv,
        )


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
