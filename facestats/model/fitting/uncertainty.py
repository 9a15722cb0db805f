"""Standard errors of the specular fit of eq. 14 (Weyrich et al. 2006 §5.3): what a stored ρs or m is worth.

Per texel the fit minimises E² = Σ r² over the parameters θ = (ρs, q = ln p),
r = y − ρs g(p), with Jacobian rows J = (g, ρs ∂g/∂q)
(:mod:`facestats.model.fitting.lobes`).  When the grey diffuse level of eq. 10 is
fitted with them (:mod:`facestats.model.fitting.diffuse_level`), θ = (ρs, q, δ),
r = y + δ d − ρs g and J = (g, ρs ∂g/∂q, −d), d = ∂y/∂α per sample.  Two
covariances of θ̂ are formed from sums over the texel's samples:

* **classic**: σ² (JᵀJ)⁻¹ of (ρs, q) with σ² = E²/(n − 2), exact for independent
  noise of equal variance.  It decides the ``ill_conditioned`` flag (the fit's
  conditioning), as do robust variances that cannot be formed (a singular JᵀJ).
* **robust** (heteroscedasticity-consistent "sandwich" with the jackknife
  weights HC3 of MacKinnon & White 1985, "Some heteroskedasticity-consistent
  covariance matrix estimators with improved finite sample properties",
  J. Econometrics 29, 305-325, as recommended by Long & Ervin 2000):
  (JᵀJ)⁻¹ (Σ r²/(1 − h)² J Jᵀ) (JᵀJ)⁻¹ with the leverage h = Jᵢᵀ (JᵀJ)⁻¹ Jᵢ of
  each sample's Jacobian row Jᵢ (capped at 0.99), over all the fitted parameters.  Camera noise
  is shot noise, whose variance grows with the signal: the few highlight
  samples that determine ρs and m are noisier than average and carry the
  leverage, which the classic σ² assumes away (on simulated captures the
  classic errors are 3-4× too small, HC1 without the leverage weights 1.7×).
  With δ among the parameters, the albedo's share of the error is in the same
  matrix: its column −d is what lets δ trade against ρs and the lobe.

The stored standard errors are the square roots of the robust diagonal (for the
lobe parameter p = e^q: p · σ_q).  With the tilts of
:mod:`facestats.model.fitting.normal_tilt` (the pipeline's default) the matrix has
four more columns, and the errors allow the lobe's and the diffuse term's normals
to differ from the photometric-stereo normal the fit is evaluated with.  What they
leave out is any other difference between the true reflectance and the model
(``docs/scale.md`` gives the coverage measured on simulated captures).

Gram matrices are inverted where no column lies within 1e-12 of the span of the
others (:func:`inverse_stack`).
"""

from __future__ import annotations

import numpy as np

from facestats.core.validate import check_choice
from facestats.model.fitting.lobes import lobe_base, lobe_moments, lobe_rate, lobe_scale
from facestats.model.fitting.samples import run_starts
from facestats.model.skin import SPECULAR_MODELS

__all__ = [
    "robust_variances",
    "inverse_stack",
    "gram_stack",
    "standard_errors",
    "lobe_jacobian",
    "rms_error",
    "LEVERAGE_CAP",
    "MAX_INFLATION",
]

#: Largest leverage used in the HC3 weights 1/(1 − h)² (a texel of two samples has h = 1).
LEVERAGE_CAP = 0.99


def lobe_jacobian(model, q, u, z):
    """(g, ∂g/∂q) per sample from the lobe base u = A e^{c z} (float64), for q = ln p repeated per sample.

    Torrance-Sparrow (eq. 12-13): g = w u, w = 1/m², ∂g/∂ln m = 2 w u (w z − 1).
    Blinn-Phong (eq. 11): g = (n + 2) u, ∂g/∂ln n = n u (1 + (n + 2) z).

    Parameters
    ----------
    model : str
        ``"torrance_sparrow"``; any other value is read as ``"blinn_phong"``.
    q : ndarray, shape (S,)
        ln p of each sample's texel.
    u : ndarray, shape (S,)
        The lobe base of :func:`facestats.model.fitting.lobes.lobe_base`.
    z : ndarray, shape (S,)
        The per-sample abscissa (tan²δ or ln cos δ).

    Returns
    -------
    g, dg : ndarray, shape (S,)
        The lobe g and ∂g/∂q (float64 for float64 inputs).
    """
    p = np.exp(q)
    if model == "torrance_sparrow":
        w = 1 / (p * p)
        return w * u, 2 * w * u * (w * z - 1)
    return (p + 2) * u, p * u * (1 + (p + 2) * z)


