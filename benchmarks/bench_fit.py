"""Fit pipeline speed and accuracy (issue: the fit pipeline).

Figures:

* ``slsqp_ratio``: the paper's method — constrained SQP per texel
  (``scipy.optimize.minimize(method="SLSQP")`` on eq. 14, one call per texel, the
  model evaluated with :func:`facestats.model.brdf.torrance_sparrow` on the
  texel's sample directions) — against the batch Levenberg-Marquardt fitter on
  the same Torrance-Sparrow samples of a default subject: texels per second of
  each, the ratio, and the median E(p) of both on the texels the baseline
  fitted, both evaluated by the same float64 eq. 14.  Also printed: a stronger SLSQP variant with
  the per-sample geometry
  precomputed (it pays only for the optimiser) and the ratio against it.
* ``accuracy``: the whole pipeline on simulated captures of default-population
  subjects with known truth: median and 90th percentile of the relative errors
  of albedo, Torrance-Sparrow and Blinn-Phong parameters (each on captures
  rendered with that model), σtr, the flagged fraction, and the relative RMSE of
  a camera held out of the fit.
* ``public_api_ratio``: the public ``fit_specular`` on dense (texels, samples)
  arrays against per-texel SLSQP on eq. 14 whose objective evaluates the
  library's Torrance-Sparrow BRDF on the texel's directions at every call, at
  300 and 900 samples per texel: texels/s of both and the ratio (target ≥ 200),
  median E(p) of both (same float64 evaluator).
* ``dask_scaling``: subjects per minute fitting twelve default-size captures
  from disk in one process, on Dask's local process scheduler with 2 workers,
  and on a ``distributed`` cluster of 1 and 2 workers (warmed up), with the
  speed-ups.  (Full resolution: ``bench_scale.py``.)
* ``determined_texels``: on the embedded default store, the share of the unflagged texels
  (:func:`facestats.io.summary.region_samples`) whose fitted ρs the fit does *not* determine: standard error
  (:func:`facestats.io.summary.region_standard_errors`) not finite or above
  :data:`facestats.io.summary.DETERMINED_RELATIVE_SE` × |ρs|, in all and per region, for Torrance-Sparrow and
  Blinn-Phong, and the largest standard error / |ρs| among them; then, for one region and parameter of the
  subjects of one skin type (default: the chin's Blinn-Phong n, type IV), ``Store.query``'s between-subject
  mean ± std and its ``mean_se`` / ``texel_se`` (determined texels only) against the baseline that counts every
  finite standard error (what the query did before 2026-12-05 evening): root mean squares over the subjects of
  sqrt(Σσ²)/n and of the texels' RMS σ.

Every benchmark takes its sizes as arguments; ``SMOKE`` gives tiny ones that the
test suite runs (``tests/test_benchmarks.py``) so that no benchmark can rot.
"""

from __future__ import annotations

import os
import tempfile
import time

import numpy as np


def _default_case(index=0, specular="torrance_sparrow", grid=48):
    """The default population (at ``grid``), subject ``index`` and a dome simulator of the procedural face."""
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator
    from facestats.face.procedural import procedural_face

    geometry = procedural_face(grid)
    pop = synthesize_population(map_size=grid, geometry=geometry)
    return pop, pop[index], DomeSimulator(geometry, specular=specular)


def _specular_problem(capture):
    """Stages 1-3 of the pipeline on a capture: packed samples and the grey specular residual."""
    from facestats.model import fitting

    lt = capture.lumitexels()
    samples = fitting.Samples.from_grid(lt.wi, lt.wo, lt.irradiance, lt.radiance, lt.valid)
    normal, _ = fitting.photometric_normals(samples, lt.scan_normal, lt.wo.shape[1])
    ci, co, ft2, use, f_r = fitting.brdf_samples(samples, normal)
    alb, _ = fitting.albedo_stable_minimum(samples, f_r, ci, co, ft2, use)
    cos_half = samples.cos_half(ci, co)
    ref, _ = fitting.refine_albedo(samples, f_r, ft2, cos_half, use)
    alb = np.where(np.isfinite(ref), ref, alb)
    f_s = fitting.specular_residual(samples, f_r, alb, ft2)
    return samples, normal, f_s, use, (ci, co)


