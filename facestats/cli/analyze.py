"""The ``facestats analyze`` command: population figures and their numbers (Weyrich et al. 2006 §5.4, §7).

Usage::

    facestats analyze pca|cca|scatter|translucency|conditions|posterior|all [--store PATH] [--out DIR]
                      [--format png|svg] [options]

Each action makes one or two calls of :mod:`facestats.analysis`, draws the
result with :mod:`facestats.analysis.plots`, writes ``<action>.png`` (or
``.svg``) and ``<action>.json`` into ``--out`` and prints a short summary
beside the published values of :mod:`facestats.core.published`.  ``all`` runs
every action but ``posterior``.  Heavy modules are imported inside the
handlers, so registering the command costs nothing at start-up.

JSON outputs
------------
Every file is a JSON object with the keys ``action``, ``facestats_version``,
``store`` (the store's label: ``"default"`` or its path) and ``figure`` (the
file name of the figure written beside it), then the keys below.  Units:
σ in mm⁻¹, variances of σ in mm⁻², ℓd in mm, ρs, m and n dimensionless.
Missing values are ``null``.  Channels are keyed ``R``, ``G``, ``B``; regions
are numbered as Weyrich Fig. 15.

``pca.json`` (Fig. 15, :func:`facestats.analysis.region_pca`)
    ``model`` (``"ts"``/``"bp"``), ``parameters`` (``["rho_s", "m"]`` or
    ``["rho_s", "exponent"]``), ``n_subjects``, ``ddof``, ``k`` (ellipse
    half-axes in standard deviations); ``regions``: a list of
    ``{region, name, n, n_subjects, mean: [ρs, lobe], eigenvalues: [λ1, λ2],
    std: [σ1, σ2], axes: [[major], [minor]] (unit directions in (ρs, lobe)),
    angle_deg (major axis from the ρs axis), total_variance (λ1 + λ2)}``;
    ``orderings``: ``{highest_rho_s: 5 regions, largest_variance: 5 regions
    (by total variance), smallest_lobe: region}`` and ``published`` (the §7
    orderings of the Torrance-Sparrow fit, ``null`` for Blinn-Phong).
``cca.json`` (Fig. 16, :func:`facestats.analysis.brdf_cca`)
    ``model``, ``n_subjects``, ``x_variables``, ``y_variables``, ``coding``,
    ``principal_correlations`` (all, descending), ``published_principal``,
    ``direct_correlations`` and ``direct_p_value`` (by variable),
    ``published_direct``, ``dimensions`` (per canonical dimension:
    ``dimension, correlation, wilks_lambda, chi2, df, p_value,
    permutation_p``), ``n_permutations``, ``seed``, ``y_loadings`` (by
    variable, per dimension), ``dropped`` (subjects left out), ``projections``
    (``subject_id`` and the canonical variates ``dimension_1``,
    ``dimension_2``: the points of Fig. 16).
``scatter.json`` (Fig. 14, :func:`facestats.analysis.absorption_scattering`)
    ``site`` (``null``: subject-level σ from α_avg and σtrAvg, as the paper),
    ``n_subjects``; ``channels``: by channel ``{n, sigma_a: {mean, std, min,
    max}, sigma_s_prime: {...}, pearson_log, spearman}`` (Pearson r of
    (σ's, ln σa), Spearman ρ of (σ's, σa)); ``by_skin_type``: by skin type
    (Roman numeral) and channel ``{n, sigma_a_mean, sigma_s_prime_mean}``.
``translucency.json`` (Table 1 and §5.4, :func:`facestats.analysis.translucency_table`)
    ``n_subjects``, ``ddof``; ``table``: a list of ``{site, channel, mean,
    var, std, n, paper_mean, paper_var}``; ``sigma_tr_avg`` and
    ``published_sigma_tr_avg`` (by channel); ``ell_d_min`` and ``ell_d_max``
    (``{subject_id, R, G, B}``: least and most translucent subject) with
    ``published_ell_d_min``/``published_ell_d_max``; ``var_note``.
``conditions.json`` (§7, :func:`facestats.analysis.condition_differences`)
    ``model``, ``person_id``, ``reference``, ``conditions``; ``values``: a list
    of ``{condition, region, rho_s, lobe, rho_s_std, lobe_std, n}``;
    ``differences``: a list of ``{condition, region, d_rho_s, d_lobe, z_rho_s,
    z_lobe}`` against the reference; ``mean_differences``: by condition the
    region-averaged ``{d_rho_s, d_lobe}``; ``distance``: ``{conditions,
    matrix}`` (in within-region standard deviations).
``posterior.json`` (§5.4 with uncertainty, :func:`facestats.analysis.site_sigma_posterior`)
    ``subject_id``, ``site``, ``seed``, ``noise``, ``level``, ``n_walkers``,
    ``n_steps``, ``converged``; ``channels``: by channel ``{sigma_s_prime,
    sigma_a, sigma_tr, ell_d: {median, mean, std, lo, hi}, diagnostics: {tau,
    acceptance, ess, steps_over_tau, chi2_dof, converged}, least_squares:
    {sigma_s_prime, sigma_a}, stored_fit: {sigma_s_prime, sigma_a, sigma_tr}}``
    (``stored_fit``: the point fit in the store, ``null`` if absent).
``posterior_population.json`` (``posterior --population``, :func:`facestats.analysis.population_sigma_tr`)
    ``model``, ``level``, ``skin_types`` (Roman numerals); ``summary``: a list
    of ``{skin_type, channel, n, sample_mean, median, mean, lo, hi}``;
    ``hyper``: by channel ``{sigma_w, mu_median, mu_lo, mu_hi, tau_median,
    tau_lo, tau_hi}`` (``null`` for the independent model).
"""

