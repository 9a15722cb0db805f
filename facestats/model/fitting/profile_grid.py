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
(:func:`scipy.optimize.least_squares`).

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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.core.validate import as_finite, check_shape
from facestats.errors import FitError, ValidationError
from facestats.model.dipole import check_dipole_eta, dipole_profile_unchecked

__all__ = ["ProfileGrid", "TABLE2_GRID", "ProfileFit", "profile_cost", "fit_profile_grid"]

#: Models evaluated per chunk of the grid search (bounds memory to chunk × levels doubles).
_CHUNK_MODELS = 4096


@dataclass(frozen=True)
class ProfileGrid:
    """Grid of reduced scattering and absorption coefficients (mm⁻¹) searched by eq. 36.

    Use :meth:`table2` for Suzuki Table 2 and :meth:`log_spaced` for media far
    from it (skin: σ's ≈ 0.5-3, σa ≈ 0.01-1 mm⁻¹).
    """

    sigma_s_prime: np.ndarray
    sigma_a: np.ndarray

    def __post_init__(self):
        for name in ("sigma_s_prime", "sigma_a"):
            v = check_shape(as_finite(getattr(self, name), name, 0, None, low_inclusive=False), name, (None,))
            if v.size < 2 or np.any(np.diff(v) <= 0):
                raise ValidationError(f"{name} of a grid must hold at least 2 increasing values, got {v!r}")
            object.__setattr__(self, name, v.astype(np.float64))

    @property
    def shape(self):
        return (self.sigma_s_prime.size, self.sigma_a.size)

    @classmethod
    def table2(cls) -> "ProfileGrid":
        """Suzuki Table 2: σ's 0.01-3.00 step 0.01, σa 0.0001-0.0030 step 0.0001 mm⁻¹ (300 × 30 = 9,000 models)."""
        return cls(np.round(np.arange(1, 301) * 0.01, 2), np.round(np.arange(1, 31) * 1e-4, 4))

    @classmethod
    def log_spaced(cls, sigma_s_prime=(0.05, 20.0), sigma_a=(1e-3, 5.0), n=(150, 150)) -> "ProfileGrid":
        """A grid evenly spaced in ln σ's and ln σa over the given ranges (mm⁻¹), ``n`` values each."""
        (s0, s1), (a0, a1) = sigma_s_prime, sigma_a
        return cls(np.geomspace(s0, s1, int(n[0])), np.geomspace(a0, a1, int(n[1])))


#: Suzuki Table 2.
TABLE2_GRID = ProfileGrid.table2()


