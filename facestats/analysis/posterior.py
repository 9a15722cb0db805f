"""Bayesian posteriors of the subsurface scattering coefficients (Weyrich et al. 2006 §5.4, with uncertainty).

Weyrich et al. fit the dipole of Jensen et al. 2001 to each contact-sensor
profile and report point values of σ's and σa (hence σtr = sqrt(3σa(σa + σ's)),
eq. 15, and ℓd = 1/σtr).  This module gives their posterior distributions.

One profile (:func:`sigma_posterior`)
-------------------------------------
* **Model**: R(r_k) = :func:`facestats.model.dipole.dipole_profile` (r_k; σ's, σa, η)
  at the fibre distances r_k (mm), in mm⁻².
* **Likelihood**: independent Gaussian per fibre, y_k ~ N(R(r_k), s_k²), with
  s_k from the sensor's noise model evaluated at the *model* profile,
  s_k = :meth:`facestats.acquire.sensor.ContactSensor.profile_std` (R(r_k))
  (shot + read + quantisation noise of the HDR merge), so the variance depends
  on the parameters and the log-likelihood keeps its log-determinant term:
  ln L = −½ Σ_k [(y_k − R_k)²/s_k² + 2 ln s_k] (+ const).  An explicit ``std``
  array (e.g. the stored ``sensor_profile_std``) replaces the noise model.
  Fibres whose reading is missing (NaN: every exposure clipped) are left out.
* **Prior**: log-uniform (flat in ln σ) and independent over physical bounds,
  σ's ∈ [0.01, 100] mm⁻¹ and σa ∈ [1e-5, 10] mm⁻¹ by default (:data:`DEFAULT_BOUNDS`).
  Sampling is in (ln σ's, ln σa), where this prior is flat.
* **Sampler**: emcee's ensemble sampler (Foreman-Mackey et al. 2013) with the
  differential-evolution move (ter Braak 2006; Nelson et al. 2013), evaluated
  with ``vectorize=True``: one numpy call per half-ensemble computes every
  walker *and every channel*.  Channels are independent given their
  parameters, so each channel is an independent 2-parameter block:
  :class:`BlockDEMove` proposes all blocks together and accepts or rejects each
  block on its own log-probability, which makes the run exactly one ensemble
  sampler per channel while sharing the likelihood calls.
* **Start**: walkers drawn around a weighted least-squares fit (coarse grid,
  then :func:`scipy.optimize.least_squares` in log space) with the fit's
  covariance.
* **Convergence**: the integrated autocorrelation time τ of every parameter
  (:func:`emcee.autocorr.integrated_time`) is re-estimated as the chain grows;
  sampling stops once the chain is at least ``min_tau`` (default 50) τ long
  for every parameter, or at ``max_steps``, in which case a
  :class:`facestats.errors.ConvergenceWarning` names the unconverged channels.
  Per channel the first ``burn_in`` τ (default 3) steps are discarded and the
  chain is thinned by ⌊τ/2⌋.  Reported: acceptance fraction, τ, effective
  sample size n_walkers · (steps − burn-in)/τ, medians and equal-tailed
  credible intervals of σ's, σa and the derived σtr and ℓd.

Population (:func:`population_sigma_tr`)
----------------------------------------
The posterior of the mean σtr of each skin type, per channel, from the
per-subject σtr (mean of the cheek and forehead fits, as σtrAvg in §5.4).
Default ``model="hierarchical"``: the normal hierarchical model of Gelman et
al., *Bayesian Data Analysis* (3rd ed.) §5.4-5.5,

    y_ij ~ N(θ_j, σ_w²),  θ_j ~ N(μ, τ²),  p(μ, τ) ∝ 1,

with the within-type variance σ_w² pooled over all types and plugged in
(it is well determined by all subjects; between-subject spread and
measurement noise are both in it).  The skin-type means θ_j borrow strength
from each other (types V and VI have few subjects).  μ and θ are
integrated in closed form and τ on a grid, so the draws are exact, with no
Markov chain to converge.  It needs at least three skin types (the flat prior
on τ gives an improper posterior otherwise).  ``model="independent"`` treats
each type alone with the Jeffreys prior p(θ_j, σ_j) ∝ 1/σ_j: θ_j ~ ȳ_j +
s_j/√n_j · t_{n_j−1}.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass

import emcee
import numpy as np

from facestats.acquire.sensor import ContactSensor
from facestats.analysis.conditions import select_population
from facestats.core.conventions import CHANNELS
from facestats.core.published import ETA_SKIN
from facestats.core.validate import as_float, check_choice, check_finite, check_range, check_shape
from facestats.errors import ConvergenceWarning, ValidationError
from facestats.model import dipole

__all__ = [
    "DEFAULT_BOUNDS",
    "PARAMETERS",
    "BlockDEMove",
    "SigmaPosterior",
    "sigma_posterior",
    "site_sigma_posterior",
    "PopulationSigmaTr",
    "population_sigma_tr",
]

#: Bounds (mm⁻¹) of the log-uniform prior.
DEFAULT_BOUNDS = {"sigma_s_prime": (0.01, 100.0), "sigma_a": (1e-5, 10.0)}
#: Sampled parameters (in this order) and derived ones.
PARAMETERS = ("sigma_s_prime", "sigma_a")
DERIVED = ("sigma_tr", "ell_d")


class BlockDEMove(emcee.moves.RedBlueMove):
    """Differential-evolution ensemble move on independent parameter blocks.

    The parameter vector holds ``n_blocks`` blocks of ``block_dim`` parameters
    whose posteriors are independent (the log-probability factorises over
    blocks).  As in emcee's ``DEMove`` (ter Braak 2006; Nelson et al. 2013) each
    walker of one half of the ensemble proposes q = x + γ (x_a − x_b), with a
    random pair (a, b) of distinct walkers of the other half and
    γ = γ0 (1 + ε N(0, 1)), γ0 = 2.38/sqrt(2 d) for the block dimension d.  The
    proposal is made for all blocks at once but each block is accepted with
    its own Metropolis ratio, which needs the per-block log-probabilities: the
    log-probability function returns them as emcee "blobs" (shape
    (n_walkers, n_blocks)).  Given the pair and γ, which do not depend on the
    walker's position, every block performs a symmetric Metropolis step that
    leaves its own posterior invariant, so the joint chain is the product of
    ``n_blocks`` independent ensemble samplers.

    Acceptance is counted per walker and block in :attr:`accepted`, over
    :attr:`n_proposals` proposals per walker.
    """

    def __init__(self, n_blocks, block_dim, gamma0=None, sigma=1e-5):
        super().__init__(nsplits=2, randomize_split=True, live_dangerously=True)
        self.n_blocks = int(n_blocks)
        self.block_dim = int(block_dim)
        self.g0 = 2.38 / np.sqrt(2 * self.block_dim) if gamma0 is None else float(gamma0)
        self.sigma = float(sigma)
        self.accepted = None
        self.n_proposals = 0

    def propose(self, model, state):
        nw, ndim = state.coords.shape
        k, d = self.n_blocks, self.block_dim
        if ndim != k * d:
            raise ValidationError(f"BlockDEMove: {ndim} parameters are not {k} blocks of {d}")
        if self.accepted is None:
            self.accepted = np.zeros((nw, k), dtype=np.int64)
        blob_shape = np.shape(state.blobs)
        block_lp = np.asarray(state.blobs, dtype=np.float64).reshape(nw, k)
        inds = np.arange(nw) % self.nsplits
        model.random.shuffle(inds)
        any_accepted = np.zeros(nw, dtype=bool)
        for split in range(self.nsplits):
            sel = inds == split
            s, c = state.coords[sel], state.coords[~sel]
            ns, nc = s.shape[0], c.shape[0]
            i1 = model.random.randint(nc, size=ns)
            i2 = (i1 + 1 + model.random.randint(nc - 1, size=ns)) % nc  # a second, distinct walker
            gamma = self.g0 * (1 + self.sigma * model.random.randn(ns, 1))
            q = s + gamma * (c[i1] - c[i2])
            _, new_blobs = model.compute_log_prob_fn(q)
            new_lp = np.asarray(new_blobs, dtype=np.float64).reshape(ns, k)
            old_lp = block_lp[sel]
            with np.errstate(invalid="ignore"):
                accept = np.log(model.random.rand(ns, k)) < new_lp - old_lp  # NaN (-inf - -inf) rejects
            moved = np.where(accept[..., None], q.reshape(ns, k, d), s.reshape(ns, k, d)).reshape(ns, ndim)
            lp = np.where(accept, new_lp, old_lp)
            state.coords[sel] = moved
            block_lp[sel] = lp
            state.log_prob[sel] = lp.sum(axis=1)
            self.accepted[sel] += accept
            any_accepted[sel] = accept.any(axis=1)
        state.blobs = block_lp.reshape(blob_shape)
        self.n_proposals += 1
        return state, any_accepted


@dataclass(frozen=True)
class SigmaPosterior:
    """Posterior samples and diagnostics of (σ's, σa) for one or more profiles (channels).

    Attributes
    ----------
    labels : tuple of str
        Channel (or profile) labels.
    samples : dict of str to pandas.DataFrame
        Per label, thinned post-burn-in samples with columns ``sigma_s_prime``,
        ``sigma_a``, ``sigma_tr`` (mm⁻¹) and ``ell_d`` (mm).
    summary : pandas.DataFrame
        Index (label, parameter); columns ``median``, ``mean``, ``std``, ``lo``,
        ``hi`` (equal-tailed credible interval at ``level``).
    diagnostics : pandas.DataFrame
        Per label: ``tau_sigma_s_prime``, ``tau_sigma_a`` (steps), ``acceptance``,
        ``burn_in``, ``thin``, ``n_samples``, ``ess_sigma_s_prime``,
        ``ess_sigma_a``, ``steps_over_tau``, ``converged`` and ``chi2_dof``
        (χ² per degree of freedom at the posterior median: ≈ 1 when the
        dipole and the noise model describe the data; much larger values mean
        a model mismatch, and intervals that are too narrow).
    least_squares : pandas.DataFrame
        The weighted least-squares start per label (``sigma_s_prime``, ``sigma_a``).
    level : float
    n_walkers, n_steps : int
    bounds : dict
    noise : str
        ``"sensor model"`` or ``"explicit std"``.
    """

    labels: tuple
    samples: dict
    summary: object
    diagnostics: object
    least_squares: object
    level: float
    n_walkers: int
    n_steps: int
    bounds: dict
    noise: str

    @property
    def converged(self) -> bool:
        """True if every channel's chain is at least ``min_tau`` autocorrelation times long."""
        return bool(self.diagnostics["converged"].all())

    def median(self, parameter) -> np.ndarray:
        """Posterior median of a parameter per label."""
        return self.summary.xs(parameter, level="parameter")["median"].loc[list(self.labels)].to_numpy()

    def interval(self, parameter, level=None) -> np.ndarray:
        """Equal-tailed credible interval per label, shape (n_labels, 2) (default: ``self.level``)."""
        if level is None:
            t = self.summary.xs(parameter, level="parameter").loc[list(self.labels)]
            return t[["lo", "hi"]].to_numpy()
        q = [(1 - level) / 2, (1 + level) / 2]
        return np.array([np.quantile(self.samples[lab][parameter].to_numpy(), q) for lab in self.labels])


def _validate_profiles(r, profile, std):
    r_a = check_range(check_finite(as_float(r, "r", np.float64), "r"), "r", 0, None, low_inclusive=False, unit="mm")
    check_shape(r_a, "r", (None,))
    y = as_float(profile, "profile", np.float64)
    if y.ndim == 1:
        y = y[:, None]
    if y.ndim != 2 or y.shape[0] != r_a.shape[0]:
        raise ValidationError(
            f"profile must have shape ({r_a.shape[0]},) or ({r_a.shape[0]}, K) to match r, got {np.shape(profile)}"
        )
    if np.any(np.isinf(y)):
        raise ValidationError("profile must not hold infinite values (NaN marks a missing fibre)")
    s = None
    if std is not None:
        s = as_float(std, "std", np.float64)
        if s.ndim == 1:
            s = s[:, None]
        if s.shape != y.shape:
            raise ValidationError(f"std must have the shape of profile {y.shape}, got {np.shape(std)}")
        bad = np.isfinite(y) & ~(np.isfinite(s) & (s > 0))
        if bad.any():
            raise ValidationError(
                f"std must be finite and > 0 where profile is given, got {int(bad.sum())} bad value(s)"
            )
    mask = np.isfinite(y)
    few = mask.sum(axis=0) < 3
    if few.any():
        raise ValidationError(f"profile needs at least 3 valid fibres per channel, got {mask.sum(axis=0).tolist()}")
    return r_a, y, s, mask


def _check_level(level) -> float:
    """A credible level in the open interval (0, 1)."""
    lv = check_shape(as_float(level, "level", np.float64), "level", ())
    check_range(lv, "level", 0, 1, low_inclusive=False, high_inclusive=False)
    return float(lv)


def _bounds(bounds):
    b = dict(DEFAULT_BOUNDS)
    if bounds:
        for key, val in bounds.items():
            check_choice(key, "bounds key", PARAMETERS)
            b[key] = tuple(float(v) for v in val)
    for key, (lo, hi) in b.items():
        if not (0 < lo < hi < np.inf):
            raise ValidationError(f"bounds[{key!r}] must satisfy 0 < low < high < inf (mm^-1), got {(lo, hi)}")
    return b


class _LogPosterior:
    """Vectorised log-posterior of K independent (ln σ's, ln σa) blocks.

    Called with θ of shape (n, 2K) it returns an (n, 1 + K) array: the total
    log-probability, then one column per block (the emcee blobs that
    :class:`BlockDEMove` uses).
    """

    def __init__(self, r, y, std, mask, sensor, eta, lo, hi):
        self.r = r[None, :, None]
        self.y = np.where(mask, y, 0.0)[None]
        self.std = None if std is None else np.where(mask, std, 1.0)[None]
        self.mask = mask[None]
        self.sensor = sensor
        self.eta = eta
        self.lo, self.hi = lo, hi  # (2,) bounds of (ln σ's, ln σa)
        self.k = y.shape[1]

    def _residuals(self, theta):
        """Standardised residuals (y − R)/s and ln s, shape (n, F, K), and the in-bounds mask (n, K)."""
        th = np.asarray(theta, dtype=np.float64).reshape(-1, self.k, 2)
        inside = np.all((th >= self.lo) & (th <= self.hi), axis=-1)
        e = np.exp(np.clip(th, self.lo, self.hi))
        mu = dipole.dipole_profile_unchecked(self.r, e[:, None, :, 0], e[:, None, :, 1], self.eta)  # (n, F, K)
        sd = self.sensor.profile_std(mu) if self.std is None else self.std
        with np.errstate(invalid="ignore"):
            return (self.y - mu) / sd, np.log(sd), inside

    def blocks(self, theta):
        """Log-posterior (up to a constant) per block, shape (n, K); −inf outside the prior bounds."""
        z, log_sd, inside = self._residuals(theta)
        ll = -0.5 * np.sum(np.where(self.mask, z * z + 2 * log_sd, 0.0), axis=1)
        ll[~np.isfinite(ll)] = -np.inf
        return np.where(inside, ll, -np.inf)

    def chi2(self, theta):
        """Σ over valid fibres of the squared standardised residuals, shape (n, K)."""
        z, _, _ = self._residuals(theta)
        return np.sum(np.where(self.mask, z * z, 0.0), axis=1)

    def __call__(self, theta):
        b = self.blocks(theta)
        return np.concatenate([b.sum(axis=1, keepdims=True), b], axis=1)


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


def _least_squares_start(post, y, std_fixed, mask):
    """Weighted least-squares (ln σ's, ln σa) and its covariance per block: grid search, then trust-region least squares."""
    from scipy.optimize import least_squares

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


def _initial_walkers(post, theta, cov, n_walkers, rng):
    """Walkers ~ N(θ̂, Σ̂) per block, inside the bounds and at finite log-probability."""
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


def sigma_posterior(
    r,
    profile,
    std=None,
    *,
    sensor=None,
    eta=ETA_SKIN,
    labels=None,
    bounds=None,
    n_walkers=16,
    min_tau=50.0,
    burn_in=3.0,
    max_steps=20000,
    initial_steps=500,
    level=0.9,
    seed=0,
):
    """Posterior of (σ's, σa) per channel of a contact-sensor profile, with σtr and ℓd (Weyrich et al. 2006 §5.4, eq. 15).

    See the module docstring for the model, likelihood (sensor noise model,
    heteroscedastic with its log-determinant), prior (log-uniform), sampler
    (emcee, vectorised, channels as independent blocks) and convergence rules.

    Parameters
    ----------
    r : array_like, shape (F,)
        Fibre distances from the source in mm (``ContactSensor().fiber_distance``).
    profile : array_like, shape (F,) or (F, K)
        Measured R(r) in mm⁻² per channel (K = 3 for R, G, B); NaN marks a
        missing fibre.
    std : array_like, optional
        Standard deviation of ``profile`` (same shape, mm⁻²).  Default: the
        noise model of ``sensor`` evaluated at the model profile.
    sensor : ContactSensor, optional
        Sensor whose :meth:`~facestats.acquire.sensor.ContactSensor.profile_std`
        is the noise model (default ``ContactSensor()``).
    eta : float
        Relative index of refraction (1.38 for skin).
    labels : sequence of str, optional
        Labels of the K columns (default R, G, B for K = 3, else 0..K−1).
    bounds : dict, optional
        Prior bounds in mm⁻¹ overriding :data:`DEFAULT_BOUNDS`.
    n_walkers : int
        Walkers (even, ≥ 8).
    min_tau : float
        Required chain length in autocorrelation times (≥ 50 recommended by emcee).
    burn_in : float
        Burn-in in autocorrelation times.
    max_steps : int
        Cap on the chain length; reaching it unconverged warns.
    initial_steps : int
        Steps before the first autocorrelation estimate.
    level : float
        Credible level of the reported intervals (0.9: 5 %-95 %).
    seed : int
        Seed of the sampler.

    Returns
    -------
    SigmaPosterior

    Warns
    -----
    ConvergenceWarning
        If a channel's chain is shorter than ``min_tau`` τ at ``max_steps``, or
        its acceptance fraction is below 0.05.
    """
    import pandas as pd

    r_a, y, s, mask = _validate_profiles(r, profile, std)
    k = y.shape[1]
    if labels is None:
        labels = CHANNELS if k == 3 else tuple(str(i) for i in range(k))
    labels = tuple(str(lab) for lab in labels)
    if len(labels) != k:
        raise ValidationError(f"labels must have {k} entries (one per profile column), got {len(labels)}")
    if int(n_walkers) < 8 or int(n_walkers) % 2:
        raise ValidationError(f"n_walkers must be an even number >= 8, got {n_walkers!r}")
    level = _check_level(level)
    if min_tau <= 0 or burn_in < 0 or int(max_steps) < int(initial_steps) or int(initial_steps) < 50:
        raise ValidationError(
            f"need min_tau > 0, burn_in >= 0, initial_steps >= 50 and max_steps >= initial_steps, got "
            f"{min_tau}, {burn_in}, {initial_steps}, {max_steps}"
        )
    sensor = ContactSensor() if sensor is None else sensor
    b = _bounds(bounds)
    lo = np.log([b[p][0] for p in PARAMETERS])
    hi = np.log([b[p][1] for p in PARAMETERS])
    post = _LogPosterior(r_a, y, s, mask, sensor, float(eta), lo, hi)
    std_fixed = s if s is not None else np.where(mask, sensor.profile_std(np.maximum(np.nan_to_num(y), 0.0)), 1.0)
    theta_ls, cov_ls = _least_squares_start(post, np.where(mask, y, 0.0), std_fixed, mask)
    rng = np.random.default_rng(seed)
    p0 = _initial_walkers(post, theta_ls, cov_ls, int(n_walkers), rng)

    move = BlockDEMove(k, 2)
    sampler = emcee.EnsembleSampler(int(n_walkers), 2 * k, post, vectorize=True, moves=[move])
    sampler.random_state = np.random.RandomState(int(rng.integers(2**31 - 1))).get_state()
    state, steps, chunk = p0, 0, int(initial_steps)
    while True:
        state = sampler.run_mcmc(state, chunk, progress=False, skip_initial_state_check=True)
        steps += chunk
        tau = emcee.autocorr.integrated_time(sampler.get_chain(), tol=0, quiet=True).reshape(k, 2)
        tau = np.where(np.isfinite(tau), tau, np.inf)
        need = min_tau * tau.max()
        if steps >= need or steps >= int(max_steps):
            break
        chunk = int(min(int(max_steps) - steps, max(100, np.ceil(1.1 * need) - steps)))

    chain = sampler.get_chain()  # (steps, walkers, 2K) in ln σ
    acceptance = move.accepted.mean(axis=0) / move.n_proposals
    q = [(1 - level) / 2, 0.5, (1 + level) / 2]
    samples, summary_rows, diag_rows = {}, [], []
    medians = np.empty((k, 2))
    for j, lab in enumerate(labels):
        tau_j = tau[j]
        tmax = tau_j.max()
        converged = bool(np.isfinite(tmax) and steps >= min_tau * tmax)
        if np.isfinite(tmax):
            burn = int(np.ceil(burn_in * tmax))
            thin = max(1, int(tmax / 2))
        else:
            burn, thin = steps // 2, 1
        burn = min(burn, steps - 1)
        x = np.exp(chain[burn::thin, :, 2 * j : 2 * j + 2].reshape(-1, 2))
        sig_tr = dipole.transport_coefficient(x[:, 1], x[:, 0])
        frame = pd.DataFrame(
            {
                "sigma_s_prime": x[:, 0],
                "sigma_a": x[:, 1],
                "sigma_tr": sig_tr,
                "ell_d": dipole.diffuse_mean_free_path(sig_tr),
            }
        )
        samples[lab] = frame
        for name in PARAMETERS + DERIVED:
            v = frame[name].to_numpy()
            lo_q, med, hi_q = np.quantile(v, q)
            summary_rows.append(
                {
                    "label": lab,
                    "parameter": name,
                    "median": med,
                    "mean": v.mean(),
                    "std": v.std(ddof=1),
                    "lo": lo_q,
                    "hi": hi_q,
                }
            )
        n_after = (steps - burn) * int(n_walkers)
        medians[j] = np.log(np.median(x, axis=0))
        diag_rows.append(
            {
                "label": lab,
                "tau_sigma_s_prime": tau_j[0],
                "tau_sigma_a": tau_j[1],
                "acceptance": acceptance[j],
                "burn_in": burn,
                "thin": thin,
                "n_samples": len(frame),
                "ess_sigma_s_prime": n_after / tau_j[0],
                "ess_sigma_a": n_after / tau_j[1],
                "steps_over_tau": steps / tmax,
                "converged": converged,
            }
        )
    diagnostics = pd.DataFrame.from_records(diag_rows).set_index("label")
    diagnostics["chi2_dof"] = post.chi2(medians.reshape(1, -1))[0] / np.maximum(mask.sum(axis=0) - 2, 1)
    bad = diagnostics.index[~diagnostics["converged"]].tolist()
    if bad:
        warnings.warn(
            f"sigma_posterior: chains of {bad} are shorter than {min_tau:g} autocorrelation times after {steps} steps "
            f"(steps/tau = {diagnostics.loc[bad, 'steps_over_tau'].round(1).tolist()}); raise max_steps, and treat "
            "their intervals as unreliable",
            ConvergenceWarning,
            stacklevel=2,
        )
    low_acc = diagnostics.index[diagnostics["acceptance"] < 0.05].tolist()
    if low_acc:
        warnings.warn(
            f"sigma_posterior: acceptance fraction below 0.05 for {low_acc}; the chains hardly move",
            ConvergenceWarning,
            stacklevel=2,
        )
    ls = pd.DataFrame(np.exp(theta_ls), index=pd.Index(labels, name="label"), columns=list(PARAMETERS))
    summary = pd.DataFrame.from_records(summary_rows).set_index(["label", "parameter"])
    return SigmaPosterior(
        labels,
        samples,
        summary,
        diagnostics,
        ls,
        float(level),
        int(n_walkers),
        int(steps),
        b,
        "sensor model" if s is None else "explicit std",
    )


def _sensor_of(ds):
    """The ContactSensor recorded with a subject's sensor data, if any (else None)."""
    for attrs in (ds["sensor_profile"].attrs, ds.attrs):
        val = attrs.get("sensor")
        if val is None and "provenance" in attrs:
            try:
                val = json.loads(attrs["provenance"]).get("sensor") if isinstance(attrs["provenance"], str) else None
            except ValueError:
                val = None
        if isinstance(val, str):
            try:
                val = json.loads(val)
            except ValueError:
                val = None
        if isinstance(val, dict) and "fiber_distance_mm" in val:
            return ContactSensor.from_attrs(val)
    return None


def site_sigma_posterior(dataset, site, *, std="model", sensor=None, **kwargs):
    """:func:`sigma_posterior` of one measurement site of a subject Dataset (``store.subject(id)``).

    Parameters
    ----------
    dataset : xarray.Dataset
        A subject with ``sensor_profile`` (and ``sensor_profile_std``) on
        (site, fiber, channel) and the ``fiber_distance`` coordinate (mm).
    site : {"cheek", "forehead", "neck"}
    std : {"model", "stored"}
        ``"model"``: the sensor noise model at the model profile (default);
        ``"stored"``: the stored ``sensor_profile_std``.
    sensor : ContactSensor, optional
        Default: the sensor recorded with the data (``sensor`` attribute or
        provenance entry), else ``ContactSensor()``.
    **kwargs
        Passed to :func:`sigma_posterior`.
    """
    check_choice(std, "std", ("model", "stored"))
    if "sensor_profile" not in dataset.data_vars:
        raise ValidationError(f"subject {dataset.attrs.get('subject_id', '?')!r} has no sensor_profile")
    sites = [str(x) for x in dataset["site"].values]
    check_choice(site, "site", sites)
    prof = dataset["sensor_profile"].sel(site=site).transpose("fiber", "channel")
    r = np.asarray(dataset["fiber_distance"].values, dtype=np.float64)
    s = None
    if std == "stored":
        s = dataset["sensor_profile_std"].sel(site=site).transpose("fiber", "channel").values
    sensor = sensor or _sensor_of(dataset) or ContactSensor()
    labels = tuple(str(c) for c in prof["channel"].values)
    return sigma_posterior(r, prof.values, s, sensor=sensor, labels=labels, **kwargs)


@dataclass(frozen=True)
class PopulationSigmaTr:
    """Posterior of the mean σtr (mm⁻¹) of each skin type, per channel.

    Attributes
    ----------
    summary : pandas.DataFrame
        Index (skin_type, channel); columns ``n`` (subjects), ``sample_mean``,
        ``median``, ``mean``, ``lo``, ``hi`` (credible interval at ``level``).
    draws : ndarray, shape (n_draws, n_types, 3)
        Posterior draws of the skin-type means θ_j.
    skin_types : tuple of int
    hyper : pandas.DataFrame or None
        Hierarchical model only: per channel, the pooled within-type standard
        deviation ``sigma_w`` and posterior median and interval of the
        population mean ``mu`` and the between-type spread ``tau``.
    model : str
    level : float
    """

    summary: object
    draws: np.ndarray
    skin_types: tuple
    hyper: object
    model: str
    level: float


def _hierarchical_draws(ybar, var, n_draws, rng):
    """Draws of (θ_j, μ, τ) of the normal hierarchical model with known variances (Gelman et al. BDA3 §5.4).

    ybar_j ~ N(θ_j, var_j), θ_j ~ N(μ, τ²), p(μ, τ) ∝ 1.  p(τ | y) on a grid:
    p(τ|y) ∝ V_μ^{1/2} Π_j (var_j + τ²)^{-1/2} exp(−(ȳ_j − μ̂)²/(2(var_j + τ²))),
    μ̂ = Σ ȳ_j/(var_j + τ²) / Σ 1/(var_j + τ²), V_μ = 1/Σ 1/(var_j + τ²); then
    μ | τ ~ N(μ̂, V_μ) and θ_j | μ, τ ~ N((ȳ_j τ² + μ var_j)/(var_j + τ²), var_j τ²/(var_j + τ²)).
    """
    scale = float(np.sqrt(np.var(ybar) + np.max(var)))
    tau = np.concatenate([[0.0], np.geomspace(1e-4 * scale, 100 * scale, 4000)])
    tot = var[None, :] + tau[:, None] ** 2  # (T, J)
    v_mu = 1 / np.sum(1 / tot, axis=1)
    mu_hat = v_mu * np.sum(ybar[None] / tot, axis=1)
    logp = 0.5 * np.log(v_mu) - 0.5 * np.sum(np.log(tot) + (ybar[None] - mu_hat[:, None]) ** 2 / tot, axis=1)
    dens = np.exp(logp - logp.max())
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(tau))])
    cdf /= cdf[-1]
    tau_d = np.interp(rng.uniform(size=n_draws), cdf, tau)  # inverse-CDF draws of τ (piecewise linear)
    tot_d = var[None, :] + tau_d[:, None] ** 2
    v_mu_d = 1 / np.sum(1 / tot_d, axis=1)
    mu_d = v_mu_d * np.sum(ybar[None] / tot_d, axis=1) + np.sqrt(v_mu_d) * rng.standard_normal(n_draws)
    t2 = tau_d[:, None] ** 2
    mean = (ybar[None] * t2 + mu_d[:, None] * var[None]) / tot_d
    sd = np.sqrt(var[None] * t2 / tot_d)
    theta = mean + sd * rng.standard_normal(mean.shape)
    return theta, mu_d, tau_d


