"""The log-space dipole fit of Suzuki, Mukaigawa & Yagi §3.4 (eq. 36) on a grid of (σ's, σa), with its interval.

Given a measured profile R'_i at distances d'_i (mm, mm⁻²), the fit is

    argmin_{σ's, σa}  Σ_i ( ln R'_i − ln R(d'_i; σ's, σa, η) )²          (eq. 36)

over the levels with R'_i > 0 (the logarithm is undefined elsewhere; the
count left out is recorded) and d'_i ≤ ``max_distance``.  R is
:func:`facestats.model.dipole.dipole_profile` — Suzuki eq. 3-13 is the same
model, and Suzuki's σs is the reduced σ's because g = 0 (eq. 13).  The search is
exhaustive over a grid, by default Suzuki Table 2 (σ's 0.01-3.00 step 0.01,
σa 0.0001-0.0030 step 0.0001 mm⁻¹, η = 1.3: 9,000 models), vectorised over all
models: with M the (models × levels) matrix of ln R, the costs are
Σ M² − 2 M y + y·y for y = ln R'.  A model whose R underflows to 0 at a fitted
level (ln R = −∞ where ln R' is finite: large σ's and σa far out, e.g. the skin
grid's corner σ's 20, σa 5 mm⁻¹ at 39 mm) costs +∞, where the expansion would
give ∞ − ∞ = NaN; if every model of the grid does, the fit raises
:class:`~facestats.errors.FitError`.  An optional refinement continues from the
best grid model with a bounded least-squares solve in (ln σ's, ln σa)
(:func:`scipy.optimize.least_squares`); its optimum is kept only if its cost,
evaluated as the grid's is, does not exceed the best grid model's (a
safeguard: the exitance fit's solve minimises the cost through an
eigen-decomposition, below, whose rounding is not the cost's), so the reported
σ's, σa and cost are always those of one model.

Interval (profile likelihood over the grid): treating the log residuals as
independent with a common variance estimated from the best fit,
s² = cost_min / (n − 2), the statistic Δ(σ's, σa) = (cost − cost_min)/s² is
compared with the χ² quantile of 2 degrees of freedom at ``level``,
−2 ln(1 − level) (5.99 at 95 %); the region is grown by one grid step in every
direction, because the continuous optimum of a grid model can lie up to a step
away (with little noise the statistical region holds a single model, and the
grid's resolution is the honest uncertainty); the
interval of each parameter is the range of grid values inside that joint
region (the projection of the joint region, so each interval is at least as
wide as a one-parameter profile interval).  The grid bounds the interval: an
interval that touches a grid edge is marked ``at_grid_edge``.  With the
refinement, the grid models bracketing the refined optimum join the region
before it is grown: the cost has a narrow diagonal valley, and its continuous
optimum can lie several grid steps from the best grid model, outside that
model's region (noise-free pyramid scenes on the skin grid: the refined
estimate fell outside its interval for 8 of 25 media, e.g. σ's 2.192 against
[2.008, 2.165]); so the interval always holds the estimate.

Fit to the exitance (:func:`fit_exitance_grid`, beyond the paper).  Eq. 36
fits the levels' R', which a scene must identify level by level; where it
cannot (levels below the patch spacing, merged for want of support), R is
interpolated linearly across them, which misrepresents the steep R of the
first mean free path wherever W integrates a patch over its area (the
``"footprint"`` and ``"surface"`` self terms of
:mod:`facestats.model.fitting.quantised`).  Instead, the dipole can be put into
eq. 34 directly, l ≈ W R(d'; σ's, σa), and fitted to the image by relative
residuals,

    argmin_{σ's, σa}  Σ_j ( W_j R(d') / l_j − 1 )²  =  Rᵀ G R − 2 gᵀ R + n

with G = AᵀA, g = Aᵀ1, A = diag(1/l) W over the n rows with l_j > 0 (the
normal equations of the monotone solve): no level needs identifying, so W is
used at its width, unmerged, and each model costs one n_levels² quadratic
form.  The interval follows the rule above with the rows as residuals
(s² = cost_min / (n − 2)).  Measured on a flat plate of 41 × 41
patches of 1 mm (exitance by a quadrature of the surface with 1/8 mm
sub-patches, :func:`facestats.acquire.synthetic.subsurface.half_lit_plate`;
Suzuki Table 1's medium, σ's 2.19, σa 0.0021 mm⁻¹) at width 0.1 mm: eq. 36
gives 1.92 / 0.003 (point self term), 2.03 / 0.0026 (footprint), 1.89 / 0.003
(surface); the exitance fit 1.82 / 0.003, 2.29 / 0.0019 and 2.19 / 0.0021:
with the surface self term it is unbiased, with the others it is not.

The exitance fit's refinement needs the cost as a residual vector.  With
D = diag(G)^½ and (Λ, V) the eigenpairs of the equilibrated D⁻¹ G D⁻¹ with
λ > 10⁻¹³ λmax, ‖Λ^½ Vᵀ D R − Λ^-½ Vᵀ D⁻¹ g‖² is the cost less the constant
n − gᵀ G⁺ g (g = Aᵀ1 lies in the range of G), so the least-squares solve
minimises the cost itself.  The equilibration matters: the 1/l² weights of
the rows far from the light make G's diagonal span 10-59 decades in the fits
measured below, and in the eigenpairs of G itself, used before 2026-12-07,
the levels near the light fall under the cut or within the solver's rounding
(ε λmax): the residual lost them.  Measured over 32 exitance fits of
synthetic scenes (surface self term, 0-3 % noise: plates of six media, the
pyramid at two widths, four contactless windows in R, G and B;
``bench_translucency_image.bench_exitance_refinement``): the refined optimum
lies within 1.4·10⁻⁷ in ln σ's and ln σa of a Nelder-Mead polish of the cost,
its cost at most 7·10⁻⁹ (relative) above the polish's.  Without the
equilibration 14 of the 32 missed the minimum by more than 10⁻⁶ of the cost;
after the rule above, which then kept the grid model or a poor optimum, the
cost was up to 1,492 times the minimum and σ's up to 10 % off the truth
(1.7 % at the minimum).  L-BFGS-B on the cost itself (no residual needed)
missed 2: its first line search, a unit step in ln σ, meets costs tens of
orders of magnitude higher and stalls at the grid model.  The solve costs an
eigen-decomposition of G, O(n_levels³), as before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.core.validate import as_finite, as_scalar, check_integer, check_shape
from facestats.errors import FitError, ValidationError
from facestats.model.dipole import check_dipole_eta, dipole_profile_unchecked
from facestats.model.fitting.quantised import equilibrate

__all__ = [
    "ProfileGrid",
    "TABLE2_GRID",
    "LOG_GRID_SIGMA_S_PRIME",
    "LOG_GRID_SIGMA_A",
    "ProfileFit",
    "profile_cost",
    "fit_profile_grid",
    "exitance_cost",
    "fit_exitance_grid",
]

#: Default ranges of :meth:`ProfileGrid.log_spaced`, mm⁻¹ (σ's, σa): skin-like media and far beyond (the command
#: line's ``--grid skin``).
LOG_GRID_SIGMA_S_PRIME = (0.05, 20.0)
LOG_GRID_SIGMA_A = (1e-3, 5.0)
#: Models evaluated per chunk of the grid search; the dipole's temporaries take about 8 × chunk × levels doubles.
_CHUNK_MODELS = 4096
#: The exitance fit's chunks hold at most this many model × level values (16 MB a temporary, ~130 MB in all).
_CHUNK_VALUES = 2**21


@dataclass(frozen=True)
class ProfileGrid:
    """Grid of reduced scattering and absorption coefficients (mm⁻¹) searched by eq. 36.

    Use :meth:`table2` for Suzuki Table 2 and :meth:`log_spaced` for media far
    from it (skin: σ's ≈ 0.5-3, σa ≈ 0.01-1 mm⁻¹).

    Attributes
    ----------
    sigma_s_prime : ndarray of float64, shape (n_s,)
        Reduced scattering coefficients σ's in mm⁻¹: finite, > 0, strictly increasing, at least 2.
    sigma_a : ndarray of float64, shape (n_a,)
        Absorption coefficients σa in mm⁻¹, likewise.

    Raises
    ------
    ValidationError
        A coefficient array that is not 1-D, not finite and > 0, or not at least 2 strictly increasing values.
    """

    sigma_s_prime: np.ndarray
    sigma_a: np.ndarray

    def __post_init__(self):
        for name in ("sigma_s_prime", "sigma_a"):
            v = check_shape(as_finite(getattr(self, name), name, 0, None, low_inclusive=False), name, (None,))
            if v.size < 2:
                raise ValidationError(f"{name} of a grid must hold at least 2 increasing values, got {v.size}")
            down = np.flatnonzero(np.diff(v) <= 0)
            if down.size:  # name the first pair out of order, not every value of a long grid
                i = int(down[0])
                raise ValidationError(
                    f"{name} of a grid must hold strictly increasing values, got {name}[{i}] = {float(v[i])!r} "
                    f"then {name}[{i + 1}] = {float(v[i + 1])!r}"
                )
            object.__setattr__(self, name, v.astype(np.float64))

    @property
    def shape(self):
        return (self.sigma_s_prime.size, self.sigma_a.size)

    @classmethod
    def table2(cls) -> "ProfileGrid":
        """Suzuki Table 2: σ's 0.01-3.00 step 0.01, σa 0.0001-0.0030 step 0.0001 mm⁻¹ (300 × 30 = 9,000 models)."""
        return cls(np.round(np.arange(1, 301) * 0.01, 2), np.round(np.arange(1, 31) * 1e-4, 4))

    @classmethod
    def log_spaced(cls, sigma_s_prime=LOG_GRID_SIGMA_S_PRIME, sigma_a=LOG_GRID_SIGMA_A, n=(150, 150)) -> "ProfileGrid":
        """A grid evenly spaced in ln σ's and ln σa over the given ranges (mm⁻¹), ``n`` values each.

        Parameters
        ----------
        sigma_s_prime : tuple of float
            (low, high) σ's in mm⁻¹, both ends included.
        sigma_a : tuple of float
            (low, high) σa in mm⁻¹, both ends included.
        n : tuple of int
            Number of σ's and of σa values.

        Returns
        -------
        ProfileGrid

        Raises
        ------
        ValidationError
            A range that is not a (low, high) pair of finite numbers with 0 < low < high, or ``n`` not a pair of
            integers ≥ 2.
        """
        counts = _pair(n, "n")
        return cls(
            np.geomspace(*_log_range(sigma_s_prime, "sigma_s_prime"), check_integer(counts[0], "n[0]", 2)),
            np.geomspace(*_log_range(sigma_a, "sigma_a"), check_integer(counts[1], "n[1]", 2)),
        )


def _pair(value, name):
    """``value`` as a tuple of two items, else ValidationError naming ``name``."""
    try:
        first, second = value
    except (TypeError, ValueError):  # not iterable, or not two items
        raise ValidationError(f"{name} must be a pair of values, got {value!r}") from None
    return first, second


def _log_range(value, name):
    """A (low, high) range of :meth:`ProfileGrid.log_spaced`: two finite numbers with 0 < low < high."""
    low, high = _pair(value, name)
    low = as_scalar(low, f"{name} low", 0, None, low_inclusive=False, unit="mm⁻¹")
    high = as_scalar(high, f"{name} high", 0, None, low_inclusive=False, unit="mm⁻¹")
    if high <= low:
        raise ValidationError(f"{name} must be a (low, high) range with low < high, got {value!r}")
    return low, high


#: Suzuki Table 2.
TABLE2_GRID = ProfileGrid.table2()


def _models(grid, distances, eta, rows):
    """R(d'_i) (models of the grid's flat indices ``rows``, levels), mm⁻²."""
    si, ai = np.unravel_index(rows, grid.shape)
    return dipole_profile_unchecked(distances[None, :], grid.sigma_s_prime[si][:, None], grid.sigma_a[ai][:, None], eta)


def _log_models(grid, distances, eta, rows):
    """ln R(d'_i) (models of the grid's flat indices ``rows``, levels), mm⁻²."""
    with np.errstate(divide="ignore"):
        return np.log(_models(grid, distances, eta, rows))


def profile_cost(distances, log_profile, grid: ProfileGrid, eta) -> np.ndarray:
    """Eq. 36 for every model of the grid: Σ_i (ln R'_i − ln R(d'_i))², shape ``grid.shape``.

    Parameters
    ----------
    distances : ndarray, shape (k,)
        The levels d'_i that enter the fit, mm.
    log_profile : ndarray, shape (k,)
        ln R'_i at those levels (R' in mm⁻²).
    grid : ProfileGrid
    eta : float
        Relative index of refraction.

    Returns
    -------
    ndarray, shape ``grid.shape``
        The cost of each model of the grid, ≥ 0.

    Notes
    -----
    Models whose R underflows to 0 at one of the levels cost ``inf`` (module docstring).
    """
    d = np.asarray(distances, np.float64)
    y = np.asarray(log_profile, np.float64)
    total = int(np.prod(grid.shape))
    cost = np.empty(total)
    yy = float(y @ y)
    for start in range(0, total, _CHUNK_MODELS):  # loop over chunks of models, vectorised within
        rows = np.arange(start, min(start + _CHUNK_MODELS, total))
        m = _log_models(grid, d, eta, rows)
        finite = np.isfinite(m).all(axis=1)  # R underflowed to 0 at some level: ln R' − ln R = +∞ (docstring)
        m[~finite] = 0.0
        cost[rows] = np.where(finite, np.einsum("ij,ij->i", m, m) - 2 * (m @ y) + yy, np.inf)
    return np.maximum(cost, 0).reshape(grid.shape)


@dataclass
class ProfileFit:
    """Result of the eq. 36 fit (:func:`fit_profile_grid`; also of the exitance fit, :func:`fit_exitance_grid`).

    Attributes
    ----------
    sigma_s_prime, sigma_a : float
        σ's and σa in mm⁻¹: the refined values when refinement ran and did not raise the cost, else the best grid
        model.
    grid_sigma_s_prime, grid_sigma_a : float
        The best grid model, mm⁻¹ (kept when refinement ran).
    cost : float
        Eq. 36 at ``sigma_s_prime``, ``sigma_a`` (the exitance fit: its sum of squared relative residuals).
    cost_surface : ndarray, shape ``grid.shape``
        The cost over the grid.
    sigma_s_prime_interval, sigma_a_interval, sigma_tr_interval : tuple of float
        (low, high) in mm⁻¹ at ``interval_level`` (σtr over the grid models inside the joint region).
    interval_level : float
        Confidence level of the intervals.
    at_grid_edge : bool
        The joint region touches an edge of the grid (the grid bounds the interval).
    used : ndarray of bool, shape (n,)
        The levels that entered the fit (R' > 0 and d' ≤ ``max_distance``; every level in the exitance fit).
    n_nonpositive : int
        The levels within range left out because R' ≤ 0 (0 in the exitance fit).
    max_distance : float
        Largest level distance within range, mm (the exitance fit: the last level).
    eta : float
        Relative index of refraction of the dipole.
    grid : ProfileGrid
        The grid searched.
    """

    sigma_s_prime: float
    sigma_a: float
    grid_sigma_s_prime: float
    grid_sigma_a: float
    cost: float
    cost_surface: np.ndarray
    sigma_s_prime_interval: tuple
    sigma_a_interval: tuple
    sigma_tr_interval: tuple
    interval_level: float
    at_grid_edge: bool
    used: np.ndarray
    n_nonpositive: int
    max_distance: float
    eta: float
    grid: ProfileGrid

    @property
    def sigma_tr(self) -> float:
        """σtr = sqrt(3 σa (σa + σ's)) (Suzuki eq. 10-11), mm⁻¹."""
        return float(np.sqrt(3 * self.sigma_a * (self.sigma_a + self.sigma_s_prime)))


def _dilate(mask):
    """A boolean grid mask grown by one grid step in each direction (3 × 3 neighbourhood)."""
    from scipy.ndimage import binary_dilation

    return binary_dilation(mask, structure=np.ones((3, 3), bool))


def _bracketing(grid, s, a):
    """Mask of the (up to 2 × 2) grid models around a point (σ's, σa) of the grid's range."""
    i = int(np.clip(np.searchsorted(grid.sigma_s_prime, s), 1, grid.shape[0] - 1))
    j = int(np.clip(np.searchsorted(grid.sigma_a, a), 1, grid.shape[1] - 1))
    mask = np.zeros(grid.shape, bool)
    mask[i - 1 : i + 1, j - 1 : j + 1] = True
    return mask


def _refine(resid, s0, a0, grid):
    """Continuous least squares of ‖resid(σ's, σa)‖² in (ln σ's, ln σa) from the grid model, within the grid's
    range; returns (σ's, σa)."""
    from scipy.optimize import least_squares

    lo = np.log([grid.sigma_s_prime[0], grid.sigma_a[0]])
    hi = np.log([grid.sigma_s_prime[-1], grid.sigma_a[-1]])
    x0 = np.clip(np.log([s0, a0]), lo, hi)
    sol = least_squares(lambda x: resid(*np.exp(x)), x0, bounds=(lo, hi), x_scale=1.0, xtol=1e-12, ftol=1e-14)
    return float(np.exp(sol.x[0])), float(np.exp(sol.x[1]))


def _grid_fit(cost, grid, n_data, refine, level, **fields) -> ProfileFit:
    """The best grid model of a cost surface, its optional refinement and the interval (module docstring).

    ``n_data`` residuals entered the cost; ``refine`` is None or (resid, model_cost): the residuals
    :func:`_refine` minimises and the cost of one model (σ's, σa) as the surface computes it; ``fields`` are the
    rest of :class:`ProfileFit`.
    """
    best = np.unravel_index(int(np.argmin(cost)), cost.shape)
    gs, ga = float(grid.sigma_s_prime[best[0]]), float(grid.sigma_a[best[1]])
    cmin = float(cost[best])
    s, a, c = (gs, ga, cmin)
    if refine is not None:
        resid, model_cost = refine
        rs, ra = _refine(resid, gs, ga, grid)
        rc = model_cost(rs, ra)
        if rc <= model_cost(gs, ga):  # both by one formula; else the grid model stays, with its own cost
            s, a, c = rs, ra, rc
    s2 = max(cmin, 1e-300) / max(n_data - 2, 1)
    inside = (cost - cmin) / s2 <= -2 * np.log1p(-level)  # χ² quantile of 2 degrees of freedom
    if refine is not None:  # the continuous optimum may lie several steps along a valley from the best model
        inside |= _bracketing(grid, s, a)
    inside = _dilate(inside)  # the grid's own resolution: the optimum may lie a step beyond a grid model
    si, ai = np.nonzero(inside)
    ss, aa = grid.sigma_s_prime[si], grid.sigma_a[ai]
    tr = np.sqrt(3 * aa * (aa + ss))
    edge = bool(si.min() == 0 or si.max() == grid.shape[0] - 1 or ai.min() == 0 or ai.max() == grid.shape[1] - 1)
    return ProfileFit(
        sigma_s_prime=s,
        sigma_a=a,
        grid_sigma_s_prime=gs,
        grid_sigma_a=ga,
        cost=c,
        cost_surface=cost,
        sigma_s_prime_interval=(float(ss.min()), float(ss.max())),
        sigma_a_interval=(float(aa.min()), float(aa.max())),
        sigma_tr_interval=(float(tr.min()), float(tr.max())),
        interval_level=level,
        at_grid_edge=edge,
        grid=grid,
        **fields,
    )


def fit_profile_grid(
    levels, profile, *, grid: ProfileGrid | None = None, eta=1.3, max_distance=None, refine=False, level=0.95
) -> ProfileFit:
    """Fit the dipole to a profile by eq. 36 on a grid (module docstring).

    Parameters
    ----------
    levels : array_like, shape (n,)
        Distances d'_i, mm.
    profile : array_like, shape (n,)
        R'_i, mm⁻² (finite; levels with R'_i ≤ 0 are left out).
    grid : ProfileGrid, optional
        Default :data:`TABLE2_GRID` (Suzuki Table 2).
    eta : float
        Relative index of refraction (Suzuki: 1.3).
    max_distance : float, optional
        Only levels with d'_i ≤ max_distance enter the fit (mm); default all.
    refine : bool
        Continue from the best grid model with a continuous least-squares solve.
    level : float
        Confidence level of the interval, in (0, 1).

    Returns
    -------
    ProfileFit
    """
    d = check_shape(as_finite(levels, "levels", 0, None, unit="mm", dtype=np.float64), "levels", (None,))
    r = check_shape(as_finite(profile, "profile", dtype=np.float64), "profile", d.shape)
    eta = float(check_dipole_eta(eta))
    lvl = as_scalar(level, "level", 0, 1, low_inclusive=False, high_inclusive=False)
    grid = TABLE2_GRID if grid is None else grid
    if not isinstance(grid, ProfileGrid):
        raise ValidationError(f"grid must be a ProfileGrid, got {type(grid).__name__}")
    dmax = np.inf if max_distance is None else as_scalar(max_distance, "max_distance", 0, None, unit="mm")
    in_range = d <= dmax
    used = in_range & (r > 0)
    n_used = int(used.sum())
    if n_used < 3:
        raise FitError(
            f"eq. 36 needs at least 3 levels with R' > 0 within max_distance={dmax:g} mm to fit 2 parameters, "
            f"got {n_used} (of {int(in_range.sum())} levels in range, of {d.size}): too few lit patches seen at "
            "distinct distances from the light (check the light's placement and the mesh's unit), or raise "
            "max_distance (--max-distance on the command line)"
        )
    du, y = d[used], np.log(r[used])
    cost = profile_cost(du, y, grid, eta)
    if not np.isfinite(cost.min()):
        (s0, s1), (a0, a1) = (grid.sigma_s_prime[[0, -1]], grid.sigma_a[[0, -1]])
        raise FitError(
            f"eq. 36: every model of the grid (sigma_s' {s0:g}-{s1:g}, sigma_a {a0:g}-{a1:g} 1/mm) has R "
            f"underflowing to 0 at some of the {n_used} levels up to {float(du.max()):g} mm; "
            "fit fewer levels (max_distance; --max-distance on the command line) or use a grid of smaller "
            "coefficients"
        )

    def resid(sp, sa):
        with np.errstate(divide="ignore"):  # R underflowing to 0: ln R = -inf, an infinite cost (module docstring)
            return np.log(dipole_profile_unchecked(du, sp, sa, eta)) - y

    def model_cost(sp, sa):
        r = resid(sp, sa)
        return float(r @ r)

    return _grid_fit(
        cost,
        grid,
        n_used,
        (resid, model_cost) if refine else None,
        lvl,
        used=used,
        n_nonpositive=int((in_range & (r <= 0)).sum()),
        max_distance=float(min(dmax, d[in_range].max())) if in_range.any() else 0.0,
        eta=eta,
    )


def exitance_cost(levels, gram, rhs, n_rows, grid: ProfileGrid, eta) -> np.ndarray:
    """Σ_j (W_j R(d') / l_j − 1)² = Rᵀ G R − 2 gᵀ R + n for every model of the grid, shape ``grid.shape``.

    The exitance fit of the module docstring (Suzuki eq. 34 with the dipole of eq. 3-13 for r), from the
    normal equations of the relative-residual problem.  No input checks (see :func:`fit_exitance_grid`).

    Parameters
    ----------
    levels : array_like, shape (k,)
        The levels d' of W, mm.
    gram, rhs : ndarray, shapes (k, k) and (k,)
        G = AᵀA and g = Aᵀ1 with A = diag(1/l) W (R in mm⁻²).
    n_rows : int
        n, the rows that entered G.
    grid : ProfileGrid
        The (σ's, σa) models, mm⁻¹.
    eta : float
        Relative index of refraction of the dipole.

    Returns
    -------
    ndarray of float64, shape ``grid.shape``
        The dimensionless cost per (σ's, σa), clipped at 0 (rounding of the expanded form).
    """
    d = np.asarray(levels, np.float64)
    total = int(np.prod(grid.shape))
    cost = np.empty(total)
    chunk = max(16, min(_CHUNK_MODELS, _CHUNK_VALUES // max(d.size, 1)))  # the dipole's temporaries: ~8 × chunk × n
    for start in range(0, total, chunk):  # loop over chunks of models, vectorised within
        rows = np.arange(start, min(start + chunk, total))
        cost[rows] = _expanded_cost(_models(grid, d, eta, rows), gram, rhs, n_rows)
    return np.maximum(cost, 0).reshape(grid.shape)


def _expanded_cost(models, gram, rhs, n_rows) -> np.ndarray:
    """Rᵀ G R − 2 gᵀ R + n for each row R of ``models`` (shape (m, k)): :func:`exitance_cost`'s formula, unclipped."""
    return np.einsum("ij,ij->i", models @ gram, models) - 2 * (models @ rhs) + n_rows


def fit_exitance_grid(levels, gram, rhs, n_rows, *, grid: ProfileGrid | None = None, eta=1.3, refine=False, level=0.95):
    """Fit the dipole to an image through eq. 34 on a grid (module docstring: Fit to the exitance).

    Parameters
    ----------
    levels : array_like, shape (n,)
        The levels d' of W, mm.
    gram, rhs : array_like, shape (n, n) and (n,)
        G = AᵀA and g = Aᵀ1 with A = diag(1/l) W over the rows with l > 0
        (:func:`facestats.model.fitting.quantised.normal_equations`, ``weighted=True``).
    n_rows : int
        Rows that entered G (≥ 3).
    grid, eta
        As :func:`fit_profile_grid`.
    refine : bool
        Continue from the best grid model to the continuous minimum of the cost (Suzuki eq. 34 by relative
        residuals) by least squares over the eigenpairs of the equilibrated G (module docstring; within about
        10⁻⁷ of the minimum in ln σ's and ln σa).
    level : float
        Confidence level of the interval, in (0, 1).

    Returns
    -------
    ProfileFit
        ``cost`` is the sum of squared relative residuals; ``used`` marks every level (all enter through W);
        ``max_distance`` is the last level.
    """
    d = check_shape(as_finite(levels, "levels", 0, None, unit="mm", dtype=np.float64), "levels", (None,))
    if d.size < 2 or np.any(np.diff(d) <= 0):
        raise ValidationError(f"levels must increase strictly (Suzuki eq. 24) with at least 2 entries, got {d!r}")
    g = check_shape(as_finite(gram, "gram", dtype=np.float64), "gram", (d.size, d.size))
    if np.any(np.diag(g) < 0):
        raise ValidationError(
            f"gram must be a Gram matrix AᵀA (diagonal ≥ 0), got diagonal minimum {np.diag(g).min()!r}"
        )
    b = check_shape(as_finite(rhs, "rhs", dtype=np.float64), "rhs", (d.size,))
    n = check_integer(n_rows, "n_rows", 0)
    if n < 3:
        raise FitError(f"the exitance fit needs at least 3 rows with l > 0 to fit 2 parameters, got {n}")
    eta = float(check_dipole_eta(eta))
    lvl = as_scalar(level, "level", 0, 1, low_inclusive=False, high_inclusive=False)
    grid = TABLE2_GRID if grid is None else grid
    if not isinstance(grid, ProfileGrid):
        raise ValidationError(f"grid must be a ProfileGrid, got {type(grid).__name__}")
    cost = exitance_cost(d, g, b, n, grid, eta)
    refine_with = None
    if refine:  # ‖Λ^½ Vᵀ D R − Λ^-½ Vᵀ D⁻¹ g‖² = cost − a constant, (Λ, V) of D⁻¹ G D⁻¹ (module docstring)
        scaled, scale = equilibrate(g)  # D = diag(scale); a level no row sees keeps 1 (its G row and g are 0)
        lam, vec = np.linalg.eigh(scaled)
        keep = lam > lam.max() * 1e-13
        root, v = np.sqrt(lam[keep]), vec[:, keep]
        vg = v.T @ (b / scale)

        def resid(sp, sa):
            return root * (v.T @ (scale * dipole_profile_unchecked(d, sp, sa, eta))) - vg / root

        def model_cost(sp, sa):
            m = dipole_profile_unchecked(d, sp, sa, eta)
            return max(float(_expanded_cost(m[None], g, b, n)[0]), 0.0)

        refine_with = (resid, model_cost)
    return _grid_fit(
        cost,
        grid,
        n,
        refine_with,
        lvl,
        used=np.ones(d.size, bool),
        n_nonpositive=0,
        max_distance=float(d[-1]),
        eta=eta,
    )
