"""The facestats parameter store API: :func:`open_store` and :class:`Store`.

A store holds one Zarr v3 group per subject (an xarray Dataset following
:mod:`facestats.io.schema`) and a population index (:mod:`facestats.io.index`);
its files are laid out as :mod:`facestats.io.layout` describes, in a directory
or a read-only zip (:mod:`facestats.io.backends`, :mod:`facestats.io.packing`).
A subject group holds the schema variables with their ``units``/``long_name``
attributes, the subject's metadata and provenance as group attributes, and the
bookkeeping attribute ``facestats_store`` with a manifest of every variable
(:mod:`facestats.io.integrity`); map variables are chunked in blocks of
:data:`MAP_CHUNK_ROWS` rows of ``v``, so a texel range of any map can be read
alone (``store.subject(id, lazy=True).isel(v=slice(0, 64))``).

Writes
------
Each write creates a *fresh generation* ``subjects/<id>/<generation>/`` with
its record (:mod:`facestats.io.generations`, :mod:`facestats.io.records`) and
commits by replacing ``index.json`` atomically under the store lock
(:mod:`facestats.io.commit`): a writer killed at any moment leaves the old
subject (or none) or the new one.  Writers write in parallel, commits are
serialised and re-read the index (no lost update); a batch
(:meth:`Store.write_subjects`) commits all its subjects at once.
:meth:`Store.gc`, :meth:`Store.validate`, :meth:`Store.plan_repair`,
:meth:`Store.repair` and the quarantine (:mod:`facestats.io.maintenance`,
:mod:`facestats.io.repair`, :mod:`facestats.io.quarantine`) never touch a live
writer's data, what the store did not create, or anything outside it; repair
never deletes data.  Design: ``docs/store.md``.

Reads
-----
Readers take the current index (every entry checked) and open the generation it
names, retrying if a concurrent writer replaced it.  Every read verifies
(:func:`facestats.io.integrity.open_generation`): manifest, dims, shapes,
dtypes, CRC-32 of the bytes (lazy reads chunk by chunk as they load), the
schema and its physical domains; problems raise
:class:`~facestats.errors.SchemaError` naming the subject and the variable.

``open_store(None)`` opens the embedded default, ``facestats/data/default_store.zip``.
``open_store``, :meth:`Store.query`, :meth:`Store.info` and the index import
only numpy and the standard library; xarray, zarr and pandas are imported
when a subject or a DataFrame is needed.
"""

from __future__ import annotations

import contextlib
import os
import threading
import zipfile
from pathlib import Path
from urllib.parse import urlparse

import numpy as np

from facestats.core.conventions import DEFAULT_STORE, TEXTURE_SAMPLE
from facestats.core.outputs import url_scheme
from facestats.core.validate import check_choice
from facestats.errors import SchemaError, StoreError, ValidationError
from facestats.io.backends import DirectoryBackend, ZipBackend
from facestats.io.batch import batch_commit, prepare_batch, refuse_existing
from facestats.io.commit import commit_index, generations_of
from facestats.io.generations import (
    MAP_CHUNK_ROWS,
    abandon_generations,
    drop_writer_lock,
    remove_generation,
    reserve_generation,
    write_generation,
)
from facestats.io.ids import check_subject_id
from facestats.io.index import INDEX_NAME, index_table, parse_index, read_index_file, utc_now
from facestats.io.integrity import STORE_ATTR, open_generation
from facestats.io.layout import ROOT_META, generation_rel, is_plain_dir, store_lock
from facestats.io.locking import FileLock
from facestats.io.maintenance import ValidationReport, check_subjects, collect_garbage, directory_notes
from facestats.io.quarantine import list_quarantine, purge_quarantine
from facestats.io.query import breakdown, run_query
from facestats.io.repair import RepairPlan, apply_repair, plan_repair
from facestats.io.root import create_store, read_root_attrs
from facestats.io.schema import MAP_REQUIRED, SAMPLE_REQUIRED, SCHEMA_VERSION

__all__ = [
    "Store",
    "ValidationReport",
    "RepairPlan",
    "open_store",
    "default_store_path",
    "MAP_CHUNK_ROWS",
    "STORE_ATTR",
]


