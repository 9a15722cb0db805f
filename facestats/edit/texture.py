"""Skin-texture statistics and Heeger-Bergen texture transfer (Weyrich et al. 2006 §8).

Statistics
----------
§8: the albedo map goes to a decorrelated colour space (the PCA of its RGB,
Heeger & Bergen 1995 §3.5, :func:`facestats.edit.colour.decorrelating_basis`);
each of the three channels gets a steerable pyramid of 7 levels and 4
orientations (:class:`facestats.edit.pyramid.SteerablePyramid`); 256-bin
histograms of the channel itself and of its 30 pyramid bands form the vector
``H`` of 256 × 31 × 3 = 23,808 values.  :class:`TextureStatistics` holds these
histograms with their bin edges and the colour basis (needed to return to
RGB), so a target can be given by its statistics alone; it saves to and loads
from ``.npz``.

Transfer
--------
Heeger & Bergen 1995 (§3, Fig. 3) synthesise a texture by iterating, from a
start image: build the pyramid, match every band's histogram to the target's,
collapse the pyramid, match the image histogram.  §8 starts from the source
albedo plus a little noise instead of pure noise.  :func:`transfer_texture`
does this per decorrelated channel, optionally inside region masks, and records
after every iteration the total-variation distance of each band's histogram to
the target's (:func:`facestats.edit.histogram.histogram_distance`).

Regions and boundaries: the pyramid is circular; an image whose sides are not
multiples of ``2**levels`` is padded by mirror reflection for the analysis and
cropped afterwards.  Inside a region mask the band coefficients of level ``i``
are those of the ``2^i × 2^i`` pixel blocks at least half inside the region (or,
if a region has no such block at a coarse level, any block touching it); pixels
outside every region are reset to the source after each iteration and returned
bit for bit; the result is blended into the source over ``feather`` pixels
inside the mask edge.

Precision: the analysis and synthesis run in float32 whatever the input dtype
(the pyramid reconstructs to ~4e-7 relative in float32, far below the 1/256 of a
band's range that a histogram bin resolves, at half the memory and a fraction of
the time of float64); results are returned in the source's dtype.
"""

from __future__ import annotations

import pathlib
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from facestats.core.validate import as_float, check_finite, check_shape
from facestats.edit.colour import ColourBasis, _blend, _check_feather, _feather_weights, _labels, decorrelating_basis
from facestats.edit.histogram import SOURCE_BINS, Histogram, _match_flat, _source_histogram, _widen, histogram_distance
from facestats.edit.pyramid import SteerablePyramid, band_names, max_levels
from facestats.errors import FormatError, ValidationError

__all__ = ["TextureStatistics", "TextureTransfer", "region_statistics", "transfer_texture"]

_FORMAT = "facestats.TextureStatistics"
_VERSION = 1


def _band_grids(levels: int, orientations: int) -> list[int]:
    """Pyramid grid (level) of each statistics band: the image, the pyramid bands in order."""
    return [0, 0] + [i for i in range(levels) for _ in range(orientations)] + [levels]


def _check_int(value, name, low):
    if not isinstance(value, (int, np.integer)) or value < low:
        raise ValidationError(f"{name} must be an int >= {low}, got {value!r}")
    return int(value)


