"""Repair of a directory store: a plan first (a dry run by default), then its application under the lock.

Rules (issue #12): repair recovers what is recoverable, never deletes data,
never follows a link out of the store, and refuses to act on a store that
looks unmounted or half-present.

:func:`plan_repair` reads the store *without the lock* (checking every
checksum can take long, and writers must not wait for it) and returns a
:class:`RepairPlan`:

* **refusals** (:class:`~facestats.errors.StoreError`, nothing planned):
  ``subjects/`` missing or not a real folder, ``index.json`` or ``.writers``
  of the wrong file type, or (unless ``allow_missing``) the folders of all or
  more than half of the indexed subjects missing (with the index lost: of the
  subjects whose records say they are committed) — an unmounted volume must
  not be mistaken for lost data;
* a **lost index** (missing, not JSON, not an index) is moved to the
  quarantine and rebuilt (an empty one if nothing is recoverable): per
  subject, the generation with the highest ``committed_revision`` in its
  record (:mod:`facestats.io.records`) that reads intact; a subject whose
  newest committed generation is damaged falls back to its previous committed
  one; generations never committed (crashed writes, crashed batches) and
  subjects whose last record says *retired* (deleted) are never revived;
  stores older than records (no record at all) use the newest intact
  generation of each subject; the new index continues the revision count;
  an intact generation whose record says *writing* (records lag the index, so
  it may have been committed) is moved to the quarantine, neither revived nor
  left for the garbage collection;
* per **indexed subject**: damaged generation → moved to the quarantine;
  damaged or missing → the subject is recovered from its newest other intact
  committed generation, else its entry is dropped (and saved in the
  quarantine); a row that disagrees with the data is recomputed; an invalid
  entry (tampered id, generation, row or histogram) is recomputed from its
  generation if that reads intact, else dropped (saved); data that could not
  be read just now (an I/O error) get *no* action;
* committed generations of subjects the index does not list are **adopted**;
* every generation found **damaged** on the way — the one the index names, or
  an older one tried while looking for an intact one to recover from or
  adopt — is moved to the quarantine (with its record), never left for the
  garbage collection to delete; the plan lists each move;
* a record with a malformed field (a revision that is not an integer, an
  unknown state) is rewritten if the index names its generation, else moved
  to the quarantine with its generation folder;
* records the index contradicts are healed; leftovers of interrupted writes
  are collected (:func:`facestats.io.maintenance.collect_garbage`): the plan
  lists what the collection would remove once the repaired index is in place
  (e.g. the generations it leaves superseded, as a completed overwrite would
  have removed them).

:func:`apply_repair` takes the store lock, re-reads the index, and applies
each action only if what it was planned against still holds (the index still
names the same generation, the lost index is still lost, ...), so a repair
never undoes what another process committed meanwhile; moves into the
quarantine happen before the index commit, so a crash in between leaves the
old index (the next repair plans again) and never a deletion.
"""

from __future__ import annotations

import copy
import os
from dataclasses import dataclass, field

from facestats.core.version import __version__
from facestats.errors import SchemaError, StoreError, ValidationError
from facestats.io.commit import commit_index, generations_of
from facestats.io.ids import check_subject_id
from facestats.io.index import INDEX_NAME, empty_index, make_entry, read_index_bytes, split_index
from facestats.io.integrity import STORE_ATTR
from facestats.io.layout import (
    LOCK_NAME,
    RECORDS,
    ROOT_META,
    SUBJECTS,
    WRITERS,
    generation_rel,
    group_meta,
    is_generation,
    is_plain_dir,
    is_plain_file,
    write_json_atomic,
    writer_lock_path,
)
from facestats.io.locking import is_locked
from facestats.io.maintenance import ValidationReport, check_subjects, survey
from facestats.io.quarantine import MANIFEST as QUARANTINE_MANIFEST
from facestats.io.quarantine import open_quarantine, quarantine_move, write_quarantine_json
from facestats.io.records import inspect_record, mark_record, read_record, record_name, record_path
from facestats.io.schema import SCHEMA_VERSION
from facestats.io.summary import albedo_histogram, summarise_subject

__all__ = ["RepairAction", "RepairPlan", "plan_repair", "apply_repair", "check_writable"]

#: Order in which the kinds of action are applied (moves before the commit, records after it).
_ORDER = (
    "quarantine-index",
    "quarantine-generation",
    "quarantine-record",
    "new-index",
    "drop-entry",
    "recover",
    "recompute",
    "adopt",
    "heal-record",
)


