"""Camera response recovery and radiance merging for cameras with a non-linear response (Debevec & Malik 1997).

A photograph records, at each pixel i of exposure j, the code Z_ij = f(E_i Δt_j)
of an unknown monotonic response f applied to the exposure X = E·Δt (irradiance
E times exposure time Δt).  With g = ln f⁻¹ (Debevec & Malik 1997, §2.1, eq. 2):

    g(Z_ij) = ln E_i + ln Δt_j.

**Recovery** (:func:`recover_response`, Debevec & Malik 1997 §2.1 eq. 5: the objective
of eq. 3 with the hat weighting of eq. 4 in both terms) minimises, per channel,

    O = Σ_ij [w(Z_ij)(g(Z_ij) − ln E_i − ln Δt_j)]² + λ² Σ_z [w(z) g''(z)]²,

with g''(z) = g(z−1) − 2g(z) + g(z+1) and the scale fixed by g(levels/2) = 0
(g(128) = 0 for 8-bit input).  λ enters as the multiplier of the smoothness rows,
as in the paper's reference code ``gsolve`` and in OpenCV's ``CalibrateDebevec``
(λ² in the objective; the paper's eq. 3 and 5 write the same term with its λ = our λ²).
The unknowns ln E_i are eliminated exactly (Schur complement: each pixel's
optimal ln E_i is the weighted mean of g(Z_ij) − ln Δt_j), leaving a K × K system
in g alone, so the solve costs the same for any number of sampled pixels.  For
more than 1,024 levels (10- to 16-bit data) g is represented by K = 1,024 knots
with linear interpolation between them, and the smoothness rows are scaled so that
they approximate the same per-level penalty (Δ^(−3/2)·second difference of knots
Δ levels apart).

**Weights**: w(z) = z − Z_min for z ≤ (Z_min + Z_max)/2, Z_max − z above (eq. 4):
zero at both clipping ends, so codes 0 and 2^bits − 1 (or the black and white
levels below) never inform g or E.

**Black level** (``black_level``, default 0): a sensor that adds a pedestal of b
DN to every reading (so that noise around zero signal is recorded, not clipped)
has f⁻¹(z) ∝ z − b, and g(z) = ln(z − b) + const plunges towards −∞ as z → b.
With Z_min = 0 the codes just above the pedestal (z − b of a few DN, a relative
noise of tens of per cent) weigh as much as z − 0 ≈ b and the smoothness term
cannot follow g's plunge: on a 12-bit linear sensor with b = 256 the recovered g
and the merge were biased by 6-10 % over two decades of radiance.  Passing
``black_level = b`` takes Z_min = b in eq. 4 (zero weight at and below the
pedestal, rising from it), and recovers g on the codes b..2^bits − 1 only (its
knots span that range; codes at and below b take g(b), extrapolated by the
smoothness term: the merge gives them no weight, and an all-dark pixel gets the
noise-floor bound below).  Merges and :func:`exposure_agreement` must then be
given the same ``black_level``.

**White level** (``white_level``, default None: the top code 2^bits − 1): a sensor
whose readings clip below the top code (raw-derived 16-bit files of a 14-bit sensor
that saturate at, say, 15,000 of 16,383 DN) records every brighter pixel as a code
at or near the white level W.  With Z_max = 2^bits − 1 those codes weigh
Z_max − z > 0, so clipped pixels count as good data: they pull g(W) up towards the
exposures of pixels far brighter than W (the smoothness term carries the distortion
down the curve) and enter the merge with the wrong radiance: on a synthetic linear
14-bit bracket clipping at 15,000 (four exposures 1/60-1 s) the merge was biased by
+8.6, +7.7 and +17 % over the decades 10²-10³, 10³-10⁴ and 10⁴-10⁵ DN/s, and pixels
clipped in every exposure came out as data; with the white level, by at most 0.24 %.
Passing ``white_level = W`` ends the hat there, Z_max = W in eq. 4 (zero weight at
and above W, falling towards it), and recovers g on the codes black..W only (codes
above W take g(W), which carries no weight); W must lie in (2^bits / 2, 2^bits − 1]
(g is pinned at 2^bits / 2, which must lie between the black and the white level). A
pixel with no usable exposure that is at or above W in one merges to NaN (saturated).  Merges and
:func:`exposure_agreement` must then be given the same ``white_level``.

**Sample selection** (``samples``): the paper needs N(P − 1) > Z_max − Z_min
sample pixels spread over the code range (§2.1).  Two documented choices, N =
max(512, ⌈4K/(P − 1)⌉) by default (at most the number of pixels):

* ``"histogram"`` (default): Grossberg & Nayar 2003 (*Determining the camera
  response from images: what is knowable?*, §5): the codes at N equal quantiles
  of each exposure's histogram form "virtual pixels" (the response is monotonic,
  so ranks are preserved); it needs no registration of the frames and ignores
  edges and compression noise.  On a synthetic 8-bit bracket it recovers g within
  0.005 (ln units) against 0.01 for the stratified choice and 0.02 for OpenCV's
  70 random pixels; on a real JPEG bracket it lands closest to OpenCV's curve.
* ``"stratified"``: the code range of the median-time exposure is cut into N
  equal bins and from each the pixel of least local variation is taken
  (:func:`stratified_samples`).

An integer array of flat pixel indices picks the pixels explicitly.

**Merge** (:func:`merge_photographs`, Debevec & Malik 1997 §2.2 eq. 6):

    ln E_i = Σ_j w(Z_ij)(g(Z_ij) − ln Δt_j) / Σ_j w(Z_ij).

A pixel with no usable exposure (zero total weight: every code dark or clipped) is
NaN when it is clipped (at or above the white level) in any exposure: unknown
radiance, above what clips there (before 2026-12-06 only when clipped in every
exposure, so a pixel dark in a short exposure and clipped in a long one took the
clipped code's estimate, a lower bound read as the value; a red team); dark in every
exposure, it takes the estimate of its longest exposure g(Z) − ln Δt (an upper bound
at the noise floor).

The existing linear-raw merge with a noise model is
:func:`facestats.acquire.hdr.merge_exposures`; this module is for cameras whose
response is unknown or non-linear.  :class:`ResponseCurve` is a known non-linear
camera (the ITU-R BT.709 opto-electronic transfer function on a shot- and
read-noise sensor) with which the simulator writes photographs whose true g is
known.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.acquire.merge_kernel import log_radiance
from facestats.core.validate import as_finite, as_scalar, check_choice, check_integer
from facestats.errors import ValidationError

__all__ = [
    "hat_weights",
    "check_black_level",
    "check_white_level",
    "stratified_samples",
    "histogram_samples",
    "recover_response",
    "merge_photographs",
    "exposure_agreement",
    "ResponseCurve",
    "MAX_KNOTS",
    "WELL_EXPOSED",
    "AGREEMENT_SAMPLES",
    "MIN_EXPOSURE_S",
    "MAX_SMOOTHNESS",
    "check_rising",
]

#: Largest number of unknowns g is solved for; finer codes are interpolated (module docstring).
MAX_KNOTS = 1024
#: A code is well exposed (:func:`exposure_agreement`) when its hat weight is at least this fraction of the peak.
WELL_EXPOSED = 0.25
#: Shortest exposure time accepted, s: a picosecond, far below any shutter (a subnormal time such as 1e-320 was
#: accepted and its reciprocal printed as infinity).
MIN_EXPOSURE_S = 1e-12
#: Samples (pixel and channel) above which :func:`exposure_agreement` takes its statistics on a regular grid of
#: pixels: a diagnostic, it took 37 bytes a sample, 2.7 GB beside a 24-megapixel bracket.
AGREEMENT_SAMPLES = 1 << 22
#: Largest smoothness λ :func:`recover_response` accepts.  Far below it g is already the straight line the term
#: tends to (an 8-bit bracket of 512 samples reaches it by λ ≈ 1e4); beyond it the solve loses precision (at λ =
#: 1e8 the same bracket's exposures disagree 5 times more, at 1e10 g is flat, at 1e200 it overflows).
MAX_SMOOTHNESS = 1e6
#: How far g may fall below an earlier code's value (its largest drawdown), as a fraction of its range, and still
#: count as rising: the noise of codes few samples reach (a 16-bit gamma camera's darkest codes under 2-5 e⁻ of read
#: noise dip by 0.06 % of the range) and the solve's rounding where the smoothness term alone decides g, not data.
#: Times that do not match the frames make g fall by tens of per cent of its range.
FALL_TOLERANCE = 0.01
#: The codes the data of :func:`recover_response` reach: between these quantiles of the usable sampled codes (the
#: rarest dark and bright codes are reached by a few noisy samples, where g is as loose as where none reach it).
#: Beyond them g is held monotonic.
SUPPORT_QUANTILES = (0.01, 0.99)


def check_rising(response, black_level: int = 0, name: str = "response") -> np.ndarray:
    """``response`` g (levels, C) if it rises with the code above ``black_level``; else a :class:`ValidationError`.

    Debevec & Malik 1997 §2.1 assume the sensor's response f is monotonic, so g = ln f⁻¹ only rises: a g
    that falls below an earlier code's value by more than :data:`FALL_TOLERANCE` of its range was recovered from
    exposure times that do not match the frames (e.g. an auto-bracket shot 0, −2, +2 EV with its times given
    in ascending order), from frames that differ in more than their exposure time, from a moving scene, from a
    sensor that clips below the top code taken for data (no white level), or with too little smoothness for the
    data's noise.  Smaller dips (noise at codes few samples reach) are kept.  Before 2026-12-06 each step from a
    code to the next was held to 0.1 % of the range: a 16-bit gamma camera's noise floor failed that, while a fall
    spread over many steps (a factor 4 over 2,000 codes of a clipping sensor) passed it.

    Parameters
    ----------
    response : ndarray, shape (levels, C) or (levels,)
        g per code (and channel).
    black_level : int
        Codes at and below it are not checked (g is constant there; code 0 may be −inf).
    name : str
        What ``response`` is, for the message.

    Returns
    -------
    ndarray
        ``response``, as float64.
    """
    g = np.asarray(response, np.float64)
    g2 = g[:, None] if g.ndim == 1 else g
    first = int(black_level) + 1
    spans = np.maximum(np.ptp(g2[first:], axis=0), 1e-300)  # g's range above the pedestal, per channel
    for c in range(g2.shape[1]):
        seg = g2[first:, c]  # code 0 may be -inf; below the pedestal g is constant
        if seg.size < 2:
            continue
        drawdown = np.maximum.accumulate(seg) - seg  # how far g lies below its largest earlier value
        if drawdown.max() <= FALL_TOLERANCE * spans[c]:
            continue
        z = int(np.argmax(drawdown)) + first  # the deepest point of the fall, and the code it fell from
        peak = int(np.argmax(seg[: z - first + 1])) + first
        steps = int((np.diff(seg) < 0).sum())
        raise ValidationError(
            f"{name} must rise with the code (a camera's response is monotonic, Debevec & Malik 1997 §2.1), got a g "
            f"that falls at {steps} of {seg.size - 1} steps in channel {c}, by {drawdown.max():.4g} at most (g({z}) "
            f"= {g2[z, c]:.4g} < g({peak}) = {g2[peak, c]:.4g}; {FALL_TOLERANCE:.0%} of its range is allowed): the "
            "exposure times likely do not match the frames (their order, e.g. an auto-bracket of 0, -2, +2 EV), or "
            "the frames differ in more than the exposure time (ISO, aperture, a moving scene), or the sensor "
            "clips below the top code (give its white level), or the smoothness is too small for the frames' noise"
        )
    return g


def hat_weights(levels: int, black_level: int = 0, white_level: int | None = None) -> np.ndarray:
    """Debevec & Malik 1997 eq. 4 weights w(z) for codes 0..levels−1, float64, Z_min = black, Z_max = white level.

    w(z) = z − Z_min for z ≤ (Z_min + Z_max)/2, Z_max − z above: 0 at and below the black level and at and above
    the white level, peak mid-way (module docstring).

    Parameters
    ----------
    levels : int
        Number of codes, 2^bits.
    black_level : int
        Z_min in DN (the sensor's pedestal; 0: none).
    white_level : int, optional
        Z_max in DN, the code at which the sensor clips; default None, the top code levels − 1.

    Returns
    -------
    ndarray of float64, shape (levels,)
        w(z) per code.
    """
    z = np.arange(levels, dtype=np.float64)
    low = float(black_level)
    top = float(levels - 1 if white_level is None else white_level)
    return np.maximum(np.where(z <= (low + top) / 2, z - low, top - z), 0.0)


def check_black_level(black_level, levels: int) -> int:
    """``black_level`` as an int, checked: a code in [0, levels/2) (g is pinned at levels/2, above it).

    Parameters
    ----------
    black_level : int
        The sensor's pedestal in DN (module docstring).
    levels : int
        Number of codes, 2**bits.

    Returns
    -------
    int

    Raises
    ------
    ValidationError
        Not an integer, or outside [0, levels/2 − 1].
    """
    return check_integer(black_level, "black_level", 0, levels // 2 - 1)


def check_white_level(white_level, levels: int, black_level: int = 0) -> int:
    """``white_level`` as an int (levels − 1 for None), checked: a code in (levels/2, levels − 1], DN.

    The white level is Z_max of Debevec & Malik 1997 eq. 4 (module docstring): the code at and above which the
    sensor clips.  g is pinned at levels/2, so that code must lie strictly between the black level (below levels/2,
    :func:`check_black_level`) and the white level; ``black_level`` is the hat's Z_min, which then lies below it.

    Parameters
    ----------
    white_level : int or None
        The clipping code in DN; None for the top code.
    levels : int
        Number of codes, 2**bits.
    black_level : int
        The pedestal in DN; the white level must also exceed it.

    Returns
    -------
    int
        The white level in DN.

    Raises
    ------
    ValidationError
        Naming ``white_level`` and the value: not an integer, at or below levels/2 (or the black level), or above
        the top code.
    """
    if white_level is None:
        return levels - 1
    low = max(levels // 2, int(black_level)) + 1
    return check_integer(white_level, "white_level", low, levels - 1)


# -- input checks --------------------------------------------------------------------------------
def _check_stack(images, exposure_times, bits, name="images"):
    """Validated ``(codes (P, ...), times (P,), bits, order)`` sorted by exposure time.

    ``order[k]`` is the caller's index of the k-th sorted image (for messages).
    """
    seq = list(images)
    t = as_finite(exposure_times, "exposure_times", MIN_EXPOSURE_S, None, unit="s", dtype=np.float64)
    if t.ndim != 1 or t.size != len(seq):
        raise ValidationError(f"exposure_times must hold one time per image ({len(seq)}), got shape {t.shape}")
    if np.unique(t).size < 2:
        raise ValidationError(
            f"{name} must hold at least two distinct exposure times to recover or merge a response, got {t.tolist()}"
        )
    arrays = [np.asarray(a) for a in seq]
    shapes = {a.shape for a in arrays}
    if len(shapes) != 1:
        raise ValidationError(f"{name} must all have one shape, got shapes {sorted(shapes)}")
    shape = arrays[0].shape
    if len(shape) < 2:
        raise ValidationError(f"{name} must be (H, W, channel) arrays, got shape {shape}")
    kinds = {a.dtype for a in arrays}
    if len(kinds) != 1 or next(iter(kinds)).kind not in "ui":
        raise ValidationError(f"{name} must be integer code images of one dtype, got dtypes {sorted(map(str, kinds))}")
    dtype = next(iter(kinds))
    if bits is None:
        bits = 8 if dtype.itemsize == 1 else 16
    bits = check_integer(bits, "bits", 1, 16)
    if dtype.kind == "u" and np.iinfo(dtype).max <= 2**bits - 1:
        arrays_to_check = []  # every value of the dtype is a valid code
    else:
        arrays_to_check = arrays
    for j, a in enumerate(arrays_to_check):
        lo, hi = int(a.min(initial=0)), int(a.max(initial=0))
        if lo < 0 or hi > 2**bits - 1:
            raise ValidationError(
                f"{name}[{j}] must hold {bits}-bit codes in [0, {2**bits - 1}], got values in [{lo}, {hi}] "
                "(wrong bit depth?)"
            )
    order = np.argsort(t, kind="stable")
    return [arrays[j] for j in order], t[order], bits, order


# -- sample selection ---------------------------------------------------------------------------------
def stratified_samples(reference, n: int, levels: int, seed: int = 0) -> np.ndarray:
    """Flat indices of ``n`` pixels whose codes in ``reference`` cover the code range (module docstring).

    The code range is cut into ``n`` equal bins; from each non-empty bin the pixel
    whose 3 × 3 neighbourhood varies least is taken (Debevec & Malik 1997 §2.1 pick
    pixels "from areas of low intensity variance", which keeps edges, where frames
    misregister or compress badly, out of the fit), ties broken by a seeded random
    order.  Missing picks are filled with random pixels.

    Parameters
    ----------
    reference : ndarray of int, shape (H, W) or (npix,)
        Codes of one channel of the reference (median-time) exposure.
    n : int
        Number of pixels (at most ``npix``).
    levels : int
        Number of codes (2^bits).
    seed : int
        Seed of the random tie-breaking order.

    Returns
    -------
    ndarray of int, shape (n,)
        Flat pixel indices, sorted.
    """
    ref = np.asarray(reference)
    flat = ref.reshape(-1).astype(np.int64)
    n = min(int(n), flat.size)
    rng = np.random.default_rng(seed)
    if ref.ndim == 2 and min(ref.shape) >= 3:
        from scipy.ndimage import maximum_filter, minimum_filter

        spread = maximum_filter(ref, 3, mode="nearest").astype(np.int64) - minimum_filter(ref, 3, mode="nearest")
        spread = spread.reshape(-1)
    else:
        spread = np.zeros(flat.size, np.int64)
    bins = (flat * n) // levels  # n equal bins over the code range
    order = np.lexsort((rng.permutation(flat.size), spread, bins))  # by bin, then flatness, then at random
    _, first = np.unique(bins[order], return_index=True)
    chosen = order[first]
    if chosen.size < n:  # fill with random pixels not yet chosen
        rest = np.setdiff1d(np.arange(flat.size), chosen, assume_unique=True)
        chosen = np.concatenate([chosen, rng.permutation(rest)[: n - chosen.size]])
    return np.sort(chosen)


def histogram_samples(codes, n: int) -> np.ndarray:
    """Grossberg & Nayar 2003 §5 "virtual pixels": codes at ``n`` equal quantiles of each exposure, (n, P).

    The quantile (k + ½)/n of exposure j is
    the code of rank ⌊(k + ½) npix / n⌋ in its cumulative histogram, so row k pairs
    codes of equal rank (an O(npix) histogram per exposure, no sort).

    Parameters
    ----------
    codes : array_like of non-negative int, shape (P, npix) or (P, ...)
        One channel's codes per exposure (trailing axes are flattened to npix).
    n : int
        Number of quantiles (virtual pixels).

    Returns
    -------
    ndarray of int64, shape (n, P)
        Row k: the code at quantile (k + ½)/n of each exposure.
    """
    c = np.asarray(codes).reshape(np.shape(codes)[0], -1)
    npix = c.shape[1]
    ranks = np.clip(((np.arange(n) + 0.5) / n * npix).astype(np.int64), 0, npix - 1)
    out = np.empty((n, c.shape[0]), np.int64)
    for j, row in enumerate(c):  # loop over exposures (a handful)
        cum = np.cumsum(np.bincount(row.astype(np.int64, copy=False)))
        out[:, j] = np.searchsorted(cum, ranks, side="right")
    return out


def _sample_codes(stack, channel, samples, levels, n):
    """(N, P) codes of one channel at the selected samples."""
    flat = np.stack([a[..., channel].reshape(-1) for a in stack])  # (P, npix)
    if isinstance(samples, str):
        if samples == "histogram":
            return histogram_samples(flat, n)
        ref = stack[(len(stack) - 1) // 2][..., channel]
        return flat[:, stratified_samples(ref, n, levels, seed=channel)].T
    idx = np.asarray(samples)
    if idx.dtype.kind not in "iu" or idx.ndim != 1 or idx.size < 2 or idx.min() < 0 or idx.max() >= flat.shape[1]:
        raise ValidationError(
            f"samples must be 'stratified', 'histogram' or a 1-D array of flat pixel indices in [0, {flat.shape[1]}), "
            f"got {samples!r}"
        )
    return flat[:, idx].T


# -- recovery ---------------------------------------------------------------------------------------------
def _interpolation(z, levels, knots, black_level=0, white_level=None):
    """Knot index k0 (int) and weight a of code(s) z: g(z) = (1 − a) g[k0] + a g[k0 + 1].

    The knots span the codes ``black_level``..``white_level`` (DN; default levels − 1); codes below take
    g(black_level), codes above g(white_level).
    """
    top = levels - 1 if white_level is None else white_level
    x = np.clip(np.asarray(z, np.float64), black_level, top) - black_level
    x *= (knots - 1) / (top - black_level)
    k0 = np.clip(np.floor(x).astype(np.int64), 0, knots - 2)
    return k0, x - k0


def _solve_channel(codes, log_t, levels, smoothness, black_level=0, white_level=None):
    """g at every code of one channel from (N, P) sampled codes (module docstring: reduced normal equations).

    The knots span the codes ``black_level``..``white_level`` (DN, default levels − 1): the non-zero span of the
    hat weights of Debevec & Malik 1997 eq. 4.
    """
    from scipy import sparse

    top = levels - 1 if white_level is None else white_level
    knots = min(top - black_level + 1, MAX_KNOTS)
    w_level = hat_weights(levels, black_level, top)
    n, p = codes.shape
    w = w_level[codes]  # (N, P)
    k0, a = _interpolation(codes, levels, knots, black_level, top)
    rows = np.repeat(np.arange(n * p), 2)
    cols = np.stack([k0, k0 + 1], -1).reshape(-1)
    bvals = np.stack([1 - a, a], -1).reshape(-1)
    wr = np.repeat(w.reshape(-1), 2)
    a_mat = sparse.csr_matrix((wr * bvals, (rows, cols)), shape=(n * p, knots))
    c_mat = sparse.csr_matrix((wr**2 * bvals, (rows // p, cols)), shape=(n, knots))  # C_i = Σ_j w² B_ij
    wsum = np.sum(w**2, axis=1)
    s = np.sum(w**2 * log_t[None, :], axis=1)  # Σ_j w² ln Δt_j
    inv = np.where(wsum > 0, 1 / np.where(wsum > 0, wsum, 1), 0)
    h = (a_mat.T @ a_mat).toarray() - (c_mat.T @ sparse.diags(inv) @ c_mat).toarray()
    b = a_mat.T @ (w.reshape(-1) * np.tile(log_t, n)) - c_mat.T @ (inv * s)
    # Smoothness rows λ w(z_k) (g[k−1] − 2g[k] + g[k+1]) Δ^(−3/2) on the interior knots.
    step = (top - black_level) / (knots - 1)
    k = np.arange(1, knots - 1)
    wk = np.interp(black_level + k * step, np.arange(levels), w_level)
    d = sparse.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(knots - 2, knots))
    d = sparse.diags(smoothness * wk * step**-1.5) @ d
    h += (d.T @ d).toarray()
    # Scale: g(levels/2) = 0 (one pinning row; the rest of the objective is shift-invariant).
    km, am = _interpolation(levels // 2, levels, knots, black_level, top)
    e = np.zeros(knots)
    e[km], e[km + 1] = 1 - am, am
    h += np.outer(e, e)
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):  # a K ≤ 1024 system: threads cost more than they save
        try:
            g = np.linalg.solve(h, b)
        except np.linalg.LinAlgError:
            g = np.linalg.lstsq(h, b, rcond=None)[0]
    kz, az = _interpolation(np.arange(levels), levels, knots, black_level, top)
    out = (1 - az) * g[kz] + az * g[kz + 1]
    return out - out[levels // 2]


#: Most histogram samples :func:`recover_response` takes (its least-squares system is about 0.6 kB per sample
#: and exposure).
MAX_SAMPLES = 1_000_000


def recover_response(
    images,
    exposure_times,
    *,
    smoothness=None,
    samples=None,
    bits=None,
    black_level: int = 0,
    white_level: int | None = None,
) -> np.ndarray:
    """Debevec & Malik 1997 camera response g = ln f⁻¹ per channel from a bracket of photographs.

    Parameters
    ----------
    images : sequence of ndarray of int, each (H, W, C)
        The same static scene at each exposure (8-bit: uint8; 10- to 16-bit: uint16).
    exposure_times : array_like, shape (P,)
        Exposure times Δt_j in seconds, in any order; at least two distinct.
    smoothness : float, optional
        λ in [0, :data:`MAX_SMOOTHNESS`], the multiplier of the smoothness rows (module
        docstring; OpenCV's and ``gsolve``'s ``lambda``).  Default 10·sqrt(N/70): OpenCV's
        default trade-off (λ = 10 at 70 samples) kept as the number of samples N grows.
    samples : {"stratified", "histogram"} or int or ndarray of int, optional
        Sample selection (module docstring); an int is the number of histogram
        samples; default ``"histogram"`` with max(512, ⌈4K/(P − 1)⌉) samples.
    bits : int, optional
        Bit depth of the codes; default 8 for uint8 input, 16 for uint16 (pass 12
        for 12-bit data stored in 16-bit files).
    black_level : int
        The sensor's pedestal in DN, in [0, 2**bits / 2): Z_min of the weights (module
        docstring); merge with the same value.
    white_level : int, optional
        The code in DN at and above which the sensor clips, in (2**bits / 2, 2**bits − 1]: Z_max of
        the weights of Debevec & Malik 1997 eq. 4 (module docstring); default None, the top code
        2**bits − 1.  Merge with the same value.

    Returns
    -------
    ndarray of float64, shape (2**bits, C)
        g(z) in natural-log exposure (ln of seconds × radiance units), g(2**bits / 2) = 0
        (g(128) = 0 for 8-bit input); codes at and below ``black_level`` take g(black_level),
        codes at and above ``white_level`` g(white_level).  Below and above the codes the data reach
        (:data:`SUPPORT_QUANTILES` of the usable sampled codes) g is held monotonic: no lower code gets a
        higher g than the lowest reached code's, no higher code a lower g than the highest's (there the
        smoothness term alone shapes it, and may make it fall).

    Raises
    ------
    ValidationError
        A recovered g that falls with the code (:func:`check_rising`: times that do not match the
        frames); fewer than two distinct exposure times, codes beyond ``bits``, images of
        different shapes or non-integer images; a highest code below 2**(bits − 2), a
        quarter of the full scale (codes of fewer bits in wider files, e.g. 12-bit codes
        in 16-bit PNGs read with the default ``bits``, or a bracket without bright
        exposures: g would be extrapolated over most of the codes; the message names the
        bit depth the codes fit in); or no usable samples in a channel
        (no sampled pixel has a code of non-zero weight, strictly between the black level and
        the white level (0 and 2**bits − 1 by default), in at least two exposures — e.g. one all-dark and one
        all-saturated frame): g would be left at 0.  The message names each frame
        with its exposure time and its fractions of dark and saturated pixels.
    """
    stack, t, bits, order = _check_stack(images, exposure_times, bits)
    levels = 2**bits
    black_level = check_black_level(black_level, levels)
    white_level = check_white_level(white_level, levels, black_level)
    _check_full_scale(stack, bits)
    knots = min(white_level - black_level + 1, MAX_KNOTS)
    p = len(stack)
    npix = int(np.prod(stack[0].shape[:-1])) if stack[0].ndim == 3 else int(np.prod(stack[0].shape))
    default_n = min(npix, max(512, int(np.ceil(4 * knots / (p - 1)))))
    if samples is None:
        samples, n = "histogram", default_n
    elif isinstance(samples, str):
        check_choice(samples, "samples", ("stratified", "histogram"))
        n = default_n
    elif isinstance(samples, (int, np.integer)) and not isinstance(samples, bool):
        # The least-squares system grows with N × P: beyond the pixels there is nothing new to sample, and past
        # MAX_SAMPLES it would need gigabytes.
        n = check_integer(samples, "samples", 2, min(npix, MAX_SAMPLES))
        samples = "histogram"
    else:
        n = None
    if smoothness is None:
        n_eff = n if n is not None else np.asarray(samples).size
        smoothness = 10.0 * np.sqrt(n_eff / 70.0)
    lam = as_scalar(smoothness, "smoothness", 0, MAX_SMOOTHNESS)  # above the range the solve overflows
    if stack[0].ndim == 2:
        stack = [a[..., None] for a in stack]
    log_t = np.log(t)
    out = np.empty((levels, stack[0].shape[-1]))
    usable = hat_weights(levels, black_level, white_level) > 0
    for ch in range(stack[0].shape[-1]):  # loop over channels (3), vectorised over samples
        codes = _sample_codes(stack, ch, samples, levels, n).astype(np.int64)
        if not np.any(np.count_nonzero(usable[codes], axis=1) >= 2):  # one usable exposure: ln E absorbs it
            raise ValidationError(
                _no_samples_message(stack, t, order, ch, levels, codes.shape[0], black_level, white_level)
            )
        out[:, ch] = _solve_channel(codes, log_t, levels, lam, black_level, white_level)
        reached = codes[usable[codes]]  # the codes the data reach
        lo, hi = np.quantile(reached, SUPPORT_QUANTILES, method="inverted_cdf")
        # Beyond the codes the data reach only the smoothness term shapes g, and it may fall there (a 16-bit gamma
        # camera's darkest codes): g is monotonic (§2.1), so it is held at least as low below them, and at least
        # as high above them, as at their ends.
        below = out[black_level + 1 : lo + 1, ch]
        out[black_level + 1 : lo + 1, ch] = np.minimum.accumulate(below[::-1])[::-1]
        out[hi:, ch] = np.maximum.accumulate(out[hi:, ch])
    return check_rising(out, black_level, "the recovered response")


def _check_full_scale(stack, bits) -> None:
    """Raise unless the bracket's highest code reaches a quarter of the full scale 2**bits − 1 (recover_response)."""
    top = max(int(a.max(initial=0)) for a in stack)
    if top >= 2 ** (bits - 2):
        return
    fit = max(top.bit_length(), 1)
    raise ValidationError(
        f"bits must be the bit depth of the codes, got {bits} while the images' highest code is {top}, below a "
        f"quarter of the full scale {2**bits - 1}: if the camera records {fit}-bit codes (stored in {bits}-bit "
        f"files), pass bits={fit} (--bits {fit}); if it records {bits}-bit codes, add longer exposures until the "
        "brightest frame nears the top code"
    )


