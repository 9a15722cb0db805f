"""Compressed relighting: clustered PCA of the solid-angle weighted reflectance functions.

Debevec et al. 2000 §3.3 relight directly from JPEG-compressed reflectance
functions (Smith & Rowe's compressed-domain products) "reducing both storage
and computation by a factor of twenty"; §5 suggests exploiting the similarity
of neighbouring reflectance functions.  facestats uses a *shared basis per
cluster of pixels* (clustered PCA, Sloan et al. 2003) instead of a per-pixel
transform:

    √δA_l R_p,c(l) ≈ s_p,c μ_k(l) + Σ_{j<K} C_{p,c,j} B_k,j(l),     k = cluster of pixel p

with s_p,c = ‖√δA R_p,c‖ and (μ_k, B_k) the mean and K leading principal
components of the *normalised* rows √δA R_p,c / s_p,c of the pixels of cluster k,
all three channels together.
Choice and justification:

* **Cost of a relight.**  The lighting is projected once on every cluster's
  basis (C·K·L multiply-adds for all pixels together) and each pixel then needs
  K multiply-adds per channel: one small dense GEMV per cluster and channel.  A
  per-pixel transform (DCT/wavelet of each 64 × 32 function, the paper's JPEG)
  keeps different coefficients per pixel and needs a gather per coefficient;
  measured on a face field, a per-pixel Haar truncation to 1/20 of the
  coefficients also errs far more (over 100 % on backlit pixels under the
  ennis probe) than a shared basis.
* **Why clusters.**  One global basis (K = 100 of 2048) cannot follow the
  specular lobe and the shadow edges, whose position moves with the normal:
  errors of tens of percent on backlit pixels under the test probes.  Pixels
  with similar reflectance functions (similar normals, similar shadowing)
  share a basis well; the clusters are found by k-means on the functions'
  projections onto a global basis.  Within a cluster the three channels'
  functions differ mostly by a colour factor and share the basis.
* **The error metric.**  Environment lighting weights each light by its solid
  angle δA (eq. 4), so each basis minimises Σ_l δA_l (R − R̂)²: rows are scaled
  by √δA before the PCA.  Unweighted, it would spend coefficients on the light
  stage's polar rows, which sample "more samples per solid angle near the
  poles" (§3.3) but carry little light.  And a relit image is judged by its
  *relative* error per pixel and channel, so the PCA runs on rows normalised to
  unit norm (each row keeps its norm s as one extra stored value): a dark blue
  channel is then represented as well as a bright red one.  Measured on a 256²
  face at ratio 20, this halves the worst relative error against the
  unnormalised PCA, whose errors concentrate in the weak channels of dark pixels.
* **Honest diagnostics.**  Components are nested, so the residual
  ‖√δA (R − R̂)‖ of every pixel is non-increasing in K (:meth:`CompressedField.truncate`),
  and by Cauchy-Schwarz the relighting error of a pixel is bounded by that
  residual times ‖L √δA‖ (:meth:`CompressedField.error_bound`).

The compression ratio counts stored values: L·P·3 dense values of the face
pixels against (K + 1)·P·3 coefficients and scales and C·(K + 1)·L basis and
mean values (background pixels are all zero and stored as a mask in both
cases; the cluster label per pixel is not counted).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from facestats.core.validate import as_finite, check_integer
from facestats.errors import ValidationError
from facestats.relight.field import as_field, image_tiles, light_dims, light_table
from facestats.relight.lighting import resample_probe

__all__ = ["CompressedField", "compress", "rank_for_ratio", "default_clusters"]

#: Target pixels per cluster of the default clustering.
PIXELS_PER_CLUSTER = 512


def rank_for_ratio(n_lights: int, n_pixels: int, ratio: float, clusters: int = 1) -> int:
    """Largest K with 3 L P / ((3 P + C L)(K + 1)) ≥ ``ratio`` (K coefficients and one scale per row).

    Raises :class:`ValidationError` when even K = 1 cannot reach the ratio.
    """
    r = float(as_finite(ratio, "ratio", 1, None))
    c = check_integer(clusters, "clusters", 1)
    dense = 3 * n_lights * n_pixels
    k = int(np.floor(dense / r / (3 * n_pixels + c * n_lights))) - 1
    if k < 1:
        best = dense / (2 * (3 * n_pixels + c * n_lights))
        raise ValidationError(
            f"ratio must be at most {best:.1f} for {n_lights} lights, {n_pixels} pixels and {c} clusters, got {r:g}"
        )
    return min(k, n_lights)


def default_clusters(n_pixels: int) -> int:
    """About one cluster per :data:`PIXELS_PER_CLUSTER` face pixels (at least 1)."""
    return max(1, int(round(n_pixels / PIXELS_PER_CLUSTER)))


@dataclass
class CompressedField:
    """A reflectance field in clustered PCA bases (module docstring); relights in O(P K + C K L).

    Attributes
    ----------
    means : ndarray, shape (C, L)
        Mean of the normalised weighted functions √δA R/‖√δA R‖ of each cluster.
    bases : ndarray, shape (C, K, L)
        Orthonormal components B_k in the √δA-weighted space.
    coefficients : ndarray, shape (3, P, K)
        C per channel and stored pixel, pixels ordered by cluster.
    scale : ndarray, shape (3, P)
        ‖√δA R‖ of each pixel and channel (the mean enters scaled by it).
    pixels : ndarray of int, shape (P,)
        Flat index (row · W + column) of each stored pixel, in cluster order.
    offsets : ndarray of int, shape (C + 1,)
        Pixels ``offsets[k]:offsets[k+1]`` belong to cluster k.
    residual : ndarray, shape (P, 3)
        ‖√δA (R − R̂)‖ of each pixel and channel at this K.
    sqrt_solid_angle : ndarray, shape (L,)
    directions : ndarray, shape (light dims..., 3)
    image_shape : tuple of int
    """

    means: np.ndarray
    bases: np.ndarray
    coefficients: np.ndarray
    scale: np.ndarray
    pixels: np.ndarray
    offsets: np.ndarray
    residual: np.ndarray
    sqrt_solid_angle: np.ndarray
    directions: np.ndarray
    image_shape: tuple

    @property
    def rank(self) -> int:
        """K, the coefficients kept per pixel and channel."""
        return int(self.bases.shape[1])

    @property
    def clusters(self) -> int:
        return int(self.bases.shape[0])

    @property
    def n_lights(self) -> int:
        return int(self.bases.shape[2])

    @property
    def ratio(self) -> float:
        """Dense face values over stored values: 3 L P / (3 P (K + 1) + C (K + 1) L)."""
        p, k, c, n = self.pixels.size, self.rank, self.clusters, self.n_lights
        return 3 * n * p / (3 * p * (k + 1) + c * (k + 1) * n)

    def truncate(self, rank: int) -> "CompressedField":
        """The same field with the first ``rank`` components of every cluster (residuals only grow)."""
        k = check_integer(rank, "rank", 1, self.rank)
        c = self.coefficients[..., k:]
        extra = np.einsum("cpk,cpk->pc", c, c, dtype=np.float64)
        res = np.sqrt(self.residual.astype(np.float64) ** 2 + extra).astype(np.float32)
        return replace(self, bases=np.ascontiguousarray(self.bases[:, :k]),
                       coefficients=np.ascontiguousarray(self.coefficients[..., :k]), residual=res)  # fmt: skip

    def _weights(self, lighting):
        w = as_finite(lighting, "lighting", dtype=np.float64)
        if w.shape[:-1] not in (self.directions.shape[:-1], (self.n_lights,)) or w.shape[-1] != 3:
            raise ValidationError(
                f"lighting must hold L·δA per light, shape {self.directions.shape[:-1] + (3,)}, got {w.shape}"
            )
        return w.reshape(-1, 3)

    def relight(self, lighting=None, *, probe=None, layout: str = "latlong", rotate: float = 0.0) -> np.ndarray:
        """Relit image from the compressed field, (H, W, 3) float32 (Debevec et al. 2000 eq. 4).

        Per cluster: base = μ_k·(W/√δA), proj = B_k (W/√δA), then pixel value =
        C_p · proj + s_p base per channel.  ``lighting`` is L·δA per light (as
        :func:`facestats.relight.relighting.relight`); or pass a ``probe`` (with
        ``layout``, ``rotate``) to resample.
        """

        if (lighting is None) == (probe is None):
            raise ValidationError("pass exactly one of lighting (L·δA per light) and probe")
        if probe is not None:
            lighting = resample_probe(probe, self.directions, layout=layout, rotate=rotate)
        wd = (self._weights(lighting) / self.sqrt_solid_angle[:, None]).astype(np.float32)  # (L, 3)
        c, k, n = self.bases.shape
        proj = (self.bases.reshape(c * k, n) @ wd).reshape(c, k, 3)
        base = self.means @ wd  # (C, 3)
        vals = np.empty((self.pixels.size, 3), np.float32)
        off = self.offsets
        for j in range(c):  # loop over clusters: one GEMV per channel each
            a, b = off[j], off[j + 1]
            if b > a:
                for ch in range(3):
                    np.matmul(self.coefficients[ch, a:b], proj[j, :, ch], out=vals[a:b, ch])
                vals[a:b] += self.scale[:, a:b].T * base[j]
        out = np.zeros((self.image_shape[0] * self.image_shape[1], 3), np.float32)
        out[self.pixels] = vals
        return out.reshape(self.image_shape + (3,))

    def error_bound(self, lighting) -> np.ndarray:
        """Per-pixel bound on |relight(compressed) − relight(dense)|: residual · ‖W/√δA‖, (H, W, 3)."""
        w = self._weights(lighting)
        norm = np.sqrt(((w / self.sqrt_solid_angle[:, None]) ** 2).sum(0))
        out = np.zeros((self.image_shape[0] * self.image_shape[1], 3), np.float32)
        out[self.pixels] = self.residual * norm
        return out.reshape(self.image_shape + (3,))

    def reconstruct(self) -> np.ndarray:
        """The approximated field, (L, H, W, 3) float32 (for inspection; memory of the dense field)."""
        out = np.zeros((self.n_lights, self.image_shape[0] * self.image_shape[1], 3), np.float32)
        for j in range(self.clusters):  # loop over clusters
            a, b = self.offsets[j], self.offsets[j + 1]
            rows = np.einsum("cpk,kl->lpc", self.coefficients[:, a:b], self.bases[j])
            rows += self.means[j][:, None, None] * self.scale[:, a:b].T[None]
            out[:, self.pixels[a:b]] = rows / self.sqrt_solid_angle[:, None, None]
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


def _weighted_rows(f, ys, xs, inside, sw):
    """√δA-weighted rows (n_pix, 3, L) float32 of the face pixels of one tile."""
    block = np.asarray(f["reflectance"].isel(y=ys, x=xs).values, np.float32)
    flat = block.reshape((sw.size, -1, 3))[:, inside, :]  # (L, n_pix, 3)
    return np.transpose(flat, (1, 2, 0)) * sw.astype(np.float32)


def _pca(rows, k):
    """Mean and K leading orthonormal components (K, L) of rows (n, L), float32."""
    mean = rows.mean(0, dtype=np.float64)
    x = (rows - mean).astype(np.float64)
    if x.shape[0] < x.shape[1]:  # fewer rows than lights: eigenvectors of the Gram matrix
        e, u = np.linalg.eigh(x @ x.T)
        e, u = e[::-1][:k], u[:, ::-1][:, :k]
        keep = e > max(e[0], 1e-300) * 1e-10
        comp = (u[:, keep].T @ x) / np.sqrt(e[keep])[:, None]
        comp = np.linalg.qr(comp.T)[0].T if comp.shape[0] else comp  # orthonormal to rounding
    else:
        e, v = np.linalg.eigh(x.T @ x)
        comp = v[:, ::-1][:, :k].T
    out = np.zeros((k, x.shape[1]), np.float32)
    out[: comp.shape[0]] = comp
    return mean.astype(np.float32), out


class _Pass:
    """Streaming reads of a field's face rows, tile by tile (the loop runs over tiles and clusters)."""

    def __init__(self, f, pixels, sw, progress):
        self.f, self.sw, self.progress = f, sw, progress
        self.tiles = _tile_pixels(f, pixels)
        self.n_pix = pixels.size

    def each(self, desc):
        from tqdm.auto import tqdm

        for ys, xs, sel, inside in tqdm(self.tiles, desc=desc, disable=not self.progress, leave=False):
            yield sel, _weighted_rows(self.f, ys, xs, inside, self.sw)

    def rows_of(self, selected, desc):
        """Weighted rows (n, 3, L) of the selected pixels and their indices."""
        parts, where = [], []
        for sel, rows in self.each(desc):
            keep = selected[sel]
            if keep.any():
                parts.append(rows[keep])
                where.append(sel[keep])
        return np.concatenate(parts), np.concatenate(where)


