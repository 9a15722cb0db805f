"""The result of a store-level edit: the new subject and what was done (:class:`SubjectEdit`).

Made by :meth:`facestats.edit.session.EditSession.write`; summarised by
:meth:`SubjectEdit.region_means` (a table of means before/after/target),
:meth:`SubjectEdit.to_dict` (plain data) and :meth:`SubjectEdit.to_text` (the
report ``facestats edit`` prints); drawn by
:func:`facestats.edit.plots.plot_subject_edit`.
"""

from __future__ import annotations

import os
import pathlib
from dataclasses import dataclass, field

import numpy as np

from facestats.core.conventions import CHANNELS, REGIONS
from facestats.edit.masks import present_regions
from facestats.edit.texture import TextureTransfer

__all__ = ["SubjectEdit", "BRDF_VARIABLES"]

#: The BRDF maps an edit can change (Torrance-Sparrow and Blinn-Phong parameters).
BRDF_VARIABLES = ("ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent")
#: Target subjects named in :meth:`SubjectEdit.to_text` before "...".
_SHOWN_TARGETS = 6


@dataclass(frozen=True)
class SubjectEdit:
    """Result of a subject edit: the new subject and what was done.

    Attributes
    ----------
    subject_id : str
        Id of the new subject.
    dataset : xarray.Dataset
        The new subject as written (or, in a :class:`~facestats.edit.session.PendingEdit`, as it will be).
    source : xarray.Dataset
        The source subject as read (unchanged).  In both, the variables no edit reads
        (:data:`facestats.edit.session.ON_DISK`: micro-normals) are dask arrays read from the
        source's files on access; once the source is replaced or deleted in its store, reading
        them raises :class:`~facestats.errors.StoreError` saying so (read the new subject from
        the store instead).
    edit : dict
        The edit record stored in the provenance: ``name``, ``parameters``,
        ``target``, ``regions_edited``.
    store : str
        Label of the store the subject was (or, pending, will be) written to.
    variables : tuple of str
        Variables whose values the edit changed.
    targets : tuple of str
        Subjects whose statistics formed the target (empty for a statistics file).
    target_means : dict
        Means of the target samples: ``{variable: {region: mean}}`` for BRDF maps,
        ``{"albedo": array (3,)}`` for colour targets (linear RGB).
    texture : TextureTransfer or None
        Convergence report of a texture transfer.
    """

    subject_id: str
    dataset: object = field(repr=False)
    source: object = field(repr=False)
    edit: dict
    store: str
    variables: tuple = ()
    targets: tuple = ()
    target_means: dict = field(default_factory=dict, repr=False)
    texture: TextureTransfer | None = field(default=None, repr=False)

    @property
    def brdf_variables(self) -> list[str]:
        """The BRDF maps the edit changed, in the order of :attr:`variables`."""
        return [v for v in self.variables if v in BRDF_VARIABLES]

    def region_means(self):
        """Means before, after and of the target, per edited map and region, as a :class:`pandas.DataFrame`.

        Columns ``variable``, ``region``, ``name``, ``before``, ``after``,
        ``target``.  BRDF maps: one row per region of the subject.  Albedo: one
        row per channel (``albedo_R``…) over the edited regions (``region`` 0,
        ``name`` "edited").  ``target`` is the mean of the target samples (NaN
        when the edit had no sample target, e.g. a texture transfer).

        Returns
        -------
        pandas.DataFrame
        """
        import pandas as pd

        rows = []
        region = np.asarray(self.source["region"].values)
        if "albedo" in self.variables:
            done = self.edit.get("regions_edited", [])
            done = done.get("albedo", []) if isinstance(done, dict) else done
            sel = np.isin(region, done) if done else region > 0
            before = np.asarray(self.source["albedo"].values, np.float64)[sel]
            after = np.asarray(self.dataset["albedo"].values, np.float64)[sel]
            tgt = self.target_means.get("albedo", np.full(3, np.nan))
            for c, ch in enumerate(CHANNELS):
                rows.append(("albedo_" + ch, 0, "edited", before[:, c].mean(), after[:, c].mean(), float(tgt[c])))
        for var in self.brdf_variables:
            before = np.asarray(self.source[var].values, np.float64)
            after = np.asarray(self.dataset[var].values, np.float64)
            for r in present_regions(region):
                sel = region == r
                tgt = self.target_means.get(var, {}).get(r, np.nan)
                rows.append((var, r, REGIONS[r], before[sel].mean(), after[sel].mean(), tgt))
        return pd.DataFrame(rows, columns=["variable", "region", "name", "before", "after", "target"])

    def to_dict(self) -> dict:
        """The edit as plain data.

        Returns
        -------
        dict
            ``subject_id``, ``store``, ``source_subject``, ``edit`` (the record
            stored in the provenance), ``variables`` and ``targets`` (lists),
            and for a texture transfer ``distance`` (the mean band-histogram
            distance to the target per iteration, a list) and ``iterations``.
        """
        out = {
            "subject_id": self.subject_id,
            "store": self.store,
            "source_subject": str(self.source.attrs["subject_id"]),
            "edit": self.edit,
            "variables": list(self.variables),
            "targets": list(self.targets),
        }
        if self.texture is not None:
            out["distance"] = [float(d) for d in self.texture.distance]
            out["distance_floor"] = float(self.texture.floor)
            out["iterations"] = self.texture.iterations
        return out

    def to_text(self, images=None, directory=".", scales=None) -> str:
        """The report of the edit, as ``facestats edit`` prints it.

        Parameters
        ----------
        images : list of pathlib.Path, optional
            Files written by :func:`facestats.edit.plots.save_edit_images`, listed by name.
        directory : str or pathlib.Path
            The directory they are in (shown as an absolute path).
        scales : dict of str to str, optional
            File name → its scale in words, shown after the name (what
            :func:`facestats.edit.plots.stage_edit_images` returns).

        Returns
        -------
        str
            Lines: the new id; the store; the edit with its parameters (those
            not None); the target (file, statistics, or up to six subjects);
            the variables changed; the images; for a texture transfer the
            histogram distance at the start and after the last iteration.
        """
        d = self.to_dict()
        edit = d["edit"]
        params = ", ".join(f"{k}={v}" for k, v in edit["parameters"].items() if v is not None)
        lines = [
            d["subject_id"],
            f"wrote subject {d['subject_id']} to store {d['store']}",
            f"  edit {edit['name']} of {d['source_subject']} ({params})",
            f"  target: {_describe_target(edit.get('target', {}), d['targets'])}",
            f"  variables changed: {', '.join(d['variables'])}",
        ]
        if images is not None:
            lines.append(f"images ({len(images)}) in {os.path.abspath(directory)}:")
            scales = scales or {}
            for f in images:
                name = pathlib.Path(f).name
                lines.append(f"  {name}: {scales[name]}" if name in scales else f"  {name}")
        if self.texture is not None:
            dist, floor = d["distance"], d["distance_floor"]
            lines.append(
                f"histogram distance to the target (mean over bands): {dist[0]:.3f} at the start, {dist[-1]:.3f} "
                f"after {d['iterations']} iteration(s); {_floor_words(dist[0], dist[-1], floor)}"
            )
        return "\n".join(lines)


