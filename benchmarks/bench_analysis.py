"""Population analysis (Weyrich §5.4, §7): whole non-posterior analysis, one profile's posterior, calibration.

Benchmarks
----------
* ``population``: region PCA, CCA (999 permutations), Fig. 14 data, Table 1,
  condition differences and the population σtr posterior on a stand-in store of
  156 normal-condition subjects (plus one person under the seven conditions),
  built from ``tests/helpers.py`` subjects with 96 × 96 maps (about 7,000
  face texels each, 1.1 million region samples in all).  Target: ≤ 10 s.  The
  store calls (``subjects()``, ``region_samples()``) of the stand-in are
  included in the time; building the stand-in is not.  Baseline for the CCA
  permutation test: one :func:`cca` call per permutation.
* ``figures``: rendering the six population figures to PNG.
* ``posterior``: one 3-channel contact-sensor profile, median of 5 seeds.
  Target: ≤ 5 s.  Baseline: what one writes with emcee's defaults, one
  sampler per channel with the stretch move, run to the same 50 τ criterion.
* ``calibration``: coverage of the 90 % intervals on 600 simulated profiles.
* ``default_store``: the whole non-posterior analysis of ``facestats.open_store()``
  (the embedded store: 155 records, 48 × 48 maps), opening the store included.
  Target: ≤ 10 s.
* ``default_store_cli``: ``facestats analyze all`` on the embedded store, in
  process: the same analysis plus rendering and writing the five PNG figures
  and JSON files.
* ``default_store_posterior``: one contact-sensor profile (3 channels) of the
  embedded store, reading the subject included; median over 5 subjects and
  sites.  Target: ≤ 5 s.
"""

from __future__ import annotations

import io
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from facestats import analysis as fa  # noqa: E402
from facestats.acquire.sensor import ContactSensor  # noqa: E402
from facestats.core.published import ETA_SKIN  # noqa: E402
from facestats.errors import ValidationError  # noqa: E402
from facestats.model import dipole  # noqa: E402

_STORE = {}


def _stand_in(n=156, size=96):
    key = ("store", n, size)
    if key not in _STORE:
        from tests.helpers import make_population

        _STORE[key] = make_population(n=n, seed=1, size=size)
    return _STORE[key]


def _analyse(store, n_permutations=999):
    """Every non-posterior statistic of a store, with per-step timings."""
    steps = {}
    t = time.perf_counter()
    out = {"pca": fa.region_pca(store)}
    steps["pca_s"] = time.perf_counter() - t
    t = time.perf_counter()
    out["cca"] = fa.brdf_cca(store, n_permutations=n_permutations)
    steps["cca_s"] = time.perf_counter() - t
    t = time.perf_counter()
    out["scatter"] = fa.absorption_scattering(store)
    out["translucency"] = fa.translucency_table(store)
    try:
        out["conditions"] = fa.condition_differences(store)
    except ValidationError:  # a store without a condition series
        out["conditions"] = None
    out["population"] = fa.population_sigma_tr(store)
    steps["rest_s"] = time.perf_counter() - t
    return out, steps


def bench_population(n_subjects=156, size=96, n_permutations=999):
    store = _stand_in(n_subjects, size)
    t0 = time.perf_counter()
    res, steps = _analyse(store, n_permutations)
    total = time.perf_counter() - t0
    n_samples = sum(e.n for e in res["pca"].regions.values())
    cca = res["cca"]
    # baseline: the permutation test as a loop of cca() calls
    frame = fa.select_population(store)
    X = frame[[f"ts_{p}_mean_r{r}" for r in range(1, 11) for p in ("rho_s", "m")]].to_numpy(float)
    Y = cca.y_data.loc[frame.index].to_numpy()
    rng = np.random.default_rng(0)
    n_loop = min(100, n_permutations)
    t = time.perf_counter()
    for _ in range(n_loop):
        fa.cca(X, Y[rng.permutation(len(Y))])
    loop_999 = (time.perf_counter() - t) * n_permutations / n_loop
    t = time.perf_counter()
    fa.cca(X, Y, n_permutations=n_permutations)
    batched = time.perf_counter() - t
    return {
        "total_s": total,
        **steps,
        "subjects": res["pca"].n_subjects,
        "region_samples": n_samples,
        "cca_r1": cca.correlations[0],
        "cca_r2": cca.correlations[1],
        "perm_batched_s": batched,
        "perm_loop_s": loop_999,
        "perm_speedup": loop_999 / batched,
    }


