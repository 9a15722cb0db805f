"""The products of a compressed relight (:meth:`facestats.relight.compression.CompressedField.relight`), compiled
with numba.

Imported when a compressed field is relit with the numba backend (``backend="numba"``, or ``"auto"`` where numba
imports): importing numba costs about a second.  The stored rows are grouped in segments (one per block, their
coefficients contiguous); each row q of pixel p takes the dot product of its coefficients with its block's
projected lighting of each channel c, t_c, and adds A_p[c, q] t_c to channel c of the pixel.  The segments are in
cluster order and the parallel parts are cut between clusters; a pixel belongs to one cluster, so no two parts
write the same value and the parts run in parallel without a race (memory: one image, whatever the number of
threads).  Same float32 products as the numpy path's GEMMs, summed in another order (agreement to float32
rounding, ``tests/relight/test_compression.py``).
``fastmath={"reassoc"}`` lets each dot product be summed in SIMD lanes (reassociation only: no assumption about
NaN, infinities or signed zeros; exact zeros stay zero); without it the float32 sums run one multiply-add at a
time and a 512² field's relight takes 30 ms instead of a few.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["project", "relight_segments"]


@numba.njit(cache=True, parallel=True, nogil=True, fastmath={"reassoc"})
def relight_segments(coef, pixel, mix, seg_row, seg_rows, seg_k, seg_proj, seg_kind, seg_coef, bounds, proj,
                     out):  # fmt: skip
    """Add Σ_rows A[pixel, c, q] (C_row · proj[c, block components]) to ``out[pixel, c]`` ((n_pix, 3) float32).

    ``coef`` flat float32 coefficients; ``pixel`` (int64) the position of every stored row; ``mix`` (n_pix, 3, 3)
    float32 each pixel's A (channels, colour rows); per segment its first row, number of rows, number of components
    K, offset of its block's components in ``proj`` ((3, components) float32), colour row q and first coefficient;
    ``bounds`` the segments of each parallel part (cut between clusters).
    """
    for t in numba.prange(bounds.size - 1):
        for s in range(bounds[t], bounds[t + 1]):
            k = seg_k[s]
            p0 = seg_proj[s]
            q = seg_kind[s]
            b = seg_coef[s]
            r0 = seg_row[s]
            for i in range(seg_rows[s]):
                a0 = np.float32(0)
                a1 = np.float32(0)
                a2 = np.float32(0)
                for j in range(k):
                    v = coef[b + i * k + j]
                    a0 += v * proj[0, p0 + j]
                    a1 += v * proj[1, p0 + j]
                    a2 += v * proj[2, p0 + j]
                p = pixel[r0 + i]
                out[p, 0] += mix[p, 0, q] * a0
                out[p, 1] += mix[p, 1, q] * a1
                out[p, 2] += mix[p, 2, q] * a2
    return out


@numba.njit(cache=True, parallel=True, nogil=True, fastmath={"reassoc"})
def project(stack, weights, proj, start):
    """``proj[c, start + i] = Σ_l stack[i, l] weights[c, l]``: the lighting (3, L_r) on a region's stacked bases
    (n, L_r), float32, into the columns of ``proj`` (3, components) from ``start``.

    Compiled beside :func:`relight_segments` rather than left to BLAS: a threaded BLAS product just before a
    numba parallel region leaves BLAS's threads spinning on the cores numba needs (measured: a 512² relight took
    26 ms after BLAS projections, 8 ms after these).
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
        proj[0, start + i] = a0
        proj[1, start + i] = a1
        proj[2, start + i] = a2
    return proj
