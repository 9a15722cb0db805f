"""The camera view of a face mesh: a square pinhole camera and the surface seen by each of its pixels.

One job: for a :class:`StageCamera`, rasterise a :class:`~facestats.face.geometry.FaceGeometry`'s mesh
(:func:`facestats.acquire.visibility.rasterize`), intersect every covered pixel's ray with its triangle
(Möller-Trumbore) and return the surface point, its barycentric coordinates and texture coordinates
(:class:`ViewSurface`).  Used by the virtual light stage (:mod:`facestats.relight.stage`) and by the
novel-view re-projection (:func:`facestats.relight.novel.reproject`).  Frame: facestats's world frame
(+y up, +z towards the frontal camera, mm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.acquire.dome import look_at
from facestats.acquire.visibility import rasterize
from facestats.core.validate import as_finite, as_scalar, check_integer, check_shape
from facestats.errors import ValidationError
from facestats.face.geometry import FaceGeometry
from facestats.face.named import named_face

__all__ = ["StageCamera", "stage_camera", "subject_geometry", "mesh_uv", "vertex_normals", "ViewSurface",
           "view_surface", "ray_triangle"]  # fmt: skip


@dataclass
class StageCamera:
    """A square pinhole camera of the virtual light stage.

    Attributes
    ----------
    position : ndarray, shape (3,)
        Camera centre, mm (world frame).
    target : ndarray, shape (3,)
        Point at the image centre, mm.
    fov_deg : float
        Full field of view, degrees, in (0, 180).
    size : int
        Image side, pixels.
    """

    position: np.ndarray
    target: np.ndarray
    fov_deg: float
    size: int

    def __post_init__(self):
        self.position = check_shape(as_finite(self.position, "position", dtype=np.float64), "position", (3,))
        self.target = check_shape(as_finite(self.target, "target", dtype=np.float64), "target", (3,))
        if np.linalg.norm(self.target - self.position) <= 0:
            raise ValidationError("target must differ from the camera position, got the same point")
        self.fov_deg = as_scalar(self.fov_deg, "fov_deg", 0, 180, low_inclusive=False, high_inclusive=False)
        self.size = check_integer(self.size, "size", 1, 8192)

    @property
    def rotation(self) -> np.ndarray:
        """World-to-camera rotation (rows x right, y down, z forward)."""
        return look_at(self.position, self.target)

    @property
    def focal(self) -> float:
        """Focal length in pixels."""
        return (self.size / 2) / np.tan(np.radians(self.fov_deg) / 2)

    def pinhole(self):
        """``(eye, rot, focal, size)`` as :func:`facestats.acquire.visibility.rasterize` takes it."""
        return self.position, self.rotation, self.focal, self.size

    def rays(self) -> np.ndarray:
        """Unit world directions from the camera centre through every pixel centre, (size, size, 3), [row, col]."""
        c = (np.arange(self.size) + 0.5 - self.size / 2) / self.focal
        cam = np.stack(np.broadcast_arrays(c[None, :], c[:, None], np.ones((1, 1))), axis=-1)
        world = cam @ self.rotation  # rows of rot are the camera axes: rotᵀ · d
        return world / np.linalg.norm(world, axis=-1, keepdims=True)


def stage_camera(
    azimuth_deg: float = 0.0,
    elevation_deg: float = 0.0,
    *,
    distance: float = 1200.0,
    size: int = 256,
    fov_deg: float = 13.0,
    target=(0.0, 0.0, 40.0),
) -> StageCamera:
    """A camera on a sphere around the head, looking at ``target``.

    Azimuth 0 is the frontal camera on +z; positive azimuths turn towards +x
    (the subject's left), positive elevations upwards: the camera sits at
    ``target + distance (cos e sin a, sin e, cos e cos a)``.  The default field
    of view frames the procedural head at 1.2 m.

    Parameters
    ----------
    azimuth_deg : float
        Azimuth a, degrees (any finite value).
    elevation_deg : float
        Elevation e, degrees, in [-90, 90].
    distance : float
        Distance from ``target``, mm, > 0.
    size : int
        Image side, pixels, in [1, 8192].
    fov_deg : float
        Full field of view, degrees, in (0, 180).
    target : array_like, shape (3,)
        Point the camera looks at, mm (world frame).

    Returns
    -------
    StageCamera

    Raises
    ------
    ValidationError
        For an argument outside the ranges above, or a non-finite one.
    """
    a = np.radians(as_scalar(azimuth_deg, "azimuth_deg"))
    e = np.radians(as_scalar(elevation_deg, "elevation_deg", -90, 90))
    dist = as_scalar(distance, "distance", 0, None, low_inclusive=False, unit="mm")
    t = check_shape(as_finite(target, "target", dtype=np.float64), "target", (3,))
    pos = t + dist * np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])
    return StageCamera(pos, t, fov_deg, size)


def subject_geometry(subject, mesh=None, *, scale: float = 1.0, mesh_grid: int = 64) -> FaceGeometry:
    """The face geometry a store subject's maps belong to: a scan given as ``mesh``, else the face its provenance names.

    The name is read by :func:`facestats.io.mesh.recorded_geometry` (the one place, shared with the exporters):
    ``"ict-N"`` (the ICT-FaceKit face of the default, its own mesh) or ``"procedural-N"`` (the procedural head of
    lumitexel grid N, rebuilt here with a ``mesh_grid``² rendering mesh), both through
    :func:`facestats.face.named.named_face`; an edit (``facestats edit``) has its source's face.
    Subjects fitted on a real scan (ingested photographs: the scan's file name is recorded) need that scan:
    ``mesh``, an OBJ/PLY with per-vertex UVs (v up in the file, mm times ``scale``) whose UV layout the maps
    follow, loaded with :func:`facestats.io.mesh.load_face_mesh` and the subject's own ``region`` map.

    Parameters
    ----------
    subject : xarray.Dataset
        A map subject of a store (its ``region`` map is used with ``mesh``, its provenance otherwise).
    mesh : str or os.PathLike, optional
        The scan the maps belong to (OBJ/PLY with per-vertex UVs); None: the face the provenance names.
    scale : float
        Factor from the mesh file's units to mm (``mesh`` only), in (0, 1e6]
        (:func:`facestats.io.mesh.check_mesh_scale`).
    mesh_grid : int
        Side of the rendering mesh of a procedural head, in [8, 1024] (checked even when unused).

    Returns
    -------
    FaceGeometry

    Raises
    ------
    ValidationError
        A subject of region samples (``facestats import-merl``: no maps to render), or one whose recorded face
        cannot be rebuilt and no ``mesh`` (the message names ``--mesh``, the command line's option), or
        ``mesh_grid`` out of range; a ``scale`` out of range, or a ``mesh`` that after ``scale`` is not a face's
        size in mm (:data:`facestats.io.mesh.FACE_SIZE_MM`: the stage camera, placed in mm, would see nothing or
        a part of it; the message starts with ``mesh``, gives the extent and suggests a scale,
        :func:`facestats.io.mesh.face_extent_problem`).
    FormatError
        A ``mesh`` that cannot be read, has no valid UVs or no vertex in the face regions
        (:func:`facestats.io.mesh.load_face_mesh`).
    """
    # local imports: keep facestats.io (21 modules) out of this module's import
    from facestats.io.exr_set import check_map_subject
    from facestats.io.mesh import check_face_extent, check_mesh_scale, load_face_mesh, recorded_geometry

    check_map_subject(subject, "relighting")
    mesh_grid = check_integer(mesh_grid, "mesh_grid", 8, 1024)
    if mesh is not None:
        scale = check_mesh_scale(scale, mesh, "scale")
        geometry = load_face_mesh(mesh, np.asarray(subject["region"].values), scale=scale)
        check_face_extent(geometry.mesh_vertices, mesh, scale)  # a scan in m read as mm: a black image, exit 0
        return geometry
    name = recorded_geometry(subject)
    try:
        return named_face(str(name), mesh_grid=mesh_grid if str(name).startswith("procedural-") else None)
    except ValidationError:
        raise ValidationError(
            f"subject {subject.attrs.get('subject_id', '?')!r} records geometry {name!r}, not a face facestats "
            "can rebuild: pass the scan its maps belong to, an OBJ/PLY with UVs (--mesh PATH on the command line; "
            "mesh=PATH of facestats.relight.camera.subject_geometry in Python)"
        ) from None


def mesh_uv(geometry: FaceGeometry) -> np.ndarray:
    """UV coordinates of every mesh vertex, (V, 2).

    Geometries that carry them (``mesh_uv``: the ICT face): those.  Procedural heads:
    their mesh is a regular grid in UV (vertex i·n + j at ((j + ½)/n, (i + ½)/n)).
    Loaded scans: the lumitexels are mesh vertices, so each vertex takes the UV of
    the nearest lumitexel (exact on the face; off-face vertices only matter as
    background).

    Parameters
    ----------
    geometry : FaceGeometry
        The face; its ``mesh_vertices`` (V, 3) get the UVs.

    Returns
    -------
    numpy.ndarray, shape (V, 2)
        Texture coordinates (u, v) per mesh vertex.

    Raises
    ------
    ValidationError
        A procedural geometry whose vertex count is not a square.
    """
    verts = np.asarray(geometry.mesh_vertices)
    if geometry.mesh_uv is not None:
        return np.asarray(geometry.mesh_uv)
    if geometry.meta.get("kind") == "procedural":
        n = int(round(np.sqrt(len(verts))))
        if n * n != len(verts):
            raise ValidationError(f"procedural mesh must be a square grid of vertices, got {len(verts)} vertices")
        c = (np.arange(n) + 0.5) / n
        uu, vv = np.meshgrid(c, c)
        return np.stack([uu.ravel(), vv.ravel()], axis=1)
    from scipy.spatial import cKDTree

    _, idx = cKDTree(geometry.position).query(verts)
    return geometry.uv[idx]


def vertex_normals(verts, faces):
    """Area-weighted vertex normals of a triangle mesh (zero-area vertices get +z).

    Parameters
    ----------
    verts : numpy.ndarray, shape (V, 3)
        Vertex positions (float).
    faces : numpy.ndarray of int, shape (F, 3)
        Vertex indices of each triangle; the normal follows their winding (right-hand rule).

    Returns
    -------
    numpy.ndarray, shape (V, 3)
        Unit normals: the normalised sum of the (area-scaled) face normals around each vertex.
    """
    tri = verts[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    out = np.zeros_like(verts)
    for k in range(3):  # the three corners, vectorised over faces
        np.add.at(out, faces[:, k], cross)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.where(norm > 0, out / np.where(norm > 0, norm, 1), np.array([0.0, 0.0, 1.0]))


@dataclass
class ViewSurface:
    """The surface seen by each covered pixel of a camera (:func:`view_surface`).

    Attributes
    ----------
    pixel : ndarray of int, shape (N,)
        Flat pixel index (row · size + column) of each covered pixel.
    position : ndarray, shape (N, 3)
        Ray-triangle intersection, mm.
    view : ndarray, shape (N, 3)
        Unit direction towards the camera.
    uv : ndarray, shape (N, 2)
        Texture coordinates.
    vertices : ndarray of int, shape (N, 3)
        Mesh vertices of the pixel's triangle.
    bary : ndarray, shape (N, 3)
        Barycentric weights of those vertices at the intersection.
    size : int
        Image side.
    """

    pixel: np.ndarray
    position: np.ndarray
    view: np.ndarray
    uv: np.ndarray
    vertices: np.ndarray
    bary: np.ndarray
    size: int

    def subset(self, keep):
        """The pixels selected by a boolean mask or index.

        Parameters
        ----------
        keep : ndarray of bool, shape (N,), or index array
            The pixels to keep, along the first axis of every per-pixel array.

        Returns
        -------
        ViewSurface
            Of the same camera ``size``.
        """
        return ViewSurface(
            self.pixel[keep], self.position[keep], self.view[keep], self.uv[keep], self.vertices[keep],
            self.bary[keep], self.size,
        )  # fmt: skip


def view_surface(geometry: FaceGeometry, camera: StageCamera) -> ViewSurface:
    """Rasterise the geometry's mesh into ``camera`` and intersect every covered pixel's ray with its triangle.

    Parameters
    ----------
    geometry : FaceGeometry
        The face, with its rendering mesh (``mesh_vertices``, ``mesh_faces``, mm).
    camera : StageCamera

    Returns
    -------
    ViewSurface
        The covered pixels whose ray meets the triangle in front of the camera (finite t > 0); UVs clipped to
        [0, 1].
    """

    verts = np.asarray(geometry.mesh_vertices, np.float64)
    faces = np.asarray(geometry.mesh_faces, np.int64)
    tri, _ = rasterize(verts, faces, *camera.pinhole())
    pix = np.nonzero(tri.reshape(-1) >= 0)[0]
    t_idx = tri.reshape(-1)[pix]
    rays = camera.rays().reshape(-1, 3)[pix]
    t, bary = ray_triangle(camera.position, rays, *(verts[faces[t_idx, k]] for k in range(3)))
    ok = np.isfinite(t) & (t > 0)
    pos = camera.position + t[:, None] * rays
    uvs = mesh_uv(geometry)[faces[t_idx]]  # (N, 3, 2)
    uv = np.einsum("nk,nkj->nj", bary, uvs)
    surf = ViewSurface(pix, pos, -rays, np.clip(uv, 0, 1), faces[t_idx], bary, camera.size)
    return surf.subset(ok)


def ray_triangle(origin, rays, a, b, c):
    """Möller-Trumbore intersection of rays origin + t·ray with triangles (a, b, c), all (N, 3).

    Returns ``t`` (N,) (NaN/inf for rays parallel to the plane) and the
    barycentric weights (N, 3) of (a, b, c), clipped to [0, 1] (rasterised pixel
    centres lie inside their triangle up to rounding).

    Parameters
    ----------
    origin : array_like, shape (3,) or (N, 3)
        Ray origin(s), e.g. the camera position (mm).
    rays : ndarray, shape (N, 3)
        Ray directions (``t`` is in units of their length).
    a, b, c : ndarray, shape (N, 3)
        The triangles' vertices, one triangle per ray.

    Returns
    -------
    t : ndarray, shape (N,)
        Ray parameter of the hit point origin + t·ray (NaN/inf for rays parallel to the plane).
    bary : ndarray, shape (N, 3)
        Barycentric weights of (a, b, c), clipped to [0, 1].
    """
    e1, e2 = b - a, c - a
    p = np.cross(rays, e2)
    det = np.einsum("nk,nk->n", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = origin - a
        b1 = np.clip(np.einsum("nk,nk->n", s, p) * inv, 0, 1)
        q = np.cross(s, e1)
        b2 = np.clip(np.einsum("nk,nk->n", rays, q) * inv, 0, 1)
        t = np.einsum("nk,nk->n", e2, q) * inv
    return t, np.stack([1 - b1 - b2, b1, b2], axis=1)
