"""Translucency from one image: Suzuki, Mukaigawa & Yagi's quantised-distance solve and dipole fit, made robust.

:func:`fit_scattering_image` takes per-patch centres, areas, the irradiance c_k
of eq. 16 and the exitance l_j of eq. 15 (see :mod:`facestats.model.irradiance`)
and returns (σ's, σa) of the dipole with an interval and the diagnostics of the
linear system:

0. **Light** (beyond the paper): the solve learns R' from where the light changes near the seen
   patches; when fewer than 30 are unevenly lit (:mod:`facestats.model.fitting.even_light`), eq. 36
   (``"monotone"``, ``"pinv"``) is refused with a :class:`facestats.errors.FitError` that says what to do, and
   ``"exitance"`` runs with a note.
1. **Levels** (eq. 22-24): a width in mm, or ``"auto"`` (below).
2. **W** (eq. 33) over the visible rows, streamed in row blocks
   (:func:`facestats.model.fitting.quantised.quantised_system`).  ``self_term``:
   ``"point"`` (default) is the paper's R(0) c_j A_j (eq. 17) for a patch's own
   light; ``"footprint"`` integrates R over the disk of its area, as a continuous
   surface gives it.  The point term is about twice the footprint for 1 mm patches
   of skin-like media, and an image of a continuous surface (the pyramid's
   exitance by quadrature, Suzuki Table 1's medium) is fitted with σ's 1.98 /
   2.08 and σa 0.0025 / 0.0023 mm⁻¹ at ``width="auto"`` / 0.25 mm (Table 2 grid;
   truth 2.19, 0.0021); with ``"footprint"`` 2.13 / 2.19 and 0.0022 / 0.0021.
   The footprint is not the default because its own pair spreads over the first
   levels, where eq. 28's linear interpolation of the steep R errs: its own round
   trip (footprint render, footprint fit) gives 2.13 at ``"auto"`` (0.42 mm)
   where the point kernel's is exact; use 0.25 mm or finer with it.
   ``"surface"`` also integrates the lit patches within
   :data:`facestats.model.disk_quadrature.NEAR_RADII` disk radii of a row over
   their disks; use it with ``method="exitance"`` (step 5), since eq. 36 cannot
   resolve the levels between a patch and its neighbours.
3. **Unsupported levels** — levels that fewer than ``min_pairs`` (visible, lit)
   patch pairs support (hat-weighted count) cannot be solved for; they are
   merged into their neighbours (:func:`~facestats.model.fitting.quantised.merge_levels`)
   with a :class:`facestats.errors.QuantisationWarning`.  Then the numerical rank
   and condition number of W (columns scaled to unit norm, rows weighted as the
   solve weights them) are computed; while the rank is below the number of
   levels, the levels whose columns are least independent (the pivots beyond
   the rank of a pivoted Cholesky factorisation of the Gram matrix, which
   orders columns as a column-pivoted QR would) are merged away, with a warning.  Everything done is
   recorded in the result (``merged_levels``, ``rank``, ``condition``,
   ``notes``); a condition number above ``CONDITION_WARNING`` = 10⁴ (well-posed
   scenes stay near 10³; nearly uniform light reaches 10⁵-10⁸) is warned about
   too.  Nothing is solved silently.
4. **Solve** for r = (R'_1 … R'_n): ``"pinv"`` — the paper's r = W⁺ l (eq. 35);
   ``"monotone"`` (default) — r ≥ 0 and non-increasing, rows weighted by 1/l
   (:func:`~facestats.model.fitting.quantised.solve_monotone`).
5. **Fit** eq. 36 on a grid, default Suzuki Table 2
   (:func:`facestats.model.fitting.profile_grid.fit_profile_grid`), over the
   levels up to ``max_distance``, with a profile-likelihood interval.
   ``method="exitance"`` (beyond the paper) fits the dipole to the image
   through W instead, l ≈ W R(d'; σ's, σa) by relative residuals, on W at its
   width before any level was merged
   (:func:`facestats.model.fitting.profile_grid.fit_exitance_grid`); R' is
   still solved as ``"monotone"`` and reported.  With ``self_term="surface"``
   it is the estimator that does not need the scene to identify R level by
   level, so an image of a continuous surface is fitted without the point
   kernel's bias (a flat plate of 1 mm patches, exitance by a quadrature of
   the surface: σ's 2.19, σa 0.0021 at 0.1 mm, truth 2.19 / 0.0021; eq. 36
   with the same self term gives 1.89 / 0.003 there; at a fixed 0.25 mm the
   exitance fit gives 2.14 / 0.0022).  Its accuracy is bounded by eq. 28's linear
   interpolation over the disks' nodes, which is what step 6 measures, so
   with ``width="auto"`` the width is narrowed (about as the square root of
   the error, at most ``EXITANCE_ROUNDS`` = 4 times, W at most 256 MiB) until
   that error is at most ``EXITANCE_QUANTISATION`` = 0.25 %.

6. **Check** the quantisation (:func:`quantisation_error`): the interval of step
   5 measures how well the grid's dipoles fit the solved profile, not how well
   the levels represent R, which eq. 28 interpolates linearly over each level
   and which falls steeply within the first mean free path 1/σ't.  So the
   fitted dipole's exitance through W (eq. 34) is compared with its point-kernel
   exitance (eq. 17) on up to ``QUANTISATION_ROWS`` = 500 visible rows; an RMS
   relative difference above ``QUANTISATION_WARNING`` = 5 % is warned about
   and noted.  Measured on noise-free point-kernel renders of Suzuki Table 1's
   medium (1/σ't = 0.46 mm): a flat plate of 0.5 mm patches lit over a strip
   gave differences of 12.7 / 6.5 / 2.5 / 0.6 % at widths 1 / 0.7 / 0.5 /
   0.25 mm and estimates σ's = 1.94 / 2.12 / 2.23 / 2.17 mm⁻¹ (the 1 mm
   interval excluded the truth); the pyramid of 1 mm patches 29 / 6.1 / 1.5 %
   at 2 / 1 / 0.5 mm and 1.77 / 2.14 / 2.19 mm⁻¹.

Maximum distance (``max_distance="auto"``) and automatic width (``width="auto"``,
the open problem of Suzuki §4.1): see :mod:`facestats.model.fitting.quantisation_choice`.
"""

