"""Population queries on the store index: the "interactive applet" of Weyrich et al. 2006 §7.

§7 (Dissemination) describes an applet that "outputs average parameter values
and histograms based on user choice for gender, age, and skin type".
:func:`run_query` does that on the population index (one row per subject,
:mod:`facestats.io.summary`), without opening any subject, using numpy only
(no xarray, zarr or pandas: ``facestats query`` must start fast).

The module is longer than most (~650 lines) because the query and its three
renderings of one document (JSON, CSV, the terminal table) stay together, so
that their fields cannot drift apart.

Filters
-------
* ``skin_type``: Fitzpatrick type, Roman (``"IV"``) or 1-6, or several (``"V,VI"``
  or a list).  The paper groups types I and II (Table 2), so asking for I or for
  II matches subjects of both.
* ``gender``: ``"M"``/``"F"`` (also male/female, 0 = M, 1 = F).
* ``age``: ``"20s"``, ``"30s"``, ``"40s"``, ``"50s+"``, ``"MIN-MAX"`` or one age (inclusive, years).
* ``condition``: one of ``facestats.core.conventions.CONDITIONS``, or ``"any"``
  (:data:`ANY_CONDITION`; ``None`` too) for every condition: records of one
  person measured under several conditions (§7) then count separately
  (``n_persons`` counts distinct people).  :meth:`facestats.io.Store.query` and
  ``facestats query`` default to ``"normal"``, the population as the paper
  analyses it (and as :mod:`facestats.analysis` does).
* ``region``: restricts the per-region BRDF section to one region (1-10 or a
  name); it does not select subjects.

Statistics
----------
For every quantity, ``mean`` and ``std`` (sample standard deviation, ddof = 1;
null for fewer than two values) are taken *across the matching subjects* of
each subject's own value, and ``n`` counts the subjects that have the quantity
(imported subjects have no sensor data, for instance).  Per-region BRDF
entries also give ``within_std``: the mean over subjects of the spread of the
parameter inside the region of one subject; and the fit's own uncertainty
(the robust HC3 standard errors of the eq. 14 fit, with the albedo's propagated
uncertainty, that the pipeline stores per texel; ``docs/scale.md``,
:mod:`facestats.io.summary`): ``mean_se``, the standard error of one
subject's region mean — the within-subject uncertainty to set beside the
between-subject ``std`` —, and ``texel_se``, the typical standard error of one
texel, both over the texels the fit determines (standard error at most the value:
:data:`facestats.io.summary.DETERMINED_RELATIVE_SE`); both are root mean squares
over the subjects that have them (null when none has: older stores, imported or
edited parameters).  Albedo statistics and
histograms are over the whole face.  The albedo histogram (256 bins over
[0, 1] per channel) is the mean of the matching subjects' normalised
histograms, so every subject weighs the same whatever its texel count.

JSON document (``QueryResult.to_dict()``, ``facestats query --format json``)
-------------------------------------------------------------------------
Format ``"facestats.query/1"``; keys are only ever added within a format
version.  ``stat`` below is ``{"mean": float|null, "std": float|null,
"n": int}`` (BRDF stats also carry ``"within_std"``, ``"mean_se"`` and ``"texel_se"``;
the subject-level ``scattering`` stats carry ``"constant"``: true when at least two
subjects have the quantity and all carry the same value, as every measured subject
carries the population's σtrAvg (Weyrich §5.4), so ``std`` 0 is no spread of
measurements but a population constant; the text report labels such a row
"(population)" and prints the value without "± 0")::

    {
      "format": "facestats.query/1",
      "store": str,                      # store path, or "default"
      "n_store_subjects": int,
      "filters": {"skin_type": [int]|null, "gender": "M"|"F"|null,
                  "age": [min, max]|null, "condition": str|null, "region": int|null,
                  "edits": bool},        # subjects written by an edit included (default false)
      "count": int,                      # matching subject records
      "n_edits_left_out": int,           # edited subjects matching the filters, left out
      "n_persons": int,                  # distinct person_id among them
      "subject_ids": [str],
      "breakdown": {"gender": {"M": int, ...}, "skin_type": {"IV": int, ...},
                    "age_group": {"20s": int, ...}, "condition": {...}, "kind": {...}},
      "units": {"rho_s": "1", "m": "1", "exponent": "1", "sigma": "mm-1", "albedo": "1"},
      "regions": [{"region": int, "name": str,
                   "ts_rho_s": stat, "ts_m": stat, "bp_rho_s": stat, "bp_exponent": stat}],
      "scattering": {"sigma_a" | "sigma_s_prime" | "sigma_tr": {"R"|"G"|"B": stat+constant}},
      "sites": {"cheek" | "forehead" | "neck": {"sigma_a" | "sigma_s_prime" | "sigma_tr": {"R"|"G"|"B": stat}}},
      "albedo": {"R"|"G"|"B": stat},
      "albedo_histogram": {"bins": 256, "range": [0.0, 1.0],
                           "R"|"G"|"B": [256 floats summing to 1] | null}
    }

When nothing matches, ``count`` is 0, every ``mean``/``std`` is null, every
``n`` is 0 and the histogram channels are null.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field

import numpy as np

from facestats.core.conventions import (
    AGE_GROUPS,
    CHANNELS,
    CONDITIONS,
    EDIT_SOURCE,
    GENDERS,
    REGIONS,
    ROMAN,
    SITES,
    parse_age,
    parse_condition,
    parse_gender,
    parse_region,
    parse_skin_type,
)
from facestats.errors import ValidationError
from facestats.io.summary import BRDF_PARAMS, HIST_BINS, column

__all__ = [
    "ANY_CONDITION",
    "parse_skin_types",
    "QUERY_FORMAT",
    "Stat",
    "QueryResult",
    "normalise_filters",
    "breakdown",
    "run_query",
    "histogram_sparkline",
]

#: Version tag of the JSON document.
QUERY_FORMAT = "facestats.query/1"
#: Scattering parameters reported per channel (subject level and per site).
SCATTERING = ("sigma_a", "sigma_s_prime", "sigma_tr")
UNITS = {"rho_s": "1", "m": "1", "exponent": "1", "sigma": "mm-1", "albedo": "1"}
_SYMBOL = {"sigma_a": "σa", "sigma_s_prime": "σ's", "sigma_tr": "σtr"}
_ASCII_SYMBOL = {"sigma_a": "sigma_a", "sigma_s_prime": "sigma_s'", "sigma_tr": "sigma_tr"}


@dataclass(frozen=True)
class Stat:
    """Mean and sample standard deviation of ``n`` values (NaN when undefined).

    BRDF statistics also carry ``within_std`` (spread inside a subject's region),
    ``mean_se`` and ``texel_se`` (the fit's standard errors; module docstring).

    Attributes
    ----------
    mean, std : float
        Mean and sample standard deviation (ddof = 1) across the subjects' values; NaN for no value (``std``:
        fewer than two); the quantity's units (mm⁻¹ for σ, 1 otherwise).
    n : int
        Subjects that have the quantity (finite values).
    within_std : float or None
        BRDF statistics: the mean over subjects of the parameter's spread inside a subject's region; None otherwise.
    mean_se, texel_se : float or None
        BRDF statistics: RMS over subjects of the standard error of a subject's region mean and of one texel
        (NaN when no subject has them); None otherwise.
    constant : bool or None
        Subject-level scattering statistics: True when at least two subjects have the quantity and all carry the
        same value (``std`` 0), as every measured subject carries the population's σtrAvg (Weyrich §5.4) — a
        population constant, not a spread of per-subject measurements; None for other statistics.
    """

    mean: float
    std: float
    n: int
    within_std: float | None = None
    mean_se: float | None = None
    texel_se: float | None = None
    constant: bool | None = None

    def to_dict(self) -> dict:
        """The statistic as a JSON-ready dict (NaN as null; the optional fields when present)."""
        d = {"mean": _num(self.mean), "std": _num(self.std), "n": int(self.n)}
        for key in ("within_std", "mean_se", "texel_se"):
            if getattr(self, key) is not None:
                d[key] = _num(getattr(self, key))
        if self.constant is not None:
            d["constant"] = bool(self.constant)
        return d


def _num(x):
    return None if x is None or not math.isfinite(x) else float(x)


def _rms(x: np.ndarray) -> float:
    """Root mean square of the finite values of ``x`` (NaN if none)."""
    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else math.nan


def _stat(x: np.ndarray, within: np.ndarray | None = None, *, constant: bool = False) -> Stat:
    """Stat of the finite values of ``x`` (no warnings on empty input); ``constant``: say whether every value is the
    same (:attr:`Stat.constant`)."""
    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    n = int(x.size)
    mean = float(x.mean()) if n else math.nan
    std = float(x.std(ddof=1)) if n > 1 else math.nan
    if n > 1 and x.min() == x.max():  # equal values (σtr from σtrAvg): no spread, not the sums' rounding (1e-16)
        mean, std = float(x[0]), 0.0
    w = None
    if within is not None:
        within = np.asarray(within, dtype=np.float64)
        within = within[np.isfinite(within)]
        w = float(within.mean()) if within.size else math.nan
    same = bool(n > 1 and std == 0.0) if constant else None
    return Stat(mean, std, n, w, constant=same)


#: The ``condition`` filter's value that matches every condition (as None does).
ANY_CONDITION = "any"


def parse_skin_types(value) -> list:
    """The skin types a ``skin_type`` filter matches: sorted ints 1-6, types I and II grouped (Weyrich Table 2).

    Parameters
    ----------
    value : int, str or sequence
        One type (``"IV"``, ``4``), several separated by commas (``"V,VI"``), or a sequence of them.

    Returns
    -------
    list of int
        E.g. ``[1, 2]`` for ``"II"``, ``[5, 6]`` for ``"V,VI"``.

    Raises
    ------
    ValidationError
        A value that is not a skin type (:func:`facestats.core.conventions.parse_skin_type`), or no value.
    """
    if isinstance(value, str):
        items = value.split(",")
    elif isinstance(value, (list, tuple)):
        items = list(value)
    else:
        items = [value]
    if not items:
        raise ValidationError(f"skin type must name at least one of I-VI or 1-6, got {value!r}")
    types = set()
    for item in items:
        try:
            t = parse_skin_type(item)
        except ValidationError as exc:  # name the whole value: "IV," fails on its empty second item
            if len(items) == 1:
                raise
            raise ValidationError(f"{exc} (an item of {value!r})") from None
        types.update((1, 2) if t in (1, 2) else (t,))
    return sorted(types)


def normalise_filters(skin_type=None, gender=None, age=None, condition=None, region=None, edits=False) -> dict:
    """Parse the query filters (raises :class:`facestats.errors.ValidationError` on a bad value).

    Parameters
    ----------
    skin_type, gender, age, condition, region
        The filters of :func:`run_query` (None: no filter).
    edits : bool
        Also match subjects written by an edit (default: measured subjects only).

    Returns
    -------
    dict
        The JSON-ready form used in :attr:`QueryResult.filters`: skin types as
        a list of ints (I and II are grouped), age as ``[min, max]``.
    """
    if not isinstance(edits, (bool, np.bool_)):
        raise ValidationError(f"edits must be True or False, got {edits!r}")
    out = {"skin_type": None, "gender": None, "age": None, "condition": None, "region": None, "edits": bool(edits)}
    if skin_type is not None:
        out["skin_type"] = parse_skin_types(skin_type)
    if gender is not None:
        out["gender"] = parse_gender(gender)
    if age is not None:
        out["age"] = list(parse_age(age))
    if condition is not None and str(condition).strip().lower() != ANY_CONDITION:
        try:
            out["condition"] = parse_condition(condition)
        except ValidationError as exc:  # "any" is a value too
            raise ValidationError(f"{exc} (or {ANY_CONDITION!r} for every condition)") from None
    if region is not None:
        out["region"] = parse_region(region)
    return out


def describe_filters(filters: dict) -> str:
    """A one-line human description of normalised filters.

    Parameters
    ----------
    filters : dict
        From :func:`normalise_filters`.

    Returns
    -------
    str
    """
    parts = []
    st = filters.get("skin_type")
    parts.append("skin type " + ("any" if st is None else "/".join(ROMAN[t] for t in st)))
    parts.append("gender " + (filters.get("gender") or "any"))
    a = filters.get("age")
    parts.append("age " + ("any" if a is None else f"{a[0]}-{a[1]}"))
    parts.append("condition " + (filters.get("condition") or "any"))
    if filters.get("region") is not None:
        r = filters["region"]
        parts.append(f"region {r} ({REGIONS[r]})")
    if filters.get("edits"):
        parts.append("edited subjects included")
    return ", ".join(parts)


@dataclass(frozen=True)
class QueryResult:
    """What :meth:`facestats.io.store.Store.query` returns (see the module docstring).

    Attributes
    ----------
    filters : dict
        Normalised filters.
    count, n_persons : int
        Matching subject records and distinct persons among them.
    subject_ids : tuple of str
    n_store : int
        Subjects in the store.
    breakdown : dict
        Counts of the matches by gender, skin type (Roman), age group, condition, kind.
    regions : tuple of dict
        Per region: ``{"region", "name", "ts_rho_s": Stat, "ts_m": Stat, "bp_rho_s": Stat, "bp_exponent": Stat}``.
    scattering : dict
        ``{param: {channel: Stat}}`` for σa, σ's, σtr of the subjects (mm⁻¹).
    sites : dict
        ``{site: {param: {channel: Stat}}}`` for the contact-sensor sites (mm⁻¹).
    albedo : dict
        ``{channel: Stat}`` of the subjects' mean face albedo.
    albedo_histogram : numpy.ndarray or None
        (3, 256) mean normalised histogram (rows R, G, B); None if nothing matches.
    store : str
        Where the data came from.
    n_edits_left_out : int
        Edited subjects that match the filters but were left out (``edits=False``).
    """

    filters: dict
    count: int
    n_persons: int
    subject_ids: tuple
    n_store: int
    breakdown: dict
    regions: tuple
    scattering: dict
    sites: dict
    albedo: dict
    albedo_histogram: np.ndarray | None = field(repr=False)
    store: str = ""
    n_edits_left_out: int = 0

    # -- JSON ----------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The documented JSON document (format ``facestats.query/1``; NaN -> null)."""
        hist = {"bins": HIST_BINS, "range": [0.0, 1.0]}
        for c, ch in enumerate(CHANNELS):
            hist[ch] = None if self.albedo_histogram is None else [float(v) for v in self.albedo_histogram[c]]
        return {
            "format": QUERY_FORMAT,
            "store": self.store,
            "n_store_subjects": int(self.n_store),
            "filters": dict(self.filters),
            "count": int(self.count),
            "n_edits_left_out": int(self.n_edits_left_out),
            "n_persons": int(self.n_persons),
            "subject_ids": list(self.subject_ids),
            "breakdown": {k: dict(v) for k, v in self.breakdown.items()},
            "units": dict(UNITS),
            "regions": [
                {"region": r["region"], "name": r["name"], **{p: r[p].to_dict() for p in BRDF_PARAMS}}
                for r in self.regions
            ],
            "scattering": {p: {ch: s.to_dict() for ch, s in d.items()} for p, d in self.scattering.items()},
            "sites": {
                site: {p: {ch: s.to_dict() for ch, s in d.items()} for p, d in params.items()}
                for site, params in self.sites.items()
            },
            "albedo": {ch: s.to_dict() for ch, s in self.albedo.items()},
            "albedo_histogram": hist,
        }

    def to_json(self, indent: int | None = 2) -> str:
        """The result as JSON text (:meth:`to_dict`; NaN as null).

        Parameters
        ----------
        indent : int or None
            Spaces per indentation level (default 2); None writes one line.

        Returns
        -------
        str
        """
        return json.dumps(self.to_dict(), indent=indent, allow_nan=False)

    # -- CSV -----------------------------------------------------------------------
    def to_csv(self) -> str:
        """Long CSV: one row per statistic, arrays (ids, histograms) space-separated in ``values``.

        Columns: ``section, quantity, region, region_name, site, channel, n,
        mean, std, within_std, values, mean_se, texel_se, constant`` (the last
        three added last so older readers of the first eleven keep working:
        the fit's standard errors of BRDF statistics, and ``true``/``false`` for
        subject-level scattering statistics, :attr:`Stat.constant`, empty
        elsewhere).  Sections: ``meta`` (count,
        n_persons, subject_ids), ``brdf``, ``scattering``, ``site``,
        ``albedo``, ``histogram``.
        """
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(_CSV_COLUMNS)
        w.writerow(["meta", "count", "", "", "", "", self.count, "", "", "", "", "", "", ""])
        w.writerow(["meta", "n_persons", "", "", "", "", self.n_persons, "", "", "", "", "", "", ""])
        ids = " ".join(self.subject_ids)
        w.writerow(["meta", "subject_ids", "", "", "", "", self.count, "", "", "", ids, "", "", ""])
        for section, quantity, s, where in self._stats():
            w.writerow(_csv_stat_row(section, quantity, s, **where))
        for c, ch in enumerate(CHANNELS):
            vals = "" if self.albedo_histogram is None else " ".join(repr(float(v)) for v in self.albedo_histogram[c])
            w.writerow(["histogram", "albedo_histogram", "", "", "", ch, self.count, "", "", "", vals, "", "", ""])
        return buf.getvalue()

    def _stats(self):
        """Every statistic as ``(section, quantity, Stat, where)`` in CSV order (``where``: region, name, site, ch)."""
        for r in self.regions:
            for p in BRDF_PARAMS:
                yield "brdf", p, r[p], {"region": r["region"], "name": r["name"]}
        for p, d in self.scattering.items():
            for ch, s in d.items():
                yield "scattering", p, s, {"ch": ch}
        for site, params in self.sites.items():
            for p, d in params.items():
                for ch, s in d.items():
                    yield "site", p, s, {"site": site, "ch": ch}
        for ch, s in self.albedo.items():
            yield "albedo", "albedo", s, {"ch": ch}

    # -- text ----------------------------------------------------------------------
    def to_table(self, *, ascii: bool = False, columns: int = 32) -> str:
        """A human-readable report; histograms drawn as ``columns``-wide bar strips.

        Parameters
        ----------
        ascii : bool
            ASCII characters only (``+-``, ``rho_s``, ``1/mm``, ``" .:-=+*#@"`` bars) instead of Unicode.
        columns : int
            Characters per histogram strip (default 32); must divide the 256 bins.

        Returns
        -------
        str
            The report's lines, each ending in a newline.

        Raises
        ------
        ValidationError
            If ``columns`` does not divide the histogram length (only checked when there is a histogram to draw).
        """
        lines = [f"facestats query: {describe_filters(self.filters)}", f"store: {self.store} ({self.n_store} subjects)"]
        if self.n_edits_left_out:
            lines.append(
                f"left out: {self.n_edits_left_out} edited subject(s) matching the filters (--edits includes them)"
            )
        if self.count == 0:
            lines.append("no subject matches these filters")
            return "\n".join(lines) + "\n"
        persons = "" if self.n_persons == self.count else f" ({self.n_persons} distinct persons)"
        lines.append(f"matching subjects: {self.count}{persons}")
        lines += self._breakdown_lines()
        pm = "+-" if ascii else "±"
        lines.append("")
        lines += self._brdf_lines(pm, ascii)
        lines.append("")
        lines += self._scattering_lines(pm, ascii)
        lines.append("")
        lines += self._histogram_lines(columns, ascii)
        return "\n".join(lines) + "\n"

    def _breakdown_lines(self) -> list[str]:
        lines = []
        for key, title in (
            ("gender", "gender"),
            ("skin_type", "skin type"),
            ("age_group", "age"),
            ("condition", "condition"),
            ("kind", "kind"),
        ):
            counts = self.breakdown.get(key, {})
            if counts:
                lines.append(f"  {title:<10} " + ", ".join(f"{k} {v}" for k, v in counts.items()))
        return lines

    def _brdf_lines(self, pm: str, ascii: bool) -> list[str]:
        lines = [f"Specular BRDF per region: mean {pm} std across subjects (n = subjects with samples)"]
        head = ["region", "TS rho_s" if ascii else "TS ρs", "TS m", "BP rho_s" if ascii else "BP ρs", "BP n", "n"]
        rows = []
        for r in self.regions:
            rows.append(
                [f"{r['region']:>2} {r['name']}"]
                + [_fmt_stat(r[p], pm) for p in BRDF_PARAMS]
                + [str(max(r[p].n for p in BRDF_PARAMS))]
            )
        lines += _grid(head, rows)
        if any(r[p].mean_se is not None and math.isfinite(r[p].mean_se) for r in self.regions for p in BRDF_PARAMS):
            lines += [
                "",
                "Within-subject uncertainty (fit standard errors, RMS over subjects): region mean / one texel",
            ]
            unc = [[f"{r['region']:>2} {r['name']}"] + [_fmt_se(r[p]) for p in BRDF_PARAMS] for r in self.regions]
            lines += _grid(head[:-1], unc)
        return lines

    def _scattering_lines(self, pm: str, ascii: bool) -> list[str]:
        unit = "1/mm" if ascii else "mm⁻¹"
        lines = [f"Scattering ({unit}) and albedo: mean {pm} std across subjects"]
        sym = _ASCII_SYMBOL if ascii else _SYMBOL
        rows, constant = [], [p for p in SCATTERING if any(self.scattering[p][ch].constant for ch in CHANNELS)]
        for p in SCATTERING:
            label = f"{sym[p]} (population)" if p in constant else sym[p]
            rows.append([label] + [_fmt_stat(self.scattering[p][ch], pm) for ch in CHANNELS])
        for site in SITES:
            for p in SCATTERING:
                stats = [self.sites[site][p][ch] for ch in CHANNELS]
                if any(s.n for s in stats):
                    rows.append([f"{sym[p]} {site}"] + [_fmt_stat(s, pm) for s in stats])
        rows.append(["albedo"] + [_fmt_stat(self.albedo[ch], pm) for ch in CHANNELS])
        lines += _grid(["", *CHANNELS], rows)
        if "sigma_tr" in constant:  # "± 0" read like a fault (fresh-user red teams): no spread shown, and why
            lines += [
                f"({sym['sigma_tr']} (population): one value shared by every subject, the population's average "
                f"{sym['sigma_tr']}Avg (Weyrich et al. 2006,",
                f" section 5.4), from which the maps' {sym['sigma_a']} and {sym['sigma_s_prime']} follow: a population "
                "constant, not a per-subject measurement;",
                " the site rows are the contact sensor's measurements)",
            ]
        others = [sym[p] for p in constant if p != "sigma_tr"]
        if others:
            lines.append(f"({', '.join(others)} (population): one value shared by every subject, no spread)")
        return lines

    def _histogram_lines(self, columns: int, ascii: bool) -> list[str]:
        if self.albedo_histogram is None:
            return ["albedo histograms: no albedo data"]
        lines = [
            f"Albedo histograms ({HIST_BINS} bins over [0, 1] drawn as {columns} columns; "
            "mean of the subjects' normalised histograms)"
        ]
        lines.append("    0" + " " * (columns - 2) + "1")
        for c, ch in enumerate(CHANNELS):
            lines.append(f"{ch}  |{histogram_sparkline(self.albedo_histogram[c], columns, ascii=ascii)}|")
        return lines


_CSV_COLUMNS = (
    "section",
    "quantity",
    "region",
    "region_name",
    "site",
    "channel",
    "n",
    "mean",
    "std",
    "within_std",
    "values",
    "mean_se",
    "texel_se",
    "constant",
)


def _csv_num(x) -> str:
    x = _num(x)
    return "" if x is None else repr(x)


def _csv_stat_row(section, quantity, s: Stat, region="", name="", site="", ch="") -> list:
    """One CSV row of a statistic."""
    within, mean_se, texel_se = ("" if v is None else _csv_num(v) for v in (s.within_std, s.mean_se, s.texel_se))
    constant = "" if s.constant is None else str(bool(s.constant)).lower()
    return [
        section,
        quantity,
        region,
        name,
        site,
        ch,
        s.n,
        _csv_num(s.mean),
        _csv_num(s.std),
        within,
        "",
        mean_se,
        texel_se,
        constant,
    ]


def _fmt_num(x: float) -> str:
    if not math.isfinite(x):
        return "-"
    return f"{x:.4g}"


def _fmt_se(s: Stat) -> str:
    """``mean_se / texel_se`` of a BRDF statistic (``-`` where undefined)."""
    if s.mean_se is None or not math.isfinite(s.mean_se):
        return "-"
    return f"{s.mean_se:.2g} / {_fmt_num(s.texel_se)}"


def _fmt_stat(s: Stat, pm: str) -> str:
    if s.n == 0:
        return "-"
    if s.constant:  # the value every subject carries: no "± 0" (labelled as a population constant)
        return _fmt_num(s.mean)
    if not math.isfinite(s.std):
        return f"{_fmt_num(s.mean)} (n={s.n})"
    return f"{_fmt_num(s.mean)} {pm} {s.std:.2g}"


def _grid(head, rows) -> list[str]:
    widths = [max(len(str(x)) for x in col) for col in zip(head, *rows)]
    out = ["  ".join(str(h).ljust(w) for h, w in zip(head, widths)).rstrip()]
    for r in rows:
        out.append("  ".join(str(x).ljust(w) for x, w in zip(r, widths)).rstrip())
    return out


_BARS = " ▁▂▃▄▅▆▇█"
_ASCII_BARS = " .:-=+*#@"


def histogram_sparkline(hist, columns: int = 32, *, ascii: bool = False) -> str:
    """Draw a histogram as ``columns`` characters (bins summed in groups; height relative to the maximum).

    ``len(hist)`` must be a multiple of ``columns``.  Empty bins print as a
    space, any non-empty bin as at least the lowest bar.

    Parameters
    ----------
    hist : array_like
        Bin counts or weights.
    columns : int
        Characters to draw.
    ascii : bool
        Use ``" .:-=+*#@"`` instead of Unicode block characters.

    Returns
    -------
    str
    """
    h = np.asarray(hist, dtype=np.float64)
    if h.size % columns:
        raise ValidationError(f"columns must divide the histogram length {h.size}, got {columns!r}")
    g = h.reshape(columns, -1).sum(axis=1)
    bars = _ASCII_BARS if ascii else _BARS
    top = g.max()
    if top <= 0:
        return " " * columns
    level = np.ceil(g / top * (len(bars) - 1)).astype(int)
    return "".join(bars[i] for i in level)


def _counts(values, order) -> dict:
    """Occurrences of each value: those of ``order`` first, in that order, then any others sorted."""
    vals, n = np.unique(np.asarray(values, dtype=object).astype(str), return_counts=True)
    d = dict(zip(vals.tolist(), n.tolist()))
    keys = [k for k in order if k in d] + sorted(k for k in d if k not in order)
    return {k: int(d[k]) for k in keys}


def breakdown(table, idx) -> dict:
    """Counts of the index rows ``idx`` by gender, skin type (Roman), age group, condition and kind.

    Parameters
    ----------
    table : facestats.io.index.IndexTable
        The population index as columns.
    idx : array_like of int
        Rows to count.

    Returns
    -------
    dict
        ``{"gender" | "skin_type" | "age_group" | "condition" | "kind": {value: count}}``, known
        values first in their conventional order, then any others sorted.
    """
    if len(idx) == 0:
        return {"gender": {}, "skin_type": {}, "age_group": {}, "condition": {}, "kind": {}}
    ages = table["age"][idx].tolist()
    age_labels = [next(lbl for lbl, lo, hi in AGE_GROUPS if lo <= a <= hi) for a in ages]
    return {
        "gender": _counts(table["gender"][idx], GENDERS),
        "skin_type": _counts([ROMAN[int(t)] for t in table["skin_type"][idx]], ROMAN.values()),
        "age_group": _counts(age_labels, [g[0] for g in AGE_GROUPS]),
        "condition": _counts(table["condition"][idx], CONDITIONS),
        "kind": _counts(table["kind"][idx], ("maps", "samples")),
    }


def run_query(
    table, *, skin_type=None, gender=None, age=None, condition=None, region=None, edits=False, store: str = ""
) -> QueryResult:
    """Filter the index and summarise the matching subjects (see the module docstring).

    Parameters
    ----------
    table : facestats.io.index.IndexTable
        The population index as columns.
    skin_type, gender, age, condition, region
        Filters; ``None`` = no filter.  Invalid values raise
        :class:`facestats.errors.ValidationError`.
    edits : bool
        Also match subjects written by an edit (index ``source`` :data:`EDIT_SOURCE`).  By default
        the statistics are of measured subjects only, as in :mod:`facestats.analysis`: an edit is a
        synthetic subject made from the population and would be counted twice.
    store : str
        Label of the store for the report.

    Returns
    -------
    QueryResult
    """
    filters = normalise_filters(skin_type, gender, age, condition, region, edits)
    mask = _filter_mask(table, filters)
    edited = _edited(table)
    idx = np.flatnonzero(mask & ~edited if not filters["edits"] else mask)
    count = int(idx.size)

    def col(name):
        return _column_values(table, idx, name)

    region_ids = [filters["region"]] if filters["region"] is not None else list(REGIONS)
    scattering = {
        p: {ch: _stat(col(column("subject", param=p, channel=ch)), constant=True) for ch in CHANNELS}
        for p in SCATTERING
    }
    sites = {
        site: {
            p: {ch: _stat(col(column("site", param=p, site=site, channel=ch))) for ch in CHANNELS} for p in SCATTERING
        }
        for site in SITES
    }
    return QueryResult(
        filters=filters,
        count=count,
        n_persons=len(set(table["person_id"][idx].tolist())) if count else 0,
        subject_ids=tuple(table.ids[i] for i in idx),
        n_store=len(table),
        breakdown=breakdown(table, idx),
        regions=tuple(_region_entry(r, col) for r in region_ids),
        scattering=scattering,
        sites=sites,
        albedo={ch: _stat(col(f"albedo_mean_{ch}")) for ch in CHANNELS},
        albedo_histogram=_mean_histogram(table.hists[idx]) if count else None,
        store=store,
        n_edits_left_out=0 if filters["edits"] else int(np.count_nonzero(mask & edited)),
    )


def _edited(table) -> np.ndarray:
    """The index rows of subjects written by an edit (bool)."""
    if "source" not in table.columns:
        return np.zeros(len(table), dtype=bool)
    return np.asarray(table["source"] == EDIT_SOURCE, dtype=bool)


def _filter_mask(table, filters: dict) -> np.ndarray:
    """The index rows matching the normalised filters (``region`` selects no subject)."""
    mask = np.ones(len(table), dtype=bool)
    if not len(table):
        return mask
    if filters["skin_type"] is not None:
        mask &= np.isin(table["skin_type"], filters["skin_type"])
    if filters["gender"] is not None:
        mask &= table["gender"] == filters["gender"]
    if filters["age"] is not None:
        lo, hi = filters["age"]
        mask &= (table["age"] >= lo) & (table["age"] <= hi)
    if filters["condition"] is not None:
        mask &= table["condition"] == filters["condition"]
    return mask


def _column_values(table, idx, name: str) -> np.ndarray:
    """Column ``name`` at the rows ``idx`` as float64 (all NaN if the index has no such column)."""
    if name in table.columns:
        return np.asarray(table[name][idx], dtype=np.float64)
    return np.full(idx.size, np.nan)


def _region_entry(r: int, col) -> dict:
    """The BRDF statistics of region ``r`` (``col(name)``: the matching subjects' column values)."""
    entry = {"region": r, "name": REGIONS[r]}
    for p in BRDF_PARAMS:
        s = _stat(col(column("mean", param=p, region=r)), col(column("std", param=p, region=r)))
        se = {k: _rms(col(column(k, param=p, region=r))) for k in ("mean_se", "se")}
        entry[p] = Stat(s.mean, s.std, s.n, s.within_std, mean_se=se["mean_se"], texel_se=se["se"])
    return entry


def _mean_histogram(hists: np.ndarray):
    """Mean of the normalised (n, 3, bins) histograms per channel, or None if a channel has no data."""
    h = hists.astype(np.float64)  # (n, 3, bins)
    tot = h.sum(axis=2, keepdims=True)
    has = tot[..., 0] > 0  # (n, 3)
    norm = np.divide(h, tot, out=np.zeros_like(h), where=tot > 0)
    k = has.sum(axis=0)  # subjects with albedo data per channel
    if np.all(k > 0):
        return norm.sum(axis=0) / k[:, None]
    return None
