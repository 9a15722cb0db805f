"""The batch Levenberg-Marquardt solve of eq. 14, compiled and run texel by texel (Weyrich et al. 2006 §5.3).

The same algorithm as :mod:`facestats.model.fitting.solver` (parameters
(ρs, q = ln p), log-linear cold start, projected steps with per-texel damping,
the same four stopping tests, float32 parameter state), written as a loop over
texels: every evaluation of a texel's lobe (:func:`_raw_sums`) makes two
passes over its samples while they sit in the CPU cache — the lobe values
(vectorised, :func:`facestats.model.fitting.kernels.fastexp.fill_lobe`) and the
five sums of :func:`facestats.model.fitting.lobes.lobe_sums` (float64, in
sample order; with ∂y/∂α two more, Σ u d and Σ u z d) — and a texel stops as
soon as it converges.  Then, with the
per-sample ∂y/∂α, the Gauss-Newton steps of the grey diffuse level
(:mod:`facestats.model.fitting.diffuse_level`), each from the seven sums of one
pass (:func:`_raw_sums`, the normal equations in closed form), and at the end
one pass over explicit residuals forms E² and the robust variances
(:func:`facestats.model.fitting.uncertainty.robust_variances`).  :func:`rms_runs`
scores given parameters on other samples (one pass per texel).

Differences from the numpy solver, all below float32 resolution of the
parameters: sums are float64 in sample order (numpy: pairwise float32), and a
converged texel stops (numpy keeps stepping converged texels until the
working set is compacted, which changes E² by less than ``tol``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from facestats.model.fitting.kernels.factors import texel_tilt_slopes
from facestats.model.fitting.kernels.fastexp import fill_lobe
from facestats.model.fitting.uncertainty import LEVERAGE_CAP, MAX_INFLATION

__all__ = ["solve_runs", "rms_runs", "TORRANCE_SPARROW", "BLINN_PHONG"]

#: Model codes of the kernel.
TORRANCE_SPARROW, BLINN_PHONG = 0, 1
_MAX_FLOAT = 1.7976931348623157e308


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _rate(model, q):
    """float32 rate c of u = A e^{c z} at q = ln p: −1/m² (TS) or n (BP), as :func:`..lobes.lobe_rate`."""
    p = math.exp(q)
    if model == TORRANCE_SPARROW:
        return np.float32(-1.0 / (p * p))
    return np.float32(p)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _moments(model, q, sums):
    """Σ y g, Σ g², Σ y g', Σ g g', Σ g'² at q (:func:`facestats.model.fitting.lobes.lobe_moments`, eq. 11-13)."""
    s_yu, s_yuz, s_uu, s_uuz, s_uuzz = sums[0], sums[1], sums[2], sums[3], sums[4]
    p = math.exp(q)
    if model == TORRANCE_SPARROW:
        w = 1.0 / (p * p)
        syg = w * s_yu
        sgg = w * w * s_uu
        sydg = 2 * w * (w * s_yuz - s_yu)
        sgdg = 2 * w * w * (w * s_uuz - s_uu)
        sdgdg = 4 * w * w * (w * w * s_uuzz - 2 * w * s_uuz + s_uu)
    else:
        k = p + 2
        syg = k * s_yu
        sgg = k * k * s_uu
        sydg = p * (s_yu + k * s_yuz)
        sgdg = k * p * (s_uu + k * s_uuz)
        sdgdg = p * p * (s_uu + 2 * k * s_uuz + k * k * s_uuzz)
    return syg, sgg, sydg, sgdg, max(sdgdg, 0.0)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _finite(x):
    """``numpy.nan_to_num`` of a scalar: NaN -> 0, ±inf -> ± the largest float64."""
    if x != x:
        return 0.0
    return min(max(x, -_MAX_FLOAT), _MAX_FLOAT)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _log_linear_start(model, y, z, a, start, n):
    """The cold start p₀ of :func:`facestats.model.fitting.solver._log_linear_start` for one texel.

    Weighted least squares of ln(y/A) against z over the samples above a quarter
    of the texel's largest y (weights y²): the slope is −1/m² (TS) or n (BP).
    """
    ymax = np.float32(-np.inf)
    for j in range(n):
        ymax = max(ymax, y[start + j])
    floor = np.float32(0.25) * ymax
    sw = 0.0
    sx = 0.0
    sy = 0.0
    sxy = 0.0
    sxx = 0.0
    for j in range(n):
        yj = y[start + j]
        if yj > floor and yj > 0:
            wt = np.float64(yj) * np.float64(yj)
            zj = np.float64(z[start + j])
            lr = math.log(np.float64(yj) / np.float64(a[start + j]))
            sw += wt
            sx += wt * zj
            sy += wt * lr
            sxy += wt * zj * lr
            sxx += wt * zj * zj
    slope = (sxy - sx * sy / sw) / (sxx - sx * sx / sw)  # NaN without strong samples
    if model == TORRANCE_SPARROW:
        return 1.0 / math.sqrt(-slope) if slope < 0 else 0.3
    return slope if slope > 0 else 20.0


