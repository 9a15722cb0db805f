"""The dipole diffusion approximation of subsurface scattering (Jensen et al. 2001).

Conventions
-----------
* Lengths in mm; ``sigma_a`` (absorption), ``sigma_s_prime`` (reduced scattering)
  and ``sigma_tr`` (effective transport) in mm⁻¹; the profile R_d(r) in mm⁻²
  (outgoing exitance per unit incident flux per unit area).
* ``eta`` is the relative index of the medium over air (1.38 for skin, Weyrich
  et al. 2006 §3; 1.3 in Jensen et al. 2001 and Suzuki et al.).
* Results are float32 if every float input is float32, else float64.

Notation (Suzuki, Mukaigawa & Yagi, eq. 3-13, which is Jensen et al. 2001):

    σ't = σ's + σa                       (eq. 11)
    α'  = σ's / σ't                      (eq. 12, the reduced albedo)
    σtr = sqrt(3 σa σ't)                 (eq. 10; Weyrich eq. 15)
    z_r = 1/σ't,  z_v = z_r (1 + 4A/3)   (eq. 6-7)
    A   = (1 + F_dr)/(1 − F_dr)          (eq. 8, corrected, see boundary_coefficient)
    d_r = sqrt(r² + z_r²),  d_v = sqrt(r² + z_v²)      (eq. 4-5)
    R_d(r) = α'/(4π) [ z_r (σtr + 1/d_r) e^{−σtr d_r}/d_r²
                     + z_v (σtr + 1/d_v) e^{−σtr d_v}/d_v² ]   (eq. 3)
"""

from __future__ import annotations

import numpy as np

from facestats.core.blocked import blockwise
from facestats.core.published import ETA_SKIN
from facestats.core.validate import as_finite, as_float, check_broadcastable, check_range, finite_result, result_dtype
from facestats.errors import FitError, ValidationError
from facestats.model.fresnel import check_eta, diffuse_fresnel_reflectance_unchecked

__all__ = [
    "boundary_coefficient",
    "dipole_profile",
    "dipole_radial_energy",
    "total_diffuse_reflectance",
    "transport_coefficient",
    "diffuse_mean_free_path",
    "reduced_albedo",
    "scattering_from_albedo",
]


def dipole_coefficients(sigma_s_prime, sigma_a):
    """Validate (σ's, σa) in mm⁻¹: finite, ≥ 0, and not both 0 anywhere."""
    s = as_finite(sigma_s_prime, "sigma_s_prime", 0, None, unit="mm^-1")
    a = as_finite(sigma_a, "sigma_a", 0, None, unit="mm^-1")
    check_broadcastable(sigma_s_prime=s, sigma_a=a)
    if np.any((s <= 0) & (a <= 0)):
        raise ValidationError(
            "sigma_s_prime + sigma_a must be > 0 mm^-1 "
            "(a medium that neither scatters nor absorbs has no dipole), got 0"
        )
    return s, a


def check_dipole_eta(eta):
    """Validate the relative index of the dipole: finite, in [1, 3] (range of the F_dr polynomial)."""
    e = check_eta(eta)
    return check_range(e, "eta", 1.0, 3.0)


def _boundary(eta):
    """A = (1 + F_dr)/(1 − F_dr) without input checks (see :func:`boundary_coefficient`)."""
    fdr = diffuse_fresnel_reflectance_unchecked(eta)
    return (1 + fdr) / (1 - fdr)


def boundary_coefficient(eta=ETA_SKIN):
    """Boundary mismatch coefficient A = (1 + F_dr)/(1 − F_dr) (Jensen et al. 2001).

    Seed typo resolved: Suzuki et al. eq. 8 prints A = (1 − F_dr)/(1 − F_dv).
    There is no F_dv in the model; the diffusion boundary condition of Jensen et
    al. 2001 (after Groenhuis et al. 1983) gives A = (1 + F_dr)/(1 − F_dr), which
    is also the factor (1 + μ_r)/(1 − μ_r) of Weyrich et al. 2006 eq. 16 with
    μ_r = F_dr.  The profile and the closed-form total reflectance
    (:func:`total_diffuse_reflectance`) share A, so their agreement does not test
    it; the published values do: with this A, Skin1 of Jensen et al. 2001 (η = 1.3)
    gives R_d = 0.436, 0.227, 0.131 (R, G, B) against the tabulated 0.44, 0.22,
    0.13, where A = 1 (no mismatch) would give 0.547, 0.291, 0.161
    (``tests/model/test_dipole.py`` checks the red channel).

    Parameters
    ----------
    eta : array_like, optional
        Relative index of refraction in [1, 3] (range of the F_dr polynomial), default 1.38.

    Returns
    -------
    ndarray
        A, dimensionless, > 1 (3.116 at η = 1.38), the shape and float dtype of ``eta``.

    Raises
    ------
    ValidationError
        A non-numeric or non-finite η, or one outside [1, 3].
    """
    return _boundary(check_dipole_eta(eta))


