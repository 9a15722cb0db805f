"""Skin-texture statistics: histograms of an albedo map and of its steerable-pyramid bands (Weyrich et al. 2006 §8).

§8: the albedo map goes to a decorrelated colour space (the PCA of its RGB,
Heeger & Bergen 1995 §3.5, :func:`facestats.edit.colourspace.decorrelating_basis`);
each of the three channels gets a steerable pyramid of 7 levels and 4
orientations (:class:`facestats.edit.pyramid.SteerablePyramid`); 256-bin
histograms of the channel itself and of its 30 pyramid bands form the vector
``H`` of 256 × 31 × 3 = 23,808 values.  :class:`TextureStatistics` holds these
histograms with their bin edges and the colour basis (needed to return to
RGB), so a target can be given by its statistics alone; it saves to and loads
from ``.npz``.  :func:`region_statistics` computes them per region of a label
map in one shared colour basis (§8 may "restrict the analysis/synthesis to
certain facial regions").

Maps whose sides are not multiples of ``2**levels`` are padded by mirror
reflection, and a region's band coefficients are those of its pixel blocks on
each level's grid (:mod:`facestats.edit.grids`).

Precision: the analysis runs in float32 whatever the input dtype (the pyramid
reconstructs to ~4e-7 relative in float32, far below the 1/256 of a band's range
that a histogram bin resolves, at half the memory and a fraction of the time of
float64).
"""

from __future__ import annotations

import os
import pathlib
from dataclasses import dataclass

import numpy as np

from facestats.core.outputs import OutputSet, check_output_file
from facestats.core.validate import as_float, check_finite, check_integer, check_shape
from facestats.edit.colourspace import ColourBasis, decorrelating_basis
from facestats.edit.grids import band_grids, grid_values, pad_plane, padded_shape, region_index
from facestats.edit.histogram import Histogram, widen_range
from facestats.edit.masks import mask_labels
from facestats.edit.pyramid import SteerablePyramid, band_names
from facestats.errors import FormatError, ValidationError

__all__ = [
    "TextureStatistics",
    "MAX_BINS",
    "statistics_path",
    "region_statistics",
    "image_statistics",
    "check_int",
    "check_settings",
]

_FORMAT = "facestats.TextureStatistics"
_VERSION = 1


#: Most histogram bins a setting may ask for: 2¹⁶ (finer than 16-bit data; 31 bands × 3 channels of
#: float64 counts stay under 50 MB, where 10⁹ bins would need 335 GiB).
MAX_BINS = 65536


def check_int(value, name, low, high=None):
    """Validate an integer setting (levels, orientations, bins, iterations).

    Parameters
    ----------
    value : int
    name : str
        Name of the argument in error messages.
    low : int
        Smallest allowed value.
    high : int, optional
        Largest allowed value (``bins``: :data:`MAX_BINS`).

    Returns
    -------
    int
    """
    return check_integer(value, name, low, MAX_BINS if name == "bins" and high is None else high)


def check_settings(levels, orientations, bins):
    """Validate pyramid levels (>= 0), orientations (>= 1) and histogram bins (>= 2).

    Parameters
    ----------
    levels, orientations, bins : int
    """
    check_int(levels, "levels", 0)
    check_int(orientations, "orientations", 1)
    check_int(bins, "bins", 2)


