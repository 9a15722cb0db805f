"""Where the profile sampler starts: a weighted least-squares fit and walkers drawn around it.

Walkers are drawn around a weighted least-squares fit of each channel (a
coarse-to-fine grid search, then :func:`scipy.optimize.least_squares` in log
space) with the fit's covariance.  ``post`` is a
:class:`facestats.analysis.posterior.likelihood.LogPosterior`.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from facestats.errors import ValidationError
from facestats.model import dipole

__all__ = ["least_squares_start", "initial_walkers"]


def _albedo_coordinates(t, ln_tr):
    """(ln σ's, ln σa) from logit(total albedo) and ln σtr.

    Weyrich et al. 2006 §5.4: the apparent albedo α' from the total diffuse
    reflectance by inverting eq. 16, then σ's = α' σ't and σa = σ't − σ's with
    σ't = σtr / sqrt(3 (1 − α')) (:func:`facestats.model.dipole.scattering_from_albedo`).
    """
    sp, sa = dipole.scattering_from_albedo(1 / (1 + np.exp(-t)), np.exp(ln_tr))
    return np.stack([np.log(sp), np.log(sa)], -1)


def _grid_start(post, y, std_fixed, mask, n_coarse=41, n_fine=11, n_best=8):
    """Best (ln σ's, ln σa) per block from a coarse-to-fine grid search of the weighted χ².

    The grid runs over the coordinates that set the profile's shape: the
    logit of the total albedo (0.005-0.995) and ln σtr (0.02-30 mm⁻¹), where
    a grid in (σ's, σa) would leave long curved valleys.  The likelihood is
    so narrow (0.5 % noise per fibre) that the χ² has several basins at the
    coarse spacing, so the ``n_best`` coarse minima are each refined on a
    ``n_fine`` × ``n_fine`` grid spanning ± one coarse step.  Points outside
    the prior bounds are excluded.
    """
    r = post.r[0, :, 0]
    t = np.linspace(-5.3, 5.3, n_coarse)
    u = np.linspace(np.log(0.02), np.log(30.0), n_coarse)
    coarse = np.stack(np.meshgrid(t, u, indexing="ij"), -1).reshape(-1, 2)  # (G, 2) in (logit α, ln σtr)

    def chi2(cand, blocks=slice(None)):  # cand (..., 2) in (logit α, ln σtr), broadcast against the blocks on axis -2
        th = _albedo_coordinates(cand[..., 0], cand[..., 1])
        inside = np.all((th >= post.lo) & (th <= post.hi), axis=-1)
        e = np.exp(th)
        mu = dipole.dipole_profile_unchecked(r, e[..., 0:1], e[..., 1:2], post.eta)  # (..., F)
        yk, sk, mk = y[:, blocks].T, std_fixed[:, blocks].T, mask[:, blocks].T  # (K, F)
        c = np.sum(np.where(mk, ((yk - mu) / sk) ** 2, 0.0), axis=-1)
        return np.where(inside, c, np.inf), th

    # blocks in chunks, so the (G, K, F) model array stays near 4 million values
    chunk = max(1, 4_000_000 // (coarse.shape[0] * r.size))
    best = np.concatenate(
        [
            np.argsort(chi2(coarse[:, None, :], slice(j, j + chunk))[0], axis=0)[:n_best].T
            for j in range(0, y.shape[1], chunk)
        ]
    )  # (K, n_best)
    step = np.array([t[1] - t[0], u[1] - u[0]])
    offsets = np.stack(np.meshgrid(*(np.linspace(-1, 1, n_fine),) * 2, indexing="ij"), -1).reshape(-1, 2) * step
    fine = (coarse[best][:, :, None, :] + offsets).reshape(y.shape[1], -1, 2)  # (K, n_best·n_fine², 2)
    c_fine, th_fine = chi2(fine.transpose(1, 0, 2))  # (M, K)
    return th_fine[np.argmin(c_fine, axis=0), np.arange(y.shape[1])]  # (K, 2)


def least_squares_start(post, y, std_fixed, mask):
    """Weighted least-squares (ln σ's, ln σa) and its covariance per block.

    A grid search (:func:`_grid_start`), then trust-region least squares
    (:func:`scipy.optimize.least_squares`) in log space; the covariance is
    (JᵀJ)⁻¹ of the standardised residuals, or 1e-4 I where that inverse is singular, non-finite or not positive
    definite.

    Parameters
    ----------
    post : LogPosterior
        The posterior; gives the fibre distances, η and the (ln σ's, ln σa) bounds.
    y : numpy.ndarray, shape (F, K)
        Profiles in mm⁻², with missing fibres set to 0 (they are masked out).
    std_fixed : numpy.ndarray, shape (F, K)
        Fixed weights: standard deviations of the readings in mm⁻² (not re-evaluated at the model).
    mask : numpy.ndarray of bool, shape (F, K)
        Valid fibres.

    Returns
    -------
    theta : numpy.ndarray, shape (K, 2)
        Fitted (ln σ's, ln σa) per block, σ in mm⁻¹.
    cov : numpy.ndarray, shape (K, 2, 2)
        Their covariance.
    """

    lo, hi = post.lo, post.hi
    k = y.shape[1]
    r = post.r[0, :, 0]
    best = _grid_start(post, y, std_fixed, mask)
    theta = np.empty((k, 2))
    cov = np.empty((k, 2, 2))
    for j in range(k):
        m = mask[:, j]
        rj, yj, sj = r[m], y[m, j], std_fixed[m, j]

        def resid(t):
            return (dipole.dipole_profile_unchecked(rj, np.exp(t[0]), np.exp(t[1]), post.eta) - yj) / sj

        fit = least_squares(resid, best[j], bounds=(lo, hi), x_scale="jac")
        theta[j] = fit.x
        jtj = fit.jac.T @ fit.jac
        try:
            c = np.linalg.inv(jtj)
            if not np.all(np.isfinite(c)) or np.any(np.linalg.eigvalsh(c) <= 0):
                raise np.linalg.LinAlgError
        except np.linalg.LinAlgError:
            c = np.eye(2) * 1e-4
        cov[j] = c
    return theta, cov


def initial_walkers(post, theta, cov, n_walkers, rng):
    """Walkers ~ N(θ̂, Σ̂) per block, inside the bounds and at finite log-probability.

    Draws are clipped into the bounds; walkers at a non-finite log-probability are redrawn from N(θ̂, 10⁻⁶ I)
    (clipped too), up to 20 times.

    Parameters
    ----------
    post : LogPosterior
        The posterior whose :meth:`~LogPosterior.blocks` the walkers must be finite under.
    theta : numpy.ndarray, shape (K, 2)
        Centre (ln σ's, ln σa) per block, e.g. from :func:`least_squares_start`.
    cov : numpy.ndarray, shape (K, 2, 2)
        Covariance per block (positive definite: it is Cholesky-factored).
    n_walkers : int
        Number of walkers.
    rng : numpy.random.Generator
        Source of the draws.

    Returns
    -------
    numpy.ndarray, shape (n_walkers, 2K)
        Starting positions, block-major: (ln σ's, ln σa) of block 1, then block 2, ...

    Raises
    ------
    ValidationError
        If some walker still has a non-finite log-probability after 20 redraws.
    """
    k = theta.shape[0]
    pad = 1e-9
    lo, hi = post.lo + pad, post.hi - pad
    chol = np.linalg.cholesky(cov)  # (K, 2, 2)
    p = theta[None] + np.einsum("kij,wkj->wki", chol, rng.standard_normal((n_walkers, k, 2)))
    p = np.clip(p, lo, hi)
    for _ in range(20):
        lp = post.blocks(p.reshape(n_walkers, 2 * k))
        bad = ~np.isfinite(lp)
        if not bad.any():
            break
        shrink = theta[None] + 1e-3 * rng.standard_normal((n_walkers, k, 2))
        p = np.where(bad[..., None], np.clip(shrink, lo, hi), p)
    else:
        raise ValidationError("could not start the sampler: the least-squares fit sits where the likelihood is zero")
    return p.reshape(n_walkers, 2 * k)