def _sigma_tr(sigma_a, sigma_t):
    """σtr = sqrt(3 σa σ't) (eq. 10) without overflow; no checks.

    Where the product 3 σa σ't overflows (coefficients near the float range), σtr
    is formed as sqrt(3 σa) sqrt(σ't) instead: the same number without the
    overflow (elsewhere the product form, bit for bit as before).
    """
    with np.errstate(over="ignore"):
        sigma_tr = np.sqrt(3 * sigma_a * sigma_t)
    if not np.all(np.isfinite(sigma_tr)):
        sigma_tr = np.where(np.isfinite(sigma_tr), sigma_tr, np.sqrt(3 * sigma_a) * np.sqrt(sigma_t))
    return sigma_tr


def reduced_albedo_unchecked(sigma_s_prime, sigma_a):
    """α' = σ's/(σ's + σa) (Suzuki eq. 6, Weyrich eq. 16), no checks; where σ's + σa overflows, 1/(1 + σa/σ's).

    The second form is used only there, so every other value keeps the bits of the plain quotient (an overflowing
    sum gave α' = 0: a red team's σ's = σa = 1e308 had a total reflectance of 0 instead of that of α' = 1/2).
    """
    with np.errstate(over="ignore"):
        sigma_t = sigma_s_prime + sigma_a
    alpha = sigma_s_prime / sigma_t
    big = np.isinf(sigma_t)
    if np.any(big):
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            alpha = np.where(big, 1 / (1 + sigma_a / sigma_s_prime), alpha)
    return alpha


def _dipole_terms(sigma_s_prime, sigma_a, eta):
    """σtr, z_r, z_v and α' of the dipole (Suzuki eq. 6-12); no checks."""
    sigma_t = sigma_s_prime + sigma_a
    alpha = sigma_s_prime / sigma_t
    sigma_tr = _sigma_tr(sigma_a, sigma_t)
    a_coef = _boundary(eta)
    z_r = 1 / sigma_t
    z_v = z_r * (1 + 4 * a_coef / 3)
    return sigma_tr, z_r, z_v, alpha


def dipole_profile_unchecked(r, sigma_s_prime, sigma_a, eta):
    """R_d(r) without input checks (internal fast path; see :func:`dipole_profile`)."""
    sigma_tr, z_r, z_v, alpha = _dipole_terms(sigma_s_prime, sigma_a, eta)
    r2 = r * r
    d_r = np.sqrt(r2 + z_r * z_r)
    d_v = np.sqrt(r2 + z_v * z_v)
    real = z_r * (sigma_tr * d_r + 1) * np.exp(-sigma_tr * d_r) / (d_r * d_r * d_r)
    virtual = z_v * (sigma_tr * d_v + 1) * np.exp(-sigma_tr * d_v) / (d_v * d_v * d_v)
    return alpha / (4 * np.pi) * (real + virtual)


