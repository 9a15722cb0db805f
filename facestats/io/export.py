"""The public statistics release of a store (Weyrich et al. 2006 §7, Dissemination).

§7: "We are releasing all reflectance data, such as BRDF coefficients,
absorption and scattering coefficients, and albedo histograms, for each
subject."  :func:`export_statistics` writes exactly that, per subject, from the
population index (which :meth:`facestats.io.store.Store.validate` checks
against the data):

CSV (``formats`` contains ``"csv"``)
    ``subjects.csv``: one row per subject with the columns of
    :func:`facestats.io.summary.summarise_subject` (metadata; per-region mean,
    std and sample count of the Torrance-Sparrow ρs, m and Blinn-Phong ρs, n,
    and the sample covariance of each model's (ρs, lobe) pairs;
    σa, σ's, σtr per channel per contact-sensor site and for the subject;
    albedo mean and std per channel; empty cells are missing values);
    ``albedo_histograms.csv``: one row per subject and channel, columns
    ``subject_id, channel, bin_000 ... bin_255`` (texel or sample counts in
    256 equal bins over [0, 1]).
JSON (``formats`` contains ``"json"``)
    ``statistics.json``, format ``"facestats.export/1"``: ``{"format",
    "facestats_version", "exported", "store", "units", "histogram": {"bins",
    "range"}, "subjects": [...]}`` where each subject is ``{"subject_id",
    "person_id", "age", "gender", "skin_type", "skin_type_roman",
    "condition", "kind", "source", "flagged_fraction",
    "brdf": {"torrance_sparrow": [{"region", "name", "n", "cov", "rho_s": {"mean",
    "std", "se", "mean_se"}, "m": {...}}], "blinn_phong": [{"region", "name", "n", "cov", "rho_s",
    "exponent"}]}, "scattering": {"sigma_a"|"sigma_s_prime"|"sigma_tr":
    {"R", "G", "B"}}, "sites": {site: {param: {"R", "G", "B"}}},
    "albedo": {"mean": {"R", "G", "B"}, "std": {...}}, "albedo_histogram":
    {"R": [256 counts], "G": [...], "B": [...]}}``; missing values are null.

A ``README.txt`` describing the files written and their units is written
beside them; its first line (:data:`RELEASE_TITLE`) marks the folder as a
release.  Units: ρs, m, n, albedo dimensionless; σ in mm⁻¹.  ``se`` is the root
mean square of the fit's per-texel standard errors over the region and
``mean_se`` the standard error of the region mean (:mod:`facestats.io.summary`);
null where the subject has no standard-error maps.  ``cov`` (CSV
``{ts,bp}_cov_r{r}``) is the sample covariance (ddof 1) of the region's (ρs, m)
or (ρs, n) pairs over the samples counted by ``n``, from which, with the
counts, means and standard deviations, the pooled covariance of any selection
of subjects follows exactly (:func:`facestats.analysis.pca.pooled_moments`,
Fig. 15).

The release is written only into a new or empty folder; any other folder is
refused unless ``overwrite=True`` (as every command that writes files asks).
With it, an earlier release is replaced (its files of the other format are
removed, so the folder holds one release), and in a folder that holds no
release the files of the release's names are replaced and nothing is removed.
"""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

from facestats.core.conventions import CHANNELS, REGIONS, ROMAN, SITES
from facestats.core.outputs import OutputSet, check_apart, check_output_dir
from facestats.core.version import __version__
from facestats.errors import ValidationError
from facestats.io.index import utc_now
from facestats.io.query import SCATTERING, UNITS
from facestats.io.summary import HIST_BINS, IDENTITY_COLUMNS, column

__all__ = ["EXPORT_FORMAT", "RELEASE_FILES", "RELEASE_TITLE", "export_statistics"]

EXPORT_FORMAT = "facestats.export/1"
#: The first line of every release's README.txt: what marks a folder as a facestats statistics release.
RELEASE_TITLE = f"facestats statistics release (format {EXPORT_FORMAT})"

_README = """{title}
Exported {when} by facestats {version} from {store} ({n} subjects).

Per subject (Weyrich et al. 2006, §7 Dissemination): BRDF coefficients, absorption
and scattering coefficients, albedo statistics and albedo histograms.
{files}"""

