"""The population index file of a store: one JSON document, replaced atomically.

``index.json`` is the commit point of the store: a subject exists when, and in
the version that, the index names.  Its layout (format 1)::

    {
      "format": 1,
      "facestats_schema": 1,            # facestats.io.schema.SCHEMA_VERSION
      "facestats_version": "0.1.0",     # the facestats that wrote this revision
      "revision": 17,                   # +1 per commit
      "updated": "2026-01-01T12:00:00.000000+00:00",
      "subjects": {
        "S001": {
          "generation": "g0182f...-1234-a1b2c3",   # subjects/S001/<generation>/ holds the data
          "written": "2026-...",                    # when that generation was written (UTC)
          "row": {...},                             # facestats.io.summary.summarise_subject (NaN -> null)
          "albedo_hist": [[256 ints], [256 ints], [256 ints]]   # summary.albedo_histogram, R G B
        }
      }
    }

Writers replace the file as a whole (write a temporary file, ``fsync``,
``os.replace``, ``fsync`` the directory) while holding the store lock, so a
reader sees one complete revision or the next, and a crash at any point
leaves the previous revision in place.

Nothing read from the file is trusted: :func:`parse_index` checks every entry
(:func:`entry_problem`) — the subject id by the one id rule
(:func:`facestats.io.ids.check_subject_id`, since ids name folders), the
generation name, the row's metadata types and values, numbers finite (the
file is written without NaN, and ``NaN``/``Infinity`` literals are refused),
the histogram's shape and counts — and refuses a tampered index with a
:class:`~facestats.errors.StoreError` naming the subject and the field.
:func:`split_index` keeps the good entries and lists the bad ones for repair.

This module only needs :mod:`json` and numpy, so ``facestats query`` can read
an index without importing xarray, zarr or pandas.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import secrets

import numpy as np

from facestats.core.conventions import CONDITIONS, GENDERS
from facestats.errors import StoreError, ValidationError
from facestats.io.ids import check_subject_id
from facestats.io.layout import fsync_path, is_generation, read_regular_file

__all__ = [
    "INDEX_NAME",
    "INDEX_FORMAT",
    "empty_index",
    "parse_index",
    "split_index",
    "entry_problem",
    "read_index_file",
    "read_index_bytes",
    "write_index_file",
    "make_entry",
    "IndexTable",
    "index_table",
    "utc_now",
    "is_index_temp",
]

#: File name of the index inside a store.
INDEX_NAME = "index.json"
#: Layout version of the index file.
INDEX_FORMAT = 1
_TMP_PREFIX = INDEX_NAME + ".tmp-"
#: Albedo histogram bins of an entry (:data:`facestats.io.summary.HIST_BINS`).
_HIST_BINS = 256
#: Row metadata: column -> check of its value (the rest of a row are numbers or null).
_META = {
    "subject_id": lambda v: isinstance(v, str),
    "person_id": lambda v: isinstance(v, str),
    "age": lambda v: _is_int(v) and 0 <= v <= 200,
    "gender": lambda v: v in GENDERS,
    "skin_type": lambda v: _is_int(v) and 1 <= v <= 6,
    "condition": lambda v: v in CONDITIONS,
    "kind": lambda v: v in ("maps", "samples"),
}
_META_EXPECTED = {
    "subject_id": "a string",
    "person_id": "a string",
    "age": "an integer 0-200",
    "gender": f"one of {list(GENDERS)}",
    "skin_type": "an integer 1-6",
    "condition": f"one of {list(CONDITIONS)}",
    "kind": "'maps' or 'samples'",
}


#: Largest integer an entry may hold (row values, histogram counts): exact in float64 and in every JSON reader,
#: and far from int64's limit, so the index's columns and sums never overflow.
MAX_INT = 2**53


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    if v is None:
        return True
    if _is_int(v):
        return -MAX_INT <= v <= MAX_INT  # (math.isfinite of a huge int raises OverflowError)
    return isinstance(v, float) and math.isfinite(v)


def _no_constants(name):
    raise ValueError(f"{name} is not a JSON number")


def utc_now() -> str:
    """The current UTC time as an ISO 8601 string (microseconds)."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="microseconds")


