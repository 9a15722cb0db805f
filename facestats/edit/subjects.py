"""Appearance edits of store subjects (Weyrich et al. 2006 §8).

§8: an artist changes a face's appearance using the statistics of another
subject or of a population subset ("skin type V", "with lotion").  The
functions here apply the array-level edits of :mod:`facestats.edit` to a
subject of a store and write the result as a **new** subject:

* :func:`transfer_brdf_subject`: per-region BRDF histogram transfer or
  interpolation (:func:`facestats.edit.transfer_brdf`), e.g. normal → lotion
  at t = 0.5;
* :func:`transfer_colour_subject`: albedo histogram transfer in a decorrelated
  colour space (:func:`facestats.edit.transfer_colour`);
* :func:`transfer_texture_subject`: Heeger-Bergen texture transfer
  (:func:`facestats.edit.transfer_texture`), e.g. freckles, optionally within
  face regions;
* :func:`change_skin_type`: colour and BRDF transfer towards the population
  subset of a Fitzpatrick skin type, e.g. II → V;
* :func:`subject_texture_statistics`: the §8 texture statistics of a subject,
  to save and reuse as a target.

Targets
-------
A *target* is another subject id of the source store, or a *query*: a dict
with any of ``skin_type``, ``gender``, ``age``, ``condition``
(:meth:`facestats.io.Store.query`; skin types I and II are grouped as in the
paper).  ``condition`` defaults to ``"normal"`` (the population as the paper
analyses it; pass ``condition=None`` for any condition).  A subset never holds
the source subject itself nor subjects written by an edit (provenance
``source`` = :data:`EDIT_SOURCE`), so earlier edits never feed later targets.

* BRDF samples of a target are its *unflagged* texels per region
  (:meth:`facestats.io.Store.region_samples`; filled texels are not
  measurements), pooled over the subset: every texel (or stored sample) is one
  draw.
* Albedo samples of a target are the linear-RGB albedo values of its face
  texels (or of the chosen regions; stored ``albedo_sample`` values for
  imported subjects), pooled over the subset.  They are read from the
  subjects' maps, not from the index histograms: the index keeps per-channel
  histograms on [0, 1], whereas the decorrelated transfer needs joint RGB
  values (for the PCA basis of Heeger & Bergen 1995 §3.5).  At most
  ``max_samples`` values are kept (an equal random share per subject, drawn
  with ``seed``; the default store's subsets stay well below the cap, so the
  draw is then not random at all).

Translucency (§5.4)
-------------------
The subject's homogeneous dipole is derived from its average albedo:
``α_avg`` = mean albedo over the face, ``(σ's, σa)`` =
:func:`facestats.model.dipole.scattering_from_albedo` (α_avg, σtr).  After an
edit that changes the albedo (colour, texture, skin type) the translucency
follows the new albedo through the pipeline's own stage
(:func:`facestats.model.fitting.scattering_parameters`): ``albedo_avg``,
``sigma_s_prime`` and ``sigma_a`` are recomputed with the subject's own
``sigma_tr`` (which is kept, so σtr = sqrt(3 σa (σa + σ's)) is unchanged) and
the relative index of refraction of its fit (provenance ``fit_settings.eta``,
else 1.38).  With ``keep_translucency=True`` ``albedo_avg``, ``sigma_s_prime``,
``sigma_a`` and ``sigma_tr`` stay the source's: the dipole keeps its profile and
the modulation texture M = albedo / albedo_avg (Weyrich eq. 7) carries the new
albedo.  A stored ``modulation`` variable is recomputed in both cases
(:func:`facestats.io.schema.modulation`).  Per-site sensor data
(``site_*``, ``sensor_profile*``) are measurements of the source and are
copied unchanged, like every variable an edit does not touch.

The new subject
---------------
The edited Dataset is a copy of the source (all variables and attributes),
with the edited variables replaced and, in ``attrs``:

* ``subject_id``: ``new_id`` or ``<source id>.<edit>-<digest>``, the digest
  being the first 8 hex digits of the SHA-256 of the edit record (so the same
  edit of the same subject gets the same id, and is refused the second time
  unless ``overwrite=True``);
* ``provenance`` (JSON): ``source`` = :data:`EDIT_SOURCE`, ``source_subject``,
  ``source_store``, ``source_provenance`` (the source's own provenance),
  ``edit`` (``name``, ``parameters``, ``target``, ``regions_edited``) and
  ``software``;
* ``skin_type`` (:func:`change_skin_type`) and ``condition``
  (:func:`transfer_brdf_subject` with a ``condition`` query) become the
  target's when ``t = 1``; for ``t < 1`` they stay the source's (the edit is in
  the provenance).  ``person_id`` stays the source's.

It is written to ``out_store`` (default: the source store) with
:meth:`facestats.io.Store.write_subject`.  The source is never modified: an
edit refuses to write the source's own id into the source's store, even with
``overwrite=True``.  The embedded default store is read-only: pass a writable
directory store (``open_store(PATH, mode="a")``) as ``out_store``.
"""

from __future__ import annotations

import hashlib
import json
import os
import pathlib
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from facestats.core.conventions import (
    CHANNELS,
    REGIONS,
    parse_condition,
    parse_region,
    parse_skin_type,
    skin_type_roman,
)
from facestats.core.validate import check_choice
from facestats.core.version import __version__
from facestats.edit.brdf import transfer_brdf
from facestats.edit.colour import transfer_colour
from facestats.edit.histogram import _check_t
from facestats.edit.plots import _display
from facestats.edit.pyramid import max_levels
from facestats.edit.texture import TextureStatistics, TextureTransfer, _pad_shape, transfer_texture
from facestats.errors import StoreError, ValidationError

