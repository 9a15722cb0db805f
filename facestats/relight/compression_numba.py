"""The per-row products of a compressed relight (:meth:`facestats.relight.compression.CompressedField.relight`),
compiled with numba.

Imported only when a compressed field is relit with ``backend="numba"``: importing numba costs about a
second.  The stored rows are grouped in segments (one per block and channel, their coefficients contiguous);
each row adds the dot product of its coefficients with its block's projected lighting to its pixel and
channel.  The segments are split into ``bounds.size − 1`` parts of about equal work, one per thread, each
summing into its own image so that no two threads write the same value; the caller adds the parts.  Same
float32 products and sums as the numpy path's GEMVs, in a different order (agreement to float32 rounding,
``tests/relight/test_compression.py``).  ``fastmath={"reassoc"}`` lets each dot product be summed in SIMD
lanes (reassociation only: no assumption about NaN, infinities or signed zeros); without it the float32 sums
run one multiply-add at a time and a 512² field's relight takes 30 ms instead of a few.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["project", "relight_segments"]


@numba.njit(cache=True, parallel=True, nogil=True, fastmath={"reassoc"})
def relight_segments(coef, pixel, seg_row, seg_rows, seg_k, seg_proj, seg_channel, seg_coef, bounds, proj, n_pix):
    """Per-part images (parts, n_pix, 3) float32 of Σ_rows C_row · proj[block components, channel].

    ``coef`` flat float32 coefficients; ``pixel`` (int32) the position of every stored row; per segment its
    first row, number of rows, number of components K, offset of its block's components in ``proj`` (columns of
    ``proj``, (3, components) float32), channel and first coefficient; ``bounds`` the segments of each part.
    """
    parts = np.zeros((bounds.size - 1, n_pix, 3), np.float32)
    for t in numba.prange(bounds.size - 1):
        for s in range(bounds[t], bounds[t + 1]):
            k = seg_k[s]
            p0 = seg_proj[s]
            c = seg_channel[s]
            b = seg_coef[s]
            r0 = seg_row[s]
            for i in range(seg_rows[s]):
                acc = np.float32(0)
                for j in range(k):
                    acc += coef[b + i * k + j] * proj[c, p0 + j]
                parts[t, pixel[r0 + i], c] += acc
    return parts


@numba.njit(cache=True, parallel=True, nogil=True, fastmath={"reassoc"})
def project(stack, weights, out):
    """``out[c, i] = Σ_l stack[i, l] weights[c, l]``: the lighting (3, L_r) on a region's stacked bases (n, L_r),
    float32.

    Compiled beside :func:`relight_segments` rather than left to BLAS: a threaded BLAS product just before a
    numba parallel region leaves BLAS's threads spinning on the cores numba needs (measured: the 512² relight
    took 26 ms after a BLAS projection, 8 ms after this one).
    """
    for i in numba.prange(stack.shape[0]):
        a0 = np.float32(0)
        a1 = np.float32(0)
        a2 = np.float32(0)
        for j in range(stack.shape[1]):
            v = stack[i, j]
            a0 += v * weights[0, j]
            a1 += v * weights[1, j]
            a2 += v * weights[2, j]
        out[0, i] = a0
        out[1, i] = a1
        out[2, i] = a2