def _slsqp(samples, normal, f_s, use, cos, texels, precomputed, batch=None):
    """The baseline: SLSQP per texel on eq. 14 (cos θi weighting, 80° limit), same samples and bounds.

    ``precomputed=False`` evaluates the model with the library's BRDF on the
    texel's directions at every call (what eq. 14 says); ``True`` precomputes the
    parameter-free geometry per sample, a stronger baseline that pays only for
    the optimiser.
    """
    from scipy.optimize import minimize

    from facestats.model import brdf, fitting

    ci, co = cos
    cos_d, k = brdf.torrance_sparrow_cosines(ci, co, samples.cos_io())
    (r_lo, r_hi), (m_lo, m_hi) = fitting.DEFAULT_BOUNDS["torrance_sparrow"]
    errors, batch_errors, t_total = [], [], 0.0
    for t in texels:  # the baseline: one optimiser call per texel
        sel = (samples.texel == t) & use & np.isfinite(f_s)
        y = (f_s[sel] * ci[sel]).astype(np.float64)
        c_i = ci[sel].astype(np.float64)
        if precomputed:
            cd, kk = cos_d[sel].astype(np.float64), k[sel].astype(np.float64)

            def e2(p):
                return np.mean((y - p[0] * brdf.beckmann_distribution(cd, p[1]) * kk * c_i) ** 2)
        else:
            n = normal[t].astype(np.float64)
            wi = samples.wi_grid[t, samples.light[sel]].astype(np.float64)
            wo = samples.wo_grid[t, samples.camera[sel]].astype(np.float64)

            def e2(p):
                return np.mean((y - brdf.torrance_sparrow(n, wi, wo, p[0], p[1]) * c_i) ** 2)

        t0 = time.perf_counter()
        res = minimize(
            e2,
            x0=[0.2, 0.3],
            method="SLSQP",
            bounds=[(r_lo, r_hi), (m_lo, m_hi)],
            options={"ftol": 1e-14, "maxiter": 200},
        )
        t_total += time.perf_counter() - t0
        errors.append(np.sqrt(res.fun))
        if batch is not None:  # E(p) of the batch fit by the same float64 evaluator
            batch_errors.append(np.sqrt(e2([batch.rho_s[t], batch.lobe[t]])))
    return len(texels) / t_total, np.asarray(errors), np.asarray(batch_errors)


def bench_slsqp_ratio(n_baseline=150, grid=48):
    from facestats.model import fitting

    pop, truth, sim = _default_case(3, grid=grid)
    cap = sim.simulate(truth)
    samples, normal, f_s, use, cos = _specular_problem(cap)
    runs = []
    for _ in range(3):
        t0 = time.perf_counter()
        batch = fitting.fit_specular_samples(samples, normal, f_s, use, "torrance_sparrow", cos=cos)
        runs.append(time.perf_counter() - t0)
    tps_batch = samples.n_texels / min(runs)
    texels = np.sort(np.random.default_rng(0).choice(samples.n_texels, n_baseline, replace=False))
    tps_direct, e_direct, e_batch_direct = _slsqp(
        samples, normal, f_s, use, cos, texels, precomputed=False, batch=batch
    )
    tps_pre, _, _ = _slsqp(samples, normal, f_s, use, cos, texels, precomputed=True)
    # Both fits' E(p) evaluated by the same (float64, direct BRDF) eq. 14.
    e_batch = float(np.median(e_batch_direct))
    return {
        "batch_texels_per_s": tps_batch,
        "slsqp_texels_per_s": tps_direct,
        "ratio": tps_batch / tps_direct,
        "median_E_batch": e_batch,
        "median_E_slsqp": float(np.median(e_direct)),
        "E_batch_over_E_slsqp_minus_1": e_batch / float(np.median(e_direct)) - 1,
        "slsqp_precomputed_texels_per_s": tps_pre,
        "ratio_vs_precomputed": tps_batch / tps_pre,
        "texels": samples.n_texels,
        "baseline_texels": n_baseline,
    }