#: Share of the distance above its sampling floor at the start that a transfer must remove to be reported as a
#: change: 5 % on the default store's 48² regions (0.708 -> 0.703 over a floor of 0.613), 66 % on the texture
#: sample's face (0.444 -> 0.279 over 0.195; README, *Texture transfer needs coefficients*).
MOVED_SHARE = 0.25


def _floor_words(start, final, floor) -> str:
    """The distances against their sampling floor, in words: the share of the distance above it the iterations
    removed, and whether that is a change at all."""
    above = start - floor
    if not above > 0:
        return (
            f"sampling floor {floor:.3f}: the start is at it, so these band histograms cannot tell the source from "
            "the target (too few coefficients per band)"
        )
    share = (start - final) / above
    verdict = "no measurable change: " if share < MOVED_SHARE else ""
    return f"sampling floor {floor:.3f}: {verdict}{100 * share:.0f} % of the distance above it removed"


def _describe_target(record, targets) -> str:
    """The target of an edit in words: its statistics file, statistics, or its subjects."""
    if "file" in record:
        return f"statistics {record['file']}"
    if "statistics" in record:
        return "texture statistics"
    n = len(targets)
    return f"{n} subject(s): " + ", ".join(targets[:_SHOWN_TARGETS]) + (" ..." if n > _SHOWN_TARGETS else "")
