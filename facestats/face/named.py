"""The faces the synthetic population can live on, by name: ``"procedural"`` and ``"ict"``.

* ``"ict"`` — :func:`facestats.face.ict.ict_face`, the face area of ICT-FaceKit's
  neutral head (a real face, registered from light-stage scans; MIT licence): the face of the
  embedded default (:data:`facestats.core.conventions.DEFAULT_FACE`);
* ``"procedural"`` — :func:`facestats.face.procedural.procedural_face`, a parametric head
  (an ellipsoidal cap with a nose), kept as an option.

A geometry records which face it is in :attr:`FaceGeometry.name` (``"ict-48"``: the ICT face with
lumitexels on a 48² grid); :func:`named_face` rebuilds it from that name, which is how a subject's
capture provenance, a truth's ``geometry`` and the exporters find the face again.
"""

from __future__ import annotations

import re

from facestats.core.validate import check_choice, check_integer
from facestats.errors import ValidationError
from facestats.face.geometry import FaceGeometry

__all__ = ["FACES", "face_geometry", "named_face", "parse_face_name"]

#: Names of the faces :func:`face_geometry` builds.
FACES = ("procedural", "ict")

_NAME = re.compile(r"^(procedural|ict)-(\d+)$")


def face_geometry(
    face: str, lumitexel_grid: int, map_size: int | None = None, *, mesh_grid: int | None = None
) -> FaceGeometry:
    """The face ``face`` (one of :data:`FACES`) with lumitexels on a ``lumitexel_grid``² UV grid.

    Parameters
    ----------
    face : {"procedural", "ict"}
        Which face.
    lumitexel_grid : int
        Side of the UV grid of lumitexels.
    map_size : int, optional
        Side of the UV maps (default ``lumitexel_grid``).
    mesh_grid : int, optional
        The procedural head's rendering mesh, 8 to 4096 (default: that of
        :func:`~facestats.face.procedural.procedural_face`); ignored for the ICT face, whose mesh is the
        scan's.

    Returns
    -------
    FaceGeometry

    Raises
    ------
    ValidationError
        An unknown ``face`` or a ``mesh_grid`` out of range (or a grid the face refuses).
    """
    check_choice(face, "face", FACES)
    if face == "ict":
        from facestats.face.ict import ict_face

        return ict_face(lumitexel_grid, map_size)
    from facestats.face.procedural import procedural_face

    mesh_grid = None if mesh_grid is None else check_integer(mesh_grid, "mesh_grid", 8, 4096)
    return procedural_face(lumitexel_grid, map_size, mesh_grid)


def parse_face_name(name: str) -> tuple[str, int]:
    """The face and lumitexel grid N of a face name ``"procedural-N"`` or ``"ict-N"`` (:attr:`FaceGeometry.name`).

    Parameters
    ----------
    name : str
        The name (converted with ``str``).

    Returns
    -------
    face : str
        ``"procedural"`` or ``"ict"``.
    n : int
        The lumitexel grid N.

    Raises
    ------
    ValidationError
        When ``name`` is not such a name (a face loaded from a scan must be loaded again from it).
    """
    m = _NAME.match(str(name))
    if not m:
        raise ValidationError(
            f"geometry must name a face facestats can rebuild ('procedural-N' or 'ict-N'), got {name!r}; "
            "a face loaded from a scan is loaded again with facestats.io.mesh.load_face_mesh"
        )
    return m.group(1), int(m.group(2))


def named_face(name: str, map_size: int | None = None, *, mesh_grid: int | None = None) -> FaceGeometry:
    """Rebuild the face a record names (``"procedural-N"`` or ``"ict-N"``, as :attr:`FaceGeometry.name`).

    Parameters
    ----------
    name : str
        ``FACE-N``: one of :data:`FACES` and its lumitexel grid N.
    map_size : int, optional
        Side of the maps (default N).
    mesh_grid : int, optional
        As :func:`face_geometry`.

    Returns
    -------
    FaceGeometry
        The face, as the record's simulation built it.

    Raises
    ------
    ValidationError
        When ``name`` is not such a name (:func:`parse_face_name`).
    """
    face, grid = parse_face_name(name)
    return face_geometry(face, grid, map_size, mesh_grid=mesh_grid)