def bench_figures(n_subjects=156, size=96):
    from facestats.analysis import plots

    store = _stand_in(n_subjects, size)
    res, _ = _analyse(store, n_permutations=0)
    t0 = time.perf_counter()
    figs = [
        plots.plot_region_pca(res["pca"]),
        plots.plot_cca(res["cca"]),
        plots.plot_absorption_scattering(res["scatter"]),
        plots.plot_translucency(res["translucency"]),
        plots.plot_conditions(res["conditions"]),
        plots.plot_population_sigma_tr(res["population"]),
    ]
    for f in figs:
        f.savefig(io.BytesIO(), format="png", dpi=80)
    return {"figures_s": time.perf_counter() - t0, "n_figures": len(figs)}


def _profile(seed):
    sensor = ContactSensor()
    rng = np.random.default_rng(seed)
    albedo = rng.uniform([0.4, 0.2, 0.15], [0.7, 0.4, 0.3])
    sigma_tr = rng.uniform([0.45, 0.85, 1.4], [0.7, 1.1, 1.7])
    sp, sa = dipole.scattering_from_albedo(albedo, sigma_tr)
    truth = np.stack([dipole.dipole_profile(sensor.fiber_distance, sp[c], sa[c]) for c in range(3)], -1)
    return sensor, sensor.capture(truth, rng)[0]


def _baseline_posterior(sensor, measured, n_walkers=16, min_tau=50):
    """emcee defaults: one stretch-move sampler per channel, vectorised over walkers, run to 50 τ."""
    import emcee

    from facestats.analysis.posterior.likelihood import LogPosterior
    from facestats.analysis.posterior.start import initial_walkers, least_squares_start

    r = sensor.fiber_distance
    lo, hi = np.log([0.01, 1e-5]), np.log([100.0, 10.0])
    steps = []
    for c in range(3):
        y = measured[:, c : c + 1]
        mask = np.isfinite(y)
        post = LogPosterior(r, y, None, mask, sensor, ETA_SKIN, lo, hi)
        theta, cov = least_squares_start(post, y, sensor.profile_std(np.maximum(y, 0)), mask)
        p0 = initial_walkers(post, theta, cov, n_walkers, np.random.default_rng(c))
        sampler = emcee.EnsembleSampler(n_walkers, 2, lambda th: post(th)[:, 0], vectorize=True)
        state, n = p0, 0
        while True:
            state = sampler.run_mcmc(state, 500, progress=False)
            n += 500
            tau = emcee.autocorr.integrated_time(sampler.get_chain(), tol=0, quiet=True).max()
            if n >= min_tau * tau or n >= 20000:
                break
        steps.append(n)
    return steps


def bench_posterior(n_seeds=5, baseline_min_tau=50):
    """One 3-channel contact-sensor profile's posterior, median over seeds, beside the emcee baseline.

    Parameters
    ----------
    n_seeds : int
        Profiles (seeds 0, 1, ...) whose posterior is timed; the figures are their median and extremes.
    baseline_min_tau : float
        The baseline's stopping rule: run each channel's sampler, 500 steps at a time, until the steps reach
        this many integrated autocorrelation times (default 50, the criterion the posterior uses; a smaller
        value stops the baseline sooner and makes its time no longer comparable).
    """
    times, taus, accs, ess, steps = [], [], [], [], []
    for seed in range(n_seeds):
        sensor, measured = _profile(seed)
        t = time.perf_counter()
        post = fa.sigma_posterior(sensor.fiber_distance, measured, seed=seed)
        times.append(time.perf_counter() - t)
        d = post.diagnostics
        taus.append(d[["tau_sigma_s_prime", "tau_sigma_a"]].to_numpy().max())
        accs.append(d["acceptance"].mean())
        ess.append(d[["ess_sigma_s_prime", "ess_sigma_a"]].to_numpy().min())
        steps.append(post.n_steps)
    sensor, measured = _profile(0)
    t = time.perf_counter()
    base_steps = _baseline_posterior(sensor, measured, min_tau=baseline_min_tau)
    base = time.perf_counter() - t
    return {
        "median_s": float(np.median(times)),
        "max_s": float(np.max(times)),
        "steps": int(np.median(steps)),
        "tau_max": float(np.max(taus)),
        "acceptance": float(np.mean(accs)),
        "min_ess": float(np.min(ess)),
        "baseline_stretch_per_channel_s": base,
        "baseline_steps": max(base_steps),
        "speedup": base / float(np.median(times)),
    }


