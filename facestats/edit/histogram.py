"""Histograms, histogram matching and histogram interpolation.

Weyrich et al. 2006 §8 edit a face by matching histograms: of the BRDF
parameters per face region (with the histogram interpolation of Matusik et al.
2005), of the albedo colour, and of the albedo's steerable-pyramid subbands
(Heeger & Bergen 1995).  Every operation here reads a histogram as a
*piecewise-uniform distribution*: the counts of a bin are spread uniformly over
the bin, so the cumulative distribution F is piecewise linear through the bin
edges and its inverse, the quantile function Q, is piecewise linear too (with a
jump across empty bins).

* :class:`Histogram` - edges and counts, with ``cdf``, ``quantile`` and ``mean``;
* :func:`match_histogram` - O(N) matching of values to a histogram,
  ``T(x) = Q_target(F_source(x))``, by piecewise-linear CDF inversion
  (Heeger & Bergen 1995 §3.3, "Match-histogram");
* :func:`match_values` - exact, sort-based matching of values to the values of
  another sample (the result has exactly the target's empirical distribution);
* :func:`interpolate_histograms` - displacement interpolation through the
  quantile functions, ``Q_t = (1 - t) Q_0 + t Q_1`` (Matusik et al. 2005);
* :func:`histogram_distance` - total-variation distance on a target's bins.

Building blocks shared with the other edit modules (public within the package,
not re-exported by :mod:`facestats.edit`): :func:`check_t` (the interpolation
weight), :func:`widen_range` (a histogram range for constant data),
:func:`source_histogram` and :func:`match_flat` (the two passes of
:func:`match_histogram` on a flat array, used by the texture synthesis), and
:func:`stable_ranks` / :func:`empirical_quantile` (the sort-based matching of
:func:`match_values`, used per region by the BRDF transfer).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.core.validate import as_finite, as_float, check_finite, check_range
from facestats.errors import ValidationError

__all__ = [
    "Histogram",
    "match_histogram",
    "match_values",
    "interpolate_histograms",
    "histogram_distance",
]

#: Values per chunk in the O(N) passes; 64 Ki values keep the temporaries in cache.
_CHUNK = 1 << 16
#: Bins of the source histogram used to estimate F_source in :func:`match_histogram`.
SOURCE_BINS = 16384


def check_t(t) -> float:
    """Validate an interpolation weight.

    Parameters
    ----------
    t : float
        Weight in [0, 1] (0: the source, 1: the target).

    Returns
    -------
    float
    """
    tt = as_float(t, "t", np.float64)
    if tt.ndim != 0:
        raise ValidationError(f"t must be a scalar in [0, 1], got an array of shape {tt.shape}")
    check_range(check_finite(tt, "t"), "t", 0.0, 1.0)
    return float(tt)


def widen_range(lo: float, hi: float) -> tuple[float, float]:
    """A non-empty histogram range: ``(lo, hi)``, or for constant data (``hi <= lo``) half-width 1e-6·max(1, |lo|).

    Parameters
    ----------
    lo, hi : float
        Smallest and largest value of the data.

    Returns
    -------
    (float, float)
    """
    if hi > lo:
        return lo, hi
    half = 1e-6 * max(1.0, abs(lo))
    return lo - half, hi + half


@dataclass(frozen=True)
class Histogram:
    """A histogram read as a piecewise-uniform distribution.

    Parameters
    ----------
    edges : array_like, shape (bins + 1,)
        Strictly increasing bin edges (in the units of the data).
    counts : array_like, shape (bins,)
        Non-negative weights (counts or probabilities) of the bins, not all zero.
    """

    edges: np.ndarray
    counts: np.ndarray

    def __post_init__(self):
        e = check_finite(as_float(self.edges, "edges", np.float64), "edges")
        c = check_finite(as_float(self.counts, "counts", np.float64), "counts")
        if e.ndim != 1 or c.ndim != 1 or e.size != c.size + 1 or c.size < 1:
            raise ValidationError(
                f"edges and counts must be 1-D with len(edges) == len(counts) + 1 >= 2, "
                f"got shapes {e.shape} and {c.shape}"
            )
        bad = np.flatnonzero(np.diff(e) <= 0)
        if bad.size:
            k = int(bad[0])
            raise ValidationError(
                f"edges must be strictly increasing, got edges[{k}] = {e[k].item()!r} >= edges[{k + 1}] = "
                f"{e[k + 1].item()!r}"
            )
        check_range(c, "counts", 0.0, None)
        if not c.sum() > 0:
            raise ValidationError("counts must not all be zero")
        object.__setattr__(self, "edges", e)
        object.__setattr__(self, "counts", c)

    @classmethod
    def from_data(cls, values, bins: int = 256, range=None) -> "Histogram":
        """Histogram of finite ``values`` on ``bins`` uniform bins over ``range``.

        ``range`` defaults to ``(min, max)`` of the values (widened by 1e-6 if the
        values are constant); values outside an explicit range are not counted.

        Parameters
        ----------
        values : array_like
            Finite values, any shape.
        bins : int
            Number of bins.
        range : (float, float), optional
            Lower and upper edge.

        Returns
        -------
        Histogram
        """
        x = check_finite(as_float(values, "values"), "values").ravel()
        if x.size == 0:
            raise ValidationError("values must not be empty")
        if not isinstance(bins, (int, np.integer)) or bins < 1:
            raise ValidationError(f"bins must be a positive int, got {bins!r}")
        if range is None:
            range = widen_range(float(x.min()), float(x.max()))
        bounds = as_finite(range, "range")
        if bounds.shape != (2,):
            raise ValidationError(f"range must be (low, high), got {range!r}")
        lo, hi = float(bounds[0]), float(bounds[1])
        if not hi > lo:
            raise ValidationError(f"range must have high > low, got {range!r}")
        counts, edges = np.histogram(x, bins=int(bins), range=(lo, hi))
        return cls(edges, counts.astype(np.float64))

    @property
    def bins(self) -> int:
        """Number of bins."""
        return self.counts.size

    @property
    def total(self) -> float:
        """Sum of the counts."""
        return float(self.counts.sum())

    @property
    def pdf(self) -> np.ndarray:
        """Bin probabilities (counts / total)."""
        return self.counts / self.total

    @property
    def cdf(self) -> np.ndarray:
        """F at the edges, shape (bins + 1,): 0 at the first edge, 1 at the last."""
        c = np.concatenate([[0.0], np.cumsum(self.counts)])
        return c / c[-1]

    def mean(self) -> float:
        """Mean of the piecewise-uniform distribution (bin centres weighted by counts)."""
        centres = 0.5 * (self.edges[1:] + self.edges[:-1])
        return float(np.dot(self.pdf, centres))

    def std(self) -> float:
        """Standard deviation of the piecewise-uniform distribution: sqrt(Σ p_k (c_k² + w_k²/12) − mean²) for bins
        of centre c_k and width w_k."""
        centres = 0.5 * (self.edges[1:] + self.edges[:-1])
        widths = np.diff(self.edges)
        second = float(np.dot(self.pdf, centres * centres + widths * widths / 12))
        return float(np.sqrt(max(second - self.mean() ** 2, 0.0)))

    def _segments(self):
        """Non-empty bins as (F at left edge, F at right edge, left edge, right edge)."""
        cdf = self.cdf
        keep = self.counts > 0
        return cdf[:-1][keep], cdf[1:][keep], self.edges[:-1][keep], self.edges[1:][keep]

    def quantile(self, u, side: str = "left") -> np.ndarray:
        """Quantile function Q(u), the inverse of the piecewise-linear CDF.

        Linear within each non-empty bin, with a jump across runs of empty bins;
        Q(0) is the left edge of the first non-empty bin, Q(1) the right edge of
        the last one.  At a jump (u equal to the CDF between two non-empty bins
        separated by empty ones) ``side`` chooses the limit: ``"left"`` Q(u−), the
        right edge of the bin below; ``"right"`` Q(u+), the left edge of the bin above.

        Parameters
        ----------
        u : array_like
            Probabilities in [0, 1].
        side : {"left", "right"}
            Which limit at a jump.

        Returns
        -------
        ndarray
            Q(u), the shape of ``u``.
        """
        if side not in ("left", "right"):
            raise ValidationError(f"side must be 'left' or 'right', got {side!r}")
        uu = check_finite(as_float(u, "u", np.float64), "u")
        check_range(uu, "u", 0.0, 1.0)
        f_lo, f_hi, e_lo, e_hi = self._segments()
        j = np.clip(np.searchsorted(f_hi, uu, side=side), 0, f_hi.size - 1)
        frac = np.clip((uu - f_lo[j]) / (f_hi[j] - f_lo[j]), 0.0, 1.0)
        return e_lo[j] + frac * (e_hi[j] - e_lo[j])


def _as_histogram(h, name) -> Histogram:
    if not isinstance(h, Histogram):
        raise ValidationError(f"{name} must be a facestats.edit.Histogram, got {type(h).__name__}")
    return h


def histogram_distance(histogram: Histogram, target: Histogram) -> float:
    """Total-variation distance between two histograms, on the target's bins.

    ``histogram`` is re-binned onto ``target.edges`` through its piecewise-linear
    CDF; its mass outside the target's range counts as mismatch:
    ``D = ½ (Σ_k |p_k - q_k| + p_outside)``, in [0, 1] (0 for equal
    distributions, 1 for disjoint ones).  Scale-free, so distances of pyramid
    bands of different magnitude can be averaged.

    Parameters
    ----------
    histogram : Histogram
        The histogram to compare.
    target : Histogram
        The reference, whose bins are used.

    Returns
    -------
    float
        D in [0, 1].
    """
    h = _as_histogram(histogram, "histogram")
    g = _as_histogram(target, "target")
    f = np.interp(g.edges, h.edges, h.cdf)
    p = np.diff(f)
    outside = 1.0 - (f[-1] - f[0])
    return float(0.5 * (np.abs(p - g.pdf).sum() + outside))


def distance_floor(target: Histogram, n, reference=None) -> float:
    """Expected :func:`histogram_distance` to ``target`` of ``n`` values drawn from ``target``'s own distribution.

    The sampling floor of the distance: what a band of ``n`` coefficients that follows the target exactly shows
    through the noise of its own histogram.  The count in bin k of n independent draws is binomial (n, p_k), and
    de Moivre's closed form of its mean absolute deviation (de Moivre 1730; Diaconis & Zabell 1991, *Closed
    form summation for classical distributions: variations on a theme of de Moivre*, Statistical Science 6(3),
    284-302, §1) gives
    E|X_k − n p_k| = 2 ν (1 − p_k) P(X_k = ν) with ν = ⌊n p_k⌋ + 1, so the floor is
    ``½ Σ_k E|X_k − n p_k| / n``: about √(B_eff / (2π n)) for B_eff occupied bins when n is large, and → 1 as
    n → 0.  With ``reference`` (the count m the target itself was built from: another sample), the two
    samples' noise adds and n is replaced by the size of equal variance, n m / (n + m).

    Independent draws make this a lower bound for a pyramid band, whose neighbouring coefficients are
    correlated: on the bands of synthetic textures of known statistics the distance measured at n = 256 (256
    bins) is a little above this formula's (``bench_edit.bench_band_noise``, README *Texture transfer needs
    coefficients*).

    Parameters
    ----------
    target : Histogram
        The distribution and bins of the comparison.
    n : float
        Values compared (> 0).
    reference : float, optional
        Values the target itself was counted from (e.g. its ``total``); default None: an exact target.

    Returns
    -------
    float
        The expected distance, in [0, 1].
    """
    from scipy.stats import binom

    g = _as_histogram(target, "target")
    n = float(n)
    if not n > 0:
        raise ValidationError(f"n must be > 0, got {n!r}")
    if reference is not None:
        m = float(reference)
        if not m > 0:
            raise ValidationError(f"reference must be > 0, got {m!r}")
        n = n * m / (n + m)
    n = max(1, int(round(n)))
    p = g.pdf
    nu = np.floor(n * p) + 1
    mad = 2 * nu * (1 - p) * binom.pmf(nu, n, p)
    return float(0.5 * np.sum(mad) / n)


def interpolate_histograms(h0: Histogram, h1: Histogram, t: float, edges=None) -> Histogram:
    """Displacement interpolation of two histograms through their quantile functions.

    Matusik et al. 2005 interpolate histograms through the inverse cumulative
    distributions: ``Q_t(u) = (1 - t) Q_0(u) + t Q_1(u)``.  Every quantile (and
    the mean) moves linearly from ``h0`` (t = 0) to ``h1`` (t = 1); a mode moves
    instead of fading out and in, as it would with ``(1 - t) p_0 + t p_1``.

    The result is computed exactly for piecewise-uniform histograms: between
    consecutive knots of the two CDFs both quantile functions are linear, so
    ``Q_t`` maps each knot interval to a uniform segment; the segments are
    integrated over the output bins.

    Parameters
    ----------
    h0, h1 : Histogram
        End points.
    t : float
        Weight in [0, 1].
    edges : array_like, optional
        Output bin edges, covering the interpolated values.  Default:
        ``(1 - t) h0.edges + t h1.edges`` if both have the same number of bins
        (so t = 0 and t = 1 reproduce ``h0`` and ``h1``), otherwise
        ``max(bins)`` uniform bins over the interpolated range.

    Returns
    -------
    Histogram
        Counts summing to ``(1 - t) h0.total + t h1.total``.
    """
    h0 = _as_histogram(h0, "h0")
    h1 = _as_histogram(h1, "h1")
    t = check_t(t)
    if edges is None:
        if h0.bins == h1.bins:
            edges = (1 - t) * h0.edges + t * h1.edges
        else:
            lo = (1 - t) * h0.edges[0] + t * h1.edges[0]
            hi = (1 - t) * h0.edges[-1] + t * h1.edges[-1]
            edges = np.linspace(lo, hi, max(h0.bins, h1.bins) + 1)
    edges = check_finite(as_float(edges, "edges", np.float64), "edges")
    s0, s1 = h0._segments(), h1._segments()
    knots = np.unique(np.concatenate([s0[0], s0[1], s1[0], s1[1]]))
    u_lo, u_hi = knots[:-1], knots[1:]
    mid = 0.5 * (u_lo + u_hi)

    def _linear(seg, u_a, u_b):
        f_lo, f_hi, e_lo, e_hi = seg
        j = np.clip(np.searchsorted(f_hi, mid, side="left"), 0, f_hi.size - 1)
        slope = (e_hi[j] - e_lo[j]) / (f_hi[j] - f_lo[j])
        return e_lo[j] + (u_a - f_lo[j]) * slope, e_lo[j] + (u_b - f_lo[j]) * slope

    a0, b0 = _linear(s0, u_lo, u_hi)
    a1, b1 = _linear(s1, u_lo, u_hi)
    y_lo = (1 - t) * a0 + t * a1
    y_hi = (1 - t) * b0 + t * b1
    mass = u_hi - u_lo
    width = y_hi - y_lo
    lo, hi = float(y_lo.min()), float(y_hi.max())  # the interpolated distribution's support
    tol = 1e-9 * max(hi - lo, abs(lo), abs(hi), 1e-300)
    if edges[0] > lo + tol or edges[-1] < hi - tol:  # counts outside the edges would be lost
        raise ValidationError(
            f"edges must cover the interpolated values [{lo:.6g}, {hi:.6g}] (at t = {t:g}), got "
            f"[{edges[0]:.6g}, {edges[-1]:.6g}]: counts outside them would be lost"
        )
    e = edges[:, None]
    safe = np.where(width > 0, width, 1.0)
    frac = np.where(width > 0, np.clip((e - y_lo) / safe, 0.0, 1.0), (e >= y_lo).astype(float))
    cdf = frac @ mass
    total = (1 - t) * h0.total + t * h1.total
    counts = np.clip(np.diff(cdf), 0.0, None) * total
    return Histogram(edges, counts)


# --------------------------------------------------------------------------- O(N) matching


def _chunk_bins(x: np.ndarray, lo: float, scale: float, bins: int):
    """Chunks of the flat ``x`` as ``(start, p, i)``: ``p = (x - lo) · scale``, ``i = floor(p)`` clipped to bins."""
    lo_, scale_ = x.dtype.type(lo), x.dtype.type(scale)
    for s in range(0, x.size, _CHUNK):
        p = np.subtract(x[s : s + _CHUNK], lo_)
        p *= scale_
        i = p.astype(np.intp)
        np.clip(i, 0, bins - 1, out=i)
        yield s, p, i


def _bin_counts(x: np.ndarray, lo: float, scale: float, bins: int) -> np.ndarray:
    """Counts of the flat array ``x`` on ``bins`` uniform bins from ``lo`` (chunked)."""
    counts = np.zeros(bins, np.int64)
    for _, _, i in _chunk_bins(x, lo, scale, bins):
        counts += np.bincount(i, minlength=bins)
    return counts


def _apply_lut(x: np.ndarray, lo: float, scale: float, intercept, slope, out: np.ndarray) -> None:
    """``out = intercept[i] + slope[i] · p`` with ``p = (x - lo) · scale``, ``i = floor(p)`` (chunked)."""
    for s, p, i in _chunk_bins(x, lo, scale, slope.size):
        o = out[s : s + _CHUNK]
        np.take(slope, i, out=o)
        o *= p
        o += np.take(intercept, i)


def source_histogram(x: np.ndarray, source_bins: int) -> tuple[Histogram, float]:
    """The fine histogram of a flat array used to estimate F_source in :func:`match_histogram`.

    Parameters
    ----------
    x : numpy.ndarray, 1-D
        Finite values.
    source_bins : int
        Uniform bins over ``widen_range(min, max)``.

    Returns
    -------
    histogram : Histogram
    scale : float
        Bins per unit of ``x`` (``source_bins / (hi - lo)``).
    """
    lo, hi = widen_range(float(x.min()), float(x.max()))
    scale = source_bins / (hi - lo)
    counts = _bin_counts(x, lo, scale, source_bins)
    return Histogram(np.linspace(lo, hi, source_bins + 1), counts.astype(np.float64)), scale


def match_flat(x: np.ndarray, target: Histogram, t: float, source_bins: int, out: np.ndarray) -> float:
    """:func:`match_histogram` of a flat array into ``out``, without input checks.

    Parameters
    ----------
    x : numpy.ndarray, 1-D
        Finite values (float32 or float64).
    target : Histogram
    t : float
        Interpolation weight in [0, 1] (checked by the caller).
    source_bins : int
        Bins of the source histogram (:func:`source_histogram`).
    out : numpy.ndarray
        Output, shape and dtype of ``x`` (may be ``x`` itself).

    Returns
    -------
    float
        :func:`histogram_distance` of ``x`` to ``target`` before matching.
    """
    src, scale = source_histogram(x, source_bins)
    distance = histogram_distance(src, target)
    if not x.max() > x.min():
        # A constant source has no distribution to match: its CDF is a step, and Q(F(x)) would
        # land on an end of the target (its minimum or maximum, by rounding), outside the
        # target's typical values.  Defined instead: the constant moves to the target's mean
        # (t-weighted), which lies inside the target's range.
        out[...] = (1 - t) * x + t * target.mean()
        return distance
    # T linear within each source bin k, from Q(F(e_k)+) at its left edge to Q(F(e_k+1)−) at its right edge,
    # then (1 - t) x + t T.  The one-sided limits keep a bin's values inside the target bins its mass maps to:
    # evaluated at the edges alone, Q jumps across the target's empty bins inside a source bin, and a source
    # bin whose values all lie in one target bin spread over the gap before it (a sample matched to its own
    # histogram moved by up to 20 bins).
    f = np.clip(src.cdf, 0.0, 1.0)
    y_lo, y_hi = target.quantile(f[:-1], side="right"), target.quantile(f[1:], side="left")
    if t < 1.0:
        y_lo, y_hi = (1 - t) * src.edges[:-1] + t * y_lo, (1 - t) * src.edges[1:] + t * y_hi
    k = np.arange(source_bins)
    slope = y_hi - y_lo
    intercept = y_lo - k * slope
    _apply_lut(x, src.edges[0], scale, intercept.astype(x.dtype), slope.astype(x.dtype), out)
    np.clip(out, y_lo[0], y_hi[-1], out=out)  # T is monotone: rounding must not carry a value past its ends
    return distance


def match_histogram(values, target: Histogram, *, t: float = 1.0, source_bins: int = SOURCE_BINS) -> np.ndarray:
    """Map values so that their distribution follows a target histogram (O(N)).

    Heeger & Bergen 1995 (§3.3, Match-histogram): ``T(x) = Q_target(F_source(x))``
    with F_source the piecewise-linear CDF of a ``source_bins``-bin histogram of
    the values and Q_target the piecewise-linear quantile function of ``target``
    (:meth:`Histogram.quantile`).  T is evaluated at the source bin edges and
    applied by linear interpolation in two passes over the data, so the cost is
    linear in the number of values.  T is monotone: ranks are preserved.

    With ``t < 1`` each value moves the fraction ``t`` of the way,
    ``(1 - t) x + t T(x)``: the values then follow the displacement
    interpolation (:func:`interpolate_histograms`) between their own
    distribution and the target's; ``t = 0`` returns the values unchanged.

    Degenerate case: constant values have no distribution to match (F_source
    is a step, and T would send them to an end of the target's range); they
    move to the target's mean, ``(1 - t) x + t mean(target)``.

    Parameters
    ----------
    values : array_like
        Finite values, any shape; float32 stays float32.
    target : Histogram
        Target distribution.
    t : float
        Interpolation weight in [0, 1].
    source_bins : int
        Bins of the source histogram (default 16384).  The result's histogram on
        the target's bins matches the target up to the non-uniformity of the
        values inside a source bin.

    Returns
    -------
    numpy.ndarray
        Matched values, same shape.
    """
    target = _as_histogram(target, "target")
    t = check_t(t)
    x = check_finite(as_float(values, "values"), "values")
    if x.size == 0:
        raise ValidationError("values must not be empty")
    if not isinstance(source_bins, (int, np.integer)) or source_bins < 2:
        raise ValidationError(f"source_bins must be an int >= 2, got {source_bins!r}")
    if t == 0.0:
        return x.copy()
    flat = np.ascontiguousarray(x).ravel()
    out = np.empty_like(flat)
    match_flat(flat, target, t, int(source_bins), out)
    return out.reshape(x.shape)


def empirical_quantile(sorted_values: np.ndarray, ranks: np.ndarray, n: int) -> np.ndarray:
    """Quantiles of a sorted sample at the rank levels (rank + ½)/n, linear in between.

    The position in the target is ``(rank + ½) · m/n - ½`` (m = its size); for
    m = n it is ``rank`` exactly, so the result is a permutation of the target.

    Parameters
    ----------
    sorted_values : numpy.ndarray, shape (m,)
        The target sample, sorted, finite.
    ranks : numpy.ndarray, shape (n,)
        Ranks 0 … n-1 of the values to match (:func:`stable_ranks`).
    n : int
        Size of the matched sample.

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    m = sorted_values.size
    pos = np.clip((ranks + 0.5) * (m / n) - 0.5, 0.0, m - 1)
    i = np.floor(pos).astype(np.intp)
    frac = pos - i
    j = np.minimum(i + 1, m - 1)
    lo = sorted_values[i]
    return np.where(frac > 0, lo + frac * (sorted_values[j] - lo), lo)


def stable_ranks(x: np.ndarray) -> np.ndarray:
    """Ranks 0 … n-1 of the values of a 1-D array, ties broken by position.

    Parameters
    ----------
    x : numpy.ndarray, 1-D

    Returns
    -------
    numpy.ndarray of float64
    """
    order = np.argsort(x, kind="stable")
    ranks = np.empty(x.size, np.float64)
    ranks[order] = np.arange(x.size)
    return ranks


def match_values(values, target_values, *, t: float = 1.0) -> np.ndarray:
    """Exact histogram matching of values to the values of another sample.

    Each value is replaced by the target's empirical quantile at its own rank
    level ``u = (rank + ½)/n`` (ties broken by position, so the result is
    deterministic).  When both samples have the same size the result is a
    permutation of ``target_values``: it has exactly the target's distribution.
    Otherwise the target quantile is interpolated linearly between order
    statistics.  With ``t < 1`` each value moves the fraction ``t`` of the way,
    ``(1 - t) x + t Q_target(u)``: the sample then follows the displacement
    interpolation of Matusik et al. 2005 between the two empirical
    distributions.  Cost O(n log n + m log m).

    Parameters
    ----------
    values, target_values : array_like
        Finite values (any shape; the target is flattened).
    t : float
        Interpolation weight in [0, 1]; 0 returns ``values`` unchanged.

    Returns
    -------
    numpy.ndarray
        Same shape as ``values``, in the float dtype of ``values``.
    """
    t = check_t(t)
    x = check_finite(as_float(values, "values"), "values")
    y = check_finite(as_float(target_values, "target_values"), "target_values").ravel()
    if x.size == 0 or y.size == 0:
        raise ValidationError("values and target_values must not be empty")
    flat = x.ravel().astype(np.float64)
    q = empirical_quantile(np.sort(y.astype(np.float64)), stable_ranks(flat), flat.size)
    out = q if t == 1.0 else (1 - t) * flat + t * q
    return out.astype(x.dtype).reshape(x.shape)
