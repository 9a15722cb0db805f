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
  (:func:`facestats.edit.transfer_texture`), e.g. of freckled skin, optionally
  within face regions;
* :func:`change_skin_type`: colour and BRDF transfer towards the population
  subset of a Fitzpatrick skin type, e.g. II → V;
* :func:`subject_texture_statistics`: the §8 texture statistics of a subject,
  to save and reuse as a target.

Each edit is the same few steps around its own computation:

* the **target** (another subject, a population subset or texture statistics)
  and its pooled samples: :mod:`facestats.edit.targets`;
* the **session** (stores, source, new id, provenance, writing the new
  subject, which a :class:`SubjectEdit` describes): :mod:`facestats.edit.session`;
* the **translucency** (§5.4) follows the new albedo after a colour, texture or
  skin-type edit unless ``keep_translucency``: :mod:`facestats.edit.translucency`.

Each writes the new subject before it returns; with ``commit=False`` it writes
nothing and returns a :class:`~facestats.edit.session.PendingEdit` whose
``commit()`` writes it, so that a caller can first do what must succeed
before the store changes (``facestats edit`` saves its images first).

The new subject is a copy of the source with the edited variables replaced.
``skin_type`` (:func:`change_skin_type`) and ``condition``
(:func:`transfer_brdf_subject` with a ``condition`` query) become the target's
when ``t = 1``; for ``t < 1`` they stay the source's (the edit is in the
provenance).  ``person_id`` stays the source's.  The source is never modified,
and the embedded default store is read-only: pass a writable directory store
(``open_store(PATH, mode="a")``) as ``out_store``.
"""

from __future__ import annotations

import numpy as np

from facestats.core.conventions import parse_skin_type, skin_type_roman
from facestats.core.validate import check_choice
from facestats.edit.brdf import transfer_brdf
from facestats.edit.colour import transfer_colour
from facestats.edit.grids import supported_levels
from facestats.edit.histogram import check_t
from facestats.edit.masks import face_mask, parse_regions, present_regions, region_labels
from facestats.edit.result import SubjectEdit
from facestats.edit.session import EDIT_SOURCE, EditSession, PendingEdit, check_store, read_map_subject
from facestats.edit.statistics import TextureStatistics
from facestats.edit.targets import (
    MAX_ALBEDO_SAMPLES,
    MODEL_VARIABLES,
    brdf_samples,
    pooled_albedo,
    resolve_target,
    select_subjects,
)
from facestats.edit.texture import transfer_texture
from facestats.edit.translucency import follow_translucency
from facestats.errors import ValidationError

__all__ = [
    "EDIT_SOURCE",
    "PendingEdit",
    "SubjectEdit",
    "change_skin_type",
    "transfer_brdf_subject",
    "transfer_colour_subject",
    "transfer_texture_subject",
    "subject_texture_statistics",
    "select_subjects",
]


def _check_model(model):
    check_choice(model, "model", ("ts", "bp", "both"))
    return ["ts", "bp"] if model == "both" else [model]


def _apply_brdf(session, samples_by_model, t, regions):
    """Transfer the BRDF maps of the session's subject; return (variables changed, regions edited per model, means)."""
    changed, edited, means = [], {}, {}
    for model, target in samples_by_model.items():
        rho_name, lobe_name = MODEL_VARIABLES[model]
        have = [r for r in session.present if r in target[rho_name] and target[rho_name][r].size]
        wanted = have if regions is None else regions
        lacking = [r for r in wanted if r not in have]
        if lacking:
            raise ValidationError(f"the target has no {model} BRDF samples in region(s) {lacking}")
        edited[model] = wanted
        if not wanted:
            continue
        new = transfer_brdf(
            {rho_name: session.dataset[rho_name].values, lobe_name: session.dataset[lobe_name].values},
            session.region,
            {rho_name: target[rho_name], lobe_name: target[lobe_name]},
            t=t,
            edit_regions=wanted,
        )
        for name in (rho_name, lobe_name):
            session.set(name, new[name])
            changed.append(name)
            means[name] = {r: float(np.mean(target[name][r])) for r in wanted}
    if not any(edited.values()):
        raise ValidationError("the target has no BRDF samples in any region of the subject")
    return changed, edited, means


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
    commit: bool = True,
) -> SubjectEdit | PendingEdit:
    """BRDF transfer per face region from a subject or a population subset (Weyrich et al. 2006 §8).

    Per region and parameter the source texels' values move to the target's
    distribution by histogram interpolation (Matusik et al. 2005,
    :func:`facestats.edit.transfer_brdf`): ``x' = (1 - t) x + t Q_target(u)``
    with ``u`` the texel's rank level in its region and ``Q_target`` the
    quantile function of the target's pooled region samples
    (:func:`facestats.edit.targets.brdf_samples`).  ``t = 1`` gives the
    target's distribution, ``t = 0.5`` is half-way (e.g. normal → lotion).
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
        ``{"skin_type": 5}`` (:mod:`facestats.edit.targets`).
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
        Id of the new subject (default ``<subject>.<edit>-<digest>``, :mod:`facestats.edit.session`).
    overwrite : bool
        Replace an existing subject ``new_id`` of ``out_store`` (never the source itself).
    commit : bool
        Write the new subject (default); False: write nothing and return a :class:`PendingEdit`, whose
        ``commit()`` writes it (:mod:`facestats.edit.session`).

    Returns
    -------
    SubjectEdit or PendingEdit
        The result, written; with ``commit=False`` the result to write.
    """
    session = EditSession(store, out_store)
    t = check_t(t)
    models = _check_model(model)
    session.open(subject)
    regions = session.regions(regions)
    target = resolve_target(session.store, target, session.source_id)
    record = {
        "name": "transfer_brdf",
        "parameters": {"t": t, "model": model, "regions": regions},
        "target": target.record,
    }
    session.assign_id("brdf", record, new_id=new_id, overwrite=overwrite)
    samples = {m: brdf_samples(session.store, target.subjects, m) for m in models}
    changed, edited, means = _apply_brdf(session, samples, t, regions)
    record["regions_edited"] = edited
    attrs = {}
    if t == 1.0 and target.record.get("query", {}).get("condition") is not None:
        attrs["condition"] = target.record["query"]["condition"]
    return session.write(
        record, variables=changed, targets=target.subjects, target_means=means, attrs=attrs, commit=commit
    )


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
    commit: bool = True,
) -> SubjectEdit | PendingEdit:
    """Skin-colour transfer: albedo histograms in a decorrelated colour space (Weyrich et al. 2006 §8).

    The albedo of the face (or of ``regions``) is matched, channel by channel
    in the target's PCA colour basis (Heeger & Bergen 1995 §3.5), to the
    target's albedo values (:func:`facestats.edit.transfer_colour`); texels
    outside stay bit for bit.  The translucency then follows the new albedo
    (§5.4, :mod:`facestats.edit.translucency`) unless ``keep_translucency``.

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
        Keep ``albedo_avg``, ``sigma_s_prime`` and ``sigma_a`` (:mod:`facestats.edit.translucency`).
    max_samples : int
        Cap on the pooled target albedo values (:func:`facestats.edit.targets.pooled_albedo`).
    seed : int, optional
        Seed of the subsample when the cap is reached.
    out_store : facestats.io.Store, optional
        Where to write the new subject (default ``store``; must be writable).
    new_id : str, optional
        Id of the new subject (default ``<subject>.<edit>-<digest>``, :mod:`facestats.edit.session`).
    overwrite : bool
        Replace an existing subject ``new_id`` of ``out_store`` (never the source itself).
    commit : bool
        Write the new subject (default); False: write nothing and return a :class:`PendingEdit`, whose
        ``commit()`` writes it (:mod:`facestats.edit.session`).

    Returns
    -------
    SubjectEdit or PendingEdit
        The result, written; with ``commit=False`` the result to write.
    """
    session = EditSession(store, out_store)
    t = check_t(t)
    session.open(subject)
    regions = session.regions(regions)
    target = resolve_target(session.store, target, session.source_id, statistics=True)
    params = {
        "t": t,
        "regions": regions,
        "feather": feather,
        "keep_translucency": bool(keep_translucency),
        "max_samples": int(max_samples),
        "seed": seed,
    }
    record = {"name": "transfer_colour", "parameters": params, "target": target.record}
    session.assign_id("colour", record, new_id=new_id, overwrite=overwrite)
    colour_target, means = target.statistics, {}
    if colour_target is None:
        colour_target = pooled_albedo(session.store, target.subjects, regions, max_samples, seed)
        target.record["n_albedo_samples"] = int(colour_target.shape[0])
        means["albedo"] = colour_target.mean(axis=0)
    mask = face_mask(session.region, regions)
    session.set(
        "albedo", transfer_colour(session.source["albedo"].values, colour_target, mask=mask, t=t, feather=feather)
    )
    changed = ["albedo"] + follow_translucency(session.dataset, keep_translucency)
    record["regions_edited"] = regions or list(session.present)
    return session.write(record, variables=changed, targets=target.subjects, target_means=means, commit=commit)


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
    commit: bool = True,
) -> SubjectEdit | PendingEdit:
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
        Keep ``albedo_avg``, ``sigma_s_prime`` and ``sigma_a`` (:mod:`facestats.edit.translucency`).
    condition : str or None
        Condition of the target subset (default ``"normal"``; None: any).
    max_samples : int
        Cap on the pooled target albedo values (:func:`facestats.edit.targets.pooled_albedo`).
    seed : int, optional
        Seed of the subsample when the cap is reached.
    out_store : facestats.io.Store, optional
        Where to write the new subject (default ``store``; must be writable).
    new_id : str, optional
        Id of the new subject (default ``<subject>.<edit>-<digest>``, :mod:`facestats.edit.session`).
    overwrite : bool
        Replace an existing subject ``new_id`` of ``out_store`` (never the source itself).
    commit : bool
        Write the new subject (default); False: write nothing and return a :class:`PendingEdit`, whose
        ``commit()`` writes it (:mod:`facestats.edit.session`).

    Returns
    -------
    SubjectEdit or PendingEdit
        The result, written; with ``commit=False`` the result to write.
    """
    session = EditSession(store, out_store)
    st = parse_skin_type(skin_type)
    t = check_t(t)
    if not (brdf or colour):
        raise ValidationError("brdf and colour must not both be False: nothing to change")
    session.open(subject)
    target = resolve_target(session.store, {"skin_type": st, "condition": condition}, session.source_id)
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
    record = {"name": "change_skin_type", "parameters": params, "target": target.record}
    session.assign_id(f"skin-{skin_type_roman(st)}", record, new_id=new_id, overwrite=overwrite)
    changed, means, edited = [], {}, {}
    if colour:
        pixels = pooled_albedo(session.store, target.subjects, None, max_samples, seed)
        target.record["n_albedo_samples"] = int(pixels.shape[0])
        session.set("albedo", transfer_colour(session.source["albedo"].values, pixels, mask=session.region > 0, t=t))
        changed += ["albedo"] + follow_translucency(session.dataset, keep_translucency)
        means["albedo"] = pixels.mean(axis=0)
        edited["albedo"] = list(session.present)
    if brdf:
        samples = {mod: brdf_samples(session.store, target.subjects, mod) for mod in ("ts", "bp")}
        c, e, m = _apply_brdf(session, samples, t, None)
        changed += c
        means.update(m)
        edited.update(e)
    record["regions_edited"] = edited
    attrs = {"skin_type": st} if t == 1.0 else {}
    return session.write(
        record, variables=changed, targets=target.subjects, target_means=means, attrs=attrs, commit=commit
    )


def _subject_texture_target(store, target_id, region, regions, levels, orientations, bins):
    """(target albedo, :func:`transfer_texture` keywords) of a target subject, region by region."""
    tds, treg = read_map_subject(store, target_id)
    lacking = sorted(set(regions or ()) - set(present_regions(treg)))
    if lacking:
        raise ValidationError(f"target subject {target_id!r} has no texel in region(s) {lacking}")
    levels = supported_levels(region.shape, treg.shape) if levels is None else levels
    kwargs = {"target_mask": region_labels(treg, regions), "levels": levels, "orientations": orientations, "bins": bins}
    return np.asarray(tds["albedo"].values), kwargs


def transfer_texture_subject(
    store,
    subject,
    target,
    *,
    regions=None,
    levels: int | None = None,
    orientations: int | None = None,
    bins: int | None = None,
    iterations: int = 5,
    seed=None,
    noise: float = 0.1,
    feather: float = 2.0,
    keep_translucency: bool = False,
    out_store=None,
    new_id=None,
    overwrite: bool = False,
    commit: bool = True,
) -> SubjectEdit | PendingEdit:
    """Skin-texture transfer by Heeger-Bergen histogram matching (Weyrich et al. 2006 §8), e.g. of freckled skin.

    The subject's albedo receives the target's texture statistics
    (:func:`facestats.edit.transfer_texture`): the histograms of the albedo
    and of its steerable-pyramid bands in a decorrelated colour space.  Each
    band is matched on its own, so the statistics carry over, not the shapes
    of sparse features: the texture sample's isolated freckles come out as a
    faint mottling, not as spots (README, *What the transfer does not do*).  With
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
    orientations, bins : int, optional
        Pyramid orientations and histogram bins for a subject target (default 4 and 256, §8).  Target
        statistics fix both: a value other than theirs is a :class:`ValidationError`.
    iterations : int
        Heeger-Bergen iterations.
    seed : int, optional
        Seed of the start noise: the same seed gives the same subject bit for bit.
    noise : float
        Start-noise amplitude relative to each decorrelated channel's standard deviation.
    feather : float
        Blend width in texels inside the mask edge (0: hard edge).
    keep_translucency : bool
        Keep ``albedo_avg``, ``sigma_s_prime`` and ``sigma_a`` (:mod:`facestats.edit.translucency`).
    out_store : facestats.io.Store, optional
        Where to write the new subject (default ``store``; must be writable).
    new_id : str, optional
        Id of the new subject (default ``<subject>.<edit>-<digest>``, :mod:`facestats.edit.session`).
    overwrite : bool
        Replace an existing subject ``new_id`` of ``out_store`` (never the source itself).
    commit : bool
        Write the new subject (default); False: write nothing and return a :class:`PendingEdit`, whose
        ``commit()`` writes it (:mod:`facestats.edit.session`).

    Returns
    -------
    SubjectEdit or PendingEdit
        The result, written; with ``commit=False`` the result to write.  ``texture`` holds the convergence
        report (:class:`TextureTransfer`).
    """
    session = EditSession(store, out_store).open(subject)
    regions = session.regions(regions)
    target = resolve_target(session.store, target, session.source_id, query=False, statistics=True)
    if target.statistics is not None:  # they fix the pyramid and the histograms: another value would be ignored
        stats = target.statistics
        for name, value, fixed in (("orientations", orientations, stats.orientations), ("bins", bins, stats.bins)):
            if value is not None and value != fixed:
                raise ValidationError(
                    f"{name} must be the target statistics' {fixed} (they fix the pyramid and the histograms), "
                    f"got {value}"
                )
    orientations = 4 if orientations is None else orientations  # §8's; recorded as given before 2026-12-05
    bins = 256 if bins is None else bins
    mask = region_labels(session.region, regions)
    if target.statistics is not None:
        texture_target, kwargs = target.statistics, {"levels": levels}
    else:
        texture_target, kwargs = _subject_texture_target(
            session.store, target.subjects[0], session.region, regions, levels, orientations, bins
        )
    params = {
        "regions": regions,
        "levels": kwargs["levels"],
        "orientations": orientations,
        "bins": bins,
        "iterations": iterations,
        "seed": seed,
        "noise": noise,
        "feather": feather,
        "keep_translucency": bool(keep_translucency),
    }
    record = {"name": "transfer_texture", "parameters": params, "target": target.record}
    session.assign_id("texture", record, new_id=new_id, overwrite=overwrite)
    res = transfer_texture(
        session.source["albedo"].values,
        texture_target,
        mask,
        iterations=iterations,
        seed=seed,
        noise=noise,
        feather=feather,
        **kwargs,
    )
    first = next(iter(res.statistics.values()))
    params.update(levels=first.levels, orientations=first.orientations, bins=first.bins)
    session.set("albedo", res.albedo)
    changed = ["albedo"] + follow_translucency(session.dataset, keep_translucency)
    record.update(
        regions_edited=regions or list(session.present),
        start_distance=float(res.distance[0]),
        final_distance=float(res.distance[-1]),
    )
    return session.write(record, variables=changed, targets=target.subjects, texture=res, commit=commit)


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
    store = check_store(store, "store")
    ds, region = read_map_subject(store, subject)
    regions = parse_regions(regions, present_regions(region))
    levels = supported_levels(region.shape) if levels is None else levels
    return TextureStatistics.from_image(
        ds["albedo"].values, face_mask(region, regions), levels=levels, orientations=orientations, bins=bins
    )
