"""Compiled reductions over runs of samples: photometric stereo's sums, micro-normals, the stable minimum.

Each kernel replaces a numpy reduction of :mod:`facestats.model.fitting`
(Weyrich et al. 2006 §5.1-5.2) by one pass over the samples:

* :func:`camera_system` and :func:`camera_rhs` — per (lumitexel, camera):
  A = Σ ωi ωiᵀ (six entries) and b = Σ y ωi / F_t(θi) over the lights used by
  :func:`facestats.model.fitting.photometric_normals` (float64, sample order;
  numpy forms them as batched products on the (lumitexel, camera, light) grid);
* :func:`run_argmax` — the first brightest sample of every (lumitexel, camera)
  run (:func:`facestats.model.fitting.micro_normals`);
* :func:`stable_minimum` — the (k+1)-th smallest penalised value per lumitexel
  and channel (:func:`facestats.model.fitting.albedo_stable_minimum`, eq. 9),
  ordered exactly as numpy's int64 keys order them (value, with −0 below +0,
  then position), in float32 arithmetic identical to numpy's, so the albedo
  is the same bits;
* :func:`refine_sums` — the mean of π f_r/(F_t F_t) over the specular-free
  samples (:func:`facestats.model.fitting.refine_albedo`), summed in float64.

Sums over a run use two partial sums (even and odd samples, added at the
end): the order is fixed by the code, so the result does not depend on the
CPU, and the two chains of additions run in parallel.
"""

from __future__ import annotations

import numba
import numpy as np

_FLT_MAX = np.float32(np.finfo(np.float32).max)

