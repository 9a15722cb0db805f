"""Kernel fitting by normal-histogram total variation (Nagano et al. 2015 eq. 7)."""

import numpy as np
import pytest

from facestats.acquire.synthetic.microstructure import (
    SkinMicrostructure,
    procedural_microstructure,
    shot_noise_microstructure,
)
from facestats.errors import FacestatsError
from facestats.model.microstructure import convolve_displacement, fit_kernel
from facestats.model.microstructure.compiled import histogram_tv
from facestats.model.microstructure.fit import ALPHA_GRID, SIGMA_GRID_UM, deformation_matrix

TEXEL = 10.0
SKIN = SkinMicrostructure(roughness=0.3, furrow_angle=None, furrow_share=0.3, pore_share=0.3, pore_density_mm2=3.0,
                          pore_radius_um=30.0)  # fmt: skip


def _patch(n, seed, **kw):
    return procedural_microstructure(n, TEXEL, params=SKIN, seed=seed, **kw).astype(np.float64)


def test_paper_grid_has_59899_combinations():
    assert len(ALPHA_GRID) * len(SIGMA_GRID_UM) == 59899
    assert ALPHA_GRID[[0, 1, -1]].tolist() == [-2.0, -1.99, 1.0] and SIGMA_GRID_UM[[0, 1, -1]].tolist() == [1, 1.5, 100]


@pytest.mark.slow
@pytest.mark.parametrize("alpha, sigma, brute", [(0.47, 30.5, True), (-1.23, 17.0, False)])
def test_target_made_from_the_same_patch_is_recovered_exactly(alpha, sigma, brute):
    neutral = _patch(136, 1)
    target = convolve_displacement(neutral, (0.6, 0.8), alpha, sigma, 0.0, 1.0, TEXEL)
    fast = fit_kernel(neutral, target, (0.6, 0.8), 1.0, TEXEL, method="coarse-to-fine")
    assert (fast.alpha, fast.sigma_um) == (alpha, sigma) and fast.tv == 0.0 and fast.n_evaluated < 59899 / 20
    if brute:  # the full search of the paper returns the same argmin
        full = fit_kernel(neutral, target, (0.6, 0.8), 1.0, TEXEL)
        assert (full.alpha, full.sigma_um) == (alpha, sigma) and full.tv == 0.0 and full.n_evaluated == 59899
        assert (alpha, sigma) in map(tuple, full.ridge)


def test_independent_realisation_lies_on_the_ridge_and_profiles_recover_each_parameter():
    neutral, other = _patch(384, 1), _patch(384, 2)
    alphas, sigmas = np.round(np.arange(-2, 1.0001, 0.05), 2), np.arange(5.0, 100.1, 5.0)  # coarser than the paper's
    for alpha, sigma in ((0.5, 30.0), (-1.0, 20.0)):
        target = convolve_displacement(other, (1.0, 0.0), alpha, sigma, 0.0, 1.0, TEXEL)
        fit = fit_kernel(neutral, target, (1.0, 0.0), 1.0, TEXEL, alphas=alphas, sigmas_um=sigmas)
        i, j = np.argmin(np.abs(fit.alphas - alpha)), np.argmin(np.abs(fit.sigmas_um - sigma))
        assert fit.tv_grid[i, j] <= fit.tv + fit.ridge_tolerance  # the truth is on the reported ridge
        assert abs(fit.alpha_given_sigma(sigma) - alpha) <= 0.1
        assert abs(fit.sigma_given_alpha(alpha) - sigma) <= TEXEL  # 1 texel


@pytest.mark.slow
def test_pure_geometric_stretch_fits_no_kernel():
    neutral = _patch(320, 1)
    # sigma >= 2 texels: below about a texel the kernel is nearly the identity for every alpha (alpha is not defined)
    alphas, sigmas = np.round(np.arange(-2, 1.0001, 0.05), 2), np.arange(20.0, 100.1, 5.0)
    for r, angle in ((1.2, 0.0), (0.85, np.pi / 3)):
        axis = np.array([np.cos(angle), np.sin(angle)])
        deformed = _patch(320, 1, deformation=deformation_matrix(axis, r))  # the same skin, stretched exactly
        fit = fit_kernel(neutral, deformed, axis, r, TEXEL, alphas=alphas, sigmas_um=sigmas)
        assert abs(fit.alpha) <= 0.05, (r, fit.alpha)
        naive = fit_kernel(neutral, deformed, axis, 1.0, TEXEL, alphas=alphas, sigmas_um=sigmas)
        assert abs(naive.alpha) >= 0.15  # without resampling the slope change is absorbed into alpha


