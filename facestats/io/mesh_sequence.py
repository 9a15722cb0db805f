"""Animated meshes with texture coordinates: OBJ/PLY frames and blendshape targets with per-frame weights.

A sequence is a neutral (rest) :class:`UVMesh` plus, for every frame, new
vertex positions on the same topology.  Two kinds:

* :class:`FrameSequence` — one OBJ or PLY file per frame (read when the frame
  is asked for, so long sequences stream);
* :class:`BlendshapeSequence` — blendshape targets (full meshes on the neutral's
  topology, e.g. the ICT-FaceKit expressions of :mod:`facestats.io.ict_facekit`)
  and a weight per target and frame (:func:`read_weights`): frame = neutral +
  Σ_k w_k (target_k − neutral).

OBJ files are read by :func:`read_obj`, which keeps the per-corner texture
indices (``f v/vt``) so that UV seams stay seams (trimesh would split the
vertices and renumber them); PLY files through trimesh with per-vertex UVs.
Conventions: positions in mm (``scale`` converts, e.g. 10 for cm), the world
frame of facestats (pass ``transform``), UV with v down (files store v up, so v
is flipped unless ``flip_v=False``).  Every frame must have the neutral's vertex
count and, where the file holds faces, the same faces; otherwise a
:class:`~facestats.errors.FormatError` names the file and what differs.
"""

from __future__ import annotations

import io
import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from facestats.core.validate import as_finite, check_rigid_transform, check_shape
from facestats.errors import FormatError, ValidationError
from facestats.io.layout import read_regular_file
from facestats.model.strain import triangulate

__all__ = [
    "UVMesh",
    "read_obj",
    "read_mesh",
    "check_mesh_file",
    "load_trimesh",
    "read_vertices",
    "FrameSequence",
    "BlendshapeSequence",
    "MAX_WEIGHT",
    "read_weights",
]


@dataclass
class UVMesh:
    """A triangle mesh with per-corner texture coordinates.

    Attributes
    ----------
    vertices : ndarray, shape (V, 3)
        Positions, mm.
    triangles : ndarray of int, shape (F, 3)
        Vertex indices (polygons of the file split into triangles).
    uv : ndarray, shape (T, 2) or None
        Texture coordinates in [0, 1], u right, v down.
    uv_triangles : ndarray of int, shape (F, 3) or None
        Index into ``uv`` of every corner.
    polygon : ndarray of int, shape (F,)
        Index of the file's polygon each triangle comes from.
    name : str
    meta : dict
        What the reader knows beyond the geometry (e.g. ``area="face"`` for ICT-FaceKit's face area).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray | None
    uv_triangles: np.ndarray | None
    polygon: np.ndarray
    name: str = "mesh"
    meta: dict = field(default_factory=dict)

    @property
    def n_vertices(self) -> int:
        return int(len(self.vertices))

    def require_uv(self):
        """Raise unless the mesh has texture coordinates."""
        if self.uv is None or self.uv_triangles is None:
            raise FormatError(f"mesh {self.name!r} has no texture coordinates (OBJ 'vt' or PLY s/t, u/v), got none")
        return self


def place_vertices(vertices, scale, transform, name):
    """Mesh vertices scaled to mm and moved by ``transform`` (4 × 4 rigid) into the world frame.

    Parameters
    ----------
    vertices : array_like, shape (V, 3)
        As stored in the file.
    scale : float
        Factor to mm (> 0), applied first.
    transform : array_like (4, 4) or None
        Rigid transform applied after scaling.
    name : str
        The file, for messages.

    Returns
    -------
    ndarray, shape (V, 3)
        float64, mm, all finite.

    Raises
    ------
    FormatError
        A vertex that is not finite (in the file, or after ``scale`` and ``transform``), named by its index.
    ValidationError
        ``scale`` not > 0, or ``transform`` not rigid.
    """
    if not float(scale) > 0:
        raise ValidationError(f"scale must be > 0, got {scale!r}")
    v = np.asarray(vertices, np.float64) * float(scale)
    if transform is not None:
        t = check_rigid_transform(transform)
        v = v @ t[:3, :3].T + t[:3, 3]
    if not np.all(np.isfinite(v)):
        bad = int(np.nonzero(~np.all(np.isfinite(v), axis=1))[0][0])
        raise FormatError(f"vertices of {name} must be finite, got {v[bad].tolist()} at vertex {bad}")
    return v


def _fan(corners):
    """Triangles (fan from the first corner) of one polygon's corner list."""
    return [(corners[0], corners[k], corners[k + 1]) for k in range(1, len(corners) - 1)]


