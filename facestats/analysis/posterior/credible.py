"""Credible levels and equal-tailed interval quantiles, shared by the posterior models."""

from __future__ import annotations

import numpy as np

from facestats.core.validate import as_float, check_range, check_shape

__all__ = ["check_level", "interval_quantiles"]


def check_level(level) -> float:
    """A credible level in the open interval (0, 1), as a float.

    Parameters
    ----------
    level : float
        Credible level, a scalar (e.g. 0.9 for a 5 %-95 % interval).

    Returns
    -------
    float

    Raises
    ------
    ValidationError
        If ``level`` is not a numeric scalar or lies outside (0, 1).
    """
    lv = check_shape(as_float(level, "level", np.float64), "level", ())
    check_range(lv, "level", 0, 1, low_inclusive=False, high_inclusive=False)
    return float(lv)


def interval_quantiles(level) -> list[float]:
    """Quantiles [lower, median, upper] of the equal-tailed credible interval at ``level``.

    Parameters
    ----------
    level : float
        Credible level in (0, 1), already checked (see :func:`check_level`).

    Returns
    -------
    list of float
        ``[(1 - level)/2, 0.5, (1 + level)/2]``.
    """
    return [(1 - level) / 2, 0.5, (1 + level) / 2]
