"""Which subjects enter a population analysis, and BRDF differences between external conditions.

Weyrich et al. 2006 §7 analyse 149 subjects measured once under normal
conditions, and one male subject measured under seven external conditions
(normal, cold, hot, sweaty, makeup, lotion, powder): "there are noticeable
differences between these BRDFs, especially between lotion / hot and cold /
powder".  This module holds both halves of that split:

* :func:`select_population` picks the rows of the population index that a
  population statistic uses (by default the subjects measured under normal
  conditions, so the repeated measurements of one person do not count seven
  times);
* :func:`condition_differences` compares, region by region, the mean
  specular parameters of one person across conditions, relative to the
  reference condition (``"normal"``).

Every function takes a *source*: a parameter store (anything with a
``subjects()`` method returning the population index, see
:mod:`facestats.io.summary` for its columns) or that index as a
:class:`pandas.DataFrame` indexed by ``subject_id``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.core.conventions import CONDITIONS, REGION_IDS, parse_condition
from facestats.core.validate import check_choice
from facestats.errors import ValidationError

__all__ = ["select_population", "ConditionDifferences", "condition_differences", "LOBE_NAMES", "index_columns"]

#: model -> (scale column stem, lobe column stem, short lobe name used in results).
LOBE_NAMES = {"ts": ("ts_rho_s", "ts_m", "m"), "bp": ("bp_rho_s", "bp_exponent", "exponent")}


def index_columns(model: str) -> tuple[str, str, str]:
    """Column stems of a specular model in the population index: (scale, lobe, lobe short name)."""
    check_choice(model, "model", tuple(LOBE_NAMES))
    return LOBE_NAMES[model]


def _index(source):
    """The population index (one row per subject, indexed by ``subject_id``) of a store or a DataFrame."""
    import pandas as pd

    if isinstance(source, pd.DataFrame):
        frame = source
    elif callable(getattr(source, "subjects", None)):
        frame = source.subjects()
    else:
        raise ValidationError(
            f"source must be a parameter store (with a subjects() method) or its population index DataFrame, "
            f"got {type(source).__name__}"
        )
    if "subject_id" in frame.columns and frame.index.name != "subject_id":
        frame = frame.set_index("subject_id")
    missing = [c for c in ("age", "gender", "skin_type", "condition") if c not in frame.columns]
    if missing:
        raise ValidationError(
            f"the population index must have columns age, gender, skin_type, condition; missing {missing}"
        )
    return frame


def select_population(source, subjects=None, conditions=("normal",)):
    """Rows of the population index that enter a population statistic.

    Parameters
    ----------
    source : store or pandas.DataFrame
        A parameter store (``subjects()`` returns its index) or the index itself.
    subjects : sequence of str, optional
        Subject ids to keep (default: all).  Unknown ids raise.
    conditions : sequence of str or None, optional
        Measurement conditions to keep, default ``("normal",)`` as in Weyrich
        §7, where the population statistics use one normal measurement per
        subject.  ``None`` keeps every condition.

    Returns
    -------
    pandas.DataFrame
        The selected rows, indexed by ``subject_id``.

    Raises
    ------
    ValidationError
        If an id is unknown or nothing is left.
    """
    frame = _index(source)
    if subjects is not None:
        ids = [str(s) for s in ([subjects] if isinstance(subjects, str) else subjects)]
        unknown = [s for s in ids if s not in frame.index]
        if unknown:
            raise ValidationError(f"subjects must be ids of the store, got unknown id(s) {unknown[:5]}")
        frame = frame.loc[ids]
    if conditions is not None:
        conds = [parse_condition(c) for c in ([conditions] if isinstance(conditions, str) else conditions)]
        frame = frame[frame["condition"].isin(conds)]
    if len(frame) == 0:
        raise ValidationError(
            f"the selection (subjects={subjects!r}, conditions={conditions!r}) leaves no subject in the population"
        )
    return frame


@dataclass(frozen=True)
class ConditionDifferences:
    """Per-region specular parameters of one person under several conditions.

    Attributes
    ----------
    person_id : str
    model : str
        ``"ts"`` (Torrance-Sparrow: ρs, m) or ``"bp"`` (Blinn-Phong: ρs, exponent n).
    reference : str
        The condition differences are taken against (``"normal"``).
    values : pandas.DataFrame
        Index (condition, region); columns ``rho_s``, ``lobe`` (region means),
        ``rho_s_std``, ``lobe_std`` (within-region spread over texels/samples),
        ``n`` (texels/samples), ``subject_id``.
    differences : pandas.DataFrame
        Index (condition, region) for the non-reference conditions; columns
        ``d_rho_s``, ``d_lobe`` (condition minus reference) and ``z_rho_s``,
        ``z_lobe``: the same differences in units of the pooled within-region
        spread sqrt((s_c² + s_ref²)/2) (a standardised effect size; not a
        significance statistic, since neighbouring texels are correlated).
    distance : pandas.DataFrame
        Condition × condition matrix of sqrt(mean over regions of
        z_ρs² + z_lobe²), with z taken between the two conditions: how far
        apart two conditions put the BRDF, in within-region spreads.
    """

    person_id: str
    model: str
    reference: str
    values: object
    differences: object
    distance: object

    @property
    def conditions(self) -> tuple[str, ...]:
        """Conditions measured for the person, in :data:`facestats.core.conventions.CONDITIONS` order."""
        present = set(self.values.index.get_level_values("condition"))
        return tuple(c for c in CONDITIONS if c in present)

    @property
    def lobe_name(self) -> str:
        return LOBE_NAMES[self.model][2]


def _combine(rows, rho_col, lobe_col, rho_std_col, lobe_std_col, n_col):
    """n-weighted mean and pooled spread of repeated measurements of one condition and region."""
    n = rows[n_col].to_numpy(float)
    keep = n > 0
    if not keep.any():
        return np.nan, np.nan, np.nan, np.nan, 0
    n = n[keep]
    out = []
    for mcol, scol in ((rho_col, rho_std_col), (lobe_col, lobe_std_col)):
        m = rows[mcol].to_numpy(float)[keep]
        s = np.nan_to_num(rows[scol].to_numpy(float)[keep])
        mean = np.sum(n * m) / n.sum()
        var = np.sum(n * (s * s + (m - mean) ** 2)) / n.sum()  # law of total variance
        out += [mean, np.sqrt(var)]
    return out[0], out[2], out[1], out[3], int(n.sum())


def condition_differences(source, person_id=None, model="ts", reference="normal"):
    """Region-wise BRDF differences between the conditions of one person (Weyrich et al. 2006 §7).

    For each condition and face region (Fig. 15 numbering) the mean specular
    parameters of the person's measurement are compared with the reference
    condition: Δρs and Δm (or Δn for Blinn-Phong) in parameter units, and the
    same differences standardised by the pooled within-region spread.  Values
    come from the population index columns ``{p}_mean_r{r}``, ``{p}_std_r{r}``
    and ``n_{model}_r{r}``; repeated measurements of one condition are combined
    (n-weighted mean, pooled spread).

    Parameters
    ----------
    source : store or pandas.DataFrame
        Parameter store or its population index.
    person_id : str, optional
        The person (index column ``person_id``).  Default: the person measured
        under the most conditions.
    model : {"ts", "bp"}
        Specular model.
    reference : str
        Reference condition, default ``"normal"``.

    Returns
    -------
    ConditionDifferences

    Raises
    ------
    ValidationError
        If no person (or not ``person_id``) was measured under the reference
        and at least one other condition.
    """
    import pandas as pd

    rho_stem, lobe_stem, _ = index_columns(model)
    reference = parse_condition(reference)
    frame = _index(source)
    if "person_id" not in frame.columns:
        frame = frame.assign(person_id=frame.index.astype(str))
    n_cond = frame.groupby("person_id")["condition"].nunique()
    if person_id is None:
        has_ref = frame.loc[frame["condition"] == reference, "person_id"].unique()
        candidates = n_cond[n_cond.index.isin(has_ref) & (n_cond > 1)]
        if candidates.empty:
            raise ValidationError(
                f"no person in the store was measured under {reference!r} and another condition; "
                "condition_differences needs one (Weyrich §7 measured one subject under seven conditions)"
            )
        person_id = str(candidates.sort_values(ascending=False, kind="stable").index[0])
    rows = frame[frame["person_id"].astype(str) == str(person_id)]
    if rows.empty:
        raise ValidationError(f"person_id must be a person of the store, got {person_id!r}")
    if reference not in set(rows["condition"]) or rows["condition"].nunique() < 2:
        raise ValidationError(
            f"person {person_id!r} must be measured under {reference!r} and at least one other condition, "
            f"got conditions {sorted(set(rows['condition']))}"
        )
    records = []
    for cond in CONDITIONS:
        sub = rows[rows["condition"] == cond]
        if sub.empty:
            continue
        for r in REGION_IDS:
            rho, lobe, rho_s, lobe_s, n = _combine(
                sub,
                f"{rho_stem}_mean_r{r}",
                f"{lobe_stem}_mean_r{r}",
                f"{rho_stem}_std_r{r}",
                f"{lobe_stem}_std_r{r}",
                f"n_{model}_r{r}",
            )
            records.append(
                {
                    "condition": cond,
                    "region": r,
                    "rho_s": rho,
                    "lobe": lobe,
                    "rho_s_std": rho_s,
                    "lobe_std": lobe_s,
                    "n": n,
                    "subject_id": ",".join(map(str, sub.index)),
                }
            )
    values = pd.DataFrame.from_records(records).set_index(["condition", "region"])
    conds = [c for c in CONDITIONS if c in set(values.index.get_level_values("condition"))]

    def effect(a, b):
        va, vb = values.loc[a], values.loc[b]
        d_rho = va["rho_s"] - vb["rho_s"]
        d_lobe = va["lobe"] - vb["lobe"]
        s_rho = np.sqrt((va["rho_s_std"] ** 2 + vb["rho_s_std"] ** 2) / 2)
        s_lobe = np.sqrt((va["lobe_std"] ** 2 + vb["lobe_std"] ** 2) / 2)
        z_rho = d_rho / s_rho.where(s_rho > 0)
        z_lobe = d_lobe / s_lobe.where(s_lobe > 0)
        return d_rho, d_lobe, z_rho, z_lobe

    diffs = []
    for cond in conds:
        if cond == reference:
            continue
        d_rho, d_lobe, z_rho, z_lobe = effect(cond, reference)
        diffs.append(
            pd.DataFrame({"d_rho_s": d_rho, "d_lobe": d_lobe, "z_rho_s": z_rho, "z_lobe": z_lobe}).assign(
                condition=cond
            )
        )
    differences = pd.concat(diffs).reset_index().set_index(["condition", "region"])
    dist = np.zeros((len(conds), len(conds)))
    for i, a in enumerate(conds):
        for j, b in enumerate(conds[:i]):
            _, _, z_rho, z_lobe = effect(a, b)
            dist[i, j] = dist[j, i] = float(np.sqrt((z_rho**2 + z_lobe**2).mean()))  # pandas: skips NaN regions
    distance = pd.DataFrame(dist, index=pd.Index(conds, name="condition"), columns=pd.Index(conds, name="condition"))
    return ConditionDifferences(str(person_id), model, reference, values, differences, distance)