def robust_variances(model, y, s1, a, d, n_use, good, rho, q, delta=None, tilt=None, albedo=None):
    """Per texel: E² = Σ r² and the robust (HC3) variances of ρs and of q = ln p (module docstring).

    From explicit residuals at the solution, samples in per-texel runs of ``n_use``;
    ``d`` None: the two parameters (ρs, q); else the three (ρs, q, δ) with r = y + δ d − ρs g
    and δ per texel (``delta``).  ``tilt`` (4, S): the slopes (∂z, ∂ln A) of two tilts of the
    lobe's normal per sample (:mod:`facestats.model.fitting.normal_tilt`), two more columns
    ρs g (∂ln A + c ∂z); (6, S) with ``d``: also ∂ln D of two tilts of the diffuse term's normal,
    two more columns (α + δ)(−d) ∂ln D with ``albedo`` α (T,) the grey albedo eq. 10 removed.
    Texels not ``good`` get NaN.

    Parameters
    ----------
    model : {"torrance_sparrow", "blinn_phong"}
        The lobe.
    y : ndarray, shape (S,)
        y = f_s cos θi per sample.
    s1, a : ndarray, shape (S,)
        The per-sample factors (z, A) of :func:`facestats.model.fitting.specular.specular_factors`.
    d : ndarray, shape (S,) or None
        ∂y/∂α per sample, or None without the diffuse level.
    n_use : ndarray of int, shape (T,)
        Samples per texel (consecutive runs).
    good : ndarray of bool, shape (T,)
        The texels solved.
    rho, q : ndarray, shape (T,)
        ρs and q = ln p at the solution.
    delta : ndarray, shape (T,), optional
        δ per texel; required with ``d``.
    tilt : ndarray, shape (4, S) or (6, S), optional
        The tilts' slopes per sample of ``y`` (:func:`facestats.model.fitting.normal_tilt.tilt_slopes`); 6 rows
        only with ``d``.
    albedo : ndarray, shape (T,), optional
        Grey albedo α per texel; required with a 6-row ``tilt``.

    Returns
    -------
    e2, var_rho, var_q : ndarray of float64, shape (T,)
        E² = Σ r² and the robust variances of ρs and q, of the scale of ``y`` (as given, not scaled back).

    Raises
    ------
    ValidationError
        ``model`` is not one of :data:`~facestats.model.skin.SPECULAR_MODELS`.
    """
    check_choice(model, "model", SPECULAR_MODELS)
    n_tex = n_use.size
    e2, var_rho, var_q = (np.full(n_tex, np.nan) for _ in range(3))
    if not good.any():
        return e2, var_rho, var_q
    cnt = n_use[good]
    kept = np.flatnonzero(np.repeat(good, n_use))
    yx, sx = (np.asarray(x).take(kept).astype(np.float64) for x in (y, s1))
    qs = np.repeat(q[good], cnt)
    u = lobe_base(model, q[good], cnt, np.asarray(s1).take(kept), np.asarray(a).take(kept)).astype(np.float64)
    g, dg = lobe_jacobian(model, qs, u, sx)
    rs = np.repeat(rho[good], cnt)
    r = yx - rs * (lobe_scale(model, qs) * u)
    cols = [g, rs * dg]
    if d is not None:
        dx = np.asarray(d).take(kept).astype(np.float64)
        r += dx * np.repeat(np.asarray(delta, np.float64)[good], cnt)
        cols.append(-dx)
    if tilt is not None:
        rate = lobe_rate(model, np.exp(qs))
        slopes = np.asarray(tilt).take(kept, axis=1).astype(np.float64)
        cols.extend(rs * g * (slopes[k + 1] + rate * slopes[k]) for k in (0, 2))
        if slopes.shape[0] == 6:
            level = np.repeat(np.asarray(albedo, np.float64)[good] + np.asarray(delta, np.float64)[good], cnt)
            cols.extend(-level * dx * slopes[k] for k in (4, 5))
    starts = run_starts(cnt)
    jac = np.stack(cols)  # (P, S)
    h_inv = inverse_stack(gram_stack(jac, jac, starts))  # (T, P, P)
    with np.errstate(invalid="ignore"):
        # P = H⁻¹ J per sample, row by row (no (S, P, P) array); the leverage is Σ_i J_i P_i and the
        # diagonal of H⁻¹ (Σ w J Jᵀ) H⁻¹ needs only the rows of ρs and q: Σ w P₀², Σ w P₁².
        proj = [sum(np.repeat(h_inv[:, i, m], cnt) * jac[m] for m in range(len(cols))) for i in range(len(cols))]
        lev = sum(jac[i] * proj[i] for i in range(len(cols)))
        rr = r * r
        w = rr / np.square(1 - np.clip(np.nan_to_num(lev), 0, LEVERAGE_CAP))
        var_rho[good] = np.add.reduceat(w * proj[0] * proj[0], starts)
        var_q[good] = np.add.reduceat(w * proj[1] * proj[1], starts)
    e2[good] = np.add.reduceat(rr, starts)
    return e2, var_rho, var_q