def _parse_faces(face_lines, n_v, n_vt, name):
    """Vertex and texture indices of the 'f' lines, fan-triangulated: (tri (F,3), uv_tri (F,3) or None, polygon)."""
    tris, uv_tris, poly = [], [], []
    has_vt = None
    for k, line in enumerate(face_lines):  # loop over polygons: OBJ face syntax is per token
        toks = [t.split("/") for t in line.split()[1:]]
        if len(toks) < 3:
            raise FormatError(f"{name}: face {k} must have at least 3 corners, got {line.strip()!r}")
        try:
            vi = [int(t[0]) for t in toks]
            ti = [int(t[1]) if len(t) > 1 and t[1] else None for t in toks]
        except ValueError:
            raise FormatError(
                f"{name}: face {k} must hold integer indices (v, v/vt or v/vt/vn), got {line.strip()!r}"
            ) from None
        if 0 in vi or 0 in ti:  # OBJ indices start at 1 (negative: relative to the end)
            raise FormatError(f"{name}: face {k} holds the index 0 (OBJ indices start at 1), got {line.strip()!r}")
        this_vt = all(t is not None for t in ti)
        has_vt = this_vt if has_vt is None else (has_vt and this_vt)
        vi = [i - 1 if i > 0 else n_v + i for i in vi]  # OBJ is 1-based; negative = relative
        for tri in _fan(vi):
            tris.append(tri)
            poly.append(k)
        if this_vt:
            ti = [i - 1 if i > 0 else n_vt + i for i in ti]
            uv_tris.extend(_fan(ti))
    try:
        tri = np.asarray(tris, np.int64).reshape(-1, 3)
        uv_tri = np.asarray(uv_tris, np.int64).reshape(-1, 3) if has_vt else None
    except OverflowError:  # an index beyond int64; the range checks of the caller name the others
        raise FormatError(f"{name}: face indices must be at most 2**63 - 1") from None
    return tri, uv_tri, np.asarray(poly, np.int64)


def _numbers(lines, width, name, what):
    """The first ``width`` numbers after the keyword of each line, (n, width) float64.

    Every line must hold at least ``width`` numbers (more are ignored: an OBJ ``v`` line may carry w or a colour).
    """
    rest = [ln.split(None, 1)[1] if " " in ln.strip() else "" for ln in lines]
    counts = np.fromiter(map(len, map(str.split, rest)), np.int64, len(rest))
    short = np.flatnonzero(counts < width)
    if short.size:
        k = int(short[0])
        raise FormatError(
            f"{name}: {what!r} lines must hold at least {width} numbers, got {lines[k].strip()!r} "
            f"(line {k + 1} of them)"
        )
    try:
        if counts.size and np.all(counts == counts[0]):  # one reshape of all the numbers
            return np.array(" ".join(rest).split(), dtype=np.float64).reshape(len(rest), -1)[:, :width]
        return np.array([r.split()[:width] for r in rest], dtype=np.float64)
    except ValueError as exc:
        raise FormatError(f"{name}: cannot read the {what} lines: {exc}") from None