@dataclass
class RepairAction:
    """One step of a :class:`RepairPlan`.

    Attributes
    ----------
    kind : str
        One of ``quarantine-index``, ``quarantine-generation``, ``quarantine-record``, ``new-index``,
        ``drop-entry``, ``recover``, ``recompute``, ``adopt``, ``heal-record``.
    subject : str or None
    expect : str or None
        The generation the index must still name for the action to apply (None: the subject is absent).
        A ``quarantine-generation`` of a generation other than the one the index names carries the
        generation the index named when the plan was made (the move is skipped if it changed).
    source : str or None
        The generation the subject's new entry points at (recover, recompute, adopt), or the one moved.
    entry : dict or None
        The new index entry, or the entry dropped.
    reason : str
    """

    kind: str
    subject: str | None = None
    expect: str | None = None
    source: str | None = None
    entry: dict | None = None
    reason: str = ""

    def describe(self) -> str:
        """What the action does, in one sentence."""
        sid = repr(self.subject)
        what = {
            "quarantine-index": f"move {INDEX_NAME} to the quarantine",
            "quarantine-generation": f"move {generation_rel(self.subject or '', self.source or '')} to the quarantine",
            "quarantine-record": f"move {RECORDS}/{record_name(self.subject or '', self.source or '')} and its "
            "generation folder (if any) to the quarantine",
            "new-index": f"write a new {INDEX_NAME}",
            "drop-entry": f"drop subject {sid} from the index (its entry is saved in the quarantine)",
            "recover": f"recover subject {sid} from generation {self.source}",
            "recompute": f"recompute the index entry of subject {sid}",
            "adopt": f"add subject {sid} back to the index from generation {self.source}",
            "heal-record": f"{'rewrite' if self.reason else 'mark'} generation {self.source} of {sid} committed in "
            "its record",
        }[self.kind]
        return f"{what}: {self.reason}" if self.reason else what


@dataclass
class RepairPlan:
    """What :func:`apply_repair` would do (see the module docstring).

    Attributes
    ----------
    store : str
    actions : list of RepairAction
    garbage : list of str
        What the garbage collection after the repair would remove: leftovers of interrupted writes and
        the generations the repaired index leaves superseded (never one the plan moves to the
        quarantine); re-decided under the lock when applied.
    problems : list of str
        What no action can repair (e.g. data that could not be read just now).
    index_lost : bool
        The index is missing or unreadable and is rebuilt.
    base_revision : int
        The revision the new index continues from.
    group_meta : bool
        ``subjects/zarr.json`` (the subjects group's own file) is missing and is written.
    """

    store: str
    actions: list = field(default_factory=list)
    garbage: list = field(default_factory=list)
    problems: list = field(default_factory=list)
    index_lost: bool = False
    base_revision: int = 0
    group_meta: bool = False

    @property
    def empty(self) -> bool:
        """Nothing at all to do: :meth:`facestats.io.Store.repair` then takes no lock and writes nothing."""
        return not self.actions and not self.garbage and not self.group_meta

    @property
    def fixes_problems(self) -> bool:
        """True if the plan repairs problems (beyond housekeeping: healing records, removing leftovers).

        Rewriting a malformed record (a ``heal-record`` with a reason) repairs a problem.
        """
        return any(a.kind != "heal-record" or a.reason for a in self.actions)

    def to_text(self, *, applied: bool = False) -> str:
        """The plan (or, ``applied``, what was done) as the lines ``facestats validate --repair`` prints.

        Parameters
        ----------
        applied : bool
            Head the lines as a repair done rather than a dry run (default False).

        Returns
        -------
        str
            The lines, each ending in a newline.
        """
        head = "repair" if applied else "repair plan (dry run: nothing was changed; add --yes to apply it)"
        lines = [f"{head} for store {self.store}:"]
        heals = [a for a in self.actions if a.kind == "heal-record" and not a.reason]
        lines += [f"  - {a.describe()}" for a in self.actions if a.kind != "heal-record" or a.reason]
        if heals:
            lines.append(f"  - mark {len(heals)} generation(s) the index names as committed in their records")
        if self.garbage:  # leftovers of interrupted writes, and folders of subjects the repair leaves empty
            shown = ", ".join(self.garbage[:GARBAGE_SHOWN]) + (", ..." if len(self.garbage) > GARBAGE_SHOWN else "")
            lines.append(f"  - remove {len(self.garbage)} leftover item(s): {shown}")
        if self.group_meta:
            lines.append(f"  - write the missing {SUBJECTS}/{ROOT_META}")
        if self.empty:
            lines.append("  nothing to repair")
        lines += [f"  cannot repair: {p}" for p in self.problems]
        return "\n".join(lines) + "\n"