def dipole_profile(r, sigma_s_prime, sigma_a, eta=ETA_SKIN):
    """Diffuse subsurface reflectance profile R_d(r) of the dipole, in mm⁻².

    Jensen et al. 2001, as printed in Suzuki, Mukaigawa & Yagi eq. 3-13:

    R_d(r) = α'/(4π) [ z_r (1 + σtr d_r) e^{−σtr d_r} / d_r³
                     + z_v (1 + σtr d_v) e^{−σtr d_v} / d_v³ ]

    (eq. 3 writes each bracket as z (σtr + 1/d) e^{−σtr d}/d², the same thing.)
    Both source terms are added: the real source at depth z_r and the negative
    virtual source at height z_v contribute flux of the same sign at the surface.
    The boundary coefficient uses the corrected A of :func:`boundary_coefficient`
    and the corrected F_dr of
    :func:`facestats.model.fresnel.diffuse_fresnel_reflectance`.

    R_d is positive and strictly decreasing in r, and 2π∫₀^∞ r R_d(r) dr equals
    :func:`total_diffuse_reflectance`.  Every finite input gives a finite
    profile (σtr is formed without overflow; a profile that underflows is 0)
    or, when the coefficients exceed the float range (σ's + σa overflowing),
    a :class:`~facestats.errors.ValidationError`.  This is the R(r) the contact sensor
    measures and the R_d(‖xo − xi‖) of Weyrich et al. 2006 eq. 6.

    Parameters
    ----------
    r : array_like
        Distance between entry and exit points in mm, ≥ 0.
    sigma_s_prime, sigma_a : array_like
        Reduced scattering and absorption coefficients in mm⁻¹, ≥ 0, not both 0.
    eta : array_like, optional
        Relative index of refraction in [1, 3], default 1.38.

    Returns
    -------
    ndarray
        R_d(r) in mm⁻², broadcast shape of the inputs.

    Examples
    --------
    Skin1 of Jensen et al. 2001 (red), the "Skin" curve of Suzuki et al. Fig. 3:

    >>> float(dipole_profile(1.0, 0.74, 0.032, eta=1.3))  # doctest: +ELLIPSIS
    0.0220...
    """
    r_a = as_finite(r, "r", 0, None, unit="mm")
    s, a = dipole_coefficients(sigma_s_prime, sigma_a)
    e = check_dipole_eta(eta)
    check_broadcastable(r=r_a, sigma_s_prime=s, sigma_a=a, eta=e)
    dtype = result_dtype(r, sigma_s_prime, sigma_a, eta)
    with np.errstate(over="ignore", invalid="ignore"):
        out = blockwise(dipole_profile_unchecked, [r_a, s, a, e], dtype)
    return finite_result(out, "dipole_profile", sigma_s_prime=s, sigma_a=a)


def dipole_radial_energy(radius, sigma_s_prime, sigma_a, eta=ETA_SKIN):
    """Fraction of incident flux leaving within ``radius`` of the entry point.

    Closed form of 2π∫₀^ρ r R_d(r) dr.  With d = sqrt(r² + z²), r dr = d dd and
    d/dd[−e^{−σtr d}/d] = (1 + σtr d) e^{−σtr d}/d², each source term integrates to
    2π z [e^{−σtr z}/z − e^{−σtr D}/D], D = sqrt(ρ² + z²), so

    E(ρ) = α'/2 [ e^{−σtr z_r} − z_r e^{−σtr D_r}/D_r + e^{−σtr z_v} − z_v e^{−σtr D_v}/D_v ].

    E(∞) is :func:`total_diffuse_reflectance`.  Used by the skin model to give
    each surface element the exact energy of its own footprint.

    Parameters
    ----------
    radius : array_like
        Radius in mm, ≥ 0 (``inf`` allowed).
    sigma_s_prime, sigma_a, eta
        As :func:`dipole_profile`.

    Returns
    -------
    ndarray
        Dimensionless energy fraction in [0, 1).
    """
    rad = as_float(radius, "radius")
    if np.any(np.isnan(rad)):
        raise ValidationError(
            f"radius must be a number of mm (inf allowed), got {int(np.isnan(rad).sum())} NaN value(s)"
        )
    check_range(rad, "radius", 0, None, unit="mm")
    s, a = dipole_coefficients(sigma_s_prime, sigma_a)
    e = check_dipole_eta(eta)
    check_broadcastable(radius=rad, sigma_s_prime=s, sigma_a=a, eta=e)
    dtype = result_dtype(radius, sigma_s_prime, sigma_a, eta)
    with np.errstate(over="ignore", invalid="ignore"):
        out = np.asarray(
            dipole_radial_energy_unchecked(rad.astype(dtype), s.astype(dtype), a.astype(dtype), e.astype(dtype)), dtype
        )
    return finite_result(out, "dipole_radial_energy", sigma_s_prime=s, sigma_a=a)  # as dipole_profile


