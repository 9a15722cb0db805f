"""Fresnel reflectance and transmittance of a smooth dielectric boundary.

Conventions
-----------
* ``cos_theta`` is the cosine of the angle between the incident direction and the
  surface normal, measured in the medium the light arrives from, in [0, 1].
* ``eta`` is the *relative* index of refraction n_t / n_i of the medium the light
  enters over the medium it comes from.  Light going from air into skin uses
  ``eta = 1.38`` (Weyrich et al. 2006, §3, after Tuchin 2000); light inside skin
  hitting the boundary uses ``1 / 1.38``, and total internal reflection then
  occurs beyond the critical angle.
* Light is unpolarised: the reflectance is the mean of the s and p reflectances.

References
----------
Born & Wolf, *Principles of Optics*, §1.5 (Fresnel equations).
Weyrich et al. 2006, eq. 6 (F_t at entry and exit) and eq. 12 (F_r at ωo·H).
Jensen et al. 2001 / Suzuki, Mukaigawa & Yagi, eq. 9 (diffuse Fresnel reflectance).
"""

from __future__ import annotations

import numpy as np

from facestats.core.blocked import blockwise
from facestats.core.published import ETA_SKIN
from facestats.core.validate import as_finite, as_scalar, check_broadcastable, check_range, result_dtype
from facestats.errors import ValidationError

__all__ = ["fresnel_reflectance", "fresnel_transmittance", "diffuse_fresnel_reflectance"]

#: Tolerance for cosines that overshoot [0, 1] by floating-point rounding.
_COS_TOL = 1e-6


def fresnel_reflectance_unchecked(cos_i, eta):
    """Unpolarised Fresnel reflectance without input checks (internal fast path).

    Uses the equivalent closed form of Cook & Torrance (1982), with
    g = sqrt(η² − 1 + cos²θi):

        F_r = ½ ((g − c)/(g + c))² [1 + ((c(g + c) − 1)/(c(g − c) + 1))²],  c = cos θi,

    which equals (r_s² + r_p²)/2 of the Fresnel equations and needs no trigonometry;
    g² < 0 is total internal reflection (F_r = 1).  ``cos_i`` must lie in [0, 1];
    ``eta`` broadcasts against it.
    """
    dtype = result_dtype(cos_i, eta)
    c = np.asarray(cos_i, dtype=dtype)
    eta = np.asarray(eta, dtype=dtype)
    g2 = eta * eta - 1 + c * c
    g = np.sqrt(np.maximum(g2, 0))
    gpc = g + c
    gmc = g - c
    with np.errstate(invalid="ignore", divide="ignore"):  # 0/0 only at η = 1, grazing
        a = gmc / gpc
        b = (c * gpc - 1) / (c * gmc + 1)
        out = 0.5 * a * a * (1 + b * b)
    out = np.where((g2 <= 0) | ~np.isfinite(out), dtype.type(1), out)
    return out.astype(dtype, copy=False)


def fresnel_reflectance_slope_unchecked(cos_i, eta):
    """dF_r/d cos θi of :func:`fresnel_reflectance_unchecked` (float64, no input checks).

    Differentiating the closed form F_r = ½ a² (1 + b²) with a = (g − c)/(g + c),
    b = N/M, N = c(g + c) − 1, M = c(g − c) + 1, g = sqrt(η² − 1 + c²) (so
    dg/dc = c/g and c² − g² = 1 − η²):

        da/dc = 2 (1 − η²) / (g (g + c)²),
        dN/dc = g + c²/g + 2c,   dM/dc = g + c²/g − 2c,   db/dc = (N' M − N M')/M²,
        dF_r/dc = a a' (1 + b²) + a² b b'.

    0 under total internal reflection (F_r = 1 there); checked against central
    differences of :func:`fresnel_reflectance_unchecked` in the tests.  ``cos_i`` in (0, 1].
    """
    c = np.asarray(cos_i, np.float64)
    eta = np.asarray(eta, np.float64)
    g2 = eta * eta - 1 + c * c
    g = np.sqrt(np.maximum(g2, 1e-300))
    gpc, gmc = g + c, g - c
    a = gmc / gpc
    da = 2 * (1 - eta * eta) / (g * gpc * gpc)
    num, den = c * gpc - 1, c * gmc + 1
    dn, dd = g + c * c / g + 2 * c, g + c * c / g - 2 * c
    b = num / den
    db = (dn * den - num * dd) / (den * den)
    return np.where(g2 > 0, a * da * (1 + b * b) + a * a * b * db, 0.0)


def _check_cos(cos_theta, name="cos_theta"):
    """Validate cosines in [0, 1] (rounding overshoot within ``_COS_TOL`` is clipped)."""
    c = as_finite(cos_theta, name)
    bad = (c < -_COS_TOL) | (c > 1 + _COS_TOL)
    if np.any(bad):
        raise ValidationError(f"{name} must lie in [0, 1], got {c[bad].reshape(-1)[0].item()!r}")
    return np.clip(c, 0, 1)