# -- planning ----------------------------------------------------------------------------------
#: Leftovers a plan's text names one by one (the rest are counted).
GARBAGE_SHOWN = 10


def plan_repair(
    root, *, label: str, open_generation, allow_missing: bool = False, progress: bool = False
) -> RepairPlan:
    """The repair plan of the directory store at ``root`` (module docstring); nothing is changed.

    Parameters
    ----------
    root : str
        The store directory.
    label : str
        The store's name in messages.
    open_generation : callable
        ``open_generation(sid, gen)``: a fully verified subject (:func:`facestats.io.integrity.open_generation`).
    allow_missing : bool
        Plan even if the folders of most indexed subjects are missing (the data are really gone).
    progress : bool
        Show a progress bar while the subjects are checked.

    Returns
    -------
    RepairPlan
        What a repair would do.

    Raises
    ------
    StoreError
        The store looks unmounted or half-present, or holds files of the wrong type where the
        store's own should be: repair refuses to act.
    """
    _preflight(root)
    plan = RepairPlan(label)
    index, bad = _read_index(root, plan)
    if index is None:
        _plan_rebuild(plan, root, open_generation, allow_missing)
    else:
        plan.base_revision = int(index.get("revision", 0))
        ids = list(index["subjects"]) + [s for s in bad if isinstance(s, str)]
        _refuse_linked_subjects(root, ids)
        then = " (their index entries are then saved in the quarantine)"
        _refuse_half_present(root, ids, "indexed subjects", allow_missing, then)
        _plan_bad_entries(plan, root, bad, open_generation)
        _plan_indexed(plan, root, index, open_generation, progress)
        s = survey(root, index)
        _plan_adoptions(plan, s, open_generation)
        malformed = {(sid, gen): message for sid, gen, message, _ in s.bad_records}
        for sid, gen in generations_of(index).items():
            rec = read_record(root, sid, gen)
            if is_plain_dir(os.path.join(root, generation_rel(sid, gen))) and (
                rec is None or rec["state"] != "committed"
            ):
                why = malformed.get((sid, gen), "")
                plan.actions.append(RepairAction("heal-record", sid, expect=gen, source=gen, reason=why))
        _plan_bad_records(plan, s, index)
    plan.actions.sort(key=lambda a: _ORDER.index(a.kind))
    plan.garbage = _garbage_after(plan, root, index)
    plan.group_meta = not os.path.lexists(os.path.join(root, SUBJECTS, ROOT_META))
    return plan


def _garbage_after(plan: RepairPlan, root, index) -> list[str]:
    """What the garbage collection would remove once ``plan`` is applied (:func:`survey` of the new index).

    The generations (and records) the plan moves to the quarantine are left out: they are moved first.
    """
    after = copy.deepcopy(index) if index is not None else empty_index(SCHEMA_VERSION, __version__)
    for a in plan.actions:
        _change_index(after["subjects"], a)
    after["revision"] = plan.base_revision + any(a.kind in _INDEX_KINDS for a in plan.actions)
    moved = {(a.subject, a.source) for a in plan.actions if a.kind in ("quarantine-generation", "quarantine-record")}
    return survey(root, after, absent=moved).leftovers  # as the moves leave it: a subject losing its last one is empty


def _preflight(root) -> None:
    """Refuse stores whose own files are missing or of the wrong type (module docstring)."""
    sub = os.path.join(root, SUBJECTS)
    if not os.path.lexists(sub):
        raise StoreError(
            f"refusing to repair {root}: its {SUBJECTS}/ folder is missing — is the volume holding the data "
            "unmounted? Nothing was changed; mount it (or restore the folder) and run the repair again"
        )
    if not is_plain_dir(sub):
        raise StoreError(
            f"refusing to repair {root}: {SUBJECTS} is not a folder of the store (a file or a symbolic link); "
            "nothing was changed"
        )
    for name, ok in ((INDEX_NAME, is_plain_file), (WRITERS, is_plain_dir), (RECORDS, is_plain_dir)):
        path = os.path.join(root, name)
        if os.path.lexists(path) and not ok(path):
            kind = "a regular file" if ok is is_plain_file else "a folder"
            raise StoreError(
                f"refusing to repair {root}: {name} must be {kind} of the store, but it is not (a directory, "
                "FIFO, device or symbolic link?); it was not created by facestats, so remove or rename it "
                "yourself, then run the repair again"
            )


