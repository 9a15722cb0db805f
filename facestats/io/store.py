"""The facestats parameter store: Zarr v3 subject groups, a population index, atomic writes.

Layout of a directory store ``X.zarr/``::

    X.zarr/
      zarr.json                    root group; attributes: facestats_schema (= schema.SCHEMA_VERSION),
                                   facestats_version (the facestats that last wrote), created
      index.json                   population index and commit point (facestats.io.index)
      .lock                        store lock (facestats.io.locking)
      .writers/                    one lock file per generation being written
      subjects/zarr.json           group
      subjects/<id>/zarr.json      group
      subjects/<id>/<generation>/  the subject: an xarray Dataset written by ``to_zarr`` (Zarr v3)

A subject group holds the variables of :mod:`facestats.io.schema` with their
``units``/``long_name`` attributes and the subject's metadata and provenance as
group attributes, plus one bookkeeping attribute ``facestats_store`` (JSON:
schema version, writer version, write time, and a *manifest* of every
variable's dims, shape, dtype and CRC-32 of its bytes).  Map variables are
chunked in blocks of :data:`MAP_CHUNK_ROWS` rows of ``v`` (all of ``u`` and the
trailing dims), so a texel range of any map can be read alone
(``store.subject(id, lazy=True).isel(v=slice(0, 64))``).  Float variables are
compressed with Blosc (zstd, byte shuffle), others with Zarr's default zstd.

Writes
------
Each write of a subject creates a *fresh generation* directory
``subjects/<id>/<generation>/``, fills and ``fsync``-s it, and only then commits
by replacing ``index.json`` atomically under the store lock.  The index names
the current generation of each subject, so a reader never sees a generation
that is being written, and a writer killed at any moment leaves the previous
index, i.e. the old subject (or none) or the new one, never half of one.
Superseded generations are deleted after the commit (renamed aside first, so
they vanish atomically); generations left by crashed writers are *orphans*,
removed by :meth:`Store.gc` / ``facestats validate --repair``, which never
touch a generation whose writer is still alive (each writer holds a lock on
``.writers/<id>~<generation>.lock`` until its commit is done).  Several
processes may write at once: data are written in parallel, commits are
serialised by the store lock, and each commit re-reads the index so no
writer's update is lost.  A batch (:meth:`Store.write_subjects`) commits all of
its subjects at once.

Reads
-----
Readers take the current index, then open the generation it names; if that
generation disappears under them (a concurrent writer replaced the subject)
they retry with the new index.  Every subject read is checked: the group must
exist, carry the manifest, have the recorded variables with the recorded
dims, shapes and dtypes, and (unless ``lazy=True``) bytes whose CRC-32 matches
(a deleted chunk file would otherwise read silently as fill values);
finally :func:`facestats.io.schema.validate_subject` runs.  Problems raise
:class:`~facestats.errors.SchemaError` naming the subject and the variable.

The embedded default
--------------------
``facestats/data/default_store.zip`` is a store packed by :func:`pack_store`
(a zip of the directory layout above holding only current generations; chunk
entries stored uncompressed since Zarr chunks are compressed already, subject
metadata deflated; the root ``zarr.json`` and ``index.json`` first and stored).  Zip stores open read-only: the root attributes and
the index are read straight from the head of the file (no need to parse the
zip directory of every chunk), subject groups through ``zarr.storage.ZipStore``.
``open_store(None)`` opens it.

``open_store``, :meth:`Store.query`, :meth:`Store.info` and the index import
only numpy and the standard library; xarray, zarr and pandas are imported
when a subject or a DataFrame is needed.
"""

from __future__ import annotations

import json
import os
import re
import secrets
import shutil
import time
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facestats.core.validate import check_choice
from facestats.core.version import __version__
from facestats.errors import SchemaError, StoreError, ValidationError
from facestats.io.ids import check_subject_id
from facestats.io.index import (
    INDEX_NAME,
    empty_index,
    index_table,
    is_index_temp,
    make_entry,
    parse_index,
    read_index_file,
    utc_now,
    write_index_file,
)
from facestats.io.locking import FileLock, create_locked, is_lock_temp, is_locked, try_lock
from facestats.io.schema import SCHEMA_VERSION, provenance, set_provenance, validate_subject

__all__ = [
    "Store",
    "ValidationReport",
    "open_store",
    "pack_store",
    "default_store_path",
    "MAP_CHUNK_ROWS",
    "STORE_ATTR",
]

#: Rows of ``v`` per chunk of a map variable.
MAP_CHUNK_ROWS = 64
#: Group attribute holding the store's bookkeeping (removed from ``Dataset.attrs`` on read).
STORE_ATTR = "facestats_store"
SUBJECTS = "subjects"
LOCK_NAME = ".lock"
WRITERS = ".writers"
ROOT_META = "zarr.json"
_TRASH = ".trash-"
_GEN_RE = re.compile(r"^g[0-9a-f]{16}-\d+-[0-9a-f]{6}$")


def default_store_path() -> Path:
    """Where the embedded default store lives: ``facestats/data/default_store.zip``."""
    return Path(__file__).resolve().parent.parent / "data" / "default_store.zip"


# -- helpers -----------------------------------------------------------------------
def _new_generation() -> str:
    return f"g{time.time_ns():016x}-{os.getpid()}-{secrets.token_hex(3)}"


def _digest(values) -> tuple[str, int]:
    """(dtype tag, CRC-32) of an array's contents; strings are hashed by text."""
    a = np.asarray(values)
    if a.dtype.kind in "UOST":
        text = "\x1f".join(str(x) for x in a.reshape(-1).tolist())
        return "str", zlib.crc32(text.encode("utf-8"))
    a = np.ascontiguousarray(a)
    if a.dtype.byteorder == ">":
        a = a.astype(a.dtype.newbyteorder("<"))
    return a.dtype.str, zlib.crc32(a.reshape(-1).view(np.uint8))


def _manifest_entry(var) -> dict:
    dtype, crc = _digest(var.values)
    return {"dims": list(var.dims), "shape": list(var.shape), "dtype": dtype, "crc32": crc}