def statistics_path(path, *, overwrite: bool = True) -> pathlib.Path:
    """The file :meth:`TextureStatistics.save` writes for ``path``: ``.npz`` appended if missing, checked writable.

    Parameters
    ----------
    path : str or os.PathLike
        Output file; ``.npz`` is appended unless the suffix is exactly ``.npz``.
    overwrite : bool
        Whether an existing file may be replaced (False: refused, pointing at ``--overwrite``).

    Returns
    -------
    pathlib.Path
        The checked path, ending in ``.npz``.

    Raises
    ------
    ValidationError
        The path cannot be written (a folder, a device, an uncreatable folder:
        :func:`facestats.core.outputs.check_output_file`), or exists and ``overwrite`` is False.
    """
    if isinstance(path, (str, os.PathLike)) and os.fspath(path).strip() and pathlib.Path(os.fspath(path)).name:
        path = pathlib.Path(os.fspath(path))
        if path.is_dir():  # not a sibling "<folder>.npz"
            raise ValidationError(f"path must be a file (.npz), got the folder {os.fspath(path)!r}")
        if path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
    return check_output_file(path, "path", suffixes=(".npz",), overwrite=overwrite)


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
        levels = check_int(self.levels, "levels", 0)
        orientations = check_int(self.orientations, "orientations", 1)
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
        """The histogram of one decorrelated channel and band.

        Parameters
        ----------
        channel : int
            Decorrelated channel, 0-2 (0 = first principal component).
        band : int
            Band index, 0 to ``n_bands - 1`` in the order of :attr:`band_names`.

        Returns
        -------
        Histogram
            Its edges and counts.
        """
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
        """Write the statistics to an ``.npz`` file (:func:`statistics_path`; written all or nothing).

        Parameters
        ----------
        path : str or os.PathLike
            Output file; ``.npz`` is appended unless the suffix is exactly ``.npz``.  An existing file is replaced.

        Returns
        -------
        pathlib.Path
            The file written.

        Raises
        ------
        ValidationError
            The path cannot be written (:func:`statistics_path`).
        """
        path = statistics_path(path)
        with OutputSet(path.parent) as out:
            self._savez(out.path(path.name))
        return path

    def _savez(self, path) -> None:
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

    @classmethod
    def load(cls, path) -> "TextureStatistics":
        """Read statistics written by :meth:`save`.

        Parameters
        ----------
        path : str or os.PathLike
            The ``.npz`` file, or the path :meth:`save` was given: when ``path`` does not exist and its suffix is
            not ``.npz``, ``path`` with ``.npz`` appended is read (as :func:`numpy.load` users expect).

        Returns
        -------
        TextureStatistics

        Raises
        ------
        FormatError
            The path is missing or not a regular file, not an ``.npz`` archive, not a facestats texture-statistics
            file of this version, or holds invalid statistics.
        """
        path = pathlib.Path(path)
        alt = path.with_name(path.name + ".npz") if path.name and path.suffix != ".npz" else None
        if alt is not None and not os.path.lexists(path) and os.path.lexists(alt):
            path = alt  # the file save(path) wrote
        if not path.is_file():  # a FIFO would block np.load forever; a folder or nothing is no statistics file
            what = "does not exist" if not os.path.lexists(path) else "is not a regular file"
            if alt is not None and not os.path.lexists(path):
                what += f" (nor does {str(alt)!r})"
            raise FormatError(f"cannot read texture statistics from {str(path)!r}: it {what}")
        with open(path, "rb") as fh:
            zipped = fh.read(4) == b"PK\x03\x04"  # an .npz is a zip archive; anything else is not ours
        if not zipped:
            raise FormatError(f"{str(path)!r} is not a facestats texture-statistics file (not an .npz archive)")
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

        Returns
        -------
        TextureStatistics
            The statistics.
        """
        img = check_finite(as_float(albedo, "albedo"), "albedo")
        check_shape(img, "albedo", (None, None, 3))
        labels, _ = mask_labels(mask, img.shape[:2])
        inside = None if labels is None else labels > 0
        return image_statistics(img, inside, [1], levels, orientations, bins, basis, SteerablePyramid, workers)[1]


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
    levels, orientations, bins, basis, workers
        As :meth:`TextureStatistics.from_image` (one colour basis for all regions: default the PCA of the
        labelled pixels).

    Returns
    -------
    dict
        Region label → :class:`TextureStatistics`.
    """
    img = check_finite(as_float(albedo, "albedo"), "albedo")
    check_shape(img, "albedo", (None, None, 3))
    lab, ids = mask_labels(labels, img.shape[:2], "labels")
    if lab is None:
        raise ValidationError("labels must be a label map, got None")
    if regions is not None:
        wanted = [int(r) for r in regions]
        missing = [r for r in wanted if r not in ids]
        if missing:
            raise ValidationError(f"regions must be labels present in labels, got {missing} (present: {ids})")
        ids = wanted
    return image_statistics(img, lab, ids, levels, orientations, bins, basis, SteerablePyramid, workers)


def image_statistics(img, labels, ids, levels, orientations, bins, basis, pyramid, workers):
    """Per-region texture statistics of an albedo map (the engine of the public functions).

    Parameters
    ----------
    img : numpy.ndarray, shape (H, W, 3)
        Finite linear RGB albedo (checked by the caller).
    labels : numpy.ndarray of bool or int, or None
        The regions: None (the whole map), a bool mask (one region, id
        ``ids[0]``) or an integer label map.
    ids : list of int
        Region ids to analyse.
    levels, orientations, bins : int
        Pyramid and histogram settings.
    basis : ColourBasis or None
        Colour basis; None: the PCA of the labelled pixels.
    pyramid : type
        Pyramid class with the interface of :class:`SteerablePyramid`.
    workers : int
        FFT threads.

    Returns
    -------
    dict
        Region id → :class:`TextureStatistics`.
    """
    check_settings(levels, orientations, bins)
    shape = img.shape[:2]
    padded = padded_shape(shape, levels)
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
    index = {r: region_index(m, shape, padded, levels) for r, m in masks.items()}
    grids = band_grids(levels, orientations)
    nb = len(grids)
    edges = {r: np.empty((3, nb, bins + 1)) for r in ids}
    counts = {r: np.empty((3, nb, bins)) for r in ids}
    pyr = pyramid(padded, levels, orientations, dtype=dtype, workers=workers)
    for c in range(3):
        plane = pad_plane(planes[c], padded)
        arrays = [plane] + pyr.decompose(plane)
        for b, (arr, g) in enumerate(zip(arrays, grids)):
            for r in ids:
                v = grid_values(arr, index[r][g])
                lo, hi = widen_range(float(v.min()), float(v.max()))
                counts[r][c, b], edges[r][c, b] = np.histogram(v, bins=bins, range=(lo, hi))
    return {r: TextureStatistics(edges[r], counts[r], basis, levels, orientations) for r in ids}