@dataclass(frozen=True)
class TextureStatistics:
    """Histograms of an albedo map and of its steerable-pyramid bands (Weyrich et al. 2006 §8).

    Parameters
    ----------
    edges : array_like, shape (3, n_bands, bins + 1)
        Bin edges per decorrelated channel and band (uniform bins over the
        band's range of values).
    counts : array_like, shape (3, n_bands, bins)
        Pixel/coefficient counts.
    basis : ColourBasis
        The decorrelating colour transform the histograms were computed in.
    levels, orientations : int
        Pyramid settings; ``n_bands = 3 + levels * orientations``.

    Notes
    -----
    Channels are the decorrelated channels (0 = first principal component).
    Band order: 0 the channel image itself (full resolution), 1 the high-pass
    residual, ``2 + i * orientations + b`` level ``i`` orientation ``b``, last the
    low-pass residual (see :attr:`band_names`).  Band values are in the units of
    the albedo (:mod:`facestats.edit.pyramid`).
    """

    edges: np.ndarray
    counts: np.ndarray
    basis: ColourBasis
    levels: int = 7
    orientations: int = 4

    def __post_init__(self):
        levels = _check_int(self.levels, "levels", 0)
        orientations = _check_int(self.orientations, "orientations", 1)
        e = check_finite(as_float(self.edges, "edges", np.float64), "edges")
        c = check_finite(as_float(self.counts, "counts", np.float64), "counts")
        nb = 3 + levels * orientations
        if e.ndim != 3 or e.shape[:2] != (3, nb) or c.shape != (3, nb, e.shape[2] - 1) or e.shape[2] < 2:
            raise ValidationError(
                f"edges and counts must have shapes (3, {nb}, bins + 1) and (3, {nb}, bins) for "
                f"levels={levels}, orientations={orientations}, got {e.shape} and {c.shape}"
            )
        bad = np.argwhere(np.any(np.diff(e, axis=-1) <= 0, axis=-1))
        if bad.size:
            raise ValidationError(
                f"edges must be strictly increasing along the last axis, got non-increasing "
                f"edges in channel {bad[0][0]}, band {bad[0][1]}"
            )
        bad = np.argwhere(np.any(c < 0, axis=-1) | (c.sum(axis=-1) <= 0))
        if bad.size:
            raise ValidationError(
                f"counts must be >= 0 with a positive total per histogram, got a negative count "
                f"or a zero total in channel {bad[0][0]}, band {bad[0][1]}"
            )
        if not isinstance(self.basis, ColourBasis):
            raise ValidationError(f"basis must be a ColourBasis, got {type(self.basis).__name__}")
        object.__setattr__(self, "edges", e)
        object.__setattr__(self, "counts", c)
        object.__setattr__(self, "levels", levels)
        object.__setattr__(self, "orientations", orientations)

    @property
    def bins(self) -> int:
        """Bins per histogram."""
        return self.counts.shape[-1]

    @property
    def n_bands(self) -> int:
        """Histograms per channel: the image and ``2 + levels * orientations`` pyramid bands."""
        return self.counts.shape[1]

    @property
    def band_names(self) -> list[str]:
        """``["image", "highpass", "level0_orient0", …, "lowpass"]``."""
        return ["image"] + band_names(self.levels, self.orientations)

    def histogram(self, channel: int, band: int) -> Histogram:
        """The histogram of one decorrelated channel and band."""
        return Histogram(self.edges[channel, band], self.counts[channel, band])

    def to_vector(self) -> np.ndarray:
        """The histogram vector ``H`` of §8: normalised histograms, concatenated.

        Shape ``(3 * n_bands * bins,)`` (23,808 for 7 levels, 4 orientations and
        256 bins); element ``(c * n_bands + b) * bins + k`` is the probability of
        bin ``k`` of band ``b`` (order of :attr:`band_names`) of decorrelated
        channel ``c``.  Each histogram sums to 1.  The bin edges are not part of
        ``H``; they are in :attr:`edges`.
        """
        return (self.counts / self.counts.sum(axis=-1, keepdims=True)).ravel()

    def save(self, path) -> pathlib.Path:
        """Write the statistics to an ``.npz`` file (``.npz`` is appended if missing)."""
        path = pathlib.Path(path)
        if path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
        np.savez(
            path,
            format=np.array(_FORMAT),
            version=np.array(_VERSION),
            edges=self.edges,
            counts=self.counts,
            basis_mean=self.basis.mean,
            basis_axes=self.basis.axes,
            basis_variances=self.basis.variances,
            levels=np.array(self.levels),
            orientations=np.array(self.orientations),
        )
        return path

    @classmethod
    def load(cls, path) -> "TextureStatistics":
        """Read statistics written by :meth:`save`."""
        path = pathlib.Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise FormatError(f"cannot read texture statistics from {str(path)!r}: {exc}") from exc
        if str(data.get("format", "")) != _FORMAT:
            raise FormatError(f"{str(path)!r} is not a facestats texture-statistics file")
        if int(data.get("version", -1)) != _VERSION:
            raise FormatError(
                f"{str(path)!r} has texture-statistics version {data.get('version')}, expected {_VERSION}"
            )
        try:
            basis = ColourBasis(data["basis_mean"], data["basis_axes"], data["basis_variances"])
            return cls(data["edges"], data["counts"], basis, int(data["levels"]), int(data["orientations"]))
        except (KeyError, ValidationError) as exc:
            raise FormatError(f"{str(path)!r} holds invalid texture statistics: {exc}") from exc

    @classmethod
    def from_image(
        cls,
        albedo,
        mask=None,
        *,
        levels: int = 7,
        orientations: int = 4,
        bins: int = 256,
        basis: ColourBasis | None = None,
        workers: int = 2,
    ) -> "TextureStatistics":
        """Statistics of an albedo map, optionally inside a mask.

        Parameters
        ----------
        albedo : array_like, shape (H, W, 3)
            Linear RGB albedo.
        mask : array_like of bool or int, shape (H, W), optional
            Pixels to analyse (nonzero = inside); default all.
        levels, orientations, bins : int
            Pyramid levels, orientations per level, bins per histogram (§8: 7, 4, 256).
        basis : ColourBasis, optional
            Colour basis; default the PCA of the analysed pixels.
        workers : int
            FFT threads.
        """
        img = check_finite(as_float(albedo, "albedo"), "albedo")
        check_shape(img, "albedo", (None, None, 3))
        labels, _ = _labels(mask, img.shape[:2])
        inside = None if labels is None else labels > 0
        return _statistics(img, inside, [1], levels, orientations, bins, basis, SteerablePyramid, workers)[1]


