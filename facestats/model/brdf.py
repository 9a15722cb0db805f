"""Analytic specular BRDFs of the skin model: Blinn-Phong and Torrance-Sparrow.

Conventions
-----------
* ``normal``, ``wi`` (towards the light) and ``wo`` (towards the viewer) are unit
  3-vectors on the last axis, all pointing *away* from the surface, in any common
  frame.  They broadcast against each other and against the parameter arrays.
* Where ``wi`` or ``wo`` is at or below the horizon (N·ω ≤ 0) the BRDF is 0.
* BRDF values are in sr⁻¹.  δ is the angle between the normal N and the half-way
  vector H = (ωi + ωo)/‖ωi + ωo‖.
* Results are float32 if every float input is float32, else float64.
* Every public function checks its arguments (numeric, finite, in its domain)
  and its result: a finite input gives a finite result or a
  :class:`~facestats.errors.ValidationError` naming the parameters, never inf
  or NaN.  The building blocks (:func:`beckmann_distribution`,
  :func:`v_groove_shadowing`, :func:`blinn_phong_lobe`,
  :func:`torrance_sparrow_cosines`) have ``*_unchecked`` twins (not in
  ``__all__``) for kernels that evaluate them on already valid arrays.

References
----------
Weyrich et al. 2006, *Analysis of Human Faces using a Measurement-Based Skin
Reflectance Model*, SIGGRAPH, eq. 11 (Blinn-Phong) and eq. 12-13
(Torrance-Sparrow).
"""

from __future__ import annotations

import numpy as np

from facestats.core.blocked import blockwise, components
from facestats.core.published import ETA_SKIN
from facestats.core.validate import (
    as_finite,
    as_float,
    check_broadcastable,
    check_shape,
    check_unit_vectors,
    finite_result,
    result_dtype,
)
from facestats.model.fresnel import check_eta, fresnel_reflectance_unchecked

__all__ = [
    "half_vector",
    "beckmann_distribution",
    "v_groove_shadowing",
    "blinn_phong_lobe",
    "torrance_sparrow_geometry",
    "torrance_sparrow_cosines",
    "blinn_phong",
    "blinn_phong_albedo",
    "torrance_sparrow",
]

_UNIT_TOL = 1e-3


def check_directions(value, name):
    """Validate finite unit 3-vectors on the last axis (norm 1 within ``_UNIT_TOL``)."""
    v = as_finite(value, name)
    check_shape(v, name, (..., 3))
    check_unit_vectors(v, name, _UNIT_TOL)
    return v


def _dot(a, b):
    """Dot products over the last axis."""
    return np.einsum("...k,...k->...", a, b) if a.shape == b.shape else np.sum(a * b, axis=-1)


def half_vector(wi, wo):
    """Half-way vector H = (ωi + ωo) / ‖ωi + ωo‖ (Weyrich et al. 2006, eq. 11-13).

    For ωi = −ωo (undefined H) the result is NaN; callers only use H for pairs
    above the horizon, where it is always defined.  ``wi`` and ``wo`` are unit
    3-vectors on the last axis, broadcast against each other; their shapes are
    checked, their norms are not.

    Parameters
    ----------
    wi, wo : array_like
        (..., 3) directions towards the light and towards the viewer (unit vectors, not checked).

    Returns
    -------
    ndarray
        (..., 3) H, unit vectors, broadcast shape of ``wi`` and ``wo``.

    Raises
    ------
    ValidationError
        Non-numeric input, a last axis other than 3, or shapes that do not broadcast.
    """
    a = check_shape(as_float(wi, "wi"), "wi", (..., 3))
    b = check_shape(as_float(wo, "wo"), "wo", (..., 3))
    check_broadcastable(wi=a, wo=b)
    h = a + b
    with np.errstate(invalid="ignore", divide="ignore"):
        return h / np.sqrt(_dot(h, h))[..., None]


