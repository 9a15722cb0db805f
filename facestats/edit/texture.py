"""Heeger-Bergen skin-texture transfer (Weyrich et al. 2006 §8).

Heeger & Bergen 1995 (§3, Fig. 3) synthesise a texture by iterating, from a
start image: build the pyramid, match every band's histogram to the target's,
collapse the pyramid, match the image histogram.  §8 starts from the source
albedo plus a little noise instead of pure noise.  :func:`transfer_texture`
does this per decorrelated channel, optionally inside region masks, and records
after every iteration the total-variation distance of each band's histogram to
the target's (:func:`facestats.edit.histogram.histogram_distance`).  The target
is given by its texture statistics (:mod:`facestats.edit.statistics`) or by an
albedo map whose statistics are computed here.

Regions and boundaries: the pyramid is circular; an image whose sides are not
multiples of ``2**levels`` is padded by mirror reflection for the analysis and
cropped afterwards.  Inside a region mask the band coefficients of level ``i``
are those of the ``2^i × 2^i`` pixel blocks at least half inside the region (or,
if a region has no such block at a coarse level, any block touching it;
:mod:`facestats.edit.grids`); pixels outside every region are reset to the
source after each iteration and returned bit for bit; the result is blended
into the source over ``feather`` pixels inside the mask edge
(:mod:`facestats.edit.masks`).

Precision: the analysis and synthesis run in float32 whatever the input dtype
(the pyramid reconstructs to ~4e-7 relative in float32, far below the 1/256 of a
band's range that a histogram bin resolves, at half the memory and a fraction of
the time of float64); results are returned in the source's dtype.

:class:`~facestats.edit.statistics.TextureStatistics` and
:func:`~facestats.edit.statistics.region_statistics` are defined in
:mod:`facestats.edit.statistics` and importable from here as before.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from facestats.core.validate import as_float, as_rgb_image, check_finite, check_seed
from facestats.edit.grids import band_grids, grid_values, pad_plane, padded_shape, region_index
from facestats.edit.histogram import SOURCE_BINS, distance_floor, histogram_distance, match_flat, source_histogram
from facestats.edit.masks import blend, check_feather, feather_weights, mask_labels
from facestats.edit.pyramid import SteerablePyramid
from facestats.edit.statistics import TextureStatistics, check_int, image_statistics, region_statistics
from facestats.errors import FacestatsWarning, ValidationError

__all__ = [
    "MAX_ITERATIONS",
    "MIN_COEFFICIENTS_PER_BIN",
    "TextureStatistics",
    "TextureTransfer",
    "region_statistics",
    "transfer_texture",
]

#: Most Heeger-Bergen iterations a transfer runs (Heeger & Bergen 1995 use about five; the distance settles by ten).
MAX_ITERATIONS = 100
#: Fewest coefficients per histogram bin a band needs (region's and target's).  With fewer than one a bin, the
#: distance of a band that follows the target exactly is above 0.3 (:func:`~facestats.edit.histogram.distance_floor`
#: 0.27, measured 0.30 on pyramid bands of a synthetic texture at n = 256 with 256 bins), as large as the distance
#: between two faces' bands (0.11-0.30 at levels 1-4 of the texture sample), so the band's histogram cannot tell
#: whether it matches (``bench_edit.bench_band_noise``; README, *Texture transfer needs coefficients*).
MIN_COEFFICIENTS_PER_BIN = 1.0


# --------------------------------------------------------------------------- synthesis


def _match_in_place(arr, idx, hist, source_bins):
    """Match the coefficients ``idx`` of ``arr`` (all of them for None) to ``hist`` in place; their distance before."""
    if idx is None:
        flat = arr.reshape(-1)
        return match_flat(flat, hist, 1.0, source_bins, flat)
    v = arr.reshape(-1)[idx]
    d = match_flat(v, hist, 1.0, source_bins, v)
    arr.reshape(-1)[idx] = v
    return d


def _band_pass(bands, grids, index, hist, source_bins, final):
    """Match every pyramid band in every region (``final``: only measure); band distances averaged over regions.

    ``hist[r][b]`` is region ``r``'s target histogram of statistics band ``b``
    (0 the image, ``k + 1`` pyramid band ``k``) of the current channel.
    """
    dist = np.zeros(len(bands))
    nreg = len(hist)
    for k, band in enumerate(bands):
        g = grids[k + 1]
        for r, h_r in hist.items():
            h = h_r[k + 1]
            if final:
                d = histogram_distance(source_histogram(grid_values(band, index[r][g]), source_bins)[0], h)
            else:
                d = _match_in_place(band, index[r][g], h, source_bins)
            dist[k] += d / nreg
    return dist


def _synthesise_channel(x, source, outside, index, hist, pyramid, iterations, grids, source_bins):
    """Heeger-Bergen iterations on one decorrelated channel plane ``x`` (modified in place until the first collapse).

    Returns the synthesised plane and the band distances, shape
    (iterations + 1, n_pyramid_bands): entry 0 after the first image-histogram
    match, entry k after k iterations.
    """
    dist = np.zeros((iterations + 1, len(grids) - 1))
    for r, h in hist.items():
        _match_in_place(x, index[r][0], h[0], source_bins)
    for it in range(iterations + 1):
        bands = pyramid.decompose(x)
        dist[it] = _band_pass(bands, grids, index, hist, source_bins, final=it == iterations)
        if it == iterations:
            break
        x = pyramid.reconstruct(bands)
        if outside is not None:
            np.copyto(x, source, where=outside)
        for r, h in hist.items():
            _match_in_place(x, index[r][0], h[0], source_bins)
    return x, dist


def _synthesise(planes, source, outside, index, targets, pyramid, iterations, source_bins):
    """Heeger-Bergen iterations on decorrelated channel planes (modified in place).

    ``planes`` (3, H, W) start images; ``source`` (3, H, W) the values restored
    outside the regions (``outside`` bool or None); ``index[r][g]`` region ``r``'s
    coefficients on grid ``g``; ``targets[r]`` its TextureStatistics.  Returns
    the band distances, shape (iterations + 1, 3, n_pyramid_bands).
    """
    any_target = next(iter(targets.values()))
    grids = band_grids(any_target.levels, any_target.orientations)
    nb = len(grids)
    dist = np.zeros((iterations + 1, 3, nb - 1))
    for c in range(3):
        hist = {r: [s.histogram(c, b) for b in range(nb)] for r, s in targets.items()}
        planes[c], dist[:, c] = _synthesise_channel(
            planes[c], source[c], outside, index, hist, pyramid, iterations, grids, source_bins
        )
    return dist


@dataclass(frozen=True)
class TextureTransfer:
    """Result of :func:`transfer_texture`.

    Attributes
    ----------
    albedo : numpy.ndarray, shape (H, W, 3)
        The edited albedo (linear RGB, the source's dtype).
    distance : numpy.ndarray, shape (iterations + 1,)
        Convergence: mean over channels, pyramid bands and regions of the
        total-variation distance (:func:`histogram_distance`, in [0, 1]) of the
        band histograms to the target's; entry 0 is the start (noisy source
        after the first image-histogram match), entry k the state after k
        iterations.
    band_distance : numpy.ndarray, shape (iterations + 1, 3, n_pyramid_bands)
        The same per decorrelated channel and pyramid band (band order of
        :func:`facestats.edit.pyramid.band_names`).
    source : numpy.ndarray
        The source albedo (the caller's array, not a copy).
    mask : numpy.ndarray of bool or None
        Pixels edited (None: all).
    statistics : dict
        Region label → target :class:`TextureStatistics` used.
    seed, noise, iterations, feather
        Settings used.
    floor : float
        The sampling floor of ``distance``: its expected value for bands that follow the target exactly, given
        how many coefficients each band holds in each region and the target was counted from
        (:func:`~facestats.edit.histogram.distance_floor`; a lower bound, band coefficients being correlated).
        A distance near it is as close as these histograms can show; a start near it, a source they cannot
        tell from the target.
    band_floor : numpy.ndarray, shape (3, n_pyramid_bands)
        The same per channel and band (mean over regions).
    coefficients : dict
        Region label → the coefficients each statistics band is compared over, the fewer of the region's and
        the target's (band order of ``TextureStatistics.band_names``; band 0 the image).
    """

    albedo: np.ndarray
    distance: np.ndarray
    band_distance: np.ndarray
    source: np.ndarray = field(repr=False)
    mask: np.ndarray | None = field(repr=False)
    statistics: dict = field(repr=False)
    seed: int | None = None
    noise: float = 0.0
    iterations: int = 0
    feather: float = 0.0
    floor: float = float("nan")
    band_floor: np.ndarray | None = field(default=None, repr=False)
    coefficients: dict = field(default_factory=dict, repr=False)


# --------------------------------------------------------------------------- target statistics


def _statistics_per_region(target, ids):
    """Region id → TextureStatistics from a mapping given per region."""
    missing = [r for r in ids if r not in target]
    if missing:
        raise ValidationError(f"target must hold statistics for every region of mask, missing {missing}")
    stats = {r: target[r] for r in ids}
    for r, s in stats.items():
        if not isinstance(s, TextureStatistics):
            raise ValidationError(f"target[{r}] must be a TextureStatistics, got {type(s).__name__}")
    return stats


def _target_image_statistics(target, target_mask, mask_is_labels, ids, settings, workers, pyramid):
    """Region id → TextureStatistics of a target albedo map (per region if both masks are label maps)."""
    levels, orientations, bins = settings
    timg = as_rgb_image(target, "target")
    levels = 7 if levels is None else levels
    orientations = 4 if orientations is None else orientations
    bins = 256 if bins is None else bins
    tm = None if target_mask is None else np.asarray(target_mask)
    per_region = mask_is_labels and tm is not None and tm.dtype.kind in "iu"
    tlabels, tids = mask_labels(tm, timg.shape[:2], "target_mask")
    if per_region:
        missing = [r for r in ids if r not in tids]
        if missing:
            raise ValidationError(f"target_mask must hold every region of mask, missing {missing}")
        return image_statistics(timg, tlabels, ids, levels, orientations, bins, None, pyramid, workers)
    inside = None if tlabels is None else tlabels > 0
    one = image_statistics(timg, inside, [1], levels, orientations, bins, None, pyramid, workers)[1]
    return {r: one for r in ids}


def _check_shared(stats, settings):
    """Raise unless all regions' statistics share settings and colour basis, and match explicit ``settings``."""
    levels, orientations, bins = settings
    first = next(iter(stats.values()))
    for s in stats.values():
        if (s.levels, s.orientations, s.bins) != (first.levels, first.orientations, first.bins):
            raise ValidationError("target statistics of all regions must share levels, orientations and bins")
        if not (np.allclose(s.basis.axes, first.basis.axes) and np.allclose(s.basis.mean, first.basis.mean)):
            raise ValidationError(
                "target statistics of all regions must share one colour basis (compute them with region_statistics)"
            )
    for name, want, have in (
        ("levels", levels, first.levels),
        ("orientations", orientations, first.orientations),
        ("bins", bins, first.bins),
    ):
        if want is not None and want != have:
            raise ValidationError(f"{name} must match the target statistics ({have}), got {want}")


def _texture_targets(target, target_mask, mask_is_labels, ids, settings, workers, pyramid):
    """Region id → target TextureStatistics for the source regions ``ids``."""
    if isinstance(target, TextureStatistics):
        stats = {r: target for r in ids}
    elif isinstance(target, Mapping):
        stats = _statistics_per_region(target, ids)
    else:
        stats = _target_image_statistics(target, target_mask, mask_is_labels, ids, settings, workers, pyramid)
    _check_shared(stats, settings)
    return stats


# --------------------------------------------------------------------------- coefficients per band


def _band_coefficients(index, padded, stats, grids):
    """Region id → coefficients per statistics band: the region's (on the band's grid), the target statistics'
    (their histogram's count; None for histograms of weights that are not counts) and the fewer of the two."""
    own, target, fewer = {}, {}, {}
    for r, idx in index.items():
        on_grid = [(padded[0] >> g) * (padded[1] >> g) if i is None else len(i) for g, i in enumerate(idx)]
        own[r] = [on_grid[g] for g in grids]
        hists = [stats[r].histogram(0, b) for b in range(len(grids))]
        counted = all(np.array_equal(h.counts, np.round(h.counts)) for h in hists)
        target[r] = [int(h.total) for h in hists] if counted else None
        fewer[r] = own[r] if target[r] is None else [min(a, t) for a, t in zip(own[r], target[r], strict=True)]
    return own, target, fewer


def _span(values, plural=""):
    """``a-b`` of the smallest and largest of ``values``, or the one value; ``plural`` goes before a range."""
    lo, hi = min(values), max(values)
    return f"{plural}{lo}-{hi}" if lo != hi else f"{' ' if plural else ''}{lo}"


def _warn_few_coefficients(fewer, own, grids, bins, shape, labelled):
    """Warn, naming regions, grids, counts and what helps, when bands hold fewer than the minimum coefficients."""
    minimum = MIN_COEFFICIENTS_PER_BIN * bins
    under = {r: [b for b, n in enumerate(c) if n < minimum] for r, c in fewer.items()}
    n_under = sum(len(b) for b in under.values())
    if not n_under:
        return
    parts = []
    for r, bands in under.items():
        if bands:
            gs, ns = [grids[b] for b in bands], [fewer[r][b] for b in bands]
            target_short = any(fewer[r][b] < own[r][b] for b in bands)
            where = f"region {r}" if labelled else ("the mask" if own[r][0] < shape[0] * shape[1] else "the map")
            parts.append(
                f"{where} ({own[r][0]} texels of the {shape[0]} x {shape[1]} map): grid{_span(gs, 's ')} "
                f"hold{'s' if len(set(gs)) == 1 else ''} "
                f"{_span(ns)} coefficients" + (" (fewer in the target statistics)" if target_short else "")
            )
    ok = [
        all(n >= minimum for c in fewer.values() for b, n in enumerate(c) if grids[b] == g)
        for g in range(max(grids) + 1)
    ]
    keep = next((g for g, good in enumerate(ok) if not good), len(ok)) - 1
    if keep >= 1:
        advice = (
            f"levels <= {keep} (--levels {keep}; saved statistics fix their own: edit stats --levels {keep}) keeps "
            "every band at or above it"
        )
    else:
        bigger = (
            "use larger maps (the texture sample, 512 x 512: --store texture-sample), larger regions (--regions) or "
            "fewer bins (--bins; edit stats --bins)"
        )
        if keep == 0:
            advice = f"only grid 0 holds enough (one level puts its low-pass residual on grid 1): {bigger}"
        else:
            finest = [r for r, c in fewer.items() if c[0] < minimum]
            whose = f"of region(s) {', '.join(str(r) for r in finest)} " if labelled else ""
            advice = (
                f"even the finest bands {whose}hold fewer: no band there can show a change, and matching them adds "
                f"texture made of sampling noise; {bigger}"
            )
    total = sum(len(c) for c in fewer.values())
    warnings.warn(
        f"texture transfer: {n_under} of {total} band histograms (over regions) hold fewer coefficients than their "
        f"{bins} bins, the minimum ({MIN_COEFFICIENTS_PER_BIN:g} a bin) below which a band's histogram distance is "
        f"mostly sampling noise (about 0.3 sqrt(bins / n) for n coefficients; README, *Texture transfer needs "
        f"coefficients*): {'; '.join(parts)} (grid g: one coefficient per 2^g x 2^g texels; grid 0 holds the "
        f"image). Those bands are matched but cannot show whether they match, and they hold the reported distance "
        f"near its sampling floor. {advice[0].upper() + advice[1:]}",
        FacestatsWarning,
        stacklevel=4,
    )


def _floors(own, target, stats, grids):
    """Sampling floor of the band distances: (3, n pyramid bands), mean over regions (as the distances)."""
    out = np.zeros((3, len(grids) - 1))
    for r, counts in own.items():
        s = stats[r]
        for c in range(3):  # the three decorrelated channels
            for k in range(len(grids) - 1):  # pyramid bands (statistics band k + 1)
                m = None if target[r] is None else max(target[r][k + 1], 1)
                out[c, k] += distance_floor(s.histogram(c, k + 1), max(counts[k + 1], 1), m) / len(own)
    return out


# --------------------------------------------------------------------------- transfer


def _check_noise(noise) -> float:
    noise_amp = float(check_finite(as_float(noise, "noise", np.float64), "noise"))
    if np.ndim(noise) != 0 or noise_amp < 0:
        raise ValidationError(f"noise must be a scalar >= 0, got {noise!r}")
    return noise_amp


def _add_start_noise(planes, union, noise_amp, rng, stats):
    """Add Gaussian noise inside ``union`` (in place): ``noise_amp`` × the larger of each channel's standard deviation
    there and the largest of the target regions' (``stats``), so that a flat source still gets variation to
    synthesise from (§8: noise "to allow for sufficient variation"; a constant source got none and came out
    constant, found by an audit)."""
    if noise_amp > 0:
        dtype = planes.dtype.type
        for c in range(3):
            target = max(t.histogram(c, 0).std() for t in stats.values())
            sd = max(float(planes[c][union].std()), target)
            z = rng.standard_normal(union.shape, dtype=dtype)
            z *= dtype(noise_amp * sd)
            np.add(planes[c], z, out=planes[c], where=union)


def transfer_texture(
    source_albedo,
    target,
    mask=None,
    *,
    target_mask=None,
    levels: int | None = None,
    orientations: int | None = None,
    bins: int | None = None,
    iterations: int = 5,
    seed=None,
    noise: float = 0.1,
    feather: float = 4.0,
    workers: int = 2,
    pyramid=None,
) -> TextureTransfer:
    """Transfer skin texture by Heeger-Bergen histogram matching (Weyrich et al. 2006 §8).

    The source albedo is expressed in the target's decorrelated colour basis;
    Gaussian noise of standard deviation ``noise`` × (the larger of the channel's
    standard deviation inside the mask and the target's) is added inside the mask
    (seeded); then, per
    channel: match the image histogram, and ``iterations`` times: build the
    steerable pyramid, match every band's histogram to the target's (within each
    region), collapse the pyramid, restore the pixels outside the mask, match
    the image histogram.  Back in RGB the result is clipped to [0, 1] and
    blended into the source over ``feather`` pixels inside the mask edge.

    Parameters
    ----------
    source_albedo : array_like, shape (H, W, 3)
        Linear RGB albedo to edit (processed in float32, returned in its dtype).
    target : TextureStatistics, dict of {int: TextureStatistics}, or array_like (H', W', 3)
        Target texture: statistics (applied to every region), statistics per
        region label (one shared colour basis, see :func:`region_statistics`),
        or a target albedo map whose statistics are computed here (per region
        if ``mask`` and ``target_mask`` are both integer label maps).
    mask : array_like of bool or int, shape (H, W), optional
        Region mask: bool (one region) or integer labels (0 = untouched; each
        label a region with its own histograms).  Default: the whole map.
    target_mask : array_like of bool or int, optional
        Pixels (or regions) of a target map to analyse.
    levels, orientations, bins : int, optional
        Pyramid and histogram settings, default 7, 4, 256 (§8) or those of
        the target statistics (a different explicit value is an error).
    iterations : int
        Heeger-Bergen iterations, 0 to :data:`MAX_ITERATIONS` (default 5; the distance settles after a few).
    seed : int or numpy.random.Generator, optional
        Seed of the start noise; the same seed gives the same result bit for bit.
    noise : float
        Start-noise amplitude relative to each decorrelated channel's standard
        deviation inside the mask, or the target's where that is larger (a flat
        source), default 0.1; 0 for none.
    feather : float
        Blend width in pixels inside the mask edge (default 4; 0 for a hard edge).
    workers : int
        FFT threads.
    pyramid : class, optional
        The steerable pyramid: :class:`facestats.edit.pyramid.SteerablePyramid`
        (default) or any class with its constructor ``(shape, levels,
        orientations, *, dtype, workers)`` and ``decompose``/``reconstruct``
        methods (``benchmarks/bench_edit.py`` plugs in pyrtools' to compare).

    Returns
    -------
    TextureTransfer
        The edited albedo and the convergence report.
    """
    return _transfer_texture(
        source_albedo,
        target,
        mask,
        target_mask=target_mask,
        levels=levels,
        orientations=orientations,
        bins=bins,
        iterations=iterations,
        seed=seed,
        noise=noise,
        feather=feather,
        workers=workers,
        pyramid=SteerablePyramid if pyramid is None else pyramid,
    )


def _transfer_texture(
    source_albedo,
    target,
    mask,
    *,
    target_mask,
    levels,
    orientations,
    bins,
    iterations,
    seed,
    noise,
    feather,
    workers,
    pyramid,
):
    """:func:`transfer_texture` after its defaults are resolved."""
    src = as_rgb_image(source_albedo, "source_albedo")
    check_seed(seed)
    iterations = check_int(iterations, "iterations", 0, MAX_ITERATIONS)
    feather = check_feather(feather)
    noise_amp = _check_noise(noise)
    for name, v in (("levels", levels), ("orientations", orientations), ("bins", bins)):
        if v is not None:
            check_int(v, name, {"levels": 0, "orientations": 1, "bins": 2}[name])  # as check_settings
    shape = src.shape[:2]
    labels, ids = mask_labels(mask, shape)
    mask_is_labels = mask is not None and np.asarray(mask).dtype.kind in "iu"
    stats = _texture_targets(target, target_mask, mask_is_labels, ids, (levels, orientations, bins), workers, pyramid)
    first = next(iter(stats.values()))
    levels, orientations = first.levels, first.orientations
    padded = padded_shape(shape, levels)
    dtype = np.float32

    inside = None if labels is None else labels > 0
    weights = np.ones(shape) if inside is None else feather_weights(inside, feather)  # checked before the work
    index = {r: region_index(None if labels is None else labels == r, shape, padded, levels) for r in ids}
    grids = band_grids(levels, orientations)
    own, target_counts, fewer = _band_coefficients(index, padded, stats, grids)
    _warn_few_coefficients(fewer, own, grids, first.bins, shape, mask_is_labels)
    union = np.zeros(padded, bool)
    union[: shape[0], : shape[1]] = True if inside is None else inside
    outside = None if union.all() else ~union

    basis = first.basis
    planes_src = basis.to_decorrelated(src, dtype)
    source = np.stack([pad_plane(planes_src[c], padded) for c in range(3)])
    planes = source.copy()
    _add_start_noise(planes, union, noise_amp, np.random.default_rng(seed), stats)

    pyr = pyramid(padded, levels, orientations, dtype=dtype, workers=workers)
    dist = _synthesise(planes, source, outside, index, stats, pyr, iterations, SOURCE_BINS)

    edited = np.clip(basis.to_rgb(planes[:, : shape[0], : shape[1]]), 0.0, 1.0).astype(src.dtype, copy=False)
    albedo = blend(src, edited, weights)
    band_floor = _floors(own, target_counts, stats, grids)
    return TextureTransfer(
        albedo=albedo,
        distance=dist.mean(axis=(1, 2)),
        band_distance=dist,
        source=src,
        mask=inside,
        statistics=stats,
        seed=None if isinstance(seed, np.random.Generator) else seed,
        noise=noise_amp,
        iterations=iterations,
        feather=feather,
        floor=float(band_floor.mean()),
        band_floor=band_floor,
        coefficients=fewer,
    )