from __future__ import annotations

import sys

__all__ = ["add_analyze", "ACTIONS", "BATCH_ACTIONS"]

#: Sub-actions of ``facestats analyze``.
ACTIONS = ("pca", "cca", "scatter", "translucency", "conditions", "posterior", "all")
#: What ``all`` runs (every analysis but the per-profile posterior).
BATCH_ACTIONS = ("pca", "cca", "scatter", "translucency", "conditions")

_MODEL_NAMES = {"ts": "Torrance-Sparrow", "bp": "Blinn-Phong"}


# -- JSON ---------------------------------------------------------------------------
def _clean(obj):
    """A JSON-serialisable copy: numpy scalars and arrays to Python, non-finite floats to None."""
    import math

    import numpy as np

    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if obj is None or isinstance(obj, str):
        return obj
    return str(obj)


def _by_channel(values):
    from facestats.core.conventions import CHANNELS

    return {ch: v for ch, v in zip(CHANNELS, values)}


def _records(frame):
    """Rows of a DataFrame (index reset) as a list of dicts."""
    return frame.reset_index().to_dict(orient="records")


# -- the actions ------------------------------------------------------------------
# Each returns (figure, document, summary lines).


def _pca(store, args):
    import numpy as np

    from facestats.analysis import region_pca
    from facestats.analysis.plots import plot_region_pca
    from facestats.core.published import HIGHEST_RHO_S, LARGEST_VARIANCE, SMALLEST_M

    res = region_pca(store, model=args.model)
    k = 1.0
    regions = []
    for r, e in res.regions.items():
        regions.append(
            {
                "region": r,
                "name": e.name,
                "n": e.n,
                "n_subjects": e.n_subjects,
                "mean": e.mean,
                "eigenvalues": e.eigenvalues,
                "std": e.std,
                "axes": e.eigenvectors.T,
                "angle_deg": np.degrees(e.angle),
                "total_variance": float(e.eigenvalues.sum()),
            }
        )
    mean_rho = {r: e.mean[0] for r, e in res.regions.items()}
    mean_lobe = {r: e.mean[1] for r, e in res.regions.items()}
    total = {r: float(e.eigenvalues.sum()) for r, e in res.regions.items()}
    orderings = {
        "highest_rho_s": sorted(mean_rho, key=mean_rho.get, reverse=True)[:5],
        "largest_variance": sorted(total, key=total.get, reverse=True)[:5],
        # the smoothest lobe: smallest m (Torrance-Sparrow), largest exponent n (Blinn-Phong)
        "smallest_lobe": (min if args.model == "ts" else max)(mean_lobe, key=mean_lobe.get),
    }
    published = None
    if args.model == "ts":
        published = {
            "highest_rho_s": list(HIGHEST_RHO_S),
            "largest_variance": list(LARGEST_VARIANCE),
            "smallest_m": SMALLEST_M,
        }
    doc = {
        "model": res.model,
        "parameters": list(res.parameters),
        "n_subjects": res.n_subjects,
        "ddof": res.ddof,
        "k": k,
        "regions": regions,
        "orderings": orderings,
        "published": published,
    }
    lobe = res.parameters[1]
    lines = [
        f"Region PCA of the {_MODEL_NAMES[res.model]} parameters (rho_s, {lobe}), {res.n_subjects} subjects "
        f"(Weyrich Fig. 15)",
        f"{'region':<13}{'n':>7}  {'rho_s':>7}  {lobe:>8}  {'sd1':>8}  {'sd2':>8}  {'angle':>6}",
    ]
    for r, e in res.regions.items():
        lines.append(
            f"{r:>2} {e.name:<10}{e.n:>7}  {e.mean[0]:7.4f}  {e.mean[1]:8.4f}  {e.std[0]:8.4f}  "
            f"{e.std[1]:8.4f}  {np.degrees(e.angle):5.0f}d"
        )
    smooth = "smallest m" if args.model == "ts" else "largest n"
    pub = published or {}
    lines += [
        f"highest rho_s:    {_regions(orderings['highest_rho_s'])}" + _paper(pub.get("highest_rho_s")),
        f"largest variance: {_regions(orderings['largest_variance'])}" + _paper(pub.get("largest_variance")),
        f"{smooth + ':':<18}{orderings['smallest_lobe']}" + (f"   (paper: {SMALLEST_M})" if published else ""),
    ]
    return plot_region_pca(res, k=k), doc, lines


