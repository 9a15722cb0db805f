"""Shadow maps of reflectance functions by brightness thresholding (Debevec et al. 2000 §4.4, Fig. 13).

"since the geometry is incomplete we instead compute the shadow map using
brightness thresholding on the original reflectance function": a light is
*lit* for a pixel when the function's luminance (here the plain sum R + G + B of the
linear values, not a photometric Y) there exceeds ``threshold``
times the function's maximum (a per-pixel relative threshold, so dark skin and
bright skin are treated alike).  On a lat-long light grid the binary map is
then cleaned morphologically — an opening removes isolated lit samples
(noise, interreflection speckle) and a closing fills isolated dark ones
(specular-free holes) — with a 3 × 3 neighbourhood that wraps around in
azimuth.  The result is compared with the geometric visibility of the virtual
light stage by :func:`shadow_agreement`, which ignores a band of ``band``
grid steps of arc around the geometric boundary (the terminator and cast-shadow edges,
where the 64 × 32 sampling and the cos θ fall-off make any threshold
ambiguous; one step is the grid's diagonal at the equator, as wide on the sphere
near the poles as there).  :func:`disagreement_causes` says, for a field of the
virtual stage, why each compared sample that disagrees does (grazing light, a
specular peak, partial visibility, the cleaning).
"""

from __future__ import annotations

import numpy as np

from facestats.core.published import ETA_SKIN
from facestats.core.validate import as_scalar, check_finite, check_integer
from facestats.errors import ValidationError
from facestats.model.fresnel import fresnel_reflectance
from facestats.model.sphere import latlong_directions
from facestats.relight.field import as_field, is_grid

__all__ = ["threshold_shadow_maps", "shadow_agreement", "disagreement_causes", "CAUSES", "NOT_COMPARED"]

#: What :func:`disagreement_causes` finds for a compared sample, indexed by its codes (0: the map agrees).
CAUSES = (
    "agree",
    "false shadow: cleaning",
    "false shadow: partial visibility",
    "false shadow: grazing",
    "false shadow: specular peak",
    "false lit: cleaning",
    "false lit: partial visibility",
    "false lit: light in geometric shadow",
)
#: The code of :func:`disagreement_causes` for samples not compared (off the mask, or in the boundary band).
NOT_COMPARED = -1
#: Samples (lights × image samples) of the blocks :func:`_near_boundary` counts neighbours in (int16: 2 MiB).
NEAR_BLOCK = 1 << 20


def _wrap_morphology(lit, op, iterations):
    """Binary opening/closing on (n_phi, n_theta, ...) with a 3 × 3 element over the first two axes, θ wrapping.

    An opening or closing of ``iterations`` = c steps reads up to 2c cells away (c erosions, then c dilations), so
    2c + 1 cells are padded on each side; c + 1 left the seam's result depending on where the map starts in
    azimuth for c ≥ 2 (an audit).
    """

    pad = 2 * iterations + 1
    n_rows, n_cols = lit.shape[:2]
    # Columns wrap (modulo, so any pad fits any width); rows do not: beyond-pole cells repeat the nearest row
    # (no false edges).
    x = np.take(lit, np.arange(-pad, n_cols + pad) % n_cols, axis=1)
    x = np.take(x, np.clip(np.arange(-pad, n_rows + pad), 0, n_rows - 1), axis=0)
    struct = np.zeros((3, 3) + (1,) * (lit.ndim - 2), bool)
    struct[:, :, ...] = True
    y = op(x, structure=struct, iterations=iterations)
    return y[pad:-pad, pad:-pad]