def _read_index(root, plan: RepairPlan):
    """The index split into valid entries and invalid ones; ``(None, {})`` (and a plan to rebuild) if it is lost."""
    try:
        return split_index(read_index_bytes(root), where=os.path.join(root, INDEX_NAME))
    except StoreError as exc:
        plan.index_lost = True
        if os.path.lexists(os.path.join(root, INDEX_NAME)):
            plan.actions.append(RepairAction("quarantine-index", reason=str(exc)))
        return None, {}


def _refuse_linked_subjects(root, ids) -> None:
    """Refuse a store where an indexed subject's folder is a symbolic link: repair never moves through links."""
    linked = [sid for sid in ids if os.path.islink(os.path.join(root, SUBJECTS, sid))]
    if linked:
        raise StoreError(
            f"refusing to repair {root}: {SUBJECTS}/{linked[0]} is a symbolic link ({len(linked)} indexed subject "
            "folder(s) are); facestats never moves or writes through links: replace each by the folder it points "
            "to, then run the repair again. Nothing was changed"
        )


def _refuse_half_present(root, ids, what: str, allow_missing: bool, then: str = "") -> None:
    """Refuse (StoreError) if the folders of all or more than half of the subjects ``ids`` are missing.

    Parameters
    ----------
    root : str
        The store directory.
    ids : list of str
        The subjects the store says it holds: those of the index, or (the index lost) those whose
        records say they are committed.
    what : str
        What ``ids`` are, for the message.
    allow_missing : bool
        Never refuse (the data are really gone).
    then : str
        What ``--allow-missing`` does with them, for the message.
    """
    missing = [s for s in ids if isinstance(s, str) and not os.path.lexists(os.path.join(root, SUBJECTS, s))]
    if ids and missing and not allow_missing and (len(missing) == len(ids) or 2 * len(missing) > len(ids)):
        raise StoreError(
            f"refusing to repair {root}: the folders of {len(missing)} of the {len(ids)} {what} are "
            f"missing (e.g. {SUBJECTS}/{missing[0]}) — the store looks unmounted or half-present. Nothing was "
            f"changed. If those data are really gone, rerun with --allow-missing{then}"
        )


def _entry(sid: str, gen: str, ds) -> dict:
    """A fresh index entry of generation ``gen`` of ``sid`` from its (verified) Dataset."""
    written = ds.encoding.get(STORE_ATTR, {}).get("written", "")
    return make_entry(gen, written, summarise_subject(ds), albedo_histogram(ds))


def _open(plan: RepairPlan, open_generation, sid: str, gen: str) -> tuple[bool, object]:
    """``(readable, dataset)`` of generation ``gen`` of ``sid``.

    ``(True, Dataset)`` if it reads intact, ``(True, None)`` if it is damaged (checksums). ``(False, None)``
    if it cannot be read now (an I/O error, :class:`StoreError`): the error is noted in ``plan.problems``
    and the caller leaves the generation alone.
    """
    try:
        return True, open_generation(sid, gen)
    except SchemaError:
        return True, None
    except StoreError as exc:
        plan.problems.append(str(exc))
        return False, None


def _records(root, sid: str) -> dict:
    """``{generation: record}`` of the generation folders of ``sid`` (record None if it has none)."""
    sdir = os.path.join(root, SUBJECTS, sid)
    if not is_plain_dir(sdir):  # a link planted in the store (subjects/X -> R2) holds no generation of X
        return {}
    try:
        names = os.listdir(sdir)
    except OSError:
        return {}
    gens = [n for n in names if is_generation(n) and is_plain_dir(os.path.join(sdir, n))]
    return {g: read_record(root, sid, g) for g in gens}


def _candidates(root, sid: str, *, exclude=(), live_only: bool = False) -> list[tuple[int, str]]:
    """Generations of ``sid`` that were committed, newest commit first: ``[(revision, gen)]``.

    ``live_only`` keeps only those not retired.  A subject without any record (a store older than
    records) gives its generations by name (newest first), revision -1.  Generations whose writer is
    still running are never candidates, nor those never committed.
    """
    recs = _records(root, sid)
    gens = [g for g in recs if g not in exclude and not is_locked(writer_lock_path(root, sid, g))]
    if not any(r is not None for r in recs.values()):
        return [(-1, g) for g in sorted(gens, reverse=True)]
    out = []
    for g in gens:
        rec = recs[g]
        if rec is None or "committed_revision" not in rec or (live_only and rec["state"] != "committed"):
            continue
        out.append((int(rec["committed_revision"]), g))
    return sorted(out, reverse=True)


