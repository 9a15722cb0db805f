"""Skin-colour transfer in a decorrelated colour space (Weyrich et al. 2006 §8).

§8: "transfer skin color histograms from one subject to another ... change the
skin type, e.g. from II to V".  :func:`transfer_colour` expresses source and
target in the target's PCA colour basis (Heeger & Bergen 1995 §3.5,
:mod:`facestats.edit.colourspace`) and matches the histogram of each
decorrelated channel of the source to the target's
(:func:`facestats.edit.histogram.match_histogram`), optionally part-way
(``t``) and inside a region mask (:mod:`facestats.edit.masks`).

Albedo is linear RGB in [0, 1] with the channel last (R, G, B).
:class:`~facestats.edit.colourspace.ColourBasis` and
:func:`~facestats.edit.colourspace.decorrelating_basis` are defined in
:mod:`facestats.edit.colourspace` and importable from here as before.
"""

from __future__ import annotations

import numpy as np

from facestats.core.validate import as_finite, as_rgb_image, check_shape
from facestats.edit.colourspace import ColourBasis, decorrelating_basis, masked_pixels
from facestats.edit.histogram import Histogram, check_t, match_histogram
from facestats.edit.masks import blend, check_feather, feather_weights, mask_labels
from facestats.edit.statistics import TextureStatistics, check_int
from facestats.errors import ValidationError

__all__ = ["ColourBasis", "decorrelating_basis", "transfer_colour"]


def _target_colour(target, target_mask, bins):
    """(ColourBasis, [Histogram × 3]) of a colour-transfer target."""
    if isinstance(target, TextureStatistics):
        return target.basis, [target.histogram(c, 0) for c in range(3)]
    values = check_shape(as_finite(target, "target"), "target", (..., 3))
    if values.size == 0:
        raise ValidationError(f"target must hold at least 2 pixels, got shape {values.shape}")
    pixels = masked_pixels(values, target_mask, "target", "target_mask")
    if pixels.shape[0] < 2:
        where = " inside target_mask" if target_mask is not None else ""
        raise ValidationError(
            f"target must hold at least 2 pixels{where}, got {pixels.shape[0]} (shape {values.shape})"
        )
    basis = decorrelating_basis(pixels)
    planes = basis.to_decorrelated(pixels, np.float64)
    return basis, [Histogram.from_data(planes[c], bins) for c in range(3)]


def transfer_colour(
    source_albedo, target, mask=None, *, target_mask=None, t: float = 1.0, bins: int = 256, feather: float = 0.0
) -> np.ndarray:
    """Skin-colour transfer: match the albedo histograms in a decorrelated colour space.

    Weyrich et al. 2006 §8 transfer skin-colour histograms between subjects
    (e.g. skin type II → V).  Source and target are expressed in the target's
    PCA colour basis (Heeger & Bergen 1995 §3.5, :func:`decorrelating_basis`);
    each of the three channels of the source (inside ``mask``) is matched to the
    target's ``bins``-bin histogram (:func:`match_histogram`), then transformed
    back to RGB and clipped to [0, 1].  Channels are matched independently
    (their joint distribution is not, Heeger & Bergen's approximation).

    Parameters
    ----------
    source_albedo : array_like, shape (H, W, 3)
        Linear RGB albedo of the face to edit (finite, at least one pixel).
    target : array_like, shape (..., 3), or TextureStatistics
        Target albedo (an image, or RGB samples, e.g. of a population subset;
        finite, at least 2 pixels inside ``target_mask``), or statistics whose
        image histograms and colour basis are used.
    mask : array_like of bool or int, shape (H, W), optional
        Pixels to edit (nonzero labels form one region); default all.
    target_mask : array_like of bool, shape target.shape[:-1], optional
        Pixels of the target image to use.
    t : float
        Interpolation weight in [0, 1]: each decorrelated value moves the
        fraction ``t`` towards its matched value (t = 0 leaves the source).
    bins : int
        Bins of the target histograms when ``target`` is an array, in [2, 65536]
        (:data:`facestats.edit.statistics.MAX_BINS`).
    feather : float
        Width in pixels of a linear blend inside the mask edge (0: hard edge).

    Returns
    -------
    numpy.ndarray, shape (H, W, 3)
        Edited albedo in the dtype of the source; pixels outside the mask are
        the source's, bit for bit.

    Raises
    ------
    ValidationError
        An argument of the wrong type, shape or domain (e.g. an empty source or
        target, whose message names it and its shape), checked before any work.
    """
    src = as_rgb_image(source_albedo, "source_albedo")
    t = check_t(t)
    bins = check_int(bins, "bins", 2)  # as every histogram of the edits: one bin matches nothing
    feather = check_feather(feather)
    labels, _ = mask_labels(mask, src.shape[:2])
    inside = np.ones(src.shape[:2], bool) if labels is None else labels > 0
    weights = feather_weights(inside, feather)  # checked before the work
    basis, hists = _target_colour(target, target_mask, bins)
    if t == 0.0:
        return src.copy()
    planes = basis.to_decorrelated(src)
    for c in range(3):
        planes[c][inside] = match_histogram(planes[c][inside], hists[c], t=t)
    edited = np.clip(basis.to_rgb(planes), 0.0, 1.0)
    return blend(src, edited, weights)
