"""Decorrelated colour space and skin-colour transfer.

Weyrich et al. 2006 §8 transform each albedo map "into a common and decorrelated
color space using the method discussed in [Heeger and Bergen 1995, §3.5]" before
matching histograms channel by channel.  Heeger & Bergen take the principal
components of the RGB pixel values: ``y = P (rgb - μ)`` with ``P`` the
eigenvectors of the RGB covariance (rows, by decreasing variance) and ``μ`` the
mean.  ``P`` is orthonormal, so the back transform is ``rgb = Pᵀ y + μ``.  The
target's basis is the common space: the source is expressed in the target's
principal axes, edited there and transformed back with the same basis.

Colour transfer (§8: "transfer skin color histograms from one subject to
another ... change the skin type, e.g. from II to V") matches the histogram of
each decorrelated channel of the source to the target's
(:func:`facestats.edit.histogram.match_histogram`), optionally part-way
(``t``) and inside a region mask.

Albedo is linear RGB in [0, 1] with the channel last (R, G, B).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.core.validate import as_float, check_finite, check_range, check_shape
from facestats.edit.histogram import Histogram, _check_t, match_histogram
from facestats.errors import ValidationError

__all__ = ["ColourBasis", "decorrelating_basis", "transfer_colour"]


@dataclass(frozen=True)
class ColourBasis:
    """An orthonormal decorrelating colour transform ``y = P (rgb - μ)``.

    Parameters
    ----------
    mean : array_like, shape (3,)
        μ, the mean linear RGB of the pixels the basis was fitted on.
    axes : array_like, shape (3, 3)
        P: row ``c`` is the ``c``-th principal axis (unit vector in RGB).
    variances : array_like, shape (3,)
        Variance of the pixels along each axis (decreasing).
    """

    mean: np.ndarray
    axes: np.ndarray
    variances: np.ndarray

    def __post_init__(self):
        m = check_shape(check_finite(as_float(self.mean, "mean", np.float64), "mean"), "mean", (3,))
        p = check_shape(check_finite(as_float(self.axes, "axes", np.float64), "axes"), "axes", (3, 3))
        v = check_shape(check_finite(as_float(self.variances, "variances", np.float64), "variances"), "variances", (3,))
        if not np.allclose(p @ p.T, np.eye(3), atol=1e-9):
            dev = float(np.abs(p @ p.T - np.eye(3)).max())
            raise ValidationError(f"axes must be orthonormal (P Pᵀ = I), got max |P Pᵀ - I| = {dev:.3g}")
        object.__setattr__(self, "mean", m)
        object.__setattr__(self, "axes", p)
        object.__setattr__(self, "variances", v)

    def to_decorrelated(self, rgb, dtype=None) -> np.ndarray:
        """Channel planes ``y[c] = Σ_k P[c, k] (rgb[..., k] - μ[k])``, shape (3, ...)."""
        x = as_float(rgb, "rgb", dtype)
        check_shape(x, "rgb", (..., 3))
        out = np.empty((3,) + x.shape[:-1], x.dtype)
        centred = [x[..., k] - x.dtype.type(self.mean[k]) for k in range(3)]
        for c in range(3):
            w = self.axes[c].astype(x.dtype)
            np.multiply(centred[0], w[0], out=out[c])
            out[c] += w[1] * centred[1]
            out[c] += w[2] * centred[2]
        return out

    def to_rgb(self, planes) -> np.ndarray:
        """Inverse of :meth:`to_decorrelated`: ``rgb[..., k] = Σ_c P[c, k] y[c] + μ[k]``, channel last."""
        y = as_float(planes, "planes")
        if y.shape[:1] != (3,):
            raise ValidationError(f"planes must have shape (3, ...), got shape {y.shape}")
        out = np.empty(y.shape[1:] + (3,), y.dtype)
        for k in range(3):
            w = self.axes[:, k].astype(y.dtype)
            acc = w[0] * y[0]
            acc += w[1] * y[1]
            acc += w[2] * y[2]
            acc += y.dtype.type(self.mean[k])
            out[..., k] = acc
        return out


def _pixels(rgb, mask, name, mask_name):
    """Pixels (n, 3) of an image (..., 3) inside an optional boolean mask."""
    x = check_finite(as_float(rgb, name), name)
    check_shape(x, name, (..., 3))
    if mask is None:
        return x.reshape(-1, 3)
    m = np.asarray(mask)
    if m.shape != x.shape[:-1]:
        raise ValidationError(f"{mask_name} must have shape {x.shape[:-1]}, got shape {m.shape}")
    return x[m.astype(bool)]


def decorrelating_basis(rgb, mask=None) -> ColourBasis:
    """PCA colour basis of linear-RGB pixels (Heeger & Bergen 1995 §3.5).

    Parameters
    ----------
    rgb : array_like, shape (..., 3)
        Linear RGB pixels (an image or a list of samples).
    mask : array_like of bool, shape rgb.shape[:-1], optional
        Pixels to use.

    Returns
    -------
    ColourBasis
        Axes sorted by decreasing variance; each axis' sign is chosen so that its
        largest component is positive (a deterministic choice; PCA leaves it free).
    """
    x = _pixels(rgb, mask, "rgb", "mask")
    if x.shape[0] < 1:
        raise ValidationError("rgb must hold at least one pixel inside mask, got none")
    mean = x.mean(axis=0, dtype=np.float64)
    xc = x.astype(np.float64) - mean
    cov = xc.T @ xc / x.shape[0]
    w, v = np.linalg.eigh(cov)
    order = np.argsort(w)[::-1]
    axes = v[:, order].T
    axes *= np.where(axes[np.arange(3), np.argmax(np.abs(axes), axis=1)] < 0, -1.0, 1.0)[:, None]
    return ColourBasis(mean, axes, np.clip(w[order], 0.0, None))


# --------------------------------------------------------------------------- region masks


def _labels(mask, shape, name="mask") -> tuple[np.ndarray | None, list[int]]:
    """Normalise a region mask: None (everything), bool, or an integer label map.

    Returns ``(labels, ids)``: ``labels`` is None for the whole image or an int
    array with 0 outside every region; ``ids`` the region labels present (for a
    bool mask: ``[1]``).
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


