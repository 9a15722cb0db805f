"""Figures of the population analysis (Weyrich et al. 2006 Fig. 14-16, Table 1 and beyond).

Every function takes a result object of :mod:`facestats.analysis` and returns a
:class:`matplotlib.figure.Figure` (built without pyplot, so nothing is shown
and no global state changes; save it with ``fig.savefig``).  Functions that
draw one panel accept an ``ax`` to draw into instead.

Encoding of subjects, as in the paper's Fig. 14 and 16: colour = skin type
(light = I/II to black = VI), marker = gender (◇ = F, ○ = M), marker size =
age (larger = older).
"""

from __future__ import annotations

import numpy as np

from facestats.analysis.population import MODEL_NAMES
from facestats.core.conventions import CHANNELS, REGIONS, skin_type_label
from facestats.core.published import TABLE1_MEAN

__all__ = [
    "skin_type_color",
    "plot_region_pca",
    "plot_cca",
    "plot_absorption_scattering",
    "plot_translucency",
    "plot_conditions",
    "plot_sigma_posterior",
    "plot_site_posterior",
    "plot_population_sigma_tr",
    "plot_model_errors",
]

#: Skin type colours from light (I, II) to black (VI).
_LIGHT = np.array([0.96, 0.86, 0.72])
_CHANNEL_COLORS = {"R": "tab:red", "G": "tab:green", "B": "tab:blue"}
_MARKERS = {"F": "D", "M": "o"}


def skin_type_color(skin_type):
    """RGB colour of a Fitzpatrick skin type: light for I-II, black for VI (linear in between).

    Parameters
    ----------
    skin_type : int or array_like
        Skin type(s) as numbers 1-6 (values outside are clipped to the end colours).

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        RGB in [0, 1], one colour per skin type (shape ``(3,)`` for a scalar).
    """
    t = np.clip((np.asarray(skin_type, dtype=float) - 2) / 4, 0, 1)
    return _LIGHT * (1 - t)[..., None]


def _age_size(age):
    """Marker area (pt²) growing with age: 15 at 20 years, 90 at 60."""
    return np.clip(15 + (np.asarray(age, dtype=float) - 20) * 75 / 40, 8, 130)


def _new_figure(figsize):
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, layout="constrained")


def _axes(ax, figsize):
    if ax is not None:
        return ax.figure, ax
    fig = _new_figure(figsize)
    return fig, fig.add_subplot()


