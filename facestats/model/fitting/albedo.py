"""Stages 2-3 of the fit: diffuse albedo by a stable minimum (eq. 9) and the specular residual (eq. 10).

Weyrich et al. 2006 §5.2: assuming the specular reflection vanishes for some
observations, the total diffuse reflectance is the largest α compliant with
every observation,

    α(xo) = min_i π f_r(xo, ωo, ωi) / (F_t(η, ωi) F_t(η, ωo)),        (eq. 9)

made stable "by penalizing grazing observations and discarding the k smallest
values".  Here the Fresnel-normalised samples v = π f_r/(F_t F_t) are *ranked*
by the penalised value v · (1 + γ g), with g rising from 0 where both θi and θo
are below ``grazing_start`` (60°) to 1 at ``grazing_end`` (80°), linearly in the
cosine of the larger angle (γ = ``grazing_penalty``; grazing samples are least
reliable, §5.3); the k smallest (k = ``discard``) are discarded, and α is the
unpenalised v of the next one, per channel.  Two
choices matter, both checked on noise-free simulated captures: returning the
penalised value would bias α upwards by the chosen sample's penalty, and a
penalty that grows from normal incidence would favour samples with light and
camera both near the normal — exactly where the specular peak is (+15 % and
+2.9 % bias respectively on the default dome).

(The seed prints F_i in eq. 9-10; it is the transmissive Fresnel term F_t of
eq. 6, the only Fresnel pair that makes the diffuse term of eq. 6 equal
(α/π) F_t F_t for a flat patch.)

The minimum of noisy samples is biased low by a few noise standard deviations
(−5 % at the default noise, about 1.5 % per sample; the (k+1)-th smallest of ~700
samples sits 2.7 σ below the mean).  :func:`refine_albedo` removes that bias: α
is re-estimated as the mean of π f_r/(F_t F_t) over the samples whose half vector
lies more than ``min_half_angle`` (50°) from the normal, where the specular lobe
of skin has mostly vanished, so the estimate averages noise instead of selecting
its extreme.  Not entirely: at a 50° half angle the Beckmann D of m = 0.5 is 2.0 %
of its peak (its exponential factor alone 0.34 %; 1/cos⁴ makes up the rest) and
Blinn-Phong's lobe with n ≥ 10 is below 1.3 %, but Torrance-Sparrow's G/(cos θi
cos θo) grows towards grazing.  Measured on noise-free synthetic lumitexels
(150 lights, 16 cameras; a review, 2026-12-06), the refined albedo is biased by
+0.03 to +0.18 % at m = 0.5, and at m = 0.68, the roughest lobe of the synthetic
population, by +0.4 to +0.8 % with ρs = 0.1 and +1.2 to +2.4 % with ρs = 0.3
(R to B: most where α is smallest); the minimum of eq. 9 itself is biased by
+0.2 to +1.3 % there.  This step goes beyond the paper; the pipeline applies it
by default and stores both estimates.

Stage 3 (§5.3): f_s = f_r − (α/π) F_t(ωi) F_t(ωo) (eq. 10), converted to grey
(mean of R, G, B: the highlight has the light's white colour).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from facestats.core.published import ETA_SKIN
from facestats.core.validate import as_finite, as_scalar, check_integer, check_shape
from facestats.errors import ValidationError
from facestats.model.fitting.samples import order_keys
from facestats.model.fresnel import check_eta, fresnel_reflectance_unchecked

__all__ = [
    "fresnel_factors",
    "BrdfSamples",
    "brdf_samples",
    "albedo_stable_minimum",
    "specular_residual",
    "refine_albedo",
]


def _check_per_sample(samples, brdf=None, **vectors):
    """Check a channel-major ``brdf`` (3, S) and per-sample vectors (S,) against ``samples``."""
    if brdf is not None:
        check_shape(np.asarray(brdf), "brdf", (3, samples.n))
    for name, v in vectors.items():
        check_shape(np.asarray(v), name, (samples.n,))


def _check_angle(value, name):
    """An angle in [0, π/2] rad."""
    return as_scalar(value, name, 0, np.pi / 2, unit="rad")


def fresnel_factors(samples, normal, eta=ETA_SKIN):
    """Per-sample cos θi, cos θo and F_t(θi) F_t(θo) for per-lumitexel unit normals.

    F_t = 1 − F_r is the unpolarised Fresnel transmittance at relative index
    ``eta`` (Weyrich et al. 2006 eq. 6, :func:`facestats.model.fresnel.fresnel_transmittance`),
    evaluated in float32 on the (lumitexel, light) and (lumitexel, camera) grids
    and gathered per sample.  Cosines below 0 are returned as they are (F_t uses
    them clipped to [0, 1]).  ``normal`` must have shape (n_texels, 3) and hold
    unit vectors (not checked).

    Parameters
    ----------
    samples : Samples
        The samples (their direction grids and indices).
    normal : ndarray, shape (n_texels, 3)
        Unit normal per lumitexel.
    eta : float
        Relative index of refraction, default 1.38.

    Returns
    -------
    cos_i, cos_o, ft2 : ndarray of float32, shape (S,)

    Raises
    ------
    ValidationError
        ``normal`` not of shape (n_texels, 3), or an invalid ``eta``.
    """
    ci_g, co_g, ft_i, ft_o = _fresnel_grids(samples, normal, eta)
    return samples.at_lights(ci_g), samples.at_cameras(co_g), samples.at_lights(ft_i) * samples.at_cameras(ft_o)


def _fresnel_grids(samples, normal, eta):
    """cos θi and F_t(θi) on the (lumitexel, light) grid, cos θo and F_t(θo) on the (lumitexel, camera) grid
    (float32)."""
    check_shape(np.asarray(normal), "normal", (samples.n_texels, 3))
    check_eta(eta)
    ci_g, co_g = samples.cos_grids(normal)
    e = np.float32(eta)
    ft_i = 1 - fresnel_reflectance_unchecked(np.clip(ci_g, 0, 1), e)
    ft_o = 1 - fresnel_reflectance_unchecked(np.clip(co_g, 0, 1), e)
    return ci_g, co_g, ft_i, ft_o


class BrdfSamples(NamedTuple):
    """Per-sample geometry and BRDF values for one set of normals (:func:`brdf_samples`).

    Attributes
    ----------
    cos_i, cos_o : ndarray of float32, shape (S,)
        cos θi and cos θo against the lumitexel's normal (below 0 as they are).
    ft2 : ndarray of float32, shape (S,)
        F_t(θi) F_t(θo), the Fresnel transmittances at both ends (:func:`fresnel_factors`).
    use : ndarray of bool, shape (S,)
        Samples with θi and θo below ``max_angle_deg``.
    f_r : ndarray of float32, shape (3, S)
        BRDF values in sr⁻¹, channel-major; NaN or inf where cos θi ≤ 0.
    """

    cos_i: np.ndarray
    cos_o: np.ndarray
    ft2: np.ndarray
    use: np.ndarray
    f_r: np.ndarray


def brdf_samples(samples, normal, eta=ETA_SKIN, max_angle_deg=80.0) -> BrdfSamples:
    """BRDF samples f_r = L_o / (E_i cos θi) (Weyrich et al. 2006 eq. 8) with their angles, for per-lumitexel normals.

    ``cos_i``, ``cos_o`` and ``ft2`` are :func:`fresnel_factors`; ``use`` marks the samples with θi and θo
    below ``max_angle_deg`` (eq. 14's domain: 80° in the paper), compared in float32; ``f_r`` is NaN or inf
    where cos θi ≤ 0 (such samples are outside ``use``).  Irradiance E_i is per unit area normal to the light,
    so the cosine is the surface's.

    Parameters
    ----------
    samples : Samples
        The valid samples (radiance and beam-normal irradiance E⊥, channel-major (3, S)).
    normal : ndarray, shape (n_texels, 3)
        Unit normal per lumitexel (not checked to be unit).
    eta : float
        Relative index of refraction of F_t, default 1.38.
    max_angle_deg : float
        Largest θi and θo of a usable sample, degrees, in [0, 90].

    Returns
    -------
    BrdfSamples
        ``cos_i``, ``cos_o``, ``ft2`` (float32) and ``use`` (bool), shape (S,); ``f_r`` (3, S) float32, sr⁻¹.

    Raises
    ------
    ValidationError
        ``max_angle_deg`` outside [0, 90], ``normal`` not of shape (n_texels, 3), or an invalid ``eta``.
    """
    lim = np.float32(np.cos(np.radians(as_scalar(max_angle_deg, "max_angle_deg", 0.0, 90.0, unit="deg"))))
    if samples.resolved_engine == "numba" and not samples.paired:
        # local import: the kernels import numba
        from facestats.model.fitting.kernels.samples import brdf_values

        grids = (np.ascontiguousarray(g, np.float32).reshape(-1) for g in _fresnel_grids(samples, normal, eta))
        light = (np.ascontiguousarray(x, np.float32) for x in (samples.radiance, samples.irradiance))
        return BrdfSamples(*brdf_values(samples.light_index, samples.camera_index, *grids, *light, lim))
    cos_i, cos_o, ft2 = fresnel_factors(samples, normal, eta)
    use = (cos_i > lim) & (cos_o > lim)
    with np.errstate(invalid="ignore", divide="ignore"):
        f_r = samples.radiance / (samples.irradiance * np.maximum(cos_i, 0))  # channel-major (3, S)
    return BrdfSamples(cos_i, cos_o, ft2, use, f_r)


def albedo_stable_minimum(
    samples,
    brdf,
    cos_i,
    cos_o,
    ft2,
    use,
    *,
    discard=2,
    grazing_penalty=1.0,
    grazing_start=np.radians(60.0),
    grazing_end=np.radians(80.0),
):
    """Diffuse albedo by the stable minimum of eq. 9 (module docstring).

    Samples are ranked per channel by the penalised value v·(1 + γ g) of
    v = π f_r/(F_t F_t), with g rising from 0 at ``grazing_start`` (60°) to 1 at
    ``grazing_end`` (80°), linearly in the cosine of the larger of θi and θo; the
    ``discard`` smallest are skipped and the unpenalised v of the next one is the
    albedo.

    Parameters
    ----------
    samples : Samples
        The samples (for their lumitexel index).
    brdf : ndarray, shape (3, S)
        BRDF samples f_r (eq. 8), channel-major.
    cos_i, cos_o, ft2 : ndarray, shape (S,)
        cos θi, cos θo and F_t(θi) F_t(θo).
    use : ndarray of bool, shape (S,)
        Samples allowed (valid, lit, within the angle limit).
    discard : int
        k, the number of smallest values discarded (≥ 0).
    grazing_penalty : float
        γ ≥ 0 of the grazing penalty.
    grazing_start, grazing_end : float
        Angles (rad), 0 ≤ start < end ≤ π/2, between which the penalty grows from 0 to γ.

    Returns
    -------
    albedo : ndarray of float32, shape (n, 3)
        α per channel; NaN where fewer than k + 1 samples are usable.
    n_used : ndarray of int, shape (n,)
        Usable samples per lumitexel.
    """
    _check_per_sample(samples, brdf, cos_i=cos_i, cos_o=cos_o, ft2=ft2, use=use)
    k = check_integer(discard, "discard", 0)
    as_finite(grazing_penalty, "grazing_penalty", 0, None)
    if not _check_angle(grazing_start, "grazing_start") < _check_angle(grazing_end, "grazing_end"):
        raise ValidationError(f"grazing_start must be < grazing_end, got {grazing_start!r} >= {grazing_end!r} rad")
    c0, c1 = np.cos(grazing_start), np.cos(grazing_end)
    if samples.resolved_engine == "numba":
        # local import: the kernels import numba
        from facestats.model.fitting.kernels.runs import stable_minimum

        out, _ = stable_minimum(
            samples.starts,
            samples.counts,
            np.ascontiguousarray(brdf, np.float32),
            np.ascontiguousarray(ft2, np.float32),
            np.ascontiguousarray(cos_i, np.float32),
            np.ascontiguousarray(cos_o, np.float32),
            np.ascontiguousarray(use, bool),
            k,
            float(np.float32(grazing_penalty)),
            float(c0),
            float(c0 - c1),
        )
        return out, samples.count(use)
    graze = np.clip((c0 - np.minimum(cos_i, cos_o)) / (c0 - c1), 0, 1)
    penalty = (1 + np.float32(grazing_penalty) * graze).astype(np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        v = (np.float32(np.pi) * brdf / ft2).astype(np.float32)  # (3, S)
    ok = use & np.isfinite(v[0] + v[1] + v[2])
    counts = samples.count(ok)
    out = np.full((samples.n_texels, 3), np.nan, np.float32)
    have = counts > k
    if not have.any():
        return out, samples.count(use)
    # Segmented selection over each lumitexel's run: k times, remove the first smallest penalised
    # value; then the first smallest left is the (k+1)-th.  One int64 key per sample orders by
    # (value, position) (:func:`facestats.model.fitting.samples.order_keys`), so a segmented minimum
    # gives value and position at once.  Excluded samples rank last (+inf).  Runs of every non-empty
    # lumitexel.
    nonempty = samples.counts > 0
    starts = samples.starts[nonempty]
    inf_high = order_keys(np.float32([np.inf]))[0]  # +inf at position 0
    for c in range(3):  # loop over channels, vectorised over samples
        ranked = v[c] * penalty
        np.putmask(ranked, ~ok, np.inf)
        key = order_keys(ranked)
        for step in range(k + 1):
            at = np.minimum.reduceat(key, starts) & 0xFFFFFFFF  # per non-empty lumitexel
            if step < k:
                key[at] = inf_high | at
        out[have, c] = v[c].take(at[have[nonempty]])
    return out, samples.count(use)


def specular_residual(samples, brdf, albedo, ft2):
    """Grey specular BRDF samples f_s = mean_RGB(f_r − (α/π) F_t F_t), eq. 10, shape (S,), float32, sr⁻¹.

    Parameters
    ----------
    samples : Samples
        The samples (for their lumitexel runs).
    brdf : ndarray, shape (3, S)
        BRDF samples f_r (eq. 8), channel-major, sr⁻¹.
    albedo : ndarray, shape (n, 3)
        Diffuse albedo α per lumitexel and channel (e.g. :func:`albedo_stable_minimum`).
    ft2 : ndarray, shape (S,)
        F_t(θi) F_t(θo) per sample.

    Returns
    -------
    ndarray of float32, shape (S,)
        f_s in sr⁻¹; NaN where the lumitexel's albedo is NaN.

    Raises
    ------
    ValidationError
        An argument whose shape does not match ``samples``.
    """
    _check_per_sample(samples, brdf, ft2=ft2)
    check_shape(np.asarray(albedo), "albedo", (samples.n_texels, 3))
    grey_albedo = samples.expand(albedo.sum(axis=1, dtype=np.float32))  # Σ_ch α
    total = brdf[0] + brdf[1] + brdf[2]
    return ((total - grey_albedo * (ft2 / np.float32(np.pi))) / np.float32(3)).astype(np.float32)


def refine_albedo(samples, brdf, ft2, cos_half, use, *, min_half_angle=np.radians(50.0), with_std=False):
    """Unbiased albedo from the specular-free samples (module docstring).

    α = mean of π f_r/(F_t F_t) over the usable samples whose half vector makes an
    angle of more than ``min_half_angle`` with the normal.

    Parameters
    ----------
    samples : Samples
    brdf : ndarray, shape (3, S)
        Channel-major BRDF samples.
    ft2 : ndarray, shape (S,)
    cos_half : ndarray, shape (S,)
        N·H per sample.
    use : ndarray of bool, shape (S,)
        Samples allowed in the estimate (valid, within the angle limit).
    min_half_angle : float
        Angle (rad, in [0, π/2]) between normal and half vector beyond which a
        sample counts as specular-free (default 50°).
    with_std : bool
        Also return the standard error of the grey albedo α_R + α_G + α_B (the
        spread of the samples' v_R + v_G + v_B over sqrt(n), n − 1 in the variance),
        which :mod:`facestats.model.fitting.uncertainty` propagates into the BRDF's.

    Returns
    -------
    albedo : ndarray of float32, shape (n, 3)
        NaN where no sample qualifies.
    n_used : ndarray of int, shape (n,)
    grey_std : ndarray of float64, shape (n,)
        Only with ``with_std``; NaN for fewer than two samples.
    """
    _check_per_sample(samples, brdf, ft2=ft2, cos_half=cos_half, use=use)
    _check_angle(min_half_angle, "min_half_angle")
    if samples.resolved_engine == "numba":
        # local import: the kernels import numba
        from facestats.model.fitting.kernels.runs import refine_sums

        alb, cnt, grey_std = refine_sums(
            samples.starts,
            samples.counts,
            np.ascontiguousarray(brdf, np.float32),
            np.ascontiguousarray(ft2, np.float32),
            np.ascontiguousarray(cos_half, np.float32),
            np.ascontiguousarray(use, bool),
            float(np.cos(min_half_angle)),
        )
        return (alb, cnt, grey_std) if with_std else (alb, cnt)
    with np.errstate(invalid="ignore", divide="ignore"):
        v = np.float32(np.pi) * brdf / ft2
    sel = use & (cos_half < np.cos(min_half_angle)) & np.isfinite(v[0] + v[1] + v[2])
    cnt = samples.count(sel)
    with np.errstate(invalid="ignore", divide="ignore"):
        alb = samples.sum(v, sel).T / cnt[:, None]
    alb = np.where(cnt[:, None] > 0, alb, np.nan).astype(np.float32)
    if not with_std:
        return alb, cnt
    grey = v[0].astype(np.float64) + v[1] + v[2]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean, mean_sq = samples.sum(grey, sel) / cnt, samples.sum(grey * grey, sel) / cnt
        grey_std = np.sqrt(np.maximum(mean_sq - mean * mean, 0) / (cnt - 1))
    return alb, cnt, np.where(cnt > 1, grey_std, np.nan)
