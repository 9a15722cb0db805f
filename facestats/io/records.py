"""Generation records: the mark that a generation is facestats' own, and whether (and when) it was committed.

For every generation directory ``subjects/<id>/<generation>/`` its writer
keeps a small JSON record ``.records/<id>~<generation>.json``::

    {"facestats_generation": 1, "subject": "S001", "generation": "g...",
     "state": "writing" | "committed" | "retired",
     "created": "<UTC>", "committed_revision": 17, "retired_revision": 18}

* ``writing``: written by the writer *before* the generation directory exists
  (so even a writer killed in its first instant leaves an owner mark);
* ``committed``: set under the store lock right after the index revision
  ``committed_revision`` named the generation;
* ``retired``: set under the store lock right after the index revision
  ``retired_revision`` stopped naming it (the subject was replaced or deleted).

The index (:mod:`facestats.io.index`) remains the one commit point: readers
never look at records.  Records serve maintenance only: garbage collection
removes a generation only if its record proves it is the store's own and was
never committed or was retired; repair recovers a subject only from a
generation whose record says it was committed, so a crashed write or a deleted
subject is never revived.  The order of the updates (index first, then
``committed``, then ``retired``) means a crash between them can only leave a
committed generation marked ``writing`` (healed by ``facestats validate
--repair``, which sees the index name it) or a replaced generation not yet
marked ``retired`` (its subject is in the index with a newer generation, so it
is still superseded).  Record updates are atomic (rename) but not ``fsync``-ed:
after a power loss a record may lag the index, never lead it.
"""

from __future__ import annotations

import json
import os

from facestats.errors import StoreError
from facestats.io.layout import RECORDS, confined, is_generation, read_regular_file, write_json_atomic

__all__ = [
    "RECORD_FORMAT",
    "STATES",
    "record_name",
    "parse_record_name",
    "record_path",
    "read_record",
    "inspect_record",
    "record_problem",
    "write_record",
    "mark_record",
]

#: Layout version of a record.
RECORD_FORMAT = 1
#: The states a record can be in.
STATES = ("writing", "committed", "retired")


def record_name(sid: str, gen: str) -> str:
    """The file name of the record of generation ``gen`` of subject ``sid`` (in ``.records/``).

    Parameters
    ----------
    sid, gen : str
        Subject id and generation name (not checked).

    Returns
    -------
    str
        ``<sid>~<gen>.json``.
    """
    return f"{sid}~{gen}.json"


def parse_record_name(name: str):
    """``(sid, gen)`` of a record file name, or None if ``name`` is not one (the id is not checked here).

    Parameters
    ----------
    name : str
        A file name in ``.records/``.

    Returns
    -------
    tuple of str or None
        ``gen`` is a generation name (:func:`facestats.io.layout.is_generation`) and ``sid`` is not empty.
    """
    if not name.endswith(".json") or "~" not in name:
        return None
    sid, _, gen = name[:-5].rpartition("~")
    return (sid, gen) if sid and is_generation(gen) else None


def record_path(root, sid: str, gen: str) -> str:
    """The record file of generation ``gen`` of subject ``sid`` in the store at ``root``.

    Parameters
    ----------
    root : str or os.PathLike
        The store directory.
    sid, gen : str
        Subject id and generation name (not checked).

    Returns
    -------
    str
        ``<root>/.records/<sid>~<gen>.json``.
    """
    return os.path.join(os.fspath(root), RECORDS, record_name(sid, gen))


def read_record(root, sid: str, gen: str) -> dict | None:
    """The record of a generation, or None if it is missing, unreadable, malformed or not a record of this generation.

    A record counts only if it is a regular file (not a link) whose content
    names this very subject and generation in the current format, with a known
    state and revisions that are integers >= 0 (:func:`inspect_record` says
    what is wrong with one that does not).

    Parameters
    ----------
    root : str or os.PathLike
        The store directory.
    sid, gen : str
        Subject id and generation name.

    Returns
    -------
    dict or None
        The record document.
    """
    return inspect_record(root, sid, gen)[0]