def region_statistics(
    albedo,
    labels,
    regions=None,
    *,
    levels: int = 7,
    orientations: int = 4,
    bins: int = 256,
    basis: ColourBasis | None = None,
    workers: int = 2,
) -> dict[int, TextureStatistics]:
    """Texture statistics of each region of a label map, in one common colour basis.

    §8 may "restrict the analysis/synthesis to certain facial regions".  One
    pyramid per channel serves every region; the basis (default: the PCA of all
    labelled pixels) is shared, as :func:`transfer_texture` needs for several
    regions at once.

    Parameters
    ----------
    albedo : array_like, shape (H, W, 3)
        Linear RGB albedo.
    labels : array_like of int, shape (H, W)
        Region labels (0 = none), e.g. the regions 1-10 of Weyrich Fig. 15.
    regions : iterable of int, optional
        Regions to analyse (default: every nonzero label present).

    Returns
    -------
    dict
        Region label → :class:`TextureStatistics`.
    """
    img = check_finite(as_float(albedo, "albedo"), "albedo")
    check_shape(img, "albedo", (None, None, 3))
    lab, ids = _labels(labels, img.shape[:2], "labels")
    if lab is None:
        raise ValidationError("labels must be a label map, got None")
    if regions is not None:
        wanted = [int(r) for r in regions]
        missing = [r for r in wanted if r not in ids]
        if missing:
            raise ValidationError(f"regions must be labels present in labels, got {missing} (present: {ids})")
        ids = wanted
    return _statistics(img, lab, ids, levels, orientations, bins, basis, SteerablePyramid, workers)


# --------------------------------------------------------------------------- engine


def _check_settings(levels, orientations, bins):
    _check_int(levels, "levels", 0)
    _check_int(orientations, "orientations", 1)
    _check_int(bins, "bins", 2)


def _pad_shape(shape, levels) -> tuple[int, ...]:
    """``shape`` with each side rounded up to a multiple of ``2**levels`` (the pyramid's grid)."""
    step = 1 << levels
    return tuple(-(-s // step) * step for s in shape)


def _padded_shape(shape, levels):
    """:func:`_pad_shape`, checked against the levels the padded grid supports."""
    padded = _pad_shape(shape, levels)
    if levels > max_levels(padded):
        raise ValidationError(
            f"levels must be at most {max_levels(padded)} for a map of shape {tuple(shape)} "
            f"(the low-pass residual needs at least 4 pixels a side), got {levels}"
        )
    return padded


def _pad(plane, padded):
    h, w = plane.shape
    if (h, w) == padded:
        return plane
    return np.pad(plane, ((0, padded[0] - h), (0, padded[1] - w)), mode="symmetric")


def _region_index(inside: np.ndarray | None, shape, padded, levels):
    """Flat coefficient indices of a region on grids 0…levels (None = the whole grid)."""
    if inside is None and tuple(shape) == tuple(padded):
        return [None] * (levels + 1)
    m = np.zeros(padded, bool)
    m[: shape[0], : shape[1]] = True if inside is None else inside
    out = [np.flatnonzero(m)]
    frac = m.astype(np.float32)
    for _ in range(levels):
        h, w = frac.shape
        frac = frac.reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3))
        idx = np.flatnonzero(frac >= 0.5)
        if idx.size == 0:
            idx = np.flatnonzero(frac > 0)
        out.append(idx)
    return out


def _values(arr, idx):
    flat = arr.reshape(-1)
    return flat if idx is None else flat[idx]


