"""Compiled reductions over runs of samples: photometric stereo's sums, micro-normals, the stable minimum.

Each kernel replaces a numpy reduction of :mod:`facestats.model.fitting`
(Weyrich et al. 2006 §5.1-5.2) by one pass over the samples:

* :func:`used_samples` and :func:`normal_passes` — photometric stereo
  (:func:`facestats.model.fitting.photometric_normals`): the samples it uses, then per lumitexel,
  while its samples sit in the cache, A = Σ ωi ωiᵀ per camera (float64, sample order; numpy forms
  it as batched products on the (lumitexel, camera, light) grid), and the passes: F_t(θi) of every
  light at the current normal (float32, as :func:`facestats.model.fresnel.fresnel_reflectance_unchecked`),
  b = Σ y ωi / F_t per camera, each camera's normal adj(A) b / ‖adj(A) b‖ and their cosine-weighted mean;
* :func:`run_argmax` — the first largest value (a BRDF sample) of every (lumitexel, camera)
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

import math

import numba
import numpy as np

from facestats.model.fitting.kernels.factors import fresnel_reflectance
from facestats.model.fitting.kernels.samples import cos_half32

_FLT_MAX = np.float32(np.finfo(np.float32).max)

__all__ = ["used_samples", "normal_passes", "run_argmax", "stable_minimum", "refine_sums"]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def used_samples(texel, light_index, camera_index, wi_flat, wo_flat, scan_normal, y, cos_specular, cos_limit):
    """y of the samples photometric stereo uses, 0 for the others (float32 (S,)).

    A sample is used when its half vector lies more than the specular exclusion
    angle from the scanned normal (N·H < ``cos_specular``), θi and θo are within
    the angle limit (cosines > ``cos_limit``) and 0 < y < ∞ (all float32 as
    :func:`facestats.model.fitting.photometric_normals` computes them).
    """
    n_s = texel.shape[0]
    y_used = np.empty(n_s, np.float32)
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
        cos_h = cos_half32(ci, co, io)
        ys = y[s]
        ok = (cos_h < cos_specular) & (ci > cos_limit) & (co > cos_limit) & (ys > 0) & (ys < np.inf)
        y_used[s] = min(ys, _FLT_MAX) if ok else np.float32(0.0)  # exactly 0 unless used (then 0 < y < inf)
    return y_used


@numba.njit(cache=True, nogil=True, error_model="numpy")
def normal_passes(
    run_keys, run_starts, run_counts, light_index, y_used, wi_grid, wo_grid, scan, eta, passes, min_lights
):
    """Photometric stereo (:func:`facestats.model.fitting.photometric_normals`) for every lumitexel, in one kernel.

    Per (lumitexel, camera): A = Σ ωi ωiᵀ over its used samples and their number k (float64), the
    adjugate adj(A) and det(A) (A⁻¹ = adj(A)/det(A); cofactors and determinant in the order the numpy
    engine of :func:`facestats.model.fitting.photometric_normals` forms them); the camera votes when
    k ≥ ``min_lights`` and det(A) > 10⁻⁶ max(k, 1)³.  Per pass: w = ωi, or ωi / F_t(θi) at the previous
    pass's normal (float32; F_t = 1 − F_r with F_r of
    :func:`facestats.model.fitting.kernels.factors.fresnel_reflectance`, θi clipped to [0°, 90°]); per voting
    camera b = Σ y w over its used samples, g = adj(A) b, N_c = g/‖g‖; the lumitexel's normal is
    Σ w_c N_c normalised, w_c = max(N_c·ωo,c, 0) (§5.1's blending weights), or the scanned normal where
    no camera votes.  Sums are float64, over even- and odd-position samples apart, in sample order.
    ``y_used`` is :func:`used_samples`'; ``run_keys``, ``run_starts``, ``run_counts`` are the
    (lumitexel, camera) runs of :meth:`facestats.model.fitting.Samples.camera_runs`.

    Returns
    -------
    normal : float64 (n, 3)
    camera_normal : float64 (n, C, 3)
        The cameras' normals of the last pass (NaN where a camera does not vote).
    """
    n, n_led = wi_grid.shape[0], wi_grid.shape[1]
    n_cam = wo_grid.shape[1]
    n_runs = run_keys.shape[0]
    normal = np.empty((n, 3))
    cam_n = np.full((n, n_cam, 3), np.nan)
    w = np.empty((n_led, 3), np.float32)
    scratch = np.empty((2, n_led), np.float32)
    # The used samples of one lumitexel, compacted per run into its even- and then odd-position samples
    # (unused ones have y = 0 and finite directions, photometric_normals checks: they add exact zeros).
    used_light = np.empty(n_cam * n_led, np.int64)
    used_y = np.empty(n_cam * n_led, np.float64)
    bounds = np.empty(3 * n_cam, np.int64)
    adj = np.empty((n_cam, 9))  # adj(A) of every camera run of the lumitexel, row-major
    votes = np.empty(n_cam, np.bool_)
    r_end = 0
    for t in range(n):
        r_begin = r_end
        while r_end < n_runs and run_keys[r_end] // n_cam == t:
            r_end += 1
        _compact_used(
            run_starts, run_counts, light_index, y_used, r_begin, r_end, t * n_led, used_light, used_y, bounds
        )
        for r in range(r_begin, r_end):
            i = 3 * (r - r_begin)
            votes[r - r_begin] = _camera_system(
                wi_grid, t, used_light, bounds[i], bounds[i + 1], bounds[i + 2], min_lights, adj[r - r_begin]
            )
        scanned = (np.float64(scan[t, 0]), np.float64(scan[t, 1]), np.float64(scan[t, 2]))
        nrm = scanned
        for it in range(passes):
            _light_weights(wi_grid, t, nrm, it > 0, eta, w, scratch)
            cam_n[t] = np.nan
            acc = (0.0, 0.0, 0.0, 0.0)  # Σ w_c N_c, Σ w_c
            for r in range(r_begin, r_end):
                if votes[r - r_begin]:
                    i = 3 * (r - r_begin)
                    cj = run_keys[r] - t * n_cam
                    b = _weighted_sum(used_light, used_y, w, bounds[i], bounds[i + 1], bounds[i + 2])
                    acc = _camera_vote(adj[r - r_begin], b, wo_grid[t, cj], cam_n[t, cj], acc)
            norm = np.sqrt(acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2])
            if acc[3] > 0:  # (NaN if the votes cancel exactly, as numpy gives)
                nrm = (acc[0] / norm, acc[1] / norm, acc[2] / norm)
            else:
                nrm = scanned
        normal[t, 0], normal[t, 1], normal[t, 2] = nrm
    return normal, cam_n


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _light_weights(wi_grid, t, nrm, fresnel, eta, w, scratch):
    """w = ωi of lumitexel ``t``'s lights, divided by F_t(θi) at the normal ``nrm`` if ``fresnel`` (float32).

    ``scratch`` is float32 (2, L): cos θi and F_t are formed in loops of their own, which LLVM vectorises.
    """
    n_led = wi_grid.shape[1]
    if not fresnel:
        for lt in range(n_led):
            w[lt, 0], w[lt, 1], w[lt, 2] = wi_grid[t, lt, 0], wi_grid[t, lt, 1], wi_grid[t, lt, 2]
        return
    zero, one = np.float32(0.0), np.float32(1.0)
    m0, m1, m2 = np.float32(nrm[0]), np.float32(nrm[1]), np.float32(nrm[2])
    cos_i, ft = scratch[0], scratch[1]
    for lt in range(n_led):
        c = wi_grid[t, lt, 0] * m0 + wi_grid[t, lt, 1] * m1 + wi_grid[t, lt, 2] * m2
        cos_i[lt] = min(max(c, zero), one)
    for lt in range(n_led):
        f = one - fresnel_reflectance(cos_i[lt], eta)
        ft[lt] = f if f > 0 else one
    for lt in range(n_led):
        f = ft[lt]
        w[lt, 0], w[lt, 1], w[lt, 2] = wi_grid[t, lt, 0] / f, wi_grid[t, lt, 1] / f, wi_grid[t, lt, 2] / f


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _compact_used(run_starts, run_counts, light_index, y_used, r_begin, r_end, base, used_light, used_y, bounds):
    """The used samples (y > 0) of runs ``r_begin:r_end`` of one lumitexel: per run its even-position samples,
    then its odd-position ones, as (light within the lumitexel, y as float64); ``bounds[3 i: 3 i + 3]`` =
    start of the even ones, start of the odd ones, end, of the i-th run."""
    m = 0
    for r in range(r_begin, r_end):
        s0, cnt = run_starts[r], run_counts[r]
        i = 3 * (r - r_begin)
        for parity in range(2):
            bounds[i + parity] = m
            for j in range(parity, cnt, 2):
                if y_used[s0 + j] > 0:
                    used_light[m] = light_index[s0 + j] - base
                    used_y[m] = np.float64(y_used[s0 + j])
                    m += 1
        bounds[i + 2] = m


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _weighted_sum(used_light, used_y, w, even, odd, end):
    """Σ y w of one run from its compacted samples (:func:`_compact_used`): the even-position ones
    ``even:odd`` and the odd-position ones ``odd:end`` summed apart in order (float64), side by side."""
    e0 = e1 = e2 = o0 = o1 = o2 = 0.0
    n_even, n_odd = odd - even, end - odd
    for k in range(min(n_even, n_odd)):  # two independent chains of additions
        le, ye, lo, yo = used_light[even + k], used_y[even + k], used_light[odd + k], used_y[odd + k]
        e0 += ye * np.float64(w[le, 0])
        e1 += ye * np.float64(w[le, 1])
        e2 += ye * np.float64(w[le, 2])
        o0 += yo * np.float64(w[lo, 0])
        o1 += yo * np.float64(w[lo, 1])
        o2 += yo * np.float64(w[lo, 2])
    for k in range(n_odd, n_even):
        le, ye = used_light[even + k], used_y[even + k]
        e0 += ye * np.float64(w[le, 0])
        e1 += ye * np.float64(w[le, 1])
        e2 += ye * np.float64(w[le, 2])
    for k in range(n_even, n_odd):
        lo, yo = used_light[odd + k], used_y[odd + k]
        o0 += yo * np.float64(w[lo, 0])
        o1 += yo * np.float64(w[lo, 1])
        o2 += yo * np.float64(w[lo, 2])
    return e0 + o0, e1 + o1, e2 + o2


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _camera_system(wi_grid, t, used_light, even, odd, end, min_lights, adj):
    """adj(A) of one camera run into ``adj`` (9, row-major) from its compacted used samples, and whether it
    votes: A = Σ ωi ωiᵀ and k summed over even and odd positions apart (float64), then the cofactors
    and det(A) in the order the numpy engine of :func:`facestats.model.fitting.photometric_normals` forms them."""
    e = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    o = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    n_even, n_odd = odd - even, end - odd
    for k in range(min(n_even, n_odd)):  # two independent chains of additions
        e = _add_outer(e, wi_grid, t, used_light[even + k])
        o = _add_outer(o, wi_grid, t, used_light[odd + k])
    for k in range(n_odd, n_even):
        e = _add_outer(e, wi_grid, t, used_light[even + k])
    for k in range(n_even, n_odd):
        o = _add_outer(o, wi_grid, t, used_light[odd + k])
    a00, a01, a02, a11, a12, a22 = e[0] + o[0], e[1] + o[1], e[2] + o[2], e[3] + o[3], e[4] + o[4], e[5] + o[5]
    count = e[6] + o[6]
    c00, c11, c22 = a11 * a22 - a12 * a12, a00 * a22 - a02 * a02, a00 * a11 - a01 * a01
    c01, c02, c12 = a02 * a12 - a01 * a22, a01 * a12 - a02 * a11, a01 * a02 - a00 * a12
    det = a00 * c00 + a01 * c01 + a02 * c02
    adj[0], adj[1], adj[2] = c00, c01, c02
    adj[3], adj[4], adj[5] = c01, c11, c12
    adj[6], adj[7], adj[8] = c02, c12, c22
    return (count >= min_lights) & (det > 1e-6 * math.pow(max(count, 1.0), 3.0))


@numba.njit(cache=True, nogil=True, inline="always")
def _add_outer(acc, wi_grid, t, light):
    """acc + (the six entries of ωi ωiᵀ, 1) of one used sample (float64)."""
    x, w, v = np.float64(wi_grid[t, light, 0]), np.float64(wi_grid[t, light, 1]), np.float64(wi_grid[t, light, 2])
    return (
        acc[0] + x * x,
        acc[1] + x * w,
        acc[2] + x * v,
        acc[3] + w * w,
        acc[4] + w * v,
        acc[5] + v * v,
        acc[6] + 1.0,
    )


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _camera_vote(adj, b, wo, out, acc):
    """One camera's normal N_c = adj(A) b / ‖adj(A) b‖ into ``out`` (left NaN if g = 0) and ``acc`` + (w_c N_c, w_c)
    with w_c = max(N_c·ωo, 0)."""
    g0 = adj[0] * b[0] + adj[1] * b[1] + adj[2] * b[2]
    g1 = adj[3] * b[0] + adj[4] * b[1] + adj[5] * b[2]
    g2 = adj[6] * b[0] + adj[7] * b[1] + adj[8] * b[2]
    norm = np.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    if not norm > 0:
        return acc
    g0, g1, g2 = g0 / norm, g1 / norm, g2 / norm
    out[0], out[1], out[2] = g0, g1, g2
    wt = g0 * np.float64(wo[0]) + g1 * np.float64(wo[1])
    wt = max(wt + g2 * np.float64(wo[2]), 0.0)
    return acc[0] + wt * g0, acc[1] + wt * g1, acc[2] + wt * g2, acc[3] + wt


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
