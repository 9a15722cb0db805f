"""Diffuse/specular separation of reflectance functions by colour (Debevec et al. 2000 §4.1-4.2, eq. 6-7).

Every reflectance-function sample R (RGB) is written as

    R = μd d + μs s + μe (d × s)                                    (§4.2)

with d the diffuse chromaticity, s the light's chromaticity (the specular
colour) and e = d × s an error direction; μ = [d s e]⁻¹ R.  The specular part
is S = max(μs, 0) s and the diffuse part D = R − S, so D + S = R exactly.
Chromaticities are unit RGB vectors.  When d and s are nearly parallel the
matrix is ill-conditioned: its condition number is returned and pixels above
``max_condition`` are flagged; μs is clamped to [0, min_c R_c/s_c] and counted.

The diffuse chromaticity is not constant (§4.1): it desaturates towards the
light colour as θi and θr grow, which eq. 6-7 model as

    d(θi, θr) = normalize(d₀ + f (d₀ − s)),  f = α₀ cos θi cos θr + α₁ (1 − cos θi cos θr)

Source check (eq. 6): as printed, d₀ + f (d₀ − s) moves *away* from s for f > 0;
desaturation towards s at grazing angles means f < 0 there, i.e. α₁ < α₀ ≤ 0 for
skin.  We keep the printed sign; fitted α then carry it.  Also note that
(d₀, α₀, α₁) are identifiable only with d₀ fixed: moving d₀ along its own ramp
rescales f, so d₀ must be given or estimated by a fixed rule.

Fitting (facestats's deviation from the paper's coarse-to-fine direct search):
for a sample of chromaticity c on the ramp, c ∥ d₀ + f (d₀ − s), so
c × d₀ + f (c × (d₀ − s)) = 0 gives f in closed form (least squares in the
direction of c × (d₀ − s)); f is linear in (α₀, α₁), so a weighted linear least
squares per pixel recovers them exactly from noise-free data.  As in the paper,
samples near the mirror direction are down-weighted so that specular colour
does not bias the ramp, and only lit samples count.

The full per-pixel procedure of §4.2 is :func:`separate_field`: d₀ from the
median R/G and G/B ratios of mid-bright samples, a rough separation with d₀, a
Lambertian fit of the rough diffuse part for the normal, the ramp fit, the final
separation with the fitted ramp, and the final normal, diffuse albedo ρd and
specular energy ρs.
"""

from __future__ import annotations

import warnings

import numpy as np

from facestats.core.validate import as_finite, as_scalar, check_broadcast, check_shape
from facestats.errors import ValidationError
from facestats.model.sphere import unit_directions
from facestats.relight.field import as_field, light_dims, light_table
from facestats.relight.photometric import lambertian_fit

__all__ = [
    "unit_rgb",
    "ramp_factor",
    "ramp_chromaticity",
    "ramp_factor_from_chromaticity",
    "fit_chromaticity_ramp",
    "diffuse_chromaticity",
    "separation_basis",
    "separation_matrix_condition",
    "separate_colour",
    "separate_field",
]

WHITE = np.full(3, 1 / np.sqrt(3))


def unit_rgb(value, name: str = "colour") -> np.ndarray:
    """RGB vectors scaled to unit length (chromaticities as unit vectors, §4.1), float64; zero vectors refused.

    Parameters
    ----------
    value : array_like, shape (..., 3)
        RGB vectors, finite.
    name : str
        The argument's name in messages.

    Returns
    -------
    numpy.ndarray of float64, shape (..., 3)

    Raises
    ------
    ValidationError
        For non-finite values, a last axis other than 3, or a zero vector.
    """
    v = check_shape(as_finite(value, name, dtype=np.float64), name, (..., 3))
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n == 0):
        raise ValidationError(f"{name} must be non-zero RGB vectors, got (0, 0, 0)")
    return v / n


