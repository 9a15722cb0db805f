"""The compiled look-up pass of the photograph merge (:mod:`facestats.acquire.merge_kernel`, which
documents it and keeps its numpy twin).  Imported only when a merge runs with numba: importing numba
costs about a second."""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["lookup_pass"]


@numba.njit(cache=True, parallel=True, nogil=True)
def lookup_pass(stack, tables, weights, dark, out, den, chunk):
    """ln E and the total weight of every flat sample (eq. 6 of Debevec & Malik 1997, see merge_kernel).

    ``stack`` is a tuple of 1-D code arrays (one per exposure, longest last), ``tables`` and ``weights``
    (P, levels, C) float32, ``dark`` (levels, C) float32; ``out`` and ``den`` are written.  Chunks of
    ``chunk`` samples run in parallel; the sums over exposures are float32 in the order of ``stack``.
    """
    n = out.size
    channels = tables.shape[2]
    half = tables.shape[1] // 2
    for k in numba.prange((n + chunk - 1) // chunk):
        for i in range(k * chunk, min(n, (k + 1) * chunk)):
            c = i % channels
            s = np.float32(0.0)
            d = np.float32(0.0)
            for j in range(len(stack)):
                z = stack[j][i]
                s += tables[j, z, c]
                d += weights[j, z, c]
            den[i] = d
            if d > 0:
                out[i] = s / d
            else:  # no usable exposure: saturated in one at least (NaN) or the longest exposure's floor
                bright = False
                for j in range(len(stack)):
                    bright = bright or stack[j][i] >= half
                out[i] = np.float32(np.nan) if bright else dark[stack[len(stack) - 1][i], c]
