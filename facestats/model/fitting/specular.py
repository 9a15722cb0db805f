"""Stage 4 of the fit: the specular BRDF per texel, as one batch solve over all texels.

Weyrich et al. 2006 §5.3 fits Torrance-Sparrow (ρs, m) and Blinn-Phong (ρs, n)
to the specular residual f_s of every lumitexel by minimising

    E(p) = sqrt( Σ w [f_s cos θi − f_sM(p) cos θi]² / Σ w )          (eq. 14)

with w = 0 for samples whose ωi or ωo lies beyond 80°.  The paper uses
constrained sequential quadratic programming per lumitexel (the baseline of
``benchmarks/bench_fit.py``).  Here every texel is solved at once by a bounded
Levenberg-Marquardt iteration vectorised over texels and samples:

* The per-sample factors A, z of both models (:mod:`facestats.model.fitting.lobes`)
  are computed once, in float32 and blockwise (:func:`specular_factors`,
  :func:`facestats.core.blocked.blockwise`); every iteration of the solver
  (:mod:`facestats.model.fitting.solver`: parameters, start, convergence, flags)
  costs one exponential per sample.
* Only samples with w = 1 are kept, compacted once for all models
  (:func:`fit_specular_models`), as flat arrays in which every texel's samples
  form one contiguous run (:class:`facestats.model.fitting.samples.Samples` is
  sorted by texel).
"""

from __future__ import annotations

import numpy as np

from facestats.core.blocked import blockwise
from facestats.core.published import ETA_SKIN
from facestats.core.validate import as_finite, as_float, check_choice, check_shape
from facestats.errors import ValidationError
from facestats.model.brdf import check_directions, torrance_sparrow_cosines_unchecked
from facestats.model.fitting.engine import resolve_engine
from facestats.model.fitting.normal_tilt import tilt_grids, tilt_inputs
from facestats.model.fitting.samples import Samples, run_starts, segment_sum
from facestats.model.fitting.solver import DEFAULT_BOUNDS, SpecularFit, solve_specular
from facestats.model.fitting.uncertainty import rms_error
from facestats.model.fresnel import check_eta

__all__ = [
    "SpecularFit",
    "fit_specular",
    "fit_specular_samples",
    "fit_specular_models",
    "specular_factors",
    "equivalent_lobe",
    "DEFAULT_BOUNDS",
]


def _ts_factor_kernel(ci, co, io, eta):
    """(tan²δ, K cos θi / cos⁴δ) of a block of samples (run through :func:`facestats.core.blocked.blockwise`)."""
    cos_d, k = torrance_sparrow_cosines_unchecked(ci, co, io, eta)
    c2 = cos_d * cos_d
    return (1 - c2) / c2, np.maximum(k * ci / (c2 * c2), 0)


def specular_factors(samples, normal, model, eta=ETA_SKIN, cos=None):
    """Parameter-free per-sample factors (s1, A) of ``model`` (module docstring), float32.

    Torrance-Sparrow (Weyrich et al. 2006 eq. 12-13): s1 = tan²δ,
    A = K cos θi / cos⁴δ (sr⁻¹) with K from
    :func:`facestats.model.brdf.torrance_sparrow_cosines`, evaluated block by
    block (:func:`facestats.core.blocked.blockwise`); Blinn-Phong (eq. 11):
    s1 = ln cos δ, A = cos θi / (2π).  A = 0 where a direction is below the
    horizon.  ``cos`` = (N·ωi, N·ωo) per sample may be passed when already known
    (``normal`` is then not used).

    Parameters
    ----------
    samples : Samples
        The samples (for ωi·ωo and, without ``cos``, their direction grids).
    normal : array_like, shape (n, 3)
        Unit normal per lumitexel.
    model : {"torrance_sparrow", "blinn_phong"}
        The lobe.
    eta : float
        Relative index of refraction of the Torrance-Sparrow Fresnel term (one number > 0), default 1.38.
    cos : tuple of 2 ndarray, shape (S,), optional
        (N·ωi, N·ωo) per sample.

    Returns
    -------
    s1, a : ndarray of float32, shape (S,)

    Raises
    ------
    ValidationError
        An unknown ``model`` or an invalid ``eta``.
    """
    check_choice(model, "model", DEFAULT_BOUNDS)
    eta = check_eta(eta, scalar=True)
    ci, co = samples.cos(normal) if cos is None else cos
    return _factors(model, ci, co, samples.cos_io(), eta)


