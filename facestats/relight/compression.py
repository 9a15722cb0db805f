"""Compressed relighting: clustered PCA of the solid-angle weighted reflectance functions, by light region.

Debevec et al. 2000 §3.3 relight directly from JPEG-compressed reflectance
functions (Smith & Rowe's compressed-domain products) "reducing both storage
and computation by a factor of twenty"; §5 suggests exploiting the similarity
of neighbouring reflectance functions.  facestats keeps a *shared basis per
cluster of pixels and per region of the light sphere* (clustered PCA, Sloan et
al. 2003, with the lights split into regions):

    √δA_l R_p,c(l) ≈ Σ_{j<K_kr} C_p,c,r,j B_kr,j(l)   for the lights l of region r,  k = cluster of pixel p

where the B_kr are the leading principal directions (uncentred) of the
region-r parts (split further by zeros, below) of the rows y = √δA R_p,c of
*every* pixel of cluster k, all three channels, each part scaled by
1 / max(s_r, ``floor`` · s) (see *The error metric* below), and the
coefficients C are the projections of the unscaled parts.  Choice and
justification (the measurements behind it: ``docs/relighting.md``, D2):

* **Cost of a relight.**  The lighting is projected once on every basis
  (Σ K_kr L_r multiply-adds per channel) and each stored row then needs K_kr
  multiply-adds: one pass over the stored coefficients, which are kept in one
  flat array (compiled, :mod:`facestats.relight.compression_numba`; or one
  small dense GEMV per (region, cluster, channel) with ``backend="numpy"``).  A
  per-pixel transform (DCT/wavelet of each 64 × 32 function, the paper's JPEG)
  keeps different coefficients per pixel and needs a gather per coefficient;
  measured on a face field, a per-pixel Haar truncation to 1/20 of the
  coefficients also errs far more than a shared basis.
* **Why clusters.**  One global basis cannot follow the specular lobe and the
  shadow edges, whose position moves with the normal.  Pixels with similar
  reflectance functions share a basis well; the clusters are found by k-means
  on the functions' projections onto a global basis.  Within a cluster the
  three channels' functions differ mostly by a colour factor and share the basis.
* **Why light regions.**  Over half of the (pixel, light) values of a face
  are exactly zero: lights below a pixel's horizon or behind the nose.  A
  basis over the whole sphere reconstructs them with small ripples, and a
  bright source there (a window, the sun) multiplies the ripple into errors of
  100 % and more on the pixels it does not light.  Split into regions (the two
  hemispheres y ≥ 0 and y < 0, each into ``sectors`` azimuth sectors about +y),
  a row that is zero over a whole region is not stored and comes back exactly
  zero, and ripples stay inside the region they belong to.
* **Components where they pay.**  Each (cluster, region) block offers its
  components in the order of its singular values; a component of block b costs
  L_r + n_b stored values (its basis row and one coefficient per stored row)
  and removes σ² of the scaled rows' squared residual.  Components are
  taken greedily by σ² per stored value until the budget of the ratio is
  spent, so flat regions get none and the specular regions many.
* **The error metric.**  Environment lighting weights each light by its solid
  angle δA (eq. 4), so each basis minimises Σ_l δA_l (R − R̂)²: rows are scaled
  by √δA.  A relit image is judged by its *relative* error per pixel and
  channel, and a pixel's relit value is the sum of its regions' shares
  y_r · (L √δA)_r.  Under a light that falls on one region only, the relative
  error of the pixel is its residual there against s_r = Σ_{l∈r} √δA_l |y_l|,
  the region's value under uniform light of unit radiance (the √δA-weighted
  L1 norm of the part).  So each region's part of a row enters its block's
  basis and the greedy choice scaled by 1 / max(s_r, ``floor`` · s), s = Σ_r s_r:
  a dark blue channel weighs as much as a bright red one, and a region that
  holds a small share of the pixel's light is weighed as if it held ``floor``
  (scaled by s_r alone, the bases would chase regions that hardly light the pixel
  under any probe).  The default floor is chosen by
  ``benchmarks/bench_relight.bench_region_floor``; its figures and those of rows
  scaled to unit L2 norm over the whole sphere (the method until 2026-12-05) are
  in docs/relighting.md, D2.  Every pixel enters its cluster's bases (a basis
  estimated from a sample of the pixels left unsampled pixels with errors near
  100 %, over 1,000 % under a rotated probe).
* **Parts by zeros.**  Over half of a face's (pixel, light) values are zero,
  and within a region a pixel's horizon or a cast shadow cuts through the
  lights its cluster's other pixels see.  A block's basis then ripples onto
  lights where a row is exactly zero, and a bright source there (a window just
  below the horizon of the face's sides) turns a ripple of 1 % of the row's
  norm into an error of 10-20 % of the pixel.  So each (region, cluster)
  block's lights are split into ``parts`` by the share of its non-zero rows
  that are zero at the light (two parts: lights zero for fewer than half of
  them, and the rest), each part with its own basis; a row that is zero over a
  part is not stored there and comes back exactly zero, and the bases of the
  lit part no longer reach the lights the cluster mostly does not see.  Each
  part costs its support's bit mask, and the rows' zero masks one bit per
  (channel, region, part).
* **Honest diagnostics.**  The components of a block are nested and the greedy
  order is fixed, so keeping fewer (:meth:`CompressedField.truncate`) never
  lowers any row's residual ‖√δA (R − R̂)‖, and by Cauchy-Schwarz the
  relighting error of a pixel is bounded by that residual times ‖L √δA‖
  (:meth:`CompressedField.error_bound`).

The compression ratio counts stored values: L·P·3 dense values of the face
pixels against the basis rows and coefficients plus, per pixel, its cluster
label and the bit mask of its zero (channel, region) rows (:func:`per_pixel_values`).
Only the face pixels (the field's ``mask``, else the pixels with a non-zero
value) are stored: pixels outside the mask relight to 0, and
:meth:`CompressedField.error_bound` covers the stored pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from dataclasses import field as dataclass_field

import numpy as np

from facestats.core.compiled import resolve_backend
from facestats.core.validate import as_finite, as_float, check_integer, check_seed
from facestats.errors import ValidationError
from facestats.relight.field import as_field, image_tiles, light_dims, light_table
from facestats.relight.lighting import resample_probe
from facestats.relight.relighting import check_relit

__all__ = ["CompressedField", "compress", "default_clusters", "light_regions", "per_pixel_values"]

#: Target pixels per cluster of the default clustering.  Smaller clusters fit their pixels better but spend more
#: of the budget on bases; on the 256² face at 20× (``benchmarks/bench_relight.bench_cluster_density``, table in
#: docs/relighting.md) the median over 12 lightings and 3 seeds of the worst pixel falls from 12.8 % at 512 pixels
#: per cluster to 9.2 % at 128 and stops falling at 64.  The compiled relight's cost does not depend on the
#: clusters (it reads every stored value once; the numpy backend's grows with them); compressing takes longer.
PIXELS_PER_CLUSTER = 128


def per_pixel_values(n_parts: int) -> int:
    """Values stored per pixel besides its coefficients: its cluster label and its bit mask of zero rows
    (3 channels × ``n_parts`` (region, part) bits, in 32-bit values)."""
    return 1 + -(-3 * n_parts // 32)


def _number(value, name, low, high=None, **bounds):
    """A finite scalar within [``low``, ``high``] (``bounds``: as :func:`facestats.core.validate.check_range`)."""
    r = as_finite(value, name, low, high, **bounds)
    if r.ndim:
        raise ValidationError(f"{name} must be a number, got an array of shape {r.shape}")
    return float(r)


def _ratio(value):
    """A positive finite scalar ratio."""
    return _number(value, "ratio", 0, low_inclusive=False)


def default_clusters(n_pixels: int) -> int:
    """About one cluster per :data:`PIXELS_PER_CLUSTER` face pixels (at least 1)."""
    return max(1, int(round(n_pixels / PIXELS_PER_CLUSTER)))


def light_regions(directions, sectors: int = 4) -> np.ndarray:
    """Region (int64, in [0, 2 ``sectors``)) of each light direction (…, 3), facestats world frame (+y up).

    Region h · ``sectors`` + s: hemisphere h = 0 for y ≥ 0, 1 below; azimuth sector
    s = ⌊(atan2(x, z) + π) / (2π / ``sectors``)⌋ about +y (sector 0 starts at −z, turning through −x).
    """
    d = as_finite(directions, "directions", dtype=np.float64)
    if d.ndim < 1 or d.shape[-1] != 3:
        raise ValidationError(f"directions must have shape (..., 3), got {d.shape}")
    n = check_integer(sectors, "sectors", 1)
    azimuth = np.arctan2(d[..., 0], d[..., 2]) + np.pi
    sector = np.minimum((azimuth / (2 * np.pi / n)).astype(np.int64), n - 1)
    return np.where(d[..., 1] >= 0, 0, n) + sector


@dataclass
class _Block:
    """One (region, cluster, part) block: its lights within the region, its basis rows and, per channel, the stored
    rows' pixels and coefficients."""

    support: np.ndarray  # (L_r,) bool: the region's lights of this part
    basis: np.ndarray  # (K, L_r) float32, orthonormal rows, zero outside the support
    rows: tuple  # per channel: positions (int64, (n_c,)) in CompressedField.pixels
    coefficients: tuple  # per channel: (n_c, K) float32

    @property
    def stored(self) -> int:
        """Basis values on the support, coefficients, and the support's bit mask (32 bits a value) unless the
        support is the whole region."""
        k = self.basis.shape[0]
        if not k:
            return 0
        return k * (int(self.support.sum()) + sum(r.size for r in self.rows)) + _mask_values(self.support)