def _top_revision(root, ids) -> int:
    """The highest revision any record of the subjects ``ids`` mentions (0 if none)."""
    top = 0
    for sid in ids:
        for rec in _records(root, sid).values():
            if rec is not None:
                top = max(top, int(rec.get("committed_revision", 0)), int(rec.get("retired_revision", 0)))
    return top


def _first_intact(plan, sid, candidates, open_generation, *, expect):
    """``(revision, gen, dataset)`` of the first candidate that reads intact, or None.

    Every damaged candidate tried before it is planned to move to the quarantine (never left for the
    garbage collection to delete), on condition that the index still names ``expect`` for ``sid``.
    """
    for rev, gen in candidates:
        readable, ds = _open(plan, open_generation, sid, gen)
        if not readable:
            continue
        if ds is not None:
            return rev, gen, ds
        plan.actions.append(
            RepairAction("quarantine-generation", sid, expect=expect, source=gen, reason="damaged (checksums)")
        )
    return None


def _recovered_why(rev: int) -> str:
    return "written before commit records existed" if rev < 0 else f"committed at revision {rev}"


def _plan_rebuild(plan: RepairPlan, root, open_generation, allow_missing: bool) -> None:
    """Recover every subject from its newest intact committed generation (the index is lost).

    A new index is written even if no subject is recoverable (an empty one); the store is refused as
    unmounted or half-present when the folders of most subjects its records call committed are missing.
    """
    s = survey(root, empty_index(SCHEMA_VERSION, __version__))
    committed = sorted(
        {sid for sid, gen in s.records if (read_record(root, sid, gen) or {}).get("state") == "committed"}
    )
    _refuse_half_present(root, committed, "subjects committed according to their records", allow_missing)
    ids = s.subject_dirs
    plan.base_revision = _top_revision(root, ids)
    _plan_bad_records(plan, s, None)
    for sid in ids:
        _plan_unconfirmed(plan, root, sid, open_generation)
        newest = _candidates(root, sid, live_only=True)
        if not newest:
            continue  # deleted, or never committed
        older = [c for c in _candidates(root, sid) if c not in newest]
        found = _first_intact(plan, sid, newest + older, open_generation, expect=None)
        if found is None:
            plan.problems.append(f"subject {sid!r}: no intact committed generation is left; it is not recovered")
            continue
        rev, gen, ds = found
        plan.actions.append(
            RepairAction("recover", sid, source=gen, entry=_entry(sid, gen, ds), reason=_recovered_why(rev))
        )
    n = sum(a.kind == "recover" for a in plan.actions)
    why = f"it lists the {n} subject(s) recovered below" if n else "no subject is recoverable: the new index is empty"
    plan.actions.append(RepairAction("new-index", reason=f"the index is lost; {why}"))


def _plan_unconfirmed(plan: RepairPlan, root, sid: str, open_generation) -> None:
    """With the index lost: intact generations of ``sid`` whose record says ``writing`` go to the quarantine.

    Records lag the index (a crash between the index's replacement and the record's update leaves a
    committed generation marked ``writing``), so with the index gone such a generation may hold committed
    data as well as a crashed write: it is neither revived nor left for the garbage collection, which
    would delete it; a damaged or incomplete one is the leftover of an interrupted write.
    """
    for gen, rec in sorted(_records(root, sid).items()):
        if rec is None or rec["state"] != "writing" or is_locked(writer_lock_path(root, sid, gen)):
            continue
        readable, ds = _open(plan, open_generation, sid, gen)
        if not readable:
            continue
        if ds is not None:
            why = (
                "the index is lost and its record says 'writing': it may have been committed (records lag the "
                "index) or be a write that crashed, so it is kept in the quarantine rather than revived or deleted"
            )
            plan.actions.append(RepairAction("quarantine-generation", sid, source=gen, reason=why))


def _plan_bad_records(plan: RepairPlan, s, index) -> None:
    """The store's own records with a malformed field, of generations the index does not name: quarantined."""
    named = generations_of(index)
    for sid, gen, message, _ in s.bad_records:
        if named.get(sid) != gen:
            plan.actions.append(
                RepairAction("quarantine-record", sid, expect=named.get(sid), source=gen, reason=message)
            )