from __future__ import annotations

import contextlib
import warnings
from dataclasses import dataclass, field

import numpy as np

from facestats.core.validate import as_finite, as_scalar, check_choice, check_integer, check_shape
from facestats.errors import FitError, QuantisationWarning, ValidationError
from facestats.model.fitting.even_light import EVEN_CONTRAST, EVEN_NEIGHBOURS, UNEVEN_ROWS, evenly_lit_rows
from facestats.model.fitting.profile_grid import (
    LOG_GRID_SIGMA_A,
    LOG_GRID_SIGMA_S_PRIME,
    TABLE2_GRID,
    ProfileFit,
    ProfileGrid,
    fit_exitance_grid,
    fit_profile_grid,
)
from facestats.model.fitting.quantisation_choice import MAX_RELATIVE_ERROR, NOISE_FLOOR, auto_width, fit_distance
from facestats.model.fitting.quantised import (
    DEFAULT_BLOCK_BYTES,
    MAX_LEVELS,
    SELF_TERMS,
    QuantisedSystem,
    conditioning,
    dependent_levels,
    interpolation_matrix,
    merge_levels,
    normal_equations,
    planned_levels,
    point_kernel_exitance,
    quantised_system,
    self_term_keywords,
    solve_monotone_normal,
    solve_pinv,
)

__all__ = [
    "METHODS",
    "ScatteringImageFit",
    "fit_scattering_image",
    "fit_scattering_system",
    "fit_scattering_channels",
    "quantisation_error",
    "QUANTISATION_WARNING",
    "SELF_TERMS",
]

#: The solves of eq. 34: the paper's pseudo-inverse, the constrained default, and the dipole fitted through W.
METHODS = ("pinv", "monotone", "exitance")
#: Default relative singular-value threshold of the numerical rank.
DEFAULT_RCOND = 1e-6
#: Condition number of W above which the result carries a warning (well-posed scenes stay near 10³).
CONDITION_WARNING = 1e4
#: Visible rows sampled by :func:`quantisation_error`.
QUANTISATION_ROWS = 500
#: :func:`quantisation_error` above which a fit carries a warning (module docstring, step 6).
QUANTISATION_WARNING = 0.05
#: Stack level of the warnings of a fit from patch positions: the frame that called fit_scattering_image or
#: fit_scattering_channels (through _fit_over_widths, _fit_candidates, _one_image, and _try_width or
#: _checked_quantisation).
_USER = 6
#: ``method="exitance"`` with ``width="auto"`` narrows the width until :func:`quantisation_error` is at most this
#: (module docstring, step 5): on noise-free renders σ's then lies within about 1 % of its converged value.
EXITANCE_QUANTISATION = 0.0025
#: At most this many narrowing rounds, and W (rows × levels, float64) at most this many bytes: the exitance fit
#: holds about 3 more of W's size at its peak (normal equations, the R' solve), so about 1 GiB in all.
EXITANCE_ROUNDS = 4
EXITANCE_W_BYTES = 256 * 2**20


@dataclass
class ScatteringImageFit:
    """Result of :func:`fit_scattering_image`.

    Attributes
    ----------
    sigma_s_prime, sigma_a : float
        Reduced scattering and absorption coefficients, mm⁻¹.
    sigma_s_prime_interval, sigma_a_interval, sigma_tr_interval : tuple of float
        (low, high) at ``interval_level`` (profile likelihood over the grid).
    interval_level : float
        Probability content of the intervals.
    levels : ndarray
        The quantised distances d'_i after merging, mm.
    profile : ndarray
        R'_i at the levels, mm⁻².
    support : ndarray
        Hat-weighted (visible, lit) pair count of each level.
    width : float
        The quantisation width used (before merging), mm.
    method : str
    rank, n_levels : int
        Numerical rank of W and its number of columns (after merging).
    condition : float
        Condition number of W (columns scaled to unit norm, rows weighted as solved).
    merged_levels : tuple of float
        Levels merged away (unsupported or rank-deficient), mm.
    max_distance : float
        Largest level distance that entered the fit, mm.
    n_rows : int
        Visible rows that entered the solve.
    profile_fit : ProfileFit
        The eq. 36 fit (cost surface, levels used, grid).
    rank_deficient : bool
        W lacked numerical rank before (or after) the least independent levels were merged.
    notes : list of str
        What was done about rank, support, non-positive levels and the fit range.
    quantisation_error : float
        How far the levels misrepresent the fitted dipole on this scene (:func:`quantisation_error`;
        NaN from :func:`fit_scattering_system`, which has no patch positions).
    self_term : str
        How W took the light of a patch itself and of its near neighbours: ``"point"``, ``"footprint"`` or
        ``"surface"`` (module docstring, step 2).
    eta : float
        Relative index of refraction the dipole was evaluated with.
    """

    sigma_s_prime: float
    sigma_a: float
    sigma_s_prime_interval: tuple
    sigma_a_interval: tuple
    sigma_tr_interval: tuple
    interval_level: float
    levels: np.ndarray
    profile: np.ndarray
    support: np.ndarray
    width: float
    method: str
    rank: int
    n_levels: int
    condition: float
    merged_levels: tuple
    max_distance: float
    n_rows: int
    eta: float
    profile_fit: ProfileFit
    rank_deficient: bool = False
    notes: list = field(default_factory=list)
    quantisation_error: float = float("nan")
    self_term: str = "point"

    @property
    def sigma_tr(self) -> float:
        """σtr = sqrt(3 σa (σa + σ's)), mm⁻¹ (Suzuki eq. 10-11)."""
        return float(np.sqrt(3 * self.sigma_a * (self.sigma_a + self.sigma_s_prime)))

    def summary(self) -> dict:
        """The estimate, interval and diagnostics as plain Python values (for JSON, provenance, printing)."""
        return {
            "sigma_s_prime": self.sigma_s_prime,
            "sigma_a": self.sigma_a,
            "sigma_tr": self.sigma_tr,
            "sigma_s_prime_interval": list(self.sigma_s_prime_interval),
            "sigma_a_interval": list(self.sigma_a_interval),
            "sigma_tr_interval": list(self.sigma_tr_interval),
            "interval_level": self.interval_level,
            "method": self.method,
            "width_mm": self.width,
            "n_levels": self.n_levels,
            "rank": self.rank,
            "condition": self.condition,
            "merged_levels_mm": [round(x, 6) for x in self.merged_levels],
            "max_distance_mm": self.max_distance,
            "n_rows": self.n_rows,
            "eta": self.eta,
            "quantisation_error": self.quantisation_error,
            "self_term": self.self_term,
            "notes": list(self.notes),
        }