def _no_samples_message(stack, t, order, channel, levels, n, black_level=0, white_level=None):
    """Why channel ``channel`` of a bracket informs no response: each frame's dark and saturated fractions.

    Dark: codes at or below ``black_level``; saturated: codes at or above ``white_level`` (DN, default the top code
    levels − 1), the zero-weight ends of Debevec & Malik 1997 eq. 4.
    """
    white = levels - 1 if white_level is None else int(white_level)
    frames = []
    at = "0" if black_level == 0 else f"or below the black level {black_level}"
    top = f"{white}" if white == levels - 1 else f"or above the white level {white}"
    for k, a in enumerate(stack):  # loop over exposures (a handful), vectorised over pixels
        c = a[..., channel]
        dark, sat = np.count_nonzero(c <= black_level) / c.size, np.count_nonzero(c >= white) / c.size
        frames.append(f"images[{order[k]}] (exposure {t[k]:.6g} s): {dark:.1%} of pixels at {at}, {sat:.1%} at {top}")
    return (
        f"images hold no usable samples in channel {channel}: none of the {n} sampled pixels has a code strictly "
        f"between {black_level} and {white} (non-zero weight) in at least two exposures, so the response g "
        f"cannot be recovered; {'; '.join(frames)} (add exposures between these, or check the frames)"
    )


