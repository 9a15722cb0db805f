"""Choosing the quantisation of Suzuki et al. §3.3: the width of the levels and the range of the fit.

Maximum distance (``max_distance="auto"``): the fit uses the levels up to the
first level (beyond d'_1 = 0) where the data do not determine the profile to
within ``MAX_RELATIVE_ERROR`` = 25 %, judged at the resolution of the patches
(levels thinned to about one per patch spacing h when the width is finer, so the
range does not shrink as the width does; before 2026-12-08 one per d'_2, the
first level left after merging, which lies below h where sub-spacing pairs
support it: on a plate of 7,200 patches (h = 0.314 mm) lit over a half plane
the range then collapsed to 0 at a width of 0.222 mm, between ranges of 12.9 mm
at 0.157 and 0.314 mm): the relative standard error of R'_i
from the unconstrained relative-residual problem
(:func:`~facestats.model.fitting.quantised.profile_covariance`), with the
relative noise taken as the residual of the solve but at least
``NOISE_FLOOR`` = 1 % (so noise-free synthetic data are treated like a
well-calibrated HDR image, not as exact).  Far levels, supported by few pairs
and carrying little of any row's light, are where both the paper's solve and
the interpolation error go wrong first.

Automatic width (``width="auto"``, the open problem of Suzuki §4.1): with h the
patches' spacing (median nearest-neighbour distance), candidate widths
h × 2^(k/2), k = −2, −1, 0, 1, … are tried from the finest.  A candidate is
accepted when the levels it makes are supported: over the levels up to the
median (visible, lit) pair distance, the median support is at least
``AUTO_MEDIAN_SUPPORT`` = 100 pairs and at most a quarter of them fall below
``min_pairs`` (estimated from the distances of at most 2,000 sampled rows);
after W is built, a rank deficit that merging cannot resolve, or a fit that fails
(e.g. a fit range of fewer than 3 levels), moves on to the next candidate, and
the width kept notes the widths skipped and why.  Finer widths shrink the interpolation error of eq. 28 (∝ w²) but
leave levels without pairs (Table 3's failure at 0.03125 mm); h/2 is the finest
candidate because no pair lies closer than about h apart except a patch and
itself, so only the first level below h can go unsupported there and merging
resolves it.
"""

from __future__ import annotations

import numpy as np

from facestats.errors import ValidationError
from facestats.model.fitting.quantised import (
    NormalEquations,
    QuantisedSystem,
    interpolation_matrix,
    patch_spacing,
    profile_covariance,
    solve_monotone_normal,
)

__all__ = ["MAX_RELATIVE_ERROR", "NOISE_FLOOR", "AUTO_MEDIAN_SUPPORT", "auto_width", "fit_distance"]

#: Relative standard error of R'_i up to which a level enters the fit (``max_distance="auto"``).
MAX_RELATIVE_ERROR = 0.25
#: Smallest relative radiance noise assumed when judging which levels the data determine.
NOISE_FLOOR = 0.01
#: Median level support (pairs) a width must reach to be chosen by ``width="auto"``.
AUTO_MEDIAN_SUPPORT = 100
#: Rows sampled to estimate the level support of candidate widths.
_AUTO_SAMPLE_ROWS = 2000


def _pair_distances_sample(points, weights, rows, seed=0):
    """Distances between at most ``_AUTO_SAMPLE_ROWS`` sampled rows and as many sampled lit patches.

    Returns the distances and the factor (pairs / sampled pairs) that scales
    counts of the sample to counts of all (visible, lit) pairs.
    """
    rng = np.random.default_rng(seed)
    lit = np.nonzero(weights > 0)[0]
    rs = rows if rows.size <= _AUTO_SAMPLE_ROWS else rng.choice(rows, _AUTO_SAMPLE_ROWS, replace=False)
    ls = lit if lit.size <= _AUTO_SAMPLE_ROWS else rng.choice(lit, _AUTO_SAMPLE_ROWS, replace=False)
    a, b = points[rs], points[ls]
    d2 = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2 * a @ b.T
    factor = (rows.size / rs.size) * (lit.size / ls.size)
    return np.sqrt(np.maximum(d2, 0)).ravel(), factor


def _support_of(d, width, n):
    """Hat-weighted pair count per uniform level of a sample of distances."""
    x = d / width
    i = x.astype(np.int64)
    t = x - i
    s = np.bincount(i, weights=1 - t, minlength=n + 1)[: n + 1]
    s[1:] += np.bincount(i, weights=t, minlength=n + 1)[:n]
    return s[:n]


