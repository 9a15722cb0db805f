"""Compiled (numba) inner loops of the microstructure subsystem, with their pure-numpy twins.

Two kernels, each available compiled (``backend="numba"``, parallel over rows
or candidates, cached on disk by numba) and in vectorised numpy
(``backend="numpy"``, the reference the compiled one is tested against):

* :func:`convolve_pass` — one spatially varying 1-D pass of Nagano et al. 2015
  eq. 3 / 5: at every texel, taps at integer steps along the texel's axis,
  bilinear samples, Gaussian weights of the texel's σ, mixed with the centre as
  in eq. 6.  Taps walk outwards from the centre on each side and stop at the
  first tap whose bilinear footprint (corners of non-zero weight) leaves the
  map or the texel's UV island; the Gaussian part is renormalised over the taps
  used.  Texels of island 0 (gutter) are copied.
* :func:`histogram_tv` — total variation (eq. 7) between a target normal
  histogram and the histograms of ``g0 + α Δg`` for many α at once (the
  brute-force fit of §5 "Parameter Fitting").

Both accumulate in float64; their results agree with the numpy twins to
rounding (≤ 1e-6 relative in float32 maps, identical histograms).
"""

from __future__ import annotations

import math

import numpy as np

from facestats.core.compiled import numba_available

__all__ = ["HAVE_NUMBA", "convolve_pass", "histogram_tv", "padded_empty"]

#: numba's kernels are defined below only where numba imports (:mod:`facestats.core.compiled`).
HAVE_NUMBA = numba_available()
if HAVE_NUMBA:
    import numba


# -- one convolution pass ------------------------------------------------------------------------
# Tap positions: the offset i·(a_u, a_v) of tap i is formed in float32 and shifted by B = R + 2 texels
# (so that truncation is the floor): column = c + int(B + i a_u) − B, fraction = (B + i a_u) − int(B + i a_u).
# Positions are exact for axis-aligned axes and within 2e-4 texel otherwise, whatever the map size.
# Gaussian weights g_i = exp(−i²/(2σ²)) by the recursion g_i = g_(i−1) q^(2i−1), q = exp(−1/(2σ²)).


def _numpy_tap(src, island, label, rows, cols, off_u, off_v, bias):
    """Bilinear samples at (rows, cols) + offsets, and whether every corner of non-zero weight is usable."""
    h, w = src.shape
    xp, yp = bias + off_u, bias + off_v  # float32
    x0, y0 = xp.astype(np.int64), yp.astype(np.int64)
    fx, fy = xp - x0.astype(np.float32), yp - y0.astype(np.float32)
    col, row = cols + x0 - bias.astype(np.int64), rows + y0 - bias.astype(np.int64)
    always = np.ones(len(rows), bool)
    ok = always.copy()
    corners = []
    for dy, need_y in ((0, always), (1, fy > 0)):  # the four corners
        for dx, need_x in ((0, always), (1, fx > 0)):
            need = need_y & need_x
            rr, cc = row + dy, col + dx
            inside = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
            rr, cc = np.clip(rr, 0, h - 1), np.clip(cc, 0, w - 1)
            if island is not None:
                inside &= island[rr, cc] == label
            ok &= inside | ~need
            corners.append((src[rr, cc], need))
    (s00, _), (s01, n01), (s10, n10), (s11, n11) = corners
    s01 = np.where(n01, s01, s00)
    s10 = np.where(n10, s10, s00)
    s11 = np.where(n11, s11, np.where(n10, s10, s01))
    top, bottom = s00 + fx * (s01 - s00), s10 + fx * (s11 - s10)
    return top + fy * (bottom - top), ok


