"""Compiled (numba) inner loops of the microstructure subsystem, with their pure-numpy twins.

Two kernels, each available compiled (``backend="numba"``, parallel over rows
or candidates, cached on disk by numba) and in vectorised numpy
(``backend="numpy"``, the reference the compiled one is tested against):

* :func:`convolve_pass` — one spatially varying 1-D pass of Nagano et al. 2015
  eq. 3 / 5: at every texel, taps along the texel's axis at whole texels of its
  major direction, read across it by Lanczos-3 (:mod:`~facestats.model.microstructure.taps`),
  Gaussian weights of the texel's σ, mixed with the centre as in eq. 6.  Taps
  walk outwards from the centre on each side and stop at the first tap that
  reads a texel (of non-zero weight) outside the map or the texel's UV island;
  the Gaussian part is renormalised over the taps used.  Texels of island 0
  (gutter) are copied.
* :func:`histogram_tv` — total variation (eq. 7) between a target normal
  histogram and the histograms of ``g0 + α Δg`` for many α at once (the
  brute-force fit of §5 "Parameter Fitting").

Both accumulate in float64; their results agree with the numpy twins to
rounding (≤ 1e-6 relative in float32 maps, identical histograms).
"""

from __future__ import annotations

import math

import numpy as np

from facestats.core.compiled import numba_available, threads_at_most
from facestats.model.microstructure.taps import (
    FOOTPRINT,
    LANCZOS,
    LANCZOS_LOBES,
    LANCZOS_STEPS,
    gaussian_spacing,
    major_axis,
    tap_across,
)

__all__ = ["HAVE_NUMBA", "convolve_pass", "histogram_tv", "padded_empty"]

#: numba's kernels are defined below only where numba imports (:mod:`facestats.core.compiled`).
HAVE_NUMBA = numba_available()
if HAVE_NUMBA:
    import numba
    from llvmlite import ir
    from numba.extending import intrinsic


# -- one convolution pass ------------------------------------------------------------------------
# Tap i of a texel lies i texels along its axis's major direction and i·slope across it, read by the
# Lanczos-3 weights of its rounded fraction from the six texels y0 − 2 … y0 + 3 across
# (:mod:`~facestats.model.microstructure.taps`).  Gaussian weights g_i = exp(−i²/(2 s²)), s = σ_px · |a_major|
# the σ in taps, by the recursion g_i = g_(i−1) q^(2i−1), q = exp(−1/(2 s²)).


def _numpy_tap(src, island, label, rows, cols, u_major, i, slope, bias):
    """Samples of the taps ``i`` (signed) of texels (rows, cols) and whether each is usable: Lanczos-3 where all six
    texels of non-zero weight are in the map and the island, else linear between the two nearest texels where
    those are (next to a border), else unusable."""
    h, w = src.shape

    def read(across, wk):
        """Texels ``across`` of the taps: values (0 where unusable) and whether each is usable or of weight 0."""
        rr = np.where(u_major, rows + across, rows + i)
        cc = np.where(u_major, cols + i, cols + across)
        inside = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        rr, cc = np.clip(rr, 0, h - 1), np.clip(cc, 0, w - 1)
        if island is not None:
            inside &= island[rr, cc] == label
        return src[rr, cc].astype(np.float64), inside | (wk == 0)

    y0, t = tap_across(slope, i, bias)
    full = np.ones(len(rows), bool)
    val = np.zeros(len(rows))
    for k in range(FOOTPRINT):  # the six texels across, in the order the compiled kernel sums them
        wk = LANCZOS[t, k]
        v, ok = read(y0 + (k + 1 - LANCZOS_LOBES), wk)
        full &= ok
        val = val + wk * v
    frac = t / LANCZOS_STEPS
    v0, ok0 = read(y0, np.ones(len(rows)))
    v1, ok1 = read(y0 + 1, frac)
    near = ok0 & ok1 & ~full  # next to a border: linear between the two nearest texels
    val = np.where(near, np.where(t > 0, v0 + frac * (v1 - v0), v0), val)
    return val, full | near