def _check_inputs(points, areas, irradiance, radiance, visible):
    p = check_shape(as_finite(points, "points", dtype=np.float64), "points", (None, 3))
    m = p.shape[0]
    if m == 0:
        raise ValidationError("points must hold at least one patch, got 0")
    a = as_finite(areas, "areas", dtype=np.float64)
    if a.shape != (m,):
        raise ValidationError(f"areas must have one value per point, shape ({m},), got {a.shape}")
    if np.any(a <= 0):
        raise ValidationError(f"areas must be > 0 mm^2, got {a[a <= 0][0]!r}")
    c = as_finite(irradiance, "irradiance", 0, None, dtype=np.float64)
    if c.shape != (m,):
        raise ValidationError(f"irradiance must have one value per point, shape ({m},), got {c.shape}")
    l = as_finite(radiance, "radiance", 0, None, dtype=np.float64)
    if l.shape != (m,):
        raise ValidationError(f"radiance must have one value per point, shape ({m},), got {l.shape}")
    if visible is None:
        vis = np.ones(m, bool)
    else:
        vis = np.asarray(visible)
        if vis.dtype != bool or vis.shape != (m,):
            raise ValidationError(
                f"visible must be a bool array of shape ({m},), got dtype {vis.dtype} shape {vis.shape}"
            )
    if not vis.any():
        raise ValidationError(
            "visible must select at least one patch (no visible rows), got none: the camera sees none of the mesh's "
            "patches (its pose, or the mesh's unit: a mesh in m or cm given as mm, --scale)"
        )
    if not np.any(c > 0):
        raise ValidationError("irradiance must be > 0 on at least one patch (nothing is lit), got all 0")
    return p, a, c, l, vis


def _resolve_rank(system, neq, rcond, notes):
    """Merge the least independent levels until W has full numerical rank (module docstring)."""
    merged = 0
    for _ in range(8):  # a few rounds: merging changes the neighbours' columns
        drop = [int(j) for j in dependent_levels(neq, rcond) if 0 < j < system.n_levels - 1]
        if not drop or system.n_levels - len(drop) < 3:
            break
        keep = np.ones(system.n_levels, bool)
        keep[drop] = False
        notes.append(
            f"W had numerical rank {system.n_levels - len(drop)} < {system.n_levels} levels (rcond {rcond:g}); "
            f"merged the least independent levels at {np.round(system.levels[drop], 4).tolist()} mm"
        )
        neq = neq.merged(interpolation_matrix(system.levels, system.levels[keep]))
        system = merge_levels(system, keep)
        merged += len(drop)
    return system, neq, conditioning(neq, rcond), merged


def _merge_unsupported(system, min_pairs, notes):
    weak = system.support < min_pairs
    weak[0] = weak[-1] = False
    if weak.any():
        notes.append(
            f"{int(weak.sum())} level(s) supported by fewer than {min_pairs} patch pairs merged into their "
            f"neighbours (first at {system.levels[weak][0]:.4g} mm)"
        )
        system = merge_levels(system, ~weak)
    return system


def _solve(system, neq, l, method, rcond, notes):
    """r by the chosen method and the number of rows that entered the solve."""
    if method == "pinv":
        return solve_pinv(system, l, rcond=rcond), int(system.rows.size)
    if neq.n_rows < l.size:
        notes.append(f"{l.size - neq.n_rows} visible row(s) with zero radiance left out of the weighted solve")
    return solve_monotone_normal(neq), neq.n_rows


def _fit_range(system, neq, l, r, method, max_distance):
    """The largest level distance of the fit, mm (``max_distance`` of :func:`fit_scattering_image`)."""
    if max_distance == "auto" and method == "monotone":
        dmax = fit_distance(system, neq, r)
        n = int(np.count_nonzero((system.levels <= dmax) & (r > 0)))
        if n < 3:
            raise FitError(
                f"max_distance='auto': the image determines R' to {100 * MAX_RELATIVE_ERROR:g} % (at "
                f"{100 * NOISE_FLOOR:g} % noise or the solve's residual, at the patches' resolution) only up to "
                f"{dmax:.4g} mm, {n} level(s) with R' > 0 where eq. 36 needs 3: the near levels are not resolved (the "
                "light varies little near the patches the camera sees, or the image is noisy). A coarser width pools "
                "them (width='auto' tries coarser ones); method='exitance' fits the dipole through W without R'; a "
                "larger max_distance forces the range, but levels the data do not determine bias the fit (command "
                "line: --width, --method exitance, --max-distance)"
            )
        return dmax
    if max_distance is None or max_distance == "auto":  # the paper fits every level
        return float(system.levels[-1])
    dmax = as_scalar(max_distance, "max_distance", 0, None, low_inclusive=False, unit="mm")
    if dmax > system.max_distance:
        raise ValidationError(
            f"max_distance must not exceed the largest patch distance {system.max_distance:.6g} mm "
            f"(no pair lies beyond it), got {dmax:g}"
        )
    return dmax


