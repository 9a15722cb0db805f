"""The complete skin reflectance model of Weyrich et al. 2006, eq. 6.

L(xo, ωo) = f_s(xo, ωi, ωo) E(xo, ωi)                                  (specular, eq. 3)
          + M(xo) F_t(ωo)/π · ∫_A R_d(‖xo − xi‖) F_t(ωi) E(xi, ωi) dA(xi)  (diffuse, eq. 4-7)

for each light, where E is the irradiance a light produces on the surface
(including N·ωi and visibility), f_s is the Torrance-Sparrow or Blinn-Phong BRDF
(:mod:`facestats.model.brdf`), R_d the dipole profile
(:mod:`facestats.model.dipole`) and M the modulation texture of eq. 7.

Seed check (factor 1/π): eq. 6 as printed omits the 1/π of the BSSRDF
decomposition eq. 5 (S_d ≈ (1/π) f_i R_d f_o, Jensen et al. 2001).  With the
1/π, a flat homogeneous patch under uniform light reflects the diffuse BRDF
(α/π) F_t(ωi) F_t(ωo) that eq. 9-10 subtract; without it eq. 6 and eq. 10 would
disagree by π.  ``tests/model/test_skin.py`` integrates the diffuse term over a flat
patch and checks it against :func:`facestats.model.dipole.total_diffuse_reflectance`.

Conventions: positions in mm, areas in mm², directions unit vectors pointing away
from the surface, irradiance E in W mm⁻² (any consistent radiometric unit works:
radiance comes out in the same unit per sr), RGB on the last axis.

Shapes (N points, L lights, C cameras): ``normal`` (N, 3), ``wi`` (N, L, 3),
``irradiance`` (N, L, 3), ``wo`` (N, C, 3); radiance (N, C, L, 3).  This is the
forward model of the dome simulator and of the renderer: batch many points,
lights and cameras in one call and chunk over points for large surfaces.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facestats.core.published import ETA_SKIN
from facestats.core.validate import (
    as_finite,
    as_float,
    as_scalar,
    check_choice,
    check_integer,
    check_range,
    check_shape,
    result_dtype,
)
from facestats.errors import ValidationError
from facestats.model import brdf as _brdf
from facestats.model.dipole import (
    dipole_coefficients,
    dipole_radial_energy_unchecked,
    reduced_albedo_unchecked,
    total_from_reduced_albedo_unchecked,
    transport_coefficient,
)
from facestats.model.fresnel import check_eta, fresnel_reflectance_unchecked

__all__ = [
    "SPECULAR_MODELS",
    "modulation_texture",
    "point_lights",
    "directional_lights",
    "view_directions",
    "SubsurfaceTransport",
    "neighbour_pairs",
    "specular_brdf",
    "skin_radiance",
]

#: The specular BRDFs of the model and the name of their second parameter.
SPECULAR_MODELS = {"torrance_sparrow": "m", "blinn_phong": "exponent"}


def _boolean_mask(mask) -> np.ndarray:
    """``mask`` as bool: booleans, or integers 0 and 1 (a float mask, NaN included, read as True before)."""
    m = np.asarray(mask)
    if m.dtype == bool:
        return m
    if m.dtype.kind in "iu" and (m.size == 0 or (m.min() >= 0 and m.max() <= 1)):
        return m.astype(bool)
    raise ValidationError(f"mask must hold booleans (or 0 and 1), got dtype {m.dtype}")


def modulation_texture(albedo, mask=None):
    """Modulation texture M(xo) = α(xo) / α_avg, Weyrich et al. 2006 eq. 7.

    R_d(r) M(xo) = R(r) α(xo)/α_avg: the homogeneous dipole R(r), whose parameters
    are derived from the average albedo (§5.4), is modulated at the exit point so
    that the local diffuse reflectance equals the albedo map.

    Parameters
    ----------
    albedo : array_like, shape (..., 3)
        Albedo map α (total diffuse reflectance per channel), ≥ 0.
    mask : array_like of bool, optional
        Texels that belong to the face (shape of ``albedo`` without the channel
        axis); α_avg is the mean over them.  Default: all texels.

    Returns
    -------
    modulation : ndarray, shape of ``albedo``
        M, 0 outside the mask.
    albedo_avg : ndarray, shape (3,)
        α_avg per channel.
    """
    a = as_finite(albedo, "albedo")
    check_shape(a, "albedo", (..., 3))
    check_range(a, "albedo", 0, 1)
    m = np.ones(a.shape[:-1], bool) if mask is None else _boolean_mask(mask)
    if m.shape != a.shape[:-1]:
        raise ValidationError(f"mask must have shape {a.shape[:-1]}, got {m.shape}")
    if not m.any():
        raise ValidationError("mask must select at least one texel, got an empty mask")
    avg = a[m].mean(axis=0)
    if np.any(avg <= 0):
        raise ValidationError(f"albedo must have a positive mean per channel, got {avg.tolist()}")
    out = np.where(m[..., None], a / avg, 0).astype(a.dtype, copy=False)
    return out, avg.astype(a.dtype)


def _dot(a, b):
    """Dot products over the last axis."""
    return np.sum(a * b, axis=-1)


def _points(value, name, n=None):
    """Validate finite 3-D points or vectors, shape (N, 3) (N = ``n`` when given)."""
    return check_shape(as_finite(value, name), name, (n, 3))


def _squared_distances(d, name, hint=""):
    """|d|² over the last axis, refused where it overflows (the direction d/|d| would come out 0)."""
    with np.errstate(over="ignore", invalid="ignore"):
        dist2 = _dot(d, d)
    if not np.all(np.isfinite(dist2)):
        raise ValidationError(
            f"{name} must lie within about 1e154 mm of the surface positions (squared distances overflow beyond){hint}"
        )
    return dist2


def point_lights(positions, normals, light_positions, intensity):
    """Directions and irradiance from isotropic point lights (inverse-square law).

    E = I cos θi / d², with d the distance to the light, I its radiant intensity
    (per channel) and cos θi = max(N·ωi, 0).  Visibility (shadowing) is the
    caller's: multiply E by it.

    Parameters
    ----------
    positions, normals : array_like, shape (N, 3)
        Surface points (mm) and unit normals.
    light_positions : array_like, shape (L, 3)
        Light positions (mm).
    intensity : array_like, shape (L,) or (L, 3)
        Radiant intensity per light (and channel), ≥ 0, in W sr⁻¹.

    Returns
    -------
    wi : ndarray, shape (N, L, 3)
        Unit directions towards the lights.
    irradiance : ndarray, shape (N, L, 3)
        E in W mm⁻².
    """
    p = _points(positions, "positions")
    n = _points(_brdf.check_directions(normals, "normals"), "normals", p.shape[0])  # unit: E scales with |N|
    lp = _points(light_positions, "light_positions")
    i = as_finite(intensity, "intensity", 0, None)
    if i.ndim == 1:
        i = np.repeat(i[:, None], 3, axis=1)
    check_shape(i, "intensity", (lp.shape[0], 3))
    d = lp[None, :, :] - p[:, None, :]
    dist2 = _squared_distances(d, "light_positions", "; light from that far is directional: use directional_lights")
    if np.any(dist2 <= 0):
        raise ValidationError("light_positions must not coincide with surface positions, got distance 0")
    wi = d / np.sqrt(dist2)[..., None]
    cos_i = np.maximum(_dot(n[:, None, :], wi), 0)
    return wi, (cos_i / dist2)[..., None] * i[None, :, :]


def directional_lights(normals, directions, irradiance):
    """Directions and irradiance from distant (directional) lights.

    E = E⊥ max(N·ωi, 0), with E⊥ the irradiance on a plane facing the light.

    Parameters
    ----------
    normals : array_like, shape (N, 3)
        Unit normals.
    directions : array_like, shape (L, 3)
        Unit directions *towards* the lights.
    irradiance : array_like, shape (L,) or (L, 3)
        E⊥ per light (and channel), ≥ 0.

    Returns
    -------
    wi : ndarray, shape (N, L, 3)
    irradiance : ndarray, shape (N, L, 3)
    """
    n = _points(_brdf.check_directions(normals, "normals"), "normals")  # unit: E scales with |N|
    w = _brdf.check_directions(directions, "directions")
    check_shape(w, "directions", (None, 3))
    e = as_finite(irradiance, "irradiance", 0, None)
    if e.ndim == 1:
        e = np.repeat(e[:, None], 3, axis=1)
    check_shape(e, "irradiance", (w.shape[0], 3))
    wi = np.broadcast_to(w[None, :, :], (n.shape[0],) + w.shape)
    cos_i = np.maximum(n @ w.T, 0)
    return wi, cos_i[..., None] * e[None, :, :]


def view_directions(positions, camera_positions):
    """Unit directions from surface points towards camera centres, shape (N, C, 3).

    Parameters
    ----------
    positions : array_like, shape (N, 3)
        Surface points, mm.
    camera_positions : array_like, shape (C, 3)
        Camera centres, mm.

    Returns
    -------
    ndarray, shape (N, C, 3)
        Unit vectors ωo from each point towards each camera.

    Raises
    ------
    ValidationError
        Non-finite or wrongly shaped points, a camera at a surface point (distance 0), or one so far away
        (about 1e154 mm) that the squared distance overflows.
    """
    p = _points(positions, "positions")
    c = _points(camera_positions, "camera_positions")
    d = c[None, :, :] - p[:, None, :]
    dist = np.sqrt(_squared_distances(d, "camera_positions"))
    if np.any(dist <= 0):
        raise ValidationError("camera_positions must not coincide with surface positions, got distance 0")
    return d / dist[..., None]


def neighbour_pairs(positions, radius):
    """All ordered pairs of distinct points at most ``radius`` apart (distance ≤ radius): ``(rows, cols, distance)``.

    Parameters
    ----------
    positions : array_like, shape (N, 3)
        Points in mm.
    radius : float
        Search radius in mm, > 0.

    Returns
    -------
    rows, cols : ndarray of int
        Indices of each pair (both orders of every pair).
    distance : ndarray
        Euclidean distance of each pair, mm.
    """
    from scipy.spatial import cKDTree

    p = _points(positions, "positions").astype(np.float64, copy=False)
    radius = as_scalar(radius, "radius", 0, None, low_inclusive=False, unit="mm")
    pairs = cKDTree(p).query_pairs(radius, output_type="ndarray")
    rows = np.concatenate([pairs[:, 0], pairs[:, 1]])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0]])
    return rows, cols, np.linalg.norm(p[rows] - p[cols], axis=1)


@dataclass
class SubsurfaceTransport:
    """The homogeneous dipole transport ∫_A R_d(‖xo − xi‖) Φ(xi) dA(xi) of eq. 6, per channel.

    Two modes:

    * **local** (``positions=None``): the flat-patch limit, B(xo) = R_total Φ(xo),
      exact where the entering flux Φ is locally constant (the diffuse BRDF
      approximation of Jensen et al. 2001 used by Weyrich eq. 16).
    * **surface** (``positions`` and ``areas`` given): a sparse quadrature over the
      surface samples.  Each sample keeps the exact energy of its own footprint
      (a disk of its area, :func:`facestats.model.dipole.dipole_radial_energy`);
      neighbours within ``radius`` receive R_d(r)·A_i, rescaled per output sample
      so that the ring between footprint and radius carries exactly its analytic
      energy; the tail beyond ``radius`` is returned locally.  Hence Σ_i w_oi equals
      the total diffuse reflectance and a flat, uniformly lit patch conserves energy
      exactly whatever the sampling.

    Parameters
    ----------
    sigma_s_prime, sigma_a : array_like, shape (3,)
        Homogeneous reduced scattering and absorption coefficients (mm⁻¹).
    eta : float
        Relative index of refraction, default 1.38.
    positions : array_like, shape (N, 3), optional
        Surface sample positions in mm.
    areas : array_like, shape (N,), optional
        Surface area each sample represents, mm².
    radius : float, optional
        Neighbourhood radius in mm.  Default: where the dipole has delivered all but
        ``tail`` of its energy in the most translucent channel, capped so that a
        sample has about ``max_neighbors`` neighbours.
    tail : float
        Energy fraction left to the local tail when choosing the default radius.
    max_neighbors : int
        Cap on the neighbourhood size that bounds cost at high resolution.  The cap can
        keep much of the light local: at 0.25 mm spacing it makes the radius 1.60 mm,
        and skin of Weyrich's σtrAvg with albedo 0.45 / 0.30 / 0.20 carries 29 / 15 / 6 %
        (R / G / B) of its diffuse energy beyond that, which returns at the entry point
        (energy is conserved, the spread of red light is not).  Raise it, or give
        ``radius``, where the spread matters more than the cost.
    neighbours : tuple of ndarray, optional
        Precomputed ``(rows, cols, distance)`` of :func:`neighbour_pairs` for these
        positions and ``radius``, to reuse the search across many subjects.
    """

    sigma_s_prime: np.ndarray
    sigma_a: np.ndarray
    eta: float = ETA_SKIN
    positions: np.ndarray | None = None
    areas: np.ndarray | None = None
    radius: float | None = None
    tail: float = 1e-3
    max_neighbors: int = 128
    neighbours: tuple | None = None
    _weights: list = field(default=None, init=False, repr=False)

    def __post_init__(self):
        s, a = dipole_coefficients(self.sigma_s_prime, self.sigma_a)
        for name, v in (("sigma_s_prime", s), ("sigma_a", a)):
            if v.shape not in ((), (3,)):
                raise ValidationError(f"{name} must be one value or one per channel, shape (3,), got shape {v.shape}")
        s = np.broadcast_to(s, (3,)).astype(np.float64)
        a = np.broadcast_to(a, (3,)).astype(np.float64)
        self.sigma_s_prime, self.sigma_a = s, a
        self.eta = as_scalar(self.eta, "eta", 1.0, 3.0)  # check_dipole_eta of one number
        alpha = reduced_albedo_unchecked(s, a)
        self.total_reflectance = total_from_reduced_albedo_unchecked(alpha, self.eta)
        if self.positions is None:
            return
        p = check_shape(as_finite(self.positions, "positions", dtype=np.float64), "positions", (None, 3))
        ar = as_finite(self.areas, "areas", dtype=np.float64)
        check_shape(ar, "areas", (p.shape[0],))
        check_range(ar, "areas", 0, None, low_inclusive=False, unit="mm^2")
        if self.radius is None:  # the settings of the default radius
            as_finite(self.tail, "tail", 0, 1, low_inclusive=False, high_inclusive=False)
            check_integer(self.max_neighbors, "max_neighbors", 1)
        self.positions, self.areas = p, ar
        self._build()

    # -- construction -------------------------------------------------------------
    def _default_radius(self):
        """The neighbourhood radius (mm) when none is given (class docstring).

        The radius where the most translucent channel (least σtr, Weyrich eq. 15) of those that
        reflect light (σ's > 0) has delivered 1 − ``tail`` of its total diffuse reflectance (eq. 16), by the closed-form
        radial energy of the dipole (:func:`facestats.model.dipole.dipole_radial_energy`),
        capped at the radius of a disk holding about ``max_neighbors`` samples of the
        median spacing √(median area), and at least that spacing.  With no channel reflecting, the
        spacing (the transport is then zero whatever the radius).
        """
        from scipy.optimize import brentq

        spacing = np.sqrt(np.median(self.areas))
        r_cap = spacing * np.sqrt(self.max_neighbors / np.pi)
        reflects = self.total_reflectance > 0  # a channel with σ's = 0 spreads no light: its radius would be 0
        if not reflects.any():
            return float(spacing)
        sigma_tr = np.where(reflects, transport_coefficient(self.sigma_a, self.sigma_s_prime), np.inf)
        c = int(np.argmin(sigma_tr))  # most translucent channel that reflects
        args = (self.sigma_s_prime[c], self.sigma_a[c], self.eta)
        target = (1 - self.tail) * self.total_reflectance[c]
        r_energy = brentq(lambda r: dipole_radial_energy_unchecked(r, *args) - target, 0.0, 1e4)
        return float(min(r_energy, max(r_cap, spacing)))

    def _build(self):
        """The three per-channel sparse quadratures of eq. 6 (Weyrich et al. 2006; class docstring).

        For output sample o and neighbour i at distance r (mm) the weight is the mean of the dipole
        R_d (Jensen et al. 2001; Suzuki eq. 3-13) over the annulus r ± w/2 (w = √A_i, mm), from the
        closed-form radial energy E(ρ) = 2π∫₀^ρ r R_d dr, times A_i (mm²):
        w_oi = [E(r_out) − E(r_in)] / (π (r_out² − r_in²)) · A_i, dimensionless.  Each row is then
        rescaled so that its neighbours carry exactly E(radius) − E(foot), the ring between the
        sample's footprint disk (radius √(A_o/π)) and ``radius``; the diagonal holds E(foot), the
        tail R_total − E(radius) (eq. 16) and, for a sample with no neighbour, the ring's energy too.
        So every row sums to the total diffuse reflectance: a uniformly lit flat patch conserves
        energy whatever the sampling (tested).
        """
        from scipy import sparse

        n = self.positions.shape[0]
        radius = self._default_radius() if self.radius is None else float(self.radius)
        check_range(np.asarray(radius), "radius", 0, None, low_inclusive=False, unit="mm")
        self.radius = radius
        if self.neighbours is None:
            rows, cols, dist = neighbour_pairs(self.positions, radius)
        else:
            rows, cols, dist = self.neighbours
        foot = np.minimum(np.sqrt(self.areas / np.pi), radius)  # footprint disk radius
        weights = []
        for c in range(3):  # loop over the three channels, not over samples
            args = (self.sigma_s_prime[c], self.sigma_a[c], self.eta)
            e_foot = dipole_radial_energy_unchecked(foot, *args)
            e_ring = dipole_radial_energy_unchecked(radius, *args) - e_foot  # analytic energy of the ring
            # Mean of R_d over the annulus of one sample width around r (exact for
            # the radial energy), times the neighbour's area.
            width = np.sqrt(self.areas[cols])
            r_in = np.maximum(dist - width / 2, foot[rows])
            r_out = np.maximum(dist + width / 2, r_in + 1e-12)
            ring = dipole_radial_energy_unchecked(r_out, *args) - dipole_radial_energy_unchecked(r_in, *args)
            w = ring / (np.pi * (r_out * r_out - r_in * r_in)) * self.areas[cols]
            raw = np.bincount(rows, weights=w, minlength=n)
            with np.errstate(invalid="ignore", divide="ignore"):
                scale = np.where(raw > 0, e_ring / raw, 0)
            w = w * scale[rows]
            # Footprint energy, plus the ring's energy where a sample has no
            # neighbour, plus the tail beyond the radius, stay at the sample itself.
            self_w = (
                e_foot
                + np.where(raw > 0, 0, e_ring)
                + (self.total_reflectance[c] - dipole_radial_energy_unchecked(radius, *args))
            )
            m = sparse.csr_matrix((w, (rows, cols)), shape=(n, n)) + sparse.diags(self_w)
            weights.append(m.tocsr())
        self._weights = weights

    # -- application ----------------------------------------------------------------
    @property
    def n_points(self):
        """Number of surface samples (None in local mode)."""
        return None if self.positions is None else self.positions.shape[0]

    def apply(self, flux):
        """Exitance B(xo) = ∫ R_d(‖xo − xi‖) Φ(xi) dA(xi) for entering flux density Φ.

        Parameters
        ----------
        flux : array_like, shape (N, ..., 3)
            Flux density entering the skin (F_t(ωi)·E) per channel, W mm⁻².

        Returns
        -------
        ndarray, shape of ``flux``
            Exitance per channel before modulation and exit Fresnel, W mm⁻² (float32 for float32 flux, else
            float64: integer flux is not truncated).
        """
        f = as_float(flux, "flux")
        ok = np.isfinite(f) & (f >= 0)
        if not ok.all():
            bad = f[~ok]
            raise ValidationError(
                f"flux must be finite and >= 0 (a flux density entering the skin), got {bad.size} value(s) that are "
                f"not, e.g. {bad.flat[0]!r}"
            )
        if f.shape[-1] != 3:
            raise ValidationError(f"flux must have 3 channels on the last axis, got shape {f.shape}")
        if self.positions is None:
            return f * self.total_reflectance.astype(f.dtype)
        if f.shape[0] != self.n_points:
            raise ValidationError(f"flux must have {self.n_points} points on axis 0, got shape {f.shape}")
        out = np.empty_like(f)
        flat = f.reshape(f.shape[0], -1, 3)
        out_flat = out.reshape(flat.shape)
        for c in range(3):  # three sparse products, one per channel
            out_flat[:, :, c] = self._weights[c] @ flat[:, :, c]
        return out


def specular_brdf(model, normal, wi, wo, rho_s, roughness, eta=ETA_SKIN):
    """Evaluate the named specular BRDF: ``"torrance_sparrow"`` (roughness m) or ``"blinn_phong"`` (exponent).

    Parameters
    ----------
    model : str
        A key of :data:`SPECULAR_MODELS`: ``"torrance_sparrow"`` (Weyrich et al. 2006 eq. 12-13) or
        ``"blinn_phong"`` (eq. 11).
    normal, wi, wo : array_like, shape (..., 3)
        Unit vectors pointing away from the surface.
    rho_s : array_like
        Specular scaling coefficient ρs ≥ 0.
    roughness : array_like
        Beckmann roughness m > 0 (Torrance-Sparrow) or specular exponent n ≥ 0 (Blinn-Phong).
    eta : float or array_like, optional
        Relative index of refraction, default 1.38; used by Torrance-Sparrow only (ignored by Blinn-Phong).

    Returns
    -------
    ndarray
        BRDF in sr⁻¹, broadcast shape of the inputs without the vector axis.

    Raises
    ------
    ValidationError
        An unknown ``model``, or the errors of :func:`facestats.model.brdf.torrance_sparrow` /
        :func:`facestats.model.brdf.blinn_phong`.
    """
    check_choice(model, "specular", SPECULAR_MODELS)
    if model == "torrance_sparrow":
        return _brdf.torrance_sparrow(normal, wi, wo, rho_s, roughness, eta)
    return _brdf.blinn_phong(normal, wi, wo, rho_s, roughness)


def _per_point(value, name, npts):
    """A scalar or one value per point, as a read-only (N,) view (values are checked by the BRDF)."""
    a = as_float(value, name)
    if a.ndim > 1 or a.size not in (1, npts):
        raise ValidationError(f"{name} must be a scalar or have shape ({npts},), got shape {a.shape}")
    return np.broadcast_to(a, (npts,))


def skin_radiance(
    normal,
    wi,
    irradiance,
    wo,
    *,
    rho_s,
    roughness,
    modulation,
    subsurface: SubsurfaceTransport,
    specular: str = "torrance_sparrow",
    eta: float = ETA_SKIN,
    components: bool = False,
):
    """Outgoing radiance of the skin model, Weyrich et al. 2006 eq. 6 (with eq. 5's 1/π).

    For N surface points, L lights and C cameras:

    L[n, c, l] = f_s(N_n, ωi[n, l], ωo[n, c]) E[n, l]
               + M[n] F_t(ωo[n, c])/π · B_l[n],   B_l = ∫ R_d Φ_l dA,  Φ_l = F_t(ωi) E_l

    The specular highlight is the colour of the light (E per channel times a grey
    BRDF, §5.3).  F_t uses the unpolarised Fresnel equations at relative index η.

    Parameters
    ----------
    normal : array_like, shape (N, 3)
        Unit surface normals (the specular normal; micro-normals if available).
    wi : array_like, shape (N, L, 3)
        Unit directions towards each light.
    irradiance : array_like, shape (N, L, 3)
        Irradiance E (with N·ωi and visibility) per light and channel, ≥ 0.
    wo : array_like, shape (N, C, 3)
        Unit directions towards each camera.
    rho_s, roughness : array_like, shape (N,)
        Specular parameters: (ρs, m) for Torrance-Sparrow, (ρs, n) for Blinn-Phong.
    modulation : array_like, shape (N, 3)
        Modulation texture M (:func:`modulation_texture`).
    subsurface : SubsurfaceTransport
        The dipole transport (local or over these N points).
    specular : {"torrance_sparrow", "blinn_phong"}
    eta : float
        Relative index of refraction for the Fresnel terms, default 1.38.
    components : bool
        If True return ``(specular, diffuse)`` separately.

    Returns
    -------
    radiance : ndarray, shape (N, C, L, 3)
        Outgoing radiance in W mm⁻² sr⁻¹ (irradiance unit per sr).
    """
    check_choice(specular, "specular", SPECULAR_MODELS)
    n = _brdf.check_directions(normal, "normal")
    check_shape(n, "normal", (None, 3))
    npts = n.shape[0]
    wi = check_shape(_brdf.check_directions(wi, "wi"), "wi", (npts, None, 3))
    wo = check_shape(_brdf.check_directions(wo, "wo"), "wo", (npts, None, 3))
    e = as_finite(irradiance, "irradiance", 0, None)
    check_shape(e, "irradiance", (npts, wi.shape[1], 3))
    mod = as_finite(modulation, "modulation", 0, None)
    check_shape(mod, "modulation", (npts, 3))
    rho = _per_point(rho_s, "rho_s", npts)
    rough = _per_point(roughness, "roughness", npts)
    eta = check_eta(eta, scalar=True)  # the diffuse transmittances read it too, whatever the specular model
    dtype = result_dtype(n, wi, wo, e, mod)

    # Specular: grey BRDF for every (point, camera, light), times the light's colour.
    f_s = specular_brdf(
        specular,
        n[:, None, None, :],
        wi[:, None, :, :],
        wo[:, :, None, :],
        rho[:, None, None],
        rough[:, None, None],
        eta,
    ).astype(dtype, copy=False)
    spec = f_s[..., None] * e[:, None, :, :]

    # Diffuse: entering flux, transport, then modulation and exit transmittance.
    cos_i = np.clip(np.einsum("nk,nlk->nl", n, wi), 0, 1)
    cos_o = np.clip(np.einsum("nk,nck->nc", n, wo), 0, 1)
    t_i = 1 - fresnel_reflectance_unchecked(cos_i.astype(dtype), dtype.type(eta))
    t_o = np.where(cos_o > 0, 1 - fresnel_reflectance_unchecked(cos_o.astype(dtype), dtype.type(eta)), 0)
    exitance = subsurface.apply((t_i[..., None] * e).astype(dtype, copy=False))  # (N, L, 3)
    diff = (mod[:, None, None, :] * (t_o / np.pi)[:, :, None, None]) * exitance[:, None, :, :]
    diff = diff.astype(dtype, copy=False)
    if components:
        return spec.astype(dtype, copy=False), diff
    return (spec + diff).astype(dtype, copy=False)
