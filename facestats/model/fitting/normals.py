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
repeated: ``iterations`` = 3 passes by default (the first without the F_t(θi)
correction).

Micro-normals (§5.1): "For each camera viewpoint, we choose the sample with
maximum value in each lumitexel.  The half-way vector between the view direction
and the sample's light source direction is the micro-normal for this view."
"""

from __future__ import annotations

import numpy as np

from ..._validate import as_finite, check_integer, check_shape
from ...errors import ValidationError
from ..fresnel import _check_eta, _fresnel_reflectance
from .samples import masked

__all__ = ["photometric_normals", "micro_normals"]


def _unit(v):
    """Vectors on the last axis scaled to unit length (NaN for zero vectors, no warning)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / n


def photometric_normals(samples, scan_normal, n_cameras, *, eta=1.38, specular_exclusion=np.radians(35.0),
                        max_angle=np.radians(75.0), iterations=3, min_lights=6):
    """Diffuse normals of lumitexels by per-camera photometric stereo (module docstring).

    Parameters
    ----------
    samples : facestats.model.fitting.Samples
        Valid samples on a dome grid (:meth:`Samples.from_grid`: one ``wo_grid``
        direction per camera).
    scan_normal : ndarray, shape (n, 3)
        Scanned normals, used only to exclude specular and grazing samples.
    n_cameras : int
        Number of cameras of the grid (≥ 1).
    eta : float
        Relative index of refraction for F_t.
    specular_exclusion : float
        Samples whose half vector lies within this angle (rad, in [0, π/2]) of the
        scan normal are ignored.
    max_angle : float
        Samples with θi or θo beyond this angle (rad, in (0, π/2]) are ignored.
    iterations : int
        Number of solves, ≥ 1 (the first without, later ones with the F_t(θi)
        correction of the previous normal; the default three bring the noise-free
        error from 1.1° to 0.08°).
    min_lights : int
        Cameras with fewer usable lights get no vote (≥ 3: three unknowns).

    Returns
    -------
    normal : ndarray, shape (n, 3)
        Unit diffuse normals (the scanned normal where no camera could vote).
    camera_normal : ndarray, shape (n, C, 3)
        Per-camera normals (NaN where a camera had too few lights).
    """
    n_cameras = _check_camera_grid(samples, n_cameras)
    check_shape(np.asarray(scan_normal), "scan_normal", (samples.n_texels, 3))
    _check_eta(eta)
    as_finite(specular_exclusion, "specular_exclusion", 0, np.pi / 2, unit="rad")
    as_finite(max_angle, "max_angle", 0, np.pi / 2, low_inclusive=False, unit="rad")
    check_integer(iterations, "iterations", 1)
    check_integer(min_lights, "min_lights", 3)
    n_scan = np.asarray(scan_normal, np.float32)
    n = samples.n_texels
    y = samples.grey()
    ci_g, co_g = samples.cos_grids(n_scan)
    ci, co = samples.at_lights(ci_g), samples.at_cameras(co_g)
    cos_h = (ci + co) / np.sqrt(np.maximum(2 + 2 * samples.cos_io(), 1e-12))  # N·H with ‖ωi + ωo‖² = 2 + 2 ωi·ωo
    lim = np.float32(np.cos(max_angle))
    with np.errstate(invalid="ignore"):
        use = (cos_h < np.float32(np.cos(specular_exclusion))) & (ci > lim) & (co > lim) & (y > 0) & (y < np.inf)
    # Per (lumitexel, camera) run of samples: A = Σ ωi ωiᵀ and b = Σ y ωi over the used lights
    # (segmented sums over the runs; runs without samples are absent).
    key, start, cnt = samples.camera_runs()
    m = use.astype(np.float32)
    wi = [samples.at_lights(np.ascontiguousarray(samples.wi_grid[..., k])) for k in range(3)]
    wm = [w * m for w in wi]  # ωi where used, 0 elsewhere
    scratch = np.empty(samples.n, np.float32)

    def run_sum(x, y):
        """Σ x y over every (lumitexel, camera) run, float64."""
        return np.add.reduceat(np.multiply(x, y, out=scratch), start).astype(np.float64)

    a = np.empty((key.size, 3, 3))
    for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)):
        a[:, i, j] = a[:, j, i] = run_sum(wm[i], wi[j])
    count = np.add.reduceat(m, start)
    ok = count >= min_lights
    det = np.linalg.det(a)
    ok &= det > 1e-6 * np.maximum(count, 1.0) ** 3
    a_inv = np.linalg.inv(np.where(ok[:, None, None], a, np.eye(3)))  # A is the same in every pass
    ym = masked(y, use)
    wig = samples.wi_grid.astype(np.float64)
    cam_dir = samples.wo_grid.astype(np.float64).reshape(-1, 3)[key]
    normal = n_scan.astype(np.float64)
    cam_n = np.full((n * n_cameras, 3), np.nan)
    e32 = np.float32(eta)
    for it in range(int(iterations)):  # refinement passes
        if it > 0:  # divide out F_t(θi) with the current normal (computed on the light grid)
            c = np.clip(np.matmul(wig, normal[:, :, None])[..., 0], 0, 1).astype(np.float32)  # (n, L)
            ft = 1 - _fresnel_reflectance(c, e32)
            yy = ym / samples.at_lights(np.where(ft > 0, ft, 1))
        else:
            yy = ym
        b = np.stack([run_sum(yy, w) for w in wi], axis=1)
        g = np.einsum("rij,rj->ri", a_inv, b)
        run_n = np.where(ok[:, None], _unit(g), np.nan)
        weight = np.where(ok, np.clip(np.einsum("rk,rk->r", np.nan_to_num(run_n), cam_dir), 0, None), 0)
        acc = np.zeros((n * n_cameras, 3))
        acc[key] = weight[:, None] * np.nan_to_num(run_n)
        acc = acc.reshape(n, n_cameras, 3).sum(1)
        wsum = np.zeros(n * n_cameras)
        wsum[key] = weight
        have = wsum.reshape(n, n_cameras).sum(1) > 0
        normal = np.where(have[:, None], _unit(acc), n_scan)
        cam_n[key] = run_n
    return normal.astype(np.float32), cam_n.reshape(n, n_cameras, 3).astype(np.float32)


