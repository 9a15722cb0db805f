"""The face the maps live on: its geometry, the procedural head, ICT-FaceKit's face and faces by name.

* :mod:`~facestats.face.geometry` — :class:`~facestats.face.geometry.FaceGeometry` (lumitexel points with
  UVs, normals, areas and Weyrich Fig. 15 regions, and a triangle mesh), the world frame and the UV
  convention every stage shares;
* :mod:`~facestats.face.procedural` — the procedural head (an ellipsoidal cap with a nose);
* :mod:`~facestats.face.ict` — ICT-FaceKit's neutral face (MIT), its regions painted: the default face;
* :mod:`~facestats.face.named` — faces by name (``ict-N``, ``procedural-N``), rebuilt from the name a record holds.

A scan (OBJ/PLY with UVs and a region image) is read as a geometry by :func:`facestats.io.mesh.load_face_mesh`.
This package imports nothing of facestats but :mod:`facestats.core` and :mod:`facestats.errors`.
"""

from facestats.face.geometry import FaceGeometry, uv_to_texel
from facestats.face.named import FACES, face_geometry, named_face

__all__ = ["FaceGeometry", "uv_to_texel", "FACES", "face_geometry", "named_face"]