def check_eta(eta, scalar: bool = False):
    """Validate a relative index of refraction: finite and > 0 (with ``scalar``, one number, returned as float)."""
    if scalar:
        return as_scalar(eta, "eta", 0.0, None, low_inclusive=False)
    return as_finite(eta, "eta", 0.0, None, low_inclusive=False)


def fresnel_reflectance(cos_theta, eta=ETA_SKIN):
    """Unpolarised Fresnel reflectance F_r of a smooth dielectric boundary.

    F_r = (r_s² + r_p²) / 2 with r_s = (cos θi − η cos θt)/(cos θi + η cos θt),
    r_p = (η cos θi − cos θt)/(η cos θi + cos θt) and sin θt = sin θi / η
    (Fresnel equations, Born & Wolf §1.5).  At normal incidence this reduces to
    ((η − 1)/(η + 1))².  When η < 1 and sin θi > η the light is totally
    internally reflected and F_r = 1.  At grazing incidence F_r → 1.

    Used by the Torrance-Sparrow BRDF (Weyrich et al. 2006, eq. 12, F_r(ωo·H)).

    Parameters
    ----------
    cos_theta : array_like
        Cosine of the incidence angle in the medium of incidence, in [0, 1]
        (values within 1e-6 outside are clipped as rounding error).
    eta : array_like, optional
        Relative index n_t / n_i, > 0.  Default 1.38 (air into skin).

    Returns
    -------
    ndarray
        Reflectance in [0, 1], broadcast shape of the inputs; float32 if all float
        inputs are float32, else float64.
    """
    c = _check_cos(cos_theta)
    e = check_eta(eta)
    check_broadcastable(cos_theta=c, eta=e)
    with np.errstate(over="ignore"):  # η² of η ≳ 1e154 overflows to inf, which gives the limit F_r = 1 exactly
        return blockwise(fresnel_reflectance_unchecked, [c, e], result_dtype(c, e))


def fresnel_transmittance(cos_theta, eta=ETA_SKIN):
    """Unpolarised Fresnel transmittance F_t = 1 − F_r (energy conservation at the boundary).

    This is the F_t(η, ω) of Weyrich et al. 2006, eq. 6, applied at the entry point
    (F_ti) and the exit point (F_to) of the diffuse subsurface term, and of
    Suzuki et al. eq. 2.  For the exit point the caller passes the cosine of the
    outgoing direction in air and η = 1.38: by reciprocity of the Fresnel
    equations the transmittance from inside to the outside direction ω equals the
    transmittance from outside along ω.

    Parameters
    ----------
    cos_theta : array_like
        Cosine of the incidence angle, in [0, 1] (as :func:`fresnel_reflectance`).
    eta : array_like, optional
        Relative index n_t / n_i, > 0.  Default 1.38 (air into skin).

    Returns
    -------
    ndarray
        Transmittance in [0, 1], broadcast shape of the inputs (a 0-d array for scalars); float32 if all float
        inputs are float32, else float64.

    Raises
    ------
    ValidationError
        As :func:`fresnel_reflectance`: a non-finite or out-of-range cosine or η.
    """
    return np.asarray(1 - fresnel_reflectance(cos_theta, eta))  # a 0-d array for scalars, as fresnel_reflectance


def diffuse_fresnel_reflectance_unchecked(eta):
    """Egan & Hilgeman polynomial for F_dr, valid for η ≥ 1 (no input checks; see
    :func:`diffuse_fresnel_reflectance`, Suzuki et al. eq. 9 with the sign corrected)."""
    return -1.440 / (eta * eta) + 0.710 / eta + 0.668 + 0.0636 * eta


def diffuse_fresnel_reflectance(eta=ETA_SKIN):
    """Diffuse Fresnel reflectance F_dr of the dipole boundary condition.

    F_dr = −1.440/η² + 0.710/η + 0.668 + 0.0636 η
    (Egan & Hilgeman 1979, as used by Jensen et al. 2001 and printed in
    Suzuki, Mukaigawa & Yagi, eq. 9).

    This is the *internal* hemispherical (cosine-weighted) reflectance seen by
    diffuse light inside a medium of relative index η hitting its boundary with
    air, F_dr = 2∫₀¹ F_r(μ, 1/η) μ dμ, including total internal reflection; about
    0.514 at η = 1.38.

    Seed typo resolved: the seed text prints ``− 0.710/η``.  With that sign F_dr is
    negative for η below about 1.88 (−0.515 at η = 1.38), which is impossible for a
    reflectance; with ``+ 0.710/η`` the polynomial matches the numerical integral
    2∫ F_r(μ, 1/η) μ dμ to within 0.3 % over η ∈ [1.2, 1.6] (checked in
    ``tests/model/test_fresnel.py``).  The dipole uses it through
    A = (1 + F_dr)/(1 − F_dr) (Jensen et al. 2001; see :mod:`facestats.model.dipole`).

    Parameters
    ----------
    eta : array_like
        Relative index of the medium over air, in [1, 3] (the polynomial's range of
        validity; it is ≈ 0 at η = 1 and increasing in η).

    Returns
    -------
    ndarray
        F_dr in (0, 1) for η > 1.
    """
    e = check_eta(eta)
    check_range(e, "eta", 1.0, 3.0)
    return diffuse_fresnel_reflectance_unchecked(e)