def _solved_profile(system, l, method, min_pairs, rcond, notes, stacklevel):
    """Steps 3-4: merge the unsupported and the dependent levels (warned about), then solve r by ``method``.

    Returns (system after merging, its normal equations, conditioning, r, rows solved, rank deficient).
    """
    system = _merge_unsupported(system, int(min_pairs), notes)
    neq = normal_equations(system, l, weighted=method != "pinv")
    system, neq, cond, n_rank_merged = _resolve_rank(system, neq, float(rcond), notes)
    if cond.condition > CONDITION_WARNING:
        notes.append(
            f"W is ill-conditioned: condition number {cond.condition:.3g} > {CONDITION_WARNING:g} (columns scaled to "
            "unit norm, rows weighted as solved); the profile is sensitive to noise, e.g. under nearly uniform light"
        )
    if cond.rank < system.n_levels:
        notes.append(
            f"W keeps numerical rank {cond.rank} < {system.n_levels} (the dependent levels include the first or "
            "the last, which eq. 22-23 keep): r is not unique; pinv truncates, the monotone constraints choose"
        )
    if system.n_levels < 3:
        raise FitError(f"only {system.n_levels} supported levels remain; at least 3 are needed to fit 2 parameters")
    for note in notes:  # warned before the fit, which may still fail on what they describe
        warnings.warn(note, QuantisationWarning, stacklevel=stacklevel)
    r, n_rows = _solve(system, neq, l, method, rcond, notes)
    return system, neq, cond, r, n_rows, n_rank_merged > 0 or cond.rank < system.n_levels


def _exitance_fit(system, l, *, max_distance, min_pairs, rcond, grid, eta, refine, level):
    """``method="exitance"`` (module docstring, step 5): the estimate through W unmerged, R' solved for display.

    Returns (the system R' is shown on, the ProfileFit, r, conditioning, rows, notes).
    """
    if not (max_distance is None or (isinstance(max_distance, str) and max_distance == "auto")):
        raise ValidationError(
            f"max_distance selects the levels of eq. 36; method='exitance' fits every row through W, got "
            f"max_distance={max_distance!r} (use 'auto' or None)"
        )
    full = normal_equations(system, l, weighted=True)
    pf = fit_exitance_grid(
        system.levels, full.gram, full.rhs, full.n_rows, grid=grid, eta=eta, refine=refine, level=level
    )
    shown_notes = []  # the R' solve's own, warned about by it
    try:
        shown, _, cond, r, _, _ = _solved_profile(system, l, "monotone", min_pairs, rcond, shown_notes, 4)
    except FitError as exc:
        shown_notes.append(f"R' was not solved ({exc}); the exitance fit does not need it")
        for note in shown_notes:  # _solved_profile stopped before warning them; to fit_scattering_system's caller
            warnings.warn(note, QuantisationWarning, stacklevel=3)
        shown, cond, r = system, conditioning(full, float(rcond)), np.full(system.n_levels, np.nan)
    note = (
        "method='exitance': the dipole is fitted to the exitance through W at its width (eq. 34, "
        f"{system.n_levels} levels, none merged); the profile R', its levels, rank and condition are the monotone "
        "solve's, shown for comparison"
    )
    return shown, pf, r, cond, full.n_rows, [note, *shown_notes]


def _grid_edge_note(pf) -> str:
    """The note of an interval that reaches the grid's edge: which edge, and advice that depends on the grid run."""
    g = pf.grid
    ends = []
    for name, values, (low, high) in (
        ("sigma_s'", g.sigma_s_prime, pf.sigma_s_prime_interval),
        ("sigma_a", g.sigma_a, pf.sigma_a_interval),
    ):
        ends += [f"{name} {values[0]:g} (lowest)"] if low <= values[0] else []
        ends += [f"{name} {values[-1]:g} (highest)"] if high >= values[-1] else []
    found = (
        f"the interval reaches the edge of the grid at {' and '.join(ends)} (grid sigma_s' {g.sigma_s_prime[0]:g}-"
        f"{g.sigma_s_prime[-1]:g}, sigma_a {g.sigma_a[0]:g}-{g.sigma_a[-1]:g} 1/mm): the grid bounds it"
    )
    (s0, s1), (a0, a1) = LOG_GRID_SIGMA_S_PRIME, LOG_GRID_SIGMA_A
    if g.sigma_s_prime[0] > s0 or g.sigma_s_prime[-1] < s1 or g.sigma_a[0] > a0 or g.sigma_a[-1] < a1:
        return (
            f"{found}, and the medium may lie outside; fit on a wider grid (grid=ProfileGrid.log_spaced(), sigma_s' "
            f"{s0:g}-{s1:g} and sigma_a {a0:g}-{a1:g} 1/mm; --grid skin on the command line)"
        )
    return (
        f"{found}, which already spans the skin grid's sigma_s' {s0:g}-{s1:g} and sigma_a {a0:g}-{a1:g} 1/mm: the "
        f"medium lies outside them, or the data do not determine that coefficient (sigma_a shapes the profile's fall "
        f"over 1/sigma_tr, and the fit reaches {pf.max_distance:.4g} mm); a grid of other ranges is "
        "grid=ProfileGrid.log_spaced((low, high), (low, high)), which the command line does not offer"
    )