# -- merge ---------------------------------------------------------------------------------------------------
def _check_response(response, channels):
    g = np.asarray(response, np.float64)
    if g.ndim == 1:
        g = g[:, None]
    levels = g.shape[0]
    if g.ndim != 2 or levels < 2 or levels & (levels - 1) or g.shape[1] not in (1, channels):
        raise ValidationError(
            f"response must be g as an array (levels, channel) with levels a power of two and {channels} or 1 "
            f"channel(s), got shape {np.shape(response)}"
        )
    if not np.all(np.isfinite(g[1:])):
        raise ValidationError("response must be finite (code 0 may be -inf), got NaN or inf")
    return g


def merge_photographs(
    images,
    exposure_times,
    response,
    *,
    weighting: str = "hat",
    return_weight: bool = False,
    backend: str = "auto",
    black_level: int = 0,
    white_level: int | None = None,
):
    """Radiance from a bracket of non-linear photographs, Debevec & Malik 1997 eq. 6 (module docstring).

    Parameters
    ----------
    images : sequence of ndarray of int, each (..., C), or (H, W) with a one-channel ``response``
        Codes of each exposure (e.g. (H, W, 3), or (N, 3) samples); their bit depth is that of ``response``.
        With a one-channel response, (H, W) frames are one channel (before 2026-12-06 their width was taken
        for the channels, and the tables grew with it).
    exposure_times : array_like, shape (P,)
        Seconds, any order, at least two distinct.
    response : ndarray, shape (levels, C) or (levels,)
        g = ln f⁻¹ per channel (:func:`recover_response`, or a calibration file).
    weighting : {"hat", "hat_time"}
        ``"hat"``: Debevec & Malik's w(z) (eq. 4, as OpenCV's ``MergeDebevec``);
        ``"hat_time"``: w(z)·Δt_j — still zero at the clipping ends, and
        proportional to the inverse variance of ln(E Δt_j) of a shot-noise-limited
        pixel (Var ln X ≈ 1/X for X electrons ∝ E Δt_j), so long exposures count
        more where both are usable (the photograph ingest uses it).
    return_weight : bool
        Also return the total weight Σ_j w(Z_ij) per pixel and channel (0 = no usable exposure).
    backend : {"auto", "numba", "numpy"}
        The look-ups compiled (default where numba is installed) or in numpy
        (:mod:`facestats.acquire.merge_kernel`); both give the same bits.
    black_level : int
        The sensor's pedestal in DN (module docstring), the one ``response`` was recovered
        with: codes at and below it get no weight.
    white_level : int, optional
        The code in DN at and above which the sensor clips (module docstring), the one
        ``response`` was recovered with: Z_max of Debevec & Malik 1997 eq. 4, codes at and above
        it get no weight; default None, the top code levels − 1.

    Returns
    -------
    ndarray of float32, shape of one image
        Linear radiance exp(ln E) in the units of exp(g)/s; NaN where no exposure is
        usable and one at least is saturated (module docstring: at or above the white level).
    """
    check_choice(weighting, "weighting", ("hat", "hat_time"))
    stack, t, _, _ = _check_stack(images, exposure_times, None)
    resp = np.asarray(response)
    one = resp.ndim == 1 or (resp.ndim == 2 and resp.shape[1] == 1)  # a one-channel response
    grey = stack[0].ndim == 2 and one and stack[0].shape[-1] != 1  # (H, W) frames, not (N, C) samples
    if grey:
        stack = [a[..., None] for a in stack]
    channels = stack[0].shape[-1]
    g = _check_response(response, channels)
    levels = g.shape[0]
    bits = levels.bit_length() - 1
    top = 0 if np.iinfo(stack[0].dtype).max <= levels - 1 else max(int(a.max(initial=0)) for a in stack)
    if top > levels - 1:
        raise ValidationError(
            f"images must hold codes below {levels} (the response has {levels} levels, {bits} bits), got {top}"
        )
    g = np.broadcast_to(g, (levels, channels))
    black_level = check_black_level(black_level, levels)
    white_level = check_white_level(white_level, levels, black_level)
    w = hat_weights(levels, black_level, white_level).astype(np.float32)
    g32 = np.where(np.isfinite(g), g, g[1]).astype(np.float32)  # code 0 has weight 0; keep it finite
    tables = np.empty((len(t), levels, channels), np.float32)
    weights = np.empty((len(t), levels, channels), np.float32)
    for j, tj in enumerate(t):  # per exposure: the tables w(z)(g(z) − ln Δt) and w(z)
        wj = w * np.float32(tj / t[-1]) if weighting == "hat_time" else w
        tables[j] = wj[:, None] * (g32 - np.float32(np.log(tj)))
        weights[j] = wj[:, None]
    dark = g32 - np.float32(np.log(t[-1]))  # the longest exposure's estimate, where no exposure is usable
    ln_e, den = log_radiance(stack, tables, weights, dark, backend=backend)
    np.exp(ln_e, out=ln_e)
    if grey:
        ln_e, den = ln_e[..., 0], den[..., 0]
    return (ln_e, den) if return_weight else ln_e


