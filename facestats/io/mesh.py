"""Real face scans: OBJ/PLY meshes with UVs and a region label image, as :class:`FaceGeometry`.

Weyrich et al. 2006 §5: the scanned mesh is subdivided to 700,000-900,000
vertices and a lumitexel is gathered at each vertex; a conformal UV
parameterisation maps the face to 2D.  :func:`load_face_mesh` reads such a mesh
(anything trimesh reads with per-vertex texture coordinates: OBJ with ``vt``,
PLY with ``s``/``t`` or ``u``/``v`` vertex properties), samples a region label
image at each vertex's UV, and returns the vertices of the labelled face as
lumitexels; the whole mesh is kept for shadowing.

Conventions and checks:

* Units: the mesh must be in mm, or pass ``scale`` (e.g. 1000 for metres).
* Frame: facestats' world frame (+y up, +z out of the face, towards the frontal
  camera); pass ``transform`` (4 × 4) to place another frame.
* UV: image convention inside facestats (v grows downwards); OBJ/PLY files store
  v upwards, so v is flipped unless ``flip_v=False``.
* Areas: each vertex represents one third of the area of its triangles.
* Region image: integer labels 0-10 (0 = not face) as a PNG/TIFF (read with
  :func:`facestats.io.images.read_integer_image`), a ``.npy`` file or an array; its side is the output map size.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass

import numpy as np

from facestats.core.raster import triangle_coverage
from facestats.core.validate import as_finite, as_scalar, check_integer, check_shape
from facestats.errors import FormatError, ValidationError
from facestats.face.geometry import FaceGeometry, uv_to_texel
from facestats.face.named import face_geometry, parse_face_name
from facestats.io.mesh_sequence import load_trimesh, place_vertices
from facestats.io.schema import provenance

__all__ = [
    "load_face_mesh",
    "read_region_image",
    "read_triangle_mesh",
    "save_face_mesh",
    "procedural_mesh",
    "geometry_mesh",
    "write_mesh",
    "FaceMesh",
    "subject_mesh",
    "recorded_geometry",
    "FACE_SIZE_MM",
    "MAX_MESH_SCALE",
    "check_mesh_scale",
    "check_face_extent",
    "face_extent_problem",
]


def read_region_image(region_image) -> np.ndarray:
    """A square label image (uint8, 0-10) from a path (PNG, TIFF, .npy) or an array.

    Parameters
    ----------
    region_image : str, os.PathLike or array_like
        The image; an RGB(A) image must be greyscale (one label per pixel).

    Returns
    -------
    ndarray of uint8, shape (n, n)

    Raises
    ------
    FormatError
        Unreadable, not square, colours, or labels outside 0-10.
    """
    if isinstance(region_image, (str, os.PathLike)):
        from facestats.io.images import INTEGER_EXTENSIONS, read_integer_image, read_npy

        path = os.fspath(region_image)
        ext = os.path.splitext(path)[1].lower()
        if ext != ".npy" and ext not in INTEGER_EXTENSIONS:  # a label image: no HDR format holds integer labels
            raise FormatError(
                f"region image {path!r} has the extension {ext!r}; expected one of {('.npy',) + INTEGER_EXTENSIONS}"
            )
        if ext == ".npy":
            img = read_npy(path, "region image")
        else:
            try:
                img, _ = read_integer_image(path)  # (H, W, C) codes as stored, C = 1 for grey
            except (OSError, ValueError) as exc:  # ImageFormatError is a ValueError (ValidationError)
                raise FormatError(f"cannot read the region image {path}: {exc}") from None
    else:
        img = np.asarray(region_image)
    if img.size == 0 or img.dtype.kind not in "biu":
        raise FormatError(f"region image must hold integer labels 0-10, got dtype {img.dtype} and shape {img.shape}")
    if img.ndim == 3:  # a label PNG saved as RGB(A) greyscale
        if not np.all(img[..., :3] == img[..., :1]):
            raise FormatError(
                f"region image must hold one label per pixel (greyscale), got shape {img.shape} with colours"
            )
        img = img[..., 0]
    if img.ndim != 2 or img.shape[0] != img.shape[1]:
        raise FormatError(f"region image must be a square 2-D label image, got shape {img.shape}")
    if not np.issubdtype(img.dtype, np.integer) or img.min() < 0 or img.max() > 10:
        raise FormatError(
            f"region image must hold integer labels 0-10, got dtype {img.dtype} and range {img.min()}..{img.max()}"
        )
    return img.astype(np.uint8)


def read_triangle_mesh(path, *, scale=1.0, transform=None, uv=False):
    """Read a triangle mesh (OBJ, PLY, anything trimesh reads) in mm, in the world frame.

    Parameters
    ----------
    path : str or path-like
        Mesh file.
    scale : float
        Factor to mm (1 if the mesh is in mm).
    transform : array_like, shape (4, 4), optional
        Rigid transform applied after scaling (module docstring).
    uv : bool
        Also return the per-vertex UV coordinates as stored (v upwards), or None
        if the file has none (OBJ ``vt``, PLY ``s``/``t``, ``u``/``v`` or
        ``texture_u``/``texture_v`` vertex properties).

    Returns
    -------
    vertices : ndarray, shape (V, 3)
        mm, all finite.
    faces : ndarray of int, shape (F, 3)
    uv : ndarray, shape (V, 2) or None
        Only when ``uv=True``.

    Raises
    ------
    FormatError
        An unreadable file, one without triangles, or a vertex that is not finite (NaN or infinite in
        the file, or after ``scale`` and ``transform``; :func:`~facestats.io.mesh_sequence.place_vertices`).
    """
    stored, faces, stored_uv = load_trimesh(path)
    if len(faces) == 0:
        raise FormatError(f"{os.fspath(path)} holds no triangle mesh")
    verts = place_vertices(stored, scale, transform, os.fspath(path))
    if not uv:
        return verts, faces
    return verts, faces, stored_uv


def load_face_mesh(path, region_image, *, scale=1.0, transform=None, flip_v=True, name=None) -> FaceGeometry:
    """Load a face scan with UVs and its region label image as a :class:`FaceGeometry`.

    Parameters
    ----------
    path : str or path-like
        OBJ or PLY file with per-vertex UV coordinates.
    region_image : str, path-like or array
        Square label image in UV space (0 = not face, 1-10 regions of Weyrich Fig. 15).
    scale : float
        Factor to mm (1 if the mesh is in mm).
    transform : array_like, shape (4, 4), optional
        Rigid transform applied (after scaling) to bring the mesh into the world frame.
    flip_v : bool
        Flip the v coordinate (files store v upwards).
    name : str, optional
        Geometry name (default: the file name).

    Returns
    -------
    FaceGeometry
        Lumitexels at the labelled vertices; map size = side of the region image.
    """
    verts, faces, stored = read_triangle_mesh(path, scale=scale, transform=transform, uv=True)
    uv = _checked_uv(stored, len(verts), path, flip_v)
    normals, area = _vertex_normals_and_areas(verts, faces)
    length = np.linalg.norm(normals, axis=1)
    regions = read_region_image(region_image)
    size = regions.shape[0]
    texel = uv_to_texel(uv, size)
    label = regions[texel[:, 0], texel[:, 1]]
    keep = (label > 0) & (length > 0) & (area > 0)
    if not keep.any():
        raise FormatError(_no_face_region_message(path, region_image, uv, regions, label))
    return FaceGeometry(
        position=verts[keep],
        normal=normals[keep] / length[keep, None],
        area=area[keep],
        uv=uv[keep],
        region=label[keep],
        map_size=size,
        mesh_vertices=verts,
        mesh_faces=faces,
        region_map=regions,
        name=name or os.path.basename(os.fspath(path)),
        meta={"kind": "mesh", "path": os.fspath(path), "mesh_grid": int(np.sqrt(len(faces) / 2))},
        mesh_uv=uv,
    )


def _no_face_region_message(path, region_image, uv, regions, label) -> str:
    """Why no vertex of a mesh became a lumitexel: the mesh's vertex count and UV range, the image's labels."""
    image = os.fspath(region_image) if isinstance(region_image, (str, os.PathLike)) else "(an array)"
    n = regions.shape[0]
    on_label = int(np.count_nonzero(label > 0))
    return (
        f"no mesh vertex falls on a labelled face region of the region image: mesh {os.fspath(path)} has "
        f"{len(uv)} vertices with UV u in [{uv[:, 0].min():.4g}, {uv[:, 0].max():.4g}], v in "
        f"[{uv[:, 1].min():.4g}, {uv[:, 1].max():.4g}] (image convention, v down); region image {image} is {n}×{n} "
        f"pixels with {int(np.count_nonzero(regions))} labelled (label 1-10); {on_label} vertices land on labelled "
        f"pixels{' (all on degenerate triangles: zero normal or area)' if on_label else ''}"
    )


def _checked_uv(uv, n_vertices, path, flip_v: bool) -> np.ndarray:
    """The per-vertex UVs checked to lie in [0, 1] (v flipped to the image convention if ``flip_v``)."""
    if uv is None or len(uv) != n_vertices:
        raise FormatError(f"{os.fspath(path)} has no per-vertex UV coordinates (OBJ 'vt' or PLY s/t, u/v properties)")
    if flip_v:
        uv[:, 1] = 1 - uv[:, 1]
    if np.any(~np.isfinite(uv)) or uv.min() < -1e-6 or uv.max() > 1 + 1e-6:
        raise FormatError(f"UV coordinates of {os.fspath(path)} must lie in [0, 1], got {uv.min():.3g}..{uv.max():.3g}")
    return np.clip(uv, 0, 1)


def _vertex_normals_and_areas(verts: np.ndarray, faces: np.ndarray):
    """Vertex normals (area-weighted face normals, not normalised) and areas (one third of each triangle)."""
    tri = verts[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    tri_area = 0.5 * np.linalg.norm(cross, axis=1)
    normals = np.zeros_like(verts)
    area = np.zeros(len(verts))
    for k in range(3):  # loop over the three corners, vectorised over faces
        np.add.at(normals, faces[:, k], cross)
        np.add.at(area, faces[:, k], tri_area / 3)
    return normals, area


def procedural_mesh(geometry: FaceGeometry):
    """The triangle mesh of a procedural geometry with the UV of every vertex (unused grid vertices dropped).

    The vertices of :func:`facestats.face.procedural.procedural_face`'s
    mesh lie on a regular ``mesh_grid``² grid in UV: vertex ``(i, j)`` sits at
    u = (j + 0.5)/n, v = (i + 0.5)/n (facestats' UV convention, v down).

    Parameters
    ----------
    geometry : FaceGeometry
        A procedural geometry.

    Returns
    -------
    vertices : ndarray, shape (V, 3)
        mm, world frame.
    faces : ndarray of int64, shape (F, 3)
    uv : ndarray, shape (V, 2)
        (u, v) in facestats' convention (v down).

    Raises
    ------
    ValidationError
        For geometries that are not procedural (their mesh vertices have no UV grid).
    """
    if geometry.grid_index is None or geometry.meta.get("kind") != "procedural":
        raise ValidationError(f"geometry must be procedural (mesh vertices on the UV grid), got {geometry.name!r}")
    verts = np.asarray(geometry.mesh_vertices)
    faces = np.asarray(geometry.mesh_faces)
    n = int(round(np.sqrt(len(verts))))
    c = (np.arange(n) + 0.5) / n
    uu, vv = np.meshgrid(c, c)
    uv = np.stack([uu.ravel(), vv.ravel()], 1)
    used = np.unique(faces)
    remap = np.full(len(verts), -1, np.int64)
    remap[used] = np.arange(len(used))
    return verts[used], remap[faces], uv[used]


def geometry_mesh(geometry: FaceGeometry):
    """The triangle mesh of a face geometry with the UV of every vertex: :func:`procedural_mesh` for a
    procedural head, the mesh as it is for a geometry that carries one UV per mesh vertex (``mesh_uv``:
    the ICT face, :func:`facestats.face.ict.ict_face`, split along its UV seams).

    Parameters
    ----------
    geometry : facestats.face.geometry.FaceGeometry
        A procedural head or a geometry with ``mesh_uv``.

    Returns
    -------
    vertices : ndarray, shape (V, 3)
    faces : ndarray of int64, shape (F, 3)
    uv : ndarray, shape (V, 2)
        (u, v) in facestats' convention (v down).

    Raises
    ------
    ValidationError
        For geometries with neither (a loaded scan: write the scan itself).
    """
    if geometry.meta.get("kind") == "procedural":
        return procedural_mesh(geometry)
    uv = geometry.mesh_uv
    if uv is None or len(uv) != len(geometry.mesh_vertices):
        raise ValidationError(
            f"geometry {geometry.name!r} has no UV per mesh vertex (procedural heads and the ICT face have); "
            "write the scan it was loaded from instead"
        )
    return np.asarray(geometry.mesh_vertices, float), np.asarray(geometry.mesh_faces, np.int64), np.asarray(uv, float)


def write_mesh(path, vertices, faces, uv=None, normals=None) -> str:
    """Write a triangle mesh as OBJ or PLY (by extension), with per-vertex UVs (``vt``; ``s``/``t``) or without.

    The OBJ has no material (``mtllib``): the maps are the material, written beside it by the caller.

    Files store v upwards (OBJ/PLY convention), so ``1 - v`` is written;
    :func:`load_face_mesh` flips it back.  Without ``uv`` the file holds the
    vertices and triangles only (OBJ ``v`` and ``f a b c`` lines): the plain
    mesh :func:`read_triangle_mesh` (and so ``facestats translucency``) reads,
    which :func:`load_face_mesh` refuses (it needs UVs).

    An OBJ holds coordinates with 8 decimals (10⁻⁸ mm for a mesh in mm), a PLY
    (binary) float32 values (trimesh's writer); the vertices keep their order and
    the triangles their corners' (the normal (b − a) × (c − a), its direction).
    Read back (:func:`read_triangle_mesh`), an OBJ loses the vertices no triangle
    uses (trimesh's reader drops them and renumbers the faces): the triangles
    are the same.

    Parameters
    ----------
    path : str or os.PathLike
        ``.obj`` or ``.ply``.
    vertices : array_like, shape (V, 3)
    faces : array_like of int, shape (F, 3)
    uv : array_like, shape (V, 2), optional
        (u, v) in facestats' convention (v down), in [0, 1]; None (default): no texture coordinates.
    normals : array_like, shape (V, 3), optional
        Per-vertex unit normals to write (OBJ ``vn``, PLY ``nx ny nz``).

    Returns
    -------
    str
        ``path``.

    Raises
    ------
    ValidationError
        Another extension, arrays of the wrong shape or not finite, or a face index outside the vertices;
        nothing is written then.
    """
    import trimesh

    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".obj", ".ply"):
        raise ValidationError(f"mesh path must end in .obj or .ply, got {path!r}")
    v = as_finite(vertices, "vertices", dtype=np.float64)
    check_shape(v, "vertices", (None, 3))
    f = np.asarray(faces)
    if f.size and not np.issubdtype(f.dtype, np.integer):
        raise ValidationError(f"faces must be integer vertex indices, got dtype {f.dtype}")
    f = f.astype(np.int64)
    check_shape(f, "faces", (None, 3))
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValidationError(f"faces must index 0..{len(v) - 1}, got {f.min()}..{f.max()}")
    t = None if uv is None else check_shape(as_finite(uv, "uv", dtype=np.float64), "uv", (len(v), 2))
    kw = {}
    if normals is not None:
        kw["vertex_normals"] = check_shape(as_finite(normals, "normals", dtype=np.float64), "normals", (len(v), 3))
    mesh = trimesh.Trimesh(v, f, process=False, **kw)
    if t is not None:
        mesh.visual = trimesh.visual.TextureVisuals(uv=np.stack([t[:, 0], 1 - t[:, 1]], 1))
    if ext == ".obj":
        from trimesh.exchange.obj import export_obj

        # UVs only: trimesh would add a placeholder material (material.mtl and a grey 2 × 2 PNG beside the OBJ).
        text = export_obj(mesh, include_normals=normals is not None, include_texture=True, write_texture=False)
        lines = [ln for ln in text.splitlines() if not ln.startswith(("mtllib ", "usemtl "))]
        with open(path, "w", encoding="ascii") as fh:
            fh.write("\n".join(lines) + "\n")
    else:
        mesh.export(path, file_type="ply")
    return path


def save_face_mesh(geometry: FaceGeometry, path, region_path=None):
    """Write a face geometry's shadowing mesh as an OBJ with per-vertex UVs (and its region image as .npy).

    The OBJ holds the triangle mesh of the geometry (:func:`geometry_mesh`: a
    procedural head or the ICT face) with the UV of every vertex (v upwards, as
    files store it), so :func:`load_face_mesh` reads it back; the lumitexels it
    then finds are the mesh vertices on labelled texels, which are a procedural
    geometry's own lumitexels when ``mesh_grid`` equals the lumitexel grid.  Use
    it to hand a face to other tools.

    Parameters
    ----------
    geometry : FaceGeometry
        A procedural geometry or the ICT face.
    path : str or os.PathLike
        The OBJ (or PLY) file to write.
    region_path : str or os.PathLike, optional
        Where to save the region label image (``.npy``).

    Returns
    -------
    str
        ``path``.

    Raises
    ------
    ValidationError
        For geometries without a UV per mesh vertex (:func:`geometry_mesh`).
    """
    verts, faces, uv = geometry_mesh(geometry)
    write_mesh(path, verts, faces, uv)
    if region_path is not None and geometry.region_map is not None:
        np.save(os.fspath(region_path), geometry.region_map)
    return os.fspath(path)


@dataclass
class FaceMesh:
    """A face mesh ready for export: vertices (mm), triangles, per-vertex UVs and normals, and where it came from.

    Attributes
    ----------
    vertices : ndarray, shape (V, 3)
        mm, facestats' world frame (+x subject's left, +y up, +z out of the face).
    faces : ndarray of int64, shape (F, 3)
        Counter-clockwise seen from outside (normals point out of the face).
    uv : ndarray, shape (V, 2)
        (u, v) in facestats' convention (v down, maps indexed ``[v, u]``).
    normals : ndarray, shape (V, 3)
        Unit vertex normals (area-weighted triangle normals).
    geometry : dict
        What geometry was used: ``kind`` (``procedural`` or ``mesh``), ``name``
        and its parameters or source file; written into every export.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    normals: np.ndarray
    geometry: dict

    def vertex_tangents(self):
        """Unit tangents orthogonal to the vertex normals and their handedness w (glTF ``TANGENT``).

        Lengyel (2001): per triangle T = ∂p/∂u and B = −∂p/∂v (up the texture),
        summed at the vertices; T made orthogonal to N; w = sign((N × T)·B), so
        the bitangent is B = w N × T (glTF 2.0 §3.7.2.1).

        Returns
        -------
        tangent : ndarray, shape (V, 3)
        w : ndarray, shape (V,)
            ±1.
        """
        t, b = _vertex_tangents(self.vertices, self.faces, self.uv)
        n = self.normals
        t = t - n * np.einsum("ij,ij->i", t, n)[:, None]
        t = _unit_or(t, np.cross(np.array([0.0, 1.0, 0.0]), n))
        w = np.where(np.einsum("ij,ij->i", np.cross(n, t), b) < 0, -1.0, 1.0)
        return t, w

    def boundary_edges(self) -> np.ndarray:
        """The edges of the surface's openings (holes and outer rim), directed as their one triangle runs them.

        Vertices split along UV seams (one position, several UVs) are welded by exact position first, so a
        seam is not an opening.  An edge (a, b) of a triangle is on the boundary when no triangle runs (b, a).
        A closed (watertight) surface has none; the default store's ``ict-48`` face has 362: the eyes (42
        each), the mouth (74) and the rim around the sides of the head and the neck (204).

        Returns
        -------
        ndarray of int64, shape (E, 2)
            Vertex indices into :attr:`vertices` (for a welded position, its first vertex).
        """
        _, first, welded = np.unique(self.vertices, axis=0, return_index=True, return_inverse=True)
        welded = welded.reshape(-1)
        f = welded[np.asarray(self.faces, np.int64)]
        edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        n = int(welded.max(initial=-1)) + 1
        open_ = ~np.isin(edges[:, 0] * n + edges[:, 1], edges[:, 1] * n + edges[:, 0])
        return first[edges[open_]].astype(np.int64)

    def tangent_frames(self, size: int):
        """Tangent frames (T, B, N) at the texel centres of a ``size``² map, each shape (size, size, 3), float32.

        Per-vertex tangents follow Lengyel (2001, "Computing tangent space basis
        vectors for an arbitrary mesh"): per triangle T = ∂p/∂u and B = −∂p/∂v
        (v down in facestats, so −∂p/∂v points up the texture, the "+Y up"
        convention of glTF 2.0 and OpenGL normal maps), summed at the vertices,
        then T is made orthogonal to N (Gram-Schmidt) and B = N × T · w with w = ±1
        the handedness (:meth:`vertex_tangents`).  A texel the UV triangles cover
        takes the frame a renderer decodes there: N and T interpolated
        barycentrically across the triangle under the texel centre
        (:func:`facestats.core.raster.triangle_coverage`), N normalised, T made
        orthogonal to it, B = w N × T (glTF 2.0 §3.7.2.1; the Khronos sample
        viewer).  A texel no triangle covers takes the frame of the vertex nearest
        to it in UV (looked up on a grid of side min(size, max(512, 4 √V)), V
        vertices).  (Before, every texel took its nearest vertex's frame, which a
        renderer interpolating across the triangle decoded 1.4° off at the median
        and 14° at worst on the ICT face.)

        Computed in float64 a band of :data:`FRAME_BAND` rows (and a group of covered texels) at a time and
        stored in float32 (orthonormal to about 1e-7): whole-map float64 temporaries took 4 GB at 4096²
        (the speed red team); the outputs take 36 bytes a texel.

        Parameters
        ----------
        size : int
            Side of the map in texels (≥ 1).

        Returns
        -------
        tangent, bitangent, normal : ndarray of float32, shape (size, size, 3)
            Orthonormal, right-handed up to ``w`` (B = w N × T).
        """
        from scipy.spatial import cKDTree

        check_integer(size, "size", 1)
        t_v, w_v = self.vertex_tangents()
        n_v = self.normals
        # texels off the triangles: the nearest vertex's frame, looked up on a grid of side min(size, max(512,
        # 4 √V)) (at least four lookups per vertex spacing) and repeated to ``size``
        res = int(min(size, max(512, 4 * np.sqrt(len(self.uv)))))
        c = (np.arange(res) + 0.5) / res
        uu, vv = np.meshgrid(c, c)
        _, near = cKDTree(self.uv).query(np.stack([uu.ravel(), vv.ravel()], 1), workers=-1)
        near = near.reshape(res, res).astype(np.int32)
        cell = (np.arange(size) * res) // size
        n = np.empty((size, size, 3), np.float32)
        t = np.empty((size, size, 3), np.float32)
        w = np.empty((size, size), np.float32)
        for r0 in range(0, size, FRAME_BAND):  # bands of rows, each vectorised
            idx = near[cell[r0 : r0 + FRAME_BAND, None], cell[None, :]]
            n[r0 : r0 + FRAME_BAND], t[r0 : r0 + FRAME_BAND], w[r0 : r0 + FRAME_BAND] = n_v[idx], t_v[idx], w_v[idx]
        groups = triangle_coverage(self.uv[:, 0] * size, self.uv[:, 1] * size, self.faces, size, size)
        for tri, row, col, *lam in groups:  # one group of covered texels at a time
            lam = np.stack(lam, -1)
            corner = self.faces[tri]
            n[row, col] = _unit_or(np.einsum("kc,kcd->kd", lam, n_v[corner]), n_v[corner[:, 0]])
            t[row, col] = np.einsum("kc,kcd->kd", lam, t_v[corner])
            w[row, col] = np.where(np.einsum("kc,kc->k", lam, w_v[corner]) < 0, -1.0, 1.0)
        b = np.empty_like(t)
        for r0 in range(0, size, FRAME_BAND):  # T made orthogonal to N, then B = w N × T, band by band
            nb = n[r0 : r0 + FRAME_BAND].reshape(-1, 3).astype(np.float64)
            tb = t[r0 : r0 + FRAME_BAND].reshape(-1, 3).astype(np.float64)
            tb -= nb * np.einsum("ij,ij->i", tb, nb)[:, None]
            tb = _unit_or(tb, nb, fallback_of_normal=True)
            shape = t[r0 : r0 + FRAME_BAND].shape
            t[r0 : r0 + FRAME_BAND] = tb.reshape(shape)
            b[r0 : r0 + FRAME_BAND] = (np.cross(nb, tb) * w[r0 : r0 + FRAME_BAND].reshape(-1, 1)).reshape(shape)
        return t, b, n


#: Rows of a map :meth:`FaceMesh.tangent_frames` works on at a time.
FRAME_BAND = 256


def _vertex_tangents(verts, faces, uv):
    """Per-vertex sums of the triangles' ∂p/∂u and −∂p/∂v (Lengyel 2001), not normalised."""
    p0, p1, p2 = (verts[faces[:, k]] for k in range(3))
    t0, t1, t2 = (uv[faces[:, k]] for k in range(3))
    e1, e2 = p1 - p0, p2 - p0
    d1, d2 = t1 - t0, t2 - t0
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    r = np.where(np.abs(det) > 1e-20, 1.0 / np.where(det == 0, 1, det), 0.0)[:, None]
    dpdu = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * r
    dpdv = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * r
    t = np.zeros_like(verts)
    b = np.zeros_like(verts)
    for k in range(3):  # the three corners, vectorised over triangles
        np.add.at(t, faces[:, k], dpdu)
        np.add.at(b, faces[:, k], -dpdv)
    return t, b


def _unit_or(v, fallback, *, fallback_of_normal=False):
    """Rows of ``v`` normalised; rows of length 0 replaced by the normalised ``fallback`` rows.

    With ``fallback_of_normal``, ``fallback`` holds unit normals and a short row takes ``(0, 1, 0) × n`` of its
    normal, computed for those rows only.
    """
    length = np.linalg.norm(v, axis=1)
    short = ~(length > 1e-12)
    if fallback_of_normal:
        v = v.copy() if short.any() else v
        v[short] = np.cross(np.array([0.0, 1.0, 0.0]), fallback[short])
    else:
        v = np.where(short[:, None], fallback, v)
    return v / np.maximum(np.linalg.norm(v, axis=1), 1e-300)[:, None]


#: Edits of edits followed by :func:`recorded_geometry` at most (a cycle cannot occur in stored JSON; a bound anyway).
MAX_EDIT_DEPTH = 64


def recorded_geometry(ds) -> str | None:
    """The name of the face a subject's maps belong to, from its provenance: the one place it is read.

    ``capture_provenance.geometry`` of a fitted subject (``ict-N`` or ``procedural-N`` for the synthetic
    population, which :func:`facestats.face.named.named_face` rebuilds; the scan's file name, e.g.
    ``face.obj``, for a subject ingested from photographs), else ``geometry`` of generated truth (the texture
    sample).  A subject written by ``facestats edit`` keeps the face of its source: without a geometry of its
    own, its ``source_provenance`` is followed (through edits of edits).  Used by :func:`subject_mesh` (the
    exporters, the web app's EXR set), :func:`facestats.relight.camera.subject_geometry` (relighting) and
    :mod:`facestats.pipeline.validation` (renders), so they agree.

    Parameters
    ----------
    ds : xarray.Dataset
        A subject (its ``provenance`` attribute).

    Returns
    -------
    str or None
        None when no provenance in the chain records a geometry.
    """
    prov = provenance(ds)
    for _ in range(MAX_EDIT_DEPTH):
        if not isinstance(prov, dict):
            return None
        cap = prov.get("capture_provenance")
        name = (cap.get("geometry") if isinstance(cap, dict) else None) or prov.get("geometry")
        if name:
            return str(name)
        prov = prov.get("source_provenance")
    return None


#: Extent (largest side of the bounding box, mm) of a face or head scan: outside it, :func:`subject_mesh` warns and
#: relighting refuses (:func:`face_extent_problem`).
FACE_SIZE_MM = (50.0, 1000.0)

#: Largest mesh ``scale`` (mm per unit of the file): a mesh in km; beyond, positions overflow in the maps' frames.
MAX_MESH_SCALE = 1e6

#: Units a suggested scale names (:func:`face_extent_problem`): mm per unit.
_UNITS = {1e-3: "µm", 0.1: "0.1 mm", 1.0: "mm", 10.0: "cm", 100.0: "dm", 1000.0: "m"}


def check_mesh_scale(scale, mesh, name: str = "mesh_scale") -> float:
    """A mesh scale checked: the factor from a mesh file's unit to mm, given only with a mesh.

    The one check of ``facestats export-subject``, ``relight`` and ``render``'s ``--mesh-scale``
    (:func:`facestats.cli.options.named_options` renames ``mesh_scale`` to the option) and of
    :func:`facestats.relight.camera.subject_geometry`'s ``scale``.

    Parameters
    ----------
    scale : float or None
        mm per unit of the mesh file, in (0, :data:`MAX_MESH_SCALE`]; None: not given (1).
    mesh : str, os.PathLike or None
        The mesh it scales; None when no mesh is given.
    name : str
        The parameter's name in messages.

    Returns
    -------
    float
        The scale, 1.0 when not given.

    Raises
    ------
    ValidationError
        A scale without a mesh, or one that is not a finite number in (0, :data:`MAX_MESH_SCALE`].
    """
    if scale is None:
        return 1.0
    if mesh is None:
        raise ValidationError(
            f"{name} applies only with a mesh (mesh=PATH; --mesh PATH on the command line), and none is given"
        )
    return as_scalar(scale, name, 0, MAX_MESH_SCALE, low_inclusive=False)


def face_extent_problem(vertices, mesh, scale: float = 1.0) -> str | None:
    """Why a face mesh read with ``scale`` has not a face's size in mm, or None when it has.

    The extent is the largest side of the vertices' bounding box; a face or head scan spans
    :data:`FACE_SIZE_MM`.  Outside it the message gives the extent and the scale, and suggests the scale, a power
    of ten, that brings the file's own extent (the extent over ``scale``) nearest to 224 mm (the range's geometric
    middle), with the unit it stands for: a scan in m read as mm is 0.2 mm across, and ``scale`` 1000 makes it
    200 mm, whatever ``scale`` it was read with.

    Parameters
    ----------
    vertices : array_like, shape (V, 3)
        The mesh's vertices after ``scale`` (mm if the scale is right).
    mesh : str or os.PathLike
        The mesh file (named in the message).
    scale : float
        The factor the vertices were read with.

    Returns
    -------
    str or None
        A message starting with ``mesh <path> is … mm across``, or None.
    """
    v = np.asarray(vertices, np.float64)
    across = float(np.ptp(v, axis=0).max()) if len(v) else 0.0
    if FACE_SIZE_MM[0] <= across <= FACE_SIZE_MM[1]:
        return None
    said = (
        f"mesh {os.fspath(mesh)} is {across:.4g} mm across with scale {scale:g}, outside a face's "
        f"{FACE_SIZE_MM[0]:g}-{FACE_SIZE_MM[1]:g} mm"
    )
    if not across > 0:  # all vertices at one point: no scale helps
        return f"{said}: its vertices are all at one point"
    # the scale for the file's own extent (across / scale, in its unit), not a factor on the scale given: with scale
    # 1e6 a 0.25-unit scan was told "if the file is in µm, pass scale 1000"
    with np.errstate(over="ignore", divide="ignore"):
        decades = float(np.log10(np.sqrt(FACE_SIZE_MM[0] * FACE_SIZE_MM[1]) * scale / across))
    suggest = 10.0 ** round(decades) if np.isfinite(decades) else None
    unit = _UNITS.get(suggest)
    if unit is None:
        return f"{said}: pass the factor from its unit to mm as scale (--mesh-scale on the command line)"
    return (
        f"{said}: if the file is in {unit}, pass scale {suggest:g} (--mesh-scale {suggest:g} on the "
        "command line, the factor from its unit to mm)"
    )


def check_face_extent(vertices, mesh, scale: float = 1.0) -> None:
    """Refuse a face mesh that, read with ``scale``, has not a face's size in mm (:func:`face_extent_problem`).

    What renders and relights check: a scan in m read as mm is a fraction of a mm across, and a camera placed in mm
    would see nothing or a part of it.  (Exports only warn: :func:`subject_mesh`.)

    Parameters
    ----------
    vertices : array_like, shape (V, 3)
        The mesh's vertices after ``scale``.
    mesh : str or os.PathLike
        The mesh file (named in the message).
    scale : float
        The factor the vertices were read with.

    Raises
    ------
    ValidationError
        The message of :func:`face_extent_problem`: the extent, the scale given and the scale to pass.
    """
    problem = face_extent_problem(vertices, mesh, scale)
    if problem is not None:
        raise ValidationError(problem)


def subject_mesh(ds, mesh=None, *, scale: float = 1.0, mesh_grid: int | None = None) -> FaceMesh:
    """The face mesh a subject's maps belong to, for export (which one is recorded in ``geometry``).

    Parameters
    ----------
    ds : xarray.Dataset
        A map subject.  Without ``mesh``, its provenance must name the face it
        was made on (:func:`recorded_geometry`: ``capture_provenance.geometry`` of
        a fitted subject, ``geometry`` of generated truth such as the texture
        sample, the source's for an edit):
        ``procedural-N`` (every subject of the embedded default; that head is
        rebuilt with :func:`facestats.face.procedural.procedural_face`)
        or ``ict-N`` (the shipped ICT-FaceKit face area,
        :func:`facestats.face.ict.ict_face_uv_mesh`).
    mesh : str or os.PathLike, optional
        An OBJ/PLY scan with per-vertex UVs (v up in the file) whose UV layout
        the subject's maps follow.
    scale : float
        Factor from the mesh file's unit to mm (with ``mesh``).  A mesh whose extent after it lies
        outside :data:`FACE_SIZE_MM` is warned about (a scan in cm or m read as mm; :func:`face_extent_problem`).
    mesh_grid : int, optional
        Grid of the procedural mesh (default 128: 2 × 127² triangles over the head).

    Returns
    -------
    FaceMesh
    """
    if mesh is not None:
        verts, faces, stored = read_triangle_mesh(mesh, scale=scale, uv=True)
        problem = face_extent_problem(verts, mesh, scale)
        if problem is not None:  # a scan in cm or m taken as mm (a user's run)
            warnings.warn(f"the {problem}; the σ maps are per mm", stacklevel=2)
        path = os.path.abspath(os.fspath(mesh))  # recorded in every export: absolute, so it says which file
        geometry = {"kind": "mesh", "name": os.path.basename(path), "path": path, "scale": scale}
        return _face_mesh(verts, faces, _checked_uv(stored, len(verts), mesh, True), geometry)

    name = str(recorded_geometry(ds) or "")
    grid = 128 if mesh_grid is None else check_integer(mesh_grid, "mesh_grid", 8, 4096)
    try:
        face, _ = parse_face_name(name)
    except ValidationError:
        raise ValidationError(
            f"subject {ds.attrs.get('subject_id', '?')!r} does not record a face facestats can rebuild "
            f"(geometry = {name!r}; procedural-N or ict-N); pass mesh=PATH (--mesh) with the scan its maps belong to"
        ) from None
    procedural = face == "procedural"
    # the mesh does not depend on the lumitexel grid: rebuild the cheapest one
    geom = face_geometry(face, 8, int(ds.sizes["u"]), mesh_grid=grid if procedural else None)
    geometry = {
        "kind": "procedural" if procedural else "ict-facekit",
        "name": name,
        "function": "facestats.face.named.named_face",
    }
    if procedural:
        geometry["mesh_grid"] = int(grid)
    return _face_mesh(*geometry_mesh(geom), geometry)


def _face_mesh(verts, faces, uv, geometry) -> FaceMesh:
    normals, _ = _vertex_normals_and_areas(verts, faces)
    normals = _unit_or(normals, np.array([[0.0, 0.0, 1.0]]))
    return FaceMesh(verts, faces, uv, normals, geometry)