def fit_scattering_system(
    system: QuantisedSystem,
    exitance,
    *,
    method="monotone",
    eta=1.3,
    grid=None,
    max_distance="auto",
    min_pairs=30,
    rcond=DEFAULT_RCOND,
    refine=False,
    level=0.95,
    width=None,
) -> ScatteringImageFit:
    """Steps 3-5 of :func:`fit_scattering_image` on a built system (reuse W for many images of one scene).

    Parameters
    ----------
    system : QuantisedSystem
        W of Suzuki eq. 33 (:func:`~facestats.model.fitting.quantised.quantised_system`).
    exitance : array_like, shape (len(system.rows),)
        l_j of eq. 15 (≥ 0) for the system's rows, in the order of ``system.rows``.
    method, eta, grid, max_distance, min_pairs, rcond, refine, level
        As :func:`fit_scattering_image`.
    width : float, optional
        Only recorded in the result (default the system's second level d'_2).

    Returns
    -------
    ScatteringImageFit

    Raises
    ------
    ValidationError
        Invalid arguments (e.g. an ``exitance`` that is negative, not finite or not of length
        ``len(system.rows)``), or a ``max_distance`` beyond the farthest pair (or given with ``method="exitance"``).
    FitError
        No row with l > 0 (except for ``method="pinv"``), fewer than 3 levels left after merging (for
        ``"exitance"`` R' is then NaN instead), fewer than 3 rows with l > 0 for the exitance fit, or an automatic
        fit range (``max_distance="auto"``, ``"monotone"``) of fewer than 3 levels with R' > 0.  The light is not
        checked here (no patch positions: :func:`fit_scattering_image` checks it).

    Warns
    -----
    QuantisationWarning
        Levels merged, rank deficit, ill-conditioning or rows left out (also listed in ``notes``).
    """
    check_choice(method, "method", METHODS)
    check_integer(min_pairs, "min_pairs", 1)
    l = check_shape(as_finite(exitance, "exitance", 0, None, dtype=np.float64), "exitance", (system.rows.size,))
    if method == "exitance":
        system, pf, r, cond, n_rows, notes = _exitance_fit(
            system,
            l,
            max_distance=max_distance,
            min_pairs=min_pairs,
            rcond=rcond,
            grid=grid,
            eta=eta,
            refine=refine,
            level=level,
        )
        deficient = False  # the estimate fits 2 parameters through W whatever its rank
    else:
        notes = []
        system, neq, cond, r, n_rows, deficient = _solved_profile(system, l, method, min_pairs, rcond, notes, 3)
        pf = fit_profile_grid(
            system.levels,
            r,
            grid=TABLE2_GRID if grid is None else grid,
            eta=eta,
            max_distance=_fit_range(system, neq, l, r, method, max_distance),
            refine=refine,
            level=level,
        )
    if pf.n_nonpositive:
        notes.append(f"{pf.n_nonpositive} level(s) within the fit range with R' ≤ 0 left out of eq. 36 (log undefined)")
    if pf.at_grid_edge:
        notes.append(_grid_edge_note(pf))
    return ScatteringImageFit(
        sigma_s_prime=pf.sigma_s_prime,
        sigma_a=pf.sigma_a,
        sigma_s_prime_interval=pf.sigma_s_prime_interval,
        sigma_a_interval=pf.sigma_a_interval,
        sigma_tr_interval=pf.sigma_tr_interval,
        interval_level=pf.interval_level,
        levels=system.levels,
        profile=r,
        support=system.support,
        width=float(width) if width is not None else float(system.levels[1]),
        method=method,
        rank=cond.rank,
        n_levels=system.n_levels,
        condition=cond.condition,
        merged_levels=system.merged,
        max_distance=pf.max_distance,
        n_rows=n_rows,
        eta=pf.eta,
        profile_fit=pf,
        rank_deficient=deficient,
        notes=notes,
        self_term=system.self_term,
    )


def fit_scattering_image(
    points,
    areas,
    irradiance,
    radiance,
    *,
    width,
    visible=None,
    eta=1.3,
    grid: ProfileGrid | None = None,
    method="monotone",
    max_distance="auto",
    min_pairs=30,
    rcond=DEFAULT_RCOND,
    refine=False,
    level=0.95,
    self_term="point",
    block_bytes=DEFAULT_BLOCK_BYTES,
    progress=False,
) -> ScatteringImageFit:
    """Dipole (σ's, σa) of a homogeneous translucent object from one image (module docstring).

    Suzuki, Mukaigawa & Yagi eq. 15-36: l ≈ W r (eq. 34), r from the visible rows,
    then eq. 36 on a grid.

    Parameters
    ----------
    points : array_like, shape (m, 3)
        Patch centres, mm.
    areas : array_like, shape (m,)
        Patch areas, mm² (> 0); they multiply c_k because R is in mm⁻² (see
        :mod:`facestats.model.fitting.quantised`).
    irradiance : array_like, shape (m,)
        c_k of eq. 16 (light entering each patch per unit area, ≥ 0; e.g. W mm⁻²).
    radiance : array_like, shape (m,)
        l_j = π L_o / F_t,o of eq. 15 (≥ 0, same unit as ``irradiance``); only
        visible entries are used.
    width : float or "auto"
        Quantisation width in mm (> 0), or ``"auto"``.
    visible : array_like of bool, shape (m,), optional
        Patches the camera sees (rows of eq. 35); default all.
    eta : float
        Relative index of refraction of the dipole (Suzuki: 1.3).
    grid : ProfileGrid, optional
        Models searched by eq. 36; default Suzuki Table 2.
    method : {"monotone", "pinv", "exitance"}
        Constrained relative-residual solve (default), the paper's pseudo-inverse, or the dipole fitted to the
        exitance through W (module docstring, step 5; best with ``self_term="surface"``).
    max_distance : "auto", float or None
        Largest level distance in the fit (mm); ``None``: all levels (the paper);
        ``"auto"``: the rule of the module docstring for ``"monotone"``, all
        levels for ``"pinv"`` (the paper's method unchanged).
    min_pairs : int
        Levels with fewer (hat-weighted) supporting pairs are merged.
    rcond : float
        Relative singular-value threshold of the numerical rank.
    refine : bool
        Refine the best grid model by continuous least squares.
    level : float
        Confidence level of the interval.
    self_term : {"point", "footprint", "surface"}
        A patch's own light: the paper's R(0) c_j A_j (eq. 17, default) or the integral of R over the disk of
        its area, as a continuous surface gives it; ``"surface"`` takes the near neighbours over their disks
        too (module docstring, step 2).
    block_bytes : int
        Memory budget of a row block of W.
    progress : bool
        Progress bar while W is built.

    Returns
    -------
    ScatteringImageFit

    Raises
    ------
    FitError
        As :func:`fit_scattering_system`; and before W is built, for ``method`` "monotone" or "pinv", light that
        is nearly uniform where the camera sees (module docstring, step 0; the message gives the lit patches and
        what to do).  With ``width="auto"`` a width whose fit fails moves on to the next candidate (the width kept
        notes it); the error is raised when none is left.
    """
    p, a, c, l, vis = _check_inputs(points, areas, irradiance, radiance, visible)
    rows = np.nonzero(vis)[0]
    options = dict(
        method=method,
        eta=eta,
        grid=grid,
        max_distance=max_distance,
        min_pairs=min_pairs,
        rcond=rcond,
        refine=refine,
        level=level,
    )
    check_choice(method, "method", METHODS)
    uneven = _even_light(p, c, rows, method)
    own = self_term_keywords(self_term, a)
    fits = _fit_over_widths(p, c * a, rows, [l[rows]], width, options, block_bytes, progress, own)
    return _with_light_note(fits, uneven)[0]