def _convolve_pass_numpy(src, out, au, av, alpha, sigma_um, texel_um, island, truncate):
    """The numpy twin of the compiled pass: Nagano et al. 2015 eq. 3 / 5 with the kernel of eq. 6.

    At each texel, out = (1 − α) src + α Σ_i g_i src(x + i·a) / Σ_i g_i over the taps i = −R..R
    along the texel's unit axis a (texels), g_i = exp(−i²/(2 s²)), s = σ/texel (σ and the texel
    size in µm, so s in texels), R = ceil(``truncate`` · s); each side stops at its first tap whose
    bilinear footprint leaves the map or the island, and the Gaussian is normalised over the taps
    used (eq. 6's G is a normalised discrete Gaussian; near an edge, over what stays inside).
    g_i is built by the recursion g_i = g_{i−1} q^(2i−1), q = exp(−1/(2 s²)), the same products in
    the same order as the compiled kernel.  Loops over tap offsets, vectorised over texels;
    arguments as :func:`convolve_pass`.
    """
    h, w = src.shape
    rows, cols = (i.reshape(-1) for i in np.indices((h, w)))
    a = alpha.reshape(-1).astype(np.float64)
    sp = (sigma_um.reshape(-1).astype(np.float32) / texel_um.reshape(-1).astype(np.float32)).astype(np.float64)
    label = None if island is None else island.reshape(-1)
    centre = src.reshape(-1)
    active = (a != 0) & (sp > 0) & (True if label is None else label != 0)
    radius = np.where(active, np.ceil(truncate * sp), 0).astype(np.int64)
    acc, wsum = centre.astype(np.float64), np.ones(h * w)
    du, dv = au.reshape(-1).astype(np.float32), av.reshape(-1).astype(np.float32)
    bias = (radius + 2).astype(np.float32)
    with np.errstate(divide="ignore", under="ignore"):
        q = np.where(active, np.exp(-0.5 / np.where(active, sp, 1.0) ** 2), 0.0)
    alive = np.stack([active, active])  # the two sides of the kernel
    g, ratio, q2 = np.ones(h * w), q.copy(), q * q
    for i in range(1, int(radius.max(initial=0)) + 1):  # loop over tap offsets, vectorised over texels
        g, ratio = g * ratio, ratio * q2
        fi = np.float32(i)
        for side, sign in enumerate((1, -1)):
            idx = np.nonzero(alive[side] & (radius >= i))[0]
            off_u, off_v = fi * du[idx], fi * dv[idx]
            if sign < 0:
                off_u, off_v = -off_u, -off_v
            val, ok = _numpy_tap(
                src, island, None if label is None else label[idx], rows[idx], cols[idx], off_u, off_v, bias[idx]
            )
            acc[idx[ok]] += g[idx[ok]] * val[ok]
            wsum[idx[ok]] += g[idx[ok]]
            alive[side, idx[~ok]] = False
    res = np.where(active, (1.0 - a) * centre + a * (acc / wsum), centre)
    out[...] = res.reshape(h, w)
    return out