def _valid_id(sid) -> bool:
    try:
        check_subject_id(sid)
    except ValidationError:
        return False
    return isinstance(sid, str)


def _plan_bad_entries(plan: RepairPlan, root, bad: dict, open_generation) -> None:
    """Invalid index entries: recomputed from their generation if it reads intact, else dropped (saved)."""
    for sid, (entry, problem) in bad.items():
        gen = entry.get("generation") if isinstance(entry, dict) else None
        ds = None
        usable = _valid_id(sid) and isinstance(gen, str) and is_generation(gen)
        if usable and is_plain_dir(os.path.join(root, generation_rel(sid, gen))):
            readable, ds = _open(plan, open_generation, sid, gen)
            if not readable:
                continue
        if ds is not None:
            plan.actions.append(RepairAction("adopt", sid, source=gen, entry=_entry(sid, gen, ds), reason=problem))
        else:
            plan.actions.append(RepairAction("drop-entry", str(sid), entry=entry, reason=problem))


def _plan_indexed(plan: RepairPlan, root, index: dict, open_generation, progress: bool = False) -> None:
    """Check every indexed subject and plan what its findings call for."""

    def exists(sid, gen):
        return is_plain_dir(os.path.join(root, generation_rel(sid, gen)))

    report = ValidationReport(path=plan.store)
    checked = check_subjects(index, open_generation, report, generation_exists=exists, progress=progress)
    plan.problems += list(checked.unreadable.values())
    for sid, (gen, msg) in sorted({**checked.damaged, **checked.missing}.items()):
        damaged = sid in checked.damaged
        if damaged:
            plan.actions.append(RepairAction("quarantine-generation", sid, expect=gen, source=gen, reason=msg))
        cands = _candidates(root, sid, exclude=(gen,))
        found = _first_intact(plan, sid, cands, open_generation, expect=gen)
        if found is None:
            why = f"{msg}; no intact earlier version is left"
            plan.actions.append(RepairAction("drop-entry", sid, expect=gen, entry=index["subjects"][sid], reason=why))
            continue
        rev, src, ds = found
        why = f"its generation {gen} is {'damaged' if damaged else 'missing'}; that one was {_recovered_why(rev)}"
        plan.actions.append(
            RepairAction("recover", sid, expect=gen, source=src, entry=_entry(sid, src, ds), reason=why)
        )
    for sid, (gen, entry, msg) in sorted(checked.stale.items()):
        plan.actions.append(RepairAction("recompute", sid, expect=gen, source=gen, entry=entry, reason=msg))


def _plan_adoptions(plan: RepairPlan, s, open_generation) -> None:
    """Committed generations of subjects the index does not list: add the newest intact one back."""
    planned = {a.subject for a in plan.actions if a.kind == "adopt"}
    for sid, cands in sorted(s.adoptable.items()):
        if sid in planned:
            continue
        found = _first_intact(plan, sid, cands, open_generation, expect=None)
        if found is not None:
            rev, gen, ds = found
            why = f"committed at revision {rev} but missing from the index"
            plan.actions.append(RepairAction("adopt", sid, source=gen, entry=_entry(sid, gen, ds), reason=why))


# -- applying ----------------------------------------------------------------------------------
def apply_repair(root, plan: RepairPlan, *, label: str, lock, root_attrs: dict) -> tuple[list[str], dict]:
    """Apply ``plan`` under the store ``lock`` (module docstring); ``(what was done, root attributes)``.

    Actions whose premise no longer holds are skipped and said so.

    Parameters
    ----------
    root : str
        The store directory.
    plan : RepairPlan
        From :func:`plan_repair`.
    label : str
        The store's name in messages.
    lock : facestats.io.locking.FileLock
        The store lock, not yet held (acquired and released here).
    root_attrs : dict
        The root group's attributes as the caller knows them.

    Returns
    -------
    done : list of str
        What was done (and skipped), one sentence each.
    root_attrs : dict
        The root attributes after the commit (as given if nothing was committed).

    Raises
    ------
    StoreError
        This process cannot write where the plan would (:func:`check_writable`: nothing was changed), the index
        became readable (or unreadable) since the plan was made, or a step failed (e.g. a full disk); what was
        done until then is named in the message.
    """
    check_writable(root, plan, label)
    done = []
    with lock:
        current, bad = _current(root)
        if plan.index_lost != (current is None):
            raise StoreError(
                f"store {label} changed while the repair was planned (its index was "
                + ("repaired" if plan.index_lost else "lost")
                + " meanwhile); nothing was changed: run the repair again"
            )
        base = current if current is not None else empty_index(SCHEMA_VERSION, __version__)
        if current is None:
            base["revision"] = plan.base_revision
        before = generations_of(current)
        state = _Apply(root, label, base, done)
        try:
            for a in plan.actions:
                state.apply(a)
            state.save_unplanned(bad, plan)
            if state.changed:
                root_attrs = commit_index(root, base, before, root_attrs, label=label)
                state.committed = True
            for a in state.heal:
                mark_record(root, a.subject, a.source, "committed", base["revision"])
                done.append(a.describe())
            _group_meta(root, done)
        except (OSError, StoreError) as exc:
            msg = exc.strerror if isinstance(exc, OSError) else str(exc)
            raise StoreError(
                f"the repair of {label} stopped: {msg}. Done before that: {done or 'nothing'}; the index was "
                + ("committed." if state.committed else "not changed.")
            ) from None
    return done, root_attrs


