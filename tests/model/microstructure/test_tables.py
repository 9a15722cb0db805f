"""Kernel tables (Nagano et al. 2015 eq. 8-9, Fig. 12)."""

import numpy as np
import pytest

from facestats.errors import FacestatsError
from facestats.model.microstructure import FOREHEAD, convolve_displacement, fit_kernel_table, kernel_parameters


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
    assert np.abs(a - _eq8(r)).max() < 1e-12 and np.abs(s - _eq9(r)).max() < 1e-12
    assert kernel_parameters(1.0)[0] == 0.0  # neutral: identity
    assert a.min() == -2 and a.max() == 1 and s.min() == 1  # clamped to the fitted ranges


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
    grid = np.linspace(0.6, 1.6, 501)
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


def test_bad_input():
    with pytest.raises(FacestatsError, match="r must lie in"):
        kernel_parameters(-0.5)
    with pytest.raises(FacestatsError, match="table must be"):
        kernel_parameters(1.1, "cheek")
    with pytest.raises(FacestatsError, match="at least 2 compression"):
        fit_kernel_table([0.9, 1.1, 1.2], [-0.3, 0.3, 0.6], [16, 15, 19], [0.8, 1.2])
    with pytest.raises(FacestatsError, match="alpha_knots must increase"):
        fit_kernel_table([0.8, 0.9, 1.1, 1.2], [-1, -0.3, 0.3, 0.6], [9, 16, 15, 19], [1.2, 0.8])