__all__ = [
    "EDIT_SOURCE",
    "SubjectEdit",
    "change_skin_type",
    "transfer_brdf_subject",
    "transfer_colour_subject",
    "transfer_texture_subject",
    "subject_texture_statistics",
    "select_subjects",
    "plot_subject_edit",
    "save_edit_images",
]

#: Provenance ``source`` of subjects written by an edit (excluded from target subsets).
EDIT_SOURCE = "facestats.edit"
#: Largest number of pooled albedo values used as a colour target.
MAX_ALBEDO_SAMPLES = 1 << 18
#: model -> (scale parameter, lobe parameter) maps of a subject.
_MODEL_VARS = {"ts": ("ts_rho_s", "ts_m"), "bp": ("bp_rho_s", "bp_exponent")}
_QUERY_KEYS = ("skin_type", "gender", "age", "condition")


@dataclass(frozen=True)
class SubjectEdit:
    """Result of a subject edit: the new subject and what was done.

    Attributes
    ----------
    subject_id : str
        Id of the new subject.
    dataset : xarray.Dataset
        The new subject as written.
    source : xarray.Dataset
        The source subject as read (unchanged).
    edit : dict
        The edit record stored in the provenance: ``name``, ``parameters``,
        ``target``, ``regions_edited``.
    store : str
        Label of the store the subject was written to.
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

    def region_means(self):
        """Means before, after and of the target, per edited map and region, as a :class:`pandas.DataFrame`.

        Columns ``variable``, ``region``, ``name``, ``before``, ``after``,
        ``target``.  BRDF maps: one row per region of the subject.  Albedo: one
        row per channel (``albedo_R``…) over the edited regions (``region`` 0,
        ``name`` "edited").  ``target`` is the mean of the target samples (NaN
        when the edit had no sample target, e.g. a texture transfer).
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
        for var in _brdf_variables(self):
            before = np.asarray(self.source[var].values, np.float64)
            after = np.asarray(self.dataset[var].values, np.float64)
            for r in _present(region):
                sel = region == r
                tgt = self.target_means.get(var, {}).get(r, np.nan)
                rows.append((var, r, REGIONS[r], before[sel].mean(), after[sel].mean(), tgt))
        return pd.DataFrame(rows, columns=["variable", "region", "name", "before", "after", "target"])


# --------------------------------------------------------------------------- helpers


def _check_store(store, name):
    from facestats.io.store import Store

    if not isinstance(store, Store):
        raise ValidationError(
            f"{name} must be a facestats Store (facestats.open_store(...)), got {type(store).__name__}"
        )
    return store


def _writable(out, name="out_store"):
    if out.read_only:
        what = "the embedded default store" if out.label == "default" else f"store {out.label}"
        raise StoreError(
            f"{what} is read-only and an edit writes a new subject: pass {name}=open_store(PATH, mode='a') "
            "(a directory store, created if missing; CLI: --out-store PATH)"
        )
    return out


def _same_store(a, b) -> bool:
    return a is b or os.path.realpath(a.path) == os.path.realpath(b.path)


def _load_source(store, subject):
    """``(dataset, region map)`` of a map subject of ``store``."""
    from facestats.io.schema import subject_kind

    sid = str(subject)
    ds = store.subject(sid)
    if subject_kind(ds) != "maps":
        raise ValidationError(
            f"subject must be a map subject (fitted maps), got {sid!r}, a sample subject imported from a "
            "statistics file: it has no maps to edit"
        )
    return ds, np.asarray(ds["region"].values)


def _parse_regions(regions, present, name="regions"):
    """Region numbers 1-10 from numbers or names, each present in ``present``; None stays None."""
    if regions is None:
        return None
    if isinstance(regions, (str, int, np.integer)):
        regions = [regions]
    out = sorted({parse_region(r) for r in regions})
    if not out:
        raise ValidationError(f"{name} must name at least one region, got {regions!r}")
    missing = [r for r in out if r not in present]
    if missing:
        raise ValidationError(f"{name} must be regions of the subject's region map, got {missing} (present: {present})")
    return out


def _present(region) -> list[int]:
    return [int(r) for r in np.unique(region) if r != 0]


def _face_mask(region, regions):
    """Texels of the face (``regions`` None) or of the listed regions, as a bool map."""
    return region > 0 if regions is None else np.isin(region, regions)


def _label_mask(region, regions):
    """The face as one region (bool map, ``regions`` None), else the listed regions' labels (0 elsewhere)."""
    return region > 0 if regions is None else np.where(np.isin(region, regions), region, 0).astype(np.int64)


def _normalise_query(query) -> dict:
    q = dict(query)
    unknown = sorted(set(q) - set(_QUERY_KEYS))
    if unknown:
        raise ValidationError(f"target query keys must be among {list(_QUERY_KEYS)}, got {unknown}")
    q.setdefault("condition", "normal")
    if q.get("skin_type") is not None:
        q["skin_type"] = parse_skin_type(q["skin_type"])
    if q.get("condition") is not None:
        q["condition"] = parse_condition(q["condition"])
    return q