def check_writable(root, plan: RepairPlan, label: str) -> None:
    """Refuse, before anything changes, a repair this process may not write: :class:`StoreError` naming the folder.

    A store read-only to this user (a shared store, a read-only mount) failed at the store lock, after the plan was
    made, or, with a lock file left writable, removed nothing and reported the store valid.  Checked
    (``os.access``, this process's permissions): read and write permission on the store lock, and write and
    search permission on the folder holding each leftover the plan removes and, for a plan with actions, on the
    store's root, ``subjects/`` and ``.records/``.  A plan with nothing to do is not checked (it writes nothing).

    Parameters
    ----------
    root : str
        The store directory.
    plan : RepairPlan
        The plan about to be applied.
    label : str
        The store's name in messages.

    Raises
    ------
    StoreError
        A folder (or the lock file) this process may not write; nothing was changed.
    """
    if plan.empty:
        return
    folders = {os.path.dirname(os.path.join(root, rel)) for rel in plan.garbage}
    if plan.actions:  # the quarantine and the index in the root, records, subject folders
        folders |= {root, os.path.join(root, SUBJECTS), os.path.join(root, RECORDS)}
    if plan.group_meta:
        folders.add(os.path.join(root, SUBJECTS))
    lock = os.path.join(root, LOCK_NAME)
    if not os.path.lexists(lock):
        folders.add(root)  # the lock file is created
    denied = sorted(f for f in folders if os.path.isdir(f) and not os.access(f, os.W_OK | os.X_OK))
    if os.path.lexists(lock) and not os.access(lock, os.R_OK | os.W_OK):
        denied.insert(0, lock)
    if denied:
        rel = os.path.relpath(denied[0], root)
        more = f" and {len(denied) - 1} other place(s) it writes" if len(denied) > 1 else ""
        raise StoreError(
            f"store {label} cannot be repaired by this user: no write permission on "
            f"{'the store folder' if rel == '.' else rel}{more}; nothing was changed (run the repair as the store's "
            "owner, or on a writable copy)"
        )


#: The kinds of action that change the index (a commit follows).
_INDEX_KINDS = ("new-index", "drop-entry", "recover", "recompute", "adopt")


def _change_index(subjects: dict, a: RepairAction):
    """Make the change ``a`` calls for in the index entries ``subjects``; the entry a ``drop-entry`` removed.

    Returns None for every other kind (``new-index`` changes no entry: the commit writes the index).
    """
    if a.kind == "drop-entry":
        return subjects.pop(a.subject, None) or a.entry
    if a.kind in ("recover", "recompute", "adopt"):
        subjects[a.subject] = copy.deepcopy(a.entry)
    return None


def _current(root):
    """The current index split (valid document, invalid entries), or ``(None, {})`` if it cannot be read."""
    try:
        return split_index(read_index_bytes(root), where=os.path.join(root, INDEX_NAME))
    except StoreError:
        return None, {}


def _group_meta(root, done: list) -> None:
    """Write ``subjects/zarr.json`` if it is missing (a store's own group file)."""
    path = os.path.join(root, SUBJECTS, ROOT_META)
    if not os.path.lexists(path):
        write_json_atomic(path, group_meta())
        done.append(f"wrote the missing {SUBJECTS}/{ROOT_META}")


