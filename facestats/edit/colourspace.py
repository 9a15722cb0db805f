"""The decorrelated colour space of the edits (Heeger & Bergen 1995 §3.5).

Weyrich et al. 2006 §8 transform each albedo map "into a common and decorrelated
color space using the method discussed in [Heeger and Bergen 1995, §3.5]" before
matching histograms channel by channel.  Heeger & Bergen take the principal
components of the RGB pixel values: ``y = P (rgb - μ)`` with ``P`` the
eigenvectors of the RGB covariance (rows, by decreasing variance) and ``μ`` the
mean.  ``P`` is orthonormal, so the back transform is ``rgb = Pᵀ y + μ``.  The
target's basis is the common space: the source is expressed in the target's
principal axes, edited there and transformed back with the same basis
(:func:`facestats.edit.transfer_colour`, :func:`facestats.edit.transfer_texture`).

Albedo is linear RGB in [0, 1] with the channel last (R, G, B).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.core.validate import as_float, check_finite, check_shape
from facestats.errors import ValidationError

__all__ = ["ColourBasis", "decorrelating_basis", "masked_pixels"]


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
        """Channel planes ``y[c] = Σ_k P[c, k] (rgb[..., k] - μ[k])``, shape (3, ...).

        Parameters
        ----------
        rgb : array_like, shape (..., 3)
            Linear RGB, channel last.
        dtype : numpy.dtype, optional
            Float dtype of the computation and result; default float32/float64 input keeps its dtype, anything
            else becomes float64.

        Returns
        -------
        numpy.ndarray, shape (3, ...)
            The decorrelated planes, channel first.

        Raises
        ------
        ValidationError
            ``rgb`` not numeric or its last axis not of length 3.
        """
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
        """Inverse of :meth:`to_decorrelated`: ``rgb[..., k] = Σ_c P[c, k] y[c] + μ[k]``, channel last.

        Parameters
        ----------
        planes : array_like, shape (3, ...)
            Decorrelated planes, channel first (float32/float64 keeps its dtype, anything else becomes float64).

        Returns
        -------
        numpy.ndarray, shape (..., 3)
            Linear RGB in the dtype of ``planes``.

        Raises
        ------
        ValidationError
            ``planes`` not numeric or its first axis not of length 3.
        """
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


def masked_pixels(rgb, mask, name, mask_name):
    """Pixels (n, 3) of an image (..., 3) inside an optional boolean mask.

    Parameters
    ----------
    rgb : array_like, shape (..., 3)
        Finite linear RGB values.
    mask : array_like of bool, shape rgb.shape[:-1], or None
        Pixels to keep; None keeps all.
    name, mask_name : str
        Names of the arguments in error messages.

    Returns
    -------
    numpy.ndarray, shape (n, 3)
    """
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
    x = masked_pixels(rgb, mask, "rgb", "mask")
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
