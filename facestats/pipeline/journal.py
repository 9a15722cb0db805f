"""The journal of a population build: which subjects are done, running or failed (``facestats build --status``).

A build (:func:`facestats.pipeline.build.build_store`,
:func:`facestats.pipeline.population.fit_population` with a store) records
every subject it works on in ``<store>/.build/<subject>.json``::

    {"subject_id": "S001", "state": "running" | "failed",
     "attempts": 2, "host": "node7", "pid": 1234,
     "started": "2026-...", "updated": "2026-...", "error": "ValueError: ..." | null}

Each record is replaced atomically (temporary file, ``os.replace``) by the
process working on the subject, so a reader sees the previous state or the
next; the record is removed when the subject is committed to the store (or,
when a build was killed between the commit and the removal, by the next build,
which finds the subject stored and skips it).
*Done* is not journalled: it is being in the store's index, the store's own
commit point.  A subject is retried up to ``retries`` times in its task; if it
still fails its record stays ``failed``, with the last error, until a later
build writes it.  A ``running`` record whose process no longer exists on this
host is reported as *interrupted* (its host and pid say where it ran).

A build also records what it was asked for, in its own plan file
``<store>/.build/.plan-<host>-<pid>-<random>.json``
(``{"subjects": [...], "host", "pid", "started"}``), written before any
subject starts and removed by that build when it returns (with or without
failures).  A plan that is still there names a build that is running or that
stopped before its end (killed, interrupted): ``--status`` then counts the
requested subjects that were not started, which a killed build would otherwise
hide (a store with no subject looked like a finished build of none).  Builds
that share a store each keep their own plan (one shared file was replaced by
the next build's and removed by whichever returned first, which hid a killed
build: a red team).

The journal lives in the store directory, so every worker of a cluster that
shares the store (a POSIX file system) writes to the same one; it is advisory
bookkeeping, never read to decide what to build (that is the store's index),
and :meth:`facestats.io.store.Store.gc` leaves it alone.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import os
import secrets
import socket
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from facestats.core.conventions import EDIT_SOURCE
from facestats.core.processes import process_gone
from facestats.core.validate import check_integer
from facestats.io.ids import check_subject_id
from facestats.io.layout import BUILD_JOURNAL, read_regular_file
from facestats.io.store import open_store
from facestats.pipeline.cluster import store_directory

__all__ = [
    "JOURNAL_DIR",
    "PLAN",
    "LEGACY_PLAN",
    "BuildJournal",
    "BuildStatus",
    "build_status",
    "gathered",
    "run_journalled",
]

#: Folder of the journal inside a directory store.
JOURNAL_DIR = BUILD_JOURNAL
#: Name pattern of the builds' plan files in the journal (not subject ids, so never a subject's record).
PLAN = ".plan-*.json"
#: The one plan file of facestats before 2026-12-06 (read, and removed like the others).
LEGACY_PLAN = ".plan.json"


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


class BuildJournal:
    """The per-subject records of builds into the directory store at ``store_path`` (module docstring).

    Parameters
    ----------
    store_path : str or os.PathLike
        The directory store; the journal is its folder :data:`JOURNAL_DIR` (created at the first write).
    """

    def __init__(self, store_path):
        self.root = Path(store_path) / JOURNAL_DIR
        self._plan = None  # this journal's own plan file, once begun

    def _path(self, sid: str) -> Path:
        return self.root / f"{check_subject_id(sid)}.json"  # an id is a file name: never a path out of the store

    def _write(self, sid: str, record: dict) -> None:
        self._write_file(self._path(sid), record)

    def _write_file(self, target: Path, record: dict) -> None:
        self.root.mkdir(parents=True, exist_ok=True)
        tmp = self.root / f".{target.name}.tmp-{os.getpid()}-{secrets.token_hex(3)}"
        try:
            tmp.write_text(json.dumps(record, sort_keys=True))
            os.replace(tmp, target)
        except BaseException:  # a full disk: no half-written temporary is left in the journal
            tmp.unlink(missing_ok=True)
            raise

    def read(self, sid: str) -> dict | None:
        """The record of ``sid``, or None (also for a file that is not a record: damaged, or not JSON).

        Parameters
        ----------
        sid : str
            The subject id (one that is not a valid id gives None too).

        Returns
        -------
        dict or None
            The record (module docstring), whose ``state`` is ``"running"`` or ``"failed"``.
        """
        try:
            rec = json.loads(read_regular_file(self._path(sid), follow_links=False))
        except (OSError, ValueError, RecursionError):  # missing, not a regular file (a FIFO, a link), not JSON
            return None
        return rec if isinstance(rec, dict) and rec.get("state") in ("running", "failed") else None

    def written_at(self, sid: str) -> float | None:
        """When the record of ``sid`` was last written (the file's modification time, s since the epoch), or None.

        Parameters
        ----------
        sid : str
            The subject id.

        Returns
        -------
        float or None
            None if there is no record.

        Raises
        ------
        ValidationError
            ``sid`` is not a valid subject id.
        """
        try:
            return self._path(sid).stat().st_mtime
        except FileNotFoundError:
            return None

    def records(self) -> dict:
        """Every record, by subject id (files whose names are not subject ids are left out)."""
        if not self.root.is_dir():
            return {}
        out = {}
        for p in sorted(self.root.glob("*.json")):
            rec = self.read(p.stem)  # None for a name that is not a subject id (the plans) and for a damaged record
            if rec is not None:
                out[p.stem] = rec
        return out

    def start(self, sid: str, attempt: int) -> None:
        """``sid`` is being worked on (attempt ``attempt``, from 1).

        Parameters
        ----------
        sid : str
            The subject id.
        attempt : int
            The attempt's number, from 1; later attempts keep the first one's ``started`` time and the last error.

        Raises
        ------
        ValidationError
            ``sid`` is not a valid subject id.
        """
        prev = self.read(sid) or {}
        self._write(
            sid,
            {
                "subject_id": sid,
                "state": "running",
                "attempts": int(attempt),
                "host": socket.gethostname(),
                "pid": os.getpid(),
                "started": _now() if attempt == 1 else prev.get("started", _now()),
                "updated": _now(),
                "error": prev.get("error") if attempt > 1 else None,
            },
        )

    def fail(self, sid: str, attempt: int, exc: BaseException) -> None:
        """Attempt ``attempt`` of ``sid`` raised ``exc``.

        Parameters
        ----------
        sid : str
            The subject id.
        attempt : int
            The attempt's number, from 1.
        exc : BaseException
            What it raised; the record's ``error`` is its type and message as :func:`traceback.format_exception_only`
            writes them, followed by its notes (``add_note``) in parentheses, whitespace collapsed to one line.

        Raises
        ------
        ValidationError
            ``sid`` is not a valid subject id.
        """
        rec = self.read(sid) or {"subject_id": sid, "host": socket.gethostname(), "pid": os.getpid()}
        rec.update(state="failed", attempts=int(attempt), updated=_now(), error=_error_text(exc))
        self._write(sid, rec)

    def begin(self, subjects) -> None:
        """A build asked for ``subjects`` (ids) starts: its plan is recorded (module docstring).

        Plans of builds that stopped before their end and whose subjects are all among ``subjects`` are removed
        (this build resumes them).

        Parameters
        ----------
        subjects : iterable of str
            The subject ids the build asks for.

        Raises
        ------
        ValidationError
            An id that is not a valid subject id.
        """
        record = {"subjects": [check_subject_id(s) for s in subjects], "host": socket.gethostname(),
                  "pid": os.getpid(), "started": _now()}  # fmt: skip
        for path in self._plan_files():  # builds killed before whose subjects this one asks for: it resumes them
            rec = self._plan_record(path)
            if rec is not None and not _alive(rec) and set(rec["subjects"]) <= set(record["subjects"]):
                path.unlink(missing_ok=True)
        host = "".join(c if c.isalnum() or c in "-_" else "_" for c in record["host"])[:64]
        self._plan = self.root / PLAN.replace("*", f"{host}-{os.getpid()}-{secrets.token_hex(4)}")
        self._write_file(self._plan, record)

    def end(self) -> None:
        """The build of this journal's plan returned: its plan goes (other builds' stay)."""
        if self._plan is not None:
            self._plan.unlink(missing_ok=True)
            self._plan = None

    @contextlib.contextmanager
    def planned(self, subjects):
        """The plan of ``subjects`` recorded for the block (:meth:`begin`), removed when it ends or fails.

        An interruption (:class:`KeyboardInterrupt`: SIGINT, SIGTERM) keeps it: the build stopped before its
        end, and ``--status`` says what it did not start. An error ends the build and leaves no plan.

        Parameters
        ----------
        subjects : iterable of str
            The subject ids the build asks for.

        Yields
        ------
        BuildJournal
            This journal.
        """
        self.begin(subjects)
        try:
            yield self
        except KeyboardInterrupt:
            raise
        except BaseException:
            self.end()
            self.prune()
            raise
        self.end()
        self.prune()

    def plans(self) -> list:
        """The recorded plans of builds that have not returned (module docstring), oldest first; files that are
        not plans (damaged, not JSON, not regular files) are left out."""
        found = (self._plan_record(p) for p in self._plan_files())
        return sorted((r for r in found if r is not None), key=lambda r: str(r.get("started", "")))

    def _plan_files(self) -> list:
        """The plan files in the journal (:data:`PLAN`, and :data:`LEGACY_PLAN` of an older build)."""
        if not self.root.is_dir():
            return []
        return sorted(self.root.glob(PLAN)) + [p for p in [self.root / LEGACY_PLAN] if p.exists()]

    @staticmethod
    def _plan_record(path) -> dict | None:
        """The plan in the file ``path``, or None (gone, not a regular file, not JSON, not a plan)."""
        try:
            rec = json.loads(read_regular_file(path, follow_links=False))
        except (OSError, ValueError, RecursionError):
            return None
        return rec if isinstance(rec, dict) and isinstance(rec.get("subjects"), list) else None

    def finish(self, sid: str) -> None:
        """``sid`` is committed to the store: its record goes.

        Parameters
        ----------
        sid : str
            The subject id (no record: nothing happens).

        Raises
        ------
        ValidationError
            ``sid`` is not a valid subject id.
        """
        self._path(sid).unlink(missing_ok=True)

    def prune(self) -> None:
        """Remove the journal folder if no record is left in it."""
        try:
            self.root.rmdir()
        except OSError:  # missing, or records left
            pass


def _error_text(exc: BaseException) -> str:
    """``exc``'s type and message, then its notes in parentheses: one line for ``--status``.

    :func:`traceback.format_exception_only` ends with the notes (``add_note``), one entry per line of each, after
    the message (itself after a syntax error's file and line): the message is the last entry of the exception
    formatted without its notes.
    """
    full = traceback.format_exception_only(type(exc), exc)
    own = traceback.TracebackException(type(exc), exc, None)
    own.__notes__ = None
    message = list(own.format_exception_only())
    notes = [" ".join(line.split()) for line in full[len(message) :]]
    notes = [n for n in notes if n]
    return " ".join(message[-1].split()) + (f" ({'; '.join(notes)})" if notes else "")


def gathered(future, store, sid):
    """The ``(id, state, result)`` of a task's future or :class:`facestats.pipeline.cluster.Outcome`; a task lost
    with its workers (e.g. ``KilledWorker`` after Dask's own resubmissions) is recorded as failed in the journal of
    ``store`` (None: not recorded), not raised.

    A lost task whose subject is in the store anyway is done: its worker committed it before the task was lost
    (the scheduler lost a worker that had finished, or a worker shared with a subject that killed it).  A failed
    subject keeps the number of attempts its record counts.

    Parameters
    ----------
    future : distributed.Future or facestats.pipeline.cluster.Outcome
        The subject's task; its result is the task's own ``(id, state, result)``.
    store : str or None
        The store directory the task writes to (and whose journal records it), or None.
    sid : str
        The task's subject id.

    Returns
    -------
    tuple
        The task's result; for a lost task ``(sid, "failed", error text)``, or ``(sid, "done", None)`` if the
        subject is in ``store``.
    """
    try:
        return future.result()
    except Exception as exc:  # the worker died or the task could not run: reported with the others
        error = " ".join(f"{type(exc).__name__}: {exc}".split())  # Dask's messages run over several lines
        if store is not None:
            with open_store(store, mode="r") as st:
                committed = sid in st
            journal = BuildJournal(store)
            if committed:
                journal.finish(sid)
                return sid, "done", None
            journal.fail(sid, int((journal.read(sid) or {}).get("attempts") or 1), exc)
        return sid, "failed", error


def run_journalled(journal, sid, fn, retries):
    """``fn()`` for subject ``sid`` with up to ``retries`` retries, recorded in ``journal`` (None: not recorded).

    Parameters
    ----------
    journal : BuildJournal or None
        Where each attempt's start, failure and finish are recorded.
    sid : str
        The subject id.
    fn : callable
        The work, called without arguments once per attempt; an ``Exception`` it raises fails the attempt.
    retries : int
        Attempts after the first, an integer ≥ 0.

    Returns
    -------
    tuple
        ``("done", result)`` or ``("failed", last error text)``: a failure of ``fn`` is reported,
        never raised, so the other subjects of a build go on.

    Raises
    ------
    ValidationError
        ``retries`` is not an integer ≥ 0 (checked before any attempt or journal record).
    """
    retries = check_integer(retries, "retries", 0)
    for attempt in range(1, retries + 2):
        try:
            if journal is not None:
                journal.start(sid, attempt)  # a journal that cannot be written (a full disk) fails the attempt
            result = fn()
        except Exception as exc:  # every failure is recorded and retried, then reported
            if journal is not None:
                try:
                    journal.fail(sid, attempt, exc)
                except OSError:  # the journal cannot be written either: the failure is still reported
                    pass
            error = f"{type(exc).__name__}: {exc}"
            continue
        if journal is not None:
            journal.finish(sid)
        return "done", result
    return "failed", error


@dataclass
class BuildStatus:
    """What :func:`build_status` finds: subjects done (in the store), running, interrupted, failed.

    Attributes
    ----------
    store : str
        The store directory.
    done : list of str
        Built subjects in the store, sorted.
    running : list of str
        Subjects whose ``running`` record's process is alive (or cannot be told to be gone), sorted.
    interrupted : list of str
        Subjects whose ``running`` record's process is gone on this host, sorted.
    failed : dict of str to str
        The subjects whose record is ``failed``, with its last error.
    records : dict of str to dict
        The journal's records of subjects not in the store, by id.
    others : list of str
        Subjects of the store that no build wrote: edits (source ``facestats.edit``) and imported sample subjects.
    plans : list of dict
        The plans of builds that have not returned (module docstring), oldest first.
    not_started : list of str
        Subjects of those plans neither stored nor in the journal: not started yet (or lost with a killed build).
    """

    store: str
    done: list
    running: list = field(default_factory=list)
    interrupted: list = field(default_factory=list)
    failed: dict = field(default_factory=dict)
    records: dict = field(default_factory=dict)
    others: list = field(default_factory=list)
    plans: list = field(default_factory=list)
    not_started: list = field(default_factory=list)

    @property
    def unfinished(self) -> bool:
        """A build's plan is left and its process is gone: it stopped before its end (rerun it to resume)."""
        return any(not _alive(p) for p in self.plans)

    def to_dict(self) -> dict:
        """JSON-ready: counts and ids per state, the failed subjects' last errors."""
        return {
            "store": self.store,
            "done": len(self.done),
            "running": self.running,
            "interrupted": self.interrupted,
            "failed": self.failed,
            "others": len(self.others),
            "requested": None if not self.plans else len({s for p in self.plans for s in p["subjects"]}),
            "not_started": self.not_started,
            "build": None if not self.plans else ("stopped" if self.unfinished else "running"),
            "builds": [
                {
                    "subjects": len(p["subjects"]),
                    "host": p.get("host"),
                    "pid": p.get("pid"),
                    "started": p.get("started"),
                    "state": "running" if _alive(p) else "stopped",
                }
                for p in self.plans
            ],
        }

    def to_text(self) -> str:
        """Counts per state, then one line per running, interrupted and failed subject."""
        lines = [
            f"store {self.store}: {len(self.done)} done, {len(self.running)} running, "
            f"{len(self.interrupted)} interrupted, {len(self.failed)} failed"
            + (f", {len(self.not_started)} not started" if self.plans else "")
            + (f" (and {len(self.others)} edited or imported subject(s), not built)" if self.others else "")
        ]
        for p in self.plans:
            state = (
                "running"
                if _alive(p)
                else f"stopped before its end (pid {p.get('pid', '?')} is gone): rerun the same command to resume"
            )
            lines.append(
                f"  build of {len(p['subjects'])} subject(s) begun {p.get('started', '?')} on {p.get('host', '?')}: "
                f"{state}"
            )
        for sid in self.running:
            r = self.records[sid]
            lines.append(
                f"  running      {sid}  attempt {r.get('attempts', '?')} on {r.get('host', '?')} "
                f"(pid {r.get('pid', '?')}) since {r.get('started', '?')}"
            )
        for sid in self.interrupted:
            r = self.records[sid]
            lines.append(
                f"  interrupted  {sid}  attempt {r.get('attempts', '?')} on {r.get('host', '?')} "
                f"(pid {r.get('pid', '?')} is gone)"
            )
        for sid, err in self.failed.items():
            lines.append(f"  failed       {sid}  after {self.records[sid].get('attempts', '?')} attempt(s): {err}")
        return "\n".join(lines)


def _alive(record) -> bool:
    """False when the record's process is known to be gone (on this host); True if it cannot be told."""
    return not process_gone(record.get("pid"), record.get("host") or "")


def build_status(store_path) -> BuildStatus:
    """Done, running, interrupted and failed subjects of builds into the store at ``store_path``.

    Parameters
    ----------
    store_path : str or os.PathLike
        A directory store (a ``file://`` URL accepted).

    Returns
    -------
    BuildStatus

    Raises
    ------
    StoreError
        ``store_path`` is an object store URL, or no readable store is there.
    """

    store_path = store_directory(store_path)  # a file:// URL, as `facestats build --store` takes, is its path
    with open_store(store_path, mode="r") as store:
        rows = {sid: entry["row"] for sid, entry in store.index_entries().items()}
    built = {sid for sid, row in rows.items() if row.get("source") != EDIT_SOURCE and row.get("kind") != "samples"}
    done, others = sorted(built), sorted(set(rows) - built)
    records = {sid: rec for sid, rec in BuildJournal(store_path).records().items() if sid not in rows}
    running = sorted(s for s, r in records.items() if r.get("state") == "running" and _alive(r))
    interrupted = sorted(s for s, r in records.items() if r.get("state") == "running" and s not in running)
    failed = {s: r.get("error") for s, r in sorted(records.items()) if r.get("state") == "failed"}
    plans = BuildJournal(store_path).plans()
    asked = dict.fromkeys(s for p in plans for s in p["subjects"])  # once each, in the plans' order
    not_started = [s for s in asked if s not in rows and s not in records]
    return BuildStatus(str(store_path), done, running, interrupted, failed, records, others, plans, not_started)