def fit_scattering_channels(points, areas, irradiance, radiance, *, width, visible=None, **options) -> list:
    """:func:`fit_scattering_image` for each channel of (m, C) radiance, building W once per distinct irradiance.

    ``irradiance`` is (m,) (one light colour for all channels) or (m, C); channels
    whose irradiance columns are equal share one W (a white light: one build for
    R, G and B).  Other parameters (``self_term`` too) as :func:`fit_scattering_image`.

    Parameters
    ----------
    points, areas
        As :func:`fit_scattering_image`.
    irradiance : array_like, shape (m,) or (m, C)
        c_k of eq. 16, ≥ 0, for all channels or per channel.
    radiance : array_like, shape (m, C)
        l_j of eq. 15 per channel, ≥ 0.
    width, visible
        As :func:`fit_scattering_image`.
    **options
        The other keywords of :func:`fit_scattering_image` (``self_term``, ``block_bytes``, ``progress`` too).

    Returns
    -------
    list of ScatteringImageFit
        One per channel.

    Raises
    ------
    FitError
        As :func:`fit_scattering_image` (the light is checked per distinct irradiance column).
    """
    lv = as_finite(radiance, "radiance", 0, None, dtype=np.float64)
    if lv.ndim != 2:
        raise ValidationError(f"radiance must have shape (m, C), got {lv.shape}")
    cv = as_finite(irradiance, "irradiance", 0, None, dtype=np.float64)
    cv = np.repeat(cv[:, None], lv.shape[1], axis=1) if cv.ndim == 1 else cv
    if cv.shape != lv.shape:
        raise ValidationError(f"irradiance must have shape ({lv.shape[0]},) or {lv.shape}, got {cv.shape}")
    block_bytes = options.pop("block_bytes", DEFAULT_BLOCK_BYTES)
    progress = options.pop("progress", False)
    self_term = check_choice(options.pop("self_term", "point"), "self_term", SELF_TERMS)
    method = check_choice(options.get("method", "monotone"), "method", METHODS)
    out = [None] * lv.shape[1]
    for ch in range(lv.shape[1]):  # loop over channels; equal irradiance columns share one group
        if out[ch] is not None:
            continue
        group = [k for k in range(lv.shape[1]) if out[k] is None and np.array_equal(cv[:, k], cv[:, ch])]
        p, a, c, _, vis = _check_inputs(points, areas, cv[:, ch], lv[:, ch], visible)
        rows = np.nonzero(vis)[0]
        uneven = _even_light(p, c, rows, method)
        own = self_term_keywords(self_term, a)
        fits = _fit_over_widths(
            p, c * a, rows, [lv[rows, k] for k in group], width, options, block_bytes, progress, own
        )
        fits = _with_light_note(fits, uneven)
        for k, fit in zip(group, fits):
            out[k] = fit
    return out


def _even_light(points, irradiance, rows, method):
    """The check of :mod:`facestats.model.fitting.even_light` before W is built.

    Returns None when enough visible patches are not evenly lit; else raises :class:`FitError` for eq. 36
    (``method`` "monotone" or "pinv"), whose estimate is then biased beyond its interval, and returns the note for
    ``"exitance"``, which fits the dipole through W from the surface's rim and shape alone.
    """
    even = evenly_lit_rows(points, irradiance, rows)
    n = int(rows.size - even.sum())
    if n >= min(UNEVEN_ROWS, rows.size):  # a scene of fewer visible patches: every one of them
        return None
    lit = irradiance[irradiance > 0]
    rule = (
        f"at least {UNEVEN_ROWS} must not be"
        if rows.size >= UNEVEN_ROWS
        else f"every one of them must not be, fewer than {UNEVEN_ROWS} being seen"
    )
    found = (
        f"the light is nearly uniform where the camera sees: {rows.size - n} of {rows.size} visible patches are lit "
        f"within {EVEN_CONTRAST:g}:1 over their {EVEN_NEIGHBOURS} nearest patches ({rule}: near a shadow edge or in "
        f"the dark); {lit.size} of {irradiance.size} patches are lit, at {lit.min():.4g} to {lit.max():.4g}"
    )
    remedy = "light the object so that a shadow edge, a spot or a stripe falls where the camera sees it"
    if method == "exitance":
        return (
            f"{found}: only where the surface ends (its rim, its shape) varies the exitance, and the dipole's "
            f"half-space does not model a real object there; {remedy}"
        )
    raise FitError(
        f"{found}. Suzuki's solve (eq. 35-36) learns R' level by level from where the light changes; under nearly "
        "uniform light only the surface's rim and shape vary the exitance, the near levels are not determined, and "
        f"eq. 36 is biased beyond its interval. {remedy[0].upper()}{remedy[1:]}; or use method='exitance' "
        "(--method exitance on the command line), which fits the dipole through W without R', though under this "
        "light only from the surface's rim, where a real object departs from the dipole's half-space"
    )


