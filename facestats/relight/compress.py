"""Compressed relighting: a shared, solid-angle weighted PCA basis of the reflectance functions.

Debevec et al. 2000 §3.3 relight directly from JPEG-compressed reflectance
functions (Smith & Rowe's compressed-domain products) "reducing both storage
and computation by a factor of twenty"; §5 suggests exploiting the similarity
of neighbouring reflectance functions.  facestats uses a *shared basis* instead
of a per-pixel transform:

    R_p,c(l) ≈ μ(l) + Σ_{k<K} C_{p,c,k} B_k(l) / √δA_l

with B the K leading principal components of the rows √δA · (R_p,c − μ) over
all face pixels p and channels c.  Choice and justification:

* **Cost of a relight.**  With a shared basis the lighting is projected once
  (K × L products, a few microseconds) and each pixel needs K multiply-adds
  per channel: one dense (P × K) GEMV per channel.  A per-pixel transform
  (DCT/wavelet of each 64 × 32 function, the paper's JPEG) keeps different
  coefficients per pixel, so the product needs a gather per coefficient and is
  several times slower per kept coefficient.
* **Accuracy per coefficient.**  Reflectance functions of a face are diffuse
  lobes of similar shape, shadow edges and a specular lobe: a few dozen
  components capture them across all pixels (and all three channels, whose
  functions differ mostly by a colour factor), while a per-pixel transform
  must code every lobe and every shadow edge anew.
* **The right error metric.**  Environment lighting weights each light by its
  solid angle δA (eq. 4), so the basis minimises Σ_l δA_l (R − R̂)²: rows are
  scaled by √δA before the PCA.  Unweighted, it would spend coefficients on
  the light stage's polar rows, which sample "more samples per solid angle
  near the poles" (§3.3) but carry little light.
* **Honest diagnostics.**  The kept components are nested, so the residual
  ‖√δA (R − R̂)‖ of every pixel is non-increasing in K, and by Cauchy-Schwarz the
  relighting error of a pixel is bounded by that residual times ‖L √δA‖
  (:meth:`CompressedField.error_bound`).

The compression ratio counts stored values: L·P·3 dense values of the face
pixels against K·P·3 coefficients, K·L basis values and L mean values
(background pixels are all zero and stored as a mask in both cases).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from facestats.core.validate import as_finite, check_integer
from facestats.errors import ValidationError
from facestats.relight.field import as_field, image_tiles, light_dims, light_table

__all__ = ["CompressedField", "compress", "rank_for_ratio"]


def rank_for_ratio(n_lights: int, n_rows: int, ratio: float) -> int:
    """Largest K with L·n_rows / (K·n_rows + K·L + L) ≥ ``ratio`` (at least 1).

    Raises :class:`ValidationError` when even K = 1 cannot reach the ratio.
    """
    r = float(as_finite(ratio, "ratio", 1, None))
    k = int(np.floor((n_lights * n_rows / r - n_lights) / (n_rows + n_lights)))
    if k < 1:
        best = n_lights * n_rows / (n_rows + 2 * n_lights)
        raise ValidationError(f"ratio must be at most {best:.1f} for {n_lights} lights and {n_rows} rows, got {r:g}")
    return min(k, n_lights)


@dataclass
class CompressedField:
    """A reflectance field in a shared PCA basis (module docstring); relights in O(P K).

    Attributes
    ----------
    mean : ndarray, shape (L,)
        Mean reflectance function μ (sr⁻¹).
    basis : ndarray, shape (K, L)
        Orthonormal components B in the √δA-weighted space.
    coefficients : ndarray, shape (3, P, K)
        C per channel and face pixel.
    pixels : ndarray of int, shape (P,)
        Flat index (row · W + column) of the stored pixels.
    residual : ndarray, shape (P, 3)
        ‖√δA (R − R̂)‖ of each pixel and channel at this K.
    energy : ndarray, shape (K_max,)
        Eigenvalues of the weighted covariance (captured energy per component).
    sqrt_solid_angle : ndarray, shape (L,)
    directions : ndarray, shape (light dims..., 3)
    image_shape : tuple of int
    """

    mean: np.ndarray
    basis: np.ndarray
    coefficients: np.ndarray
    pixels: np.ndarray
    residual: np.ndarray
    energy: np.ndarray
    sqrt_solid_angle: np.ndarray
    directions: np.ndarray
    image_shape: tuple

    @property
    def rank(self) -> int:
        """K, the coefficients kept per pixel and channel."""
        return int(self.basis.shape[0])

    @property
    def n_lights(self) -> int:
        return int(self.basis.shape[1])

    @property
    def ratio(self) -> float:
        """Dense face values over stored values: L·P·3 / (K·P·3 + K·L + L)."""
        n_rows = 3 * self.pixels.size
        return self.n_lights * n_rows / (self.rank * n_rows + self.rank * self.n_lights + self.n_lights)

    def truncate(self, rank: int) -> "CompressedField":
        """The same field with its first ``rank`` components (nested: residuals only grow)."""
        k = check_integer(rank, "rank", 1, self.rank)
        c = self.coefficients[..., k:]
        extra = np.sqrt(np.einsum("cpk,cpk->pc", c, c, dtype=np.float64))
        res = np.sqrt(self.residual.astype(np.float64) ** 2 + extra**2).astype(np.float32)
        return replace(self, basis=self.basis[:k], coefficients=np.ascontiguousarray(self.coefficients[..., :k]),
                       residual=res)  # fmt: skip

    def _weights(self, lighting):
        w = as_finite(lighting, "lighting", dtype=np.float64)
        if w.shape[:-1] not in (self.directions.shape[:-1], (self.n_lights,)) or w.shape[-1] != 3:
            raise ValidationError(
                f"lighting must hold L·δA per light, shape {self.directions.shape[:-1] + (3,)}, got {w.shape}"
            )
        return w.reshape(-1, 3)

    def relight(self, lighting=None, *, probe=None, layout: str = "latlong", rotate: float = 0.0) -> np.ndarray:
        """Relit image from the compressed field: μ·W + C (B (W/√δA)) per channel, (H, W, 3) float32.

        ``lighting`` is L·δA per light (as :func:`facestats.relight.relight.relight`);
        or pass a ``probe`` (with ``layout``, ``rotate``) to resample.
        """
        from facestats.relight.lighting import resample_probe

        if (lighting is None) == (probe is None):
            raise ValidationError("pass exactly one of lighting (L·δA per light) and probe")
        if probe is not None:
            lighting = resample_probe(probe, self.directions, layout=layout, rotate=rotate)
        w = self._weights(lighting)
        proj = (self.basis.astype(np.float64) @ (w / self.sqrt_solid_angle[:, None])).astype(np.float32)  # (K, 3)
        base = (self.mean.astype(np.float64) @ w).astype(np.float32)  # (3,)
        out = np.zeros((self.image_shape[0] * self.image_shape[1], 3), np.float32)
        vals = np.empty((self.pixels.size, 3), np.float32)
        for c in range(3):  # one GEMV per channel
            np.matmul(self.coefficients[c], proj[:, c], out=vals[:, c])
        out[self.pixels] = vals + base
        return out.reshape(self.image_shape + (3,))

    def error_bound(self, lighting) -> np.ndarray:
        """Per-pixel bound on |relight(compressed) − relight(dense)|: residual · ‖W/√δA‖, (H, W, 3)."""
        w = self._weights(lighting)
        norm = np.sqrt(((w / self.sqrt_solid_angle[:, None]) ** 2).sum(0))
        out = np.zeros((self.image_shape[0] * self.image_shape[1], 3), np.float32)
        out[self.pixels] = self.residual * norm
        return out.reshape(self.image_shape + (3,))

    def reconstruct(self) -> np.ndarray:
        """The approximated field, (L, H, W, 3) float32 (for inspection; memory as the dense field)."""
        rows = np.einsum("cpk,kl->lpc", self.coefficients, self.basis) / self.sqrt_solid_angle[:, None, None]
        out = np.zeros((self.n_lights, self.image_shape[0] * self.image_shape[1], 3), np.float32)
        out[:, self.pixels] = rows + self.mean[:, None, None]
        return out.reshape((self.n_lights,) + self.image_shape + (3,))


def _face_pixels(f):
    """Flat indices of the pixels to store: the field's mask, else every pixel with a non-zero value."""
    h, w = f.sizes["y"], f.sizes["x"]
    if "mask" in f.data_vars:
        return np.flatnonzero(np.asarray(f["mask"].values).reshape(h * w))
    refl = f["reflectance"]
    nl = len(light_dims(f))
    any_nz = (refl != 0).any(dim=list(refl.dims[:nl]) + ["channel"])
    return np.flatnonzero(np.asarray(any_nz.values).reshape(h * w))


