"""A real face for the synthetic population: ICT-FaceKit's neutral face area with the 10 regions of Fig. 15.

The mesh is the face area (vertices 0-9408, polygons 0-9229, quads split in two)
of the generic neutral head of ICT-FaceKit (public repository
``ICT-VGL/ICT-FaceKit``, MIT licence, ``facestats/data/ICT-FaceKit-LICENSE.txt``;
Li et al. 2020), a face registered from light-stage scans.  It ships as
``facestats/data/ict_face_area.npz`` (written by ``scripts/make_ict_face_data.py``
through :func:`facestats.io.ict_facekit.read_ict_facekit`: mm, +y up, +z out of
the face, +x to the subject's left; UV with v down) and is moved by
:data:`ICT_OFFSET_MM` so that its nose tip sits where the procedural head's does
(z ≈ 101 mm, the dome's centre behind the face).

Lumitexels are the texel centres of a ``lumitexel_grid``² grid in the mesh's UV
layout that a UV triangle covers, as for the procedural head
(:func:`facestats.face.procedural.procedural_face`): position and normal
interpolated barycentrically (area-weighted vertex normals), and the area each
texel represents is the triangle's 3-D area over its UV area in texels.

Regions (:func:`ict_regions`) are painted by position on the face, in mm of the
model frame, from landmarks measured on the mesh: eyebrows centred at
(±32, 47), eyelids at (±32, 32), under-eye at (±32, 17), nose from the bridge
(y = 40) to the subnasale (y = −18), mustache between subnasale and upper lip
(−26 < y ≤ −18), lips around the mouth slit (0, −34), chin (0, −64) and beard
along the jaw, forehead above y = 52, cheeks elsewhere; the face ends at the
hairline, in front of the ears and at the jaw (an ellipse of half-axes 72 × 92 mm
centred at (0, 8)), so the neck and the ears are not face; nor is surface that
is turned more than 80° from the frontal view (:data:`FRONTAL_LIMIT_DEG`: the eye sockets behind the
eyeballs, the underside of the jaw and chin) or lies beside the ears.  Fig. 15's regions are drawn on a
frontal photograph, where such surface is seen edge-on, and the dome lights it only at grazing angles:
on a first build of the default population with the limit at 90°, those 8 % of face texels had 42 % of
their Blinn-Phong fits flagged (1.4 % elsewhere), which made the Blinn-Phong maps of chin and beard
mostly filled values.
``facestats.face.ict.ict_face(256).region_map`` is the label
image in the mesh's UV layout.
"""

from __future__ import annotations

import functools
from importlib import resources

import numpy as np

from facestats.core.raster import triangle_coverage
from facestats.core.validate import check_integer
from facestats.face.geometry import FaceGeometry

__all__ = ["ict_face", "ict_face_mesh", "ict_face_uv_mesh", "ict_regions", "FRONTAL_LIMIT_DEG", "ICT_OFFSET_MM"]

#: Translation (mm) from the ICT-FaceKit model frame into the dome frame: the nose tip (z = 130.9 mm in the
#: model) to z = 100.9 mm, near the procedural head's (z ≈ 103 mm).
ICT_OFFSET_MM = (0.0, 0.0, -30.0)
#: Surface turned more than this (degrees) from the frontal view (+z) is not face (module docstring).
FRONTAL_LIMIT_DEG = 80.0


@functools.cache
def ict_face_mesh():
    """The shipped face area: ``(vertices, triangles, uv, uv_triangles)``.

    ``vertices`` (V, 3) in mm in the dome frame, ``triangles`` (F, 3), ``uv`` (U, 2) with v down,
    ``uv_triangles`` (F, 3); read-only arrays.
    """
    with resources.files("facestats").joinpath("data/ict_face_area.npz").open("rb") as f, np.load(f) as z:
        out = (
            z["vertices"].astype(np.float64) + np.asarray(ICT_OFFSET_MM),
            z["triangles"].astype(np.int64),
            z["uv"].astype(np.float64),
            z["uv_triangles"].astype(np.int64),
        )
    for a in out:
        a.setflags(write=False)
    return out


def ict_face_uv_mesh():
    """The face area with its vertices split along the UV seams: ``(vertices, triangles, uv)``.

    ``vertices`` (U, 3) mm in the dome frame, one per UV vertex, so that ``uv`` (U, 2, v down) holds one
    UV per vertex; ``triangles`` (F, 3) index both (the file's ``uv_triangles``).
    """
    vertices, triangles, uv, uv_triangles = ict_face_mesh()
    split = np.empty((len(uv), 3))
    split[uv_triangles.ravel()] = vertices[triangles.ravel()]
    return split, uv_triangles, uv


def _inside(x, y, x0, y0, ax, ay):
    return ((x - x0) / ax) ** 2 + ((y - y0) / ay) ** 2 <= 1