def population_sigma_tr(
    source,
    model="hierarchical",
    subjects=None,
    conditions=("normal",),
    level=0.9,
    n_draws=20000,
    seed=0,
    group_i_ii=True,
):
    """Posterior of the mean σtr per skin type and channel (see the module docstring for both models).

    Parameters
    ----------
    source : store or pandas.DataFrame
        Parameter store or its population index (columns ``site_sigma_tr_{site}_{ch}``).
    model : {"hierarchical", "independent"}
    subjects, conditions
        Population selection (:func:`facestats.analysis.conditions.select_population`).
    level : float
        Credible level.
    n_draws : int
        Posterior draws.
    seed : int
    group_i_ii : bool
        Group skin types I and II, as the paper does (default).

    Returns
    -------
    PopulationSigmaTr
    """
    import pandas as pd
    from scipy import stats

    from facestats.analysis.translucency import subject_sigma_tr

    check_choice(model, "model", ("hierarchical", "independent"))
    level = _check_level(level)
    frame = select_population(source, subjects, conditions)
    sig = subject_sigma_tr(frame)
    types = frame["skin_type"].astype(int)
    if group_i_ii:
        types = types.clip(lower=2)
    rng = np.random.default_rng(seed)
    skin_types = tuple(int(t) for t in sorted(types[sig.notna().all(axis=1)].unique()))
    if not skin_types:
        raise ValidationError("no selected subject has cheek or forehead sigma_tr in all channels")
    q = [(1 - level) / 2, 0.5, (1 + level) / 2]
    draws = np.full((int(n_draws), len(skin_types), len(CHANNELS)), np.nan)
    rows, hyper_rows = [], []
    for c, ch in enumerate(CHANNELS):
        ok = sig[ch].notna()
        y, t = sig.loc[ok, ch].to_numpy(float), types[ok].to_numpy()
        groups = [y[t == st] for st in skin_types]
        n = np.array([g.size for g in groups])
        ybar = np.array([g.mean() if g.size else np.nan for g in groups])
        if model == "hierarchical":
            present = n > 0
            dof = n.sum() - present.sum()
            if present.sum() < 3 or dof < 1:
                raise ValidationError(
                    f"the hierarchical model needs >= 3 skin types and more subjects than types, got types "
                    f"{[st for st, k in zip(skin_types, n) if k]} with {int(n.sum())} subjects (use model='independent')"
                )
            s_w2 = sum(float(np.sum((g - g.mean()) ** 2)) for g in groups if g.size) / dof
            theta, mu_d, tau_d = _hierarchical_draws(ybar[present], s_w2 / n[present], int(n_draws), rng)
            draws[:, present, c] = theta
            mq, tq = np.quantile(mu_d, q), np.quantile(tau_d, q)
            hyper_rows.append(
                {
                    "channel": ch,
                    "sigma_w": np.sqrt(s_w2),
                    "mu_median": mq[1],
                    "mu_lo": mq[0],
                    "mu_hi": mq[2],
                    "tau_median": tq[1],
                    "tau_lo": tq[0],
                    "tau_hi": tq[2],
                }
            )
        else:
            for j, g in enumerate(groups):
                if g.size >= 2:
                    se = g.std(ddof=1) / np.sqrt(g.size)
                    draws[:, j, c] = g.mean() + se * stats.t.rvs(g.size - 1, size=int(n_draws), random_state=rng)
        for j, st in enumerate(skin_types):
            d = draws[:, j, c]
            if np.all(np.isfinite(d)):
                lo_q, med, hi_q = np.quantile(d, q)
                mean = d.mean()
            else:
                lo_q = med = hi_q = mean = np.nan
            rows.append(
                {
                    "skin_type": st,
                    "channel": ch,
                    "n": int(n[j]),
                    "sample_mean": ybar[j],
                    "median": med,
                    "mean": mean,
                    "lo": lo_q,
                    "hi": hi_q,
                }
            )
    summary = pd.DataFrame.from_records(rows).set_index(["skin_type", "channel"])
    hyper = pd.DataFrame.from_records(hyper_rows).set_index("channel") if hyper_rows else None
    return PopulationSigmaTr(summary, draws, skin_types, hyper, model, float(level))
