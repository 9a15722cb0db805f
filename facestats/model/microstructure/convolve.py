"""Spatially varying two-pass convolution of a displacement map (Nagano et al. 2015 eq. 1-5).

Nagano et al. 2015 §5 "Deformation Model": the deformed microdisplacement map
is ``D' = D * K_{u,v}`` (eq. 1-2), approximated by two spatially varying 1-D
passes, first along the per-texel axis s (eq. 5: ``D^s = D *[s] k^s``), then
along t (eq. 4: ``D' = D^s *[t] k^t``), where ``*[a]`` samples ``D(u − i a_u,
v − i a_v)`` (eq. 3) and ``k = (1 − α) δ + α G(σ)`` (eq. 6, see
:mod:`~facestats.model.microstructure.kernel`).  The kernel of each texel is
the one of the output texel (a gather).

Conventions: ``displacement`` is indexed ``[v, u]`` (u indexes columns), heights
in µm (any unit works: the filter is linear); axes are unit vectors ``(a_u,
a_v)`` in texel units (u right, v down), t ⟂ s unless given; σ in µm of skin,
converted to texels by ``texel_um`` (µm per texel along each axis: a scalar,
(H, W), a pair ``(s, t)`` or (H, W, 2)).  Taps lie at whole texels of the axis's
major direction and are read across it by Lanczos-3
(:mod:`~facestats.model.microstructure.taps`; on the grid every tap is a texel).
Borders: taps stop at the first one that reads a texel outside the map or
the texel's UV island (``islands``; island 0 = gutter, copied unchanged) and the
Gaussian is renormalised over the taps used, so nothing is read across a gutter
or from outside the map.
"""

from __future__ import annotations

import math

import numpy as np

from facestats.core.compiled import resolve_backend
from facestats.core.validate import as_finite, as_float
from facestats.errors import ValidationError
from facestats.model.microstructure.compiled import convolve_pass, padded_empty
from facestats.model.microstructure.kernel import ALPHA_RANGE, MAX_RADIUS, SIGMA_RANGE_UM, TRUNCATE
from facestats.model.microstructure.taps import LANCZOS

__all__ = [
    "convolve_displacement",
    "island_reach",
    "displacement_limit",
    "MAX_PASS_GAIN",
    "LANCZOS_GAIN",
    "MAX_WEIGHT_SUM",
]

#: Bound of max|out| / max|in| of one pass: Σ|k_i| ≤ 1 + 2 max|α| (eq. 6: for α < 0 the centre tap is
#: 1 + |α| (1 − G_0) and the side taps sum to |α| (1 − G_0); for α ≥ 0 all taps are ≥ 0 and sum to 1;
#: renormalising at a border keeps both), times :data:`LANCZOS_GAIN`.
LANCZOS_GAIN = float(np.abs(LANCZOS).sum(axis=1).max())
MAX_PASS_GAIN = (1.0 + 2.0 * max(abs(a) for a in ALPHA_RANGE)) * LANCZOS_GAIN
#: Bound of Σ g_i, the unnormalised Gaussian weights a pass sums before dividing by them:
#: Σ_i exp(−i² / (2 s²)) ≤ 1 + 2 ∫_0^∞ exp(−x² / (2 s²)) dx = 1 + s √(2π) (a decreasing summand), with
#: s ≤ MAX_RADIUS / TRUNCATE taps (the largest kernel :func:`convolve_displacement` accepts).
MAX_WEIGHT_SUM = 1.0 + math.sqrt(2.0 * math.pi) * MAX_RADIUS / TRUNCATE


def displacement_limit(dtype) -> float:
    """Largest |value| of a displacement map of ``dtype`` that the two passes convolve without overflow.

    Each pass stores its result in the map's dtype, at most :data:`MAX_PASS_GAIN` times its input, so two
    passes need ``max|D| · MAX_PASS_GAIN² ≤`` the dtype's largest number.  Each tap reads its value from
    Lanczos-3 weights in the map's dtype (at most :data:`LANCZOS_GAIN` times the input) and the pass sums
    ``g_i`` times these in float64 before dividing by Σ g_i, so the second pass also needs
    ``max|D| · MAX_PASS_GAIN · LANCZOS_GAIN · MAX_WEIGHT_SUM ≤`` float64's largest number.  The smaller bound,
    with 0.1 % to spare for rounding: about 5.7e36 for float32 and 4.4e303 for float64, far beyond any
    displacement (µm), so only damaged or hostile maps meet it (a float32 map of ±3e38 sharpened to inf).

    Parameters
    ----------
    dtype : numpy dtype
        float32 or float64.

    Returns
    -------
    float
    """
    stored = float(np.finfo(dtype).max) / MAX_PASS_GAIN**2
    summed = float(np.finfo(np.float64).max) / (MAX_PASS_GAIN * LANCZOS_GAIN * MAX_WEIGHT_SUM)
    return min(stored, summed) / 1.001