def empty_index(schema_version: int, facestats_version: str) -> dict:
    """An index with no subjects.

    Parameters
    ----------
    schema_version : int
        :data:`facestats.io.schema.SCHEMA_VERSION` of the store.
    facestats_version : str
        The facestats writing it.

    Returns
    -------
    dict
        The index document, revision 0.
    """
    return {
        "format": INDEX_FORMAT,
        "facestats_schema": int(schema_version),
        "facestats_version": str(facestats_version),
        "revision": 0,
        "updated": utc_now(),
        "subjects": {},
    }


def _json_value(v):
    """A JSON-safe scalar: NaN/inf -> None, numpy scalars -> Python."""
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def make_entry(generation: str, written: str, row: dict, hist) -> dict:
    """The index entry of one subject generation.

    Parameters
    ----------
    generation, written : str
        The generation and when it was written (UTC, ISO 8601).
    row : dict
        :func:`facestats.io.summary.summarise_subject` of the subject (NaN and inf become None).
    hist : array_like, shape (3, bins)
        :func:`facestats.io.summary.albedo_histogram` of the subject.

    Returns
    -------
    dict
        ``{"generation", "written", "row", "albedo_hist"}`` (JSON-ready).
    """
    hist = np.asarray(hist)
    if hist.ndim != 2 or hist.shape[0] != 3:
        raise StoreError(f"albedo histogram must have shape (3, bins), got {hist.shape}")
    return {
        "generation": str(generation),
        "written": str(written),
        "row": {k: _json_value(v) for k, v in row.items()},
        "albedo_hist": hist.astype(np.int64).tolist(),
    }


def entry_problem(sid, entry) -> str | None:
    """Why the index entry ``entry`` of ``sid`` is not a valid entry, or None if it is.

    Checks the id (:func:`facestats.io.ids.check_subject_id`), the generation
    name, ``written``, the row (metadata of :data:`_META`, ``subject_id`` equal
    to the id, ``source`` a string, every other value a finite number or null)
    and the histogram (3 lists of 256 non-negative integers).

    Parameters
    ----------
    sid : object
        The entry's key in the index's ``subjects`` mapping.
    entry : object
        The entry as decoded from JSON.

    Returns
    -------
    str or None
        What is wrong (naming the field), or None.
    """
    try:
        check_subject_id(sid)
    except ValidationError as exc:
        return f"invalid subject id: {exc}"
    if not isinstance(entry, dict):
        return f"the entry must be an object, got {type(entry).__name__}"
    gen = entry.get("generation")
    if not isinstance(gen, str) or not is_generation(gen):
        return f"field 'generation' must be a generation name, got {gen!r}"
    if not isinstance(entry.get("written", ""), str):
        return f"field 'written' must be a string, got {entry.get('written')!r}"
    return _row_problem(sid, entry.get("row")) or _hist_problem(entry.get("albedo_hist"))


def _row_problem(sid, row) -> str | None:
    if not isinstance(row, dict):
        return f"field 'row' must be an object, got {type(row).__name__}"
    for key, ok in _META.items():
        if key not in row:
            return f"row field {key!r} is missing"
        if not ok(row[key]):
            return f"row field {key!r} must be {_META_EXPECTED[key]}, got {row[key]!r}"
    if row["subject_id"] != sid:
        return f"row field 'subject_id' must be {sid!r}, got {row['subject_id']!r}"
    for key, v in row.items():
        if key in _META:
            continue
        if key == "source" and isinstance(v, str):
            continue
        if not _is_number(v):
            shown = repr(v) if len(repr(v)) <= 40 else repr(v)[:37] + "..."
            return f"row field {key!r} must be a finite number (integers within ±2**53) or null, got {shown}"
    return None


