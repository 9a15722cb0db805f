"""Targets of the store-level edits: which subjects, and their pooled samples (Weyrich et al. 2006 §8).

§8: an artist changes a face's appearance using the statistics of another
subject or of a population subset ("skin type V", "with lotion").  A *target*
is another subject id of the source store, or a *query*: a dict with any of
``skin_type``, ``gender``, ``age``, ``condition``
(:meth:`facestats.io.Store.query`; skin types I and II are grouped as in the
paper).  ``condition`` defaults to ``"normal"`` (the population as the paper
analyses it; pass ``condition=None`` for any condition).  A subset never holds
the source subject itself nor subjects written by an edit (provenance
``source`` = :data:`~facestats.edit.session.EDIT_SOURCE`), so earlier edits
never feed later targets: :func:`select_subjects`.  Colour and texture edits
also take texture statistics or a file of them: :func:`resolve_target`.

* BRDF samples of a target are its *unflagged* texels per region
  (:func:`facestats.analysis.population.region_samples`; filled texels are not
  measurements), pooled over the subset: every texel (or stored sample) is one
  draw (:func:`brdf_samples`).
* Albedo samples of a target are the linear-RGB albedo values of its face
  texels (or of the chosen regions; stored ``albedo_sample`` values for
  imported subjects), pooled over the subset (:func:`pooled_albedo`).  They are
  read from the subjects' maps, not from the index histograms: the index keeps
  per-channel histograms on [0, 1], whereas the decorrelated transfer needs
  joint RGB values (for the PCA basis of Heeger & Bergen 1995 §3.5).  At most
  ``max_samples`` values are kept (an equal random share per subject, drawn
  with ``seed``; the default store's subsets stay well below the cap, so the
  draw is then not random at all).

:func:`target_from_options` turns the target options of ``facestats edit``
(``--target``, ``--stats``, ``--skin-type`` …) into one of these targets.
"""

from __future__ import annotations

import hashlib
import pathlib
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from facestats.analysis.population import region_samples
from facestats.core.conventions import ROMAN, parse_condition, parse_skin_type
from facestats.core.validate import check_seed
from facestats.edit.masks import face_mask
from facestats.edit.session import EDIT_SOURCE, check_store
from facestats.edit.statistics import TextureStatistics
from facestats.errors import StoreError, ValidationError
from facestats.io.query import ANY_CONDITION

__all__ = [
    "MAX_ALBEDO_SAMPLES",
    "MODEL_VARIABLES",
    "QUERY_KEYS",
    "Target",
    "select_subjects",
    "resolve_target",
    "brdf_samples",
    "pooled_albedo",
    "target_from_options",
]

#: Largest number of pooled albedo values used as a colour target.
MAX_ALBEDO_SAMPLES = 1 << 18
#: model -> (scale parameter, lobe parameter) maps of a subject.
MODEL_VARIABLES = {"ts": ("ts_rho_s", "ts_m"), "bp": ("bp_rho_s", "bp_exponent")}
#: Keys of a target query.
QUERY_KEYS = ("skin_type", "gender", "age", "condition")


@dataclass(frozen=True)
class Target:
    """A resolved edit target.

    Attributes
    ----------
    subjects : list of str
        The target subjects (empty for statistics).
    statistics : TextureStatistics or None
        The target statistics (None for subjects).
    record : dict
        What the provenance stores as ``edit.target``: ``subject``, or
        ``query`` and ``subjects``, or ``statistics`` (a digest) and ``file``.
        An edit may add to it (e.g. ``n_albedo_samples``).
    """

    subjects: list = field(default_factory=list)
    statistics: TextureStatistics | None = None
    record: dict = field(default_factory=dict)


def _normalise_query(query) -> dict:
    q = dict(query)
    unknown = sorted(set(q) - set(QUERY_KEYS))
    if unknown:
        raise ValidationError(f"target query keys must be among {list(QUERY_KEYS)}, got {unknown}")
    q.setdefault("condition", "normal")
    if q.get("skin_type") is not None:
        q["skin_type"] = parse_skin_type(q["skin_type"])
    if isinstance(q.get("condition"), str) and q["condition"].strip().lower() == ANY_CONDITION:
        q["condition"] = None  # every condition, as facestats query --condition any
    if q.get("condition") is not None:
        q["condition"] = parse_condition(q["condition"])
    return q