def dipole_radial_energy_unchecked(radius, sigma_s_prime, sigma_a, eta):
    """E(ρ) of :func:`dipole_radial_energy` without input checks (E(∞) is handled: the tails vanish)."""
    sigma_tr, z_r, z_v, alpha = _dipole_terms(sigma_s_prime, sigma_a, eta)
    with np.errstate(invalid="ignore", over="ignore"):
        d_r = np.sqrt(radius * radius + z_r * z_r)
        d_v = np.sqrt(radius * radius + z_v * z_v)
        tail_r = np.where(np.isinf(d_r), 0, z_r * np.exp(-sigma_tr * d_r) / d_r)
        tail_v = np.where(np.isinf(d_v), 0, z_v * np.exp(-sigma_tr * d_v) / d_v)
    return alpha / 2 * (np.exp(-sigma_tr * z_r) - tail_r + np.exp(-sigma_tr * z_v) - tail_v)


def total_from_reduced_albedo_unchecked(alpha, eta):
    """Weyrich et al. 2006 eq. 16 as a total reflectance (no checks)."""
    s = np.sqrt(3 * (1 - alpha))
    a_coef = _boundary(eta)
    return alpha / 2 * (1 + np.exp(-4 / 3 * a_coef * s)) * np.exp(-s)


def total_diffuse_reflectance(sigma_s_prime, sigma_a, eta=ETA_SKIN):
    """Total diffuse reflectance R_d = 2π∫₀^∞ r R_d(r) dr of the dipole, closed form.

    Jensen et al. 2001; Weyrich et al. 2006 eq. 16:

    R_d = α'/2 · (1 + e^{−(4/3) A sqrt(3(1 − α'))}) · e^{−sqrt(3(1 − α'))}

    Seed check: Weyrich eq. 16 prints the leading factor α'/(2π) because it is
    written as the BRDF S_BRDF = R_d/π of a diffuse surface; the reflectance that
    the profile integrates to (and that an albedo map stores) has α'/2.  Its
    exponent (1 + μ_r)/(1 − μ_r) is the boundary coefficient A with μ_r = F_dr.
    Derivation: integrating each source term of :func:`dipole_profile` over the
    plane gives (α'/2) e^{−σtr z}, and σtr z_r = sqrt(3(1 − α')),
    σtr z_v = sqrt(3(1 − α'))(1 + 4A/3).  ``tests/model/test_dipole.py`` checks the
    closed form against a numerical integral to 1e-8.

    Published check: Skin1 of Jensen et al. 2001 (σ's = 0.74, σa = 0.032 mm⁻¹,
    η = 1.3, the "Skin" curve of Suzuki et al. Fig. 3) gives 0.436, the tabulated
    R_d = 0.44.

    Parameters
    ----------
    sigma_s_prime, sigma_a : array_like
        Reduced scattering and absorption coefficients in mm⁻¹.
    eta : array_like, optional
        Relative index of refraction in [1, 3], default 1.38.

    Returns
    -------
    ndarray
        Dimensionless total diffuse reflectance in [0, 1).
    """
    s, a = dipole_coefficients(sigma_s_prime, sigma_a)
    e = check_dipole_eta(eta)
    check_broadcastable(sigma_s_prime=s, sigma_a=a, eta=e)
    dtype = result_dtype(sigma_s_prime, sigma_a, eta)
    alpha = reduced_albedo_unchecked(s, a).astype(dtype)
    return np.asarray(total_from_reduced_albedo_unchecked(alpha, e.astype(dtype)), dtype=dtype)


