"""Spatial subsurface rendering over surface patches: the forward model l = R c of Suzuki et al. eq. 17-21.

For patches with centres x_k, areas A_k and entering irradiance c_k (eq. 16),
the exitance of patch j is

    l_j = Σ_k R(‖x_j − x_k‖) c_k A_k                                   (eq. 17, with areas)

with R the dipole profile (:func:`facestats.model.dipole.dipole_profile`, mm⁻²,
Suzuki eq. 3-13) evaluated at the patch-centre distances: the point kernel,
not the quantised model.  A patch's own light (``self_term``): by default
eq. 17's R(0) c_j A_j (the paper's); ``"footprint"`` takes c_j E(ρ_j), the
dipole's energy within the disk of its area (ρ_j = sqrt(A_j/π),
:func:`facestats.model.dipole.dipole_radial_energy`), as a continuous surface
gives it.  For 1 mm patches of Suzuki Table 1's medium the point term is about
twice the footprint's (0.451 against 0.216 per unit c): against a quadrature
of the surface (sub-patches of 1/8 the spacing), the lit half of a flat plate of
1 mm patches is 21 % brighter with the point term (42 % at worst) and 4.2 %
darker with the footprint (4.8 % at worst; the rest is the neighbours' point
kernel), the lit face of the pyramid of 1.8 mm patches 27 % brighter and
2.6 % darker.  ``"surface"`` takes the near neighbours (centres within
:data:`facestats.model.disk_quadrature.NEAR_RADII` radii of the source) over
their disks too, by the polar rule of :mod:`facestats.model.disk_quadrature`:
the plate's lit patches are then within 0.2-0.4 % of that quadrature at the
median (0.42 % at worst; :func:`half_lit_plate`, 21-41 patches a side).  The radiance
a camera sees is L_o = F_t,o l / π (eq. 14-15,
:func:`facestats.model.irradiance.radiance_from_exitance`).

Radius cut-off (optional): pairs farther apart than ``radius`` are left out; by
default none is (``radius=numpy.inf``), so the exitance is exact.
:func:`cutoff_radius` gives the radius where the dipole's radial energy
(:func:`facestats.model.dipole.dipole_radial_energy`) reaches all but
``tail`` = 10⁻⁴ of the total diffuse reflectance in the most translucent
channel: the light dropped is then below 10⁻⁴ of the light transported.  That
bound is on the total, not per row: a row near or beyond the radius from the
lit patches loses much or all of its own exitance (the contactless study's
simulator, which used it by default before 2026-12-07, was up to 89 % off in
σtr: ``bench_contactless_methods``).  Images to be fitted by relative residuals
(``method="monotone"`` and ``"exitance"`` weight the rows by 1/l) must not use
it.

Blocked evaluation: rows (exiting patches) in blocks whose distances to all lit
patches fit ``block_bytes``; only pairs within the radius are evaluated
(compressed), and summed per row with ``numpy.bincount``.  No m × m array exists.
"""

from __future__ import annotations

import numpy as np

from facestats.core.validate import as_finite, as_scalar, check_choice, check_integer, check_shape
from facestats.errors import ValidationError
from facestats.model.dipole import (
    check_dipole_eta,
    dipole_coefficients,
    dipole_profile_unchecked,
    dipole_radial_energy_unchecked,
    total_diffuse_reflectance,
)
from facestats.model.disk_quadrature import disk_node_distances, is_near
from facestats.model.fitting.quantised import SELF_TERMS

__all__ = ["cutoff_radius", "render_exitance", "half_lit_plate"]

#: Energy fraction left beyond the default cut-off radius.
DEFAULT_TAIL = 1e-4
_BYTES_PER_PAIR = 40


def cutoff_radius(sigma_s_prime, sigma_a, eta, tail=DEFAULT_TAIL) -> float:
    """Radius (mm) holding all but ``tail`` of the dipole's total diffuse reflectance, in the most translucent channel.

    Solves E(ρ) = (1 − tail) R_total with E the closed-form radial energy
    (:func:`facestats.model.dipole.dipole_radial_energy`) by bracketing.

    Parameters
    ----------
    sigma_s_prime, sigma_a : array_like, scalar or shape (C,)
        Reduced scattering and absorption coefficients in mm⁻¹ per channel (≥ 0, not both 0).
    eta : float
        Relative index of refraction, in [1, 3].
    tail : float
        Energy fraction left beyond the radius, in (0, 1) (default :data:`DEFAULT_TAIL`, 10⁻⁴).

    Returns
    -------
    float
        The largest of the channels' radii, mm.

    Raises
    ------
    ValidationError
        Coefficients, ``eta`` or ``tail`` out of their domains.
    """
    from scipy.optimize import brentq

    s, a = dipole_coefficients(sigma_s_prime, sigma_a)
    s, a = np.broadcast_arrays(np.atleast_1d(s), np.atleast_1d(a))
    t = as_scalar(tail, "tail", 0, 1, low_inclusive=False, high_inclusive=False)
    total = total_diffuse_reflectance(s, a, eta)
    radius = 0.0
    for c in range(s.size):  # loop over channels (≤ 3)
        args = (s.flat[c], a.flat[c], float(eta))
        target = (1 - t) * float(total.flat[c])
        hi = 1.0
        while dipole_radial_energy_unchecked(hi, *args) < target:  # doubling bracket, ~10 steps
            hi *= 2
        radius = max(radius, brentq(lambda r: dipole_radial_energy_unchecked(r, *args) - target, 0.0, hi))
    return float(radius)


