"""Principal stretches and strain axes of a deforming triangle mesh, in texture space (Nagano et al. 2015 §5).

Nagano, Fyffe, Alexander, Barbič, Li, Ghosh, Debevec 2015, *Skin Microstructure
Deformation with Displacement Map Convolution*, §5 "Applying to a Novel Surface
Animation", eq. 10-13:

1. Per triangle, Q (2 × 3) is the affine map from world to UV coordinates and
   R (2 × 3) the closest rotation to it, truncated to its first two rows (the
   tangent frame).  R is the polar factor of Q: the 3 × 3 matrix
   ``[q1; q2; q1 × q2]`` has ``A Aᵀ = diag(Q Qᵀ, |q1 × q2|²)`` and a positive
   determinant, so its closest rotation is ``[(Q Qᵀ)^(-1/2) Q; n̂]`` and
   ``R = (Q Qᵀ)^(-1/2) Q`` in closed form (no 3 × 3 SVD).  ``M = Q Rᵀ =
   (Q Qᵀ)^(1/2)`` is the symmetric positive definite map from tangent
   coordinates (mm) to UV.
2. T (2 × 2) maps the rest triangle's tangent-frame edges onto the deformed
   triangle's (eq. 10): ``[e1' e2'] = T [e1 e2]``, ``e_i = R (v_i − v_0)``,
   ``e_i' = R' (v_i' − v_0')``.  With E the 3-D edges and W the (shared) UV
   edges, Q = W (EᵀE)⁻¹ Eᵀ, so ``R E = M⁻¹ Q E = M⁻¹ W`` and ``T = (M'⁻¹ W)
   (M⁻¹ W)⁻¹ = M'⁻¹ M``: only 2 × 2 algebra per triangle and frame.  ``det T``
   is the ratio of the triangle areas.
3. T and M are averaged over the triangles around each UV vertex (plain mean,
   as the paper; UV vertices, not 3-D vertices, because tangent frames follow
   the UV layout and differ across a seam) and interpolated as tensors into the
   texels (barycentric rasterisation by :func:`facestats.core.raster.triangle_coverage`);
   vectors are never interpolated (their sign is ambiguous).
4. At each site the closed-form SVD ``T = U Σ Vᵀ`` (eq. 11-12) gives the
   principal stretches ``r_s ≥ r_t`` (> 1 stretch, < 1 compression) and
   ``S = Q Rᵀ V = M V`` (eq. 13): its normalised columns are the UV directions
   of the strain axes s and t in the rest (neutral) texture, its column norms
   the UV length per mm of skin along them (×1e-3 per µm).

Conventions: positions in mm; UV in [0, 1] with u right and v down; axes are
unit 2-vectors ``(a_u, a_v)``; in a texel grid of W × H texels the axes are
given in texel units (``(W a_u, H a_v)`` normalised; identical to UV axes for
square maps) with ``texel_um_s``/``texel_um_t`` the µm of skin per texel step
along them.  Quads are split into two triangles.  Triangles of (near) zero
area in 3-D (rest or deformed) or in UV, or with non-finite data, are
*degenerate*: masked, counted, excluded from vertex averages, and given T = I,
never NaN.  So are rest *slivers* (:data:`SLIVER_RATIO`, :func:`slivers`):
triangles of near-zero 3-D area under a UV triangle of ordinary size.  The
construction is orientation-blind: both tangent frames are
built from the same UV layout, so ``det T = area'/area > 0`` always and a
triangle turned over by the deformation gives the T of its mirror image (the
paper's recipe has no notion of inversion; facestats does not add one).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.core.raster import triangle_coverage
from facestats.core.validate import as_finite, check_shape, check_window
from facestats.errors import ValidationError

__all__ = [
    "Strain",
    "TexelStrain",
    "MeshStrain",
    "triangulate",
    "svd2x2",
    "inv2x2",
    "tangent_frames",
    "principal_strain",
    "triangle_strain",
    "vertex_strain",
    "texel_strain",
    "uv_islands",
    "slivers",
    "RASTER_CACHE_BYTES",
]

#: A triangle is degenerate when |e1 × e2| ≤ DEGENERATE_SINE · |e1| |e2| (rest, deformed or UV).
DEGENERATE_SINE = 1e-9
#: A rest triangle is a *sliver* (masked like a degenerate one) when the largest UV length it gives a mm of skin
#: (the larger eigenvalue of its M) exceeds SLIVER_RATIO × the median of the mesh's other triangles: near-zero area
#: in 3-D under a UV triangle of ordinary size.  ICT-FaceKit's face area reaches 45.8 × its median (eyelids and lip
#: corners), so none of its triangles is one.  A sliver's M would otherwise set the texel size of its own texels and,
#: through the UV-vertex averages, of its neighbours', far below the rest of the map's (to 1/1000 of it and less,
#: where the kernels need more taps than a pass may read).
SLIVER_RATIO = 100.0
#: How far beyond one triangle each texel of a mesh's UV layout may lie on average
#: (:meth:`MeshStrain.check_uv_overlap`): ICT-FaceKit's face area gives 1.00 (shared edges do not count); its whole
#: head, whose eyes and mouth share the face's UV square, 2.39; a mirrored layout 2.
MAX_UV_OVERLAP = 0.01
#: Texels along the longer side of the UV layout when :meth:`MeshStrain.check_uv_overlap` rasterises it.
OVERLAP_RASTER = 1024
#: Bytes of rasters a :class:`MeshStrain` keeps (:meth:`MeshStrain.raster`), stored as runs of one triangle along
#: the rows: the least recently used are dropped beyond it.  ICT-FaceKit's face area on a whole 16K map in the
#: 512-texel tiles of :func:`facestats.pipeline.microstructure.render_sequence`, with their halos: 425 M texels in
#: 5.5 M runs, 42 MiB, where int32 rasters kept for ever took 1.6 GiB.
RASTER_CACHE_BYTES = 256 * 2**20
#: Barycentric coordinate at or below which a texel centre lies on a triangle's edge
#: (:meth:`MeshStrain.check_uv_overlap`).
_EDGE = 1e-9


def triangulate(polygons) -> tuple[np.ndarray, np.ndarray]:
    """Split triangles or quads into triangles: ``(triangles (F', 3), source polygon (F',))``.

    A quad ``(a, b, c, d)`` becomes ``(a, b, c)`` and ``(a, c, d)`` (fan split;
    the winding is kept).

    Parameters
    ----------
    polygons : array_like of int, shape (F, 3) or (F, 4)
        Vertex indices of triangles or quads.

    Returns
    -------
    triangles : ndarray of int64, shape (F', 3)
        F' = F for triangles (returned as given), 2F for quads (a quad's two triangles next to each other).
    source : ndarray of int, shape (F',)
        Index of the polygon each triangle comes from.

    Raises
    ------
    ValidationError
        ``polygons`` not an integer array of shape (F, 3) or (F, 4).
    """
    p = np.asarray(polygons)
    if p.ndim != 2 or p.shape[1] not in (3, 4) or p.dtype.kind not in "iu":
        raise ValidationError(f"polygons must be an integer array of shape (F, 3) or (F, 4), got {p.dtype} {p.shape}")
    p = p.astype(np.int64)
    idx = np.arange(len(p))
    if p.shape[1] == 3:
        return p, idx
    tri = np.concatenate([p[:, [0, 1, 2]], p[:, [0, 2, 3]]])
    src = np.concatenate([idx, idx])
    order = np.argsort(src, kind="stable")  # the two halves of a quad next to each other
    return tri[order], src[order]


def svd2x2(a, compute_u=True):
    """Closed-form SVD of 2 × 2 matrices: ``a = U diag(s1, s2) Vᵀ`` (Nagano et al. 2015 eq. 11-12).

    With E = (a00 + a11)/2, F = (a00 − a11)/2, G = (a10 + a01)/2,
    H = (a10 − a01)/2: s1 = √(E² + H²) + √(F² + G²) ≥ |s2|,
    s2 = √(E² + H²) − √(F² + G²) (negative when det a < 0), and with
    θ = (atan2(H, E) − atan2(G, F))/2, φ = (atan2(H, E) + atan2(G, F))/2,
    ``a = Rot(φ) diag(s1, s2) Rot(θ)``, so U = Rot(φ), V = Rot(−θ).

    Parameters
    ----------
    a : ndarray, shape (..., 2, 2)
    compute_u : bool
        False skips U (returned as None).

    Returns
    -------
    u : ndarray, shape (..., 2, 2) or None
        Rotation (left singular vectors in its columns).
    s : ndarray, shape (..., 2)
        ``s1 ≥ |s2|``; ``s2 < 0`` for a reflection.
    v : ndarray, shape (..., 2, 2)
        Rotation (right singular vectors in its columns).
    """
    a = np.asarray(a, np.float64)
    e = 0.5 * (a[..., 0, 0] + a[..., 1, 1])
    f = 0.5 * (a[..., 0, 0] - a[..., 1, 1])
    g = 0.5 * (a[..., 1, 0] + a[..., 0, 1])
    h = 0.5 * (a[..., 1, 0] - a[..., 0, 1])
    q, r = np.hypot(e, h), np.hypot(f, g)
    a1, a2 = np.arctan2(g, f), np.arctan2(h, e)
    u = _rot(0.5 * (a2 + a1)) if compute_u else None
    return u, np.stack([q + r, q - r], -1), _rot(0.5 * (a1 - a2))


def _rot(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def _sqrt_spd2(b):
    """Square root of symmetric positive definite 2 × 2 matrices: (B + √det I)/√(tr B + 2√det).

    The closed form of Levinger 1980 ("The square root of a 2 × 2 matrix", Math. Mag. 53(4)): for
    S = √B, Cayley-Hamilton gives S² − tr(S) S + det(S) I = 0, i.e. B + √det(B) I = tr(S) S, and
    tr(S)² = tr(S²) + 2 det(S) = tr(B) + 2√det(B).  Used for M = (QQᵀ)^½ of Nagano et al. 2015
    eq. 13.
    """
    sdet = np.sqrt(np.maximum(b[..., 0, 0] * b[..., 1, 1] - b[..., 0, 1] * b[..., 1, 0], 0.0))
    t = np.sqrt(np.maximum(b[..., 0, 0] + b[..., 1, 1] + 2 * sdet, 1e-300))
    out = b.copy()
    out[..., 0, 0] += sdet
    out[..., 1, 1] += sdet
    return out / t[..., None, None]


def inv2x2(m):
    """Inverses of 2 × 2 matrices in closed form: adj(M) / det M (Cramer's rule), and det M.

    Elementwise over any leading axes: 0.042 s against :func:`numpy.linalg.inv`'s 0.17 s for a million
    matrices (2026-12-06). A singular matrix gives inf or NaN entries (no warning, no error): callers test ``det``.
    The determinant is formed directly, so entries must keep it representable: for float64, magnitudes
    between about 1e-150 and 1e150 (float32: 1e-18 to 1e18); beyond, det overflows to inf (inverse 0) or
    underflows to 0 (inverse inf), silently. Strain tensors are of order 1.

    Parameters
    ----------
    m : ndarray, shape (..., 2, 2)

    Returns
    -------
    inverse : ndarray, shape (..., 2, 2)
    det : ndarray, shape (...)
    """
    inv = np.stack([np.stack([m[..., 1, 1], -m[..., 0, 1]], -1), np.stack([-m[..., 1, 0], m[..., 0, 0]], -1)], -2)
    with np.errstate(all="ignore"):
        det = m[..., 0, 0] * m[..., 1, 1] - m[..., 0, 1] * m[..., 1, 0]
        return inv / det[..., None, None], det


def _gram(vertices, triangles):
    """Edges ``v1 − v0``, ``v2 − v0`` as (F, 3, 2) columns and their Gram matrix EᵀE (F, 2, 2)."""
    p = vertices[triangles]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    g11, g12, g22 = np.einsum("fi,fi->f", e1, e1), np.einsum("fi,fi->f", e1, e2), np.einsum("fi,fi->f", e2, e2)
    return np.stack([e1, e2], -1), np.stack([np.stack([g11, g12], -1), np.stack([g12, g22], -1)], -2)


def _thin(edges):
    """|e1 × e2| ≤ DEGENERATE_SINE |e1| |e2| for edge columns (F, 3, 2) or (F, 2, 2); NaN counts as thin.

    The cross product is formed from the coordinates, whose rounding leaves about 1e-16 |e1| |e2| in it.  The Gram
    determinant |e1|²|e2|² − (e1·e2)² it replaced cancels to about 1e-16 |e1|²|e2|², a sine of about 1e-8, above
    DEGENERATE_SINE: triangles collapsed onto a line passed as valid with r_t ~ 1e-8 (a mutation audit).
    """
    a, b = edges[..., 0], edges[..., 1]
    if a.shape[-1] == 3:
        c = np.cross(a, b)
        cross2 = np.einsum("fi,fi->f", c, c)
    else:
        cross2 = (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]) ** 2
    return ~(cross2 > DEGENERATE_SINE**2 * np.einsum("fi,fi->f", a, a) * np.einsum("fi,fi->f", b, b))


def _uv_edges(uv_corners):
    """UV edges as columns W (F, 2, 2) and the degenerate (zero UV area) flags."""
    w = np.stack([uv_corners[:, 1] - uv_corners[:, 0], uv_corners[:, 2] - uv_corners[:, 0]], -1)
    return w, _thin(w)


def uv_metric(vertices, triangles, uv_corners, uv_edges=None):
    """``M = Q Rᵀ = (Q Qᵀ)^(1/2)`` per triangle: tangent coordinates (mm) → UV (Nagano et al. 2015 §5, eq. 13).

    Q = W (EᵀE)⁻¹ Eᵀ maps the triangle's 3-D edges E onto its UV edges W (and
    its normal to 0), so Q Qᵀ = W (EᵀE)⁻¹ Wᵀ needs only 2 × 2 algebra.

    Returns
    -------
    m : ndarray, shape (F, 2, 2)
        Symmetric positive definite; the identity for degenerate triangles.
    degenerate : ndarray of bool, shape (F,)
        Zero 3-D or UV area, or non-finite data.
    """
    w, deg_uv = _uv_edges(uv_corners) if uv_edges is None else uv_edges
    e, gram = _gram(vertices, triangles)
    degenerate = _thin(e) | deg_uv
    gram = np.where(degenerate[:, None, None], np.eye(2), gram)
    w = np.where(degenerate[:, None, None], np.eye(2), w)
    g_inv, _ = inv2x2(gram)
    m = _sqrt_spd2(w @ g_inv @ np.swapaxes(w, -1, -2))
    return m, degenerate


def slivers(m, degenerate, ratio=SLIVER_RATIO):
    """Rest triangles whose largest UV per mm exceeds ``ratio`` × the median of the other triangles' (bool (F,)).

    Parameters
    ----------
    m : ndarray, shape (F, 2, 2)
        The UV metric M of :func:`uv_metric` (symmetric; UV per mm).
    degenerate : ndarray of bool, shape (F,)
        Triangles already masked (left out of the median, never slivers).
    ratio : float
        :data:`SLIVER_RATIO` by default.

    Returns
    -------
    ndarray of bool, shape (F,)
    """
    a, b, c = m[:, 0, 0], m[:, 0, 1], m[:, 1, 1]
    top = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)  # the larger eigenvalue of [[a, b], [b, c]]
    ok = ~degenerate
    if not ok.any():
        return np.zeros(len(m), bool)
    return ok & (top > ratio * np.median(top[ok]))


def tangent_frames(vertices, triangles, uv_corners):
    """World → UV maps Q and tangent frames R of triangles (Nagano et al. 2015 §5, before eq. 10).

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        Positions, mm.
    triangles : ndarray of int, shape (F, 3)
    uv_corners : ndarray, shape (F, 3, 2)
        UV of each triangle corner.

    Returns
    -------
    q : ndarray, shape (F, 2, 3)
        The affine world → UV map (its linear part).
    r : ndarray, shape (F, 2, 3)
        ``R = (Q Qᵀ)^(-1/2) Q``: orthonormal rows, the closest rotation to Q truncated to two rows.
    degenerate : ndarray of bool, shape (F,)
    """
    w, deg_uv = _uv_edges(uv_corners)
    e, gram = _gram(vertices, triangles)
    degenerate = _thin(e) | deg_uv
    gram = np.where(degenerate[:, None, None], np.eye(2), gram)
    w = np.where(degenerate[:, None, None], np.eye(2), w)
    e = np.where(degenerate[:, None, None], np.eye(3, 2), e)
    g_inv, _ = inv2x2(gram)
    q = w @ g_inv @ np.swapaxes(e, -1, -2)
    m = _sqrt_spd2(q @ np.swapaxes(q, -1, -2))
    m_inv, _ = inv2x2(m)
    return q, m_inv @ q, degenerate


@dataclass
class Strain:
    """Deformation, principal stretches and strain axes at a set of sites (triangles, UV vertices or texels).

    Attributes
    ----------
    t : ndarray, shape (..., 2, 2)
        Deformation in tangent frames (eq. 10); identity where not valid.
    m : ndarray, shape (..., 2, 2)
        ``M = Q Rᵀ``: rest tangent coordinates (mm) → UV.
    r_s, r_t : ndarray, shape (...)
        Principal stretch ratios, ``r_s ≥ r_t`` (eq. 12); 1 where not valid.
    axis_s, axis_t : ndarray, shape (..., 2)
        Unit UV directions ``(a_u, a_v)`` of the strain axes in the rest texture (eq. 13).
    uv_per_um_s, uv_per_um_t : ndarray, shape (...)
        UV length per µm of skin along the axes (the column norms of S = Q Rᵀ V, /1000).
    valid : ndarray of bool, shape (...)
        False at degenerate sites (and texels no triangle covers).
    n_degenerate : int
        Number of degenerate triangles.
    """

    t: np.ndarray
    m: np.ndarray
    r_s: np.ndarray
    r_t: np.ndarray
    axis_s: np.ndarray
    axis_t: np.ndarray
    uv_per_um_s: np.ndarray
    uv_per_um_t: np.ndarray
    valid: np.ndarray
    n_degenerate: int = 0

    @property
    def area_ratio(self) -> np.ndarray:
        """``det T``: deformed over rest area."""
        return self.t[..., 0, 0] * self.t[..., 1, 1] - self.t[..., 0, 1] * self.t[..., 1, 0]


@dataclass
class TexelStrain(Strain):
    """:class:`Strain` rasterised into texels of a map (or a window of it); arrays indexed ``[v, u]``.

    The fields of :class:`Strain` hold one entry per texel of the (H, W) window; those from ``texel_um_s`` on
    are its own.

    Attributes
    ----------
    t : ndarray, shape (H, W, 2, 2)
        Deformation in tangent frames (eq. 10), interpolated from the UV vertices; identity where not valid.
    m : ndarray, shape (H, W, 2, 2)
        ``M = Q Rᵀ`` interpolated from the UV vertices; identity where not valid.
    r_s, r_t : ndarray, shape (H, W)
        Principal stretch ratios, ``r_s ≥ r_t`` (eq. 12); 1 where not valid.
    axis_s, axis_t : ndarray, shape (H, W, 2)
        Unit directions of the strain axes (eq. 13).
        Here in texel units (equal to UV directions for square maps).
    uv_per_um_s, uv_per_um_t : ndarray, shape (H, W)
        UV length per µm of skin along the axes, as in :class:`Strain`.
    valid : ndarray of bool, shape (H, W)
        False for texels no (non-degenerate rest) triangle covers.
    n_degenerate : int
        Number of degenerate triangles of the frame.
    texel_um_s, texel_um_t : ndarray, shape (H, W)
        µm of rest skin per texel step along ``axis_s`` / ``axis_t``.
    island : ndarray of int32, shape (H, W)
        UV island (1, 2, ...) of each texel, 0 where no triangle covers it.
    map_shape : tuple of int
        ``(height, width)`` of the whole map in texels.
    window : tuple of int
        ``(row0, col0, height, width)`` of the rasterised window.
    """

    texel_um_s: np.ndarray | None = None
    texel_um_t: np.ndarray | None = None
    island: np.ndarray | None = None
    map_shape: tuple = ()
    window: tuple = ()


def principal_strain(t, m) -> tuple:
    """Principal stretches and UV strain axes from T and M = Q Rᵀ (Nagano et al. 2015 eq. 11-13).

    Parameters
    ----------
    t, m : ndarray, shape (..., 2, 2)

    Returns
    -------
    r_s, r_t : ndarray, shape (...)
        Singular values of T, ``r_s ≥ r_t`` (r_t < 0 for a reflection).
    axis_s, axis_t : ndarray, shape (..., 2)
        Normalised columns of ``S = M V``, unit UV vectors.
    uv_per_um_s, uv_per_um_t : ndarray, shape (...)
        Column norms of S divided by 1000 (UV per µm).
    """
    _, s, v = svd2x2(t, compute_u=False)
    big_s = m @ v
    n_s, n_t = np.linalg.norm(big_s[..., :, 0], axis=-1), np.linalg.norm(big_s[..., :, 1], axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        a_s = big_s[..., :, 0] / n_s[..., None]
        a_t = big_s[..., :, 1] / n_t[..., None]
    return s[..., 0], s[..., 1], a_s, a_t, n_s / 1000.0, n_t / 1000.0


def _strain(t, m, valid, n_degenerate, cls=Strain, **extra):
    t = np.where(valid[..., None, None], t, np.eye(2))
    r_s, r_t, a_s, a_t, k_s, k_t = principal_strain(t, m)
    return cls(
        t=t,
        m=m,
        r_s=r_s,
        r_t=r_t,
        axis_s=a_s,
        axis_t=a_t,
        uv_per_um_s=k_s,
        uv_per_um_t=k_t,
        valid=valid,
        n_degenerate=int(n_degenerate),
        **extra,
    )


def _check_mesh(rest_vertices, triangles, uv, uv_triangles):
    rest = check_shape(as_finite(rest_vertices, "rest_vertices", dtype=np.float64), "rest_vertices", (None, 3))
    tri, src = triangulate(triangles)
    if tri.size and (tri.min() < 0 or tri.max() >= len(rest)):
        raise ValidationError(f"triangles must index the {len(rest)} vertices, got indices {tri.min()}..{tri.max()}")
    if uv is None:
        raise ValidationError("uv must hold texture coordinates (the mesh has no UVs), got None")
    uvs = check_shape(as_finite(uv, "uv", dtype=np.float64), "uv", (None, 2))
    if uv_triangles is None:
        if len(uvs) != len(rest):
            raise ValidationError(
                f"uv must hold one coordinate per vertex ({len(rest)}) unless uv_triangles is given, got {len(uvs)}"
            )
        uv_tri = tri
    else:
        uv_tri, _ = triangulate(uv_triangles)
        if uv_tri.shape != tri.shape:
            raise ValidationError(f"uv_triangles must match triangles in shape, got {uv_tri.shape} vs {tri.shape}")
        if uv_tri.size and (uv_tri.min() < 0 or uv_tri.max() >= len(uvs)):
            raise ValidationError(f"uv_triangles must index the {len(uvs)} UVs, got {uv_tri.min()}..{uv_tri.max()}")
    return rest, tri, uvs, uv_tri


class MeshStrain:
    """The rest (neutral) mesh with its UV layout, ready to measure the strain of deformed frames.

    Everything that depends only on the rest mesh (tangent frames, rest edges,
    UV-vertex incidence, the rasterisation of a texture window) is computed
    once; each frame then costs one pass over its triangles.

    Parameters
    ----------
    rest_vertices : array_like, shape (V, 3)
        Rest positions, mm.
    triangles : array_like of int, shape (F, 3) or (F, 4)
        Triangles or quads (split by :func:`triangulate`).
    uv : array_like, shape (V, 2) or (T, 2)
        Texture coordinates in [0, 1] (u right, v down); per vertex, or indexed by ``uv_triangles``.
    uv_triangles : array_like of int, optional
        UV index of every corner, shape of ``triangles`` (OBJ ``vt`` indices), for meshes with seams.
    """

    def __init__(self, rest_vertices, triangles, uv, uv_triangles=None):
        self.rest, self.triangles, self.uv, self.uv_triangles = _check_mesh(rest_vertices, triangles, uv, uv_triangles)
        self.uv_corners = self.uv[self.uv_triangles]
        self.uv_edges = _uv_edges(self.uv_corners)
        m, degenerate = uv_metric(self.rest, self.triangles, self.uv_corners, self.uv_edges)
        #: Rest triangles masked as slivers (:data:`SLIVER_RATIO`); they are also in ``rest_degenerate``.
        self.rest_slivers = slivers(m, degenerate)
        self.rest_degenerate = degenerate | self.rest_slivers
        self.m = np.where(self.rest_slivers[:, None, None], np.eye(2), m)  # as uv_metric gives degenerate ones
        self._rasters = {}  # (map_shape, window) -> (triangle, run length) of the raster, least recently used first
        self._raster_bytes = 0

    @property
    def n_vertices(self) -> int:
        return len(self.rest)

    def _deformed(self, deformed_vertices):
        d = check_shape(
            as_finite(deformed_vertices, "deformed_vertices", dtype=np.float64), "deformed_vertices", (None, 3)
        )
        if len(d) != len(self.rest):
            raise ValidationError(
                f"deformed_vertices must have the rest mesh's {len(self.rest)} vertices (same topology), got {len(d)}"
            )
        return d

    def triangle_t(self, deformed_vertices):
        """``(T (F, 2, 2), valid (F,), n_degenerate)`` of a deformed frame (eq. 10).

        Parameters
        ----------
        deformed_vertices : array_like, shape (V, 3)
            Deformed positions, mm, in the rest mesh's vertex order.

        Returns
        -------
        t : ndarray, shape (F, 2, 2)
            T = M'⁻¹ M per triangle (not reset at invalid triangles).
        valid : ndarray of bool, shape (F,)
            False for triangles degenerate (or slivers) at rest or degenerate in the frame.
        n_degenerate : int
            Number of triangles not valid.

        Raises
        ------
        ValidationError
            ``deformed_vertices`` not finite, not of shape (V, 3), or of another vertex count than the rest mesh.
        """
        d = self._deformed(deformed_vertices)
        m2, deg2 = uv_metric(d, self.triangles, self.uv_corners, self.uv_edges)
        m2_inv, _ = inv2x2(m2)
        t = m2_inv @ self.m  # T = M'⁻¹ M (module docstring)
        valid = ~(self.rest_degenerate | deg2)
        return t, valid, int(np.sum(~valid))

    def triangles_strain(self, deformed_vertices) -> Strain:
        """Per-triangle :class:`Strain` of a deformed frame.

        Parameters
        ----------
        deformed_vertices : array_like, shape (V, 3)
            Deformed positions, mm, in the rest mesh's vertex order.

        Returns
        -------
        Strain
            One entry per triangle (F,).

        Raises
        ------
        ValidationError
            ``deformed_vertices`` not finite, not of shape (V, 3), or of another vertex count than the rest mesh.
        """
        t, valid, n_deg = self.triangle_t(deformed_vertices)
        return _strain(t, self.m, valid, n_deg)

    def _uv_vertex_average(self, field, valid):
        """Mean of a (F, 2, 2) tensor over the ``valid`` triangles around each UV vertex: ((U, 2, 2), has any (U,))."""
        n_uv = len(self.uv)
        idx = self.uv_triangles[valid].reshape(-1)
        count = np.bincount(idx, minlength=n_uv).astype(np.float64)
        vals = np.repeat(field[valid].reshape(-1, 4), 3, axis=0)
        sums = np.stack([np.bincount(idx, vals[:, k], minlength=n_uv) for k in range(4)], -1)  # 4 entries
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = sums / count[:, None]
        return np.where(count[:, None] > 0, mean, np.eye(2).reshape(4)).reshape(-1, 2, 2), count > 0

    @property
    def vertex_m(self):
        """M = Q Rᵀ averaged over the rest triangles around each UV vertex, (U, 2, 2)."""
        if not hasattr(self, "_vertex_m"):
            self._vertex_m, _ = self._uv_vertex_average(self.m, ~self.rest_degenerate)
        return self._vertex_m

    def vertices_strain(self, deformed_vertices) -> Strain:
        """Per-UV-vertex :class:`Strain` (T and M averaged over the valid triangles around the UV vertex).

        Parameters
        ----------
        deformed_vertices : array_like, shape (V, 3)
            Deformed positions, mm, in the rest mesh's vertex order.

        Returns
        -------
        Strain
            One entry per UV coordinate (U,); ``valid`` False where no valid triangle touches the UV vertex.

        Raises
        ------
        ValidationError
            ``deformed_vertices`` not finite, not of shape (V, 3), or of another vertex count than the rest mesh.
        """
        t, valid, n_deg = self.triangle_t(deformed_vertices)
        tv, ok = self._uv_vertex_average(t, valid)
        return _strain(tv, self.vertex_m, ok, n_deg)

    def raster(self, map_shape, window):
        """Triangle covering each texel of a window, (h, w) int32, -1 where none.

        Where UV triangles overlap the last one wins; :meth:`texels_strain` refuses a mesh whose UVs overlap
        (:meth:`check_uv_overlap`).  Rest triangles that are degenerate or slivers cover no texel.  Rasters are
        cached per map and window, as runs of one triangle, up to :data:`RASTER_CACHE_BYTES` (the least recently
        used dropped first), so the tiles of a sequence's frames are rasterised once however large the map.

        Parameters
        ----------
        map_shape : int or (int, int)
            ``(height, width)`` of the whole map in texels (an int for a square map).
        window : (row0, col0, height, width) or None
            The texels to rasterise, inside the map; None: the whole map.

        Returns
        -------
        ndarray of int32, shape (height, width) of the window
            Triangle index per texel, -1 where none (a new array: changing it leaves the cache alone).

        Raises
        ------
        ValidationError
            ``map_shape`` or ``window`` not integers ≥ 1 (≥ 0 for the window's origin), or the window not inside
            the map.
        """
        map_shape, window = check_window(map_shape, window)
        key = (map_shape, window)
        runs = self._rasters.pop(key, None)  # re-inserted below: most recently used last
        if runs is None:
            runs = _runs(self._coverage(map_shape, window, count=False)[0])
            self._raster_bytes += runs[0].nbytes + runs[1].nbytes
        self._rasters[key] = runs
        while self._raster_bytes > RASTER_CACHE_BYTES:  # drop the least recently used (the new one, if it alone is)
            old = self._rasters.pop(next(iter(self._rasters)))
            self._raster_bytes -= old[0].nbytes + old[1].nbytes
        return np.repeat(*runs).reshape(window[2], window[3])

    def _coverage(self, map_shape, window, count=True):
        """``(tri_map (h w,), inner, events)``: the last triangle over each texel of the window, the texels whose
        centres lie strictly inside a triangle, and how many (texel, triangle) pairs hold such a centre (both 0
        without ``count``)."""
        x, y = self._pixel_corners(map_shape, window)
        h, w = window[2], window[3]
        corners = np.arange(3 * len(self.triangles)).reshape(-1, 3)
        sel = np.nonzero(~self.rest_degenerate)[0]
        tri_map = np.full(h * w, -1, np.int32)
        inside = np.zeros(h * w, bool)  # texel centres strictly inside a triangle (not on its edges)
        events = 0  # and how many times: beyond the texels, each is one of an overlap
        for tri, row, col, l0, l1, l2 in triangle_coverage(x.reshape(-1), y.reshape(-1), corners[sel], w, h):
            flat = row * w + col
            tri_map[flat] = sel[tri]
            if not count:
                continue
            strict = (l0 > _EDGE) & (l1 > _EDGE) & (l2 > _EDGE)
            events += int(np.count_nonzero(strict))
            inside[flat[strict]] = True
        return tri_map, int(np.count_nonzero(inside)), events

    def check_uv_overlap(self) -> None:
        """Refuse a mesh whose UV triangles overlap (:class:`ValidationError`; checked once, then cached).

        A texel stands for one place on the surface.  The whole UV layout is rasterised with
        :data:`OVERLAP_RASTER` texels along its longer side; where the texels whose centres lie strictly inside
        a triangle lie inside more than 1 + :data:`MAX_UV_OVERLAP` triangles each on average (a whole head whose
        eyes share the face's UV square, a mirrored layout), the mesh is refused.  A centre on a shared edge
        (a barycentric coordinate ≤ 1e-9) is not an overlap.  The test depends on the mesh alone, not on the map,
        window or tile a render uses.
        """
        if getattr(self, "_overlap_checked", False):
            return
        uv = self.uv_corners.reshape(-1, 2)
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        n = int(OVERLAP_RASTER / max(float((hi - lo).max()), 1e-12))
        n = max(1, min(n, 1 << 20))
        c0, r0 = (int(np.floor(v * n)) for v in lo)
        c1, r1 = (int(np.ceil(v * n)) for v in hi)
        window = (r0, c0, max(r1 - r0, 1), max(c1 - c0, 1))
        _, inner, events = self._coverage((n, n), window)
        if inner and events - inner > MAX_UV_OVERLAP * inner:
            raise ValidationError(
                f"the mesh's UV triangles overlap: rasterised with {OVERLAP_RASTER} texels along its UV layout, the "
                f"{inner} texels whose centres lie inside a triangle lie inside {events / inner:.2f} triangles each "
                f"on average ({1 + MAX_UV_OVERLAP:.2f} allowed), so a texel would stand for several places on the "
                "surface; give a mesh whose UVs do not overlap (e.g. ICT-FaceKit's face area: its folder, not "
                "generic_neutral_mesh.obj, whose eyes and mouth share the face's UVs)"
            )
        self._overlap_checked = True

    def _pixel_corners(self, map_shape, window):
        """Triangle corners in the window's pixel units: x, y (F, 3)."""
        (height, width), (row0, col0) = map_shape, window[:2]
        return self.uv_corners[..., 0] * width - col0, self.uv_corners[..., 1] * height - row0

    def _barycentric(self, map_shape, window, texels, tri):
        """Barycentric coordinates (K, 3) of texel centres (flat indices in the window) in their triangles."""
        x, y = self._pixel_corners(map_shape, window)
        x, y = x[tri], y[tri]
        px, py = texels % window[3] + 0.5, texels // window[3] + 0.5
        den = (y[:, 1] - y[:, 2]) * (x[:, 0] - x[:, 2]) + (x[:, 2] - x[:, 1]) * (y[:, 0] - y[:, 2])
        l0 = ((y[:, 1] - y[:, 2]) * (px - x[:, 2]) + (x[:, 2] - x[:, 1]) * (py - y[:, 2])) / den
        l1 = ((y[:, 2] - y[:, 0]) * (px - x[:, 2]) + (x[:, 0] - x[:, 2]) * (py - y[:, 2])) / den
        return np.stack([l0, l1, 1 - l0 - l1], -1)

    def islands(self) -> np.ndarray:
        """UV island (1, 2, ...) of each triangle (see :func:`uv_islands`)."""
        if not hasattr(self, "_islands"):
            self._islands = uv_islands(self.uv_triangles, len(self.uv))
        return self._islands

    def texels_strain(self, deformed_vertices, map_shape, window=None) -> TexelStrain:
        """Per-texel :class:`TexelStrain` of a deformed frame in a map (or a window of it).

        Parameters
        ----------
        deformed_vertices : array_like, shape (V, 3)
        map_shape : int or (int, int)
            Size of the whole map in texels, ``(height, width)`` (an int for a square map).
        window : (row0, col0, height, width), optional
            Texels to rasterise (default: the whole map), e.g. a tile of a 16K map.

        Returns
        -------
        TexelStrain
            The strain of every texel of the window.
        """
        map_shape, window = check_window(map_shape, window)
        self.check_uv_overlap()
        t, valid, n_deg = self.triangle_t(deformed_vertices)
        tv, _ = self._uv_vertex_average(t, valid)
        tri_map = self.raster(map_shape, window).reshape(-1)
        texels = np.nonzero(tri_map >= 0)[0]
        tri = tri_map[texels]
        bary = self._barycentric(map_shape, window, texels, tri)
        corner_uv = self.uv_triangles[tri]  # (K, 3) UV-vertex index of each corner
        h, w = window[2], window[3]

        def interpolate(field):  # (U, 2, 2) per UV vertex -> (h, w, 2, 2) tensors per texel, identity off the mesh
            flat = field.reshape(-1, 4)  # three gathers of 4-vectors: 5x faster than an einsum over (K, 3, 2, 2)
            mixed = bary[:, 0, None] * flat[corner_uv[:, 0]]
            mixed += bary[:, 1, None] * flat[corner_uv[:, 1]]
            mixed += bary[:, 2, None] * flat[corner_uv[:, 2]]
            out = np.empty((h * w, 4))
            out[:] = (1.0, 0.0, 0.0, 1.0)
            out[texels] = mixed
            return out.reshape(h, w, 2, 2)

        covered = (tri_map >= 0).reshape(h, w)
        island = np.zeros(h * w, np.int32)
        island[texels] = self.islands()[tri]
        res = _strain(interpolate(tv), interpolate(self.vertex_m), covered, n_deg, cls=TexelStrain)
        # Axes and lengths in texel units: S_texel = diag(W, H) S.
        scale = np.array([map_shape[1], map_shape[0]], float)
        s_tex_s = scale * res.axis_s * (1000.0 * res.uv_per_um_s)[..., None]
        s_tex_t = scale * res.axis_t * (1000.0 * res.uv_per_um_t)[..., None]
        n_s, n_t = np.linalg.norm(s_tex_s, axis=-1), np.linalg.norm(s_tex_t, axis=-1)
        res.axis_s, res.axis_t = s_tex_s / n_s[..., None], s_tex_t / n_t[..., None]
        res.texel_um_s, res.texel_um_t = 1000.0 / n_s, 1000.0 / n_t
        res.island = island.reshape(h, w)
        res.map_shape, res.window = map_shape, window
        return res


def _runs(values):
    """``(value, length)`` of the runs of equal values of a non-empty 1-D array: ``np.repeat`` of them gives it
    (lengths int32 when the array is shorter than 2³¹, else int64)."""
    start = np.concatenate([[0], np.flatnonzero(values[1:] != values[:-1]) + 1])
    length = np.diff(np.append(start, values.size))
    return values[start], length.astype(np.int32) if values.size < 2**31 else length


def uv_islands(uv_triangles, n_uv=None) -> np.ndarray:
    """Connected components (1, 2, ...) of triangles that share a UV vertex: the UV islands.

    Parameters
    ----------
    uv_triangles : ndarray of int, shape (F, 3)
        UV index of every corner.
    n_uv : int, optional
        Number of UV coordinates (default: largest index + 1).

    Returns
    -------
    ndarray of int32, shape (F,)
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    uvt = np.asarray(uv_triangles, np.int64)
    n_uv = int(uvt.max()) + 1 if n_uv is None else int(n_uv)
    f = len(uvt)
    rows = np.repeat(np.arange(f), 3)
    graph = coo_matrix((np.ones(3 * f), (rows, f + uvt.reshape(-1))), shape=(f + n_uv, f + n_uv))
    _, labels = connected_components(graph, directed=False)
    _, island = np.unique(labels[:f], return_inverse=True)
    return (island + 1).astype(np.int32)


def triangle_strain(rest_vertices, deformed_vertices, triangles, uv, *, uv_triangles=None) -> Strain:
    """Per-triangle principal stretches and strain axes (Nagano et al. 2015 eq. 10-13).

    Parameters
    ----------
    rest_vertices, deformed_vertices : array_like, shape (V, 3)
        Rest (neutral) and deformed positions, mm, same topology.
    triangles : array_like of int, shape (F, 3) or (F, 4)
        Triangles or quads (quads are split in two, so the result has one entry per triangle).
    uv : array_like, shape (V, 2) or (T, 2)
        Texture coordinates in [0, 1], u right, v down.
    uv_triangles : array_like of int, optional
        Per-corner UV indices (meshes with UV seams).

    Returns
    -------
    Strain
        ``r_s, r_t`` (F,), ``axis_s, axis_t`` (F, 2) unit UV vectors, ``uv_per_um_s, uv_per_um_t``,
        ``t`` (F, 2, 2), ``valid`` and the count of degenerate triangles.
    """
    return MeshStrain(rest_vertices, triangles, uv, uv_triangles).triangles_strain(deformed_vertices)


def vertex_strain(rest_vertices, deformed_vertices, triangles, uv, *, uv_triangles=None) -> Strain:
    """Per-UV-vertex strain: T and M averaged over the triangles around each UV vertex, then eq. 11-13.

    Parameters as :func:`triangle_strain`; the result has one entry per UV
    coordinate (per vertex when ``uv_triangles`` is None).

    Parameters
    ----------
    rest_vertices, deformed_vertices, triangles, uv
        As :func:`triangle_strain` (positions in mm, UV in [0, 1], u right, v down).
    uv_triangles : array_like of int, optional
        Per-corner UV indices (meshes with UV seams).

    Returns
    -------
    Strain
        One entry per UV coordinate.
    """
    return MeshStrain(rest_vertices, triangles, uv, uv_triangles).vertices_strain(deformed_vertices)


def texel_strain(
    rest_vertices, deformed_vertices, triangles, uv, map_shape, *, uv_triangles=None, window=None
) -> TexelStrain:
    """Per-texel strain: per-UV-vertex T and M interpolated as tensors into texels, then eq. 11-13.

    Texels no triangle covers have ``valid`` False, ``island`` 0 and r = 1.

    Parameters
    ----------
    rest_vertices, deformed_vertices, triangles, uv
        As :func:`triangle_strain` (positions in mm, UV in [0, 1], u right, v down).
    map_shape : int or (int, int)
        Size of the whole map in texels, ``(height, width)`` (an int for a square map).
    uv_triangles : array_like of int, optional
        Per-corner UV indices (meshes with UV seams).
    window : (row0, col0, height, width), optional
        Texels to rasterise (default: the whole map).

    Returns
    -------
    TexelStrain
        The strain of every texel of the window, arrays indexed ``[v, u]``.
    """
    return MeshStrain(rest_vertices, triangles, uv, uv_triangles).texels_strain(deformed_vertices, map_shape, window)