@dataclass
class _Packed:
    """The stored values of a :class:`CompressedField` in flat arrays (the blocks' bases and coefficients are
    views of them): per region the stacked bases of its blocks, all coefficients, and per (block, channel)
    segment where its rows, coefficients and components are, and the image it adds to (one per (region, part):
    each pixel has at most one block there); segments in (region, cluster, part, channel) order."""

    stacks: list  # per region: (Σ K, L_r) float32
    region_start: np.ndarray  # (n_regions + 1,) first component of each region in the projections
    coef: np.ndarray  # flat float32
    pixel: np.ndarray  # int64 position of every stored row
    n_images: int  # (region, part) pairs that hold blocks
    seg_image: np.ndarray  # int64 (region, part) image of each segment
    seg_row: np.ndarray  # int64 first row of each segment
    seg_rows: np.ndarray  # int64 rows
    seg_k: np.ndarray  # int64 components
    seg_proj: np.ndarray  # int64 first component in the projections
    seg_channel: np.ndarray  # int64
    seg_coef: np.ndarray  # int64 first coefficient

    @property
    def components(self) -> int:
        return int(self.region_start[-1])


def _pack(blocks, regions):
    """Pack the blocks' bases and coefficients into new flat arrays and make the blocks' arrays views of them
    (the values are stored once)."""
    keys = sorted(blocks)  # by region, then cluster, then part
    stacks, region_start, offset, proj_of = [], [0], 0, {}
    for r, lights in enumerate(regions):
        here = [key for key in keys if key[0] == r]
        for key in here:
            proj_of[key] = offset
            offset += blocks[key].basis.shape[0]
        region_start.append(offset)
        stacks.append(
            np.concatenate([blocks[key].basis for key in here]) if here else np.zeros((0, lights.size), np.float32)
        )
    segments = [(key, c) for key in keys for c in range(3) if blocks[key].rows[c].size]
    seg_rows = np.array([blocks[key].rows[c].size for key, c in segments], np.int64)
    seg_k = np.array([blocks[key].basis.shape[0] for key, _ in segments], np.int64)
    seg_coef = np.concatenate([[0], np.cumsum(seg_rows * seg_k)]).astype(np.int64)
    coef = np.empty(int(seg_coef[-1]), np.float32)
    segment_of = {seg: i for i, seg in enumerate(segments)}
    for key in keys:  # loop over blocks: copy their arrays into the flat ones and keep views
        b = blocks[key]
        lo = proj_of[key] - region_start[key[0]]
        cfs = list(b.coefficients)
        for c in range(3):
            i = segment_of.get((key, c))
            if i is not None:
                view = coef[seg_coef[i] : seg_coef[i + 1]].reshape(cfs[c].shape)
                view[...] = cfs[c]
                cfs[c] = view
        b.basis, b.coefficients = stacks[key[0]][lo : lo + b.basis.shape[0]], tuple(cfs)
    image_of = {pair: i for i, pair in enumerate(sorted({(key[0], key[2]) for key in keys}))}
    return _Packed(
        stacks=stacks,
        region_start=np.asarray(region_start, np.int64),
        n_images=len(image_of),
        seg_image=np.array([image_of[key[0], key[2]] for key, _ in segments], np.int64),
        coef=coef,
        pixel=np.concatenate([blocks[key].rows[c] for key, c in segments] + [np.zeros(0, np.int64)]).astype(np.int64),
        seg_row=np.cumsum(seg_rows) - seg_rows,
        seg_rows=seg_rows,
        seg_k=seg_k,
        seg_proj=np.array([proj_of[key] for key, _ in segments], np.int64),
        seg_channel=np.array([c for _, c in segments], np.int64),
        seg_coef=seg_coef[:-1],
    )