if HAVE_NUMBA:
    _FAST = {"nsz", "arcp", "contract", "reassoc"}  # no assumptions about NaN/inf (inputs are checked finite)

    @numba.njit(cache=True, inline="always", fastmath=_FAST)
    def _checked_tap(src, island, label, use_islands, r, c, off_u, off_v, bias, ibias):
        """Bilinear sample at (r, c) + offset and whether every corner of non-zero weight is usable."""
        h, w = src.shape
        xp = bias + off_u
        yp = bias + off_v
        x0 = np.int32(xp)
        y0 = np.int32(yp)
        fx = xp - np.float32(x0)
        fy = yp - np.float32(y0)
        col = c + x0 - ibias
        row = r + y0 - ibias
        nx = 2 if fx > 0 else 1
        ny = 2 if fy > 0 else 1
        if row < 0 or col < 0 or row + ny > h or col + nx > w:
            return False, 0.0
        if use_islands:
            for dy in range(ny):
                for dx in range(nx):
                    if island[row + dy, col + dx] != label:
                        return False, 0.0
        s00 = src[row, col]
        s01 = src[row, col + 1] if nx == 2 else s00
        s10 = src[row + 1, col] if ny == 2 else s00
        s11 = src[row + 1, col + 1] if nx == 2 and ny == 2 else (s10 if ny == 2 else s01)
        top = s00 + fx * (s01 - s00)
        bottom = s10 + fx * (s11 - s10)
        return True, top + fy * (bottom - top)

    # The interior ("fast") path, where every tap's bilinear footprint is known to lie in the map and
    # the texel's island, is split in two loops.  Profiled on the 4096² benchmark (one thread, one pass):
    # the former single loop was bound by floating-point issue (about 45 scalar FP operations per pair
    # of taps: float→int→float round trips for both coordinates of both sides), not by memory.
    #
    # 1. _tap_positions: the flat offset and the bilinear fractions of every tap.  Nothing in it
    #    depends on the map, so LLVM vectorises it (8 lanes); the arithmetic is the same float32
    #    expression as before and in the numpy twin (bias ± i·a in float32, truncation = floor as the
    #    position is positive), so the positions are bit-identical.
    # 2. _interior_sum: the taps themselves, scalar loads.  The Gaussian weight is advanced in the
    #    loop by the recursion above (the same multiplications in the same order as the former weight
    #    table, hence the same values); the recursion is also what keeps LLVM from turning the loads
    #    into AVX-512 gathers, which are slower than scalar loads on this (Zen 4) machine.  Offsets
    #    are used as unsigned integers: they are ≥ 0 by the fast-path test, and numba then skips its
    #    negative-index wrap-around (a compare and a select per load).
    # The accumulation (float64, tap pairs in order of i) is unchanged.

    @numba.njit(cache=True, inline="always", fastmath=_FAST)
    def _tap_positions(rad, base, w, du, dv, bias, off, fxs, fys):
        """Flat offset of the top-left corner and the fractions of taps +i (slot 2i − 2) and −i (slot 2i − 1)."""
        for k in range(2 * rad):
            fi = np.float32((k >> 1) + 1)
            ou = fi * du
            ov = fi * dv
            if k & 1:
                ou = -ou
                ov = -ov
            xp = bias + ou
            yp = bias + ov
            x0 = np.int32(xp)
            y0 = np.int32(yp)
            fxs[k] = xp - np.float32(x0)
            fys[k] = yp - np.float32(y0)
            off[k] = base + y0 * w + x0

    @numba.njit(cache=True, inline="always", fastmath=_FAST)
    def _bilinear(flat, o, w, fx, fy):
        """Bilinear sample with top-left corner at flat offset ``o`` (≥ 0, all four corners in the map)."""
        i = numba.uint64(o)
        s00 = flat[i]
        s01 = flat[i + numba.uint64(1)]
        s10 = flat[i + numba.uint64(w)]
        s11 = flat[i + numba.uint64(w + 1)]
        top = s00 + fx * (s01 - s00)
        bottom = s10 + fx * (s11 - s10)
        return top + fy * (bottom - top)

    @numba.njit(cache=True, inline="always", fastmath=_FAST)
    def _interior_sum(flat, w, rad, q, centre, off, fxs, fys):
        """Σ over taps −R … R of g_i · sample and Σ g_i (g_0 = 1), taps from :func:`_tap_positions`."""
        q2 = q * q
        ratio = q
        g = 1.0
        acc = np.float64(centre)
        wsum = 1.0
        for i in range(rad):
            g *= ratio
            ratio *= q2
            vp = _bilinear(flat, off[2 * i], w, fxs[2 * i], fys[2 * i])
            vn = _bilinear(flat, off[2 * i + 1], w, fxs[2 * i + 1], fys[2 * i + 1])
            acc += g * (vp + vn)
            wsum += 2.0 * g
        return acc, wsum

    @numba.njit(cache=True, inline="always", fastmath=_FAST)
    def _checked_sum(src, r, c, rad, q, du, dv, label, island, use_islands):
        """As :func:`_interior_sum` near borders and islands: each side stops at its first unusable tap."""
        q2 = q * q
        ratio = q
        g = 1.0
        acc = np.float64(src[r, c])
        wsum = 1.0
        ibias = rad + 2
        bias = np.float32(ibias)
        alive_p = True
        alive_n = True
        for i in range(1, rad + 1):
            g *= ratio
            ratio *= q2
            fi = np.float32(i)
            ou = fi * du
            ov = fi * dv
            if alive_p:
                alive_p, val = _checked_tap(src, island, label, use_islands, r, c, ou, ov, bias, ibias)
                if alive_p:
                    acc += g * val
                    wsum += g
            if alive_n:
                alive_n, val = _checked_tap(src, island, label, use_islands, r, c, -ou, -ov, bias, ibias)
                if alive_n:
                    acc += g * val
                    wsum += g
            if not (alive_p or alive_n):
                break
        return acc, wsum

    # Explicit signatures: C-contiguous maps, read-only any-layout ("A") parameters, so one compiled
    # version per map dtype serves any mix of arrays and (read-only) broadcast views.  Each dtype's
    # version is compiled on first use (and cached on disk by numba).
    def _ro(dtype):
        return numba.types.Array(dtype, 2, "A", readonly=True)

    def _pass_signature(t):
        return numba.void(
            numba.types.Array(t, 2, "A", readonly=True),
            numba.types.Array(t, 1, "C", readonly=True),
            numba.int64,
            numba.types.Array(t, 2, "A"),
            *[_ro(numba.float32)] * 5,
            _ro(numba.int32),
            _ro(numba.float32),
            numba.boolean,
            numba.float64,
            numba.int64,
        )

    #: Columns per strip: the rows a strip's taps touch stay in the L2 cache.
    STRIP = 256

    def _convolve_pass_py(
        src, flat, rs, out, au, av, alpha, sigma_um, texel_um, island, reach, use_islands, truncate, rmax
    ):
        h, w = src.shape
        for c0 in range(0, w, STRIP):  # column strips (serial), rows in parallel
            c1 = min(w, c0 + STRIP)
            for r in numba.prange(h):
                off = np.empty(2 * rmax, np.int64)  # per-row scratch of _tap_positions
                fxs = np.empty(2 * rmax, np.float32)
                fys = np.empty(2 * rmax, np.float32)
                for c in range(c0, c1):
                    a = alpha[r, c]
                    label = island[r, c] if use_islands else 1
                    sp = np.float64(sigma_um[r, c] / texel_um[r, c])
                    centre = src[r, c]
                    if a == 0.0 or label == 0 or not sp > 0.0:
                        out[r, c] = centre
                        continue
                    rad = int(math.ceil(truncate * sp))
                    q = math.exp(-0.5 / (sp * sp))
                    fast = c - rad - 1 >= 0 and c + rad + 1 < w and r - rad - 1 >= 0 and r + rad + 1 < h
                    if use_islands and reach[r, c] <= rad + 3:
                        fast = False
                    if fast:
                        ibias = rad + 2
                        base = (r - ibias) * rs + (c - ibias)
                        _tap_positions(rad, base, rs, au[r, c], av[r, c], np.float32(ibias), off, fxs, fys)
                        acc, wsum = _interior_sum(flat, rs, rad, q, centre, off, fxs, fys)
                    else:
                        acc, wsum = _checked_sum(src, r, c, rad, q, au[r, c], av[r, c], label, island, use_islands)
                    out[r, c] = (1.0 - a) * centre + a * (acc / wsum)

    _PASS_KERNELS = {}

    def _pass_kernel(dtype):
        """The compiled pass for maps of ``dtype`` (compiled on first use)."""
        key = np.dtype(dtype).name
        if key not in _PASS_KERNELS:
            sig = _pass_signature(numba.from_dtype(np.dtype(dtype)))
            _PASS_KERNELS[key] = numba.njit(sig, cache=True, parallel=True, fastmath=_FAST)(_convolve_pass_py)
        return _PASS_KERNELS[key]