def _factors(model, ci, co, io, eta):
    """(s1, A) of :func:`specular_factors` from N·ωi, N·ωo and ωi·ωo per sample (no checks).

    float32 throughout: the factors' relative error stays below 2e-5 (1e-6
    typical), far below the noise of any measured sample.
    """
    io = np.asarray(io, np.float32)
    if model == "torrance_sparrow":
        return blockwise(_ts_factor_kernel, [ci, co, io, np.float32(eta)], np.float32, n_out=2)
    above = (ci > 0) & (co > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_d = (ci + co) / np.sqrt(np.maximum(2 + 2 * io, 1e-12))
    return np.log(np.clip(cos_d, 1e-6, 1)).astype(np.float32), np.where(above, ci / (2 * np.pi), 0).astype(np.float32)


def equivalent_lobe(lobe, source, target):
    """The ``target`` model's lobe parameter closest to a ``source`` lobe: n = 2/m² − 2, m = sqrt(2/(n + 2)).

    The Beckmann-Phong correspondence α_p = 2 α_b⁻² − 2 under which Walter et al.
    2007 ("Microfacet models for refraction through rough surfaces", §5.2) find
    the two distributions very similar.  It is only a starting point: one
    model's fit starts the other's, which then converges on its own.  ``m`` is
    clamped at 10⁻³ (so the result stays finite) and ``n`` at 0, in and out (m > 1 gives n = 0).

    Parameters
    ----------
    lobe : array_like
        Lobe parameter of ``source``: roughness m (Torrance-Sparrow) or exponent n (Blinn-Phong).
    source, target : {"torrance_sparrow", "blinn_phong"}
        The models to convert from and to.

    Returns
    -------
    ndarray of float64
        The ``target`` lobe parameter, shape of ``lobe`` (``lobe`` itself as float64 when the models agree).

    Raises
    ------
    ValidationError
        An unknown model name.
    """
    check_choice(source, "source", DEFAULT_BOUNDS)
    check_choice(target, "target", DEFAULT_BOUNDS)
    lobe = np.asarray(lobe, np.float64)
    if source == target:
        return lobe
    if target == "blinn_phong":
        return np.maximum(2 / np.maximum(lobe, 1e-3) ** 2 - 2, 0)  # m > 1 has no positive n (gave n < 0)
    return np.sqrt(2 / (np.maximum(lobe, 0) + 2))


def fit_specular_samples(
    samples,
    normal,
    f_s,
    use,
    model,
    *,
    eta=ETA_SKIN,
    bounds=None,
    min_samples=30,
    max_iter=40,
    tol=1e-6,
    max_relative_error=0.25,
    start=None,
    cos=None,
    engine=None,
) -> SpecularFit:
    """Fit ``model`` to grey specular samples on flat :class:`Samples` (the pipeline's form of :func:`fit_specular`).

    Parameters
    ----------
    samples : Samples
    normal : ndarray, shape (n, 3)
    f_s : ndarray, shape (S,)
        Grey specular BRDF samples.
    use : ndarray of bool, shape (S,)
        Samples that enter eq. 14 (w = 1).
    model : {"torrance_sparrow", "blinn_phong"}
    eta, bounds, min_samples, max_iter, tol, max_relative_error
        As :func:`fit_specular`.
    start : ndarray, shape (n,), optional
        Starting lobe parameter per texel (e.g. a previous fit); NaN entries use
        the log-linear start.
    cos : tuple of ndarray, optional
        (N·ωi, N·ωo) per sample, when already known.
    engine : {"numba", "numpy"}, optional
        Implementation of the solve (:mod:`facestats.model.fitting.engine`; default: the configured one).

    Returns
    -------
    SpecularFit
    """
    check_choice(model, "model", DEFAULT_BOUNDS)
    return fit_specular_models(
        samples,
        normal,
        f_s,
        use,
        (model,),
        eta=eta,
        bounds={model: bounds},
        min_samples=min_samples,
        max_iter=max_iter,
        tol=tol,
        max_relative_error=max_relative_error,
        start=start,
        cos=cos,
        engine=engine,
    )[model]


def fit_specular_models(
    samples,
    normal,
    f_s,
    use,
    models,
    *,
    eta=ETA_SKIN,
    bounds=None,
    min_samples=30,
    max_iter=40,
    tol=1e-6,
    max_relative_error=0.25,
    start=None,
    cos=None,
    engine=None,
    ft2=None,
    max_angle=None,
    normal_tilt=False,
    albedo=None,
) -> dict:
    """Fit several models to the same grey specular samples; later models start from the first.

    The samples entering eq. 14 are selected and compacted once for all models
    (``use``, finite ``f_s``, ωi and ωo above the horizon), and each model's
    factors (:func:`specular_factors`) are computed on those samples only.  The
    first model starts from ``start`` (or cold), each later one from the
    first's fit through :func:`equivalent_lobe`.

    Parameters
    ----------
    samples, normal, f_s, use
        As :func:`fit_specular_samples`.
    models : sequence of {"torrance_sparrow", "blinn_phong"}
    eta
        As :func:`fit_specular_samples`.
    bounds : dict, optional
        Bounds per model (as :func:`fit_specular`); missing models use :data:`DEFAULT_BOUNDS`.
    min_samples, max_iter, tol, max_relative_error, start, cos, engine
        As :func:`fit_specular_samples`.
    ft2 : ndarray, shape (S,), optional
        F_t(θi) F_t(θo) per sample, with which eq. 10 subtracted the diffuse term from ``f_s``:
        the grey diffuse level is then fitted with each lobe (:mod:`facestats.model.fitting.diffuse_level`),
        and its uncertainty enters the standard errors.
    max_angle : dict, optional
        ``{model: angle}`` (rad): a model's samples are further limited to θi and θo below
        its angle (e.g. Blinn-Phong at 70°, :class:`facestats.pipeline.FitSettings`); the
        samples are then compacted per distinct limit.  Its E(p) (``error``) is still
        reported over all of ``use``, the domain the other models are scored on.
    normal_tilt : bool
        Let the standard errors allow the lobe's normal a tilt, two nuisance parameters, and with
        ``ft2`` the normal of the diffuse term eq. 10 removed too, two more
        (:mod:`facestats.model.fitting.normal_tilt`): for a ``normal`` that is an estimate, such as
        photometric stereo's.  False: the errors are conditional on ``normal``.
    albedo : ndarray, shape (n, 3), optional
        The albedo eq. 10 removed the diffuse term with (:func:`facestats.model.fitting.specular_residual`);
        required with ``normal_tilt`` and ``ft2``.

    Returns
    -------
    dict
        :class:`SpecularFit` per model, in the order of ``models``.
    """
    models = tuple(models) if not isinstance(models, str) else (models,)
    if not models or len(set(models)) != len(models):
        raise ValidationError(f"models must name one or more distinct models, got {models!r}")
    for m in models:
        check_choice(m, "models", DEFAULT_BOUNDS)
    eta = check_eta(eta, scalar=True)
    engine = resolve_engine(samples.engine if engine is None else engine)
    _check_specular_inputs(samples, normal, f_s, use, start)
    bounds = bounds or {}
    ci, co = samples.cos(normal) if cos is None else cos
    groups = {}  # models by the samples they use (one compaction per distinct angle limit)
    for m in models:
        groups.setdefault(None if not max_angle or m not in max_angle else float(max_angle[m]), []).append(m)
    # The full domain of eq. 14, with every model's factors: the unlimited models fit on it, the limited
    # ones are scored on it.
    domains = _domain_inputs(samples, ci, co, f_s, use, models, groups, eta, ft2, engine)
    full = domains[None]
    grey = _grey_albedo(samples, albedo, normal_tilt and ft2 is not None)
    grids = tilt_grids(samples, np.asarray(normal, np.float64), eta, engine) if normal_tilt else None
    kept = {}
    for limit, group in groups.items():
        y, factors, counts, d, index = domains[limit]
        tilt = None  # the group's models share their samples, and so the tilts' inputs
        if grids is not None:
            tilt = tilt_inputs(samples, index, (ci, co, samples.cos_io()), grids, grey is not None)
        kept.update({m: (y, factors[m], counts, d, tilt) for m in group})
    settings = dict(min_samples=min_samples, max_iter=max_iter, tol=tol, max_relative_error=max_relative_error)
    fits = _solve_models(models, kept, bounds, start, engine, settings, grey)
    for limit, group in groups.items():
        if limit is not None:  # scored on the full domain of eq. 14, as the other models
            _rescore(fits, group, full, engine)
    return fits


def _domain_inputs(samples, ci, co, f_s, use, models, groups, eta, ft2, engine):
    """(y, factors per model, kept count per texel, d, kept sample indices) of the samples of eq. 14 in ``use``,
    by ``engine``, per domain: ``None`` the full one (every model's factors), and each angle limit of ``groups``
    (its models' factors, on the samples of ``use`` with cos θi and cos θo above the limit's cosine in float32,
    compared in the dtype of ``ci``/``co``).  The compiled engine forms the full domain and the first limited
    one in one pass."""
    domains = {}
    for limit in groups:
        if limit is not None:
            c = np.float32(np.cos(as_finite(limit, "max_angle", 0, np.pi / 2, low_inclusive=False, unit="rad")))
            domains[limit] = np.asarray(use, bool) & (ci > c) & (co > c)
    limits = list(domains)
    if engine == "numba":
        first = limits[0] if limits else None
        runs = (samples.starts, samples.counts, ci, co, samples.cos_io(), f_s)
        full, limited = _kept_factors_compiled(
            *runs, use, models, eta, ft2, domains.get(first), tuple(groups.get(first, ()))
        )
        out = {None: full} if first is None else {None: full, first: limited}
        for limit in limits[1:]:
            out[limit] = _kept_factors_compiled(*runs, domains[limit], groups[limit], eta, ft2)[0]
        return out
    out = {None: _kept_factors(samples, ci, co, f_s, use, tuple(models), eta, ft2)}
    for limit in limits:
        out[limit] = _kept_factors(samples, ci, co, f_s, domains[limit], tuple(groups[limit]), eta, ft2)
    return out


def _rescore(fits, group, full, engine):
    """Replace the ``error`` of the fits of ``group`` by E(p) over the samples ``full`` of :func:`_domain_inputs`
    (with their diffuse level, if fitted)."""
    y, factors, counts, d, _ = full
    for m in group:
        fit = fits[m]
        shift = None if d is None or fit.diffuse_shift is None else np.nan_to_num(fit.diffuse_shift)
        if engine == "numba":
            err = _rms_compiled(m, y, factors[m], counts, fit, d, shift)
        else:
            err = rms_error(m, y, *factors[m], counts, fit.rho_s, fit.lobe, d=d, shift=shift)
        fit.error = np.where(np.isfinite(fit.error), err, np.nan).astype(fit.error.dtype)


def _grey_albedo(samples, albedo, wanted):
    """α = α_R + α_G + α_B per texel (float64) of the (n, 3) ``albedo`` when ``wanted``, else None."""
    if not wanted:
        return None
    if albedo is None:
        raise ValidationError(
            "albedo (the one eq. 10 removed the diffuse term with) is required with normal_tilt and ft2"
        )
    albedo = as_finite(albedo, "albedo")
    check_shape(albedo, "albedo", (samples.n_texels, 3))
    return albedo.sum(axis=1, dtype=np.float32).astype(np.float64)


def _rms_compiled(model, y, factors, counts, fit, d, shift):
    """:func:`facestats.model.fitting.uncertainty.rms_error` in one compiled pass per texel
    (:func:`facestats.model.fitting.kernels.lm.rms_runs`)."""
    # local import: the kernels import numba
    from facestats.model.fitting.kernels import lm

    n_use = np.asarray(counts, np.int64)
    good = (n_use > 0) & np.isfinite(fit.rho_s) & np.isfinite(fit.lobe) & (fit.lobe > 0)
    with_d = d is not None and shift is not None
    return lm.rms_runs(
        lm.TORRANCE_SPARROW if model == "torrance_sparrow" else lm.BLINN_PHONG,
        np.ascontiguousarray(y, np.float32),
        np.ascontiguousarray(factors[0], np.float32),
        np.ascontiguousarray(factors[1], np.float32),
        np.ascontiguousarray(d, np.float32) if with_d else np.zeros(0, np.float32),
        run_starts(n_use),
        n_use,
        good,
        np.asarray(fit.rho_s, np.float64),
        np.log(np.where(good, fit.lobe, 1.0).astype(np.float64)),
        np.asarray(shift, np.float64) if with_d else np.zeros(n_use.size),
    )


def _solve_models(models, kept, bounds, start, engine, settings, albedo=None):
    """Solve eq. 14 for each model on its kept samples; later models start from the first's fit.

    ``kept[model]`` = (y, (s1, A), counts, d, tilt) with ``d`` None or ∂y/∂α per kept sample and ``tilt``
    None or the :class:`~facestats.model.fitting.normal_tilt.TiltInputs` of the kept samples;
    ``settings`` the solver's ``min_samples``, ``max_iter``, ``tol``, ``max_relative_error``; ``albedo`` the grey
    albedo per texel (with a ``tilt`` whose diffuse normal tilts).
    """
    fits = {}
    for m in models:
        y, (s1, a), counts, d, tilt = kept[m]
        first = fits[models[0]] if fits else None
        st = start if first is None else equivalent_lobe(first.lobe, first.model, m)
        fits[m] = solve_specular(
            m,
            y,
            s1,
            a,
            counts,
            bounds=bounds.get(m),
            start=st,
            engine=engine,
            d=d,
            tilt=tilt,
            albedo=albedo,
            **settings,
        )
    return fits


def _kept_factors(samples, ci, co, f_s, use, models, eta, ft2=None):
    """y = f_s cos θi, the factors (s1, A) per model, the kept count per texel, d = ∂y/∂α and the indices of the
    samples of eq. 14.

    Kept: ``use``, finite ``f_s``, ωi and ωo above the horizon and A > 0 for every model
    (compacted once for all models, one contiguous run per texel).  d = −F_t F_t cos θi/(3π)
    (eq. 10 subtracts (α/π) F_t F_t, averaged over three channels), None without ``ft2``.
    """
    with np.errstate(invalid="ignore"):
        ok = np.asarray(use, bool) & np.isfinite(f_s) & (ci > 0) & (co > 0)
    kept = np.flatnonzero(ok)  # one index, several gathers (faster than one compress per array)
    ci_u, co_u, io_u, y = (np.asarray(x).take(kept) for x in (ci, co, samples.cos_io(), f_s))
    ft_u = None if ft2 is None else np.asarray(ft2).take(kept)
    factors = {m: _factors(m, ci_u, co_u, io_u, eta) for m in models}
    keep = np.logical_and.reduce([a > 0 for _, a in factors.values()])  # A underflows only in extreme geometry
    counts = samples.count(ok)
    if not keep.all():
        counts = segment_sum(keep, np.cumsum(counts) - counts, counts)
        again = np.flatnonzero(keep)
        kept, ci_u, y = kept.take(again), ci_u.take(again), y.take(again)
        ft_u = None if ft_u is None else ft_u.take(again)
        factors = {m: (s1.take(again), a.take(again)) for m, (s1, a) in factors.items()}
    d = None if ft_u is None else (-(ft_u * ci_u) / np.float32(3 * np.pi)).astype(np.float32)
    return (y * ci_u).astype(np.float32, copy=False), factors, counts, d, kept


def _kept_factors_compiled(
    starts, counts, ci, co, io, f_s, use, models, eta, ft2=None, use_limited=None, limit_models=()
):
    """:func:`_kept_factors` of the runs ``starts``, ``counts`` in one compiled pass
    (:func:`facestats.model.fitting.kernels.factors.specular_inputs`), and, with ``use_limited``, the same
    for ``limit_models`` (among ``models``) on those samples (else None)."""
    # local import: the kernels import numba
    from facestats.model.fitting.kernels.factors import specular_inputs

    models, limit_models = tuple(models), tuple(limit_models)
    if not set(limit_models) <= set(models):
        raise ValidationError(f"limit_models must be among models {models!r}, got {limit_models!r}")
    full, limited = specular_inputs(
        np.ascontiguousarray(ci, np.float32),
        np.ascontiguousarray(co, np.float32),
        np.ascontiguousarray(io, np.float32),
        np.ascontiguousarray(f_s, np.float32),
        np.ascontiguousarray(use, bool),
        use_limited is not None,
        np.zeros(0, bool) if use_limited is None else np.ascontiguousarray(use_limited, bool),
        np.zeros(0, np.float32) if ft2 is None else np.ascontiguousarray(ft2, np.float32),
        starts,
        counts,
        np.float32(eta),
        "torrance_sparrow" in models,
        "blinn_phong" in models,
        "torrance_sparrow" in limit_models,
        "blinn_phong" in limit_models,
    )

    def inputs(kept, y, ts_z, ts_a, bp_z, bp_a, d, index, wanted):
        all_factors = {"torrance_sparrow": (ts_z, ts_a), "blinn_phong": (bp_z, bp_a)}
        return y, {m: all_factors[m] for m in wanted}, kept, (None if ft2 is None else d), index

    return inputs(*full, models), (None if use_limited is None else inputs(*limited, limit_models))


def _check_specular_inputs(samples, normal, f_s, use, start):
    check_shape(np.asarray(normal), "normal", (samples.n_texels, 3))
    check_shape(np.asarray(f_s), "f_s", (samples.n,))
    check_shape(np.asarray(use), "use", (samples.n,))
    if start is not None:
        check_shape(np.asarray(start), "start", (samples.n_texels,))


def _check_unit_samples(w, valid, name) -> None:
    """Directions of the valid samples must be finite unit vectors (norm 1 ± 1e-3), like the BRDFs require."""
    with np.errstate(invalid="ignore"):
        norm = np.sqrt(np.einsum("tsk,tsk->ts", w, w))
    bad = valid & ~(np.abs(norm - 1) <= 1e-3)
    if bad.any():
        t, k = np.argwhere(bad)[0]
        raise ValidationError(
            f"{name} must hold unit vectors (norm 1 ± 0.001) for the valid samples, got norm {norm[t, k]:.6g} at "
            f"texel {t}, sample {k}"
        )


def fit_specular(
    wi,
    wo,
    normal,
    f_s,
    valid,
    model,
    *,
    bounds=None,
    eta=ETA_SKIN,
    max_angle=np.radians(80.0),
    min_samples=30,
    max_iter=40,
    tol=1e-6,
    max_relative_error=0.25,
    engine=None,
):
    """Fit Torrance-Sparrow or Blinn-Phong to specular samples of every texel at once (eq. 14).

    Parameters
    ----------
    wi, wo : array_like, shape (texels, samples, 3)
        Unit directions towards light and camera of every sample (broadcastable
        views are fine, e.g. ``np.broadcast_to``).
    normal : array_like, shape (texels, 3)
        Unit normals the BRDF is evaluated with.
    f_s : array_like, shape (texels, samples)
        Grey specular BRDF samples (eq. 10), sr⁻¹.
    valid : array_like of bool, shape (texels, samples)
        Usable samples (NaN ``f_s`` and samples beyond ``max_angle`` are excluded too).
    model : {"torrance_sparrow", "blinn_phong"}
    bounds : ((rho_lo, rho_hi), (lobe_lo, lobe_hi)), optional
        Default :data:`DEFAULT_BOUNDS`.
    eta : float
        Relative index for the Torrance-Sparrow Fresnel term.
    max_angle : float
        The 80° limit of eq. 14 (rad).
    min_samples : int
        Texels with fewer samples are flagged ``few_samples`` (values NaN).
    max_iter, tol
        Iteration cap and relative convergence tolerance on E(p)².
    max_relative_error : float
        Relative standard error above which a texel is flagged ``ill_conditioned``.
    engine : {"numba", "numpy"}, optional
        Implementation (:mod:`facestats.model.fitting.engine`; default: the configured one).

    Returns
    -------
    SpecularFit
        Its standard errors are conditional on ``normal`` (the caller's); the pipeline, whose normal is
        photometric stereo's estimate, lets them allow a tilt (:func:`fit_specular_models`, ``normal_tilt``).
    """
    check_choice(model, "model", DEFAULT_BOUNDS)
    as_finite(max_angle, "max_angle", 0, np.pi / 2, low_inclusive=False, unit="rad")
    eta = check_eta(eta, scalar=True)  # both engines: the compiled one reads it as a float32
    wi = as_float(wi, "wi")
    wo = as_float(wo, "wo")
    normal = as_float(normal, "normal")
    f_s = as_float(f_s, "f_s")
    check_shape(normal, "normal", (None, 3))
    n_tex = normal.shape[0]
    check_shape(f_s, "f_s", (n_tex, None))
    n_smp = f_s.shape[1]
    check_shape(wi, "wi", (n_tex, n_smp, 3))
    check_shape(wo, "wo", (n_tex, n_smp, 3))
    valid = check_shape(np.asarray(valid, bool), "valid", (n_tex, n_smp))
    check_directions(normal, "normal")
    for name, w in (("wi", wi), ("wo", wo)):
        _check_unit_samples(w, valid, name)
    big = valid & np.isfinite(f_s) & (np.abs(f_s) > np.finfo(np.float32).max)
    if big.any():
        t, k = np.argwhere(big)[0]
        raise ValidationError(
            f"f_s must be a BRDF in sr^-1 within the float32 range the fit works in, got {f_s[t, k]!r} at "
            f"texel {t}, sample {k}"
        )
    lim = np.cos(max_angle)
    kwargs = dict(min_samples=min_samples, max_iter=max_iter, tol=tol, max_relative_error=max_relative_error)
    if resolve_engine(engine) == "numba":
        return _fit_dense_compiled(wi, wo, normal, f_s, valid, model, lim, eta, bounds, kwargs)
    valid = (
        valid
        & np.isfinite(f_s)
        & (np.einsum("tk,tsk->ts", normal, wi) > lim)
        & (np.einsum("tk,tsk->ts", normal, wo) > lim)
    )
    samples = Samples.from_arrays(wi, wo, valid, engine="numpy")
    fs = f_s[valid].astype(np.float32)
    return fit_specular_samples(
        samples, normal, fs, np.ones(samples.n, bool), model, eta=eta, bounds=bounds, engine="numpy", **kwargs
    )


def _fit_dense_compiled(wi, wo, normal, f_s, valid, model, lim, eta, bounds, kwargs):
    """:func:`fit_specular` with the numba engine: the dense arrays are read once by a kernel, never copied."""
    # local import: the kernels import numba
    from facestats.model.fitting.kernels.samples import dense_samples

    counts, ci, co, io, fs = dense_samples(
        np.ascontiguousarray(wi), np.ascontiguousarray(wo), np.ascontiguousarray(normal), f_s, valid, float(lim)
    )
    starts = run_starts(counts)
    (y, factors, kept, _, _), _ = _kept_factors_compiled(
        starts, counts, ci, co, io, fs, np.ones(fs.size, bool), (model,), eta
    )
    return _solve_models(
        (model,), {model: (y, factors[model], kept, None, None)}, {model: bounds}, None, "numba", kwargs
    )[model]
