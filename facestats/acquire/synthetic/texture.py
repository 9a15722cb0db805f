"""Skin texture of the synthetic population: albedo maps with tints, pores, freckles and moles.

Spot sizes and densities are physical (mm and per cm²), so the texture looks the
same at any map resolution: pores are dark 0.3 mm dots (5 per cm², densest where
the region map allows), freckles 2 mm melanin spots on cheeks, nose and forehead
(2 per cm², darkening blue and green more than red), moles 4 mm dark spots.
The external conditions of Weyrich et al. 2006 §7 change the albedo slightly
(makeup evens the texture and lightens it, powder lightens, heat reddens).
"""

from __future__ import annotations

import numpy as np

__all__ = ["albedo_map", "smooth_noise", "wrap_gaussian"]


#: Widest Gaussian (taps) :func:`wrap_gaussian` applies directly; wider ones go through the FFT.  The direct filter
#: costs taps × texels, and the callers' σ grows with the map (n / 10): at 4096² it took 50 s, against 0.8 s by FFT.
#: 65 taps is σ < 8.125 (truncated at 4σ): albedo noise of maps up to 81² (the default store's 48², σ = 4.8) and the
#: population's σ = n / 48 up to 389² keep the direct filter and its bits.
DIRECT_TAPS = 65


def wrap_gaussian(x, sigma_px, truncate=4.0):
    """``scipy.ndimage.gaussian_filter(x, sigma_px, mode="wrap", truncate=truncate)`` of a 2-D array, in O(n log n).

    The same truncated, normalised kernel (radius ``int(truncate σ + 0.5)``, weights ∝ exp(−x²/(2σ²)), as
    :func:`scipy.ndimage.gaussian_filter1d` builds it) applied along each axis as a circular convolution by FFT:
    the periodic extension of ``mode="wrap"`` is exactly circular.  Equal to SciPy's to rounding (≤ 1e-15 of the
    input's scale, tested); kernels of at most :data:`DIRECT_TAPS` taps go to SciPy directly.

    Parameters
    ----------
    x : array_like, shape (H, W)
        The field, periodic in both axes.
    sigma_px : float
        Gaussian σ in pixels, the same along both axes.
    truncate : float
        Kernel radius in σ.

    Returns
    -------
    ndarray, shape of ``x``
        ``x``'s float dtype, float64 for an integer ``x``.
    """
    from scipy.ndimage import gaussian_filter

    radius = int(truncate * float(sigma_px) + 0.5)
    if 2 * radius + 1 <= DIRECT_TAPS:
        return gaussian_filter(x, sigma_px, mode="wrap", truncate=truncate)
    dtype = np.asarray(x).dtype if np.asarray(x).dtype.kind == "f" else np.float64  # as gaussian_filter returns
    offsets = np.arange(-radius, radius + 1)
    w = np.exp(-0.5 * (offsets / float(sigma_px)) ** 2)
    w /= w.sum()
    out = np.asarray(x, np.float64)
    for axis in range(out.ndim):  # separable: one circular convolution per axis
        n = out.shape[axis]
        h = np.zeros(n)
        np.add.at(h, offsets % n, w)  # a kernel longer than the axis wraps onto itself, as mode="wrap" reads
        shape = [1] * out.ndim
        shape[axis] = n // 2 + 1
        spectrum = np.fft.rfft(h).reshape(shape)  # real and even: convolution equals SciPy's correlation
        out = np.fft.irfft(np.fft.rfft(out, axis=axis) * spectrum, n=n, axis=axis)
    return out.astype(dtype, copy=False)


def smooth_noise(rng, shape, sigma_px):
    """Gaussian-filtered white noise (periodic, :func:`wrap_gaussian`), scaled to unit standard deviation.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the white noise.
    shape : tuple of int
        Shape of the field, e.g. (H, W).
    sigma_px : float
        Gaussian σ in pixels.

    Returns
    -------
    ndarray of float64, shape ``shape``
    """
    z = wrap_gaussian(rng.standard_normal(shape), sigma_px)
    return z / max(z.std(), 1e-12)