def _with_light_note(fits, note):
    """``fits`` with the ``note`` of :func:`_even_light` appended to each and warned about once."""
    if note is not None:
        for fit in fits:
            fit.notes.append(note)
        warnings.warn(note, QuantisationWarning, stacklevel=3)
    return fits


def _try_width(system, exitance, w, options, candidates, skipped, auto):
    """One image at one width: the fit, or None when ``width="auto"`` should try the next candidate."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", QuantisationWarning)
        error = None
        try:
            fit = fit_scattering_system(system, exitance, width=w, **options)
        except FitError as exc:
            error = exc
    if error is not None:  # what was found about the system is still reported, then the error propagates
        for x in caught:
            warnings.warn(x.message, x.category, stacklevel=_USER)
        raise error
    if auto and fit.rank_deficient and w != candidates[-1]:
        skipped.append((f"{w:.4g} mm (rank {fit.rank} of {fit.n_levels}, condition {fit.condition:.3g})", True))
        return None  # a rank deficit moves on to the next candidate
    if auto:
        fit.notes.insert(0, f"width='auto' chose {w:.4g} mm (candidates {np.round(candidates, 4).tolist()})")
        if skipped:
            note = f"width='auto' skipped finer widths: {'; '.join(text for text, _ in skipped)}"
            fit.notes.insert(1, note)
            fit.rank_deficient = fit.rank_deficient or any(rank for _, rank in skipped)
            warnings.warn(note, QuantisationWarning, stacklevel=_USER)
    for x in caught:
        warnings.warn(x.message, x.category, stacklevel=_USER)
    return fit


def quantisation_error(system: QuantisedSystem, points, weights, fit, *, rows=QUANTISATION_ROWS, seed=0) -> float:
    """RMS over visible rows of l_q / l_e − 1 for the fitted dipole (module docstring, step 6).

    l_q = W R(d') is the exitance the quantised model gives the fitted dipole
    (Suzuki et al. eq. 34, R at the levels d'), l_e = Σ_k R(d_jk) c_k A_k its
    exitance with every pair at its own distance (eq. 17; a patch's own light
    as W took it: over the disk of its area when the system holds ``areas``,
    :func:`facestats.model.dipole.dipole_radial_energy`); both with the fit's
    (σ's, σa, η) in the dipole of eq. 3-13.  Rows where l_e = 0 are left out.

    Parameters
    ----------
    system : QuantisedSystem
        W as built for the fit (before merging: the levels of the width).
    points, weights : ndarray
        Patch centres (m, 3), mm, and c_k A_k (m,), as W was built from.
    fit : ScatteringImageFit
    rows : int
        At most this many visible rows, sampled with ``seed``.
    seed : int
        Seeds the choice of rows.

    Returns
    -------
    float
        Dimensionless; NaN if no sampled row receives light.
    """
    from facestats.model.dipole import dipole_profile_unchecked, dipole_radial_energy_unchecked

    n = system.rows.size
    pick = np.arange(n) if n <= rows else np.sort(np.random.default_rng(seed).choice(n, rows, replace=False))

    def profile(d):
        return dipole_profile_unchecked(d, fit.sigma_s_prime, fit.sigma_a, fit.eta)

    l_q = system.matrix[pick] @ profile(system.levels)

    def energy(rho):
        return dipole_radial_energy_unchecked(rho, fit.sigma_s_prime, fit.sigma_a, fit.eta)

    own = {} if system.areas is None else {"areas": system.areas, "energy": energy, "near": system.near}
    l_e = point_kernel_exitance(points, weights, system.rows[pick], profile, **own)
    ok = l_e > 0
    return float(np.sqrt(np.mean((l_q[ok] / l_e[ok] - 1) ** 2))) if ok.any() else float("nan")


def _checked_quantisation(system, points, weights, fit) -> None:
    """Record :func:`quantisation_error` in ``fit``; note and warn about it above :data:`QUANTISATION_WARNING`."""
    err = quantisation_error(system, points, weights, fit)
    fit.quantisation_error = err
    if err > QUANTISATION_WARNING:
        note = (
            f"at width {fit.width:.4g} mm the levels misrepresent the fitted dipole by {100 * err:.3g} % (RMS of the "
            f"quantised against the point-kernel exitance, eq. 34 vs 17; above {100 * QUANTISATION_WARNING:g} %): "
            f"R falls steeply within 1/sigma_t' = {1 / (fit.sigma_s_prime + fit.sigma_a):.3g} mm, and the estimate "
            "can be biased beyond its interval; use a finer width or width='auto'"
        )
        fit.notes.append(note)
        warnings.warn(note, QuantisationWarning, stacklevel=_USER)


def _fit_over_widths(p, weights, rows, exitances, width, options, block_bytes, progress, own) -> list:
    """Fit each exitance vector (rows) with W built at the width, or at the ``"auto"`` candidates in turn
    (``own``: the self term's keywords of :func:`quantised_system`, from ``self_term_keywords``); with
    ``method="exitance"`` and ``width="auto"``, then narrow the width (:func:`_narrowed`).  Warnings are those of
    the width each image keeps, in the images' order."""
    auto = isinstance(width, str)
    if not (auto and options.get("method") == "exitance"):
        return _fit_candidates(p, weights, rows, exitances, width, options, block_bytes, progress, own)
    sinks = [[] for _ in exitances]  # each image's warnings at its candidate width
    kept = []
    try:
        first = _fit_candidates(p, weights, rows, exitances, width, options, block_bytes, progress, own, sinks)
        for i, (fit, l) in enumerate(zip(first, exitances)):  # the images (channels), each narrowed on its own
            narrowed, caught = _narrowed(fit, p, weights, rows, l, options, block_bytes, progress, own)
            if narrowed is not fit:
                sinks[i] = caught
            kept.append(narrowed)
    finally:  # also when a later image fails: what was found about the earlier ones is reported
        for sink in sinks:
            for x in sink:
                warnings.warn(x.message, x.category, stacklevel=3)
    return kept


def _fit_candidates(p, weights, rows, exitances, width, options, block_bytes, progress, own, sinks=None) -> list:
    """Each exitance vector fitted at the width, or at the first ``"auto"`` candidate that suits it; with ``sinks``
    (one list per image) each image's warnings are recorded there instead of being issued."""
    auto = isinstance(width, str)
    if auto:
        check_choice(width, "width", ("auto",))
        candidates = auto_width(p, weights, rows, min_pairs=options.get("min_pairs", 30))
    else:
        candidates = [as_scalar(width, "width", 0, None, low_inclusive=False, unit="mm")]
    n = len(exitances)
    results, skipped, errors = [None] * n, [[] for _ in range(n)], [None] * n
    for w in candidates:  # loop over candidate widths (one unless width="auto" meets a rank deficit)
        pending = [i for i in range(n) if results[i] is None]
        if not pending:
            break
        system = quantised_system(p, weights, rows, width=w, block_bytes=block_bytes, progress=progress, **own)
        for i in pending:  # the images sharing this W
            sink = None if sinks is None else sinks[i]
            results[i], errors[i] = _one_image(
                system, p, weights, exitances[i], w, options, candidates, skipped[i], auto, sink
            )
            if errors[i] is not None:  # a failed width is reported by the width the image keeps, if any
                skipped[i].append((f"{w:.4g} mm (failed: {errors[i]})", False))
    for fit, error in zip(results, errors):
        if fit is None:
            if not auto:
                raise error
            raise FitError(f"no candidate width gave a solvable system; the last said: {error}")
    return results


def _one_image(system, p, weights, exitance, w, options, candidates, skipped, auto, sink):
    """One image at one candidate width: (fit or None, FitError or None), its quantisation checked; its warnings
    recorded into ``sink`` when given (a list), else issued."""
    with warnings.catch_warnings(record=True) if sink is not None else contextlib.nullcontext() as caught:
        if sink is not None:
            warnings.simplefilter("always")
        try:
            fit = _try_width(system, exitance, w, options, candidates, skipped, auto)
            if fit is not None:
                _checked_quantisation(system, p, weights, fit)
            return fit, None
        except FitError as exc:
            return None, exc
        finally:
            if sink is not None:
                sink.extend(caught)


def _finest_width(p, weights, rows, own, width) -> float:
    """The finest width whose W fits :data:`EXITANCE_W_BYTES` and MAX_LEVELS (from the levels at ``width``)."""
    farthest = (planned_levels(p, weights, rows, width=width, **own) - 1) * width  # ≥ the distance W must span
    most = min(MAX_LEVELS, EXITANCE_W_BYTES // (8 * max(rows.size, 1)))
    return farthest / max(most - 2, 1)


def _narrowed(fit, p, weights, rows, exitance, options, block_bytes, progress, own):
    """``method="exitance"``, ``width="auto"``: narrow the width while the levels misrepresent the fitted dipole
    by more than :data:`EXITANCE_QUANTISATION` (module docstring, step 5).

    Returns the fit kept and the warnings of its fit (none when it is ``fit``, whose warnings the caller holds).
    """
    first, caught = fit, []
    for _ in range(EXITANCE_ROUNDS):  # a few rounds: the error falls about as the width squared
        err = fit.quantisation_error
        if not err > EXITANCE_QUANTISATION:
            if not np.isfinite(err):
                fit.notes.append("width='auto' kept the width: the quantisation error could not be measured")
            break
        w = max(fit.width * 0.9 * np.sqrt(EXITANCE_QUANTISATION / err), _finest_width(p, weights, rows, own, fit.width))
        if not w < 0.95 * fit.width:
            fit.notes.append(
                f"width='auto' kept {fit.width:.4g} mm (quantisation error {100 * err:.3g} %): a finer W would exceed "
                f"MAX_LEVELS or {EXITANCE_W_BYTES} bytes"
            )
            break
        system = quantised_system(p, weights, rows, width=w, block_bytes=block_bytes, progress=progress, **own)
        with warnings.catch_warnings(record=True) as record:
            warnings.simplefilter("always")
            fit = fit_scattering_system(system, exitance, width=w, **options)
            _checked_quantisation(system, p, weights, fit)
        caught = record
    if fit is not first:
        carried = [note for note in first.notes if note.startswith("width='auto'")]  # the candidates, skips
        fit.notes[:0] = carried + [
            f"width='auto' chose {first.width:.4g} mm, then narrowed it to {fit.width:.4g} mm for method='exitance' "
            f"(quantisation error {100 * first.quantisation_error:.3g} % -> {100 * fit.quantisation_error:.3g} %, "
            f"target {100 * EXITANCE_QUANTISATION:g} %)"
        ]
        fit.rank_deficient = first.rank_deficient
    return fit, caught