def transport_coefficient(sigma_a, sigma_s_prime):
    """Effective transport coefficient σtr = sqrt(3 σa (σa + σ's)), Weyrich et al. 2006 eq. 15.

    (Suzuki et al. eq. 10-11.)  σtr ≈ 1/ℓd, with ℓd the diffuse mean free path
    in mm (see :func:`diffuse_mean_free_path`).

    Parameters
    ----------
    sigma_a, sigma_s_prime : array_like
        Absorption and reduced scattering coefficients in mm⁻¹, ≥ 0.

    Returns
    -------
    ndarray
        σtr in mm⁻¹.

    Raises
    ------
    ValidationError
        Invalid coefficients, or coefficients so large that σtr (or σa + σ's)
        leaves the float range: finite inputs give a finite σtr or this error.
    """
    s, a = dipole_coefficients(sigma_s_prime, sigma_a)
    dtype = result_dtype(sigma_a, sigma_s_prime)
    with np.errstate(over="ignore"):
        out = np.asarray(_sigma_tr(a, a + s), dtype=dtype)
    return finite_result(out, "transport_coefficient", sigma_a=a, sigma_s_prime=s)


def diffuse_mean_free_path(sigma_tr):
    """Diffuse mean free path ℓd = 1/σtr in mm (Weyrich et al. 2006 eq. 15 and §5.4).

    ℓd measures translucency; Weyrich et al. report subjects with ℓd from
    [1.0904, 0.6376, 0.6035] to [2.8106, 1.2607, 0.6590] mm (R, G, B).

    Parameters
    ----------
    sigma_tr : array_like
        Effective transport coefficient in mm⁻¹, > 0.

    Returns
    -------
    ndarray
        ℓd in mm, the shape and float dtype of ``sigma_tr``.

    Raises
    ------
    ValidationError
        An invalid σtr, or one so small (e.g. 5e-324) that 1/σtr leaves the float range.
    """
    t = as_finite(sigma_tr, "sigma_tr", 0, None, low_inclusive=False, unit="mm^-1")
    with np.errstate(over="ignore", divide="ignore"):
        out = 1 / t
    return finite_result(out, "diffuse_mean_free_path", sigma_tr=t)


#: Largest s = sqrt(3(1 − α')) (α' = 0).
_S_MAX = np.sqrt(3.0)


def _solve_s(total, eta, tol=1e-13, max_iter=100):
    """s = sqrt(3(1 − α')) of a total reflectance, inverting eq. 16 by a bracketing secant (Illinois), in float64.

    Solved in s ∈ [0, √3], where eq. 16 becomes
    g(s) = (1 − s²/3)/2 · (1 + e^{−4As/3}) e^{−s}: smooth and strictly decreasing
    from g(0) = 1 to g(√3) = 0, unlike the α' form whose slope is infinite at α' = 1.
    The Illinois modification of regula falsi keeps the root bracketed while
    converging superlinearly like the secant method.  No input checks; the
    result is float64 whatever the input (callers that need 1 − α' use s²/3,
    which does not cancel as α' → 1).
    """
    total = np.asarray(total, dtype=np.float64)
    eta = np.asarray(eta, dtype=np.float64)
    total, eta = np.broadcast_arrays(total, eta)
    a_coef = _boundary(eta)

    def g(s):
        return (1 - s * s / 3) / 2 * (1 + np.exp(-4 / 3 * a_coef * s)) * np.exp(-s) - total

    lo = np.zeros_like(total)
    hi = np.full_like(total, _S_MAX)
    g_lo, g_hi = g(lo), g(hi)  # g_lo > 0 > g_hi for total in (0, 1)
    s = lo
    for _ in range(max_iter):
        denom = g_hi - g_lo
        with np.errstate(invalid="ignore", divide="ignore"):
            step = np.where(denom != 0, g_hi * (hi - lo) / denom, 0)
        s = hi - step  # secant step, always inside the bracket [lo, hi]
        g_s = g(s)
        same = np.sign(g_s) == np.sign(g_hi)
        # Illinois: halve the retained end-point's value when it is kept twice.
        g_lo = np.where(same, g_lo / 2, g_hi)
        lo = np.where(same, lo, hi)
        hi, g_hi = s, g_s
        if np.all((np.abs(step) <= tol) | (np.abs(g_s) <= 1e-16)):
            break
    else:  # pragma: no cover - the bracket always converges for total in (0, 1)
        raise FitError("reduced_albedo: secant iteration did not converge")
    return s


def _reduced_albedo(total, eta):
    """α' = 1 − s²/3 of :func:`_solve_s`, in the float dtype of ``total`` (no checks)."""
    dtype = np.result_type(total, np.float32)
    s = _solve_s(total, eta)
    return (1 - s * s / 3).astype(dtype if dtype in (np.float32, np.float64) else np.float64)


