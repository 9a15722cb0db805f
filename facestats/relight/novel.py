"""Reflectance functions for a novel viewpoint (Debevec et al. 2000 §4.3, eq. 8-9) and re-projection (§4.5).

**Specular** (eq. 8-9).  A specular sample under the light l (view v₀) measures
the microfacets around the half vector h = normalize(v₀ + l).  For the novel
view vₙ and a light lₚ, h = normalize(vₙ + lₚ) and the original light that
probed the same facets is the mirror of v₀ about h,

    l_q = 2 (h·v₀) h − v₀,

and the Torrance-Sparrow relation L = P L_i Ω G F / (4 v·n) (eq. 8, per unit
L_i Ω) gives

    S(lₚ; vₙ) = S(l_q; v₀) · G(vₙ, lₚ, n) F(vₙ·h) (v₀·n) / (G(v₀, l_q, n) F(v₀·h) (vₙ·n))     (eq. 9)

with G the V-groove shadowing (:func:`facestats.model.brdf.v_groove_shadowing`)
and F the unpolarised Fresnel reflectance at v·h
(:func:`facestats.model.fresnel.fresnel_reflectance`).  l_q falls between the
stage's lights, so S is interpolated there.  Following the paper's
view-independent representation (Fig. 12e), the samples are first turned into
the facet distribution P(h) ∝ S · (v₀·n)/(G F) and P is interpolated
bilinearly *in its logarithm* on the lat-long grid of lights: the lobe is close
to a Gaussian in the angles, whose logarithm is quadratic, so the
interpolation error is a small uniform fraction instead of growing in the
tails.  The ratio of the non-D terms is clamped near grazing (v·n at least
``min_cos``; G F is not clamped: where it vanishes at the original view, S
does too, and P = S/(G F/(v·n)) is taken as 0 where the ratio is 0), lights
lₚ or l_q below the horizon give 0, and a shadow mask (if given) zeroes
shadowed lₚ (§4.4).  A pixel without a separated normal (NaN) takes its view
direction as the normal.

**Diffuse** (§4.3).  Each diffuse sample's chromaticity is moved along the
ramp of eq. 6-7 (:mod:`facestats.relight.separate`): its own chromaticity stands
for d₀ at the original f(θi, θr₀) — the shift is inverted to recover that
sample's d₀ — and is re-applied at f(θi, θrₙ); the sample keeps its norm.

**Rendering** (§4.5).  The resynthesised field is relit from the original
camera (the face is shaded as seen from the novel view) and then projected onto
the face geometry and seen from the novel camera: :func:`reproject` builds a
mesh from the source pixels' surface positions and rasterises it into the new
camera (:func:`facestats.acquire.visibility.rasterize`).
"""

from __future__ import annotations

import numpy as np

from facestats.acquire.visibility import rasterize
from facestats.core.published import ETA_SKIN
from facestats.core.validate import as_finite, as_float, check_shape
from facestats.errors import ValidationError
from facestats.face.geometry import grid_triangles
from facestats.model.brdf import v_groove_shadowing_unchecked
from facestats.model.fresnel import check_eta, fresnel_reflectance_unchecked
from facestats.model.sphere import latlong_coordinates, latlong_directions, unit_directions
from facestats.relight.camera import ray_triangle
from facestats.relight.field import make_field
from facestats.relight.separate import ramp_chromaticity, ramp_factor, unit_rgb

__all__ = [
    "specular_terms",
    "mirror_light",
    "remap_specular",
    "shift_diffuse_chromaticity",
    "novel_view_field",
    "reproject",
]


def _dot(a, b):
    return np.einsum("...k,...k->...", a, b)