def default_store_path() -> Path:
    """Where the embedded default store lives: ``facestats/data/default_store.zip``."""
    return Path(__file__).resolve().parent.parent / "data" / "default_store.zip"


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
        Seconds a writer waits for the store lock before :class:`StoreError`, in [0, 86400].

    Returns
    -------
    Store
        The store (close it, or use it as a context manager).

    Raises
    ------
    ValidationError
        ``mode`` or ``lock_timeout`` out of range (NaN, a negative number, not a number).
    StoreError
        Missing or unreadable store, read-write access to a zip store, or the
        default store not built yet.
    SchemaError
        A store written with a schema version this facestats cannot read.
    """
    check_choice(mode, "mode", ("r", "r+", "a"))
    lock_timeout = _check_lock_timeout(lock_timeout)
    if path is None:
        return _open_default(mode, lock_timeout)
    p = _store_path(path)
    if p.exists() and not (p.is_file() or p.is_dir()):
        raise StoreError(f"store {p} is neither a directory nor a zip file (it is a FIFO, socket or device)")
    if p.is_file():
        return _open_zip(p, mode, lock_timeout)
    if not p.exists() or (p.is_dir() and not (p / ROOT_META).exists()):
        if mode != "a":
            what = "does not exist" if not p.exists() else "is not a facestats store (no zarr.json)"
            raise StoreError(f"store {p} {what}{_embedded_name_hint(path)}")
        if p.suffix == ".zip":
            raise StoreError(f"cannot create zip store {p}: create a directory store and pack it with pack_store")
        create_store(p)
    return Store(DirectoryBackend(str(p)), read_only=(mode == "r"), label=str(p), lock_timeout=lock_timeout)


def _embedded_name_hint(path) -> str:
    """What a missing store named like the command line's embedded stores (``--store default``,
    ``--store texture-sample``) is opened with in Python, or ''."""
    if path == DEFAULT_STORE:
        return f"; the command line's --store {DEFAULT_STORE} is open_store() with no path (the embedded store)"
    if path == TEXTURE_SAMPLE:
        return (
            f"; the command line's --store {TEXTURE_SAMPLE} is open_store(texture_sample()), texture_sample from "
            "facestats.pipeline.texture_sample (built into the cache on first use)"
        )
    return ""


#: Longest wait for the store lock ``open_store`` accepts (a day): commits hold it for milliseconds.
MAX_LOCK_TIMEOUT = 86400.0


def _check_lock_timeout(value) -> float:
    """``lock_timeout`` as a float, or :class:`ValidationError` naming it unless it is a number of seconds in
    [0, :data:`MAX_LOCK_TIMEOUT`] (NaN would wait forever, a string fail late, a negative time out at once)."""
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    if not ok or not 0 <= float(value) <= MAX_LOCK_TIMEOUT:  # NaN fails too
        raise ValidationError(f"lock_timeout must be a number of seconds in [0, {MAX_LOCK_TIMEOUT:g}], got {value!r}")
    return float(value)


def _open_default(mode: str, lock_timeout: float) -> "Store":
    zp = default_store_path()
    if not zp.is_file():
        raise StoreError(
            f"the embedded default store has not been built ({zp} is missing); build it with "
            "`facestats build` or pass --store PATH to use another store"
        )
    if mode != "r":
        raise StoreError("the embedded default store is read-only; pass --store PATH to write to a directory store")
    return Store(ZipBackend(str(zp)), read_only=True, label="default", lock_timeout=lock_timeout)


def _open_zip(p: Path, mode: str, lock_timeout: float) -> "Store":
    if not zipfile.is_zipfile(p):
        raise StoreError(f"{p} is neither a store directory nor a zip store")
    if mode != "r":
        raise StoreError(
            f"zip store {p} is read-only; write to a directory store (e.g. --store {p.with_suffix('.zarr')})"
        )
    return Store(ZipBackend(str(p)), read_only=True, label=str(p), lock_timeout=lock_timeout)


def _store_path(path) -> Path:
    """``path`` as a :class:`~pathlib.Path`; :class:`ValidationError` unless it is a non-empty str or path-like."""
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    if not isinstance(path, (str, os.PathLike)):
        raise ValidationError(f"path must be a store path (str or os.PathLike) or None, got {type(path).__name__}")
    text = os.fspath(path)
    if not text.strip() or "\x00" in text:
        raise ValidationError(f"path must name a store (a directory or a zip file), got {text!r}")
    scheme = url_scheme(text)
    if scheme == "file":  # file:///data/pop.zarr, as `facestats build --store` accepts
        text = urlparse(text).path
    elif scheme:
        raise StoreError(
            f"store {text!r} is a {scheme}:// location: facestats opens stores on a file system (a path or a "
            "file:// URL); copy it to a local or shared disk first"
        )
    return Path(text).expanduser()


def _variable_names(variables, name: str = "variables") -> list[str]:
    """``variables`` of :meth:`Store.subject` as a list of names; :class:`ValidationError` naming it otherwise.

    A single string is refused rather than taken letter by letter (``"albedo"`` is not ``["a", "l", ...]``).
    """
    if isinstance(variables, (str, bytes)):
        raise ValidationError(
            f"{name} must be a list of variable names, got the string {variables!r} (write [{variables!r}])"
        )
    try:
        names = list(variables)
    except TypeError:
        raise ValidationError(f"{name} must be a list of variable names, got {type(variables).__name__}") from None
    bad = [v for v in names if not isinstance(v, str)]
    if bad:
        raise ValidationError(f"{name} must be a list of variable names (strings), got {bad[0]!r} among them")
    return names


def _excluded_names(exclude) -> list[str]:
    """``exclude`` of :meth:`Store.subject`: optional data variables only (a subject without one stays valid;
    coordinates are refused when the subject is opened, :func:`facestats.io.integrity.open_generation`)."""
    names = _variable_names(exclude, "exclude")
    required = [n for n in names if n in MAP_REQUIRED or n in SAMPLE_REQUIRED]
    if required:
        raise ValidationError(
            f"exclude may name optional variables only (e.g. 'micro_normal'), got {required[0]!r}, which a subject "
            "must have"
        )
    return names


# -- the store ---------------------------------------------------------------------
class _SynchronousDask:
    """Dask's scheduler set to ``"synchronous"`` while at least one write of lazy data runs, then restored.

    ``dask.config.set`` changes the whole process's configuration, not one thread's: two threads each
    setting and restoring it would undo each other's setting (a red team: the first writer to finish
    restored the thread pool under the second, whose tasks then outlived its failed write, and the last
    to finish left ``"synchronous"`` for good).  Here the first writer sets it, the last one restores what
    was there before the first, and a lock orders them.
    """

    def __init__(self):
        self._lock = threading.Lock()
        self._users = 0
        self._restore = None

    @contextlib.contextmanager
    def __call__(self):
        import dask  # local import: only a write of data read with on_disk (or built lazily) needs it

        with self._lock:
            if self._users == 0:
                self._restore = dask.config.set(scheduler="synchronous")
            self._users += 1
        try:
            yield
        finally:
            with self._lock:
                self._users -= 1
                if self._users == 0:
                    self._restore.__exit__(None, None, None)
                    self._restore = None


_synchronous_dask = _SynchronousDask()


def _lazy_data_computed_here(datasets):
    """A context computing dask arrays in the calling thread, one task at a time, whatever scheduler (e.g. a
    distributed client) is the default; nothing (and no dask import) if no variable of ``datasets`` is a dask array.

    One task at a time holds one band (25 MB of a 2048² micro-normal map of 16 cameras) however many cores the
    machine has, and leaves no task running after a failure, which could write chunks into a generation after it
    was abandoned (a helper's red team found such strays with a thread pool).  It is no slower: zarr-python decodes
    and encodes the chunks of a band concurrently itself (a colour edit of the 2048² subject of
    ``bench_edit.bench_colour_edit``: 11.9-13.1 s either way, 2026-12-07).  Writes in several threads at once
    share the setting (:class:`_SynchronousDask`); meanwhile other dask work of the process runs synchronously
    too.
    """
    lazy = any(var.chunks is not None for ds in datasets if hasattr(ds, "data_vars") for var in ds.data_vars.values())
    return _synchronous_dask() if lazy else contextlib.nullcontext()


class Store:
    """A facestats parameter store (see the module docstring); create with :func:`open_store`.

    Parameters
    ----------
    backend : DirectoryBackend or ZipBackend
        Byte access to the store's files (:mod:`facestats.io.backends`); its root attributes are read at once.
    read_only : bool
        Refuse every write (:class:`StoreError`).
    label : str
        The store's name in messages and query reports (the path, or ``"default"``).
    lock_timeout : float
        Seconds a writer waits for the store lock before :class:`StoreError`.

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
        self.root_attrs = read_root_attrs(backend, label)
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

    def _require_writable(self) -> None:
        if self.read_only:
            if self.kind == "zip":
                raise StoreError(
                    f"store {self.label} is a read-only zip store; write to a directory store instead "
                    "(pass --store PATH, or open_store(PATH, mode='a'))"
                )
            raise StoreError(f"store {self.label} was opened read-only; open it with mode='r+' or 'a' to write")

    def _lock(self) -> FileLock:
        return store_lock(self.path, self.lock_timeout)

    # -- index -------------------------------------------------------------------
    def _index(self) -> dict:
        """The current index document (re-read when the file changed)."""
        key = self._b.index_key()
        if key is None:
            if self.kind != "directory":
                raise StoreError(
                    f"store {self.label} has no {INDEX_NAME}; a zip store is read-only: unpack it, rebuild the index "
                    "with `facestats validate --repair --yes` on the directory, and pack it again"
                )
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

        One row per subject, sorted by id (the order of :meth:`albedo_histograms`); the columns are those of
        :func:`facestats.io.summary.summarise_subject` (its module docstring has them all).  Missing quantities
        are NaN.

        Three different things are called "std" or "se" (``p`` a BRDF parameter ``ts_rho_s``, ``ts_m``,
        ``bp_rho_s`` or ``bp_exponent``, ``r`` a region 1-10 of Weyrich Fig. 15):

        * ``{p}_std_r{r}``: the **spread of the values** inside the region, the sample standard deviation
          (ddof 1) of the region's unflagged texel values, beside their mean ``{p}_mean_r{r}`` and count
          ``n_ts_r{r}`` / ``n_bp_r{r}`` — not an uncertainty;
        * ``{p}_se_r{r}``: the typical **standard error of one texel's fit**, the root mean square of the
          subject's ``{p}_std`` map (a per-texel standard error, :meth:`subject`) over the region's unflagged
          texels that the fit *determines* only: standard error at most the value's magnitude
          (:func:`facestats.io.summary.determined`).  The others have linearised errors of up to thousands of
          times their value, which say only that the fit leaves the value open; they stay in the mean and the
          spread but not here, so the RMS of the whole map over the region can be far larger (nose of S013 of
          the default store: 0.93 over all 56 texels, 0.028 here, the three it leaves out up to 6.9 for
          ρs ≈ 0.31).  :func:`facestats.io.summary.region_undetermined` counts them per region;
        * ``{p}_mean_se_r{r}``: the **standard error of the region mean**, sqrt(Σσ²)/n over the same determined
          texels.

        The ``se`` columns are NaN for subjects without standard-error maps (sample subjects, stores written
        before them, parameters changed by an edit).  Other columns: ``{ts,bp}_cov_r{r}`` (covariance of the
        region's (scale, lobe) pairs, ddof 1), the scattering coefficients per site
        (``site_sigma_tr_{site}_{ch}``, …) and per subject (``sigma_tr_{ch}``, …; ``sigma_tr`` is the population's
        σtrAvg in every measured subject, Weyrich §5.4), ``albedo_mean_{ch}``, ``albedo_std_{ch}`` (the spread
        over the face) and ``flagged_fraction``.  See also ``docs/store.md`` (The population index).

        Returns
        -------
        pandas.DataFrame
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

    def query(self, skin_type=None, gender=None, age=None, condition="normal", region=None, edits=False):
        """Population statistics of the subjects matching the filters (:class:`facestats.io.query.QueryResult`).

        See :mod:`facestats.io.query` for the filters (skin types I and II are
        grouped; ``edits=True`` also matches subjects written by an edit), the
        statistics and the JSON form.

        Parameters
        ----------
        skin_type : int, str or sequence, optional
            Fitzpatrick type, Roman (``"IV"``) or 1-6, or several (``"V,VI"``, a list); I or II matches subjects of
            both.
        gender : str or int, optional
            ``"M"``/``"F"`` (also male/female, 0 = M, 1 = F).
        age : str, int or pair, optional
            ``"20s"``, ``"30s"``, ``"40s"``, ``"50s+"``, ``"MIN-MAX"``, one age or ``(MIN, MAX)`` (inclusive, years).
        condition : str or None
            One of ``facestats.core.conventions.CONDITIONS`` (default ``"normal"``, the population as the paper
            analyses it); ``"any"`` or None match every condition (one person's records under several conditions
            then count separately).
        region : int or str, optional
            Restricts the per-region BRDF section to one region (1-10 or a name); it does not select subjects.
        edits : bool
            Also match subjects written by an edit (default: measured subjects only).

        Returns
        -------
        facestats.io.query.QueryResult

        Raises
        ------
        ValidationError
            An invalid filter value.
        StoreError
            The index is missing or cannot be read.
        """

        return run_query(
            self._table(),
            skin_type=skin_type,
            gender=gender,
            age=age,
            condition=condition,
            region=region,
            edits=edits,
            store=self.label,
        )

    # -- reading subjects ----------------------------------------------------------
    def _open_generation(self, sid: str, gen: str, **kw):
        """Open and check one generation (:func:`facestats.io.integrity.open_generation`'s keywords)."""
        return open_generation(self._b, sid, gen, label=self.label, **kw)

    def _check_generation(self, sid: str, gen: str):
        """Open one generation and check everything, the per-chunk checksums too, large maps band by band (validate,
        repair)."""
        return open_generation(self._b, sid, gen, label=self.label, check_chunks=True, banded=True)

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

    def subject(self, subject_id, *, lazy: bool = False, variables=None, exclude=None, on_disk=None):
        """One subject as an :class:`xarray.Dataset`.

        Parameters
        ----------
        subject_id : str
            The subject's id (``str()`` of it is looked up in the index).
        lazy : bool
            With ``lazy=False`` (default) every variable is loaded, checked against its stored CRC-32 and the
            subject validated against the schema.  With ``lazy=True`` only metadata are checked (dims, shapes,
            dtypes) and variables are read on access, chunk by chunk (e.g. a 64-row band of a map); a lazy
            Dataset may fail if a concurrent writer replaces the subject before it is read (a
            :class:`StoreError` saying so).
        variables : list of str, optional
            With ``lazy=True``: names variables to load and CRC-verify now; the others stay lazy.
        exclude : list of str, optional
            Names optional data variables to leave out, never read (e.g. ``["micro_normal"]``, 805 MB of a
            2048² subject fitted from 16 cameras, for a reader that needs the other maps); names the subject
            lacks are ignored, and the rest is loaded and checked as without it.
        on_disk : list of str, optional
            With ``lazy=False``: names map variables to leave on disk as dask arrays of one stored band of rows
            per chunk, each band CRC-verified when computed but not validated (an edit passes the source's
            micro-normals on this way; writing them validates them); the others are loaded and checked as
            without it (:func:`facestats.io.integrity.open_generation`).

        Returns
        -------
        xarray.Dataset

        Raises
        ------
        ValidationError
            ``variables`` without ``lazy=True``, ``on_disk`` with it, a name list that is a string or holds
            a non-string, ``exclude`` naming a required variable or a variable also in ``variables``/``on_disk``.
        StoreError
            No such subject, or the index or the data cannot be read.
        SchemaError
            The subject fails its checks (manifest, dims, CRC-32, schema, physical domains).
        """
        if variables is not None and not lazy:
            raise ValidationError("variables requires lazy=True (without it every variable is loaded and verified)")
        if on_disk is not None and lazy:
            raise ValidationError("on_disk requires lazy=False (with lazy=True every variable stays on disk)")
        variables = None if variables is None else _variable_names(variables)
        exclude = () if exclude is None else _excluded_names(exclude)
        on_disk = () if on_disk is None else _variable_names(on_disk, "on_disk")
        both = sorted(set(exclude) & (set(variables or ()) | set(on_disk)))
        if both:
            other = "variables" if variables else "on_disk"
            raise ValidationError(f"exclude and {other} both name {both[0]!r}: a variable is either read or left out")
        return self._load(str(subject_id), lazy=lazy, variables=variables, exclude=exclude, on_disk=on_disk)

    # -- writing -----------------------------------------------------------------
    def write_subject(self, dataset, *, overwrite: bool = False, precondition=None) -> str:
        """Write one subject atomically; return its id.

        The Dataset is validated first (:func:`facestats.io.schema.validate_subject`)
        and refused without touching the store if invalid.  An existing id
        raises :class:`StoreError` unless ``overwrite=True``, which replaces
        the subject atomically (readers see the old or the new version).
        Edits must write a new id with ``source_subject`` and ``edit`` in
        their provenance rather than overwrite their source.

        Parameters
        ----------
        dataset : xarray.Dataset
            A valid subject.
        overwrite : bool
            Replace the subject if its id exists.
        precondition : callable, optional
            As in :meth:`write_subjects`.

        Returns
        -------
        str
            The subject id.

        Raises
        ------
        StoreError
            The store is read-only, or the id exists and ``overwrite`` is False.
        ValidationError, SchemaError
            An invalid subject (:func:`facestats.io.batch.prepare_batch`).
        """
        return self.write_subjects([dataset], overwrite=overwrite, precondition=precondition)[0]

    def write_subjects(self, datasets, *, overwrite: bool = False, precondition=None) -> list[str]:
        """Write several subjects and commit them together (all or none); return their ids.

        Variables held as dask arrays (e.g. read with ``on_disk``) are validated, checksummed and
        written band by band, computed in this thread one task at a time whatever dask scheduler is
        the default (a distributed client included): one band of a variable is in memory at once,
        and no task is left running after a failure, when the generation being written is removed.

        Parameters
        ----------
        datasets : iterable of xarray.Dataset
            Valid subjects with distinct ids; all are checked before anything is written.
        overwrite : bool
            Replace subjects that exist (otherwise :class:`StoreError`, nothing written).
        precondition : callable, optional
            ``precondition(store)``, called while the store's commit lock is held, after the subjects'
            data are written and just before the index names them: no other writer can commit between
            its check and this commit.  An exception it raises aborts the write (nothing is committed,
            the data written are removed) and propagates.  It may read the store, never write to it.

        Returns
        -------
        list of str
            The subject ids, in order.

        Raises
        ------
        StoreError
            The store is read-only, or an id exists and ``overwrite`` is False.
        ValidationError, SchemaError
            An invalid subject or an id twice in the batch (:func:`facestats.io.batch.prepare_batch`).
        """
        self._require_writable()
        datasets = list(datasets)
        with _lazy_data_computed_here(datasets):
            return self._write_subjects(datasets, overwrite, precondition)

    def _write_subjects(self, datasets, overwrite, precondition):
        prepared = prepare_batch(datasets)
        if not prepared:
            return []
        if not overwrite:
            refuse_existing(self._index(), {sid for sid, *_ in prepared})
        written = []  # (sid, gen, lock, when)
        superseded = []
        try:
            for sid, ds, _, _ in prepared:
                when = utc_now()
                gen, lock = reserve_generation(self.path, sid, when)
                written.append((sid, gen, lock, when))
                write_generation(self.path, sid, gen, ds, when)
            commit = batch_commit(prepared, written, overwrite, superseded)
            if precondition is not None:
                unchecked = commit

                def commit(index):
                    precondition(self)
                    return unchecked(index)

            self._commit(commit)
        except BaseException:
            abandon_generations(self.path, written)
            raise
        for _, _, lock, _ in written:
            drop_writer_lock(lock)
        for sid, gen in superseded:
            self._remove_generation(sid, gen)
        return [sid for sid, *_ in written]

    def delete_subject(self, subject_id) -> None:
        """Remove a subject (atomic: the index drops it, then its data are deleted).

        Parameters
        ----------
        subject_id : str
            The subject's id.

        Raises
        ------
        ValidationError
            ``subject_id`` is not a valid subject id.
        StoreError
            The store is read-only, or has no such subject.
        """
        self._require_writable()
        sid = check_subject_id(subject_id)
        gone = []

        def mutate(index):
            if sid not in index["subjects"]:
                raise StoreError(f"no subject {sid!r} in store {self.label}")
            gone.append(index["subjects"].pop(sid)["generation"])

        self._commit(mutate)
        self._remove_generation(sid, gone[0])

    def _commit(self, mutate):
        """Apply ``mutate(index)`` to a fresh copy of the index and commit it (:mod:`facestats.io.commit`)."""
        with self._lock():
            index = read_index_file(self.path)
            before = generations_of(index)
            result = mutate(index)
            self._set_root_attrs(commit_index(self.path, index, before, self.root_attrs, label=self.label))
        return result

    def _set_root_attrs(self, attrs: dict) -> None:
        self.root_attrs = attrs
        self.writer_version = str(attrs.get("facestats_version", "unknown"))

    def _remove_generation(self, sid: str, gen: str) -> None:
        """Delete an unreferenced generation: rename it aside (atomic), then remove it."""
        remove_generation(self.path, sid, gen)

    # -- maintenance ---------------------------------------------------------------
    def gc(self) -> list[str]:
        """Remove what interrupted writers left (their generations, temporary files, stale locks).

        Removes only what is provably the store's own and of no use
        (:func:`facestats.io.maintenance.survey`): never a generation the
        index names, one whose writer is still running, a committed one the
        index lost (repair recovers it), one holding files Zarr did not
        write, nor anything the store did not create (links, other files);
        decisions are taken under the store lock, and the generations to
        delete are renamed aside under it (removed after it is released), so
        no concurrent commit or repair can name them again.
        Returns the removed paths relative to the store.
        """
        self._require_writable()
        return collect_garbage(self.path, self._lock())

    def validate(
        self, *, repair: bool = False, allow_missing: bool = False, progress: bool = False
    ) -> ValidationReport:
        """Check every subject and the agreement of the index with the data.

        Each indexed subject is opened (group present, manifest, dims, CRC-32,
        schema and physical domains) and its index row and histograms are
        recomputed and compared; leftovers, items that are not the store's and
        the quarantine are reported as notes.  ``repair=True`` applies the
        repair plan (:meth:`plan_repair`, :meth:`repair`) and reports the state
        after it.

        Parameters
        ----------
        repair : bool
            Apply the repair (directory stores opened read-write).
        allow_missing : bool
            With ``repair``: act even if most subject folders are missing (:meth:`plan_repair`).
        progress : bool
            Show a progress bar while the subjects are checked.

        Returns
        -------
        ValidationReport
            After a repair, the problems and notes of a second validation.
        """
        if repair:
            return self.repair(allow_missing=allow_missing, progress=progress)
        report = ValidationReport(path=self.label)
        try:
            index = self._index()
        except StoreError as exc:  # includes SchemaError
            report.problems.append(str(exc))
            self._directory_notes(report, None)
            return report
        report.n_subjects = len(index["subjects"])
        exists = None
        if self.kind == "directory":

            def exists(sid, gen):
                return is_plain_dir(os.path.join(self.path, generation_rel(sid, gen)))

        reread = self._fresh_entries
        check_subjects(
            index, self._check_generation, report, reread=reread, generation_exists=exists, progress=progress
        )
        self._directory_notes(report, index)
        return report

    def _fresh_entries(self) -> dict:
        """The entries of the index as it is now (empty if it cannot be read)."""
        try:
            return self._index()["subjects"]
        except StoreError:
            return {}

    def _directory_notes(self, report: ValidationReport, index) -> None:
        """Problems and notes of a directory store beyond its subjects (:mod:`facestats.io.maintenance`)."""
        if self.kind == "directory":
            problems, notes = directory_notes(self.path, self.label, index)
            report.problems += problems
            report.notes += notes

    def plan_repair(self, *, allow_missing: bool = False, progress: bool = False) -> RepairPlan:
        """What :meth:`repair` would do, without changing anything (:mod:`facestats.io.repair`).

        Parameters
        ----------
        allow_missing : bool
            Plan even if the folders of most indexed subjects are missing (otherwise the store looks
            unmounted or half-present and repair refuses).
        progress : bool
            Show a progress bar while the subjects are checked.

        Returns
        -------
        facestats.io.repair.RepairPlan
            What :meth:`repair` would do.

        Raises
        ------
        StoreError
            A zip store, or a store repair refuses to act on (the message says why).
        """
        if self.kind != "directory":
            raise StoreError(f"store {self.label} is a read-only zip store: it cannot be repaired")
        return plan_repair(
            self.path,
            label=self.label,
            open_generation=self._check_generation,
            allow_missing=allow_missing,
            progress=progress,
        )

    def repair(
        self, plan: RepairPlan | None = None, *, allow_missing: bool = False, progress: bool = False
    ) -> ValidationReport:
        """Apply a repair plan (default: :meth:`plan_repair` now), collect garbage, and validate again.

        Damaged data are moved to the quarantine (``quarantine/``, listed by
        :meth:`validate`, deleted only by :meth:`purge_quarantine`), never
        deleted; see :mod:`facestats.io.repair` for the rules.

        Parameters
        ----------
        plan : facestats.io.repair.RepairPlan, optional
            The plan to apply (e.g. one :meth:`plan_repair` showed); default a plan made now.
        allow_missing : bool
            Without ``plan``: act even if most subject folders are missing (:meth:`plan_repair`).
        progress : bool
            Without ``plan``: show a progress bar while the subjects are checked.

        Returns
        -------
        ValidationReport
            ``repaired`` lists what was done; problems and notes are those of the validation after it.

        Raises
        ------
        StoreError
            The store is read-only, or this process may not write where the plan would
            (:func:`facestats.io.repair.check_writable`; nothing was changed).  A plan with nothing to do takes no
            lock and writes nothing, so a store read-only to this user with nothing to repair is only validated.
        """
        self._require_writable()
        plan = self.plan_repair(allow_missing=allow_missing, progress=progress) if plan is None else plan
        if plan.empty:  # no lock taken: a store this user may not write, with nothing to repair, is valid (exit 0)
            report = self.validate()
            report.repaired = []
            return report
        done, attrs = apply_repair(self.path, plan, label=self.label, lock=self._lock(), root_attrs=self.root_attrs)
        self._set_root_attrs(attrs)
        removed = self.gc()
        if removed:
            done.append(f"removed {len(removed)} leftover item(s) of interrupted writes")
        report = self.validate()
        report.repaired = done
        return report

    def quarantine(self) -> list[dict]:
        """The folders repairs moved data into (:func:`facestats.io.quarantine.list_quarantine`)."""
        return list_quarantine(self.path) if self.kind == "directory" else []

    def purge_quarantine(self, names=None) -> list[str]:
        """Delete the quarantine (all folders, or those named); the folders removed.

        Parameters
        ----------
        names : collection of str, optional
            Names of the quarantine folders to remove (as :meth:`quarantine` lists them); default all.

        Returns
        -------
        list of str
            The folders removed, relative to the store root.

        Raises
        ------
        StoreError
            The store is read-only (zip stores always are), or a folder cannot be removed.
        """
        self._require_writable()
        return purge_quarantine(self.path, names)

    def info(self) -> dict:
        """Summary of the store: versions, counts by skin type/gender/condition/kind/age, size on disk."""

        index = self._index()
        t = self._table()
        n = len(t)
        counts = breakdown(t, np.arange(n))
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
