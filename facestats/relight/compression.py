"""Compressed relighting: clustered PCA of solid-angle weighted reflectance functions by colour row and light region.

Debevec et al. 2000 §3.3 relight directly from JPEG-compressed reflectance
functions (Smith & Rowe's compressed-domain products) "reducing both storage
and computation by a factor of twenty"; §5 suggests exploiting the similarity
of neighbouring reflectance functions.  facestats writes each pixel's three
channel functions in the colour basis of the paper's §4.2 and keeps a *shared
basis per cluster of pixels, colour row and region of the light sphere*
(clustered PCA, Sloan et al. 2003, with the lights split into regions):

    √δA_l R_p(l) = Σ_q A_p,q g_p,q(l),    A_p = [d_p  s  d_p × s]              (§4.2: R = μd d + μs s + μe e)
    g_p,q(l) ≈ Σ_{j<K} C_p,q,r,j B_kqr,j(l)   for the lights l of region r,  k = cluster of pixel p

where R_p(l) is the pixel's RGB value under light l, d_p its diffuse colour and
s the light's (unit RGB vectors), g_p,q the rows of its coordinates μ (diffuse,
specular, off the plane; below), the B_kqr the leading principal directions
(uncentred) of the region-r parts (split further by zeros, below) of the rows
g_p,q of *every* pixel of cluster k, each part scaled for the error it makes in
the channels (see *The error metric* below), and the coefficients C the
projections of the unscaled parts.  Choice and
justification (the measurements behind it: ``docs/relighting.md``, D2):

* **Colour rows.**  Per pixel the three channel functions lie in one plane
  of colour space, spanned by the diffuse colour d and the light's colour s:
  the diffuse term has one shape in all channels (the chromaticity ramp of
  eq. 6 moves its colour within that plane) and the specular term has the
  light's colour.  So each pixel is stored as two rows, its coordinates μd
  and μs in the basis [d s d×s] of §4.2, instead of three channel rows: a
  third of the coefficients is saved and spent on more components.  The μs
  row is zero wherever no specular light falls, and diffuse shapes and
  specular lobes get bases of their own (each colour row q its own blocks).
  The coordinate off the plane, μe, holds noise and inter-reflections of
  another colour; it is stored as a third row only where its contribution's
  norm exceeds ``off_plane`` times the pixel's (none on a rendered field; on
  measured data the greedy choice below weighs it like any row), and left
  out (counted in the residual) elsewhere.  d is the most saturated colour
  among the pixel's lit samples (:func:`diffuse_colours`): a sample of pure
  diffuse light has the diffuse colour, and specular light only moves a
  sample towards s, so μs ≥ 0 and μs = 0 off the lobe (the median colour of
  mid-bright samples, :func:`facestats.relight.separate.diffuse_chromaticity`,
  lies inside the cone and gives μs < 0 on every purely diffuse sample).
  Measured against three channel rows on the 256² face at 20× (12 lightings,
  docs/relighting.md, D2): the median worst pixel fell from 5.0 % to 3.4 %.
* **Cost of a relight.**  The lighting is projected once on every basis
  (Σ K L_r multiply-adds per channel) and each stored row then needs 3 K
  multiply-adds (its coordinate under each channel's lighting) and mixes the
  three results into the pixel's channels with A_p: one pass over the stored
  coefficients, which are kept in one flat array (compiled,
  :mod:`facestats.relight.compression_numba`; or one small dense GEMM per
  block with ``backend="numpy"``).  A
  per-pixel transform (DCT/wavelet of each 64 × 32 function, the paper's JPEG)
  keeps different coefficients per pixel and needs a gather per coefficient;
  measured on a face field, a per-pixel Haar truncation to 1/20 of the
  coefficients also errs far more than a shared basis.
* **Why clusters.**  One global basis cannot follow the specular lobe and the
  shadow edges, whose position moves with the normal.  Pixels with similar
  reflectance functions share a basis well; the clusters are found by k-means
  on the projections of their luminance functions onto a global basis.
* **Why light regions.**  Over half of the (pixel, light) values of a face
  are exactly zero: lights below a pixel's horizon or behind the nose.  A
  basis over the whole sphere reconstructs them with small ripples, and a
  bright source there (a window, the sun) multiplies the ripple into errors of
  100 % and more on the pixels it does not light.  Split into regions (the two
  hemispheres y ≥ 0 and y < 0, each into ``sectors`` azimuth sectors about +y),
  a row that is zero over a whole region is not stored and comes back exactly
  zero (a pixel's rows are zero wherever all its channels are), and ripples
  stay inside the region they belong to.
* **Components where they pay.**  Each (cluster, region) block offers its
  components in the order of its singular values; a component of block b costs
  L_b + n_b stored values (its basis row and one coefficient per stored row),
  its first one also the block's header (its number of components), and
  removes σ² of the scaled rows' squared residual.  Components are taken
  greedily by σ² per stored value until the budget of the ratio is spent, so
  flat regions get none and the specular regions many.
* **The error metric.**  Environment lighting weights each light by its solid
  angle δA (eq. 4), so each basis minimises Σ_l δA_l (R − R̂)²: rows are scaled
  by √δA.  A relit image is judged by its *relative* error per pixel and
  channel, and a pixel's relit value is the sum of its regions' shares
  y_r · (L √δA)_r.  Under a light that falls on one region only, the relative
  error of the pixel is its residual there against s_r = Σ_{l∈r} √δA_l |y_l|,
  the region's value under uniform light of unit radiance (the √δA-weighted
  L1 norm of the part).  Its tolerance is t_c,r = max(s_c,r, ``floor`` · s_c),
  s_c = Σ_r s_c,r: a dark blue channel weighs as much as a bright red one, and
  a region that holds a small share of the pixel's light is weighed as if it
  held ``floor`` (scaled by s_r alone, the bases would chase regions that hardly
  light the pixel under any probe).  An error in colour row q adds A_cq times
  it to channel c, so each region's part of row q enters its block's basis and
  the greedy choice scaled by max_c |A_cq| / t_c,r (with A the identity, one row
  per channel, this is the scaling of the channel rows by 1 / t_c,r).  The default floor is chosen by
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
  (colour row, region, part).
* **Honest diagnostics.**  The components of a block are nested and the greedy
  order is fixed, so keeping fewer (:meth:`CompressedField.truncate`) never
  lowers any row's residual ρ_q = ‖g_q − ĝ_q‖, and by Cauchy-Schwarz and the
  triangle inequality the relighting error of channel c of a pixel is bounded
  by Σ_q |A_cq| ρ_q ‖L_c / √δA‖ (:meth:`CompressedField.error_bound`).

The compression ratio counts stored values: L·P·3 dense values of the face
pixels against the basis rows and coefficients plus, per pixel, its cluster
label, the bit mask of its zero (colour row, region, part) rows and its diffuse
colour d (:func:`per_pixel_values`), and the light colour s.
Only the face pixels (the field's ``mask``, else the pixels with a non-zero
value) are stored: pixels outside the mask relight to 0, and
:meth:`CompressedField.error_bound` covers the stored pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from dataclasses import field as dataclass_field

import numpy as np

from facestats.core.compiled import resolve_backend
from facestats.core.progress import progress_bar
from facestats.core.validate import as_finite, as_float, check_integer, check_seed
from facestats.errors import ValidationError
from facestats.relight.field import as_field, image_tiles, light_dims, light_table
from facestats.relight.lighting import resample_probe
from facestats.relight.relighting import check_relit
from facestats.relight.separate import WHITE, separation_basis, unit_rgb

__all__ = [
    "CompressedField",
    "compress",
    "default_clusters",
    "diffuse_colours",
    "light_regions",
    "per_pixel_values",
    "ratio_bound",
    "relative_errors",
]

#: Target pixels per cluster of the default clustering.  Smaller clusters fit their pixels better but spend more
#: of the budget on bases; on the 256² face at 20× (``benchmarks/bench_relight.bench_cluster_density``, table in
#: docs/relighting.md, measured with one row per channel) the median over 12 lightings and 3 seeds of the worst
#: pixel falls from 12.8 % at 512 pixels per cluster to 9.2 % at 128 and stops falling at 64.  The compiled
#: relight's cost does not depend on the clusters (it reads every stored value once; the numpy backend's grows
#: with them); compressing takes longer.
PIXELS_PER_CLUSTER = 128

#: Negative values summing to at most this share of the positive ones are a field of radiance's noise
#: (:attr:`CompressedField.nonnegative`): a single value of −1e-9 turned the clamp off (a red team).
NEGATIVE_NOISE = 1e-3

#: Samples whose coordinate along the light colour s reaches this share of the pixel's largest take part in its
#: diffuse colour (:func:`diffuse_colours`): dimmer samples' colours are dominated by rounding and noise.
LIT_SHARE = 0.05

#: A diffuse colour within this angle (radians) of the light colour is not used as a basis vector (the basis
#: [d s d×s] would be ill-conditioned): such grey pixels use the direction of their colours' offset from s.
GREY_ANGLE = np.radians(5.0)

#: Colour rows: 0 the diffuse coordinate μd, 1 the specular μs, 2 the one off the plane μe (§4.2).
ROWS = 3


def per_pixel_values(n_parts: int) -> int:
    """Values stored per pixel besides its coefficients: its cluster label, its bit mask of zero rows
    (3 colour rows × ``n_parts`` (region, part) bits, in 32-bit values) and its diffuse colour (3).

    Parameters
    ----------
    n_parts : int
        Number of (light region, part) pairs of the field.

    Returns
    -------
    int
        ``1 + ceil(3 n_parts / 32) + 3``.
    """
    return 1 + -(-ROWS * n_parts // 32) + 3


def _number(value, name, low, high=None, **bounds):
    """A finite scalar within [``low``, ``high``] (``bounds``: as :func:`facestats.core.validate.check_range`)."""
    if isinstance(value, (bool, np.bool_)):
        raise ValidationError(f"{name} must be a number, got {value!r}")
    r = as_finite(value, name, low, high, **bounds)
    if r.ndim:
        raise ValidationError(f"{name} must be a number, got an array of shape {r.shape}")
    return float(r)


def _ratio(value):
    """A positive finite scalar ratio."""
    return _number(value, "ratio", 0, low_inclusive=False)


def default_clusters(n_pixels: int) -> int:
    """About one cluster per :data:`PIXELS_PER_CLUSTER` face pixels (at least 1).

    Parameters
    ----------
    n_pixels : int
        Number of face pixels stored.

    Returns
    -------
    int
        ``max(1, round(n_pixels / PIXELS_PER_CLUSTER))``.
    """
    return max(1, int(round(n_pixels / PIXELS_PER_CLUSTER)))


def ratio_bound(directions, sectors: int = 4, parts: int = 2) -> float:
    """The compression ratio at which the per-pixel values alone fill the budget of a field of these lights.

    At ratio ρ a field of L lights and P face pixels keeps 3 L P / ρ values; :func:`per_pixel_values` of them
    per pixel go to labels, zero masks and colours, for ``sectors`` × 2 regions × ``parts``.  At or above
    3 L / :func:`per_pixel_values` no component fits, whatever P (``compress`` would refuse).

    Parameters
    ----------
    directions : array_like, shape (L, 3)
        The field's light directions.
    sectors, parts : int
        As :func:`compress` takes them (its defaults).

    Returns
    -------
    float
        The compression ratio.
    """
    d = as_finite(directions, "directions", dtype=np.float64).reshape(-1, 3)
    regions = np.unique(light_regions(d, sectors)).size
    return 3 * len(d) / per_pixel_values(regions * check_integer(parts, "parts", 1))


def light_regions(directions, sectors: int = 4) -> np.ndarray:
    """Region (int64, in [0, 2 ``sectors``)) of each light direction (…, 3), facestats world frame (+y up).

    Region h · ``sectors`` + s: hemisphere h = 0 for y ≥ 0, 1 below; azimuth sector
    s = ⌊(atan2(x, z) + π) / (2π / ``sectors``)⌋ about +y (sector 0 starts at −z, turning through −x).

    Parameters
    ----------
    directions : array_like, shape (..., 3)
        Light directions (finite; need not be unit vectors).
    sectors : int
        Azimuth sectors per hemisphere, ≥ 1.

    Returns
    -------
    numpy.ndarray of int64, shape (...)
        The region of each direction.

    Raises
    ------
    ValidationError
        Non-finite directions, a last axis other than 3, or ``sectors`` < 1.
    """
    d = as_finite(directions, "directions", dtype=np.float64)
    if d.ndim < 1 or d.shape[-1] != 3:
        raise ValidationError(f"directions must have shape (..., 3), got {d.shape}")
    n = check_integer(sectors, "sectors", 1)
    azimuth = np.arctan2(d[..., 0], d[..., 2]) + np.pi
    sector = np.minimum((azimuth / (2 * np.pi / n)).astype(np.int64), n - 1)
    return np.where(d[..., 1] >= 0, 0, n) + sector


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


def _normalised(rows):
    """Rows divided by their norms (taken in float64: no overflow for float32 rows; zero rows stay zero)."""
    norm = np.sqrt(np.einsum("...l,...l->...", rows, rows, dtype=np.float64))[..., None]
    return (rows / np.where(norm > 0, norm, 1)).astype(rows.dtype)


def light_colour(value, name: str = "specular") -> np.ndarray:
    """A light colour as a unit RGB vector (3,) float64: finite, no component negative, not all zero."""
    c = as_finite(value, name, dtype=np.float64)
    if c.shape != (3,):
        raise ValidationError(f"{name} must be one RGB colour, shape (3,), got shape {c.shape}")
    if np.any(c < 0) or not np.any(c > 0):
        raise ValidationError(f"{name} must have components >= 0, not all zero (a light's colour), got {c.tolist()}")
    return unit_rgb(c, name)


def diffuse_colours(rows, specular=WHITE) -> np.ndarray:
    """Diffuse colour d of each pixel's reflectance functions, (n, 3) float64 unit RGB vectors.

    ``rows`` (n, 3, L): each pixel's channel functions (any positive weight per light, e.g. √δA); ``specular``
    the light's colour s (3,).  Debevec et al. 2000 §4.2 write a sample as R = μd d + μs s + μe (d × s).  The
    lit samples (coordinate along s at least :data:`LIT_SHARE` of the pixel's largest) of a diffuse and specular
    pixel lie in the cone between d and s: a sample of pure diffuse light has colour d and specular light only
    moves it towards s.  So d is the lit sample farthest from s: with u the unit direction of the pixel's summed
    offset from s, d ∝ s + t u, t the largest ratio (R · u) / (R · s) over the lit samples; then μs ≥ 0 on the
    lit samples.  When the pixel has a purely diffuse lit sample, d is its diffuse colour and μs = 0 on those
    samples (exactly, without noise); when every lit sample holds some specular light (a broad lobe's tail), d
    lies that little towards s (9e-5 for a Torrance-Sparrow lobe of m = 0.35 in the tests).  A pixel whose d
    would lie within :data:`GREY_ANGLE` of s (grey), or with no offset at all, gets d = u (a unit vector
    orthogonal to s) instead.

    Parameters
    ----------
    rows : array_like, shape (n, 3, L)
        Channel functions per pixel (finite; read as float32), at least one light.
    specular : array_like, shape (3,)
        Light colour s: components ≥ 0, not all zero (normalised here); default white.

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        Unit diffuse colours d, float64 (d = u also for a pixel without lit samples).

    Raises
    ------
    ValidationError
        For non-finite ``rows`` or another shape, or an invalid ``specular``.
    """
    r = as_finite(rows, "rows", dtype=np.float32)
    if r.ndim != 3 or r.shape[1] != 3 or r.shape[2] < 1:
        raise ValidationError(f"rows must have shape (pixels, 3, lights) with at least one light, got {r.shape}")
    s = light_colour(specular)
    along = np.einsum("ncl,c->nl", r, s.astype(np.float32), dtype=np.float64)  # (n, L)
    total = r.sum(-1, dtype=np.float64)  # (n, 3)
    offset = total - (total @ s)[:, None] * s
    norm = np.linalg.norm(offset, axis=-1)
    offset_ok = norm > 1e-6 * np.linalg.norm(total, axis=-1)  # not rounding of a grey pixel's sum
    spare = np.eye(3)[np.argmin(np.abs(s))]  # a unit vector orthogonal to s, for pixels with no offset
    spare = spare - (spare @ s) * s
    u = np.where(offset_ok[:, None], offset / np.where(offset_ok, norm, 1)[:, None], spare / np.linalg.norm(spare))
    across = np.einsum("ncl,nc->nl", r, u.astype(np.float32), dtype=np.float64)  # (n, L): R · u
    lit = (along > 0) & (along >= LIT_SHARE * along.max(-1, keepdims=True))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(lit, across / np.where(lit, along, 1), -np.inf).max(-1)
    grey = ~offset_ok | ~(t > np.tan(GREY_ANGLE))
    d = np.where(grey[:, None], u, s + np.where(grey, 0, t)[:, None] * u)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _colour_inverse(d, s):
    """[d s d×s]⁻¹ (n, 3, 3) float64 of unit diffuse colours ``d`` (n, 3) and light colour ``s`` (3,)."""
    return np.linalg.inv(separation_basis(d, s))


class _Pass:
    """Streaming reads of a field's face rows, tile by tile (the loop runs over tiles and clusters): √δA-weighted
    channel rows, and once :meth:`set_colours` has run, each pixel's colour rows."""

    def __init__(self, f, pixels, sw, progress):
        self.f, self.sw, self.progress = f, sw, progress
        self.signed = bool(f.attrs.get("signed", False))  # a field of differences (indirect_field)
        self.tiles = _tile_pixels(f, pixels)
        self.n_pix = pixels.size
        self.inverse = self.off_plane = None

    def channels(self, desc):
        """(indices into the face pixels, weighted channel rows (n, 3, L) float32) per tile."""
        for ys, xs, sel, inside in progress_bar(self.tiles, desc=desc, enabled=self.progress, leave=False):
            yield sel, _weighted_rows(self.f, ys, xs, inside, self.sw)

    def set_colours(self, inverse, off_plane):
        """Each pixel's [d s d×s]⁻¹ (P, 3, 3) and whether its off-plane row is stored (P,) bool."""
        self.inverse, self.off_plane = inverse, off_plane

    def colour_rows(self, sel, rows):
        """The colour rows g = [d s d×s]⁻¹ y (n, 3, L) float32 of channel rows y, the product taken in float64 (a
        faint coordinate, e.g. the μs that alone makes a blue channel where the albedo has no blue, keeps its
        own precision), in slices of pixels; off-plane rows not stored set to 0."""
        g = np.empty(rows.shape, np.float32)
        inverse = self.inverse[sel]
        for i in range(0, rows.shape[0], 1024):  # loop over slices of pixels: a float64 slice at a time
            g[i : i + 1024] = np.matmul(inverse[i : i + 1024], rows[i : i + 1024].astype(np.float64))
        g[~self.off_plane[sel], 2] = 0
        return g

    def each(self, desc):
        """(indices, weighted channel rows (n, 3, L), colour rows (n, 3, L)) per tile."""
        for sel, rows in self.channels(desc):
            yield sel, rows, self.colour_rows(sel, rows)

    def rows_of(self, selected, desc):
        """Weighted channel rows (n, 3, L) of the selected pixels and their indices."""
        parts, where = [], []
        for sel, rows in self.channels(desc):
            keep = selected[sel]
            if keep.any():
                parts.append(rows[keep])
                where.append(sel[keep])
        return np.concatenate(parts), np.concatenate(where)


def _colours(stream, s, off_plane):
    """Per face pixel: its diffuse colour d (P, 3), whether its off-plane row is stored (its contribution
    ‖(d×s) μe‖ above ``off_plane`` times the pixel's norm ‖y‖), the squared norm of the rows left out, and whether
    the field holds radiance, not differences (:attr:`CompressedField.nonnegative`)."""
    d = np.empty((stream.n_pix, 3))
    keep = np.zeros(stream.n_pix, bool)
    dropped = np.zeros(stream.n_pix)
    negative = positive = 0.0
    for sel, rows in stream.channels("compress: colours"):
        negative += float(np.sum(np.minimum(rows, 0), dtype=np.float64))
        positive += float(np.sum(np.maximum(rows, 0), dtype=np.float64))
        dd = diffuse_colours(rows, s)
        e = np.einsum("nql,nql->n", rows, rows, dtype=np.float64)
        mu_e = np.einsum("nc,ncl->nl", _colour_inverse(dd, s)[:, 2].astype(np.float32), rows)
        off = np.einsum("nl,nl->n", mu_e, mu_e, dtype=np.float64)
        size = np.linalg.norm(np.cross(dd, s), axis=-1) ** 2 * off
        d[sel], keep[sel] = dd, size > off_plane**2 * e
        dropped[sel] = np.where(keep[sel], 0, off)
    # A field of radiance may carry a little negative noise (a dark-subtracted capture); one of differences
    # (indirect_field: white - black) carries more, and says so.
    nonnegative = -negative <= NEGATIVE_NOISE * positive and not stream.signed
    return d, keep, dropped, nonnegative


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
    for sel, rows in stream.channels("compress: features"):
        feats[sel] = (_normalised(rows.sum(1)) - g_mean) @ g_basis.T  # the shapes of the functions
    _, labels = kmeans2(feats.astype(np.float64), c, seed=int(rng.integers(2**31)), minit="++", iter=20)
    return labels.astype(np.int64)


def _region_scales(rows, regions, sw, floor, mix):
    """Per region, the divisor (n, 3) float64 of each colour row's part (module docstring, *The error metric*).

    ``rows`` (n, 3, L) the weighted channel rows y; the channel tolerances t_c,r = max(s_c,r, ``floor`` · s_c),
    s_c,r = Σ_{l∈r} √δA_l |y_c,l|, s_c = Σ_r s_c,r.  ``mix`` (n, 3, 3), A with channels on axis 1 and colour rows
    on axis 2: the divisor of colour row q is min_c t_c,r / |A_cq| (rows that reach no channel get 1; with A the
    identity, one row per channel, the divisors are the t_c,r).
    """
    absw = np.abs(rows)
    parts = [np.einsum("ncl,l->nc", absw[:, :, lights], sw[lights], dtype=np.float64) for lights in regions]
    total = np.sum(parts, axis=0)
    weight = np.abs(mix)
    out = []
    for part in parts:
        t = np.maximum(part, floor * total)
        with np.errstate(divide="ignore", invalid="ignore"):
            ok = (weight > 0) & (t[:, :, None] > 0)  # a channel that is zero throughout is left out
            q = np.min(np.where(ok, t[:, :, None] / np.where(ok, weight, 1), np.inf), axis=1)
        out.append(np.where(np.isfinite(q), q, 1.0))
    return out


def _supports(stream, labels, regions, parts):
    """The lights of each (region, cluster, row, part) block, (L_r,) bool: the region's lights split by the share
    of the (region, cluster, row) block's non-zero colour rows that are zero there, part q holding the shares in
    [q/``parts``, (q + 1)/``parts``) (the last one including 1).  Parts with no light are left out."""
    zeros, rows_of = {}, {}
    for sel, _, g in stream.each("compress: zero patterns"):
        lab = labels[sel]
        for r, lights in enumerate(regions):
            sub = g[:, :, lights]  # (n, 3, L_r)
            nonzero = np.any(sub != 0, axis=-1)
            for k in np.unique(lab):  # loop over the clusters present in this tile
                for q in range(ROWS):  # and the colour rows
                    here = (lab == k) & nonzero[:, q]
                    if here.any():
                        key = (r, int(k), q)
                        z = zeros.setdefault(key, np.zeros(lights.size, np.int64))
                        z += np.count_nonzero(sub[here, q] == 0, axis=0)
                        rows_of[key] = rows_of.get(key, 0) + int(here.sum())
    out = {}
    for (r, k, q), z in zeros.items():  # loop over (region, cluster, row) blocks
        part = np.minimum((z * parts) // rows_of[r, k, q], parts - 1)  # exact integer shares
        for i in range(parts):
            if np.any(part == i):
                out[(r, k, q, i)] = part == i
    return out


def _parts_of(keys):
    """(region, cluster) → its (region, cluster, row, part) keys among ``keys``."""
    out = {}
    for key in keys:
        out.setdefault(key[:2], []).append(key)
    return out


def _grams(stream, mix, labels, regions, floor, supports):
    """Gram matrices Σ yᵀy (float64, (L, L) over the block's L lights) of the scaled non-zero parts of the colour
    rows (:func:`_region_scales`) of each (region, cluster, row, part) block, and the number of those parts."""
    grams, counts = {}, {}
    parts_of = _parts_of(supports)
    for sel, rows, g in stream.each("compress: gram matrices"):
        lab = labels[sel]
        scales = _region_scales(rows, regions, stream.sw, floor, mix[sel])
        for r, lights in enumerate(regions):
            sub = g[:, :, lights] / scales[r][..., None]  # (n, 3, L_r) float64: the Gram sums need it
            for k in np.unique(lab):  # loop over the clusters present in this tile
                mine = sub[lab == k]
                for key in parts_of.get((r, int(k)), ()):  # loop over the block's rows and parts
                    part = mine[:, key[2]][:, supports[key]]
                    y = part[np.any(part != 0, axis=-1)]
                    if y.shape[0]:
                        gm = grams.setdefault(key, np.zeros((y.shape[1], y.shape[1])))
                        gm += y.T @ y
                        counts[key] = counts.get(key, 0) + y.shape[0]
    return grams, counts


def _no_room(ratio, first, budget):
    """The message of a ratio whose budget cannot hold the first component of the greedy order."""
    return (
        f"ratio {ratio:g} leaves {max(budget, 0):.0f} values after the per-pixel ones, and the first component "
        f"costs {first}; use a smaller ratio"
    )


def _take(order, cost, budget, first):
    """The greedy prefix of ``order`` (rows (region, cluster, part)) within ``budget`` stored values, one component of
    block b costing ``cost[b]`` and its first one ``first[b]`` more (the block's header): (its length, components
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


def _header_values(support):
    """Stored values of a block besides its components: its number of components (1) and its support's bit mask
    (32 bits a value; none when the support is the whole region)."""
    return 1 + (0 if support.all() else -(-support.size // 32))


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


def _coefficients(stream, labels, regions, bases, supports):
    """Per block: the stored rows (positions in the face pixels) and their coefficients on the block's K
    components (``bases``: the kept ones); the squared residual ‖g − ĝ‖² (P, 3) of every colour row."""
    stored = {key: ([], []) for key in bases}
    parts_of = _parts_of(bases)
    res2 = np.zeros((stream.n_pix, ROWS))
    for sel, _, g in stream.each("compress: coefficients"):
        lab = labels[sel]
        for r, lights in enumerate(regions):
            sub = g[:, :, lights]  # (n, 3, L_r), unscaled
            for k in np.unique(lab):  # loop over the clusters present in this tile
                mine = np.flatnonzero(lab == k)
                sub_k = sub[mine]
                for key in parts_of.get((r, int(k)), ()):  # loop over the block's rows and parts
                    basis = bases[key][:, supports[key]]  # (K, L) on the support
                    part = sub_k[:, key[2]][:, supports[key]]  # (m, L)
                    here = np.flatnonzero(np.any(part != 0, axis=-1))
                    if not here.size:
                        continue
                    y = part[here]
                    cf = y @ basis.T  # (n, K)
                    res2[sel[mine[here]], key[2]] += np.sum((y - cf @ basis).astype(np.float64) ** 2, axis=-1)
                    if basis.shape[0]:  # a block without components stores nothing
                        stored[key][0].append(sel[mine[here]])
                        stored[key][1].append(cf)
    return stored, res2


@dataclass
class _Block:
    """One (region, cluster, colour row, part) block: its lights within the region, its basis rows, and the stored
    rows' pixels and coefficients."""

    support: np.ndarray  # (L_r,) bool: the region's lights of this part
    basis: np.ndarray  # (K, L_r) float32, orthonormal rows, zero outside the support
    rows: np.ndarray  # positions (int64, (n,)) in CompressedField.pixels
    coefficients: np.ndarray  # (n, K) float32

    @property
    def stored(self) -> int:
        """Basis values on the support, coefficients, and the header (:func:`_header_values`) of a block with
        components."""
        k = self.basis.shape[0]
        if not k:
            return 0
        return k * (int(self.support.sum()) + self.rows.size) + _header_values(self.support)


@dataclass
class _Packed:
    """The stored values of a :class:`CompressedField` in flat arrays (the blocks' bases and coefficients are
    views of them): per region the stacked bases of its blocks, all coefficients, and per block (a segment) where
    its rows, coefficients and components are and which colour row it holds; segments in (cluster, region, row,
    part) order, so that the segments of different clusters write different pixels (``cluster_end``: the segment
    after each cluster's last)."""

    stacks: list  # per region: (Σ K, L_r) float32
    region_start: np.ndarray  # (n_regions + 1,) first component of each region in the projections
    coef: np.ndarray  # flat float32
    pixel: np.ndarray  # int64 position of every stored row
    mix: np.ndarray  # (P, 3, 3) float32: A of every pixel, channels on axis 1, colour rows on axis 2
    seg_row: np.ndarray  # int64 first row of each segment
    seg_rows: np.ndarray  # int64 rows
    seg_k: np.ndarray  # int64 components
    seg_proj: np.ndarray  # int64 first component in the projections
    seg_kind: np.ndarray  # int64 colour row
    seg_coef: np.ndarray  # int64 first coefficient
    cluster_end: np.ndarray  # int64

    @property
    def components(self) -> int:
        return int(self.region_start[-1])


def _pack(blocks, regions, mix):
    """Pack the blocks' bases and coefficients into new flat arrays and make the blocks' arrays views of them
    (the values are stored once)."""
    keys = sorted(blocks)  # by region, then cluster, row, part: the order of the stacked bases
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
    segments = sorted((key for key in keys if blocks[key].rows.size), key=lambda key: (key[1], key[0], key[2], key[3]))
    seg_rows = np.array([blocks[key].rows.size for key in segments], np.int64)
    seg_k = np.array([blocks[key].basis.shape[0] for key in segments], np.int64)
    seg_coef = np.concatenate([[0], np.cumsum(seg_rows * seg_k)]).astype(np.int64)
    coef = np.empty(int(seg_coef[-1]), np.float32)
    for i, key in enumerate(segments):  # loop over blocks with rows: copy their coefficients, keep views
        b = blocks[key]
        view = coef[seg_coef[i] : seg_coef[i + 1]].reshape(b.coefficients.shape)
        view[...] = b.coefficients
        b.coefficients = view
    for key in keys:  # loop over blocks: their bases become views of the stacks
        b = blocks[key]
        lo = proj_of[key] - region_start[key[0]]
        b.basis = stacks[key[0]][lo : lo + b.basis.shape[0]]
    cluster = np.array([key[1] for key in segments], np.int64)
    return _Packed(
        stacks=stacks,
        region_start=np.asarray(region_start, np.int64),
        coef=coef,
        pixel=np.concatenate([blocks[key].rows for key in segments] + [np.zeros(0, np.int64)]).astype(np.int64),
        mix=np.ascontiguousarray(mix, dtype=np.float32),
        seg_row=np.cumsum(seg_rows) - seg_rows,
        seg_rows=seg_rows,
        seg_k=seg_k,
        seg_proj=np.array([proj_of[key] for key in segments], np.int64),
        seg_kind=np.array([key[2] for key in segments], np.int64),
        seg_coef=seg_coef[:-1],
        cluster_end=np.flatnonzero(np.diff(np.append(cluster, -1)) != 0).astype(np.int64) + 1,
    )


def _relight_numba(pk, wd, regions, n_pix):
    """The compiled relight (:mod:`facestats.relight.compression_numba`): the lighting ``wd`` (L, 3) projected on
    every region's stacked bases, then the rows' products in parallel parts of about equal work (a few per
    thread, cut between clusters: each part writes only its clusters' pixels); (n_pix, 3) float32."""
    import numba

    from facestats.relight.compression_numba import project, relight_segments

    proj = np.empty((3, pk.components), np.float32)
    for r, lights in enumerate(regions):  # loop over the light regions: one compiled product each
        project(pk.stacks[r], np.ascontiguousarray(wd[lights].T), proj, pk.region_start[r])
    out = np.zeros((n_pix, 3), np.float32)
    if not pk.seg_rows.size:
        return out
    work = np.cumsum(pk.seg_rows * (3 * pk.seg_k + 3))[pk.cluster_end - 1]  # work up to each cluster's end
    n_parts = max(1, min(4 * numba.get_num_threads(), work.size))  # a few parts per thread balance better
    cuts = np.searchsorted(work, work[-1] * np.arange(1, n_parts) / n_parts)
    bounds = np.unique(np.concatenate([[0], pk.cluster_end[np.minimum(cuts, work.size - 1)], [pk.seg_rows.size]]))
    relight_segments(
        pk.coef,
        pk.pixel,
        pk.mix,
        pk.seg_row,
        pk.seg_rows,
        pk.seg_k,
        pk.seg_proj,
        pk.seg_kind,
        pk.seg_coef,
        bounds.astype(np.int64),
        proj,
        out,
    )
    return out


@dataclass
class CompressedField:
    """A reflectance field in clustered PCA bases per colour row and light region (module docstring).

    Attributes
    ----------
    pixels : ndarray of int, shape (P,)
        Flat index (row · W + column) of each stored pixel.
    labels : ndarray of int, shape (P,)
        Cluster of each stored pixel.
    colours : ndarray, shape (P, 3)
        Diffuse colour d of each stored pixel (unit RGB, :func:`diffuse_colours`).
    specular : ndarray, shape (3,)
        Light colour s (unit RGB).
    regions : list of ndarray of int
        The lights (flat indices) of each region.
    blocks : dict
        (region, cluster, colour row, part) → block: its support (the region's lights of the part), basis (K, L_r),
        zero off its support, its stored rows and their coefficients.
    residual : ndarray, shape (P, 3)
        ‖g_q − ĝ_q‖ of each pixel's colour rows q (μd, μs, μe: √δA-weighted coordinates).
    order : ndarray of int, shape (N, 4)
        (region, cluster, row, part) of every offered component in the greedy order; the first ``kept`` are kept.
    kept : int
    sqrt_solid_angle : ndarray, shape (L,)
    directions : ndarray, shape (light dims..., 3)
    image_shape : tuple of int
    parts : int
        Parts per (region, cluster, row) block (:func:`compress`).
    nonnegative : bool
        The compressed field holds radiance (its negative values, noise, sum to at most
        :data:`NEGATIVE_NOISE` of its positive ones), so its relights under lighting ≥ 0 are ≥ 0 and
        :meth:`relight` clamps the bases' ringing at 0; False for a field of differences (its ``signed``
        attribute, set by :func:`facestats.relight.relighting.indirect_field`, or more negative mass), whose
        relights may be negative and are returned as they are.

    Notes
    -----
    At construction the blocks' bases and coefficients are packed into flat arrays that the relight reads, and
    become views of them: treat ``blocks`` as read-only (a changed block would not reach :meth:`relight`).
    """

    pixels: np.ndarray
    labels: np.ndarray
    colours: np.ndarray
    specular: np.ndarray
    regions: list
    blocks: dict
    residual: np.ndarray
    order: np.ndarray
    kept: int
    sqrt_solid_angle: np.ndarray
    directions: np.ndarray
    image_shape: tuple
    parts: int
    nonnegative: bool = True
    _packed: _Packed = dataclass_field(init=False, repr=False, compare=False)

    def __post_init__(self):
        self._packed = _pack(self.blocks, self.regions, self.mix)

    @property
    def mix(self) -> np.ndarray:
        """A = [d s d×s] of every stored pixel, (P, 3, 3) float64: channel c = Σ_q A[c, q] · colour row q."""
        return separation_basis(self.colours, self.specular)

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
        """Stored values: basis rows, coefficients, :func:`per_pixel_values` per pixel, and the light colour."""
        per_pixel = per_pixel_values(len(self.regions) * self.parts)
        return int(sum(b.stored for b in self.blocks.values())) + per_pixel * self.pixels.size + 3

    @property
    def ratio(self) -> float:
        """Dense face values over stored values: 3 L P / :attr:`stored`."""
        return 3 * self.n_lights * self.pixels.size / self.stored

    def truncate(self, ratio: float) -> "CompressedField":
        """The same field with the greedy prefix of its components that meets ``ratio`` (residuals only grow; a
        ratio at or below :attr:`ratio` keeps them all).

        Parameters
        ----------
        ratio : float
            Dense face values over stored values to meet (> 0, finite; as :attr:`ratio`).

        Returns
        -------
        CompressedField
            A new field sharing the kept blocks' supports and rows; ``residual`` grows by the dropped coefficients.

        Raises
        ------
        ValidationError
            ``ratio`` is not a positive finite number, or leaves no room for the first component of the greedy order.
        """
        r = _ratio(ratio)
        budget = _budget(self.n_lights, self.pixels.size, r, len(self.regions) * self.parts)
        cost = {key: int(b.support.sum()) + b.rows.size for key, b in self.blocks.items()}
        first = {key: _header_values(b.support) for key, b in self.blocks.items()}
        keep, per_block = _take(self.order[: self.kept], cost, budget, first)
        if keep == 0:
            key = tuple(self.order[0])
            raise ValidationError(_no_room(r, cost[key] + first[key], budget))
        res2 = self.residual.astype(np.float64) ** 2
        blocks = {}
        for key, b in self.blocks.items():
            k = per_block.get(key, 0)
            dropped = b.coefficients[:, k:]
            res2[b.rows, key[2]] += np.einsum("nk,nk->n", dropped, dropped, dtype=np.float64)
            if k:
                blocks[key] = _Block(
                    support=b.support,
                    basis=b.basis[:k].copy(),
                    rows=b.rows,
                    coefficients=np.ascontiguousarray(b.coefficients[:, :k]),
                )
        return replace(self, blocks=blocks, residual=np.sqrt(res2).astype(np.float32), kept=keep)

    def _weights(self, lighting):
        """L·δA per light as (L, 3) float64; grey lighting (one value per light) is given to every channel."""
        w = as_finite(lighting, "lighting", 0, None, dtype=np.float64)  # L·δA >= 0, as render_subject asks
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

        Per block: proj = B (W/√δA)_r per channel (one product per region over its blocks' stacked bases); each
        stored row q of pixel p then gives t_c = C · proj_c for the three channels c and adds A_p[c, q] t_c to
        channel c.  For a :attr:`nonnegative` field, values below 0 (the truncated bases'
        ringing under lighting much narrower than their components) are returned as 0: its radiance is not
        negative; a field of differences keeps them.

        Parameters
        ----------
        lighting : array_like, optional
            L·δA per light (as :func:`facestats.relight.relighting.relight`), ≥ 0: shape (light dims..., 3) or
            (L, 3), or one grey value per light.  Exactly one of ``lighting`` and ``probe``.
        probe : array_like, shape (H, W, 3), optional
            A light probe to resample to the field's lights (:func:`facestats.relight.lighting.resample_probe`).
        layout : {"latlong", "angular"}
            The probe's layout.
        rotate : float
            Rotate the probe's environment about +y first (radians); with a probe only.
        backend : {"auto", "numba", "numpy"}
            :data:`facestats.core.compiled.BACKENDS`: ``"numba"`` computes the projections and the rows' products
            in compiled passes over the stored values on all cores (:mod:`facestats.relight.compression_numba`;
            its cost does not grow with the number of blocks), ``"numpy"`` one BLAS product per region and one
            small GEMM per block (a Python loop over the blocks); they agree to float32 rounding.

        Returns
        -------
        ndarray of float32, shape (H, W, 3)
            0 at the pixels not stored.

        Raises
        ------
        ValidationError
            Both or neither of ``lighting`` and ``probe``, ``rotate`` with ``lighting``, lighting of another
            shape or negative, or a relit value that is not finite.
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
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported by check_relit
            if engine == "numba":
                vals = _relight_numba(pk, wd, self.regions, self.pixels.size)
            else:
                proj = np.empty((3, pk.components), np.float32)  # per channel, the lighting on every component
                for r, lights in enumerate(self.regions):  # one GEMM per region: its blocks' bases are stacked
                    proj[:, pk.region_start[r] : pk.region_start[r + 1]] = (pk.stacks[r] @ wd[lights]).T
                vals = np.zeros((self.pixels.size, 3), np.float32)
                for s in range(pk.seg_rows.size):  # loop over blocks: one small GEMM each
                    n, k, q = pk.seg_rows[s], pk.seg_k[s], pk.seg_kind[s]
                    rows = pk.pixel[pk.seg_row[s] : pk.seg_row[s] + n]
                    cf = pk.coef[pk.seg_coef[s] : pk.seg_coef[s] + n * k].reshape(n, k)
                    vals[rows] += pk.mix[rows, :, q] * (cf @ proj[:, pk.seg_proj[s] : pk.seg_proj[s] + k].T)
        out = np.zeros((self.image_shape[0] * self.image_shape[1], 3), np.float32)
        out[self.pixels] = vals
        out = check_relit(out.reshape(self.image_shape + (3,)), "compressed relight")
        # radiance is not negative: the truncated bases ring below 0 under lighting much narrower than their
        # components (a single light of a 32 x 64 field: 314 pixels, down to -19 % of the image's maximum).
        # Lighting >= 0 on reflectance >= 0 relights to >= 0, so clamping never moves a value away from it; a
        # field of differences (indirect_field's white - black) relights to negative values legitimately.
        return np.maximum(out, 0, out=out) if self.nonnegative else out

    def error_bound(self, lighting) -> np.ndarray:
        """Per-pixel bound on |relight(compressed) − relight(dense)| over the stored pixels (0 elsewhere):
        Σ_q |A_cq| ρ_q ‖W_c/√δA‖, (H, W, 3) (Cauchy-Schwarz and the triangle inequality).

        Parameters
        ----------
        lighting : array_like
            L·δA per light, ≥ 0, as :meth:`relight` takes it.

        Returns
        -------
        ndarray of float32, shape (H, W, 3)
        """
        w = self._weights(lighting)
        norm = np.sqrt(((w / self.sqrt_solid_angle[:, None]) ** 2).sum(0))
        out = np.zeros((self.image_shape[0] * self.image_shape[1], 3), np.float32)
        out[self.pixels] = np.einsum("pcq,pq->pc", np.abs(self.mix), self.residual.astype(np.float64)) * norm
        return out.reshape(self.image_shape + (3,))

    def reconstruct(self) -> np.ndarray:
        """The approximated field, (L, H, W, 3) float32 (for inspection; memory of the dense field)."""
        rows = np.zeros((ROWS, self.pixels.size, self.n_lights), np.float32)
        for (r, _, q, _), b in self.blocks.items():  # loop over blocks
            rows[q, b.rows[:, None], self.regions[r][None, :]] += b.coefficients @ b.basis  # parts add
        channels = np.einsum("pcq,qpl->lpc", self.mix.astype(np.float32), rows)
        out = np.zeros((self.n_lights, self.image_shape[0] * self.image_shape[1], 3), np.float32)
        out[:, self.pixels] = channels / self.sqrt_solid_angle[:, None, None].astype(np.float32)
        return out.reshape((self.n_lights,) + self.image_shape + (3,))


def relative_errors(image, reference, mask=None, *, floor=0.0) -> np.ndarray:
    """Relative errors |image − reference| / max(reference, ``floor``) of the pixel channels in ``mask``, flat (the
    accuracy of a compressed relight against the dense one; a denominator below 1e-30 counts as 1e-30, so with no
    ``floor`` an error where the reference is 0 is huge).

    Parameters
    ----------
    image, reference : array_like, shape (H, W, 3)
        A relit image and the reference it approximates (:func:`facestats.relight.relighting.relight`).
    mask : array_like of bool, shape (H, W), optional
        The pixels to compare (default all).
    floor : float or array_like, shape (3,)
        Smallest denominator (per channel), ≥ 0: a reference darker than it (in shadow, where a relative error has
        no meaning) is measured against it, e.g. a fraction of the image's mean (``facestats relight --ratio``).

    Returns
    -------
    numpy.ndarray of float64, shape (n · 3,)
        One value per compared pixel channel.

    Raises
    ------
    ValidationError
        Images of different shapes or not (H, W, 3), non-finite values, a mask of another (H, W), or a ``floor``
        that is negative, not finite or not one value or three.
    """
    img = as_finite(image, "image", dtype=np.float64)
    ref = as_finite(reference, "reference", dtype=np.float64)
    if img.shape != ref.shape or img.ndim != 3 or img.shape[-1] != 3:
        raise ValidationError(f"image and reference must be (H, W, 3) of one shape, got {img.shape} and {ref.shape}")
    m = np.ones(img.shape[:2], bool) if mask is None else np.asarray(mask, bool)
    if m.shape != img.shape[:2]:
        raise ValidationError(f"mask must have the images' shape {img.shape[:2]}, got {m.shape}")
    low = as_finite(floor, "floor", 0, None, dtype=np.float64)
    if low.shape not in ((), (3,)):
        raise ValidationError(f"floor must be one value or one per channel (3,), got shape {low.shape}")
    return (np.abs(img[m] - ref[m]) / np.maximum(np.maximum(np.abs(ref[m]), low), 1e-30)).reshape(-1)


def _budget(n_lights, n_pix, ratio, n_parts):
    """Values left for bases and coefficients at ``ratio``: 3 L P / ratio less the per-pixel values and s."""
    return 3 * n_lights * n_pix / ratio - per_pixel_values(n_parts) * n_pix - 3


def compress(
    field,
    ratio: float = 20,
    *,
    clusters: int | None = None,
    sectors: int = 4,
    floor: float = 0.2,
    parts: int = 2,
    specular=WHITE,
    off_plane: float = 1e-3,
    features: int = 32,
    sample: int = 256,
    seed: int = 0,
    progress: bool = False,
) -> CompressedField:
    """Compress a reflectance field into clustered, solid-angle weighted PCA bases per colour row and light region
    (module docstring).

    Streaming passes over the field's tiles (in memory or on disk): each
    pixel's diffuse colour (:func:`diffuse_colours`) and so its colour rows,
    the coordinates of §4.2; a global basis of ``features`` components from a
    sample of pixels and every pixel's projection on it; k-means of those
    projections into ``clusters``; how often each (region, cluster, row)
    block's rows are zero at each light, which splits its lights into
    ``parts`` (a pass of its own: the split must be known before the Gram
    matrices count the rows each part stores); the Gram matrix of every
    (region, cluster, row, part) block from all its pixels' scaled non-zero
    parts, and its principal directions; the greedy choice of components for
    the ratio; then every stored row's coefficients and every row's residual.

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
        In [0, 1]: a region's share of a pixel's channel is taken as at least ``floor`` of the channel when the
        rows are scaled (module docstring, *The error metric*; 1 scales every part by its channel's total).
    parts : int
        In [1, 8]: each (region, cluster, row) block's lights are split into this many parts by how often the
        cluster's functions are zero there, each part with its own basis (module docstring, *Parts by zeros*).
    specular : array_like, shape (3,)
        Colour of the light (and so of the specular reflection) in the field's RGB (components ≥ 0, not all 0); the
        field's values are per unit irradiance of each light, so white unless the lights' colours were not divided
        out.
    off_plane : float
        In [0, 1]: a pixel's coordinate off the plane of its diffuse colour and ``specular`` is stored as a
        third row when its contribution's norm exceeds this share of the pixel's norm (0 stores every non-zero
        one), and is left out, counted in the residual, otherwise.
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
    light = light_colour(specular)
    tol = _number(off_plane, "off_plane", 0, 1)
    nf = min(check_integer(features, "features", 1), n)
    rng = np.random.default_rng(check_seed(seed))
    region_of = light_regions(directions, sectors)
    regions = [np.flatnonzero(region_of == r) for r in range(2 * sectors)]
    regions = [lights for lights in regions if lights.size]
    stream = _Pass(f, pixels, sw, progress)
    colours, off_kept, off_dropped, nonnegative = _colours(stream, light, tol)
    mix = separation_basis(colours, light)
    stream.set_colours(_colour_inverse(colours, light), off_kept)
    labels = _clusters(stream, c, nf, s, rng)
    supports = _supports(stream, labels, regions, n_parts)
    grams, rows_of = _grams(stream, mix, labels, regions, fl, supports)  # rows_of: the rows a block stores
    bases = _bases(grams, supports)
    cost = {key: int(supports[key].sum()) + rows_of[key] for key in bases}  # stored values of one component
    first = {key: _header_values(supports[key]) for key in bases}  # and of a block's header
    gain = [(e / cost[key], key) for key, (_, sigma2) in bases.items() for e in sigma2]
    gain.sort(key=lambda g: -g[0])
    order = np.array([key for _, key in gain], np.int64).reshape(-1, 4)
    if not order.size:
        raise ValidationError("field has no face pixel with a non-zero reflectance: nothing to compress")
    budget = _budget(n, pixels.size, r_min, len(regions) * n_parts)
    kept, counts = _take(order, cost, budget, first)
    if kept == 0:
        key = tuple(order[0])
        raise ValidationError(_no_room(r_min, cost[key] + first[key], budget))
    bases = {key: basis[: counts.get(key, 0)].copy() for key, (basis, _) in bases.items()}  # free the rest
    stored, res2 = _coefficients(stream, labels, regions, bases, supports)
    res2[:, 2] += off_dropped
    blocks = {}
    for key, basis in bases.items():
        k = basis.shape[0]
        if k:
            rows = np.concatenate(stored[key][0]) if stored[key][0] else np.zeros(0, np.int64)
            coef = np.concatenate(stored[key][1]) if stored[key][1] else np.zeros((0, k), np.float32)
            blocks[key] = _Block(support=supports[key], basis=basis, rows=rows, coefficients=coef)
    return CompressedField(
        pixels=pixels,
        labels=labels,
        colours=colours,
        specular=light,
        regions=regions,
        blocks=blocks,
        residual=np.sqrt(res2).astype(np.float32),
        order=order,
        kept=kept,
        sqrt_solid_angle=sw,
        directions=np.asarray(f["direction"].values, np.float64),
        image_shape=(f.sizes["y"], f.sizes["x"]),
        parts=n_parts,
        nonnegative=nonnegative,
    )