def reduced_albedo(total_reflectance, eta=ETA_SKIN):
    """Reduced (apparent) albedo α' from a total diffuse reflectance, inverting Weyrich eq. 16.

    Weyrich et al. 2006 §5.4: "Using S_BRDF = α_avg, we compute the apparent albedo
    α' by inverting Equation (16) using a secant root finder."  Here eq. 16 is used
    as a reflectance (leading factor α'/2, see :func:`total_diffuse_reflectance`),
    and the secant iteration is safeguarded by a bracket (Illinois method) and
    vectorised over all inputs.  Round trip error below 1e-9 over (0.01, 0.99).

    Parameters
    ----------
    total_reflectance : array_like
        Total diffuse reflectance (e.g. an average albedo α_avg), strictly in (0, 1).
    eta : array_like, optional
        Relative index of refraction in [1, 3], default 1.38.

    Returns
    -------
    ndarray
        α' = σ's/σ't in (0, 1).

    Raises
    ------
    ValidationError
        If a reflectance lies outside (0, 1): no albedo α' ∈ [0, 1] produces it.
    """
    t = as_finite(total_reflectance, "total_reflectance", 0, 1, low_inclusive=False, high_inclusive=False)
    e = check_dipole_eta(eta)
    check_broadcastable(total_reflectance=t, eta=e)
    dtype = result_dtype(total_reflectance, eta)
    return np.asarray(_reduced_albedo(t, e), dtype=dtype)


def scattering_from_albedo(albedo, sigma_tr, eta=ETA_SKIN):
    """Reduced scattering and absorption coefficients from albedo and σtr (Weyrich et al. 2006 §5.4).

    α' = :func:`reduced_albedo` (albedo) inverts eq. 16, then (Jensen & Buhler 2002)

        σ't = σtr / sqrt(3(1 − α')),  σ's = α' σ't,  σa = σ't − σ's,

    which reproduces σtr exactly: 3 σa σ't = 3 (1 − α') σ't² = σtr².  Weyrich et
    al. use the average albedo α_avg and the population's
    σtrAvg = [0.5508, 0.9791, 1.5497] mm⁻¹.

    Numerics: computed in float64 whatever the input dtype, and written in
    s = sqrt(3(1 − α')) — σ't = σtr/s, σ's = (1 − s²/3) σtr/s, σa = σtr s/3 — so
    nothing cancels as α' → 1.  (Forming 1 − α' from a float32 α' gave σ's = inf
    and σa = NaN for albedo ≥ 0.9995, and the float64 form did so from 1 − 1e-8.)
    Results are finite over the whole open interval (0, 1) in float64: σ's grows
    as (albedo → 1) like σtr/s with s ≥ 3·10⁻¹⁷, i.e. at most ~10¹⁷ σtr; a float32
    result is rounded from the float64 one (and overflow-checked).

    Parameters
    ----------
    albedo : array_like
        Total diffuse reflectance in (0, 1) (per channel, any shape).
    sigma_tr : array_like
        Effective transport coefficient in mm⁻¹, > 0; broadcasts against albedo.
    eta : array_like, optional
        Relative index of refraction, default 1.38.

    Returns
    -------
    sigma_s_prime, sigma_a : ndarray
        In mm⁻¹, broadcast shape of the inputs.
    """
    a = as_finite(albedo, "albedo", 0, 1, low_inclusive=False, high_inclusive=False)
    e = check_dipole_eta(eta)
    t = as_finite(sigma_tr, "sigma_tr", 0, None, low_inclusive=False, unit="mm^-1")
    check_broadcastable(albedo=a, sigma_tr=t, eta=e)
    dtype = result_dtype(albedo, sigma_tr, eta)
    s = np.maximum(_solve_s(a, e), np.finfo(np.float64).eps * 1e-3)
    t = t.astype(np.float64)
    sigma_s_prime = np.asarray((1 - s * s / 3) * t / s, dtype)
    sigma_a = np.asarray(t * s / 3, dtype)
    finite_result(sigma_s_prime, "scattering_from_albedo (sigma_s_prime)", albedo=a, sigma_tr=t)
    return sigma_s_prime, sigma_a
