"""Compiled per-sample inputs of the specular fit: y and the lobe factors (z, A) of eq. 11-13, compacted.

One pass over the samples does what
:func:`facestats.model.fitting.fit_specular_models` does in numpy before the
solve: keep the samples of eq. 14 (``use``, finite f_s, ωi and ωo above the
horizon, A > 0 for every model), and write, in per-texel runs,

* y = f_s cos θi;
* Torrance-Sparrow (eq. 12-13): z = tan²δ, A = K cos θi / cos⁴δ with
  K = G F_r(ωo·H)/(π N·ωi N·ωo) (:func:`facestats.model.brdf.torrance_sparrow_cosines`:
  N·H = (N·ωi + N·ωo)/‖ωi + ωo‖, ωo·H = (1 + ωi·ωo)/‖ωi + ωo‖, G the V-groove term,
  F_r the unpolarised Fresnel reflectance in Cook & Torrance's closed form);
* Blinn-Phong (eq. 11): z = ln cos δ, A = cos θi/(2π).

The arithmetic is float32 in the order of the numpy functions, so the factors
agree with theirs to the last bit, except z of Blinn-Phong, whose logarithm is
:func:`facestats.model.fitting.kernels.fastexp.fill_log` (within 2e-7 of numpy's).

The same module forms what the standard errors' tilts of the normals need
(:mod:`facestats.model.fitting.normal_tilt`): the per-(lumitexel, direction) grids
(:func:`tilt_grid`) and a texel's slopes of the factors (:func:`texel_tilt_slopes`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from facestats.model.fitting.kernels.fastexp import fill_log
from facestats.model.fitting.kernels.samples import cos_half32

__all__ = ["fresnel_reflectance", "specular_inputs", "texel_tilt_slopes", "tilt_grid"]

_ONE = np.float32(1.0)
_TWO = np.float32(2.0)
_HALF = np.float32(0.5)
_PI = np.float32(np.pi)
_TWO_PI = np.float32(2 * np.pi)
_THREE_PI = np.float32(3 * np.pi)
_TINY = np.float32(np.finfo(np.float32).tiny)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def fresnel_reflectance(c, eta):
    """Unpolarised Fresnel reflectance at cos θ = ``c`` in [0, 1], relative index ``eta`` (float32).

    Cook & Torrance (1982) closed form, g = sqrt(η² − 1 + c²):
    F_r = ½ ((g − c)/(g + c))² [1 + ((c(g + c) − 1)/(c(g − c) + 1))²]; 1 for total
    internal reflection (g² ≤ 0) — :func:`facestats.model.fresnel.fresnel_reflectance_unchecked`.
    """
    g2 = (eta * eta - _ONE) + c * c
    g = np.sqrt(max(g2, np.float32(0.0)))
    gpc = g + c
    gmc = g - c
    a = gmc / gpc
    b = (c * gpc - _ONE) / (c * gmc + _ONE)
    out = (_HALF * a) * a * (_ONE + b * b)
    if g2 <= 0 or not np.isfinite(out):
        return _ONE
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _ts_factors(ci, co, io, eta):
    """(tan²δ, K cos θi / cos⁴δ) of one sample above the horizon (float32, eq. 12-13)."""
    inv = _ONE / np.sqrt(max(_TWO + _TWO * io, np.float32(0.0)))
    n_h = min(max((ci + co) * inv, _TINY), _ONE)
    wo_h = min(max((_ONE + io) * inv, _TINY), _ONE)
    g = min(_ONE, (_TWO * n_h) * min(ci, co) / wo_h)
    k = (g * fresnel_reflectance(wo_h, eta)) / ((_PI * ci) * co)
    c2 = n_h * n_h
    return (_ONE - c2) / c2, max((k * ci) / (c2 * c2), np.float32(0.0))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _all_factors(ci, co, io, f_s, use, limited, use_limited, ft2, eta, want_ts, want_bp, limit_ts, limit_bp):
    """Every sample's keep flags (the full domain; the limited one, all False unless ``limited``), y,
    TS (z, A), clipped cos δ (BP) and d, uncompacted (a vectorised loop)."""
    n_s = ci.shape[0]
    keep = np.empty(n_s, np.bool_)
    keep_limited = np.empty(n_s, np.bool_)
    y = np.empty(n_s, np.float32)
    ts_z = np.empty(n_s if want_ts else 0, np.float32)
    ts_a = np.empty(n_s if want_ts else 0, np.float32)
    cos_d = np.empty(n_s if want_bp else 0, np.float32)
    with_d = ft2.shape[0] > 0
    d = np.empty(n_s if with_d else 0, np.float32)
    for s in range(n_s):  # every sample, no branches out of the loop: vectorised
        c_i, c_o, fs, io_s = ci[s], co[s], f_s[s], io[s]
        base = np.isfinite(fs) & (c_i > 0) & (c_o > 0)
        ok = use[s] & base
        ok_limited = (use_limited[s] & base) if limited else False
        y[s] = fs * c_i
        if with_d:
            d[s] = -(ft2[s] * c_i) / _THREE_PI
        if want_ts:
            tz, ta = _ts_factors(c_i, c_o, io_s, eta)
            ts_z[s] = tz
            ts_a[s] = ta
            ok = ok & (ta > 0)  # A underflows only in extreme geometry
            ok_limited = ok_limited & ((ta > 0) | ~limit_ts)
        if want_bp:
            cos_d[s] = min(max(cos_half32(c_i, c_o, io_s), np.float32(1e-6)), _ONE)
            positive = c_i / _TWO_PI > 0
            ok = ok & positive
            ok_limited = ok_limited & (positive | ~limit_bp)
        keep[s] = ok
        keep_limited[s] = ok_limited
    return keep, keep_limited, y, ts_z, ts_a, cos_d, d


@numba.njit(cache=True, nogil=True, error_model="numpy")
def specular_inputs(
    ci, co, io, f_s, use, limited, use_limited, ft2, starts, counts, eta, want_ts, want_bp, limit_ts, limit_bp
):
    """Kept samples of eq. 14 and their factors, in per-texel runs (module docstring), on the full domain
    and on one limited domain (e.g. θi and θo below a smaller angle).

    Parameters
    ----------
    ci, co, io, f_s : ndarray of float32, shape (S,)
        N·ωi, N·ωo, ωi·ωo and the grey specular residual per sample.
    use : ndarray of bool, shape (S,)
        Samples of the full domain.
    limited : bool
        Whether there is a limited domain (else its arrays are empty).
    use_limited : ndarray of bool, shape (S,)
        Samples of the limited domain (any shape without one).
    ft2 : ndarray of float32, shape (S,) or (0,)
        F_t(θi) F_t(θo) per sample, for d = ∂y/∂α = −F_t F_t cos θi/(3π) (empty: no d).
    starts, counts : ndarray of int64
        Every texel's run of samples.
    eta : float32
    want_ts, want_bp : bool
        Models whose factors are wanted on the full domain (a sample is kept only where every wanted
        A > 0).
    limit_ts, limit_bp : bool
        Models fitted on the limited domain (kept there where their A > 0); among the wanted ones.

    Returns
    -------
    full, limited : tuple
        Each (kept, y, ts_z, ts_a, bp_z, bp_a, d, index): ``kept`` int64 (T,) kept samples per texel,
        the next six float32 (S'), compacted; a model's factors (or d) are empty when not wanted there;
        ``index`` int64 (S') the kept samples' indices in the inputs.
        The per-sample values are the same whichever domain keeps them.
    """
    n_s = ci.shape[0]
    keep, keep_limited, y, ts_z, ts_a, cos_d, d = _all_factors(
        ci, co, io, f_s, use, limited, use_limited, ft2, eta, want_ts, want_bp, limit_ts, limit_bp
    )
    bp_z = np.empty(n_s if want_bp else 0, np.float32)
    if want_bp:
        fill_log(cos_d, bp_z, np.empty(n_s, np.int32))
    bp_a = np.empty(n_s if want_bp else 0, np.float32)
    for s in range(bp_a.shape[0]):
        bp_a[s] = ci[s] / _TWO_PI
    lim = _compact(keep_limited, starts, counts, y, ts_z, ts_a, bp_z, bp_a, d, limit_ts, limit_bp, limited)
    full = _compact(keep, starts, counts, y, ts_z, ts_a, bp_z, bp_a, d, want_ts, want_bp, True)
    return full, lim


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _compact(keep, starts, counts, y, ts_z, ts_a, bp_z, bp_a, d, with_ts, with_bp, wanted):
    """The samples with ``keep`` in per-texel runs: (kept per texel, y, ts_z, ts_a, bp_z, bp_a, d, index), copies
    (a model's arrays empty unless ``with_*``, d empty without it; all empty unless ``wanted``) and the kept
    samples' indices."""
    n_s = keep.shape[0] if wanted else 0
    kept = np.zeros(starts.shape[0] if wanted else 0, np.int64)
    index = np.empty(n_s, np.int64)
    m = 0
    for t in range(kept.shape[0]):  # branch-free: every sample is written, the next one overwrites it if dropped
        m0 = m
        for s in range(starts[t], starts[t] + counts[t]):
            index[m] = s
            m += keep[s]
        kept[t] = m - m0
    index = index[:m]
    return (
        kept,
        _gather(y, index, wanted),
        _gather(ts_z, index, wanted and with_ts),
        _gather(ts_a, index, wanted and with_ts),
        _gather(bp_z, index, wanted and with_bp),
        _gather(bp_a, index, wanted and with_bp),
        _gather(d, index, wanted and d.shape[0] > 0),
        index,
    )


@numba.njit(cache=True, nogil=True)
def _gather(values, index, wanted):
    """``values[index]`` (a vectorised gather), or an empty array if not ``wanted``."""
    out = np.empty(index.shape[0] if wanted else 0, values.dtype)
    for k in range(out.shape[0]):
        out[k] = values[index[k]]
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _kappa(cos, e2, with_inverse):
    """κ = (1/cos θ if ``with_inverse``) − F_r'(θ)/F_t(θ) at cos θ = ``cos`` > 0 (float64; η² = ``e2``):
    :func:`facestats.model.fitting.normal_tilt.diffuse_coefficients`, with F_r and F_r' the closed form of
    :func:`fresnel_reflectance` and its derivative
    (:func:`facestats.model.fresnel.fresnel_reflectance_slope_unchecked`)."""
    c = min(cos, 1.0)
    kappa = 1.0 / c if with_inverse else 0.0
    g2 = e2 - 1.0 + c * c
    if g2 > 0.0:  # else total internal reflection: F_r = 1, F_r' = 0 (F_t = 0: no diffuse light)
        g = math.sqrt(g2)
        gpc, gmc = g + c, g - c
        a = gmc / gpc
        da = 2.0 * (1.0 - e2) / (g * gpc * gpc)
        num, den = c * gpc - 1.0, c * gmc + 1.0
        dn, dd = g + c * c / g + 2.0 * c, g + c * c / g - 2.0 * c
        b = num / den
        db = (dn * den - num * dd) / (den * den)
        f = 0.5 * a * a * (1.0 + b * b)
        kappa -= (a * da * (1.0 + b * b) + a * a * b * db) / (1.0 - f)
    return kappa


@numba.njit(cache=True, nogil=True, error_model="numpy")
def tilt_grid(directions, normal, t1, t2, eta, with_inverse):
    """The tilts' grid of one direction grid (n, D, 3) float32: (n D, 4) float32 with columns ω·t₁, ω·t₂, κ and 1/N·ω
    per (lumitexel, direction), κ and 1/N·ω 0 at or below the horizon
    (:func:`facestats.model.fitting.normal_tilt.tilt_grids`: the same float32 dot products, κ of :func:`_kappa`
    with 1/cos θ for the lights (``with_inverse``), 1/N·ω in float64 rounded to float32)."""
    n, m = directions.shape[0], directions.shape[1]
    out = np.zeros((n * m, 4), np.float32)
    e2 = np.float64(eta) * np.float64(eta)
    for t in range(n):
        for k in range(m):
            x, y, z = directions[t, k, 0], directions[t, k, 1], directions[t, k, 2]
            row = t * m + k
            out[row, 0] = x * t1[t, 0] + y * t1[t, 1] + z * t1[t, 2]
            out[row, 1] = x * t2[t, 0] + y * t2[t, 1] + z * t2[t, 2]
            c = x * normal[t, 0] + y * normal[t, 1] + z * normal[t, 2]
            if c > 0:
                out[row, 2] = np.float32(_kappa(np.float64(c), e2, with_inverse))
                out[row, 3] = np.float32(1.0 / np.float64(c))
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def texel_tilt_slopes(torrance_sparrow, rows, tilt, z, start, n, out):
    """The slopes of two tilts of the normals for the kept samples ``start`` … ``start + n`` into ``out[:rows, :n]``
    (float64): rows ∂z₁, ∂ln A₁, ∂z₂, ∂ln A₂ of the lobe and, with ``rows`` = 6, ∂ln D₁, ∂ln D₂ of the diffuse
    term D = F_t F_t cos θi (:func:`facestats.model.fitting.normal_tilt.tilt_slopes`).

    ``tilt`` = (index, light_index, camera_index, ci, co, io, light, camera), the arrays of
    :class:`facestats.model.fitting.normal_tilt.TiltInputs` (1/N·ω read from the grids' fourth columns);
    ``z`` the kept samples' lobe factor z;
    ``torrance_sparrow``: the model (else Blinn-Phong).  Without a square root: d cos δ / cos δ =
    (d(N·ωi) + d(N·ωo)) / (N·ωi + N·ωo), 1/cos²δ = 1 + tan²δ = 1 + z (Torrance-Sparrow), and G < 1 where
    2 (N·ωi + N·ωo) min(N·ωi, N·ωo) < 1 + ωi·ωo (G's test multiplied by ‖ωi + ωo‖).
    """
    index, light_index, camera_index, ci, co, io, light, camera = tilt
    for j in range(n):
        s = index[start + j]
        li, cj = light_index[s], camera_index[s]
        c_i, c_o = np.float64(ci[s]), np.float64(co[s])
        r_i, r_o, r_s = np.float64(light[li, 3]), np.float64(camera[cj, 3]), 1.0 / (c_i + c_o)
        # G < 1, and which of N·ωi, N·ωo sets it, as 0/1 weights (branch-free: both are data-dependent)
        g_on = 1.0 if 2.0 * (c_i + c_o) * min(c_i, c_o) < 1.0 + np.float64(io[s]) else 0.0
        by_i = 1.0 if c_i <= c_o else 0.0
        for t in range(2):
            dci, dco = np.float64(light[li, t]), np.float64(camera[cj, t])
            dc = (dci + dco) * r_s  # d cos δ / cos δ
            if torrance_sparrow:
                d_ln_g = g_on * (dc + by_i * dci * r_i + (1.0 - by_i) * dco * r_o)
                out[2 * t, j] = -2.0 * dc * (1.0 + np.float64(z[start + j]))
                out[2 * t + 1, j] = d_ln_g - dco * r_o - 4.0 * dc
            else:
                out[2 * t, j] = dc
                out[2 * t + 1, j] = dci * r_i
            if rows == 6:
                out[4 + t, j] = np.float64(light[li, 2]) * dci + np.float64(camera[cj, 2]) * dco