def threshold_shadow_maps(field, threshold: float = 0.02, *, clean: int = 1):
    """Lit/shadowed map of every reflectance function: luminance > ``threshold`` × its maximum, cleaned.

    Parameters
    ----------
    field : xarray.Dataset or array_like
        A reflectance field, or an array (light dims..., y, x, 3) of its values.
    threshold : float
        Relative threshold in (0, 1).
    clean : int
        Iterations of the 3 × 3 opening and closing on a lat-long light grid (0: none;
        list fields are never cleaned, their lights have no grid neighbours).

    Returns
    -------
    ndarray of bool, shape (light dims..., y, x)
        True where the light reaches the pixel.
    """

    grid = True
    if hasattr(field, "data_vars") or hasattr(field, "dims"):
        f = as_field(field)
        grid = is_grid(f)
        vals = np.asarray(f["reflectance"].values, np.float32)
    else:
        vals = np.asarray(field, np.float32)
        grid = vals.ndim == 5
    t = as_scalar(threshold, "threshold", 0, 1, low_inclusive=False, high_inclusive=False)
    c = check_integer(clean, "clean", 0, 8)
    if vals.ndim not in (4, 5) or vals.shape[-1] != 3:
        raise ValidationError(
            f"field values must have shape (light dims..., y, x, 3) with one or two light dims, got {vals.shape}"
        )
    check_finite(vals, "field values")  # a NaN would compare as shadowed
    lum = vals.sum(-1)
    nl = 2 if grid else 1
    peak = lum.max(axis=tuple(range(nl)), keepdims=True)
    lit = (lum > t * peak) & (peak > 0)
    if grid and c:
        from scipy import ndimage

        lit = _wrap_morphology(lit, ndimage.binary_opening, c)
        lit = _wrap_morphology(lit, ndimage.binary_closing, c)
    return lit


