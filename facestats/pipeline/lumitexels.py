"""Stages 1-4 of the fit pipeline on a block of lumitexels (Weyrich et al. 2006 §5.1-5.3).

Lumitexels are independent, so a block runs in cache-sized pieces: the valid
samples are flattened into :class:`facestats.model.fitting.Samples`, then
photometric-stereo normals, the stable-minimum albedo (eq. 9), the specular
residual (eq. 10) and the batch specular fits (eq. 14).
"""

from __future__ import annotations

import time

import numpy as np

from facestats.errors import ValidationError
from facestats.model import fitting
from facestats.pipeline.settings import MAP_VARS, MODEL_PREFIX, STD_VARS, FitSettings, checked_settings

__all__ = ["fit_lumitexels", "PIECE"]


#: Lumitexels per piece inside :func:`fit_lumitexels`: about 1 MB per per-sample array, so each
#: stage's temporaries stay in the CPU cache (0.47 s against 0.60 s per 2048 lumitexels).
PIECE = 256


def fit_lumitexels(lt, settings: FitSettings | None = None, *, timings: dict | None = None) -> dict:
    """Stages 1-4 on a block of lumitexels (:class:`facestats.acquire.capture.Lumitexels`).

    The block's valid samples (minus ``settings.exclude_cameras``) are flattened
    into :class:`facestats.model.fitting.Samples`, one contiguous run per
    lumitexel; then: diffuse normals by photometric stereo (4 passes) and
    micro-normals; BRDF samples f_r (eq. 8) with the photometric normal; the
    albedo by the stable minimum (eq. 9), refined over specular-free samples if
    ``settings.refine_albedo``; the grey specular residual (eq. 10); and the
    batch fit of each of ``settings.models`` (eq. 14), the later ones started
    from the first.  Lumitexels are independent: a block runs in pieces of
    :data:`PIECE` lumitexels (cache-sized), concatenated.

    Parameters
    ----------
    lt : facestats.acquire.capture.Lumitexels
        The block of n lumitexels with their samples.
    settings : FitSettings, optional
        The fit's settings (default ``FitSettings()``); validated again (:func:`checked_settings`).
    timings : dict, optional
        If given, accumulates the wall time of each stage (seconds, by stage name;
        ``benchmarks/bench_scale.bench_fit_stages``).

    Returns
    -------
    dict of ndarray
        ``normal`` (n, 3), ``micro_normal`` (n, C, 3) if requested, ``albedo`` and
        ``albedo_min`` (n, 3; refined and stable-minimum albedo), ``n_samples``
        (usable samples), ``n_invalid`` (masked: NaN, negative, unlit, occluded, clipped),
        ``n_grazing`` (valid but beyond the angle limit of eq. 14), and for each model
        ``*_rho_s``, ``*_m``/``*_exponent``, ``*_error``, ``*_flag`` and the standard errors
        ``*_rho_s_std``, ``*_m_std``/``*_exponent_std`` (robust HC3 standard errors of the fit, with the
        grey diffuse level fitted alongside: :mod:`facestats.model.fitting.diffuse_level`).
    """
    st = checked_settings(settings)
    clock = _Clock(timings)
    if lt.n <= PIECE:
        return _fit_piece(lt, st, clock)
    parts = [_fit_piece(lt[a : a + PIECE], st, clock) for a in range(0, lt.n, PIECE)]
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    clock.lap("other")
    return out


class _Clock:
    """Wall time per stage into a dict (or nothing without one): ``lap(name)`` adds the time since the last lap."""

    def __init__(self, timings):
        self.timings = timings
        self.last = time.perf_counter()

    def lap(self, name):
        if self.timings is not None:
            now = time.perf_counter()
            self.timings[name] = self.timings.get(name, 0.0) + now - self.last
            self.last = now


