"""The normals as nuisance parameters of the specular standard errors (Weyrich et al. 2006 §5.2-5.3).

Eq. 10 removes the diffuse term and eq. 14 fits the lobe at the photometric-stereo
normal N of stage 1, which is an estimate, and the diffuse one: light carried
under the skin tilts the normal photometric stereo sees away from the surface's
(``docs/scale.md``).  Errors of ρs and p conditional on N are then too narrow:
neither the lobe nor the removed diffuse term can move while the samples ask
them to.  The standard errors can instead allow each of them a small tilt of its
normal, N' = N + ε₁ t₁ + ε₂ t₂ (t₁, t₂ a tangent pair of N; N' is unit to first
order): two more columns of the Jacobian for the lobe, two for the diffuse term,
evaluated at the fitted (ρs, p, δ) and ε = 0.  These are the errors of a joint fit
with a specular and a diffuse normal of their own, to first order, without
moving the stored estimate.

A tilt along t changes the sample cosines by d(N·ωi) = ωi·t, d(N·ωo) = ωo·t
(ωi·ωo does not change), and with the lobe g = s(p) A e^{c z}
(:mod:`facestats.model.fitting.lobes`)

    ∂(ρs g)/∂ε = ρs g (∂ln A/∂ε + c ∂z/∂ε).

The slopes of the parameter-free factors (z, ln A) of
:func:`facestats.model.fitting.specular.specular_factors`, with
cos δ = (N·ωi + N·ωo)/‖ωi + ωo‖ and d cos δ = (ωi·t + ωo·t)/‖ωi + ωo‖:

* Torrance-Sparrow (eq. 12-13): z = tan²δ = 1/cos²δ − 1, so ∂z = −2 d cos δ / cos³δ;
  A = K cos θi / cos⁴δ = G F_r(ωo·H) / (π (N·ωo) cos⁴δ) (F_r depends on ωo·H only,
  which a tilt leaves alone), so ∂ln A = ∂ln G − d(N·ωo)/(N·ωo) − 4 d cos δ / cos δ,
  with ∂ln G = 0 where G = 1 and d cos δ / cos δ + d(N·ω)/(N·ω) where
  G = 2 cos δ (N·ω)/(ωo·H) for the smaller of N·ωi, N·ωo.
* Blinn-Phong (eq. 11): z = ln cos δ, ∂z = d cos δ / cos δ; A = cos θi/(2π),
  ∂ln A = d(N·ωi)/(N·ωi).

The diffuse term eq. 10 removed from y = f_s cos θi is (α + δ)/(3π) D with
D = F_t(θi) F_t(θo) cos θi (grey α = α_R + α_G + α_B; δ the fitted diffuse level,
:mod:`facestats.model.fitting.diffuse_level`), so its column is
(α + δ) (−d) ∂ln D/∂ε with d = −D/(3π) and

    ∂ln D = κi d(N·ωi) + κo d(N·ωo),   κi = 1/cos θi − F_r'(θi)/F_t(θi),   κo = −F_r'(θo)/F_t(θo),

F_r' = dF_r/d cos θ (:func:`facestats.model.fresnel.fresnel_reflectance_slope_unchecked`).

ωi·t and κi depend on the lumitexel and the light only, ωo·t and κo on the
lumitexel and the camera: they are formed on the (lumitexel, light) and
(lumitexel, camera) grids (:func:`tilt_grids`) and read per sample.

ε is in radians; the slopes are per radian of tilt.  All are checked against
finite differences of the factors in the tests.  The compiled twin is
:func:`facestats.model.fitting.kernels.factors.texel_tilt_slopes` (the same
quantities without a square root).  On simulated captures (procedural and ICT
face, dipole and local transport) the nominal 90 % intervals of all four
parameters cover the truth in 87.6-94.8 % of the texels with both tilts,
79.6-90.4 % without (``docs/scale.md``, 2026-12-07).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.model.brdf import v_groove_shadowing_unchecked
from facestats.model.fresnel import fresnel_reflectance_slope_unchecked, fresnel_reflectance_unchecked

__all__ = [
    "TiltInputs",
    "tangent_pair",
    "tilt_grids",
    "tilt_inputs",
    "tilt_slopes",
    "factor_slopes",
    "diffuse_coefficients",
]


@dataclass(frozen=True)
class TiltInputs:
    """What the tilts' columns need for the kept samples of one domain of eq. 14 (:func:`tilt_inputs`).

    Attributes
    ----------
    index : ndarray of int64, shape (S',)
        Each kept sample's index among the samples.
    light_index, camera_index : ndarray of int64, shape (S,)
        Every sample's flat index into ``light`` and ``camera``.
    ci, co, io : ndarray of float32, shape (S,)
        N·ωi, N·ωo, ωi·ωo of every sample.
    light, camera : ndarray of float32, shapes (n L, 4) and (n C, 4)
        :func:`tilt_grids`.
    diffuse : bool
        Whether the diffuse term's normal tilts too (two more columns).
    """

    index: np.ndarray
    light_index: np.ndarray
    camera_index: np.ndarray
    ci: np.ndarray
    co: np.ndarray
    io: np.ndarray
    light: np.ndarray
    camera: np.ndarray
    diffuse: bool

    @property
    def rows(self) -> int:
        """Rows of :func:`tilt_slopes`: 4, or 6 with the diffuse term."""
        return 6 if self.diffuse else 4


def tilt_inputs(samples, index, cosines, grids, diffuse):
    """:class:`TiltInputs` of the kept samples ``index`` of :class:`~facestats.model.fitting.samples.Samples`,
    with ``cosines`` = (N·ωi, N·ωo, ωi·ωo) per sample and ``grids`` from :func:`tilt_grids`.

    Parameters
    ----------
    samples : Samples
        The samples (for their ``light_index`` and ``camera_index``).
    index : array_like of int, shape (S',)
        Indices of the kept samples (those of the domain of eq. 14) among the S samples.
    cosines : tuple of 3 array_like, shape (S,)
        N·ωi, N·ωo and ωi·ωo of every sample (stored as float32).
    grids : tuple of 2 ndarray
        The light (n L, 4) and camera (n C, 4) grids of :func:`tilt_grids`.
    diffuse : bool
        Whether the diffuse term's normal tilts too.

    Returns
    -------
    TiltInputs
    """
    ci, co, io = (np.ascontiguousarray(x, np.float32) for x in cosines)
    light, camera = grids
    return TiltInputs(
        np.asarray(index, np.int64),
        np.asarray(samples.light_index, np.int64),
        np.asarray(samples.camera_index, np.int64),
        ci,
        co,
        io,
        light,
        camera,
        bool(diffuse),
    )


def tilt_slopes(model, tilt):
    """float32 (4, S') with rows ∂z₁, ∂ln A₁, ∂z₂, ∂ln A₂ of ``model``'s factors along the two tilts for the kept
    samples of :class:`TiltInputs` ``tilt`` (:func:`factor_slopes`), and with its ``diffuse`` (6, S') with
    ∂ln D₁, ∂ln D₂ = κi d(N·ωi) + κo d(N·ωo) of the diffuse term (module docstring).  The numpy reference; the
    compiled fit forms the same per texel (:func:`facestats.model.fitting.kernels.factors.texel_tilt_slopes`).

    Parameters
    ----------
    model : str
        ``"torrance_sparrow"``; any other value is read as ``"blinn_phong"``.
    tilt : TiltInputs
        :func:`tilt_inputs` of the kept samples.

    Returns
    -------
    ndarray of float32, shape (4, S') or (6, S')
        The slopes per radian of tilt; 6 rows when ``tilt.diffuse``.
    """
    ci, co, io = (x.take(tilt.index) for x in (tilt.ci, tilt.co, tilt.io))
    dci = tilt.light.take(tilt.light_index.take(tilt.index), axis=0).T
    dco = tilt.camera.take(tilt.camera_index.take(tilt.index), axis=0).T
    rows = [*factor_slopes(model, ci, co, io, dci[0], dco[0]), *factor_slopes(model, ci, co, io, dci[1], dco[1])]
    if tilt.diffuse:
        k_i, k_o = dci[2].astype(np.float64), dco[2].astype(np.float64)
        rows += [(k_i * dci[t] + k_o * dco[t]).astype(np.float32) for t in (0, 1)]
    return np.stack(rows)


def tangent_pair(normal):
    """Two unit tangents (t₁, t₂) per normal: t₁ = N × ŷ normalised (perpendicular to N and +y; N × x̂ where N
    is within 0.06° of ±y), t₂ = N × t₁.

    Parameters
    ----------
    normal : array_like, shape (n, 3)
        Unit normals (not validated; t₂ is unit only if N is).

    Returns
    -------
    t1, t2 : ndarray of float64, shape (n, 3)
    """
    n = np.asarray(normal, np.float64)
    t1 = np.cross(n, (0.0, 1.0, 0.0))
    near_y = np.linalg.norm(t1, axis=1) < 1e-3
    t1[near_y] = np.cross(n[near_y], (1.0, 0.0, 0.0))
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(n, t1)


def tilt_grids(samples, normal, eta, engine="numpy"):
    """The tilts' grids of :class:`~facestats.model.fitting.samples.Samples`: float32 (n L, 4) with columns ωi·t₁,
    ωi·t₂, κi, 1/N·ωi on the (lumitexel, light) grid and (n C, 4) with ωo·t₁, ωo·t₂, κo, 1/N·ωo on the
    (lumitexel, camera) grid, flat as ``samples.light_index`` and ``camera_index`` index them; t₁, t₂ of
    :func:`tangent_pair`, κ of :func:`diffuse_coefficients` (κ and 1/N·ω 0 where the direction is at or below
    the horizon of ``normal``), formed by ``engine`` ("numba": one compiled pass per grid,
    :func:`facestats.model.fitting.kernels.factors.tilt_grid`).

    Parameters
    ----------
    samples : Samples
        The samples (for their ``wi_grid`` and ``wo_grid``).
    normal : array_like, shape (n, 3)
        Unit normal per lumitexel.
    eta : float
        Relative index of refraction of F_t (not validated).
    engine : str
        ``"numba"``; any other value forms the grids with numpy.

    Returns
    -------
    light : ndarray of float32, shape (n L, 4)
    camera : ndarray of float32, shape (n C, 4)
    """
    t1, t2 = tangent_pair(normal)
    if engine == "numba":
        # local import: the kernels import numba
        from facestats.model.fitting.kernels.factors import tilt_grid

        vectors = [np.ascontiguousarray(v, np.float32) for v in (normal, t1, t2)]
        wi, wo = (np.ascontiguousarray(g, np.float32) for g in (samples.wi_grid, samples.wo_grid))
        return tilt_grid(wi, *vectors, np.float32(eta), True), tilt_grid(wo, *vectors, np.float32(eta), False)
    (ti1, to1), (ti2, to2) = (samples.cos_grids(t) for t in (t1, t2))
    ci, co = (c.reshape(-1) for c in samples.cos_grids(normal))
    up_i, up_o = ci > 0, co > 0
    k_i, k_o = diffuse_coefficients(np.where(up_i, ci, 1), np.where(up_o, co, 1), eta)
    with np.errstate(divide="ignore"):
        r_i, r_o = 1 / ci.astype(np.float64), 1 / co.astype(np.float64)
    light = np.stack([ti1.reshape(-1), ti2.reshape(-1), k_i, r_i], axis=1)
    camera = np.stack([to1.reshape(-1), to2.reshape(-1), k_o, r_o], axis=1)
    light[~up_i, 2:], camera[~up_o, 2:] = 0, 0
    return light.astype(np.float32), camera.astype(np.float32)


def factor_slopes(model, ci, co, io, dci, dco):
    """(∂z, ∂ln A) per sample along a tilt with cosine changes ``dci`` = ωi·t, ``dco`` = ωo·t (module docstring).

    Parameters
    ----------
    model : str
        ``"torrance_sparrow"``; any other value is read as ``"blinn_phong"``.
    ci, co, io : array_like, shape (S,)
        N·ωi, N·ωo (both > 0) and ωi·ωo per sample.
    dci, dco : array_like, shape (S,)
        ωi·t and ωo·t, the changes of N·ωi and N·ωo per radian of tilt along t.

    Returns
    -------
    dz, d_ln_a : ndarray of float32
        ∂z and ∂ln A per radian, broadcast shape of the inputs (computed in float64).
    """
    ci, co, io, dci, dco = (np.asarray(x, np.float64) for x in (ci, co, io, dci, dco))
    inv = 1 / np.sqrt(np.maximum(2 + 2 * io, 1e-300))
    cos_d = np.clip((ci + co) * inv, np.finfo(np.float64).tiny, 1)
    dc = (dci + dco) * inv / cos_d  # d cos δ / cos δ
    if model == "torrance_sparrow":
        wo_h = np.clip((1 + io) * inv, np.finfo(np.float64).tiny, 1)
        g = v_groove_shadowing_unchecked(cos_d, ci, co, wo_h)
        by_i = ci <= co
        d_ln_g = np.where(g < 1, dc + np.where(by_i, dci / ci, dco / co), 0.0)
        dz = -2 * dc / (cos_d * cos_d)
        d_ln_a = d_ln_g - dco / co - 4 * dc
    else:
        dz = dc
        d_ln_a = dci / ci
    return dz.astype(np.float32), d_ln_a.astype(np.float32)


def diffuse_coefficients(ci, co, eta):
    """(κi, κo) with ∂ln(F_t(θi) F_t(θo) cos θi) = κi d(N·ωi) + κo d(N·ωo) (module docstring).

    Parameters
    ----------
    ci, co : array_like
        N·ωi and N·ωo, in (0, 1] (values above 1 are read as 1; not validated).
    eta : float
        Relative index of refraction.

    Returns
    -------
    kappa_i, kappa_o : ndarray of float64
        κi = 1/cos θi − F_r'(θi)/F_t(θi) (shape of ``ci``) and κo = −F_r'(θo)/F_t(θo) (shape of ``co``).
    """
    out = []
    for c in (np.asarray(ci, np.float64), np.asarray(co, np.float64)):
        c = np.minimum(c, 1.0)
        out.append(-fresnel_reflectance_slope_unchecked(c, eta) / (1 - fresnel_reflectance_unchecked(c, eta)))
    return out[0] + 1 / np.minimum(np.asarray(ci, np.float64), 1.0), out[1]