@numba.njit(cache=True, nogil=True, inline="always")
def _jacobian_row(model, w, p, rho, uj, zj):
    """(g, ρs ∂g/∂q) of one sample from its lobe base u (:func:`facestats.model.fitting.uncertainty.lobe_jacobian`)."""
    if model == TORRANCE_SPARROW:
        return w * uj, rho * 2 * w * uj * (w * zj - 1)
    return (p + 2) * uj, rho * p * uj * (1 + (p + 2) * zj)


@numba.njit(cache=True, nogil=True, inline="always")
def _add_lobe(acc, uj, zj, yj):
    """acc + (y u, y u z, u², u² z, u² z²) of one sample (the first five of :func:`_add_raw`)."""
    yu = yj * uj
    uu = uj * uj
    return (acc[0] + yu, acc[1] + yu * zj, acc[2] + uu, acc[3] + uu * zj, acc[4] + uu * zj * zj)


@numba.njit(cache=True, nogil=True, inline="always")
def _add_raw(acc, uj, zj, yj, dj):
    """acc + (y u, y u z, u², u² z, u² z², u d, u z d) of one sample."""
    yu = yj * uj
    uu = uj * uj
    ud = uj * dj
    return (
        acc[0] + yu,
        acc[1] + yu * zj,
        acc[2] + uu,
        acc[3] + uu * zj,
        acc[4] + uu * zj * zj,
        acc[5] + ud,
        acc[6] + ud * zj,
    )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _raw_sums(model, q, y, z, a, d, with_d, start, n, u, bits, raw):
    """The lobe base u at q into ``u`` and Σ y u, Σ y u z, Σ u², Σ u² z, Σ u² z², Σ u d, Σ u z d of one texel
    into ``raw`` (float64; even and odd samples summed apart, in sample order; the last two 0 without ``d``,
    and then not formed)."""
    fill_lobe(_rate(model, q), z, a, start, n, u, bits)
    if with_d:
        _sums_with_d(y, z, d, start, n, u, raw)
        return
    e = (0.0, 0.0, 0.0, 0.0, 0.0)
    o = (0.0, 0.0, 0.0, 0.0, 0.0)
    j = 0
    while j + 1 < n:
        e = _add_lobe(e, np.float64(u[j]), np.float64(z[start + j]), np.float64(y[start + j]))
        o = _add_lobe(o, np.float64(u[j + 1]), np.float64(z[start + j + 1]), np.float64(y[start + j + 1]))
        j += 2
    if j < n:
        e = _add_lobe(e, np.float64(u[j]), np.float64(z[start + j]), np.float64(y[start + j]))
    for k in range(5):
        raw[k] = e[k] + o[k]
    raw[5] = raw[6] = 0.0


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _sums_with_d(y, z, d, start, n, u, raw):
    """The seven sums of :func:`_raw_sums` with ∂y/∂α ``d``, from the lobe base ``u``."""
    e = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    o = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    j = 0
    while j + 1 < n:
        d0 = np.float64(d[start + j])
        d1 = np.float64(d[start + j + 1])
        e = _add_raw(e, np.float64(u[j]), np.float64(z[start + j]), np.float64(y[start + j]), d0)
        o = _add_raw(o, np.float64(u[j + 1]), np.float64(z[start + j + 1]), np.float64(y[start + j + 1]), d1)
        j += 2
    if j < n:
        d0 = np.float64(d[start + j])
        e = _add_raw(e, np.float64(u[j]), np.float64(z[start + j]), np.float64(y[start + j]), d0)
    for k in range(7):
        raw[k] = e[k] + o[k]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _constant_sums(y, d, with_d, start, n, const):
    """Σ y², Σ y d, Σ d² of one texel into ``const`` (float64, in sample order)."""
    syy = syd = sdd = 0.0
    for j in range(n):
        yj = np.float64(y[start + j])
        syy += yj * yj
        if with_d:
            dj = np.float64(d[start + j])
            syd += yj * dj
            sdd += dj * dj
    const[0], const[1], const[2] = syy, syd, sdd


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _normal_equations(model, q, rho, delta, raw, const, acc):
    """E², the upper triangle of JᵀJ (h00, h01, h02, h11, h12, h22) and Jᵀr (three) into ``acc``, in closed form
    from the raw sums at q (:func:`_raw_sums`) and the constant ones (:func:`_constant_sums`).

    J = (g, ρs ∂g/∂q, −d), r = y + δ d − ρs g (:mod:`facestats.model.fitting.diffuse_level`); g = s u and
    ∂g/∂q = c₁ u + c₂ u z with s = 1/m², c₁ = −2/m², c₂ = 2/m⁴ (Torrance-Sparrow) or s = n + 2, c₁ = n,
    c₂ = n (n + 2) (Blinn-Phong), as in :func:`facestats.model.fitting.lobes.lobe_moments`.
    """
    p = math.exp(q)
    if model == TORRANCE_SPARROW:
        sc = 1.0 / (p * p)
        c1, c2 = -2 * sc, 2 * sc * sc
    else:
        sc = p + 2
        c1, c2 = p, p * sc
    sgy, sgg, sdgy, sgdg, sdgdg = _moments(model, q, raw)  # raw[0:5] are the lobe sums
    syy, syd, sdd = const[0], const[1], const[2]
    sgd = sc * raw[5]  # Σ g d
    sdgd = c1 * raw[5] + c2 * raw[6]  # Σ g' d
    acc[0] = syy + 2 * delta * syd + delta * delta * sdd - 2 * rho * (sgy + delta * sgd) + rho * rho * sgg
    acc[1] = sgg
    acc[2] = rho * sgdg
    acc[3] = -sgd
    acc[4] = rho * rho * sdgdg
    acc[5] = -rho * sdgd
    acc[6] = sdd
    acc[7] = sgy + delta * sgd - rho * sgg
    acc[8] = rho * (sdgy + delta * sdgd - rho * sgdg)
    acc[9] = -(syd + delta * sdd - rho * sgd)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _inverse(h00, h01, h02, h11, h12, h22):
    """Upper triangle of the inverse of the symmetric 3 × 3 JᵀJ of (ρs, q, δ); NaN where singular, by the test
    of :func:`facestats.model.fitting.uncertainty.inverse_stack`."""
    c00 = h11 * h22 - h12 * h12
    c01 = h02 * h12 - h01 * h22
    c02 = h01 * h12 - h02 * h11
    det = h00 * c00 + h01 * c01 + h02 * c02
    c11 = h00 * h22 - h02 * h02
    c12 = h01 * h02 - h00 * h12
    c22 = h00 * h11 - h01 * h01
    nan = np.nan
    if not (math.isfinite(det) and det != 0 and h00 != 0 and h11 != 0 and h22 != 0):
        return nan, nan, nan, nan, nan, nan
    v0, v1, v2 = h00 * c00 / det, h11 * c11 / det, h22 * c22 / det  # variance inflation factors
    if not (0 < v0 <= MAX_INFLATION and 0 < v1 <= MAX_INFLATION and 0 < v2 <= MAX_INFLATION):
        return nan, nan, nan, nan, nan, nan
    return c00 / det, c01 / det, c02 / det, c11 / det, c12 / det, c22 / det


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _diffuse_steps(model, y, z, a, d, start, n, limits, steps, u, bits, raw, const, acc, par):
    """The Gauss-Newton steps of (ρs, q, δ) of :func:`facestats.model.fitting.diffuse_level.fit_diffuse_level`
    for one texel, from ``par`` = (ρs, q, 0) in place.  Returns whether ``raw`` and ``u`` still hold the
    evaluation at the final ``par`` (not after an undone step)."""
    r_lo, r_hi, q_lo, q_hi = limits[0], limits[1], limits[2], limits[3]
    e_prev = np.inf
    p0, p1, p2 = par[0], par[1], par[2]
    for k in range(steps + 1):
        _raw_sums(model, par[1], y, z, a, d, True, start, n, u, bits, raw)
        _normal_equations(model, par[1], par[0], par[2], raw, const, acc)
        if not (acc[0] <= e_prev):  # the last step did not lower E²: undo it and stop
            par[0], par[1], par[2] = p0, p1, p2
            return False
        if k == steps:
            return True
        i00, i01, i02, i11, i12, i22 = _inverse(acc[1], acc[2], acc[3], acc[4], acc[5], acc[6])
        b0, b1, b2 = acc[7], acc[8], acc[9]
        s0 = i00 * b0 + i01 * b1 + i02 * b2
        s1 = i01 * b0 + i11 * b1 + i12 * b2
        s2 = i02 * b0 + i12 * b1 + i22 * b2
        if not (math.isfinite(s0) and math.isfinite(s1) and math.isfinite(s2)):
            return True
        p0, p1, p2 = par[0], par[1], par[2]
        e_prev = acc[0]
        par[0] = min(max(par[0] + s0, r_lo), r_hi)
        par[1] = min(max(par[1] + s1, q_lo), q_hi)
        par[2] = par[2] + s2
    return True


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _eliminate(a, out, c, k):
    """One Gauss-Jordan step on column ``c`` of ``a`` (pivot row ``c`` already chosen), the same row operations on
    ``out``; returns the pivot."""
    pv = a[c, c]
    for j in range(k):
        a[c, j] /= pv
        out[c, j] /= pv
    for r in range(k):
        f = a[r, c]
        if r != c and f != 0.0:
            for j in range(k):
                a[r, j] -= f * a[c, j]
                out[r, j] -= f * out[c, j]
    return pv


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _invert(h, k, a, out):
    """The inverse of the symmetric k × k matrix ``h`` (its lower triangle is read) into ``out`` by Gauss-Jordan
    elimination with partial pivoting (``a`` scratch); False where singular, by the test of
    :func:`facestats.model.fitting.uncertainty.inverse_stack` (a variance inflation factor above
    :data:`~facestats.model.fitting.uncertainty.MAX_INFLATION`)."""
    for i in range(k):
        if not (h[i, i] != 0.0 and math.isfinite(h[i, i])):
            return False
        for j in range(k):
            a[i, j] = h[max(i, j), min(i, j)]
            out[i, j] = 1.0 if i == j else 0.0
    det = 1.0
    for c in range(k):
        piv = c
        for r in range(c + 1, k):
            if abs(a[r, c]) > abs(a[piv, c]):
                piv = r
        if not (a[piv, c] != 0.0):
            return False
        if piv != c:
            det = -det
            for j in range(k):
                a[c, j], a[piv, j] = a[piv, j], a[c, j]
                out[c, j], out[piv, j] = out[piv, j], out[c, j]
        det *= _eliminate(a, out, c, k)
    return math.isfinite(det) and det != 0.0 and _invertible(h, out, k)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _invertible(h, h_inv, k):
    """Whether the inverse ``h_inv`` of ``h`` is finite with every variance inflation factor H_ii (H⁻¹)_ii in
    (0, :data:`~facestats.model.fitting.uncertainty.MAX_INFLATION`]."""
    for i in range(k):
        if not (0.0 < h[i, i] * h_inv[i, i] <= MAX_INFLATION):
            return False
        for j in range(k):
            if not math.isfinite(h_inv[i, j]):
                return False
    return True


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _columns(model, q, rho, delta, y, z, d, with_d, rows, slopes, level, start, n, u, cols, rr):
    """The per-sample columns of J into the rows of ``cols`` (k, n) and the squared residuals into ``rr``.
    Columns: g, ρs ∂g/∂q, −d (with ``d``), the lobe tilts ρs g (∂ln A + c ∂z) (``rows`` ≥ 4) and the
    diffuse tilts ``level`` (−d) ∂ln D (``rows`` = 6, with ``d``), from the texel's ``slopes`` (rows, ≥ n)."""
    with_tilt = rows >= 4
    with_diffuse_tilt = with_d and rows == 6
    p = math.exp(q)
    w = 1.0 / (p * p)
    rate = -w if model == TORRANCE_SPARROW else p  # c of g = s A e^{c z}
    c = 3 if with_d else 2
    for j in range(n):  # u holds the lobe base at q
        g, j1 = _jacobian_row(model, w, p, rho, np.float64(u[j]), np.float64(z[start + j]))
        cols[0, j], cols[1, j] = g, j1
        r = np.float64(y[start + j]) - rho * g
        if with_d:
            dj = np.float64(d[start + j])
            r += delta * dj
            cols[2, j] = -dj
        if with_tilt:
            m = rho * g
            cols[c, j] = m * (slopes[1, j] + rate * slopes[0, j])
            cols[c + 1, j] = m * (slopes[3, j] + rate * slopes[2, j])
        if with_diffuse_tilt:
            m = -level * np.float64(d[start + j])
            cols[c + 2, j] = m * slopes[4, j]
            cols[c + 3, j] = m * slopes[5, j]
        rr[j] = r * r


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _column_count(with_d, rows):
    """The number of columns of J of :func:`_columns`."""
    k = 3 if with_d else 2
    if rows >= 4:
        k += 2
    if with_d and rows == 6:
        k += 2
    return k


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _robust(
    model, q, rho, delta, y, z, a, d, with_d, rows, tilt, level, start, n, u, bits, raw, fresh, sums, out, scratch
):
    """E², the HC3 variances of ρs and q (:func:`facestats.model.fitting.uncertainty.robust_variances`) into
    ``out[0:3]``, and the five lobe sums at the solution of y + δ d into ``sums``.  ``fresh``: ``raw`` and
    ``u`` already hold :func:`_raw_sums` at this solution.  Columns of J: :func:`_columns`; with ``rows`` > 0
    the tilts' slopes of the texel's samples are formed first
    (:func:`facestats.model.fitting.kernels.factors.texel_tilt_slopes` from the arrays ``tilt``; ``level`` =
    α + δ: :mod:`facestats.model.fitting.normal_tilt`).  ``scratch`` float64 (≥ 15 n).

    H = JᵀJ and P = H⁻¹ J are BLAS products (k ≤ 7 rows of n samples); the leverage of a sample is
    h = Σᵢ Jᵢ Pᵢ, and the diagonal of H⁻¹ (Σ w J Jᵀ) H⁻¹ needs only the rows 0 and 1 of P:
    var ρs = Σ w P₀², var q = Σ w P₁² with w = r²/(1 − h)².
    """
    if not fresh:
        _raw_sums(model, q, y, z, a, d, with_d, start, n, u, bits, raw)
    sums[0] = raw[0] + delta * raw[5]  # Σ (y + δ d) u
    sums[1] = raw[1] + delta * raw[6]
    sums[2], sums[3], sums[4] = raw[2], raw[3], raw[4]
    k = _column_count(with_d, rows)
    cols = scratch[: k * n].reshape((k, n))
    rr = scratch[k * n : (k + 1) * n]
    lev = scratch[(k + 1) * n : (k + 2) * n]
    slopes = scratch[(k + 2) * n : (k + 2 + rows) * n].reshape((rows, n))
    if rows > 0:
        texel_tilt_slopes(model == TORRANCE_SPARROW, rows, tilt, z, start, n, slopes)
    _columns(model, q, rho, delta, y, z, d, with_d, rows, slopes, level, start, n, u, cols, rr)
    e2 = 0.0
    for j in range(n):
        e2 += rr[j]
    out[0] = e2
    h = np.dot(cols, cols.T)
    h_inv = np.empty((k, k))
    if not _invert(h, k, np.empty((k, k)), h_inv):
        out[1] = out[2] = np.nan
        return
    proj = np.dot(h_inv, cols)
    lev[:] = 0.0
    for i in range(k):
        for j in range(n):
            lev[j] += cols[i, j] * proj[i, j]
    v0 = v1 = 0.0
    for j in range(n):
        hj = min(max(_finite(lev[j]), 0.0), LEVERAGE_CAP)
        wj = rr[j] / ((1 - hj) * (1 - hj))
        v0 += wj * proj[0, j] * proj[0, j]
        v1 += wj * proj[1, j] * proj[1, j]
    out[1] = v0
    out[2] = v1


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _solve_one(
    model,
    y,
    z,
    a,
    d,
    rows,
    tilt,
    albedo,
    start,
    n,
    p0,
    bounds,
    max_iter,
    tol,
    steps,
    u,
    bits,
    sums,
    trial,
    work,
    par,
    out,
    terms,
):
    """The whole solve of one texel; ``out`` receives (ρs, q, δ, converged, iterations, E², var ρs, var q)."""
    r_lo, r_hi, q_lo, q_hi, p_lo, p_hi = bounds[0], bounds[1], bounds[2], bounds[3], bounds[4], bounds[5]
    with_d = d.shape[0] > 0
    raw, const, acc = work[0:7], work[7:10], work[10:20]
    _constant_sums(y, d, with_d, start, n, const)
    swyy = const[0]
    if p0 != p0:
        p0 = _log_linear_start(model, y, z, a, start, n)
        if p0 != p0:
            p0 = 0.3 if model == TORRANCE_SPARROW else 20.0
    q_start = min(max(math.log(min(max(p0, p_lo), p_hi)), q_lo), q_hi)
    _raw_sums(model, q_start, y, z, a, d, False, start, n, u, bits, sums)
    syg, sgg, _, _, _ = _moments(model, q_start, sums)
    rho = np.float64(np.float32(min(max(_finite(syg / sgg), r_lo), r_hi)))
    q = np.float64(np.float32(q_start))
    lam = np.float32(1e-3)
    done = False
    it = 0
    while it < max_iter and not done:
        it += 1
        syg, sgg, sydg, sgdg, sdgdg = _moments(model, q, sums)
        e0 = swyy - 2 * rho * syg + rho * rho * sgg
        h00, h01, h11 = sgg, rho * sgdg, rho * rho * sdgdg
        b0, b1 = syg - rho * sgg, rho * (sydg - rho * sgdg)
        # Gauss-Newton decrement bᵀH⁻¹b: the most a full step could still lower E².
        decrement = (h11 * b0 * b0 - 2 * h01 * b0 * b1 + h00 * b1 * b1) / (h00 * h11 - h01 * h01)
        if decrement < 0.1 * tol * e0:
            done = True
            break
        lm = np.float64(lam)
        d00 = h00 * (1 + lm) + 1e-30
        d11 = h11 * (1 + lm) + 1e-30
        det = d00 * d11 - h01 * h01
        dr = _finite((d11 * b0 - h01 * b1) / det)
        dq = _finite((d00 * b1 - h01 * b0) / det)
        r1 = min(max(rho + dr, r_lo), r_hi)
        q1 = min(max(q + dq, q_lo), q_hi)
        _raw_sums(model, q1, y, z, a, d, False, start, n, u, bits, trial)
        syg1, sgg1, _, _, _ = _moments(model, q1, trial)
        e1 = swyy - 2 * r1 * syg1 + r1 * r1 * sgg1
        accept = e1 < e0
        small = abs(r1 - rho) <= 1e-5 * max(abs(rho), 1e-6) and abs(q1 - q) <= 1e-5
        if accept:
            rel = (e0 - e1) / max(e0, 1e-30)
            rho = np.float64(np.float32(r1))
            q = np.float64(np.float32(q1))
            lam = np.float32(lm / 3)
            sums[:] = trial
        else:
            rel = 0.0
            lam = np.float32(lm * 4)
        done = (accept and rel < tol) or small or lam > 1e10
    par[0], par[1], par[2] = rho, q, 0.0
    fresh = False
    if with_d:
        fresh = _diffuse_steps(model, y, z, a, d, start, n, bounds, steps, u, bits, raw, const, acc, par)
    out[0], out[1], out[2] = par[0], par[1], par[2] if with_d else np.nan
    out[3] = 1.0 if done else 0.0
    out[4] = it
    _robust(
        model,
        par[1],
        par[0],
        par[2],
        y,
        z,
        a,
        d,
        with_d,
        rows,
        tilt,
        albedo + par[2] if with_d else 0.0,
        start,
        n,
        u,
        bits,
        raw,
        fresh,
        sums,
        out[5:],
        terms,
    )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def solve_runs(model, y, z, a, d, rows, tilt, albedo, starts, counts, solve, p_start, bounds, max_iter, tol, steps):
    """Solve eq. 14 for every texel with ``solve[t]`` (module docstring).

    Parameters
    ----------
    model : int
        :data:`TORRANCE_SPARROW` or :data:`BLINN_PHONG`.
    y, z, a : ndarray of float32, shape (S,)
        y = f_s cos θi, and the lobe factors (z, A) of every kept sample, in per-texel runs.
    d : ndarray of float32, shape (S,) or (0,)
        ∂y/∂α of the grey albedo per sample: the grey diffuse level is fitted too
        (:mod:`facestats.model.fitting.diffuse_level`); empty: (ρs, p) alone.
    rows : int
        0: the errors are conditional on the normal; 4: they allow the lobe's normal two tilts; 6
        (with ``d``): the diffuse term's normal too (:mod:`facestats.model.fitting.normal_tilt`).
    tilt : tuple
        (index, light_index, camera_index, ci, co, io, light, camera): the arrays of
        :class:`facestats.model.fitting.normal_tilt.TiltInputs` (read with ``rows`` > 0).
    albedo : ndarray of float64, shape (T,)
        The grey albedo α eq. 10 removed, per texel (read with ``rows`` = 6 only).
    starts, counts : ndarray of int64, shape (T,)
        The runs.
    solve : ndarray of bool, shape (T,)
        Texels to solve (the others are left NaN).
    p_start : ndarray of float64, shape (T,)
        Start of the lobe parameter (NaN: the log-linear cold start).
    bounds : ndarray of float64, shape (6,)
        ρs low, ρs high, ln p low, ln p high, p low, p high.
    max_iter : int
    tol : float
    steps : int
        Gauss-Newton steps of the diffuse level (with ``d``).

    Returns
    -------
    rho, q, delta : ndarray of float64
        ρs and ln p (float32 values after the Levenberg-Marquardt iteration, as the numpy
        solver keeps them, then refined with δ), and δ (NaN without ``d``).
    converged : ndarray of bool
    iterations : ndarray of int32
    sums : ndarray of float64, shape (5, T)
        The lobe sums at the solution (:func:`facestats.model.fitting.lobes.lobe_sums`) of y + δ d.
    robust : ndarray of float64, shape (3, T)
        E² and the HC3 variances of ρs and q
        (:func:`facestats.model.fitting.uncertainty.robust_variances`).
    """
    n_tex = starts.shape[0]
    rho = np.full(n_tex, np.nan)
    q = np.full(n_tex, np.nan)
    delta = np.full(n_tex, np.nan)
    converged = np.zeros(n_tex, np.bool_)
    iterations = np.zeros(n_tex, np.int32)
    all_sums = np.zeros((5, n_tex))
    robust = np.full((3, n_tex), np.nan)
    width = 1
    for t in range(n_tex):
        width = max(width, counts[t])
    u = np.empty(width, np.float32)
    bits = np.empty(width, np.int32)
    terms = np.empty(15 * width)  # per-sample columns and terms of the robust variances (_robust)
    sums = np.zeros(7)  # the lobe sums of lobes.lobe_sums, then Σ u d, Σ u z d (_raw_sums)
    trial = np.zeros(7)
    work = np.zeros(20)
    par = np.zeros(3)
    out = np.zeros(8)
    for t in range(n_tex):
        if not solve[t]:
            continue
        _solve_one(
            model,
            y,
            z,
            a,
            d,
            rows,
            tilt,
            albedo[t],
            starts[t],
            counts[t],
            p_start[t],
            bounds,
            max_iter,
            tol,
            steps,
            u,
            bits,
            sums,
            trial,
            work,
            par,
            out,
            terms,
        )
        rho[t] = out[0]
        q[t] = out[1]
        delta[t] = out[2]
        converged[t] = out[3] > 0
        iterations[t] = np.int32(out[4])
        robust[:, t] = out[5:]
        all_sums[:, t] = sums[:5]
    return rho, q, delta, converged, iterations, all_sums, robust