_README_CSV = """
subjects.csv          one row per subject
  subject_id, person_id, age (years), gender (M/F), skin_type (Fitzpatrick 1-6; I and II are
  grouped by the paper), condition, kind (maps = fitted maps, samples = imported samples), source
  {{ts_rho_s,ts_m,bp_rho_s,bp_exponent}}_{{mean,std}}_r{{1..10}}
                      per-region mean and standard deviation of the Torrance-Sparrow rho_s and m
                      and the Blinn-Phong rho_s and exponent n (dimensionless); regions as in
                      Weyrich Fig. 15: {regions}
  n_ts_r*, n_bp_r*    number of texels/samples behind each region statistic
  ts_cov_r*, bp_cov_r*
                      sample covariance (ddof 1) of the region's (rho_s, m) pairs (Torrance-Sparrow)
                      and (rho_s, n) pairs (Blinn-Phong) over those texels/samples; with the counts,
                      means and standard deviations it gives the pooled covariance of any selection
                      of subjects exactly (the ellipses of Weyrich Fig. 15)
  {{...}}_se_r*, {{...}}_mean_se_r*
                      the fit's uncertainty: RMS of the per-texel standard errors (sigma^2 (J^T J)^-1
                      of the eq. 14 fit) over the region, and the standard error of the region mean
  site_{{sigma_tr,sigma_s_prime,sigma_a}}_{{cheek,forehead,neck}}_{{R,G,B}}
                      contact-sensor coefficients per site (1/mm)
  {{sigma_s_prime,sigma_a,sigma_tr}}_{{R,G,B}}
                      subject scattering coefficients (1/mm, Weyrich 5.4)
  albedo_{{mean,std}}_{{R,G,B}}
                      diffuse albedo over the face (dimensionless)
  flagged_fraction    fraction of face texels whose Torrance-Sparrow fit was flagged
  Empty cells are missing values (e.g. imported subjects have no sensor data).
albedo_histograms.csv one row per subject and channel: counts in 256 equal bins over [0, 1]
"""

_README_JSON = """
statistics.json       per subject: metadata, per-region BRDF statistics (n, cov, and mean, std, se,
                      mean_se of rho_s and m / exponent), scattering per site and subject, albedo
                      statistics and histograms (format {fmt}); missing values are null
"""


def _num(v):
    if v is None:
        return None
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _subject_json(sid: str, row: dict, hist) -> dict:
    get = lambda k: _num(row.get(k))  # noqa: E731
    out = {k: get(k) for k in ("subject_id", "person_id", "age", "gender", "skin_type")}
    out["skin_type_roman"] = ROMAN.get(row.get("skin_type"))
    for k in ("condition", "kind", "source", "flagged_fraction"):
        out[k] = get(k)
    brdf = {}
    for model, name, lobe in (
        ("ts", "torrance_sparrow", ("ts_m", "m")),
        ("bp", "blinn_phong", ("bp_exponent", "exponent")),
    ):
        items = []
        for r, rname in REGIONS.items():
            item = {
                "region": r,
                "name": rname,
                "n": get(column("n", model=model, region=r)),
                "cov": get(column("cov", model=model, region=r)),
            }
            for param, key in ((f"{model}_rho_s", "rho_s"), lobe):
                item[key] = {
                    stat: get(column(stat, param=param, region=r)) for stat in ("mean", "std", "se", "mean_se")
                }
            items.append(item)
        brdf[name] = items
    out["brdf"] = brdf
    out["scattering"] = {p: {ch: get(column("subject", param=p, channel=ch)) for ch in CHANNELS} for p in SCATTERING}
    out["sites"] = {
        s: {p: {ch: get(column("site", param=p, site=s, channel=ch)) for ch in CHANNELS} for p in SCATTERING}
        for s in SITES
    }
    out["albedo"] = {stat: {ch: get(f"albedo_{stat}_{ch}") for ch in CHANNELS} for stat in ("mean", "std")}
    out["albedo_histogram"] = {ch: [int(v) for v in hist[c]] for c, ch in enumerate(CHANNELS)}
    return out


#: The files of each format of a statistics release (besides README.txt).
RELEASE_FILES = {"csv": ("subjects.csv", "albedo_histograms.csv"), "json": ("statistics.json",)}