def _encoded_scatter(ax, x, y, skin_type, gender, age):
    """Scatter with the paper's encoding (colour = skin type, marker = gender, size = age)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    colors = skin_type_color(skin_type)
    sizes = _age_size(age)
    gender = np.asarray(gender).astype(str)
    for g, marker in _MARKERS.items():
        sel = gender == g
        if sel.any():
            ax.scatter(x[sel], y[sel], s=sizes[sel], c=colors[sel], marker=marker, edgecolors="0.35", linewidths=0.5)


def _encoding_legend(ax, skin_types, genders, ages, grouped_i_ii=False):
    """Legend of the encoding: the skin types and genders present, the youngest and oldest age (2 is "I-II" where
    ``grouped_i_ii``)."""
    from matplotlib.lines import Line2D

    handles = []
    for st in sorted(set(int(s) for s in skin_types)):
        label = f"type {skin_type_label(st, grouped_i_ii)}"
        handles.append(Line2D([], [], ls="", marker="s", ms=8, mfc=skin_type_color(st), mec="0.35", label=label))
    present = set(np.asarray(genders).astype(str))
    for g, marker in _MARKERS.items():
        if g in present:
            handles.append(Line2D([], [], ls="", marker=marker, ms=6, mfc="white", mec="0.2", label=g))
    ages = np.asarray(ages, float)
    if ages.size and np.nanmax(ages) > np.nanmin(ages):
        for a in (np.nanmin(ages), np.nanmax(ages)):
            handles.append(
                Line2D([], [], ls="", marker="o", ms=np.sqrt(_age_size(a)), mfc="0.8", mec="0.35", label=f"age {a:.0f}")
            )
    ax.legend(handles=handles, fontsize=7, loc="best", framealpha=0.8)


def plot_region_pca(result, k=1.0, ax=None, annotate=True):
    """Fig. 15 (right): per-region PCA ellipses of (ρs, m) (or (ρs, n) for Blinn-Phong).

    Each ellipse is centred on the region mean; its axes follow the
    eigenvectors with half-axes k·σ_i = k·sqrt(λ_i) (k = 1: one standard
    deviation, as stated in the title).

    Parameters
    ----------
    result : RegionPCA
    k : float
        Half-axes in standard deviations.
    ax : matplotlib Axes, optional
    annotate : bool
        Write the region number at each centre.

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    from matplotlib.patches import Ellipse

    fig, ax = _axes(ax, (7.5, 5))
    cmap = _tab10()
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    for r, e in result.regions.items():
        color = cmap[(r - 1) % 10]
        w, h = 2 * e.half_axes(k)
        ax.add_patch(
            Ellipse(
                e.mean,
                w,
                h,
                angle=np.degrees(e.angle),
                facecolor=(*color, 0.18),
                edgecolor=color,
                lw=1.5,
                label=f"{r} {e.name}",
            )
        )
        for i in range(2):
            d = e.eigenvectors[:, i] * e.half_axes(k)[i]
            ax.plot([e.mean[0] - d[0], e.mean[0] + d[0]], [e.mean[1] - d[1], e.mean[1] + d[1]], color=color, lw=0.8)
        if annotate:
            ax.annotate(str(r), e.mean, ha="center", va="center", fontsize=9, fontweight="bold", color="0.1")
        ext = np.abs(e.eigenvectors) @ e.half_axes(k)
        lo, hi = np.minimum(lo, e.mean - ext), np.maximum(hi, e.mean + ext)
    pad = 0.08 * (hi - lo)
    ax.set_xlim(lo[0] - pad[0], hi[0] + pad[0])
    ax.set_ylim(lo[1] - pad[1], hi[1] + pad[1])
    lobe = {"m": "m (Beckmann roughness)", "exponent": "n (Blinn-Phong exponent)"}[result.parameters[1]]
    ax.set_xlabel(r"$\rho_s$ (specular scale)")
    ax.set_ylabel(lobe)
    left_out = f"\nleft out: {result.left_out_text()}" if result.left_out else ""
    ax.set_title(
        f"{MODEL_NAMES[result.model]} parameters per region, {result.n_subjects} subjects\n"
        f"ellipses: mean ± {k:g}σ along the principal axes{left_out}",
        fontsize=10,
    )
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), title="region", title_fontsize=8)
    return fig


def _tab10():
    from matplotlib import colormaps

    return [colormaps["tab10"](i)[:3] for i in range(10)]


def _encoding_columns(result, skin_type, gender, age):
    data = getattr(result, "y_data", None)

    def pick(given, name, default):
        if given is not None:
            return np.asarray(given)
        if data is not None and name in data.columns:
            return np.asarray(data[name])
        return np.full(result.n, default)

    st = pick(skin_type, "skin_type", 3)
    g = pick(gender, "gender", "M")
    if np.asarray(g).dtype.kind in "fiu":
        g = np.where(np.asarray(g, float) >= 0.5, "F", "M")  # the paper's coding 0 = M, 1 = F
    return st, g, pick(age, "age", 30.0)