def _relight_numba(pk, wd, regions, n_pix):
    """The compiled relight (:mod:`facestats.relight.compression_numba`): the lighting ``wd`` (L, 3) projected on
    every region's stacked bases, then the rows' products in parts of about equal work (a few per thread), into
    one image per (region, part); (n_pix, 3) float32."""
    import numba

    from facestats.relight.compression_numba import project, relight_segments

    proj = np.empty((3, pk.components), np.float32)
    for r, lights in enumerate(regions):  # loop over the light regions: one compiled product each
        project(pk.stacks[r], np.ascontiguousarray(wd[lights].T), proj, pk.region_start[r])
    work = np.cumsum(pk.seg_rows * (pk.seg_k + 1))
    n_parts = max(1, min(4 * numba.get_num_threads(), work.size))  # a few parts per thread balance better
    cuts = np.searchsorted(work, work[-1] * np.arange(1, n_parts) / n_parts) if work.size else []
    bounds = np.concatenate([[0], cuts, [work.size]]).astype(np.int64)
    out = np.zeros((pk.n_images, n_pix, 3), np.float32)
    relight_segments(
        pk.coef,
        pk.pixel,
        pk.seg_image,
        pk.seg_row,
        pk.seg_rows,
        pk.seg_k,
        pk.seg_proj,
        pk.seg_channel,
        pk.seg_coef,
        bounds,
        proj,
        out,
    )
    return out.sum(0)


