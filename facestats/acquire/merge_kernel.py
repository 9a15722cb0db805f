"""The table look-ups of the photograph merge (Debevec & Malik 1997 eq. 6), compiled and in numpy.

For P exposures with codes Z_j, per-exposure tables T_j(z, c) = w_j(z)(g(z, c) − ln Δt_j)
and W_j(z, c) = w_j(z) (:func:`facestats.acquire.response.merge_photographs` builds
them), every sample (pixel, channel c) gets

    num = Σ_j T_j(Z_j, c),  den = Σ_j W_j(Z_j, c),  ln E = num / den,

the weighted mean of eq. 6.  Where den = 0 (no usable exposure) ln E is NaN if any
exposure's code is at or above mid-range (saturated there: with zero weight every code
is dark or clipped, and a pixel dark in a short exposure and clipped in a long one lies
between the two, unknown), and otherwise (dark in every exposure) the longest
exposure's estimate D(Z_P, c) = g(Z_P, c) − ln Δt_P (:mod:`facestats.acquire.response`'s
docstring).  Two implementations, the same sums in the same order (float32, exposures in
the given order), so the results are identical:

* ``backend="numba"`` (:mod:`facestats.acquire.merge_numba`): one pass over the samples,
  parallel over chunks of them, every exposure's code read once; about 2× faster than the
  numpy path on two cores.
* ``backend="numpy"``: one whole-array look-up per exposure and table (8-bit
  three-channel codes through OpenCV's ``LUT``), rows in blocks that stay in the CPU
  cache, spread over a thread per core.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from facestats.core.compiled import resolve_backend, threads_at_most

__all__ = ["log_radiance"]

#: Rows per block of the numpy path, and the number of samples from which blocks are spread over threads.
BLOCK_ROWS = 64
THREADED = 1 << 18
#: Samples per parallel chunk of the compiled path.
CHUNK = 1 << 14


def log_radiance(stack, tables, weights, dark, *, backend: str = "auto"):
    """Eq. 6's weighted mean of g(Z_j) − ln Δt_j over exposures, and its total weight.

    Parameters
    ----------
    stack : sequence of ndarray of unsigned int, each (..., C)
        The codes of each exposure, all of one shape and dtype, already checked to lie below ``levels``.
    tables, weights : ndarray of float32, shape (P, levels, C)
        T_j and W_j of the module docstring, one per exposure in the order of ``stack``.
    dark : ndarray of float32, shape (levels, C)
        D of the module docstring, for the last exposure of ``stack`` (the longest).
    backend : {"auto", "numba", "numpy"}
        Compiled (default where numba is installed) or numpy.

    Returns
    -------
    ln_e, den : ndarray of float32, shape of one image
        ln E (module docstring) and den.
    """
    shape = stack[0].shape
    out = np.empty(shape, np.float32)
    den = np.empty(shape, np.float32)
    if resolve_backend(backend) == "numba":
        from facestats.acquire.merge_numba import lookup_pass  # imports numba: only when a merge runs

        flat = tuple(np.ascontiguousarray(z).reshape(-1) for z in stack)
        t = np.ascontiguousarray(tables, np.float32)
        w = np.ascontiguousarray(weights, np.float32)
        d = np.ascontiguousarray(dark, np.float32)
        with threads_at_most(-(-out.size // CHUNK)):  # an image of up to CHUNK samples: one thread
            lookup_pass(flat, t, w, d, out.reshape(-1), den.reshape(-1), CHUNK)
        return out, den
    rows = shape[0] if len(shape) == 3 else 1
    blocks = [slice(a, min(a + BLOCK_ROWS, rows)) for a in range(0, rows, BLOCK_ROWS)] if rows > 1 else [slice(None)]

    def run(sl):
        _numpy_block([z[sl] for z in stack], tables, weights, dark, out[sl], den[sl])

    if len(blocks) > 1 and stack[0].size >= THREADED:
        with ThreadPoolExecutor(min(len(blocks), os.cpu_count() or 1)) as ex:  # look-ups and ufuncs release the GIL
            list(ex.map(run, blocks))
    else:
        for sl in blocks:
            run(sl)
    return out, den


def _numpy_block(stack, tables, weights, dark, num, den):
    """ln E and den of one block of rows (views), written into ``num`` and ``den``."""
    num[...] = 0
    den[...] = 0
    for z, lut, wlut in zip(stack, tables, weights):  # loop over exposures, vectorised over samples
        _add_lookup(num, z, lut)
        _add_lookup(den, z, wlut)
    with np.errstate(invalid="ignore", divide="ignore"):
        np.divide(num, den, out=num)
    none = np.nonzero(den == 0)  # no usable exposure: treated on these samples only
    if none[0].size:
        levels = dark.shape[0]
        bright = np.any([z[none] >= levels // 2 for z in stack], axis=0)
        num[none] = np.where(bright, np.float32(np.nan), dark[stack[-1][none], none[-1]])


def _add_lookup(acc, z, lut):
    """acc[..., c] += lut[z[..., c], c]: one table look-up per sample (OpenCV's LUT for 8-bit 3-channel codes)."""
    if z.dtype == np.uint8 and lut.shape == (256, 3) and z.ndim == 3 and z.shape[-1] == 3:
        import cv2

        acc += cv2.LUT(np.ascontiguousarray(z), np.ascontiguousarray(lut, np.float32).reshape(1, 256, 3))
        return
    flat = np.ascontiguousarray(lut, np.float32).reshape(-1)
    idx = z.astype(np.intp) * lut.shape[1] + np.arange(lut.shape[1])
    acc += flat[idx]