def _convolve_pass_numpy(src, out, au, av, alpha, sigma_um, texel_um, island, truncate):
    """The numpy twin of the compiled pass: Nagano et al. 2015 eq. 3 / 5 with the kernel of eq. 6.

    At each texel, out = (1 − α) src + α Σ_i g_i src(tap i) / Σ_i g_i over the taps i = −n..n of
    :mod:`~facestats.model.microstructure.taps` (whole texels along the axis's major direction,
    Lanczos-3 across it), g_i = exp(−i²/(2 s²)) with s = σ_px · |a_major| (σ_px = σ/texel, σ and the
    texel size in µm), n = ceil(``truncate`` · s); each side stops at its first tap that reads a
    texel outside the map or the island, and the Gaussian is normalised over the taps used (eq. 6's
    G is a normalised discrete Gaussian; near an edge, over what stays inside).  g_i is built by the
    recursion g_i = g_{i−1} q^(2i−1), q = exp(−1/(2 s²)), the same products in the same order as the
    compiled kernel.  Loops over tap offsets, vectorised over texels; arguments as :func:`convolve_pass`.
    """
    h, w = src.shape
    rows, cols = (i.reshape(-1) for i in np.indices((h, w)))
    a = alpha.reshape(-1).astype(np.float64)
    u_major, slope, major = major_axis(au.reshape(-1), av.reshape(-1))
    sp = (sigma_um.reshape(-1).astype(np.float32) / texel_um.reshape(-1).astype(np.float32)).astype(np.float64)
    sp = gaussian_spacing(sp, major)
    label = None if island is None else island.reshape(-1)
    centre = src.reshape(-1)
    active = (a != 0) & (sp > 0) & (True if label is None else label != 0)
    radius = np.where(active, np.ceil(truncate * sp), 0).astype(np.int64)
    acc, wsum = centre.astype(np.float64), np.ones(h * w)
    bias = (radius + LANCZOS_LOBES).astype(np.float64)
    with np.errstate(divide="ignore", under="ignore"):
        q = np.where(active, np.exp(-0.5 / np.where(active, sp, 1.0) ** 2), 0.0)
    alive = np.stack([active, active])  # the two sides of the kernel
    g, ratio, q2 = np.ones(h * w), q.copy(), q * q
    for i in range(1, int(radius.max(initial=0)) + 1):  # loop over tap offsets, vectorised over texels
        g, ratio = g * ratio, ratio * q2
        for side, sign in enumerate((1, -1)):
            idx = np.nonzero(alive[side] & (radius >= i))[0]
            val, ok = _numpy_tap(
                src, island, None if label is None else label[idx], rows[idx], cols[idx], u_major[idx],
                sign * i, slope[idx], bias[idx],
            )  # fmt: skip
            acc[idx[ok]] += g[idx[ok]] * val[ok]
            wsum[idx[ok]] += g[idx[ok]]
            alive[side, idx[~ok]] = False
    res = np.where(active, (1.0 - a) * centre + a * (acc / wsum), centre)
    out[...] = res.reshape(h, w)
    return out