__all__ = ["camera_system", "camera_rhs", "run_argmax", "stable_minimum", "refine_sums"]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def camera_system(
    texel,
    light_index,
    camera_index,
    run_keys,
    run_starts,
    run_counts,
    wi_flat,
    wo_flat,
    scan_normal,
    y,
    cos_specular,
    cos_limit,
):
    """Used samples of photometric stereo and the per-(lumitexel, camera) sums A = Σ ωi ωiᵀ.

    A sample is used when its half vector lies more than the specular exclusion
    angle from the scanned normal (N·H < ``cos_specular``), θi and θo are within
    the angle limit (cosines > ``cos_limit``) and 0 < y < ∞ (all float32 as
    :func:`facestats.model.fitting.photometric_normals` computes them).  ``run_keys``,
    ``run_starts``, ``run_counts`` are the (lumitexel, camera) runs of
    :meth:`facestats.model.fitting.Samples.camera_runs`.

    Returns
    -------
    y_used : float32 (S,)
        y of the used samples, 0 elsewhere.
    a : float64 (6, n C)
        A00, A01, A02, A11, A12, A22 per (lumitexel, camera), flat index t C + c.
    count : float64 (n C,)
        Used lights per (lumitexel, camera).
    """
    n_s = texel.shape[0]
    n_keys = scan_normal.shape[0] * (wo_flat.shape[0] // scan_normal.shape[0])
    y_used = np.empty(n_s, np.float32)
    two = np.float32(2.0)
    tiny = np.float32(1e-12)
    for s in range(n_s):  # the mask: no reductions, vectorised
        t = texel[s]
        li = light_index[s]
        cj = camera_index[s]
        ix, iy, iz = wi_flat[li, 0], wi_flat[li, 1], wi_flat[li, 2]
        ox, oy, oz = wo_flat[cj, 0], wo_flat[cj, 1], wo_flat[cj, 2]
        nx, ny, nz = scan_normal[t, 0], scan_normal[t, 1], scan_normal[t, 2]
        ci = ix * nx + iy * ny + iz * nz
        co = ox * nx + oy * ny + oz * nz
        io = ox * ix + oy * iy + oz * iz
        cos_h = (ci + co) / np.sqrt(max(two + two * io, tiny))
        ys = y[s]
        ok = (cos_h < cos_specular) & (ci > cos_limit) & (co > cos_limit) & (ys > 0) & (ys < np.inf)
        y_used[s] = np.float32(ok) * min(ys, _FLT_MAX)  # 0 unless used (then y < inf): branch-free
    a = np.zeros((6, n_keys))
    count = np.zeros(n_keys)
    zero = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    for r in range(run_keys.shape[0]):  # one run per (lumitexel, camera): sums in registers, even/odd halves
        e = zero
        o = zero
        s0, n = run_starts[r], run_counts[r]
        j = 0
        while j + 1 < n:
            e = _add_outer(e, wi_flat, light_index[s0 + j], y_used[s0 + j])
            o = _add_outer(o, wi_flat, light_index[s0 + j + 1], y_used[s0 + j + 1])
            j += 2
        if j < n:
            e = _add_outer(e, wi_flat, light_index[s0 + j], y_used[s0 + j])
        cj = run_keys[r]
        for q in range(6):
            a[q, cj] = e[q] + o[q]
        count[cj] = e[6] + o[6]
    return y_used, a, count


@numba.njit(cache=True, nogil=True, inline="always")
def _add_outer(acc, wi_flat, li, y_used):
    """acc + (the six entries of ωi ωiᵀ, 1), times 1 for a used sample (y_used > 0), else 0 (branch-free)."""
    m = np.float64(y_used > 0)
    x, w, v = np.float64(wi_flat[li, 0]), np.float64(wi_flat[li, 1]), np.float64(wi_flat[li, 2])
    mx, mw = m * x, m * w
    return (
        acc[0] + mx * x,
        acc[1] + mx * w,
        acc[2] + mx * v,
        acc[3] + mw * w,
        acc[4] + mw * v,
        acc[5] + (m * v) * v,
        acc[6] + m,
    )


@numba.njit(cache=True, nogil=True)
def camera_rhs(light_index, run_keys, run_starts, run_counts, y_used, w_flat, n_keys):
    """b = Σ y w per (lumitexel, camera) (float64), w = ωi or ωi/F_t per light, shape (n C, 3).

    ``y_used`` is :func:`camera_system`'s (0 for unused samples, so every sample adds, branch-free).
    """
    b = np.zeros((n_keys, 3))
    for r in range(run_keys.shape[0]):
        e0 = e1 = e2 = o0 = o1 = o2 = 0.0
        s0, n = run_starts[r], run_counts[r]
        j = 0
        while j + 1 < n:
            s = s0 + j
            li, lk = light_index[s], light_index[s + 1]
            ye, yo = np.float64(y_used[s]), np.float64(y_used[s + 1])
            e0 += ye * np.float64(w_flat[li, 0])
            e1 += ye * np.float64(w_flat[li, 1])
            e2 += ye * np.float64(w_flat[li, 2])
            o0 += yo * np.float64(w_flat[lk, 0])
            o1 += yo * np.float64(w_flat[lk, 1])
            o2 += yo * np.float64(w_flat[lk, 2])
            j += 2
        if j < n:
            s = s0 + j
            li = light_index[s]
            ye = np.float64(y_used[s])
            e0 += ye * np.float64(w_flat[li, 0])
            e1 += ye * np.float64(w_flat[li, 1])
            e2 += ye * np.float64(w_flat[li, 2])
        cj = run_keys[r]
        b[cj, 0], b[cj, 1], b[cj, 2] = e0 + o0, e1 + o1, e2 + o2
    return b


@numba.njit(cache=True, nogil=True)
def _brighter(a, b):
    """``a`` ranks before ``b`` in the brightness order of :func:`run_argmax` (NaN last, +0 above −0)."""
    if a != a:
        return False
    if b != b:
        return True
    if a > b:
        return True
    return a == b and a == 0 and np.signbit(b) and not np.signbit(a)


@numba.njit(cache=True, nogil=True)
def run_argmax(values, starts, counts):
    """Position of the first largest value of every run (NaN ranks last), shape (runs,)."""
    out = np.empty(starts.shape[0], np.int64)
    for r in range(starts.shape[0]):
        s0 = starts[r]
        best = s0
        for s in range(s0 + 1, s0 + counts[r]):
            if _brighter(values[s], values[best]):
                best = s
        out[r] = best
    return out


@numba.njit(cache=True, nogil=True)
def _before(a, pa, b, pb):
    """(a, position pa) ranks before (b, pb): by value with −0 below +0, then by position."""
    if a < b:
        return True
    if a > b:
        return False
    sa, sb = np.signbit(a), np.signbit(b)
    if sa != sb:
        return sa
    return pa < pb


@numba.njit(cache=True, nogil=True, error_model="numpy")
def stable_minimum(starts, counts, brdf, ft2, cos_i, cos_o, use, k, gamma, c0, c_span):
    """Eq. 9 with the grazing penalty: per lumitexel and channel, v of the (k+1)-th smallest v·(1 + γ g).

    v = π f_r/(F_t F_t) in float32, g = clip((c0 − min(cos θi, cos θo))/c_span, 0, 1) in
    float64 and the penalty 1 + γ g rounded to float32, as
    :func:`facestats.model.fitting.albedo_stable_minimum` computes them (``gamma`` is
    γ rounded to float32); samples count only where ``use`` and v is finite in all channels.

    Returns
    -------
    albedo : float32 (n, 3)
        NaN where fewer than k + 1 samples count.
    n_ok : int64 (n,)
        Samples that count per lumitexel.
    """
    n = starts.shape[0]
    out = np.full((n, 3), np.nan, np.float32)
    n_ok = np.zeros(n, np.int64)
    pi32 = np.float32(np.pi)
    best_v = np.empty((3, k + 1), np.float32)
    best_p = np.empty((3, k + 1), np.int64)
    for t in range(n):
        m = 0  # entries held in each channel's sorted buffer of the k + 1 smallest
        for s in range(starts[t], starts[t] + counts[t]):
            if not use[s]:
                continue
            f = ft2[s]
            v0, v1, v2 = (pi32 * brdf[0, s]) / f, (pi32 * brdf[1, s]) / f, (pi32 * brdf[2, s]) / f
            if not np.isfinite(v0 + v1 + v2):
                continue
            n_ok[t] += 1
            g = min(max((c0 - np.float64(min(cos_i[s], cos_o[s]))) / c_span, 0.0), 1.0)
            penalty = np.float32(1.0 + gamma * g)
            _insert(best_v[0], best_p[0], m, k, v0 * penalty, s)
            _insert(best_v[1], best_p[1], m, k, v1 * penalty, s)
            _insert(best_v[2], best_p[2], m, k, v2 * penalty, s)
            if m < k + 1:
                m += 1
        if m == k + 1:
            for c in range(3):
                p = best_p[c, k]
                out[t, c] = (pi32 * brdf[c, p]) / ft2[p]
    return out, n_ok


@numba.njit(cache=True, nogil=True)
def _insert(best_v, best_p, m, k, ranked, s):
    """Insert (ranked, s) into the sorted buffer holding ``m`` ≤ k + 1 entries (kept at the k + 1 smallest)."""
    if m == k + 1 and not _before(ranked, s, best_v[k], best_p[k]):
        return
    j = m if m < k + 1 else k
    while j > 0 and _before(ranked, s, best_v[j - 1], best_p[j - 1]):
        best_v[j] = best_v[j - 1]
        best_p[j] = best_p[j - 1]
        j -= 1
    best_v[j] = ranked
    best_p[j] = s


@numba.njit(cache=True, nogil=True, error_model="numpy")
def refine_sums(starts, counts, brdf, ft2, cos_half, use, cos_max):
    """Mean of v = π f_r/(F_t F_t) per lumitexel and channel over the samples with ``use``, N·H < ``cos_max``
    and v finite in every channel (float32 v, float64 sums); NaN where none qualifies.

    Returns
    -------
    albedo : float32 (n, 3)
    count : int64 (n,)
    grey_std : float64 (n,)
        Standard error of the mean of v_R + v_G + v_B (NaN for fewer than two samples).
    """
    n = starts.shape[0]
    out = np.full((n, 3), np.nan, np.float32)
    cnt = np.zeros(n, np.int64)
    grey_std = np.full(n, np.nan)
    pi32 = np.float32(np.pi)
    for t in range(n):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        sq = 0.0
        k = 0
        for s in range(starts[t], starts[t] + counts[t]):  # branch-free: selects, no jumps
            f = ft2[s]
            v0, v1, v2 = (pi32 * brdf[0, s]) / f, (pi32 * brdf[1, s]) / f, (pi32 * brdf[2, s]) / f
            ok = use[s] & (np.float64(cos_half[s]) < cos_max) & np.isfinite(v0 + v1 + v2)
            g = np.float64(v0) + np.float64(v1) + np.float64(v2)
            s0 += v0 if ok else 0.0
            s1 += v1 if ok else 0.0
            s2 += v2 if ok else 0.0
            sq += g * g if ok else 0.0
            k += ok
        cnt[t] = k
        if k:
            out[t, 0], out[t, 1], out[t, 2] = s0 / k, s1 / k, s2 / k
        if k > 1:
            mean = (s0 + s1 + s2) / k
            grey_std[t] = np.sqrt(max(sq / k - mean * mean, 0.0) * k / (k - 1) / k)
    return out, cnt, grey_std
