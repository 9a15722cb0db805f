"""Where the taps of one convolution pass fall, and how each is read from the texel grid.

Nagano et al. 2015 eq. 3 samples the map at ``D(u − i a_u, v − i a_v)``: points on a line through
the texel along its unit axis a, which lie between texels unless a is on the grid.  The paper does
not say how such a point is read.  Reading it bilinearly (this package until 2026-12-07) averages
across the axis as well as along it, so a pass along s also blurred across s: with a at 45° and the
stretch kernel of r = 2.2 (α = 1, σ = 57.5 µm at 6 µm per texel), a wave across s at ω = π/2 rad
per texel kept 0.81 of its amplitude where eq. 3 keeps all of it, and compression (α < 0) then
blurred where eq. 6 sharpens.  Here:

* **Taps at whole texels along the major direction.**  The major direction is u where
  ``|a_u| ≥ |a_v|``, else v.  Tap i (i = −n … n) sits at ``i`` texels along it and at
  ``i · slope`` texels across it, slope = a_minor / a_major (|slope| ≤ 1): a point of the line
  through the texel along a, at distance ``i · h`` with spacing ``h = 1 / |a_major|`` (1 to √2
  texels).  The Gaussian weight of tap i is ``exp(−(i h)² / (2 σ_px²))``, the discrete Gaussian of
  σ_px / h taps: that is what :func:`gaussian_spacing` returns, and the pass uses it in place of
  σ_px, with ``n = ceil(TRUNCATE · σ_px / h)`` taps each side.
* **One-dimensional interpolation across.**  The point is read between the texels of its column (u
  major) or row (v major) only, by a Lanczos-3 filter (the sinc windowed by a sinc three times as
  wide, weights normalised to sum 1): six texels, y0 − 2 … y0 + 3 for a point at y0 + f.  The
  fraction f is rounded to 1/``LANCZOS_STEPS`` of a texel (≤ 4.9e-4 texel) and the weights are
  read from :data:`LANCZOS`; f = 0 reads the one texel y0 exactly.  Next to a border (a texel of the
  six outside the map or the texel's UV island) the point is read linearly between y0 and y0 + 1;
  a side of the kernel ends at the first tap whose two texels are not both usable.  Off the grid
  Lanczos-3's negative weights let a blur overshoot a step by about 0.5 %.

On the grid (a = (±1, 0) or (0, ±1)) every tap is a texel, exactly as before.  At 45° every tap
is a texel too (slope ±1).  In between, with the stretch kernel above, pass 1 keeps 1.000-1.014 of
a wave across s at ω = π/2 rad per texel (0.812-0.844 read bilinearly), and 0.70-1.00 at ω = 0.9π
(0.50-0.57); ``benchmarks/bench_microstructure.py`` (``bench_rotation``) measures it and
``tests/model/microstructure/test_convolve.py`` tests it.  Left: near 45° taps are √2 texels apart,
so a kernel narrower than that is sampled coarsely (docs/microstructure.md).  The six texels are one
contiguous run in a map laid out with the minor direction along its rows: the
compiled pass reads u-major taps from the map's transpose.

Positions agree between implementations: ``|i| · slope`` of a float32 slope and an integer
|i| ≤ 8192 is exact in float64, and so is ×1024; the sum with the bias and the rounding are the same
float64 operations in the compiled pass, its numpy twin and the fit's stencil, so all three find the
same texels and the same fraction (a test checks the compiled positions against :func:`tap_across`).
Tap −i is tap i mirrored through the centre, and the table is exactly mirror-symmetric, so the
compiled pass reads one table row for both taps of a pair, and every kernel is exactly symmetric (a
linear ramp passes a blur unchanged).

Reference: the Lanczos window, C. E. Duchon (1979), "Lanczos filtering in one and two dimensions",
*J. Appl. Meteorology* 18, 1016-1022; here its usual image-resampling form with a = 3 lobes.
"""

from __future__ import annotations

import numpy as np

__all__ = ["LANCZOS_STEPS", "LANCZOS_LOBES", "LANCZOS", "FOOTPRINT", "major_axis", "gaussian_spacing", "tap_across"]

#: Fractions of a texel the cross-axis position is rounded to (a power of 2: ×1024 is exact).
LANCZOS_STEPS = 1024
#: Lobes of the Lanczos window (Lanczos-3: six texels per tap).
LANCZOS_LOBES = 3
#: Texels a tap reads across the axis: y0 − 2 … y0 + 3 (y0 − LANCZOS_LOBES + 1 … y0 + LANCZOS_LOBES).
FOOTPRINT = 2 * LANCZOS_LOBES


