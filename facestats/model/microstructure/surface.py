"""Slopes, tangent-space normals and normal histograms of displacement maps (Nagano et al. 2015 §4-5).

Nagano et al. 2015 compare skin patches by "histograms of the surface
orientations" (§4), "splatting the surface normal computed at each pixel in
the displacement map into a grid of buckets, based on the u and v components
of the normal in tangent space" (§5, 64 × 64 buckets).  Conventions pinned down
here:

* Height gradient by central differences in texel units (one-sided at the
  map's edges): ``∂h/∂u[v, u] = (h[v, u+1] − h[v, u−1]) / 2``, likewise along v.
* A 2 × 2 ``jacobian`` J maps that texel gradient (height units per texel) to
  dimensionless slopes in the tangent frame, ``g = J ∇h``: J = I / texel_µm for
  a flat patch with heights in µm; ``A⁻ᵀ / texel_µm`` for the patch deformed by
  A (the neutral map "stretched or compressed ... to match the deformed shape",
  applied to the gradient exactly — the chain rule — instead of resampling the
  map, whose interpolation would smooth it); per texel ``T⁻ᵀ Mᵀ diag(W, H) /
  1000`` on a deforming mesh (:mod:`facestats.model.strain`: the slope along the
  deformed tangent frame of a map over the rest UV layout).
* Normal ``n = (−g_u, −g_v, 1) / √(1 + |g|²)`` in the tangent frame (t_u, t_v, n):
  t_u along +u, t_v along +v (down the map).
* Histogram: ``bins`` × ``bins`` buckets of (n_u, n_v) over ``[−extent, extent]²``
  (values outside go to the edge buckets, so every sample counts), indexed
  ``[n_v bucket, n_u bucket]``, as fractions summing to 1.  Total variation
  (eq. 7) = Σ_b |H_b − Ĥ_b| ∈ [0, 2].
"""

from __future__ import annotations

import numpy as np

from facestats.core.validate import as_finite, as_scalar, check_integer
from facestats.errors import ValidationError

__all__ = [
    "height_gradient",
    "slopes",
    "tangent_normals",
    "normal_histogram",
    "histogram_extent",
    "total_variation",
    "tv_noise",
]


def height_gradient(displacement):
    """Central-difference gradient ``(∂h/∂u, ∂h/∂v)`` in height units per texel, float64 (H, W) each.

    Parameters
    ----------
    displacement : array_like, shape (H, W)
        Heights, H, W ≥ 2 (one-sided differences at the edges).

    Returns
    -------
    gu, gv : ndarray of float64, shape (H, W)

    Raises
    ------
    ValidationError
        ``displacement`` not 2-D or smaller than 2 × 2.
    """
    h = np.asarray(displacement, np.float64)
    if h.ndim != 2 or min(h.shape) < 2:
        raise ValidationError(f"displacement must be a 2-D map of at least 2 x 2 texels, got shape {h.shape}")
    gv, gu = np.gradient(h)
    return gu, gv


def _jacobian(jacobian):
    j = as_finite(jacobian, "jacobian", dtype=np.float64)
    if j.shape[-2:] != (2, 2):
        raise ValidationError(f"jacobian must have shape (2, 2) or (H, W, 2, 2), got {j.shape}")
    return j


def slopes(displacement, jacobian):
    """Tangent-frame slopes ``g = J ∇h`` (dimensionless), float64 (H, W) each (module docstring).

    Parameters
    ----------
    displacement : array_like, shape (H, W)
        Heights (µm when ``jacobian`` carries 1/texel_µm).
    jacobian : array_like, shape (2, 2) or (H, W, 2, 2)
        Texel gradient → tangent slope, one for the map or one per texel.

    Returns
    -------
    gx, gy : ndarray of float64, shape (H, W)
        Slopes along t_u and t_v.

    Raises
    ------
    ValidationError
        A ``displacement`` not 2-D of at least 2 × 2 texels, or a non-finite or wrongly shaped ``jacobian``.
    """
    gu, gv = height_gradient(displacement)
    j = _jacobian(jacobian)
    if j.shape not in ((2, 2), gu.shape + (2, 2)):
        raise ValidationError(
            f"jacobian must have shape (2, 2) or {gu.shape + (2, 2)} (one per texel of the displacement), got {j.shape}"
        )
    return j[..., 0, 0] * gu + j[..., 0, 1] * gv, j[..., 1, 0] * gu + j[..., 1, 1] * gv


def tangent_normals(displacement, jacobian, dtype=np.float32):
    """Unit tangent-space normals (n_u, n_v, n_n) of a displacement map, shape (H, W, 3).

    Parameters
    ----------
    displacement : ndarray (H, W)
        Heights (µm when ``jacobian`` carries 1/texel_µm).
    jacobian : array_like, shape (2, 2) or (H, W, 2, 2)
        Texel gradient → tangent slope (module docstring).
    dtype : numpy dtype
        Of the returned normals.

    Returns
    -------
    ndarray, shape (H, W, 3)
        Unit normals (n_u, n_v, n_n), of ``dtype``.
    """
    gx, gy = slopes(displacement, jacobian)
    inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
    return np.stack([-gx * inv, -gy * inv, inv], -1).astype(dtype)


def _bins(bins):
    return check_integer(bins, "bins", 2, 4096)