def beckmann_distribution_unchecked(cos_delta, m):
    """D of :func:`beckmann_distribution` without input checks (kernels' fast path)."""
    c2 = cos_delta * cos_delta
    tan2 = (1 - c2) / c2
    m2 = m * m
    return np.exp(-tan2 / m2) / (m2 * c2 * c2)


def beckmann_distribution(cos_delta, m):
    """Beckmann microfacet distribution D exactly as printed in Weyrich et al. 2006, eq. 13.

    D = exp(−(tan δ / m)²) / (m² cos⁴ δ)

    Convention: **no 1/π factor** (the Cook-Torrance form).  The normalised Beckmann
    distribution, whose projected area ∫ D cos δ dω integrates to one, is D/π; in
    Weyrich's eq. 12 that π is supplied by the ρs/π prefactor.  Fitted ρs values
    depend on this convention (see :func:`torrance_sparrow`).

    Parameters
    ----------
    cos_delta : array_like
        cos δ = N·H in (0, 1].
    m : array_like
        RMS micro-facet slope (roughness), > 0, dimensionless.

    Returns
    -------
    ndarray
        D, dimensionless (per unit solid angle once divided by π), broadcast shape
        of the inputs (a building block of :func:`torrance_sparrow`; kernels use
        :func:`beckmann_distribution_unchecked`).

    Raises
    ------
    ValidationError
        Non-numeric, non-finite or out-of-domain arguments, or finite arguments
        whose D leaves the float range (e.g. m = 1e-200, whose m² underflows).
    """
    c = as_finite(cos_delta, "cos_delta", 0, 1, low_inclusive=False)
    m_a = as_finite(m, "m", 0, None, low_inclusive=False)
    dtype = result_dtype(cos_delta, m)
    with np.errstate(over="ignore", under="ignore", invalid="ignore", divide="ignore"):
        out = beckmann_distribution_unchecked(c.astype(dtype, copy=False), m_a.astype(dtype, copy=False))
    return finite_result(out, "beckmann_distribution", cos_delta=c, m=m_a)


def v_groove_shadowing_unchecked(n_h, n_wi, n_wo, wo_h):
    """G of :func:`v_groove_shadowing` without input checks (kernels' fast path)."""
    return np.minimum(1, 2 * n_h * np.minimum(n_wi, n_wo) / wo_h)  # the same min: every factor is positive


def v_groove_shadowing(n_h, n_wi, n_wo, wo_h):
    """Torrance-Sparrow V-groove masking/shadowing term G (Weyrich et al. 2006, eq. 13).

    G = min{1, 2(N·H)(N·ωo)/(ωo·H), 2(N·H)(N·ωi)/(ωo·H)}

    The seed prints ωo·H in both denominators; since H bisects ωi and ωo,
    ωi·H = ωo·H, so the printed form equals the symmetric Cook-Torrance form and G
    is reciprocal.

    Parameters
    ----------
    n_h, n_wi, n_wo, wo_h : array_like
        The cosines N·H, N·ωi, N·ωo and ωo·H, > 0 (directions above the horizon).

    Returns
    -------
    ndarray
        G, dimensionless, in (0, 1], broadcast shape of the inputs (kernels use
        :func:`v_groove_shadowing_unchecked`).

    Raises
    ------
    ValidationError
        A non-numeric, non-finite or non-positive cosine (named).
    """
    names = ("n_h", "n_wi", "n_wo", "wo_h")
    args = (n_h, n_wi, n_wo, wo_h)
    checked = [as_finite(v, name, 0, None, low_inclusive=False) for v, name in zip(args, names)]
    dtype = result_dtype(*args)
    cos = [c.astype(dtype, copy=False) for c in checked]
    with np.errstate(over="ignore"):
        out = v_groove_shadowing_unchecked(*cos)
    return finite_result(out, "v_groove_shadowing", **dict(zip(names, cos)))


def blinn_phong_lobe_unchecked(cos_delta, exponent):
    """The lobe of :func:`blinn_phong_lobe` without input checks (kernels' fast path)."""
    return (exponent + 2) / (2 * np.pi) * cos_delta**exponent


