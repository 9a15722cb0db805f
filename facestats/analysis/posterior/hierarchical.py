"""Posterior of the mean σtr of each skin type, per channel (Weyrich et al. 2006 §5.4, with uncertainty).

The posterior of the mean σtr of each skin type, per channel, from the
per-subject σtr (mean of the cheek and forehead fits, as σtrAvg in §5.4;
:func:`facestats.analysis.translucency.subject_sigma_tr`).
Default ``model="hierarchical"``: the normal hierarchical model of Gelman et
al., *Bayesian Data Analysis* (3rd ed.) §5.4-5.5,

    y_ij ~ N(θ_j, σ_w²),  θ_j ~ N(μ, τ²),  p(μ, τ) ∝ 1,

with the within-type variance σ_w² pooled over all types and plugged in
(it is well determined by all subjects; between-subject spread and
measurement noise are both in it).  The skin-type means θ_j borrow strength
from each other (types V and VI have few subjects).  μ and θ are
integrated in closed form and τ on a grid with its power-law tail beyond in
closed form (:func:`hierarchical_draws`), so the draws are exact up to the
grid's quadrature, with no Markov chain to converge.  It needs at least three skin types (the flat prior
on τ gives an improper posterior otherwise).  ``model="independent"`` treats
each type alone with the Jeffreys prior p(θ_j, σ_j) ∝ 1/σ_j: θ_j ~ ȳ_j +
s_j/√n_j · t_{n_j−1}.

:class:`PopulationSigmaTr` holds the result, its JSON document and its summary.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from facestats.analysis.population import select_population
from facestats.analysis.posterior.credible import check_level, interval_quantiles
from facestats.analysis.serialize import json_ready, records
from facestats.analysis.translucency import subject_sigma_tr
from facestats.core.conventions import CHANNELS, skin_type_label
from facestats.core.published import SIGMA_TR_AVG
from facestats.core.validate import check_choice, check_seed
from facestats.errors import ValidationError

__all__ = ["PopulationSigmaTr", "population_sigma_tr", "hierarchical_draws"]


@dataclass(frozen=True)
class PopulationSigmaTr:
    """Posterior of the mean σtr (mm⁻¹) of each skin type, per channel.

    Attributes
    ----------
    summary : pandas.DataFrame
        Index (skin_type, channel); columns ``n`` (subjects), ``sample_mean``,
        ``median``, ``mean``, ``lo``, ``hi`` (credible interval at ``level``).
    draws : ndarray, shape (n_draws, n_types, 3)
        Posterior draws of the skin-type means θ_j.
    skin_types : tuple of int
    hyper : pandas.DataFrame or None
        Hierarchical model only: per channel, the pooled within-type standard
        deviation ``sigma_w`` and posterior median and interval of the
        population mean ``mu`` and the between-type spread ``tau``.
    model : str
    level : float
    seed : int
        Seed of the draws.
    grouped_i_ii : bool
        Skin types I and II are pooled under II (the paper's grouping): :meth:`type_label` names that group I-II.
    """

    summary: object
    draws: np.ndarray
    skin_types: tuple
    hyper: object
    model: str
    level: float
    seed: int = 0
    grouped_i_ii: bool = False

    def type_label(self, skin_type: int) -> str:
        """The Roman numeral of a skin type, ``I-II`` for the pooled group of types I and II.

        Parameters
        ----------
        skin_type : int
            Fitzpatrick skin type, 1 to 6 (2 stands for the pooled I-II where ``grouped_i_ii``).
        """
        return skin_type_label(skin_type, self.grouped_i_ii)

    def compare_published(self):
        """Posterior median and interval of each skin type's mean σtr beside the paper's σtrAvg.

        The paper uses one σtrAvg (§5.4) for every subject; the comparison
        shows whether the skin types' intervals hold it.

        Returns
        -------
        pandas.DataFrame
            Index (``skin_type``, ``channel``); columns ``n``, ``median``,
            ``lo``, ``hi`` and ``paper_sigma_tr_avg`` (mm⁻¹).
        """

        table = self.summary[["n", "median", "lo", "hi"]]
        avg = dict(zip(CHANNELS, SIGMA_TR_AVG))
        return table.assign(paper_sigma_tr_avg=[avg[ch] for ch in table.index.get_level_values("channel")])

    def to_dict(self) -> dict:
        """The JSON document (``facestats analyze posterior --population`` writes it as ``posterior_population.json``).

        Keys (conventions: :mod:`facestats.analysis.serialize`): ``model``,
        ``level``, ``skin_types`` (labels, :meth:`type_label`: Roman numerals, ``"I-II"`` for the
        pooled group where ``grouped_i_ii``; before 2026-12-08 that group read ``"II"``),
        ``skin_type_numbers`` (the same as Fitzpatrick numbers, 2 for the pooled I-II), ``grouped_i_ii``,
        ``seed``; ``summary``: a list of ``{skin_type (label), channel, n, sample_mean, median, mean, lo, hi}``;
        ``hyper``: by channel ``{sigma_w, mu_median, mu_lo, mu_hi, tau_median, tau_lo, tau_hi}`` (``null`` for
        the independent model).
        """
        summary = records(self.summary)
        for row in summary:
            row["skin_type"] = self.type_label(row["skin_type"])
        hyper = None if self.hyper is None else {ch: row.to_dict() for ch, row in self.hyper.iterrows()}
        doc = {
            "model": self.model,
            "level": self.level,
            "skin_types": [self.type_label(t) for t in self.skin_types],
            "skin_type_numbers": list(self.skin_types),
            "grouped_i_ii": self.grouped_i_ii,
            "seed": self.seed,
            "summary": summary,
            "hyper": hyper,
        }
        return json_ready(doc)

    def to_text(self) -> str:
        """Median and interval per skin type and channel (what ``facestats analyze posterior --population`` prints)."""
        lines = [
            f"Posterior of the mean sigma_tr (1/mm) per skin type ({self.model} model): "
            f"median [{self.level:.0%} interval]"
        ]
        for st in self.skin_types:
            cells = []
            for ch in CHANNELS:
                r = self.summary.loc[(st, ch)]
                cells.append(f"{ch} {r['median']:.3f} [{r['lo']:.3f}, {r['hi']:.3f}]")
            lines.append(
                f"type {self.type_label(st):<5}n={int(self.summary.loc[(st, 'R'), 'n']):<4}" + "   ".join(cells)
            )
        return "\n".join(lines)


def hierarchical_draws(ybar, var, n_draws, rng):
    """Draws of (θ_j, μ, τ) of the normal hierarchical model with known variances (Gelman et al. BDA3 §5.4).

    ybar_j ~ N(θ_j, var_j), θ_j ~ N(μ, τ²), p(μ, τ) ∝ 1 (BDA3 eq. 5.21):
    p(τ|y) ∝ V_μ^{1/2} Π_j (var_j + τ²)^{-1/2} exp(−(ȳ_j − μ̂)²/(2(var_j + τ²))),
    μ̂ = Σ ȳ_j/(var_j + τ²) / Σ 1/(var_j + τ²), V_μ = 1/Σ 1/(var_j + τ²); then
    μ | τ ~ N(μ̂, V_μ) and θ_j | μ, τ ~ N((ȳ_j τ² + μ var_j)/(var_j + τ²), var_j τ²/(var_j + τ²)).

    τ is drawn from p(τ|y) on a grid from 0 to τ_max = 10⁴ s (s = √(var(ȳ) + max var_j)), trapezoid rule,
    and beyond τ_max from its tail in closed form: there var_j + τ² = τ²(1 + O(10⁻⁸)) and the exponent is 1
    to the same order, so p(τ|y) ∝ τ^{−(J−1)}, whose mass beyond τ_max is p(τ_max) τ_max/(J − 2) and whose
    draws are τ_max w^{−1/(J−2)} with w uniform on (0, 1] (a Pareto tail).  With the flat prior and J = 3
    the tail falls only as τ⁻²: a grid cut at 100 s without it left out enough mass to put the 95 %
    quantile of τ 14 % low (a red team's check against a grid to 10⁶ s).

    Parameters
    ----------
    ybar : ndarray, shape (J,)
        Group means, J ≥ 3 (the posterior of τ is improper for fewer).
    var : ndarray, shape (J,)
        Their variances, > 0.
    n_draws : int
    rng : numpy.random.Generator

    Returns
    -------
    theta : ndarray, shape (n_draws, J)
    mu : ndarray, shape (n_draws,)
    tau : ndarray, shape (n_draws,)
    """
    ybar, var = np.asarray(ybar, np.float64), np.asarray(var, np.float64)
    j = ybar.size
    if j < 3 or var.shape != ybar.shape:
        raise ValidationError(
            f"ybar and var must hold one value per group for >= 3 groups, got {ybar.shape}, {var.shape}"
        )
    if not (np.all(np.isfinite(ybar)) and np.all(np.isfinite(var)) and np.all(var > 0)):
        raise ValidationError(
            f"ybar must be finite and var finite and > 0, got ybar {ybar.tolist()}, var {var.tolist()}"
        )
    scale = float(np.sqrt(np.var(ybar) + np.max(var)))
    tau = np.concatenate([[0.0], np.geomspace(1e-4 * scale, 1e4 * scale, 6000)])
    tot = var[None, :] + tau[:, None] ** 2  # (T, J)
    v_mu = 1 / np.sum(1 / tot, axis=1)
    mu_hat = v_mu * np.sum(ybar[None] / tot, axis=1)
    logp = 0.5 * np.log(v_mu) - 0.5 * np.sum(np.log(tot) + (ybar[None] - mu_hat[:, None]) ** 2 / tot, axis=1)
    dens = np.exp(logp - logp.max())
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(tau))])
    tail = dens[-1] * tau[-1] / (j - 2)  # the mass of p(τ|y) ∝ τ^-(J-1) beyond the grid
    u = rng.uniform(size=n_draws) * (cdf[-1] + tail)
    beyond = u > cdf[-1]
    tau_d = np.interp(u, cdf, tau)  # inverse-CDF draws of τ (piecewise linear) on the grid
    tau_d[beyond] = tau[-1] * ((u[beyond] - cdf[-1]) / tail) ** (-1.0 / (j - 2))
    tot_d = var[None, :] + tau_d[:, None] ** 2
    v_mu_d = 1 / np.sum(1 / tot_d, axis=1)
    mu_d = v_mu_d * np.sum(ybar[None] / tot_d, axis=1) + np.sqrt(v_mu_d) * rng.standard_normal(n_draws)
    t2 = tau_d[:, None] ** 2
    mean = (ybar[None] * t2 + mu_d[:, None] * var[None]) / tot_d
    sd = np.sqrt(var[None] * t2 / tot_d)
    theta = mean + sd * rng.standard_normal(mean.shape)
    return theta, mu_d, tau_d


def population_sigma_tr(
    source,
    model="hierarchical",
    subjects=None,
    conditions=("normal",),
    level=0.9,
    n_draws=20000,
    seed=0,
    group_i_ii=True,
):
    """Posterior of the mean σtr per skin type and channel (see the module docstring for both models).

    Parameters
    ----------
    source : store or pandas.DataFrame
        Parameter store or its population index (columns ``site_sigma_tr_{site}_{ch}``).
    model : {"hierarchical", "independent"}
    subjects, conditions
        Population selection (:func:`facestats.analysis.population.select_population`).
    level : float
        Credible level.
    n_draws : int
        Posterior draws.
    seed : int
    group_i_ii : bool
        Group skin types I and II, as the paper does (default).

    Returns
    -------
    PopulationSigmaTr
    """
    import pandas as pd

    check_choice(model, "model", ("hierarchical", "independent"))
    level = check_level(level)
    frame = select_population(source, subjects, conditions)
    sig = subject_sigma_tr(frame)
    types = frame["skin_type"].astype(int)
    if group_i_ii:
        types = types.clip(lower=2)
    rng = np.random.default_rng(check_seed(seed))
    skin_types = tuple(int(t) for t in sorted(types[sig.notna().all(axis=1)].unique()))
    if not skin_types:
        raise ValidationError("no selected subject has cheek or forehead sigma_tr in all channels")
    q = interval_quantiles(level)
    draws = np.full((int(n_draws), len(skin_types), len(CHANNELS)), np.nan)
    rows, hyper_rows = [], []
    for c, ch in enumerate(CHANNELS):
        ok = sig[ch].notna()
        y, t = sig.loc[ok, ch].to_numpy(float), types[ok].to_numpy()
        groups = [y[t == st] for st in skin_types]
        n = np.array([g.size for g in groups])
        ybar = np.array([g.mean() if g.size else np.nan for g in groups])
        if model == "hierarchical":
            theta, hyper = _hierarchical_channel(groups, skin_types, int(n_draws), rng, q)
            draws[:, n > 0, c] = theta
            hyper_rows.append({"channel": ch, **hyper})
        else:
            draws[:, :, c] = _independent_channel(groups, int(n_draws), rng)
        rows += _summary_rows(draws[:, :, c], skin_types, ch, n, ybar, q)
    summary = pd.DataFrame.from_records(rows).set_index(["skin_type", "channel"])
    hyper = pd.DataFrame.from_records(hyper_rows).set_index("channel") if hyper_rows else None
    return PopulationSigmaTr(
        summary, draws, skin_types, hyper, model, float(level), seed=seed, grouped_i_ii=bool(group_i_ii)
    )


def _hierarchical_channel(groups, skin_types, n_draws, rng, q):
    """Draws of the types' mean σtr of one channel (types with subjects) and the hyperparameter summary.

    The within-type variance σ_w² is pooled over the types and plugged in:
    ybar_j has variance σ_w²/n_j (:func:`hierarchical_draws`).
    """
    n = np.array([g.size for g in groups])
    present = n > 0
    dof = n.sum() - present.sum()
    if present.sum() < 3 or dof < 1:
        raise ValidationError(
            f"the hierarchical model needs >= 3 skin types and more subjects than types, got types "
            f"{[st for st, k in zip(skin_types, n) if k]} with {int(n.sum())} subjects "
            "(use the independent model: model='independent' in Python, `analyze posterior` without --population)"
        )
    ybar = np.array([g.mean() for g in groups if g.size])
    s_w2 = sum(float(np.sum((g - g.mean()) ** 2)) for g in groups if g.size) / dof
    if not s_w2 > (64 * np.finfo(float).eps * np.max(np.abs(ybar))) ** 2:  # 0 up to the rounding of the means
        raise ValidationError(
            "the hierarchical model needs spread within the skin types, got a pooled within-type variance of 0 "
            f"(up to rounding: every subject of a type has the same sigma_tr; type means {ybar.tolist()}): use the "
            "independent model (model='independent' in Python, `analyze posterior` without --population)"
        )
    theta, mu_d, tau_d = hierarchical_draws(ybar, s_w2 / n[present], n_draws, rng)
    mq, tq = np.quantile(mu_d, q), np.quantile(tau_d, q)
    hyper = {
        "sigma_w": np.sqrt(s_w2),
        "mu_median": mq[1],
        "mu_lo": mq[0],
        "mu_hi": mq[2],
        "tau_median": tq[1],
        "tau_lo": tq[0],
        "tau_hi": tq[2],
    }
    return theta, hyper


def _independent_channel(groups, n_draws, rng):
    """Draws (n_draws, n_types) of each type's mean under the Jeffreys prior, NaN for types of fewer than 2 subjects.

    θ_j ~ ȳ_j + s_j/√n_j · t_{n_j−1}.
    """

    out = np.full((n_draws, len(groups)), np.nan)
    for j, g in enumerate(groups):
        if g.size >= 2:
            se = g.std(ddof=1) / np.sqrt(g.size)
            out[:, j] = g.mean() + se * stats.t.rvs(g.size - 1, size=n_draws, random_state=rng)
    return out


def _summary_rows(draws, skin_types, ch, n, ybar, q):
    """Rows (skin type, channel, n, sample mean, posterior median, mean and interval) of one channel's draws."""
    rows = []
    for j, st in enumerate(skin_types):
        d = draws[:, j]
        if np.all(np.isfinite(d)):
            lo_q, med, hi_q = np.quantile(d, q)
            mean = d.mean()
        else:
            lo_q = med = hi_q = mean = np.nan
        rows.append(
            {
                "skin_type": st,
                "channel": ch,
                "n": int(n[j]),
                "sample_mean": ybar[j],
                "median": med,
                "mean": mean,
                "lo": lo_q,
                "hi": hi_q,
            }
        )
    return rows
