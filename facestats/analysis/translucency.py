"""Translucency statistics of a population (Weyrich et al. 2006 §5.4, Table 1).

Table 1 gives, per measurement site (cheek, forehead, neck) and colour channel,
the mean and "Var." of the effective transport coefficient
σtr = sqrt(3 σa (σa + σ's)) (eq. 15, mm⁻¹) fitted to the contact-sensor
profiles.  §5.4 adds σtrAvg = [0.5508, 0.9791, 1.5497] mm⁻¹, "the mean over all
subjects of the measurements for the forehead and cheek, ignoring the neck",
and the subjects with the minimum and maximum translucency ℓd = 1/σtr (mm).

Reproduction choices (stated because the paper does not fix them):

* **"Var." is reproduced as the sample variance** (``ddof=1`` by default) of
  our per-subject σtr values; the standard deviation is reported beside it.
  Read as variances, the published values are hard to reconcile with the
  published extreme subjects: their red ℓd of 1.09 and 2.81 mm mean σtr of
  0.92 and 0.36 mm⁻¹, and values within a range of 0.56 mm⁻¹ have a variance
  of at most (0.56/2)² ≈ 0.08 mm⁻², against the published 0.17 (cheek, red).
  Unless single-site values spread much further than the subjects' ranked
  extremes, the published "Var." is closer to a standard deviation.
  :meth:`TranslucencyTable.compare_published` puts both beside the paper.
* σtrAvg: per subject the mean of the cheek and forehead σtr (whichever are
  present), then the mean over subjects.  With complete data this equals the
  mean of the cheek and forehead columns of Table 1, as in the paper
  ((0.5572 + 0.5443)/2 = 0.5508).
* ℓd per subject is 1/σtr of that same per-subject cheek/forehead σtr; the
  least and most translucent subjects are ranked by the mean ℓd over the
  three channels by default (or one channel, ``rank_by``).

:meth:`TranslucencyTable.compare_published` and
:meth:`TranslucencyTable.compare_published_extremes` put the numbers beside the
paper's; :meth:`TranslucencyTable.to_dict` and :meth:`TranslucencyTable.to_text`
give the numbers and the summary of ``facestats analyze translucency``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.analysis.population import select_population
from facestats.analysis.serialize import by_channel, json_ready, records
from facestats.core.conventions import CHANNELS, SITES
from facestats.core.published import ELL_D_MAX, ELL_D_MIN, SIGMA_TR_AVG, TABLE1_MEAN, TABLE1_VAR
from facestats.core.validate import check_choice, check_integer
from facestats.errors import InsufficientDataError

__all__ = ["TranslucencyTable", "translucency_table", "subject_sigma_tr"]

#: Sites whose σtr define σtrAvg and each subject's ℓd (§5.4: "ignoring the neck").
AVERAGE_SITES = ("cheek", "forehead")

#: How to read the "Var." column beside ours (see the module docstring).
VAR_NOTE = (
    "The synthetic population of the default store reads Table 1's 'Var.' column as a standard deviation "
    "(facestats.acquire.synthetic.population): compare the paper's 'Var.' with our 'std'.  'var' is the sample "
    "variance of the per-subject sigma_tr."
)


def subject_sigma_tr(frame, sites=AVERAGE_SITES):
    """Per-subject σtr (mm⁻¹) per channel: mean over ``sites`` of ``site_sigma_tr_{site}_{ch}``.

    The per-subject values behind σtrAvg (Weyrich et al. 2006 §5.4: cheek and
    forehead, "ignoring the neck").  Missing sites are skipped; a subject with
    none of them gets NaN.

    Parameters
    ----------
    frame : pandas.DataFrame
        One row per subject, with columns ``site_sigma_tr_{site}_{ch}`` (mm⁻¹) for ch in R, G, B.
    sites : sequence of str
        Measurement sites to average (default cheek and forehead).

    Returns
    -------
    pandas.DataFrame
        Columns R, G, B, indexed like ``frame``.
    """
    import pandas as pd

    out = {}
    for ch in CHANNELS:
        cols = [f"site_sigma_tr_{s}_{ch}" for s in sites if f"site_sigma_tr_{s}_{ch}" in frame.columns]
        out[ch] = frame[cols].astype(float).mean(axis=1, skipna=True) if cols else pd.Series(np.nan, index=frame.index)
    return pd.DataFrame(out, index=frame.index)


@dataclass(frozen=True)
class TranslucencyTable:
    """Table 1 and the §5.4 translucency statistics of a population.

    Attributes
    ----------
    table : pandas.DataFrame
        Index ``channel`` (R, G, B); columns a MultiIndex (site, statistic) with
        statistics ``mean``, ``var`` (sample variance with ``ddof``), ``std`` and
        ``n`` (subjects with a value), σtr in mm⁻¹ (var in mm⁻²).
    sigma_tr_avg : ndarray, shape (3,)
        σtrAvg (mm⁻¹), mean over subjects of the cheek/forehead σtr.
    subjects : pandas.DataFrame
        Per subject: ``sigma_tr_{ch}``, ``ell_d_{ch}`` (mm) and ``ell_d_mean``,
        with ``skin_type``, ``gender``, ``age``.
    min_subject, max_subject : str
        Subjects with the smallest and largest ℓd (by ``rank_by``).
    ell_d_min, ell_d_max : ndarray, shape (3,)
        Their ℓd per channel, mm.
    rank_by : str
    ddof : int
    """

    table: object
    sigma_tr_avg: np.ndarray
    subjects: object
    min_subject: str
    max_subject: str
    ell_d_min: np.ndarray
    ell_d_max: np.ndarray
    rank_by: str
    ddof: int

    def mean(self, site) -> np.ndarray:
        """Mean σtr (R, G, B) of a site, mm⁻¹.

        Parameters
        ----------
        site : str
            ``"cheek"``, ``"forehead"`` or ``"neck"``, one of the sites in ``table``.

        Returns
        -------
        ndarray, shape (3,)

        Raises
        ------
        ValidationError
            ``site`` is not a site of ``table``.
        """
        return self.table[(self._site(site), "mean")].to_numpy()

    def var(self, site) -> np.ndarray:
        """Variance of σtr (R, G, B) of a site, mm⁻².

        Parameters
        ----------
        site : str
            ``"cheek"``, ``"forehead"`` or ``"neck"``, one of the sites in ``table``.

        Returns
        -------
        ndarray, shape (3,)
            Sample variance with ``ddof``.

        Raises
        ------
        ValidationError
            ``site`` is not a site of ``table``.
        """
        return self.table[(self._site(site), "var")].to_numpy()

    def _site(self, site):
        """``site`` if ``table`` has statistics of it, else ValidationError naming the sites it has."""
        return check_choice(site, "site", set(self.table.columns.get_level_values(0)))

    def compare_published(self):
        """Our mean, variance and standard deviation beside Weyrich Table 1 (one row per site and channel)."""
        import pandas as pd

        rows = []
        for site in SITES:
            if (site, "mean") not in self.table.columns:
                continue
            for c, ch in enumerate(CHANNELS):
                rows.append(
                    {
                        "site": site,
                        "channel": ch,
                        "mean": self.table.loc[ch, (site, "mean")],
                        "paper_mean": TABLE1_MEAN[site][c],
                        "var": self.table.loc[ch, (site, "var")],
                        "std": self.table.loc[ch, (site, "std")],
                        "paper_var": TABLE1_VAR[site][c],
                    }
                )
        return pd.DataFrame.from_records(rows).set_index(["site", "channel"])

    def compare_published_extremes(self):
        """σtrAvg and the ℓd of the least and most translucent subject beside Weyrich §5.4.

        Returns
        -------
        pandas.DataFrame
            Index (``quantity``, ``source``): quantities ``sigma_tr_avg`` (mm⁻¹),
            ``ell_d_min``, ``ell_d_max`` (mm), each from ``ours`` and ``paper``;
            columns ``subject_id`` (ours: the subject; else None), ``R``,
            ``G``, ``B``.
        """
        import pandas as pd

        rows = []
        for quantity, subject, ours, paper in (
            ("sigma_tr_avg", None, self.sigma_tr_avg, SIGMA_TR_AVG),
            ("ell_d_min", self.min_subject, self.ell_d_min, ELL_D_MIN),
            ("ell_d_max", self.max_subject, self.ell_d_max, ELL_D_MAX),
        ):
            rows.append({"quantity": quantity, "source": "ours", "subject_id": subject, **by_channel(ours)})
            rows.append({"quantity": quantity, "source": "paper", "subject_id": None, **by_channel(paper)})
        return pd.DataFrame.from_records(rows).set_index(["quantity", "source"])

    def to_frame(self):
        """Table 1 as one row per site and channel, beside the paper's (the ``table`` of :meth:`to_dict`).

        Returns
        -------
        pandas.DataFrame
            Index (``site``, ``channel``): sites as in :attr:`table`, channels R, G, B.  Columns ``mean`` (σtr,
            mm⁻¹), ``paper_mean`` (Weyrich Table 1, mm⁻¹), ``var`` (sample variance with :attr:`ddof`, mm⁻²),
            ``std`` (mm⁻¹), ``paper_var`` (Table 1's "Var.", :data:`VAR_NOTE`) and ``n`` (subjects with a value,
            int).
        """
        frame = self.compare_published()
        counts = self.table.xs("n", axis=1, level="statistic").T.stack()  # (site, channel) -> n
        frame["n"] = counts.reindex(frame.index).to_numpy(np.int64)
        return frame

    def to_dict(self) -> dict:
        """The JSON document of the analysis (``facestats analyze translucency`` writes it as ``translucency.json``).

        Keys (conventions: :mod:`facestats.analysis.serialize`):
        ``n_subjects``, ``ddof``; ``table``: a list of ``{site, channel, mean,
        var, std, n, paper_mean, paper_var}`` (:meth:`compare_published` and
        the subject count); ``sigma_tr_avg`` and ``published_sigma_tr_avg``
        (by channel); ``ell_d_min`` and ``ell_d_max`` (``{subject_id, R, G,
        B}``: least and most translucent subject) with
        ``published_ell_d_min``/``published_ell_d_max``; ``var_note``
        (:data:`VAR_NOTE`).
        """

        doc = {
            "n_subjects": int(len(self.subjects)),
            "ddof": self.ddof,
            "table": records(self.to_frame()),
            "sigma_tr_avg": by_channel(self.sigma_tr_avg),
            "published_sigma_tr_avg": by_channel(SIGMA_TR_AVG),
            "ell_d_min": {"subject_id": self.min_subject, **by_channel(self.ell_d_min)},
            "ell_d_max": {"subject_id": self.max_subject, **by_channel(self.ell_d_max)},
            "published_ell_d_min": by_channel(ELL_D_MIN),
            "published_ell_d_max": by_channel(ELL_D_MAX),
            "var_note": VAR_NOTE,
        }
        return json_ready(doc)

    def to_text(self) -> str:
        """Table 1, σtrAvg and the ℓd extremes beside the paper's (what ``facestats analyze translucency`` prints)."""
        lines = [
            f"Table 1: sigma_tr (1/mm) per site and channel, {len(self.subjects)} subjects (Weyrich Table 1, §5.4)",
            f"{'site':<9}{'ch':<3}{'mean':>8}{'paper':>8}   {'var':>7}{'std':>8}{'paper Var.':>12}",
        ]
        for (site, ch), row in self.compare_published().iterrows():
            lines.append(
                f"{site:<9}{ch:<3}{row['mean']:8.4f}{row['paper_mean']:8.4f}   {row['var']:7.4f}"
                f"{row['std']:8.4f}{row['paper_var']:12.4f}"
            )
        ext = self.compare_published_extremes()

        def rgb(quantity, source):
            return " ".join(f"{x:.4f}" for x in ext.loc[(quantity, source), list(CHANNELS)])

        lines += [
            f"sigma_trAvg (cheek and forehead): {rgb('sigma_tr_avg', 'ours')}   (paper {rgb('sigma_tr_avg', 'paper')})",
            f"l_d least translucent {self.min_subject}: {rgb('ell_d_min', 'ours')} mm   "
            f"(paper {rgb('ell_d_min', 'paper')})",
            f"l_d most translucent {self.max_subject}: {rgb('ell_d_max', 'ours')} mm   "
            f"(paper {rgb('ell_d_max', 'paper')})",
            "note: " + VAR_NOTE,
        ]
        return "\n".join(lines)