@dataclass
class CompressedField:
    """A reflectance field in clustered PCA bases per light region (module docstring).

    Attributes
    ----------
    pixels : ndarray of int, shape (P,)
        Flat index (row · W + column) of each stored pixel.
    labels : ndarray of int, shape (P,)
        Cluster of each stored pixel.
    regions : list of ndarray of int
        The lights (flat indices) of each region.
    blocks : dict
        (region, cluster, part) → block: its support (the region's lights of the part), basis (K, L_r), zero
        off the support, per channel the stored rows and their coefficients.
    residual : ndarray, shape (P, 3)
        ‖√δA (R − R̂)‖ of each pixel and channel.
    order : ndarray of int, shape (N, 3)
        (region, cluster, part) of every offered component in the greedy order; the first ``kept`` are kept.
    kept : int
    sqrt_solid_angle : ndarray, shape (L,)
    directions : ndarray, shape (light dims..., 3)
    image_shape : tuple of int
    parts : int
        Parts per (region, cluster) block (:func:`compress`).

    Notes
    -----
    At construction the blocks' bases and coefficients are packed into flat arrays that the relight reads, and
    become views of them: treat ``blocks`` as read-only (a changed block would not reach :meth:`relight`).
    """

    pixels: np.ndarray
    labels: np.ndarray
    regions: list
    blocks: dict
    residual: np.ndarray
    order: np.ndarray
    kept: int
    sqrt_solid_angle: np.ndarray
    directions: np.ndarray
    image_shape: tuple
    parts: int
    _packed: _Packed = dataclass_field(init=False, repr=False, compare=False)

    def __post_init__(self):
        self._packed = _pack(self.blocks, self.regions)

    @property
    def clusters(self) -> int:
        return int(self.labels.max()) + 1 if self.labels.size else 0

    @property
    def n_lights(self) -> int:
        return int(self.sqrt_solid_angle.size)

    @property
    def components(self) -> int:
        """Basis rows kept over all blocks."""
        return int(sum(b.basis.shape[0] for b in self.blocks.values()))

    @property
    def stored(self) -> int:
        """Stored values: basis rows, coefficients and :func:`per_pixel_values` per pixel."""
        per_pixel = per_pixel_values(len(self.regions) * self.parts)
        return int(sum(b.stored for b in self.blocks.values())) + per_pixel * self.pixels.size

    @property
    def ratio(self) -> float:
        """Dense face values over stored values: 3 L P / :attr:`stored`."""
        return 3 * self.n_lights * self.pixels.size / self.stored

    def truncate(self, ratio: float) -> "CompressedField":
        """The same field with the greedy prefix of its components that meets ``ratio`` (residuals only grow; a
        ratio at or below :attr:`ratio` keeps them all)."""
        r = _ratio(ratio)
        per_pixel = per_pixel_values(len(self.regions) * self.parts)
        budget = (3 * self.n_lights - per_pixel * r) * self.pixels.size / r
        cost = {key: int(b.support.sum()) + sum(x.size for x in b.rows) for key, b in self.blocks.items()}
        first = {key: _mask_values(b.support) for key, b in self.blocks.items()}
        keep, per_block = _take(self.order[: self.kept], cost, budget, first)
        if keep == 0:
            key = tuple(self.order[0])
            raise ValidationError(_no_room(r, cost[key] + first[key], budget))
        res2 = self.residual.astype(np.float64) ** 2
        blocks = {}
        for key, b in self.blocks.items():
            k = per_block.get(key, 0)
            for c in range(3):
                dropped = b.coefficients[c][:, k:]
                res2[b.rows[c], c] += np.einsum("nk,nk->n", dropped, dropped, dtype=np.float64)
            if k:
                blocks[key] = _Block(
                    support=b.support,
                    basis=b.basis[:k].copy(),
                    rows=b.rows,
                    coefficients=tuple(np.ascontiguousarray(cf[:, :k]) for cf in b.coefficients),
                )
        return replace(self, blocks=blocks, residual=np.sqrt(res2).astype(np.float32), kept=keep)

    def _weights(self, lighting):
        """L·δA per light as (L, 3) float64; grey lighting (one value per light) is given to every channel."""
        w = as_finite(lighting, "lighting", dtype=np.float64)
        if w.shape in (self.directions.shape[:-1], (self.n_lights,)):
            w = np.repeat(w[..., None], 3, axis=-1)
        if w.shape[:-1] not in (self.directions.shape[:-1], (self.n_lights,)) or w.shape[-1] != 3:
            raise ValidationError(
                f"lighting must hold L·δA per light, shape {self.directions.shape[:-1] + (3,)}, got {w.shape}"
            )
        return w.reshape(-1, 3)

    def relight(
        self, lighting=None, *, probe=None, layout: str = "latlong", rotate: float = 0.0, backend: str = "auto"
    ) -> np.ndarray:
        """Relit image from the compressed field, (H, W, 3) float32 (Debevec et al. 2000 eq. 4).

        Per block: proj = B_kr (W/√δA)_r (one product per region over its blocks' stacked bases), then each
        stored row adds C · proj of its channel.  ``lighting`` is L·δA per light (as
        :func:`facestats.relight.relighting.relight`); or pass a ``probe`` (with ``layout``, ``rotate``) to
        resample.  ``backend`` (:data:`facestats.core.compiled.BACKENDS`): ``"numba"`` computes the projections
        and the rows' products in compiled passes over the stored values on all cores
        (:mod:`facestats.relight.compression_numba`; its cost does not grow with the number of blocks),
        ``"numpy"`` one BLAS product per region and one GEMV per block and channel (a Python loop over
        3 × regions × clusters segments); they agree to float32 rounding.
        """
        if (lighting is None) == (probe is None):
            raise ValidationError("pass exactly one of lighting (L·δA per light) and probe")
        if probe is None and rotate != 0:
            raise ValidationError(f"rotate applies to a probe, got rotate={rotate!r} with lighting")
        engine = resolve_backend(backend)
        if probe is not None:
            lighting = resample_probe(probe, self.directions, layout=layout, rotate=rotate)
        wd = as_float(self._weights(lighting) / self.sqrt_solid_angle[:, None], "lighting / √δA", np.float32)  # (L, 3)
        pk = self._packed
        if engine == "numba":
            vals = _relight_numba(pk, wd, self.regions, self.pixels.size)
        else:
            proj = np.empty((3, pk.components), np.float32)  # per channel, the lighting on every component
            for r, lights in enumerate(self.regions):  # one GEMM per region: its blocks' bases are stacked
                proj[:, pk.region_start[r] : pk.region_start[r + 1]] = (pk.stacks[r] @ wd[lights]).T
            vals = np.zeros((self.pixels.size, 3), np.float32)
            for s in range(pk.seg_rows.size):  # loop over (block, channel) segments: one GEMV each
                n, k, c = pk.seg_rows[s], pk.seg_k[s], pk.seg_channel[s]
                rows = pk.pixel[pk.seg_row[s] : pk.seg_row[s] + n]
                cf = pk.coef[pk.seg_coef[s] : pk.seg_coef[s] + n * k].reshape(n, k)
                vals[rows, c] += cf @ proj[c, pk.seg_proj[s] : pk.seg_proj[s] + k]
        out = np.zeros((self.image_shape[0] * self.image_shape[1], 3), np.float32)
        out[self.pixels] = vals
        return check_relit(out.reshape(self.image_shape + (3,)), "compressed relight")

    def error_bound(self, lighting) -> np.ndarray:
        """Per-pixel bound on |relight(compressed) − relight(dense)| over the stored pixels (0 elsewhere):
        residual · ‖W/√δA‖, (H, W, 3) (Cauchy-Schwarz)."""
        w = self._weights(lighting)
        norm = np.sqrt(((w / self.sqrt_solid_angle[:, None]) ** 2).sum(0))
        out = np.zeros((self.image_shape[0] * self.image_shape[1], 3), np.float32)
        out[self.pixels] = self.residual * norm
        return out.reshape(self.image_shape + (3,))

    def reconstruct(self) -> np.ndarray:
        """The approximated field, (L, H, W, 3) float32 (for inspection; memory of the dense field)."""
        rows = np.zeros((3, self.pixels.size, self.n_lights), np.float32)
        for (r, _, _), b in self.blocks.items():  # loop over blocks
            lights = self.regions[r]
            for c in range(3):
                rows[c, b.rows[c][:, None], lights[None, :]] += b.coefficients[c] @ b.basis  # parts add
        out = np.zeros((self.n_lights, self.image_shape[0] * self.image_shape[1], 3), np.float32)
        out[:, self.pixels] = np.transpose(rows, (2, 1, 0)) / self.sqrt_solid_angle[:, None, None]
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
    block = np.asarray(f["reflectance"].isel(y=ys, x=xs).values)
    flat = block.reshape((sw.size, -1, 3))[:, inside, :]  # (L, n_pix, 3), gathered in the stored dtype
    bad = ~np.isfinite(flat)
    if bad.any():  # a NaN would make the bases' eigendecomposition fail or spread into a whole cluster
        light, i, c = (int(v) for v in np.argwhere(bad)[0])
        y, x = ys.start + int(inside[i]) // (xs.stop - xs.start), xs.start + int(inside[i]) % (xs.stop - xs.start)
        raise ValidationError(
            f"field reflectance must be finite, got {float(flat[light, i, c])!r} at pixel (y={y}, x={x}), light "
            f"{light} (flat index), channel {c} ({int(bad.sum())} non-finite value(s) in that tile)"
        )
    rows = np.empty((inside.size, 3, sw.size), np.float32)
    rows[...] = np.transpose(flat, (1, 2, 0))  # converted once, face pixels only
    rows *= sw.astype(np.float32)
    return rows


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


