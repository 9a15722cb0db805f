"""Kernel tables (Nagano et al. 2015 eq. 8-9, Fig. 12)."""

import numpy as np
import pytest

from facestats.errors import FacestatsError
from facestats.model.microstructure import (
    FOREHEAD,
    KernelTable,
    convolve_displacement,
    fit_kernel_table,
    kernel_parameters,
)


def _eq8(r):
    return np.clip(np.minimum(np.minimum(1.0, 15.4 * r - 13.8), 3.09 * (r - 1)), -2, 1)


def _eq9(r):
    return np.clip(np.where(r >= 1, 38.2 * r - 26.5, 70.5 * r - 46.9), 1, 100)


@pytest.mark.parametrize(
    "r, alpha, sigma",
    # Hand-evaluated from eq. 8-9: alpha = min(1, 15.4 r - 13.8, 3.09 (r - 1)); sigma by the two lines.
    [(0.8, -1.48, 9.5), (0.9, -0.309, 16.55), (1.1, 0.309, 15.52), (1.2, 0.618, 19.34)],
)
def test_forehead_table_values(r, alpha, sigma):
    a, s = kernel_parameters(r)
    assert abs(a - alpha) < 1e-3 and abs(s - sigma) < 1e-3


def test_forehead_table_is_eq_8_9_clamped_everywhere():
    r = np.linspace(0.3, 2.5, 20001)
    a, s = kernel_parameters(r, FOREHEAD)
    held = np.maximum(r, 0.73)  # below Fig. 11's smallest ratio, its parameters
    assert np.abs(a - _eq8(held)).max() < 1e-12 and np.abs(s - _eq9(held)).max() < 1e-12
    assert kernel_parameters(1.0)[0] == 0.0  # neutral: identity
    assert kernel_parameters(1.0)[1] == pytest.approx(38.2 - 26.5)  # eq. 9's stretch line holds from r = 1 on
    assert a.min() == -2 and a.max() == 1  # clamped to the fitted range
    assert s.min() == pytest.approx(70.5 * 0.73 - 46.9)  # never the 1 um clamp (an identity kernel)


def test_compression_beyond_the_measured_ratios_keeps_roughening():
    """Eq. 9 extrapolated reaches sigma = 1 um at r = 0.68 (an identity kernel): the most compressed skin would not
    roughen at all.  Held at Fig. 11's smallest ratio, every stronger compression sharpens as r = 0.73 does."""
    from facestats.acquire.synthetic.microstructure import procedural_microstructure

    d = procedural_microstructure(128, 6.0, seed=1).astype(np.float64)

    def slope_gain(r):  # rms slope along the compressed axis, after / before (> 1: rougher)
        a, s = (float(x) for x in kernel_parameters(r))
        out = convolve_displacement(d, (1.0, 0.0), a, s, 0.0, 1.0, 6.0)
        return np.gradient(out, axis=1)[16:-16, 16:-16].std() / np.gradient(d, axis=1)[16:-16, 16:-16].std()

    at_73 = slope_gain(0.73)
    assert at_73 > 1.03  # measured 1.057 (1.166 at r = 0.8)
    for r in (0.4, 0.6, 0.68):
        assert slope_gain(r) == at_73  # the extrapolated line gave 1.000 here


def test_convolved_map_is_continuous_across_r_1():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(64, 64))
    maps = {}
    for r in (1 - 1e-6, 1 + 1e-6):  # sigma jumps from 23.6 to 11.7 um here, alpha does not
        a, s = kernel_parameters(r)
        maps[r] = convolve_displacement(d, (0.6, 0.8), float(a), float(s), float(a), float(s), 10.0)
    jump = np.abs(maps[1 + 1e-6] - maps[1 - 1e-6]).max()
    assert jump < 1e-4 * np.abs(d).max()
    a_lo, s_lo = kernel_parameters(1 - 1e-6)
    a_hi, s_hi = kernel_parameters(1 + 1e-6)
    assert s_lo - s_hi > 10  # the discontinuity of eq. 9 is real and harmless