def _parse_obj(name: str, faces: bool = True):
    """The arrays of an OBJ file as stored, checked for structure: ``(vertices, uv, tri, uv_tri, polygon)``.

    ``uv`` and ``uv_tri`` are None when the file has no ``vt`` or a face lacks texture indices; with ``faces``
    False only the vertices are read (the rest empty or None).
    """
    try:
        lines = read_regular_file(name).decode("utf-8", errors="replace").splitlines()
    except OSError as exc:  # a FIFO or a device is refused, never read
        raise FormatError(f"cannot read the mesh {name}: {exc}") from None
    v_lines = [ln for ln in lines if ln.startswith("v ")]
    if not v_lines:
        raise FormatError(f"{name} holds no vertices ('v' lines)")
    verts = _numbers(v_lines, 3, name, "v")
    if not faces:
        return verts, None, np.zeros((0, 3), np.int64), None, np.zeros(0, np.int64)
    vt_lines = [ln for ln in lines if ln.startswith("vt ")]
    uv = _numbers(vt_lines, 2, name, "vt") if vt_lines else None
    tri, uv_tri, poly = _parse_faces([ln for ln in lines if ln.startswith("f ")], len(verts), len(vt_lines), name)
    if tri.size and (tri.min() < 0 or tri.max() >= len(verts)):
        raise FormatError(f"{name}: faces must index the {len(verts)} vertices, got {tri.min() + 1}..{tri.max() + 1}")
    if uv is None or uv_tri is None:
        return verts, None, tri, None, poly
    if uv_tri.size and (uv_tri.min() < 0 or uv_tri.max() >= len(uv)):
        raise FormatError(f"{name}: faces must index the {len(uv)} texture coordinates")
    return verts, uv, tri, uv_tri, poly


def read_obj(path, *, scale=1.0, transform=None, flip_v=True, faces=True) -> UVMesh:
    """Read a Wavefront OBJ with its per-corner texture coordinates.

    Parameters
    ----------
    path : str or path-like
    scale : float
        Factor to mm (e.g. 10 for cm).
    transform : array_like (4, 4), optional
        Rigid transform applied after scaling.
    flip_v : bool
        Flip v (OBJ stores v up; facestats has v down).
    faces : bool
        False reads only the vertices (a blendshape target or frame; faces are then not checked).

    Returns
    -------
    UVMesh
        Polygons fan-triangulated (quads into two triangles); ``uv`` None when
        the file has no ``vt`` or a face lacks texture indices.
    """
    name = os.fspath(path)
    stored, uv, tri, uv_tri, poly = _parse_obj(name, faces)
    verts = place_vertices(stored, scale, transform, name)
    if not faces:
        return UVMesh(verts, tri, None, None, poly, name=os.path.basename(name))
    if uv is not None and uv_tri is not None:
        if flip_v:
            uv[:, 1] = 1 - uv[:, 1]
        if not np.all(np.isfinite(uv)):
            raise FormatError(f"{name}: texture coordinates must be finite")
    else:
        uv, uv_tri = None, None
    return UVMesh(verts, tri, uv, uv_tri, poly, name=os.path.basename(name))


def load_trimesh(path):
    """A mesh file read by trimesh (no processing) and checked: ``(vertices, faces, uv)``.

    An OBJ file is first parsed as :func:`read_obj` does, with checks trimesh does not
    make (a ``v`` line with two numbers drops z from every vertex in trimesh, the
    invalid index 0 becomes vertex 1), and read without its materials: the UVs as stored,
    not repacked into a texture atlas of the materials' images.

    Parameters
    ----------
    path : str or path-like
        A mesh file trimesh reads (OBJ, PLY, ...).

    Returns
    -------
    vertices : ndarray of float64, shape (V, 3)
        As stored (no scale, no transform).
    faces : ndarray of int64, shape (F, 3)
        Indexing ``vertices``.
    uv : ndarray of float64, shape (V, 2), or None
        Per-vertex UVs as stored (v upwards; texture visuals, or PLY ``s``/``t``, ``u``/``v`` or
        ``texture_u``/``texture_v`` vertex properties), finite.

    Raises
    ------
    FormatError
        An unreadable file, one without vertices, or arrays of the wrong shape or range.
    """
    import trimesh

    name = os.fspath(path)
    options = {}
    if os.path.splitext(name)[1].lower() == ".obj":
        _parse_obj(name)
        # With its materials (an .mtl beside it naming textures), trimesh packs the parts' textures into one atlas
        # and rewrites the UVs into it: the maps would land on the wrong vertices (a user's real-data run).
        options["skip_materials"] = True
    try:
        mesh = trimesh.load(name, force="mesh", process=False, **options)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise FormatError(f"cannot read the mesh {name}: {exc}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.vertices) == 0:
        raise FormatError(f"{name} holds no mesh")
    verts = np.asarray(mesh.vertices, np.float64)
    if verts.ndim != 2 or verts.shape[1] != 3:
        raise FormatError(f"vertices of {name} must have 3 coordinates, got shape {verts.shape}")
    faces = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= len(verts)):
        raise FormatError(
            f"faces of {name} must index its {len(verts)} vertices, got indices {faces.min()}..{faces.max()}"
        )
    uv = _trimesh_uv(mesh)
    if uv is not None and (uv.shape != (len(verts), 2) or not np.all(np.isfinite(uv))):
        raise FormatError(
            f"texture coordinates of {name} must be finite (u, v) pairs, one per vertex, got shape {uv.shape}"
            + ("" if uv.shape != (len(verts), 2) else " with non-finite values")
        )
    return verts, faces, uv