def blinn_phong_lobe(cos_delta, exponent):
    """Normalised Blinn-Phong lobe (n + 2)/(2π) cosⁿ δ (Weyrich et al. 2006, eq. 11 without ρs).

    The factor (n + 2)/(2π) makes the cosine-weighted lobe over half-vector
    directions integrate to one: ∫ (n+2)/(2π) cosⁿ δ cos δ dω_H = 1.

    Parameters
    ----------
    cos_delta : array_like
        cos δ = N·H in [0, 1].
    exponent : array_like
        The specular exponent n ≥ 0.

    Returns
    -------
    ndarray
        The lobe in sr⁻¹, broadcast shape of the inputs (kernels use
        :func:`blinn_phong_lobe_unchecked`).

    Raises
    ------
    ValidationError
        Non-numeric, non-finite or out-of-domain arguments (named).
    """
    c = as_finite(cos_delta, "cos_delta", 0, 1)
    n = as_finite(exponent, "exponent", 0, None)
    dtype = result_dtype(cos_delta, exponent)
    with np.errstate(over="ignore", under="ignore"):
        out = blinn_phong_lobe_unchecked(c.astype(dtype, copy=False), n.astype(dtype, copy=False))
    return finite_result(out, "blinn_phong_lobe", cos_delta=c, exponent=n)


def _ts_geometry_kernel(nx, ny, nz, ix, iy, iz, ox, oy, oz, eta):
    """cos δ and K = G F_r(ωo·H)/(π N·ωi N·ωo) from vector components (no checks).

    Written on components so that :func:`facestats.core.blocked.blockwise` can stream
    it through the cache; the geometry itself is :func:`torrance_sparrow_cosines`.
    """
    n_wi = nx * ix + ny * iy + nz * iz
    n_wo = nx * ox + ny * oy + nz * oz
    wi_wo = ix * ox + iy * oy + iz * oz
    return torrance_sparrow_cosines_unchecked(n_wi, n_wo, wi_wo, eta)


def torrance_sparrow_cosines_unchecked(n_wi, n_wo, wi_wo, eta=ETA_SKIN):
    """cos δ and K of :func:`torrance_sparrow_cosines` without input checks (kernels' fast path)."""
    dtype = np.result_type(n_wi, np.float32)
    one = dtype.type(1)
    above = (n_wi > 0) & (n_wo > 0)
    everywhere = bool(np.all(above))  # the fitter's samples: no masking needed
    if not everywhere:  # evaluate below-horizon samples at N·ωi = N·ωo = ωi·ωo = 1 (N·H = 1), K = 0 below
        n_wi, n_wo, wi_wo = (np.where(above, x, one) for x in (n_wi, n_wo, wi_wo))
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = 1 / np.sqrt(np.maximum(2 + 2 * wi_wo, 0))
    tiny = np.finfo(dtype).tiny
    n_h = np.clip((n_wi + n_wo) * inv, tiny, one)
    wo_h = np.clip((1 + wi_wo) * inv, tiny, one)
    g = v_groove_shadowing_unchecked(n_h, n_wi, n_wo, wo_h)
    k = g * fresnel_reflectance_unchecked(wo_h, eta) / (np.pi * n_wi * n_wo)
    if not everywhere:
        k = np.where(above, k, 0)
    return n_h.astype(dtype, copy=False), k.astype(dtype, copy=False)


