"""Committing a new revision of the index, under the store lock: the one way any change becomes visible.

Every change of a directory store — a write, a batch, a delete, a repair, a
rebuilt index — ends in :func:`commit_index`, called while the caller holds the
store lock, in this order:

1. the group metadata (``zarr.json``) of every subject folder the new index
   names is created if missing (inside the store only);
2. the revision is the old one + 1 (a rebuilt index continues after the
   highest revision any record mentions), ``updated`` and the writer version
   are set, and ``index.json`` is replaced atomically — the commit point;
3. the records (:mod:`facestats.io.records`) of the generations the new
   index names for the first time become ``committed`` at that revision, then
   those of the generations it no longer names become ``retired``;
4. the root group's ``facestats_version`` is brought up to date.

A failure before step 2 completes (e.g. a full disk, or the folder of a
subject the index names gone missing: the message names the subject and the
repair) raises :class:`~facestats.errors.StoreError` and leaves the store
exactly as it was;
failures in steps 3-4 are ignored (``facestats validate --repair`` heals a
record the index contradicts).
"""

from __future__ import annotations

import os

from facestats.core.version import __version__
from facestats.errors import StoreError
from facestats.io.index import utc_now, write_index_file
from facestats.io.layout import (
    ROOT_META,
    SUBJECTS,
    confined,
    group_meta,
    is_generation,
    is_plain_dir,
    write_json_atomic,
)
from facestats.io.records import mark_record

__all__ = ["generations_of", "commit_index"]


def generations_of(index: dict | None) -> dict:
    """``{subject id: generation}`` named by an index document (empty for None).

    Parameters
    ----------
    index : dict or None
        An index document (:mod:`facestats.io.index`), or None (no index).

    Returns
    -------
    dict of str to str
        The generation each subject's entry names.
    """
    return {} if index is None else {sid: e["generation"] for sid, e in index["subjects"].items()}


def commit_index(root, index: dict, before: dict, root_attrs: dict, *, label: str) -> dict:
    """Write ``index`` as the next revision of the store at ``root`` (module docstring); the caller holds the lock.

    Parameters
    ----------
    root : str
        The store directory.
    index : dict
        The new index document (its ``revision`` is the previous one: it is increased here).
    before : dict
        ``{sid: generation}`` of the index being replaced (:func:`generations_of`).
    root_attrs : dict
        The root group's attributes as the caller knows them.
    label : str
        The store's name in messages.

    Returns
    -------
    dict
        The root attributes after the commit.

    Raises
    ------
    StoreError
        The index could not be written (nothing was committed).
    """
    for sid in index["subjects"]:  # a subject the index names whose folder is gone: name it, and the way out
        folder = os.path.join(root, SUBJECTS, sid)
        if not os.path.lexists(os.path.join(folder, ROOT_META)) and not is_plain_dir(folder):
            raise StoreError(
                f"could not commit to store {label}: the folder of subject {sid!r} ({SUBJECTS}/{sid}) is missing "
                f"(or is not a folder), so the index would name data that are not there; nothing was committed, "
                f"the store is as it was: run `facestats validate --repair --store {root}` (it recovers or drops "
                f"{sid!r}), then try again"
            )
    try:
        for sid in index["subjects"]:
            node = os.path.join(root, SUBJECTS, sid, ROOT_META)
            if not os.path.lexists(node):
                write_json_atomic(confined(root, node), group_meta())
        index["revision"] = int(index.get("revision", 0)) + 1
        index["updated"] = utc_now()
        index["facestats_version"] = __version__
        write_index_file(root, index)
    except OSError as exc:
        raise StoreError(
            f"could not commit to store {label}: {exc.strerror or exc}"
            + (f" ({exc.filename})" if getattr(exc, "filename", None) else "")
            + "; nothing was committed, the store is as it was"
        ) from None
    after = generations_of(index)
    revision = index["revision"]
    _mark(root, [(s, g) for s, g in after.items() if before.get(s) != g], "committed", revision)
    _mark(root, [(s, g) for s, g in before.items() if after.get(s) != g], "retired", revision)
    if root_attrs.get("facestats_version") != __version__:
        attrs = dict(root_attrs, facestats_version=__version__)
        try:
            write_json_atomic(os.path.join(root, ROOT_META), group_meta(attrs))
            return attrs
        except OSError:
            pass
    return root_attrs


def _mark(root, pairs, state: str, revision: int) -> None:
    """Set the records of ``(sid, generation)`` pairs to ``state``; failures are left to repair."""
    for sid, gen in pairs:
        if not is_generation(gen) or not os.path.isdir(os.path.join(root, SUBJECTS, sid, gen)):
            continue  # gone (e.g. moved to the quarantine): no record to keep
        try:
            mark_record(root, sid, gen, state, revision)
        except (OSError, ValueError, StoreError):
            pass