def plot_cca(result, dims=(0, 1), ax=None, skin_type=None, gender=None, age=None):
    """Fig. 16: the BRDF data projected on the two most correlated canonical directions.

    Colour = skin type, marker = gender, size = age, taken from the result's
    ``y_data`` (as :func:`facestats.analysis.brdf_cca` codes them) unless given.
    With a single canonical dimension, the X variate is plotted against the Y
    variate instead.

    Parameters
    ----------
    result : CCAResult
    dims : (int, int)
        Canonical dimensions (0-based) on the x and y axes.
    ax : matplotlib Axes, optional
    skin_type, gender, age : array_like, optional
        Encodings per row of the projections.

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    fig, ax = _axes(ax, (6.5, 5))
    st, g, a = _encoding_columns(result, skin_type, gender, age)
    r = result.correlations
    if r.size >= 2:
        i, j = dims
        x, y = result.projections[:, i], result.projections[:, j]
        ax.set_xlabel(f"canonical variate {i + 1} (r = {r[i]:.3f})")
        ax.set_ylabel(f"canonical variate {j + 1} (r = {r[j]:.3f})")
    else:
        x, y = result.projections[:, 0], result.y_projections[:, 0]
        ax.set_xlabel(f"BRDF canonical variate 1 (r = {r[0]:.3f})")
        ax.set_ylabel("experimental canonical variate 1")
    _encoded_scatter(ax, x, y, st, g, a)
    # brdf_cca codes the skin type with types I and II pooled as 2 (its CODING); given values are taken as they are
    grouped = skin_type is None and "skin_type" in (result.coding or {})
    direct = ", ".join(f"{n} {v:.3f}" for n, v in zip(result.y_names, result.direct_correlations))
    ax.set_title(
        f"CCA, n = {result.n}; principal r = " + ", ".join(f"{v:.3f}" for v in r[:2]) + f"\ndirect r: {direct}",
        fontsize=9,
    )
    _encoding_legend(ax, st, g, a, grouped_i_ii=grouped)
    return fig


def plot_absorption_scattering(result):
    """Fig. 14: σa against σ's (mm⁻¹) for all subjects, one panel per channel, with the paper's encoding.

    Parameters
    ----------
    result : AbsorptionScattering
        :func:`facestats.analysis.absorption_scattering`'s result.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = _new_figure((12, 4))
    axes = fig.subplots(1, 3)
    d = result.data
    for ax, ch in zip(axes, CHANNELS):
        sub = d[d["channel"] == ch]
        _encoded_scatter(ax, sub["sigma_s_prime"], sub["sigma_a"], sub["skin_type"], sub["gender"], sub["age"])
        ax.set_xlabel(r"$\sigma'_s$ (mm$^{-1}$)")
        ax.set_ylabel(r"$\sigma_a$ (mm$^{-1}$)")
        ax.set_title(f"{ch} channel", color=_CHANNEL_COLORS[ch])
    _encoding_legend(axes[-1], d["skin_type"], d["gender"], d["age"])
    src = "from albedo and $\\sigma_{trAvg}$" if result.site is None else f"fitted at the {result.site}"
    fig.suptitle(f"Absorption against reduced scattering ({src}), {d['subject_id'].nunique()} subjects", fontsize=10)
    return fig


def plot_translucency(table, ax=None, published=True):
    """Table 1 as bars: mean σtr per site and channel with ±1 standard deviation; the paper's means as markers.

    Parameters
    ----------
    table : TranslucencyTable
        :func:`facestats.analysis.translucency_table`'s result (σtr in mm⁻¹).
    ax : matplotlib.axes.Axes, optional
        Axes to draw into (default a new figure).
    published : bool
        Mark Weyrich et al. 2006 Table 1's means beside the bars.

    Returns
    -------
    matplotlib.figure.Figure
    """

    fig, ax = _axes(ax, (7, 4.5))
    sites = list(dict.fromkeys(table.table.columns.get_level_values("site")))
    width = 0.25
    x = np.arange(len(sites))
    for c, ch in enumerate(CHANNELS):
        means = [table.table.loc[ch, (s, "mean")] for s in sites]
        stds = [table.table.loc[ch, (s, "std")] for s in sites]
        ax.bar(x + (c - 1) * width, means, width, yerr=stds, color=_CHANNEL_COLORS[ch], alpha=0.75, capsize=3, label=ch)
        if published:
            ax.plot(
                x + (c - 1) * width,
                [TABLE1_MEAN[s][c] for s in sites],
                "D",
                mfc="white",
                mec="k",
                ms=6,
                label="Weyrich Table 1 mean" if c == 0 else None,
            )
    ax.set_xticks(x, sites)
    ax.set_ylabel(r"$\sigma_{tr}$ (mm$^{-1}$)")
    avg = ", ".join(f"{v:.4f}" for v in table.sigma_tr_avg)
    lo, hi = (", ".join(f"{v:.3f}" for v in e) for e in (table.ell_d_min, table.ell_d_max))
    ax.set_title(
        f"Translucency per site (mean ± 1 sd); $\\sigma_{{trAvg}}$ = [{avg}]\n"
        f"$\\ell_d$ range: {table.min_subject} [{lo}] mm to {table.max_subject} [{hi}] mm",
        fontsize=9,
    )
    ax.legend(fontsize=8, ncol=2)
    return fig


