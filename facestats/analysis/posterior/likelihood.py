"""The posterior density of the dipole parameters of one contact-sensor profile (Weyrich et al. 2006 §5.4).

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

Channels are independent given their parameters: :class:`LogPosterior`
evaluates K channels as K independent 2-parameter blocks in one numpy call.
"""

from __future__ import annotations

import numpy as np

from facestats.core.validate import as_float, check_choice, check_finite, check_range, check_shape
from facestats.errors import ValidationError
from facestats.model import dipole

__all__ = ["DEFAULT_BOUNDS", "PARAMETERS", "DERIVED", "validate_profiles", "prior_bounds", "LogPosterior"]

#: Bounds (mm⁻¹) of the log-uniform prior.
DEFAULT_BOUNDS = {"sigma_s_prime": (0.01, 100.0), "sigma_a": (1e-5, 10.0)}
#: Sampled parameters (in this order) and derived ones.
PARAMETERS = ("sigma_s_prime", "sigma_a")
DERIVED = ("sigma_tr", "ell_d")


def validate_profiles(r, profile, std):
    """Checked fibre distances, profiles (F, K), their std (or None) and the mask of valid fibres.

    Parameters
    ----------
    r : array_like, shape (F,)
        Fibre distances in mm, finite and > 0.
    profile : array_like, shape (F,) or (F, K)
        Readings in mm⁻², one column per channel (block); NaN marks a missing fibre.
    std : array_like or None
        Standard deviations of the readings in mm⁻², the shape of ``profile``; None to use the sensor's noise model.

    Returns
    -------
    r : numpy.ndarray, shape (F,)
        Distances as float64.
    y : numpy.ndarray, shape (F, K)
        Profiles as float64 (a 1-D profile becomes one column), NaN kept.
    s : numpy.ndarray, shape (F, K), or None
        ``std`` as float64, or None if it was None.
    mask : numpy.ndarray of bool, shape (F, K)
        True where the reading is finite.

    Raises
    ------
    ValidationError
        For non-positive or non-finite distances, mismatched shapes, infinite
        readings, a bad ``std`` where a reading is given, or fewer than three
        valid fibres in a channel.
    """
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


def prior_bounds(bounds):
    """:data:`DEFAULT_BOUNDS` overridden by ``bounds``, checked: 0 < low < high < inf (mm⁻¹).

    Parameters
    ----------
    bounds : dict or None
        ``{name: (low, high)}`` in mm⁻¹ for some of :data:`PARAMETERS`; None or empty keeps the defaults.

    Returns
    -------
    dict
        ``{name: (low, high)}`` as floats for every key of :data:`DEFAULT_BOUNDS`.

    Raises
    ------
    ValidationError
        For a key not in :data:`PARAMETERS`, or bounds that do not satisfy 0 < low < high < inf.
    """
    b = dict(DEFAULT_BOUNDS)
    if bounds:
        for key, val in bounds.items():
            check_choice(key, "bounds key", PARAMETERS)
            pair = np.asarray(as_float(val, f"bounds[{key!r}]", dtype=np.float64))
            b[key] = tuple(float(v) for v in check_shape(pair, f"bounds[{key!r}] (low, high)", (2,)))
    for key, (lo, hi) in b.items():
        if not (0 < lo < hi < np.inf):
            raise ValidationError(f"bounds[{key!r}] must satisfy 0 < low < high < inf (mm^-1), got {(lo, hi)}")
    return b


class LogPosterior:
    """Vectorised log-posterior of K independent (ln σ's, ln σa) blocks.

    Called with θ of shape (n, 2K) it returns an (n, 1 + K) array: the total
    log-probability, then one column per block (the emcee blobs that
    :class:`facestats.analysis.posterior.moves.BlockDEMove` uses).

    The inputs are taken as checked (:func:`validate_profiles`, :func:`prior_bounds`); the constructor does not
    check them again.

    Parameters
    ----------
    r : numpy.ndarray, shape (F,)
        Fibre distances in mm.
    y : numpy.ndarray, shape (F, K)
        Measured profiles in mm⁻², one column per block; values where ``mask`` is False are ignored (NaN allowed).
    std : numpy.ndarray, shape (F, K), or None
        Standard deviations of ``y`` in mm⁻²; None to use ``sensor``'s noise model at the model profile.
    mask : numpy.ndarray of bool, shape (F, K)
        True for the fibres that enter the likelihood.
    sensor : ContactSensor
        Its :meth:`~facestats.acquire.sensor.ContactSensor.profile_std` is the noise model when ``std`` is None.
    eta : float
        Relative index of refraction of the dipole.
    lo, hi : numpy.ndarray, shape (2,)
        Prior bounds of (ln σ's, ln σa), natural log of mm⁻¹.
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
        """Log-posterior (up to a constant) per block, shape (n, K); −inf outside the prior bounds.

        Parameters
        ----------
        theta : array_like, shape (n, 2K) or (2K,)
            Parameters per sample, (ln σ's, ln σa) of block 1, then of block 2, …, natural log of mm⁻¹.

        Returns
        -------
        numpy.ndarray, shape (n, K)
            ln L per block (prior flat inside the bounds); −inf outside them or where ln L is not finite.
        """
        z, log_sd, inside = self._residuals(theta)
        ll = -0.5 * np.sum(np.where(self.mask, z * z + 2 * log_sd, 0.0), axis=1)
        ll[~np.isfinite(ll)] = -np.inf
        return np.where(inside, ll, -np.inf)

    def chi2(self, theta):
        """Σ over valid fibres of the squared standardised residuals, shape (n, K).

        Parameters
        ----------
        theta : array_like, shape (n, 2K) or (2K,)
            Parameters as in :meth:`blocks`; values outside the prior bounds are clipped to them (no −inf here).

        Returns
        -------
        numpy.ndarray, shape (n, K)
            χ² per sample and block.
        """
        z, _, _ = self._residuals(theta)
        return np.sum(np.where(self.mask, z * z, 0.0), axis=1)

    def __call__(self, theta):
        """The log posterior of ``theta`` and its blocks: columns (total, block 1, block 2, ...)."""
        b = self.blocks(theta)
        return np.concatenate([b.sum(axis=1, keepdims=True), b], axis=1)