def _regions(ids):
    return " ".join(str(r) for r in ids)


def _paper(ids):
    return f"   (paper: {_regions(ids)})" if ids else ""


def _cca(store, args):
    from facestats.analysis import brdf_cca
    from facestats.analysis.plots import plot_cca
    from facestats.core.published import CCA_DIRECT, CCA_PRINCIPAL

    if args.permutations < 0:
        from facestats.errors import ValidationError

        raise ValidationError(f"--permutations must be >= 0, got {args.permutations}")
    res = brdf_cca(store, model=args.model, n_permutations=args.permutations, seed=args.seed)
    dims = _records(res.summary())
    if res.permutation_p is None:
        for d in dims:
            d["permutation_p"] = None
    k = min(2, res.projections.shape[1])
    projections = {"subject_id": [str(s) for s in res.index]}
    for i in range(k):
        projections[f"dimension_{i + 1}"] = res.projections[:, i]
    doc = {
        "model": args.model,
        "n_subjects": res.n,
        "x_variables": list(res.x_names),
        "y_variables": list(res.y_names),
        "coding": {
            "skin_type": "Fitzpatrick number, type I grouped into II (2-6)",
            "gender": "0 = M, 1 = F",
            "age": "years",
        },
        "principal_correlations": res.correlations,
        "published_principal": list(CCA_PRINCIPAL),
        "direct_correlations": dict(zip(res.y_names, res.direct_correlations)),
        "direct_p_value": dict(zip(res.y_names, res.direct_p_value)),
        "published_direct": dict(CCA_DIRECT),
        "dimensions": dims,
        "n_permutations": res.n_permutations,
        "seed": args.seed,
        "y_loadings": {n: res.y_loadings[j] for j, n in enumerate(res.y_names)},
        "dropped": [str(s) for s in res.dropped],
        "projections": projections,
    }
    paper = "Weyrich 2006" + (" (TS)" if args.model != "ts" else "")
    lines = [
        f"CCA of the {_MODEL_NAMES[args.model]} region means ({len(res.x_names)} variables) against "
        f"{', '.join(res.y_names)}: {res.n} subjects (Weyrich Fig. 16)",
        f"{'':<22}{'ours':>7}  {paper:>12}",
    ]
    for i, p in enumerate(CCA_PRINCIPAL):
        if i < res.correlations.size:
            lines.append(f"{'principal r' + str(i + 1):<22}{res.correlations[i]:7.3f}  {p:>12.3f}")
    for name, r in zip(res.y_names, res.direct_correlations):
        lines.append(f"{'direct ' + name:<22}{r:7.3f}  {CCA_DIRECT.get(name, float('nan')):>12.3f}")
    if res.permutation_p is not None:
        lines.append(
            f"permutation test ({res.n_permutations} permutations): p = "
            + ", ".join(f"{p:.3g}" for p in res.permutation_p)
        )
    lines.append("Bartlett chi2 test: p = " + ", ".join(f"{p:.3g}" for p in res.p_value))
    if res.dropped:
        lines.append(f"left out (missing region means): {len(res.dropped)} subject(s)")
    return plot_cca(res), doc, lines