def plot_conditions(result):
    """Per-region differences of ρs and the lobe parameter against the reference condition, and condition distances.

    Parameters
    ----------
    result : ConditionDifferences
        :func:`facestats.analysis.condition_differences`'s result.

    Returns
    -------
    matplotlib.figure.Figure
        Heat maps of ``d_rho_s`` and ``d_lobe`` (condition × region) and of the distance matrix.  A region with
        no value (no texels: :attr:`ConditionDifferences.left_out`) is a hatched column marked ``n/a``, and
        the figure names the regions left out.
    """
    from matplotlib.patches import Rectangle

    fig = _new_figure((13, 4.4))
    axes = fig.subplots(1, 3, width_ratios=[1, 1, 0.8])
    diff = result.differences
    conds = [c for c in result.conditions if c != result.reference]
    regions = sorted(set(diff.index.get_level_values("region")))
    for ax, col, label in (
        (axes[0], "d_rho_s", r"$\Delta\rho_s$"),
        (axes[1], "d_lobe", f"$\\Delta {result.lobe_name}$"),
    ):
        m = np.array([[diff.loc[(c, r), col] for r in regions] for c in conds], dtype=float)
        lim = np.nanmax(np.abs(m)) if np.isfinite(m).any() else 1.0
        im = ax.imshow(m, cmap="RdBu_r", vmin=-lim, vmax=lim, aspect="auto")
        for k in np.flatnonzero(~np.isfinite(m).any(axis=0)):  # a blank column: say it is empty, not white
            ax.add_patch(Rectangle((k - 0.5, -0.5), 1, len(conds), fill=False, hatch="///", edgecolor="0.6", lw=0))
            ax.text(k, (len(conds) - 1) / 2, "n/a", rotation=90, ha="center", va="center", fontsize=8, color="0.3")
        ax.set_xticks(range(len(regions)), [str(r) for r in regions])
        ax.set_yticks(range(len(conds)), conds)
        ax.set_xlabel("region")
        ax.set_title(f"{label} vs {result.reference}", fontsize=10)
        fig.colorbar(im, ax=ax, shrink=0.8)
    dist = result.distance
    im = axes[2].imshow(dist.to_numpy(), cmap="viridis")
    axes[2].set_xticks(range(len(dist)), dist.columns, rotation=60)
    axes[2].set_yticks(range(len(dist)), dist.index)
    axes[2].set_title("distance: RMS over texels,\nin pooled within-region sd", fontsize=10)
    fig.colorbar(im, ax=axes[2], shrink=0.8)
    title = f"BRDF under external conditions, person {result.person_id}"
    if result.left_out:
        title += "\nleft out: " + result.left_out_text()
    fig.suptitle(title, fontsize=10)
    return fig


_LABELS = {
    "sigma_s_prime": r"$\sigma'_s$ (mm$^{-1}$)",
    "sigma_a": r"$\sigma_a$ (mm$^{-1}$)",
    "sigma_tr": r"$\sigma_{tr}$ (mm$^{-1}$)",
    "ell_d": r"$\ell_d$ (mm)",
}