def _fsync_path(path, directory=False) -> None:
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_tree(path) -> None:
    for root, _, files in os.walk(path):
        for f in files:
            _fsync_path(os.path.join(root, f))
        _fsync_path(root, directory=True)


def _write_json_atomic(path, obj) -> None:
    tmp = f"{path}.tmp-{os.getpid()}-{secrets.token_hex(3)}"
    with open(tmp, "w") as fh:
        json.dump(obj, fh, indent=2)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _group_meta(attributes=None) -> dict:
    return {"zarr_format": 3, "node_type": "group", "attributes": dict(attributes or {})}


def _rows_differ(a: dict, b: dict) -> list[str]:
    """Keys whose values differ between two index rows (None and NaN are equal)."""

    def norm(v):
        if v is None or (isinstance(v, float) and v != v):
            return None
        return v

    return sorted(k for k in set(a) | set(b) if norm(a.get(k)) != norm(b.get(k)))


def _strings_to_str(ds, names):
    """Turn string variables read back from Zarr (StringDType/object) into numpy ``str`` arrays."""
    for name in names:
        var = ds.variables[name]
        if var.dtype.kind in "OT":
            new = ds[name].copy(data=np.asarray(var.values).astype(object).astype(str))
            ds = ds.assign_coords({name: new}) if name in ds.coords else ds.assign({name: new})
    return ds