def _scatter(store, args):
    from facestats.analysis import absorption_scattering
    from facestats.analysis.plots import plot_absorption_scattering
    from facestats.core.conventions import CHANNELS, ROMAN

    res = absorption_scattering(store, site=args.site)
    corr = res.correlations()
    d = res.data
    channels = {}
    for ch in CHANNELS:
        sub = d[d["channel"] == ch]
        channels[ch] = {
            "n": len(sub),
            **{
                p: {"mean": sub[p].mean(), "std": sub[p].std(ddof=1), "min": sub[p].min(), "max": sub[p].max()}
                for p in ("sigma_a", "sigma_s_prime")
            },
            "pearson_log": corr.loc[ch, "pearson_log"],
            "spearman": corr.loc[ch, "spearman"],
        }
    g = d.groupby(["skin_type", "channel"])
    means = g[["sigma_a", "sigma_s_prime"]].mean()
    counts = g.size()
    by_type = {}
    for (st, ch), row in means.iterrows():
        by_type.setdefault(ROMAN[int(st)], {})[ch] = {
            "n": counts.loc[(st, ch)],
            "sigma_a_mean": row["sigma_a"],
            "sigma_s_prime_mean": row["sigma_s_prime"],
        }
    doc = {"site": args.site, "n_subjects": d["subject_id"].nunique(), "channels": channels, "by_skin_type": by_type}
    src = "from albedo and sigma_trAvg" if args.site is None else f"fitted at the {args.site}"
    lines = [
        f"Absorption against reduced scattering ({src}), {doc['n_subjects']} subjects (Weyrich Fig. 14)",
        f"{'channel':<8}{'sigma_a mean':>13}{'sigma_s_prime mean':>20}{'r(ss, ln sa)':>14}{'Spearman':>10}",
    ]
    for ch in CHANNELS:
        c = channels[ch]
        lines.append(
            f"{ch:<8}{c['sigma_a']['mean']:13.4f}{c['sigma_s_prime']['mean']:20.4f}"
            f"{c['pearson_log']:14.3f}{c['spearman']:10.3f}"
        )
    lines.append(
        "sigma_a falls as sigma_s_prime rises (negative correlations), as in the paper; "
        "darker skin types absorb more and scatter less"
    )
    return plot_absorption_scattering(res), doc, lines


_VAR_NOTE = (
    "The synthetic population of the default store reads Table 1's 'Var.' column as a standard deviation "
    "(facestats.acquire.synthetic.population): compare the paper's 'Var.' with our 'std'.  'var' is the sample "
    "variance of the per-subject sigma_tr."
)