def _counts_ok(counts: list) -> bool:
    """Every element an integer (not a bool) in [0, MAX_INT]; a non-empty list."""
    if set(map(type, counts)) == {int}:  # what JSON decodes: the types and the range by C loops (query's start-up)
        return 0 <= min(counts) and max(counts) <= MAX_INT
    return all(_is_int(c) and 0 <= c <= MAX_INT for c in counts)


def _hist_problem(hist) -> str | None:
    ok = isinstance(hist, list) and len(hist) == 3
    ok = ok and all(isinstance(h, list) and len(h) == _HIST_BINS for h in hist)
    ok = ok and all(_counts_ok(h) for h in hist)
    if not ok:
        return f"field 'albedo_hist' must be 3 lists of {_HIST_BINS} counts (integers 0 to 2**53)"
    return None


def _load_document(data, where: str) -> dict:
    """The JSON document of an index, checked as far as its top level."""
    try:
        index = json.loads(data, parse_constant=_no_constants)
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise StoreError(
            f"{where} is not valid JSON ({exc}); run `facestats validate --repair` to rebuild it"
        ) from None
    if not isinstance(index, dict) or not isinstance(index.get("subjects"), dict):
        raise StoreError(
            f"{where} is not a facestats index (no 'subjects' mapping); run `facestats validate --repair` to rebuild it"
        )
    if index.get("format") != INDEX_FORMAT:
        raise StoreError(
            f"{where} has index format {index.get('format')!r}; this facestats reads format {INDEX_FORMAT}"
        )
    rev = index.get("revision", 0)
    if not _is_int(rev) or rev < 0:
        raise StoreError(f"{where}: 'revision' must be an integer >= 0, got {rev!r}; run `facestats validate --repair`")
    return index


def parse_index(data: bytes | str, *, where: str = INDEX_NAME) -> dict:
    """Decode and check an index document; :class:`StoreError` naming ``where`` if it is not one.

    Parameters
    ----------
    data : bytes or str
        The JSON text.
    where : str
        Its name in messages.

    Returns
    -------
    dict
        The index document (format :data:`INDEX_FORMAT`, every entry valid: :func:`entry_problem`).
    """
    index = _load_document(data, where)
    for sid, entry in index["subjects"].items():
        problem = entry_problem(sid, entry)
        if problem:
            raise StoreError(
                f"{where}: the entry of subject {sid!r} is invalid: {problem}; "
                "run `facestats validate --repair` to recompute or drop it"
            )
    return index


def split_index(data: bytes | str, *, where: str = INDEX_NAME) -> tuple[dict, dict]:
    """Like :func:`parse_index`, but keep the valid entries and return the invalid ones apart.

    Parameters
    ----------
    data : bytes or str
        The JSON text.
    where : str
        Its name in messages.

    Returns
    -------
    index : dict
        The document with its valid entries only.
    bad : dict
        ``{subject id: (entry, problem)}`` of the invalid entries.
    """
    index = _load_document(data, where)
    bad = {}
    for sid in list(index["subjects"]):
        problem = entry_problem(sid, index["subjects"][sid])
        if problem:
            bad[sid] = (index["subjects"].pop(sid), problem)
    return index, bad


def read_index_file(root) -> dict:
    """Read ``<root>/index.json``; :class:`StoreError` if it is missing or unreadable.

    Parameters
    ----------
    root : str or os.PathLike
        The store directory.

    Returns
    -------
    dict
        The index document (:func:`parse_index`).
    """
    return parse_index(read_index_bytes(root), where=os.path.join(os.fspath(root), INDEX_NAME))


