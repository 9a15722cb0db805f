"""Stage 1 of the fit: normals by photometric stereo and per-camera micro-normals (Weyrich et al. 2006 §5.1).

Photometric stereo (Barsky & Petrou 2001, as cited in §5.1): under the diffuse
part of the skin model a lumitexel seen by camera c under light l reflects

    y_cl = L_cl / E⊥_l = (Σ_ch α_ch F_t(θo,c)/π) · F_t(θi,l) · (N·ωi,l)

(summed over the three channels, §5.2 eq. 9-10 without the specular term), which
is linear in g = k N once F_t(θi) is divided out.  For every camera the
least-squares g over its lights gives a normal N_c = g/‖g‖; the diffuse normal
is the average of the N_c weighted by the cosine between each camera and its
normal (§5.1 "blending weights").  Samples near the mirror direction of the
scanned normal (half-vector within ``specular_exclusion`` of it) and beyond
``max_angle`` are left out so the specular lobe does not bias the estimate, and
the F_t(θi) factor is divided out with the current normal estimate and the solve
repeated (``iterations``).

Micro-normals (§5.1): "For each camera viewpoint, we choose the sample with
maximum value in each lumitexel.  The half-way vector between the view direction
and the sample's light source direction is the micro-normal for this view."
"""

from __future__ import annotations

import numpy as np

from ..fresnel import _fresnel_reflectance

__all__ = ["photometric_normals", "micro_normals"]


def _unit(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / n


def _grey_brdf_cos(samples):
    """y = Σ_ch L / Σ_ch E⊥ per sample (grey f_r cos θi)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return samples.radiance.sum(1) / samples.irradiance.sum(1)


def photometric_normals(samples, scan_normal, n_cameras, *, eta=1.38, specular_exclusion=np.radians(35.0),
                        max_angle=np.radians(75.0), iterations=3, min_lights=6):
    """Diffuse normals of lumitexels by per-camera photometric stereo (module docstring).

    Parameters
    ----------
    samples : facestats.model.fitting.Samples
        Valid samples with camera indices.
    scan_normal : ndarray, shape (n, 3)
        Scanned normals, used only to exclude specular and grazing samples.
    n_cameras : int
    eta : float
        Relative index of refraction for F_t.
    specular_exclusion : float
        Samples whose half vector lies within this angle (rad) of the scan normal are ignored.
    max_angle : float
        Samples with θi or θo beyond this angle (rad) are ignored.
    iterations : int
        Number of solves (the first without, later ones with the F_t(θi) correction
        of the previous normal; three bring the noise-free error from 1.1° to 0.08°).
    min_lights : int
        Cameras with fewer usable lights get no vote.

    Returns
    -------
    normal : ndarray, shape (n, 3)
        Unit diffuse normals (the scanned normal where no camera could vote).
    camera_normal : ndarray, shape (n, C, 3)
        Per-camera normals (NaN where a camera had too few lights).
    """
    n_scan = np.asarray(scan_normal, np.float32)
    n, n_key = samples.n_texels, samples.n_texels * int(n_cameras)
    y = _grey_brdf_cos(samples)
    ci, co = samples.cos(n_scan)
    io = np.einsum("sk,sk->s", samples.wi, samples.wo)
    cos_h = (ci + co) / np.sqrt(np.maximum(2 + 2 * io, 1e-12))  # N·H with ‖ωi + ωo‖² = 2 + 2 ωi·ωo
    lim = np.cos(max_angle)
    use = (cos_h < np.cos(specular_exclusion)) & (ci > lim) & (co > lim) & np.isfinite(y) & (y > 0)
    key = samples.texel.astype(np.int64)[use] * n_cameras + samples.camera[use]
    wi = samples.wi[use].astype(np.float64)
    wo = samples.wo[use].astype(np.float64)
    yu = y[use].astype(np.float64)
    texel_u = samples.texel[use]
    count = np.bincount(key, minlength=n_key)
    # Σ ωi ωiᵀ per (lumitexel, camera): six distinct entries of the symmetric matrix.
    pairs = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    a = np.zeros((n_key, 3, 3))
    for i, j in pairs:  # six bincounts, each vectorised over samples
        a[:, i, j] = a[:, j, i] = np.bincount(key, weights=wi[:, i] * wi[:, j], minlength=n_key)
    cam_dir = np.stack([np.bincount(key, weights=wo[:, k], minlength=n_key) for k in range(3)], 1)
    cam_dir = _unit(cam_dir).reshape(n, n_cameras, 3)
    ok = count >= min_lights
    det = np.linalg.det(a)
    ok &= det > 1e-6 * np.maximum(count, 1.0) ** 3
    a_safe = np.where(ok[:, None, None], a, np.eye(3))
    normal = n_scan.astype(np.float64)
    cam_n = None
    e32 = np.float32(eta)
    for it in range(int(iterations)):  # refinement passes
        if it > 0:  # divide out F_t(θi) with the current normal
            c = np.clip(np.einsum("sk,sk->s", normal[texel_u], wi), 0, 1).astype(np.float32)
            ft = 1 - _fresnel_reflectance(c, e32)
            yy = yu / np.where(ft > 0, ft, 1)
        else:
            yy = yu
        b = np.stack([np.bincount(key, weights=yy * wi[:, k], minlength=n_key) for k in range(3)], 1)
        g = np.linalg.solve(a_safe, b[..., None])[..., 0]
        cam_n = np.where(ok[:, None], _unit(g), np.nan).reshape(n, n_cameras, 3)
        weight = np.where(ok.reshape(n, n_cameras), np.clip(np.einsum("nck,nck->nc", np.nan_to_num(cam_n), np.nan_to_num(cam_dir)), 0, None), 0)
        acc = np.einsum("nc,nck->nk", weight, np.nan_to_num(cam_n))
        have = weight.sum(-1) > 0
        normal = np.where(have[:, None], _unit(acc), n_scan)
    return normal.astype(np.float32), cam_n.astype(np.float32)


def micro_normals(samples, n_cameras):
    """Per-camera micro-normals: the half vector of each view's brightest sample (§5.1).

    "Brightest" is the largest grey BRDF-like value L/E⊥ among the camera's valid
    samples.

    Returns
    -------
    ndarray, shape (n, C, 3)
        Unit half vectors; NaN where a camera has no valid sample.
    """
    n = samples.n_texels
    y = np.nan_to_num(_grey_brdf_cos(samples), nan=-np.inf)
    key = samples.texel.astype(np.int64) * n_cameras + samples.camera
    if np.any(np.diff(key) < 0):  # not grouped by (lumitexel, camera): sort once
        order = np.argsort(key, kind="stable")
        key, y = key[order], y[order]
    else:
        order = np.arange(key.size)
    starts = np.flatnonzero(np.concatenate([[True], key[1:] != key[:-1]]))
    peak = np.maximum.reduceat(y, starts)
    seg = np.cumsum(np.concatenate([[False], key[1:] != key[:-1]]))  # run index of each sample
    hit = np.flatnonzero(y == peak[seg])
    first = np.concatenate([[True], seg[hit][1:] != seg[hit][:-1]])
    best = order[hit[first]]
    key = samples.texel.astype(np.int64)[best] * n_cameras + samples.camera[best]
    out = np.full((n * n_cameras, 3), np.nan, np.float32)
    out[key] = _unit(samples.wi[best] + samples.wo[best])
    return out.reshape(n, n_cameras, 3)