def ramp_factor(cos_i, cos_r, alpha0, alpha1):
    """f(θi, θr) = α₀ cos θi cos θr + α₁ (1 − cos θi cos θr) (Debevec et al. 2000 eq. 7), broadcast.

    Parameters
    ----------
    cos_i, cos_r : array_like
        cos θi (N·l) and cos θr (N·v); not checked.
    alpha0, alpha1 : array_like
        The ramp's parameters (NaN passes through).

    Returns
    -------
    numpy.ndarray
        f, the broadcast shape of the inputs.
    """
    x = np.asarray(cos_i, np.float64) * np.asarray(cos_r, np.float64)
    return np.asarray(alpha0) * x + np.asarray(alpha1) * (1 - x)


def ramp_chromaticity(d0, s, f):
    """Diffuse chromaticity normalize(d₀ + f (d₀ − s)) (eq. 6), unit RGB vectors on the last axis.

    ``d0`` and ``s`` are normalised first; ``f`` broadcasts against them without
    their last axis.

    Parameters
    ----------
    d0 : array_like, shape (..., 3)
        Diffuse chromaticity at f = 0 (non-zero RGB).
    s : array_like, shape (..., 3)
        Light chromaticity (non-zero RGB).
    f : array_like, shape (...)
        Ramp factor of eq. 7 (:func:`ramp_factor`).

    Returns
    -------
    numpy.ndarray of float64, shape (..., 3)
        Unit RGB vectors.

    Raises
    ------
    ValidationError
        For a zero or non-finite ``d0`` or ``s``, or an ``f`` at which d₀ + f (d₀ − s) vanishes.
    """
    d0 = unit_rgb(d0, "d0")
    s = unit_rgb(s, "s")
    v = d0 + np.asarray(f, np.float64)[..., None] * (d0 - s)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n == 0):
        raise ValidationError("f must not reach the value where d0 + f (d0 - s) vanishes")
    return v / n


def ramp_factor_from_chromaticity(c, d0, s):
    """The f of eq. 6 that a chromaticity ``c`` lies at on the ramp of (d₀, s); least squares off the ramp.

    From c × (d₀ + f (d₀ − s)) = 0: f = −(c × d₀)·(c × u)/‖c × u‖² with u = d₀ − s.
    NaN where c × u = 0 (c parallel to d₀ − s).

    Parameters
    ----------
    c : array_like, shape (..., 3)
        Chromaticities (any length: f does not depend on it; not checked).
    d0, s : array_like, shape (3,) or broadcastable to ``c``
        Diffuse and light chromaticities (non-zero RGB; normalised here).

    Returns
    -------
    numpy.ndarray of float64, shape (...)

    Raises
    ------
    ValidationError
        For a zero or non-finite ``d0`` or ``s``.
    """
    c = np.asarray(c, np.float64)
    d0 = unit_rgb(d0, "d0")
    u = d0 - unit_rgb(s, "s")
    a = np.cross(c, d0)
    b = np.cross(c, np.broadcast_to(u, c.shape))
    den = np.einsum("...k,...k->...", b, b)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, -np.einsum("...k,...k->...", a, b) / den, np.nan)