def select_subjects(store, query, *, exclude=()) -> list[str]:
    """Ids of the population subset matching a query, without edited subjects.

    Parameters
    ----------
    store : facestats.io.Store
    query : dict
        Any of ``skin_type``, ``gender``, ``age``, ``condition``
        (:meth:`facestats.io.Store.query`; skin types I and II are grouped).
        ``condition`` defaults to ``"normal"``; ``None`` means any condition.
    exclude : iterable of str
        Ids to leave out (e.g. the subject being edited).

    Returns
    -------
    list of str
        Matching subjects whose provenance ``source`` is not :data:`EDIT_SOURCE`.
    """
    store = _check_store(store, "store")
    if not isinstance(query, Mapping):
        raise ValidationError(f"query must be a dict of {list(_QUERY_KEYS)}, got {type(query).__name__}")
    q = _normalise_query(query)
    ids = store.query(**q).subject_ids
    entries = store.index_entries()
    skip = {str(s) for s in exclude}
    return [s for s in ids if s not in skip and entries[s]["row"].get("source") != EDIT_SOURCE]


def _statistics_sha(stats: TextureStatistics) -> str:
    h = hashlib.sha256()
    for arr in (stats.edges, stats.counts, stats.basis.mean, stats.basis.axes):
        h.update(np.ascontiguousarray(arr, np.float64).tobytes())
    return h.hexdigest()[:16]


def _resolve_target(store, target, source_id, *, query=True, statistics=False):
    """Classify a target: ``("subjects", ids, descriptor)`` or ``("statistics", stats, descriptor)``.

    Subject ids and (if ``query``) query dicts select subjects of ``store``;
    with ``statistics``, a :class:`TextureStatistics`, a :class:`pathlib.Path`
    or a string naming an existing file (and no subject) give statistics.
    """
    if statistics:
        if isinstance(target, TextureStatistics):
            return "statistics", target, {"statistics": _statistics_sha(target)}
        is_file = isinstance(target, str) and target not in store and pathlib.Path(target).is_file()
        if isinstance(target, pathlib.PurePath) or is_file:
            stats = TextureStatistics.load(target)
            return "statistics", stats, {"statistics": _statistics_sha(stats), "file": str(target)}
    if isinstance(target, str):
        if target not in store:
            also = " nor an existing texture-statistics file" if statistics else ""
            raise StoreError(f"target {target!r} is neither a subject of store {store.label}{also}")
        if target == source_id:
            raise ValidationError(f"target must differ from the edited subject, got {target!r}")
        return "subjects", [target], {"subject": target}
    if query and isinstance(target, Mapping):
        q = _normalise_query(target)
        ids = select_subjects(store, q, exclude=[source_id])
        if not ids:
            raise ValidationError(
                f"target query {q} matches no subject in store {store.label} (the edited subject and edited "
                "subjects excluded)"
            )
        return "subjects", ids, {"query": q, "subjects": ids}
    kinds = ["a subject id (str)"] + (["a query dict of " + str(list(_QUERY_KEYS))] if query else [])
    kinds += ["a TextureStatistics", "a path to saved statistics"] if statistics else []
    raise ValidationError(f"target must be {', '.join(kinds[:-1])} or {kinds[-1]}, got {type(target).__name__}")


def _brdf_targets(store, ids, model):
    """``{parameter: {region: samples}}`` of the subjects ``ids`` for one model (unflagged texels, pooled)."""
    df = store.region_samples(model, subjects=ids)
    rho_name, lobe_name = _MODEL_VARS[model]
    out = {rho_name: {}, lobe_name: {}}
    region = df["region"].to_numpy()
    rho, lobe = df["rho_s"].to_numpy(), df["lobe"].to_numpy()
    for r in np.unique(region):
        sel = region == r
        out[rho_name][int(r)] = rho[sel]
        out[lobe_name][int(r)] = lobe[sel]
    return out