def bench_calibration(n=600):
    sensor = ContactSensor()
    rng = np.random.default_rng(99)
    sigma_tr = rng.uniform(0.4, 2.0, n)
    albedo = rng.uniform(0.1, 0.7, n)
    sp, sa = dipole.scattering_from_albedo(albedo, sigma_tr)
    truth = dipole.dipole_profile(sensor.fiber_distance[:, None], sp[None], sa[None])
    measured, _ = sensor.capture(truth, rng)
    t = time.perf_counter()
    cover = {}
    for start in range(0, n, 200):
        sl = slice(start, min(start + 200, n))
        post = fa.sigma_posterior(sensor.fiber_distance, measured[:, sl], seed=start)
        for name, tr in (("sigma_s_prime", sp), ("sigma_a", sa), ("sigma_tr", sigma_tr)):
            iv = post.interval(name)
            cover.setdefault(name, []).append((iv[:, 0] <= tr[sl]) & (tr[sl] <= iv[:, 1]))
    out = {f"coverage_{k}": float(np.mean(np.concatenate(v))) for k, v in cover.items()}
    out["profiles"] = n
    out["s_per_profile"] = (time.perf_counter() - t) / n
    return out


def _default_store():
    import facestats
    from facestats.errors import StoreError

    try:
        return facestats.open_store()
    except StoreError:  # the embedded store is built by `facestats build --default`
        return None


def bench_default_store(n_permutations=999):
    t0 = time.perf_counter()
    store = _default_store()
    if store is None:
        return {"status": "unavailable (the embedded store is not built)"}
    res, steps = _analyse(store, n_permutations)
    return {
        "total_s": time.perf_counter() - t0,
        **steps,
        "subjects": res["pca"].n_subjects,
        "cca_r1": res["cca"].correlations[0],
        "cca_r2": res["cca"].correlations[1],
    }


def bench_default_store_cli(n_permutations=999):
    import argparse
    import contextlib
    import tempfile

    from facestats.cli.analyze import add_analyze

    if _default_store() is None:
        return {"status": "unavailable (the embedded store is not built)"}
    parser = argparse.ArgumentParser(prog="facestats")
    add_analyze(parser.add_subparsers())
    with tempfile.TemporaryDirectory() as out:
        args = parser.parse_args(["analyze", "all", "--out", out, "--permutations", str(n_permutations)])
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            args.func(args)
        total = time.perf_counter() - t0
        n_files = len(list(pathlib.Path(out).iterdir()))
    return {"total_s": total, "files": n_files}


def bench_default_store_posterior(n_profiles=5):
    store = _default_store()
    if store is None:
        return {"status": "unavailable (the embedded store is not built)"}
    cases = [("S001", "cheek"), ("S040", "forehead"), ("S080", "neck"), ("S120", "cheek"), ("S008", "forehead")]
    cases = cases[:n_profiles]
    times, steps, taus = [], [], []
    for seed, (sid, site) in enumerate(cases):
        t = time.perf_counter()
        post = fa.site_sigma_posterior(store.subject(sid), site, seed=seed)
        times.append(time.perf_counter() - t)
        steps.append(post.n_steps)
        taus.append(post.diagnostics[["tau_sigma_s_prime", "tau_sigma_a"]].to_numpy().max())
    return {
        "median_s": float(np.median(times)),
        "max_s": float(np.max(times)),
        "steps": int(np.median(steps)),
        "tau_max": float(np.max(taus)),
        "profiles": len(cases),
    }