def _rows(f, ys, xs, pixels_in, n):
    """Reflectance rows (3 · n_pix, L) float64 of the face pixels of one tile, channel-major within a pixel."""
    nl = len(light_dims(f))
    block = np.asarray(f["reflectance"].isel(y=ys, x=xs).values, np.float32)
    block = block.reshape((n,) + block.shape[nl:])  # (L, ty, tx, 3)
    flat = block.reshape(n, -1, 3)[:, pixels_in, :]  # (L, n_pix, 3)
    return np.transpose(flat, (1, 2, 0)).reshape(-1, n)


def _tile_pixels(f, pixels):
    """For each image tile: (ys, xs, indices into ``pixels``, positions inside the tile)."""
    w = f.sizes["x"]
    r, c = pixels // w, pixels % w
    out = []
    for ys, xs in image_tiles(f):
        sel = np.flatnonzero((r >= ys.start) & (r < ys.stop) & (c >= xs.start) & (c < xs.stop))
        if sel.size:
            inside = (r[sel] - ys.start) * (xs.stop - xs.start) + (c[sel] - xs.start)
            out.append((ys, xs, sel, inside))
    return out


def compress(field, ratio: float = 20, *, rank: int | None = None, sample: int = 20000, seed: int = 0,
             progress: bool = False) -> CompressedField:  # fmt: skip
    """Compress a reflectance field into a shared weighted PCA basis (module docstring).

    Parameters
    ----------
    field : xarray.Dataset
        In memory or on disk (read tile by tile twice: basis, then coefficients).
    ratio : float
        Minimum compression ratio (dense face values / stored values); sets the
        rank K = :func:`rank_for_ratio` unless ``rank`` is given.
    rank : int, optional
        Keep exactly this many components.
    sample : int
        Face pixels (all three channels each) sampled to estimate the basis.
    seed : int
        Seed of that sample.
    progress : bool
        Progress bar over tiles.

    Returns
    -------
    CompressedField
    """
    from tqdm.auto import tqdm

    f = as_field(field)
    _, sa, _ = light_table(f)
    n = sa.size
    pixels = _face_pixels(f)
    if pixels.size == 0:
        raise ValidationError("field has no pixel with a non-zero reflectance (or its mask is empty)")
    k = rank_for_ratio(n, 3 * pixels.size, ratio) if rank is None else check_integer(rank, "rank", 1, n)
    tiles = _tile_pixels(f, pixels)
    rng = np.random.default_rng(check_integer(seed, "seed"))
    n_s = min(check_integer(sample, "sample", 1), pixels.size)
    chosen = np.zeros(pixels.size, bool)
    chosen[rng.choice(pixels.size, n_s, replace=False)] = True
    sw = np.sqrt(sa)
    # Pass 1: mean (over every face row) and weighted covariance (over the sample).
    total = np.zeros(n)
    picked = []
    for ys, xs, sel, inside in tqdm(tiles, desc="compress: basis", disable=not progress, leave=False):
        rows = _rows(f, ys, xs, inside, n)
        total += rows.sum(0)
        picked.append(rows.reshape(-1, 3, n)[chosen[sel]].reshape(-1, n))
    mean = total / (3 * pixels.size)
    x = (np.concatenate(picked) - mean) * sw
    evals, evecs = np.linalg.eigh(x.T @ x)
    order = np.argsort(evals)[::-1]
    energy, basis = np.maximum(evals[order], 0), evecs[:, order[:k]].T.astype(np.float32)
    # Pass 2: coefficients and residual norms of every face row.
    coef = np.empty((3, pixels.size, k), np.float32)
    res = np.empty((pixels.size, 3), np.float32)
    for ys, xs, sel, inside in tqdm(tiles, desc="compress: coefficients", disable=not progress, leave=False):
        y = ((_rows(f, ys, xs, inside, n) - mean) * sw).astype(np.float32)
        c = y @ basis.T  # (3 n_pix, K)
        r2 = np.einsum("rl,rl->r", y, y, dtype=np.float64) - np.einsum("rk,rk->r", c, c, dtype=np.float64)
        coef[:, sel, :] = np.transpose(c.reshape(-1, 3, k), (1, 0, 2))
        res[sel] = np.sqrt(np.maximum(r2, 0)).reshape(-1, 3)
    return CompressedField(
        mean=mean.astype(np.float32),
        basis=basis,
        coefficients=coef,
        pixels=pixels,
        residual=res,
        energy=energy,
        sqrt_solid_angle=sw,
        directions=np.asarray(f["direction"].values, np.float64),
        image_shape=(f.sizes["y"], f.sizes["x"]),
    )