def gram_stack(left, right, starts):
    """Per-run Σ left_i right_j as (T, P, Q) for rows ``left`` (P, S) and ``right`` (Q, S) (float64 sums; when
    ``right`` is ``left``, each symmetric pair once).

    Parameters
    ----------
    left : ndarray, shape (P, S)
        Rows of per-sample values (e.g. Jacobian columns).
    right : ndarray, shape (Q, S)
        Rows of per-sample values; ``left`` itself for a Gram matrix.
    starts : ndarray of int, shape (T,)
        Offsets of the T runs (consecutive and non-empty: ``np.add.reduceat``).

    Returns
    -------
    ndarray of float64, shape (T, P, Q)
    """
    out = np.empty((starts.size, left.shape[0], right.shape[0]))
    for i in range(left.shape[0]):  # P, Q ≤ 7: segmented sums, each over all samples
        for j in range(right.shape[0]):
            if right is left and j < i:
                out[:, i, j] = out[:, j, i]
            else:
                out[:, i, j] = np.add.reduceat(left[i] * right[j], starts)
    return out


#: Largest variance inflation factor H_ii (H⁻¹)_ii of a Gram matrix H taken as invertible (:func:`inverse_stack`).
MAX_INFLATION = 1e12


def inverse_stack(h):
    """Inverses of a stack of small Gram matrices (T, P, P); NaN where singular.

    Singular: a zero or non-finite determinant or diagonal, or a column within 1e-12 of the
    span of the others, i.e. a variance inflation factor H_ii (H⁻¹)_ii above
    :data:`MAX_INFLATION` (1/(1 − R²) of column i regressed on the others), or one ≤ 0 (it is
    ≥ 1 for a positive definite H: rounding in a rank-deficient H can make it negative).  For two columns
    this is the test |det| > 1e-12 × the diagonal's product; for more it does not shrink with
    their number as that determinant test does.

    Parameters
    ----------
    h : ndarray, shape (T, P, P)
        Gram matrices (:func:`gram_stack`).

    Returns
    -------
    ndarray, shape (T, P, P)
        H⁻¹ per matrix, in ``h``'s dtype; all NaN where H is singular.
    """
    det = np.linalg.det(h)
    diag = np.diagonal(h, axis1=1, axis2=2)
    ok = np.isfinite(det) & (det != 0) & np.all(np.isfinite(diag) & (diag != 0), axis=1)
    out = np.full_like(h, np.nan)
    if ok.any():
        inv = np.linalg.inv(h[ok])
        inflation = diag[ok] * np.diagonal(inv, axis1=1, axis2=2)
        plausible = np.all((inflation > 0) & (inflation <= MAX_INFLATION), axis=1)
        good = plausible & np.all(np.isfinite(inv), axis=(1, 2))
        out[np.flatnonzero(ok)[good]] = inv[good]
    return out


def rms_error(model, y, s1, a, n_use, rho, lobe, d=None, shift=None):
    """E(p) of eq. 14 per texel for given parameters on samples in runs of ``n_use`` (NaN for texels without).

    For scoring a fit on other samples than it was made on (a Blinn-Phong fit made within
    70° scored on the 80° domain of the Torrance-Sparrow fit).  With ``d`` (∂y/∂α per
    sample) and ``shift`` (δ per texel) the residuals are y + δ d − ρs g
    (:mod:`facestats.model.fitting.diffuse_level`).  The compiled twin is
    :func:`facestats.model.fitting.kernels.lm.rms_runs`.

    Parameters
    ----------
    model : {"torrance_sparrow", "blinn_phong"}
        The lobe.
    y : ndarray, shape (S,)
        y = f_s cos θi per sample.
    s1, a : ndarray, shape (S,)
        The per-sample factors (z, A) of :func:`facestats.model.fitting.specular.specular_factors`.
    n_use : array_like of int, shape (T,)
        Samples per texel (consecutive runs).
    rho, lobe : ndarray, shape (T,)
        ρs and the lobe parameter p (m or n, not its logarithm) per texel.
    d : ndarray, shape (S,), optional
        ∂y/∂α per sample; used only with ``shift``.
    shift : ndarray, shape (T,), optional
        The diffuse level δ per texel; used only with ``d``.

    Returns
    -------
    ndarray of float64, shape (T,)
        E(p) in the unit of ``y``; NaN for texels without samples or with a non-finite ρs or lobe or a lobe ≤ 0.

    Raises
    ------
    ValidationError
        ``model`` is not one of :data:`~facestats.model.skin.SPECULAR_MODELS`.
    """
    check_choice(model, "model", SPECULAR_MODELS)
    n_use = np.asarray(n_use, np.int64)
    out = np.full(n_use.size, np.nan)
    good = (n_use > 0) & np.isfinite(rho) & np.isfinite(lobe) & (lobe > 0)
    if not good.any():
        return out
    q = np.log(np.where(good, lobe, 1.0).astype(np.float64))
    with_d = d is not None and shift is not None
    cnt = n_use[good]
    kept = np.flatnonzero(np.repeat(good, n_use))
    s1k, ak = np.asarray(s1).take(kept), np.asarray(a).take(kept)
    u = lobe_base(model, q[good], cnt, s1k, ak).astype(np.float64)
    model_y = np.repeat(np.asarray(rho, np.float64)[good] * lobe_scale(model, q[good]), cnt) * u
    r = np.asarray(y).take(kept).astype(np.float64) - model_y
    if with_d:
        r += np.asarray(d).take(kept).astype(np.float64) * np.repeat(np.asarray(shift, np.float64)[good], cnt)
    out[good] = np.sqrt(np.add.reduceat(r * r, run_starts(cnt)) / cnt)
    return out