def _translucency(store, args):
    from facestats.analysis import translucency_table
    from facestats.analysis.plots import plot_translucency
    from facestats.core.published import ELL_D_MAX, ELL_D_MIN, SIGMA_TR_AVG

    t = translucency_table(store)
    cmp = t.compare_published()
    table = [
        {"site": site, "channel": ch, **row.to_dict(), "n": t.table.loc[ch, (site, "n")]}
        for (site, ch), row in cmp.iterrows()
    ]
    n = int(len(t.subjects))
    doc = {
        "n_subjects": n,
        "ddof": t.ddof,
        "table": table,
        "sigma_tr_avg": _by_channel(t.sigma_tr_avg),
        "published_sigma_tr_avg": _by_channel(SIGMA_TR_AVG),
        "ell_d_min": {"subject_id": t.min_subject, **_by_channel(t.ell_d_min)},
        "ell_d_max": {"subject_id": t.max_subject, **_by_channel(t.ell_d_max)},
        "published_ell_d_min": _by_channel(ELL_D_MIN),
        "published_ell_d_max": _by_channel(ELL_D_MAX),
        "var_note": _VAR_NOTE,
    }
    lines = [
        f"Table 1: sigma_tr (1/mm) per site and channel, {n} subjects (Weyrich Table 1, §5.4)",
        f"{'site':<9}{'ch':<3}{'mean':>8}{'paper':>8}   {'var':>7}{'std':>8}{'paper Var.':>12}",
    ]
    for (site, ch), row in cmp.iterrows():
        lines.append(
            f"{site:<9}{ch:<3}{row['mean']:8.4f}{row['paper_mean']:8.4f}   {row['var']:7.4f}"
            f"{row['std']:8.4f}{row['paper_var']:12.4f}"
        )

    def rgb(v):
        return " ".join(f"{x:.4f}" for x in v)

    lines += [
        f"sigma_trAvg (cheek and forehead): {rgb(t.sigma_tr_avg)}   (paper {rgb(SIGMA_TR_AVG)})",
        f"l_d least translucent {t.min_subject}: {rgb(t.ell_d_min)} mm   (paper {rgb(ELL_D_MIN)})",
        f"l_d most translucent {t.max_subject}: {rgb(t.ell_d_max)} mm   (paper {rgb(ELL_D_MAX)})",
        "note: " + _VAR_NOTE,
    ]
    return plot_translucency(t), doc, lines


def _conditions(store, args):
    from facestats.analysis import condition_differences
    from facestats.analysis.plots import plot_conditions

    res = condition_differences(store, model=args.model)
    diff = res.differences
    mean_diff = diff.groupby(level="condition", sort=False)[["d_rho_s", "d_lobe"]].mean()
    dist = res.distance
    doc = {
        "model": args.model,
        "person_id": res.person_id,
        "reference": res.reference,
        "conditions": list(res.conditions),
        "values": _records(res.values.drop(columns="subject_id")),
        "differences": _records(diff),
        "mean_differences": {c: {"d_rho_s": r["d_rho_s"], "d_lobe": r["d_lobe"]} for c, r in mean_diff.iterrows()},
        "distance": {"conditions": list(dist.index), "matrix": dist.to_numpy()},
    }
    lobe = res.lobe_name
    lines = [
        f"{_MODEL_NAMES[args.model]} BRDF of person {res.person_id} under {len(res.conditions)} conditions "
        f"(Weyrich §7), mean over regions against {res.reference!r}",
        f"{'condition':<10}{'d rho_s':>9}{'d ' + lobe:>11}{'distance':>10}",
    ]
    for c, r in mean_diff.iterrows():
        lines.append(f"{c:<10}{r['d_rho_s']:9.4f}{r['d_lobe']:11.4f}{dist.loc[c, res.reference]:10.2f}")
    m = dist.to_numpy()
    i, j = divmod(int(m.argmax()), m.shape[1])
    lines.append(
        f"most different pair: {dist.index[i]} / {dist.columns[j]} ({m[i, j]:.1f} within-region sd); "
        "the paper notes lotion / hot against cold / powder"
    )
    return plot_conditions(res), doc, lines


def _default_subject(store):
    """The first subject (by id) measured under normal conditions, else the first subject."""
    frame = store.subjects()
    if len(frame) == 0:
        from facestats.errors import StoreError

        raise StoreError(f"store {store.label} holds no subject")
    normal = frame.index[frame["condition"] == "normal"]
    return str(normal[0] if len(normal) else frame.index[0])


