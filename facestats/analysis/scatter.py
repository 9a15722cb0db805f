"""Absorption against reduced scattering per subject and channel (Weyrich et al. 2006 §7, Fig. 14).

Fig. 14 plots σa against σ's (mm⁻¹) of all subjects per colour channel, with
colour = skin type, marker = gender and size = age.  The paper's values are the
subject-level coefficients "estimated from the average albedo α_avg and the
average translucency σtrAvg" (§5.4, :func:`facestats.model.dipole.scattering_from_albedo`),
i.e. the index columns ``sigma_a_{ch}`` and ``sigma_s_prime_{ch}``.  Per-site
coefficients fitted to the contact-sensor profiles (``site_sigma_a_{site}_{ch}``)
can be analysed instead with ``site=``.

The paper observes that σa falls as σ's rises, "near-exponential" because both
come through eq. 16 from one albedo at fixed σtr; :meth:`AbsorptionScattering.correlations`
quantifies it per channel (Pearson on log σa vs σ's, and Spearman rank);
:meth:`AbsorptionScattering.to_dict` and :meth:`AbsorptionScattering.to_text`
give the numbers and the summary of ``facestats analyze scatter``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.analysis.population import select_population
from facestats.analysis.serialize import json_ready
from facestats.core.conventions import CHANNELS, ROMAN, SITES
from facestats.core.validate import check_choice
from facestats.errors import InsufficientDataError, ValidationError

__all__ = ["AbsorptionScattering", "absorption_scattering"]


@dataclass(frozen=True)
class AbsorptionScattering:
    """Per-subject σa and σ's per channel (Fig. 14 data).

    Attributes
    ----------
    data : pandas.DataFrame
        Long form, one row per subject and channel: ``subject_id``, ``channel``,
        ``sigma_a``, ``sigma_s_prime`` (mm⁻¹), ``skin_type``, ``gender``, ``age``.
    site : str or None
        Contact-sensor site the values come from, or None for the subject-level
        coefficients from α_avg and σtrAvg (the paper's Fig. 14).
    """

    data: object
    site: str | None

    def correlations(self):
        """Per channel: n, Pearson r of (σ's, ln σa) and Spearman ρ of (σ's, σa)."""
        import pandas as pd

        rows = []
        for ch in CHANNELS:
            d = self.data[self.data["channel"] == ch]
            with np.errstate(invalid="ignore", divide="ignore"):  # constant columns give NaN
                pear = np.corrcoef(d["sigma_s_prime"], np.log(d["sigma_a"]))[0, 1] if len(d) > 2 else np.nan
            spear = _spearman(d["sigma_s_prime"], d["sigma_a"])
            rows.append({"channel": ch, "n": len(d), "pearson_log": pear, "spearman": spear})
        return pd.DataFrame.from_records(rows).set_index("channel")

    def by_skin_type(self):
        """Mean, standard deviation and count of σa and σ's per skin type and channel."""
        g = self.data.groupby(["skin_type", "channel"])[["sigma_a", "sigma_s_prime"]]
        return g.agg(["mean", "std", "count"])

    @property
    def n_subjects(self) -> int:
        """Subjects with a value in at least one channel."""
        return int(self.data["subject_id"].nunique())

    def compare_published(self):
        """Per channel our means and correlations, and whether σa falls as σ's rises, as the paper observes.

        Fig. 14 gives no numbers; the paper's observation is the falling,
        "near-exponential" relation, i.e. negative correlations.

        Returns
        -------
        pandas.DataFrame
            Index ``channel``; columns ``n``, ``sigma_a_mean``,
            ``sigma_s_prime_mean``, ``pearson_log``, ``spearman`` (as
            :meth:`correlations`) and ``falls`` (both correlations negative).
        """
        import pandas as pd

        rows = [
            {
                "channel": ch,
                "n": c["n"],
                "sigma_a_mean": c["sigma_a"]["mean"],
                "sigma_s_prime_mean": c["sigma_s_prime"]["mean"],
                "pearson_log": c["pearson_log"],
                "spearman": c["spearman"],
            }
            for ch, c in self._channel_stats(self.correlations()).items()
        ]
        table = pd.DataFrame.from_records(rows).set_index("channel")
        table["falls"] = (table["pearson_log"] < 0) & (table["spearman"] < 0)
        return table

    def _channel_stats(self, corr):
        """The ``channels`` entry of :meth:`to_dict` (raw values)."""
        d = self.data
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
        return channels

    def _type_means(self):
        """The ``by_skin_type`` entry of :meth:`to_dict` (raw values)."""
        g = self.data.groupby(["skin_type", "channel"])
        means = g[["sigma_a", "sigma_s_prime"]].mean()
        counts = g.size()
        by_type = {}
        for (st, ch), row in means.iterrows():
            by_type.setdefault(ROMAN[int(st)], {})[ch] = {
                "n": counts.loc[(st, ch)],
                "sigma_a_mean": row["sigma_a"],
                "sigma_s_prime_mean": row["sigma_s_prime"],
            }
        return by_type

    def to_dict(self) -> dict:
        """The JSON document of the analysis (``facestats analyze scatter`` writes it as ``scatter.json``).

        Keys (conventions: :mod:`facestats.analysis.serialize`): ``site``
        (``null``: subject-level σ from α_avg and σtrAvg, as the paper),
        ``n_subjects``; ``channels``: by channel ``{n, sigma_a: {mean, std, min,
        max}, sigma_s_prime: {...}, pearson_log, spearman}`` (Pearson r of
        (σ's, ln σa), Spearman ρ of (σ's, σa)); ``by_skin_type``: by skin type
        (Roman numeral) and channel ``{n, sigma_a_mean, sigma_s_prime_mean}``.
        """
        doc = {
            "site": self.site,
            "n_subjects": self.n_subjects,
            "channels": self._channel_stats(self.correlations()),
            "by_skin_type": self._type_means(),
        }
        return json_ready(doc)

    def to_text(self) -> str:
        """Means and correlations per channel (what ``facestats analyze scatter`` prints)."""
        src = "from albedo and sigma_trAvg" if self.site is None else f"fitted at the {self.site}"
        lines = [
            f"Absorption against reduced scattering ({src}), {self.n_subjects} subjects (Weyrich Fig. 14)",
            f"{'channel':<8}{'sigma_a mean':>13}{'sigma_s_prime mean':>20}{'r(ss, ln sa)':>14}{'Spearman':>10}",
        ]
        table = self.compare_published()
        for ch, c in table.iterrows():
            lines.append(
                f"{ch:<8}{c['sigma_a_mean']:13.4f}{c['sigma_s_prime_mean']:20.4f}"
                f"{c['pearson_log']:14.3f}{c['spearman']:10.3f}"
            )
        lines.append(self._conclusion(table))
        return "\n".join(lines)

    def _conclusion(self, table) -> str:
        """What the correlations and the skin-type trend show, against the paper's Fig. 14 (from the numbers)."""
        defined = table[["pearson_log", "spearman"]].notna().all(axis=1)
        if not defined.any():
            return "correlations undefined (fewer than 3 subjects, or constant values): nothing to compare"
        if table["falls"].all():
            text = "sigma_a falls as sigma_s_prime rises in every channel (negative correlations), as in the paper"
        else:
            other = ", ".join(ch for ch in table.index[~table["falls"]])
            text = f"unlike the paper, sigma_a does not fall as sigma_s_prime rises in channel(s) {other}"
        trend = self._skin_type_trend()
        if trend is not None:
            text += "; " + trend
        return text

    def _skin_type_trend(self):
        """Whether darker skin types absorb more and scatter less in every channel (Spearman ρ against skin type)."""
        d = self.data
        if d["skin_type"].nunique() < 2:
            return None
        rho = [
            (_spearman(sub["skin_type"], sub["sigma_a"]), _spearman(sub["skin_type"], sub["sigma_s_prime"]))
            for sub in (d[d["channel"] == ch] for ch in CHANNELS)
        ]
        if all(a > 0 and s < 0 for a, s in rho):
            return "darker skin types absorb more and scatter less, as in the paper"
        return "darker skin types do not both absorb more and scatter less in every channel, unlike the paper"


def _spearman(a, b) -> float:
    """Spearman ρ of two pandas Series (Pearson r of their average ranks); NaN below 3 values or for constants."""
    return a.rank().corr(b.rank()) if len(a) > 2 else np.nan


def absorption_scattering(source, site=None, subjects=None, conditions=("normal",)):
    """σa and σ's of every subject per channel, with skin type, gender and age (Weyrich et al. 2006 Fig. 14).

    Parameters
    ----------
    source : store or pandas.DataFrame
        Parameter store or its population index.
    site : {None, "cheek", "forehead", "neck"}
        None (default): the subject-level coefficients from α_avg and σtrAvg
        (§5.4), as in the paper; a site: the coefficients fitted to that site's
        contact-sensor profile.
    subjects, conditions
        Population selection (:func:`facestats.analysis.conditions.select_population`).

    Returns
    -------
    AbsorptionScattering
        Subjects without positive finite values in a channel are left out of
        that channel.
    """
    import pandas as pd

    if site is not None:
        check_choice(site, "site", SITES)
    frame = select_population(source, subjects, conditions)
    parts = []
    for ch in CHANNELS:
        if site is None:
            ca, cs = f"sigma_a_{ch}", f"sigma_s_prime_{ch}"
        else:
            ca, cs = f"site_sigma_a_{site}_{ch}", f"site_sigma_s_prime_{site}_{ch}"
        if ca not in frame.columns or cs not in frame.columns:
            raise ValidationError(f"the population index has no columns {ca!r}/{cs!r}")
        part = pd.DataFrame(
            {
                "subject_id": frame.index.astype(str),
                "channel": ch,
                "sigma_a": frame[ca].astype(float).to_numpy(),
                "sigma_s_prime": frame[cs].astype(float).to_numpy(),
                "skin_type": frame["skin_type"].astype(int).to_numpy(),
                "gender": frame["gender"].astype(str).to_numpy(),
                "age": frame["age"].astype(float).to_numpy(),
            }
        )
        ok = (
            np.isfinite(part["sigma_a"])
            & np.isfinite(part["sigma_s_prime"])
            & (part["sigma_a"] > 0)
            & (part["sigma_s_prime"] > 0)
        )
        parts.append(part[ok])
    data = pd.concat(parts, ignore_index=True)
    if data.empty:
        raise InsufficientDataError("no selected subject has positive sigma_a and sigma_s_prime")
    return AbsorptionScattering(data, site)
