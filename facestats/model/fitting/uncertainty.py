"""Standard errors of the specular fit of eq. 14 (Weyrich et al. 2006 §5.3): what a stored ρs or m is worth.

Per texel the fit minimises E² = Σ r², r = y − ρs g(p), over the parameters
θ = (ρs, q = ln p) with Jacobian rows J = (g, ρs ∂g/∂q) (:mod:`facestats.model.fitting.lobes`).
Three covariances of θ̂ are formed from sums over the texel's samples:

* **classic**: σ² (JᵀJ)⁻¹ with σ² = E²/(n − 2) — exact for independent noise of
  equal variance.  It decides the ``ill_conditioned`` flag (the fit's
  conditioning) as before.
* **robust** (heteroscedasticity-consistent "sandwich" with the jackknife
  weights HC3 of MacKinnon & White 1985, "Some heteroskedasticity-consistent
  covariance matrix estimators with improved finite sample properties",
  J. Econometrics 29, 305-325, as recommended by Long & Ervin 2000):
  (JᵀJ)⁻¹ (Σ r²/(1 − h)² JᵀJ) (JᵀJ)⁻¹ with the leverage h = J (JᵀJ)⁻¹ Jᵀ of
  each sample (capped at 0.99).  Camera noise is shot noise, whose variance
  grows with the signal: the few highlight samples that determine ρs and m are
  noisier than the average the classic σ² assumes, and they carry the
  leverage.  On simulated captures the classic errors are 3-4× too small; HC1
  (no leverage weights) leaves them 1.7× too small, HC3 1.3-1.6×
  (``docs/scale.md``).
* **albedo term**: eq. 10 subtracts (α/π) F_t F_t from every sample, so an error
  δ of the grey albedo α_R + α_G + α_B shifts every y by δ d, d = −F_t F_t cos θi/(3π),
  and θ̂ by (JᵀJ)⁻¹ Jᵀd δ (first order, the same for every sample: the sandwich
  cannot see it).  With the albedo's standard error σ_α (the spread of the
  specular-free samples it is the mean of, :func:`facestats.model.fitting.refine_albedo`)
  this adds b bᵀ σ_α², b = (JᵀJ)⁻¹ Jᵀ d.

The stored standard errors are the square roots of the diagonal of robust +
albedo term (for the lobe parameter p = e^q: p · σ_q).  What they leave out is
the error of the photometric-stereo normal the fit is evaluated with, and any
difference between the true reflectance and the model (see ``docs/scale.md``
for the coverage measured on simulated captures).
"""

from __future__ import annotations

import numpy as np

from facestats.model.fitting.lobes import lobe_base, lobe_moments, lobe_scale

__all__ = ["residual_sums", "standard_errors", "lobe_jacobian", "rms_error", "LEVERAGE_CAP"]

#: Largest leverage used in the HC3 weights 1/(1 − h)² (a texel of two samples has h = 1).
LEVERAGE_CAP = 0.99


def lobe_jacobian(model, q, u, z):
    """(g, ∂g/∂q) per sample from the lobe base u = A e^{c z} (float64), for q = ln p repeated per sample.

    Torrance-Sparrow (eq. 12-13): g = w u, w = 1/m², ∂g/∂ln m = 2 w u (w z − 1).
    Blinn-Phong (eq. 11): g = (n + 2) u, ∂g/∂ln n = n u (1 + (n + 2) z).
    """
    p = np.exp(q)
    if model == "torrance_sparrow":
        w = 1 / (p * p)
        return w * u, 2 * w * u * (w * z - 1)
    return (p + 2) * u, p * u * (1 + (p + 2) * z)


def residual_sums(model, y, s1, a, d, n_use, good, rho, q, all_sums):
    """Per texel: E² = Σ r², the meat Σ r²/(1 − h)² (J00, J01, J11) and Jᵀd = (Σ g d, Σ ρs g' d).

    From explicit residuals r = y − ρs g at the solution; ``all_sums`` (the five lobe
    sums there) give JᵀJ for the leverages h.  Samples in per-texel runs of ``n_use``;
    texels not ``good`` get zeros.  ``d`` may be None (no albedo term: Jᵀd = 0).
    """
    n_tex = n_use.size
    out = np.zeros((6, n_tex))
    if not good.any():
        return out
    cnt = n_use[good]
    kept = np.flatnonzero(np.repeat(good, n_use))
    yx, sx, ax = (np.asarray(x).take(kept).astype(np.float64) for x in (y, s1, a))
    qs = np.repeat(q[good], cnt)
    u = lobe_base(model, q[good], cnt, np.asarray(s1).take(kept), np.asarray(a).take(kept)).astype(np.float64)
    g, dg = lobe_jacobian(model, qs, u, sx)
    rs = np.repeat(rho[good], cnt)
    r = yx - rs * (lobe_scale(model, qs) * u)
    j1 = rs * dg
    starts = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    i00, i01, i11 = _inverse_normal_matrix(model, rho[good], q[good], all_sums[:, good])
    with np.errstate(invalid="ignore"):
        lev = np.repeat(i00, cnt) * g * g + 2 * np.repeat(i01, cnt) * g * j1 + np.repeat(i11, cnt) * j1 * j1
    rr = r * r
    wr = rr / np.square(1 - np.clip(np.nan_to_num(lev), 0, LEVERAGE_CAP))
    cols = [rr, wr * g * g, wr * g * j1, wr * j1 * j1]
    if d is not None:
        dx = np.asarray(d).take(kept).astype(np.float64)
        cols += [g * dx, j1 * dx]
    out[: len(cols), good] = np.add.reduceat(np.stack(cols), starts, axis=1)
    return out


