"""Pyramid grids of maps of any size: padding, and a region's coefficients on every level.

The steerable pyramid (:mod:`facestats.edit.pyramid`) is circular and needs
each side to be a multiple of ``2**levels``.  The texture statistics and
synthesis (:mod:`facestats.edit.statistics`, :mod:`facestats.edit.texture`)
therefore pad a map by mirror reflection for the analysis and crop afterwards
(:func:`pad_shape`, :func:`padded_shape`, :func:`pad_plane`), and restrict a
region to the coefficients of level ``i`` whose ``2^i × 2^i`` pixel blocks are at
least half inside the region (or, if a region has no such block at a coarse
level, any block touching it): :func:`region_index`, :func:`grid_values`.
:func:`band_grids` maps each histogram band to its grid level;
:func:`supported_levels` is the most levels (at most 7, Weyrich et al. 2006 §8)
that maps of given shapes support.

Building blocks of the edit modules (public within the package, not
re-exported by :mod:`facestats.edit`).
"""

from __future__ import annotations

import numpy as np

from facestats.edit.pyramid import max_levels
from facestats.errors import ValidationError

__all__ = ["band_grids", "pad_shape", "padded_shape", "pad_plane", "region_index", "grid_values", "supported_levels"]


def band_grids(levels: int, orientations: int) -> list[int]:
    """Pyramid grid (level) of each statistics band: the image, the pyramid bands in order.

    Parameters
    ----------
    levels, orientations : int
        Pyramid settings.

    Returns
    -------
    list of int
        ``3 + levels * orientations`` grid levels (0 = full resolution), in the
        band order of :attr:`facestats.edit.TextureStatistics.band_names`.
    """
    return [0, 0] + [i for i in range(levels) for _ in range(orientations)] + [levels]


def pad_shape(shape, levels) -> tuple[int, ...]:
    """``shape`` with each side rounded up to a multiple of ``2**levels`` (the pyramid's grid).

    Parameters
    ----------
    shape : tuple of int
    levels : int

    Returns
    -------
    tuple of int
    """
    step = 1 << levels
    return tuple(-(-s // step) * step for s in shape)


def padded_shape(shape, levels):
    """:func:`pad_shape`, checked against the levels the padded grid supports.

    Parameters
    ----------
    shape : tuple of int
        Shape of the map.
    levels : int
        Pyramid levels.

    Returns
    -------
    tuple of int
    """
    padded = pad_shape(shape, levels)
    if levels > max_levels(padded):
        # The padding grows with the levels asked for: the limit is the largest count its own padding supports.
        most = max((k for k in range(1, 33) if k <= max_levels(pad_shape(shape, k))), default=0)
        raise ValidationError(
            f"levels must be at most {most} for a map of shape {tuple(shape)} "
            f"(the low-pass residual needs at least 4 pixels a side), got {levels}; the paper's 7 levels need "
            "maps of at least 385 pixels a side (padded to 512), e.g. those of the texture sample (512 x 512: "
            "--store texture-sample, facestats.pipeline.texture_sample)"
        )
    return padded


def pad_plane(plane, padded):
    """A 2-D plane padded by mirror reflection to ``padded`` (itself if it has that shape).

    Parameters
    ----------
    plane : numpy.ndarray, shape (H, W)
    padded : tuple of int
        Target shape, at least (H, W) (:func:`padded_shape`).

    Returns
    -------
    numpy.ndarray
    """
    h, w = plane.shape
    if (h, w) == padded:
        return plane
    return np.pad(plane, ((0, padded[0] - h), (0, padded[1] - w)), mode="symmetric")


def region_index(inside: np.ndarray | None, shape, padded, levels):
    """Flat coefficient indices of a region on grids 0…levels (None = the whole grid).

    Parameters
    ----------
    inside : numpy.ndarray of bool, shape ``shape``, or None
        The region (None: the whole map).
    shape, padded : tuple of int
        The map's shape and its padded shape.
    levels : int
        Pyramid levels.

    Returns
    -------
    list
        ``levels + 1`` entries: the flat indices of the region's coefficients on
        grid ``i`` (blocks at least half inside, else any block touching it), or
        None when the region is the whole (unpadded) grid.
    """
    if inside is None and tuple(shape) == tuple(padded):
        return [None] * (levels + 1)
    m = np.zeros(padded, bool)
    m[: shape[0], : shape[1]] = True if inside is None else inside
    out = [np.flatnonzero(m)]
    frac = m.astype(np.float32)
    for _ in range(levels):
        h, w = frac.shape
        frac = frac.reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3))
        idx = np.flatnonzero(frac >= 0.5)
        if idx.size == 0:
            idx = np.flatnonzero(frac > 0)
        out.append(idx)
    return out


def grid_values(arr, idx):
    """The values of a coefficient array at flat indices.

    Parameters
    ----------
    arr : numpy.ndarray
        A band or plane on one grid.
    idx : numpy.ndarray of int or None
        Flat indices (:func:`region_index`); None: every value.

    Returns
    -------
    numpy.ndarray, 1-D
        A view of ``arr`` for None, else a copy.
    """
    flat = arr.reshape(-1)
    return flat if idx is None else flat[idx]


def supported_levels(*shapes) -> int:
    """The most pyramid levels (at most 7, §8) that maps of every shape in ``shapes`` support.

    Parameters
    ----------
    *shapes : tuple of int
        Map shapes (each padded to the pyramid's grid, :func:`pad_shape`).

    Returns
    -------
    int
        0 if no level fits.
    """
    for levels in range(7, 0, -1):
        if all(levels <= max_levels(pad_shape(shape, levels)) for shape in shapes):
            return levels
    return 0