def export_statistics(store, out_dir, formats=("csv", "json"), *, overwrite: bool = False) -> list[Path]:
    """Write the per-subject statistics release of ``store`` into ``out_dir``.

    Parameters
    ----------
    store : facestats.io.store.Store
    out_dir : str or os.PathLike
        Created if missing; never the store's folder or a folder inside it.  An existing folder must be
        empty unless ``overwrite``.  Checked before anything is written, and the files are written all or
        none (:class:`facestats.core.outputs.OutputSet`): a failure (e.g. a full disk) leaves the folder as
        it was.
    formats : iterable of {"csv", "json"}
    overwrite : bool
        Also write into a non-empty folder.  Over an earlier release (its ``README.txt`` starts with
        :data:`RELEASE_TITLE`) the release's files are replaced and those of a format not written now
        (:data:`RELEASE_FILES`) removed, so the folder holds one release; other files there are kept.  In a
        folder that holds no release its files of the release's names (``README.txt`` and those of
        ``formats``) are replaced and nothing is removed.

    Returns
    -------
    list of pathlib.Path
        The files written.

    Raises
    ------
    ValidationError
        Bad ``formats``; ``out_dir`` not a writable folder, inside the store, or non-empty and no release
        without ``overwrite``.
    """
    formats = tuple(formats)
    if not formats or any(f not in ("csv", "json") for f in formats):
        raise ValidationError(f"formats must be a non-empty subset of ['csv', 'json'], got {list(formats)!r}")
    out_dir = check_output_dir(out_dir, "out_dir")
    check_apart(out_dir, store.path, "out_dir")
    entries = sorted(os.listdir(out_dir)) if out_dir.is_dir() else []
    release = _is_release(out_dir)
    if entries and not overwrite:
        shown = ", ".join(repr(e) for e in entries[:5]) + (", ..." if len(entries) > 5 else "")
        what = "an earlier statistics release" if release else f"{len(entries)} entries ({shown})"
        raise ValidationError(
            "out_dir must be a new or empty folder (overwrite=True, --overwrite: replace an earlier release, or "
            f"write into any folder replacing files of the release's names), got {str(out_dir)!r}, which holds "
            f"{what}"
        )
    with OutputSet(out_dir) as out:
        _write_release(store, out, formats)
    if release:  # the earlier release's other format would contradict README.txt; it was written by facestats
        for fmt in set(RELEASE_FILES) - set(formats):
            for name in RELEASE_FILES[fmt]:
                (out_dir / name).unlink(missing_ok=True)
    return out.written


def _is_release(folder: Path) -> bool:
    """Whether ``folder`` holds a statistics release: its ``README.txt`` starts with :data:`RELEASE_TITLE`."""
    readme = folder / "README.txt"
    if not readme.is_file():
        return False
    try:
        with open(readme, encoding="utf-8", errors="replace") as fh:
            first = fh.readline(len(RELEASE_TITLE) + 2)
    except OSError:
        return False
    return first.rstrip("\r\n") == RELEASE_TITLE


def _write_release(store, out: OutputSet, formats) -> None:
    """Write the release files through ``out`` (temporary names, renamed together at the end)."""
    entries = store.index_entries()
    ids = sorted(entries)
    rows = [entries[i]["row"] for i in ids]
    hists = [entries[i]["albedo_hist"] for i in ids]
    if "csv" in formats:
        # every column, in first-seen order (an empty store: the identity columns, a header without rows)
        cols = list(dict.fromkeys(k for r in rows for k in r)) or list(IDENTITY_COLUMNS)
        with open(out.path("subjects.csv"), "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(cols)
            for r in rows:
                w.writerow(["" if _num(r.get(c)) is None else r.get(c) for c in cols])
        with open(out.path("albedo_histograms.csv"), "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["subject_id", "channel"] + [f"bin_{b:03d}" for b in range(HIST_BINS)])
            for sid, h in zip(ids, hists):
                for c, ch in enumerate(CHANNELS):
                    w.writerow([sid, ch] + [int(v) for v in h[c]])
    when = utc_now()
    if "json" in formats:
        doc = {
            "format": EXPORT_FORMAT,
            "facestats_version": __version__,
            "exported": when,
            "store": store.label,
            "units": {**UNITS, "age": "years"},
            "histogram": {"bins": HIST_BINS, "range": [0.0, 1.0]},
            "subjects": [_subject_json(sid, r, h) for sid, r, h in zip(ids, rows, hists)],
        }
        out.path("statistics.json").write_text(json.dumps(doc, indent=1, allow_nan=False))
    files = ""
    if "csv" in formats:
        files += _README_CSV.format(regions=", ".join(f"{k} {v}" for k, v in REGIONS.items()))
    if "json" in formats:
        files += _README_JSON.format(fmt=EXPORT_FORMAT)
    out.path("README.txt").write_text(
        _README.format(title=RELEASE_TITLE, when=when, version=__version__, store=store.label, n=len(ids), files=files)
    )