def rms_error(model, y, s1, a, n_use, rho, lobe):
    """E(p) of eq. 14 per texel for given parameters on samples in runs of ``n_use`` (NaN for texels without).

    For scoring a fit on other samples than it was made on (a Blinn-Phong fit made within
    70° scored on the 80° domain of the Torrance-Sparrow fit).
    """
    n_use = np.asarray(n_use, np.int64)
    out = np.full(n_use.size, np.nan)
    good = (n_use > 0) & np.isfinite(rho) & np.isfinite(lobe) & (lobe > 0)
    if not good.any():
        return out
    q = np.log(np.where(good, lobe, 1.0).astype(np.float64))
    cnt = n_use[good]
    kept = np.flatnonzero(np.repeat(good, n_use))
    s1k, ak = np.asarray(s1).take(kept), np.asarray(a).take(kept)
    u = lobe_base(model, q[good], cnt, s1k, ak).astype(np.float64)
    model_y = np.repeat(np.asarray(rho, np.float64)[good] * lobe_scale(model, q[good]), cnt) * u
    r = np.asarray(y).take(kept).astype(np.float64) - model_y
    out[good] = np.sqrt(np.add.reduceat(r * r, np.concatenate([[0], np.cumsum(cnt)[:-1]])) / cnt)
    return out


def _inverse_normal_matrix(model, rho, q, all_sums):
    """The entries (i00, i01, i11) of (JᵀJ)⁻¹ per texel from the lobe sums at the solution."""
    _, sgg, _, sgdg, sdgdg = lobe_moments(model, q, all_sums)
    h00, h01, h11 = sgg, rho * sgdg, rho * rho * sdgdg
    det = h00 * h11 - h01 * h01
    with np.errstate(invalid="ignore", divide="ignore"):
        return h11 / det, -h01 / det, h00 / det


def standard_errors(model, n_use, good, rho, q, all_sums, sums, albedo_std, max_relative_error):
    """(RMS error, std of ρs, std of the lobe, ill-conditioned) per texel (module docstring).

    ``all_sums`` are the five lobe sums at the solution (:func:`facestats.model.fitting.lobes.lobe_sums`),
    ``sums`` the six of :func:`residual_sums` (or of the compiled solve), ``albedo_std`` the
    standard error of the grey albedo per texel (NaN or None: no albedo term).
    """
    n_tex = n_use.size
    err, r_std, p_std = (np.full(n_tex, np.nan) for _ in range(3))
    ill = np.zeros(n_tex, bool)
    if not good.any():
        return err, r_std, p_std, ill
    _, sgg, _, sgdg, sdgdg = lobe_moments(model, q[good], all_sums[:, good])
    h00, h01, h11 = (np.zeros(n_tex) for _ in range(3))
    h00[good], h01[good], h11[good] = sgg, rho[good] * sgdg, rho[good] ** 2 * sdgdg
    e, m00, m01, m11, b0, b1 = sums
    sw = n_use.astype(np.float64)
    det = h00 * h11 - h01 * h01
    s_alb = np.zeros(n_tex) if albedo_std is None else np.nan_to_num(np.asarray(albedo_std, np.float64))
    with np.errstate(invalid="ignore", divide="ignore"):
        err = np.where(good, np.sqrt(e / sw), np.nan)
        i00, i01, i11 = h11 / det, -h01 / det, h00 / det  # (JᵀJ)⁻¹
        sigma2 = e / np.maximum(sw - 2, 1)
        c00 = i00 * (i00 * m00 + i01 * m01) + i01 * (i00 * m01 + i01 * m11)
        c11 = i01 * (i01 * m00 + i11 * m01) + i11 * (i01 * m01 + i11 * m11)
        c00 += (i00 * b0 + i01 * b1) ** 2 * s_alb**2
        c11 += (i01 * b0 + i11 * b1) ** 2 * s_alb**2
        r_std = np.where(good, np.sqrt(c00), np.nan)
        p_std = np.where(good, np.exp(q) * np.sqrt(c11), np.nan)  # std of ln p times p
        rel_r = np.sqrt(sigma2 * i00) / rho  # the classic errors judge the conditioning
        rel_q = np.sqrt(sigma2 * i11)
        singular = ~(det > 1e-12 * np.maximum(h00 * h11, 1e-300))
        ill = good & (singular | ~(rel_r <= max_relative_error) | ~(rel_q <= max_relative_error))
    return err, r_std, p_std, ill
