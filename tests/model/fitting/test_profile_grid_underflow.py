"""Eq. 36 on a grid whose models underflow: R = 0 at a fitted level costs inf (not inf - inf = NaN)."""

import numpy as np
import pytest

from facestats.errors import FitError
from facestats.model.dipole import dipole_profile
from facestats.model.fitting.profile_grid import ProfileGrid, fit_profile_grid, profile_cost
from facestats.pipeline.image_translucency import GRIDS

D = np.arange(0, 40, 0.5)  # a pyramid's distances: the skin grid's corner has R = 0 beyond ~37 mm


def test_models_whose_profile_underflows_cost_inf_and_are_never_chosen():
    skin = GRIDS["skin"]
    prof = dipole_profile(D, 2.19, 0.0021, 1.3)
    cost = profile_cost(D, np.log(prof), skin, 1.3)
    assert not np.isnan(cost).any()
    assert cost[-1, -1] == np.inf and np.isfinite(cost[0, 0])
    fit = fit_profile_grid(D, prof, grid=skin, eta=1.3)
    # within a step of the truth (the grid's steps: 3.8 % in sigma_s', 5.5 % in sigma_a)
    assert fit.grid_sigma_s_prime == pytest.approx(2.19, rel=0.04) and fit.grid_sigma_a == pytest.approx(
        0.0021, rel=0.06
    )
    s0, s1 = fit.sigma_s_prime_interval
    assert s0 <= 2.19 <= s1 and not fit.at_grid_edge
    refined = fit_profile_grid(D, prof, grid=skin, eta=1.3, refine=True)  # starts from a finite model
    assert refined.sigma_s_prime == pytest.approx(2.19, rel=1e-5)
    assert refined.sigma_a == pytest.approx(0.0021, rel=1e-5)


def test_a_grid_whose_every_model_underflows_is_a_fit_error():
    grid = ProfileGrid.log_spaced((100, 200), (50, 100), (4, 4))
    with pytest.raises(FitError) as err:
        fit_profile_grid(D, dipole_profile(D, 2.19, 0.0021, 1.3), grid=grid, eta=1.3)
    assert str(err.value) == (
        "eq. 36: every model of the grid (sigma_s' 100-200, sigma_a 50-100 1/mm) has R underflowing to 0 at some "
        "of the 80 levels up to 39.5 mm; fit fewer levels (max_distance; --max-distance on the command line) or use a "
        "grid of smaller coefficients"
    )
