"""Stages 2-3 of the fit: diffuse albedo by a stable minimum (eq. 9) and the specular residual (eq. 10).

Weyrich et al. 2006 §5.2: assuming the specular reflection vanishes for some
observations, the total diffuse reflectance is the largest α compliant with
every observation,

    α(xo) = min_i π f_r(xo, ωo, ωi) / (F_t(η, ωi) F_t(η, ωo)),        (eq. 9)

made stable "by penalizing grazing observations and discarding the k smallest
values".  Here each Fresnel-normalised sample v = π f_r/(F_t F_t) is penalised
as v · (1 + γ (1 − min(cos θi, cos θo))) (γ = ``grazing_penalty``; grazing
samples are least reliable, §5.3), samples beyond ``max_angle`` are dropped, and
α is the (k+1)-th smallest value per channel (k = ``discard``).

(The seed prints F_i in eq. 9-10; it is the transmissive Fresnel term F_t of
eq. 6, the only Fresnel pair that makes the diffuse term of eq. 6 equal
(α/π) F_t F_t for a flat patch.)

The minimum of noisy samples is biased low by a few noise standard deviations.
:func:`refine_albedo` removes that bias once the specular lobe is known: α is
re-estimated as the weighted mean of π (f_r − f_sM)/(F_t F_t) over samples whose
fitted specular part is small (an alternation the paper does not describe; the
pipeline applies it by default and reports both).

Stage 3 (§5.3): f_s = f_r − (α/π) F_t(ωi) F_t(ωo) (eq. 10), converted to grey
(mean of R, G, B: the highlight has the light's white colour).
"""

from __future__ import annotations

import numpy as np

from ..fresnel import _fresnel_reflectance

__all__ = ["fresnel_factors", "albedo_stable_minimum", "specular_residual", "refine_albedo"]


def fresnel_factors(samples, normal, eta=1.38):
    """Per-sample cos θi, cos θo and F_t(θi) F_t(θo) for per-lumitexel unit normals (no checks)."""
    ci, co = samples.cos(normal)
    e = np.float32(eta)
    ft_i = 1 - _fresnel_reflectance(np.clip(ci, 0, 1).astype(np.float32), e)
    ft_o = 1 - _fresnel_reflectance(np.clip(co, 0, 1).astype(np.float32), e)
    return ci.astype(np.float32), co.astype(np.float32), (ft_i * ft_o).astype(np.float32)


def albedo_stable_minimum(samples, brdf, cos_i, cos_o, ft2, use, *, discard=2, grazing_penalty=1.0):
    """Diffuse albedo by the stable minimum of eq. 9 (module docstring).

    Parameters
    ----------
    samples : Samples
        The samples (for their lumitexel index).
    brdf : ndarray, shape (S, 3)
        BRDF samples f_r (eq. 8).
    cos_i, cos_o, ft2 : ndarray, shape (S,)
        cos θi, cos θo and F_t(θi) F_t(θo).
    use : ndarray of bool, shape (S,)
        Samples allowed (valid, lit, within the angle limit).
    discard : int
        k, the number of smallest values discarded (≥ 0).
    grazing_penalty : float
        γ ≥ 0 of the grazing penalty.

    Returns
    -------
    albedo : ndarray, shape (n, 3)
        α per channel; NaN where fewer than k + 1 samples are usable.
    n_used : ndarray of int, shape (n,)
        Usable samples per lumitexel.
    """
    penalty = 1 + np.float32(grazing_penalty) * (1 - np.minimum(cos_i, cos_o))
    k = int(discard)
    out = np.empty((samples.n_texels, 3), np.float32)
    for c in range(3):  # loop over channels, vectorised over samples
        with np.errstate(invalid="ignore", divide="ignore"):
            v = np.float32(np.pi) * brdf[:, c] / ft2 * penalty
        ok = use & np.isfinite(v)
        pad, counts = samples.padded(v.astype(np.float32), np.inf, ok)
        if pad.shape[1] <= k:
            out[:, c] = np.nan
            continue
        kth = np.partition(pad, k, axis=1)[:, k]
        out[:, c] = np.where(counts > k, kth, np.nan)
    return out, samples.count(use)


def specular_residual(samples, brdf, albedo, ft2):
    """Grey specular BRDF samples f_s = mean_RGB(f_r − (α/π) F_t F_t), eq. 10, shape (S,)."""
    diffuse = albedo[samples.texel] * (ft2 / np.float32(np.pi))[:, None]
    return np.mean(brdf - diffuse, axis=1).astype(np.float32)


def refine_albedo(samples, brdf, ft2, specular_model, use, *, specular_fraction=0.02):
    """Unbiased albedo given a fitted specular lobe (module docstring).

    α = mean over samples of π (f_r − f_sM)/(F_t F_t), over the usable samples
    whose fitted specular value is below ``specular_fraction`` of the diffuse
    value they sit on.

    Parameters
    ----------
    samples : Samples
    brdf : ndarray, shape (S, 3)
    ft2 : ndarray, shape (S,)
    specular_model : ndarray, shape (S,)
        Fitted f_sM (grey) at every sample.
    use : ndarray of bool, shape (S,)
        Samples allowed in the estimate (valid, within the angle limit).

    Returns
    -------
    albedo : ndarray, shape (n, 3)
        NaN where no sample qualifies.
    n_used : ndarray of int, shape (n,)
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        v = np.float32(np.pi) * (brdf - specular_model[:, None]) / ft2[:, None]
    ok = use & np.all(np.isfinite(v), axis=1)
    cnt0 = samples.count(ok)
    with np.errstate(invalid="ignore", divide="ignore"):
        first = samples.sum(v.mean(1), ok) / cnt0  # grey first guess per lumitexel
    small = specular_model * np.float32(np.pi) < specular_fraction * first[samples.texel] * ft2
    sel = ok & small
    cnt = samples.count(sel)
    with np.errstate(invalid="ignore", divide="ignore"):
        alb = np.stack([samples.sum(v[:, c], sel) for c in range(3)], 1) / cnt[:, None]
    return np.where(cnt[:, None] > 0, alb, np.nan).astype(np.float32), cnt