def _bounded(arr, name, low=None, high=None, unit=""):
    """Check finiteness and range by a min and a max (no temporaries the size of a 4K map).

    Only when the check fails is the array handed to :func:`facestats.core.validate.as_finite`,
    which raises the standard message naming the argument and the offending value.
    """
    if arr.size:
        lo, hi = float(np.min(arr)), float(np.max(arr))  # NaN propagates through min and max
        ok = np.isfinite(lo) and np.isfinite(hi)
        ok = ok and (low is None or lo >= low) and (high is None or hi <= high)
        if not ok:
            as_finite(arr, name, low, high, unit=unit)
    return arr


def _map(displacement):
    d = np.asarray(displacement)
    if d.dtype not in (np.float32, np.float64):
        raise ValidationError(f"displacement must be a float32 or float64 map, got dtype {d.dtype}")
    if d.ndim != 2 or min(d.shape) < 1:
        raise ValidationError(f"displacement must be a 2-D map (v, u), got shape {d.shape}")
    limit = displacement_limit(d.dtype)
    return _bounded(d, "displacement", -limit, limit)


def _field(value, name, shape, bounds, unit=""):
    """A per-texel float32 parameter (a broadcast view for scalars), validated against ``bounds``."""
    arr = as_float(value, name)
    if arr.ndim not in (0, 2) or (arr.ndim == 2 and arr.shape != shape):
        raise ValidationError(f"{name} must be a scalar or a map of shape {shape}, got shape {arr.shape}")
    arr = _bounded(arr, name, *bounds, unit=unit)
    return np.broadcast_to(arr.astype(np.float32, copy=False), shape)


def _axes(axis_s, axis_t, shape):
    """Unit s and t axes as (au, av) float32 pairs of (H, W) views."""

    def unit(a, name):
        a = _bounded(as_float(a, name, np.float32), name)
        if a.shape not in ((2,), shape + (2,)):
            raise ValidationError(f"{name} must have shape (2,) or {shape + (2,)}, got {a.shape}")
        au, av = a[..., 0], a[..., 1]
        n2 = au * au + av * av
        lo, hi = float(np.min(n2)), float(np.max(n2))
        if lo < 1 - 2e-3 or hi > 1 + 2e-3:  # |norm - 1| > 1e-3
            bad = lo if lo < 1 - 2e-3 else hi
            raise ValidationError(f"{name} must hold unit vectors (norm 1 ± 1e-3), got norm {np.sqrt(bad):.6g}")
        if lo < 1 - 1e-6 or hi > 1 + 1e-6:  # renormalise what float32 rounding cannot explain
            n = np.sqrt(n2)
            au, av = au / n, av / n
        return np.broadcast_to(au, shape), np.broadcast_to(av, shape)

    su, sv = unit(axis_s, "axis_s")
    if axis_t is None:
        return (su, sv), (-sv, su)  # t = s rotated by 90 degrees
    return (su, sv), unit(axis_t, "axis_t")


def _texel_sizes(texel_um, shape):
    t = as_float(texel_um, "texel_um")
    t = _bounded(t, "texel_um")
    if t.shape in ((), shape):
        pair = (t, t)
    elif t.shape in ((2,), shape + (2,)):
        pair = (t[..., 0], t[..., 1])
    else:
        raise ValidationError(f"texel_um must be a scalar, (2,), {shape} or {shape + (2,)}, got shape {t.shape}")
    if t.size and float(np.min(t)) <= 0:
        raise ValidationError(f"texel_um must be > 0 um, got {float(np.min(t))!r}")
    return tuple(np.broadcast_to(p.astype(np.float32, copy=False), shape) for p in pair)


def _check_kernel_size(s_s, px_s, s_t, px_t):
    """Both passes' widest kernel within :data:`MAX_RADIUS` taps (as :func:`gaussian_taps` requires of one kernel).

    Compared without a division: a texel size that rounds to 0 in float32 (1e-300 um) is refused here, not met
    as a division by zero in the compiled pass.
    """
    for sigma, px in ((s_s, px_s), (s_t, px_t)):
        if sigma.size:
            top, texel = float(np.max(sigma)), float(np.min(px))
            if not texel * MAX_RADIUS >= TRUNCATE * top:
                raise ValidationError(
                    f"texel_um must be at least {TRUNCATE * top / MAX_RADIUS:.3g} um for sigma up to {top:g} um "
                    f"(kernels of at most {2 * MAX_RADIUS + 1} taps, MAX_RADIUS), got {texel:.3g} um (as float32)"
                )