def plot_sigma_posterior(post, labels=None, parameters=("sigma_s_prime", "sigma_a", "sigma_tr"), truth=None, bins=40):
    """Corner plot of the posterior of one profile, one corner per channel.

    Diagonal: marginal histograms with the median and the credible interval
    (dashed); below: joint sample clouds.  τ, acceptance and convergence are
    given in each corner's title.

    Parameters
    ----------
    post : SigmaPosterior
    labels : sequence of str, optional
        Channels to draw (default all).
    parameters : sequence of str
        Among ``sigma_s_prime``, ``sigma_a``, ``sigma_tr``, ``ell_d``.
    truth : dict, optional
        ``{label: {parameter: value}}`` drawn as black lines (simulations).
    bins : int

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    labels = list(post.labels if labels is None else labels)
    p = len(parameters)
    fig = _new_figure((1.7 * p * len(labels) + 0.5, 1.7 * p + 0.5))
    subfigs = np.atleast_1d(fig.subfigures(1, len(labels)))
    diag = post.channel_diagnostics()
    for sf, lab in zip(subfigs, labels):
        _corner(sf, post, lab, parameters, truth[lab] if truth and lab in truth else None, bins)
        d = diag.loc[lab]
        flag = "" if d["converged"] else "  NOT CONVERGED"
        sf.suptitle(
            f"{lab}: τ = {d['tau']:.1f}, acc = {d['acceptance']:.2f}, {post.level:.0%} intervals{flag}",
            fontsize=9,
            color="firebrick" if flag else "k",
        )
    return fig


def plot_site_posterior(post):
    """:func:`plot_sigma_posterior` of a site's profile, titled with its subject and site (``facestats analyze``).

    Parameters
    ----------
    post : SigmaPosterior
        From :func:`facestats.analysis.site_sigma_posterior` (or ``store_sigma_posterior``), which sets
        ``subject_id`` and ``site``; every channel is drawn, with σ's, σa and σtr.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = plot_sigma_posterior(post)
    fig.suptitle(f"Posterior of the scattering coefficients: {post.subject_id}, {post.site} profile", fontsize=10)
    return fig


def _corner(sf, post, lab, parameters, truth, bins):
    """One channel's corner: marginals on the diagonal, sample clouds below, ``truth`` lines if given."""
    s = post.samples[lab]
    color = _CHANNEL_COLORS.get(lab, "tab:purple")
    p = len(parameters)
    axes = sf.subplots(p, p, squeeze=False)
    for i, pi in enumerate(parameters):
        for j, pj in enumerate(parameters):
            ax = axes[i, j]
            if j > i:
                ax.set_visible(False)
                continue
            if i == j:
                _marginal(ax, s[pi], post.summary.loc[(lab, pi)], color, bins)
            else:
                ax.plot(s[pj], s[pi], ",", color=color, alpha=0.4)
            _truth_lines(ax, truth, pi, pj, i != j)
            _corner_axes(ax, i, j, p, pi, pj)


def _marginal(ax, values, row, color, bins):
    """Histogram with the median (solid) and the credible interval (dashed)."""
    ax.hist(values, bins=bins, color=color, alpha=0.6, density=True)
    ax.axvline(row["median"], color="k", lw=1)
    for v in (row["lo"], row["hi"]):
        ax.axvline(v, color="k", lw=0.8, ls="--")
    ax.set_yticks([])


def _truth_lines(ax, truth, pi, pj, joint):
    """Black lines at the true values (x: ``pj``; y: ``pi`` on joint panels)."""
    if truth is None:
        return
    if pj in truth:
        ax.axvline(truth[pj], color="k", lw=1.2, alpha=0.7)
    if joint and pi in truth:
        ax.axhline(truth[pi], color="k", lw=1.2, alpha=0.7)


def _corner_axes(ax, i, j, p, pi, pj):
    """Ticks and labels of panel (i, j) of a p × p corner: labels on the outer panels only."""
    from matplotlib.ticker import MaxNLocator

    ax.tick_params(labelsize=6)
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.xaxis.set_major_locator(MaxNLocator(4))  # narrow posteriors have long tick labels
    if i != j:
        ax.yaxis.set_major_locator(MaxNLocator(4))
    if i == p - 1:
        ax.set_xlabel(_LABELS[pj], fontsize=8)
    else:
        ax.set_xticklabels([])
    if j == 0 and i > 0:
        ax.set_ylabel(_LABELS[pi], fontsize=8)
    elif j > 0:
        ax.set_yticklabels([])


