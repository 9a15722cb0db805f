"""How well each specular model fits, per face region: the Blinn-Phong / Torrance-Sparrow error ratio (Weyrich §5.3).

Weyrich et al. 2006 fit both models to every lumitexel and find the spatially
varying Blinn-Phong model "overestimates the specular component and does not
match the photograph as closely as the spatially-varying Torrance-Sparrow
model" (§5.3, Fig. 7).  :func:`model_errors` puts numbers on that from a store:
per region of Fig. 15, over the subjects selected (default: measured under
normal conditions), the median of each subject's median ratio E_BP/E_TS of the
fit errors (eq. 14; both scored on the same 80° samples, see
:class:`facestats.pipeline.FitSettings`), over texels where neither fit is
flagged; the flagged fraction of each model; and the Blinn-Phong exponents
(median, 95th percentile) with the share of texels whose exponent lies outside
the range skin can have (:data:`facestats.model.fitting.solver.PLAUSIBLE_LOBE`,
flagged ``implausible`` by the fit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.analysis.population import select_population
from facestats.analysis.serialize import json_ready
from facestats.core.conventions import FLAG_BITS, REGION_IDS, REGIONS
from facestats.core.progress import progress_bar
from facestats.errors import InsufficientDataError

__all__ = ["ModelErrors", "model_errors"]

_VARIABLES = ["region", "ts_error", "bp_error", "ts_flag", "bp_flag", "bp_exponent"]


@dataclass
class ModelErrors:
    """Per-region comparison of the Blinn-Phong and Torrance-Sparrow fits of a store (:func:`model_errors`).

    Attributes
    ----------
    regions : list of int
        Regions 1-10 (Weyrich Fig. 15).
    error_ratio : ndarray, shape (10,)
        Median over subjects of the subject's median E_BP/E_TS in the region.
    error_ratio_iqr : ndarray, shape (10, 2)
        25th and 75th percentile of the subjects' medians.
    ts_flagged, bp_flagged : ndarray, shape (10,)
        Flagged share of the region's texels over all subjects.
    bp_exponent_median, bp_exponent_p95 : ndarray, shape (10,)
        Of the unflagged Blinn-Phong exponents of the region over all subjects.
    bp_implausible : ndarray, shape (10,)
        Share of the region's texels flagged ``implausible`` by the Blinn-Phong fit.
    overall : dict
        ``error_ratio`` (median over subjects of the face-wide median), ``ts_flagged``,
        ``bp_flagged`` (face-wide shares), ``subjects``.
    subjects : list of str
    """

    regions: list
    error_ratio: np.ndarray
    error_ratio_iqr: np.ndarray
    ts_flagged: np.ndarray
    bp_flagged: np.ndarray
    bp_exponent_median: np.ndarray
    bp_exponent_p95: np.ndarray
    bp_implausible: np.ndarray
    overall: dict
    subjects: list

    def to_dict(self) -> dict:
        """JSON document: ``overall`` and ``regions`` (one entry per region with the attributes above)."""

        rows = []
        for k, r in enumerate(self.regions):
            rows.append(
                {
                    "region": r,
                    "name": REGIONS[r],
                    "error_ratio": self.error_ratio[k],
                    "error_ratio_iqr": self.error_ratio_iqr[k],
                    "ts_flagged": self.ts_flagged[k],
                    "bp_flagged": self.bp_flagged[k],
                    "bp_exponent_median": self.bp_exponent_median[k],
                    "bp_exponent_p95": self.bp_exponent_p95[k],
                    "bp_implausible": self.bp_implausible[k],
                }
            )
        return json_ready({"overall": self.overall, "regions": rows, "subjects": len(self.subjects)})

    def compare_published(self) -> dict:
        """Weyrich §5.3 states the direction only (Blinn-Phong fits worse): ``{"bp_fits_worse": (ours, True)}``."""
        return {"bp_fits_worse": (bool(self.overall["error_ratio"] > 1), True)}

    def to_text(self) -> str:
        """Per region: E_BP/E_TS (median, IQR), flagged shares, Blinn-Phong exponents."""
        o = self.overall
        lines = [
            f"Blinn-Phong vs Torrance-Sparrow fit error E(p) (eq. 14) over {o['subjects']} subjects: "
            f"median ratio {_number(o['error_ratio'])}; flagged {100 * o['ts_flagged']:.2f} % (TS), "
            f"{100 * o['bp_flagged']:.2f} % (BP) of face texels (Weyrich §5.3: Blinn-Phong fits worse)",
            f"{'region':<16}{'E_BP/E_TS':>10}{'IQR':>14}{'TS flag':>9}{'BP flag':>9}"
            f"{'BP n':>8}{'n p95':>8}{'n out':>8}",
        ]
        for k, r in enumerate(self.regions):
            if not np.isfinite(self.error_ratio[k]) and not np.isfinite(self.bp_flagged[k]):
                lines.append(f"{r:>2} {REGIONS[r]:<13}{'-':>10}  (no texels)")
                continue
            lo, hi = self.error_ratio_iqr[k]
            iqr = f"{lo:.1f}-{hi:.1f}" if np.isfinite(lo) else "-"  # a region with texels but none unflagged
            lines.append(
                f"{r:>2} {REGIONS[r]:<13}{_number(self.error_ratio[k]):>10}{iqr:>14}"
                f"{100 * self.ts_flagged[k]:>8.2f}%{100 * self.bp_flagged[k]:>8.2f}%"
                f"{_number(self.bp_exponent_median[k]):>8}{_number(self.bp_exponent_p95[k]):>8}"
                f"{100 * self.bp_implausible[k]:>7.2f}%"
            )
        if o.get("skipped"):
            lines.append(f"left out, without both models' fit errors: {', '.join(o['skipped'])}")
        return "\n".join(lines)


def _number(x) -> str:
    """``x`` with one decimal, or ``-`` when it is NaN (no unflagged texel)."""
    return f"{x:.1f}" if np.isfinite(x) else "-"


def model_errors(store, subjects=None, conditions=("normal",), *, progress: bool = False) -> ModelErrors:
    """Compare the two specular fits of the map subjects of a store, region by region (module docstring).

    Parameters
    ----------
    store : parameter store
        Anything with ``subjects()`` and ``subject(id, lazy=..., variables=...)``.
    subjects : sequence of str, optional
        Subject ids (default: all).
    conditions : sequence of str or None
        Conditions to keep (default normal; None: all).
    progress : bool
        A progress bar over the subjects, whose maps are read one by one (about 75 ms each on a directory store).

    Returns
    -------
    ModelErrors
    """
    frame = select_population(store, subjects, conditions)
    if "kind" in frame.columns:
        frame = frame[frame["kind"] == "maps"]
    if len(frame) == 0:
        raise InsufficientDataError(
            "the selection holds no map subject (fitted maps): there are no fit errors to compare"
        )
    opened, skipped = {}, []
    for sid in (str(s) for s in frame.index):  # the fit errors are optional in the schema (older subjects)
        ds = store.subject(sid, lazy=True)  # opened once (each opening reads and checks its metadata)
        if all(v in ds.variables for v in _VARIABLES):
            opened[sid] = ds
        else:
            skipped.append(sid)
    if not opened:
        raise InsufficientDataError(
            f"no map subject of the selection holds both models' fit errors (ts_error, bp_error): {skipped[:5]}"
        )
    ids = list(opened)
    ratios = np.full((len(ids), len(REGION_IDS)), np.nan)
    face_ratio = np.full(len(ids), np.nan)
    counts = np.zeros((4, len(REGION_IDS)))  # texels, TS flagged, BP flagged, BP implausible
    exponents = [[] for _ in REGION_IDS]
    bar = progress_bar(ids, enabled=progress, desc="fit errors", unit="subject", leave=False)
    for i, sid in enumerate(bar):
        ds = opened.pop(sid)
        region, e_ts, e_bp, f_ts, f_bp, n_bp = (np.asarray(ds[v].values) for v in _VARIABLES)
        both = (f_ts == 0) & (f_bp == 0) & (e_ts > 0)
        ratio = np.where(both, e_bp / np.where(both, e_ts, 1), np.nan)
        face_ratio[i] = np.nanmedian(ratio[region > 0]) if np.any(both & (region > 0)) else np.nan
        for k, r in enumerate(REGION_IDS):
            sel = region == r
            if np.any(sel & both):
                ratios[i, k] = np.nanmedian(ratio[sel])
            counts[:, k] += [sel.sum(), (sel & (f_ts != 0)).sum(), (sel & (f_bp != 0)).sum()] + [
                (sel & ((f_bp & FLAG_BITS["implausible"]) != 0)).sum()
            ]
            exponents[k].append(n_bp[sel & (f_bp == 0)])
    res = _result(ids, ratios, face_ratio, counts, exponents)
    res.overall["skipped"] = skipped
    return res


def _result(ids, ratios, face_ratio, counts, exponents):
    """The :class:`ModelErrors` of the per-subject ratios, flag counts and exponents."""
    with np.errstate(invalid="ignore", divide="ignore"):
        shares = counts[1:] / counts[0]
    n_all = [np.concatenate(e) for e in exponents]
    stat = np.array([[np.median(n), np.percentile(n, 95)] if n.size else [np.nan, np.nan] for n in n_all])
    empty = np.all(np.isnan(ratios), axis=0)
    filled = np.where(empty[None], 0.0, ratios)
    med = np.where(empty, np.nan, np.nanmedian(filled, axis=0))
    iqr = np.where(empty[:, None], np.nan, np.nanpercentile(filled, [25, 75], axis=0).T)
    total = counts.sum(axis=1)
    return ModelErrors(
        regions=list(REGION_IDS),
        error_ratio=med,
        error_ratio_iqr=iqr,
        ts_flagged=shares[0],
        bp_flagged=shares[1],
        bp_exponent_median=stat[:, 0],
        bp_exponent_p95=stat[:, 1],
        bp_implausible=shares[2],
        overall={
            "error_ratio": float(np.nanmedian(face_ratio)) if np.isfinite(face_ratio).any() else float("nan"),
            "ts_flagged": float(total[1] / total[0]),
            "bp_flagged": float(total[2] / total[0]),
            "subjects": len(ids),
        },
        subjects=ids,
    )
