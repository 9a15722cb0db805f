"""Photometric stereo: Lambertian normals and albedo from images under known distant lights (Woodham 1980).

One job: the per-pixel least-squares fit of a Lambertian lobe R = ρ/π max(N·l, 0)
to reflectance functions, used for the normals of one-light-at-a-time data
(:func:`photometric_stereo`, e.g. DiLiGenT folders read by
:func:`facestats.relight.olat.read_olat_folder`) and for the diffuse normal of the
colour-space separation (Debevec et al. 2000 §4.2, "fit a Lambertian lobe to the
diffuse component").  Samples that do not follow the lobe — attached and cast
shadows, specular highlights — are left out by weights: per pixel the darkest
and the brightest fractions of the samples (rank filtering, robust to the
unknown albedo).
"""

from __future__ import annotations

import numpy as np

from facestats.core.validate import as_scalar, check_shape
from facestats.errors import ValidationError
from facestats.relight.field import as_field, light_table

__all__ = ["lambertian_fit", "rank_weights", "photometric_stereo", "angular_error_deg"]


def lambertian_fit(values, directions, weights):
    """Per-pixel weighted least squares of a Lambertian lobe: values ≈ g·l over the weighted lights.

    Woodham 1980 (photometric stereo, "Photometric method for determining surface orientation
    from multiple images", Opt. Eng. 19(1)): with R = ρ/π N·l for every lit sample, g = ρ/π N
    solves the normal equations (Σ w l lᵀ) g = Σ w R l (three or more lights not in one plane),
    so N = g/‖g‖ and ρ = π‖g‖.  Radiometric convention: ``values`` are radiance per unit
    irradiance (sr⁻¹), so a white Lambertian surface gives 1/π at normal incidence.  The
    channels share the normal of their sum (an equal-weight R + G + B, not a photometric
    luminance).

    Parameters
    ----------
    values : array_like, shape (L, N) or (L, N, 3)
        Radiance per unit irradiance (R = ρ/π N·l for a Lambertian surface).
    directions : array_like, shape (L, 3)
        Unit vectors towards the lights.
    weights : array_like, shape (L, N)
        Sample weights ≥ 0 (0 for shadowed or specular samples).

    Returns
    -------
    normal : ndarray, shape (N, 3)
        g/‖g‖ of the channel sum (NaN where fewer than 3 independent lights).
    albedo : ndarray, shape (N,) or (N, 3)
        ρ = π ‖g‖ per channel, with every channel projected on the common normal:
        ρ_c = π Σ w y_c (N·l) / Σ w (N·l)².
    """
    y = np.asarray(values, np.float64)
    lit = np.asarray(directions, np.float64)
    w = np.asarray(weights, np.float64)
    ysum = y.sum(-1) if y.ndim == 3 else y
    a = np.einsum("ln,li,lj->nij", w, lit, lit)
    b = np.einsum("ln,ln,li->ni", w, ysum, lit)
    det = np.linalg.det(a)
    good = np.abs(det) > 1e-10 * np.maximum(np.einsum("nii->n", a), 1e-300) ** 3
    g = np.full(b.shape, np.nan)
    if good.any():
        g[good] = np.linalg.solve(a[good], b[good][..., None])[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        normal = g / np.linalg.norm(g, axis=-1, keepdims=True)
        cos = lit @ normal.T  # (L, N)
        den = (w * cos * cos).sum(0)
        if y.ndim == 3:
            albedo = np.pi * np.einsum("ln,lnc,ln->nc", w, y, cos) / den[:, None]
        else:
            albedo = np.pi * (w * y * cos).sum(0) / den
    return normal, albedo


def rank_weights(luminance, dark: float = 0.25, bright: float = 0.1):
    """Weights (L, N) that keep, per pixel, the samples between the ``dark`` and 1 − ``bright`` rank fractions.

    A trimmed least squares by rank, facestats' own rule (no paper's): the darkest samples of a
    pixel are the likeliest to be attached or cast shadows and the brightest to be highlights,
    whatever the pixel's albedo, the two kinds of sample photometric stereo must leave out
    (Barsky & Petrou 2003 detect them by other means).  ``luminance`` is any brightness that
    orders the samples (callers pass R + G + B).  Samples of zero luminance are always dropped.
    ``dark`` + ``bright`` < 1.

    Parameters
    ----------
    luminance : array_like, shape (L, N)
        Brightness of each pixel's samples, lights on axis 0 (ties are ranked in light order).
    dark : float
        Fraction of each pixel's darkest samples dropped (⌊dark · L⌋ of them), in [0, 1).
    bright : float
        Fraction of its brightest samples dropped (⌊bright · L⌋), in [0, 1).

    Returns
    -------
    numpy.ndarray of float64, shape of ``luminance``
        1 for the samples kept, 0 for the others (and for every sample of luminance ≤ 0).

    Raises
    ------
    ValidationError
        For ``dark`` or ``bright`` outside [0, 1), or ``dark`` + ``bright`` ≥ 1.
    """
    lum = np.asarray(luminance, np.float64)
    d = as_scalar(dark, "dark", 0, 1, high_inclusive=False)
    b = as_scalar(bright, "bright", 0, 1, high_inclusive=False)
    if d + b >= 1:
        raise ValidationError(f"dark + bright must be < 1, got {d} + {b}")
    n = lum.shape[0]
    ranks = np.argsort(np.argsort(lum, axis=0), axis=0)
    keep = (ranks >= int(np.floor(d * n))) & (ranks < n - int(np.floor(b * n))) & (lum > 0)
    return keep.astype(np.float64)


def photometric_stereo(field, *, dark: float = 0.25, bright: float = 0.1, mask=None):
    """Normals and albedo of every pixel of a reflectance field by robust Lambertian least squares.

    Woodham 1980's photometric stereo (:func:`lambertian_fit`) over the samples that
    :func:`rank_weights` keeps (ranked by R + G + B).

    Parameters
    ----------
    field : xarray.Dataset
        A reflectance field (any light set, e.g. :func:`facestats.relight.olat.read_olat_folder`).
    dark, bright : float
        Fractions of each pixel's darkest (shadows) and brightest (highlights)
        samples left out (:func:`rank_weights`).
    mask : array_like of bool, shape (y, x), optional
        Pixels to fit (default the field's ``mask``, else all).

    Returns
    -------
    normal : ndarray, shape (y, x, 3)
        Unit normals in the field's frame (NaN outside the mask or where unfit).
    albedo : ndarray, shape (y, x, 3)
        ρ per channel, in the field's unit (relative when the light intensities are).
    """

    f = as_field(field)
    dirs, _, _ = light_table(f)
    h, w = f.sizes["y"], f.sizes["x"]
    n_l = dirs.shape[0]
    if mask is None:
        mask = f["mask"].values if "mask" in f.data_vars else np.ones((h, w), bool)
    m = check_shape(np.asarray(mask, bool), "mask", (h, w)).reshape(h * w)
    vals = np.asarray(f["reflectance"].values, np.float64).reshape(n_l, h * w, 3)[:, m]
    wts = rank_weights(vals.sum(-1), dark, bright)
    nrm, alb = lambertian_fit(vals, dirs, wts)
    normal = np.full((h * w, 3), np.nan)
    albedo = np.full((h * w, 3), np.nan)
    normal[m], albedo[m] = nrm, alb
    return normal.reshape(h, w, 3), albedo.reshape(h, w, 3)


def angular_error_deg(normal, reference, mask=None) -> np.ndarray:
    """Angle between estimated and reference unit normals, degrees, over ``mask`` (flattened).

    Parameters
    ----------
    normal, reference : array_like, shape (..., 3)
        Normals of the same shape (both are normalised here; NaN normals give NaN angles).
    mask : array_like of bool, shape (...), optional
        Pixels to compare (default all).

    Returns
    -------
    numpy.ndarray of float64, shape (M,)
        Angles in [0, 180] degrees, one per selected pixel (M = number of True values of ``mask``).

    Raises
    ------
    ValidationError
        If the shapes differ, the last axis is not 3, or ``mask`` is not of the normals' shape without it.
    """
    a = np.asarray(normal, np.float64)
    b = np.asarray(reference, np.float64)
    if a.shape != b.shape or a.shape[-1] != 3:
        raise ValidationError(f"normal and reference must have the same shape (..., 3), got {a.shape}, {b.shape}")
    m = np.ones(a.shape[:-1], bool) if mask is None else check_shape(np.asarray(mask, bool), "mask", a.shape[:-1])
    cos = np.einsum("...k,...k->...", a[m], b[m]) / (np.linalg.norm(a[m], axis=-1) * np.linalg.norm(b[m], axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))