def torrance_sparrow_cosines(n_wi, n_wo, wi_wo, eta=ETA_SKIN):
    """cos δ and K = G F_r(ωo·H)/(π (N·ωi)(N·ωo)) of eq. 12-13 from three cosines.

    With ‖ωi + ωo‖ = sqrt(2 + 2 ωi·ωo), the half vector gives
    N·H = (N·ωi + N·ωo)/‖ωi + ωo‖ and ωo·H = (1 + ωi·ωo)/‖ωi + ωo‖, so the
    Torrance-Sparrow geometry needs only N·ωi, N·ωo and ωi·ωo; the fitter gathers
    these per sample from small per-lumitexel grids instead of building
    per-sample vectors.  Below the horizon cos δ = 1 and K = 0.

    Parameters
    ----------
    n_wi, n_wo, wi_wo : array_like
        The cosines N·ωi, N·ωo and ωi·ωo (finite; ≤ 0 for N·ω below the horizon).
    eta : array_like, optional
        Relative index of refraction, > 0, default 1.38.

    Returns
    -------
    cos_delta : ndarray
        N·H, clipped to (0, 1]; 1 below the horizon.
    k : ndarray
        K in sr⁻¹; 0 below the horizon.  Both in the broadcast shape of the inputs
        (kernels use :func:`torrance_sparrow_cosines_unchecked`).

    Raises
    ------
    ValidationError
        Non-numeric or non-finite arguments, an invalid ``eta`` (None included),
        or finite cosines whose K leaves the float range (e.g. N·ωi = N·ωo = 1e-300).
    """
    names = ("n_wi", "n_wo", "wi_wo")
    args = (n_wi, n_wo, wi_wo)
    checked = [as_finite(v, name) for v, name in zip(args, names)]
    dtype = result_dtype(*args)
    cos = [c.astype(dtype, copy=False) for c in checked]
    eta_a = check_eta(eta)
    with np.errstate(over="ignore", under="ignore", invalid="ignore", divide="ignore"):
        cos_delta, k = torrance_sparrow_cosines_unchecked(*cos, eta_a)
    return cos_delta, finite_result(k, "torrance_sparrow_cosines (K)", **dict(zip(names, cos)))


def torrance_sparrow_geometry(normal, wi, wo, eta=ETA_SKIN):
    """Parameter-free factors of the Torrance-Sparrow BRDF, for fitting and rendering.

    Splits Weyrich et al. 2006, eq. 12 as f_sTS = ρs · D(cos δ; m) · K with

    K = G · F_r(ωo·H) / (π (N·ωi)(N·ωo))

    so a fitter can evaluate the model for many (ρs, m) at the cost of one
    exponential per sample.  K = 0 where ωi or ωo is at or below the horizon.
    Only the types are checked (numeric arrays, :class:`~facestats.errors.ValidationError`
    otherwise): callers pass unit vectors (see :func:`torrance_sparrow`).

    Parameters
    ----------
    normal, wi, wo : array_like, shape (..., 3)
        Unit vectors pointing away from the surface (shapes checked, norms not).
    eta : array_like, optional
        Relative index of refraction of F_r, default 1.38 (not range-checked).

    Returns
    -------
    cos_delta : ndarray
        N·H, clipped to (0, 1]; set to 1 below the horizon (where K = 0).
    k : ndarray
        The factor K in sr⁻¹ (before multiplication by D), same broadcast shape.
    """
    normal, wi, wo = (as_float(v, name) for v, name in ((normal, "normal"), (wi, "wi"), (wo, "wo")))
    for v, name in ((normal, "normal"), (wi, "wi"), (wo, "wo")):
        check_shape(v, name, (..., 3))
    eta = as_float(eta, "eta")
    check_broadcastable(normal=normal[..., 0], wi=wi[..., 0], wo=wo[..., 0], eta=eta)
    dtype = result_dtype(normal, wi, wo)
    ops = [*components(normal), *components(wi), *components(wo), eta]
    return blockwise(_ts_geometry_kernel, ops, dtype, n_out=2)


def _check_common(normal, wi, wo, rho_s):
    """Validate the arguments both BRDFs take: three unit directions and ρs ≥ 0."""
    return (
        check_directions(normal, "normal"),
        check_directions(wi, "wi"),
        check_directions(wo, "wo"),
        as_finite(rho_s, "rho_s", 0, None),
    )