def _trimesh_uv(mesh):
    """Per-vertex UVs of a trimesh mesh as stored (texture visuals, else PLY vertex properties), float64, or None."""
    uv = getattr(mesh.visual, "uv", None)
    if uv is None and "ply_raw" in mesh.metadata:
        props = mesh.metadata["ply_raw"]["vertex"]["data"]
        names = props.dtype.names or ()
        for a, b in (("s", "t"), ("u", "v"), ("texture_u", "texture_v")):
            if a in names and b in names:
                uv = np.stack([props[a], props[b]], 1)
                break
    return None if uv is None else np.array(uv, np.float64)


def _read_ply(path, scale, transform, flip_v) -> UVMesh:
    name = os.fspath(path)
    verts, faces, uv = load_trimesh(name)
    tri, poly = triangulate(faces)
    verts = place_vertices(verts, scale, transform, name)
    if uv is not None and flip_v:
        uv[:, 1] = 1 - uv[:, 1]
    return UVMesh(verts, tri, uv, None if uv is None else tri, poly, name=os.path.basename(name))


def read_mesh(path, *, scale=1.0, transform=None, flip_v=True) -> UVMesh:
    """Read an OBJ (:func:`read_obj`) or PLY (through trimesh, per-vertex UVs) mesh.

    Parameters
    ----------
    path : str or path-like
        An existing ``.obj`` or ``.ply`` file.
    scale : float
        Factor to mm (> 0; e.g. 10 for cm).
    transform : array_like (4, 4), optional
        Rigid transform applied after scaling.
    flip_v : bool
        Flip v (files store v up; facestats has v down).

    Returns
    -------
    UVMesh
        ``uv`` None when the file has no texture coordinates; a PLY's UVs are per vertex (``uv_triangles`` equals
        ``triangles``).

    Raises
    ------
    ValidationError
        ``path`` does not exist or has another extension (:func:`check_mesh_file`), ``scale`` is not > 0 or
        ``transform`` is not rigid.
    FormatError
        A file that cannot be read as a mesh (the message names it).
    """
    if check_mesh_file(path) == ".obj":
        return read_obj(path, scale=scale, transform=transform, flip_v=flip_v)
    return _read_ply(path, scale, transform, flip_v)


def check_mesh_file(path, name: str = "mesh file") -> str:
    """The suffix (``.obj`` or ``.ply``, lower case) of ``path``, which must exist: the files :func:`read_mesh` reads.

    Parameters
    ----------
    path : str or path-like
        The file.
    name : str
        What ``path`` was given as, for the message (e.g. ``"frames"``: the parameter of
        :func:`facestats.pipeline.microstructure.open_sequence`, which the command line names by its option).

    Returns
    -------
    str
        ``".obj"`` or ``".ply"``.

    Raises
    ------
    ValidationError
        ``path`` does not exist (checked first: ``/nope`` was "must be .obj or .ply", a fresh-user red team), or
        its extension is another; the message starts with ``name`` and gives ``path``.
    """
    if not os.path.exists(path):
        raise ValidationError(f"{name} must name an existing .obj or .ply file, got {os.fspath(path)!r}")
    ext = os.path.splitext(os.fspath(path))[1].lower()
    if ext not in (".obj", ".ply"):
        raise ValidationError(f"{name} must be .obj or .ply, got {os.fspath(path)!r}")
    return ext