def _posterior(store, args):
    import warnings

    import numpy as np

    from facestats.analysis import site_sigma_posterior
    from facestats.analysis.plots import plot_sigma_posterior
    from facestats.errors import ConvergenceWarning

    sid = args.subject or _default_subject(store)
    site = args.site or "cheek"
    ds = store.subject(sid)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        post = site_sigma_posterior(ds, site, std=args.noise, seed=args.seed)
    for w in caught:
        if issubclass(w.category, ConvergenceWarning):
            print(f"facestats: warning: {w.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    stored = {}
    for p in ("sigma_s_prime", "sigma_a", "sigma_tr"):
        var = f"site_{p}"
        stored[p] = ds[var].sel(site=site).values if var in ds.data_vars else np.full(len(post.labels), np.nan)
    channels = {}
    for j, lab in enumerate(post.labels):
        d = post.diagnostics.loc[lab]
        entry = {p: post.summary.loc[(lab, p)].to_dict() for p in ("sigma_s_prime", "sigma_a", "sigma_tr", "ell_d")}
        entry["diagnostics"] = {
            "tau": max(d["tau_sigma_s_prime"], d["tau_sigma_a"]),
            "acceptance": d["acceptance"],
            "ess": min(d["ess_sigma_s_prime"], d["ess_sigma_a"]),
            "steps_over_tau": d["steps_over_tau"],
            "chi2_dof": d["chi2_dof"],
            "converged": bool(d["converged"]),
        }
        entry["least_squares"] = post.least_squares.loc[lab].to_dict()
        entry["stored_fit"] = {p: float(stored[p][j]) for p in stored}
        channels[lab] = entry
    doc = {
        "subject_id": sid,
        "site": site,
        "seed": args.seed,
        "noise": post.noise,
        "level": post.level,
        "n_walkers": post.n_walkers,
        "n_steps": post.n_steps,
        "converged": post.converged,
        "channels": channels,
    }
    lines = [
        f"Posterior of (sigma_s_prime, sigma_a) of {sid}, {site} profile (Weyrich §5.4 with uncertainty): "
        f"median [{post.level:.0%} interval]",
        f"{'ch':<3}{'sigma_s_prime (1/mm)':>28}{'sigma_a (1/mm)':>28}{'sigma_tr (1/mm)':>28}{'l_d (mm)':>28}",
    ]
    for lab in post.labels:
        cells = []
        for p in ("sigma_s_prime", "sigma_a", "sigma_tr", "ell_d"):
            s = channels[lab][p]
            cells.append(f"{s['median']:#.4g} [{s['lo']:#.4g}, {s['hi']:#.4g}]".rjust(28))
        lines.append(f"{lab:<3}" + "".join(cells))
    lines.append(
        f"{post.n_steps} steps x {post.n_walkers} walkers; "
        + ", ".join(
            f"{lab}: tau {channels[lab]['diagnostics']['tau']:.1f}, "
            f"chi2/dof {channels[lab]['diagnostics']['chi2_dof']:.2f}"
            for lab in post.labels
        )
        + ("" if post.converged else "  (NOT CONVERGED)")
    )
    if np.isfinite(stored["sigma_tr"]).all():
        lines.append("stored point fit sigma_tr: " + " ".join(f"{v:.4g}" for v in stored["sigma_tr"]))
    fig = plot_sigma_posterior(post)
    fig.suptitle(f"Posterior of the scattering coefficients: {sid}, {site} profile", fontsize=10)
    return fig, doc, lines


def _population_posterior(store, args):
    from facestats.analysis import population_sigma_tr
    from facestats.analysis.plots import plot_population_sigma_tr
    from facestats.core.conventions import CHANNELS, ROMAN

    res = population_sigma_tr(store, seed=args.seed)
    summary = _records(res.summary)
    for row in summary:
        row["skin_type"] = ROMAN[int(row["skin_type"])]
    hyper = None if res.hyper is None else {ch: row.to_dict() for ch, row in res.hyper.iterrows()}
    doc = {
        "model": res.model,
        "level": res.level,
        "skin_types": [ROMAN[t] for t in res.skin_types],
        "seed": args.seed,
        "summary": summary,
        "hyper": hyper,
    }
    lines = [
        f"Posterior of the mean sigma_tr (1/mm) per skin type ({res.model} model): median [{res.level:.0%} interval]"
    ]
    for st in res.skin_types:
        cells = []
        for ch in CHANNELS:
            r = res.summary.loc[(st, ch)]
            cells.append(f"{ch} {r['median']:.3f} [{r['lo']:.3f}, {r['hi']:.3f}]")
        lines.append(f"type {ROMAN[st]:<4}n={int(res.summary.loc[(st, 'R'), 'n']):<4}" + "   ".join(cells))
    return plot_population_sigma_tr(res), doc, lines


_HANDLERS = {"pca": _pca, "cca": _cca, "scatter": _scatter, "translucency": _translucency, "conditions": _conditions}


# -- writing ------------------------------------------------------------------------
def _out_dir(path):
    from pathlib import Path

    from facestats.errors import ValidationError

    out = Path(path).expanduser()
    if out.exists() and not out.is_dir():
        raise ValidationError(f"--out must be a directory, got the file {str(out)!r}")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValidationError(f"--out: cannot create directory {str(out)!r}: {exc.strerror}") from None
    return out


def _write(out, name, fig, doc, fmt, store):
    """Write ``name.<fmt>`` and ``name.json``; return their paths."""
    import json

    from facestats.core.version import __version__

    figure = out / f"{name}.{fmt}"
    fig.savefig(figure, format=fmt, dpi=150)
    head = {"action": name, "facestats_version": __version__, "store": store.label, "figure": figure.name}
    path = out / f"{name}.json"
    with open(path, "w", encoding="utf-8") as f:
        json.dump(_clean({**head, **doc}), f, indent=2, allow_nan=False)
        f.write("\n")
    return figure, path


def _emit(lines, files):
    for line in lines:
        print(line)
    print("wrote " + ", ".join(str(f) for f in files))


def _cmd_analyze(args) -> int:
    from facestats.errors import ValidationError
    from facestats.io.store import open_store

    out = _out_dir(args.out)
    with open_store(args.store) as store:
        if args.action == "posterior":
            if args.population:
                if args.subject or args.site:
                    raise ValidationError("posterior --population takes no --subject or --site")
                name, handler = "posterior_population", _population_posterior
            else:
                name, handler = "posterior", _posterior
            fig, doc, lines = handler(store, args)
            _emit(lines, _write(out, name, fig, doc, args.format, store))
            return 0
        actions = BATCH_ACTIONS if args.action == "all" else (args.action,)
        for i, action in enumerate(actions):
            if i:
                print()
            try:
                fig, doc, lines = _HANDLERS[action](store, args)
            except ValidationError as exc:
                # ``all`` on a store without a condition series: skip that analysis, run the others.
                if args.action == "all" and action == "conditions":
                    print(f"conditions: skipped ({exc})")
                    continue
                raise
            _emit(lines, _write(out, action, fig, doc, args.format, store))
    return 0


# -- registration -----------------------------------------------------------------
def _common(p, model=False):
    p.add_argument(
        "--store",
        default=None,
        metavar="PATH",
        help="a store directory (X.zarr) or zip; default: the store embedded in facestats",
    )
    p.add_argument("--out", default=".", metavar="DIR", help="output directory (created if missing; default: .)")
    p.add_argument("--format", choices=("png", "svg"), default="png", help="figure format (default png)")
    if model:
        p.add_argument(
            "--model",
            choices=("ts", "bp"),
            default="ts",
            help="specular model: ts = Torrance-Sparrow (rho_s, m), as the paper; bp = Blinn-Phong (rho_s, n)",
        )


def _permutations(p):
    p.add_argument(
        "--permutations",
        type=int,
        default=999,
        metavar="N",
        help="permutations of the CCA permutation test (default 999; 0 skips it)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the permutations (default 0)")


def add_analyze(subparsers):
    """Register ``facestats analyze`` and its actions.

    Parameters
    ----------
    subparsers : argparse sub-parsers action
        What ``ArgumentParser.add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    argparse.ArgumentParser
        The ``analyze`` parser; every action sets ``func`` to its handler, which
        returns the exit status (errors raise :class:`facestats.FacestatsError`).
    """
    p = subparsers.add_parser(
        "analyze",
        help="population analysis: Fig. 14-16, Table 1, condition differences, sigma posteriors (PNG/SVG + JSON)",
        description=(
            "Population analysis of a parameter store (Weyrich et al. 2006 §5.4 and §7). Each action writes "
            "ACTION.png (or .svg) and ACTION.json (the numbers) into --out and prints a summary beside the "
            "published values; 'all' runs every action but 'posterior'."
        ),
    )
    sub = p.add_subparsers(title="actions", metavar="ACTION", dest="action", required=True)
    a = sub.add_parser(
        "pca",
        help="region PCA ellipses of the specular parameters (Fig. 15)",
        description="PCA of the (rho_s, m) samples of every face region over the subjects measured "
        "under normal conditions; ellipses at ±1 sd (Weyrich Fig. 15).",
    )
    _common(a, model=True)
    a = sub.add_parser(
        "cca",
        help="canonical correlation of region BRDF means with skin type, gender, age (Fig. 16)",
        description="CCA of the 20 region means of (rho_s, m) against skin type, gender and age, "
        "with principal and direct correlations, Bartlett and permutation tests "
        "(Weyrich Fig. 16).",
    )
    _common(a, model=True)
    _permutations(a)
    a = sub.add_parser(
        "scatter",
        help="sigma_a against sigma_s' per subject and channel (Fig. 14)",
        description="Absorption against reduced scattering of every subject per channel, coloured by "
        "skin type, marker by gender, size by age (Weyrich Fig. 14).",
    )
    _common(a)
    a.add_argument(
        "--site",
        default=None,
        metavar="SITE",
        help="cheek, forehead or neck: coefficients fitted at that site (default: subject-level, "
        "from the albedo and sigma_trAvg as in the paper)",
    )
    a = sub.add_parser(
        "translucency",
        help="mean and spread of sigma_tr per site, sigma_trAvg, l_d extremes (Table 1)",
        description="Weyrich Table 1 (mean and variance of sigma_tr per site and channel) with the "
        "published values side by side, sigma_trAvg and the least/most translucent "
        "subjects.",
    )
    _common(a)
    a = sub.add_parser(
        "conditions",
        help="BRDF differences of the person measured under seven conditions (§7)",
        description="Per-region differences of the specular parameters of one person between external "
        "conditions (normal, cold, hot, sweaty, makeup, lotion, powder), Weyrich §7.",
    )
    _common(a, model=True)
    a = sub.add_parser(
        "posterior",
        help="Bayesian posterior of sigma_s', sigma_a, sigma_tr of one sensor profile",
        description="emcee posterior of (sigma_s', sigma_a) per channel of one contact-sensor profile, "
        "with sigma_tr and l_d (Weyrich §5.4 with uncertainty). --population instead gives "
        "the posterior of the mean sigma_tr per skin type.",
    )
    _common(a)
    a.add_argument(
        "--subject",
        default=None,
        metavar="ID",
        help="subject id (default: the first subject measured under normal conditions)",
    )
    a.add_argument("--site", default=None, metavar="SITE", help="cheek, forehead or neck (default cheek)")
    a.add_argument(
        "--noise",
        choices=("model", "stored"),
        default="model",
        help="likelihood noise: the sensor noise model (default) or the stored profile std",
    )
    a.add_argument("--seed", type=int, default=0, help="sampler seed (default 0)")
    a.add_argument(
        "--population",
        action="store_true",
        help="posterior of the mean sigma_tr per skin type instead (writes posterior_population.*)",
    )
    a = sub.add_parser(
        "all",
        help="every analysis but the posterior",
        description="Run pca, cca, scatter, translucency and conditions (skipped when the store has "
        "no person measured under several conditions).",
    )
    _common(a, model=True)
    _permutations(a)
    a.set_defaults(site=None)
    for action in ACTIONS:
        sub.choices[action].set_defaults(func=_cmd_analyze)
    return p