def test_compiled_and_numpy_histograms_agree():
    rng = np.random.default_rng(0)
    g = [rng.normal(0, 0.2, 5000) for _ in range(4)]
    target = np.bincount(rng.integers(0, 64 * 64, 5000), minlength=64 * 64) / 5000
    args = (*g, np.linspace(-2, 1, 13), target, -0.6, 64 / 1.2, 64)
    assert np.allclose(histogram_tv(*args, backend="numba"), histogram_tv(*args, backend="numpy"), rtol=0, atol=1e-12)


def test_bad_input():
    p = np.random.default_rng(0).normal(0, 1, (120, 120))
    with pytest.raises(FacestatsError, match="neutral must be at least 74 texels"):
        fit_kernel(p[:40, :40], p, (1, 0), 1.0, TEXEL)
    with pytest.raises(FacestatsError, match="neutral must have relief"):
        fit_kernel(np.zeros((120, 120)), p, (1, 0), 1.0, TEXEL)
    with pytest.raises(FacestatsError, match="deformed must be a float32/float64 displacement patch .* int8"):
        fit_kernel(p, (p * 10).astype(np.int8), (1, 0), 1.0, TEXEL)
    with pytest.raises(FacestatsError, match="deformed_texel_um must"):
        fit_kernel(p, p, (1, 0), 1.0, TEXEL, deformed_texel_um=0)
    with pytest.raises(FacestatsError, match="axis must be a unit 2-vector"):
        fit_kernel(p, p, (1, 1), 1.0, TEXEL)
    with pytest.raises(FacestatsError, match="r must lie in"):
        fit_kernel(p, p, (1, 0), 0.0, TEXEL)
    with pytest.raises(FacestatsError, match="deformed must be finite"):
        fit_kernel(p, np.full((120, 120), np.nan), (1, 0), 1.0, TEXEL)
    with pytest.raises(FacestatsError, match="method must be one of"):
        fit_kernel(p, p, (1, 0), 1.0, TEXEL, method="random")


@pytest.mark.parametrize("alpha, sigma", [(0.5, 30.0), (-1.5, 40.0)])
def test_independent_realisation_of_a_dense_surface_recovers_the_joint_argmin(alpha, sigma):
    # Nagano et al. eq. 7 from an independent realisation with the same statistics: a shot-noise surface (500 bumps
    # per mm^2, thousands per patch). bench_microstructure.bench_independent_dense: 24 fits at 512^2 (8 truths x 3
    # seeds) all within the tolerance (max 0.09 in alpha, 0.45 texel in sigma); at 256^2 four miss.
    neutral = shot_noise_microstructure(512, TEXEL, seed=1).astype(np.float64)
    other = shot_noise_microstructure(512, TEXEL, seed=2).astype(np.float64)
    target = convolve_displacement(other, (0.6, 0.8), alpha, sigma, 0.0, 1.0, TEXEL)
    fit = fit_kernel(neutral, target, (0.6, 0.8), 1.0, TEXEL, method="coarse-to-fine")
    assert abs(fit.alpha - alpha) <= 0.1 and abs(fit.sigma_um - sigma) <= TEXEL, (fit.alpha, fit.sigma_um)


@pytest.mark.parametrize("method", ["brute", "coarse-to-fine"])
def test_an_unchanged_patch_fits_no_filter_not_the_first_grid_point(method):
    """Kernels narrower than a texel are all the identity: every α ties at TV 0, and the tie goes to α = 0 (the
    grid's first α, -2, the strongest sharpening, would corrupt a kernel table built from such points)."""
    patch = np.random.default_rng(3).normal(size=(96, 96))
    fit = fit_kernel(patch, patch, (1, 0), 1.0, 10.0, method=method)
    assert fit.tv == 0.0 and fit.alpha == 0.0 and fit.sigma_um == fit.sigmas_um.min()


def test_normal_histogram_names_a_nan_slope_and_a_bad_extent():
    from facestats.model.microstructure.surface import normal_histogram

    h = normal_histogram(np.zeros(3), np.zeros(3), bins=4, extent=0.5)
    assert h.sum() == pytest.approx(1.0)
    with pytest.raises(FacestatsError, match="gx must be finite"):  # was a raw ValueError from np.bincount
        normal_histogram(np.array([np.nan, 0, 0]), np.zeros(3), bins=4, extent=0.5)
    for extent in ("a", None, 0.0, 1.5, [0.5, 0.5]):
        with pytest.raises(FacestatsError, match="extent"):
            normal_histogram(np.zeros(3), np.zeros(3), bins=4, extent=extent)