def _describe_query(q: dict) -> str:
    """A normalised target query as a user would type it: ``skin type V, condition normal``."""
    parts = [
        f"{key.replace('_', ' ')} {ROMAN[v] if key == 'skin_type' else v}" for key, v in q.items() if v is not None
    ]
    return ", ".join(parts) or "any subject"


def select_subjects(store, query, *, exclude=()) -> list[str]:
    """Ids of the population subset matching a query, without edited subjects.

    Parameters
    ----------
    store : facestats.io.Store
    query : dict
        Any of ``skin_type``, ``gender``, ``age``, ``condition``
        (:meth:`facestats.io.Store.query`; skin types I and II are grouped).
        ``condition`` defaults to ``"normal"``; ``None`` or ``"any"`` means any condition.
    exclude : iterable of str
        Ids to leave out (e.g. the subject being edited).

    Returns
    -------
    list of str
        Matching subjects whose provenance ``source`` is not :data:`EDIT_SOURCE`.
    """
    store = check_store(store, "store")
    if not isinstance(query, Mapping):
        raise ValidationError(f"query must be a dict of {list(QUERY_KEYS)}, got {type(query).__name__}")
    q = _normalise_query(query)
    ids = store.query(**q).subject_ids
    entries = store.index_entries()
    skip = {str(s) for s in exclude}
    return [s for s in ids if s not in skip and entries[s]["row"].get("source") != EDIT_SOURCE]


def _statistics_digest(stats: TextureStatistics) -> str:
    """First 16 hex digits of the SHA-256 of the statistics' edges, counts and colour basis."""
    h = hashlib.sha256()
    for arr in (stats.edges, stats.counts, stats.basis.mean, stats.basis.axes):
        h.update(np.ascontiguousarray(arr, np.float64).tobytes())
    return h.hexdigest()[:16]


def _statistics_target(store, target) -> Target | None:
    """The statistics a target names (object, path, or a str naming a file and no subject), else None."""
    if isinstance(target, TextureStatistics):
        return Target(statistics=target, record={"statistics": _statistics_digest(target)})
    is_file = isinstance(target, str) and target not in store and pathlib.Path(target).is_file()
    if isinstance(target, pathlib.PurePath) or is_file:
        stats = TextureStatistics.load(target)
        return Target(statistics=stats, record={"statistics": _statistics_digest(stats), "file": str(target)})
    return None


def resolve_target(store, target, source_id, *, query=True, statistics=False) -> Target:
    """Classify and resolve the target of an edit of subject ``source_id`` of ``store``.

    Parameters
    ----------
    store : facestats.io.Store
    target : str, dict, TextureStatistics or path
        A subject id of ``store``; with ``query``, a query dict
        (:func:`select_subjects`, the source excluded); with ``statistics``, a
        :class:`TextureStatistics`, a :class:`pathlib.Path` or a string naming
        an existing file (and no subject).
    source_id : str
        The edited subject (never its own target).
    query, statistics : bool
        Which kinds of target the edit accepts besides a subject id.

    Returns
    -------
    Target
    """
    if statistics:
        found = _statistics_target(store, target)
        if found is not None:
            return found
    if isinstance(target, str):
        if target not in store:
            if statistics:
                raise StoreError(
                    f"target {target!r} is neither a subject of store {store.label} nor an existing texture-statistics "
                    "file"
                )
            raise StoreError(f"target {target!r} is not a subject of store {store.label}")
        if target == source_id:
            raise ValidationError(f"target must differ from the edited subject, got {target!r}")
        return Target(subjects=[target], record={"subject": target})
    if query and isinstance(target, Mapping):
        q = _normalise_query(target)
        ids = select_subjects(store, q, exclude=[source_id])
        if not ids:
            raise ValidationError(
                f"target query ({_describe_query(q)}) matches no subject in store {store.label} (the edited subject "
                "and edited "
                "subjects excluded)"
            )
        return Target(subjects=ids, record={"query": q, "subjects": ids})
    kinds = ["a subject id (str)"] + (["a query dict of " + str(list(QUERY_KEYS))] if query else [])
    kinds += ["a TextureStatistics", "a path to saved statistics"] if statistics else []
    raise ValidationError(f"target must be {', '.join(kinds[:-1])} or {kinds[-1]}, got {type(target).__name__}")


