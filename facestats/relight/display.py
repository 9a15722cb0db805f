"""Display of relit images: exposure for tone-mapped previews (the EXR keeps the linear radiance).

One job: choose the exposure that maps a high-dynamic-range relit image into
[0, 1] for an sRGB PNG without min-max normalising the data itself: a single
scale factor puts the ``percentile``-th percentile of the luminance of the
subject's pixels at ``target`` (highlights above it clip), and the sRGB
transfer function is applied by :func:`facestats.io.images.write_image`.
"""

from __future__ import annotations

import numpy as np

from facestats.core.validate import as_finite, as_scalar
from facestats.errors import ValidationError

__all__ = ["exposure_scale"]


def exposure_scale(image, mask=None, *, percentile: float = 99.0, target: float = 0.9) -> float:
    """Scale factor s so that the ``percentile`` of luminance over ``mask`` becomes ``target`` (1 for black images).

    ``image`` is linear radiance (not sRGB-encoded), shape (..., ≥3); its "luminance" here is the plain
    mean of R, G and B, not Rec. 709 Y: a scale for a preview, the same for any channel balance.

    Parameters
    ----------
    image : array_like, shape (..., C), C ≥ 3
        Linear relit image (finite); channels past the third are ignored.
    mask : array_like of bool, shape (...), optional
        The subject's pixels (default: every pixel), at least one.  Only pixels of positive luminance count.
    percentile : float
        Percentile of the luminance, in [0, 100].
    target : float
        Value that percentile is mapped to, in (0, 1].

    Returns
    -------
    float
        The scale s (1.0 when no pixel has positive luminance).

    Raises
    ------
    ValidationError
        For a non-finite ``image``, an image of fewer than 3 channels, a ``mask`` of another shape than the image's
        pixels or selecting none, ``percentile``/``target`` out of range, or a percentile so small that the scale is
        not a finite float (a subnormal luminance).
    """
    img = as_finite(image, "image", dtype=np.float64)
    p = as_scalar(percentile, "percentile", 0, 100)
    t = as_scalar(target, "target", 0, 1, low_inclusive=False)
    if img.ndim < 1 or img.shape[-1] < 3:
        raise ValidationError(f"image must have at least 3 channels on its last axis, got shape {img.shape}")
    lum = img[..., :3].mean(-1)
    if mask is not None:
        m = np.asarray(mask, bool)
        if m.shape != lum.shape:  # numpy raised an IndexError, or broadcast a mask of one row
            raise ValidationError(f"mask must have the image's pixel shape {lum.shape}, got {m.shape}")
        if not m.any():  # not a black subject: no subject at all (a mesh the camera missed gave "x1" silently)
            raise ValidationError("mask must select at least one pixel to choose an exposure over, got none")
        vals = lum[m]
    else:
        vals = lum.reshape(-1)
    vals = vals[vals > 0]
    if vals.size == 0:
        return 1.0
    scale = t / float(np.percentile(vals, p))
    if not np.isfinite(scale):
        raise ValidationError(
            f"image's {p:g}th luminance percentile {float(np.percentile(vals, p)):.3g} is too small for a finite "
            "exposure scale"
        )
    return scale
