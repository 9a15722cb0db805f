"""Per-patch light entering and leaving a translucent surface: Suzuki, Mukaigawa & Yagi eq. 15-16.

For a patch with normal N, the light entering the medium is (eq. 16)

    c_k = ∫_Ω L_i(P_k, ω) F_t,i(η, ω) max(0, N·ω) dω,

and the exitance that the dipole predicts from an observed radiance L_o is (eq. 15)

    l_j = π L_o(P_j) / F_t,o(η, ω_o),

which follow from the BSSRDF factorisation S = (1/π) F_t,o R F_t,i (eq. 2): then
L_o = (1/π) F_t,o Σ_k R(d_jk) c_k A_k (eq. 14 with the patch areas A_k of
:mod:`facestats.model.fitting.quantised`), i.e. l_j = Σ_k R(d_jk) c_k A_k.

Light sources (all give c in the unit of their irradiance, e.g. W mm⁻²):

* point lights: E = I max(0, N·ω)/d² (inverse-square law), through
  :func:`facestats.model.skin.point_lights`;
* directional lights: E = E⊥ max(0, N·ω), through
  :func:`facestats.model.skin.directional_lights`;
* environment lighting as a set of directions with their radiance times solid
  angle L·δΩ (the quadrature of eq. 16): each direction is a directional light
  with E⊥ = L·δΩ.  (Resampling a light probe to such directions is the job of a
  light-probe module, not of this one.)

F_t = 1 − F_r is the unpolarised Fresnel transmittance
(:func:`facestats.model.fresnel.fresnel_transmittance`) at relative index η;
Suzuki et al. fix η = 1.3 (§3.2), the default here.  Visibility is the
caller's: ``visible`` (patches × lights) zeroes the light a patch does not
receive (shadows, projector masks); no patch receives light from behind
(max(0, N·ω)).  Colour: intensities and irradiances may carry a channel axis
(last, R G B); results are (m, 3).
"""

from __future__ import annotations

import numpy as np

from facestats.core.validate import as_finite, check_shape
from facestats.errors import ValidationError
from facestats.model.fresnel import fresnel_reflectance_unchecked, fresnel_transmittance
from facestats.model.skin import directional_lights, point_lights

__all__ = [
    "SUZUKI_ETA",
    "point_light_irradiance",
    "directional_light_irradiance",
    "environment_irradiance",
    "exitance_from_radiance",
    "radiance_from_exitance",
]

#: Relative index of refraction assumed by Suzuki et al. §3.2 (after Jensen et al. 2001).
SUZUKI_ETA = 1.3
#: Patches per block of the environment sum (bounds memory to block × directions × 3 doubles).
_ENV_BLOCK = 4096


def _visibility(visible, shape, name="visible"):
    if visible is None:
        return np.ones(shape, bool)
    v = np.asarray(visible)
    if v.dtype != bool:
        raise ValidationError(f"{name} must be a bool array, got dtype {v.dtype}")
    if v.shape != shape:
        raise ValidationError(f"{name} must have shape {shape} (patches, lights), got {v.shape}")
    return v


def _entering(normals, wi, irradiance, visible, eta):
    """Σ_l F_t(N·ω_l) E_l V_l over lights (axis 1): the c of eq. 16 for discrete directions, (m, 3)."""
    cos = np.clip(np.einsum("mk,mlk->ml", normals, wi), 0, 1)
    ft = 1 - fresnel_reflectance_unchecked(cos, float(eta))
    return np.einsum("ml,mlc->mc", ft * visible, irradiance)


def _per_light(value, n_lights, name):
    """A scalar, (L,) or (L, 3) light strength as (L,) or (L, 3) (scalars repeat over lights)."""
    v = as_finite(value, name, 0, None)
    return np.full(n_lights, float(v)) if v.ndim == 0 else v


def _check_eta(eta):
    return float(fresnel_transmittance(1.0, eta))  # validates eta (finite, > 0) with the library's check


def point_light_irradiance(points, normals, positions, intensity, *, visible=None, eta=SUZUKI_ETA):
    """c_k of Suzuki eq. 16 from isotropic point lights: Σ_l F_t,i I_l max(0, N·ω)/d² V, shape (m, 3).

    Parameters
    ----------
    points, normals : array_like, shape (m, 3)
        Patch centres (mm) and unit normals.
    positions : array_like, shape (L, 3)
        Light positions, mm.
    intensity : float or array_like, shape (L,) or (L, 3)
        Radiant intensity per light (and channel), ≥ 0 (e.g. W sr⁻¹).
    visible : array_like of bool, shape (m, L), optional
        Whether patch k receives light l (shadows, projector masks); default all.
    eta : float
        Relative index of refraction of the medium (default 1.3, Suzuki §3.2).

    Returns
    -------
    ndarray, shape (m, 3)
        c_k per channel, in intensity units per mm² (e.g. W mm⁻²).
    """
    _check_eta(eta)
    p = check_shape(as_finite(points, "points"), "points", (None, 3))
    n = as_finite(normals, "normals")
    if n.shape != p.shape:
        raise ValidationError(f"normals must have the shape of points, {p.shape}, got {n.shape}")
    lp = np.atleast_2d(as_finite(positions, "positions"))
    wi, e = point_lights(p, n, lp, _per_light(intensity, lp.shape[0], "intensity"))
    return _entering(n, wi, e, _visibility(visible, (p.shape[0], lp.shape[0])), eta)