def _spots(rng, shape, count, radius_px, strength_sampler):
    """A field of Gaussian spots scaled by strengths: each spot's integral is strength × 2π radius² texels.

    A spot of radius r (the Gaussian's σ, in texels) and strength s is s·exp(−d²/2r²): its peak is s and its
    integral s·2π r², i.e. s·2π r_mm² in mm² at any texel size (sampled on texels, a narrow spot's peak is
    lower: 0.72 s at r = 0.35, 0.97 s at 0.5; the integral is exact away from the map's edge).  A spot narrower
    than a texel cannot be drawn at that width, so it is blurred to σ = 0.35 texels (its footprint) and keeps
    its integral, which lowers its peak by a further (r / 0.35)²: the map holds each texel's area average.
    Scaling by 2π·0.35² instead (the blurred kernel's own integral, until 2026-12-07) made every sub-texel spot
    remove 0.77 s texels whatever its size in mm: the face-mean albedo of the default population's 149 subjects
    was 12 %, 3 % and 0.6 % darker at 24², 48² and 96² than it is now.
    """
    from scipy.ndimage import gaussian_filter

    field_ = np.zeros(shape)
    if count <= 0:
        return field_
    iy = rng.integers(0, shape[0], count)
    ix = rng.integers(0, shape[1], count)
    np.add.at(field_, (iy, ix), strength_sampler(count))
    out = gaussian_filter(field_, max(radius_px, 0.35), mode="constant")
    return out * (2 * np.pi * radius_px * radius_px)


def albedo_map(region_map, base_rgb, rng, *, texel_mm=2.5, freckles=False, moles=0, condition="normal"):
    """A textured albedo map for a face (module docstring).

    Parameters
    ----------
    region_map : ndarray of uint8, shape (n, n)
        Region labels (0 = not face).
    base_rgb : array_like, shape (3,)
        The subject's mean skin colour (linear RGB).
    rng : numpy.random.Generator
    texel_mm : float
        Texel size in mm (spot sizes are physical).
    freckles : bool
        Add freckles (melanin spots, 2 mm) on cheeks, nose and forehead.
    moles : int
        Number of moles (4 mm dark spots).
    condition : {"normal", "makeup", "powder", "hot", ...}
        The external condition of Weyrich et al. 2006 §7 (module docstring): makeup pulls the texture 40 % towards its
        mean and lightens it by 4 %, powder lightens by 5 %, heat reddens by 5 %; the others leave it as is.

    Returns
    -------
    ndarray of float32, shape (n, n, 3)
        Albedo in (0, 1), 0 outside the face.
    """
    n = region_map.shape[0]
    face = region_map > 0
    base = np.asarray(base_rgb, float)
    low = 1 + 0.06 * smooth_noise(rng, (n, n), max(n / 10, 1.0))
    tint = np.ones((n, n, 3))
    tints = {
        8: (1.12, 0.80, 0.85),
        6: (1.04, 0.97, 0.97),
        7: (1.03, 0.98, 0.98),
        3: (0.80, 0.78, 0.78),
        5: (0.94, 0.93, 0.95),
    }
    for r, t in tints.items():
        tint[region_map == r] = t
    from scipy.ndimage import gaussian_filter

    tint = gaussian_filter(tint, (max(n / 64, 0.5), max(n / 64, 0.5), 0))  # soft region borders
    alb = base[None, None, :] * low[..., None] * tint
    # Pores: small dark dots, densest on the nose and cheeks.
    n_pores = int(0.05 * texel_mm**2 * face.sum())  # 5 visible pores per cm²
    pores = _spots(rng, (n, n), n_pores, 0.3 / texel_mm, lambda k: rng.uniform(0.03, 0.08, k))
    alb *= (1 - np.clip(pores, 0, 0.3))[..., None]
    if freckles:
        allowed = np.isin(region_map, (2, 6, 7))
        k = int(0.02 * texel_mm**2 * allowed.sum())  # 2 freckles per cm²
        fr = _spots(rng, (n, n), k, 1.0 / texel_mm, lambda k_: rng.uniform(0.15, 0.35, k_)) * allowed
        # Melanin darkens blue and green more than red.
        alb *= 1 - np.clip(fr, 0, 0.6)[..., None] * np.array([0.45, 0.75, 0.85])
    if moles:
        mo = _spots(rng, (n, n), int(moles), 2.0 / texel_mm, lambda k_: rng.uniform(0.5, 0.8, k_))
        alb *= 1 - np.clip(mo, 0, 0.8)[..., None] * np.array([0.6, 0.75, 0.8])
    if condition == "makeup":  # foundation evens the texture and lightens slightly
        mean = alb[face].mean(axis=0)
        alb = mean + 0.6 * (alb - mean)
        alb *= 1.04
    elif condition == "powder":
        alb *= 1.05
    elif condition == "hot":
        alb *= np.array([1.05, 0.99, 0.99])
    alb = np.clip(alb, 0.01, 0.95)
    alb[~face] = 0
    return alb.astype(np.float32)