def _unit(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / n


def specular_terms(normal, light, view, eta=ETA_SKIN, min_cos: float = 0.02):
    """G(v, l, n) F(v·h) / (v·n), the non-D factor of eq. 8 (up to the constant 1/4), broadcast; 0 below the horizon.

    v·n is clamped at ``min_cos`` (grazing views).  No input is checked (the callers have).

    Parameters
    ----------
    normal, light, view : array_like, shape (..., 3)
        Unit surface normal n, unit direction towards the light l and towards the viewer v; broadcast together.
    eta : float
        Relative index of refraction of the Fresnel term (default skin's 1.38).
    min_cos : float
        Lower clamp of the denominator v·n.

    Returns
    -------
    numpy.ndarray of float64, shape (...)
        The factor; 0 where n·l, n·v, n·h or v·h is ≤ 0.
    """
    n, l, v = (np.asarray(a, np.float64) for a in (normal, light, view))
    h = _unit(l + v)
    n_l, n_v, n_h, v_h = _dot(n, l), _dot(n, v), _dot(n, h), _dot(v, h)
    above = (n_l > 0) & (n_v > 0) & (n_h > 0) & (v_h > 0)
    tiny = 1e-12
    g = v_groove_shadowing_unchecked(
        np.maximum(n_h, tiny), np.maximum(n_l, tiny), np.maximum(n_v, tiny), np.maximum(v_h, tiny)
    )
    f = fresnel_reflectance_unchecked(np.clip(v_h, 0, 1), eta)
    return np.where(above, g * f / np.maximum(n_v, min_cos), 0.0)


def mirror_light(light, view_new, view_old):
    """l_q = 2 (h·v₀) h − v₀ with h = normalize(vₙ + lₚ) (§4.3): the original light that probed the same facets.

    Parameters
    ----------
    light : array_like, shape (..., 3)
        Unit direction lₚ towards the light, for the novel view.
    view_new, view_old : array_like, shape (..., 3)
        Unit directions towards the novel (vₙ) and original (v₀) viewpoints; broadcast with ``light``.

    Returns
    -------
    numpy.ndarray of float64, shape (..., 3)
        l_q (a unit vector for unit inputs; NaN where lₚ = −vₙ).
    """
    h = _unit(np.asarray(light, np.float64) + np.asarray(view_new, np.float64))
    v0 = np.asarray(view_old, np.float64)
    return 2 * _dot(h, v0)[..., None] * h - v0


def _bilinear_log(p, coords_r, coords_c):
    """Bilinear interpolation of log p on a lat-long grid (n_phi, n_theta, N) at per-pixel coordinates (L, N).

    Columns wrap; rows clamp.  Neighbours with p ≤ 0 are left out (weights
    renormalised); 0 where all four are.
    """
    n_phi, n_theta, n = p.shape
    r0 = np.floor(coords_r).astype(np.int64)
    c0 = np.floor(coords_c).astype(np.int64)
    fr, fc = coords_r - r0, coords_c - c0
    pix = np.broadcast_to(np.arange(n)[None, :], coords_r.shape)
    num = np.zeros(coords_r.shape)
    den = np.zeros(coords_r.shape)
    for dr, dc, wgt in ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc), (1, 0, fr * (1 - fc)), (1, 1, fr * fc)):
        rr = np.clip(r0 + dr, 0, n_phi - 1)
        cc = np.mod(c0 + dc, n_theta)
        val = p[rr, cc, pix]
        ok = val > 0
        num += np.where(ok, wgt * np.log(np.where(ok, val, 1.0)), 0.0)
        den += np.where(ok, wgt, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 1e-9, np.exp(num / den), 0.0)


def remap_specular(specular, normal, view_old, view_new, *, eta=ETA_SKIN, shadow=None, min_cos: float = 0.02):
    """Specular reflectance functions seen from a novel view (eq. 9), on a lat-long light grid.

    Parameters
    ----------
    specular : array_like, shape (n_phi, n_theta, N) or (n_phi, n_theta, N, C)
        S per light (the light stage grid of :func:`facestats.model.sphere.light_stage_directions`).
    normal, view_old, view_new : array_like, shape (N, 3)
        Unit surface normal, original and novel view directions per pixel.
    eta : float
        Relative index of refraction of the Fresnel term.
    shadow : array_like of bool, shape (n_phi, n_theta, N), optional
        Lit samples (True); shadowed novel-view samples are set to 0 (§4.4).
    min_cos : float
        Clamp of the grazing denominator v·n.

    Returns
    -------
    ndarray, shape of ``specular``
    """
    s = as_finite(specular, "specular", 0, None, dtype=np.float64)
    if s.ndim not in (3, 4):
        raise ValidationError(f"specular must have shape (n_phi, n_theta, N[, C]), got {s.shape}")
    n_phi, n_theta, n = s.shape[:3]
    nrm = check_shape(unit_directions(normal, "normal", allow_zero=True), "normal", (n, 3))  # 0: no surface
    v0 = check_shape(unit_directions(view_old, "view_old", allow_zero=True), "view_old", (n, 3))
    vn = check_shape(unit_directions(view_new, "view_new", allow_zero=True), "view_new", (n, 3))
    dirs = latlong_directions(n_phi, n_theta).reshape(-1, 1, 3)  # (L, 1, 3)
    # View-independent facet distribution P ∝ S / (G F/(v·n)) at the original view.
    t0 = specular_terms(nrm[None], dirs, v0[None], eta, min_cos)  # (L, N)
    t0g = t0.reshape(n_phi, n_theta, n)
    lq = mirror_light(dirs, vn[None], v0[None])  # (L, N, 3)
    rows, cols = latlong_coordinates(lq, n_phi, n_theta)
    tn = specular_terms(nrm[None], dirs, vn[None], eta, min_cos)  # G F/(v·n) at (vₙ, lₚ)
    valid = (tn > 0) & (_dot(nrm[None], lq) > 0)  # l_q below the horizon: dropped
    out = np.empty_like(s)
    chans = [None] if s.ndim == 3 else range(s.shape[3])
    for c in chans:  # at most three channels; each a vectorised interpolation over lights and pixels
        sc = s if c is None else s[..., c]
        with np.errstate(invalid="ignore", divide="ignore"):
            p = np.where(t0g > 0, sc / np.where(t0g > 0, t0g, 1), 0.0)
        pq = _bilinear_log(p, rows, cols)  # P(h) read at l_q, where v₀ saw the facets h
        val = np.where(valid, pq * tn, 0.0).reshape(n_phi, n_theta, n)  # = S(l_q; v₀) × the ratio of eq. 9
        if c is None:
            out[...] = val
        else:
            out[..., c] = val
    if shadow is not None:
        sh = np.asarray(shadow, bool)
        if sh.shape != (n_phi, n_theta, n):
            raise ValidationError(f"shadow must have shape {(n_phi, n_theta, n)}, got {sh.shape}")
        out = out * (sh if s.ndim == 3 else sh[..., None])
    return out