def read_vertices(path, neutral: UVMesh, *, scale=1.0, transform=None) -> np.ndarray:
    """The vertex positions of a frame or target file, checked against the neutral's topology.

    Parameters
    ----------
    path : str or path-like
        An OBJ or PLY file (read as :func:`read_obj` / :func:`read_mesh` do, v not flipped).
    neutral : UVMesh
        The rest mesh, in mm.
    scale : float
        Factor to mm (> 0; e.g. 10 for cm).
    transform : array_like (4, 4), optional
        Rigid transform applied after scaling.

    Returns
    -------
    ndarray of float64, shape (V, 3)
        Positions, mm.

    Raises
    ------
    FormatError
        If the vertex count differs, the file's faces (if it has any) differ from the neutral's, or the
        frame's extent (bounding-box diagonal) is not within 0.5-2 times the neutral's (a unit mismatch);
        or the file cannot be read.
    ValidationError
        ``scale`` not > 0 or ``transform`` not rigid; a missing PLY file.
    """
    name = os.fspath(path)
    ext = os.path.splitext(name)[1].lower()
    mesh = (
        read_obj(path, scale=scale, transform=transform, flip_v=False)
        if ext == ".obj"
        else read_mesh(path, scale=scale, transform=transform, flip_v=False)
    )
    if mesh.n_vertices != neutral.n_vertices:
        raise FormatError(
            f"{name}: topology differs from the neutral {neutral.name!r}: "
            f"{mesh.n_vertices} vertices, expected {neutral.n_vertices}"
        )
    if len(mesh.triangles) and not np.array_equal(mesh.triangles, neutral.triangles):
        n_diff = (
            int(np.sum(np.any(mesh.triangles != neutral.triangles, axis=1)))
            if mesh.triangles.shape == neutral.triangles.shape
            else f"{len(mesh.triangles)} vs {len(neutral.triangles)} triangles"
        )
        raise FormatError(f"{name}: topology differs from the neutral {neutral.name!r}: faces differ ({n_diff})")
    size = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    rest = float(np.linalg.norm(np.ptp(neutral.vertices, axis=0)))
    if rest > 0 and not (0.5 <= size / rest <= 2.0):  # no expression halves or doubles a face's extent
        raise FormatError(
            f"{name}: its extent is {size / rest:.3g} x the neutral's ({size:.4g} vs {rest:.4g} mm after scale "
            f"{scale}); frames must be in the neutral mesh's units (with an ICT-FaceKit folder as the neutral, read "
            "in mm, pass the scale of the frames' units, e.g. 10 for cm)"
        )
    return mesh.vertices


class FrameSequence:
    """Frames read from one OBJ/PLY file each, on the topology of a neutral mesh.

    Parameters
    ----------
    neutral : UVMesh
        The rest mesh (with UVs).
    paths : sequence of path-like
        One file per frame, in order.
    scale, transform
        As for :func:`read_obj` (applied to every frame).
    """

    def __init__(self, neutral: UVMesh, paths, *, scale=1.0, transform=None):
        self.neutral = neutral.require_uv()
        self.paths = [os.fspath(p) for p in paths]
        if not self.paths:
            raise ValidationError("paths must name at least one frame file, got none")
        missing = [p for p in self.paths if not os.path.isfile(p)]
        if missing:
            raise ValidationError(f"paths must name existing frame files, got missing {missing[0]!r}")
        self.scale, self.transform = scale, transform

    def __len__(self) -> int:
        return len(self.paths)

    def frame(self, index: int) -> np.ndarray:
        """Vertex positions of frame ``index`` (mm).

        Parameters
        ----------
        index : int
            The frame's position in :attr:`paths` (Python indexing: negative counts from the end).

        Returns
        -------
        ndarray of float64, shape (V, 3)
            Positions, mm (:func:`read_vertices`, which raises :class:`FormatError` for a frame whose topology
            or extent differs from the neutral's).
        """
        return read_vertices(self.paths[index], self.neutral, scale=self.scale, transform=self.transform)

    def frame_names(self) -> list[str]:
        """The frames' file names, in order."""
        return [os.path.basename(p) for p in self.paths]


#: Largest |weight| of a blendshape target in a frame (weights are fractions of the target's displacement,
#: usually 0-1; beyond ten times a target's displacement a frame is no longer a face and its strain overflows).
MAX_WEIGHT = 10.0