def _lanczos_table(steps=LANCZOS_STEPS, lobes=LANCZOS_LOBES):
    """Weights (float64, rows sum to 1) of texels y0 − lobes + 1 … y0 + lobes for a point at y0 + j/steps.

    w_k ∝ sinc(x) sinc(x / lobes), x = k − f the distance of texel k from the point (sinc(x) = sin(πx)/(πx)).
    Row 0 (f = 0) is the unit impulse on y0 exactly (np.sinc leaves ~1e-17 at whole x).
    """
    f = np.arange(steps) / steps
    x = np.arange(1 - lobes, lobes + 1)[None, :] - f[:, None]
    w = np.sinc(x) * np.sinc(x / lobes)
    w /= w.sum(axis=1, keepdims=True)
    w[0] = 0.0
    w[0, lobes - 1] = 1.0
    # Exactly mirror-symmetric: the point y0 + j/steps seen from the other side is −y0 − 1 + (steps − j)/steps, whose
    # weights are row j's reversed (so a tap pair ±i needs one row, and the compiled pass loads it once).
    half = steps // 2
    w[half] = 0.5 * (w[half] + w[half, ::-1])
    w[half + 1 :] = w[1:half][::-1, ::-1]
    return w


#: Lanczos-3 weights, (LANCZOS_STEPS, FOOTPRINT) float64: row j for the fraction j / LANCZOS_STEPS.
LANCZOS = _lanczos_table()
LANCZOS.flags.writeable = False


def major_axis(au, av):
    """The major direction, slope and major component of unit axes (a_u, a_v) (float32 arrays or scalars).

    Parameters
    ----------
    au, av : array_like
        Components of unit axes, read as float32, broadcast against each other.

    Returns
    -------
    u_major : ndarray of bool
        True where ``|a_u| ≥ |a_v|``: taps step along u (columns), else along v (rows).
    slope : ndarray of float32
        a_v / a_u (u major) or a_u / a_v (v major): cross-axis texels per tap, in [−1, 1].
    major : ndarray of float32
        |a_u| or |a_v|, in [1/√2, 1]: the tap spacing along the axis is 1 / major texels.
    """
    au, av = np.asarray(au, np.float32), np.asarray(av, np.float32)
    u_major = np.abs(au) >= np.abs(av)
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = np.where(u_major, av / au, au / av).astype(np.float32)
    major = np.where(u_major, np.abs(au), np.abs(av)).astype(np.float32)
    return u_major, slope, major


def gaussian_spacing(sigma_px, major):
    """σ in taps, σ_px · |a_major| (float64): the Gaussian of σ_px texels sampled every 1/|a_major| texels.

    Parameters
    ----------
    sigma_px : array_like
        Gaussian standard deviation in texels.
    major : array_like
        |a_major| of :func:`major_axis`, in [1/√2, 1].

    Returns
    -------
    ndarray of float64
        σ in taps, broadcast shape of the inputs.
    """
    return np.asarray(sigma_px, np.float64) * np.asarray(major, np.float64)


def tap_across(slope, i, bias):
    """Cross-axis texel y0 (relative to the centre) and Lanczos row of tap ``i`` (signed), exactly.

    The point of tap |i| lies ``|i| · slope`` texels across; ``bias`` (an integer > |i|, float) keeps the
    position positive so that the integer part is the floor.  Tap −|i| is its mirror image through the
    centre: y0 = −y0₊ − 1 and row = LANCZOS_STEPS − row₊ (y0 = −y0₊, row 0 where row₊ is 0), so the two
    taps of a pair are rounded alike.

    Parameters
    ----------
    slope : array_like
        Cross-axis texels per tap (:func:`major_axis`), read as float32.
    i : array_like of int
        Signed tap index.
    bias : float or array_like
        An integer-valued float > |i| that keeps the position positive.

    Returns
    -------
    y0, row : ndarray of int64
        The point is y0 + row / LANCZOS_STEPS texels across (rounded to the nearest step); broadcast shape of
        the inputs.
    """
    b = np.asarray(bias, np.float64)
    i = np.asarray(i)
    across = np.abs(i).astype(np.float64) * np.asarray(slope, np.float32).astype(np.float64)
    q = np.floor((b + across) * LANCZOS_STEPS + 0.5).astype(np.int64)
    y0, row = q // LANCZOS_STEPS - b.astype(np.int64), q % LANCZOS_STEPS
    mirror = i < 0
    y0 = np.where(mirror, -y0 - (row > 0), y0)
    row = np.where(mirror, (LANCZOS_STEPS - row) % LANCZOS_STEPS, row)
    return y0, row
