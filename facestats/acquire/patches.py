"""A surface as small patches: centres, normals, areas (Suzuki, Mukaigawa & Yagi §3.2).

Suzuki et al. divide the object's surface into small patches of equal area and
take each patch's centre as its sample point.  :func:`mesh_patches` does that
for a triangle mesh: every triangle is split uniformly into k² congruent
sub-triangles (k = ⌈longest edge / spacing⌉), whose centroids, normals and areas
are the patches.  Within a triangle all patches have exactly equal area; across
triangles of different sizes the areas differ by the rounding of k, and every
function downstream takes the areas explicitly.  :func:`read_mesh_patches` reads
the mesh with :func:`facestats.io.mesh.read_triangle_mesh` (OBJ, PLY).  Patches
made from arrays (e.g. the lumitexels of a
:class:`facestats.face.geometry.FaceGeometry`) need only centres, normals and
areas; the sub-triangles are kept when known, for rendering images.

Conventions: mm, mm²; unit normals pointing out of the object; the source mesh is
kept as the occluder for shadow maps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.core.validate import as_finite, as_scalar, check_range, check_shape, check_unit_vectors
from facestats.errors import ValidationError

__all__ = ["MAX_PATCHES", "Patches", "mesh_patches", "read_mesh_patches", "subdivide_triangles"]

#: Most patches a mesh may be divided into (Suzuki's W pairs every visible patch with every lit one: O(m²)).
MAX_PATCHES = 1_000_000


@dataclass
class Patches:
    """Patches of a surface.

    Attributes
    ----------
    centre : ndarray, shape (m, 3)
        Sample points (patch centroids), mm.
    normal : ndarray, shape (m, 3)
        Unit normals.
    area : ndarray, shape (m,)
        Patch areas, mm², > 0.
    corners : ndarray, shape (m, 3, 3), optional
        The triangle of each patch (for rendering images).
    mesh_vertices, mesh_faces : ndarray, optional
        The occluding mesh (for shadow maps).
    """

    centre: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    corners: np.ndarray | None = None
    mesh_vertices: np.ndarray | None = None
    mesh_faces: np.ndarray | None = None

    def __post_init__(self):
        c = check_shape(as_finite(self.centre, "centre", dtype=np.float64), "centre", (None, 3))
        m = c.shape[0]
        if m == 0:
            raise ValidationError("centre must hold at least one patch, got 0")
        n = as_finite(self.normal, "normal", dtype=np.float64)
        if n.shape != c.shape:
            raise ValidationError(f"normal must have the shape of centre, {c.shape}, got {n.shape}")
        check_unit_vectors(n, "normal", 1e-6)
        a = check_shape(as_finite(self.area, "area", dtype=np.float64), "area", (m,))
        check_range(a, "area", 0, None, low_inclusive=False, unit="mm^2")
        if self.corners is not None:
            self.corners = check_shape(as_finite(self.corners, "corners", dtype=np.float64), "corners", (m, 3, 3))
        self.centre, self.normal, self.area = c, n, a

    def __len__(self):
        return int(self.centre.shape[0])

    @property
    def spacing(self) -> float:
        """Typical distance between neighbouring patch centres, mm: median nearest-neighbour distance."""
        from scipy.spatial import cKDTree

        if len(self) < 2:
            return float(np.sqrt(self.area[0]))
        d, _ = cKDTree(self.centre).query(self.centre, k=2)
        return float(np.median(d[:, 1]))

    @property
    def has_mesh(self) -> bool:
        return self.mesh_vertices is not None and self.mesh_faces is not None

    def subset(self, index) -> "Patches":
        """The patches selected by ``index`` (the occluding mesh is kept whole).

        Parameters
        ----------
        index : array_like of int or bool
            Indices or a boolean mask of length m, as numpy indexes the per-patch arrays.

        Returns
        -------
        Patches
            A new set of patches; this one is not modified.

        Raises
        ------
        ValidationError
            ``index`` selects no patch.
        """
        idx = np.asarray(index)
        return Patches(
            self.centre[idx],
            self.normal[idx],
            self.area[idx],
            None if self.corners is None else self.corners[idx],
            self.mesh_vertices,
            self.mesh_faces,
        )


def subdivide_triangles(tri, k):
    """The k² congruent sub-triangles, shape (T, k², 3, 3), of triangles ``tri`` (T, 3, 3) split k times per edge.

    Corners keep the orientation of their triangle; all k² have its area / k².

    Parameters
    ----------
    tri : ndarray, shape (T, 3, 3)
        Triangle corners a, b, c.
    k : int
        Splits per edge, ≥ 1.

    Returns
    -------
    ndarray, shape (T, k², 3, 3)
        Corners of the sub-triangles: first the k(k + 1)/2 pointing like their triangle, then the k(k − 1)/2
        inverted ones (turned by 180°, same winding).
    """
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    up = (i + j) <= k - 1
    down = (i + j) <= k - 2
    # Barycentric (along edge a→b, along a→c) corners of the "up" and "down" sub-triangles.
    up_c = np.stack([np.stack([i, j], -1), np.stack([i + 1, j], -1), np.stack([i, j + 1], -1)], 2)[up]
    down_c = np.stack([np.stack([i + 1, j], -1), np.stack([i + 1, j + 1], -1), np.stack([i, j + 1], -1)], 2)[down]
    ij = np.concatenate([up_c, down_c]) / k  # (k², 3, 2)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    return (
        a[:, None, None, :]
        + (b - a)[:, None, None, :] * ij[None, :, :, 0:1]
        + (c - a)[:, None, None, :] * ij[None, :, :, 1:2]
    )


def mesh_patches(vertices, faces, *, spacing, occluder=True) -> Patches:
    """Patches of a triangle mesh: each triangle split into k² congruent sub-triangles (module docstring).

    Parameters
    ----------
    vertices : array_like, shape (V, 3)
        Mesh vertices, mm.
    faces : array_like of int, shape (F, 3)
        Triangles, counter-clockwise seen from outside (the normal is (b − a) × (c − a)).
    spacing : float or None
        Target patch edge length in mm (> 0): k = ⌈longest edge / spacing⌉ per
        triangle; ``None`` makes every triangle one patch (k = 1).
    occluder : bool
        Keep the mesh as the occluder for shadow maps.

    Returns
    -------
    Patches
    """
    v = check_shape(as_finite(vertices, "vertices", dtype=np.float64), "vertices", (None, 3))
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or f.dtype.kind not in "iu" or f.size == 0:
        raise ValidationError(f"faces must be a non-empty (F, 3) integer array, got shape {f.shape} dtype {f.dtype}")
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise ValidationError(f"faces must index vertices 0..{v.shape[0] - 1}, got {int(f.min())}..{int(f.max())}")
    h = None if spacing is None else as_scalar(spacing, "spacing", 0, None, low_inclusive=False, unit="mm")
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    ok = area2 > 1e-12 * max(float(area2.max()), 1e-300)
    if not ok.any():
        raise ValidationError("faces must include at least one triangle of positive area, got only degenerate ones")
    tri, cross, area2 = tri[ok], cross[ok], area2[ok]
    edges = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(1)
    kf = np.ones(tri.shape[0]) if h is None else np.maximum(1.0, np.ceil(edges / h - 1e-9))
    n = float(np.sum(kf * kf))
    if n > MAX_PATCHES:  # checked in float64, before any allocation
        raise ValidationError(
            f"spacing must be at least {h * np.sqrt(n / MAX_PATCHES):.3g} mm, got {h:g} mm: it gives {n:.3g} patches, "
            f"more than MAX_PATCHES = {MAX_PATCHES:,}"
        )
    ks = kf.astype(np.int64)
    centres, normals, areas, corners = [], [], [], []
    for k in np.unique(ks):  # one vectorised subdivision per distinct k
        sel = ks == k
        sub = subdivide_triangles(tri[sel], int(k)).reshape(-1, 3, 3)
        nrm = np.repeat(cross[sel] / area2[sel, None], int(k) * int(k), axis=0)
        centres.append(sub.mean(1))
        normals.append(nrm)
        areas.append(np.repeat(0.5 * area2[sel] / (k * k), int(k) * int(k)))
        corners.append(sub)
    return Patches(
        np.concatenate(centres),
        np.concatenate(normals),
        np.concatenate(areas),
        np.concatenate(corners),
        v if occluder else None,
        f.astype(np.int64) if occluder else None,
    )


def read_mesh_patches(path, *, spacing, scale=1.0, transform=None) -> Patches:
    """Patches of a mesh file (OBJ, PLY; :func:`facestats.io.mesh.read_triangle_mesh`), see :func:`mesh_patches`.

    Parameters
    ----------
    path : str or path-like
        The mesh file.
    spacing : float or None
        Target patch edge length in mm, as :func:`mesh_patches`.
    scale, transform
        As :func:`facestats.io.mesh.read_triangle_mesh` (factor to mm; a 4 × 4 rigid transform after scaling).

    Returns
    -------
    Patches
        With the mesh kept as the occluder.

    Raises
    ------
    FormatError
        An unreadable mesh file (:func:`facestats.io.mesh.read_triangle_mesh`).
    ValidationError
        A bad ``spacing``, or no triangle of positive area (:func:`mesh_patches`).
    """
    # local import: keeps facestats.io (25 modules) out of this module's import
    from facestats.io.mesh import read_triangle_mesh

    vertices, faces = read_triangle_mesh(path, scale=scale, transform=transform)
    return mesh_patches(vertices, faces, spacing=spacing)