#: Row padding where a map's row stride is a multiple of 1 KiB.  The interior pass reads a window of up
#: to 2R + 2 rows; with such strides (e.g. 4096 float32 texels, 16 KiB) the same column of every row maps
#: to the same few sets of the L1 and L2 caches, and the window keeps evicting itself.  256 bytes more per
#: row spread the rows over the sets: the 4096² benchmark frame takes about 13 % less time (same bits).
ROW_PAD_BYTES = 256


def padded_empty(shape, dtype) -> np.ndarray:
    """An uninitialised (H, W) map whose rows do not alias in the CPU caches (a view of a wider buffer).

    The pass reads such a map without a copy (see :data:`ROW_PAD_BYTES`); other maps are copied once.
    """
    h, w = shape
    item = np.dtype(dtype).itemsize
    pad = ROW_PAD_BYTES // item if (w * item) % 1024 == 0 else 0
    return np.empty((h, w + pad), dtype)[:, :w]


def _rows(src):
    """``src`` laid out for the compiled pass: unit column stride and a row stride that does not alias.

    Returns the (possibly copied) map, a read-only flat view of its rows from the first texel, and the row
    stride in elements (texel (r, c) is ``flat[r * rs + c]``).
    """
    item = src.itemsize
    h, w = src.shape
    rs_bytes = src.strides[0]
    if src.strides[1] != item or rs_bytes < w * item or rs_bytes % item or rs_bytes % 1024 == 0:
        buf = padded_empty(src.shape, src.dtype)
        buf[...] = src
        src = buf
    rs = src.strides[0] // item
    flat = np.lib.stride_tricks.as_strided(src, shape=((h - 1) * rs + w,), strides=(item,), writeable=False)
    return src, flat, rs


def convolve_pass(src, out, au, av, alpha, sigma_um, texel_um, island, reach, *, truncate, backend):
    """One spatially varying 1-D pass (eq. 3 / 5 with the kernel of eq. 6), written into ``out``.

    Parameters
    ----------
    src, out : ndarray (H, W), float32 or float64
        Input map and output buffer (not the same array); either may be a view with padded rows
        (:func:`padded_empty`); ``src`` is copied to padded rows where its row stride would alias.
    au, av : ndarray (H, W), float32
        Unit axis per texel in texel units (column, row components).
    alpha, sigma_um, texel_um : ndarray (H, W), float32
        Filter strength, Gaussian σ (µm) and texel size along the axis (µm); may be broadcast views.
    island : ndarray (H, W) of int32 or None
        UV island labels (0 = gutter, copied); None: the whole map is one island.
    reach : ndarray (H, W) of float32 or None
        Distance (texels) to the nearest texel next to another island (fast-path test of the compiled kernel).
    truncate : float
        Gaussian truncation in standard deviations.
    backend : {"numba", "numpy"}

    Returns
    -------
    ndarray
        ``out``, written.
    """
    if backend == "numpy":
        return _convolve_pass_numpy(src, out, au, av, alpha, sigma_um, texel_um, island, truncate)
    use = island is not None
    if not use:
        island = np.zeros((1, 1), np.int32)
        reach = np.zeros((1, 1), np.float32)
    src, flat, rs = _rows(src)
    rmax = int(np.ceil(truncate * float(np.max(sigma_um)) / float(np.min(texel_um)))) + 1  # bounds every radius
    kernel = _pass_kernel(src.dtype)
    kernel(src, flat, rs, out, au, av, alpha, sigma_um, texel_um, island, reach, use, float(truncate), rmax)
    return out


