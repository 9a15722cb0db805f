"""The batch Levenberg-Marquardt solve of eq. 14, compiled and run texel by texel (Weyrich et al. 2006 §5.3).

The same algorithm as :mod:`facestats.model.fitting.solver` (parameters
(ρs, q = ln p), log-linear cold start, projected steps with per-texel damping,
the same four stopping tests, float32 parameter state), written as a loop over
texels: every evaluation of a texel's lobe (:func:`_lobe_sums`) makes two
passes over its samples while they sit in the CPU cache — the lobe values
(vectorised, :func:`facestats.model.fitting.kernels.fastexp.fill_lobe`) and the
five sums of :func:`facestats.model.fitting.lobes.lobe_sums` (float64, in
sample order) — and a texel stops as soon as it converges.  At the end one
pass over explicit residuals r = y − ρs g forms E² and the sums of the
standard errors (:func:`facestats.model.fitting.uncertainty.residual_sums`).

Differences from the numpy solver, all below float32 resolution of the
parameters: sums are float64 in sample order (numpy: pairwise float32), and a
converged texel stops (numpy keeps stepping converged texels until the
working set is compacted, which changes E² by less than ``tol``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from facestats.model.fitting.kernels.fastexp import fill_lobe
from facestats.model.fitting.uncertainty import LEVERAGE_CAP

__all__ = ["solve_runs", "TORRANCE_SPARROW", "BLINN_PHONG"]

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
def _lobe_sums(model, q, y, z, a, start, n, u, bits, sums):
    """Σ y u, Σ y u z, Σ u², Σ u² z, Σ u² z² of one texel into ``sums`` (float64; even and odd samples
    summed apart, in sample order, then added)."""
    fill_lobe(_rate(model, q), z, a, start, n, u, bits)
    e = (0.0, 0.0, 0.0, 0.0, 0.0)
    o = (0.0, 0.0, 0.0, 0.0, 0.0)
    j = 0
    while j + 1 < n:  # even and odd samples in two chains of additions
        e = _add_lobe(e, np.float64(u[j]), np.float64(z[start + j]), np.float64(y[start + j]))
        o = _add_lobe(o, np.float64(u[j + 1]), np.float64(z[start + j + 1]), np.float64(y[start + j + 1]))
        j += 2
    if j < n:
        e = _add_lobe(e, np.float64(u[j]), np.float64(z[start + j]), np.float64(y[start + j]))
    for k in range(5):
        sums[k] = e[k] + o[k]


@numba.njit(cache=True, nogil=True, inline="always")
def _add_lobe(acc, uj, zj, yj):
    """acc + (y u, y u z, u², u² z, u² z²) of one sample."""
    yu = yj * uj
    uu = uj * uj
    return (acc[0] + yu, acc[1] + yu * zj, acc[2] + uu, acc[3] + uu * zj, acc[4] + uu * zj * zj)


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


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _residual_sums(model, q, rho, y, z, a, d, start, n, u, bits, sums, out):
    """E², Σ r²/(1 − h)² (J00, J01, J11) and Jᵀd of one texel (float64) into ``out[0:6]``.

    As :func:`facestats.model.fitting.uncertainty.residual_sums`: J = (g, ρs ∂g/∂q), leverages
    h from JᵀJ of the lobe sums ``sums`` at the solution; ``d`` empty: Jᵀd = 0.
    """
    _, sgg, _, sgdg, sdgdg = _moments(model, q, sums)
    h00, h01, h11 = sgg, rho * sgdg, rho * rho * sdgdg
    det = h00 * h11 - h01 * h01
    i00, i01, i11 = h11 / det, -h01 / det, h00 / det
    fill_lobe(_rate(model, q), z, a, start, n, u, bits)
    p = math.exp(q)
    w = 1.0 / (p * p)
    scale32 = np.float32(rho * (w if model == TORRANCE_SPARROW else p + 2))
    e = m00 = m01 = m11 = b0 = b1 = 0.0
    with_d = d.shape[0] > 0
    for j in range(n):
        uj = np.float64(u[j])
        zj = np.float64(z[start + j])
        r = np.float64(y[start + j] - scale32 * u[j])
        if model == TORRANCE_SPARROW:
            g = w * uj
            j1 = rho * 2 * w * uj * (w * zj - 1)
        else:
            g = (p + 2) * uj
            j1 = rho * p * uj * (1 + (p + 2) * zj)
        rr = r * r
        lev = min(max(_finite(i00 * g * g + 2 * i01 * g * j1 + i11 * j1 * j1), 0.0), LEVERAGE_CAP)
        wr = rr / ((1 - lev) * (1 - lev))
        e += rr
        m00 += wr * g * g
        m01 += wr * g * j1
        m11 += wr * j1 * j1
        if with_d:
            dj = np.float64(d[start + j])
            b0 += g * dj
            b1 += j1 * dj
    out[0], out[1], out[2], out[3], out[4], out[5] = e, m00, m01, m11, b0, b1


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _solve_one(model, y, z, a, d, start, n, p0, bounds, max_iter, tol, u, bits, sums, trial, out):
    """The whole solve of one texel; ``out`` receives (ρs, q, converged, iterations, then the six residual sums)."""
    r_lo, r_hi, q_lo, q_hi, p_lo, p_hi = bounds[0], bounds[1], bounds[2], bounds[3], bounds[4], bounds[5]
    swyy = 0.0
    for j in range(n):
        swyy += np.float64(y[start + j]) * np.float64(y[start + j])
    if p0 != p0:
        p0 = _log_linear_start(model, y, z, a, start, n)
        if p0 != p0:
            p0 = 0.3 if model == TORRANCE_SPARROW else 20.0
    q_start = min(max(math.log(min(max(p0, p_lo), p_hi)), q_lo), q_hi)
    _lobe_sums(model, q_start, y, z, a, start, n, u, bits, sums)
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
        _lobe_sums(model, q1, y, z, a, start, n, u, bits, trial)
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
    out[0] = rho
    out[1] = q
    out[2] = 1.0 if done else 0.0
    out[3] = it
    _residual_sums(model, q, rho, y, z, a, d, start, n, u, bits, sums, out[4:])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def solve_runs(model, y, z, a, d, starts, counts, solve, p_start, bounds, max_iter, tol):
    """Solve eq. 14 for every texel with ``solve[t]`` (module docstring).

    Parameters
    ----------
    model : int
        :data:`TORRANCE_SPARROW` or :data:`BLINN_PHONG`.
    y, z, a : ndarray of float32, shape (S,)
        y = f_s cos θi, and the lobe factors (z, A) of every kept sample, in per-texel runs.
    d : ndarray of float32, shape (S,) or (0,)
        ∂y/∂α of the grey albedo per sample (empty: no albedo term).
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

    Returns
    -------
    rho, q : ndarray of float64
        ρs and ln p (float32 values, as the numpy solver keeps them).
    converged : ndarray of bool
    iterations : ndarray of int32
    sums : ndarray of float64, shape (5, T)
        The lobe sums at the solution (:func:`facestats.model.fitting.lobes.lobe_sums`).
    residual : ndarray of float64, shape (6, T)
        E² = Σ (y − ρs g)², Σ r² J J (three entries) and Jᵀd
        (:func:`facestats.model.fitting.uncertainty.residual_sums`).
    """
    n_tex = starts.shape[0]
    rho = np.full(n_tex, np.nan)
    q = np.full(n_tex, np.nan)
    converged = np.zeros(n_tex, np.bool_)
    iterations = np.zeros(n_tex, np.int32)
    all_sums = np.zeros((5, n_tex))
    residual = np.zeros((6, n_tex))
    width = 1
    for t in range(n_tex):
        width = max(width, counts[t])
    u = np.empty(width, np.float32)
    bits = np.empty(width, np.int32)
    sums = np.zeros(5)
    trial = np.zeros(5)
    out = np.zeros(10)
    for t in range(n_tex):
        if not solve[t]:
            continue
        _solve_one(
            model, y, z, a, d, starts[t], counts[t], p_start[t], bounds, max_iter, tol, u, bits, sums, trial, out
        )
        rho[t] = out[0]
        q[t] = out[1]
        converged[t] = out[2] > 0
        iterations[t] = np.int32(out[3])
        residual[:, t] = out[4:]
        all_sums[:, t] = sums
    return rho, q, converged, iterations, all_sums, residual
