"""Upkeep of a directory store: garbage collection, validation against the data, rebuilding the index.

Generations left by crashed writers are *orphans*: :func:`collect_garbage`
removes them (with temporary files and stale writer locks) but never a
generation the index references or one whose writer is still alive (its writer
lock is held).  :func:`check_subjects` opens every indexed subject and compares
its index entry with the data; :func:`rebuild_index` makes a new index from
the newest intact generation of every subject when the index is lost.
:meth:`facestats.io.store.Store.validate` and :meth:`~facestats.io.store.Store.gc`
run these under the store lock and commit the repairs.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field

import numpy as np

from facestats.core.version import __version__
from facestats.errors import StoreError
from facestats.io.index import empty_index, is_index_temp, make_entry, read_index_file
from facestats.io.integrity import STORE_ATTR
from facestats.io.layout import (
    GENERATION_PATTERN,
    ROOT_META,
    SUBJECTS,
    TRASH_PREFIX,
    WRITERS,
    is_meta_temp,
    writer_lock_path,
)
from facestats.io.locking import is_lock_temp, is_locked, try_lock
from facestats.io.schema import SCHEMA_VERSION
from facestats.io.summary import albedo_histogram, summarise_subject

__all__ = [
    "ValidationReport",
    "collect_garbage",
    "list_orphans",
    "orphan_note",
    "rebuild_index",
    "check_subjects",
    "index_repairs",
]


@dataclass
class ValidationReport:
    """Outcome of :meth:`facestats.io.store.Store.validate`.

    ``problems`` make the store invalid (``ok`` is False); ``notes`` are
    harmless findings (orphaned data of interrupted writes); ``repaired``
    lists what ``repair=True`` changed.
    """

    path: str
    n_subjects: int = 0
    n_checked: int = 0
    problems: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    repaired: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def to_text(self) -> str:
        lines = [f"store: {self.path}", f"subjects checked: {self.n_checked} of {self.n_subjects}"]
        lines += [f"problem: {p}" for p in self.problems]
        lines += [f"note: {n}" for n in self.notes]
        lines += [f"repaired: {r}" for r in self.repaired]
        lines.append("store is valid" if self.ok else f"store is INVALID ({len(self.problems)} problem(s))")
        return "\n".join(lines) + "\n"


def _subject_dirs(root):
    """``(subject id, directory)`` of every directory under ``subjects/``, by id."""
    sub_root = os.path.join(root, SUBJECTS)
    for sid in sorted(os.listdir(sub_root)) if os.path.isdir(sub_root) else []:
        sdir = os.path.join(sub_root, sid)
        if os.path.isdir(sdir):
            yield sid, sdir


def _live(index) -> set:
    """``(subject id, generation)`` pairs the index references."""
    return {(sid, e["generation"]) for sid, e in index["subjects"].items()}


# -- garbage collection ---------------------------------------------------------------
@dataclass
class _Sweep:
    """What garbage collection decided under the store lock."""

    doomed: list = field(default_factory=list)  # paths to delete
    held: list = field(default_factory=list)  # writer locks of dead writers, held until the deletion is done
    emptied: list = field(default_factory=list)  # subject directories to remove if empty


def collect_garbage(root, lock) -> list[str]:
    """Remove what interrupted writers left (orphaned generations, temporary files, stale locks).

    Parameters
    ----------
    root : str
        The store directory.
    lock : facestats.io.locking.FileLock
        The store lock (not held); decisions are taken while holding it, so no
        commit can reference a generation being removed.

    Returns
    -------
    list of str
        The removed paths, relative to ``root``.
    """
    sweep = _Sweep()
    with lock:
        index = read_index_file(root)
        live = _live(index)
        for sid, sdir in _subject_dirs(root):
            if not _sweep_subject(sweep, root, sid, sdir, live) and sid not in index["subjects"]:
                sweep.emptied.append(sdir)
                try:
                    os.remove(os.path.join(sdir, ROOT_META))
                except OSError:
                    pass
        _sweep_writers(sweep, os.path.join(root, WRITERS))
        for name in os.listdir(root):
            if is_index_temp(name) or is_meta_temp(name):
                sweep.doomed.append(os.path.join(root, name))
    removed = _remove_paths(root, sweep.doomed)
    for lk in sweep.held:
        lk.release()
    for sdir in sweep.emptied:
        try:  # fails harmlessly if a writer has started a new generation in it meanwhile
            os.rmdir(sdir)
            removed.append(os.path.relpath(sdir, root))
        except OSError:
            pass
    return removed


def _sweep_subject(sweep: _Sweep, root, sid: str, sdir: str, live: set) -> bool:
    """Doom the leftovers in one subject directory; True if a generation there must be kept."""
    keep = False
    for name in os.listdir(sdir):
        p = os.path.join(sdir, name)
        if name.startswith(TRASH_PREFIX) or is_meta_temp(name):
            sweep.doomed.append(p)
        elif not os.path.isdir(p):
            continue
        elif (sid, name) in live:
            keep = True
        elif not _claim_orphan(sweep, writer_lock_path(root, sid, name), p):
            keep = True  # its writer is alive
    return keep


def _claim_orphan(sweep: _Sweep, lock_path: str, path: str) -> bool:
    """Doom an unreferenced generation unless its writer is alive (then False)."""
    # The writer lock exists before the generation directory is created and
    # stays held until the writer is done: check it *after* seeing the directory.
    if os.path.exists(lock_path):
        lk = try_lock(lock_path)
        if lk is None:
            return False
        sweep.held.append(lk)
        sweep.doomed.append(lock_path)
    sweep.doomed.append(path)
    return True


def _sweep_writers(sweep: _Sweep, writers: str) -> None:
    """Doom the writer locks (and temporary lock files) no live writer holds."""
    for name in sorted(os.listdir(writers)) if os.path.isdir(writers) else []:
        p = os.path.join(writers, name)
        if p in sweep.doomed or not (is_lock_temp(name) or name.endswith(".lock")):
            continue
        lk = try_lock(p)  # free: its writer is dead or done
        if lk is not None:
            sweep.held.append(lk)
            sweep.doomed.append(p)


def _remove_paths(root, paths) -> list[str]:
    """Delete files and directory trees; the ones removed, relative to ``root``."""
    removed = []
    for p in paths:
        if os.path.isdir(p):
            shutil.rmtree(p, ignore_errors=True)
        else:
            try:
                os.remove(p)
            except OSError:
                continue
        removed.append(os.path.relpath(p, root))
    return removed


# -- validation -----------------------------------------------------------------------
def list_orphans(root, index) -> list[str]:
    """Unreferenced generation directories and index temporary files, relative paths.

    Parameters
    ----------
    root : str
        The store directory.
    index : dict
        The index document.

    Returns
    -------
    list of str
        Paths relative to ``root``, by subject id.
    """
    live = _live(index)
    out = []
    for sid, sdir in _subject_dirs(root):
        for name in sorted(os.listdir(sdir)):
            if os.path.isdir(os.path.join(sdir, name)) and (sid, name) not in live:
                out.append(f"{SUBJECTS}/{sid}/{name}")
    out += [n for n in os.listdir(root) if is_index_temp(n)]
    return out


def orphan_note(orphans) -> str:
    """The report note about unreferenced items (``orphans`` from :func:`list_orphans`, not empty)."""
    return (
        f"{len(orphans)} unreferenced item(s) left by interrupted or running writers "
        f"(e.g. {orphans[0]}); `facestats validate --repair` removes dead ones"
    )


def _rows_differ(a: dict, b: dict) -> list[str]:
    """Keys whose values differ between two index rows (None and NaN are equal)."""

    def norm(v):
        if v is None or (isinstance(v, float) and v != v):
            return None
        return v

    return sorted(k for k in set(a) | set(b) if norm(a.get(k)) != norm(b.get(k)))


def check_subjects(index, open_generation, report: ValidationReport):
    """Open every indexed subject and compare its index entry with its data.

    Parameters
    ----------
    index : dict
        The index document.
    open_generation : callable
        ``open_generation(sid, gen)``: the checked subject
        (:func:`facestats.io.integrity.open_generation`).
    report : ValidationReport
        Problems are appended; ``n_checked`` counts the subjects opened.

    Returns
    -------
    drop : dict
        ``{sid: generation}`` of the subjects whose data are broken.
    fix : dict
        ``{sid: (generation, new index entry)}`` of the entries that disagree with the data.
    """
    drop, fix = {}, {}
    for sid in sorted(index["subjects"]):
        entry = index["subjects"][sid]
        gen = entry["generation"]
        try:
            ds = open_generation(sid, gen)
        except StoreError as exc:
            report.problems.append(str(exc))
            drop[sid] = gen
            continue
        report.n_checked += 1
        problem = _entry_problem(sid, entry, gen, ds)
        if problem:
            report.problems.append(problem[0])
            fix[sid] = (gen, problem[1])
    return drop, fix


def _entry_problem(sid: str, entry: dict, gen: str, ds):
    """``(message, recomputed entry)`` if the index entry disagrees with the subject ``ds``, else None."""
    row, hist = summarise_subject(ds), albedo_histogram(ds)
    diff = _rows_differ(make_entry(gen, "", row, hist)["row"], entry["row"])
    if diff:
        message = f"subject {sid!r}: index row disagrees with the data in {diff[:5]}" + (
            f" and {len(diff) - 5} more" if len(diff) > 5 else ""
        )
    elif np.asarray(entry["albedo_hist"]).tolist() != hist.tolist():
        message = f"subject {sid!r}: index albedo histogram disagrees with the data"
    else:
        return None
    return message, make_entry(gen, entry.get("written", ""), row, hist)


def index_repairs(drop: dict, fix: dict, report: ValidationReport):
    """The index mutation applying the repairs of :func:`check_subjects` (committed by the store).

    Entries are changed only if the index still names the generation that
    was checked; each change is appended to ``report.repaired``.

    Parameters
    ----------
    drop, fix : dict
        From :func:`check_subjects`.
    report : ValidationReport

    Returns
    -------
    callable
        ``mutate(index)``, changing the index document in place.
    """

    def mutate(ix):
        for sid, gen in drop.items():
            if ix["subjects"].get(sid, {}).get("generation") == gen:
                del ix["subjects"][sid]
                report.repaired.append(f"removed broken subject {sid!r} from the index")
        for sid, (gen, entry) in fix.items():
            if ix["subjects"].get(sid, {}).get("generation") == gen:
                ix["subjects"][sid] = entry
                report.repaired.append(f"recomputed the index entry of subject {sid!r}")

    return mutate


def rebuild_index(root, open_generation) -> tuple[dict, list[str]]:
    """A new index from the newest intact generation of every subject directory.

    Generations whose writer is still running are skipped, and so are those
    ``open_generation(sid, gen)`` refuses (:class:`StoreError`).

    Returns
    -------
    index : dict
    notes : list of str
        One line per subject recovered.
    """
    index = empty_index(SCHEMA_VERSION, __version__)
    notes = []
    for sid, sdir in _subject_dirs(root):
        gens = sorted((n for n in os.listdir(sdir) if GENERATION_PATTERN.match(n)), reverse=True)
        for gen in gens:
            if is_locked(writer_lock_path(root, sid, gen)):
                continue  # its writer is still running
            try:
                ds = open_generation(sid, gen)
            except StoreError:
                continue
            when = ds.encoding[STORE_ATTR].get("written", "")
            index["subjects"][sid] = make_entry(gen, when, summarise_subject(ds), albedo_histogram(ds))
            notes.append(f"recovered subject {sid!r} from generation {gen}")
            break
    return index, notes