def standard_errors(model, n_use, good, rho, q, all_sums, e2, var_rho, var_q, max_relative_error):
    """(RMS error, std of ρs, std of the lobe, ill-conditioned) per texel (module docstring).

    ``all_sums`` are the five lobe sums at the solution (:func:`facestats.model.fitting.lobes.lobe_sums`),
    which give the classic (JᵀJ)⁻¹ of (ρs, q); ``e2``, ``var_rho``, ``var_q`` those of
    :func:`robust_variances` (or of the compiled solve).

    Parameters
    ----------
    model : {"torrance_sparrow", "blinn_phong"}
        The lobe.
    n_use : ndarray of int, shape (T,)
        Samples per texel.
    good : ndarray of bool, shape (T,)
        The texels that were solved.
    rho, q : ndarray, shape (T,)
        ρs and q = ln p at the solution.
    all_sums : ndarray, shape (5, T)
        The five lobe sums at the solution.
    e2, var_rho, var_q : ndarray, shape (T,)
        E² = Σ r² and the robust variances of ρs and q.
    max_relative_error : float
        Classic relative standard error of ρs or of q above which a texel is ill-conditioned.

    Returns
    -------
    err : ndarray of float64, shape (T,)
        E(p) = sqrt(E²/n), in the unit of y; NaN where not ``good`` (as the two below).
    rho_std, lobe_std : ndarray of float64, shape (T,)
        Robust standard errors of ρs and of p (p σ_q).
    ill : ndarray of bool, shape (T,)
        Good texels whose classic JᵀJ is singular, whose robust variances are not finite, or whose classic
        relative error exceeds ``max_relative_error``.

    Raises
    ------
    ValidationError
        ``model`` is not one of :data:`~facestats.model.skin.SPECULAR_MODELS`.
    """
    check_choice(model, "model", SPECULAR_MODELS)
    n_tex = n_use.size
    err, r_std, p_std = (np.full(n_tex, np.nan) for _ in range(3))
    ill = np.zeros(n_tex, bool)
    if not good.any():
        return err, r_std, p_std, ill
    _, sgg, _, sgdg, sdgdg = lobe_moments(model, q[good], all_sums[:, good])
    h00, h01, h11 = (np.zeros(n_tex) for _ in range(3))
    h00[good], h01[good], h11[good] = sgg, rho[good] * sgdg, rho[good] ** 2 * sdgdg
    sw = n_use.astype(np.float64)
    det = h00 * h11 - h01 * h01
    with np.errstate(invalid="ignore", divide="ignore"):
        err = np.where(good, np.sqrt(e2 / sw), np.nan)
        i00, i11 = h11 / det, h00 / det  # diagonal of (JᵀJ)⁻¹
        sigma2 = e2 / np.maximum(sw - 2, 1)
        r_std = np.where(good, np.sqrt(var_rho), np.nan)
        p_std = np.where(good, np.exp(q) * np.sqrt(var_q), np.nan)  # std of ln p times p
        rel_r = np.sqrt(sigma2 * i00) / rho  # the classic errors judge the conditioning
        rel_q = np.sqrt(sigma2 * i11)
        singular = ~(det > 1e-12 * np.maximum(h00 * h11, 1e-300))
        unknown = ~(np.isfinite(var_rho) & np.isfinite(var_q))  # e.g. a singular 3 × 3 with the diffuse level
        ill = good & (singular | unknown | ~(rel_r <= max_relative_error) | ~(rel_q <= max_relative_error))
    return err, r_std, p_std, ill