def _pooled_albedo(store, ids, regions, max_samples, seed):
    """Linear-RGB albedo values (n, 3) of the face (or ``regions``) of the subjects ``ids``, pooled."""
    entries = store.index_entries()
    per = max(1, int(max_samples) // len(ids))
    rng = np.random.default_rng(seed)
    parts = []
    for sid in ids:  # loop over subjects; each is vectorised over texels
        ds = store.subject(sid, lazy=True)
        if entries[sid]["row"].get("kind") == "maps":
            px = np.asarray(ds["albedo"].values)[_face_mask(np.asarray(ds["region"].values), regions)]
        elif "albedo_sample" in ds.variables:
            px = np.asarray(ds["albedo_sample"].values).reshape(-1, 3)
            if regions is not None and "albedo_sample_region" in ds.variables:
                px = px[np.isin(np.asarray(ds["albedo_sample_region"].values), regions)]
        else:
            continue
        px = px[np.all(np.isfinite(px), axis=1)].astype(np.float64)
        if px.shape[0] > per:
            px = px[np.sort(rng.choice(px.shape[0], per, replace=False))]
        parts.append(px)
    pixels = np.concatenate(parts) if parts else np.empty((0, 3))
    if pixels.shape[0] < 2:
        raise ValidationError(f"target subjects {ids[:5]} hold fewer than 2 albedo values in the chosen regions")
    return pixels


def _eta(ds) -> float:
    from facestats.core.published import ETA_SKIN
    from facestats.io.schema import provenance

    try:
        return float(provenance(ds).get("fit_settings", {}).get("eta", ETA_SKIN))
    except (TypeError, ValueError, AttributeError):
        return float(ETA_SKIN)


def _follow_translucency(ds, keep: bool) -> list[str]:
    """Update the §5.4 scattering of ``ds`` to its (new) albedo in place; return the variables changed."""
    from facestats.core.published import SIGMA_TR_AVG
    from facestats.io.schema import modulation
    from facestats.model.fitting import scattering_parameters

    changed = []
    if not keep:
        face = np.asarray(ds["region"].values) > 0
        alb = np.clip(np.asarray(ds["albedo"].values, np.float64), 1e-4, 1 - 1e-4)  # as the fit pipeline
        if "sigma_tr" not in ds:
            ds["sigma_tr"] = (("channel",), np.asarray(SIGMA_TR_AVG, np.float64))
            changed.append("sigma_tr")
        sigma_tr = np.asarray(ds["sigma_tr"].values, np.float64)
        avg, sp, sa, _ = scattering_parameters(np.where(face[..., None], alb, 0.0), face, sigma_tr, _eta(ds))
        for name, value in (("albedo_avg", avg), ("sigma_s_prime", sp), ("sigma_a", sa)):
            attrs = ds[name].attrs if name in ds else {}
            ds[name] = (("channel",), np.asarray(value, np.float64), attrs)
            changed.append(name)
    if "modulation" in ds:
        _set(ds, "modulation", modulation(ds).values)
        changed.append("modulation")
    return changed


def _digest(record) -> str:
    text = json.dumps(record, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:8]


def _output(store, out_store):
    """The writable store the edited subject goes to (checked before any work)."""
    return _writable(_check_store(store if out_store is None else out_store, "out_store"))


def _new_id(store, out, sid, new_id, overwrite, tag, record) -> str:
    """The id of the edited subject: ``new_id`` or ``<sid>.<tag>-<digest of the edit record>``."""
    from facestats.io.ids import check_subject_id

    if new_id is None:
        suffix = f".{tag}-{_digest({'source_subject': sid, 'edit': record})}"
        new_id = sid[: 64 - len(suffix)] + suffix
    new_id = check_subject_id(new_id)
    if _same_store(store, out) and new_id == sid:
        raise ValidationError(
            f"new_id must differ from the source subject {sid!r}: an edit never overwrites its source"
        )
    if not overwrite and new_id in out:
        raise StoreError(
            f"subject {new_id!r} already exists in store {out.label}; pass overwrite=True to replace it "
            "or choose another new_id"
        )
    return new_id


def _set(ds, name, values):
    ds[name] = ds[name].copy(data=np.asarray(values).astype(ds[name].dtype, copy=False))


def _finish(
    store, src, ds, out, new_id, overwrite, record, variables, targets, target_means=None, texture=None, attrs=None
):
    """Set id, attributes and provenance of the edited Dataset ``ds``, write it and return the SubjectEdit."""
    from facestats.io.schema import provenance, set_provenance, set_variable_attrs

    ds.attrs["subject_id"] = new_id
    ds.attrs.update(attrs or {})
    ds.attrs["provenance"] = "{}"
    set_provenance(
        ds,
        source=EDIT_SOURCE,
        source_subject=str(src.attrs["subject_id"]),
        source_store=store.label,
        source_provenance=provenance(src),
        edit=record,
        software=f"facestats {__version__}",
    )
    set_variable_attrs(ds)
    out.write_subject(ds, overwrite=overwrite)
    return SubjectEdit(
        subject_id=new_id,
        dataset=ds,
        source=src,
        edit=record,
        store=out.label,
        variables=tuple(variables),
        targets=tuple(targets),
        target_means=target_means or {},
        texture=texture,
    )


def _apply_brdf(ds, region, targets_by_model, t, regions):
    """Transfer the BRDF maps of ``ds`` in place; return (variables changed, regions edited per model, target means)."""
    changed, edited, means = [], {}, {}
    for model, target in targets_by_model.items():
        rho_name, lobe_name = _MODEL_VARS[model]
        have = [r for r in _present(region) if r in target[rho_name] and target[rho_name][r].size]
        wanted = have if regions is None else regions
        lacking = [r for r in wanted if r not in have]
        if lacking:
            raise ValidationError(f"the target has no {model} BRDF samples in region(s) {lacking}")
        edited[model] = wanted
        if not wanted:
            continue
        new = transfer_brdf(
            {rho_name: ds[rho_name].values, lobe_name: ds[lobe_name].values},
            region,
            {rho_name: target[rho_name], lobe_name: target[lobe_name]},
            t=t,
            edit_regions=wanted,
        )
        for name in (rho_name, lobe_name):
            _set(ds, name, new[name])
            changed.append(name)
            means[name] = {r: float(np.mean(target[name][r])) for r in wanted}
    if not any(edited.values()):
        raise ValidationError("the target has no BRDF samples in any region of the subject")
    return changed, edited, means


def _check_model(model):
    check_choice(model, "model", ("ts", "bp", "both"))
    return ["ts", "bp"] if model == "both" else [model]


# --------------------------------------------------------------------------- edits


def transfer_brdf_subject(
    store,
    subject,
    target,
    *,
    t: float = 1.0,
    model: str = "both",
    regions=None,
    out_store=None,
    new_id=None,
    overwrite: bool = False,
) -> SubjectEdit:
    """BRDF transfer per face region from a subject or a population subset (Weyrich et al. 2006 §8).

    Per region and parameter the source texels' values move to the target's
    distribution by histogram interpolation (Matusik et al. 2005,
    :func:`facestats.edit.transfer_brdf`): ``x' = (1 - t) x + t Q_target(u)``
    with ``u`` the texel's rank level in its region and ``Q_target`` the
    quantile function of the target's pooled region samples.  ``t = 1`` gives
    the target's distribution, ``t = 0.5`` is half-way (e.g. normal → lotion).
    Albedo and scattering are not touched; texels outside the edited regions
    are returned bit for bit.

    Parameters
    ----------
    store : facestats.io.Store
        Store holding the subject and the target.
    subject : str
        Id of the (map) subject to edit.
    target : str or dict
        A subject id, or a query such as ``{"condition": "lotion"}`` or
        ``{"skin_type": 5}`` (module docstring).
    t : float
        Interpolation weight in [0, 1].
    model : {"both", "ts", "bp"}
        Torrance-Sparrow (``ts_rho_s``, ``ts_m``), Blinn-Phong (``bp_rho_s``,
        ``bp_exponent``) or both.
    regions : iterable of int or str, optional
        Regions to edit (1-10 or names); default every region with target samples.
    out_store : facestats.io.Store, optional
        Where to write the new subject (default ``store``; must be writable).
    new_id : str, optional
        Id of the new subject (default ``<subject>.<edit>-<digest>``, module docstring).
    overwrite : bool
        Replace an existing subject ``new_id`` of ``out_store`` (never the source itself).

    Returns
    -------
    SubjectEdit
    """
    store = _check_store(store, "store")
    out = _output(store, out_store)
    t = _check_t(t)
    models = _check_model(model)
    src, region = _load_source(store, subject)
    sid = str(subject)
    regions = _parse_regions(regions, _present(region))
    _, ids, descriptor = _resolve_target(store, target, sid)
    record = {"name": "transfer_brdf", "parameters": {"t": t, "model": model, "regions": regions}, "target": descriptor}
    new_id = _new_id(store, out, sid, new_id, overwrite, "brdf", record)
    ds = src.copy(deep=True)
    changed, edited, means = _apply_brdf(ds, region, {m: _brdf_targets(store, ids, m) for m in models}, t, regions)
    record["regions_edited"] = edited
    attrs = {}
    if t == 1.0 and descriptor.get("query", {}).get("condition") is not None:
        attrs["condition"] = descriptor["query"]["condition"]
    return _finish(store, src, ds, out, new_id, overwrite, record, changed, ids, means, attrs=attrs)


def transfer_colour_subject(
    store,
    subject,
    target,
    *,
    t: float = 1.0,
    regions=None,
    feather: float = 0.0,
    keep_translucency: bool = False,
    max_samples: int = MAX_ALBEDO_SAMPLES,
    seed=None,
    out_store=None,
    new_id=None,
    overwrite: bool = False,
) -> SubjectEdit:
    """Skin-colour transfer: albedo histograms in a decorrelated colour space (Weyrich et al. 2006 §8).

    The albedo of the face (or of ``regions``) is matched, channel by channel
    in the target's PCA colour basis (Heeger & Bergen 1995 §3.5), to the
    target's albedo values (:func:`facestats.edit.transfer_colour`); texels
    outside stay bit for bit.  The translucency then follows the new albedo
    (§5.4, module docstring) unless ``keep_translucency``.

    Parameters
    ----------
    store : facestats.io.Store
    subject : str
        Id of the (map) subject to edit.
    target : str, dict, TextureStatistics or path
        A subject id, a query (e.g. ``{"skin_type": 5}``), texture statistics
        (their image histograms and colour basis are used) or a saved
        statistics file.
    t : float
        Interpolation weight in [0, 1].
    regions : iterable of int or str, optional
        Regions to edit and, for subject and query targets, to take the target
        albedo from; default the whole face.
    feather : float
        Blend width in texels inside the edited area's edge (0: hard edge).
    keep_translucency : bool
        Keep ``albedo_avg``, ``sigma_s_prime`` and ``sigma_a`` (module docstring).
    max_samples : int
        Cap on the pooled target albedo values (module docstring).
    seed : int, optional
        Seed of the subsample when the cap is reached.
    out_store : facestats.io.Store, optional
        Where to write the new subject (default ``store``; must be writable).
    new_id : str, optional
        Id of the new subject (default ``<subject>.<edit>-<digest>``, module docstring).
    overwrite : bool
        Replace an existing subject ``new_id`` of ``out_store`` (never the source itself).

    Returns
    -------
    SubjectEdit
    """
    store = _check_store(store, "store")
    out = _output(store, out_store)
    t = _check_t(t)
    src, region = _load_source(store, subject)
    sid = str(subject)
    regions = _parse_regions(regions, _present(region))
    kind, tgt, descriptor = _resolve_target(store, target, sid, statistics=True)
    params = {
        "t": t,
        "regions": regions,
        "feather": feather,
        "keep_translucency": bool(keep_translucency),
        "max_samples": int(max_samples),
        "seed": seed,
    }
    record = {"name": "transfer_colour", "parameters": params, "target": descriptor}
    new_id = _new_id(store, out, sid, new_id, overwrite, "colour", record)
    ids, means = [], {}
    if kind == "subjects":
        ids = tgt
        tgt = _pooled_albedo(store, ids, regions, max_samples, seed)
        descriptor["n_albedo_samples"] = int(tgt.shape[0])
        means["albedo"] = tgt.mean(axis=0)
    ds = src.copy(deep=True)
    _set(
        ds, "albedo", transfer_colour(src["albedo"].values, tgt, mask=_face_mask(region, regions), t=t, feather=feather)
    )
    changed = ["albedo"] + _follow_translucency(ds, keep_translucency)
    record["regions_edited"] = regions or _present(region)
    return _finish(store, src, ds, out, new_id, overwrite, record, changed, ids, means)


def change_skin_type(
    store,
    subject,
    skin_type,
    *,
    t: float = 1.0,
    brdf: bool = True,
    colour: bool = True,
    keep_translucency: bool = False,
    condition: str | None = "normal",
    max_samples: int = MAX_ALBEDO_SAMPLES,
    seed=None,
    out_store=None,
    new_id=None,
    overwrite: bool = False,
) -> SubjectEdit:
    """Change a face's skin type with the statistics of the population subset of that type (§8, e.g. II → V).

    The target is the subset of ``store`` with Fitzpatrick type ``skin_type``
    measured under ``condition`` (types I and II grouped, as in the paper;
    the edited subject and edited subjects excluded).  With ``colour`` the
    face albedo is matched to the subset's pooled albedo in a decorrelated
    colour space (as :func:`transfer_colour_subject`) and the translucency
    follows it through §5.4 unless ``keep_translucency``; with ``brdf`` the
    Torrance-Sparrow and Blinn-Phong maps of every region are matched to the
    subset's pooled region samples (as :func:`transfer_brdf_subject`).  The
    ``skin_type`` attribute becomes ``skin_type`` when ``t = 1``.  The edit
    involves no randomness unless the subset holds more than ``max_samples``
    albedo values.

    Parameters
    ----------
    store : facestats.io.Store
    subject : str
        Id of the (map) subject to edit.
    skin_type : int or str
        Target Fitzpatrick type, 1-6 or I-VI.
    t : float
        Interpolation weight in [0, 1] (colour and BRDF).
    brdf, colour : bool
        Which parts to transfer (at least one).
    keep_translucency : bool
        Keep ``albedo_avg``, ``sigma_s_prime`` and ``sigma_a`` (module docstring).
    condition : str or None
        Condition of the target subset (default ``"normal"``; None: any).
    max_samples : int
        Cap on the pooled target albedo values (module docstring).
    seed : int, optional
        Seed of the subsample when the cap is reached.
    out_store : facestats.io.Store, optional
        Where to write the new subject (default ``store``; must be writable).
    new_id : str, optional
        Id of the new subject (default ``<subject>.<edit>-<digest>``, module docstring).
    overwrite : bool
        Replace an existing subject ``new_id`` of ``out_store`` (never the source itself).

    Returns
    -------
    SubjectEdit
    """
    store = _check_store(store, "store")
    out = _output(store, out_store)
    st = parse_skin_type(skin_type)
    t = _check_t(t)
    if not (brdf or colour):
        raise ValidationError("brdf and colour must not both be False: nothing to change")
    src, region = _load_source(store, subject)
    sid = str(subject)
    _, ids, descriptor = _resolve_target(store, {"skin_type": st, "condition": condition}, sid)
    params = {
        "skin_type": st,
        "t": t,
        "brdf": bool(brdf),
        "colour": bool(colour),
        "keep_translucency": bool(keep_translucency),
        "condition": condition,
        "max_samples": int(max_samples),
        "seed": seed,
    }
    record = {"name": "change_skin_type", "parameters": params, "target": descriptor}
    new_id = _new_id(store, out, sid, new_id, overwrite, f"skin-{skin_type_roman(st)}", record)
    ds = src.copy(deep=True)
    changed, means, edited = [], {}, {}
    if colour:
        pixels = _pooled_albedo(store, ids, None, max_samples, seed)
        descriptor["n_albedo_samples"] = int(pixels.shape[0])
        _set(ds, "albedo", transfer_colour(src["albedo"].values, pixels, mask=region > 0, t=t))
        changed += ["albedo"] + _follow_translucency(ds, keep_translucency)
        means["albedo"] = pixels.mean(axis=0)
        edited["albedo"] = _present(region)
    if brdf:
        c, e, m = _apply_brdf(ds, region, {mod: _brdf_targets(store, ids, mod) for mod in ("ts", "bp")}, t, None)
        changed += c
        means.update(m)
        edited.update(e)
    record["regions_edited"] = edited
    attrs = {"skin_type": st} if t == 1.0 else {}
    return _finish(store, src, ds, out, new_id, overwrite, record, changed, ids, means, attrs=attrs)


def _levels_for(*shapes) -> int:
    """The most pyramid levels (at most 7, §8) that maps of every shape in ``shapes`` support."""
    for levels in range(7, 0, -1):
        if all(levels <= max_levels(_pad_shape(shape, levels)) for shape in shapes):
            return levels
    return 0


def transfer_texture_subject(
    store,
    subject,
    target,
    *,
    regions=None,
    levels: int | None = None,
    orientations: int = 4,
    bins: int = 256,
    iterations: int = 5,
    seed=None,
    noise: float = 0.1,
    feather: float = 2.0,
    keep_translucency: bool = False,
    out_store=None,
    new_id=None,
    overwrite: bool = False,
) -> SubjectEdit:
    """Skin-texture transfer by Heeger-Bergen histogram matching (Weyrich et al. 2006 §8), e.g. freckles.

    The subject's albedo receives the target's texture statistics
    (:func:`facestats.edit.transfer_texture`): the histograms of the albedo
    and of its steerable-pyramid bands in a decorrelated colour space.  With
    ``regions`` the synthesis is restricted to those regions of the subject's
    region map, each region matched on its own (to the same region of a target
    subject, or to the given statistics) and blended over ``feather`` texels
    inside its edge; texels outside the regions (and outside the face) are
    returned bit for bit.  The translucency then follows the new albedo (§5.4)
    unless ``keep_translucency``.

    Parameters
    ----------
    store : facestats.io.Store
    subject : str
        Id of the (map) subject to edit.
    target : str, TextureStatistics or path
        A subject id of ``store`` (its face, or its ``regions``), statistics,
        or a ``.npz`` file written by :meth:`TextureStatistics.save` (e.g. of
        :func:`subject_texture_statistics`).
    regions : iterable of int or str, optional
        Regions to edit (1-10 or names; e.g. forehead, nose, cheeks = 2, 6, 7);
        default the whole face as one region.
    levels : int, optional
        Pyramid levels; default those of target statistics, else the most the
        maps support (at most 7, §8; 3 for 48 × 48 maps).
    orientations, bins : int
        Pyramid orientations and histogram bins for a subject target (§8: 4, 256).
    iterations : int
        Heeger-Bergen iterations.
    seed : int, optional
        Seed of the start noise: the same seed gives the same subject bit for bit.
    noise : float
        Start-noise amplitude relative to each decorrelated channel's standard deviation.
    feather : float
        Blend width in texels inside the mask edge (0: hard edge).
    keep_translucency : bool
        Keep ``albedo_avg``, ``sigma_s_prime`` and ``sigma_a`` (module docstring).
    out_store : facestats.io.Store, optional
        Where to write the new subject (default ``store``; must be writable).
    new_id : str, optional
        Id of the new subject (default ``<subject>.<edit>-<digest>``, module docstring).
    overwrite : bool
        Replace an existing subject ``new_id`` of ``out_store`` (never the source itself).

    Returns
    -------
    SubjectEdit
        ``texture`` holds the convergence report (:class:`TextureTransfer`).
    """
    store = _check_store(store, "store")
    out = _output(store, out_store)
    src, region = _load_source(store, subject)
    sid = str(subject)
    regions = _parse_regions(regions, _present(region))
    kind, tgt, descriptor = _resolve_target(store, target, sid, query=False, statistics=True)
    mask = _label_mask(region, regions)
    if kind == "statistics":
        ids, kwargs = [], {"levels": levels}
    else:
        ids = tgt
        tds, treg = _load_source(store, ids[0])
        lacking = sorted(set(regions or ()) - set(_present(treg)))
        if lacking:
            raise ValidationError(f"target subject {ids[0]!r} has no texel in region(s) {lacking}")
        tmask = _label_mask(treg, regions)
        levels = _levels_for(region.shape, treg.shape) if levels is None else levels
        kwargs = {"target_mask": tmask, "levels": levels, "orientations": orientations, "bins": bins}
        tgt = np.asarray(tds["albedo"].values)
    params = {
        "regions": regions,
        "levels": levels,
        "orientations": orientations,
        "bins": bins,
        "iterations": iterations,
        "seed": seed,
        "noise": noise,
        "feather": feather,
        "keep_translucency": bool(keep_translucency),
    }
    record = {"name": "transfer_texture", "parameters": params, "target": descriptor}
    new_id = _new_id(store, out, sid, new_id, overwrite, "texture", record)
    res = transfer_texture(
        src["albedo"].values, tgt, mask, iterations=iterations, seed=seed, noise=noise, feather=feather, **kwargs
    )
    first = next(iter(res.statistics.values()))
    params.update(levels=first.levels, orientations=first.orientations, bins=first.bins)
    ds = src.copy(deep=True)
    _set(ds, "albedo", res.albedo)
    changed = ["albedo"] + _follow_translucency(ds, keep_translucency)
    record.update(
        regions_edited=regions or _present(region),
        start_distance=float(res.distance[0]),
        final_distance=float(res.distance[-1]),
    )
    return _finish(store, src, ds, out, new_id, overwrite, record, changed, ids, texture=res)


def subject_texture_statistics(
    store, subject, *, regions=None, levels: int | None = None, orientations: int = 4, bins: int = 256
) -> TextureStatistics:
    """The §8 texture statistics of a subject's albedo (its face, or the union of ``regions``).

    Parameters
    ----------
    store : facestats.io.Store
    subject : str
        Id of a map subject.
    regions : iterable of int or str, optional
        Regions to analyse; default the whole face.
    levels : int, optional
        Pyramid levels; default the most the map supports (at most 7; 3 for 48 × 48 maps).
    orientations, bins : int
        §8: 4 orientations, 256 bins.

    Returns
    -------
    TextureStatistics
        Save with :meth:`TextureStatistics.save` and pass the file as a target
        of :func:`transfer_texture_subject`.
    """
    store = _check_store(store, "store")
    ds, region = _load_source(store, subject)
    regions = _parse_regions(regions, _present(region))
    levels = _levels_for(region.shape) if levels is None else levels
    return TextureStatistics.from_image(
        ds["albedo"].values, _face_mask(region, regions), levels=levels, orientations=orientations, bins=bins
    )


# --------------------------------------------------------------------------- figures


def _brdf_variables(edit):
    return [v for v in edit.variables if v in ("ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent")]


def _map_range(before, after, face):
    vals = np.concatenate([before[face], after[face]])
    lo, hi = np.percentile(vals, [1, 99])
    return (float(lo), float(hi)) if hi > lo else (float(lo) - 1e-6, float(hi) + 1e-6)


def plot_subject_edit(edit: SubjectEdit, *, title: str | None = None):
    """Before, after and difference of the albedo and of every edited BRDF map.

    Parameters
    ----------
    edit : SubjectEdit
        Result of one of the subject edits.
    title : str, optional
        Figure title (default: the new id and the edit's name).

    Returns
    -------
    matplotlib.figure.Figure
        One row per map: before, after (albedo sRGB-encoded for display, BRDF
        maps on one colour scale), and after − before (albedo: mean over the
        channels; diverging scale clipped at the 99th percentile of the
        absolute change).  Texels outside the face are blank.
    """
    from matplotlib.figure import Figure

    if not isinstance(edit, SubjectEdit):
        raise ValidationError(f"edit must be a SubjectEdit, got {type(edit).__name__}")
    face = np.asarray(edit.source["region"].values) > 0
    rows = (["albedo"] if "albedo" in edit.variables else []) + _brdf_variables(edit)
    if not rows:
        rows = ["albedo"]
    fig = Figure(figsize=(10.0, 3.0 * len(rows)), layout="constrained")
    # Columns: before, after, their colour bar, difference, its colour bar (same widths in every row).
    grid = fig.add_gridspec(len(rows), 5, width_ratios=[1, 1, 0.05, 1, 0.05])
    for k, var in enumerate(rows):
        before = np.asarray(edit.source[var].values, np.float64)
        after = np.asarray(edit.dataset[var].values, np.float64)
        ax_b, ax_a, cax, ax_d, dax = (fig.add_subplot(grid[k, j]) for j in range(5))
        if var == "albedo":
            ax_b.imshow(_display(before), interpolation="nearest")
            ax_a.imshow(_display(after), interpolation="nearest")
            cax.set_axis_off()
            diff = (after - before).mean(axis=-1)
        else:
            lo, hi = _map_range(before, after, face)
            for ax, img in ((ax_b, before), (ax_a, after)):
                im = ax.imshow(np.where(face, img, np.nan), vmin=lo, vmax=hi, cmap="viridis", interpolation="nearest")
            fig.colorbar(im, cax=cax, label=var)
            diff = after - before
        lim = float(np.percentile(np.abs(diff[face]), 99)) or 1e-6  # robust: a few texels may jump further
        im = ax_d.imshow(np.where(face, diff, np.nan), vmin=-lim, vmax=lim, cmap="RdBu_r", interpolation="nearest")
        fig.colorbar(im, cax=dax, label="after − before" + (" (mean RGB)" if var == "albedo" else ""))
        ax_b.set_title(f"{var}: before")
        ax_a.set_title(f"{var}: after")
        ax_d.set_title("difference")
        for ax in (ax_b, ax_a, ax_d):
            ax.set_axis_off()
    fig.suptitle(title or f"{edit.subject_id} ({edit.edit['name']} of {edit.source.attrs['subject_id']})")
    return fig


def _upscale(img, min_side=256):
    k = max(1, -(-min_side // max(img.shape[:2])))
    return np.repeat(np.repeat(img, k, axis=0), k, axis=1)


def save_edit_images(edit: SubjectEdit, directory=".") -> list[pathlib.Path]:
    """Write before/after PNGs of an edit.

    Files (``<id>`` the new subject id), in ``directory`` (created if missing):
    ``<id>_albedo_before.png`` and ``<id>_albedo_after.png`` (linear albedo
    sRGB-encoded for display), ``<id>_<map>_before.png`` /
    ``<id>_<map>_after.png`` for every edited BRDF map (viridis on one scale
    for both, 1st-99th percentile of the face texels; black outside the face),
    and ``<id>_summary.png`` (:func:`plot_subject_edit`, with colour bars).
    Small maps are enlarged by pixel repetition to at least 256 pixels a side.

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    from matplotlib import colormaps
    from matplotlib.image import imsave

    if not isinstance(edit, SubjectEdit):
        raise ValidationError(f"edit must be a SubjectEdit, got {type(edit).__name__}")
    d = pathlib.Path(directory)
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValidationError(f"directory must be a writable directory, got {str(d)!r} ({exc.strerror})") from None
    face = np.asarray(edit.source["region"].values) > 0
    written = []
    for when, ds in (("before", edit.source), ("after", edit.dataset)):
        path = d / f"{edit.subject_id}_albedo_{when}.png"
        imsave(path, _upscale(_display(np.asarray(ds["albedo"].values))))
        written.append(path)
    cmap = colormaps["viridis"]
    for var in _brdf_variables(edit):
        before = np.asarray(edit.source[var].values, np.float64)
        after = np.asarray(edit.dataset[var].values, np.float64)
        lo, hi = _map_range(before, after, face)
        for when, img in (("before", before), ("after", after)):
            rgb = cmap(np.clip((img - lo) / (hi - lo), 0.0, 1.0))[..., :3]
            rgb[~face] = 0.0
            path = d / f"{edit.subject_id}_{var}_{when}.png"
            imsave(path, _upscale(rgb))
            written.append(path)
    path = d / f"{edit.subject_id}_summary.png"
    plot_subject_edit(edit).savefig(path, dpi=100)
    written.append(path)
    return written
