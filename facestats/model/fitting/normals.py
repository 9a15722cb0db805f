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
repeated: ``iterations`` = 4 passes by default (the first without the F_t(θi)
correction).  This fixed point converges linearly, each pass cutting the error
left by the previous one about threefold.  Measured on S001 of the default population
(procedural face, 48², ``benchmarks/bench_scale.bench_normal_passes``), the
median angle to the true normal after 1, 2, 3, 4 and 5 passes is 1.06°, 0.24°,
0.082°, 0.022° and 0.021° for noise-free captures with local subsurface transport.
With camera noise it is 1.08°, 0.25°, 0.12°, 0.080° and 0.082°: from the fourth pass on,
the noise, not the passes, sets the error.  The median hides a tail: after four passes the
99th percentile is 0.40° and the largest error 1.04° (noise-free; 0.39° and 1.11° with noise),
and more passes do not shrink them (0.42° and 1.06° after six), so the fixed point is not
what limits those texels (the same benchmark reports both figures; 2026-12-07).  Three passes, the default
before 2026-12-04, left a tilt shared by all cameras that biased the albedo (+0.24 %) and, through it,
Blinn-Phong's ρs (−1.5 % in the fit of then, without the diffuse level; −0.28 % with today's fit held to three
passes, −0.08 % with four) (median over S001's lumitexels, local transport with noise,
``bench_calibration_budget(passes=3)``).

Micro-normals (§5.1): "For each camera viewpoint, we choose the sample with
maximum value in each lumitexel.  The half-way vector between the view direction
and the sample's light source direction is the micro-normal for this view."  A
lumitexel "stores samples of the skin BRDF f_r" (§4, eq. 8), so the value ranked
is the grey f_r = Σ_ch L / (Σ_ch E⊥ cos θi), with θi to the diffuse normal, over
the samples of eq. 14's domain (θi, θo ≤ 80°: "measurements close to extreme
grazing angles are generally unreliable", §5.3).  Before 2026-12-06 the rank was
L/E⊥ = f_r cos θi, which pulls the choice towards lights near the normal: on
synthetic lumitexels with a known normal (150 lights, 16 cameras) the median
angle of the micro-normal to the true normal was 6.7° (Blinn-Phong n = 30) and
13.1° (Torrance-Sparrow m = 0.3); ranking f_r over the 80° domain gives 3.3° and
8.4° (``tests/model/fitting/test_stages.py``).
"""

from __future__ import annotations

import numpy as np

from facestats.core.published import ETA_SKIN
from facestats.core.validate import as_finite, check_integer, check_shape
from facestats.errors import ValidationError
from facestats.model.fitting.samples import masked, order_keys
from facestats.model.fresnel import check_eta, fresnel_reflectance_unchecked

__all__ = ["photometric_normals", "micro_normals"]


def _unit(v):
    """Vectors on the last axis scaled to unit length (NaN for zero vectors, no warning)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / n