def _pair_kernel(d, other, rho, s, a, eta, *, near):
    """R of each pair per channel, shape (C, pairs): at the centre distance d, or with ``near`` over the source's
    disk (radius ρ) for the pairs of two patches (``other``) nearer than NEAR_RADII ρ (module docstring)."""
    kernel = np.stack([dipole_profile_unchecked(d, s[ch], a[ch], eta) for ch in range(s.size)])
    if near:
        pick = np.nonzero(other & is_near(d, rho))[0]
        r, wq = disk_node_distances(d[pick], rho[pick])
        for ch in range(s.size):  # loop over channels (≤ 3)
            kernel[ch, pick] = dipole_profile_unchecked(r, s[ch], a[ch], eta) @ wq
    return kernel


def render_exitance(
    points,
    areas,
    irradiance,
    sigma_s_prime,
    sigma_a,
    *,
    eta=1.3,
    rows=None,
    radius=np.inf,
    self_term="point",
    block_bytes=64 * 2**20,
):
    """Exitance l_j = Σ_k R(d_jk) c_k A_k of every row patch (module docstring), per channel.

    Parameters
    ----------
    points : array_like, shape (m, 3)
        Patch centres, mm.
    areas : array_like, shape (m,)
        Patch areas, mm², > 0.
    irradiance : array_like, shape (m,) or (m, C)
        c_k of eq. 16 per patch (and channel), ≥ 0.
    sigma_s_prime, sigma_a : float or array_like, shape (C,)
        Reduced scattering and absorption coefficients, mm⁻¹ (per channel).
    eta : float
        Relative index of refraction of the dipole (default 1.3, Suzuki §3.2).
    rows : array_like of int, optional
        Patches whose exitance is wanted (default all).
    radius : float, optional
        Cut-off distance in mm (> 0); default ``inf``, none: the exact exitance. :func:`cutoff_radius` gives a
        radius that drops below 10⁻⁴ of the transported light in total, but up to all of a far row's (module
        docstring); before 2026-12-07 it was the default.
    self_term : {"footprint", "point", "surface"}
        A patch's own light: eq. 17's R(0) c_j A_j (default, the paper's) or over the disk of its area; with
        ``"surface"`` the near neighbours' over theirs too (module docstring).
    block_bytes : int
        Memory budget of a row block (≥ 1 MiB).

    Returns
    -------
    ndarray, shape (rows,) or (rows, C)
        l_j in the unit of c (e.g. W mm⁻²).
    """
    p = check_shape(as_finite(points, "points", dtype=np.float64), "points", (None, 3))
    m = p.shape[0]
    ar = check_shape(as_finite(areas, "areas", dtype=np.float64), "areas", (m,))
    if np.any(ar <= 0):
        raise ValidationError(f"areas must be > 0 mm^2, got {ar[ar <= 0][0]!r}")
    c = as_finite(irradiance, "irradiance", 0, None, dtype=np.float64)
    if c.shape[:1] != (m,) or c.ndim > 2:
        raise ValidationError(f"irradiance must have shape ({m},) or ({m}, C), got {c.shape}")
    flat = c.ndim == 1
    c2 = c[:, None] if flat else c
    n_ch = c2.shape[1]
    s, a = dipole_coefficients(sigma_s_prime, sigma_a)
    s = np.broadcast_to(s, (n_ch,)) if s.ndim == 0 or s.size == 1 else check_shape(s, "sigma_s_prime", (n_ch,))
    a = np.broadcast_to(a, (n_ch,)) if a.ndim == 0 or a.size == 1 else check_shape(a, "sigma_a", (n_ch,))
    eta = float(check_dipole_eta(eta))
    try:
        rad = float(radius)
    except (TypeError, ValueError):
        raise ValidationError(f"radius must be a number of mm (> 0, inf for no cut-off), got {radius!r:.60}") from None
    if not rad > 0:  # inf allowed (no cut-off); NaN and ≤ 0 are not
        raise ValidationError(f"radius must be > 0 mm (inf for no cut-off), got {radius!r}")
    check_integer(block_bytes, "block_bytes", 2**20)
    check_choice(self_term, "self_term", SELF_TERMS)
    idx = np.arange(m) if rows is None else np.asarray(rows, np.int64)
    lit = np.nonzero(np.any(c2 > 0, axis=1))[0]
    out = np.zeros((idx.size, n_ch))
    if lit.size == 0:
        return out[:, 0] if flat else out
    centre = p.mean(0)
    q = p[lit] - centre
    ca = c2[lit] * ar[lit, None]
    sq = np.einsum("ij,ij->i", q, q)
    rho = np.sqrt(ar / np.pi)  # the patches' disk radii, mm
    block = max(1, int(block_bytes) // (_BYTES_PER_PAIR * lit.size))
    for start in range(0, idx.size, block):  # loop over row blocks, vectorised over their pairs
        rows = idx[start : start + block]
        rp = p[rows] - centre
        d2 = np.maximum(np.einsum("ij,ij->i", rp, rp)[:, None] + sq[None, :] - 2 * rp @ q.T, 0)
        jj, kk = np.nonzero(d2 < rad * rad)
        d = np.sqrt(d2[jj, kk])
        kernel = _pair_kernel(d, rows[jj] != lit[kk], rho[lit[kk]], s, a, eta, near=self_term == "surface")
        for ch in range(n_ch):  # loop over channels (≤ 3)
            out[start : start + rows.size, ch] = np.bincount(jj, weights=kernel[ch] * ca[kk, ch], minlength=rows.size)
    if self_term != "point":  # each row's own pair (d = 0, always within the radius): its disk instead
        for ch in range(n_ch):  # loop over channels (≤ 3)
            zero = dipole_profile_unchecked(np.zeros(1), s[ch], a[ch], eta)[0]
            own = dipole_radial_energy_unchecked(rho[idx], s[ch], a[ch], eta) - zero * ar[idx]
            out[:, ch] += c2[idx, ch] * own
    return out[:, 0] if flat else out


def half_lit_plate(sigma_s_prime, sigma_a, *, n=41, sub=4, eta=1.3):
    """A flat plate of n × n patches of 1 mm lit over x < 0, and its exitance by a quadrature of the surface.

    The reference of a continuous surface for the self terms (module docstring): the patches' centres lie on the
    integer grid of z = 0 (centre patch at the origin for odd n), irradiance c = 1 on the patches with x < 0 and 0
    elsewhere, so the light enters over x < −½ mm.  The exitance at each centre is the point kernel summed over
    sub-patches of 1/``sub`` mm (none at a centre, no cut-off): for Suzuki Table 1's medium it changes by 0.3 %
    from ``sub`` = 4 to 12 and by 0.05 % from 8 to 12.

    Parameters
    ----------
    sigma_s_prime, sigma_a : float
        The medium, mm⁻¹.
    n : int
        Patches per side (≥ 2).
    sub : int
        Sub-patches per patch edge of the quadrature (≥ 2, even, so that no sub-patch centre is a patch centre).
    eta : float
        Relative index of refraction.

    Returns
    -------
    centres : ndarray, shape (n², 3)
        mm.
    areas : ndarray, shape (n²,)
        1 mm² each.
    irradiance : ndarray, shape (n²,)
        c of eq. 16 per patch.
    exitance : ndarray, shape (n²,)
        l at the centres, in the unit of c.
    """
    n = check_integer(n, "n", 2)
    sub = check_integer(sub, "sub", 2)
    if sub % 2:
        raise ValidationError(f"sub must be even (no sub-patch centre on a patch centre), got {sub}")
    g = np.arange(n) - n // 2
    centres = np.c_[np.stack(np.meshgrid(g, g), -1).reshape(-1, 2), np.zeros(n * n)].astype(np.float64)
    f = (np.arange(n * sub) - (n * sub - 1) / 2) / sub + (g[0] + g[-1]) / 2  # sub-patch centres, mm
    fine = np.c_[np.stack(np.meshgrid(f, f), -1).reshape(-1, 2), np.zeros(f.size**2)]
    light = np.r_[(fine[:, 0] < -0.5).astype(np.float64), np.zeros(n * n)]
    areas = np.r_[np.full(len(fine), 1.0 / sub**2), np.ones(n * n)]
    rows = np.arange(len(fine), len(fine) + n * n)
    exitance = render_exitance(
        np.r_[fine, centres], areas, light, sigma_s_prime, sigma_a, eta=eta, radius=np.inf, rows=rows
    )
    return centres, np.ones(n * n), (centres[:, 0] < 0).astype(np.float64), exitance