def island_reach(islands) -> np.ndarray:
    """Distance (texels, float32) from each texel to the nearest texel with another island in its 3 × 3 block.

    Texels next to the map border count as next to another island.  Every texel a
    straight line from the texel to a point d texels away passes through lies within
    d + √2/2 of the texel, so where the reach exceeds d + 1 every texel up to d away is
    in the texel's own island.  Taps lie up to n / |a_major| texels away (n taps each
    side) and read up to 3 texels across (Lanczos-3), so the compiled pass skips the
    per-tap checks where the reach exceeds n / |a_major| + 4.

    Parameters
    ----------
    islands : array_like of int, shape (H, W)
        UV island label of each texel (0 = gutter; any integers: the map border is marked as such, not by a
        label reserved for the outside).

    Returns
    -------
    ndarray of float32, shape (H, W)
        The Euclidean distance in texels (0 on a texel that has another island, or the border, among its
        8 neighbours).
    """
    from scipy.ndimage import distance_transform_edt, maximum_filter, minimum_filter

    lab = np.asarray(islands, np.int64)
    if lab.size == 0:
        return np.zeros(lab.shape, np.float32)
    # no padding label for the outside: an island could carry it (e.g. −1) and hide the border
    boundary = (maximum_filter(lab, 3, mode="nearest") != lab) | (minimum_filter(lab, 3, mode="nearest") != lab)
    boundary[[0, -1], :] = True  # the texels next to the map border
    boundary[:, [0, -1]] = True
    return distance_transform_edt(~boundary).astype(np.float32)


def _islands(islands, shape):
    if islands is None:
        return None, None
    lab = np.asarray(islands)
    if lab.shape != shape or lab.dtype.kind not in "iub":
        raise ValidationError(f"islands must be an integer map of shape {shape}, got {lab.dtype} {lab.shape}")
    lab = lab.astype(np.int32)
    return lab, island_reach(lab)


def convolve_displacement(
    displacement,
    axis_s,
    alpha_s,
    sigma_s,
    alpha_t,
    sigma_t,
    texel_um,
    *,
    axis_t=None,
    islands=None,
    backend="auto",
):
    """Convolve a displacement map along per-texel strain axes (Nagano et al. 2015 eq. 1-6).

    Parameters
    ----------
    displacement : ndarray, shape (H, W), float32 or float64
        Neutral displacement map D, indexed ``[v, u]``; |values| at most :func:`displacement_limit` of its dtype.
    axis_s : array_like, shape (2,) or (H, W, 2)
        Unit direction ``(a_u, a_v)`` of the first pass (the stretch axis), texel units.
    alpha_s, sigma_s : float or ndarray (H, W)
        Kernel k^s: strength α ∈ [−2, 1] and Gaussian σ ∈ [1, 100] µm.
    alpha_t, sigma_t : float or ndarray (H, W)
        Kernel k^t of the second pass, along t.
    texel_um : float or ndarray
        µm of skin per texel step: scalar or (H, W) for both axes, (2,) or
        (H, W, 2) for the s and t axes separately.
    axis_t : array_like, optional
        Direction of the second pass; default s rotated by 90° (t ⟂ s).
    islands : ndarray of int, shape (H, W), optional
        UV island of each texel (0 = gutter, left unchanged); taps never leave their island.
    backend : {"auto", "numba", "numpy"}
        Compiled kernel (default when numba is installed) or the pure-numpy fallback.

    Returns
    -------
    ndarray, shape (H, W), dtype of ``displacement``
        The deformed displacement map D'.

    Raises
    ------
    ValidationError
        A bad argument, named; among them a displacement beyond :func:`displacement_limit` of its dtype (a
        sharpening pass could overflow it to inf).
    """
    d = _map(displacement)
    shape = d.shape
    backend = resolve_backend(backend)
    (su, sv), (tu, tv) = _axes(axis_s, axis_t, shape)
    a_s, a_t = _field(alpha_s, "alpha_s", shape, ALPHA_RANGE), _field(alpha_t, "alpha_t", shape, ALPHA_RANGE)
    s_s = _field(sigma_s, "sigma_s", shape, SIGMA_RANGE_UM, "um")
    s_t = _field(sigma_t, "sigma_t", shape, SIGMA_RANGE_UM, "um")
    px_s, px_t = _texel_sizes(texel_um, shape)
    _check_kernel_size(s_s, px_s, s_t, px_t)
    lab, reach = _islands(islands, shape)
    d_s = padded_empty(shape, d.dtype)  # read again by the second pass: rows that do not alias in the caches
    convolve_pass(d, d_s, su, sv, a_s, s_s, px_s, lab, reach, truncate=TRUNCATE, backend=backend)  # eq. 5
    out = np.empty_like(d)
    convolve_pass(d_s, out, tu, tv, a_t, s_t, px_t, lab, reach, truncate=TRUNCATE, backend=backend)  # eq. 4
    return out