def _clusters(stream, c, nf, s, rng):
    """Cluster labels of every face pixel: k-means of their projections on a global luminance basis."""
    from scipy.cluster.vq import kmeans2

    if c == 1:
        return np.zeros(stream.n_pix, np.int64)
    chosen = np.zeros(stream.n_pix, bool)
    chosen[rng.choice(stream.n_pix, min(stream.n_pix, s * c), replace=False)] = True
    smp, _ = stream.rows_of(chosen, "compress: global basis")
    g_mean, g_basis = _pca(_normalised(smp.sum(1)), nf)
    feats = np.empty((stream.n_pix, nf), np.float32)
    for sel, rows in stream.each("compress: features"):
        feats[sel] = (_normalised(rows.sum(1)) - g_mean) @ g_basis.T  # the shapes of the functions
    _, labels = kmeans2(feats.astype(np.float64), c, seed=int(rng.integers(2**31)), minit="++", iter=20)
    return labels.astype(np.int64)


def _cluster_bases(stream, labels, order, offsets, k, s, rng):
    """Mean (C, L) and K components (C, K, L) of each cluster, from up to ``s`` of its pixels."""
    c, n = offsets.size - 1, stream.sw.size
    picked = np.zeros(stream.n_pix, bool)
    for j in range(c):  # loop over clusters: draw each one's sample
        members = order[offsets[j] : offsets[j + 1]]
        if members.size:
            picked[rng.choice(members, min(members.size, s), replace=False)] = True
    rows, where = stream.rows_of(picked, "compress: cluster bases")
    rows = _normalised(rows)
    means = np.zeros((c, n), np.float32)
    bases = np.zeros((c, k, n), np.float32)
    lab = labels[where]
    for j in range(c):  # loop over clusters
        r = rows[lab == j]
        if r.shape[0]:
            means[j], bases[j] = _pca(r.reshape(-1, n), k)
    return means, bases


