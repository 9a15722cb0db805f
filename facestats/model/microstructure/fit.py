"""Fit a kernel (α, σ) to a neutral/deformed patch pair by normal-histogram total variation (Nagano et al. 2015 eq. 7).

Nagano et al. 2015 §5 "Parameter Fitting": brute force over α ∈ [−2, 1] step
0.01 and σ ∈ [1, 100] µm step 0.5 (301 × 199 = 59,899 combinations) of the
parameters minimising the total variation (eq. 7) between the normal histogram
of the deformed (ground-truth) patch and that of the neutral patch convolved
with the 1-D kernel along the axis of deformation and *resampled to the
deformed shape*; 64 × 64 buckets of tangent-space (n_u, n_v).

How it is computed (same result as convolving every candidate, much faster):

* k = (1 − α) δ + α G(σ) is linear in α: the convolved map is
  ``D + α (G_σ * D − D)`` and its slopes ``g0 + α Δg_σ``; one Gaussian pass per
  σ (199), then all α at once (:func:`facestats.model.microstructure.compiled.histogram_tv`).
* The Gaussian pass is the interior operator of
  :func:`~facestats.model.microstructure.convolve.convolve_displacement`
  (taps at whole texels of the axis's major direction, read across it by
  Lanczos-3: same positions and weights, :mod:`~facestats.model.microstructure.taps`)
  applied as a 2-D stencil by FFT; histograms use the patch interior (a margin
  of the largest kernel radius + 3 texels, + 5 for an axis off the grid, whose
  taps read 3 texels across) where no tap leaves the patch, so border handling
  plays no part.
* "Resampled to the deformed shape" is the chain rule on the slopes: the patch
  deformed by A (stretch r along the axis, r_t across it) has slopes
  ``A⁻ᵀ ∇h`` (:mod:`~facestats.model.microstructure.surface`), exact for a
  uniform deformation and free of the smoothing an interpolating resampler adds.
  Without it, the pure slope change of a stretch would be absorbed into α.
* Coarse-to-fine: the coarse grid (α step 0.1, σ step 5 µm, a subset of the
  fine grid, 651 points) is evaluated first, then the full-resolution grid
  within one coarse step of the N_STARTS = 3 best coarse points (≤ 3 × 21 × 21
  points).  Where the minimum is distinct (e.g. a target made from the same
  patch) it returns the brute-force argmin (tested); on a flat ridge it returns a
  point of the ridge, not necessarily the brute-force argmin, which is itself
  arbitrary there.  Exact ties go to the smallest |α|, then the smallest σ: kernels
  narrower than a texel are all the identity, so an unchanged patch fits α = 0
  (not the grid's first α, the strongest sharpening).
* The ridge: TV is flat along a curve of (α, σ) trading strength against width
  (both set the slope variance).  The fit reports every evaluated grid point
  within ``ridge_tolerance`` of the minimum (default: the TV noise level of the
  target histogram, :func:`~facestats.model.microstructure.surface.tv_noise`);
  with coarse-to-fine, of the points it evaluated.  The profiles
  :meth:`KernelFit.alpha_given_sigma` and :meth:`KernelFit.sigma_given_alpha`
  are the conditional minima along the grid lines: with one parameter known
  they recover the other even where the ridge makes the joint argmin slide
  (see the documentation's figures).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facestats.core.compiled import resolve_backend
from facestats.core.progress import progress_bar
from facestats.core.validate import as_finite, as_scalar, check_choice
from facestats.errors import ValidationError
from facestats.model.microstructure import taps
from facestats.model.microstructure.compiled import histogram_tv
from facestats.model.microstructure.kernel import ALPHA_RANGE, SIGMA_RANGE_UM, kernel_radius
from facestats.model.microstructure.surface import histogram_extent, normal_histogram, slopes, tv_noise

__all__ = ["KernelFit", "fit_kernel", "ALPHA_GRID", "SIGMA_GRID_UM", "gaussian_stencil", "deformation_matrix"]

#: The paper's search grids (§5): α ∈ [−2, 1] step 0.01, σ ∈ [1, 100] µm step 0.5.
ALPHA_GRID = np.round(np.linspace(ALPHA_RANGE[0], ALPHA_RANGE[1], 301), 10)
SIGMA_GRID_UM = np.round(np.linspace(SIGMA_RANGE_UM[0], SIGMA_RANGE_UM[1], 199), 10)
#: Coarse grid of the coarse-to-fine search (every 10th α, every 10th σ, and the last σ).
_COARSE_A = np.arange(0, 301, 10)
_COARSE_S = np.unique(np.append(np.arange(0, 199, 10), 198))
#: Coarse points whose neighbourhoods coarse-to-fine searches at full resolution.
N_STARTS = 3


@dataclass
class KernelFit:
    """Result of :func:`fit_kernel`.

    Attributes
    ----------
    alpha, sigma_um : float
        The argmin of eq. 7 on the grid.
    tv : float
        Its total variation.
    alphas, sigmas_um : ndarray
        The grid axes.
    tv_grid : ndarray, shape (len(alphas), len(sigmas_um))
        TV of every combination (NaN where coarse-to-fine did not evaluate).
    ridge : ndarray, shape (K, 2)
        (α, σ) of the evaluated points with TV ≤ tv + ridge_tolerance.
    ridge_tolerance, tv_noise : float
        The ridge's TV tolerance and the target histogram's noise level.
    n_evaluated : int
        Combinations evaluated.
    target_histogram, fitted_histogram : ndarray (bins, bins)
    extent : float
        Histogram half-width in normal components.
    method : str
    meta : dict
        The fit's setting: stretch ratios ``r``, ``r_t``, the stretch ``axis``, ``texel_um``, ``margin``, ``bins``.
    """

    alpha: float
    sigma_um: float
    tv: float
    alphas: np.ndarray
    sigmas_um: np.ndarray
    tv_grid: np.ndarray
    ridge: np.ndarray
    ridge_tolerance: float
    tv_noise: float
    n_evaluated: int
    target_histogram: np.ndarray
    fitted_histogram: np.ndarray
    extent: float
    method: str
    meta: dict = field(default_factory=dict)

    def alpha_given_sigma(self, sigma_um: float) -> float:
        """The α minimising TV on the grid column nearest ``sigma_um`` (the profile of the landscape).

        Parameters
        ----------
        sigma_um : float
            Kernel σ in µm; the nearest value of ``sigmas_um`` is used.

        Returns
        -------
        float
            α of the lowest evaluated TV in that column.

        Raises
        ------
        ValidationError
            No combination of that column was evaluated (coarse-to-fine).
        """
        col = self.tv_grid[:, int(np.argmin(np.abs(self.sigmas_um - sigma_um)))]
        if np.all(np.isnan(col)):
            raise ValidationError(f"sigma_um={sigma_um} was not evaluated (coarse-to-fine); use method='brute'")
        return float(self.alphas[np.nanargmin(col)])

    def sigma_given_alpha(self, alpha: float) -> float:
        """The σ (µm) minimising TV on the grid row nearest ``alpha``.

        Parameters
        ----------
        alpha : float
            Kernel α; the nearest value of ``alphas`` is used.

        Returns
        -------
        float
            σ in µm of the lowest evaluated TV in that row.

        Raises
        ------
        ValidationError
            No combination of that row was evaluated (coarse-to-fine).
        """
        row = self.tv_grid[int(np.argmin(np.abs(self.alphas - alpha)))]
        if np.all(np.isnan(row)):
            raise ValidationError(f"alpha={alpha} was not evaluated (coarse-to-fine); use method='brute'")
        return float(self.sigmas_um[np.nanargmin(row)])


def deformation_matrix(axis, r, r_t=1.0) -> np.ndarray:
    """A = r a aᵀ + r_t b bᵀ: stretch r along the unit axis a and r_t across it (b ⟂ a).

    Parameters
    ----------
    axis : array_like, shape (2,)
        Unit axis a = (a_u, a_v) (not normalised here); b = (−a_v, a_u).
    r : float
        Stretch ratio along a (> 1 stretch, < 1 compression).
    r_t : float
        Stretch ratio across a (default 1: no change).

    Returns
    -------
    ndarray of float64, shape (2, 2)
        A, symmetric.
    """
    a = np.asarray(axis, np.float64)
    b = np.array([-a[1], a[0]])
    return r * np.outer(a, a) + r_t * np.outer(b, b)


def gaussian_stencil(axis, sigma_px):
    """The 2-D stencil of one Gaussian pass along a constant axis (interior of eq. 3 with G of eq. 6).

    Tap i (1 ≤ |i| ≤ n) lies i texels along the axis's major direction and i·slope across it, and is
    read by Lanczos-3 from six texels across (:mod:`~facestats.model.microstructure.taps`, as the
    compiled pass reads it); it spreads its weight g_i = exp(−i²/(2 s²)), s = σ_px |a_major| the σ in
    taps, over those texels.  The stencil sums to 1.

    Parameters
    ----------
    axis : array_like, shape (2,)
        Unit axis (a_u, a_v) of the pass.
    sigma_px : float
        Gaussian standard deviation in texels, ≥ 0.

    Returns
    -------
    stencil : ndarray of float64, shape (2 half + 1, 2 half + 1)
        Weights indexed [v, u], centred at ``[half, half]``, summing to 1.
    half : int
        n + 3, with n = ceil(TRUNCATE · s) the taps each side.
    """
    u_major, slope, major = taps.major_axis(np.float32(axis[0]), np.float32(axis[1]))
    sp = float(taps.gaussian_spacing(sigma_px, major))
    n = int(kernel_radius(sp))
    half = n + taps.LANCZOS_LOBES
    st = np.zeros((2 * half + 1, 2 * half + 1))
    st[half, half] = 1.0
    i = np.arange(1, n + 1)
    g = np.exp(-(i * i) / (2 * sp * sp))
    for sign in (1, -1):  # the two sides
        y0, t = taps.tap_across(slope, sign * i, half)
        for k in range(taps.FOOTPRINT):  # the six texels across
            across, along = y0 + (k + 1 - taps.LANCZOS_LOBES), sign * i
            r, c = (across, along) if u_major else (along, across)
            np.add.at(st, (half + r, half + c), g * taps.LANCZOS[t, k])
    return st / (1.0 + 2.0 * g.sum()), half


def _patch(value, name):
    dtype = np.asarray(value).dtype
    if dtype not in (np.float32, np.float64):
        raise ValidationError(f"{name} must be a float32/float64 displacement patch (um), got dtype {dtype}")
    p = as_finite(value, name, dtype=np.float64)
    if p.ndim != 2:
        raise ValidationError(f"{name} must be a 2-D displacement patch, got shape {p.shape}")
    if np.ptp(p) == 0:
        raise ValidationError(f"{name} must have relief (a flat patch has no normal distribution), got all {p.flat[0]}")
    return p


class _Problem:
    """Neutral spectrum, slopes and target histogram shared by all candidates."""

    def __init__(self, neutral, deformed, axis, jac_n, jac_d, margin, bins, extent, backend):
        self.neutral, self.axis, self.jac, self.margin = neutral, axis, jac_n, margin
        self.bins, self.backend = bins, backend
        m = margin
        self.g0 = [g[m:-m, m:-m].reshape(-1) for g in slopes(neutral, jac_n)]
        gt = [g[m:-m, m:-m] for g in slopes(deformed, jac_d)]
        self.extent = histogram_extent(tuple(self.g0), tuple(gt)) if extent is None else float(extent)
        self.target = normal_histogram(*gt, bins=bins, extent=self.extent)
        self.n_target = gt[0].size
        self.spectrum = np.fft.rfft2(neutral)

    def delta(self, sigma_px):
        """Slope change Δg of a unit α for one σ (interior, flat)."""
        st, c = gaussian_stencil(self.axis, sigma_px)
        h, w = self.neutral.shape
        kernel = np.zeros((h, w))
        rows, cols = (np.arange(st.shape[0]) - c) % h, (np.arange(st.shape[1]) - c) % w
        kernel[np.ix_(rows, cols)] = st  # centred at (0, 0), wrapped
        blurred = np.fft.irfft2(self.spectrum * np.fft.rfft2(kernel), s=(h, w))
        m = self.margin
        gb = [g[m:-m, m:-m].reshape(-1) for g in slopes(blurred, self.jac)]
        return gb[0] - self.g0[0], gb[1] - self.g0[1]

    def tv(self, sigma_px, alphas):
        dgx, dgy = self.delta(sigma_px)
        nb = self.bins
        return histogram_tv(
            self.g0[0], self.g0[1], dgx, dgy, alphas, self.target.reshape(-1), -self.extent,
            nb / (2 * self.extent), nb, backend=self.backend,
        )  # fmt: skip

    def histogram(self, alpha, sigma_px):
        dgx, dgy = self.delta(sigma_px)
        return normal_histogram(self.g0[0] + alpha * dgx, self.g0[1] + alpha * dgy, bins=self.bins, extent=self.extent)


def _progress(it, enabled, total, desc):
    return progress_bar(it, enabled=enabled, total=total, desc=desc, unit="sigma")


def _search(problem, alphas, sigmas_px, cells, progress):
    """TV on the grid points ``cells`` (bool (n_a, n_s)); NaN elsewhere."""
    grid = np.full(cells.shape, np.nan)
    cols = np.nonzero(cells.any(0))[0]
    for j in _progress(cols, progress, len(cols), "fit_kernel"):  # loop over sigma, all alphas at once
        rows = np.nonzero(cells[:, j])[0]
        grid[rows, j] = problem.tv(sigmas_px[j], alphas[rows])
    return grid


def _refine_cells(coarse, n_starts=N_STARTS):
    """Fine-grid cells around the ``n_starts`` best coarse points: ± one coarse step in α and σ, at full resolution."""
    cells = np.zeros(coarse.shape, bool)
    sub = coarse[np.ix_(_COARSE_A, _COARSE_S)]
    order = np.argsort(np.where(np.isnan(sub), np.inf, sub), axis=None)[:n_starts]
    for i, j in zip(*np.unravel_index(order, sub.shape)):  # loop over the starts
        a0, a1 = _COARSE_A[max(i - 1, 0)], _COARSE_A[min(i + 1, len(_COARSE_A) - 1)]
        s0, s1 = _COARSE_S[max(j - 1, 0)], _COARSE_S[min(j + 1, len(_COARSE_S) - 1)]
        cells[a0 : a1 + 1, s0 : s1 + 1] = True
    return cells


def fit_kernel(
    neutral,
    deformed,
    axis,
    r,
    texel_um,
    *,
    r_t=1.0,
    deformed_texel_um=None,
    bins=64,
    extent=None,
    method="brute",
    alphas=None,
    sigmas_um=None,
    ridge_tolerance=None,
    backend="auto",
    progress=False,
) -> KernelFit:
    """Fit (α, σ) of the 1-D kernel along ``axis`` that turns ``neutral`` into ``deformed`` (Nagano et al. 2015 eq. 7).

    Parameters
    ----------
    neutral, deformed : ndarray (H, W)
        Displacement patches (heights in µm), the deformed one as imaged (its own grid).
    axis : array_like, shape (2,)
        Unit direction ``(a_u, a_v)`` of the deformation (caliper movement) in the neutral patch.
    r : float
        Stretch ratio along ``axis`` (> 1 stretch, < 1 compression).
    texel_um : float
        µm per texel of the neutral patch.
    r_t : float
        Stretch ratio across the axis (1: the paper's uniaxial caliper).
    deformed_texel_um : float, optional
        µm per texel of the deformed patch (default ``texel_um``: same camera).
    bins : int
        Histogram buckets per axis (64 in the paper).
    extent : float, optional
        Histogram half-width in normal components (default: 1.1 × the 99.9th percentile of both patches).
    method : {"brute", "coarse-to-fine"}
    alphas, sigmas_um : array_like, optional
        Other search grids (brute force only); default the paper's (``ALPHA_GRID``, ``SIGMA_GRID_UM``).
    ridge_tolerance : float, optional
        TV tolerance of the reported ridge (default: the target's TV noise level).
    backend : {"auto", "numba", "numpy"}
    progress : bool
        Show a progress bar over σ.

    Returns
    -------
    KernelFit
    """
    n = _patch(neutral, "neutral")
    d = _patch(deformed, "deformed")
    a = as_finite(axis, "axis", dtype=np.float64)
    if a.shape != (2,) or abs(np.linalg.norm(a) - 1) > 1e-3:
        raise ValidationError(f"axis must be a unit 2-vector (a_u, a_v), got {np.asarray(axis).tolist()}")
    a = a / np.linalg.norm(a)
    r = as_scalar(r, "r", 0.0, low_inclusive=False)
    r_t = as_scalar(r_t, "r_t", 0.0, low_inclusive=False)
    texel = as_scalar(texel_um, "texel_um", 0.0, low_inclusive=False, unit="um")
    texel_d = (
        texel
        if deformed_texel_um is None
        else as_scalar(deformed_texel_um, "deformed_texel_um", 0.0, low_inclusive=False, unit="um")
    )
    check_choice(method, "method", ("brute", "coarse-to-fine"))
    backend = resolve_backend(backend)
    margin = int(kernel_radius(SIGMA_RANGE_UM[1] / texel)) + 3
    if a[0] != 0 and a[1] != 0:  # off the grid the taps read up to 3 texels across their position, not 1
        margin += taps.LANCZOS_LOBES - 1
    for name, p in (("neutral", n), ("deformed", d)):
        if min(p.shape) < 2 * margin + 8:
            raise ValidationError(
                f"{name} must be at least {2 * margin + 8} texels on a side (a {margin}-texel margin for "
                f"sigma up to {SIGMA_RANGE_UM[1]:g} um at {texel:g} um/texel), got shape {p.shape}"
            )
    jac_n = np.linalg.inv(deformation_matrix(a, r, r_t)).T / texel  # chain rule: slopes of the deformed shape
    problem = _Problem(n, d, a, jac_n, np.eye(2) / texel_d, margin, bins, extent, backend)
    a_grid = ALPHA_GRID if alphas is None else np.sort(as_finite(alphas, "alphas", *ALPHA_RANGE).reshape(-1))
    s_grid = (
        SIGMA_GRID_UM if sigmas_um is None else np.sort(as_finite(sigmas_um, "sigmas_um", *SIGMA_RANGE_UM).reshape(-1))
    )
    if method == "coarse-to-fine" and (alphas is not None or sigmas_um is not None):
        raise ValidationError(
            "alphas and sigmas_um must be None for method='coarse-to-fine' (it refines the paper's grid)"
        )
    sig_px = s_grid / texel
    noise = tv_noise(problem.target, problem.n_target)
    tol = noise if ridge_tolerance is None else as_scalar(ridge_tolerance, "ridge_tolerance", 0.0)
    if method == "brute":
        grid = _search(problem, a_grid, sig_px, np.ones((len(a_grid), len(sig_px)), bool), progress)
    else:
        coarse_cells = np.zeros((len(a_grid), len(sig_px)), bool)
        coarse_cells[np.ix_(_COARSE_A, _COARSE_S)] = True
        grid = _search(problem, a_grid, sig_px, coarse_cells, False)
        fine = _refine_cells(grid) & np.isnan(grid)
        grid = np.where(np.isnan(grid), _search(problem, a_grid, sig_px, fine, progress), grid)
    best = float(np.nanmin(grid))
    ti, tj = np.nonzero(grid == best)  # exact ties (kernels narrower than a texel are all the identity):
    k = np.lexsort((s_grid[tj], np.abs(a_grid[ti])))[0]  # the smallest |α|, then σ: an unchanged patch fits α = 0
    i, j = int(ti[k]), int(tj[k])
    ri, rj = np.nonzero(grid <= best + tol)
    return KernelFit(
        alpha=float(a_grid[i]),
        sigma_um=float(s_grid[j]),
        tv=best,
        alphas=a_grid.copy(),
        sigmas_um=s_grid.copy(),
        tv_grid=grid,
        ridge=np.stack([a_grid[ri], s_grid[rj]], -1),
        ridge_tolerance=tol,
        tv_noise=noise,
        n_evaluated=int(np.count_nonzero(~np.isnan(grid))),
        target_histogram=problem.target,
        fitted_histogram=problem.histogram(a_grid[i], sig_px[j]),
        extent=problem.extent,
        method=method,
        meta={"r": r, "r_t": r_t, "axis": a.tolist(), "texel_um": texel, "margin": margin, "bins": int(bins)},
    )