def brdf_samples(store, ids, model) -> dict:
    """BRDF samples of target subjects for one model: unflagged texels per region, pooled.

    Parameters
    ----------
    store : facestats.io.Store
    ids : list of str
        Target subjects.
    model : {"ts", "bp"}
        Torrance-Sparrow or Blinn-Phong.

    Returns
    -------
    dict
        ``{map name: {region: samples}}`` for the model's two maps
        (:data:`MODEL_VARIABLES`).
    """
    df = region_samples(store, model, subjects=ids)
    rho_name, lobe_name = MODEL_VARIABLES[model]
    out = {rho_name: {}, lobe_name: {}}
    region = df["region"].to_numpy()
    rho, lobe = df["rho_s"].to_numpy(), df["lobe"].to_numpy()
    for r in np.unique(region):
        sel = region == r
        out[rho_name][int(r)] = rho[sel]
        out[lobe_name][int(r)] = lobe[sel]
    return out


def pooled_albedo(store, ids, regions, max_samples, seed):
    """Linear-RGB albedo values of the face (or ``regions``) of target subjects, pooled.

    Parameters
    ----------
    store : facestats.io.Store
    ids : list of str
        Target subjects (map subjects, or sample subjects with ``albedo_sample``).
    regions : list of int or None
        Regions to take the values from; None: the face.
    max_samples : int
        Cap: each subject contributes at most ``max_samples // len(ids)``
        values (at least 1), a random subset drawn with ``seed`` beyond that.
    seed : int or None

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        Finite values, float64.
    """
    entries = store.index_entries()
    per = max(1, int(max_samples) // len(ids))
    rng = np.random.default_rng(check_seed(seed))
    parts = []
    for sid in ids:  # loop over subjects; each is vectorised over texels
        ds = store.subject(sid, lazy=True)
        if entries[sid]["row"].get("kind") == "maps":
            px = np.asarray(ds["albedo"].values)[face_mask(np.asarray(ds["region"].values), regions)]
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


def target_from_options(*, target=None, stats=None, query=None, stats_allowed=False):
    """The target given by the options of ``facestats edit``: exactly one of a subject, statistics or a subset.

    Parameters
    ----------
    target : str, optional
        ``--target``: a subject id.
    stats : str, optional
        ``--stats``: a statistics file (only where ``stats_allowed``).
    query : dict, optional
        ``--skin-type``, ``--condition``, ``--gender``, ``--age``: the options
        given (falsy values are ignored).
    stats_allowed : bool
        Whether the action takes ``--stats`` (named in the error message).

    Returns
    -------
    str, pathlib.Path or dict
        A target for :func:`resolve_target`; a query's ``condition`` defaults
        to ``"normal"``.

    Raises
    ------
    ValidationError
        Unless exactly one of the three is given (the message names the options).
    """
    query = {k: v for k, v in (query or {}).items() if v}
    given = [name for name, v in (("--target", target), ("--stats", stats)) if v]
    if query:
        given.append("--skin-type/--condition/--gender/--age")
    if len(given) != 1:
        opts = (
            "--target ID" + (", --stats FILE" if stats_allowed else "") + " or a subset (--skin-type, --condition, ...)"
        )
        raise ValidationError(f"give exactly one target: {opts}, got {given or 'none'}")
    if target:
        return target
    if stats:
        return pathlib.Path(stats)
    if "condition" not in query:
        query["condition"] = "normal"
    return query