def exposure_agreement(
    images, exposure_times, response, *, black_level: int = 0, white_level: int | None = None
) -> np.ndarray:
    """How well a response makes a bracket's exposures agree: the diagnostic of a recovered g.

    With the right g, a pixel well exposed in two exposures j < k (times sorted)
    gives the same radiance from both, g(Z_ij) − ln Δt_j = g(Z_ik) − ln Δt_k
    (Debevec & Malik 1997 eq. 2).  For each pair of consecutive exposures this
    returns the median and 90th percentile of |exp(difference) − 1| over the
    samples (pixel and channel) whose codes have a hat weight (eq. 4) of at least
    :data:`WELL_EXPOSED` of its peak in both; NaN for a pair without such samples.  Frames of more than
    :data:`AGREEMENT_SAMPLES` samples are read on a regular grid of pixels (every k-th row and column, the
    smallest k that keeps them within it).
    Noise and compression set a floor (a few per cent for 8-bit JPEGs); a wrong
    curve adds a level-dependent disagreement.

    Parameters
    ----------
    images : sequence of ndarray of int, each (H, W, C)
    exposure_times : array_like, shape (P,)
        Seconds, any order.
    response : ndarray, shape (levels, C) or (levels,)
        g = ln f⁻¹ per channel.
    black_level : int
        The sensor's pedestal in DN (module docstring): Z_min of the weights.
    white_level : int, optional
        The code in DN at and above which the sensor clips (module docstring): Z_max of the
        weights (eq. 4); default None, the top code levels − 1.

    Returns
    -------
    ndarray, shape (P − 1, 2)
        Per consecutive pair (in order of exposure time): median and 90th percentile.
    """
    stack, t, _, _ = _check_stack(images, exposure_times, None)
    if stack[0].ndim == 2:
        stack = [a[..., None] for a in stack]
    channels = stack[0].shape[-1]
    g = _check_response(response, channels)
    levels = g.shape[0]
    g = np.broadcast_to(g, (levels, channels))
    top = max(int(a.max(initial=0)) for a in stack)
    step = int(np.ceil(np.sqrt(stack[0].size / AGREEMENT_SAMPLES)))
    if step > 1:  # a regular grid of pixels holds the statistics (every step-th row and column)
        stack = [a[::step, ::step] for a in stack]
    if top > levels - 1:
        raise ValidationError(f"images must hold codes below {levels} (the response has {levels} levels), got {top}")
    black_level = check_black_level(black_level, levels)
    w = hat_weights(levels, black_level, check_white_level(white_level, levels, black_level))
    well = w >= WELL_EXPOSED * w.max()
    ch = np.arange(channels)
    out = np.full((len(t) - 1, 2), np.nan)
    for j in range(len(t) - 1):  # loop over consecutive pairs (a handful), vectorised over samples
        za, zb = stack[j], stack[j + 1]  # codes index the tables as they are (no int64 copies)
        ok = well[za] & well[zb]
        if ok.any():
            c = np.broadcast_to(ch, za.shape)[ok]
            d = (g[za[ok], c] - np.log(t[j])) - (g[zb[ok], c] - np.log(t[j + 1]))
            out[j] = np.percentile(np.abs(np.expm1(d)), [50, 90])
    return out


