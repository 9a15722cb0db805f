"""Lumitexel samples as flat arrays: the data structure every fit stage works on.

A lumitexel gathers up to (cameras × lights) BRDF samples but only a fraction is
valid (about 900 of 2,400 in the default dome, §5).  Rather than dense
(lumitexel, camera, light) grids that are mostly empty, the stages keep only the
valid samples in flat arrays sorted by lumitexel, so every pass touches useful
data; per-lumitexel sums are ``np.bincount`` over the lumitexel index and
per-lumitexel order statistics use a padded view built once.
"""

from __future__ import annotations

from dataclasses import dataclass

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
    camera, light : ndarray of int16, shape (S,)
        Camera and light of each sample (−1 when the samples do not come from a grid).
    wi, wo : ndarray of float32, shape (S, 3)
        Unit directions towards the light and the camera.
    radiance : ndarray of float32, shape (S, 3)
        Radiance per channel (RGB).
    irradiance : ndarray of float32, shape (S, 3)
        Beam-normal irradiance E⊥ per channel.
    """

    n_texels: int
    texel: np.ndarray
    camera: np.ndarray
    light: np.ndarray
    wi: np.ndarray
    wo: np.ndarray
    radiance: np.ndarray
    irradiance: np.ndarray

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
        t, c, l = np.nonzero(v)  # row-major: sorted by lumitexel, then camera
        rad = np.asarray(radiance)[t, c, l].astype(np.float32)
        return cls(
            n_texels=n, texel=t.astype(np.int32), camera=c.astype(np.int16), light=l.astype(np.int16),
            wi=np.asarray(wi, np.float32)[t, l], wo=np.asarray(wo, np.float32)[t, c],
            radiance=rad, irradiance=np.asarray(irradiance, np.float32)[t, l],
        )

    @classmethod
    def from_arrays(cls, wi, wo, valid, radiance=None, irradiance=None):
        """From per-texel sample arrays ``wi``, ``wo`` (T, S, 3) and ``valid`` (T, S)."""
        v = np.asarray(valid, bool)
        t, s = np.nonzero(v)
        n_s = t.size
        rad = np.zeros((n_s, 3), np.float32) if radiance is None else np.asarray(radiance, np.float32)[t, s]
        irr = np.ones((n_s, 3), np.float32) if irradiance is None else np.asarray(irradiance, np.float32)[t, s]
        minus = np.full(n_s, -1, np.int16)
        return cls(n_texels=v.shape[0], texel=t.astype(np.int32), camera=minus, light=minus,
                   wi=np.asarray(wi, np.float32)[t, s], wo=np.asarray(wo, np.float32)[t, s], radiance=rad, irradiance=irr)

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.texel.shape[0])

    def count(self, mask=None) -> np.ndarray:
        """Samples per lumitexel (optionally only where ``mask``)."""
        t = self.texel if mask is None else self.texel[mask]
        return np.bincount(t, minlength=self.n_texels)

    def sum(self, values, mask=None) -> np.ndarray:
        """Per-lumitexel sum of per-sample ``values`` (S,) (optionally only where ``mask``)."""
        if mask is None:
            return np.bincount(self.texel, weights=values, minlength=self.n_texels)
        return np.bincount(self.texel[mask], weights=values[mask], minlength=self.n_texels)

    def segment_sum(self, values, key, n_keys) -> np.ndarray:
        """Sum of ``values`` per arbitrary integer ``key`` (e.g. lumitexel × camera)."""
        return np.bincount(key, weights=values, minlength=n_keys)

    def cos(self, normal):
        """(N·ωi, N·ωo) per sample for per-lumitexel normals (n, 3)."""
        nrm = np.asarray(normal, np.float32)[self.texel]
        return np.einsum("sk,sk->s", nrm, self.wi), np.einsum("sk,sk->s", nrm, self.wo)

    def padded(self, values, fill, mask=None):
        """Per-lumitexel padded view (n_texels, S_max) of ``values`` (S,) (only ``mask`` samples kept)."""
        sel = np.ones(self.n, bool) if mask is None else np.asarray(mask, bool)
        t = self.texel[sel]
        counts = np.bincount(t, minlength=self.n_texels)
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        rank = np.arange(t.size) - start[t]
        out = np.full((self.n_texels, max(int(counts.max(initial=0)), 1)), fill, dtype=np.asarray(values).dtype)
        out[t, rank] = np.asarray(values)[sel]
        return out, counts
