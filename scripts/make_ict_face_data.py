"""Write facestats/data/ict_face_area.npz from an ICT-FaceKit checkout (or tests/data/ict-facekit).

Usage::

    python scripts/make_ict_face_data.py [ICT_FACEKIT_ROOT]   # default: tests/data/ict-facekit

The archive holds the face area of ICT-FaceKit's generic neutral mesh (MIT licence; vertices 0-9408,
polygons 0-9229 split into triangles), read by :func:`facestats.io.ict_facekit.read_ict_facekit`:
``vertices`` (V, 3) float32 mm, ``triangles`` (F, 3) int32, ``uv`` (U, 2) float32 (u right, v down),
``uv_triangles`` (F, 3) int32.  The licence is copied beside it.
"""

import pathlib
import shutil
import sys

import numpy as np

from facestats.io.ict_facekit import read_ict_facekit

here = pathlib.Path(__file__).resolve().parent.parent
root = pathlib.Path(sys.argv[1]) if len(sys.argv) > 1 else here / "tests" / "data" / "ict-facekit"
mesh, _ = read_ict_facekit(root, expressions=[])
out = here / "facestats" / "data" / "ict_face_area.npz"
np.savez_compressed(
    out,
    vertices=mesh.vertices.astype(np.float32),
    triangles=mesh.triangles.astype(np.int32),
    uv=mesh.uv.astype(np.float32),
    uv_triangles=mesh.uv_triangles.astype(np.int32),
)
shutil.copyfile(root / "LICENSE", here / "facestats" / "data" / "ICT-FaceKit-LICENSE.txt")
print(f"wrote {out} ({out.stat().st_size / 1e3:.0f} kB)")
