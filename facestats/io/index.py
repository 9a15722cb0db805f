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

from facestats.errors import StoreError
from facestats.io.layout import fsync_path

__all__ = [
    "INDEX_NAME",
    "INDEX_FORMAT",
    "empty_index",
    "parse_index",
    "read_index_file",
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
        The index document (format :data:`INDEX_FORMAT`, complete entries).
    """
    try:
        index = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise StoreError(
            f"{where} is not valid JSON ({exc}); run `facestats validate --repair` to rebuild it"
        ) from None
    if not isinstance(index, dict) or not isinstance(index.get("subjects"), dict):
        raise StoreError(f"{where} is not a facestats index (no 'subjects' mapping)")
    if index.get("format") != INDEX_FORMAT:
        raise StoreError(
            f"{where} has index format {index.get('format')!r}; this facestats reads format {INDEX_FORMAT}"
        )
    for sid, entry in index["subjects"].items():
        if not isinstance(entry, dict) or not {"generation", "row", "albedo_hist"} <= set(entry):
            raise StoreError(f"{where}: the entry of subject {sid!r} is incomplete")
    return index


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
    path = os.path.join(os.fspath(root), INDEX_NAME)
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        raise StoreError(
            f"store {os.fspath(root)} has no {INDEX_NAME}; run `facestats validate --repair --store "
            f"{os.fspath(root)}` to rebuild it from the subject groups"
        ) from None
    return parse_index(data, where=path)


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
    """True for the temporary files :func:`write_index_file` creates."""
    return name.startswith(_TMP_PREFIX)


class IndexTable:
    """The index as columns: ``ids`` (sorted), ``columns[name]`` arrays, ``hists`` (n, 3, bins).

    Integer columns without missing values (``age``, ``skin_type``, sample
    counts) are int64 arrays, other numeric columns float64 (missing values
    NaN); text columns (``subject_id``, ``person_id``, ``gender``,
    ``condition``, ``kind``, ``source``) are object arrays.
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
