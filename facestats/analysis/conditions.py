"""BRDF differences of one person between external conditions (Weyrich et al. 2006 §7).

Weyrich et al. measured one male subject under seven external conditions
(normal, cold, hot, sweaty, makeup, lotion, powder) and report "noticeable
differences between these BRDFs, especially between lotion / hot and cold /
powder".  :func:`condition_differences` compares, region by region, the mean
specular parameters of one person across conditions, relative to the
reference condition (``"normal"``); :class:`ConditionDifferences` holds the
result, its JSON document and its summary.

Distance between conditions
---------------------------
The paper gives no measure of how different two conditions are.  facestats
standardises the differences of region means by one spread per parameter,
the within-region spread pooled over every region and condition of the
person (the within-group mean square of a one-way analysis of variance whose
groups are the (condition, region) cells),

    s² = Σ_{c,r} (n_{c,r} − 1) s_{c,r}² / Σ_{c,r} (n_{c,r} − 1)

(n texels, s their sample standard deviation in condition c and region r), and
weights each region by its share of the texels, w_r = Σ_c n_{c,r} / Σ_{c,r'} n_{c,r'}:

    d(a, b)² = Σ_r w_r [((ρ̄_{a,r} − ρ̄_{b,r}) / s_ρ)² + ((m̄_{a,r} − m̄_{b,r}) / s_m)²]

(m stands for the lobe parameter, m or the Blinn-Phong n): the root mean
square, over the face's texels, of the standardised difference of their
region's means.  It is the Euclidean distance between the conditions'
vectors (√w_r ρ̄_{c,r} / s_ρ, √w_r m̄_{c,r} / s_m), so a metric: the triangle
inequality holds.  Regions without texels under some condition are left out
(``left_out``).

Before 2026-12-08 each pair of conditions and each region had its own spread,
sqrt((s_a² + s_b²)/2), and every region counted alike.  That is not a metric
(on a 16² store: cold–lotion 62.0 against cold–normal 11.8 plus
normal–lotion 19.5), and regions of a few texels dominated it: at 16² the
eyelids hold 2 texels per condition whose spread of m is 0.0002-0.0015,
against 0.01-0.02 at 48².  A spread per region pooled over the conditions
alone is a metric but keeps that: weighted by texels, the eyelids (2 % of
them) still made 73 % of d² at 16² (2 % at 48²).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facestats.analysis.population import LOBE_NAMES, MODEL_NAMES, index_columns, select_population
from facestats.analysis.serialize import json_ready, records
from facestats.core.conventions import CONDITIONS, REGION_IDS, REGIONS, parse_condition
from facestats.errors import InsufficientDataError, ValidationError

__all__ = ["ConditionDifferences", "condition_differences", "PUBLISHED_PAIRS"]

#: Weyrich §7: the condition pairs the paper singles out ("especially between lotion / hot and cold / powder").
PUBLISHED_PAIRS = (("lotion", "hot"), ("cold", "powder"))


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
        spread (:attr:`spread`; a standardised effect size, not a significance
        statistic, since neighbouring texels are correlated).
    distance : pandas.DataFrame
        Condition × condition matrix of sqrt(Σ_r w_r (z_ρs² + z_lobe²)), with
        z taken between the two conditions (module docstring): how far apart
        two conditions put the BRDF, in pooled within-region spreads, as the
        root mean square over texels.  A metric.
    spread : pandas.Series or None
        ``rho_s_std``, ``lobe_std``: the within-region spread pooled over the
        person's regions and conditions; ``dof``: its degrees of freedom
        Σ (n − 1).
    weights : pandas.Series or None
        Index ``region``: w_r, each region's share of the texels over the
        conditions (summing to 1; 0 in the regions left out).
    left_out : dict of int to str
        Regions left out of :attr:`distance`, with the reason.
    """

    person_id: str
    model: str
    reference: str
    values: object
    differences: object
    distance: object
    spread: object = None
    weights: object = None
    left_out: dict = field(default_factory=dict)

    @property
    def conditions(self) -> tuple[str, ...]:
        """Conditions measured for the person, in :data:`facestats.core.conventions.CONDITIONS` order."""
        present = set(self.values.index.get_level_values("condition"))
        return tuple(c for c in CONDITIONS if c in present)

    @property
    def lobe_name(self) -> str:
        return LOBE_NAMES[self.model][2]

    def mean_differences(self):
        """Region-averaged ``d_rho_s`` and ``d_lobe`` per non-reference condition (DataFrame indexed by condition)."""
        return self.differences.groupby(level="condition", sort=False)[["d_rho_s", "d_lobe"]].mean()

    def most_different_pair(self) -> tuple[str, str, float]:
        """The two conditions furthest apart in :attr:`distance`: (condition, condition, distance)."""
        m = self.distance.to_numpy()
        i, j = divmod(int(m.argmax()), m.shape[1])
        return str(self.distance.index[i]), str(self.distance.columns[j]), float(m[i, j])

    def compare_published(self):
        """Per condition the region-averaged differences and the distance to the reference.

        The paper gives no numbers for §7, only the pairs it singles out
        (:data:`PUBLISHED_PAIRS`); :meth:`most_different_pair` is ours.

        Returns
        -------
        pandas.DataFrame
            Index ``condition`` (non-reference conditions); columns
            ``d_rho_s``, ``d_lobe`` (:meth:`mean_differences`) and ``distance``
            (to the reference, in pooled within-region standard deviations; :attr:`distance`).
        """
        table = self.mean_differences()
        return table.assign(distance=[self.distance.loc[c, self.reference] for c in table.index])

    def to_dict(self) -> dict:
        """The JSON document of the analysis (``facestats analyze conditions`` writes it as ``conditions.json``).

        Keys (conventions: :mod:`facestats.analysis.serialize`): ``model``,
        ``person_id``, ``reference``, ``conditions``; ``values``: a list of
        ``{condition, region, rho_s, lobe, rho_s_std, lobe_std, n}``;
        ``differences``: a list of ``{condition, region, d_rho_s, d_lobe,
        z_rho_s, z_lobe}`` against the reference; ``mean_differences``: by
        condition the region-averaged ``{d_rho_s, d_lobe}``; ``distance``:
        ``{conditions, matrix}`` (in pooled within-region standard deviations,
        the texel-weighted root mean square of the module docstring);
        ``spread``: ``{rho_s_std, lobe_std, dof}`` (the pooled within-region
        spreads); ``weights``: by region the share of the texels w_r;
        ``left_out``: a list of ``{region, name, reason}``.
        """
        mean_diff = self.mean_differences()
        doc = {
            "model": self.model,
            "person_id": self.person_id,
            "reference": self.reference,
            "conditions": list(self.conditions),
            "values": records(self.values.drop(columns="subject_id")),
            "differences": records(self.differences),
            "mean_differences": {c: {"d_rho_s": r["d_rho_s"], "d_lobe": r["d_lobe"]} for c, r in mean_diff.iterrows()},
            "distance": {"conditions": list(self.distance.index), "matrix": self.distance.to_numpy()},
            "spread": None if self.spread is None else self.spread.to_dict(),
            "weights": None if self.weights is None else {str(r): w for r, w in self.weights.items()},
            "left_out": [{"region": r, "name": REGIONS[r], "reason": why} for r, why in self.left_out.items()],
        }
        return json_ready(doc)

    def to_text(self) -> str:
        """Differences and distances per condition and the most different pair (``facestats analyze conditions``)."""
        lines = [
            f"{MODEL_NAMES[self.model]} BRDF of person {self.person_id} under {len(self.conditions)} conditions "
            f"(Weyrich §7), mean over regions against {self.reference!r}",
            f"{'condition':<10}{'d rho_s':>9}{'d ' + self.lobe_name:>11}{'distance':>10}",
        ]
        for c, r in self.compare_published().iterrows():
            lines.append(f"{c:<10}{r['d_rho_s']:9.4f}{r['d_lobe']:11.4f}{r['distance']:10.2f}")
        a, b, d = self.most_different_pair()
        paper = " against ".join(" / ".join(p) for p in PUBLISHED_PAIRS)
        lines.append(
            "distance: root mean square over texels of the region-mean differences, in within-region sd pooled "
            "over regions and conditions (a metric)"
        )
        lines.append(f"most different pair: {a} / {b} ({d:.1f} pooled within-region sd); the paper notes {paper}")
        if self.left_out:
            lines.append("left out: " + self.left_out_text())
        return "\n".join(lines)

    def left_out_text(self) -> str:
        """The regions left out of :attr:`distance` and why (``"region 1 mustache (no texels)"``; ``""`` if none)."""
        return _left_out_text(self.left_out)


