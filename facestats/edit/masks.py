"""Region masks of the edits: which texels an edit touches, and how the result is blended in.

Weyrich et al. 2006 §8 may "restrict the analysis/synthesis to certain facial
regions".  Every edit of :mod:`facestats.edit` takes its regions the same way:

* on arrays, a mask is None (the whole image), a bool map (one region) or an
  integer label map (0 outside, each label a region): :func:`mask_labels`;
* the edited image is blended into the source over ``feather`` pixels inside
  the mask edge (:func:`check_feather`, :func:`feather_weights`,
  :func:`blend`); texels outside the mask are the source's, bit for bit;
* on store subjects, regions are the labels 1-10 of the subject's region map
  (Weyrich Fig. 15), given by number or name: :func:`present_regions`,
  :func:`parse_regions`, :func:`face_mask`, :func:`region_labels`.

These are building blocks of the edit modules (public within the package, not
re-exported by :mod:`facestats.edit`).
"""

from __future__ import annotations

import warnings

import numpy as np

from facestats.core.conventions import parse_region
from facestats.core.validate import as_float, check_finite, check_range
from facestats.errors import FacestatsWarning, ValidationError

__all__ = [
    "mask_labels",
    "check_feather",
    "feather_weights",
    "blend",
    "present_regions",
    "parse_regions",
    "face_mask",
    "region_labels",
]


# --------------------------------------------------------------------------- masks of arrays


def mask_labels(mask, shape, name="mask") -> tuple[np.ndarray | None, list[int]]:
    """Normalise a region mask: None (everything), bool, or an integer label map.

    Parameters
    ----------
    mask : None or array_like of bool or int
        The mask; integer labels must be >= 0 (0 = outside).
    shape : tuple of int
        The image's shape (without the channel axis).
    name : str
        Name of the argument in error messages.

    Returns
    -------
    labels : numpy.ndarray or None
        None for the whole image, else an int array with 0 outside every region.
    ids : list of int
        The region labels present (for a bool mask or None: ``[1]``).
    """
    if mask is None:
        return None, [1]
    m = np.asarray(mask)
    if m.shape != tuple(shape):
        raise ValidationError(f"{name} must have shape {tuple(shape)}, got shape {m.shape}")
    if m.dtype == bool:
        labels = m.astype(np.int32)
    elif m.dtype.kind in "iu":
        labels = m.astype(np.int64)
        if labels.min(initial=0) < 0:
            raise ValidationError(f"{name} labels must be >= 0 (0 = outside), got {labels.min()}")
    else:
        raise ValidationError(f"{name} must be a bool mask or an integer label map, got dtype {m.dtype}")
    ids = [int(k) for k in np.unique(labels) if k != 0]
    if not ids:
        raise ValidationError(f"{name} must select at least one pixel, got none")
    return labels, ids


def check_feather(feather) -> float:
    """Validate a blend width.

    Parameters
    ----------
    feather : float
        Width in pixels, finite and >= 0.

    Returns
    -------
    float
    """
    f = as_float(feather, "feather", np.float64)
    if f.ndim != 0:
        raise ValidationError(f"feather must be a scalar >= 0 pixels, got an array of shape {f.shape}")
    check_range(check_finite(f, "feather"), "feather", 0.0, None, unit="pixels")
    return float(f)