def _dense_problem(samples_per_texel, grid, n_texels, seed=0):
    """Dense per-texel arrays for the public :func:`facestats.model.fitting.fit_specular`.

    Stages 1-3 on a default subject's capture (:func:`_specular_problem`); of the texels with
    at least ``samples_per_texel`` usable samples, ``n_texels`` are drawn, and of each, that many
    samples: ``wi``, ``wo`` (T, S, 3), ``normal`` (T, 3), ``f_s`` (T, S), all valid.
    """
    rng = np.random.default_rng(seed)
    _, truth, sim = _default_case(3, grid=grid)
    samples, normal, f_s, use, (ci, co) = _specular_problem(sim.simulate(truth))
    ok = use & np.isfinite(f_s) & (ci > 0) & (co > 0)
    counts = samples.count(ok)
    rich = np.flatnonzero(counts >= samples_per_texel)
    texels = np.sort(rng.choice(rich, min(n_texels, rich.size), replace=False))
    idx = np.stack(
        [rng.choice(np.flatnonzero(ok & (samples.texel == t)), samples_per_texel, replace=False) for t in texels]
    )
    wi, wo = samples.wi.astype(np.float64)[idx], samples.wo.astype(np.float64)[idx]
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    nrm = normal[texels].astype(np.float64)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    return wi, wo, nrm, f_s[idx].astype(np.float64), np.ones(idx.shape, bool)


def _slsqp_dense(wi, wo, normal, f_s, texels, batch):
    """Per-texel SLSQP on eq. 14 whose objective recomputes the geometry from the directions at every call.

    What a straightforward user writes: the Torrance-Sparrow BRDF of the library
    (:func:`facestats.model.brdf.torrance_sparrow`) evaluated on the texel's (S, 3)
    directions inside the objective.  Returns texels/s, and E(p) of SLSQP and of the
    batch fit on those texels from the same float64 evaluator.
    """
    from scipy.optimize import minimize

    from facestats.model import brdf, fitting

    (r_lo, r_hi), (m_lo, m_hi) = fitting.DEFAULT_BOUNDS["torrance_sparrow"]
    e_slsqp, e_batch, t_total = [], [], 0.0
    for t in texels:  # the baseline: one optimiser call per texel
        n, a, b = normal[t], wi[t], wo[t]
        ci = a @ n
        y = f_s[t] * ci

        def e2(p):
            return np.mean((y - brdf.torrance_sparrow(n, a, b, p[0], p[1]) * ci) ** 2)

        t0 = time.perf_counter()
        res = minimize(e2, x0=[0.2, 0.3], method="SLSQP", bounds=[(r_lo, r_hi), (m_lo, m_hi)], options={"ftol": 1e-14})
        t_total += time.perf_counter() - t0
        e_slsqp.append(np.sqrt(res.fun))
        e_batch.append(np.sqrt(e2([batch.rho_s[t], batch.lobe[t]])))
    return len(texels) / t_total, np.asarray(e_slsqp), np.asarray(e_batch)


def bench_public_api_ratio(samples=(300, 900), n_texels=2000, n_baseline=100, grid=96):
    """Public ``fit_specular`` on dense (T, S) arrays against per-texel SLSQP, at each S in ``samples``."""
    from facestats.model import fitting

    out = {}
    for s in samples:
        wi, wo, nrm, f_s, valid = _dense_problem(s, grid, n_texels)
        fitting.fit_specular(wi[:8], wo[:8], nrm[:8], f_s[:8], valid[:8], "torrance_sparrow")  # compile/warm
        runs = []
        for _ in range(3):
            t0 = time.perf_counter()
            batch = fitting.fit_specular(wi, wo, nrm, f_s, valid, "torrance_sparrow")
            runs.append(time.perf_counter() - t0)
        tps_batch = len(nrm) / min(runs)
        base = np.sort(np.random.default_rng(1).choice(len(nrm), min(n_baseline, len(nrm)), replace=False))
        tps_slsqp, e_slsqp, e_batch = _slsqp_dense(wi, wo, nrm, f_s, base, batch)
        out[f"ratio_{s}"] = tps_batch / tps_slsqp
        out[f"batch_texels_per_s_{s}"] = tps_batch
        out[f"slsqp_texels_per_s_{s}"] = tps_slsqp
        out[f"batch_ns_per_sample_{s}"] = 1e9 / (tps_batch * s)
        out[f"median_E_batch_{s}"] = float(np.median(e_batch))
        out[f"median_E_slsqp_{s}"] = float(np.median(e_slsqp))
        out[f"texels_{s}"] = len(nrm)
    out["target_ratio"] = 200.0
    return out