def fit_chromaticity_ramp(values, cos_i, cos_r, d0, s=WHITE, weights=None):
    """Fit α₀, α₁ of eq. 6-7 per pixel from sample chromaticities (closed-form weighted least squares).

    Parameters
    ----------
    values : array_like, shape (L, N, 3)
        RGB samples of N reflectance functions (diffuse parts, or the original
        functions with ``weights`` that suppress the specular samples).
    cos_i : array_like, shape (L, N)
        cos θi of each sample (N·l).
    cos_r : array_like, shape (N,)
        cos θr of each pixel (N·v).
    d0 : array_like, shape (N, 3) or (3,)
        Representative diffuse chromaticity per pixel (normalised).
    s : array_like, shape (3,)
        Light chromaticity (default white).
    weights : array_like, shape (L, N), optional
        Sample weights ≥ 0 (default: the sample's brightness where cos θi > 0).

    Returns
    -------
    alpha0, alpha1 : ndarray, shape (N,)
        NaN where fewer than two usable samples with distinct cos θi cos θr exist.
    """
    r = check_shape(as_finite(values, "values", dtype=np.float64), "values (samples, pixels, 3)", (None, None, 3))
    ci = check_shape(as_finite(cos_i, "cos_i", dtype=np.float64), "cos_i", r.shape[:2])
    cr = check_shape(as_finite(cos_r, "cos_r", dtype=np.float64), "cos_r", r.shape[1:2])
    norm = np.linalg.norm(r, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = r / norm[..., None]
    f = ramp_factor_from_chromaticity(c, check_broadcast(unit_rgb(d0, "d0"), "d0", r.shape[1:], "a pixel of values"), s)
    if weights is None:
        w = norm * (ci > 0)
    else:
        w = check_broadcast(as_finite(weights, "weights", 0, None, dtype=np.float64), "weights", r.shape[:2], "cos_i")
    w = np.where(np.isfinite(f) & (norm > 0), w, 0.0)
    f = np.where(w > 0, f, 0.0)
    x = ci * cr[None, :]
    # f = α₁ + (α₀ − α₁) x: weighted line fit of f against x per pixel.
    sw, sx, sf = w.sum(0), (w * x).sum(0), (w * f).sum(0)
    sxx, sxf = (w * x * x).sum(0), (w * x * f).sum(0)
    det = sw * sxx - sx * sx
    ok = det > 1e-12 * np.maximum(sw * sxx, 1e-300)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):  # the pixels not ok are NaN anyway
        slope = (sw * sxf - sx * sf) / det
        icpt = (sf - slope * sx) / sw
        both = icpt + slope  # inf - inf where det is 0 (a RuntimeWarning on real data before: a user's run)
    alpha1 = np.where(ok, icpt, np.nan)
    alpha0 = np.where(ok, both, np.nan)
    return alpha0, alpha1


