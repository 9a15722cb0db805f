"""The compiled kernels of the linear-raw camera model: readings from noise draws
(:func:`facestats.acquire.hdr.expose`) and the HDR merge (:func:`facestats.acquire.hdr.merge_exposures`);
that module documents the model and keeps their numpy twins, which give the same bits.  Imported only
when numba runs them: importing numba costs about a second."""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["expose_pass", "merge_pass"]


@numba.njit(cache=True, nogil=True)
def merge_pass(d, t, sat, gain, black, var0, rate, std, n_used):
    """Both passes of the inverse-variance merge for every sample, in one sweep over the readings.

    ``d`` is (E, N) readings in DN, ``t`` (E,) exposure times, both in the dtype of ``rate`` and ``std``
    (N,), which are written with ``n_used`` (N,) int16.  ``sat`` is the clipping level in DN, ``gain``
    electrons per DN, ``black`` the pedestal in DN and ``var0`` the constant part of the variance,
    σ_read² + g²/12 (e⁻²), all scalars of the readings' dtype.  Each sample's sums run over the exposures
    in order with the operations of the numpy twin in the same order, so both give the same bits.
    Serial: callers (simulator workers) run one per process.
    """
    n_exp, n = d.shape
    zero = rate.dtype.type(0)
    one = rate.dtype.type(1)
    for i in range(n):
        num = zero
        den = zero
        used = 0
        for j in range(n_exp):
            if d[j, i] < sat:
                used += 1
                num += (d[j, i] - black) * gain
                den += t[j]
        n_used[i] = used
        if used == 0:
            rate[i] = np.nan
            std[i] = np.nan
            continue
        rate0 = max(num / den, zero)
        num = zero
        wsum = zero
        for j in range(n_exp):
            if d[j, i] < sat:
                e = rate0 * t[j]
                w = t[j] * t[j] / (max(e, zero) + var0)
                num += w * ((d[j, i] - black) * gain / t[j])
                wsum += w
        rate[i] = num / wsum
        std[i] = one / np.sqrt(wsum)


@numba.njit(cache=True, nogil=True)
def expose_pass(rate, tj, noise, read2, inv_gain, black, max_dn, out):
    """Readings of one exposure from standard-normal ``noise``: DN = clip(rint((n·√(m + σ²) + m)/g + b), 0, max).

    ``rate``, ``noise`` and ``out`` are 1-D of one float dtype, m = rate·``tj`` the expected electrons,
    ``read2`` = σ_read², ``inv_gain`` = 1/g, ``black`` = b and ``max_dn`` scalars of that dtype.  The
    operations and their order are those of the numpy twin in :func:`facestats.acquire.hdr.expose`.
    """
    zero = out.dtype.type(0)
    for i in range(rate.size):
        mean = rate[i] * tj
        e = noise[i] * np.sqrt(mean + read2)
        e = (e + mean) * inv_gain + black
        out[i] = min(max(np.rint(e), zero), max_dn)
