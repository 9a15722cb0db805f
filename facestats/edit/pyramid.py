"""A real steerable pyramid built in the frequency domain (Simoncelli & Freeman 1995).

Weyrich et al. 2006 §8 analyse albedo texture with the steerable pyramid of
Heeger & Bergen 1995: seven levels of four oriented filters, down-sampling by two
per level, the first level a high-pass/low-pass pair.  This module builds that
pyramid with the same construction as pyrtools' ``SteerablePyramidFreq`` (the
MATLAB ``buildSFpyr`` of Simoncelli's matlabPyrTools), on real FFTs
(:func:`scipy.fft.rfft2`), in float32 or float64, with the masks cached per shape.

Construction
------------
On a grid of ``M_y × M_x`` samples, with frequencies ``f_y, f_x`` in cycles per
sample (|f| ≤ 1/2), let ``r = 2 sqrt(f_x² + f_y²)`` (1 at the Nyquist frequency of
an axis) and ``θ = atan2(f_y, f_x)``; rows are ``v`` (axis 0) and columns ``u``
(axis 1).  With ``x = log2 r``:

* high-pass ``H0(r) = cos(π/2 · x)`` on -1 ≤ x ≤ 0, 0 below, 1 above;
* low-pass ``L0(r) = -sin(π/2 · x)`` on -1 ≤ x ≤ 0, 1 below, 0 above,
  so ``H0² + L0² = 1`` exactly (raised-cosine transition of one octave, pyrtools
  ``twidth=1``);
* band-pass of a level ``B(r) = H0(2r)``;
* angular masks ``A_b(θ) = α_K cos^(K-1)(θ - π b / K)``, ``b = 0 … K-1``, with
  ``α_K² = 2^(2n) (n!)² / (K (2n)!)`` and ``n = K - 1``, so ``Σ_b A_b² = 1``
  (steerability of order ``n``).

Decomposition: ``X = F[image]``; ``highpass = F⁻¹[X H0]``; ``Y_0 = X L0``; at
level ``i`` the oriented bands are ``F⁻¹[i · Y_i B A_b]`` (real, the odd-symmetric
filters, pyrtools ``is_complex=False``), then ``Y_{i+1}`` is the central half of
``Y_i`` (down-sampling by two) times ``L0`` on the smaller grid; the last ``Y`` is
the low-pass residual.  Reconstruction applies the transposed filters and sums;
since ``L0² + B² Σ_b A_b² = 1`` and ``H0² + L0² = 1`` it is exact to rounding.

Differences from pyrtools
-------------------------
* pyrtools tabulates the masks (256 and 3072 samples) and interpolates linearly,
  so its masks differ from the closed forms above by up to ~5e-6 and its
  reconstruction is exact only to that order; here they are evaluated in closed
  form.
* Amplitude convention: here a band of level ``i`` is in the units of the image
  (a constant image has a low-pass residual equal to that constant).  pyrtools
  does not rescale after cropping the spectrum, so its level-``i`` bands are
  ``4**i`` times these and its low-pass residual ``4**levels`` times.
* Each image side must be divisible by ``2**levels`` (pyrtools accepts other
  sizes with an inexact reconstruction).  Boundaries are circular in both.

Band order (used by :mod:`facestats.edit.texture`): index 0 the high-pass
residual, then level 0 orientations 0…K-1, level 1, …, level ``levels-1``, and
last the low-pass residual: ``2 + levels·K`` bands (30 for 7 levels, 4
orientations).  Level ``i`` bands have shape ``(M_y/2^i, M_x/2^i)``; the low-pass
residual ``(M_y/2^levels, M_x/2^levels)``.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from facestats.core.validate import as_float, check_finite, check_integer, check_shape
from facestats.errors import ValidationError

__all__ = ["SteerablePyramid", "band_names", "max_levels"]


def max_levels(shape) -> int:
    """Largest number of levels for an image of ``shape``: ``floor(log2(min side)) - 2``.

    This is the limit of pyrtools' ``SteerablePyramidFreq`` (the low-pass residual
    keeps at least 4 samples on its shorter side).

    Parameters
    ----------
    shape : tuple of int
        Image shape.

    Returns
    -------
    int
        0 for images smaller than 8 pixels a side.
    """
    sides = [check_integer(n, "shape", 0) for n in shape]
    if not sides or min(sides) == 0:
        return 0  # an empty image holds no level (log2 of 0 is undefined)
    return max(int(math.floor(math.log2(min(sides)))) - 2, 0)


def band_names(levels: int = 7, orientations: int = 4) -> list[str]:
    """Names of the bands in pyramid order: ``highpass``, ``level{i}_orient{b}``…, ``lowpass``.

    Parameters
    ----------
    levels, orientations : int
        Pyramid settings (§8: 7, 4).

    Returns
    -------
    list of str
        ``2 + levels * orientations`` names.
    """
    names = ["highpass"]
    names += [f"level{i}_orient{b}" for i in range(levels) for b in range(orientations)]
    names.append("lowpass")
    return names


def _level_shapes(shape, levels):
    return [(shape[0] >> i, shape[1] >> i) for i in range(levels + 1)]


def _radius_angle(shape):
    """r = 2|f| and θ = atan2(f_y, f_x) on the rfft2 grid of an image of ``shape``.

    The DC sample gets the radius of its neighbour along axis 1 (as in pyrtools),
    which avoids log2(0); every mask is 0 or 1 there either way.
    """
    import scipy.fft as sfft

    fy = sfft.fftfreq(shape[0])[:, None]
    fx = sfft.rfftfreq(shape[1])[None, :]
    r = 2.0 * np.hypot(fy, fx)
    r[0, 0] = 2.0 / shape[1]
    theta = np.arctan2(fy, fx)
    return r, theta


def _lowpass_mask(r):
    """L0(r) = -sin(π/2 log2 r) for 1/2 ≤ r ≤ 1, 1 below, 0 above."""
    x = np.clip(np.log2(r), -1.0, 0.0)
    return -np.sin(0.5 * np.pi * x)


def _highpass_mask(r):
    """H0(r) = cos(π/2 log2 r) for 1/2 ≤ r ≤ 1, 0 below, 1 above."""
    x = np.clip(np.log2(r), -1.0, 0.0)
    return np.cos(0.5 * np.pi * x)


def _angular_constant(orientations):
    """α_K = sqrt(2^(2n) (n!)² / (K (2n)!)), n = K - 1, so that Σ_b A_b² = 1 (Simoncelli & Freeman 1995)."""
    n = orientations - 1
    return math.sqrt(2.0 ** (2 * n) * math.factorial(n) ** 2 / (orientations * math.factorial(2 * n)))


@functools.lru_cache(maxsize=8)
def _masks(shape, levels, orientations, dtype):
    """Frequency masks of a pyramid on the rfft2 grids (cached per shape).

    Returns ``(hi0, lo, oriented)``: ``hi0`` on grid 0; ``lo[i]`` the low-pass
    mask of grid ``i`` (``lo[0]`` is L0 on the full grid, ``lo[i+1]`` the one
    applied after down-sampling from level ``i``); ``oriented[i][b] = B A_b`` on
    grid ``i``.
    """
    shapes = _level_shapes(shape, levels)
    alpha = _angular_constant(orientations)
    order = orientations - 1
    hi0 = None
    los, oriented = [], []
    for i, s in enumerate(shapes):
        r, theta = _radius_angle(s)
        if i == 0:
            hi0 = _highpass_mask(r).astype(dtype)
        los.append(_lowpass_mask(r).astype(dtype))
        if i < levels:
            band = _highpass_mask(2.0 * r)
            oriented.append(
                tuple(
                    (alpha * np.cos(theta - np.pi * b / orientations) ** order * band).astype(dtype)
                    for b in range(orientations)
                )
            )
    for m in [hi0, *los, *(x for lev in oriented for x in lev)]:
        m.setflags(write=False)
    return hi0, tuple(los), tuple(oriented)


def _crop(spec, small):
    """The central (low-frequency) part of an rfft2 spectrum, for a grid of shape ``small``."""
    ny, nxh = small[0], small[1] // 2 + 1
    top = (ny + 1) // 2
    return np.concatenate([spec[:top, :nxh], spec[spec.shape[0] - (ny - top) :, :nxh]], axis=0)


def _embed(spec, big_shape, dtype):
    """Zero-pad an rfft2 spectrum of a small grid into the rfft2 layout of ``big_shape``."""
    ny = spec.shape[0]
    top = (ny + 1) // 2
    out = np.zeros((big_shape[0], big_shape[1] // 2 + 1), dtype=dtype)
    out[:top, : spec.shape[1]] = spec[:top]
    out[big_shape[0] - (ny - top) :, : spec.shape[1]] = spec[top:]
    return out


class SteerablePyramid:
    """Real frequency-domain steerable pyramid for images of one shape.

    Parameters
    ----------
    shape : tuple of int
        ``(rows, columns)`` of the images; each divisible by ``2**levels``.
    levels : int
        Number of oriented levels (Weyrich et al. 2006 §8: 7), at most
        :func:`max_levels` of ``shape``.
    orientations : int
        Oriented filters per level, 1-16 (§8: 4); the filters are derivatives of
        order ``orientations - 1``.
    dtype : {numpy.float32, numpy.float64}
        Working precision.  float32 halves memory and FFT time; float64
        reconstructs to ~1e-15 relative, float32 to ~1e-7.
    workers : int
        Threads for :mod:`scipy.fft`.

    Notes
    -----
    See the module docstring for the construction, the band order and the
    differences from pyrtools.  Masks are cached per ``(shape, levels,
    orientations, dtype)``, so building several pyramids of one shape is cheap.
    """

    def __init__(self, shape, levels: int = 7, orientations: int = 4, *, dtype=np.float32, workers: int = 2):
        if not isinstance(shape, (tuple, list, np.ndarray)) or len(shape) != 2:
            raise ValidationError(f"shape must be (rows, columns) of positive ints, got {shape!r}")
        shape = tuple(check_integer(s, "shape", 1) for s in shape)
        if not isinstance(levels, (int, np.integer)) or levels < 0:
            raise ValidationError(f"levels must be a non-negative int, got {levels!r}")
        if levels > max_levels(shape):
            raise ValidationError(
                f"levels must be at most {max_levels(shape)} for an image of shape {shape} "
                f"(floor(log2(min side)) - 2), got {levels}"
            )
        if any(s % (1 << levels) for s in shape):
            raise ValidationError(f"shape must be divisible by 2**levels = {1 << levels} on each side, got {shape}")
        if not isinstance(orientations, (int, np.integer)) or not 1 <= orientations <= 16:
            raise ValidationError(f"orientations must be an int in 1-16, got {orientations!r}")
        dtype = np.dtype(dtype)
        if dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
            raise ValidationError(f"dtype must be float32 or float64, got {dtype}")
        if not isinstance(workers, (int, np.integer)) or workers < 1:
            raise ValidationError(f"workers must be a positive int, got {workers!r}")
        self.shape = shape
        self.levels = int(levels)
        self.orientations = int(orientations)
        self.dtype = dtype
        self.workers = int(workers)
        self._cdtype = np.result_type(dtype, np.complex64)
        self._shapes = _level_shapes(shape, self.levels)
        self._hi0, self._lo, self._oriented = _masks(shape, self.levels, self.orientations, dtype)
        # (−i)^(K−1): the angular masks cos^(K−1) are odd about the origin for even K and even for odd K, so this
        # factor keeps every band's spectrum Hermitian (a real band); a fixed i lost the f_x = 0 column of the
        # bands for odd K (reconstruction error 0.34 on a smooth 256² image), as in pyrtools' buildSFpyr.
        self._phase = np.asarray((-1j) ** (self.orientations - 1), self._cdtype)

    @property
    def n_bands(self) -> int:
        """Number of bands: ``2 + levels * orientations``."""
        return 2 + self.levels * self.orientations

    @property
    def band_shapes(self) -> list[tuple[int, int]]:
        """Shape of each band, in band order."""
        out = [self.shape]
        for i in range(self.levels):
            out += [self._shapes[i]] * self.orientations
        out.append(self._shapes[self.levels])
        return out

    def band_level(self, index: int) -> int:
        """Grid level of band ``index`` (0 for the high-pass, ``levels`` for the low-pass).

        Parameters
        ----------
        index : int
            Band index in band order, 0 to ``n_bands - 1``.

        Returns
        -------
        int
            The level ``i`` whose grid the band lies on (shape ``band_shapes[index]``); an oriented band of
            level ``i`` has index ``1 + i * orientations + b``.

        Raises
        ------
        ValidationError
            ``index`` is not an integer in [0, ``n_bands - 1``].
        """
        index = check_integer(index, "index", 0, self.n_bands - 1)
        if index == 0:
            return 0
        if index == self.n_bands - 1:
            return self.levels
        return (index - 1) // self.orientations

    def _rfft(self, x):
        import scipy.fft as sfft

        return sfft.rfft2(x, norm="forward", workers=self.workers)

    def _irfft(self, spec, shape):
        import scipy.fft as sfft

        return sfft.irfft2(spec, s=shape, norm="forward", workers=self.workers, overwrite_x=True)

    def decompose(self, image) -> list[np.ndarray]:
        """Bands of ``image`` in band order (see the module docstring).

        Parameters
        ----------
        image : array_like, shape ``self.shape``
            Real, finite image; computed in ``self.dtype``.

        Returns
        -------
        list of numpy.ndarray
            ``2 + levels * orientations`` real arrays.
        """
        img = check_finite(check_shape(as_float(image, "image", self.dtype), "image", self.shape), "image")
        spec = self._rfft(img)
        bands = [self._irfft(spec * self._hi0, self.shape)]
        low = spec * self._lo[0]
        for i in range(self.levels):
            s = self._shapes[i]
            low_i = low * self._phase
            for mask in self._oriented[i]:
                bands.append(self._irfft(low_i * mask, s))
            low = _crop(low, self._shapes[i + 1])
            low *= self._lo[i + 1]
        bands.append(self._irfft(low, self._shapes[self.levels]))
        return bands

    def reconstruct(self, bands) -> np.ndarray:
        """The image whose pyramid is ``bands`` (the transpose of :meth:`decompose`).

        Exact inverse of :meth:`decompose` to rounding; for modified bands it is
        the least-squares image of the (tight-frame) pyramid.

        Parameters
        ----------
        bands : sequence of array_like
            ``n_bands`` real arrays of the shapes :attr:`band_shapes`, in band order; computed in ``self.dtype``.

        Returns
        -------
        numpy.ndarray, shape ``self.shape``
            The image, in ``self.dtype``.

        Raises
        ------
        ValidationError
            The wrong number of bands, or a band of the wrong shape.
        """
        if len(bands) != self.n_bands:
            raise ValidationError(f"bands must hold {self.n_bands} arrays, got {len(bands)}")
        for k, (b, s) in enumerate(zip(bands, self.band_shapes)):
            if np.shape(b) != s:
                raise ValidationError(f"bands[{k}] must have shape {s}, got {np.shape(b)}")
        low = self._rfft(np.asarray(bands[-1], self.dtype))
        conj_phase = np.conj(self._phase)
        for i in reversed(range(self.levels)):
            low *= self._lo[i + 1]
            acc = None
            for b, mask in enumerate(self._oriented[i]):
                term = self._rfft(np.asarray(bands[1 + i * self.orientations + b], self.dtype))
                term *= mask
                if acc is None:
                    acc = term
                else:
                    acc += term
            acc *= conj_phase
            acc += _embed(low, self._shapes[i], self._cdtype)
            low = acc
        low *= self._lo[0]
        hp = self._rfft(np.asarray(bands[0], self.dtype))
        hp *= self._hi0
        low += hp
        return self._irfft(low, self.shape)