def diffuse_chromaticity(values, low: float = 25.0, high: float = 75.0, use=None):
    """Representative diffuse chromaticity d₀ of each reflectance function (Debevec et al. 2000 §4.2).

    "the median of the red-green and green-blue ratios over reflectance function
    values falling in a certain brightness range".  The paper does not give the
    range; facestats takes the samples whose luminance (the plain sum R + G + B of the
    linear values) lies between the
    ``low`` and ``high`` percentiles of the function's lit (non-zero) samples —
    a range relative to the function itself that excludes shadows and noise
    below and the specular lobe above whatever its height (a range relative to
    the maximum would be emptied by one strong highlight).  With a = median R/G
    and b = median G/B, d₀ = normalize(a b, b, 1).

    A broad lobe also lifts mid-bright samples: on a Lambertian + Torrance-Sparrow
    sphere (m = 0.35, ρs = 0.25, 7 × 7 pixels) d₀ from all samples is up to 1.6°
    off the albedo's colour, towards white.  :func:`separate_field` therefore
    passes ``use``: only the samples farther than its ``mirror_deg`` from the
    mirror direction, which gives 0.5° there.

    Parameters
    ----------
    values : array_like, shape (L, N, 3)
    low, high : float
        Percentiles, 0 ≤ low < high ≤ 100.
    use : array_like of bool, shape (L, N), optional
        The samples that may count (default all); the percentiles are those of
        the lit samples among them.

    Returns
    -------
    ndarray, shape (N, 3)
        Unit RGB; NaN for functions without a usable sample.
    """

    r = check_shape(as_finite(values, "values", dtype=np.float64), "values", (None, None, 3))
    lo = as_scalar(low, "low", 0, 100)
    hi = as_scalar(high, "high", lo, 100, low_inclusive=False)
    lum = r.sum(-1)
    lit = (lum > 0) & (r[..., 1] > 0) & (r[..., 2] > 0)
    if use is not None:
        lit &= check_broadcast(np.asarray(use, bool), "use", r.shape[:2], "values without the RGB axis")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns give NaN, reported as such
        q = np.nanpercentile(np.where(lit, lum, np.nan), [lo, hi], axis=0)
        use = lit & (lum >= q[0]) & (lum <= q[1])
        with np.errstate(invalid="ignore", divide="ignore"):
            rg = np.where(use, r[..., 0] / r[..., 1], np.nan)
            gb = np.where(use, r[..., 1] / r[..., 2], np.nan)
        a, b = np.nanmedian(rg, axis=0), np.nanmedian(gb, axis=0)
    d = np.stack([a * b, b, np.ones_like(a)], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def separation_basis(d, s=WHITE) -> np.ndarray:
    """The matrices [d s d×s] (..., 3, 3) of §4.2, columns d, s and e = d × s, for unit RGB vectors ``d`` (..., 3)
    and ``s`` (3,): R = μd d + μs s + μe e (the coordinates μ of :func:`separate_colour`).

    Parameters
    ----------
    d : array_like, shape (..., 3)
        Unit diffuse colours (not normalised or checked here).
    s : array_like, shape (3,)
        Unit light colour (default white), broadcast to ``d``.

    Returns
    -------
    numpy.ndarray of float64, shape (..., 3, 3)
        Columns d, s, d × s.
    """
    d = np.asarray(d, np.float64)
    s = np.broadcast_to(np.asarray(s, np.float64), d.shape)
    return np.stack([d, s, np.cross(d, s)], axis=-1)


def separation_matrix_condition(d, s=WHITE) -> np.ndarray:
    """2-norm condition number of [d s d×s] per chromaticity (∞ when d ∥ s).

    Parameters
    ----------
    d : array_like, shape (..., 3)
        Diffuse chromaticities (non-zero RGB; normalised here).
    s : array_like, shape (3,)
        Light chromaticity (default white; normalised here).

    Returns
    -------
    numpy.ndarray of float64, shape (...)
        σ_max / σ_min of each matrix, ≥ 1.

    Raises
    ------
    ValidationError
        For a zero or non-finite ``d`` or ``s``.
    """
    m = separation_basis(unit_rgb(d, "d"), unit_rgb(s, "s"))
    sv = np.linalg.svd(m, compute_uv=False)
    with np.errstate(divide="ignore"):
        return np.where(sv[..., -1] > 0, sv[..., 0] / sv[..., -1], np.inf)


def separate_colour(values, d, s=WHITE):
    """Split RGB samples into diffuse and specular parts: μ = [d s d×s]⁻¹ R, S = μs s, D = R − S (§4.2).

    μs is clamped to [0, min_c R_c / s_c], so that 0 ≤ S ≤ R and D ≥ 0 in every channel (beyond the paper,
    which clamps at 0 only: where d is nearly parallel to s the inverse amplifies noise into S far above R).

    Parameters
    ----------
    values : array_like, shape (..., 3)
        Samples R.
    d : array_like, shape broadcastable to ``values``
        Diffuse chromaticity per sample (unit after normalisation).
    s : array_like, shape (3,)
        Light (specular) chromaticity.

    Returns
    -------
    diffuse, specular : ndarray, shape of ``values``
        D + S = R exactly.
    mu : ndarray, shape of ``values``
        (μd, μs, μe) before clamping.
    clamped : ndarray of bool, shape ``values.shape[:-1]``
        Samples whose μs left [0, min_c R_c / s_c] beyond rounding (10⁻⁶ ‖R‖); every
        μs is clamped into it.
    """
    r = check_shape(as_finite(values, "values", dtype=np.float64), "values", (..., 3))
    dd = check_broadcast(unit_rgb(d, "d"), "d", r.shape, "values")
    ss = unit_rgb(s, "s")
    e = np.cross(dd, np.broadcast_to(ss, r.shape))
    # Inverse of [d s e] by cross products: rows (s × e, e × d, d × s) / det.
    det = np.einsum("...k,...k->...", dd, np.cross(np.broadcast_to(ss, r.shape), e))
    if np.any(np.abs(det) < 1e-12):
        raise ValidationError("d and s must not be parallel (the separation matrix is singular); check its condition")
    rows = np.stack([np.cross(np.broadcast_to(ss, r.shape), e), np.cross(e, dd), np.cross(dd, ss)], axis=-2)
    mu = np.einsum("...ij,...j->...i", rows, r) / det[..., None]
    # 0 <= S <= R in every channel: mu_s <= min_c R_c / s_c (D >= 0), which the solve breaks where d is nearly
    # parallel to s (a ramp pushed there by few samples): S of 315 x R and D < 0 were seen
    top = np.min(np.where(ss > 0, np.maximum(r, 0) / np.where(ss > 0, ss, 1.0), np.inf), axis=-1)
    tol = 1e-6 * np.linalg.norm(r, axis=-1)  # rounding-level excursions are not counted
    clamped = (mu[..., 1] < -tol) | (mu[..., 1] > top + tol)
    spec = np.clip(mu[..., 1], 0, top)[..., None] * ss
    return r - spec, spec, mu, clamped


def separate_field(field, s=WHITE, *, view=None, ramp: bool = True, mirror_deg: float = 60.0,
                   shadow_threshold: float = 0.05, max_condition: float = 50.0, d0=None):  # fmt: skip
    """The colour-space separation of §4.2 applied to every pixel of a reflectance field.

    Steps per pixel: d₀ (:func:`diffuse_chromaticity`, or given), rough
    separation with d₀, Lambertian normal of the rough diffuse part over lit
    samples (luminance ≥ ``shadow_threshold`` × the pixel's maximum, the
    brightness thresholding of §4.4), ramp fit (α₀, α₁) on the original
    samples with those within ``mirror_deg`` of the mirror direction of the view
    left out, separation with the ramp chromaticity, the ramp fitted again about
    the normal of that diffuse part (not in the paper: the rough normal is tilted by
    the ramp itself), final separation, final normal, diffuse
    albedo ρd (Lambertian fit of D) and specular energy ρs = Σ_l mean_c(S) δA (the
    specular radiance per channel under uniform unit white light, a grey reflectance).

    Parameters
    ----------
    field : xarray.Dataset
        In memory; needs ``view`` per pixel (the stage stores it) unless given.
    s : array_like, shape (3,)
        Light chromaticity.
    view : array_like, shape (y, x, 3), optional
    ramp : bool
        Fit the chromaticity ramp (§4.1-4.2).  False: the diffuse colour is d₀
        for every sample (the separation of D4 with a known skin colour).
        Colour alone cannot tell a ramp shift towards s from specular light
        (both lie in the plane of d₀ and s), so the ramp is fitted only on
        samples farther than ``mirror_deg`` from the mirror direction; broad
        lobes (skin's m ≈ 0.3-0.4) need a wide exclusion.
    mirror_deg : float
        Degrees, in [0, 90]: samples closer than this to the mirror direction of
        the view (about a first Lambertian normal) are left out of d₀ and of the
        ramp fit.  The paper only says "downweight values near the mirror angle".
        The default, 60°, was chosen on Lambertian + Torrance-Sparrow spheres
        (``docs/relighting.md``, D3): at skin's m = 0.35 the ramp fit, with 45°,
        reads the lobe's tail as a ramp and ρs comes out 14 % low, against 5.5 %
        with 60°.
    shadow_threshold, max_condition : float
    d0 : array_like, shape (y, x, 3) or (3,), optional
        Known diffuse chromaticity instead of the median-ratio estimate
        (:func:`diffuse_chromaticity` over the samples outside ``mirror_deg``).

    Returns
    -------
    xarray.Dataset
        ``diffuse`` and ``specular`` (dims of the field's reflectance), per pixel
        ``normal``, ``specular_normal`` (half vector of the specular peak; NaN where the
        specular is nowhere above 1e-6 of the pixel's brightest sample),
        ``albedo`` (ρd, RGB), ``rho_s``, ``alpha0``, ``alpha1``, ``d0``,
        ``condition`` and ``ill_conditioned``, ``n_clamped`` (μs clamped into [0, min_c R_c / s_c]).

    Notes
    -----
    ρs sums the clamped specular parts, so noise in the samples biases it high: by 13 % at 2 %
    relative noise per channel for m = 0.2, 5 % for m = 0.35 (``docs/relighting.md``, D3, "Noise").

    Pixels that face the camera are the weak spot of the ramp fit: their mirror direction lies along the normal,
    so α₀ is extrapolated from grazing samples, and their specular is a percent or two of the diffuse, so a small
    ramp error moves much of it into D. With the defaults, broad lobes lose much of their ρs there (median ratio
    0.54 within 10° of the view at m = 0.35, 0.94 at 30-45°, 0.98 at 45-60°, on flat data;
    ``docs/relighting.md``, D3, "Pixels facing the camera", ``bench_relight.bench_separation_by_tilt``).
    """

    f = as_field(field)
    mirror_deg = as_scalar(mirror_deg, "mirror_deg", 0, 90, unit="deg")
    shadow_threshold = as_scalar(shadow_threshold, "shadow_threshold", 0, 1, high_inclusive=False)
    max_condition = as_scalar(max_condition, "max_condition", 1, None)
    nl = len(light_dims(f))
    dirs, sa, _ = light_table(f)
    n_l = dirs.shape[0]
    h, w = f.sizes["y"], f.sizes["x"]
    r = np.asarray(f["reflectance"].values, np.float64).reshape(n_l, h * w, 3)
    if view is None:
        if "view" not in f.data_vars:
            raise ValidationError("field must carry a 'view' variable (unit vectors to the camera) or pass view=")
        view = f["view"].values
    v = unit_directions(view, "view", allow_zero=True)  # 0 off the face
    if v.shape == (3,):  # one direction for every pixel
        v = np.broadcast_to(v, (h, w, 3))
    v = check_shape(v, "view", (h, w, 3)).reshape(h * w, 3)
    s_unit = unit_rgb(s, "s")
    if d0 is None:  # the median ratios of mid-bright samples away from the mirror direction of a first normal
        far, _, _ = _far_from_mirror(r, dirs, v, _lit(r, shadow_threshold), mirror_deg)
        d0_est = diffuse_chromaticity(r, use=far)
    else:
        d0_est = np.broadcast_to(unit_rgb(d0, "d0"), (h, w, 3)).reshape(-1, 3)
    finite = np.all(np.isfinite(d0_est), axis=-1)
    cond = np.full(h * w, np.inf)
    cond[finite] = separation_matrix_condition(d0_est[finite], s_unit)
    sel = finite & (cond < 1e6) & (r.sum(-1).max(0) > 0)  # separable pixels (the others keep D = R, S = 0)
    if "mask" in f.data_vars:
        sel &= np.asarray(f["mask"].values, bool).reshape(h * w)
    out = _separate_pixels(r[:, sel], dirs, sa, v[sel], d0_est[sel], s_unit, ramp, mirror_deg, shadow_threshold)
    full = {
        "diffuse": r.copy(), "specular": np.zeros_like(r), "normal": np.full((h * w, 3), np.nan),
        "specular_normal": np.full((h * w, 3), np.nan), "albedo": np.full((h * w, 3), np.nan),
        "rho_s": np.zeros(h * w), "alpha0": np.full(h * w, np.nan), "alpha1": np.full(h * w, np.nan),
        "clamped": np.zeros((n_l, h * w), bool),
    }  # fmt: skip
    for key, val in out.items():
        if full[key].shape[0] == n_l:
            full[key][:, sel] = val
        else:
            full[key][sel] = val
    return _separation_dataset(f, nl, h, w, full, d0_est, cond, max_condition)


def _lit(r, shadow_threshold):
    """Samples whose luminance (R + G + B) reaches ``shadow_threshold`` × the pixel's maximum (§4.4).

    r (L, N, 3) → (L, N).
    """
    lum = r.sum(-1)
    return lum >= shadow_threshold * lum.max(0)


def _far_from_mirror(r, dirs, v, lit, mirror_deg):
    """(samples farther than ``mirror_deg`` from the mirror direction, cos θi (L, N), cos θr (N,)) for the
    Lambertian normal of ``r`` (L, N, 3) over the ``lit`` samples; the view ``v`` (N, 3) where that has none."""
    normal, _ = lambertian_fit(r, dirs, lit * 1.0)
    n_safe = np.where(np.isfinite(normal), normal, v)
    cos_i = dirs @ n_safe.T
    cos_r = np.clip(np.einsum("nk,nk->n", n_safe, v), 0, 1)
    mirror = 2 * cos_r[:, None] * n_safe - v  # (N, 3)
    return (dirs @ mirror.T) < np.cos(np.radians(mirror_deg)), cos_i, cos_r


def _separate_pixels(r, dirs, sa, v, d0, s_unit, ramp, mirror_deg, shadow_threshold):
    """The §4.2 procedure on separable pixels: r (L, N, 3), v (N, 3), d0 (N, 3) → dict of results.

    With ``ramp``, the ramp is fitted twice: about the normal of the rough separation (the paper's order),
    then about the normal of the diffuse part that fit gives. The rough diffuse part still holds the ramp's
    shift towards s, which tilts its normal; the ramp fitted about that normal was biased even on data without
    specular light (α₀ off by up to 0.011 for a ramp (−0.05, −0.4)), and a narrow lobe's ρs by up to 9.5 % at
    single pixels (a red team, 2026-12-06; ``docs/relighting.md``, D3).
    """
    n = r.shape[1]
    lum = r.sum(-1)
    lit = _lit(r, shadow_threshold)
    diffuse, _, _, _ = separate_colour(r, d0[None], s_unit)  # the rough separation, with d₀
    for _ in range(2 if ramp else 1):
        far_from_mirror, cos_i, cos_r = _far_from_mirror(diffuse, dirs, v, lit, mirror_deg)
        if ramp:
            wts = lum * lit * far_from_mirror * (cos_i > 0)
            a0, a1 = fit_chromaticity_ramp(r, np.clip(cos_i, 0, 1), cos_r, d0, s_unit, weights=wts)
        else:
            a0 = a1 = np.zeros(n)
        fr = ramp_factor(np.clip(cos_i, 0, 1), cos_r[None, :], np.nan_to_num(a0)[None, :], np.nan_to_num(a1)[None, :])
        d_ramp = ramp_chromaticity(np.broadcast_to(d0, r.shape), s_unit, fr)
        diffuse, spec, _, clamped = separate_colour(r, d_ramp, s_unit)
    normal, albedo = lambertian_fit(diffuse, dirs, lit * 1.0)
    size = np.linalg.norm(spec, axis=-1)
    peak = np.argmax(size, axis=0)
    hv = dirs[peak] + v
    hv /= np.linalg.norm(hv, axis=-1, keepdims=True)
    # No specular above rounding (1e-6 of the pixel's brightest sample): no peak, so no specular normal.
    hv[size[peak, np.arange(n)] <= 1e-6 * np.linalg.norm(r, axis=-1).max(0)] = np.nan
    return {
        "diffuse": diffuse, "specular": spec, "normal": normal,
        "specular_normal": hv, "albedo": albedo,
        "rho_s": np.einsum("ln,l->n", spec.mean(-1), sa), "alpha0": a0, "alpha1": a1, "clamped": clamped,
    }  # fmt: skip


def _separation_dataset(f, nl, h, w, full, d0, cond, max_condition):
    import xarray as xr

    ldims = tuple(f["reflectance"].dims[:nl])
    lshape = tuple(f["reflectance"].shape[:nl])
    dims = ldims + ("y", "x", "channel")

    def img(name, extra=()):
        a = np.asarray(full[name] if isinstance(name, str) else name, np.float32)
        return (("y", "x") + extra, a.reshape((h, w) + a.shape[1:]))

    ds = xr.Dataset(
        {
            "diffuse": (dims, full["diffuse"].reshape(lshape + (h, w, 3)).astype(np.float32)),
            "specular": (dims, full["specular"].reshape(lshape + (h, w, 3)).astype(np.float32)),
            "normal": img("normal", ("component",)),
            "specular_normal": img("specular_normal", ("component",)),
            "albedo": img("albedo", ("channel",)),
            "rho_s": img("rho_s"),
            "alpha0": img("alpha0"),
            "alpha1": img("alpha1"),
            "d0": img(d0, ("channel",)),
            "condition": img(cond),
            "ill_conditioned": (("y", "x"), (cond > max_condition).reshape(h, w)),
            "n_clamped": (("y", "x"), full["clamped"].sum(0).reshape(h, w).astype(np.int32)),
        },
        coords={k: f.coords[k] for k in f.coords},
    )
    ds.attrs.update(source="colour-space separation, Debevec et al. 2000 §4.2", max_condition=float(max_condition))
    return ds