def _normalised(rows):
    """Rows divided by their norms (taken in float64: no overflow for float32 rows; zero rows stay zero)."""
    norm = np.sqrt(np.einsum("...l,...l->...", rows, rows, dtype=np.float64))[..., None]
    return (rows / np.where(norm > 0, norm, 1)).astype(rows.dtype)


def _region_scales(rows, regions, sw, floor):
    """Per region, the divisor max(s_r, ``floor`` · s) (n, 3) float64 of each row's part (module docstring, *The
    error metric*): s_r = Σ_{l∈r} √δA_l |y_l| of the weighted rows y (n, 3, L), s = Σ_r s_r."""
    absw = np.abs(rows)
    parts = [np.einsum("ncl,l->nc", absw[:, :, lights], sw[lights], dtype=np.float64) for lights in regions]
    total = np.sum(parts, axis=0)
    return [np.maximum(part, floor * total) for part in parts]


def _supports(stream, labels, regions, parts):
    """The lights of each (region, cluster, part) block, (L_r,) bool: the region's lights split by the share of the
    (region, cluster) block's non-zero rows that are zero there, part q holding the shares in [q/``parts``,
    (q + 1)/``parts``) (the last one including 1).  Parts with no light are left out."""
    zeros, rows_of = {}, {}
    for sel, rows in stream.each("compress: zero patterns"):
        lab = labels[sel]
        for r, lights in enumerate(regions):
            sub = rows[:, :, lights]  # (n, 3, L_r)
            nonzero = np.any(sub != 0, axis=-1)
            for k in np.unique(lab):  # loop over the clusters present in this tile
                here = (lab == k)[:, None] & nonzero
                if here.any():
                    key = (r, int(k))
                    z = zeros.setdefault(key, np.zeros(lights.size, np.int64))
                    z += np.count_nonzero(sub[here] == 0, axis=0)
                    rows_of[key] = rows_of.get(key, 0) + int(here.sum())
    out = {}
    for (r, k), z in zeros.items():  # loop over (region, cluster) blocks
        part = np.minimum((z * parts) // rows_of[r, k], parts - 1)  # exact integer shares
        for q in range(parts):
            if np.any(part == q):
                out[(r, k, q)] = part == q
    return out


def _parts_of(keys):
    """(region, cluster) → its (region, cluster, part) keys among ``keys``."""
    out = {}
    for key in keys:
        out.setdefault(key[:2], []).append(key)
    return out


def _grams(stream, labels, regions, floor, supports):
    """Gram matrices Σ yᵀy (float64, (L, L) over the block's L lights) of the scaled non-zero parts of the rows
    (:func:`_region_scales`) of each (region, cluster, part) block, and the number of those parts."""
    grams, counts = {}, {}
    parts_of = _parts_of(supports)
    for sel, rows in stream.each("compress: gram matrices"):
        lab = labels[sel]
        scales = _region_scales(rows, regions, stream.sw, floor)
        for r, lights in enumerate(regions):
            sub = rows[:, :, lights]  # (n, 3, L_r)
            sub = sub / np.where(scales[r] > 0, scales[r], 1)[..., None]
            for k in np.unique(lab):  # loop over the clusters present in this tile
                mine = sub[lab == k]
                for key in parts_of.get((r, int(k)), ()):  # loop over the block's parts
                    part = mine[:, :, supports[key]]
                    y = part[np.any(part != 0, axis=-1)]
                    if y.shape[0]:
                        g = grams.setdefault(key, np.zeros((y.shape[1], y.shape[1])))
                        g += y.T @ y
                        counts[key] = counts.get(key, 0) + y.shape[0]
    return grams, counts


def _bases(grams, supports):
    """Per block: the principal directions (K, L_r) float32, zero off its support, and their σ², non-increasing
    (σ² > 1e-12 σ²_max).  Empties ``grams`` as it goes (each Gram matrix is freed once its directions are known)."""
    out = {}
    for key in list(grams):  # loop over blocks
        e, v = np.linalg.eigh(grams.pop(key))
        e, v = e[::-1], v[:, ::-1]
        keep = e > max(e[0], 1e-300) * 1e-12
        basis = np.zeros((int(keep.sum()), supports[key].size), np.float32)
        basis[:, supports[key]] = v[:, keep].T
        out[key] = (basis, e[keep])
    return out


def _no_room(ratio, first, budget):
    """The message of a ratio whose budget cannot hold the first component of the greedy order."""
    return (
        f"ratio {ratio:g} leaves {max(budget, 0):.0f} values after the per-pixel ones, and the first component "
        f"costs {first}; use a smaller ratio"
    )


def _take(order, cost, budget, first):
    """The greedy prefix of ``order`` (rows (region, cluster, part)) within ``budget`` stored values, one component of
    block b costing ``cost[b]`` and its first one ``first[b]`` more (the support's mask): (its length, components
    per block)."""
    used, counts = 0, {}
    for i, row in enumerate(order):
        key = tuple(int(v) for v in row)
        price = cost[key] + (0 if key in counts else first[key])
        if used + price > budget:
            return i, counts
        used += price
        counts[key] = counts.get(key, 0) + 1
    return len(order), counts


def _mask_values(support):
    """Stored values of a block's support mask: none when it is the whole region."""
    return 0 if support.all() else -(-support.size // 32)


def _coefficients(stream, labels, regions, bases, supports):
    """Per block and channel: the stored rows (positions in the face pixels) and their coefficients on the
    block's K components (``bases``: the kept ones); the residual ‖√δA (R − R̂)‖ (P, 3) of every row."""
    stored = {key: ([[], [], []], [[], [], []]) for key in bases}
    parts_of = _parts_of(bases)
    res2 = np.zeros((stream.n_pix, 3))
    for sel, rows in stream.each("compress: coefficients"):
        lab = labels[sel]
        for r, lights in enumerate(regions):
            sub = rows[:, :, lights]  # (n, 3, L_r), unscaled
            for k in np.unique(lab):  # loop over the clusters present in this tile
                mine = np.flatnonzero(lab == k)
                sub_k = sub[mine]
                for key in parts_of.get((r, int(k)), ()):  # loop over the block's parts
                    basis = bases[key][:, supports[key]]  # (K, L) on the support
                    part = sub_k[:, :, supports[key]]  # (m, 3, L)
                    nonzero = np.any(part != 0, axis=-1)
                    for c in range(3):
                        here = np.flatnonzero(nonzero[:, c])
                        if not here.size:
                            continue
                        y = part[here, c]
                        cf = y @ basis.T  # (n, K)
                        res2[sel[mine[here]], c] += np.sum((y - cf @ basis).astype(np.float64) ** 2, axis=-1)
                        if basis.shape[0]:  # a block without components stores nothing
                            stored[key][0][c].append(sel[mine[here]])
                            stored[key][1][c].append(cf)
    return stored, np.sqrt(res2).astype(np.float32)


def compress(
    field,
    ratio: float = 20,
    *,
    clusters: int | None = None,
    sectors: int = 4,
    floor: float = 0.2,
    parts: int = 2,
    features: int = 32,
    sample: int = 256,
    seed: int = 0,
    progress: bool = False,
) -> CompressedField:
    """Compress a reflectance field into clustered, solid-angle weighted PCA bases per light region (module docstring).

    Streaming passes over the field's tiles (in memory or on disk): a global
    basis of ``features`` components from a sample of pixels and every pixel's
    projection on it; k-means of those projections into ``clusters``; how often
    each (region, cluster) block's rows are zero at each light, which splits its
    lights into ``parts`` (a pass of its own: the split must be known before the
    Gram matrices count the rows each part stores); the Gram matrix of every
    (region, cluster, part) block from all its pixels' scaled non-zero parts,
    and its principal directions; the greedy choice of components for the ratio;
    then every stored row's coefficients and every row's residual.

    Parameters
    ----------
    field : xarray.Dataset
    ratio : float
        Minimum compression ratio (> 0; below 1 stores more than the dense field, e.g. every component).
    clusters : int, optional
        Number of clusters C (default :func:`default_clusters`: one per 128 face pixels).
    sectors : int
        Azimuth sectors per hemisphere of :func:`light_regions` (2 × ``sectors`` regions).
    floor : float
        In [0, 1]: a region's part of a row is scaled by 1 / max(s_r, ``floor`` · s) before the bases are found
        (module docstring, *The error metric*; 1 scales every part by its row's s).
    parts : int
        In [1, 8]: each (region, cluster) block's lights are split into this many parts by how often the cluster's
        functions are zero there, each part with its own basis (module docstring, *Parts by zeros*).
    features : int
        Components of the global basis that the clustering works on (at most the number of lights).
    sample : int
        Pixels per cluster (times C) that estimate the global basis of the clustering.
    seed : int
        Seed of that sample and of k-means.
    progress : bool
        Progress bar over tiles.

    Returns
    -------
    CompressedField
    """
    f = as_field(field)
    directions, sa, _ = light_table(f)
    sw = np.sqrt(sa)
    n = sa.size
    pixels = _face_pixels(f)
    if pixels.size == 0:
        raise ValidationError("field has no pixel with a non-zero reflectance (or its mask is empty)")
    r_min = _ratio(ratio)
    c = default_clusters(pixels.size) if clusters is None else check_integer(clusters, "clusters", 1, pixels.size)
    s = check_integer(sample, "sample", 1)
    fl = _number(floor, "floor", 0, 1)
    n_parts = check_integer(parts, "parts", 1, 8)
    nf = min(check_integer(features, "features", 1), n)
    rng = np.random.default_rng(check_seed(seed))
    region_of = light_regions(directions, sectors)
    regions = [np.flatnonzero(region_of == r) for r in range(2 * sectors)]
    regions = [lights for lights in regions if lights.size]
    stream = _Pass(f, pixels, sw, progress)
    labels = _clusters(stream, c, nf, s, rng)
    supports = _supports(stream, labels, regions, n_parts)
    grams, rows_of = _grams(stream, labels, regions, fl, supports)  # rows_of: the rows a block stores
    bases = _bases(grams, supports)
    cost = {key: int(supports[key].sum()) + rows_of[key] for key in bases}  # stored values of one component
    first = {key: _mask_values(supports[key]) for key in bases}  # and of a block's support mask
    gain = [(e / cost[key], key) for key, (_, sigma2) in bases.items() for e in sigma2]
    gain.sort(key=lambda g: -g[0])
    order = np.array([key for _, key in gain], np.int64).reshape(-1, 3)
    if not order.size:
        raise ValidationError("field has no face pixel with a non-zero reflectance: nothing to compress")
    budget = 3 * n * pixels.size / r_min - per_pixel_values(len(regions) * n_parts) * pixels.size
    kept, counts = _take(order, cost, budget, first)
    if kept == 0:
        key = tuple(order[0])
        raise ValidationError(_no_room(r_min, cost[key] + first[key], budget))
    bases = {key: basis[: counts.get(key, 0)].copy() for key, (basis, _) in bases.items()}  # free the rest
    stored, residual = _coefficients(stream, labels, regions, bases, supports)
    blocks = {}
    for key, basis in bases.items():
        k = basis.shape[0]
        if k:
            rows = tuple(np.concatenate(p) if p else np.zeros(0, np.int64) for p in stored[key][0])
            coef = tuple(np.concatenate(p) if p else np.zeros((0, k), np.float32) for p in stored[key][1])
            blocks[key] = _Block(support=supports[key], basis=basis, rows=rows, coefficients=coef)
    return CompressedField(
        pixels=pixels,
        labels=labels,
        regions=regions,
        blocks=blocks,
        residual=residual,
        order=order,
        kept=kept,
        sqrt_solid_angle=sw,
        directions=np.asarray(f["direction"].values, np.float64),
        image_shape=(f.sizes["y"], f.sizes["x"]),
        parts=n_parts,
    )