def test_histogram_extent_names_nan_slopes_and_missing_pairs():
    """A NaN slope gave a NaN extent (Python's max/min with NaN skip the clip); no pairs gave a bare ValueError."""
    from facestats.errors import ValidationError
    from facestats.model.microstructure.surface import histogram_extent

    g = np.array([0.1, -0.2, 0.3])
    assert 1e-6 <= histogram_extent((g, g)) <= 1.0
    with pytest.raises(ValidationError, match="gx of slope pair 1 must be finite"):
        histogram_extent((g, g), (np.array([np.nan, 0.0, 0.0]), g))
    with pytest.raises(ValidationError, match="slope_pairs must hold at least one"):
        histogram_extent()
    with pytest.raises(ValidationError, match="slope_pairs must hold at least one texel"):
        histogram_extent((np.zeros(0), np.zeros(0)))
    with pytest.raises(ValidationError, match="slope pair 0 must be gx and gy of one shape"):
        histogram_extent((g, g[:2]))
    with pytest.raises(ValidationError, match="quantile"):
        histogram_extent((g, g), quantile=1.5)


def test_slopes_and_normals_of_a_tilted_plane_follow_the_conventions_of_the_surface_module():
    """h = 2 u + 3 v (u the column): ∂h/∂u = 2, ∂h/∂v = 3 (one-sided at the edges too), g = J ∇h with J applied
    as a matrix (row i of J times the gradient), and the normal (−g_u, −g_v, 1)/√(1 + |g|²) leans against the
    slope: a plane rising along +u has a normal pointing towards −u."""
    from facestats.model.microstructure.surface import height_gradient, slopes, tangent_normals

    v, u = np.indices((5, 7), dtype=np.float64)
    h = 2.0 * u + 3.0 * v
    gu, gv = height_gradient(h)
    assert np.allclose(gu, 2.0) and np.allclose(gv, 3.0)
    gx, gy = slopes(h, np.array([[1.0, 2.0], [3.0, 4.0]]))
    assert np.allclose(gx, 1 * 2 + 2 * 3) and np.allclose(gy, 3 * 2 + 4 * 3)
    n = tangent_normals(h, np.eye(2) / 10.0, dtype=np.float64)  # 10 um texels: slopes 0.2 and 0.3
    assert np.allclose(n, np.array([-0.2, -0.3, 1.0]) / np.sqrt(1.13))


def test_normal_histogram_puts_a_tilted_normal_in_its_bucket_and_tv_noise_is_the_binomial_mean():
    """A single slope g_u = 0.2 has n_u = −0.2/√1.04 = −0.196: bucket floor((n_u + 0.5) · 4) = 1 of 4 over
    [−0.5, 0.5], n_v = 0 bucket 2; the histogram is indexed [n_v, n_u].  tv_noise against the exact mean of
    |X − Y|/N for two independent binomials X, Y ~ B(N, p) on two buckets (each bucket counts it once)."""
    from scipy.stats import binom

    from facestats.model.microstructure.surface import normal_histogram, tv_noise

    h = normal_histogram(np.array([0.2]), np.array([0.0]), bins=4, extent=0.5)
    assert h[2, 1] == 1.0 and h.sum() == 1.0
    n, p = 400, 0.3
    pmf = binom.pmf(np.arange(n + 1), n, p)
    diff = np.abs(np.subtract.outer(np.arange(n + 1), np.arange(n + 1))) / n
    exact = 2 * float(pmf @ diff @ pmf)  # both buckets of the pair (p, 1 − p) differ by the same amount
    assert tv_noise([p, 1 - p], n) == pytest.approx(exact, rel=0.01)


def test_coarse_to_fine_refines_one_coarse_step_on_both_sides_of_its_best_start():
    """The fine grid is searched within one coarse step (0.1 in alpha, 5 um in sigma) of the best coarse points, on
    both sides: alpha = -1.23 lies between the coarse -1.3 and -1.2 and is recovered exactly."""
    neutral = _patch(136, 1)
    target = convolve_displacement(neutral, (0.6, 0.8), -1.23, 17.0, 0.0, 1.0, TEXEL)
    fit = fit_kernel(neutral, target, (0.6, 0.8), 1.0, TEXEL, method="coarse-to-fine")
    assert (fit.alpha, fit.sigma_um) == (-1.23, 17.0) and fit.tv == 0.0
    coarse_s = np.unique(np.append(np.arange(0, 199, 10), 198))
    coarse = fit.tv_grid[np.ix_(np.arange(0, 301, 10), coarse_s)]
    i, j = np.unravel_index(np.argmin(coarse), coarse.shape)
    rows = slice(max(10 * i - 10, 0), min(10 * i + 10, 300) + 1)
    cols = slice(coarse_s[max(j - 1, 0)], coarse_s[min(j + 1, len(coarse_s) - 1)] + 1)
    assert not np.isnan(fit.tv_grid[rows, cols]).any()  # the whole box around the best start was evaluated