def test_fitting_points_of_eq_8_9_recovers_the_forehead_table():
    r = np.linspace(0.7, 1.4, 29)
    table = fit_kernel_table(r, _eq8(r), _eq9(r), FOREHEAD.alpha_knots, name="refit")
    assert table.min_ratio == 0.7  # the smallest fitted ratio (the forehead's is Fig. 11's, 0.73)
    grid = np.linspace(0.73, 1.6, 501)
    assert np.abs(table.alpha(grid) - FOREHEAD.alpha(grid)).max() < 1e-9
    assert np.abs(table.sigma(grid) - FOREHEAD.sigma(grid)).max() < 1e-9


def test_fitted_table_passes_through_the_neutral_case_exactly():
    rng = np.random.default_rng(1)
    r = np.concatenate([rng.uniform(0.72, 0.99, 12), rng.uniform(1.01, 1.3, 12)])
    alpha = np.clip(_eq8(r) + rng.normal(0, 0.2, r.size) + 0.3, -2, 1)  # noisy, biased data
    sigma = _eq9(r) + rng.normal(0, 2, r.size)
    table = fit_kernel_table(r, alpha, sigma, [0.8, 0.9, 1.05, 1.3])
    assert abs(table.alpha(1.0)) < 1e-12
    assert table.sigma(0.999) != pytest.approx(table.sigma(1.0))  # one line per side
    # A knot at 1 is set to 0 exactly: the constrained least squares leaves ~1e-16 there (1.2e-16 here), and a
    # kernel of alpha 1e-16 is not skipped as the identity
    assert fit_kernel_table(r, alpha, sigma, [0.8, 0.9, 1.0, 1.3]).alpha(1.0) == 0.0


def test_a_patch_at_r_1_belongs_to_the_stretch_line():
    """Eq. 9's lines: r < 1 compression, r >= 1 stretch; the line through (1, 5) and (1.2, 25) um."""
    table = fit_kernel_table([0.8, 0.9, 1.0, 1.2], [-1.0, -0.3, 0.0, 0.6], [10.0, 20.0, 5.0, 25.0], [0.8, 1.2])
    assert table.sigma_stretch == pytest.approx((100.0, -95.0)) and table.sigma_compress == pytest.approx((100, -70))


def test_bad_input():
    with pytest.raises(FacestatsError, match="r must lie in"):
        kernel_parameters(-0.5)
    with pytest.raises(FacestatsError, match="table must be"):
        kernel_parameters(1.1, "cheek")
    with pytest.raises(FacestatsError, match="at least 2 distinct compression"):
        fit_kernel_table([0.9, 1.1, 1.2], [-0.3, 0.3, 0.6], [16, 15, 19], [0.8, 1.2])
    # Repeated patches at one ratio leave the line's slope undetermined (polyfit's RankWarning before: an API red team)
    with pytest.raises(FacestatsError, match=r"2 distinct compression .* got 3 patch\(es\) at \[0.9\]"):
        fit_kernel_table([0.9, 0.9, 0.9, 1.1, 1.2], [-0.3] * 3 + [0.3, 0.6], [16, 17, 15, 15, 19], [0.8, 1.2])
    with pytest.raises(FacestatsError, match=r"min_ratio must be a stretch ratio in \[0, 1\), got nan"):
        KernelTable((1.0,), (0.0,), (70.5, -46.9), (38.2, -26.5), min_ratio=float("nan"))
    with pytest.raises(FacestatsError, match="alpha_knots must increase"):
        fit_kernel_table([0.8, 0.9, 1.1, 1.2], [-1, -0.3, 0.3, 0.6], [9, 16, 15, 19], [1.2, 0.8])


def test_a_huge_ratio_is_clipped_to_the_sigma_range_without_warnings():
    import warnings

    from facestats.model.microstructure import kernel_parameters

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a ratio near 1e308 overflowed a_s r + b_s (the value was right)
        alpha, sigma = kernel_parameters(1e308)
    assert (float(alpha), float(sigma)) == (1.0, 100.0)
