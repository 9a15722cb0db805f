"""Small reflectance fields with known truth for the relighting tests (analytic, no rendering)."""

import numpy as np

from facestats.model.brdf import torrance_sparrow
from facestats.model.sphere import light_stage_directions
from facestats.relight.field import make_field
from facestats.relight.separate import WHITE, ramp_chromaticity, ramp_factor, unit_rgb


def sphere_normals(h, w):
    """Unit normals of a hemisphere seen from +z, (h, w, 3), with a mask of the disc."""
    y, x = np.mgrid[0:h, 0:w]
    u = (x + 0.5) / w * 2 - 1
    v = 1 - (y + 0.5) / h * 2
    r2 = u * u + v * v
    inside = r2 < 0.95
    z = np.sqrt(np.clip(1 - r2, 0, 1))
    n = np.stack([u, v, z], -1)
    n = np.where(inside[..., None], n, [0, 0, 1])
    return n / np.linalg.norm(n, axis=-1, keepdims=True), inside


def lambertian_field(h=6, w=6, albedo=(0.6, 0.4, 0.3), n_theta=64, n_phi=32):
    """R = ρ/π max(N·l, 0) on a lat-long light stage for the normals of :func:`sphere_normals`."""
    d, _ = light_stage_directions(n_theta, n_phi)
    n, inside = sphere_normals(h, w)
    cos = np.clip(np.einsum("abk,yxk->abyx", d, n), 0, None)
    vals = cos[..., None] * np.asarray(albedo)[None, None, None, None, :] / np.pi
    view = np.broadcast_to([0.0, 0.0, 1.0], (h, w, 3))
    return make_field(vals, d, mask=inside, view=view, normal=n), n, inside


def ts_lambert_field(h=6, w=6, albedo=(0.5, 0.3, 0.2), rho_s=0.3, m=0.35, n_theta=64, n_phi=32, view=(0, 0, 1),
                     ramp=None, noise=0.0, seed=0):  # fmt: skip
    """Lambertian diffuse of colour ``albedo`` plus a white Torrance-Sparrow lobe, per unit L·δA.

    ``ramp`` = (α₀, α₁): the diffuse colour follows Debevec et al. 2000 eq. 6-7 with d₀ the albedo's colour
    (each sample keeps the Lambertian diffuse's RGB length).  ``noise``: relative Gaussian noise of that
    standard deviation on every sample and channel (seeded by ``seed``), clipped at 0; the returned
    specular and diffuse parts are the noise-free truth.
    """
    d, _ = light_stage_directions(n_theta, n_phi)
    n, inside = sphere_normals(h, w)
    v = np.broadcast_to(np.asarray(view, float) / np.linalg.norm(view), (h, w, 3))
    cos = np.clip(np.einsum("abk,yxk->abyx", d, n), 0, None)
    spec = torrance_sparrow(n[None, None], d[:, :, None, None], v[None, None], rho_s, m) * cos
    diff = cos[..., None] * np.asarray(albedo) / np.pi
    if ramp is not None:
        f = ramp_factor(cos, np.einsum("yxk,yxk->yx", n, v).clip(0, 1), *ramp)
        colour = ramp_chromaticity(np.broadcast_to(unit_rgb(albedo), f.shape + (3,)), WHITE, f)
        diff = np.linalg.norm(diff, axis=-1, keepdims=True) * colour
    vals = diff + spec[..., None] / np.sqrt(3) * np.sqrt(3)  # white light: equal in R, G, B
    if noise:
        vals = np.clip(vals * (1 + noise * np.random.default_rng(seed).standard_normal(vals.shape)), 0, None)
    return make_field(vals, d, mask=inside, view=v, normal=n), spec, diff