def feather_weights(inside: np.ndarray, feather: float) -> np.ndarray:
    """Blend weights: ``min(1, d / feather)`` inside, 0 outside.

    ``d`` is the Euclidean distance in pixels from a pixel inside the mask to the
    nearest pixel outside (1 next to the edge); ``feather = 0`` gives a hard edge.
    The image border does not count as an edge.

    Parameters
    ----------
    inside : numpy.ndarray of bool
        The mask.
    feather : float
        Blend width in pixels (checked, :func:`check_feather`).

    Returns
    -------
    numpy.ndarray of float64, shape of ``inside``

    Raises
    ------
    ValidationError
        ``feather`` wider than the image.

    Warns
    -----
    FacestatsWarning
        ``feather`` wider than the mask's depth: no pixel gets the whole edit.
    """
    if inside.all():
        return np.ones(inside.shape, np.float64)
    if feather <= 0:
        return inside.astype(np.float64)
    if feather > max(inside.shape):
        raise ValidationError(
            f"feather must be at most the image's size, {max(inside.shape)} pixels (a blend wider than the image "
            f"leaves almost nothing of the edit), got {feather:g}"
        )
    from scipy import ndimage

    d = ndimage.distance_transform_edt(inside)
    depth = float(d.max())
    if feather > depth:  # a red team: feather 1000 on a 48² map kept 0.04 % of the edit, without a word
        warnings.warn(
            f"feather {feather:g} pixels exceeds the depth of the mask, {depth:g} pixels (the largest distance of "
            f"a pixel inside from its edge): no pixel gets the whole edit, at most {depth / feather:.0%} of it",
            FacestatsWarning,
            stacklevel=3,
        )
    return np.clip(d / feather, 0.0, 1.0)


def blend(source: np.ndarray, edited: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``w edited + (1 - w) source`` where ``w > 0``; the source itself (bit for bit) elsewhere.

    Parameters
    ----------
    source, edited : numpy.ndarray
        Images of one shape, (H, W) or (H, W, C).
    weights : numpy.ndarray, shape (H, W)
        Blend weights in [0, 1] (:func:`feather_weights`).

    Returns
    -------
    numpy.ndarray
        In the dtype of ``source``.
    """
    w = weights[..., None].astype(source.dtype) if edited.ndim == weights.ndim + 1 else weights.astype(source.dtype)
    mixed = w * edited + (1 - w) * source
    return np.where(w > 0, mixed, source)


# --------------------------------------------------------------------------- region maps of subjects


def present_regions(region) -> list[int]:
    """The nonzero labels of a region map, ascending.

    Parameters
    ----------
    region : array_like of int
        Region map (0 = outside the face).

    Returns
    -------
    list of int
    """
    return [int(r) for r in np.unique(region) if r != 0]


def parse_regions(regions, present, name="regions"):
    """Region numbers 1-10 from numbers or names, each present in ``present``; None stays None.

    Parameters
    ----------
    regions : None, int, str or iterable of int or str
        Regions by number (1-10) or name (:func:`facestats.core.conventions.parse_region`).
    present : list of int
        The regions of the subject's region map (:func:`present_regions`).
    name : str
        Name of the argument in error messages.

    Returns
    -------
    list of int or None
        Sorted, without duplicates.
    """
    if regions is None:
        return None
    if isinstance(regions, (str, int, np.integer)):
        regions = [regions]
    out = sorted({parse_region(r) for r in regions})
    if not out:
        raise ValidationError(f"{name} must name at least one region, got {regions!r}")
    missing = [r for r in out if r not in present]
    if missing:
        raise ValidationError(f"{name} must be regions of the subject's region map, got {missing} (present: {present})")
    return out


def face_mask(region, regions):
    """Texels of the face (``regions`` None) or of the listed regions, as a bool map.

    Parameters
    ----------
    region : numpy.ndarray of int
        Region map.
    regions : list of int or None

    Returns
    -------
    numpy.ndarray of bool
    """
    return region > 0 if regions is None else np.isin(region, regions)


def region_labels(region, regions):
    """The face as one region (bool map, ``regions`` None), else the listed regions' labels (0 elsewhere).

    Parameters
    ----------
    region : numpy.ndarray of int
        Region map.
    regions : list of int or None

    Returns
    -------
    numpy.ndarray of bool or int64
        A mask for :func:`mask_labels`: each listed region is matched on its own.
    """
    return region > 0 if regions is None else np.where(np.isin(region, regions), region, 0).astype(np.int64)