def _left_out_text(left_out):
    return "; ".join(f"region {r} {REGIONS[r]} ({why})" for r, why in left_out.items())


def _combine(rows, rho_col, lobe_col, rho_std_col, lobe_std_col, n_col):
    """n-weighted mean and pooled spread of repeated measurements of one condition and region.

    The stored spreads are sample standard deviations (ddof 1, :mod:`facestats.io.summary`), so the pooled
    one is the sample standard deviation of all N = Σ n_i values: the within sums of squares (n_i − 1) s_i²
    plus the between term n_i (m_i − m)², over N − 1 (0 for N = 1).
    """
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
        ss = np.sum((n - 1) * s * s + n * (m - mean) ** 2)  # within + between sums of squares
        var = ss / (n.sum() - 1) if n.sum() > 1 else 0.0
        out += [mean, np.sqrt(var)]
    return out[0], out[2], out[1], out[3], int(n.sum())


def _pick_person(frame, person_id, reference):
    """(person id, their index rows): ``person_id``, or the person measured under the most conditions."""
    if person_id is None:
        n_cond = frame.groupby("person_id")["condition"].nunique()
        has_ref = frame.loc[frame["condition"] == reference, "person_id"].unique()
        candidates = n_cond[n_cond.index.isin(has_ref) & (n_cond > 1)]
        if candidates.empty:
            raise InsufficientDataError(
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
    return str(person_id), rows


def _condition_values(rows, model):
    """Region means and spreads per condition of one person's rows (the ``values`` table)."""
    import pandas as pd

    rho_stem, lobe_stem, _ = index_columns(model)
    out = []
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
            out.append(
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
    return pd.DataFrame.from_records(out).set_index(["condition", "region"])


def _pooled_spread(values, conds):
    """``(spread, weights, left_out)`` of the module docstring.

    ``spread``: the within-region spread of each parameter pooled over the (condition, region) cells,
    s² = Σ (n − 1) s² / Σ (n − 1), with its degrees of freedom; ``weights``: per region w_r = n_r / Σ n (0 where
    the region is left out: no texels under some condition); ``left_out``: those regions and why.
    """
    import pandas as pd

    table = values.loc[conds]
    n = table["n"].unstack("condition").reindex(columns=conds).fillna(0).to_numpy(float)  # (regions, conditions)
    regions = table["n"].unstack("condition").index
    dof = np.clip(n - 1, 0, None)
    left_out = {}
    for r, counts in zip(regions, n):
        if (counts == 0).all():
            left_out[int(r)] = "no texels"
        elif (counts == 0).any():
            left_out[int(r)] = "no texels under " + ", ".join(c for c, m in zip(conds, counts) if m == 0)
    pooled = {}
    for col in ("rho_s_std", "lobe_std"):
        sd = np.nan_to_num(table[col].unstack("condition").reindex(columns=conds).to_numpy(float))
        pooled[col] = float(np.sqrt(np.sum(dof * sd * sd) / dof.sum())) if dof.sum() > 0 else float("nan")
    spread = pd.Series({**pooled, "dof": int(dof.sum())}, dtype=object)
    used = ~regions.isin(list(left_out))
    share = np.where(used, n.sum(axis=1), 0.0)
    weights = pd.Series(share / share.sum() if share.sum() > 0 else share, index=regions, name="weight")
    return spread, weights, left_out


def _standardised(values, spread, cond):
    """(ρ̄, lobe mean) per region of ``cond`` over the pooled spreads."""
    v = values.loc[cond]
    return v["rho_s"] / spread["rho_s_std"], v["lobe"] / spread["lobe_std"]


def _differences(values, spread, conds, reference):
    """The ``differences`` table: every non-reference condition against the reference."""
    import pandas as pd

    ref = values.loc[reference]
    diffs = []
    for cond in conds:
        if cond == reference:
            continue
        v = values.loc[cond]
        d_rho, d_lobe = v["rho_s"] - ref["rho_s"], v["lobe"] - ref["lobe"]
        diffs.append(
            pd.DataFrame(
                {
                    "d_rho_s": d_rho,
                    "d_lobe": d_lobe,
                    "z_rho_s": d_rho / spread["rho_s_std"],
                    "z_lobe": d_lobe / spread["lobe_std"],
                }
            ).assign(condition=cond)
        )
    return pd.concat(diffs).reset_index().set_index(["condition", "region"])


def _distance(values, spread, weights, conds):
    """Condition × condition matrix of the texel-weighted distance (module docstring): the Euclidean distance
    between the conditions' vectors (√w_r ρ̄_r / s_ρ, √w_r lobe_r / s_lobe) over the regions of weight > 0."""
    import pandas as pd

    used = weights.index[weights > 0]
    root_w = np.sqrt(weights.loc[used].to_numpy())
    coords = np.stack(
        [np.concatenate([root_w * z.loc[used].to_numpy() for z in _standardised(values, spread, c)]) for c in conds]
    )  # (conditions, 2 × regions used)
    diff = coords[:, None, :] - coords[None, :, :]
    dist = np.sqrt(np.sum(diff * diff, axis=-1))
    return pd.DataFrame(dist, index=pd.Index(conds, name="condition"), columns=pd.Index(conds, name="condition"))


def condition_differences(source, person_id=None, model="ts", reference="normal"):
    """Region-wise BRDF differences between the conditions of one person (Weyrich et al. 2006 §7).

    For each condition and face region (Fig. 15 numbering) the mean specular
    parameters of the person's measurement are compared with the reference
    condition: Δρs and Δm (or Δn for Blinn-Phong) in parameter units, and the
    same differences standardised by the within-region spread pooled over all
    the person's regions and conditions; the distance between two conditions
    is the texel-weighted root mean square of these standardised differences,
    a metric (module docstring).  Values
    come from the population index columns ``{p}_mean_r{r}``, ``{p}_std_r{r}``
    and ``n_{model}_r{r}``; repeated measurements of one condition are combined
    (n-weighted mean, pooled spread).  Subjects written by an edit are not
    measurements and are left out (as by :func:`select_population`): they keep
    their source's ``person_id`` and would count as repeated measurements.

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
    InsufficientDataError
        If no region has texels under every condition of the person, or the texels have no spread within
        their regions.
    """
    index_columns(model)  # validates the model before anything is read
    reference = parse_condition(reference)
    frame = select_population(source, conditions=None)  # measurements only: an edit keeps its source's person
    if "person_id" not in frame.columns:
        frame = frame.assign(person_id=frame.index.astype(str))
    person_id, rows = _pick_person(frame, person_id, reference)
    values = _condition_values(rows, model)
    conds = [c for c in CONDITIONS if c in set(values.index.get_level_values("condition"))]
    spread, weights, left_out = _pooled_spread(values, conds)
    if not (weights > 0).any() or not (spread["rho_s_std"] > 0 and spread["lobe_std"] > 0):
        why = f"left out: {_left_out_text(left_out)}" if left_out else f"pooled spreads {spread.to_dict()}"
        raise InsufficientDataError(
            f"person {person_id!r} needs a region with texels under every condition and a spread within the "
            f"regions to compare conditions ({why})"
        )
    differences = _differences(values, spread, conds, reference)
    distance = _distance(values, spread, weights, conds)
    return ConditionDifferences(person_id, model, reference, values, differences, distance, spread, weights, left_out)
