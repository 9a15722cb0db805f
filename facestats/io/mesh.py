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
  scikit-image), a ``.npy`` file or an array; its side is the output map size.
"""

from __future__ import annotations

import os

import numpy as np

from facestats.acquire.geometry import FaceGeometry, uv_to_texel
from facestats.errors import FormatError, ValidationError

__all__ = ["load_face_mesh", "read_region_image", "save_face_mesh"]


def read_region_image(region_image) -> np.ndarray:
    """A square label image (uint8, 0-10) from a path (PNG, TIFF, .npy) or an array."""
    if isinstance(region_image, (str, os.PathLike)):
        path = os.fspath(region_image)
        try:
            if path.endswith(".npy"):
                img = np.load(path)
            else:
                from skimage.io import imread

                img = imread(path)
        except (OSError, ValueError) as exc:
            raise FormatError(f"cannot read the region image {path}: {exc}") from None
    else:
        img = np.asarray(region_image)
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
    import trimesh

    try:
        mesh = trimesh.load(os.fspath(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise FormatError(f"cannot read the mesh {os.fspath(path)}: {exc}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise FormatError(f"{os.fspath(path)} holds no triangle mesh")
    uv = getattr(mesh.visual, "uv", None)
    if uv is None and "ply_raw" in mesh.metadata:
        props = mesh.metadata["ply_raw"]["vertex"]["data"]
        names = props.dtype.names or ()
        for a, b in (("s", "t"), ("u", "v"), ("texture_u", "texture_v")):
            if a in names and b in names:
                uv = np.stack([props[a], props[b]], 1).astype(np.float64)
                break
    if uv is None or len(uv) != len(mesh.vertices):
        raise FormatError(f"{os.fspath(path)} has no per-vertex UV coordinates (OBJ 'vt' or PLY s/t, u/v properties)")
    uv = np.asarray(uv, np.float64).copy()
    if flip_v:
        uv[:, 1] = 1 - uv[:, 1]
    if np.any(~np.isfinite(uv)) or uv.min() < -1e-6 or uv.max() > 1 + 1e-6:
        raise FormatError(f"UV coordinates of {os.fspath(path)} must lie in [0, 1], got {uv.min():.3g}..{uv.max():.3g}")
    uv = np.clip(uv, 0, 1)
    if not float(scale) > 0:
        raise ValidationError(f"scale must be > 0, got {scale!r}")
    verts = np.asarray(mesh.vertices, np.float64) * float(scale)
    if transform is not None:
        t = np.asarray(transform, np.float64)
        if t.shape != (4, 4):
            raise ValidationError(f"transform must be a 4x4 matrix, got shape {t.shape}")
        verts = verts @ t[:3, :3].T + t[:3, 3]
    faces = np.asarray(mesh.faces, np.int64)
    # Vertex normals (area-weighted face normals) and areas (one third of each triangle).
    tri = verts[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    tri_area = 0.5 * np.linalg.norm(cross, axis=1)
    normals = np.zeros_like(verts)
    area = np.zeros(len(verts))
    for k in range(3):  # loop over the three corners, vectorised over faces
        np.add.at(normals, faces[:, k], cross)
        np.add.at(area, faces[:, k], tri_area / 3)
    length = np.linalg.norm(normals, axis=1)
    regions = read_region_image(region_image)
    size = regions.shape[0]
    texel = uv_to_texel(uv, size)
    label = regions[texel[:, 0], texel[:, 1]]
    keep = (label > 0) & (length > 0) & (area > 0)
    if not keep.any():
        raise FormatError("no mesh vertex falls on a labelled face region of the region image")
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


def save_face_mesh(geometry: FaceGeometry, path, region_path=None):
    """Write a procedural geometry's shadowing mesh as an OBJ with per-vertex UVs (and its region image as .npy).

    The OBJ holds the triangle mesh of :func:`facestats.acquire.synthetic.face.procedural_face`
    (its vertices lie on a regular UV grid of side ``mesh_grid``) with the UV of
    every vertex (v upwards, as files store it), so :func:`load_face_mesh` reads
    it back; the lumitexels it then finds are the mesh vertices on labelled
    texels, which are the geometry's own lumitexels when ``mesh_grid`` equals the
    lumitexel grid.  Use it to hand a procedural face to other tools.

    Raises
    ------
    ValidationError
        For geometries that are not procedural (their mesh vertices have no UV grid).
    """
    import trimesh

    if geometry.grid_index is None or geometry.meta.get("kind") != "procedural":
        raise ValidationError(f"geometry must be procedural (mesh vertices on the UV grid), got {geometry.name!r}")
    verts = np.asarray(geometry.mesh_vertices)
    faces = np.asarray(geometry.mesh_faces)
    mesh = trimesh.Trimesh(verts, faces, process=False)
    n = int(round(np.sqrt(len(verts))))
    c = (np.arange(n) + 0.5) / n
    uu, vv = np.meshgrid(c, c)
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.stack([uu.ravel(), 1 - vv.ravel()], 1))
    mesh.export(os.fspath(path))
    if region_path is not None and geometry.region_map is not None:
        np.save(os.fspath(region_path), geometry.region_map)
    return os.fspath(path)
