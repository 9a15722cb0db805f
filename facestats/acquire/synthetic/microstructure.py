"""Procedural skin microstructure: seeded displacement maps with pores and fine anisotropic furrows, per face region.

Nagano et al. 2015 §5: the neutral microstructure displacement map "can come
from any source, such as noise functions [von der Pahlen et al. 2014]".  This
module is facestats' source when no measured map exists: a random height
field h (µm) on a grid of ``texel_um`` (10-20 µm/texel is the scale of the
paper's measurements), the sum of

* a **base** roughness: an isotropic band-limited Gaussian field, a sum of
  cosines of random directions and wavelengths log-uniform in
  ``BASE_WAVELENGTH_UM`` (both stratified, so that seeds share the spectrum and
  differ in phases) with amplitude ∝ wavelength (a flat slope spectrum);
* **furrows**: ridged fields −√(n² + c²) (V-shaped grooves along the zero lines
  of a smooth field n, their bottoms rounded over about one texel) in four
  orientation families (0°, 45°, 90°, 135° in UV;
  each family's wave vectors lie within ±20° of the family's normal, so its
  grooves run along the family angle), wavelengths in ``FURROW_WAVELENGTH_UM``,
  blended per texel with weights max(0, cos 2(θ − θ_k))² towards the region's
  furrow direction θ, or equally (a crossing network, as on the cheeks) for
  regions without one;
* **pores**: Gaussian pits ``−d exp(−|x − c|² / (2 ρ²))`` at Poisson-distributed
  centres.

Scale: the mean-square slope ⟨|∇h|²⟩ of each region equals its ``roughness``²,
split between the components by ``furrow_share`` and ``pore_share``, from
closed forms (no measurement of the map): a cosine sum Σ a_k cos(2π f_k·x + φ)
has ⟨|∇h|²⟩ = Σ a_k² (2π|f_k|)² / 2 — with 2π f replaced by sin(2π f h)/h, the
central differences over texels h that measure the map's slopes; the ridged
furrows keep a known fraction of it (:func:`_ridged`); a Poisson field of pits of density λ and depth d has
⟨|∇h|²⟩ = π λ d² (∫|∇ exp(−r²/2ρ²)|² dA = π, independent of ρ; central differences of a pit of
a few texels see less, tabulated numerically).  With a store
subject (:func:`subject_microstructure_parameters`) the roughness of a region is
the subject's median Torrance-Sparrow m there: Beckmann's m is the rms slope of
the microfacets (Weyrich et al. 2006 eq. 13), so the generated microstructure
has the subject's fitted specular roughness.  Orientation, shares and pore
statistics per region (``REGION_DEFAULTS``) are facestats' choices, stated, not
measurements.

Deformation: ``deformation = A`` (2 × 2, µm → µm) renders the same realisation
deformed by A, h'(x) = h(A⁻¹ x) — cosines with wave vectors A⁻ᵀ f, pits moved to
A c and sheared — exactly, with no resampling: the ground truth of a purely
geometric stretch for the kernel fit (:func:`facestats.model.microstructure.fit_kernel`).

A second, simpler generator, :func:`shot_noise_microstructure`, draws a
stationary shot-noise surface (many small bumps at Poisson-distributed texels):
a test surface whose independent realisations share their slope statistics
closely at patch sizes, which the procedural skin's few pores and finite wave
sums do not (see :func:`shot_noise_microstructure`).

Speed: the cosine sums are separable (cos(a + b) = cos a cos b − sin a sin b),
so a field is two matrix products (rows × waves)·(waves × columns) per family.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, replace

import numpy as np

from facestats.core.validate import as_finite, as_scalar, check_integer, check_window
from facestats.errors import ValidationError

__all__ = [
    "SkinMicrostructure",
    "REGION_DEFAULTS",
    "BASE_WAVELENGTH_UM",
    "FURROW_WAVELENGTH_UM",
    "procedural_microstructure",
    "shot_noise_microstructure",
    "subject_microstructure_parameters",
    "subject_microstructure",
    "region_labels",
    "BLOCK_TEXELS",
]

#: Wavelength range of the base roughness, µm.
BASE_WAVELENGTH_UM = (40.0, 400.0)
#: Wavelength range of the furrow fields, µm (groove spacing is about half a wavelength).
FURROW_WAVELENGTH_UM = (200.0, 800.0)
#: Orientation families of the furrows (radians in UV, u towards v).
FURROW_FAMILIES = (0.0, np.pi / 4, np.pi / 2, 3 * np.pi / 4)
#: Half-width of the wave-vector fan of a furrow family, radians.
FURROW_SPREAD = np.deg2rad(20.0)
#: Waves per field.
N_WAVES = 256
#: Width (texels) over which the bottom of a furrow is rounded.
RIDGE_ROUNDING_PX = 1.0
#: Shortest wavelength a map holds, in texels (finer waves are moved up to it).
MIN_WAVELENGTH_PX = 6.0


@dataclass(frozen=True)
class SkinMicrostructure:
    """Statistics of the microstructure of one face region.

    Attributes
    ----------
    roughness : float
        rms slope √⟨|∇h|²⟩ (dimensionless; Beckmann m).
    furrow_angle : float or None
        Direction of the furrow lines in UV, radians from +u towards +v; None: a crossing network.
    furrow_share, pore_share : float
        Fractions of ⟨|∇h|²⟩ carried by furrows and pores (the rest is base roughness).
    pore_density_mm2 : float
        Pores per mm².
    pore_radius_um : float
        Gaussian radius ρ of a pore, µm.
    """

    roughness: float = 0.27
    furrow_angle: float | None = None
    furrow_share: float = 0.4
    pore_share: float = 0.2
    pore_density_mm2: float = 1.0
    pore_radius_um: float = 35.0

    def __post_init__(self):
        as_finite(self.roughness, "roughness", 0.0, 2.0)
        as_finite(self.furrow_share, "furrow_share", 0.0, 1.0)
        as_finite(self.pore_share, "pore_share", 0.0, 1.0)
        if self.furrow_share + self.pore_share > 1:
            raise ValidationError(
                f"furrow_share + pore_share must be <= 1, got {self.furrow_share} + {self.pore_share}"
            )
        as_finite(self.pore_density_mm2, "pore_density_mm2", 0.0, 100.0)
        as_finite(self.pore_radius_um, "pore_radius_um", 1.0, 1000.0, unit="um")
        if self.pore_share > 0 and self.pore_density_mm2 <= 0:
            raise ValidationError(f"pore_density_mm2 must be > 0 when pore_share > 0, got {self.pore_density_mm2}")


#: Per-region defaults (regions of Weyrich Fig. 15); roughness is replaced by a subject's m.
#: Forehead, eyebrows and eyelids furrow along u (horizontal lines); lips and the mustache
#: area along v; under the eyes and on the cheeks obliquely; nose, chin and beard form networks.
REGION_DEFAULTS = {
    1: SkinMicrostructure(furrow_angle=np.pi / 2, furrow_share=0.4, pore_share=0.2, pore_density_mm2=1.0),
    2: SkinMicrostructure(furrow_angle=0.0, furrow_share=0.55, pore_share=0.15, pore_density_mm2=1.0),
    3: SkinMicrostructure(furrow_angle=0.0, furrow_share=0.5, pore_share=0.1, pore_density_mm2=0.6),
    4: SkinMicrostructure(furrow_angle=0.0, furrow_share=0.6, pore_share=0.05, pore_density_mm2=0.3),
    5: SkinMicrostructure(furrow_angle=np.pi / 8, furrow_share=0.5, pore_share=0.1, pore_density_mm2=0.6),
    6: SkinMicrostructure(furrow_angle=None, furrow_share=0.2, pore_share=0.45, pore_density_mm2=2.5),
    7: SkinMicrostructure(furrow_angle=np.pi / 4, furrow_share=0.35, pore_share=0.3, pore_density_mm2=1.5),
    8: SkinMicrostructure(furrow_angle=np.pi / 2, furrow_share=0.6, pore_share=0.0, pore_density_mm2=0.0),
    9: SkinMicrostructure(furrow_angle=None, furrow_share=0.3, pore_share=0.3, pore_density_mm2=1.5),
    10: SkinMicrostructure(furrow_angle=None, furrow_share=0.3, pore_share=0.25, pore_density_mm2=1.2),
}


def _stratified(rng, n):
    """n samples of U(0, 1), one in each of n equal strata, in random order (a low-variance spectrum)."""
    return rng.permutation((np.arange(n) + rng.uniform(0, 1, n)) / n)


def _waves(rng, n, wavelengths, texel_um, angle=None, spread=None):
    """Random wave vectors (n, 2) in cycles/µm and phases; directions uniform, or within ±spread of ``angle``.

    Log-wavelengths and directions are stratified (one wave per stratum, paired at
    random), so two seeds have nearly the same spectrum and differ in phases: realisations
    of the same statistics.  Wavelengths below MIN_WAVELENGTH_PX texels are raised to it.
    """
    lo = max(wavelengths[0], MIN_WAVELENGTH_PX * texel_um)
    hi = max(wavelengths[1], 2 * lo)
    lam = np.exp(np.log(lo) + (np.log(hi) - np.log(lo)) * _stratified(rng, n))
    u = _stratified(rng, n)
    theta = np.pi * u if angle is None else angle + spread * (2 * u - 1)
    f = np.stack([np.cos(theta), np.sin(theta)], -1) / lam[:, None]
    return f, rng.uniform(0, 2 * np.pi, n), lam


def _cosine_field(f, phase, amp, xs, ys):
    """Σ_k amp_k cos(2π (f_k,x x + f_k,y y) + φ_k) on the grid xs (columns) × ys (rows), by two matrix products."""
    ax = 2 * np.pi * np.outer(xs, f[:, 0]) + phase  # (W, K)
    ay = 2 * np.pi * np.outer(ys, f[:, 1])  # (H, K)
    return (np.cos(ay) * amp) @ np.cos(ax).T - (np.sin(ay) * amp) @ np.sin(ax).T


def _unit_msq(f, amp, texel_um):
    """Mean-square slope of a cosine sum as central differences at ``texel_um`` measure it.

    A cosine of wave vector f has the continuous slope energy a² (2π f_x)² / 2 along x; a
    central difference over ±1 texel h scales 2π f_x to sin(2π f_x h) / h, likewise along y.
    """
    d = np.sin(2 * np.pi * f * texel_um) / texel_um
    return float(np.sum(amp**2 * np.sum(d * d, 1)) / 2)


def _pit_msq_factor(radius_px):
    """Slope energy of a sampled Gaussian pit (central differences) relative to the continuous π (per unit depth)."""
    half = int(np.ceil(5 * radius_px)) + 2
    x = np.arange(-half, half + 1, dtype=float)
    pit = np.exp(-(x[:, None] ** 2 + x[None, :] ** 2) / (2 * radius_px**2))
    gy, gx = np.gradient(pit)
    return float(np.sum(gx * gx + gy * gy)) / np.pi


def _ridged(n, amp, texel_um):
    """Furrows −√(n² + c²) of a unit-slope-energy Gaussian field n, scaled back to unit slope energy.

    c rounds the groove bottom over about RIDGE_ROUNDING_PX texels (c = that width × rms|∇n|),
    so central differences resolve it.  For Gaussian n (value independent of gradient at a point)
    ⟨|∇√(n² + c²)|²⟩ = ⟨|∇n|²⟩ E[n² / (n² + c²)] and, with s² = Var n,
    E[n² / (n² + c²)] = 1 − √(π/2) (c/s) exp(c²/2s²) erfc(c/(s√2)).
    """
    from scipy.special import erfcx

    s = np.sqrt(np.sum(amp**2) / 2)
    c = RIDGE_ROUNDING_PX * texel_um  # × rms|∇n| = 1
    k = c / s
    factor = 1 - np.sqrt(np.pi / 2) * k * erfcx(k / np.sqrt(2))
    return -np.sqrt(n * n + c * c) / np.sqrt(factor)


_PIT_RADII_PX = np.geomspace(0.3, 200.0, 60)
_PIT_TABLE = (_PIT_RADII_PX, np.array([_pit_msq_factor(r) if r < 50 else 1.0 for r in _PIT_RADII_PX]))


#: Texels per block of rows the map is generated in (bounded memory: about 85 bytes a texel of a block are live,
#: besides the float32 output).
BLOCK_TEXELS = 1 << 20


def _region_maps(params, region_map):
    """Per-region parameters and the label map as given: (dict, labels or None)."""
    if region_map is None:
        p = params if isinstance(params, SkinMicrostructure) else SkinMicrostructure()
        return {None: p}, None
    lab = np.asarray(region_map)
    if lab.ndim != 2 or lab.dtype.kind not in "iu":
        raise ValidationError(f"region_map must be a 2-D integer label map, got {lab.dtype} {lab.shape}")
    table = dict(REGION_DEFAULTS) if params is None else dict(params)
    present = [int(k) for k in np.unique(lab) if int(k) in table]
    if not present:
        raise ValidationError(
            f"region_map must contain a region with parameters ({sorted(table)}), got {np.unique(lab)}"
        )
    fallback = table[present[0]] if 0 not in table else table[0]
    return {k: table.get(k, fallback) for k in np.unique(lab).tolist()}, lab


def region_labels(region_map, shape, window=None) -> np.ndarray:
    """The region label of each texel of a map: the label map (spanning the whole map) read nearest.

    Texel (r, c) of a ``shape`` = (H, W) map reads label ``[⌊(r + ½) L_h / H⌋, ⌊(c + ½) L_w / W⌋]`` of an
    L_h × L_w label map that covers the same UV area: the label cell its centre lies in.  These are the
    labels :func:`procedural_microstructure` places each pore by (its per-region statistics are blended over
    ``smooth_mm`` and one label cell across borders).

    Parameters
    ----------
    region_map : ndarray of int, shape (L_h, L_w)
        Region labels over the whole map's UV area (e.g. a store subject's ``region``).
    shape : int or (int, int)
        The whole map's size in texels.
    window : (row0, col0, height, width), optional
        Only these texels (default: all).

    Returns
    -------
    ndarray, shape (height, width)
        Labels, of ``region_map``'s dtype.
    """
    lab = np.asarray(region_map)
    if lab.ndim != 2 or lab.dtype.kind not in "iu":
        raise ValidationError(f"region_map must be a 2-D integer label map, got {lab.dtype} {lab.shape}")
    shape, (r0, c0, h, w) = check_window(shape, window)
    return lab[np.ix_(_label_index(np.arange(r0, r0 + h), lab.shape[0], shape[0]),
                      _label_index(np.arange(c0, c0 + w), lab.shape[1], shape[1]))]  # fmt: skip


def _label_index(texels, n_labels, n_texels):
    """Index of the label cell holding the centres of ``texels`` (a label map of n_labels cells over n_texels)."""
    return np.minimum((texels + 0.5) * n_labels / n_texels, n_labels - 1).astype(int)


def _region_values(regions, getter, shape, smooth_px):
    """Per-region values on the label map's grid, blurred across region borders by ``smooth_px`` texels of the map.

    The blur runs on the region map as given (cheap: it is coarse); :func:`_at_texels` interpolates the result
    onto texels.  One region: the value itself.
    """
    per_region, lab = regions
    if lab is None:
        return float(getter(per_region[None]))
    values = _lookup(per_region, getter)[lab]
    if smooth_px > 0:
        from scipy.ndimage import gaussian_filter

        sigma = (smooth_px * lab.shape[0] / shape[0], smooth_px * lab.shape[1] / shape[1])
        values = gaussian_filter(values, sigma, mode="nearest")
    return values


def _at_texels(values, shape, rows, cols):
    """Label-grid ``values`` (spanning a map of ``shape``) at the texels ``rows`` × ``cols``, bilinearly."""
    if np.ndim(values) == 0:
        return np.full((len(rows), len(cols)), values)
    from scipy.ndimage import map_coordinates

    lr = (rows + 0.5) * values.shape[0] / shape[0] - 0.5
    lc = (cols + 0.5) * values.shape[1] / shape[1] - 0.5
    rr, cc = np.meshgrid(lr, lc, indexing="ij")
    return map_coordinates(values, [rr, cc], order=1, mode="nearest")


def _family_weight(p: SkinMicrostructure, k: int) -> float:
    if p.furrow_angle is None:
        return 0.5  # equal weights: Σ w² = 1 over the four families
    return max(0.0, np.cos(2 * (p.furrow_angle - FURROW_FAMILIES[k]))) ** 2


def _lookup(per_region, getter):
    """Per-region values as an array indexed by label (labels absent from the map give 0)."""
    keys = [k for k in per_region if k is not None]
    table = np.zeros(max(keys, default=0) + 1)
    for k in keys:  # at most the ten regions
        table[k] = getter(per_region[k])
    return table


def _draw_pores(rng, regions, shape, texel):
    """Poisson pits over the whole map at the largest region density, thinned to each region's density.

    Returns centres (n, 2) in µm from the map's corner (x along u, y along v), Gaussian radii (µm) and depths
    (µm), vectorised over pores.  Drawn over the whole map whatever part is rendered, so a window of the map
    holds the pores of the whole map's realisation there.
    """
    per_region, lab = regions
    dmax = max(p.pore_density_mm2 for p in per_region.values())
    if dmax <= 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    n = rng.poisson(dmax * 1e-6 * shape[0] * shape[1] * texel * texel)
    centres = rng.uniform(0, 1, (n, 2)) * np.array([shape[1] * texel, shape[0] * texel])
    thin, jitter = rng.uniform(0, 1, n), rng.uniform(0.7, 1.3, n)
    if lab is None:
        p = per_region[None]
        dens, share, rough, radius = (
            np.full(n, v) for v in (p.pore_density_mm2, p.pore_share, p.roughness, p.pore_radius_um)
        )
    else:
        row = _label_index(np.clip((centres[:, 1] / texel).astype(int), 0, shape[0] - 1), lab.shape[0], shape[0])
        col = _label_index(np.clip((centres[:, 0] / texel).astype(int), 0, shape[1] - 1), lab.shape[1], shape[1])
        label = lab[row, col]
        dens, share, rough, radius = (
            _lookup(per_region, g)[label]
            for g in (
                lambda p: p.pore_density_mm2,
                lambda p: p.pore_share,
                lambda p: p.roughness,
                lambda p: p.pore_radius_um,
            )
        )
    keep = (thin * dmax < dens) & (share > 0)
    radius = jitter[keep] * radius[keep]
    # π λ d² = share · m², with π corrected for central differences at the pit's size in texels.
    factor = np.interp(radius / texel, *_PIT_TABLE)
    depth = rough[keep] * np.sqrt(share[keep] / (np.pi * factor * dens[keep] * 1e-6))
    return centres[keep], radius, depth


def _pore_reach(radii, texel_um, a_inv):
    """Half-width (texels) of the window each pore is rendered in: ±3.5 ρ of the largest pore, deformed, + 1."""
    if radii.size == 0:
        return 0
    stretch = np.linalg.norm(np.linalg.inv(a_inv), 2)
    return int(np.ceil(3.5 * radii.max() * stretch / texel_um)) + 1


def _render_pores(out, centres, radii, depth, texel_um, a_inv, xs0, ys0, half):
    """Subtract Gaussian pits (depth per pore) into ``out``, whose corner texel starts at (xs0, ys0) µm.

    Each pore touches a window of ±``half`` texels around its deformed centre (:func:`_pore_reach`, the same for
    every part of a map, so a part holds exactly what the whole map holds there).
    """
    h, w = out.shape
    if centres.size == 0:
        return
    off = np.arange(-half, half + 1)
    for start in range(0, len(centres), 2048):  # blocks of pores, vectorised within
        c = centres[start : start + 2048] @ np.linalg.inv(a_inv).T  # deformed centres, µm
        cc = np.floor((c[:, 0] - xs0) / texel_um).astype(int)
        cr = np.floor((c[:, 1] - ys0) / texel_um).astype(int)
        rr = cr[:, None, None] + off[None, :, None]
        rr, ccc = np.broadcast_arrays(rr, cc[:, None, None] + off[None, None, :])
        dx = xs0 + (ccc + 0.5) * texel_um - c[:, 0, None, None]
        dy = ys0 + (rr + 0.5) * texel_um - c[:, 1, None, None]
        ux = a_inv[0, 0] * dx + a_inv[0, 1] * dy
        uy = a_inv[1, 0] * dx + a_inv[1, 1] * dy
        rho = radii[start : start + 2048, None, None]
        val = depth[start : start + 2048, None, None] * np.exp(-(ux * ux + uy * uy) / (2 * rho * rho))
        ok = (rr >= 0) & (rr < h) & (ccc >= 0) & (ccc < w)
        np.subtract.at(out, (rr[ok], ccc[ok]), val[ok])


def _map_shape(shape, minimum):
    """``shape`` (an int or a pair) as (height, width), each at least ``minimum`` texels."""
    shape = (shape, shape) if np.ndim(shape) == 0 else tuple(shape)
    if len(shape) != 2:
        raise ValidationError(f"shape must be an int or (height, width), got {shape!r}")
    return check_integer(shape[0], "shape height", minimum), check_integer(shape[1], "shape width", minimum)


def procedural_microstructure(
    shape, texel_um=15.0, *, params=None, region_map=None, seed=0, deformation=None, smooth_mm=0.5, window=None
) -> np.ndarray:
    """A seeded procedural skin microstructure displacement map (module docstring), or a window of one.

    The map is generated in blocks of rows (:data:`BLOCK_TEXELS`), so memory is the float32 output plus a
    block's work: a whole 16,384² map takes about 1.2 GB.  A ``window`` is computed alone, and equals the
    whole map's texels there (the waves are evaluated at the window's texel positions and the pores are drawn
    over the whole map): a patch of a large face map costs what its own size costs.

    Parameters
    ----------
    shape : int or (int, int)
        Size in texels ``(height, width)`` of the whole map, over which ``region_map`` is spread.
    texel_um : float
        µm of skin per texel (10-20 in Nagano et al. 2015's measurements).
    params : SkinMicrostructure or dict of int to SkinMicrostructure, optional
        One set of statistics, or statistics per region label (default ``REGION_DEFAULTS``).
    region_map : ndarray of int, optional
        Region labels over the whole map's UV area (any resolution; :func:`region_labels`); None: one region.
    seed : int
        Seed of the realisation.
    deformation : array_like (2, 2), optional
        Render the realisation deformed by A, h(A⁻¹ x) (x in µm from the whole map's corner).
    smooth_mm : float
        Width (Gaussian σ, mm) of the blend between regions.
    window : (row0, col0, height, width), optional
        Generate only these texels of the whole map (default: all of it).

    Returns
    -------
    ndarray of float32, shape (height, width)
        Heights in µm, indexed ``[v, u]``: the whole map, or the window.
    """
    shape = _map_shape(shape, 2)
    shape, (r0, c0, h, w) = check_window(shape, window)
    texel = as_scalar(texel_um, "texel_um", 0.0, 1000.0, low_inclusive=False, unit="um")
    seed = check_integer(seed, "seed", 0)
    a = np.eye(2) if deformation is None else as_finite(deformation, "deformation", dtype=np.float64)
    if a.shape != (2, 2) or not np.linalg.det(a) > 0:
        raise ValidationError(f"deformation must be a 2x2 matrix with a positive determinant, got {a.tolist()}")
    a_inv = np.linalg.inv(a)
    regions = _region_maps(params, region_map)
    smooth_px = float(smooth_mm) * 1000 / texel
    rng = np.random.default_rng(seed)

    def values(getter):
        return _region_values(regions, getter, shape, smooth_px)

    # Base roughness: isotropic waves, amplitude ∝ wavelength.
    f, ph, lam = _waves(rng, N_WAVES, BASE_WAVELENGTH_UM, texel)
    base = (f @ a_inv, ph, lam / np.sqrt(_unit_msq(f, lam, texel)))
    base_msq = values(lambda p: p.roughness**2 * (1 - p.furrow_share - p.pore_share))
    # Furrows: four orientation families of ridged fields, blended towards each region's direction.
    families = []
    for k, fam in enumerate(FURROW_FAMILIES):  # four families
        f, ph, lam = _waves(rng, N_WAVES, FURROW_WAVELENGTH_UM, texel, fam + np.pi / 2, FURROW_SPREAD)
        amp = lam / np.sqrt(_unit_msq(f, lam, texel))
        families.append((f @ a_inv, ph, amp, values(lambda p, k=k: _family_weight(p, k))))
    furrow_msq = values(lambda p: p.roughness**2 * p.furrow_share)
    norm = values(lambda p: sum(_family_weight(p, k) ** 2 for k in range(4)))
    # Pores: Poisson pits at the largest density, thinned per region; depth from π λ d² = pore share · m².
    centres, radii, depth = _draw_pores(rng, regions, shape, texel)
    half = _pore_reach(radii, texel, a_inv)
    deformed = centres @ a.T / texel  # (col, row) of the deformed centres, texels

    out = np.empty((h, w), np.float32)
    cols = np.arange(c0, c0 + w)
    step = max(1, BLOCK_TEXELS // w)
    for start in range(r0, r0 + h, step):  # blocks of rows: bounded memory
        rows = np.arange(start, min(start + step, r0 + h))
        xs, ys = (cols + 0.5) * texel, (rows + 0.5) * texel
        block = np.sqrt(_at_texels(base_msq, shape, rows, cols)) * _cosine_field(*base, xs, ys)
        furrow_scale = np.sqrt(_at_texels(furrow_msq, shape, rows, cols))
        furrow_norm = np.sqrt(np.maximum(_at_texels(norm, shape, rows, cols), 1e-12))
        for f, ph, amp, weight in families:  # four families
            wk = _at_texels(weight, shape, rows, cols)
            if np.any(wk > 0):
                block += furrow_scale * wk / furrow_norm * _ridged(_cosine_field(f, ph, amp, xs, ys), amp, texel)
        near = (
            (deformed[:, 1] >= rows[0] - half - 1)
            & (deformed[:, 1] < rows[-1] + half + 2)
            & (deformed[:, 0] >= c0 - half - 1)
            & (deformed[:, 0] < c0 + w + half + 1)
        )
        _render_pores(block, centres[near], radii[near], depth[near], texel, a_inv, c0 * texel, rows[0] * texel, half)
        out[start - r0 : start - r0 + len(rows)] = block
    return out


def shot_noise_microstructure(
    shape, texel_um=10.0, *, density_mm2=500.0, bump_radius_um=10.0, rms_slope=0.2, seed=0
) -> np.ndarray:
    """A stationary shot-noise surface: Gaussian bumps of exponential height at Poisson-distributed texels.

    h = c · (X ∗ g) with X a field of independent compound-Poisson texel values
    (a Poisson number of bumps per texel, mean μ = ``density_mm2`` × texel area,
    each of unit-mean exponential height, so Var X = 2μ) and g the discrete
    Gaussian of σ = ``bump_radius_um`` (``scipy.ndimage.gaussian_filter``,
    periodic boundaries, so the map tiles).  Its slopes are non-Gaussian (each
    is a sum of few heavy-tailed terms) and a Gaussian blur of σ pixels
    averages more of them, so the shape of the normal histogram changes with a
    kernel's (α, σ), not only its variance: this is what makes Nagano et al.
    2015 eq. 7's joint argmin identifiable.  With hundreds of bumps per mm² a
    patch holds thousands of independent features and two realisations have
    the same statistics to sampling accuracy; the procedural skin
    (:func:`procedural_microstructure`) has a few pores per mm² and finite
    wave sums whose realisations differ in slope kurtosis by several per cent
    (docs/microstructure.md).  This surface is a test object, not a model of
    any skin region.

    Scale, in closed form (not measured on the realisation): the central-difference
    slope of h is c · X ∗ ∂g with Σ ∂g = 0, so
    ⟨|∇h|²⟩ = c² · Var X · Σ |∂g|² = c² · 2μ · Σ |∂g|², and c is chosen so that
    this equals ``rms_slope``².

    Parameters
    ----------
    shape : int or (int, int)
        Map size in texels ``(height, width)``.
    texel_um : float
        µm of skin per texel.
    density_mm2 : float
        Bumps per mm² (> 0).
    bump_radius_um : float
        Gaussian σ of a bump, µm.  Under about 0.3 texel the discrete Gaussian is nearly the identity and
        each bump is a one-texel spike.
    rms_slope : float
        √⟨|∇h|²⟩ of the central-difference slope (µm/µm): the root of the *expected* mean square.  A
        realisation's own rms slope scatters about it by about √(6 / number of bumps) relative, and at
        a few bumps per map its average falls below it (a root of a mean is below the mean of the root).
    seed : int
        Seed of the realisation.

    Returns
    -------
    ndarray of float32, shape (height, width)
        Heights in µm, indexed ``[v, u]``.
    """
    from scipy.ndimage import gaussian_filter

    shape = _map_shape(shape, 8)
    texel = as_scalar(texel_um, "texel_um", 0.0, 1000.0, low_inclusive=False, unit="um")
    density = as_scalar(density_mm2, "density_mm2", 0.0, 1e6, low_inclusive=False, unit="1/mm^2")
    radius_px = as_scalar(bump_radius_um, "bump_radius_um", 0.0, 1e4, low_inclusive=False, unit="um") / texel
    slope = as_scalar(rms_slope, "rms_slope", 0.0, 10.0, low_inclusive=False)
    seed = check_integer(seed, "seed", 0)
    if 8 * radius_px > min(shape):
        raise ValidationError(
            f"bump_radius_um must be at most 1/8 of the map's shorter side ({min(shape) * texel / 8:g} um), "
            f"got {bump_radius_um}"
        )
    mu = density * (texel / 1000.0) ** 2  # mean bumps per texel
    rng = np.random.default_rng(seed)
    counts = rng.poisson(mu, shape)
    x = np.where(counts > 0, rng.gamma(np.maximum(counts, 1), 1.0), 0.0)  # sum of `counts` unit exponentials
    h = gaussian_filter(x, radius_px, mode="wrap")
    half = int(4 * radius_px + 0.5) + 2  # the filter's own truncation (truncate=4) plus the difference stencil
    impulse = np.zeros((2 * half + 1, 2 * half + 1))
    impulse[half, half] = 1.0
    g = gaussian_filter(impulse, radius_px, mode="constant")
    dgy, dgx = np.gradient(g, texel)
    c = slope / np.sqrt(2.0 * mu * np.sum(dgx**2 + dgy**2))
    return (c * h).astype(np.float32)


def subject_microstructure_parameters(subject, defaults=None) -> dict:
    """Per-region :class:`SkinMicrostructure` of a store subject: roughness = its median Torrance-Sparrow m per region.

    Parameters
    ----------
    subject : xarray.Dataset
        A map subject of the store (``region`` and ``ts_m`` maps).
    defaults : dict of int to SkinMicrostructure, optional
        The other statistics per region (default ``REGION_DEFAULTS``).

    Returns
    -------
    dict
        Region label → :class:`SkinMicrostructure`.
    """
    if "region" not in subject or "ts_m" not in subject:
        raise ValidationError(
            f"subject must be a map subject with 'region' and 'ts_m', got variables {sorted(subject.data_vars)}"
        )
    region = np.asarray(subject["region"].values)
    m = np.asarray(subject["ts_m"].values, np.float64)
    ok = (region > 0) & np.isfinite(m)
    if not ok.any():
        raise ValidationError(f"subject {subject.attrs.get('subject_id', '?')!r} has no finite ts_m on the face")
    face = float(np.median(m[ok]))
    table = dict(REGION_DEFAULTS if defaults is None else defaults)
    out = {}
    for k, p in table.items():  # loop over the ten regions
        sel = ok & (region == k)
        out[k] = replace(p, roughness=float(np.median(m[sel])) if sel.any() else face)
    return out


def subject_microstructure(subject, shape, texel_um=15.0, *, seed=None, deformation=None, window=None) -> np.ndarray:
    """:func:`procedural_microstructure` over a store subject's UV layout, per region from its parameters.

    The subject's region map spans the whole map of ``shape`` texels (its UV square), read nearest
    (:func:`region_labels`); the seed defaults to one derived from the subject id, so a subject always gets the
    same skin.  The map's texels are ``texel_um`` of skin each, so ``shape`` × ``texel_um`` should be the size
    the subject's face has in that UV layout: ICT-FaceKit's maps its face at 18.1 µm per texel (median over its
    triangles) in a 16,384² map, 290 µm in a 1,024² one.  A smaller map at 15 µm per texel squeezes the
    whole face, forehead to chin, into a few mm; a ``window`` of the full-size map is a patch of the face at its
    true scale, with the regions that lie there (docs/microstructure.md).

    Parameters
    ----------
    subject : xarray.Dataset
        A map subject of the store (``region`` and ``ts_m`` maps, :func:`subject_microstructure_parameters`).
    shape : int or (int, int)
        Size in texels ``(height, width)`` of the whole map (the subject's UV square).
    texel_um : float
        µm of skin per texel.
    seed : int, optional
        Seed of the realisation; default the CRC-32 of the subject's ``subject_id`` attribute.
    deformation : array_like (2, 2), optional
        As :func:`procedural_microstructure`.
    window : (row0, col0, height, width), optional
        Generate only these texels of the whole map (the window a render covers; default: all).

    Returns
    -------
    ndarray of float32, shape (height, width)
        Heights in µm, indexed ``[v, u]``: the whole map, or the window.

    Raises
    ------
    ValidationError
        A subject without ``region`` or ``ts_m``, or a bad ``shape``, ``texel_um``, ``seed``, ``deformation`` or
        ``window``.
    """

    params = subject_microstructure_parameters(subject)
    if seed is None:
        seed = zlib.crc32(str(subject.attrs.get("subject_id", "")).encode())
    region = np.asarray(subject["region"].values).astype(np.int64)
    return procedural_microstructure(
        shape, texel_um, params=params, region_map=region, seed=seed, deformation=deformation, window=window
    )