def _fit_piece(lt, st, clock):
    """Stages 1-4 on lumitexels ``lt`` (:func:`fit_lumitexels`), timed by ``clock``."""
    n_cam = lt.wo.shape[1]
    if any(c >= n_cam for c in st.exclude_cameras):
        raise ValidationError(f"exclude_cameras must be camera indices below {n_cam}, got {st.exclude_cameras!r}")
    keep = np.ones(n_cam, bool)
    keep[list(st.exclude_cameras)] = False
    clock.lap("other")
    samples, n_invalid = fitting.Samples.from_dome(
        lt.wi, lt.wo, lt.irradiance, lt.radiance, keep_cameras=keep, engine=st.engine
    )
    clock.lap("samples")
    out = {"n_invalid": n_invalid}
    # Stage 1: normals.
    normal, _ = fitting.photometric_normals(samples, lt.scan_normal, n_cam, eta=st.eta)
    out["normal"] = normal
    clock.lap("photometric_normals")
    # Stage 2: albedo from BRDF samples with the photometric normal (eq. 8).
    cos_i, cos_o, ft2, use, f_r = fitting.brdf_samples(samples, normal, st.eta, st.max_angle_deg)
    clock.lap("brdf_samples")
    if st.micro_normals:
        out["micro_normal"] = fitting.micro_normals(samples, n_cam, cos_i, use)
        clock.lap("micro_normals")
    albedo_min, _ = fitting.albedo_stable_minimum(
        samples, f_r, cos_i, cos_o, ft2, use, discard=st.discard, grazing_penalty=st.grazing_penalty
    )
    clock.lap("stable_minimum")
    albedo = np.where(np.isfinite(albedo_min), albedo_min, 0).astype(np.float32)
    out["n_samples"] = samples.count(use)
    out["n_grazing"] = samples.count(~use)
    clock.lap("other")
    if st.refine_albedo:
        # Stage 2b: the mean over specular-free samples removes the noise bias of the minimum.
        cos_half = samples.cos_half(cos_i, cos_o)
        refined, n_ref = fitting.refine_albedo(samples, f_r, ft2, cos_half, use)
        ok = np.isfinite(refined).all(1) & (n_ref >= st.min_samples)
        albedo = np.where(ok[:, None], refined, albedo).astype(np.float32)
        clock.lap("refine_albedo")
    # Stages 3-4: the specular residual (eq. 10) and the batch fit of each model (eq. 14), each with
    # the grey diffuse level left by eq. 10 (fitting.diffuse_level).
    f_s = fitting.specular_residual(samples, f_r, albedo, ft2)
    clock.lap("specular_residual")
    fits = fitting.fit_specular_models(
        samples,
        normal,
        f_s,
        use,
        st.models,
        eta=st.eta,
        min_samples=st.min_samples,
        max_relative_error=st.max_relative_error,
        cos=(cos_i, cos_o),
        engine=st.engine,
        ft2=ft2,
        max_angle=_model_angles(st),
        normal_tilt=st.normal_tilt,
        albedo=albedo,
    )
    clock.lap("specular_fits")
    few = out["n_samples"] < st.min_samples
    out["albedo"] = np.where(few[:, None], np.nan, albedo).astype(np.float32)
    out["albedo_min"] = albedo_min.astype(np.float32)
    for model, res in fits.items():
        key = MODEL_PREFIX[model]
        k_rho, k_lobe, k_err = MAP_VARS[key]
        out[k_rho], out[k_lobe], out[k_err], out[f"{key}_flag"] = res.rho_s, res.lobe, res.error, res.flags
        out[STD_VARS[key][0]], out[STD_VARS[key][1]] = res.rho_s_std, res.lobe_std
    clock.lap("other")
    return out


def _model_angles(st):
    """Per-model angle limits (rad) stricter than ``max_angle_deg``: Blinn-Phong's ``bp_max_angle_deg``."""
    if "blinn_phong" in st.models and st.bp_max_angle_deg < st.max_angle_deg:
        return {"blinn_phong": np.radians(st.bp_max_angle_deg)}
    return None
