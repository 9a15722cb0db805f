"""The products of a compressed relight (:meth:`facestats.relight.compression.CompressedField.relight`), compiled
with numba.

Imported when a compressed field is relit with the numba backend (``backend="numba"``, or ``"auto"`` where numba
imports): importing numba costs about a second.  The stored rows are grouped in segments (one per block and
channel, their coefficients contiguous); each row adds the dot product of its coefficients with its block's
projected lighting to its pixel and channel of its (region, part) image.  Within one light region and part every
pixel belongs to one block (its cluster's), so no two segments write the same value of an image, and the
segments run in parallel (in parts of about equal work) without a race; the caller adds the images
(memory: (region, part) pairs × pixels × 3 values, whatever the number of threads).  Same float32 products as the numpy
path's GEMVs, summed in another order (agreement to float32 rounding, ``tests/relight/test_compression.py``).
``fastmath={"reassoc"}`` lets each dot product be summed in SIMD lanes (reassociation only: no assumption about
NaN, infinities or signed zeros; exact zeros stay zero); without it the float32 sums run one multiply-add at a
time and a 512² field's relight takes 30 ms instead of a few.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["project", "relight_segments"]


@numba.njit(cache=True, parallel=True, nogil=True, fastmath={"reassoc"})
def relight_segments(coef, pixel, seg_image, seg_row, seg_rows, seg_k, seg_proj, seg_channel, seg_coef, bounds, proj,
                     out):  # fmt: skip
    """Add Σ_rows C_row · proj[channel, block components] to ``out[image]`` ((images, n_pix, 3) float32).

    ``coef`` flat float32 coefficients; ``pixel`` (int64) the position of every stored row; per segment its
    (region, part) image, first row, number of rows, number of components K, offset of its block's components
    in ``proj`` ((3, components) float32), channel and first coefficient; ``bounds`` the segments of each
    parallel part.
    """
    for t in numba.prange(bounds.size - 1):
        for s in range(bounds[t], bounds[t + 1]):
            k = seg_k[s]
            p0 = seg_proj[s]
            c = seg_channel[s]
            b = seg_coef[s]
            r0 = seg_row[s]
            o = out[seg_image[s]]
            for i in range(seg_rows[s]):
                acc = np.float32(0)
                for j in range(k):
                    acc += coef[b + i * k + j] * proj[c, p0 + j]
                o[pixel[r0 + i], c] += acc
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
