"""The ICT-FaceKit face model (USC ICT Vision and Graphics Lab, MIT licence): neutral mesh and expression shapes.

ICT-FaceKit (public repository ``ICT-VGL/ICT-FaceKit``; Li et al. 2020,
*Learning Formation of Physically-Based Face Attributes*) ships a generic
neutral head (``FaceXModel/generic_neutral_mesh.obj``, 26,719 vertices, quads,
per-corner UVs) and 53 expression shapes named after ARKit (``mouthSmile_L``,
``jawOpen``, ...) as full meshes on the same topology.  Its README gives the
face area as vertices 0-9408 and polygons 0-9229; the face area's UVs fill the
unit square.

:func:`read_ict_facekit` reads a checkout (or the trimmed sample of the tests,
which keeps the face area only) as facestats data: positions from cm to mm
(factor 10), the model's frame already being facestats' (+y up, +z out of the
face, +x to the subject's left: ``_L`` shapes move +x), v flipped to point down.
"""

from __future__ import annotations

import os

from facestats.errors import FormatError, ValidationError
from facestats.io.mesh_sequence import UVMesh, read_obj, read_vertices

__all__ = ["ICT_SCALE_MM", "FACE_VERTICES", "FACE_POLYGONS", "ict_expressions", "read_ict_facekit"]

#: Millimetres per ICT model unit (the model is in cm).
ICT_SCALE_MM = 10.0
#: Vertices and polygons of the full face area (README "Face Area Details").
FACE_VERTICES = 9409
FACE_POLYGONS = 9230

_MODEL_DIR = "FaceXModel"
_NEUTRAL = "generic_neutral_mesh.obj"


def _model_dir(root) -> str:
    root = os.fspath(root)
    for cand in (os.path.join(root, _MODEL_DIR), root):
        if os.path.isfile(os.path.join(cand, _NEUTRAL)):
            return cand
    raise ValidationError(f"root must be an ICT-FaceKit checkout (holding {_MODEL_DIR}/{_NEUTRAL}), got {root!r}")


def ict_expressions(root) -> list[str]:
    """Names of the expression shapes present in a checkout (``identity*`` shapes excluded), sorted.

    Parameters
    ----------
    root : path-like
        An ICT-FaceKit checkout, or its ``FaceXModel`` directory.

    Returns
    -------
    list of str
        File names without ``.obj`` (the neutral mesh excluded).

    Raises
    ------
    ValidationError
        ``root`` holds no ``FaceXModel/generic_neutral_mesh.obj`` (nor ``generic_neutral_mesh.obj`` itself).
    """
    d = _model_dir(root)
    names = [f[:-4] for f in os.listdir(d) if f.endswith(".obj") and f != _NEUTRAL and not f.startswith("identity")]
    return sorted(names)


def _face_area(mesh: UVMesh) -> UVMesh:
    """The mesh restricted to the face area (its polygons index only face-area vertices)."""
    keep = mesh.polygon < FACE_POLYGONS
    tri = mesh.triangles[keep]
    if tri.size and tri.max() >= FACE_VERTICES:
        raise FormatError(f"{mesh.name}: face-area polygons must use vertices 0-{FACE_VERTICES - 1}")
    return UVMesh(
        mesh.vertices[:FACE_VERTICES],
        tri,
        mesh.uv,
        mesh.uv_triangles[keep],
        mesh.polygon[keep],
        name=mesh.name,
        meta=dict(mesh.meta, area="face"),
    )


def read_ict_facekit(root, expressions=None, *, face_only=True):
    """The ICT-FaceKit neutral mesh and expression shapes, in mm with v down.

    Parameters
    ----------
    root : path-like
        An ICT-FaceKit checkout (or its ``FaceXModel`` directory, or a trimmed copy with that layout).
    expressions : sequence of str, optional
        Expression shapes to read (default: every one present, see :func:`ict_expressions`).
    face_only : bool
        Keep the face area (vertices 0-9408, polygons 0-9229) only.

    Returns
    -------
    neutral : UVMesh
        Triangulated (each quad in two), with per-corner UVs.
    targets : dict of str to ndarray (V, 3)
        Expression shapes' positions, mm, on the neutral's vertices; use with
        :class:`facestats.io.mesh_sequence.BlendshapeSequence`.

    Raises
    ------
    FormatError
        A shape whose vertex count or faces differ from the neutral's.
    """
    d = _model_dir(root)
    mesh = read_obj(os.path.join(d, _NEUTRAL), scale=ICT_SCALE_MM).require_uv()
    names = ict_expressions(root) if expressions is None else list(expressions)
    missing = [n for n in names if not os.path.isfile(os.path.join(d, n + ".obj"))]
    if missing:
        raise ValidationError(f"expressions must be shapes of the checkout, got missing {missing}")
    neutral = _face_area(mesh) if face_only else mesh
    targets = {}
    for n in names:  # loop over expression files
        v = read_vertices(os.path.join(d, n + ".obj"), mesh, scale=ICT_SCALE_MM)
        targets[n] = v[:FACE_VERTICES] if face_only else v
    neutral.name = "ICT-FaceKit generic neutral" + (" (face area)" if face_only else "")
    return neutral, targets