class BlendshapeSequence:
    """Frames as the neutral plus weighted blendshape deltas.

    Parameters
    ----------
    neutral : UVMesh
    targets : dict of str to ndarray (V, 3)
        Target positions (mm) by name, on the neutral's topology.
    weights : array_like, shape (n_frames, n_targets)
        Weight of each target (columns in the order of ``names``) in each frame, within
        ±:data:`MAX_WEIGHT`.
    names : sequence of str, optional
        Target names of the weight columns (default: the order of ``targets``).
    """

    def __init__(self, neutral: UVMesh, targets: dict, weights, names=None):
        self.neutral = neutral.require_uv()
        self.names = list(targets) if names is None else list(names)
        unknown = [n for n in self.names if n not in targets]
        if unknown:
            raise ValidationError(f"names must be targets {sorted(targets)}, got unknown {unknown}")
        for n in self.names:
            t = np.asarray(targets[n])
            if t.shape != neutral.vertices.shape:
                raise FormatError(
                    f"target {n!r}: topology differs from the neutral: shape {t.shape}, "
                    f"expected {neutral.vertices.shape}"
                )
            bad = ~np.isfinite(t).all(axis=1)
            if bad.any():
                k = int(np.argmax(bad))
                raise ValidationError(f"target {n!r} must hold finite vertices, got {t[k].tolist()} at vertex {k}")
        self.deltas = np.stack([np.asarray(targets[n], np.float64) - neutral.vertices for n in self.names])
        w = as_finite(weights, "weights", -MAX_WEIGHT, MAX_WEIGHT, dtype=np.float64)
        if w.ndim == 1 and len(self.names) == 1:
            w = w[:, None]
        self.weights = check_shape(w, "weights", (None, len(self.names)))

    def __len__(self) -> int:
        return int(self.weights.shape[0])

    def frame(self, index: int) -> np.ndarray:
        """Vertex positions of frame ``index``: neutral + Σ_k w_k Δ_k (mm).

        Parameters
        ----------
        index : int
            The frame: a row of the weights (Python indexing: negative counts from the end).

        Returns
        -------
        ndarray of float64, shape (V, 3)
            Positions, mm.
        """
        return self.neutral.vertices + np.tensordot(self.weights[index], self.deltas, axes=1)

    def frame_names(self) -> list[str]:
        """``frame00000``, ``frame00001``, ... one per row of the weights."""
        return [f"frame{i:05d}" for i in range(len(self))]


def read_weights(path) -> tuple[list[str], np.ndarray]:
    """Per-frame blendshape weights from a CSV file: a header of target names, one row per frame.

    A first column named ``frame`` (frame numbers) is ignored.

    Parameters
    ----------
    path : str or path-like
        The CSV file.

    Returns
    -------
    names : list of str
    weights : ndarray, shape (n_frames, n_targets)
    """
    import pandas as pd

    try:
        data = io.BytesIO(read_regular_file(path))  # a FIFO or a device is refused, never read
        with warnings.catch_warnings():  # a row longer than the header: pandas drops or shifts its values
            warnings.simplefilter("error", pd.errors.ParserWarning)
            table = pd.read_csv(data, index_col=False)
    except (OSError, ValueError, pd.errors.ParserWarning) as exc:
        raise FormatError(f"cannot read the weights {os.fspath(path)}: {exc}") from None
    if table.shape[1] and str(table.columns[0]).strip().lower() == "frame":
        table = table.iloc[:, 1:]
    if table.shape[1] == 0 or table.shape[0] == 0:
        raise FormatError(f"weights {os.fspath(path)} must have a header of target names and one row per frame")
    names = [str(c).strip() for c in table.columns]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:  # pandas renames a repeated header (a, a.1), and names equal after stripping stay apart
        raise FormatError(f"weights {os.fspath(path)} must name each target once, got {twice} more than once")
    try:
        w = table.to_numpy(np.float64)
    except ValueError as exc:
        raise FormatError(f"weights {os.fspath(path)} must be numbers: {exc}") from None
    if not np.all(np.isfinite(w)):
        raise FormatError(f"weights {os.fspath(path)} must be finite numbers, got NaN or empty cells")
    return names, w