def photometric_normals(
    samples,
    scan_normal,
    n_cameras,
    *,
    eta=ETA_SKIN,
    specular_exclusion=np.radians(35.0),
    max_angle=np.radians(75.0),
    iterations=4,
    min_lights=6,
):
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
        correction of the previous normal; the default four bring the noise-free
        error from 1.1° to 0.02°, module docstring).
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
    _check_finite_directions(samples)
    check_shape(np.asarray(scan_normal), "scan_normal", (samples.n_texels, 3))
    check_eta(eta)
    as_finite(specular_exclusion, "specular_exclusion", 0, np.pi / 2, unit="rad")
    as_finite(max_angle, "max_angle", 0, np.pi / 2, low_inclusive=False, unit="rad")
    check_integer(iterations, "iterations", 1)
    check_integer(min_lights, "min_lights", 3)
    n_scan = np.asarray(scan_normal, np.float32)
    y = samples.grey()
    lim = np.float32(np.cos(max_angle))
    cos_spec = np.float32(np.cos(specular_exclusion))
    if samples.resolved_engine == "numba":
        return _compiled_normals(samples, n_scan, y, cos_spec, lim, eta, iterations, min_lights)
    a, count, rhs = _numpy_system(samples, n_scan, y, cos_spec, lim)
    adj, det = _adjugate_sym3(a)  # A is the same in every pass: g = A⁻¹ b ∝ adj(A) b
    ok = (count >= min_lights) & (det > 1e-6 * np.maximum(count, 1.0) ** 3)
    wi = np.asarray(samples.wi_grid, np.float32)  # (n, L, 3)
    cam_dir = samples.wo_grid.astype(np.float64)  # (n, C, 3)
    normal = n_scan.astype(np.float64)
    e32 = np.float32(eta)
    for it in range(int(iterations)):  # refinement passes
        w_eff = wi
        if it > 0:  # divide out F_t(θi) with the current normal: y / F_t = Σ_l y_l ωi_l / F_t,l
            c = np.clip(samples.cos_grids(normal)[0], 0, 1)  # (n, L)
            ft = 1 - fresnel_reflectance_unchecked(c, e32)
            w_eff = wi / np.where(ft > 0, ft, 1)[..., None]
        b = rhs(w_eff)  # (n, C, 3)
        g = np.einsum("ijnc,ncj->nci", adj, b)  # det(A) > 0 where ok: the direction of A⁻¹ b
        cam_n = np.where(ok[..., None], _unit(g), np.nan)
        weight = np.where(ok, np.clip(np.einsum("nck,nck->nc", np.nan_to_num(cam_n), cam_dir), 0, None), 0)
        acc = np.einsum("nc,nck->nk", weight, np.nan_to_num(cam_n))
        have = weight.sum(1) > 0
        normal = np.where(have[:, None], _unit(acc), n_scan)
    return normal.astype(np.float32), cam_n.astype(np.float32)


def _numpy_system(samples, n_scan, y, cos_spec, lim):
    """Per-(lumitexel, camera) A (6, n, C), light count (n, C) and b(w) over the used samples, in numpy.

    A = Σ ωi ωiᵀ and b = Σ y w over the used lights, as batched products of the
    (lumitexel, camera, light) grids of the mask and of y with the lights' directions.
    """
    ci_g, co_g = samples.cos_grids(n_scan)
    ci, co = samples.at_lights(ci_g), samples.at_cameras(co_g)
    cos_h = samples.cos_half(ci, co)
    with np.errstate(invalid="ignore"):
        use = (cos_h < cos_spec) & (ci > lim) & (co > lim) & (y > 0) & (y < np.inf)
    m_grid = samples.on_grid(use.astype(np.float32))  # (n, C, L)
    y_grid = samples.on_grid(masked(y, use).astype(np.float64))
    wi64 = np.asarray(samples.wi_grid, np.float64)
    i, j = np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2])  # the 6 entries of a symmetric 3×3
    # The sums over lights run in float64: BLAS kernels (chosen per CPU) sum in different orders, and float32
    # sums would make the normals, and every fit after them, depend on the machine in the last bits.
    a = np.moveaxis(np.matmul(m_grid.astype(np.float64), wi64[..., i] * wi64[..., j]), -1, 0)  # (6, n, C)

    def rhs(w):
        return np.matmul(y_grid, np.asarray(w).astype(np.float64))

    return a, m_grid.sum(-1), rhs


def _compiled_normals(samples, n_scan, y, cos_spec, lim, eta, iterations, min_lights):
    """:func:`photometric_normals` by two compiled passes over the samples
    (:func:`facestats.model.fitting.kernels.runs.used_samples`, then
    :func:`~facestats.model.fitting.kernels.runs.normal_passes`, which forms A, adj(A) and the passes
    per lumitexel)."""
    # local import: the kernels import numba
    from facestats.model.fitting.kernels.runs import normal_passes, used_samples

    wi = np.ascontiguousarray(samples.wi_grid, np.float32)
    wo = np.ascontiguousarray(samples.wo_grid, np.float32)
    y_used = used_samples(
        samples.texel,
        samples.light_index,
        samples.camera_index,
        wi.reshape(-1, 3),
        wo.reshape(-1, 3),
        n_scan,
        np.ascontiguousarray(y, np.float32),
        cos_spec,
        lim,
    )
    args = (samples.light_index, y_used, wi, wo, n_scan, np.float32(eta), int(iterations), float(min_lights))
    normal, cam_n = normal_passes(*samples.camera_runs(), *args)
    return normal.astype(np.float32), cam_n.astype(np.float32)