# -- a known non-linear camera (simulation) -----------------------------------------------------------------
def _bt709_oetf(x):
    """ITU-R BT.709 opto-electronic transfer function: 4.5x below 0.018, 1.099 x^0.45 − 0.099 above."""
    x = np.clip(np.asarray(x), 0, 1)
    shape, x = x.shape, np.atleast_1d(x)  # a 0-d x: its y would be a scalar, which takes no item assignment
    y = 4.5 * x
    hi = x >= 0.018
    y[hi] = 1.099 * np.power(x[hi], 0.45) - 0.099  # the power only where it applies (dark pixels dominate frames)
    return y.reshape(shape)


def _bt709_inverse(v):
    """Inverse of :func:`_bt709_oetf` on [0, 1]."""
    v = np.clip(v, 0, 1)
    return np.where(v < 0.081, v / 4.5, np.power((v + 0.099) / 1.099, 1 / 0.45))


@dataclass(frozen=True)
class ResponseCurve:
    """A camera with a known non-linear response: shot and read noise, BT.709 transfer curve, ``bits`` codes.

    A pixel collecting e electrons (expected value rate·Δt) reads
    Z = round(f(e_noisy / full_well) · (2^bits − 1)), clipped to [0, 2^bits − 1], with
    f the ITU-R BT.709 OETF and e_noisy = e + N(0, e + σ_read²) (Gaussian
    approximation of shot noise plus read noise).  :meth:`log_exposure` is the
    true g of Debevec & Malik (ln electrons) at each code.

    Parameters
    ----------
    bits : int
        Code depth (8 for 8-bit PNG/JPEG, 12 for 12-bit data in 16-bit files).
    full_well : float
        Electrons at the top code, > 0.
    read_noise : float
        Read noise, electrons rms, ≥ 0.
    """

    bits: int = 12
    full_well: float = 20000.0
    read_noise: float = 5.0

    def __post_init__(self):
        check_integer(self.bits, "bits", 2, 16)
        as_finite(self.full_well, "full_well", 0, None, low_inclusive=False)
        as_finite(self.read_noise, "read_noise", 0, None)

    @property
    def levels(self) -> int:
        """Number of codes, 2^bits."""
        return 2**self.bits

    def encode(self, electrons, rng: np.random.Generator | None = None) -> np.ndarray:
        """Codes (uint8 for ≤ 8 bits, else uint16) of pixels with ``electrons`` expected; noiseless without ``rng``.

        Parameters
        ----------
        electrons : array_like
            Expected electrons per pixel, any shape (a 0-d value gives a 0-d array); computed in float32.
        rng : numpy.random.Generator, optional
            Source of the shot and read noise (class docstring); None: no noise.

        Returns
        -------
        ndarray of uint8 or uint16
            Codes in [0, 2^bits − 1], the shape of ``electrons``.
        """
        e = np.asarray(electrons, np.float32)
        if rng is not None:
            noise = rng.standard_normal(e.shape, dtype=np.float32)
            noise *= np.sqrt(np.maximum(e, 0) + np.float32(self.read_noise**2))
            e = e + noise
        v = _bt709_oetf(e / np.float32(self.full_well)) * (self.levels - 1)
        return np.asarray(np.rint(v).astype(np.uint8 if self.bits <= 8 else np.uint16))  # 0-d: rint gives a scalar

    def log_exposure(self) -> np.ndarray:
        """True g(z) = ln(electrons) at each code's centre, shape (levels,); code 0 at a quarter code (finite)."""
        z = np.maximum(np.arange(self.levels, dtype=np.float64), 0.25)
        return np.log(_bt709_inverse(z / (self.levels - 1)) * self.full_well)