def _feather_weights(inside: np.ndarray, feather: float) -> np.ndarray:
    """Blend weights: ``min(1, d / feather)`` inside, 0 outside.

    ``d`` is the Euclidean distance in pixels from a pixel inside the mask to the
    nearest pixel outside (1 next to the edge); ``feather = 0`` gives a hard edge.
    The image border does not count as an edge.
    """
    if inside.all():
        return np.ones(inside.shape, np.float64)
    if feather <= 0:
        return inside.astype(np.float64)
    from scipy import ndimage

    d = ndimage.distance_transform_edt(inside)
    return np.clip(d / feather, 0.0, 1.0)


def _check_feather(feather) -> float:
    f = as_float(feather, "feather", np.float64)
    if f.ndim != 0:
        raise ValidationError(f"feather must be a scalar >= 0 pixels, got an array of shape {f.shape}")
    check_range(check_finite(f, "feather"), "feather", 0.0, None, unit="pixels")
    return float(f)


def _blend(source: np.ndarray, edited: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``w edited + (1 - w) source`` where ``w > 0``; the source itself (bit for bit) elsewhere."""
    w = weights[..., None].astype(source.dtype) if edited.ndim == weights.ndim + 1 else weights.astype(source.dtype)
    mixed = w * edited + (1 - w) * source
    return np.where(w > 0, mixed, source)


# --------------------------------------------------------------------------- colour transfer


def _target_colour(target, target_mask, bins):
    """(ColourBasis, [Histogram × 3]) of a colour-transfer target."""
    from facestats.edit.texture import TextureStatistics  # texture imports this module

    if isinstance(target, TextureStatistics):
        return target.basis, [target.histogram(c, 0) for c in range(3)]
    pixels = _pixels(target, target_mask, "target", "target_mask")
    if pixels.shape[0] < 2:
        raise ValidationError(f"target must hold at least 2 pixels inside target_mask, got {pixels.shape[0]}")
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
        Linear RGB albedo of the face to edit.
    target : array_like, shape (..., 3), or TextureStatistics
        Target albedo (an image, or RGB samples, e.g. of a population subset),
        or statistics whose image histograms and colour basis are used.
    mask : array_like of bool or int, shape (H, W), optional
        Pixels to edit (nonzero labels form one region); default all.
    target_mask : array_like of bool, shape target.shape[:-1], optional
        Pixels of the target image to use.
    t : float
        Interpolation weight in [0, 1]: each decorrelated value moves the
        fraction ``t`` towards its matched value (t = 0 leaves the source).
    bins : int
        Bins of the target histograms when ``target`` is an array.
    feather : float
        Width in pixels of a linear blend inside the mask edge (0: hard edge).

    Returns
    -------
    numpy.ndarray, shape (H, W, 3)
        Edited albedo in the dtype of the source; pixels outside the mask are
        the source's, bit for bit.
    """
    src = check_finite(as_float(source_albedo, "source_albedo"), "source_albedo")
    check_shape(src, "source_albedo", (None, None, 3))
    t = _check_t(t)
    feather = _check_feather(feather)
    labels, _ = _labels(mask, src.shape[:2])
    inside = np.ones(src.shape[:2], bool) if labels is None else labels > 0
    basis, hists = _target_colour(target, target_mask, bins)
    if t == 0.0:
        return src.copy()
    planes = basis.to_decorrelated(src)
    for c in range(3):
        planes[c][inside] = match_histogram(planes[c][inside], hists[c], t=t)
    edited = np.clip(basis.to_rgb(planes), 0.0, 1.0)
    return _blend(src, edited, _feather_weights(inside, feather))