def _normalised(rows):
    """Rows divided by their norms (zero rows stay zero)."""
    norm = np.linalg.norm(rows, axis=-1, keepdims=True)
    return rows / np.where(norm > 0, norm, 1)


def _coefficients(stream, labels, order, means, bases):
    """Coefficients (3, P, K), scales (3, P) in cluster order and residual norms (P, 3) of every face pixel.

    A row y is stored as ‖y‖ μ_k + C B_k with C = (y − ‖y‖ μ_k) B_kᵀ: the basis was
    fitted to normalised rows, so its error is relative to each row's norm.
    """
    k = bases.shape[1]
    rank_in = np.empty(stream.n_pix, np.int64)
    rank_in[order] = np.arange(stream.n_pix)
    coef = np.empty((3, stream.n_pix, k), np.float32)
    scale = np.empty((3, stream.n_pix), np.float32)
    res = np.empty((stream.n_pix, 3), np.float32)
    for sel, tile_rows in stream.each("compress: coefficients"):
        for j in np.unique(labels[sel]):  # loop over the clusters present in this tile
            here = labels[sel] == j
            norm = np.linalg.norm(tile_rows[here], axis=-1)  # (n, 3)
            y = tile_rows[here] - norm[..., None] * means[j]
            cf = y @ bases[j].T  # (n, 3, K)
            dest = rank_in[sel[here]]
            coef[:, dest, :] = np.transpose(cf, (1, 0, 2))
            scale[:, dest] = norm.T
            res[dest] = np.linalg.norm(y - cf @ bases[j], axis=-1)
    return coef, scale, res


