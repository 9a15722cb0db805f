"""The quantised-distance linear system of Suzuki, Mukaigawa & Yagi §3.3 (eq. 22-35), built in row blocks.

One image of a homogeneous translucent object gives, per visible patch j, the
exitance l_j = Σ_k R(d_jk) c_k A_k (eq. 17, with the patch area A_k, see below).
Quantising the distances d_jk to levels d'_1 = 0 < … < d'_n (eq. 22-24) and
interpolating R linearly between them (eq. 26-28),

    R(d_jk) ≈ β_jk R'_i + (1 − β_jk) R'_{i+1},   β_jk = (d'_{i+1} − d_jk)/(d'_{i+1} − d'_i),   d'_i ≤ d_jk < d'_{i+1},

turns the m² unknowns R(d_jk) into n unknowns r = (R'_1 … R'_n):
l ≈ W r with W_j = Σ_k c_k A_k w_jk (eq. 29-34).

Conventions and choices (stated once here, used by every function):

* **Source typos.**  Eq. 14 as printed sums over j (Σ_{j=1}^m) a summand indexed by k; the sum
  runs over the source patches k (j is the output patch on the left).  Eq. 33 lists W's rows
  as 1, ⋮, 2, ⋮, m; row j is Σ_k c_k w_jk (eq. 32), one row per visible patch in order.
* **Patch area.**  Suzuki eq. 14 sums R(d_jk) times the per-area integral c_k of
  eq. 16; R has units mm⁻² (exitance per unit incident flux per unit area), so the
  sum is the quadrature of ∫ R(‖x_o − x_i‖) E(x_i) dA(x_i) and each term carries
  the patch area A_k (mm²).  The weights passed here are c_k A_k.  The paper's
  patches have equal areas, where A only scales r.
* **A patch's own light** (beyond the paper).  Eq. 17 pairs a patch with
  itself at d = 0, R(0) c_j A_j; a surface gives c_j ∫_patch R(‖x_j − y‖) dA(y),
  about half of that for skin-like media and 1 mm patches (Table 1's medium,
  A = 1.13 mm²: 0.216 against 0.451), so an image of a real, continuous surface
  is fitted with a biased medium (σ's 8.6 % low, σa 17 % high on the pyramid at
  ``width="auto"`` on a 200² log grid, refined).
  With ``areas``, :func:`quantised_system` takes the patch as the disk of its
  area around its centre, ρ_j = sqrt(A_j/π), and spreads its own pair over the
  levels by ∫_0^ρ 2πr hat_i(r) dr (:func:`disk_hat_integrals`): the footprint
  integral of the piecewise-linear R, in the same unknowns r.  Without
  ``areas`` the pair is the paper's R(0) c_j A_j (to reproduce its Table 3).
* **Near neighbours' light** (beyond the paper).  The point kernel R(d_jk) c_k A_k
  of a neighbour is its integral over the patch only to second order in ρ_k/d_jk;
  with ``near=True`` (and ``areas``) the lit patches with d_jk < NEAR_RADII ρ_k
  (:mod:`facestats.model.disk_quadrature`, 3 radii: the nearest 8 of a square
  grid) are integrated over their disks instead, c_k A_k Σ_q w_q hat_i(r_q) by
  the polar rule of that module, again in the same unknowns.  The two self
  terms together are ``self_term="surface"`` (:func:`self_term_keywords`).
  The support still counts the pairs' centres.
* **Rows and columns.**  Only visible patches give rows (§3.3, last paragraph);
  only lit patches (c_k A_k ≠ 0) contribute to W, so the distances computed are
  those of (visible, lit) pairs.  ``support`` counts those pairs per level,
  each pair split by its hat weights (β, 1 − β), so a pair at exactly d'_i
  (e.g. the patch itself at d = 0) supports level i only.
* **Streaming.**  W is accumulated over blocks of rows: a block's distances to
  all lit patches, the level index i and the fraction t = 1 − β of each pair,
  then two ``numpy.bincount`` reductions over (row, level) — Σ c A and Σ c A t —
  give the block's rows of W.  No m × m matrix exists; memory is bounded by
  ``block_bytes`` (about 48 bytes per pair of a block) plus W itself.
* **Levels.**  From a width w: d'_i = (i − 1) w, as many as needed for
  d'_n > max d_jk (eq. 23) and no more.  Explicit levels must satisfy eq. 22-24.
* **Merging.**  A level that no pair supports (or fewer than a threshold) is
  removed and its neighbours' hats widened: the coarser piecewise-linear basis is
  a subspace of the finer one, so W_coarse = W P with P the linear interpolation
  from the coarse levels to the fine ones (:func:`interpolation_matrix`); no
  distance is recomputed.

Solves (eq. 35 and beyond the paper), on the rows of the visible patches:

* ``"pinv"`` — r = W⁺ l, the paper's pseudo-inverse (computed on W with columns
  scaled to unit norm, which leaves a full-rank solution unchanged): the
  minimum-norm least-squares solution by a complete orthogonal factorisation
  (LAPACK ``gelsy``), with the numerical rank at ``rcond``.
* ``"monotone"`` — the default of :func:`facestats.model.fitting.fit_scattering_image`:
  r non-negative and non-increasing in distance, r = U u with u ≥ 0 and
  U_ik = 1 for k ≥ i (r_i = Σ_{k ≥ i} u_k), rows weighted by 1/l_j (relative
  residuals, right for multiplicative image noise): min ‖D (W U u − l)‖, u ≥ 0,
  D = diag(1/l), reduced to an n × n triangle (Cholesky factor of the Gram
  matrix of D W U, columns scaled to unit norm) and solved by non-negative
  least squares (Lawson-Hanson, :func:`scipy.optimize.nnls`).

The solves, ranks and covariances work on the normal equations (G = AᵀA, Aᵀy:
:class:`NormalEquations`), formed once per image by one matrix product; merging
levels maps them exactly (Pᵀ G P), so the rows × n matrix is touched once.
  Rows with l_j = 0 carry no relative information and are left out.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from facestats.core.progress import progress_bar
from facestats.core.validate import as_finite, as_scalar, check_choice, check_integer, check_shape
from facestats.errors import FitError, ValidationError
from facestats.model.disk_quadrature import DISK_RULE, disk_node_distances, is_near

__all__ = [
    "DEFAULT_BLOCK_BYTES",
    "MAX_LEVELS",
    "QuantisedSystem",
    "Conditioning",
    "uniform_levels",
    "patch_spacing",
    "planned_levels",
    "quantised_system",
    "point_kernel_exitance",
    "disk_hat_integrals",
    "SELF_TERMS",
    "self_term_keywords",
    "interpolation_matrix",
    "merge_levels",
    "NormalEquations",
    "normal_equations",
    "equilibrate",
    "conditioning",
    "dependent_levels",
    "solve_pinv",
    "solve_monotone",
    "solve_monotone_normal",
    "profile_covariance",
]

#: A patch's own light (module docstring): over the disk of its area, or the paper's R(0) c A (eq. 17); "surface"
#: also integrates the near neighbours over their disks.
SELF_TERMS = ("footprint", "point", "surface")
#: Default memory budget of one row block of :func:`quantised_system` (bytes).
DEFAULT_BLOCK_BYTES = 128 * 2**20
#: Most levels a width may give (W holds one column per level; Suzuki's scenes need tens to hundreds).
MAX_LEVELS = 4096
#: Bytes of temporaries per (row, lit patch) pair of a block.
_BYTES_PER_PAIR = 48
#: Nodes of the disk rule a near pair is integrated over.
_DISK_NODES = DISK_RULE[0] * DISK_RULE[1]


@dataclass
class QuantisedSystem:
    """The matrix W of Suzuki eq. 33 on the visible rows, with its levels and their support.

    Attributes
    ----------
    matrix : ndarray, shape (rows, n)
        W (units of c A: irradiance × mm²); row j is Σ_k c_k A_k w_jk.
    levels : ndarray, shape (n,)
        Quantised distances d'_i in mm (d'_1 = 0).
    rows : ndarray of int, shape (rows,)
        Indices of the visible patches the rows belong to.
    support : ndarray, shape (n,)
        Hat-weighted number of (visible, lit) patch pairs per level.
    max_distance : float
        Largest distance of a (visible, lit) pair, mm.
    n_pairs : int
        Number of (visible, lit) pairs.
    merged : tuple of float
        Levels (mm) removed by :func:`merge_levels`, in the order they were removed.
    areas : ndarray or None
        The patch areas (mm², one per point) whose disks gave each lit row its own light (module docstring:
        A patch's own light), or None for the paper's R(0) c_j A_j.
    near : bool
        The near neighbours' light was integrated over their disks (module docstring: Near neighbours' light).
    spacing : float
        The resolution of the patches W was built on, mm: :func:`patch_spacing` of the visible and the lit
        patches (NaN for a system built otherwise).  The fit range of
        :func:`facestats.model.fitting.quantisation_choice.fit_distance` is judged at no finer levels.
    """

    matrix: np.ndarray
    levels: np.ndarray
    rows: np.ndarray
    support: np.ndarray
    max_distance: float
    n_pairs: int
    merged: tuple = field(default=())
    areas: np.ndarray | None = None
    near: bool = False
    spacing: float = float("nan")

    @property
    def n_levels(self) -> int:
        return int(self.levels.shape[0])

    @property
    def self_term(self) -> str:
        """How W took the light of a patch itself and of its neighbours: one of :data:`SELF_TERMS`."""
        if self.areas is None:
            return "point"
        return "surface" if self.near else "footprint"


def self_term_keywords(self_term, areas) -> dict:
    """The ``areas`` and ``near`` keywords of :func:`quantised_system` that give W a self term of :data:`SELF_TERMS`.

    ``"point"``: none (the paper's eq. 17); ``"footprint"``: a patch's own light over the disk of its area;
    ``"surface"``: that, and the near neighbours' over theirs (module docstring).

    Parameters
    ----------
    self_term : str
        One of :data:`SELF_TERMS`.
    areas : array_like, shape (m,) or None
        Patch areas, mm², passed on unchecked (:func:`quantised_system` checks them).

    Returns
    -------
    dict
        ``{}`` for ``"point"``, else ``{"areas": areas, "near": self_term == "surface"}``.

    Raises
    ------
    ValidationError
        A ``self_term`` not in :data:`SELF_TERMS`.
    """
    check_choice(self_term, "self_term", SELF_TERMS)
    if self_term == "point":
        return {}
    return {"areas": areas, "near": self_term == "surface"}


def uniform_levels(width, max_distance) -> np.ndarray:
    """Levels d'_i = (i − 1) w, i = 1 … n, with n the smallest count giving d'_n > ``max_distance`` (eq. 22-24).

    Parameters
    ----------
    width : float
        Quantisation width w in mm, > 0.
    max_distance : float
        Largest patch distance to cover, mm, ≥ 0.

    Returns
    -------
    ndarray, shape (n,)
        The levels d'_i, mm.
    """
    w = as_scalar(width, "width", 0, None, low_inclusive=False, unit="mm")
    dmax = as_scalar(max_distance, "max_distance", 0, None, unit="mm")
    n = np.floor(dmax / w) + 2
    if n > MAX_LEVELS:
        raise ValidationError(
            f"width must be at least {dmax / (MAX_LEVELS - 2):.4g} mm, got {w:g} mm: it gives {n:.4g} levels over "
            f"{dmax:.4g} mm, more than MAX_LEVELS = {MAX_LEVELS}"
        )
    return np.arange(int(n)) * w


def _check_levels(levels) -> np.ndarray:
    lev = check_shape(as_finite(levels, "levels", 0, None, unit="mm", dtype=np.float64), "levels", (None,))
    if lev.size < 2 or lev[0] != 0 or np.any(np.diff(lev) <= 0):
        raise ValidationError(
            "levels must start at 0 (Suzuki eq. 22) and increase strictly (eq. 24) with at least 2 entries, "
            f"got {np.array2string(lev[:6], precision=4)}{' …' if lev.size > 6 else ''}"
        )
    return lev


def patch_spacing(points) -> float:
    """Median distance from each point to its nearest other point, mm (the patches' spacing h).

    Parameters
    ----------
    points : array_like, shape (m, 3)
        Patch centres, mm (not validated).

    Returns
    -------
    float
        NaN for fewer than two points.
    """
    from scipy.spatial import cKDTree

    p = np.asarray(points, np.float64)
    if p.shape[0] < 2:
        return float("nan")
    d, _ = cKDTree(p).query(p, k=2)
    return float(np.median(d[:, 1]))


def _farthest(rows_xyz, cols_xyz, rho=None) -> float:
    """An upper bound of the distances W meets: the diagonal of the points' joint bounding box, plus the largest
    disk radius when near pairs are taken over their disks (``rho``, mm)."""
    both = np.concatenate([rows_xyz, cols_xyz])
    extra = 0.0 if rho is None or rho.size == 0 else float(rho.max())
    return float(np.linalg.norm(both.max(0) - both.min(0))) + extra


def planned_levels(points, weights, rows=None, *, width, areas=None, near=False) -> int:
    """Number of levels :func:`quantised_system` allocates W with at ``width`` (before trimming to the farthest
    pair): W then takes len(rows) × this × 8 bytes.

    Parameters
    ----------
    points : array_like, shape (m, 3)
        Patch centres, mm (not validated).
    weights : array_like, shape (m,)
        c_k A_k (lit patches > 0).
    rows : array_like of int, optional
        Indices of the visible patches (default: all).
    width : float
        Quantisation width w in mm, > 0.
    areas : array_like, shape (m,), optional
        Patch areas A_k, mm² (> 0); read only with ``near`` (needed then).
    near : bool
        Whether :func:`quantised_system` takes the near neighbours over their disks (their radii extend the range);
        True only with ``areas``.

    Returns
    -------
    int
        The level count n.

    Raises
    ------
    ValidationError
        An invalid ``width``, or one that would give more than :data:`MAX_LEVELS`, a ``near`` that is not a bool
        or True without ``areas``, or invalid ``areas`` with ``near``, as :func:`quantised_system` does.
    """
    p = np.asarray(points, np.float64)
    wk = np.asarray(weights, np.float64)
    idx = np.arange(p.shape[0]) if rows is None else np.asarray(rows)
    lit = np.nonzero(wk > 0)[0]
    if not isinstance(near, (bool, np.bool_)) or (near and areas is None):  # as quantised_system
        raise ValidationError(f"near must be True or False, and True only with areas, got {near!r}")
    rho = np.sqrt(_check_areas(areas, p.shape[0])[lit] / np.pi) if near else None
    w = as_scalar(width, "width", 0, None, low_inclusive=False, unit="mm")
    return int(uniform_levels(w, _farthest(p[idx], p[lit], rho)).size)


def _levels_of(d, levels, width):
    """Level index i (d'_i ≤ d < d'_{i+1}) and fraction t = 1 − β (eq. 25-27) of each distance.

    With a uniform width the distances' buffer is reused for t (``d`` is overwritten).
    """
    if width is not None:
        d *= 1.0 / width
        i = d.astype(np.int64)
        np.subtract(d, i, out=d)
        return i, d
    i = np.searchsorted(levels, d, side="right") - 1
    t = (d - levels[i]) / (levels[i + 1] - levels[i])
    return i, t


def _pair_distances(rows_xyz, self_cols, cols_xyz, sq_c) -> np.ndarray:
    """Distances (b, nc) between a block of rows and the lit columns, mm; a patch and itself exactly 0 apart.

    ``self_cols`` holds, per row, the column of the same patch among the lit ones (−1 if unlit).
    """
    d2 = rows_xyz @ cols_xyz.T
    d2 *= -2
    d2 += np.einsum("ij,ij->i", rows_xyz, rows_xyz)[:, None]
    d2 += sq_c[None, :]
    np.maximum(d2, 0, out=d2)
    # ‖p‖² + ‖q‖² − 2 p·q leaves a rounding residue where p = q: a patch and itself must lie exactly
    # 0 apart, so that they support level 0 only.
    own = np.nonzero(self_cols >= 0)[0]
    d2[own, self_cols[own]] = 0
    return np.sqrt(d2, out=d2)


def _hat_sums(flat, weight, weight_t, n_rows, n):
    """Σ weight · hat_i(d) per (row, level), shape (n_rows, n), by two ``numpy.bincount`` reductions.

    ``flat`` = row · (n + 1) + i holds each entry's bin, with i its level and t its fraction (:func:`_levels_of`);
    ``weight_t`` = weight · t (``weight`` None: a count of 1 per entry).  hat_i takes 1 − t, hat_(i+1) takes t.
    """
    size = n_rows * (n + 1)
    s_c = np.bincount(flat, weights=weight, minlength=size).reshape(n_rows, n + 1)
    s_ct = np.bincount(flat, weights=weight_t, minlength=size).reshape(n_rows, n + 1)
    out = s_c[:, :n] - s_ct[:, :n]
    out[:, 1:] += s_ct[:, : n - 1]
    return out


def _near_pairs(d, self_cols, cols_rho):
    """(row, column) of the pairs of a block nearer than NEAR_RADII source radii, a patch and itself left out.

    ``d`` holds the block's pair distances (b, nc), ``self_cols`` each row's own column (−1 if unlit), ``cols_rho``
    the columns' disk radii (mm).
    """
    jj, kk = np.nonzero(is_near(d, cols_rho[None, :]))
    keep = kk != self_cols[jj]
    return jj[keep], kk[keep]


def _near_correction(d, self_cols, cols_w, cols_rho, levels, width, budget):
    """A block's change of W from taking its near pairs over the source disk (module docstring), and their reach.

    A pair (row j, lit column k ≠ j) is near when d_jk < NEAR_RADII ρ_k; it changes row j by c_k A_k [Σ_q w_q
    hat_i(r_q) − hat_i(d_jk)], with r_q the distances to the disk's nodes
    (:func:`facestats.model.disk_quadrature.disk_node_distances`).  Nodes beyond the last level take its hat.
    The pairs are taken in chunks whose temporaries (about 48 bytes a node) stay within ``budget`` bytes.

    Returns
    -------
    ndarray, shape (b, k)
        The change of the block's rows in its first k levels (k: those the near disks reach; later ones do not
        change, so the temporaries stay b × k).
    float
        The farthest node distance of a near pair, mm (0 if none).
    """
    b, n = d.shape[0], levels.shape[0]
    jj, kk = _near_pairs(d, self_cols, cols_rho)
    dist = d[jj, kk]
    if jj.size == 0:
        return np.zeros((b, 0)), 0.0
    reach = float(np.max(dist + cols_rho[kk]))
    k = min(n, int(np.searchsorted(levels, reach, side="right")) + 1)  # levels[k - 1] > reach, or k = n
    out = np.zeros((b, k))
    step = max(1, int(budget) // (48 * _DISK_NODES))
    for start in range(0, jj.size, step):  # loop over chunks of near pairs, vectorised within
        sl = slice(start, start + step)
        r, wq = disk_node_distances(dist[sl], cols_rho[kk[sl]])
        r = np.concatenate([r.ravel(), dist[sl]])  # the disk's nodes, then the centre the point kernel took
        np.minimum(r, np.nextafter(levels[-1], 0), out=r)
        weight = np.concatenate([(cols_w[kk[sl]][:, None] * wq).ravel(), -cols_w[kk[sl]]])
        rows = np.concatenate([np.repeat(jj[sl], wq.size), jj[sl]])
        i, t = _levels_of(r, levels, width)
        t *= weight
        out += _hat_sums(rows * (k + 1) + i, weight, t, b, k)
    return out, reach


def _accumulate_block(rows_xyz, self_cols, cols_xyz, sq_c, cols_w, levels, width, cols_rho=None, budget=None):
    """One row block: its rows of W, its level support, its largest pair distance and its near pairs' reach.

    ``self_cols`` holds, per row, the column of the same patch among the lit ones (−1 if unlit);
    ``cols_rho`` (the lit columns' disk radii, mm) takes the near pairs over their disks
    (:func:`_near_correction`, within ``budget`` bytes), None keeps the point kernel.
    """
    n = levels.shape[0]
    b, nc = rows_xyz.shape[0], cols_xyz.shape[0]
    d = _pair_distances(rows_xyz, self_cols, cols_xyz, sq_c)
    dmax = float(d.max(initial=0.0))
    if dmax >= levels[-1]:
        raise ValidationError(
            f"levels must extend beyond the largest patch distance (Suzuki eq. 23): last level "
            f"{levels[-1]:.6g} mm, but a pair lies {dmax:.6g} mm apart"
        )
    near, reach = None, 0.0
    if cols_rho is not None:
        near, reach = _near_correction(d, self_cols, cols_w, cols_rho, levels, width, budget)
    i, t = _levels_of(d, levels, width)
    i_flat, t_flat = i.ravel(), t.ravel()
    support = _hat_sums(i_flat, None, t_flat, 1, n)[0]
    i += (np.arange(b) * (n + 1))[:, None]  # flat (row, level) bins
    weight = np.broadcast_to(cols_w, (b, nc)).ravel()
    t *= cols_w
    w_block = _hat_sums(i_flat, weight, t_flat, b, n)
    if cols_rho is not None:
        w_block[:, : near.shape[1]] += near
    return w_block, support, dmax, reach


def disk_hat_integrals(levels, radius) -> np.ndarray:
    """H_ki = ∫_0^ρ_k 2πr hat_i(r) dr: the piecewise-linear R of the levels integrated over disks (mm²).

    hat_i is the hat function of level i (eq. 26-28: 1 at d'_i, 0 at its neighbours), so Σ_i H_ki r_i is the
    integral of the interpolated profile over a disk of radius ρ_k, and Σ_i H_ki = π ρ_k².  On a level
    interval [d'_k, d'_(k+1)] of width Δ, with a ≤ b inside it,

        ∫_a^b 2πr (d'_(k+1) − r)/Δ dr = 2π/Δ [d'_(k+1) (b² − a²)/2 − (b³ − a³)/3]   (hat_k),
        ∫_a^b 2πr (r − d'_k)/Δ dr = 2π/Δ [(b³ − a³)/3 − d'_k (b² − a²)/2]          (hat_(k+1)).

    A radius beyond the last level is taken up to it.

    Parameters
    ----------
    levels : array_like, shape (n,)
        d'_1 = 0 < … < d'_n, mm (eq. 22-24).
    radius : array_like, shape (k,)
        Disk radii ρ, mm, ≥ 0.

    Returns
    -------
    ndarray, shape (k, n)
    """
    lev = _check_levels(levels)
    rho = check_shape(as_finite(radius, "radius", 0, None, unit="mm", dtype=np.float64), "radius", (None,))
    rho = np.minimum(rho, lev[-1])
    out = np.zeros((rho.size, lev.size))
    if rho.size == 0:
        return out
    n_int = int(np.searchsorted(lev, rho.max(), side="left"))  # intervals that some disk reaches into
    lo, hi = lev[:n_int], lev[1 : n_int + 1]
    a = np.broadcast_to(lo, (rho.size, n_int))
    b = np.clip(rho[:, None], lo, hi)
    sq, cu = (b * b - a * a) / 2, (b**3 - a**3) / 3
    scale = 2 * np.pi / (hi - lo)
    out[:, :n_int] += scale * (hi * sq - cu)
    out[:, 1 : n_int + 1] += scale * (cu - lo * sq)
    return out


def quantised_system(
    points,
    weights,
    rows=None,
    *,
    width=None,
    levels=None,
    areas=None,
    near=False,
    block_bytes=DEFAULT_BLOCK_BYTES,
    progress=False,
) -> QuantisedSystem:
    """Build W of Suzuki eq. 33 for the visible rows, streaming row blocks (module docstring).

    Parameters
    ----------
    points : array_like, shape (m, 3)
        Patch centres, mm.
    weights : array_like, shape (m,)
        c_k A_k: the per-area irradiance integral of eq. 16 times the patch area
        (mm²), ≥ 0; patches with weight 0 (unlit) contribute nothing and are skipped.
    rows : array_like of int, optional
        Indices of the visible patches (default: all).
    width : float, optional
        Quantisation width in mm (> 0): levels 0, w, 2w, … just beyond the
        largest (visible, lit) distance (eq. 22-24).
    levels : array_like, optional
        Explicit levels instead of ``width`` (eq. 22-24; the last must exceed
        the largest distance, eq. 23).
    areas : array_like, shape (m,), optional
        Patch areas A_k, mm² (> 0): a lit row's own light is the footprint integral over the disk of its
        area, c_j Σ_i H_i(ρ_j) r_i with c_j = weights_j / A_j (:func:`disk_hat_integrals`); default the paper's
        R(0) c_j A_j (module docstring: A patch's own light).
    near : bool
        With ``areas``: also take each lit patch within ``NEAR_RADII`` radii of a row over its disk instead of
        at its centre (module docstring: Near neighbours' light).  ``self_term_keywords`` gives ``areas`` and
        ``near`` for a self term by name.
    block_bytes : int
        Memory budget of a row block (≥ 1 MiB).
    progress : bool
        Show a progress bar over the row blocks (:mod:`facestats.core.progress`).

    Returns
    -------
    QuantisedSystem
    """
    p = check_shape(as_finite(points, "points", dtype=np.float64), "points", (None, 3))
    m = p.shape[0]
    wk = check_shape(as_finite(weights, "weights", 0, None, dtype=np.float64), "weights", (m,))
    idx = np.arange(m) if rows is None else np.asarray(rows)
    if idx.ndim != 1 or idx.dtype.kind not in "iu" or (idx.size and (idx.min() < 0 or idx.max() >= m)):
        raise ValidationError(f"rows must be a 1-D array of patch indices in [0, {m}), got {idx!r}")
    if idx.size == 0:
        raise ValidationError("rows must select at least one visible patch, got none")
    lit = np.nonzero(wk > 0)[0]
    if lit.size == 0:
        raise ValidationError("weights must be positive for at least one patch (no patch is lit), got all 0")
    if (width is None) == (levels is None):
        raise ValidationError(f"give exactly one of width and levels, got width={width!r} and levels={levels!r}")
    check_integer(block_bytes, "block_bytes", 2**20)
    area = None if areas is None else _check_areas(areas, m)
    if not isinstance(near, (bool, np.bool_)) or (near and area is None):
        raise ValidationError(f"near must be True or False, and True only with areas, got {near!r}")
    centre = p[np.concatenate([idx, lit])].mean(0)
    rows_xyz, cols_xyz = p[idx] - centre, p[lit] - centre
    rho = np.sqrt(area[lit] / np.pi) if near else None  # the lit patches' disk radii, mm
    if width is not None:
        w = as_scalar(width, "width", 0, None, low_inclusive=False, unit="mm")
        lev = uniform_levels(w, _farthest(rows_xyz, cols_xyz, rho))
    else:
        w, lev = None, _check_levels(levels)
    block = max(1, int(block_bytes) // (_BYTES_PER_PAIR * lit.size))
    starts = range(0, idx.size, block)
    starts = progress_bar(starts, desc="W (Suzuki eq. 33)", unit="block", enabled=progress)
    sq_c = np.einsum("ij,ij->i", cols_xyz, cols_xyz)
    lit_pos = np.full(m, -1)
    lit_pos[lit] = np.arange(lit.size)
    self_cols = lit_pos[idx]
    w_mat = np.empty((idx.size, lev.size))
    support, dmax, reach = np.zeros(lev.size), 0.0, 0.0
    for start in starts:  # loop over row blocks, vectorised over the pairs of a block
        sub = slice(start, min(start + block, idx.size))
        w_mat[sub], sb, db, rb = _accumulate_block(
            rows_xyz[sub], self_cols[sub], cols_xyz, sq_c, wk[lit], lev, w, rho, block_bytes
        )
        support += sb
        dmax, reach = max(dmax, db), max(reach, rb)
    if w is not None:  # trim to the levels eq. 23 needs: d'_n is the first level beyond the largest distance
        n = min(int(np.floor(max(dmax, reach) / w)) + 2, lev.size)  # (or beyond the near disks' farthest node)
        w_mat, lev, support = w_mat[:, :n], lev[:n], support[:n]
    if area is not None:  # each lit row's own pair: its disk's footprint instead of R(0) c_j A_j at level 0
        own = np.nonzero(self_cols >= 0)[0]
        j = idx[own]
        w_mat[own] += (wk[j] / area[j])[:, None] * disk_hat_integrals(lev, np.sqrt(area[j] / np.pi))
        w_mat[own, 0] -= wk[j]
    return QuantisedSystem(
        matrix=w_mat,
        levels=lev,
        rows=idx,
        support=np.asarray(support, np.float64),
        max_distance=dmax,
        n_pairs=int(idx.size) * int(lit.size),
        areas=area,
        near=bool(near),
        spacing=patch_spacing(p[np.union1d(idx, lit)]),
    )


def _check_areas(areas, m) -> np.ndarray:
    """Patch areas, mm², one per point, finite and > 0."""
    return check_shape(
        as_finite(areas, "areas", 0, None, low_inclusive=False, unit="mm^2", dtype=np.float64), "areas", (m,)
    )


def point_kernel_exitance(
    points, weights, rows, profile, *, areas=None, energy=None, near=False, block_bytes=DEFAULT_BLOCK_BYTES
) -> np.ndarray:
    """l_j = Σ_k R(d_jk) w_k of the ``rows``: Suzuki et al. eq. 17 with w_k = c_k A_k, the exitance W r approximates.

    The point kernel before quantisation: every pair at its own distance, a patch
    and itself at d = 0 (as in :func:`quantised_system`, where that pair supports
    level 0 only, so both give it R(0) w_j); with ``areas`` and ``energy``, a lit
    row's own light is c_j E(ρ_j) instead, the profile's energy within the disk
    of its area (as :func:`quantised_system` with ``areas`` takes it); with ``near``
    too, the lit patches within ``NEAR_RADII`` radii of a row are taken over
    their disks (the profile at the nodes of
    :func:`facestats.model.disk_quadrature.disk_node_distances`), as
    :func:`quantised_system` with ``near`` takes them.

    Parameters
    ----------
    points : array_like, shape (m, 3)
        Patch centres, mm.
    weights : array_like, shape (m,)
        w_k = c_k A_k ≥ 0 (irradiance × area).
    rows : array_like of int
        The patches whose exitance is wanted.
    profile : callable
        R(d) for an array of distances d in mm, vectorised (mm⁻²).
    areas : array_like, shape (m,), optional
        Patch areas, mm² (> 0), with ``energy``.
    energy : callable, optional
        E(ρ) = ∫_0^ρ 2πr R(r) dr for an array of radii in mm (dimensionless), e.g.
        :func:`facestats.model.dipole.dipole_radial_energy` of the same medium.
    near : bool
        With ``areas`` and ``energy``: the near neighbours over their disks.
    block_bytes : int
        Memory budget of a row block.

    Returns
    -------
    ndarray, shape (len(rows),)
        In the unit of ``weights`` × mm⁻².
    """
    p = check_shape(as_finite(points, "points", dtype=np.float64), "points", (None, 3))
    wk = check_shape(as_finite(weights, "weights", 0, None, dtype=np.float64), "weights", (p.shape[0],))
    idx = np.asarray(rows, np.int64)
    lit = np.nonzero(wk > 0)[0]
    lit_pos = np.full(p.shape[0], -1)
    lit_pos[lit] = np.arange(lit.size)
    centre = p[lit].mean(0) if lit.size else np.zeros(3)
    rows_xyz, cols_xyz = p[idx] - centre, p[lit] - centre
    sq_c = np.einsum("ij,ij->i", cols_xyz, cols_xyz)
    out = np.zeros(idx.size)
    if not isinstance(near, (bool, np.bool_)):
        raise ValidationError(f"near must be True or False, got {near!r}")
    if (areas is None) != (energy is None) or (near and areas is None):
        raise ValidationError(
            "areas and energy go together (a patch's own light over the disk of its area), and near needs them, "
            f"got areas {'None' if areas is None else 'given'}, energy {energy!r}, near {near!r}"
        )
    area = None if areas is None else _check_areas(areas, p.shape[0])
    rho = np.sqrt(area[lit] / np.pi) if near else None
    block = max(1, int(check_integer(block_bytes, "block_bytes", 2**20)) // (16 * max(lit.size, 1)))
    for start in range(0, idx.size if lit.size else 0, block):  # loop over row blocks, vectorised over pairs
        sub = slice(start, start + block)
        d = _pair_distances(rows_xyz[sub], lit_pos[idx[sub]], cols_xyz, sq_c)
        kern = profile(d)
        if near:  # the near pairs over the source's disk (quantised_system's near)
            jj, kk = _near_pairs(d, lit_pos[idx[sub]], rho)
            r, wq = disk_node_distances(d[jj, kk], rho[kk])
            kern[jj, kk] = profile(r) @ wq
        out[sub] = kern @ wk[lit]
    if areas is not None:
        own = np.nonzero(lit_pos[idx] >= 0)[0]
        j = idx[own]
        c = wk[j] / area[j]
        out[own] += c * np.asarray(energy(np.sqrt(area[j] / np.pi))) - wk[j] * float(profile(np.zeros(1))[0])
    return out


def interpolation_matrix(levels, coarse) -> np.ndarray:
    """P (n_fine, n_coarse): values at ``levels`` of the piecewise-linear function with nodal values at ``coarse``.

    ``coarse`` must be a subset of ``levels`` holding its first and last entry, so
    that every hat function of the coarse levels is a combination of the fine
    ones and W_coarse = W_fine P exactly.

    Parameters
    ----------
    levels : array_like, shape (n_fine,)
        The fine levels d'_i, mm, increasing.
    coarse : array_like, shape (n_coarse,)
        The kept levels, mm (≥ 2; not validated).

    Returns
    -------
    ndarray of float64, shape (n_fine, n_coarse)
        P; each row sums to 1.
    """
    lev = np.asarray(levels, np.float64)
    cl = np.asarray(coarse, np.float64)
    j = np.clip(np.searchsorted(cl, lev, side="right") - 1, 0, cl.size - 2)
    t = np.clip((lev - cl[j]) / (cl[j + 1] - cl[j]), 0, 1)
    out = np.zeros((lev.size, cl.size))
    rows = np.arange(lev.size)
    out[rows, j] = 1 - t
    out[rows, j + 1] += t
    return out


def merge_levels(system: QuantisedSystem, keep) -> QuantisedSystem:
    """Remove the levels not in ``keep`` (bool mask), widening their neighbours' hats (module docstring).

    The first level (d'_1 = 0, eq. 22) and the last (eq. 23) are always kept.

    Parameters
    ----------
    system : QuantisedSystem
        The system to coarsen.
    keep : array_like of bool, shape (n,)
        The levels to keep, one entry per level of ``system``.

    Returns
    -------
    QuantisedSystem
        A copy with W P, the kept levels, the support mapped by P and the removed levels appended to ``merged``;
        ``system`` itself when nothing is removed.

    Raises
    ------
    ValidationError
        ``keep`` of another shape than the levels.
    """
    k = np.asarray(keep, bool).copy()
    if k.shape != system.levels.shape:
        raise ValidationError(f"keep must have one entry per level, shape {system.levels.shape}, got {k.shape}")
    k[0] = k[-1] = True
    if k.all():
        return system
    cl = system.levels[k]
    p = interpolation_matrix(system.levels, cl)
    return replace(
        system,
        matrix=system.matrix @ p,
        levels=cl,
        support=system.support @ p,
        merged=system.merged + tuple(float(x) for x in system.levels[~k]),
    )


@dataclass
class NormalEquations:
    """The least-squares problem ‖A r − y‖² of a system in n × n form: G = AᵀA, g = Aᵀy, yy = yᵀy.

    ``weighted``: A = D W with D = diag(1/l_j) over the rows with l_j > 0 and
    y = 1 (relative residuals, the monotone solve); otherwise A = W and y = l
    (the paper's solve).  Everything the solves, the rank and the covariance
    need follows from (G, g, yy), and merging levels maps it exactly:
    G ← Pᵀ G P, g ← Pᵀ g (:func:`merge_levels`), so W is multiplied once.

    Attributes
    ----------
    gram : ndarray of float64, shape (n, n)
        G = AᵀA over the n levels.
    rhs : ndarray of float64, shape (n,)
        g = Aᵀy.
    yy : float
        yᵀy (``weighted``: the number of rows used, y being 1).
    n_rows : int
        Rows that entered A (``weighted``: those with l_j > 0).
    weighted : bool
        True for the relative-residual problem, False for the paper's.
    """

    gram: np.ndarray
    rhs: np.ndarray
    yy: float
    n_rows: int
    weighted: bool

    def merged(self, p) -> "NormalEquations":
        """The problem in the coarser basis r = P r_coarse.

        Parameters
        ----------
        p : ndarray, shape (n, n_coarse)
            P, e.g. :func:`interpolation_matrix` of the levels and the kept levels.

        Returns
        -------
        NormalEquations
            Pᵀ G P and Pᵀ g, with ``yy``, ``n_rows`` and ``weighted`` unchanged.
        """
        return NormalEquations(p.T @ self.gram @ p, p.T @ self.rhs, self.yy, self.n_rows, self.weighted)

    def residual(self, r) -> float:
        """‖A r − y‖² from the normal equations.

        Parameters
        ----------
        r : ndarray, shape (n,)
            Profile R'_i at the levels, mm⁻².

        Returns
        -------
        float
            rᵀ G r − 2 rᵀ g + yy, clipped at 0 (rounding of the expanded form).
        """
        return float(max(r @ self.gram @ r - 2 * r @ self.rhs + self.yy, 0.0))


def _check_exitance(exitance, n_rows):
    return check_shape(as_finite(exitance, "exitance", 0, None, dtype=np.float64), "exitance", (n_rows,))


def normal_equations(system: QuantisedSystem, exitance, *, weighted=True) -> NormalEquations:
    """(G, g, yy) of the weighted (relative, rows with l_j > 0) or plain problem (see :class:`NormalEquations`).

    Parameters
    ----------
    system : QuantisedSystem
        W of Suzuki eq. 33 on the visible rows.
    exitance : array_like, shape (rows,)
        l_j of eq. 15 for the system's rows, ≥ 0.
    weighted : bool
        True: A = diag(1/l) W over the rows with l_j > 0, y = 1 (the monotone solve); False: A = W, y = l
        (the paper's solve).

    Returns
    -------
    NormalEquations

    Raises
    ------
    ValidationError
        A negative or non-finite exitance, or one not of shape (rows,).
    FitError
        ``weighted`` with l = 0 on every row.
    """
    l = _check_exitance(exitance, system.matrix.shape[0])
    if weighted:
        use = l > 0
        if not use.any():
            raise FitError("exitance is 0 on every visible row: the weighted solve has no relative information")
        a = system.matrix[use] / l[use, None]
        return NormalEquations(a.T @ a, a.sum(0), float(use.sum()), int(use.sum()), True)
    a = system.matrix
    return NormalEquations(a.T @ a, a.T @ l, float(l @ l), int(l.size), False)


@dataclass
class Conditioning:
    """Singular values of W (columns scaled to unit norm, rows weighted as solved), numerical rank and condition.

    Attributes
    ----------
    singular_values : ndarray, shape (n,)
        Singular values, descending (square roots of the eigenvalues of the scaled Gram matrix, :func:`conditioning`).
    rank : int
        Numerical rank: singular values above ``rcond`` × s_max (0 if s_max is 0).
    condition : float
        s_max / s_min (inf if a singular value is 0).
    rcond : float
        The relative threshold of the rank.
    """

    singular_values: np.ndarray
    rank: int
    condition: float
    rcond: float


def equilibrate(gram):
    """A Gram matrix scaled to a unit diagonal: ``(D⁻¹ G D⁻¹, d)`` with D = diag(d), d = sqrt(diag G).

    The columns of A scaled to unit norm (G = AᵀA): the 1/l² weights of the exitance rows spread G's diagonal over
    tens of decades, and rank, condition and eigenpairs are only resolved after this scaling. A level no row sees
    (a zero on the diagonal, with its row and column of G zero) keeps d = 1.

    Parameters
    ----------
    gram : ndarray, shape (n, n)
        A symmetric positive semi-definite matrix (negative diagonal entries, rounding, count as 0).

    Returns
    -------
    scaled : ndarray, shape (n, n)
    d : ndarray, shape (n,)
        The scale, > 0.
    """
    g = np.asarray(gram, np.float64)
    d = np.sqrt(np.maximum(np.diag(g), 0))
    d = np.where(d > 0, d, 1.0)
    return g / np.outer(d, d), d


def _scaled_gram(neq: NormalEquations):
    return equilibrate(neq.gram)[0]


def conditioning(neq: NormalEquations, rcond=1e-10) -> Conditioning:
    """Numerical rank and condition number of the problem's matrix A with columns scaled to unit norm.

    The singular values are the square roots of the eigenvalues of the scaled
    Gram matrix: exact to rounding for singular values above about 10⁻⁷ s_max,
    so ranks at ``rcond`` ≥ 10⁻⁷ and condition numbers up to about 10⁷ are
    resolved; larger condition numbers are reported as at least that.

    Parameters
    ----------
    neq : NormalEquations
        The problem (its Gram matrix G = AᵀA).
    rcond : float
        Relative threshold of the rank, in (0, 1).

    Returns
    -------
    Conditioning

    Raises
    ------
    ValidationError
        An ``rcond`` outside (0, 1).
    """
    from scipy.linalg import eigvalsh

    rc = as_scalar(rcond, "rcond", 0, 1, low_inclusive=False, high_inclusive=False)
    s = np.sqrt(np.maximum(eigvalsh(_scaled_gram(neq), check_finite=False)[::-1], 0))
    smax = float(s[0]) if s.size else 0.0
    rank = int(np.sum(s > rc * smax)) if smax > 0 else 0
    with np.errstate(divide="ignore"):
        cond = float(smax / s[-1]) if s.size and s[-1] > 0 else np.inf
    return Conditioning(singular_values=s, rank=rank, condition=cond, rcond=rc)


def dependent_levels(neq: NormalEquations, rcond=1e-10) -> np.ndarray:
    """Indices of the columns beyond the numerical rank, least independent last (pivoted Cholesky).

    The pivoted Cholesky factorisation of the scaled Gram matrix (LAPACK
    ``dpstrf``, tolerance rcond²) orders the columns as a column-pivoted QR of
    A would; the columns after the rank are those a rank-revealing solve drops.

    Parameters
    ----------
    neq : NormalEquations
        The problem (its Gram matrix G = AᵀA).
    rcond : float
        Relative singular-value threshold (not validated).

    Returns
    -------
    ndarray of int64
        0-based level indices, empty at full rank.
    """
    from scipy.linalg.lapack import dpstrf

    _, piv, rank, _ = dpstrf(_scaled_gram(neq), lower=0, tol=float(rcond) ** 2)
    return np.asarray(piv[rank:], np.int64) - 1  # LAPACK pivots are 1-based


def solve_pinv(system: QuantisedSystem, exitance, rcond=1e-10) -> np.ndarray:
    """r = W⁺ l on the visible rows (Suzuki eq. 35), singular values below ``rcond`` × s_max dropped.

    Parameters
    ----------
    system : QuantisedSystem
    exitance : array_like, shape (rows,)
        l_j of eq. 15 for the system's rows (≥ 0).
    rcond : float
        Relative singular-value threshold of the pseudo-inverse.

    Returns
    -------
    ndarray, shape (n,)
        R'_i in mm⁻² (may be negative: the paper's solve has no constraint).
    """
    from scipy.linalg import lstsq

    l = _check_exitance(exitance, system.matrix.shape[0])
    norm = np.linalg.norm(system.matrix, axis=0)
    norm = np.where(norm > 0, norm, 1.0)
    sol, *_ = lstsq(system.matrix / norm, l, cond=rcond, lapack_driver="gelsy", check_finite=False)
    return sol / norm


def _monotone_triangle(neq: NormalEquations):
    """The n × n least-squares problem of the monotone basis: triangle, right-hand side and column scale.

    With T_ik = 1 for i ≤ k (r = T u), the Gram matrix of A T is Tᵀ G T =
    cumsum(cumsum(G, 1), 0) and Tᵀ g = cumsum(g); scaled to unit columns, its
    Cholesky factor R and z = R⁻ᵀ Tᵀ g give ‖A T u − y‖² = ‖R u' − z‖² + const.
    """
    from scipy.linalg import LinAlgError, cholesky, eigh, solve_triangular

    gu = np.cumsum(np.cumsum(neq.gram, axis=1), axis=0)
    gu = 0.5 * (gu + gu.T)
    bu = np.cumsum(neq.rhs)
    gs, scale = equilibrate(gu)
    try:
        tri = cholesky(gs, lower=False, check_finite=False)
    except LinAlgError:  # numerically singular: the PSD square root keeps what the data determine
        w, v = eigh(gs, check_finite=False)
        tri = np.sqrt(np.maximum(w, 0))[:, None] * v.T
        z = np.where(w > 0, (v.T @ (bu / scale)) / np.sqrt(np.where(w > 0, w, 1.0)), 0.0)
        return tri, z, scale
    return tri, solve_triangular(tri, bu / scale, trans="T", check_finite=False), scale


def solve_monotone_normal(neq: NormalEquations) -> np.ndarray:
    """r ≥ 0, non-increasing, minimising ‖A r − y‖ for weighted normal equations (module docstring).

    Parameters
    ----------
    neq : NormalEquations
        The problem, usually weighted (:func:`normal_equations`).

    Returns
    -------
    ndarray of float64, shape (n,)
        R'_i in mm⁻², non-negative and non-increasing.
    """
    from scipy.optimize import nnls

    tri, z, scale = _monotone_triangle(neq)
    u, _ = nnls(tri, z, maxiter=50 * tri.shape[1])
    return np.cumsum((u / scale)[::-1])[::-1]


def solve_monotone(system: QuantisedSystem, exitance) -> tuple[np.ndarray, np.ndarray]:
    """r ≥ 0, non-increasing, minimising the relative residual ‖D (W r − l)‖ (module docstring).

    Parameters
    ----------
    system : QuantisedSystem
    exitance : array_like, shape (rows,)
        l_j of eq. 15 for the system's rows (≥ 0); rows with l_j = 0 are left out.

    Returns
    -------
    r : ndarray, shape (n,)
        R'_i in mm⁻², non-negative and non-increasing.
    used : ndarray of bool, shape (rows,)
        The rows that entered the solve (l_j > 0).
    """
    l = _check_exitance(exitance, system.matrix.shape[0])
    return solve_monotone_normal(normal_equations(system, l)), l > 0


def profile_covariance(neq: NormalEquations, profile) -> np.ndarray:
    """Covariance σ̂² (AᵀA)⁺ of r in the unconstrained problem, σ̂² = ‖A r − y‖² / (rows − n).

    Used to judge which levels the data determine; the constraints of the
    monotone solve are ignored (the local, unconstrained spread).

    Parameters
    ----------
    neq : NormalEquations
        The problem.
    profile : array_like, shape (n,)
        The solution r (R'_i, mm⁻²) whose residual gives σ̂².

    Returns
    -------
    ndarray of float64, shape (n, n)
        The covariance of r, in the square of r's unit.
    """
    from scipy.linalg import pinvh

    n = neq.gram.shape[0]
    s2 = neq.residual(np.asarray(profile, np.float64)) / max(neq.n_rows - n, 1)
    scaled, d = equilibrate(neq.gram)
    return s2 * pinvh(scaled, check_finite=False) / np.outer(d, d)
