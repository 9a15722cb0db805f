"""Packing a directory store into a read-only zip store (e.g. the embedded default).

``facestats/data/default_store.zip`` is a store packed by :func:`pack_store`:
a zip of the directory layout (:mod:`facestats.io.layout`) holding only the
current generations; chunk entries stored uncompressed since Zarr chunks are
compressed already, subject metadata deflated; the root ``zarr.json`` and
``index.json`` first and stored, so :mod:`facestats.io.backends` reads them
without the zip directory.  Timestamps are fixed, so the same store packs to
the same bytes.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

from facestats.core.outputs import check_apart, check_output_file
from facestats.errors import StoreError
from facestats.io.index import INDEX_NAME, read_index_file
from facestats.io.layout import ROOT_META, SUBJECTS, group_meta, store_lock, walk
from facestats.io.store import open_store

__all__ = ["pack_store"]

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

    Parameters
    ----------
    src : str or os.PathLike
        The directory store.
    zip_path : str or os.PathLike
        The zip store to write.
    overwrite : bool
        Replace an existing ``zip_path`` (otherwise :class:`StoreError`).

    Returns
    -------
    pathlib.Path
        ``zip_path``.

    Raises
    ------
    ValidationError
        ``zip_path`` is the store or lies inside it (it would replace or mix into the store's files), or cannot
        be written (:func:`facestats.core.outputs.check_output_file`).
    StoreError
        ``zip_path`` exists (without ``overwrite``), or the store is not valid.
    """
    check_apart(zip_path, src, "zip_path", "the source store")  # never a file inside the store it packs
    zip_path = Path(zip_path)
    if zip_path.exists() and not overwrite:
        raise StoreError(f"{zip_path} exists; pass overwrite=True to replace it")
    check_output_file(zip_path, "zip_path")  # before the validation: a path that cannot be written (e.g. in /proc)
    store = open_store(src, mode="r")
    if store.kind != "directory":
        raise StoreError(f"pack_store needs a directory store, got {store.kind} store {src}")
    lock = _try_lock(store)
    try:
        report = store.validate()
        if not report.ok:
            raise StoreError(f"cannot pack {src}: it is not valid: " + "; ".join(report.problems[:3]))
        _write_zip_atomic(Path(store.path), read_index_file(store.path), zip_path)
    finally:
        if lock is not None:
            lock.release()
        store.close()
    with open_store(zip_path) as packed:
        report = packed.validate()
        if not report.ok:  # pragma: no cover - would be a bug in the packer
            raise StoreError(f"packed store {zip_path} does not validate: {report.problems[:3]}")
    return zip_path


def _try_lock(store):
    """The held store lock of ``store``, or None if it cannot be taken (read-only source)."""
    lock = store_lock(store.path, store.lock_timeout)
    try:
        lock.acquire()
    except StoreError:
        return None  # read-only source: pack without blocking writers
    return lock


def _write_zip_atomic(root: Path, index: dict, zip_path: Path) -> None:
    """Write the zip of the store at ``root`` to a temporary file and move it to ``zip_path``."""
    tmp = zip_path.with_name(f".{zip_path.name}.tmp-{os.getpid()}")
    zip_path.parent.mkdir(parents=True, exist_ok=True)
    try:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as zf:
            _add(zf, ROOT_META, (root / ROOT_META).read_bytes())
            _add(zf, INDEX_NAME, json.dumps(index, separators=(",", ":"), allow_nan=False).encode())
            _add(zf, f"{SUBJECTS}/{ROOT_META}", json.dumps(group_meta(), indent=2).encode(), deflate=True)
            for sid in sorted(index["subjects"]):
                _add_subject(zf, root, sid, index["subjects"][sid]["generation"])
        os.replace(tmp, zip_path)
    except BaseException:
        if tmp.exists():
            tmp.unlink()
        raise


def _add_subject(zf, root: Path, sid: str, gen: str) -> None:
    """Add a subject's group metadata and every file of its current generation."""
    _add(zf, f"{SUBJECTS}/{sid}/{ROOT_META}", json.dumps(group_meta(), indent=2).encode(), deflate=True)
    gdir = root / SUBJECTS / sid / gen
    files = (Path(base, name) for base, _, names in walk(gdir) for name in names)
    for f in sorted(p for p in files if p.is_file()):
        data = f.read_bytes()
        meta = f.name == ROOT_META
        if meta:  # Zarr metadata: drop the indentation (a third of a small subject)
            data = json.dumps(json.loads(data), separators=(",", ":")).encode()
        _add(zf, f"{SUBJECTS}/{sid}/{gen}/{f.relative_to(gdir).as_posix()}", data, deflate=meta)


def _add(zf, arcname: str, data: bytes, deflate: bool = False) -> None:
    """Add one entry with the fixed timestamp, stored or deflated."""
    info = zipfile.ZipInfo(arcname, date_time=_ZIP_TIME)
    # Chunks are compressed by Zarr already; subject metadata (JSON) deflates 5x.
    info.compress_type = zipfile.ZIP_DEFLATED if deflate else zipfile.ZIP_STORED
    info.external_attr = 0o644 << 16
    zf.writestr(info, data, compresslevel=9 if deflate else None)
