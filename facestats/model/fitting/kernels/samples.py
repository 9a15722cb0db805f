"""Compiled kernels of :mod:`facestats.model.fitting.samples`: the dome grid flattened, per-sample cosines.

* :func:`flatten_grid` — the valid samples of a (lumitexel, camera, light)
  grid in one pass: validity exactly as
  :func:`facestats.model.fitting.samples.valid_samples` (float16 radiance tested
  on its bit patterns, every E⊥ channel > 0), minus the cameras left out, then
  the flat arrays of :meth:`facestats.model.fitting.Samples.from_grid`.
* :func:`sample_cosines` — N·ωi, N·ωo and ωi·ωo per sample straight from the
  direction grids (three products and two sums each, in float32 and in the
  order of :func:`facestats.model.fitting.samples._dot3`, so the bits equal
  numpy's), without the (lumitexel, camera, light) grid numpy goes through;
* :func:`brdf_values` — the per-sample values of :func:`facestats.model.fitting.brdf_samples` (eq. 8)
  gathered from its grids in one pass, and :func:`half_cosines` the N·H of
  :meth:`facestats.model.fitting.Samples.cos_half`, both with numpy's bits;
* :func:`dense_samples` — the usable samples of dense per-texel arrays (the
  public :func:`facestats.model.fitting.fit_specular`), compacted into runs
  with their cosines, without copying the arrays.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = [
    "halves_to_singles",
    "flatten_grid",
    "sample_cosines",
    "brdf_values",
    "cos_half32",
    "half_cosines",
    "dense_samples",
]


@numba.njit(cache=True, nogil=True)
def _valid_bits(u0, u1, u2):
    """A float16 RGB triple (as uint16 patterns) is ≥ 0 and not NaN in every channel."""
    ok0 = (u0 <= 0x7C00) | (u0 == 0x8000)
    ok1 = (u1 <= 0x7C00) | (u1 == 0x8000)
    ok2 = (u2 <= 0x7C00) | (u2 == 0x8000)
    return ok0 & ok1 & ok2


_SUBNORMAL_HALF = np.float32(2.0**-24)  # the value of the last mantissa bit of a subnormal float16


@numba.njit(cache=True, nogil=True)
def halves_to_singles(bits):
    """float16 bit patterns held in the int32 array ``bits`` replaced in place by the float32 values' bits
    (exact, as numpy's cast; IEEE 754-2008 binary16); returns the float32 view.

    Normal halves: exponent and mantissa move into float32's places and the exponent bias grows by
    127 − 15 = 112 (integer arithmetic); ±inf and NaN (exponent all ones) get float32's all-ones exponent;
    subnormal halves and zeros are m · 2⁻²⁴ for their 10-bit mantissa m, computed in float32 (exact, and
    normal: no float32 subnormal is formed, so a CPU flushing subnormals to zero gives the same bits); the
    sign is copied.
    """
    flat = bits.reshape(-1)
    values = flat.view(np.float32)
    for i in range(flat.shape[0]):
        h = flat[i]
        em = h & np.int32(0x7FFF)
        if em < np.int32(0x0400):
            values[i] = np.float32(em) * _SUBNORMAL_HALF
        elif em >= np.int32(0x7C00):
            flat[i] = np.int32(0x7F800000) | ((em & np.int32(0x03FF)) << np.int32(13))
        else:
            flat[i] = (em << np.int32(13)) + np.int32(0x38000000)
        flat[i] = flat[i] | ((h & np.int32(0x8000)) << np.int32(16))
    return bits.view(np.float32)


@numba.njit(cache=True, nogil=True)
def _lit(irradiance):
    """(n, L): every channel of E⊥ is > 0."""
    n, n_led = irradiance.shape[0], irradiance.shape[1]
    lit = np.empty((n, n_led), np.bool_)
    for t in range(n):
        for l in range(n_led):
            lit[t, l] = (irradiance[t, l, 0] > 0) & (irradiance[t, l, 1] > 0) & (irradiance[t, l, 2] > 0)
    return lit


@numba.njit(cache=True, nogil=True)
def _run_lengths(valid, lit, keep_camera, n_cam):
    """Valid and lit samples of every (lumitexel, camera) of a kept camera, shape (n C,)."""
    n, n_led = lit.shape[0], lit.shape[1]
    per_camera = np.zeros(n * n_cam, np.int64)
    for t in range(n):
        for c in range(n_cam):
            if keep_camera[c]:
                base = (t * n_cam + c) * n_led
                k = 0
                for l in range(n_led):
                    k += valid[base + l] & lit[t, l]
                per_camera[t * n_cam + c] = k
    return per_camera


@numba.njit(cache=True, nogil=True)
def flatten_grid(rad_bits, irradiance, keep_camera):
    """The valid samples of a dome grid, sorted by lumitexel, camera, light.

    Parameters
    ----------
    rad_bits : ndarray of uint16, shape (n, C, L, 3)
        float16 radiance read as its bit patterns.
    irradiance : ndarray of float32, shape (n, L, 3)
        E⊥ per light and channel.
    keep_camera : ndarray of bool, shape (C,)
        Cameras whose samples may be used.

    Returns
    -------
    texel : ndarray of int32, shape (S,)
        The lumitexel t of every sample.
    camera_index : ndarray of intp, shape (S,)
        t C + c of every sample.
    light_index : ndarray of intp, shape (S,)
        t L + l of every sample.
    grid_index : ndarray of intp, shape (S,)
        (t C + c) L + l of every sample.
    rad : float32 (3, S)
        Radiance, channel-major (converted from float16 exactly).
    irr : float32 (3, S)
        E⊥ per sample, channel-major.
    per_camera : int64 (n C,)
        Valid samples of every (lumitexel, camera).
    """
    n, n_cam, n_led = rad_bits.shape[0], rad_bits.shape[1], rad_bits.shape[2]
    lit = _lit(irradiance)
    flat = rad_bits.reshape(n * n_cam * n_led, 3)
    valid = np.empty(n * n_cam * n_led, np.bool_)
    for g in range(n * n_cam * n_led):  # the validity of every grid entry: no reductions, vectorised
        valid[g] = _valid_bits(flat[g, 0], flat[g, 1], flat[g, 2])
    per_camera = _run_lengths(valid, lit, keep_camera, n_cam)
    total = per_camera.sum()
    texel = np.empty(total, np.int32)
    camera_index = np.empty(total, np.intp)
    light_index = np.empty(total, np.intp)
    grid_index = np.empty(total, np.intp)
    rad = np.empty((3, total), np.int32)  # float16 bits, then float32 values (halves_to_singles)
    irr = np.empty((3, total), np.float32)
    s = 0
    for t in range(n):
        for c in range(n_cam):
            if per_camera[t * n_cam + c] == 0:
                continue
            base = (t * n_cam + c) * n_led
            for l in range(n_led):
                if valid[base + l] & lit[t, l]:
                    texel[s] = t
                    camera_index[s] = t * n_cam + c
                    light_index[s] = t * n_led + l
                    grid_index[s] = base + l
                    rad[0, s] = flat[base + l, 0]
                    rad[1, s] = flat[base + l, 1]
                    rad[2, s] = flat[base + l, 2]
                    irr[0, s] = irradiance[t, l, 0]
                    irr[1, s] = irradiance[t, l, 1]
                    irr[2, s] = irradiance[t, l, 2]
                    s += 1
    return texel, camera_index, light_index, grid_index, halves_to_singles(rad), irr, per_camera


@numba.njit(cache=True, nogil=True)
def sample_cosines(texel, light_index, camera_index, wi_flat, wo_flat, normal, with_normal):
    """(N·ωi, N·ωo, ωi·ωo) per sample, float32; the first two only if ``with_normal``.

    ``wi_flat``/``wo_flat`` are the (n L, 3)/(n C, 3) direction grids, ``normal``
    (n, 3) float32.
    """
    n_s = texel.shape[0]
    io = np.empty(n_s, np.float32)
    ci = np.empty(n_s if with_normal else 0, np.float32)
    co = np.empty(n_s if with_normal else 0, np.float32)
    for s in range(n_s):
        li = light_index[s]
        cj = camera_index[s]
        ix, iy, iz = wi_flat[li, 0], wi_flat[li, 1], wi_flat[li, 2]
        ox, oy, oz = wo_flat[cj, 0], wo_flat[cj, 1], wo_flat[cj, 2]
        io[s] = ox * ix + oy * iy + oz * iz
        if with_normal:
            t = texel[s]
            nx, ny, nz = normal[t, 0], normal[t, 1], normal[t, 2]
            ci[s] = ix * nx + iy * ny + iz * nz
            co[s] = ox * nx + oy * ny + oz * nz
    return ci, co, io


@numba.njit(cache=True, nogil=True, error_model="numpy")
def brdf_values(light_index, camera_index, cos_i_grid, cos_o_grid, ft_i_grid, ft_o_grid, radiance, irradiance, limit):
    """Per sample: cos θi, cos θo, F_t(θi) F_t(θo), θi and θo within the limit, f_r = L/(E⊥ max(cos θi, 0)).

    The per-sample values of :func:`facestats.model.fitting.brdf_samples` (eq. 8) in one pass, from its
    (lumitexel, light) and (lumitexel, camera) grids flattened (``cos_i_grid``, ``ft_i_grid`` (n L,);
    ``cos_o_grid``, ``ft_o_grid`` (n C,)), all float32 as numpy computes them (max(±0, 0) is +0 and
    max(NaN, 0) NaN, as ``numpy.maximum`` gives them), so the bits equal numpy's.

    Returns
    -------
    cos_i, cos_o, ft2 : float32 (S,)
    use : bool (S,)
        cos θi > ``limit`` and cos θo > ``limit``.
    f_r : float32 (3, S)
    """
    n_s = light_index.shape[0]
    ci = np.empty(n_s, np.float32)
    co = np.empty(n_s, np.float32)
    ft2 = np.empty(n_s, np.float32)
    use = np.empty(n_s, np.bool_)
    f_r = np.empty((3, n_s), np.float32)
    zero = np.float32(0.0)
    for s in range(n_s):
        li, cj = light_index[s], camera_index[s]
        c_i, c_o = cos_i_grid[li], cos_o_grid[cj]
        ci[s], co[s] = c_i, c_o
        ft2[s] = ft_i_grid[li] * ft_o_grid[cj]
        use[s] = (c_i > limit) & (c_o > limit)
        pos = c_i if (c_i > zero) | (c_i != c_i) else zero  # numpy.maximum(c, 0): NaN kept, ±0 -> +0
        f_r[0, s] = radiance[0, s] / (irradiance[0, s] * pos)
        f_r[1, s] = radiance[1, s] / (irradiance[1, s] * pos)
        f_r[2, s] = radiance[2, s] / (irradiance[2, s] * pos)
    return ci, co, ft2, use, f_r


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def cos_half32(cos_i, cos_o, cos_io):
    """N·H = (cos θi + cos θo)/√max(2 + 2 ωi·ωo, 10⁻¹²) of one sample in float32, as
    :meth:`facestats.model.fitting.Samples.cos_half` computes it in numpy (H the half vector)."""
    two = np.float32(2.0)
    return (cos_i + cos_o) / np.sqrt(max(two + two * cos_io, np.float32(1e-12)))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def half_cosines(cos_i, cos_o, cos_io):
    """:func:`cos_half32` of every sample (float32 arrays of one shape)."""
    out = np.empty(cos_i.shape[0], np.float32)
    for s in range(cos_i.shape[0]):
        out[s] = cos_half32(cos_i[s], cos_o[s], cos_io[s])
    return out


@numba.njit(cache=True, nogil=True)
def dense_samples(wi, wo, normal, f_s, valid, cos_limit):
    """Usable samples of dense arrays: ``valid``, finite f_s, θi and θo within the angle limit.

    ``wi``, ``wo`` (T, S, 3) and ``normal`` (T, 3) of any float dtype, ``f_s`` (T, S),
    ``valid`` (T, S) bool; the limit is tested in float64 (N·ω > ``cos_limit``), as the
    numpy path does.

    Returns
    -------
    counts : int64 (T,)
    ci, co, io, fs : float32 (S',)
        N·ωi, N·ωo, ωi·ωo and f_s of the kept samples, in per-texel runs.
    """
    n_t, n_s = f_s.shape[0], f_s.shape[1]
    size = n_t * n_s
    ci = np.empty(size, np.float32)
    co = np.empty(size, np.float32)
    io = np.empty(size, np.float32)
    fs = np.empty(size, np.float32)
    counts = np.zeros(n_t, np.int64)
    m = 0
    for t in range(n_t):
        nx, ny, nz = np.float64(normal[t, 0]), np.float64(normal[t, 1]), np.float64(normal[t, 2])
        m0 = m
        for s in range(n_s):
            ix, iy, iz = np.float64(wi[t, s, 0]), np.float64(wi[t, s, 1]), np.float64(wi[t, s, 2])
            ox, oy, oz = np.float64(wo[t, s, 0]), np.float64(wo[t, s, 1]), np.float64(wo[t, s, 2])
            c_i = nx * ix + ny * iy + nz * iz
            c_o = nx * ox + ny * oy + nz * oz
            f = f_s[t, s]
            ci[m] = c_i
            co[m] = c_o
            io[m] = ix * ox + iy * oy + iz * oz
            fs[m] = f
            m += valid[t, s] & np.isfinite(f) & (c_i > cos_limit) & (c_o > cos_limit)
        counts[t] = m - m0
    return counts, ci[:m], co[:m], io[:m], fs[:m]