def histogram_extent(*slope_pairs, quantile=0.999, margin=1.1) -> float:
    """A histogram half-width covering the normal components of the given slopes (``quantile`` × ``margin``).

    Parameters
    ----------
    *slope_pairs : tuple of 2 ndarray
        One or more (gx, gy) slope maps (:func:`slopes`), each pair of one shape, finite (as
        :func:`normal_histogram` takes them); at least one texel in all.
    quantile : float
        Quantile, in [0, 1], of max(|n_u|, |n_v|) over all their texels.
    margin : float
        Factor applied to that quantile, > 0.

    Returns
    -------
    float
        The half-width ``extent`` for :func:`normal_histogram`, clipped to [1e-6, 1].

    Raises
    ------
    ValidationError
        No slope pairs or no texels, a pair that is not two slope maps of one shape, non-finite slopes, or an
        invalid ``quantile`` or ``margin``.
    """
    if not slope_pairs:
        raise ValidationError("slope_pairs must hold at least one (gx, gy) pair of slope maps, got none")
    q = as_scalar(quantile, "quantile", 0, 1)
    k = as_scalar(margin, "margin", 0, None, low_inclusive=False)
    parts = []
    for i, pair in enumerate(slope_pairs):
        try:
            gx, gy = pair
        except (TypeError, ValueError):  # not iterable, or not of length 2
            raise ValidationError(
                f"slope pair {i} must be a (gx, gy) pair of slope maps, got {type(pair).__name__}"
            ) from None
        gx = as_finite(gx, f"gx of slope pair {i}", dtype=np.float64)  # a NaN would make the quantile NaN
        gy = as_finite(gy, f"gy of slope pair {i}", dtype=np.float64)
        if gx.shape != gy.shape:
            raise ValidationError(f"slope pair {i} must be gx and gy of one shape, got {gx.shape} and {gy.shape}")
        inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
        parts.append(np.maximum(np.abs(gx * inv), np.abs(gy * inv)).reshape(-1))
    components = np.concatenate(parts)
    if components.size == 0:
        raise ValidationError("slope_pairs must hold at least one texel, got only empty slope maps")
    ext = float(np.quantile(components, q)) * k
    return min(max(ext, 1e-6), 1.0)


def normal_histogram(gx, gy, *, bins=64, extent):
    """Histogram (fractions, shape (bins, bins), [n_v, n_u]) of the tangent normals of slopes (gx, gy).

    Parameters
    ----------
    gx, gy : array_like
        Tangent-frame slopes of one shape, non-empty, finite.
    bins : int
        Buckets per axis, in [2, 4096] (64 in Nagano et al. 2015 §5).
    extent : float
        Half-width of the histogram in normal components, in (0, 1]; values beyond go to the edge buckets.

    Returns
    -------
    ndarray of float64, shape (bins, bins)
        Fractions summing to 1, indexed [n_v bucket, n_u bucket].

    Raises
    ------
    ValidationError
        An invalid ``bins`` or ``extent``, non-finite slopes, or slopes of different shapes or none.
    """
    nb = _bins(bins)
    e = as_finite(extent, "extent", 0, 1, low_inclusive=False)
    if e.ndim:
        raise ValidationError(f"extent must be one number in (0, 1], got shape {e.shape}")
    e = float(e)
    gx, gy = as_finite(gx, "gx", dtype=np.float64), as_finite(gy, "gy", dtype=np.float64)  # a NaN has no bin
    if gx.shape != gy.shape or gx.size == 0:
        raise ValidationError(f"gx and gy must be non-empty slopes of one shape, got {gx.shape} and {gy.shape}")
    gx, gy = gx.reshape(-1), gy.reshape(-1)
    inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
    scale = nb / (2 * e)
    bu = np.clip(np.floor((-gx * inv + e) * scale), 0, nb - 1).astype(np.int64)
    bv = np.clip(np.floor((-gy * inv + e) * scale), 0, nb - 1).astype(np.int64)
    return (np.bincount(bv * nb + bu, minlength=nb * nb) / gx.size).reshape(nb, nb)


def total_variation(h1, h2) -> float:
    """Σ_b |H_b − Ĥ_b| of two histograms (eq. 7), in [0, 2] for histograms of fractions.

    Parameters
    ----------
    h1, h2 : array_like
        Two histograms of one shape (:func:`normal_histogram`).

    Returns
    -------
    float
    """
    return float(np.abs(np.asarray(h1) - np.asarray(h2)).sum())


def tv_noise(histogram, n_samples) -> float:
    """Expected total variation between two independent ``n_samples`` histograms of the distribution ``histogram``.

    Each bucket's fraction has standard deviation √(p (1 − p) / N); the difference
    of two independent estimates has E|Δ| = √(4 p (1 − p) / (π N)) (half-normal
    mean), summed over the buckets.  The TV values of a fit are not resolved
    below this level.

    Parameters
    ----------
    histogram : array_like
        Bucket probabilities p (fractions summing to 1).
    n_samples : int
        N, the samples (texels) of each histogram.

    Returns
    -------
    float
        Expected total variation.
    """
    p = np.asarray(histogram, np.float64).reshape(-1)
    return float(np.sqrt(4 * p * (1 - p) / (np.pi * float(n_samples))).sum())