def read_index_bytes(root) -> bytes:
    """The bytes of ``<root>/index.json``; :class:`StoreError` if it is missing or not a readable file.

    Parameters
    ----------
    root : str or os.PathLike
        The store directory.

    Returns
    -------
    bytes
        The file's content, not checked (:func:`parse_index` does that).

    Raises
    ------
    StoreError
        ``index.json`` is missing (the message names the repair), a symbolic link, not a regular file or unreadable.
    """
    path = os.path.join(os.fspath(root), INDEX_NAME)
    try:
        return read_regular_file(path, follow_links=False)
    except FileNotFoundError:
        raise StoreError(
            f"store {os.fspath(root)} has no {INDEX_NAME}; run `facestats validate --repair --store "
            f"{os.fspath(root)}` to rebuild it from the subject groups"
        ) from None
    except OSError as exc:
        raise StoreError(
            f"cannot read {path}: {exc.strerror or exc}; it must be the store's index file (a regular file)"
        ) from None


def write_index_file(root, index: dict) -> None:
    """Replace ``<root>/index.json`` atomically and durably (the caller holds the store lock).

    Parameters
    ----------
    root : str or os.PathLike
        The store directory.
    index : dict
        The index document (no NaN: :func:`make_entry` entries).
    """
    root = os.fspath(root)
    data = json.dumps(index, separators=(",", ":"), allow_nan=False).encode()
    tmp = os.path.join(root, f"{_TMP_PREFIX}{os.getpid()}-{secrets.token_hex(4)}")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, os.path.join(root, INDEX_NAME))
    except BaseException:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise
    fsync_path(root, directory=True)


def is_index_temp(name: str) -> bool:
    """True for the temporary files :func:`write_index_file` creates.

    Parameters
    ----------
    name : str
        A file name in the store root (not a path).

    Returns
    -------
    bool
    """
    return name.startswith(_TMP_PREFIX)


class IndexTable:
    """The index as columns: ``ids`` (sorted), ``columns[name]`` arrays, ``hists`` (n, 3, bins).

    Built by :func:`index_table`; ``len(table)`` is the number of subjects and ``table[name]`` a column.

    Parameters
    ----------
    ids : iterable of str
        The subject ids, sorted (kept as a list).
    columns : dict of str to ndarray, shape (n,)
        One array per index column, rows aligned with ``ids``. Integer columns without missing values (``age``,
        ``skin_type``, sample counts) are int64 arrays, other numeric columns float64 (missing values NaN); text
        columns (``subject_id``, ``person_id``, ``gender``, ``condition``, ``kind``, ``source``) are object arrays.
    hists : ndarray of int64, shape (n, 3, bins)
        Albedo histogram counts per subject and channel (R, G, B), ``bins`` (256) equal bins over [0, 1].
    """

    TEXT = ("subject_id", "person_id", "gender", "condition", "kind", "source")

    def __init__(self, ids, columns: dict, hists: np.ndarray):
        self.ids = list(ids)
        self.columns = columns
        self.hists = hists

    def __len__(self) -> int:
        return len(self.ids)

    def __getitem__(self, name) -> np.ndarray:
        return self.columns[name]


def index_table(index: dict) -> IndexTable:
    """Column arrays of an index document, subjects sorted by id.

    Parameters
    ----------
    index : dict
        The index document.

    Returns
    -------
    IndexTable
    """
    ids = sorted(index["subjects"])
    entries = [index["subjects"][i] for i in ids]
    names = dict.fromkeys(k for e in entries for k in e["row"])  # every column, in first-seen order
    columns = {}
    for name in names:
        vals = [e["row"].get(name) for e in entries]
        if name in IndexTable.TEXT or any(isinstance(v, str) for v in vals):
            columns[name] = np.array(["" if v is None else str(v) for v in vals], dtype=object)
        elif vals and all(isinstance(v, int) and not isinstance(v, bool) for v in vals):
            columns[name] = np.array(vals, dtype=np.int64)
        else:
            columns[name] = np.array([np.nan if v is None else v for v in vals], dtype=np.float64)
    if entries:
        hists = np.array([e["albedo_hist"] for e in entries], dtype=np.int64)
    else:
        hists = np.zeros((0, 3, 256), dtype=np.int64)
    return IndexTable(ids, columns, hists)