def compress(
    field,
    ratio: float = 20,
    *,
    clusters: int | None = None,
    rank: int | None = None,
    features: int = 32,
    sample: int = 256,
    seed: int = 0,
    progress: bool = False,
) -> CompressedField:
    """Compress a reflectance field into clustered, solid-angle weighted PCA bases (module docstring).

    Streaming passes over the field's tiles (in memory or on disk): a global
    basis of ``features`` components from a sample of pixels and every pixel's
    projection on it; k-means of those projections into ``clusters``; each
    cluster's mean and K components from up to ``sample`` of its pixels; then
    every pixel's coefficients and residual.

    Parameters
    ----------
    field : xarray.Dataset
    ratio : float
        Minimum compression ratio; sets K = :func:`rank_for_ratio` unless ``rank`` is given.
    clusters : int, optional
        Number of clusters C (default :func:`default_clusters`: one per 512 face pixels).
    rank : int, optional
        Keep exactly K components per cluster.
    features : int
        Components of the global basis that the clustering works on.
    sample : int
        Pixels per cluster (and, times C, for the global basis) used to estimate the bases.
    seed : int
        Seed of the samples and of k-means.
    progress : bool
        Progress bar over tiles.

    Returns
    -------
    CompressedField
    """
    f = as_field(field)
    _, sa, _ = light_table(f)
    sw = np.sqrt(sa)
    n = sa.size
    pixels = _face_pixels(f)
    if pixels.size == 0:
        raise ValidationError("field has no pixel with a non-zero reflectance (or its mask is empty)")
    c = default_clusters(pixels.size) if clusters is None else check_integer(clusters, "clusters", 1, pixels.size)
    k = rank_for_ratio(n, pixels.size, ratio, c) if rank is None else check_integer(rank, "rank", 1, n)
    s = check_integer(sample, "sample", 1)
    nf = check_integer(features, "features", 1, n)
    rng = np.random.default_rng(check_integer(seed, "seed"))
    stream = _Pass(f, pixels, sw, progress)
    labels = _clusters(stream, c, nf, s, rng)
    order = np.argsort(labels, kind="stable")
    offsets = np.concatenate([[0], np.cumsum(np.bincount(labels, minlength=c))])
    means, bases = _cluster_bases(stream, labels, order, offsets, k, s, rng)
    coef, scale, res = _coefficients(stream, labels, order, means, bases)
    return CompressedField(
        means=means,
        bases=bases,
        coefficients=coef,
        scale=scale,
        pixels=pixels[order],
        offsets=offsets,
        residual=res,
        sqrt_solid_angle=sw,
        directions=np.asarray(f["direction"].values, np.float64),
        image_shape=(f.sizes["y"], f.sizes["x"]),
    )