if HAVE_NUMBA:
    _FAST = {"nsz", "arcp", "contract", "reassoc"}  # no assumptions about NaN/inf (inputs are checked finite)
    _IR_FAST = tuple(sorted(_FAST))  # the same flags on the instructions of the intrinsic below
    # The Lanczos table's shape (steps, 2 · lobes) is read from the table passed in, not from taps.py's
    # constants: numba's cache would keep constants of another module after they changed.

    @numba.njit(cache=True, inline="always")
    def _log2(n):
        """log2 of a power of 2."""
        k = 0
        while (1 << k) < n:
            k += 1
        return k

    @numba.njit(cache=True, inline="always", fastmath=_FAST)
    def _across(slope, i, bias, steps, shift):
        """Cross-axis texel y0 (relative) and Lanczos row of tap ``i``: :func:`taps.tap_across`, exactly.

        ``steps`` = 2 ** ``shift`` (a shift and a mask, not an integer division).
        """
        qq = np.int64((bias + np.float64(abs(i)) * np.float64(slope)) * steps + 0.5)  # positive: truncation = floor
        y0 = (qq >> shift) - np.int64(bias)
        row = qq & (steps - 1)
        if i < 0:  # the mirror image of tap |i| (taps.tap_across)
            y0 = -y0 - (1 if row > 0 else 0)
            row = (steps - row) & (steps - 1)
        return y0, row

    @numba.njit(cache=True, inline="always", fastmath=_FAST)
    def _checked_tap(src, island, label, use_islands, r, c, u_major, i, slope, bias, table):
        """Sample of tap ``i`` and whether it is usable: Lanczos-3 where its six texels are in the map and the
        island, else linear between the two texels around it where those are (next to a border), else unusable."""
        h, w = src.shape
        steps, foot = table.shape
        lobes = foot // 2
        y0, t = _across(slope, i, bias, steps, _log2(steps))
        full = True
        for k in range(foot):
            if table[t, k] == 0.0:
                continue
            across = y0 + k + 1 - lobes
            rr = r + across if u_major else r + i
            cc = c + i if u_major else c + across
            if rr < 0 or cc < 0 or rr >= h or cc >= w or (use_islands and island[rr, cc] != label):
                full = False
                break
        if not full:  # the two nearest texels, y0 and (for a fraction > 0) y0 + 1
            for k in range(2 if t > 0 else 1):
                rr = r + y0 + k if u_major else r + i
                cc = c + i if u_major else c + y0 + k
                if rr < 0 or cc < 0 or rr >= h or cc >= w or (use_islands and island[rr, cc] != label):
                    return False, 0.0
            rr = r + y0 if u_major else r + i
            cc = c + i if u_major else c + y0
            v0 = np.float64(src[rr, cc])
            if t == 0:
                return True, v0
            f = np.float64(t) / steps
            v1 = np.float64(src[rr + 1, cc] if u_major else src[rr, cc + 1])
            return True, v0 + f * (v1 - v0)
        val = 0.0
        for k in range(foot):
            across = y0 + k + 1 - lobes
            rr = r + across if u_major else r + i
            cc = c + i if u_major else c + across
            wk = table[t, k]
            if wk != 0.0:
                val += wk * np.float64(src[rr, cc])
        return True, val

    # The interior ("fast") path, where every tap's texels are known to lie in the map and the texel's
    # island, is split in two loops (profiled on the 4096² benchmark: a single loop was bound by
    # floating-point issue, not by memory):
    #
    # 1. _tap_positions: the flat offset of the first of the six texels of every tap and its Lanczos row.
    #    Nothing in it depends on the map, so LLVM vectorises it (eight taps a step: the caller rounds the
    #    count up to a multiple of 8, so no scalar remainder runs); the arithmetic is exact (see taps.py),
    #    so the positions are those of the numpy twin.
    # 2. _interior_sum: the taps themselves, a pair ±i at a time, each tap an eight-texel vector load
    #    (_lanczos_pair): u-major taps are read from the map's transpose, whose rows are the map's
    #    columns.  The Gaussian weight is advanced in the loop by the recursion above.  A pair's twelve
    #    products and their sum are in the map's precision (float32 for float32 maps: the weights differ
    #    from the float64 table by ≤ 6e-8 relative), the checked path and the numpy twin's in float64.
    #    Offsets are unsigned: they are ≥ 0 by the fast-path test.
    # The accumulation over the pairs (float64, in order of i) is that of the checked path.

    @numba.njit(cache=True, inline="always", fastmath=_FAST)
    def _tap_positions(rad, along, across, stride, slope, bias, steps, shift, lobes, off, rows):
        """Flat offset of the first texel each tap reads and the Lanczos row of taps +i (slot 2i − 2) and −i
        (slot 2i − 1; the interior sum reads it with row +i reversed, from texel −y0₊ − 3).

        ``along``, ``across``: the texel's index along the major direction (the map's row in ``flat``) and
        across it; ``stride``: the row stride of ``flat``.
        """
        for k in range(rad):  # the pair ±i: tap −i is tap i mirrored through the centre (taps.tap_across)
            i = k + 1
            qq = np.int64((bias + np.float64(i) * np.float64(slope)) * steps + 0.5)
            row = qq & (steps - 1)
            y0 = (qq >> shift) - np.int64(bias)
            rows[2 * k] = row
            rows[2 * k + 1] = (steps - row) & (steps - 1)
            off[2 * k] = (along + i) * stride + across + y0 + 1 - lobes
            # tap −i read with row ``row`` reversed: its run of six starts at −y0 − 1 − 2 (for a whole-texel
            # position, row 0, that is one texel below tap_across's y0 − 2; the reversed row weighs −y0 alone)
            off[2 * k + 1] = (along - i) * stride + across - y0 - lobes

    def _halves(builder, v, n):
        """The two halves of the n-lane vector ``v``, added lane by lane (one step of a horizontal sum)."""
        lanes = ir.VectorType(ir.IntType(32), n // 2)
        lo = builder.shuffle_vector(v, v, ir.Constant(lanes, list(range(n // 2))))
        hi = builder.shuffle_vector(v, v, ir.Constant(lanes, list(range(n // 2, n))))
        return builder.fadd(lo, hi, flags=_IR_FAST)

    @intrinsic
    def _lanczos_pair(typingctx, flat, op, on, lanes, t):
        """The pair of taps ±i: Σ_k lanes[t, k] · flat[op + k] + lanes[t, 8 + k] · flat[on + k], k = 0 … 7.

        Row ``t`` of :func:`_lanczos_lanes` holds tap +i's six Lanczos weights and tap −i's (the same row
        reversed: the table is mirror-symmetric, taps.py), each followed by two zeros.  Two unaligned
        eight-texel loads of the map, two of the row, a multiply, a fused multiply-add and a horizontal sum
        of the eight lanes, all in the map's precision (numba does not vectorise the scalar form: its
        straight-line vectoriser is off by default).  All sixteen texels must be in the map: the fast
        path of :func:`convolve_pass` keeps two texels more from the map's far edge for the two lanes of
        weight 0.  ``flat``: 1-D C-contiguous map; ``op``, ``on``: uint64 offsets; ``t``: int64 row.
        """
        ok = (
            isinstance(flat, numba.types.Array) and flat.ndim == 1 and flat.layout == "C"
            and flat.dtype in (numba.float32, numba.float64)
            and isinstance(lanes, numba.types.Array) and lanes.ndim == 2 and lanes.layout == "C"
            and lanes.dtype == flat.dtype and op == numba.uint64 and on == numba.uint64 and t == numba.int64
        )  # fmt: skip
        if not ok:
            return None
        sig = flat.dtype(flat, op, on, lanes, t)

        def codegen(context, builder, signature, args):
            flat_v, op_v, on_v, lanes_v, t_v = args
            data = context.make_array(signature.args[0])(context, builder, flat_v).data
            table = context.make_array(signature.args[3])(context, builder, lanes_v).data
            vec = ir.VectorType(context.get_value_type(signature.args[0].dtype), 8)

            def load8(base, index):
                return builder.load(builder.bitcast(builder.gep(base, [index]), vec.as_pointer()), align=1)

            row = builder.mul(t_v, ir.Constant(t_v.type, 16))
            plus = builder.fmul(load8(data, op_v), load8(table, row), flags=_IR_FAST)
            minus = builder.fmul(load8(data, on_v), load8(table, builder.add(row, ir.Constant(t_v.type, 8))),
                                 flags=_IR_FAST)  # fmt: skip
            two = _halves(builder, _halves(builder, builder.fadd(plus, minus, flags=_IR_FAST), 8), 4)
            first = builder.extract_element(two, ir.Constant(ir.IntType(32), 0))
            second = builder.extract_element(two, ir.Constant(ir.IntType(32), 1))
            return builder.fadd(first, second, flags=_IR_FAST)

        return sig, codegen

    @numba.njit(cache=True, inline="always", fastmath=_FAST)
    def _interior_sum(flat, rad, q, centre, off, rows, lanes):
        """Σ over taps −n … n of g_i · sample and Σ g_i (g_0 = 1), taps from :func:`_tap_positions`.

        Nagano et al. 2015 eq. 3 with the Gaussian part of eq. 6 (renormalised by the caller); ``lanes``:
        :func:`_lanczos_lanes` in the map's dtype.
        """
        q2 = q * q
        ratio = q
        g = 1.0
        acc = np.float64(centre)
        wsum = 1.0
        for i in range(rad):
            g *= ratio
            ratio *= q2
            pair = _lanczos_pair(flat, numba.uint64(off[2 * i]), numba.uint64(off[2 * i + 1]), lanes, rows[2 * i])
            acc += g * np.float64(pair)
            wsum += 2.0 * g
        return acc, wsum

    @numba.njit(cache=True, inline="always", fastmath=_FAST)
    def _checked_sum(src, r, c, rad, q, u_major, slope, label, island, use_islands, table):
        """As :func:`_interior_sum` near borders and islands: each side stops at its first unusable tap."""
        q2 = q * q
        ratio = q
        g = 1.0
        acc = np.float64(src[r, c])
        wsum = 1.0
        bias = np.float64(rad + table.shape[1] // 2)
        alive_p = True
        alive_n = True
        for i in range(1, rad + 1):
            g *= ratio
            ratio *= q2
            if alive_p:
                alive_p, val = _checked_tap(src, island, label, use_islands, r, c, u_major, i, slope, bias, table)
                if alive_p:
                    acc += g * val
                    wsum += g
            if alive_n:
                alive_n, val = _checked_tap(src, island, label, use_islands, r, c, u_major, -i, slope, bias, table)
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
        flat = numba.types.Array(t, 1, "C", readonly=True)
        return numba.void(
            numba.types.Array(t, 2, "A", readonly=True),
            flat,
            numba.int64,
            flat,
            numba.int64,
            numba.types.Array(t, 2, "A"),
            *[_ro(numba.float32)] * 5,
            _ro(numba.int32),
            _ro(numba.float32),
            numba.boolean,
            numba.float64,
            numba.int64,
            numba.types.Array(numba.float64, 2, "C", readonly=True),
            numba.types.Array(t, 2, "C", readonly=True),
        )

    #: Columns per strip: the rows a strip's taps touch stay in the L2 cache.
    STRIP = 256

    def _convolve_pass_py(
        src, flat, rs, flat_t, rs_t, out, au, av, alpha, sigma_um, texel_um, island, reach, use_islands, truncate,
        rmax, table, lanes,
    ):  # fmt: skip
        h, w = src.shape
        steps, foot = table.shape
        lobes = foot // 2
        shift = _log2(steps)
        for c0 in range(0, w, STRIP):  # column strips (serial), rows in parallel
            c1 = min(w, c0 + STRIP)
            for r in numba.prange(h):
                off = np.empty(2 * rmax + 16, np.int64)  # per-row scratch of _tap_positions (up to rmax + 7 taps)
                rows = np.empty(2 * rmax + 16, np.int64)
                for c in range(c0, c1):
                    a = alpha[r, c]
                    label = island[r, c] if use_islands else 1
                    du = au[r, c]
                    dv = av[r, c]
                    u_major = abs(du) >= abs(dv)
                    major = abs(du) if u_major else abs(dv)
                    slope = dv / du if u_major else du / dv
                    sp = np.float64(sigma_um[r, c] / texel_um[r, c]) * np.float64(major)
                    centre = src[r, c]
                    if a == 0.0 or label == 0 or not sp > 0.0:
                        out[r, c] = centre
                        continue
                    rad = int(math.ceil(truncate * sp))
                    q = math.exp(-0.5 / (sp * sp))
                    # along: rad texels each way; across: the six texels of a point up to rad texels off
                    along, across, n_along, n_across = (c, r, w, h) if u_major else (r, c, h, w)
                    fast = along - rad >= 0 and along + rad < n_along
                    # (+ 2: a tap's eight-texel load reads two texels of weight 0 past its six, _lanczos_pair)
                    fast = fast and across - rad - lobes >= 0 and across + rad + lobes + 2 < n_across
                    if use_islands and reach[r, c] <= rad / np.float64(major) + lobes + 1:
                        fast = False
                    if fast:
                        bias = np.float64(rad + lobes)
                        n8 = (rad + 7) & ~7  # positions of taps past rad are computed, not read
                        if u_major:
                            _tap_positions(n8, along, across, rs_t, slope, bias, steps, shift, lobes, off, rows)
                            acc, wsum = _interior_sum(flat_t, rad, q, centre, off, rows, lanes)
                        else:
                            _tap_positions(n8, along, across, rs, slope, bias, steps, shift, lobes, off, rows)
                            acc, wsum = _interior_sum(flat, rad, q, centre, off, rows, lanes)
                    else:
                        acc, wsum = _checked_sum(src, r, c, rad, q, u_major, slope, label, island, use_islands, table)
                    out[r, c] = (1.0 - a) * centre + a * (acc / wsum)

    #: Side of the square blocks of the transpose (two 64 × 64 float32 blocks fit in the L1 cache).
    BLOCK = 64

    def _transpose_signature(t):
        return numba.void(numba.types.Array(t, 2, "A", readonly=True), numba.types.Array(t, 2, "A"))

    # One compiled version per dtype, for any layout (a padded view and a contiguous map alike).
    @numba.njit([_transpose_signature(numba.float32), _transpose_signature(numba.float64)], cache=True, parallel=True)
    def _transpose_into(src, dst):
        """dst[j, i] = src[i, j], by square blocks, block rows in parallel."""
        h, w = src.shape
        for b in numba.prange((h + BLOCK - 1) // BLOCK):
            r0 = b * BLOCK
            r1 = min(h, r0 + BLOCK)
            for c0 in range(0, w, BLOCK):
                c1 = min(w, c0 + BLOCK)
                for c in range(c0, c1):
                    for r in range(r0, r1):
                        dst[c, r] = src[r, c]

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

    Parameters
    ----------
    shape : tuple of 2 int
        (H, W).
    dtype : numpy dtype
        Of the map.

    Returns
    -------
    ndarray, shape (H, W)
        Uninitialised; rows are :data:`ROW_PAD_BYTES` longer in memory when W texels fill a multiple of 1024 bytes.
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


_LANCZOS_BY_DTYPE = {}


def _lanczos_lanes(dtype):
    """:data:`taps.LANCZOS` as the interior path reads it, in the map's dtype: row j holds row j's six weights,
    two zeros, row j reversed and two zeros (the weights of taps +i and −i in eight lanes each)."""
    key = np.dtype(dtype).name
    if key not in _LANCZOS_BY_DTYPE:
        steps, foot = LANCZOS.shape
        lanes = np.zeros((steps, 2, 8), dtype)
        lanes[:, 0, :foot] = LANCZOS
        lanes[:, 1, :foot] = LANCZOS[:, ::-1]
        _LANCZOS_BY_DTYPE[key] = lanes.reshape(steps, 16)
    return _LANCZOS_BY_DTYPE[key]


def _transposed(src):
    """The transpose of ``src`` in rows that do not alias in the caches (:func:`padded_empty`)."""
    t = padded_empty(src.shape[::-1], src.dtype)
    _transpose_into(src, t)
    return t


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
    steps, foot = LANCZOS.shape
    if foot != 6 or steps & (steps - 1):
        raise RuntimeError(f"the compiled pass needs a Lanczos-3 table of 2**k rows, got shape {LANCZOS.shape}")
    use = island is not None
    if not use:
        island = np.zeros((1, 1), np.int32)
        reach = np.zeros((1, 1), np.float32)
    src, flat, rs = _rows(src)
    _, flat_t, rs_t = _rows(_transposed(src))  # u-major taps read six texels of a column: a row of the transpose
    rmax = int(np.ceil(truncate * float(np.max(sigma_um)) / float(np.min(texel_um)))) + 1  # bounds every radius
    kernel = _pass_kernel(src.dtype)
    kernel(
        src, flat, rs, flat_t, rs_t, out, au, av, alpha, sigma_um, texel_um, island, reach, use, float(truncate), rmax,
        LANCZOS, _lanczos_lanes(src.dtype),
    )  # fmt: skip
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

    The compiled kernel runs the α in parallel, on at most one thread per α.

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
    with threads_at_most(args[4].size):  # a profile's one α per σ: one thread
        return _tv_kernel()(*args)