def bench_default_store_accuracy(path=None, n_subjects=None):
    """The shipped store's fitted maps against the truth they were simulated from (README, "The default face").

    Every normal-condition subject of the store at ``path`` (None: the embedded default) is compared
    with its truth, drawn again from the default population (``DEFAULT_SEED``, the store's map size,
    the default face): the relative error |fit − truth| / truth over the face texels of the albedo
    (three channels), Torrance-Sparrow ρs and m (median and 90th percentile), and the share of face
    texels flagged for each model, the relative errors of the 20 region means of ρs and m that the CCA reads,
    and the principal correlations of Fig. 16 of the truth's region means beside the store's
    (:func:`facestats.analysis.brdf_cca`).  The Blinn-Phong maps against the Blinn-Phong truth (n = 2/m² − 2,
    ρs_BP = ρs F_r(0)), over the texels neither model flagged: the ratios' median and 10th-90th percentiles, and on
    the chin (region 9) the share above 5× and the largest; they are fits to the Torrance-Sparrow-rendered
    captures, not estimates of that truth (README, "BRDF").  ``n_subjects`` limits the comparison to the first
    subjects (the CCA needs at least 25).
    """
    import facestats
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.core.conventions import DEFAULT_SEED

    store = facestats.open_store(path) if path is not None else _default_store()
    if store is None:
        return {"status": "unavailable (the embedded store is not built)"}
    table = store.subjects()
    ids = sorted(table.index[table.condition == "normal"])[:n_subjects]
    size = int(store.subject(ids[0]).sizes["u"])
    truths = {t.subject_id: t for t in synthesize_population(DEFAULT_SEED, size, subjects=ids)}
    per_subject = [_fit_against_truth(store.subject(sid), truths[sid]) for sid in ids]
    parts = {key: np.concatenate([p[key] for p in per_subject]) for key in per_subject[0]}
    out = {"subjects": len(ids), "face_texels": int(parts["ts_flagged"].size)}
    for var in ("albedo", "ts_rho_s", "ts_m", "region_mean"):
        out[f"{var}_median_rel_error"] = float(np.median(parts[var]))
        out[f"{var}_p90_rel_error"] = float(np.percentile(parts[var], 90))
    for key in ("ts", "bp"):
        out[f"{key}_flagged"] = float(parts[f"{key}_flagged"].mean())
    for var in ("bp_rho_s", "bp_exponent"):
        out[f"{var}_over_truth_median"] = float(np.median(parts[var]))
        out[f"{var}_over_truth_p10_p90"] = [float(v) for v in np.percentile(parts[var], [10, 90])]
    out["chin_bp_rho_s_over_truth_share_above_5"] = float(np.mean(parts["chin_bp_rho_s"] > 5))
    out["chin_bp_rho_s_over_truth_max"] = float(parts["chin_bp_rho_s"].max())
    if len(ids) >= 25:
        t = [truths[sid] for sid in ids]
        x = [[getattr(s, v)[s.region_map == r].mean() for r in range(1, 11) for v in ("ts_rho_s", "ts_m")] for s in t]
        y = [[max(s.skin_type, 2), s.gender == "F", s.age] for s in t]  # as brdf_cca reads them from a store
        truth_r = fa.cca(np.array(x), np.array(y, float)).correlations
        store_r = fa.brdf_cca(store, n_permutations=0).correlations
        out.update(truth_cca_r1=float(truth_r[0]), truth_cca_r2=float(truth_r[1]))
        out.update(store_cca_r1=float(store_r[0]), store_cca_r2=float(store_r[1]))
    return out


def _fit_against_truth(ds, truth):
    """One subject's fitted maps against its truth (:func:`bench_default_store_accuracy`): relative errors of the
    face texels and of the 20 region means, flags, and the Blinn-Phong maps over the Blinn-Phong truth where
    neither model flagged the texel (all, and on the chin)."""
    region = ds.region.values
    face = region > 0
    out = {}
    for var in ("albedo", "ts_rho_s", "ts_m"):
        out[var] = (np.abs(ds[var].values[face] - getattr(truth, var)[face]) / getattr(truth, var)[face]).ravel()
    measured = ds.ts_flag.values == 0  # the index's region means (which the CCA reads) leave flagged texels out
    out["region_mean"] = np.array(
        [
            abs(ds[var].values[(region == r) & measured].mean() / getattr(truth, var)[region == r].mean() - 1)
            for var in ("ts_rho_s", "ts_m")
            for r in range(1, 11)
        ]
    )
    for key in ("ts", "bp"):
        out[f"{key}_flagged"] = ds[f"{key}_flag"].values[face] != 0
    fitted = face & (ds.ts_flag.values == 0) & (ds.bp_flag.values == 0)
    for var in ("bp_rho_s", "bp_exponent"):
        out[var] = ds[var].values[fitted] / getattr(truth, var)[fitted]
    chin = fitted & (region == 9)
    out["chin_bp_rho_s"] = ds.bp_rho_s.values[chin] / truth.bp_rho_s[chin]
    return out


BENCHMARKS = [
    ("population", bench_population),
    ("figures", bench_figures),
    ("posterior", bench_posterior),
    ("calibration", bench_calibration),
    ("default_store", bench_default_store),
    ("default_store_cli", bench_default_store_cli),
    ("default_store_posterior", bench_default_store_posterior),
    ("default_store_accuracy", bench_default_store_accuracy),
]

#: Tiny sizes for the test suite (tests/test_benchmarks.py).
SMOKE = {
    "population": {"n_subjects": 26, "size": 24, "n_permutations": 9},  # a CCA of 20 + 3 variables needs 25 rows
    "figures": {"n_subjects": 26, "size": 24},
    "posterior": {"n_seeds": 1, "baseline_min_tau": 1},  # the baseline's first 500 steps: its code, not its time
    "calibration": {"n": 20},
    "default_store": {"n_permutations": 9},
    "default_store_cli": {"n_permutations": 9},
    "default_store_posterior": {"n_profiles": 1},
    "default_store_accuracy": {"n_subjects": 2},
}