def blinn_phong_albedo(exponent):
    """Directional albedo at normal incidence of :func:`blinn_phong` per unit ρs (Weyrich et al. 2006, eq. 11).

    a(n) = ∫ (n + 2)/(2π) cosⁿ δ cos θo dωo over the upper hemisphere, with ωi = N (so δ = θo/2).
    Derivation: dωo = 2π sin θo dθo; with u = θo/2 and c = cos u,

        a(n) = 4 (n + 2) ∫_{1/√2}^{1} c^(n+1) (2c² − 1) dc
             = 4 (n + 2) [2 (1 − s^(n+4))/(n + 4) − (1 − s^(n+2))/(n + 2)],   s = 1/√2.

    a(0) = 8 (2 (1 − 1/4)/4 − (1 − 1/2)/2) = 1, 2.30 at n = 5, 3.85 at n = 100, → 4 as n → ∞ (the
    (n + 2)/(2π) normalisation is over half-vectors, not outgoing directions; checked against a midpoint
    integral in ``tests/model/test_brdf.py``).  A texel reflects more than it receives at normal incidence
    where ρs a(n) > 1; oblique incidence puts part of the lobe below the horizon and reflects less.

    Parameters
    ----------
    exponent : array_like
        n ≥ 0.

    Returns
    -------
    ndarray
        a(n), dimensionless, shape of ``exponent``.
    """
    n = as_finite(exponent, "exponent", 0, None).astype(np.float64)
    s = np.sqrt(0.5)
    return 4 * (n + 2) * (2 * (1 - s ** (n + 4)) / (n + 4) - (1 - s ** (n + 2)) / (n + 2))


def blinn_phong(normal, wi, wo, rho_s, exponent):
    """Blinn-Phong specular BRDF, Weyrich et al. 2006, eq. 11.

    f_sBP = ρs (n + 2)/(2π) cosⁿ δ

    with δ the angle between N and H.  Symmetric in ωi and ωo (Helmholtz
    reciprocity).  0 where ωi or ωo is at or below the horizon.

    Seed check (energy): Weyrich et al. state that (n + 2)/(2π) makes "the cosine
    lobe integrate to one" so that ρs = 1 reflects 100 % of the energy.  The lobe
    does integrate to one over *half-vector* directions (∫ lobe · cos δ dω_H = 1,
    checked in ``tests/model/test_brdf.py``), but over outgoing directions
    dωo = 4 (ωo·H) dω_H, and the numerically integrated directional albedo at
    normal incidence is 2.30 ρs at n = 5 and 3.85 ρs at n = 100 (→ 4 ρs).  The
    formula is implemented as printed; energy conservation needs ρs ≲ 1/4, which
    fitted skin values satisfy.

    Parameters
    ----------
    normal, wi, wo : array_like, shape (..., 3)
        Unit vectors pointing away from the surface.
    rho_s : array_like
        Specular scaling coefficient ρs ≥ 0 (dimensionless).
    exponent : array_like
        Specular exponent n ≥ 0 (dimensionless).

    Returns
    -------
    ndarray
        BRDF in sr⁻¹, broadcast shape of the inputs without the vector axis.

    Raises
    ------
    ValidationError
        Invalid arguments, or finite arguments whose BRDF leaves the float range
        (e.g. ρs = 1e308): every finite input gives a finite BRDF or this error.
    """
    normal, wi, wo, rho_s = _check_common(normal, wi, wo, rho_s)
    exponent = as_finite(exponent, "exponent", 0, None)
    check_broadcastable(normal=normal[..., 0], wi=wi[..., 0], wo=wo[..., 0], rho_s=rho_s, exponent=exponent)
    dtype = result_dtype(normal, wi, wo, rho_s, exponent)
    ops = [*components(normal), *components(wi), *components(wo), rho_s, exponent]
    with np.errstate(over="ignore", invalid="ignore"):
        out = blockwise(_bp_kernel, ops, dtype)
    return finite_result(out, "blinn_phong", rho_s=rho_s, exponent=exponent)