def _check_camera_grid(samples, n_cameras):
    """``n_cameras`` as an int, checked against the samples' camera grid."""
    n_cameras = check_integer(n_cameras, "n_cameras", 1)
    if samples.wo_grid.shape[1] != n_cameras:
        raise ValidationError(
            f"samples must hold one wo_grid direction per camera (build them with Samples.from_grid): "
            f"n_cameras is {n_cameras}, got wo_grid of shape {samples.wo_grid.shape}"
        )
    return n_cameras


def micro_normals(samples, n_cameras):
    """Per-camera micro-normals: the half vector of each view's brightest sample (§5.1).

    "Brightest" is the largest grey BRDF-like value L/E⊥ among the camera's valid
    samples.

    Parameters
    ----------
    samples : facestats.model.fitting.Samples
        Valid samples on a dome grid (:meth:`Samples.from_grid`).
    n_cameras : int
        Number of cameras of the grid.

    Returns
    -------
    ndarray, shape (n, C, 3)
        Unit half vectors; NaN where a camera has no valid sample.
    """
    n_cameras = _check_camera_grid(samples, n_cameras)
    n = samples.n_texels
    out = np.full((n * n_cameras, 3), np.nan, np.float32)
    if samples.n == 0:
        return out.reshape(n, n_cameras, 3)
    y = np.nan_to_num(samples.grey(), nan=-np.inf)
    key, start, cnt = samples.camera_runs()
    peak = np.maximum.reduceat(y, start)
    run = np.repeat(np.arange(key.size), cnt)  # run of each sample
    hit = np.flatnonzero(y == np.repeat(peak, cnt))
    first = np.concatenate([[True], run[hit][1:] != run[hit][:-1]])
    best = hit[first]  # the first brightest sample of every run
    t, l, c = samples.texel[best], samples.light[best], samples.camera[best]
    out[key[run[best]]] = _unit(samples.wi_grid[t, l] + samples.wo_grid[t, c])
    return out.reshape(n, n_cameras, 3)