# -- histogram total variation for many alphas ---------------------------------------------------
def _bins_numpy(gx, gy, lo, scale, nb):
    """Flat 2-D bin of each slope sample's tangent-space normal (n_u, n_v), clipped to the grid.

    The normal of a height field of slopes (g_x, g_y) is (−g_x, −g_y, 1)/√(1 + g_x² + g_y²); its
    (n_u, n_v) components are binned as in :func:`histogram_tv` (the histograms of eq. 7).
    """
    inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
    bu = np.clip(np.floor((-gx * inv - lo) * scale), 0, nb - 1).astype(np.int64)
    bv = np.clip(np.floor((-gy * inv - lo) * scale), 0, nb - 1).astype(np.int64)
    return bv * nb + bu


def _histogram_tv_numpy(g0x, g0y, dgx, dgy, alphas, target, lo, scale, nb):
    """The numpy twin of the compiled :func:`histogram_tv`: Nagano et al. 2015 eq. 7 per candidate α."""
    n = g0x.size
    tv = np.empty(len(alphas))
    for k, a in enumerate(alphas):  # loop over candidates, vectorised over texels
        h = np.bincount(_bins_numpy(g0x + a * dgx, g0y + a * dgy, lo, scale, nb), minlength=nb * nb) / n
        tv[k] = np.abs(h - target).sum()
    return tv


if HAVE_NUMBA:

    def _histogram_tv_py(g0x, g0y, dgx, dgy, alphas, target, lo, scale, nb):
        n = g0x.size
        tv = np.empty(alphas.size)
        for k in numba.prange(alphas.size):
            a = alphas[k]
            hist = np.zeros(nb * nb, np.int32)
            for j in range(n):
                gx = g0x[j] + a * dgx[j]
                gy = g0y[j] + a * dgy[j]
                inv = 1.0 / math.sqrt(1.0 + gx * gx + gy * gy)
                # truncation then clipping equals floor then clipping (values below 0 clip to bin 0)
                bu = min(max(int((-gx * inv - lo) * scale), 0), nb - 1)
                bv = min(max(int((-gy * inv - lo) * scale), 0), nb - 1)
                hist[bv * nb + bu] += 1
            s = 0.0
            for b in range(nb * nb):
                s += abs(hist[b] / n - target[b])
            tv[k] = s
        return tv

    _TV_KERNEL = []

    def _tv_kernel():
        """The compiled histogram kernel (compiled on first use, cached on disk by numba)."""
        if not _TV_KERNEL:
            sig = "float64[:](" + ", ".join(["float64[:]"] * 6) + ", float64, float64, int64)"
            _TV_KERNEL.append(numba.njit(sig, cache=True, parallel=True)(_histogram_tv_py))
        return _TV_KERNEL[0]


def histogram_tv(g0x, g0y, dgx, dgy, alphas, target, lo, scale, nb, *, backend):
    """Total variation Σ_b |H_b(α) − target_b| (eq. 7) for the slopes ``g0 + α Δg``, every α at once.

    Parameters
    ----------
    g0x, g0y, dgx, dgy : ndarray (N,), float64
        Slopes (dimensionless) of the neutral map and the change a unit α adds.
    alphas : ndarray (K,)
    target : ndarray (nb * nb,)
        Target histogram (fractions, sums to 1), flat ``[v_bin, u_bin]``.
    lo, scale : float
        Bin of a normal component n: ``floor((n − lo) · scale)``, clipped to ``[0, nb − 1]``.
    nb : int
        Bins per axis.
    backend : {"numba", "numpy"}

    Returns
    -------
    ndarray
        The total variation for each α.
    """
    args = (g0x, g0y, dgx, dgy, np.asarray(alphas, np.float64), target, float(lo), float(scale), int(nb))
    if backend == "numpy":
        return _histogram_tv_numpy(*args)
    return _tv_kernel()(*args)
