"""The exitance fit on a grid (facestats.model.fitting.profile_grid.fit_exitance_grid): bad input."""

import numpy as np
import pytest


def test_the_exitance_fit_refuses_bad_normal_equations():
    from facestats.errors import FitError, ValidationError
    from facestats.model.fitting.profile_grid import fit_exitance_grid

    d, g, b = np.array([0.0, 1.0, 2.0]), np.eye(3), np.ones(3)
    with pytest.raises(ValidationError, match="n_rows must be an integer"):
        fit_exitance_grid(d, g, b, 3.9)
    with pytest.raises(ValidationError, match="levels must increase strictly"):
        fit_exitance_grid(d[::-1], g, b, 5)
    with pytest.raises(ValidationError, match="gram must be a Gram matrix"):
        fit_exitance_grid(d, -g, b, 5)
    with pytest.raises(FitError, match="at least 3 rows"):
        fit_exitance_grid(d, g, b, 2)
