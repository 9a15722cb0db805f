"""The faces the synthetic population can live on, by name: ``"procedural"`` and ``"ict"``.

* ``"procedural"`` — :func:`facestats.acquire.synthetic.face.procedural_face`, the parametric head
  of the embedded default;
* ``"ict"`` — :func:`facestats.acquire.synthetic.ict_face.ict_face`, the face area of ICT-FaceKit's
  neutral head (a real face, registered from light-stage scans; MIT licence).
"""

from __future__ import annotations

from facestats.acquire.geometry import FaceGeometry
from facestats.core.validate import check_choice

__all__ = ["FACES", "face_geometry"]

#: Names of the faces :func:`face_geometry` builds.
FACES = ("procedural", "ict")


def face_geometry(face: str, lumitexel_grid: int, map_size: int | None = None) -> FaceGeometry:
    """The face ``face`` (one of :data:`FACES`) with lumitexels on a ``lumitexel_grid``² UV grid and
    ``map_size``² maps (default ``lumitexel_grid``)."""
    check_choice(face, "face", FACES)
    if face == "ict":
        from facestats.acquire.synthetic.ict_face import ict_face

        return ict_face(lumitexel_grid, map_size)
    from facestats.acquire.synthetic.face import procedural_face

    return procedural_face(lumitexel_grid, map_size)