def _log_models(grid, distances, eta, rows):
    """ln R(d'_i) (models of the grid's flat indices ``rows``, levels), mm⁻²."""
    si, ai = np.unravel_index(rows, grid.shape)
    s = grid.sigma_s_prime[si][:, None]
    a = grid.sigma_a[ai][:, None]
    with np.errstate(divide="ignore"):
        return np.log(dipole_profile_unchecked(distances[None, :], s, a, eta))


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
    """Result of the eq. 36 fit.

    ``sigma_s_prime``, ``sigma_a`` (mm⁻¹): the best grid model, or the refined
    values when refinement ran (``grid_sigma_s_prime``/``grid_sigma_a`` keep the
    grid model); ``cost`` eq. 36 at the result; ``cost_surface`` over the grid;
    ``sigma_s_prime_interval``, ``sigma_a_interval``, ``sigma_tr_interval``:
    (low, high) in mm⁻¹ at ``interval_level`` (σtr over the grid models inside
    the joint region); ``used`` the levels that entered the fit (R' > 0 and
    d' ≤ ``max_distance``); ``n_nonpositive`` the levels within range left out
    because R' ≤ 0.
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


def _refine(d, y, s0, a0, eta, grid):
    """Continuous least squares of eq. 36 in (ln σ's, ln σa) from the grid model, within the grid's range."""
    from scipy.optimize import least_squares

    def resid(x):
        return np.log(dipole_profile_unchecked(d, np.exp(x[0]), np.exp(x[1]), eta)) - y

    lo = np.log([grid.sigma_s_prime[0], grid.sigma_a[0]])
    hi = np.log([grid.sigma_s_prime[-1], grid.sigma_a[-1]])
    x0 = np.clip(np.log([s0, a0]), lo, hi)
    sol = least_squares(resid, x0, bounds=(lo, hi), x_scale=1.0, xtol=1e-12, ftol=1e-14)
    return float(np.exp(sol.x[0])), float(np.exp(sol.x[1])), float(2 * sol.cost)


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
    lvl = float(as_finite(level, "level", 0, 1, low_inclusive=False, high_inclusive=False))
    grid = TABLE2_GRID if grid is None else grid
    if not isinstance(grid, ProfileGrid):
        raise ValidationError(f"grid must be a ProfileGrid, got {type(grid).__name__}")
    dmax = np.inf if max_distance is None else float(as_finite(max_distance, "max_distance", 0, None, unit="mm"))
    in_range = d <= dmax
    used = in_range & (r > 0)
    n_used = int(used.sum())
    if n_used < 3:
        raise FitError(
            f"eq. 36 needs at least 3 levels with R' > 0 within max_distance={dmax:g} mm to fit 2 parameters, "
            f"got {n_used} (of {int(in_range.sum())} levels in range)"
        )
    du, y = d[used], np.log(r[used])
    cost = profile_cost(du, y, grid, eta)
    best = np.unravel_index(int(np.argmin(cost)), cost.shape)
    gs, ga = float(grid.sigma_s_prime[best[0]]), float(grid.sigma_a[best[1]])
    cmin = float(cost[best])
    if not np.isfinite(cmin):
        (s0, s1), (a0, a1) = (grid.sigma_s_prime[[0, -1]], grid.sigma_a[[0, -1]])
        raise FitError(
            f"eq. 36: every model of the grid (sigma_s' {s0:g}-{s1:g}, sigma_a {a0:g}-{a1:g} 1/mm) has R "
            f"underflowing to 0 at some of the {n_used} levels up to {float(du.max()):g} mm; "
            "fit fewer levels (max_distance) or use a grid of smaller coefficients"
        )
    s, a, c = (gs, ga, cmin)
    if refine:
        s, a, c = _refine(du, y, gs, ga, eta, grid)
        c = min(c, cmin)
    s2 = max(cmin, 1e-300) / max(n_used - 2, 1)
    inside = (cost - cmin) / s2 <= -2 * np.log1p(-lvl)  # χ² quantile of 2 degrees of freedom
    if refine:  # the continuous optimum may lie several steps along a valley from the best grid model
        inside |= _bracketing(grid, s, a)
    inside = _dilate(inside)  # the grid's own resolution: the optimum may lie a step beyond a grid model
    si, ai = np.nonzero(inside)
    ss, aa = grid.sigma_s_prime[si], grid.sigma_a[ai]
    tr = np.sqrt(3 * aa * (aa + ss))
    edge = bool(si.min() == 0 or si.max() == grid.shape[0] - 1 or ai.min() == 0 or ai.max() == grid.shape[1] - 1)
    fit = ProfileFit(
        sigma_s_prime=s,
        sigma_a=a,
        grid_sigma_s_prime=gs,
        grid_sigma_a=ga,
        cost=c,
        cost_surface=cost,
        sigma_s_prime_interval=(float(ss.min()), float(ss.max())),
        sigma_a_interval=(float(aa.min()), float(aa.max())),
        sigma_tr_interval=(float(tr.min()), float(tr.max())),
        interval_level=lvl,
        at_grid_edge=edge,
        used=used,
        n_nonpositive=int((in_range & (r <= 0)).sum()),
        max_distance=float(min(dmax, d[in_range].max())) if in_range.any() else 0.0,
        eta=eta,
        grid=grid,
    )
    return fit