def _statistics(img, labels, ids, levels, orientations, bins, basis, pyramid, workers):
    """Per-region statistics of ``img`` (H, W, 3); ``labels`` None, bool or int (region ids ``ids``)."""
    _check_settings(levels, orientations, bins)
    shape = img.shape[:2]
    padded = _padded_shape(shape, levels)
    if labels is None:
        masks = {ids[0]: None}
    elif labels.dtype == bool:
        masks = {ids[0]: labels}
    else:
        masks = {r: labels == r for r in ids}
    if basis is None:
        union = None if labels is None else labels.astype(bool)
        basis = decorrelating_basis(img, union)
    elif not isinstance(basis, ColourBasis):
        raise ValidationError(f"basis must be a ColourBasis, got {type(basis).__name__}")
    dtype = np.float32  # the working precision of all texture analysis (see the module docstring)
    planes = basis.to_decorrelated(img, dtype)
    index = {r: _region_index(m, shape, padded, levels) for r, m in masks.items()}
    grids = _band_grids(levels, orientations)
    nb = len(grids)
    edges = {r: np.empty((3, nb, bins + 1)) for r in ids}
    counts = {r: np.empty((3, nb, bins)) for r in ids}
    pyr = pyramid(padded, levels, orientations, dtype=dtype, workers=workers)
    for c in range(3):
        plane = _pad(planes[c], padded)
        arrays = [plane] + pyr.decompose(plane)
        for b, (arr, g) in enumerate(zip(arrays, grids)):
            for r in ids:
                v = _values(arr, index[r][g])
                lo, hi = _widen(float(v.min()), float(v.max()))
                counts[r][c, b], edges[r][c, b] = np.histogram(v, bins=bins, range=(lo, hi))
    return {r: TextureStatistics(edges[r], counts[r], basis, levels, orientations) for r in ids}


def _synthesise(planes, source, outside, index, targets, pyramid, iterations, source_bins):
    """Heeger-Bergen iterations on decorrelated channel planes (modified in place).

    ``planes`` (3, H, W) start images; ``source`` (3, H, W) the values restored
    outside the regions (``outside`` bool or None); ``index[r][g]`` region ``r``'s
    coefficients on grid ``g``; ``targets[r]`` its TextureStatistics.  Returns
    the band distances, shape (iterations + 1, 3, n_pyramid_bands).
    """
    any_target = next(iter(targets.values()))
    grids = _band_grids(any_target.levels, any_target.orientations)
    nb = len(grids)
    hist = {r: [[s.histogram(c, b) for b in range(nb)] for c in range(3)] for r, s in targets.items()}
    dist = np.zeros((iterations + 1, 3, nb - 1))
    nreg = len(targets)

    def match(arr, idx, h):
        if idx is None:
            flat = arr.reshape(-1)
            return _match_flat(flat, h, 1.0, source_bins, flat)
        v = arr.reshape(-1)[idx]
        d = _match_flat(v, h, 1.0, source_bins, v)
        arr.reshape(-1)[idx] = v
        return d

    for c in range(3):
        x = planes[c]
        for r in targets:
            match(x, index[r][0], hist[r][c][0])
        for it in range(iterations + 1):
            bands = pyramid.decompose(x)
            for k, band in enumerate(bands):
                g = grids[k + 1]
                for r in targets:
                    h = hist[r][c][k + 1]
                    if it == iterations:
                        d = histogram_distance(_source_histogram(_values(band, index[r][g]), source_bins)[0], h)
                    else:
                        d = match(band, index[r][g], h)
                    dist[it, c, k] += d / nreg
            if it == iterations:
                break
            x = pyramid.reconstruct(bands)
            if outside is not None:
                np.copyto(x, source[c], where=outside)
            for r in targets:
                match(x, index[r][0], hist[r][c][0])
        planes[c] = x
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


