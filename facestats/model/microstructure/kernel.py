"""The kernel family of displacement-map convolution: k = (1 − α) δ + α G(σ) (Nagano et al. 2015 eq. 6).

Nagano, Fyffe, Alexander, Barbič, Li, Ghosh, Debevec 2015, *Skin Microstructure
Deformation with Displacement Map Convolution*, §5 "Deformation Model": a
two-parameter family of 1-D kernels from sharpening (α < 0) through the
identity (α = 0) to blurring (α > 0), −2 ≤ α ≤ 1, with G the normalised
discrete Gaussian of standard deviation σ.

Discretisation pinned down here (the paper leaves it open):

* σ is given in µm of skin and becomes texels through the texel size:
  ``σ_px = σ_µm / texel_µm``.
* Taps at integer steps i = −R … R along the axis (1-texel spacing), with
  ``R = ceil(TRUNCATE · σ_px)``, TRUNCATE = 3; ``G_i = exp(−i² / (2 σ_px²)) /
  Σ_j exp(−j² / (2 σ_px²))`` (renormalised after truncation), so Σ k = 1 for
  every α and α = 0 is the identity exactly.  σ_px = 0 gives G = δ.
* Frequency response (real, the kernel is symmetric): ``K(ω) = 1 − α + α Ĝ(ω)``
  with ``Ĝ(ω) = Σ_i G_i cos(ω i)``, Ĝ(0) = 1.  The truncated Gaussian's Ĝ dips
  slightly below 0 (measured with :func:`frequency_response`: minimum −1.35e-3
  over σ_px ∈ [0.1, 150]; GAUSSIAN_RESPONSE_FLOOR = 2e-3 bounds it), so blurring kernels
  (0 ≤ α ≤ 1) satisfy ``1 − α − α·floor ≤ K(ω) ≤ 1`` and sharpening ones
  (α < 0) ``1 ≤ K(ω) ≤ 1 − α (1 + floor)``: blurs never amplify and sharpening
  gains at most 1 + |α|.
* For 0 ≤ α ≤ 1 every tap is ≥ 0 and they sum to 1: the output lies between the
  minimum and maximum of the input (maximum principle); sharpening kernels have
  negative side taps and can overshoot.
"""

from __future__ import annotations

import math

import numpy as np

from facestats.core.validate import as_finite, as_scalar
from facestats.errors import ValidationError

__all__ = [
    "ALPHA_RANGE",
    "SIGMA_RANGE_UM",
    "TRUNCATE",
    "MAX_RADIUS",
    "GAUSSIAN_RESPONSE_FLOOR",
    "kernel_radius",
    "gaussian_taps",
    "kernel_taps",
    "frequency_response",
    "check_alpha",
    "check_sigma",
]

#: Filter strength range of eq. 6 (−2 sharpest, 0 identity, 1 pure Gaussian).
ALPHA_RANGE = (-2.0, 1.0)
#: Gaussian standard deviations searched by the paper's fit (§5 "Parameter Fitting"), µm.
SIGMA_RANGE_UM = (1.0, 100.0)
#: The Gaussian is truncated at TRUNCATE standard deviations (then renormalised).
TRUNCATE = 3.0
#: Largest half-width R of a discrete Gaussian, taps (σ up to 1365 texels; 100 µm at 0.07 µm per texel).
MAX_RADIUS = 4096
#: Bound of how far below 0 the truncated, renormalised Gaussian's response dips (see module docstring).
GAUSSIAN_RESPONSE_FLOOR = 2e-3


def check_alpha(alpha, name="alpha") -> np.ndarray:
    """α as a finite float array in [−2, 1] (eq. 6), else a ValidationError naming ``name``.

    Parameters
    ----------
    alpha : array_like
        Filter strength α of eq. 6.
    name : str
        The argument's name, for the message.

    Returns
    -------
    ndarray
        α as float32 or float64 (float64 for integer input), shape of ``alpha``.

    Raises
    ------
    ValidationError
        A non-numeric or non-finite α, or one outside [−2, 1].
    """
    return as_finite(alpha, name, *ALPHA_RANGE)


