"""Upkeep of a directory store: one survey of its files, garbage collection, and the check of every subject.

:func:`survey` is maintenance's single view of a directory store: it walks the
layout (:mod:`facestats.io.layout`) without following links and sorts every
entry into

* **garbage** — provably the store's own and of no use: generations whose
  record (``.records/``, :mod:`facestats.io.records`) says they were never
  committed or were retired, once their writer is dead; trash folders and
  records of such generations; temporary files of interrupted atomic writes
  (``index.json``, ``zarr.json`` and records, also under ``subjects/``);
  writer locks no live writer holds;
* **kept** — the generations the index names, those whose writer is alive,
  and committed generations the index does not name (``adoptable`` when their
  subject is not in the index: ``facestats validate --repair`` recovers them;
  never deleted);
* **foreign** — anything the store did not provably create: symbolic links
  (e.g. ``subjects/X1 -> /elsewhere``, or ``subjects/X -> R2``: a link never
  makes another subject's generations look like its own), files and folders of
  other names, generations without a record (written before records existed).
  They are reported and never touched; so are items Zarr did not write found
  inside a generation folder (*strays*), and the generation holding them is
  kept;
* **damaged records** — the store's own records with a malformed field (a
  revision that is not an integer, an unknown state): a problem for
  ``facestats validate``; the generation and the record are kept (repair
  rewrites the record of a generation the index names and moves the others to
  the quarantine).

:func:`collect_garbage` deletes exactly the survey's garbage (decided, and the
doomed generations renamed aside, under the store lock), and ``facestats
validate`` reports exactly it, so the two always agree.  :func:`check_subjects`
opens every indexed subject and sorts the failures: *damaged* data
(:class:`~facestats.errors.SchemaError`), a *missing* generation, an index row
that disagrees with the data, or data that could not be read just now (an I/O
error: no action may follow from it).  A subject
replaced by a concurrent writer while it is checked is checked again in its
new version.  What repair does with these findings is :mod:`facestats.io.repair`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from facestats.core.progress import progress_bar
from facestats.errors import SchemaError, StoreError, ValidationError
from facestats.io.ids import check_subject_id
from facestats.io.index import INDEX_NAME, is_index_temp, make_entry, read_index_file
from facestats.io.layout import (
    BUILD_JOURNAL,
    LOCK_NAME,
    QUARANTINE,
    RECORDS,
    ROOT_META,
    SUBJECTS,
    TRASH_PREFIX,
    WRITERS,
    confined,
    generation_rel,
    generation_strays,
    is_generation,
    is_meta_temp,
    is_plain_dir,
    is_plain_file,
    remove_tree,
    sorted_names,
    writer_lock_path,
)
from facestats.io.locking import is_lock_temp, is_locked, try_lock
from facestats.io.quarantine import list_quarantine
from facestats.io.records import inspect_record, parse_record_name, read_record, record_name
from facestats.io.summary import albedo_histogram, summarise_subject

__all__ = [
    "ValidationReport",
    "Survey",
    "Checked",
    "survey",
    "collect_garbage",
    "check_subjects",
    "directory_notes",
]

_ROOT_NAMES = {ROOT_META, "index.json", LOCK_NAME, WRITERS, RECORDS, SUBJECTS, QUARANTINE, BUILD_JOURNAL}


@dataclass
class ValidationReport:
    """Outcome of :meth:`facestats.io.store.Store.validate`.

    Attributes
    ----------
    path : str
        The store, as its label names it.
    n_subjects : int
        Subjects the index lists (0 if the index cannot be read).
    n_checked : int
        Subjects opened and checked without error.
    problems : list of str
        Findings that make the store invalid (``ok`` is False).
    notes : list of str
        Harmless findings (leftovers of interrupted writes, items that are not the store's, the quarantine).
    repaired : list of str
        What a repair changed.
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
        """The report as the lines ``facestats validate`` prints."""
        lines = [f"store: {self.path}", f"subjects checked: {self.n_checked} of {self.n_subjects}"]
        lines += [f"problem: {p}" for p in self.problems]
        lines += [f"note: {n}" for n in self.notes]
        lines += [f"repaired: {r}" for r in self.repaired]
        lines.append("store is valid" if self.ok else f"store is INVALID ({len(self.problems)} problem(s))")
        return "\n".join(lines) + "\n"


# -- the survey --------------------------------------------------------------------------
@dataclass
class Survey:
    """What is in a directory store, sorted against an index (module docstring).

    Attributes
    ----------
    garbage : list of str
        Paths (relative to the root) :func:`collect_garbage` deletes.
    stale_locks : list of str
        The writer locks among ``garbage`` (to be held while they are deleted).
    adoptable : dict
        ``{subject id: [(revision, generation)]}``: committed, unretired generations of subjects the
        index does not list (newest first).
    newer : list of str
        Committed generations kept although the index names another: committed after the index
        revision (an index restored from an old copy?), or of a subject whose current generation is
        missing (what repair may recover).
    foreign : list of str
        Entries the store did not create: reported, never touched.
    subject_dirs : list of str
        Ids of the real subject folders.
    empty_subjects : list of str
        Subject folders (not in the index) that hold nothing of value once the garbage is gone.
    records : list of tuple
        ``(sid, generation)`` of the record files in ``.records/`` (valid ids), whatever their state.
    bad_records : list of tuple
        ``(sid, generation, message, live)`` of the store's own records with a malformed field (an unknown
        state, a revision that is not an integer): damage, reported as a problem; the generation and
        its record are kept (repair rewrites the record of a generation the index names and moves the
        others to the quarantine).
    strays : list of str
        Files and folders inside generation folders that Zarr did not write (e.g.
        ``subjects/R1/<generation>/notes.txt``): reported, never deleted, and the generation holding
        them is kept (of the generations the index names only when asked: :func:`survey`).
    kept_trash : set of (str, str)
        ``(subject id, generation)`` of trash folders kept (with their records) because they hold strays.
    """

    garbage: list = field(default_factory=list)
    stale_locks: list = field(default_factory=list)
    adoptable: dict = field(default_factory=dict)
    newer: list = field(default_factory=list)
    foreign: list = field(default_factory=list)
    subject_dirs: list = field(default_factory=list)
    empty_subjects: list = field(default_factory=list)
    records: list = field(default_factory=list)
    bad_records: list = field(default_factory=list)
    strays: list = field(default_factory=list)
    kept_trash: set = field(default_factory=set, repr=False)  # (sid, gen) of trash folders kept for their strays

    @property
    def leftovers(self) -> list[str]:
        """What :func:`collect_garbage` removes: the garbage, then the folders of subjects left empty by it.

        ``facestats validate`` counts these and the repair plan lists them, so both say the same number (the
        validation counted the garbage alone: "3 leftover item(s)" for a plan removing 4, the fourth the folder of
        the subject whose interrupted write was the three).
        """
        return self.garbage + [f"{SUBJECTS}/{sid}" for sid in self.empty_subjects]

    def problems(self) -> list[str]:
        """The report problems of this survey: the store's own records that are malformed."""
        return [
            f"{message}; `facestats validate --repair --yes` "
            + ("rewrites it from the index" if live else "moves it, with its generation, to the quarantine")
            for _, _, message, live in self.bad_records
        ]

    def notes(self) -> list[str]:
        """The report notes of this survey (none if there is nothing to say)."""
        out = []
        leftovers = self.leftovers
        if leftovers:
            out.append(
                f"{len(leftovers)} leftover item(s) of interrupted writes (e.g. {leftovers[0]}); "
                "`facestats validate --repair --yes` removes them"
            )
        if self.adoptable:
            ids = sorted(self.adoptable)
            out.append(
                f"{len(ids)} subject(s) with committed data are missing from the index ({', '.join(ids[:5])}); "
                "`facestats validate --repair` recovers them"
            )
        if self.newer:
            out.append(
                f"{len(self.newer)} committed generation(s) the index does not name were kept for repair to judge "
                f"(e.g. {self.newer[0]})"
            )
        if self.foreign:
            out.append(f"{len(self.foreign)} item(s) not created by facestats were left alone (e.g. {self.foreign[0]})")
        if self.strays:
            out.append(
                f"{len(self.strays)} item(s) inside generation folders were not written by facestats "
                f"(e.g. {self.strays[0]}); they were left alone, and a generation holding such items is never "
                "deleted: move them out, and `facestats validate --repair --yes` removes what is leftover"
            )
        return out


def survey(root, index: dict, *, live_strays: bool = False, absent=frozenset()) -> Survey:
    """Walk the store at ``root`` (no link followed) and sort its entries against ``index`` (module docstring).

    Parameters
    ----------
    root : str
        The store directory.
    index : dict
        A valid index document (:func:`facestats.io.index.parse_index`).
    live_strays : bool
        Also look for items Zarr did not write inside the generations the index names
        (:attr:`Survey.strays`; ``facestats validate`` does, garbage collection needs not).
    absent : set of (str, str)
        ``(subject, generation)`` pairs to survey as if gone, folder and record (a repair's plan surveys the
        store as its moves to the quarantine will leave it).

    Returns
    -------
    Survey
        The store's entries, sorted out.
    """
    s = Survey()
    for name in sorted_names(root):
        if is_index_temp(name) or is_meta_temp(name):
            (s.garbage if is_plain_file(os.path.join(root, name)) else s.foreign).append(name)
        elif name not in _ROOT_NAMES:
            s.foreign.append(name)
    _survey_writers(s, root)
    recorded = _survey_records(s, root)
    s.records = sorted(recorded)
    pairs = recorded | _survey_subjects(s, root)
    kept = set()
    for sid, gen in sorted(pairs - set(absent)):
        if _survey_generation(s, root, sid, gen, index):
            kept.add(sid)
    if live_strays:
        for sid, entry in sorted(index["subjects"].items()):
            rel = generation_rel(sid, entry["generation"])
            if sid in s.subject_dirs and is_plain_dir(os.path.join(root, rel)):
                s.strays += [f"{rel}/{x}" for x in generation_strays(os.path.join(root, rel))]
    s.empty_subjects = [
        sid for sid in s.subject_dirs if sid not in kept and sid not in index["subjects"] and sid not in s.adoptable
    ]
    return s


def _survey_subjects(s: Survey, root) -> set:
    """Sort the entries of ``subjects/``; the ``(sid, gen)`` of the generation folders found."""
    sub_root = os.path.join(root, SUBJECTS)
    pairs = set()
    for name in sorted_names(sub_root) if is_plain_dir(sub_root) else []:
        path = os.path.join(sub_root, name)
        if name == ROOT_META:
            continue
        if is_meta_temp(name) and is_plain_file(path):
            s.garbage.append(f"{SUBJECTS}/{name}")
        elif _valid_id(name) and is_plain_dir(path):
            s.subject_dirs.append(name)
            pairs |= _survey_subject(s, root, name)
        else:
            s.foreign.append(f"{SUBJECTS}/{name}")
    return pairs


def _valid_id(name: str) -> bool:
    try:
        check_subject_id(name)
    except ValidationError:
        return False
    return True


def _survey_writers(s: Survey, root) -> None:
    """Writer locks no live writer holds (and temporary lock files) are garbage; other entries foreign."""
    writers = os.path.join(root, WRITERS)
    for name in sorted_names(writers) if is_plain_dir(writers) else []:
        path = os.path.join(writers, name)
        sid, _, rest = name.partition("~")
        ours = is_lock_temp(name) or (rest.endswith(".lock") and _valid_id(sid) and is_generation(rest[:-5]))
        if not ours or not is_plain_file(path):
            s.foreign.append(f"{WRITERS}/{name}")
        elif not is_locked(path):
            s.garbage.append(f"{WRITERS}/{name}")
            s.stale_locks.append(f"{WRITERS}/{name}")


def _survey_records(s: Survey, root) -> set:
    """``(sid, gen)`` of the record files; temporary files are garbage, other entries foreign."""
    folder = os.path.join(root, RECORDS)
    pairs = set()
    for name in sorted_names(folder) if is_plain_dir(folder) else []:
        path = os.path.join(folder, name)
        parsed = parse_record_name(name)
        if is_meta_temp(name) and is_plain_file(path):
            s.garbage.append(f"{RECORDS}/{name}")
        elif parsed is not None and _valid_id(parsed[0]):
            pairs.add(parsed)
        else:
            s.foreign.append(f"{RECORDS}/{name}")
    return pairs


def _survey_subject(s: Survey, root, sid: str) -> set:
    """Sort the entries of one subject folder; the ``(sid, gen)`` of its generation folders."""
    sdir = os.path.join(root, SUBJECTS, sid)
    pairs = set()
    for name in sorted_names(sdir):
        path = os.path.join(sdir, name)
        rel = f"{SUBJECTS}/{sid}/{name}"
        trash = name.startswith(TRASH_PREFIX) and is_generation(name[len(TRASH_PREFIX) :])
        if name == ROOT_META:
            continue
        if is_generation(name):
            pairs.add((sid, name))
        elif is_meta_temp(name) and is_plain_file(path):
            s.garbage.append(rel)
        elif trash and is_plain_dir(path) and read_record(root, sid, name[len(TRASH_PREFIX) :]) is not None:
            gen = name[len(TRASH_PREFIX) :]
            strays = generation_strays(path)
            s.strays += [f"{rel}/{x}" for x in strays]
            if strays:
                s.kept_trash.add((sid, gen))  # and its record with it
            else:
                s.garbage.append(rel)
            pairs.add((sid, gen))
        else:
            s.foreign.append(rel)
    return pairs


def _survey_generation(s: Survey, root, sid: str, gen: str, index: dict) -> bool:
    """Sort one generation (its folder and/or record); True if something of it is kept.

    A generation counts as present only in a real subject folder (``subjects/X -> R2``, a link planted
    in the store, never makes ``R2``'s generations look like ``X``'s); one holding items Zarr did not
    write is kept (:attr:`Survey.strays`), as is one whose record is malformed (:attr:`Survey.bad_records`).
    """
    rel = generation_rel(sid, gen)
    rec_rel = f"{RECORDS}/{record_name(sid, gen)}"
    path = os.path.join(root, rel)
    has_dir = is_plain_dir(os.path.join(root, SUBJECTS, sid)) and is_plain_dir(path)
    live = index["subjects"].get(sid, {}).get("generation")
    if os.path.lexists(path) and not has_dir:
        s.foreign.append(rel)
        return True
    rec, problem = inspect_record(root, sid, gen)
    if problem is not None:
        s.bad_records.append((sid, gen, problem, gen == live))
        return True
    if gen == live or is_locked(writer_lock_path(root, sid, gen)) or (sid, gen) in s.kept_trash:
        return True
    if rec is None:  # no record: not provably ours (or written before records existed)
        for item in (rel, rec_rel):
            if os.path.lexists(os.path.join(root, item)):
                s.foreign.append(item)
        return True
    if has_dir and _keep_committed(s, root, sid, gen, rec, live, index):
        return True
    if has_dir:
        strays = generation_strays(path)
        if strays:  # never deleted with what someone put there
            s.strays += [f"{rel}/{x}" for x in strays]
            return True
        s.garbage.append(rel)
    s.garbage.append(rec_rel)
    return False


def _keep_committed(s: Survey, root, sid: str, gen: str, rec: dict, live, index: dict) -> bool:
    """True (and noted) for a committed generation the index does not name but that must be kept."""
    rel = generation_rel(sid, gen)
    if rec["state"] != "writing" and _live_missing(root, sid, live):
        s.newer.append(rel)  # the generation the index names is missing: this one may be what repair recovers
        return True
    if rec["state"] != "committed":
        return False
    rev = int(rec.get("committed_revision", 0))
    if live is None:
        s.adoptable.setdefault(sid, []).append((rev, gen))
        s.adoptable[sid].sort(reverse=True)
        return True
    if rev > int(index.get("revision", 0)):
        s.newer.append(rel)
        return True
    return False


def _live_missing(root, sid: str, live) -> bool:
    """True if the index names a generation of ``sid`` whose folder is missing."""
    return live is not None and not is_plain_dir(os.path.join(root, generation_rel(sid, live)))


# -- garbage collection ---------------------------------------------------------------------
def collect_garbage(root, lock) -> list[str]:
    """Delete the survey's garbage (module docstring); the paths removed, relative to ``root``.

    Decisions are taken holding the store ``lock`` (not yet held), so no commit
    can name a generation being removed, and, under the same hold, every
    generation to delete is renamed aside to ``subjects/<id>/.trash-<generation>``
    (a rename: the lock stays short, whatever the size of the data).  A trash
    folder is never a generation, so no commit or repair taken after the lock
    is released can name it again: a repair that planned to recover a subject
    from such a generation finds it gone and skips that step, instead of
    committing an index that names data about to be deleted.  The trees are
    removed after the lock is released.  Stale writer locks are held while they
    are deleted.  Every path is checked to stay inside the store without
    passing through a link (:func:`facestats.io.layout.confined`) before it is
    renamed or removed; directory trees are removed without following links,
    and never while they hold items Zarr did not write.

    Parameters
    ----------
    root : str
        The store directory.
    lock : facestats.io.locking.FileLock
        The store lock (:func:`facestats.io.layout.store_lock`), acquired and released here.

    Returns
    -------
    list of str
        The paths removed, relative to ``root``.

    Raises
    ------
    StoreError
        The index cannot be read (garbage is judged against it: repair first).
    """
    held = []
    with lock:
        index = read_index_file(root)
        s = survey(root, index)
        for rel in s.stale_locks:
            try:
                lk = try_lock(os.path.join(root, rel), create=False)
            except FileNotFoundError:  # removed by its writer since the survey: nothing left to collect
                s.garbage.remove(rel)
                continue
            if lk is None:  # taken again meanwhile (cannot happen for a dead writer's name): keep it
                s.garbage.remove(rel)
            else:
                held.append(lk)
        trashed = _trash_generations(root, s.garbage)
    try:
        removed = _remove(root, s.garbage, trashed)
    finally:
        for lk in held:
            lk.release()
    for sid in s.empty_subjects:
        removed += _remove_empty_subject(root, sid)
    return removed


def _generation_of(rel: str):
    """``(sid, generation)`` if ``rel`` is a generation folder ``subjects/<id>/<generation>``, else None."""
    parts = rel.split("/")
    if len(parts) == 3 and parts[0] == SUBJECTS and is_generation(parts[2]):
        return parts[1], parts[2]
    return None


def _trash_generations(root, rels) -> dict:
    """Rename the generation folders among ``rels`` to their trash names (the caller holds the store lock).

    Returns ``{rel: trash path}`` of those renamed; a generation that cannot be renamed (gone meanwhile,
    its trash name taken, a link on the way) is not deleted this time.
    """
    out = {}
    for rel in rels:
        pair = _generation_of(rel)
        if pair is None:
            continue
        src = os.path.join(root, rel)
        dst = os.path.join(root, SUBJECTS, pair[0], TRASH_PREFIX + pair[1])
        try:
            confined(root, src)
            if not is_plain_dir(src) or os.path.lexists(confined(root, dst)):
                continue
            os.rename(src, dst)
        except (OSError, StoreError):
            continue
        out[rel] = dst
    return out


def _remove(root, rels, trashed=None) -> list[str]:
    """Delete files and folder trees (the generation folders before any record); those removed.

    Generation folders are removed from their trash names (``trashed``, :func:`_trash_generations`);
    one that was not renamed aside is left for the next collection.  A record is removed only once its
    generation folder and trash folder are both gone, so a leftover never loses the record that proves
    it is the store's own (another process may be deleting the same leftover at the same time).  A
    folder tree that holds items Zarr did not write is left alone.
    """
    trashed = trashed or {}
    removed = []
    for rel in sorted(rels, key=lambda p: (p.startswith(RECORDS + "/"), p)):
        if _generation_of(rel) is not None and rel not in trashed:
            continue
        path = trashed.get(rel, os.path.join(root, rel))
        try:
            confined(root, path)
            pair = parse_record_name(os.path.basename(rel)) if rel.startswith(RECORDS + "/") else None
            if pair is not None:
                sid, gen = pair
                folder = os.path.join(root, SUBJECTS, sid)
                if os.path.lexists(os.path.join(folder, gen)) or os.path.lexists(
                    os.path.join(folder, TRASH_PREFIX + gen)
                ):
                    continue
            if is_plain_dir(path):
                if generation_strays(path):  # put there since the survey: never deleted with the tree
                    continue
                remove_tree(path)
            else:
                os.remove(path)
        except (OSError, StoreError):
            continue
        removed.append(rel)
    return removed


def _remove_empty_subject(root, sid: str) -> list[str]:
    """Remove a subject folder that holds only its group metadata (fails harmlessly if a writer started)."""
    sdir = os.path.join(root, SUBJECTS, sid)
    try:
        confined(root, sdir)
        if set(os.listdir(sdir)) - {ROOT_META}:
            return []
        meta = os.path.join(sdir, ROOT_META)
        if is_plain_file(meta):
            os.remove(meta)
        os.rmdir(sdir)
    except (OSError, StoreError):
        return []
    return [f"{SUBJECTS}/{sid}"]


# -- checking the subjects -------------------------------------------------------------------
@dataclass
class Checked:
    """What :func:`check_subjects` found, per subject id.

    Attributes
    ----------
    damaged : dict
        ``{sid: (generation, message)}``: the generation exists but its data are damaged.
    missing : dict
        ``{sid: (generation, message)}``: the generation the index names is not there.
    stale : dict
        ``{sid: (generation, recomputed entry, message)}``: the index entry disagrees with the data.
    unreadable : dict
        ``{sid: message}``: an I/O error; the data may be intact, nothing may be done about it.
    current : dict
        ``{sid: generation}`` checked (after following concurrent replacements).
    """

    damaged: dict = field(default_factory=dict)
    missing: dict = field(default_factory=dict)
    stale: dict = field(default_factory=dict)
    unreadable: dict = field(default_factory=dict)
    current: dict = field(default_factory=dict)


def check_subjects(
    index, open_generation, report: ValidationReport, *, reread=None, generation_exists=None, progress=False
) -> Checked:
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
    reread : callable, optional
        ``reread()``: the current index entries; a subject that fails is looked
        up again and, if a concurrent writer replaced it, checked in its new
        version.
    generation_exists : callable, optional
        ``generation_exists(sid, gen)``: tells a missing generation from a damaged one.
    progress : bool
        Show a progress bar (:mod:`facestats.core.progress`).

    Returns
    -------
    Checked
    """
    out = Checked()
    ids = sorted(index["subjects"])
    ids = progress_bar(ids, desc="check", unit="subject", enabled=progress)
    for sid in ids:
        entry = index["subjects"][sid]
        for _ in range(5):
            gen = entry["generation"]
            try:
                # never bound here: the subject (and the face texels a validation gathered for its index row,
                # GATHERED_TEXELS) is not held while the next one is opened
                problem = entry_disagreement(sid, entry, gen, open_generation(sid, gen))  # may read maps on disk
            except StoreError as exc:  # SchemaError: damaged; else an I/O error (the data may be intact)
                fresh = reread().get(sid) if reread is not None else None
                if fresh is not None and fresh["generation"] != gen:
                    entry = fresh  # replaced meanwhile: check the new version
                    continue
                if isinstance(exc, SchemaError):
                    gone = generation_exists is not None and not generation_exists(sid, gen)
                    (out.missing if gone else out.damaged)[sid] = (gen, str(exc))
                else:
                    out.unreadable[sid] = str(exc)
                report.problems.append(str(exc))
            else:
                out.current[sid] = gen
                report.n_checked += 1
                if problem:
                    report.problems.append(problem[0])
                    out.stale[sid] = (gen, problem[1], problem[0])
            break
    return out


#: Relative tolerance of float values when an index row is compared with the one recomputed from the data: the
#: row was computed by the version that wrote it, and a later version may sum in another order or scale against
#: overflow (the last bits differ); a value changed by more than this is a disagreement.
ROW_RTOL = 1e-9


def _rows_differ(a: dict, b: dict) -> list[str]:
    """Keys whose values differ between two index rows (None and NaN are equal; floats within :data:`ROW_RTOL`)."""

    def norm(v):
        if v is None or (isinstance(v, float) and v != v):
            return None
        return v

    def same(x, y):
        x, y = norm(x), norm(y)
        if isinstance(x, float) and isinstance(y, float):
            return math.isclose(x, y, rel_tol=ROW_RTOL, abs_tol=0.0)
        return x == y

    return sorted(k for k in set(a) | set(b) if not same(a.get(k), b.get(k)))


def entry_disagreement(sid: str, entry: dict, gen: str, ds):
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


def directory_notes(root, label: str, index) -> tuple[list[str], list[str]]:
    """``(problems, notes)`` of a directory store beyond its subjects: ``subjects/`` missing, survey, quarantine.

    Parameters
    ----------
    root : str
        The store directory.
    label : str
        The store's name in messages.
    index : dict or None
        The index document (None if it cannot be read: no survey then).

    Returns
    -------
    problems, notes : list of str
        What makes the store invalid, and what is only worth knowing.
    """
    problems, notes = [], []
    if not os.path.lexists(os.path.join(root, SUBJECTS)):
        problems.append(
            f"store {label}: its subjects/ folder is missing (an unmounted volume?); no subject can be read"
        )
    for name, plain, kind in ((INDEX_NAME, is_plain_file, "a regular file"), (SUBJECTS, is_plain_dir, "a folder")):
        path = os.path.join(root, name)
        if os.path.lexists(path) and not plain(path):  # read through, but writes and repairs refuse it
            problems.append(
                f"store {label}: {name} must be {kind} of the store, but it is a symbolic link, FIFO or device; "
                "facestats reads through it but refuses to write or repair there: replace it by what it points to"
            )
    if index is not None:
        s = survey(root, index, live_strays=True)
        problems += s.problems()
        notes += s.notes()
        linked = [sid for sid in index["subjects"] if os.path.islink(os.path.join(root, SUBJECTS, sid))]
        if linked:  # read through, but repair and writes refuse them
            problems.append(
                f"store {label}: {SUBJECTS}/{linked[0]} is a symbolic link ({len(linked)} indexed subject folder(s) "
                "are); facestats reads through it but refuses to write or repair there: replace it by its folder"
            )
    q = list_quarantine(root)
    problems += [
        f"store {label}: quarantine/{e['name']}/QUARANTINE.json {e['problem']}; that folder is never purged: fix "
        "the file or remove the folder yourself"
        for e in q
        if e.get("problem")
    ]
    if q:
        n, size = sum(len(e["items"]) for e in q), sum(e["bytes"] for e in q)
        notes.append(
            f"quarantine: {len(q)} folder(s), {n} item(s), {size / 1e6:.1f} MB moved aside by repairs "
            f"({', '.join(e['name'] for e in q[:3])}); `facestats validate --purge --yes` deletes them"
        )
    return problems, notes