def _band_half_widths(n_phi, n_theta, band):
    """Half-widths w[i, r] of the runs of columns of row r within ``band`` steps of arc of a light of row i.

    With the rows' polar angles φ and the column step Δθ = 2π/n_theta of :func:`latlong_directions`, the lights
    (i, j) and (r, j + k) are

        |d_ij − d_r,j+k|² = (cos φ_i − cos φ_r)² + (sin φ_i − sin φ_r)² + 4 sin φ_i sin φ_r sin²(k Δθ / 2)

    apart (squared chord, written without the cancellation of 2 − 2 cos γ at small angles).  It does not depend on
    j, and it grows with |k| up to n_theta / 2 (sin φ ≥ 0 on every row): the lights of row r within a chord c of
    (i, j) are the columns j − w … j + w taken circularly, w the largest k ≤ n_theta // 2 with the distance ≤ c
    (−1 when even k = 0 is farther, n_theta // 2 when the whole row is within), centred on j even when the arc
    reaches over the pole.  c is :func:`_near_boundary`'s chord.  Rows are taken one at a time:
    (n_phi, n_theta // 2 + 1) floats each.

    Returns
    -------
    ndarray of intp, shape (n_phi, n_phi)
        w[i, r].
    """
    arc = min(band * np.hypot(np.pi / n_phi, 2 * np.pi / n_theta), np.pi)
    limit = (2 * np.sin(arc / 2) * (1 + 1e-9)) ** 2  # the chord of the arc, a hair more for rounding, squared
    meridian = latlong_directions(n_phi, 1)[:, 0]  # θ = 0: (0, cos φ, −sin φ)
    c, s = meridian[:, 1], -meridian[:, 2]
    along = np.sin(np.arange(n_theta // 2 + 1) * (np.pi / n_theta)) ** 2  # sin²(k Δθ / 2), k = 0 … n_theta // 2
    half = np.empty((n_phi, n_phi), np.intp)
    for r in range(n_phi):
        chord2 = ((c - c[r]) ** 2 + (s - s[r]) ** 2)[:, None] + (4 * s * s[r])[:, None] * along
        half[:, r] = np.count_nonzero(chord2 <= limit, axis=1) - 1
    return half


def _near_boundary(visible, band):
    """Samples (n_phi, n_theta, ...) whose light lies within ``band`` grid steps of arc of a light whose ``visible``
    differs.

    The step is the lat-long grid's diagonal at the equator, √(Δφ² + Δθ²) with Δφ = π/n_phi and Δθ = 2π/n_theta
    (7.9° on the 64 × 32 stage): at the equator of a 2:1 grid (Δφ = Δθ) the band of one step is the 3 × 3
    neighbourhood of cells (on other grids more cells along the finer axis: 5 rows × 3 columns on 32 × 32); towards
    the poles, where a cell's width in azimuth shrinks as sin φ, it spans more columns, and it reaches across the
    pole.  A band of 3 × 3 cells there was 0.27° wide in azimuth in the rows next to the poles of the 64 × 32 grid,
    narrower than the 3.6° above the horizon where a 2 % threshold cannot tell grazing light from shadow (an
    audit, 2026-12-08: 1,786 of the 2,146 grazing false shadows of S001 at 64² lay in those four rows).

    A light's neighbours are the lights of :func:`latlong_directions` within the chord 2 sin(arc / 2) (1 + 10⁻⁹)
    of it, arc = min(``band`` steps, π), itself included.  A visible light is near a dark one when fewer than all of
    its neighbours are visible, a dark light near a visible one when any is.  In row r the neighbours of the light
    (i, j) are the columns j − w … j + w, circularly, with w = w[i, r] the same for every j
    (:func:`_band_half_widths`), so its visible neighbours in that row are a difference of the row's prefix sums
    of ``visible`` along the azimuth, and their count a sum over the rows.  Counts are integers, exact; image samples
    are taken in blocks of :data:`NEAR_BLOCK` samples (lights × samples) and rows one at a time, so the memory is
    a few blocks whatever ``band`` is.

    These are the pairs of the kd-tree it replaced (``cKDTree.sparse_distance_matrix`` at the same chord, a sparse
    matrix of every pair, whose size grew with the lights × band²: for 256 × 128 lights at band 16 and 16² image
    samples it traced 2.8 GB (5.2 GB resident) and took 23 s, against 18 MB, the 8 MB result included, and 0.3 s).
    Both compare a float64 squared distance between the same directions with the same chord, each within about
    10⁻¹³ of the exact value (relative), so they can differ only on a pair whose exact distance is that close to
    the chord.  The grids' pairs are either exactly at the arc (a whole number of steps along a meridian, or
    antipodes when the arc is π), which the factor 1 + 10⁻⁹ keeps 2 × 10⁻⁹ inside, or at least 3 × 10⁻⁷ (relative,
    squared) away from it on every grid of 8 to 256 columns and 4 to 128 rows at bands 0 to 16, where the two sets
    of pairs were compared pair by pair and are equal (``benchmarks/bench_relight.py``, ``boundary_band_pairs``,
    2026-12-08).
    """
    if not band:
        return np.zeros_like(visible)
    n_phi, n_theta = visible.shape[:2]
    half = _band_half_widths(n_phi, n_theta, band)
    length = np.where(half < 0, 0, np.minimum(2 * half + 1, n_theta))  # (i, r): neighbours of (i, j) in row r
    total = length.sum(axis=1)[:, None, None]  # (n_phi, 1, 1): neighbours of a light of row i
    v = visible.reshape(n_phi, n_theta, -1)
    out = np.empty(v.shape, bool)
    cols = np.arange(n_theta)
    # The smallest integers that hold the counts exactly: prefix sums reach 2 n_theta, a light's count its total
    # (plus a prefix sum between the two updates of a row).
    prefix_type = np.int16 if 2 * n_theta < 2**15 else np.int32
    count_type = np.int16 if total.max() + 2 * n_theta < 2**15 else np.int32
    # For each row r, the light rows with neighbours in it, [a, b): consecutive (|φ_i − φ_r| within the arc); a row
    # between without any would add 0.
    spans = [(r, near[0], near[-1] + 1) for r in range(n_phi) if (near := np.flatnonzero(length[:, r])).size]
    step = max(1, NEAR_BLOCK // (n_phi * n_theta))  # samples of the image at a time: blocks, not the field
    for lo in range(0, v.shape[2], step):
        block = v[:, :, lo : lo + step]
        # Prefix sums of each row along the azimuth, over the row twice (a run of ≤ n_theta columns from any start
        # in the first copy ends in the second): window sum = prefix[start + length] − prefix[start].
        prefix = np.zeros((n_phi, 2 * n_theta + 1, block.shape[2]), prefix_type)
        np.cumsum(block, axis=1, dtype=prefix_type, out=prefix[:, 1 : n_theta + 1])
        np.add(prefix[:, n_theta : n_theta + 1], prefix[:, 1 : n_theta + 1], out=prefix[:, n_theta + 1 :])
        lit = np.zeros(block.shape, count_type)  # visible neighbours of each light
        for r, a, b in spans:
            start = (cols[None, :] - half[a:b, r, None]) % n_theta  # (rows, n_theta)
            lit[a:b] += prefix[r][start + length[a:b, r, None]]
            lit[a:b] -= prefix[r][start]
        out[:, :, lo : lo + step] = np.where(block, lit < total, lit > 0)
    return out.reshape(visible.shape)


def shadow_agreement(lit, visible, band: int = 1, mask=None) -> dict:
    """Agreement of a thresholded shadow map with geometric visibility, away from the boundaries.

    Parameters
    ----------
    lit, visible : array_like of bool, shape (n_phi, n_theta, y, x)
        Thresholded map and geometric visibility (light reaches the front side
        unoccluded) on a lat-long light grid.
    band : int
        Samples whose light lies within ``band`` steps of arc of a light with the other
        ``visible`` are excluded; a step is √(Δφ² + Δθ²), the grid's diagonal at the equator
        (7.9° on the 64 × 32 stage, 31.8° on 16 × 8): the 3 × 3 cells there on a 2:1 grid, more columns
        towards the poles and across them.
    mask : array_like of bool, shape (y, x), optional
        Pixels to compare (default all).

    Returns
    -------
    dict
        ``agreement`` (fraction of compared samples equal), ``compared``,
        ``false_lit`` and ``false_shadow`` counts, ``excluded`` (boundary samples).
    """
    a = np.asarray(lit, bool)
    v = np.asarray(visible, bool)
    if a.shape != v.shape or a.ndim != 4:
        raise ValidationError(
            f"lit and visible must have the same shape (n_phi, n_theta, y, x), got {a.shape}, {v.shape}"
        )
    near = _near_boundary(v, check_integer(band, "band", 0, 16))
    use = ~near
    if mask is not None:
        use &= np.asarray(mask, bool)[None, None]
    n = int(use.sum())
    if n == 0:
        raise ValidationError("no sample is left to compare (empty mask or band too wide)")
    return {
        "agreement": float((a == v)[use].mean()),
        "compared": n,
        "false_lit": int((a & ~v)[use].sum()),
        "false_shadow": int((~a & v)[use].sum()),
        "excluded": int((near & (np.ones_like(v) if mask is None else np.asarray(mask, bool)[None, None])).sum()),
    }


def disagreement_causes(field, threshold: float = 0.02, *, clean: int = 1, band: int = 1):
    """Why the thresholded shadow maps of a virtual-stage field disagree with its geometric visibility, per sample.

    The field must come from :func:`facestats.relight.stage.light_stage_field` with ``visibility=True``: its
    reflectance is R = f_s (N·l) V + colour · F_t(N·l) (N·l) V per sample (Weyrich et al. 2006 eq. 6 with local
    transport, F_t = 1 − F_r the Fresnel transmittance at the field's ``eta``; N the ``normal``, l the light's
    ``direction``, V ∈ [0, 1] the ``visibility``, the fraction of the light reaching the pixel's front side).
    "Visible" is V > 0.5, "lit" the map of :func:`threshold_shadow_maps` (luminance R + G + B above ``threshold``
    × the pixel's maximum over the lights, then ``clean`` steps of opening and closing), and the samples compared
    are those :func:`shadow_agreement` compares (face pixels, off a ``band``-cell band around a change of
    visibility).  Each compared sample gets the first cause that holds (codes index :data:`CAUSES`):

    0. agree: lit == visible.
    1. false shadow, cleaning: above the threshold, removed by the opening.
    2. false shadow, partial visibility: the unshadowed value R / V is above the threshold but V < 1 dims it below
       (a cast-shadow edge crosses the pixel's mesh triangle: V is interpolated from the vertices).
    3. false shadow, grazing: the diffuse shape F_t(N·l) N·l is below ``threshold`` × its maximum over the pixel's
       lights (weighted by V), so even a pixel without highlights would be thresholded as shadowed: the threshold
       on brightness cannot tell light near the horizon from shadow (for a pixel whose brightest diffuse light is
       head-on, N·l below 0.062 at ``threshold`` = 0.02 and η = 1.38).
    4. false shadow, specular peak: the diffuse shape clears ``threshold`` × its own maximum, yet R is below
       ``threshold`` × the pixel's maximum: R ≥ colour · F_t(N·l) N·l, so that maximum exceeds the diffuse one — a
       specular highlight (strongest at grazing view, where the Torrance-Sparrow lobe grows) raised the threshold.
    5. false lit, cleaning: below the threshold, filled by the closing.
    6. false lit, partial visibility: 0 < V ≤ 0.5 and V R above the threshold.
    7. false lit, light in geometric shadow: V = 0 yet R above the threshold (subsurface light bleeding into the
       shadow, or indirect light; none in the stage's local transport, where V multiplies both terms).

    Parameters
    ----------
    field : xarray.Dataset
        A lat-long grid field of the virtual stage with ``visibility``, ``normal`` and ``mask``
        (attribute ``eta``, default skin's 1.38).
    threshold, clean
        As :func:`threshold_shadow_maps`.
    band
        As :func:`shadow_agreement`.

    Returns
    -------
    ndarray of int8, shape (n_phi, n_theta, y, x)
        The code of each sample, :data:`NOT_COMPARED` (−1) for samples not compared.

    Raises
    ------
    ValidationError
        A field that is not a lat-long grid, or lacks ``visibility``, ``normal`` or ``mask``.
    """
    f = as_field(field)
    missing = [name for name in ("visibility", "normal", "mask") if name not in f.data_vars]
    if missing or not is_grid(f):
        raise ValidationError(
            "field must be a lat-long stage field made with light_stage_field(..., visibility=True), "
            f"missing {missing}" + ("" if is_grid(f) else " and not a grid")
        )
    t = as_scalar(threshold, "threshold", 0, 1, low_inclusive=False, high_inclusive=False)
    vals = np.asarray(f["reflectance"].values, np.float32)
    vis = np.asarray(f["visibility"].values, np.float32)
    lit = threshold_shadow_maps(vals, t, clean=clean)
    raw = threshold_shadow_maps(vals, t, clean=0)
    visible = vis > 0.5
    compare = ~_near_boundary(visible, check_integer(band, "band", 0, 16))
    compare &= np.asarray(f["mask"].values, bool)[None, None]
    lum = vals.sum(-1)
    level = t * lum.max(axis=(0, 1), keepdims=True)  # the threshold_shadow_maps level
    unshadowed = lum / np.where(vis > 0, vis, 1)
    cos = np.clip(np.einsum("pqk,yxk->pqyx", f["direction"].values, f["normal"].values).astype(np.float32), 0, 1)
    shape = (1 - fresnel_reflectance(cos, float(f.attrs.get("eta", ETA_SKIN)))) * cos
    grazing = shape <= t * (shape * vis).max(axis=(0, 1), keepdims=True)
    false_shadow, false_lit = visible & ~lit, ~visible & lit
    code = np.select(
        [
            false_shadow & raw,
            false_shadow & (unshadowed > level),
            false_shadow & grazing,
            false_shadow,
            false_lit & ~raw,
            false_lit & (vis > 0),
            false_lit,
        ],
        [1, 2, 3, 4, 5, 6, 7],
        0,
    ).astype(np.int8)
    return np.where(compare, code, np.int8(NOT_COMPARED))