def _rel(a, b, mask):
    return np.abs(a[mask] / b[mask] - 1)


def bench_accuracy(n_subjects=12, grid=48):
    from facestats.pipeline import FitSettings, fit_subject, held_out_camera_error

    pop, _, sim = _default_case(grid=grid)
    _, _, sim_bp = _default_case(specular="blinn_phong", grid=grid)
    picks = np.linspace(0, len(pop.subjects) - 1, n_subjects).astype(int)
    acc = {k: [] for k in ("albedo", "ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent", "sigma_tr")}
    flagged, held = [], []
    for i in picks:
        truth = pop[int(i)]
        face = truth.region_map > 0
        cap = sim.simulate(truth)
        ds = fit_subject(cap, pop.sigma_tr_avg, FitSettings(micro_normals=False, exclude_cameras=(7,)))
        ok = face & (ds.ts_flag.values == 0)
        flagged.append(1 - ok.sum() / face.sum())
        acc["albedo"].append(_rel(ds.albedo.values, truth.albedo, face).ravel())
        acc["ts_rho_s"].append(_rel(ds.ts_rho_s.values, truth.ts_rho_s, ok))
        acc["ts_m"].append(_rel(ds.ts_m.values, truth.ts_m, ok))
        acc["sigma_tr"].append(np.abs(ds.site_sigma_tr.values / truth.site_sigma_tr - 1).ravel())
        held.append(held_out_camera_error(ds, cap, 7))
        cap_bp = sim_bp.simulate(truth)
        dsb = fit_subject(cap_bp, pop.sigma_tr_avg, FitSettings(models=("blinn_phong",), micro_normals=False))
        okb = face & (dsb.bp_flag.values == 0)
        acc["bp_rho_s"].append(_rel(dsb.bp_rho_s.values, truth.bp_rho_s, okb))
        acc["bp_exponent"].append(_rel(dsb.bp_exponent.values, truth.bp_exponent, okb))
    out = {}
    for k, v in acc.items():
        e = np.concatenate(v)
        out[f"{k}_median"] = float(np.median(e))
        out[f"{k}_p90"] = float(np.percentile(e, 90))
    out["flagged_max"] = float(np.max(flagged))
    out["held_out_rmse_median"] = float(np.median(held))
    out["subjects"] = int(n_subjects)
    return out


def _fit_paths(paths, workers=1, client=None):
    from facestats.pipeline import FitSettings, fit_population

    t0 = time.perf_counter()
    scheduler = "synchronous" if workers == 1 else "processes"
    fit_population(paths, FitSettings(micro_normals=False), scheduler=scheduler, num_workers=workers, client=client)
    return time.perf_counter() - t0