@dataclass
class ValidationReport:
    """Outcome of :meth:`Store.validate`.

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


# -- backends ----------------------------------------------------------------------
class _DirBackend:
    kind = "directory"

    def __init__(self, root: str):
        self.root = root

    def read(self, rel: str) -> bytes:
        with open(os.path.join(self.root, rel), "rb") as fh:
            return fh.read()

    def exists(self, rel: str) -> bool:
        return os.path.exists(os.path.join(self.root, rel))

    def index_key(self):
        try:
            st = os.stat(os.path.join(self.root, INDEX_NAME))
        except FileNotFoundError:
            return None
        return (st.st_ino, st.st_mtime_ns, st.st_size)

    def zarr_target(self, rel: str):
        return os.path.join(self.root, rel), None

    def size(self) -> int:
        total = 0
        for root, _, files in os.walk(self.root):
            for f in files:
                try:
                    total += os.path.getsize(os.path.join(root, f))
                except OSError:
                    pass
        return total

    def close(self):
        pass


def _leading_entries(path: str, names) -> dict:
    """Read the stored entries ``names`` from the start of a zip without parsing its central directory.

    :func:`pack_store` writes ``zarr.json`` and ``index.json`` first, uncompressed,
    so ``facestats query`` can read them with two small reads instead of
    parsing the directory of every chunk file.  Stops at the first entry that
    is not one of ``names`` or is compressed; the caller falls back to
    :class:`zipfile.ZipFile` for whatever was not found.  CRCs are checked.
    """
    import struct

    out = {}
    with open(path, "rb") as fh:
        while len(out) < len(names):
            head = fh.read(30)
            if len(head) < 30 or head[:4] != b"PK\x03\x04":
                break
            _, _, flag, method, _, _, crc, csize, _, nlen, xlen = struct.unpack("<IHHHHHIIIHH", head)
            name = fh.read(nlen).decode("utf-8", "replace")
            if method != 0 or flag & 0x08 or name not in names:
                break
            fh.seek(xlen, os.SEEK_CUR)
            data = fh.read(csize)
            if len(data) != csize or zlib.crc32(data) != crc:
                raise StoreError(f"zip store {path}: entry {name} is truncated or corrupt")
            out[name] = data
    return out


class _ZipBackend:
    kind = "zip"

    def __init__(self, path: str):
        self.root = path
        try:
            self._lead = _leading_entries(path, (ROOT_META, INDEX_NAME))
        except OSError as exc:
            raise StoreError(f"cannot open zip store {path}: {exc}") from None
        self._zip = None
        self._names = None
        self._zarr = None

    def _zf(self):
        if self._zip is None:
            try:
                self._zip = zipfile.ZipFile(self.root)
            except (zipfile.BadZipFile, OSError) as exc:
                raise StoreError(f"cannot open zip store {self.root}: {exc}") from None
            self._names = set(self._zip.namelist())
        return self._zip

    def read(self, rel: str) -> bytes:
        if rel in self._lead:
            return self._lead[rel]
        try:
            return self._zf().read(rel)
        except KeyError:
            raise FileNotFoundError(rel) from None

    def exists(self, rel: str) -> bool:
        if rel in self._lead:
            return True
        self._zf()
        return rel in self._names

    def index_key(self):
        return "zip" if self.exists(INDEX_NAME) else None

    def zarr_target(self, rel: str):
        if self._zarr is None:
            from zarr.storage import ZipStore

            self._zarr = ZipStore(self.root, mode="r")
        return self._zarr, rel

    def size(self) -> int:
        return os.path.getsize(self.root)

    def close(self):
        if self._zip is not None:
            self._zip.close()
            self._zip = None
        if self._zarr is not None:
            self._zarr.close()
            self._zarr = None


# -- opening -----------------------------------------------------------------------
def open_store(path=None, mode: str = "r", *, lock_timeout: float = 60.0) -> "Store":
    """Open a parameter store.

    Parameters
    ----------
    path : str, os.PathLike or None
        A directory store (``X.zarr``), a zip store (``.zip``, read-only) or
        None for the embedded default (read-only).
    mode : {"r", "r+", "a"}
        ``"r"`` read-only; ``"r+"`` read-write, the store must exist; ``"a"``
        read-write, created if missing (directory stores only).
    lock_timeout : float
        Seconds a writer waits for the store lock before :class:`StoreError`.

    Raises
    ------
    StoreError
        Missing or unreadable store, read-write access to a zip store, or the
        default store not built yet.
    SchemaError
        A store written with a schema version this facestats cannot read.
    """
    check_choice(mode, "mode", ("r", "r+", "a"))
    if path is None:
        zp = default_store_path()
        if not zp.is_file():
            raise StoreError(
                f"the embedded default store has not been built ({zp} is missing); build it with "
                "`facestats build` or pass --store PATH to use another store"
            )
        if mode != "r":
            raise StoreError("the embedded default store is read-only; pass --store PATH to write to a directory store")
        return Store(_ZipBackend(str(zp)), read_only=True, label="default", lock_timeout=lock_timeout)
    p = Path(path).expanduser()
    if p.is_file():
        if not zipfile.is_zipfile(p):
            raise StoreError(f"{p} is neither a store directory nor a zip store")
        if mode != "r":
            raise StoreError(
                f"zip store {p} is read-only; write to a directory store (e.g. --store {p.with_suffix('.zarr')})"
            )
        return Store(_ZipBackend(str(p)), read_only=True, label=str(p), lock_timeout=lock_timeout)
    if not p.exists() or (p.is_dir() and not (p / ROOT_META).exists()):
        if mode != "a":
            what = "does not exist" if not p.exists() else "is not a facestats store (no zarr.json)"
            raise StoreError(f"store {p} {what}")
        if p.suffix == ".zip":
            raise StoreError(f"cannot create zip store {p}: create a directory store and pack it with pack_store")
        _create_store(p)
    return Store(_DirBackend(str(p)), read_only=(mode == "r"), label=str(p), lock_timeout=lock_timeout)


_CREATION_LEFTOVERS = {LOCK_NAME, WRITERS, SUBJECTS, INDEX_NAME}


def _create_store(p: Path) -> None:
    """Create an empty directory store at ``p`` (safe against concurrent creators)."""
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StoreError(f"cannot create store directory {p}: {exc.strerror}") from None
    with FileLock(p / LOCK_NAME):
        if (p / ROOT_META).exists():
            return
        extra = [n for n in os.listdir(p) if n not in _CREATION_LEFTOVERS and not is_index_temp(n)]
        if extra:
            raise StoreError(f"{p} exists, is not empty and is not a facestats store (contains {sorted(extra)[:5]})")
        (p / WRITERS).mkdir(exist_ok=True)
        (p / SUBJECTS).mkdir(exist_ok=True)
        _write_json_atomic(p / SUBJECTS / ROOT_META, _group_meta())
        if not (p / INDEX_NAME).exists():
            write_index_file(p, empty_index(SCHEMA_VERSION, __version__))
        attrs = {"facestats_schema": SCHEMA_VERSION, "facestats_version": __version__, "created": utc_now()}
        _write_json_atomic(p / ROOT_META, _group_meta(attrs))  # last: its presence marks a complete store
        _fsync_path(p, directory=True)


# -- the store ---------------------------------------------------------------------
class Store:
    """A facestats parameter store (see the module docstring); create with :func:`open_store`.

    Attributes
    ----------
    path : str
        The store directory or zip file ("default" stores report the zip path).
    read_only : bool
    schema_version : int
    writer_version : str
        The facestats version recorded in the root attributes.
    """

    def __init__(self, backend, *, read_only: bool, label: str, lock_timeout: float = 60.0):
        self._b = backend
        self.read_only = read_only
        self.label = label
        self.lock_timeout = lock_timeout
        self._index_cache = None  # (key, index)
        self._table_cache = None  # (key, IndexTable)
        self.root_attrs = self._read_root()
        self.schema_version = int(self.root_attrs["facestats_schema"])
        self.writer_version = str(self.root_attrs.get("facestats_version", "unknown"))

    # -- basics ------------------------------------------------------------------
    @property
    def path(self) -> str:
        return self._b.root

    @property
    def kind(self) -> str:
        return self._b.kind

    def __repr__(self):
        mode = "read-only" if self.read_only else "read-write"
        try:
            n = f"{len(self)} subjects"
        except StoreError:
            n = "unreadable index"
        return f"<facestats Store {self.label} ({self.kind}, {n}, {mode})>"

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self) -> None:
        """Release open files (zip stores)."""
        self._b.close()

    def _read_root(self) -> dict:
        try:
            meta = json.loads(self._b.read(ROOT_META))
        except FileNotFoundError:
            raise StoreError(f"{self.label} is not a facestats store: no root {ROOT_META}") from None
        except ValueError as exc:
            raise StoreError(f"{self.label}: root {ROOT_META} is not valid JSON ({exc})") from None
        if not isinstance(meta, dict) or meta.get("zarr_format") != 3 or meta.get("node_type") != "group":
            raise SchemaError(
                f"{self.label}: the root is not a Zarr v3 group (zarr.json: zarr_format "
                f"{meta.get('zarr_format') if isinstance(meta, dict) else '?'!r})"
            )
        attrs = meta.get("attributes") or {}
        if "facestats_schema" not in attrs:
            raise StoreError(f"{self.label} is a Zarr group but not a facestats store (no facestats_schema attribute)")
        v = attrs["facestats_schema"]
        if v != SCHEMA_VERSION:
            hint = (
                " (written by a newer facestats: upgrade facestats)"
                if isinstance(v, int) and v > SCHEMA_VERSION
                else ""
            )
            raise SchemaError(
                f"store {self.label} has schema version {v!r}; facestats {__version__} reads schema version "
                f"{SCHEMA_VERSION}{hint}"
            )
        return attrs

    def _require_writable(self) -> None:
        if self.read_only:
            if self.kind == "zip":
                raise StoreError(
                    f"store {self.label} is a read-only zip store; write to a directory store instead "
                    "(pass --store PATH, or open_store(PATH, mode='a'))"
                )
            raise StoreError(f"store {self.label} was opened read-only; open it with mode='r+' or 'a' to write")

    def _lock(self) -> FileLock:
        return FileLock(os.path.join(self.path, LOCK_NAME), timeout=self.lock_timeout)

    # -- index -------------------------------------------------------------------
    def _index(self) -> dict:
        """The current index document (re-read when the file changed)."""
        key = self._b.index_key()
        if key is None:
            raise StoreError(
                f"store {self.label} has no {INDEX_NAME}; run `facestats validate --repair --store {self.path}` "
                "to rebuild it from the subject groups"
            )
        if self._index_cache is None or self._index_cache[0] != key:
            if self.kind == "directory":
                index = read_index_file(self.path)
            else:
                index = parse_index(self._b.read(INDEX_NAME), where=f"{self.label}:{INDEX_NAME}")
            if index.get("facestats_schema") != SCHEMA_VERSION:
                raise SchemaError(
                    f"{self.label}: {INDEX_NAME} has schema version {index.get('facestats_schema')!r}, "
                    f"expected {SCHEMA_VERSION}"
                )
            self._index_cache = (key, index)
        return self._index_cache[1]

    def _table(self):
        index = self._index()
        if self._table_cache is None or self._table_cache[0] is not index:
            self._table_cache = (index, index_table(index))
        return self._table_cache[1]

    def ids(self) -> list[str]:
        """Subject ids, sorted."""
        return sorted(self._index()["subjects"])

    def __len__(self) -> int:
        return len(self._index()["subjects"])

    def __contains__(self, subject_id) -> bool:
        return str(subject_id) in self._index()["subjects"]

    def _entry(self, sid: str) -> dict:
        subjects = self._index()["subjects"]
        if sid not in subjects:
            sample = ", ".join(sorted(subjects)[:5]) + (" ..." if len(subjects) > 5 else "")
            raise StoreError(f"no subject {sid!r} in store {self.label} ({len(subjects)} subjects: {sample or 'none'})")
        return subjects[sid]

    def index_entries(self) -> dict:
        """The current index entries ``{subject_id: {"generation", "written", "row", "albedo_hist"}}``.

        ``row`` is the subject's :func:`facestats.io.summary.summarise_subject`
        row with missing values as None; ``albedo_hist`` its (3, 256) counts.
        The mapping belongs to the store's cache: do not modify it.
        """
        return self._index()["subjects"]

    @property
    def revision(self) -> int:
        """Index revision (increases by one per commit)."""
        return int(self._index().get("revision", 0))

    def subjects(self):
        """The population index as a :class:`pandas.DataFrame` indexed by ``subject_id``.

        Columns are those of :func:`facestats.io.summary.summarise_subject`;
        rows are sorted by id (the order of :meth:`albedo_histograms`).
        """
        import pandas as pd

        cols = self._table().columns
        df = pd.DataFrame(cols, columns=list(cols))
        if "subject_id" not in df:
            df["subject_id"] = pd.Series([], dtype=object)
        return df.set_index("subject_id")

    def albedo_histograms(self) -> np.ndarray:
        """Albedo histogram counts, shape (n_subjects, 3, 256), rows aligned with :meth:`subjects`."""
        return self._table().hists.copy()

    def query(self, skin_type=None, gender=None, age=None, condition=None, region=None):
        """Population statistics of the subjects matching the filters (:class:`facestats.io.query.QueryResult`).

        See :mod:`facestats.io.query` for the filters (skin types I and II are
        grouped), the statistics and the JSON form.
        """
        from facestats.io.query import run_query

        return run_query(
            self._table(),
            skin_type=skin_type,
            gender=gender,
            age=age,
            condition=condition,
            region=region,
            store=self.label,
        )

    # -- reading subjects ----------------------------------------------------------
    def _gen_rel(self, sid: str, gen: str) -> str:
        return f"{SUBJECTS}/{sid}/{gen}"

    def _open_generation(self, sid: str, gen: str, *, lazy: bool = False, variables=None):
        """Open and check one generation; ``variables`` (with lazy=True): load and verify just these."""
        import xarray as xr

        rel = self._gen_rel(sid, gen)
        if not self._b.exists(f"{rel}/{ROOT_META}"):
            raise SchemaError(f"subject {sid!r}: group {rel} is missing from store {self.label}")
        target, group = self._b.zarr_target(rel)
        try:
            ds = xr.open_zarr(target, group=group, consolidated=False, zarr_format=3, chunks=None)
        except Exception as exc:
            raise SchemaError(f"subject {sid!r}: cannot open group {rel}: {type(exc).__name__}: {exc}") from None
        attrs = dict(ds.attrs)
        raw = attrs.pop(STORE_ATTR, None)
        if raw is None:
            raise SchemaError(
                f"subject {sid!r}: group {rel} lacks the {STORE_ATTR!r} attribute (not written by facestats)"
            )
        try:
            meta = json.loads(raw)
            manifest = meta["manifest"]
        except (ValueError, KeyError, TypeError):
            raise SchemaError(f"subject {sid!r}: the {STORE_ATTR!r} attribute of {rel} is corrupt") from None
        if meta.get("schema") != SCHEMA_VERSION:
            raise SchemaError(f"subject {sid!r}: schema version {meta.get('schema')!r}, expected {SCHEMA_VERSION}")
        if str(attrs.get("subject_id")) != sid:
            raise SchemaError(f"subject {sid!r}: group {rel} holds subject_id {attrs.get('subject_id')!r}")
        ds.attrs = attrs
        ds.encoding[STORE_ATTR] = {k: v for k, v in meta.items() if k != "manifest"}
        missing = [n for n in manifest if n not in ds.variables]
        if missing:
            raise SchemaError(f"subject {sid!r}: variable(s) {missing} missing from group {rel}")
        extra = [n for n in ds.variables if n not in manifest]
        if extra:
            raise SchemaError(f"subject {sid!r}: unexpected variable(s) {extra} in group {rel}")
        for name, m in manifest.items():
            var = ds.variables[name]
            if list(var.dims) != m["dims"]:
                raise SchemaError(
                    f"subject {sid!r}: variable {name!r} has dims {tuple(var.dims)}, expected {tuple(m['dims'])}"
                )
            if list(var.shape) != m["shape"]:
                raise SchemaError(
                    f"subject {sid!r}: variable {name!r} has shape {tuple(var.shape)}, "
                    f"expected {tuple(m['shape'])} (truncated array?)"
                )
            dt = "str" if var.dtype.kind in "UOST" else var.dtype.str
            if dt != m["dtype"]:
                raise SchemaError(f"subject {sid!r}: variable {name!r} has dtype {dt}, expected {m['dtype']}")
        check = list(manifest) if not lazy else list(variables or [])
        for name in check:
            if name not in manifest:
                raise SchemaError(f"subject {sid!r}: no variable {name!r}")
            var = ds.variables[name]
            try:
                var.load()
            except Exception as exc:
                raise SchemaError(
                    f"subject {sid!r}: variable {name!r} cannot be read (truncated or corrupt chunk): "
                    f"{type(exc).__name__}: {exc}"
                ) from None
            if _digest(var.values)[1] != manifest[name]["crc32"]:
                raise SchemaError(
                    f"subject {sid!r}: variable {name!r} does not match its checksum "
                    "(a chunk file is missing, truncated or altered)"
                )
        ds = _strings_to_str(ds, set(check) | set(ds.indexes))
        if not lazy:
            validate_subject(ds, name=sid)
        return ds

    def _load(self, sid: str, **kw):
        """Open the current generation of ``sid``, retrying if a concurrent writer replaced it."""
        sid = str(sid)
        err = None
        for _ in range(5):
            gen = self._entry(sid)["generation"]
            try:
                return self._open_generation(sid, gen, **kw)
            except SchemaError as exc:
                if self._entry(sid)["generation"] == gen:
                    raise
                err = exc
        raise err

    def subject(self, subject_id, *, lazy: bool = False):
        """One subject as an :class:`xarray.Dataset`.

        With ``lazy=False`` (default) every variable is loaded, checked
        against its stored CRC-32 and the subject validated against the
        schema.  With ``lazy=True`` only metadata are checked (dims, shapes,
        dtypes) and variables are read on access, chunk by chunk (e.g. a
        64-row band of a map); a lazy Dataset may fail if a concurrent writer
        replaces the subject before it is read.
        """
        return self._load(str(subject_id), lazy=lazy)

    def region_samples(self, model: str = "ts", subjects=None):
        """Per-region BRDF samples of many subjects as a long :class:`pandas.DataFrame`.

        Columns ``subject_id, region, rho_s, lobe`` (``lobe`` is m for
        ``model="ts"``, the Blinn-Phong exponent for ``"bp"``); samples are
        those of :func:`facestats.io.summary.region_samples` (unflagged
        texels of map subjects, stored samples of imported subjects).  Only
        the needed variables are read (and checksum-verified).
        """
        import pandas as pd

        from facestats.io.summary import MODEL_PARAMS, region_samples

        check_choice(model, "model", MODEL_PARAMS)
        if subjects is None:
            ids = self.ids()
        else:
            ids = [str(s) for s in ([subjects] if isinstance(subjects, str) else subjects)]
            for s in ids:
                self._entry(s)
        kinds = self._table()
        kind_of = dict(zip(kinds.ids, kinds["kind"].tolist())) if len(kinds) else {}
        sid_parts, reg_parts, rho_parts, lobe_parts = [], [], [], []
        for sid in ids:
            if kind_of.get(sid) == "maps":
                needed = ["region", *MODEL_PARAMS[model]]
            else:
                needed = ["ts_sample_region", "ts_sample_rho_s", "ts_sample_m"]
            ds = self._load(sid, lazy=True, variables=needed)
            for r, (rho, lobe) in region_samples(ds, model).items():
                sid_parts.append(np.full(rho.size, sid, dtype=object))
                reg_parts.append(np.full(rho.size, r, dtype=np.int64))
                rho_parts.append(rho)
                lobe_parts.append(lobe)
        cat = lambda parts, dt: np.concatenate(parts) if parts else np.empty(0, dtype=dt)
        return pd.DataFrame(
            {
                "subject_id": cat(sid_parts, object),
                "region": cat(reg_parts, np.int64),
                "rho_s": cat(rho_parts, np.float64),
                "lobe": cat(lobe_parts, np.float64),
            }
        )

    # -- writing -----------------------------------------------------------------
    def write_subject(self, dataset, *, overwrite: bool = False) -> str:
        """Write one subject atomically; return its id.

        The Dataset is validated first (:func:`facestats.io.schema.validate_subject`)
        and refused without touching the store if invalid.  An existing id
        raises :class:`StoreError` unless ``overwrite=True``, which replaces
        the subject atomically (readers see the old or the new version).
        Edits must write a new id with ``source_subject`` and ``edit`` in
        their provenance rather than overwrite their source.
        """
        return self.write_subjects([dataset], overwrite=overwrite)[0]

    def write_subjects(self, datasets, *, overwrite: bool = False) -> list[str]:
        """Write several subjects and commit them together (all or none); return their ids."""
        import xarray as xr

        from facestats.io.summary import albedo_histogram, summarise_subject

        self._require_writable()
        prepared = []
        seen = set()
        for k, ds in enumerate(datasets):
            if not isinstance(ds, xr.Dataset):
                raise ValidationError(f"datasets[{k}] must be an xarray.Dataset, got {type(ds).__name__}")
            validate_subject(ds)
            sid = check_subject_id(ds.attrs["subject_id"])
            try:
                provenance(ds)
            except (ValueError, TypeError):
                raise SchemaError(
                    f"subject {sid!r}: attribute provenance must be a JSON object string, "
                    f"got {str(ds.attrs['provenance'])[:60]!r}"
                ) from None
            if sid in seen:
                raise ValidationError(f"subject_id {sid!r} appears twice in one write")
            seen.add(sid)
            prepared.append((sid, ds, summarise_subject(ds), albedo_histogram(ds)))
        if not prepared:
            return []
        if not overwrite:
            self._refuse_existing(self._index(), seen)
        written = []  # (sid, gen, lock, when)
        superseded = []
        try:
            for sid, ds, _, _ in prepared:
                gen, lock = self._reserve_generation(sid)
                written.append((sid, gen, lock, utc_now()))
                self._write_generation(sid, gen, ds, written[-1][3])

            def mutate(index):
                if not overwrite:
                    self._refuse_existing(index, seen)
                for (sid, gen, _, when), (_, _, row, hist) in zip(written, prepared):
                    old = index["subjects"].get(sid)
                    if old is not None:
                        superseded.append((sid, old["generation"]))
                    index["subjects"][sid] = make_entry(gen, when, row, hist)
                return [sid for sid, *_ in written]

            self._commit(mutate)
        except BaseException:
            try:  # an interrupt may land after the commit: never delete what the index references
                current = read_index_file(self.path)["subjects"]
            except (StoreError, OSError):
                current = {}
            for sid, gen, lock, _ in written:
                if current.get(sid, {}).get("generation") != gen:
                    shutil.rmtree(os.path.join(self.path, self._gen_rel(sid, gen)), ignore_errors=True)
                self._drop_writer_lock(lock)
            raise
        for _, _, lock, _ in written:
            self._drop_writer_lock(lock)
        for sid, gen in superseded:
            self._remove_generation(sid, gen)
        return [sid for sid, *_ in written]

    def delete_subject(self, subject_id) -> None:
        """Remove a subject (atomic: the index drops it, then its data are deleted)."""
        self._require_writable()
        sid = str(subject_id)
        gone = []

        def mutate(index):
            if sid not in index["subjects"]:
                raise StoreError(f"no subject {sid!r} in store {self.label}")
            gone.append(index["subjects"].pop(sid)["generation"])

        self._commit(mutate)
        self._remove_generation(sid, gone[0])

    @staticmethod
    def _refuse_existing(index, ids) -> None:
        clash = sorted(set(ids) & set(index["subjects"]))
        if clash:
            raise StoreError(
                f"subject(s) {clash} already exist in the store; pass overwrite=True to replace them "
                "(edits should write a new subject id)"
            )

    def _reserve_generation(self, sid: str):
        """Pick a new generation name and take its writer lock (before any data exist)."""
        writers = os.path.join(self.path, WRITERS)
        for _ in range(10):
            gen = _new_generation()
            try:
                os.makedirs(writers, exist_ok=True)
                return gen, create_locked(os.path.join(writers, f"{sid}~{gen}.lock"))
            except (FileNotFoundError, StoreError):
                continue  # raced with gc removing a temporary lock file: try another name
        raise StoreError(f"cannot create a writer lock in {writers}")

    @staticmethod
    def _drop_writer_lock(lock) -> None:
        try:
            os.remove(lock.path)
        except OSError:
            pass
        lock.release()

    def _write_generation(self, sid: str, gen: str, ds, written: str) -> None:
        path = os.path.join(self.path, self._gen_rel(sid, gen))
        for _ in range(10):
            try:
                os.makedirs(path)
                break
            except FileNotFoundError:  # gc removed an empty subject directory meanwhile
                continue
        out = ds.copy(deep=False)
        out.attrs = {k: v for k, v in ds.attrs.items() if k != STORE_ATTR}
        if "software_version" not in provenance(out):
            set_provenance(out, software_version=__version__)
        for name in list(out.variables):
            var = out.variables[name]
            if var.dtype.kind in "UST":
                obj = out[name].copy(data=np.asarray(var.values).astype(object))
                out = out.assign_coords({name: obj}) if name in out.coords else out.assign({name: obj})
        from zarr.codecs import BloscCodec

        encoding = {}
        for name, var in out.variables.items():
            var.encoding = {}
            enc = {}
            if "v" in var.dims and var.ndim >= 2:
                enc["chunks"] = tuple(
                    max(1, min(MAP_CHUNK_ROWS, s)) if d == "v" else max(1, s) for d, s in zip(var.dims, var.shape)
                )
            if var.dtype.kind == "f":  # byte shuffle + zstd: ~20 % smaller than plain zstd on smooth maps
                enc["compressors"] = [BloscCodec(cname="zstd", clevel=5, shuffle="shuffle")]
            if enc:
                encoding[name] = enc
        manifest = {name: _manifest_entry(var) for name, var in out.variables.items()}
        out.attrs[STORE_ATTR] = json.dumps(
            {
                "schema": SCHEMA_VERSION,
                "facestats_version": __version__,
                "written": written,
                "generation": gen,
                "manifest": manifest,
            }
        )
        try:
            out.to_zarr(path, mode="w", zarr_format=3, consolidated=False, encoding=encoding, write_empty_chunks=True)
        except Exception as exc:
            raise StoreError(f"writing subject {sid!r} to {path} failed: {type(exc).__name__}: {exc}") from exc
        _fsync_tree(path)

    def _commit(self, mutate):
        """Apply ``mutate(index)`` to a fresh copy of the index and replace it atomically, under the lock."""
        root = self.path
        with self._lock():
            index = read_index_file(root)
            result = mutate(index)
            for sid in index["subjects"]:
                node = os.path.join(root, SUBJECTS, sid, ROOT_META)
                if not os.path.exists(node):
                    _write_json_atomic(node, _group_meta())
            index["revision"] = int(index.get("revision", 0)) + 1
            index["updated"] = utc_now()
            index["facestats_version"] = __version__
            write_index_file(root, index)
            if self.root_attrs.get("facestats_version") != __version__:
                attrs = dict(self.root_attrs, facestats_version=__version__)
                _write_json_atomic(os.path.join(root, ROOT_META), _group_meta(attrs))
                self.root_attrs = attrs
                self.writer_version = __version__
        return result

    def _subject_dirs(self):
        """``(subject id, directory)`` of every directory under ``subjects/`` (directory stores), by id."""
        sub_root = os.path.join(self.path, SUBJECTS)
        for sid in sorted(os.listdir(sub_root)) if os.path.isdir(sub_root) else []:
            sdir = os.path.join(sub_root, sid)
            if os.path.isdir(sdir):
                yield sid, sdir

    def _remove_generation(self, sid: str, gen: str) -> None:
        """Delete an unreferenced generation: rename it aside (atomic), then remove it."""
        src = os.path.join(self.path, self._gen_rel(sid, gen))
        dst = os.path.join(self.path, SUBJECTS, sid, f"{_TRASH}{gen}")
        try:
            os.rename(src, dst)
        except OSError:
            return
        shutil.rmtree(dst, ignore_errors=True)

    # -- maintenance ---------------------------------------------------------------
    def gc(self) -> list[str]:
        """Remove what interrupted writers left (orphaned generations, temporary files, stale locks).

        Never removes a generation the index references or one whose writer
        is still running (its writer lock is held).  Decisions are taken under
        the store lock, so no commit can reference a generation being removed.
        Returns the removed paths relative to the store.
        """
        self._require_writable()
        root = self.path
        writers = os.path.join(root, WRITERS)
        doomed, held, emptied = [], [], []
        with self._lock():
            index = read_index_file(root)
            live = {(sid, e["generation"]) for sid, e in index["subjects"].items()}
            for sid, sdir in self._subject_dirs():
                keep = False
                for name in os.listdir(sdir):
                    p = os.path.join(sdir, name)
                    if name.startswith(_TRASH) or name.startswith(ROOT_META + ".tmp-"):
                        doomed.append(p)
                    elif not os.path.isdir(p):
                        continue
                    elif (sid, name) in live:
                        keep = True
                    else:
                        # The writer lock exists before the generation directory is created and
                        # stays held until the writer is done: check it *after* seeing the directory.
                        lockp = os.path.join(writers, f"{sid}~{name}.lock")
                        if os.path.exists(lockp):
                            lk = try_lock(lockp)
                            if lk is None:
                                keep = True  # its writer is alive
                                continue
                            held.append(lk)
                            doomed.append(lockp)
                        doomed.append(p)
                if not keep and sid not in index["subjects"]:
                    emptied.append(sdir)
                    try:
                        os.remove(os.path.join(sdir, ROOT_META))
                    except OSError:
                        pass
            for name in sorted(os.listdir(writers)) if os.path.isdir(writers) else []:
                p = os.path.join(writers, name)
                if p in doomed or not (is_lock_temp(name) or name.endswith(".lock")):
                    continue
                lk = try_lock(p)  # free: its writer is dead or done
                if lk is not None:
                    held.append(lk)
                    doomed.append(p)
            for name in os.listdir(root):
                if is_index_temp(name) or name.startswith(ROOT_META + ".tmp-"):
                    doomed.append(os.path.join(root, name))
        removed = []
        for p in doomed:
            if os.path.isdir(p):
                shutil.rmtree(p, ignore_errors=True)
            else:
                try:
                    os.remove(p)
                except OSError:
                    continue
            removed.append(os.path.relpath(p, root))
        for lk in held:
            lk.release()
        for sdir in emptied:
            try:  # fails harmlessly if a writer has started a new generation in it meanwhile
                os.rmdir(sdir)
                removed.append(os.path.relpath(sdir, root))
            except OSError:
                pass
        return removed

    def _orphans(self, index) -> list[str]:
        """Unreferenced generation directories and leftovers (directory stores), relative paths."""
        if self.kind != "directory":
            return []
        live = {(sid, e["generation"]) for sid, e in index["subjects"].items()}
        out = []
        for sid, sdir in self._subject_dirs():
            for name in sorted(os.listdir(sdir)):
                if os.path.isdir(os.path.join(sdir, name)) and (sid, name) not in live:
                    out.append(f"{SUBJECTS}/{sid}/{name}")
        out += [n for n in os.listdir(self.path) if is_index_temp(n)]
        return out

    def _rebuild_index(self) -> tuple[dict, list[str]]:
        """A new index from the newest intact generation of every subject directory."""
        from facestats.io.summary import albedo_histogram, summarise_subject

        index = empty_index(SCHEMA_VERSION, __version__)
        notes = []
        for sid, sdir in self._subject_dirs():
            gens = sorted((n for n in os.listdir(sdir) if _GEN_RE.match(n)), reverse=True)
            for gen in gens:
                if is_locked(os.path.join(self.path, WRITERS, f"{sid}~{gen}.lock")):
                    continue  # its writer is still running
                try:
                    ds = self._open_generation(sid, gen)
                except StoreError:
                    continue
                when = ds.encoding[STORE_ATTR].get("written", "")
                index["subjects"][sid] = make_entry(gen, when, summarise_subject(ds), albedo_histogram(ds))
                notes.append(f"recovered subject {sid!r} from generation {gen}")
                break
        return index, notes

    def validate(self, *, repair: bool = False) -> ValidationReport:
        """Check every subject and the agreement of the index with the data.

        Each indexed subject is opened (group present, manifest, dims, CRC-32,
        schema) and its index row and histograms are recomputed and compared.
        With ``repair=True`` (directory stores): a missing or unreadable index
        is rebuilt from the newest intact generation of each subject; subjects
        whose data are broken are dropped from the index; disagreeing rows are
        recomputed; then :meth:`gc` removes orphans.
        """
        from facestats.io.summary import albedo_histogram, summarise_subject

        if repair:
            self._require_writable()
        report = ValidationReport(path=self.label)
        try:
            index = self._index()
        except StoreError as exc:
            report.problems.append(str(exc))
            if not repair:
                return report
            with self._lock():
                index, notes = self._rebuild_index()
                write_index_file(self.path, index)
            report.repaired.append(f"rebuilt {INDEX_NAME} with {len(index['subjects'])} subject(s)")
            report.repaired += notes
            index = self._index()
        report.n_subjects = len(index["subjects"])
        drop, fix = {}, {}
        for sid in sorted(index["subjects"]):
            entry = index["subjects"][sid]
            gen = entry["generation"]
            try:
                ds = self._open_generation(sid, gen)
            except StoreError as exc:
                report.problems.append(str(exc))
                drop[sid] = gen
                continue
            report.n_checked += 1
            row, hist = summarise_subject(ds), albedo_histogram(ds)
            diff = _rows_differ(make_entry(gen, "", row, hist)["row"], entry["row"])
            if diff:
                report.problems.append(
                    f"subject {sid!r}: index row disagrees with the data in {diff[:5]}"
                    + (f" and {len(diff) - 5} more" if len(diff) > 5 else "")
                )
                fix[sid] = (gen, make_entry(gen, entry.get("written", ""), row, hist))
            elif np.asarray(entry["albedo_hist"]).tolist() != hist.tolist():
                report.problems.append(f"subject {sid!r}: index albedo histogram disagrees with the data")
                fix[sid] = (gen, make_entry(gen, entry.get("written", ""), row, hist))
        orphans = self._orphans(index)
        if orphans:
            report.notes.append(
                f"{len(orphans)} unreferenced item(s) left by interrupted or running writers "
                f"(e.g. {orphans[0]}); `facestats validate --repair` removes dead ones"
            )
        if repair and (drop or fix):

            def mutate(ix):
                for sid, gen in drop.items():
                    if ix["subjects"].get(sid, {}).get("generation") == gen:
                        del ix["subjects"][sid]
                        report.repaired.append(f"removed broken subject {sid!r} from the index")
                for sid, (gen, entry) in fix.items():
                    if ix["subjects"].get(sid, {}).get("generation") == gen:
                        ix["subjects"][sid] = entry
                        report.repaired.append(f"recomputed the index entry of subject {sid!r}")

            self._commit(mutate)
        if repair:
            removed = self.gc()
            if removed:
                report.repaired.append(f"removed {len(removed)} orphaned item(s)")
            after = self.validate()
            report.problems, report.notes = after.problems, after.notes
            report.n_subjects, report.n_checked = after.n_subjects, after.n_checked
        return report

    def info(self) -> dict:
        """Summary of the store: versions, counts by skin type/gender/condition/kind/age, size on disk."""
        from facestats.io.query import _breakdown

        index = self._index()
        t = self._table()
        n = len(t)
        counts = _breakdown(t, np.arange(n))
        return {
            "store": self.label,
            "path": self.path,
            "kind": self.kind,
            "read_only": self.read_only,
            "schema_version": self.schema_version,
            "writer_version": self.writer_version,
            "created": self.root_attrs.get("created"),
            "index_revision": int(index.get("revision", 0)),
            "updated": index.get("updated"),
            "n_subjects": n,
            "n_persons": len(set(t["person_id"].tolist())) if n else 0,
            "by_skin_type": counts["skin_type"],
            "by_gender": counts["gender"],
            "by_age_group": counts["age_group"],
            "by_condition": counts["condition"],
            "by_kind": counts["kind"],
            "size_bytes": self._b.size(),
        }


# -- packing -----------------------------------------------------------------------
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def pack_store(src, zip_path, *, overwrite: bool = False) -> Path:
    """Pack a directory store into a read-only zip store (e.g. the embedded default).

    The store is validated first (:class:`StoreError` if it is not valid);
    only the current generation of each subject, the root and subject group
    metadata and the index go into the zip, with fixed timestamps so the same
    store packs to the same bytes: the root ``zarr.json`` and ``index.json``
    first and stored (uncompressed, read without the zip directory), chunks
    stored (Zarr compressed them already), group and Zarr metadata deflated
    (Zarr metadata re-serialised without indentation).  The zip is written to
    a temporary file and moved into place, then opened and checked.

    Returns
    -------
    pathlib.Path
        ``zip_path``.
    """
    zip_path = Path(zip_path)
    if zip_path.exists() and not overwrite:
        raise StoreError(f"{zip_path} exists; pass overwrite=True to replace it")
    store = open_store(src, mode="r")
    if store.kind != "directory":
        raise StoreError(f"pack_store needs a directory store, got {store.kind} store {src}")
    try:
        lock = store._lock()
        lock.acquire()
    except StoreError:
        lock = None  # read-only source: pack without blocking writers
    try:
        report = store.validate()
        if not report.ok:
            raise StoreError(f"cannot pack {src}: it is not valid: " + "; ".join(report.problems[:3]))
        index = store._index()
        tmp = zip_path.with_name(f".{zip_path.name}.tmp-{os.getpid()}")
        zip_path.parent.mkdir(parents=True, exist_ok=True)

        def add(zf, arcname, data, deflate=False):
            info = zipfile.ZipInfo(arcname, date_time=_ZIP_TIME)
            # Chunks are compressed by Zarr already; subject metadata (JSON) deflates 5x.
            info.compress_type = zipfile.ZIP_DEFLATED if deflate else zipfile.ZIP_STORED
            info.external_attr = 0o644 << 16
            zf.writestr(info, data, compresslevel=9 if deflate else None)

        try:
            with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as zf:
                root = Path(store.path)
                add(zf, ROOT_META, (root / ROOT_META).read_bytes())
                add(zf, INDEX_NAME, json.dumps(index, separators=(",", ":"), allow_nan=False).encode())
                add(zf, f"{SUBJECTS}/{ROOT_META}", json.dumps(_group_meta(), indent=2).encode(), deflate=True)
                for sid in sorted(index["subjects"]):
                    add(zf, f"{SUBJECTS}/{sid}/{ROOT_META}", json.dumps(_group_meta(), indent=2).encode(), deflate=True)
                    gen = index["subjects"][sid]["generation"]
                    gdir = root / SUBJECTS / sid / gen
                    for f in sorted(p for p in gdir.rglob("*") if p.is_file()):
                        data = f.read_bytes()
                        meta = f.name == ROOT_META
                        if meta:  # Zarr metadata: drop the indentation (a third of a small subject)
                            data = json.dumps(json.loads(data), separators=(",", ":")).encode()
                        add(zf, f"{SUBJECTS}/{sid}/{gen}/{f.relative_to(gdir).as_posix()}", data, deflate=meta)
            os.replace(tmp, zip_path)
        except BaseException:
            if tmp.exists():
                tmp.unlink()
            raise
    finally:
        if lock is not None:
            lock.release()
        store.close()
    with open_store(zip_path) as packed:
        report = packed.validate()
        if not report.ok:  # pragma: no cover - would be a bug in the packer
            raise StoreError(f"packed store {zip_path} does not validate: {report.problems[:3]}")
    return zip_path