def _remove_empty_quarantine(qdir: str) -> None:
    """Remove a quarantine folder that received nothing: its manifest, then the folder and ``quarantine/`` if empty.

    Only empty folders are removed (``os.rmdir``): anything moved there meanwhile stays.
    """
    try:
        os.remove(os.path.join(qdir, QUARANTINE_MANIFEST))
    except OSError:
        pass
    for folder in (qdir, os.path.dirname(qdir)):
        try:
            os.rmdir(folder)
        except OSError:
            pass


class _Apply:
    """The state of one application: the index being changed, the quarantine folder, what was done."""

    def __init__(self, root, label, base, done):
        self.root, self.label, self.base, self.done = root, label, base, done
        self.qdir = None
        self.dropped = {}
        self.heal = []
        self.changed = False
        self.committed = False

    def quarantine(self, rel: str, why: str) -> None:
        fresh = self.qdir is None
        if fresh:
            self.qdir = open_quarantine(self.root, f"facestats validate --repair ({self.label})")
        try:
            quarantine_move(self.root, self.qdir, rel, why)
        except BaseException:
            moved = os.path.lexists(os.path.join(self.qdir, rel))  # a whole copy whose original was not removed
            if fresh and not moved and os.path.lexists(os.path.join(self.root, rel)):  # refused before anything moved
                _remove_empty_quarantine(self.qdir)
                self.qdir = None
            raise

    def premise(self, a: RepairAction) -> bool:
        """True if what ``a`` was planned against still holds."""
        named = self.base["subjects"].get(a.subject, {}).get("generation") if a.subject else None
        if a.kind in ("quarantine-index", "new-index"):
            return True  # apply_repair checked that the index is still lost
        if a.kind in ("recover", "recompute", "drop-entry", "heal-record"):
            ok = named == a.expect
        elif a.kind == "adopt":
            ok = named is None
        elif a.kind == "quarantine-record":  # never the record of what the index names; no writer on it
            ok = named != a.source and not is_locked(writer_lock_path(self.root, a.subject, a.source))
            ok = ok and inspect_record(self.root, a.subject, a.source)[1] is not None  # still malformed
        else:  # quarantine-generation: the index names what it named when planned, and no writer is on it
            ok = named == a.expect and not is_locked(writer_lock_path(self.root, a.subject, a.source))
        if ok and a.kind in ("recover", "recompute", "adopt", "quarantine-generation"):
            ok = is_plain_dir(os.path.join(self.root, generation_rel(a.subject, a.source)))
        return ok

    def apply(self, a: RepairAction) -> None:
        if not self.premise(a):
            self.done.append(f"skipped (the store changed meanwhile): {a.describe()}")
            return
        if a.kind == "quarantine-index":
            self.quarantine(INDEX_NAME, a.reason)
        elif a.kind == "quarantine-generation":
            rel = generation_rel(a.subject, a.source)
            self.quarantine(rel, a.reason)
            if os.path.lexists(record_path(self.root, a.subject, a.source)):
                self.quarantine(f"{RECORDS}/{record_name(a.subject, a.source)}", "the record of " + rel)
        elif a.kind == "quarantine-record":
            rel = generation_rel(a.subject, a.source)
            if is_plain_dir(os.path.join(self.root, SUBJECTS, a.subject)) and is_plain_dir(
                os.path.join(self.root, rel)
            ):
                self.quarantine(rel, a.reason)
            self.quarantine(f"{RECORDS}/{record_name(a.subject, a.source)}", a.reason)
        elif a.kind == "heal-record":
            self.heal.append(a)
            return
        else:  # new-index, drop-entry, recover, recompute, adopt
            dropped = _change_index(self.base["subjects"], a)
            if a.kind == "drop-entry":
                self.dropped[a.subject] = dropped
            self.changed = True
        self.done.append(a.describe())

    def save_unplanned(self, bad: dict, plan: RepairPlan) -> None:
        """Invalid entries found now but not in the plan are dropped with the rest (saved, like them)."""
        planned = {a.subject for a in plan.actions}
        for sid, (entry, problem) in bad.items():
            if sid not in planned:
                self.dropped[str(sid)] = entry
                self.done.append(f"drop the invalid entry of {sid!r} found while repairing: {problem}")
            self.changed = True
        if self.dropped:
            if self.qdir is None:
                self.qdir = open_quarantine(self.root, f"facestats validate --repair ({self.label})")
            write_quarantine_json(self.qdir, "dropped-entries.json", self.dropped, "index entries the repair dropped")