def _bp_kernel(nx, ny, nz, ix, iy, iz, ox, oy, oz, rho_s, exponent):
    """Blinn-Phong on vector components (no checks); 0 below the horizon."""
    n_wi = nx * ix + ny * iy + nz * iz
    n_wo = nx * ox + ny * oy + nz * oz
    above = (n_wi > 0) & (n_wo > 0)
    hx, hy, hz = ix + ox, iy + oy, iz + oz
    with np.errstate(invalid="ignore", divide="ignore"):
        n_h = (nx * hx + ny * hy + nz * hz) / np.sqrt(hx * hx + hy * hy + hz * hz)
    n_h = np.where(above, np.clip(n_h, 0, 1), 0)
    return np.where(above, rho_s * blinn_phong_lobe_unchecked(n_h, exponent), 0)


def torrance_sparrow(normal, wi, wo, rho_s, m, eta=ETA_SKIN):
    """Torrance-Sparrow specular BRDF exactly as printed in Weyrich et al. 2006, eq. 12-13.

    f_sTS = (ρs/π) · D G / ((N·ωi)(N·ωo)) · F_r(ωo·H)

    with the Beckmann D of eq. 13 **without 1/π** (:func:`beckmann_distribution`),
    the V-groove G of eq. 13 (:func:`v_groove_shadowing`) and the unpolarised
    Fresnel reflectance F_r at ωo·H for relative index η
    (:func:`facestats.model.fresnel.fresnel_reflectance`).

    Convention and consequence for ρs: ρs/π · D equals ρs times the *normalised*
    Beckmann distribution, so this model is ρs·4 times the usual Cook-Torrance
    microfacet BRDF D_norm G F / (4 cosθi cosθo); ρs = 1/4 is a surface made
    entirely of Fresnel mirror facets.  Fitted ρs are in this convention, which is
    the one of the published MERL/ETH statistics.

    Symmetric in ωi and ωo (G and F_r are, because ωi·H = ωo·H), so the BRDF obeys
    Helmholtz reciprocity.  0 where ωi or ωo is at or below the horizon.

    Parameters
    ----------
    normal, wi, wo : array_like, shape (..., 3)
        Unit vectors pointing away from the surface.
    rho_s : array_like
        Specular scaling coefficient ρs ≥ 0.
    m : array_like
        Beckmann roughness m > 0 (RMS slope).
    eta : float or array_like, optional
        Relative index of refraction of skin, default 1.38 (Weyrich §3).

    Returns
    -------
    ndarray
        BRDF in sr⁻¹, broadcast shape of the inputs without the vector axis.

    Raises
    ------
    ValidationError
        Invalid arguments, or finite arguments whose BRDF leaves the float range
        (e.g. ρs = 1e308, or m = 1e-200, whose peak 1/m² no float holds):
        every finite input gives a finite BRDF or this error, never inf or NaN.
    """
    normal, wi, wo, rho_s = _check_common(normal, wi, wo, rho_s)
    m = as_finite(m, "m", 0, None, low_inclusive=False)
    eta_a = check_eta(eta)
    check_broadcastable(normal=normal[..., 0], wi=wi[..., 0], wo=wo[..., 0], rho_s=rho_s, m=m, eta=eta_a)
    dtype = result_dtype(normal, wi, wo, rho_s, m, eta)
    ops = [*components(normal), *components(wi), *components(wo), eta_a, rho_s, m]
    with np.errstate(over="ignore", invalid="ignore", under="ignore", divide="ignore"):
        out = blockwise(_ts_kernel, ops, dtype)
    return finite_result(out, "torrance_sparrow", rho_s=rho_s, m=m)


def _ts_kernel(nx, ny, nz, ix, iy, iz, ox, oy, oz, eta, rho_s, m):
    """Torrance-Sparrow on vector components (no checks): ρs · D(cos δ; m) · K."""
    cos_delta, k = _ts_geometry_kernel(nx, ny, nz, ix, iy, iz, ox, oy, oz, eta)
    return rho_s * beckmann_distribution_unchecked(cos_delta, m) * k