def ict_regions(x, y):
    """Region labels (Weyrich Fig. 15 numbering, 0: not face) of points of the ICT face at x, y (mm, model frame).

    Parameters
    ----------
    x, y : array_like, same shape
        Coordinates in mm.

    Returns
    -------
    ndarray of uint8, shape of ``x``
        Labels 0-10.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    reg = np.full(x.shape, 7, np.uint8)  # cheeks by default
    reg[y > 52] = 2  # forehead
    reg[(y < -22) & (np.abs(x) > 26)] = 10  # beard along the jaw
    reg[y < -76] = 10
    reg[_inside(x, y, 0, -64, 22, 18) & (y < -44)] = 9  # chin
    for s in (-1, 1):
        reg[_inside(x, y, s * 32, 47, 21, 6.5)] = 3  # eyebrows
        reg[_inside(x, y, s * 32, 32, 16, 8)] = 4  # eyelids
        reg[_inside(x, y, s * 32, 17, 17, 6)] = 5  # under-eye (region 5)
    reg[(y > -18) & (y < 40) & (np.abs(x) < 6 + 0.2 * (40 - y))] = 6  # nose
    reg[(y <= -18) & (y > -26) & (np.abs(x) < 22)] = 1  # mustache
    reg[_inside(x, y, 0, -34, 25, 8.5)] = 8  # lips
    reg[~_inside(x, y, 0, 8, 72, 92)] = 0
    return reg


def _labels(position, normal):
    """Regions of surface points (dome frame): :func:`ict_regions`, and not face where the surface is turned
    more than :data:`FRONTAL_LIMIT_DEG` from the frontal view (n_z ≤ cos 80°: the eye sockets behind the
    eyeballs, the underside of the jaw and chin) or lies behind the front of the head (z ≤ 40 mm in the
    model frame: beside the ears)."""
    model = position - np.asarray(ICT_OFFSET_MM)
    reg = ict_regions(model[:, 0], model[:, 1])
    reg[(normal[:, 2] <= np.cos(np.radians(FRONTAL_LIMIT_DEG))) | (model[:, 2] <= 40)] = 0
    return reg


def _vertex_normals(vertices, triangles):
    """Area-weighted unit vertex normals (V, 3)."""
    p = vertices[triangles]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # |cross| = 2 × area, pointing out of the face
    n = np.zeros_like(vertices)
    for k in range(3):  # the three corners
        np.add.at(n, triangles[:, k], cross)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def _texels(n: int):
    """The texels of an n² grid the UV triangles cover: (row, col, triangle, barycentrics (K, 3)), one per texel."""
    vertices, triangles, uv, uv_triangles = ict_face_mesh()
    corners = uv[uv_triangles]  # (F, 3, 2)
    ids = np.arange(3 * len(triangles)).reshape(-1, 3)
    parts = list(triangle_coverage(corners[..., 0].ravel() * n, corners[..., 1].ravel() * n, ids, n, n))
    tri, row, col = (np.concatenate([p[i] for p in parts]) for i in range(3))
    lam = np.stack([np.concatenate([p[i] for p in parts]) for i in (3, 4, 5)], -1)
    _, first = np.unique(row * n + col, return_index=True)  # texels on shared edges: the first triangle
    return row[first], col[first], tri[first], lam[first]


def _surface(n: int):
    """Position (K, 3), normal (K, 3), mm² per texel (K,), row, col of the covered texels of an n² grid."""
    vertices, triangles, uv, uv_triangles = ict_face_mesh()
    row, col, tri, lam = _texels(n)
    corner = triangles[tri]
    pos = np.einsum("kc,kcd->kd", lam, vertices[corner])
    nrm = np.einsum("kc,kcd->kd", lam, _vertex_normals(vertices, triangles)[corner])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    p = vertices[triangles]
    area3d = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    t = uv[uv_triangles] * n  # in texels
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    area_uv = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return pos, nrm, area3d[tri] / area_uv[tri], row, col


def ict_face(lumitexel_grid: int = 48, map_size: int | None = None) -> FaceGeometry:
    """The ICT-FaceKit face (module docstring) as lumitexels on a UV grid, with its region map.

    Parameters
    ----------
    lumitexel_grid : int
        Lumitexels are the face texels of a ``lumitexel_grid``² grid in the mesh's UV layout (≥ 8;
        48 gives about 1,760 lumitexels 3.5 mm apart).
    map_size : int, optional
        Side of the output UV maps and of ``region_map``; default ``lumitexel_grid``.

    Returns
    -------
    FaceGeometry
        Shadowed by the face-area mesh itself (vertices split along UV seams, so that
        ``mesh_uv`` holds one UV per vertex).
    """
    n = check_integer(lumitexel_grid, "lumitexel_grid", 8)
    map_size = n if map_size is None else check_integer(map_size, "map_size", 2)
    pos, nrm, area, row, col = _surface(n)
    reg = _labels(pos, nrm)
    face = reg > 0
    mpos, mnrm, _, mrow, mcol = _surface(map_size)
    region_map = np.zeros((map_size, map_size), np.uint8)
    region_map[mrow, mcol] = _labels(mpos, mnrm)
    split, uv_triangles, uv = ict_face_uv_mesh()
    return FaceGeometry(
        position=pos[face],
        normal=nrm[face],
        area=area[face],
        uv=np.stack([(col[face] + 0.5) / n, (row[face] + 0.5) / n], -1),
        region=reg[face],
        map_size=map_size,
        mesh_vertices=split,
        mesh_faces=uv_triangles,
        grid_index=np.stack([row[face], col[face]], -1),
        region_map=region_map,
        name=f"ict-{n}",
        meta={"kind": "ict-facekit", "lumitexel_grid": n, "mesh_grid": int(np.sqrt(len(uv_triangles) / 2))},
        mesh_uv=uv,
    )