def directional_light_irradiance(normals, directions, irradiance, *, visible=None, eta=SUZUKI_ETA):
    """c_k of Suzuki eq. 16 from distant lights: Σ_l F_t,i E⊥_l max(0, N·ω_l) V, shape (m, 3).

    Parameters
    ----------
    normals : array_like, shape (m, 3)
        Unit patch normals.
    directions : array_like, shape (L, 3)
        Unit directions towards the lights.
    irradiance : float or array_like, shape (L,) or (L, 3)
        E⊥, the irradiance on a plane facing each light, ≥ 0 (e.g. W mm⁻²).
    visible : array_like of bool, shape (m, L), optional
    eta : float

    Returns
    -------
    ndarray, shape (m, 3)
    """
    _check_eta(eta)
    n = check_shape(as_finite(normals, "normals"), "normals", (None, 3))
    d = np.atleast_2d(as_finite(directions, "directions"))
    wi, e = directional_lights(n, d, _per_light(irradiance, d.shape[0], "irradiance"))
    return _entering(n, wi, e, _visibility(visible, (n.shape[0], d.shape[0])), eta)


def environment_irradiance(normals, directions, radiance_solid_angle, *, visible=None, eta=SUZUKI_ETA):
    """c_k of Suzuki eq. 16 for environment lighting given as directions with L·δΩ, shape (m, 3).

    c_k = Σ_d L_d δΩ_d F_t,i(N·ω_d) max(0, N·ω_d) V_kd: the quadrature of eq. 16,
    each direction a distant light of irradiance L·δΩ.  Evaluated in blocks of
    patches (memory: block × directions × 3 doubles).

    Parameters
    ----------
    normals : array_like, shape (m, 3)
    directions : array_like, shape (D, 3)
        Unit directions towards the environment samples.
    radiance_solid_angle : array_like, shape (D,) or (D, 3)
        Radiance times the solid angle each direction represents, ≥ 0.
    visible : array_like of bool, shape (m, D), optional
        Whether each patch sees each direction unoccluded.
    eta : float

    Returns
    -------
    ndarray, shape (m, 3)
        c_k per patch and channel.
    """
    n = check_shape(as_finite(normals, "normals"), "normals", (None, 3))
    d = np.atleast_2d(as_finite(directions, "directions"))
    vis = _visibility(visible, (n.shape[0], d.shape[0]))
    out = np.zeros((n.shape[0], 3))
    for start in range(0, n.shape[0], _ENV_BLOCK):  # blocks of patches, vectorised over directions
        sl = slice(start, start + _ENV_BLOCK)
        out[sl] = directional_light_irradiance(n[sl], d, radiance_solid_angle, visible=vis[sl], eta=eta)
    return out


def _exit_transmittance(cos_o, eta):
    c = as_finite(cos_o, "cos_o")
    if np.any((c < -1e-6) | (c > 1 + 1e-6)):
        raise ValidationError(f"cos_o must lie in [0, 1] (the patch faces the camera), got {c[(c < 0) | (c > 1)][0]!r}")
    return fresnel_transmittance(np.clip(c, 0, 1), eta)


def exitance_from_radiance(radiance, cos_o, eta=SUZUKI_ETA):
    """l_j = π L_o(P_j) / F_t,o(η, ω_o), Suzuki eq. 15.

    Parameters
    ----------
    radiance : array_like, shape (m,) or (m, C)
        Observed radiance L_o (e.g. W mm⁻² sr⁻¹), ≥ 0.
    cos_o : array_like, shape (m,)
        N·ω_o of each patch towards the camera, in [0, 1].
    eta : float

    Returns
    -------
    ndarray
        l_j in the irradiance unit (W mm⁻²), shape of ``radiance``; NaN where cos_o = 0 (F_t,o = 0: a
        patch seen edge-on tells nothing of its exitance; it was 0 before 2026-12-06, which read any
        radiance there as no light).
    """
    lo = as_finite(radiance, "radiance", 0, None)
    ft = _exit_transmittance(cos_o, eta)
    ft = ft.reshape(ft.shape + (1,) * (lo.ndim - ft.ndim))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ft > 0, np.pi * lo / ft, np.nan)


def radiance_from_exitance(exitance, cos_o, eta=SUZUKI_ETA):
    """L_o = F_t,o(η, ω_o) l_j / π, the inverse of :func:`exitance_from_radiance` (Suzuki eq. 14-15).

    Parameters
    ----------
    exitance : array_like, shape (m,) or (m, C)
        Exitance l_j in an irradiance unit (e.g. W mm⁻²), ≥ 0.
    cos_o : array_like, shape (m,)
        N·ω_o of each patch towards the camera, in [0, 1].
    eta : float
        Relative index of refraction (default 1.3, Suzuki §3.2).

    Returns
    -------
    ndarray
        L_o (e.g. W mm⁻² sr⁻¹), shape of ``exitance``; 0 where cos_o = 0 (F_t,o = 0).

    Raises
    ------
    ValidationError
        A negative or non-finite exitance, a cos_o outside [0, 1], or an invalid η.
    """
    l = as_finite(exitance, "exitance", 0, None)
    ft = _exit_transmittance(cos_o, eta)
    return ft.reshape(ft.shape + (1,) * (l.ndim - ft.ndim)) * l / np.pi