def _resolve_target(target, target_mask, mask_is_labels, ids, shape_levels, workers, pyramid):
    """Region label → TextureStatistics for the source regions ``ids``."""
    levels, orientations, bins = shape_levels
    if isinstance(target, TextureStatistics):
        stats = {r: target for r in ids}
    elif isinstance(target, Mapping):
        missing = [r for r in ids if r not in target]
        if missing:
            raise ValidationError(f"target must hold statistics for every region of mask, missing {missing}")
        stats = {r: target[r] for r in ids}
        for r, s in stats.items():
            if not isinstance(s, TextureStatistics):
                raise ValidationError(f"target[{r}] must be a TextureStatistics, got {type(s).__name__}")
    else:
        timg = check_finite(as_float(target, "target"), "target")
        check_shape(timg, "target", (None, None, 3))
        levels = 7 if levels is None else levels
        orientations = 4 if orientations is None else orientations
        bins = 256 if bins is None else bins
        tm = None if target_mask is None else np.asarray(target_mask)
        per_region = mask_is_labels and tm is not None and tm.dtype.kind in "iu"
        tlabels, tids = _labels(tm, timg.shape[:2], "target_mask")
        if per_region:
            missing = [r for r in ids if r not in tids]
            if missing:
                raise ValidationError(f"target_mask must hold every region of mask, missing {missing}")
            stats = _statistics(timg, tlabels, ids, levels, orientations, bins, None, pyramid, workers)
        else:
            inside = None if tlabels is None else tlabels > 0
            one = _statistics(timg, inside, [1], levels, orientations, bins, None, pyramid, workers)[1]
            stats = {r: one for r in ids}
    first = next(iter(stats.values()))
    for r, s in stats.items():
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
    return stats


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
) -> TextureTransfer:
    """Transfer skin texture by Heeger-Bergen histogram matching (Weyrich et al. 2006 §8).

    The source albedo is expressed in the target's decorrelated colour basis;
    Gaussian noise of standard deviation ``noise`` × (the channel's standard
    deviation inside the mask) is added inside the mask (seeded); then, per
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
        Heeger-Bergen iterations (default 5).
    seed : int or numpy.random.Generator, optional
        Seed of the start noise; the same seed gives the same result bit for bit.
    noise : float
        Start-noise amplitude relative to each decorrelated channel's standard
        deviation inside the mask (default 0.1; 0 for none).
    feather : float
        Blend width in pixels inside the mask edge (default 4; 0 for a hard edge).
    workers : int
        FFT threads.

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
        pyramid=SteerablePyramid,
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
    """:func:`transfer_texture` with a pluggable pyramid class (``benchmarks/bench_edit.py`` swaps in pyrtools)."""
    src = check_finite(as_float(source_albedo, "source_albedo"), "source_albedo")
    check_shape(src, "source_albedo", (None, None, 3))
    iterations = _check_int(iterations, "iterations", 0)
    feather = _check_feather(feather)
    noise_amp = float(check_finite(as_float(noise, "noise", np.float64), "noise"))
    if np.ndim(noise) != 0 or noise_amp < 0:
        raise ValidationError(f"noise must be a scalar >= 0, got {noise!r}")
    for name, v in (("levels", levels), ("orientations", orientations), ("bins", bins)):
        if v is not None:
            _check_int(v, name, 0 if name == "levels" else 1)
    shape = src.shape[:2]
    labels, ids = _labels(mask, shape)
    mask_is_labels = mask is not None and np.asarray(mask).dtype.kind in "iu"
    stats = _resolve_target(target, target_mask, mask_is_labels, ids, (levels, orientations, bins), workers, pyramid)
    first = next(iter(stats.values()))
    levels, orientations = first.levels, first.orientations
    padded = _padded_shape(shape, levels)
    dtype = np.float32

    inside = None if labels is None else labels > 0
    index = {r: _region_index(None if labels is None else labels == r, shape, padded, levels) for r in ids}
    union = np.zeros(padded, bool)
    union[: shape[0], : shape[1]] = True if inside is None else inside
    outside = None if union.all() else ~union

    basis = first.basis
    planes_src = basis.to_decorrelated(src, dtype)
    source = np.stack([_pad(planes_src[c], padded) for c in range(3)])
    planes = source.copy()
    rng = np.random.default_rng(seed)
    if noise_amp > 0:
        for c in range(3):
            sd = float(planes[c][union].std())
            z = rng.standard_normal(padded, dtype=dtype)
            z *= dtype(noise_amp * sd)
            np.add(planes[c], z, out=planes[c], where=union)

    pyr = pyramid(padded, levels, orientations, dtype=dtype, workers=workers)
    dist = _synthesise(planes, source, outside, index, stats, pyr, iterations, SOURCE_BINS)

    edited = np.clip(basis.to_rgb(planes[:, : shape[0], : shape[1]]), 0.0, 1.0).astype(src.dtype, copy=False)
    weights = np.ones(shape) if inside is None else _feather_weights(inside, feather)
    albedo = _blend(src, edited, weights)
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
    )