def _adjugate_sym3(a):
    """Adjugate (3, 3, ...) and determinant (...) of symmetric 3×3 matrices given as their
    6 entries (a00, a01, a02, a11, a12, a22) on the first axis: A⁻¹ = adj(A)/det(A) (cofactors)."""
    a00, a01, a02, a11, a12, a22 = a
    c00, c11, c22 = a11 * a22 - a12 * a12, a00 * a22 - a02 * a02, a00 * a11 - a01 * a01
    c01, c02, c12 = a02 * a12 - a01 * a22, a01 * a12 - a02 * a11, a01 * a02 - a00 * a12
    adj = np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]])
    return adj, a00 * c00 + a01 * c01 + a02 * c02


def _check_camera_grid(samples, n_cameras):
    """``n_cameras`` as an int, checked against the samples' camera grid."""
    n_cameras = check_integer(n_cameras, "n_cameras", 1)
    if samples.wo_grid.shape[1] != n_cameras:
        raise ValidationError(
            f"samples must hold one wo_grid direction per camera (build them with Samples.from_grid): "
            f"n_cameras is {n_cameras}, got wo_grid of shape {samples.wo_grid.shape}"
        )
    return n_cameras


def _check_finite_directions(samples):
    """The light and view directions of ``samples`` are finite (a point at a light or camera has none)."""
    for name in ("wi_grid", "wo_grid"):
        grid = getattr(samples, name)
        if not np.isfinite(grid).all():
            t, k = np.argwhere(~np.isfinite(grid).all(axis=-1))[0]
            raise ValidationError(
                f"samples.{name} must hold finite directions, got {grid[t, k].tolist()} "
                f"for lumitexel {t}, {'light' if name == 'wi_grid' else 'camera'} {k}"
            )


def micro_normals(samples, n_cameras, cos_i, use):
    """Per-camera micro-normals: the half vector of each view's largest BRDF sample (Weyrich et al. 2006 §5.1).

    The value ranked is the grey f_r = Σ_ch L / (Σ_ch E⊥ cos θi) of eq. 8 over the samples in ``use``
    (module docstring); the first of equal values wins.

    Parameters
    ----------
    samples : facestats.model.fitting.Samples
        Valid samples on a dome grid (:meth:`Samples.from_grid`).
    n_cameras : int
        Number of cameras of the grid.
    cos_i : ndarray, shape (S,)
        cos θi of each sample to the diffuse normal (:func:`brdf_samples`); samples with cos θi ≤ 0 never win.
    use : ndarray of bool, shape (S,)
        The samples that may win (:func:`brdf_samples`'s ``use``: θi and θo within eq. 14's 80°).

    Returns
    -------
    ndarray, shape (n, C, 3)
        Unit half vectors; NaN where a camera has no sample in ``use``.
    """
    n_cameras = _check_camera_grid(samples, n_cameras)
    check_shape(np.asarray(cos_i), "cos_i", (samples.n,))
    check_shape(np.asarray(use), "use", (samples.n,))
    n = samples.n_texels
    out = np.full((n * n_cameras, 3), np.nan, np.float32)
    if samples.n == 0:
        return out.reshape(n, n_cameras, 3)
    cos = np.asarray(cos_i, np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        value = np.where(np.asarray(use, bool) & (cos > 0), samples.grey() / cos, np.float32(np.nan))
    key, start, cnt = samples.camera_runs()
    if samples.resolved_engine == "numba":
        # local import: the kernels import numba
        from facestats.model.fitting.kernels.runs import run_argmax

        best = run_argmax(value, start, cnt)
    else:
        darkness = -np.nan_to_num(value, nan=-np.inf)  # NaN ranks last
        best = np.minimum.reduceat(order_keys(darkness), start) & 0xFFFFFFFF  # first largest sample of each run
    seen = np.isfinite(value[best])  # a run whose samples are all outside ``use`` has none
    wi = samples.wi_grid.reshape(-1, 3)[samples.light_index[best[seen]]]
    wo = samples.wo_grid.reshape(-1, 3)[samples.camera_index[best[seen]]]
    out[key[seen]] = _unit(wi + wo)
    return out.reshape(n, n_cameras, 3)