@numba.njit(cache=True, nogil=True, error_model="numpy")
def rms_runs(model, y, z, a, d, starts, counts, good, rho, q, shift):
    """E(p) = sqrt(Σ r² / n) per texel with ``good[t]`` (NaN for the others), r = y + δ d − ρs g at the given
    (ρs, q = ln p, δ = ``shift``) (:func:`facestats.model.fitting.uncertainty.rms_error`; ``d`` empty: no δ)."""
    n_tex = starts.shape[0]
    out = np.full(n_tex, np.nan)
    width = 1
    for t in range(n_tex):
        width = max(width, counts[t])
    u = np.empty(width, np.float32)
    bits = np.empty(width, np.int32)
    with_d = d.shape[0] > 0
    for t in range(n_tex):
        if not good[t]:
            continue
        start, n = starts[t], counts[t]
        fill_lobe(_rate(model, q[t]), z, a, start, n, u, bits)
        p = math.exp(q[t])
        sc = rho[t] * (1.0 / (p * p) if model == TORRANCE_SPARROW else p + 2)
        e2 = 0.0
        for j in range(n):
            r = np.float64(y[start + j]) - sc * np.float64(u[j])
            if with_d:
                r += shift[t] * np.float64(d[start + j])
            e2 += r * r
        out[t] = math.sqrt(e2 / n)
    return out
