"""Vectorisable float32 exponential and logarithm for the lobes of eq. 11-13.

Both specular lobes are ρs · s(p) · A · e^{c z} with c z ≤ 0 (Torrance-Sparrow:
c = −1/m², z = tan²δ; Blinn-Phong: c = n, z = ln cos δ; see
:mod:`facestats.model.fitting.lobes`).  numba compiles ``math.exp`` to a call of
the C library per element, which stops the loop from being vectorised; here
the exponential is written out in IEEE arithmetic so that LLVM vectorises the
loop that fills a lumitexel's lobe values:

    e^x = 2^k e^f,  k = round(x log₂e),  f = x − k ln 2  (|f| ≤ ln 2 / 2),

with ln 2 split in two constants (Cody & Waite 1980, "Software Manual for the
Elementary Functions", ch. 6) and e^f from the degree-7 polynomial of the
Cephes ``expf`` (S. L. Moshier 1992, "Methods and Programs for Mathematical
Functions"; peak relative error 1.7e-7 over its range).  2^k is built from its
bits, (k + 127) · 2²³ read as float32.  Arguments are clamped to [−87, 0] (the
float32 normal range: e^{−87} = 1.6e-38; the lobes there are 0 for any
purpose).  Measured against float64 ``numpy.exp`` on 10⁶ arguments in
[−87, 0] the relative error is below 3e-7 (``tests/model/fitting/test_engines.py``).

The Blinn-Phong abscissa z = ln cos δ needs a logarithm of every sample;
:func:`fill_log` writes x = m 2^e with m in [√½, √2) from the bits of x and
evaluates ln m by the degree-9 polynomial of the Cephes ``logf`` (Moshier 1992;
peak relative error 7.6e-8 over its range), plus e ln 2 with ln 2 split as
above.  For x in (0, 1]; measured against float64 ``numpy.log`` on [1e-6, 1] the
error is below 1.5e-7 + 6e-8 |ln x|, about one float32 ulp of the result (the same test).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["fill_lobe", "fill_log"]

_LOG2E = np.float32(1.4426950408889634)
_LN2_HI = np.float32(0.693359375)
_LN2_LO = np.float32(-2.12194440e-4)
_P0 = np.float32(1.9875691500e-4)
_P1 = np.float32(1.3981999507e-3)
_P2 = np.float32(8.3334519073e-3)
_P3 = np.float32(4.1665795894e-2)
_P4 = np.float32(1.6666665459e-1)
_P5 = np.float32(5.0000001201e-1)
_LOW = np.float32(-87.0)
_ZERO = np.float32(0.0)
_HALF = np.float32(0.5)
_ONE = np.float32(1.0)


@numba.njit(cache=True, nogil=True)
def fill_lobe(rate, z, a, start, n, out, bits):
    """``out[j] = a[start + j] · exp(rate · z[start + j])`` for j < n (float32; the lobe base u of eq. 11-13).

    ``bits`` is int32 scratch of at least ``n`` entries (the 2^k factors); both
    loops are free of calls and reductions, so LLVM vectorises them.
    """
    zs = z[start : start + n]
    as_ = a[start : start + n]
    scale = bits[:n].view(np.float32)
    for j in range(n):
        x = min(max(rate * zs[j], _LOW), _ZERO)
        k = np.floor(x * _LOG2E + _HALF)
        f = (x - k * _LN2_HI) - k * _LN2_LO
        p = _P0 * f + _P1
        p = p * f + _P2
        p = p * f + _P3
        p = p * f + _P4
        p = p * f + _P5
        out[j] = ((p * (f * f) + f) + _ONE) * as_[j]
        bits[j] = (np.int32(k) + np.int32(127)) << np.int32(23)
    for j in range(n):
        out[j] *= scale[j]


_SQRT_HALF = np.float32(0.707106781186547524)
_L = (
    np.float32(7.0376836292e-2),
    np.float32(-1.1514610310e-1),
    np.float32(1.1676998740e-1),
    np.float32(-1.2420140846e-1),
    np.float32(1.4249322787e-1),
    np.float32(-1.6668057665e-1),
    np.float32(2.0000714765e-1),
    np.float32(-2.4999993993e-1),
    np.float32(3.3333331174e-1),
)


@numba.njit(cache=True, nogil=True)
def fill_log(x, out, bits):
    """``out[j] = ln x[j]`` for normal float32 x in (0, 1] (module docstring); ``bits`` int32 scratch like ``x``.

    Both loops are free of calls and reductions, so LLVM vectorises them.
    """
    n = x.shape[0]
    xb = x.view(np.int32)
    mant = bits[:n].view(np.float32)
    for j in range(n):  # m in [0.5, 1): the mantissa bits with the exponent of 0.5
        bits[j] = (xb[j] & np.int32(0x007FFFFF)) | np.int32(0x3F000000)
    for j in range(n):
        e = np.float32(((xb[j] >> np.int32(23)) & np.int32(0xFF)) - np.int32(126))
        m = mant[j]
        if m < _SQRT_HALF:
            e = e - _ONE
            f = (m + m) - _ONE
        else:
            f = m - _ONE
        z = f * f
        p = _L[0] * f + _L[1]
        p = p * f + _L[2]
        p = p * f + _L[3]
        p = p * f + _L[4]
        p = p * f + _L[5]
        p = p * f + _L[6]
        p = p * f + _L[7]
        p = p * f + _L[8]
        y = ((p * f) * z + e * _LN2_LO) - _HALF * z
        out[j] = (f + y) + e * _LN2_HI