def auto_width(points, weights, rows, *, spacing=None, min_pairs=30) -> list:
    """Candidate widths for ``width="auto"`` (module docstring), finest acceptable first, in mm.

    Parameters
    ----------
    points : ndarray, shape (m, 3)
    weights : ndarray, shape (m,)
        c_k A_k (lit patches > 0).
    rows : ndarray of int
        Visible patches.
    spacing : float, optional
        Patch spacing h (mm); default the median nearest-neighbour distance.
    min_pairs : int
        Support below which a level is merged.

    Returns
    -------
    list of float
        Acceptable candidate widths, finest first (at least one: the coarsest tried).

    Raises
    ------
    ValidationError
        Without ``spacing``: fewer than two visible or lit patches, or patches whose median nearest distance is 0
        (no spacing to build the ladder on; give the width in mm).
    """
    if spacing is None:
        used = np.union1d(rows, np.nonzero(weights > 0)[0])
        spacing = patch_spacing(points[used])
        if not spacing > 0:  # NaN for one patch (no neighbour), 0 for patches stacked at one place
            where = "" if used.size < 2 else f" at a median nearest distance of {spacing:g} mm"
            raise ValidationError(
                f"width='auto' needs the spacing of at least two patches (visible or lit), got {used.size}{where}: "
                "give the width in mm (--width on the command line)"
            )
    d, scale = _pair_distances_sample(points, weights, rows)
    median_d = float(np.median(d))
    out = []
    for k in range(-2, 9):  # the ladder h·2^(k/2), finest first
        w = spacing * 2 ** (k / 2)
        n = int(np.floor(d.max() / w)) + 2
        sup = _support_of(d, w, n) * scale
        near = sup[1 : max(2, int(np.floor(median_d / w)) + 1)]
        if np.median(near) >= AUTO_MEDIAN_SUPPORT and np.mean(near < min_pairs) <= 0.25:
            out.append(float(w))
    return out or [float(spacing * 2**4)]


def fit_distance(system: QuantisedSystem, neq: NormalEquations, profile) -> float:
    """The ``max_distance="auto"`` rule (module docstring): last distance before R' is undetermined to 25 %, mm.

    Judged at the resolution of the patches: the levels are thinned to about
    one per max(d'_2, h) (d'_2 the first level beyond 0 after merging, h the
    system's ``spacing`` when known; the system itself when the width is
    coarser), the thinned
    problem is solved (monotone), and the relative standard errors of its R'
    come from :func:`~facestats.model.fitting.quantised.profile_covariance`
    with the noise floored at ``NOISE_FLOOR``.

    Parameters
    ----------
    system : QuantisedSystem
        W of Suzuki eq. 33 and its levels d'_i (mm).
    neq : NormalEquations
        The weighted normal equations of ``system``
        (:func:`~facestats.model.fitting.quantised.normal_equations`, ``weighted=True``).
    profile : ndarray, shape (n,)
        R'_i at the system's levels, mm⁻² (the monotone solve of ``neq``); re-solved on the thinned levels when
        they are fewer.

    Returns
    -------
    float
        The fit's maximum distance, mm: the last thinned level before the first (beyond d'_1 = 0) whose R' is
        not positive or has a relative standard error above ``MAX_RELATIVE_ERROR``; the last level if none.
    """
    lev = system.levels
    step = max(lev[1], system.spacing) if np.isfinite(system.spacing) else lev[1]
    keep = np.zeros(lev.size, bool)
    keep[np.searchsorted(lev, np.arange(0, lev[-1], step) - 1e-9 * step)] = True
    keep[0] = keep[-1] = True
    coarse = lev[keep]
    if coarse.size < lev.size:
        neq = neq.merged(interpolation_matrix(lev, coarse))
        profile = solve_monotone_normal(neq)
    cov = profile_covariance(neq, profile)
    s2 = neq.residual(profile) / max(neq.n_rows - coarse.size, 1)
    inflate = max(1.0, NOISE_FLOOR**2 / max(s2, 1e-300))
    with np.errstate(invalid="ignore", divide="ignore"):
        rse = np.where(profile > 0, np.sqrt(np.maximum(np.diag(cov), 0) * inflate) / profile, np.inf)
    bad = np.nonzero(~(rse[1:] <= MAX_RELATIVE_ERROR))[0] + 1
    return float(coarse[bad[0] - 1] if bad.size else coarse[-1])
