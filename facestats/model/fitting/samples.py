"""Lumitexel samples as flat arrays: the data structure every fit stage works on.

A lumitexel gathers up to (cameras × lights) BRDF samples but only a fraction is
valid (about 900 of 2,400 in the default dome, §5).  Rather than dense
(lumitexel, camera, light) grids that are mostly empty, the stages keep only the
valid samples, sorted by lumitexel, as flat arrays: the lumitexel, camera and
light of each sample and its radiance and irradiance (channel-major, so every
channel is contiguous).  Directions stay on the per-lumitexel grids they come
from (towards each light, towards each camera); the stages need only cosines
(N·ωi, N·ωo, ωi·ωo), which are computed on the small grids and gathered per
sample, so no per-sample 3-vector is ever built.  Because the samples of a
lumitexel are contiguous, per-lumitexel sums are ``np.bincount`` over the
lumitexel index (:meth:`Samples.sum`) or ``np.add.reduceat`` over the runs (the
specular solver); per-lumitexel order statistics use a padded
(lumitexel, rank) layout (:meth:`Samples.ranks`, :meth:`Samples.padded`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...errors import ValidationError

__all__ = ["Samples"]


@dataclass
class Samples:
    """Valid samples of ``n_texels`` lumitexels, sorted by lumitexel.

    Attributes
    ----------
    n_texels : int
    texel : ndarray of int32, shape (S,)
        Lumitexel of each sample (non-decreasing).
    camera, light : ndarray of int32, shape (S,)
        Index of each sample's outgoing and incident direction in ``wo_grid`` and ``wi_grid``.
    wi_grid : ndarray of float32, shape (n, L, 3)
        Unit directions from each lumitexel towards each light.
    wo_grid : ndarray of float32, shape (n, C, 3)
        Unit directions from each lumitexel towards each camera.
    radiance : ndarray of float32, shape (3, S)
        Radiance per channel (RGB).
    irradiance : ndarray of float32, shape (3, S)
        Beam-normal irradiance E⊥ per channel.
    """

    n_texels: int
    texel: np.ndarray
    camera: np.ndarray
    light: np.ndarray
    wi_grid: np.ndarray
    wo_grid: np.ndarray
    radiance: np.ndarray
    irradiance: np.ndarray
    _cache: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_grid(cls, wi, wo, irradiance, radiance, valid):
        """Flatten a dome grid: ``wi`` (n, L, 3), ``wo`` (n, C, 3), ``irradiance`` (n, L, 3),
        ``radiance`` (n, C, L, 3), ``valid`` (n, C, L)."""
        v = np.asarray(valid, bool)
        n, n_cam, n_led = v.shape
        if np.shape(radiance)[:3] != v.shape or np.shape(wi)[:2] != (n, n_led) or np.shape(wo)[:2] != (n, n_cam):
            raise ValidationError(
                f"grid shapes disagree: valid {v.shape}, radiance {np.shape(radiance)}, wi {np.shape(wi)}, wo {np.shape(wo)}"
            )
        flat = np.flatnonzero(v)  # row-major: sorted by lumitexel, then camera, then light
        t, rem = np.divmod(flat, n_cam * n_led)
        c, l = np.divmod(rem, n_led)
        rad = np.asarray(radiance).reshape(-1, 3)[flat]
        irr = np.asarray(irradiance).reshape(-1, 3)[t * n_led + l]
        return cls(
            n_texels=n, texel=t.astype(np.int32), camera=c.astype(np.int32), light=l.astype(np.int32),
            wi_grid=np.asarray(wi, np.float32), wo_grid=np.asarray(wo, np.float32),
            radiance=np.ascontiguousarray(rad.T, dtype=np.float32), irradiance=np.ascontiguousarray(irr.T, dtype=np.float32),
        )

    @classmethod
    def from_arrays(cls, wi, wo, valid, radiance=None, irradiance=None):
        """From per-texel sample arrays ``wi``, ``wo`` (T, S, 3) and ``valid`` (T, S)."""
        v = np.asarray(valid, bool)
        t, s = np.nonzero(v)
        n_s = t.size
        rad = np.zeros((3, n_s), np.float32) if radiance is None else np.asarray(radiance, np.float32)[t, s].T
        irr = np.ones((3, n_s), np.float32) if irradiance is None else np.asarray(irradiance, np.float32)[t, s].T
        return cls(n_texels=v.shape[0], texel=t.astype(np.int32), camera=s.astype(np.int32), light=s.astype(np.int32),
                   wi_grid=np.asarray(wi, np.float32), wo_grid=np.asarray(wo, np.float32),
                   radiance=np.ascontiguousarray(rad), irradiance=np.ascontiguousarray(irr))

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.texel.shape[0])

    @property
    def wi(self) -> np.ndarray:
        """Per-sample unit directions towards the light, (S, 3) (built on demand)."""
        return self.wi_grid[self.texel, self.light]

    @property
    def wo(self) -> np.ndarray:
        """Per-sample unit directions towards the camera, (S, 3) (built on demand)."""
        return self.wo_grid[self.texel, self.camera]

    def count(self, mask=None) -> np.ndarray:
        """Samples per lumitexel (optionally only where ``mask``)."""
        t = self.texel if mask is None else self.texel[mask]
        return np.bincount(t, minlength=self.n_texels)

    def sum(self, values, mask=None) -> np.ndarray:
        """Per-lumitexel sum of per-sample ``values`` (S,) (optionally only where ``mask``)."""
        if mask is None:
            return np.bincount(self.texel, weights=values, minlength=self.n_texels)
        return np.bincount(self.texel[mask], weights=values[mask], minlength=self.n_texels)

    def cos(self, normal, dtype=np.float32):
        """(N·ωi, N·ωo) per sample for per-lumitexel normals (n, 3)."""
        nrm = np.asarray(normal, dtype)
        ci = np.matmul(self.wi_grid.astype(dtype, copy=False), nrm[:, :, None])[..., 0]  # (n, L)
        co = np.matmul(self.wo_grid.astype(dtype, copy=False), nrm[:, :, None])[..., 0]  # (n, C)
        return ci[self.texel, self.light], co[self.texel, self.camera]

    def cos_io(self) -> np.ndarray:
        """ωi·ωo per sample (float64, cached)."""
        if "io" not in self._cache:
            n = self.n_texels
            wo = self.wo_grid.astype(np.float64)
            grid = np.matmul(wo, np.swapaxes(self.wi_grid.astype(np.float64), 1, 2))  # (n, C, L)
            self._cache["io"] = grid.reshape(n, -1)[self.texel, self.camera * self.wi_grid.shape[1] + self.light]
        return self._cache["io"]

    def grey(self) -> np.ndarray:
        """Σ_ch L / Σ_ch E⊥ per sample: the grey f_r cos θi (cached)."""
        if "grey" not in self._cache:
            r, e = self.radiance, self.irradiance
            with np.errstate(invalid="ignore", divide="ignore"):
                self._cache["grey"] = (r[0] + r[1] + r[2]) / (e[0] + e[1] + e[2])
        return self._cache["grey"]

    def ranks(self, mask=None):
        """Position of each kept sample within its lumitexel: ``(texel, rank, counts)``.

        ``texel`` and ``rank`` (S',) index the padded (lumitexel, rank) layout of the
        samples kept by ``mask`` (all by default); ``counts`` (n_texels,) is the
        number kept per lumitexel.  Relies on the samples being sorted by lumitexel.
        """
        t = self.texel if mask is None else self.texel[np.asarray(mask, bool)]
        counts = np.bincount(t, minlength=self.n_texels)
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        return t, np.arange(t.size) - start[t], counts

    def padded(self, values, fill, mask=None):
        """Per-lumitexel padded view (n_texels, S_max) of ``values`` (S,) (only ``mask`` samples kept)."""
        t, rank, counts = self.ranks(mask)
        vals = np.asarray(values)
        out = np.full((self.n_texels, max(int(counts.max(initial=0)), 1)), fill, dtype=vals.dtype)
        out[t, rank] = vals if mask is None else vals[np.asarray(mask, bool)]
        return out, counts