def check_sigma(sigma_um, name="sigma") -> np.ndarray:
    """σ as a finite float array in [1, 100] µm (the fitted range of §5), else a ValidationError.

    Parameters
    ----------
    sigma_um : array_like
        Gaussian standard deviation σ, µm of skin.
    name : str
        The argument's name, for the message.

    Returns
    -------
    ndarray
        σ in µm as float32 or float64 (float64 for integer input), shape of ``sigma_um``.

    Raises
    ------
    ValidationError
        A non-numeric or non-finite σ, or one outside [1, 100] µm.
    """
    return as_finite(sigma_um, name, *SIGMA_RANGE_UM, unit="um")


def kernel_radius(sigma_px) -> np.ndarray:
    """Half-width R = ceil(TRUNCATE · σ_px) of the discrete Gaussian, in taps (int).

    Parameters
    ----------
    sigma_px : array_like
        Gaussian standard deviation in texels (not validated).

    Returns
    -------
    ndarray or numpy.int64
        R, int64, shape of ``sigma_px`` (a scalar for a scalar).
    """
    return np.ceil(TRUNCATE * np.asarray(sigma_px, np.float64)).astype(np.int64)


def gaussian_taps(sigma_px: float) -> np.ndarray:
    """The truncated, renormalised discrete Gaussian G (eq. 6) of ``sigma_px`` texels, taps −R … R.

    Parameters
    ----------
    sigma_px : float
        Standard deviation in texels, finite and ≥ 0 (0 gives the unit impulse).

    Returns
    -------
    ndarray of float64, shape (2R + 1,)
        The taps, summing to 1 (R = :func:`kernel_radius`; a single 1 for σ_px = 0).

    Raises
    ------
    ValidationError
        A ``sigma_px`` that is not one number (a string, an array), negative or not finite, or one whose radius
        exceeds :data:`MAX_RADIUS`.
    """
    s = as_scalar(sigma_px, "sigma_px", 0.0)
    if s == 0:
        return np.ones(1)
    if TRUNCATE * s > MAX_RADIUS:  # compared as floats: a huge sigma's radius does not fit an integer
        raise ValidationError(
            f"sigma_px={s:g} texels needs a kernel of {2 * math.ceil(TRUNCATE * s) + 1} taps, more than the "
            f"{2 * MAX_RADIUS + 1} allowed (MAX_RADIUS); check sigma and the texel size (same unit, um)"
        )
    r = int(kernel_radius(s))
    i = np.arange(-r, r + 1, dtype=np.float64)
    if 2 * s * s == 0:  # sigma so far below a texel that its square underflows: the Gaussian is a unit impulse
        return (i == 0).astype(np.float64)
    g = np.exp(-(i * i) / (2 * s * s))
    return g / g.sum()


def kernel_taps(alpha: float, sigma_um: float, texel_um: float) -> np.ndarray:
    """The 1-D kernel k = (1 − α) δ + α G(σ) of eq. 6, taps −R … R (they sum to 1).

    Parameters
    ----------
    alpha : float
        Filter strength, −2 ≤ α ≤ 1 (< 0 sharpens, 0 identity, > 0 blurs).
    sigma_um : float
        Gaussian standard deviation, µm of skin (any value ≥ 0 here; the
        fitting range [1, 100] µm is enforced by the map-level functions).
    texel_um : float
        Texel size along the kernel's axis, µm.

    Returns
    -------
    ndarray, shape (2R + 1,)
        The taps, summing to 1.
    """
    a = as_scalar(alpha, "alpha", *ALPHA_RANGE)  # check_alpha of one number
    s = as_scalar(sigma_um, "sigma_um", 0.0, unit="um")
    t = as_scalar(texel_um, "texel_um", 0.0, low_inclusive=False, unit="um")
    k = a * gaussian_taps(s / t)
    k[len(k) // 2] += 1.0 - a
    return k


def frequency_response(taps, omega) -> np.ndarray:
    """Real frequency response Σ_i k_i cos(ω i) of a symmetric kernel (taps −R … R), ω in rad/texel.

    Parameters
    ----------
    taps : array_like, shape (2R + 1,)
        The kernel, centre tap in the middle (e.g. :func:`kernel_taps`).
    omega : array_like
        Angular frequencies, rad/texel.

    Returns
    -------
    ndarray of float64
        K(ω), shape of ``omega``.
    """
    k = np.asarray(taps, np.float64)
    i = np.arange(len(k)) - len(k) // 2
    return np.cos(np.multiply.outer(np.asarray(omega, np.float64), i)) @ k