def bench_dask_scaling(n=12, grid=48, workers=(1, 2)):
    """Subjects per minute fitting ``n`` captures from disk: 1 worker, Dask's local processes, and distributed
    clusters of each size in ``workers`` (their speedup when there are two)."""
    pop, _, sim = _default_case(grid=grid)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        paths = [sim.simulate(pop[i]).to_zarr(os.path.join(tmp, f"{i}.zarr")) for i in range(n)]
        t1 = _fit_paths(paths, 1)
        t2 = _fit_paths(paths, 2)
        out.update(
            {
                "subjects_per_min_1_worker": 60 * n / t1,
                "subjects_per_min_2_local_processes": 60 * n / t2,
                "speedup_local": t1 / t2,
            }
        )
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            return out
        for w in workers:
            with (
                LocalCluster(n_workers=w, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
                Client(cluster) as client,
            ):
                _fit_paths(paths[:2], client=client)  # warm the workers (imports)
                t = _fit_paths(paths, client=client)
            out[f"subjects_per_min_distributed_{w}_workers"] = 60 * n / t
        if len(workers) == 2:
            w0, w1 = workers
            out["speedup_distributed"] = (
                out[f"subjects_per_min_distributed_{w1}_workers"] / out[f"subjects_per_min_distributed_{w0}_workers"]
            )
    return out


def bench_determined_texels(subjects=None, skin_type="IV", region=9, param="bp_exponent"):
    """Texels whose ρs the fit leaves open, on the default store, and their weight in the query (module docstring).

    ``subjects``: the store's subjects to count (default all); the query's selection (``skin_type``) is read whole,
    its baseline over those of ``subjects``.
    """
    import facestats
    from facestats.core.conventions import REGIONS
    from facestats.io.summary import (
        DETERMINED_RELATIVE_SE,
        MODEL_PARAMS,
        region_samples,
        region_standard_errors,
    )

    model, lobe = next((m, names.index(param)) for m, names in MODEL_PARAMS.items() if param in names)
    counts = {m: np.zeros((2, len(REGIONS)), np.int64) for m in ("ts", "bp")}  # (open, all) per region
    worst = dict.fromkeys(counts, 0.0)
    baseline = []  # (sqrt(Σσ²)/n, RMS σ) of every finite σ of the region's `param`, per subject of the query
    with facestats.open_store() as st:
        q = st.query(skin_type=skin_type)
        ids = st.ids() if subjects is None else list(subjects)
        for sid in ids:
            ds = st.subject(sid)
            errors_of = {m: region_standard_errors(ds, m) for m in counts}
            for m in counts:
                values, errors = region_samples(ds, m), errors_of[m]
                if errors is None:  # a subject without standard-error maps
                    continue
                for k, r in enumerate(REGIONS):
                    rho, sd = values[r][0], errors[r][0]
                    open_ = ~(np.isfinite(sd) & (sd <= DETERMINED_RELATIVE_SE * np.abs(rho)))
                    counts[m][:, k] += open_.sum(), rho.size
                    ratio = sd[open_ & np.isfinite(sd)] / np.abs(rho[open_ & np.isfinite(sd)])
                    worst[m] = max(worst[m], float(ratio.max(initial=0.0)))
            errors = errors_of[model]
            if sid in q.subject_ids and errors is not None:
                sd = errors[region][lobe]
                sd = sd[np.isfinite(sd)]
                if sd.size:
                    baseline.append((np.sqrt(np.sum(sd**2)) / sd.size, np.sqrt(np.mean(sd**2))))
        row = next(r for r in q.to_dict()["regions"] if r["region"] == region)[param]
    out = {}
    for m, (n_open, n_all) in counts.items():
        out[f"{m}_open_pct"] = 100 * float(n_open.sum() / max(n_all.sum(), 1))
        out.update({f"{m}_open_pct_{REGIONS[r]}": 100 * float(n_open[k] / max(n_all[k], 1))
                    for k, r in enumerate(REGIONS)})  # fmt: skip
        out[f"{m}_open_texels"] = int(n_open.sum())
        out[f"{m}_texels"] = int(n_all.sum())
        out[f"{m}_worst_se_over_value"] = worst[m]
    rms = np.sqrt(np.mean(np.square(baseline), axis=0)) if baseline else (np.nan, np.nan)
    name = f"{REGIONS[region]}_{param}_{skin_type}"
    out.update({
        f"{name}_mean": row["mean"],
        f"{name}_std": row["std"],
        f"{name}_mean_se": row["mean_se"],
        f"{name}_texel_se": row["texel_se"],
        f"{name}_every_se_mean_se": float(rms[0]),
        f"{name}_every_se_texel_se": float(rms[1]),
        "subjects": len(ids),
        "query_subjects": q.count,
    })  # fmt: skip
    return out


BENCHMARKS = [
    ("public_api_ratio", bench_public_api_ratio),
    ("slsqp_ratio", bench_slsqp_ratio),
    ("accuracy", bench_accuracy),
    ("dask_scaling", bench_dask_scaling),
    ("determined_texels", bench_determined_texels),
]

#: Tiny sizes for the test suite (the full-resolution case keeps its maps finer than its grid).
SMOKE = {
    "public_api_ratio": {"samples": (40,), "n_texels": 30, "n_baseline": 2, "grid": 16},
    "slsqp_ratio": {"n_baseline": 3, "grid": 16},
    "accuracy": {"n_subjects": 1, "grid": 16},
    # clusters of one and two workers: the distributed code path and its speedup (tests/test_benchmarks.py checks the
    # ratio; the second cluster adds about 3 s); n=2: the local process pool runs only for two or more subjects
    "dask_scaling": {"n": 2, "grid": 16, "workers": (1, 2)},
    "determined_texels": {"subjects": ("S001", "S003")},
}