def translucency_table(source, subjects=None, conditions=("normal",), ddof=1, rank_by="mean"):
    """Mean and variance of σtr per site and channel, σtrAvg and the ℓd extremes (Weyrich et al. 2006 Table 1, §5.4).

    Reads the population index columns ``site_sigma_tr_{site}_{ch}`` (σtr of
    each site's profile fit, eq. 15).  See the module docstring for how
    "Var.", σtrAvg and the ℓd ranking are reproduced.

    Parameters
    ----------
    source : store or pandas.DataFrame
        Parameter store or its population index.
    subjects, conditions
        Population selection (:func:`facestats.analysis.conditions.select_population`).
    ddof : int
        Delta degrees of freedom of the variance (1: sample variance).
    rank_by : {"mean", "R", "G", "B"}
        Rank subjects' ℓd by its channel mean or by one channel.

    Returns
    -------
    TranslucencyTable

    Raises
    ------
    InsufficientDataError
        If no selected subject has a cheek or forehead σtr, or a site has σtr for at most ``ddof`` subjects
        (a :class:`ValidationError` too).
    """
    import pandas as pd

    check_choice(rank_by, "rank_by", ("mean",) + CHANNELS)
    ddof = check_integer(ddof, "ddof", 0)
    frame = select_population(source, subjects, conditions)
    stats = {}
    for site in SITES:
        cols = [f"site_sigma_tr_{site}_{ch}" for ch in CHANNELS]
        if not all(c in frame.columns for c in cols):
            continue
        vals = frame[cols].astype(float)
        vals.columns = list(CHANNELS)
        n = vals.notna().sum(axis=0)
        few = (n > 0) & (n <= ddof)  # the variance would be NaN or negative: say so rather than print it
        if few.any():  # too few subjects for the variance asked for (analyze all skips the table and says why)
            raise InsufficientDataError(
                f"ddof must be less than the number of subjects with a {site} sigma_tr ({int(n[few].min())}), "
                f"got {ddof}"
            )
        stats[(site, "mean")] = vals.mean(axis=0)
        stats[(site, "var")] = vals.var(axis=0, ddof=ddof)
        stats[(site, "std")] = vals.std(axis=0, ddof=ddof)
        stats[(site, "n")] = n
    table = pd.DataFrame(stats, index=pd.Index(list(CHANNELS), name="channel"))
    table.columns = pd.MultiIndex.from_tuples(table.columns, names=["site", "statistic"])

    sig = subject_sigma_tr(frame)
    have = sig.notna().all(axis=1) & (sig > 0).all(axis=1)
    if not have.any():
        raise InsufficientDataError("no selected subject has a cheek or forehead sigma_tr in all three channels")
    sig = sig[have]
    sigma_tr_avg = sig.mean(axis=0).to_numpy()
    ell = 1.0 / sig
    per = pd.DataFrame(index=sig.index)
    for ch in CHANNELS:
        per[f"sigma_tr_{ch}"] = sig[ch]
    for ch in CHANNELS:
        per[f"ell_d_{ch}"] = ell[ch]
    per["ell_d_mean"] = ell.mean(axis=1)
    for meta in ("skin_type", "gender", "age"):
        per[meta] = frame.loc[sig.index, meta]
    key = per["ell_d_mean"] if rank_by == "mean" else per[f"ell_d_{rank_by}"]
    lo, hi = key.idxmin(), key.idxmax()
    ell_cols = [f"ell_d_{ch}" for ch in CHANNELS]
    return TranslucencyTable(
        table=table,
        sigma_tr_avg=sigma_tr_avg,
        subjects=per,
        min_subject=str(lo),
        max_subject=str(hi),
        ell_d_min=per.loc[lo, ell_cols].to_numpy(float),
        ell_d_max=per.loc[hi, ell_cols].to_numpy(float),
        rank_by=rank_by,
        ddof=ddof,
    )