def plot_population_sigma_tr(result):
    """Posterior median and credible interval of the mean σtr per skin type, one panel per channel.

    Parameters
    ----------
    result : PopulationSigmaTr
        :func:`facestats.analysis.population_sigma_tr`'s result (σtr in mm⁻¹); the sample means are drawn too,
        and the population mean's interval where ``result.hyper`` is given.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = _new_figure((11, 3.8))
    axes = fig.subplots(1, 3)
    s = result.summary
    for ax, ch in zip(axes, CHANNELS):
        t = s.xs(ch, level="channel")
        x = np.arange(len(t))
        ax.errorbar(
            x,
            t["median"],
            yerr=[t["median"] - t["lo"], t["hi"] - t["median"]],
            fmt="o",
            color=_CHANNEL_COLORS[ch],
            capsize=4,
            label=f"posterior median, {result.level:.0%} interval",
        )
        ax.plot(x, t["sample_mean"], "kx", label="sample mean")
        for xi, n in zip(x, t["n"]):
            ax.annotate(
                f"n={n}", (xi, t["hi"].iloc[xi]), textcoords="offset points", xytext=(0, 4), ha="center", fontsize=7
            )
        if result.hyper is not None:
            h = result.hyper.loc[ch]
            ax.axhspan(h["mu_lo"], h["mu_hi"], color="0.85", zorder=0, label=r"population mean $\mu$")
        lo, hi = np.nanmin(t["lo"]), np.nanmax(t["hi"])
        if np.isfinite(lo) and np.isfinite(hi) and hi > lo:  # headroom for the n= labels above the intervals
            ax.set_ylim(lo - 0.05 * (hi - lo), hi + 0.15 * (hi - lo))
        ax.set_xticks(x, [result.type_label(v) for v in t.index])
        ax.set_xlabel("skin type")
        ax.set_ylabel(r"mean $\sigma_{tr}$ (mm$^{-1}$)")
        ax.set_title(f"{ch} channel", color=_CHANNEL_COLORS[ch])
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), fontsize=8, frameon=False)
    fig.suptitle(f"Posterior of the mean translucency per skin type ({result.model} model)", fontsize=10)
    return fig


def plot_model_errors(result):
    """Blinn-Phong / Torrance-Sparrow error ratio per region (median and IQR over subjects), flagged shares beside.

    Parameters
    ----------
    result : ModelErrors
        :func:`facestats.analysis.model_errors`'s result.

    Returns
    -------
    matplotlib.figure.Figure
    """

    fig = _new_figure((8.0, 3.6))
    ax, ax2 = fig.subplots(1, 2, width_ratios=(3, 2))
    x = np.arange(len(result.regions))
    lo, hi = result.error_ratio_iqr[:, 0], result.error_ratio_iqr[:, 1]
    ax.bar(x, result.error_ratio, color="tab:red", alpha=0.7)
    ax.errorbar(x, result.error_ratio, yerr=[result.error_ratio - lo, hi - result.error_ratio], fmt="none", color="k")
    ax.axhline(1, color="0.5", lw=0.8)
    ax.set_xticks(x, [f"{r} {REGIONS[r]}" for r in result.regions], rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("E(p) Blinn-Phong / Torrance-Sparrow")
    ax.set_title(f"fit error ratio, median and IQR over {result.overall['subjects']} subjects", fontsize=9)
    w = 0.4
    ax2.bar(x - w / 2, 100 * result.ts_flagged, w, label="Torrance-Sparrow", color="tab:blue")
    ax2.bar(x + w / 2, 100 * result.bp_flagged, w, label="Blinn-Phong", color="tab:red")
    ax2.set_xticks(x, [str(r) for r in result.regions])
    ax2.set_xlabel("region")
    ax2.set_ylabel("flagged texels (%)")
    ax2.legend(fontsize=7)
    return fig