def inspect_record(root, sid: str, gen: str) -> tuple[dict | None, str | None]:
    """``(record, problem)`` of the record file of a generation.

    ``record`` is the valid record (or None); ``problem`` is None unless the
    file is the store's own record of this generation — a regular file whose
    JSON names this subject and generation in the current format — with a
    malformed field (an unknown state, a revision that is not an integer >= 0,
    a creation time that is not a string): a message naming the file, the
    field and the value.  Anything else that is not a valid record (a link,
    unreadable, not JSON, about another generation) is not provably the
    store's: ``(None, None)``.

    Parameters
    ----------
    root : str or os.PathLike
        The store directory.
    sid, gen : str
        Subject id and generation name.

    Returns
    -------
    record : dict or None
    problem : str or None
    """
    path = record_path(root, sid, gen)
    try:
        confined(root, path)  # a record read through a link planted in the store proves nothing
    except StoreError:
        return None, None
    try:  # a link, a FIFO or a device is refused (OSError) without blocking, never read
        rec = json.loads(read_regular_file(path, 65536, follow_links=False))
    except (OSError, ValueError, RecursionError):
        return None, None
    if (
        not isinstance(rec, dict)
        or rec.get("facestats_generation") != RECORD_FORMAT
        or rec.get("subject") != sid
        or rec.get("generation") != gen
    ):
        return None, None
    problem = record_problem(rec)
    if problem is not None:
        return None, f"the record {RECORDS}/{record_name(sid, gen)} is malformed: {problem}"
    return rec, None


def _is_revision(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 2**53


def record_problem(rec: dict) -> str | None:
    """What is wrong with the fields of a record document (its state, revisions, creation time), or None.

    Parameters
    ----------
    rec : dict
        A record document (its identity fields are not checked here).

    Returns
    -------
    str or None
        The first problem found, naming the field and the value.
    """
    if rec.get("state") not in STATES:
        return f"field 'state' must be one of {list(STATES)}, got {rec.get('state')!r}"
    for key in ("committed_revision", "retired_revision"):
        if key in rec and not _is_revision(rec[key]):
            return f"field {key!r} must be an integer >= 0, got {rec[key]!r}"
    if not isinstance(rec.get("created", ""), str):
        return f"field 'created' must be a string, got {rec['created']!r}"
    return None


def write_record(root, sid: str, gen: str, state: str, **fields) -> dict:
    """Write (replace) the record of a generation atomically; the record written.

    Parameters
    ----------
    root : str
        The store directory.
    sid, gen : str
        Subject id and generation name (checked).
    state : {"writing", "committed", "retired"}
    **fields
        Further entries (``created``, ``committed_revision``, ``retired_revision``).

    Returns
    -------
    dict
        The record written.
    """
    if state not in STATES or not is_generation(gen):
        raise ValueError(f"bad record state {state!r} or generation {gen!r}")  # a bug, not bad input
    rec = {"facestats_generation": RECORD_FORMAT, "subject": sid, "generation": gen, "state": state, **fields}
    write_json_atomic(confined(root, record_path(root, sid, gen)), rec, durable=False)
    return rec


def mark_record(root, sid: str, gen: str, state: str, revision: int) -> None:
    """Set a generation's record to ``committed`` or ``retired`` at index ``revision``, keeping its other entries.

    A missing record (a generation written before records existed) is created.
    Called under the store lock by the commit; failures are left to
    ``facestats validate --repair`` to heal (the index is the commit point).

    Parameters
    ----------
    root : str or os.PathLike
        The store directory.
    sid, gen : str
        Subject id and generation name.
    state : {"committed", "retired"}
        The new state; ``<state>_revision`` is set to ``revision``.
    revision : int
        The index revision.

    Raises
    ------
    OSError
        The record could not be written.
    StoreError
        The record's path passes through a symbolic link (:func:`facestats.io.layout.confined`).
    """
    rec = read_record(root, sid, gen) or {}
    fields = {k: v for k, v in rec.items() if k not in ("facestats_generation", "subject", "generation", "state")}
    fields[f"{state}_revision"] = int(revision)
    write_record(root, sid, gen, state, **fields)