def shift_diffuse_chromaticity(diffuse, cos_i, cos_r_old, cos_r_new, alpha0, alpha1, s=None):
    """Diffuse samples re-coloured for a novel view along the ramp of eq. 6-7 (§4.3), norms kept.

    Each sample's own chromaticity c is taken as the ramp's value at
    f₀ = f(θi, θr₀); its d₀ is recovered by inverting eq. 6 (the unit d₀ with
    normalize(d₀ + f₀ (d₀ − s)) = c) and the ramp re-applied at fₙ = f(θi, θrₙ).

    Parameters
    ----------
    diffuse : array_like, shape (L, N, 3)
    cos_i : array_like, shape (L, N)
    cos_r_old, cos_r_new : array_like, shape (N,)
    alpha0, alpha1 : array_like, shape (N,)
        The ramp of each pixel (:func:`facestats.relight.separate.fit_chromaticity_ramp`); NaN where it has none
        (too few samples): those pixels keep their colours.
    s : array_like, shape (3,), optional
        Light chromaticity (default white).

    Returns
    -------
    ndarray, shape (L, N, 3)
    """
    d = check_shape(as_finite(diffuse, "diffuse", dtype=np.float64), "diffuse (L, N, 3)", (None, None, 3))
    s_unit = unit_rgb(np.ones(3) if s is None else s, "s")
    norm = np.linalg.norm(d, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = d / norm[..., None]
    ci = np.clip(check_shape(as_finite(cos_i, "cos_i", dtype=np.float64), "cos_i", d.shape[:2]), 0, 1)
    n = d.shape[1:2]
    cr0 = check_shape(as_finite(cos_r_old, "cos_r_old", dtype=np.float64), "cos_r_old", n)
    crn = check_shape(as_finite(cos_r_new, "cos_r_new", dtype=np.float64), "cos_r_new", n)
    a0 = check_shape(as_float(alpha0, "alpha0", np.float64), "alpha0", n)  # NaN: no ramp
    a1 = check_shape(as_float(alpha1, "alpha1", np.float64), "alpha1", n)
    f0 = ramp_factor(ci, cr0[None], a0[None], a1[None])
    fn = ramp_factor(ci, crn[None], a0[None], a1[None])
    # d₀ from c: λ c = (1 + f₀) d₀ − f₀ s with ‖d₀‖ = 1 → ‖λ c + f₀ s‖ = 1 + f₀, λ > 0.
    cs = _dot(c, s_unit)
    lam = -f0 * cs + np.sqrt(np.maximum((f0 * cs) ** 2 - f0**2 + (1 + f0) ** 2, 0))
    d0 = _unit(lam[..., None] * c + f0[..., None] * s_unit)
    ok = (norm > 0) & np.all(np.isfinite(d0), axis=-1) & np.isfinite(fn)
    new = ramp_chromaticity(np.where(ok[..., None], d0, s_unit), s_unit, np.where(ok, fn, 0.0))
    return np.where(ok[..., None], norm[..., None] * new, d)


def novel_view_field(separation, view_new, *, eta=ETA_SKIN, shadow=None, s=None):
    """A lat-long reflectance field resynthesised for novel view directions (§4.3) from :func:`separate_field`.

    Parameters
    ----------
    separation : xarray.Dataset
        Output of :func:`facestats.relight.separate.separate_field` on a grid field
        (``diffuse``, ``specular``, ``normal``, ``alpha0``, ``alpha1``) merged with
        the field's ``view``.
    view_new : array_like, shape (y, x, 3) or (3,)
        Unit novel view direction per pixel (or one for all pixels).
    eta : float
        Relative index of refraction of the Fresnel terms.
    shadow : array_like of bool, shape (n_phi, n_theta, y, x), optional
    s : array_like, shape (3,), optional
        Light chromaticity (default white).

    Returns
    -------
    xarray.Dataset
        A field (``reflectance`` = remapped specular + shifted diffuse) with ``view`` = ``view_new``.
    """

    sep = separation
    if "light_phi" not in sep["diffuse"].dims or "view" not in sep.data_vars:
        raise ValidationError("separation must be of a lat-long grid field and carry the field's 'view'")
    n_phi, n_theta, h, w = (sep.sizes[k] for k in ("light_phi", "light_theta", "y", "x"))
    n = h * w
    raw = np.asarray(sep["normal"].values, np.float64).reshape(n, 3)
    nrm = np.nan_to_num(raw)
    v0 = np.asarray(sep["view"].values, np.float64).reshape(n, 3)
    vn = unit_directions(view_new, "view_new")
    vn = check_shape(np.broadcast_to(vn, (h, w, 3)) if vn.shape == (3,) else vn, "view_new", (h, w, 3)).reshape(n, 3)
    check_eta(eta)
    spec = np.asarray(sep["specular"].values, np.float64).reshape(n_phi, n_theta, n, 3)
    diff = np.asarray(sep["diffuse"].values, np.float64).reshape(n_phi * n_theta, n, 3)
    sh = None if shadow is None else check_shape(np.asarray(shadow, bool), "shadow", (n_phi, n_theta, h, w))
    sh = None if sh is None else sh.reshape(n_phi, n_theta, n)
    # A pixel without a separated normal keeps its specular about the view (the NaN test on the raw normals: on
    # nan_to_num's zeros it never fired, and such pixels lost their specular in the new view).
    new_spec = remap_specular(np.nan_to_num(spec), np.where(np.isfinite(raw).all(1, keepdims=True), raw, v0), v0,
                              vn, eta=eta, shadow=sh)  # fmt: skip
    dirs = latlong_directions(n_phi, n_theta).reshape(-1, 3)
    cos_i = dirs @ nrm.T
    cr0 = np.clip(_dot(nrm, v0), 0, 1)
    crn = np.clip(_dot(nrm, vn), 0, 1)
    a0 = np.nan_to_num(np.asarray(sep["alpha0"].values, np.float64).reshape(n))
    a1 = np.nan_to_num(np.asarray(sep["alpha1"].values, np.float64).reshape(n))
    new_diff = shift_diffuse_chromaticity(diff, cos_i, cr0, crn, a0, a1, s)
    vals = new_spec.reshape(n_phi, n_theta, h, w, 3) + new_diff.reshape(n_phi, n_theta, h, w, 3)
    extra = {k: np.nan_to_num(sep[k].values) for k in ("position", "normal") if k in sep.data_vars}
    if "mask" in sep.data_vars:
        extra["mask"] = sep["mask"].values
    return make_field(np.maximum(vals, 0), latlong_directions(n_phi, n_theta), view=vn.reshape(h, w, 3),
                      attrs={"source": "novel-view resynthesis, Debevec et al. 2000 §4.3"}, **extra)  # fmt: skip


def reproject(image, position, mask, camera):
    """Project a relit image onto its surface positions and view it from another camera (§4.5).

    The source pixels (``mask``) form a grid mesh through their 3-D
    ``position``; it is rasterised into ``camera`` and each covered pixel takes
    the barycentric blend of its triangle's source colours.

    Parameters
    ----------
    image : array_like, shape (H, W, 3)
    position : array_like, shape (H, W, 3)
        Surface point of every source pixel, mm.
    mask : array_like of bool, shape (H, W)
    camera : facestats.relight.camera.StageCamera

    Returns
    -------
    image : ndarray of float32, shape (size, size, 3)
    covered : ndarray of bool, shape (size, size)
    """

    img = check_shape(as_finite(image, "image", dtype=np.float64), "image", (None, None, 3))
    pos = as_finite(position, "position", dtype=np.float64)
    m = np.asarray(mask, bool)
    if img.shape[:2] != m.shape or pos.shape[:2] != m.shape:
        raise ValidationError(f"image, position and mask must share (H, W), got {img.shape}, {pos.shape}, {m.shape}")
    faces = grid_triangles(m)
    verts = pos.reshape(-1, 3)
    tri, _ = rasterize(verts, faces, *camera.pinhole())
    hit = tri >= 0
    out = np.zeros((camera.size, camera.size, 3))
    if hit.any():
        t = tri[hit]
        _, bary = ray_triangle(camera.position, camera.rays()[hit], *(verts[faces[t, k]] for k in range(3)))
        cols = img.reshape(-1, 3)[faces[t]]  # (n, 3 corners, 3)
        out[hit] = np.nan_to_num(np.einsum("nk,nkc->nc", bary, cols))
    return out.astype(np.float32), hit
