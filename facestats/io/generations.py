"""Generations of a subject in a directory store: reserve one, write it durably, remove it.

Each write of a subject creates a *fresh generation* directory
``subjects/<id>/<generation>/`` (:mod:`facestats.io.layout`).  Its writer first
takes the writer lock ``.writers/<id>~<generation>.lock``
(:func:`reserve_generation`), then writes the Dataset as Zarr v3 with its
manifest and ``fsync``-s it (:func:`write_generation`); the store commits it
by replacing the index, then drops the lock (:func:`drop_writer_lock`).
Garbage collection never deletes a generation whose writer lock is held.

Map variables are chunked in blocks of :data:`MAP_CHUNK_ROWS` rows of ``v``
(all of ``u`` and the trailing dims), so a texel range of any map can be read
alone.  Float variables are compressed with Blosc (zstd, byte shuffle), others
with Zarr's default zstd.  zarr is imported when a generation is written.
"""

from __future__ import annotations

import os
import shutil

import numpy as np

from facestats.core.version import __version__
from facestats.errors import StoreError
from facestats.io.index import read_index_file
from facestats.io.integrity import STORE_ATTR, manifest_entry, store_attr_json
from facestats.io.layout import (
    SUBJECTS,
    TRASH_PREFIX,
    WRITERS,
    fsync_tree,
    generation_rel,
    new_generation,
    writer_lock_path,
)
from facestats.io.locking import create_locked
from facestats.io.schema import provenance, set_provenance

__all__ = [
    "MAP_CHUNK_ROWS",
    "reserve_generation",
    "drop_writer_lock",
    "write_generation",
    "zarr_encoding",
    "abandon_generations",
    "remove_generation",
]

#: Rows of ``v`` per chunk of a map variable.
MAP_CHUNK_ROWS = 64


def reserve_generation(root, sid: str):
    """Pick a new generation name for ``sid`` and take its writer lock (before any data exist).

    Returns
    -------
    gen : str
    lock : facestats.io.locking.FileLock
        The held writer lock.
    """
    writers = os.path.join(root, WRITERS)
    for _ in range(10):
        gen = new_generation()
        try:
            os.makedirs(writers, exist_ok=True)
            return gen, create_locked(writer_lock_path(root, sid, gen))
        except (FileNotFoundError, StoreError):
            continue  # raced with gc removing a temporary lock file: try another name
    raise StoreError(f"cannot create a writer lock in {writers}")


def drop_writer_lock(lock) -> None:
    """Delete a writer lock file, then release the lock."""
    try:
        os.remove(lock.path)
    except OSError:
        pass
    lock.release()


def write_generation(root, sid: str, gen: str, ds, written: str) -> None:
    """Write ``ds`` as generation ``gen`` of ``sid`` with its manifest, and ``fsync`` it.

    Parameters
    ----------
    root : str
        The store directory.
    sid, gen : str
        Subject id and the generation reserved by :func:`reserve_generation`.
    ds : xarray.Dataset
        A valid subject (not modified).
    written : str
        The write time recorded in the bookkeeping attribute.
    """
    path = os.path.join(root, generation_rel(sid, gen))
    _make_generation_dir(path)
    out = _zarr_ready(ds)
    encoding = zarr_encoding(out)
    manifest = {name: manifest_entry(var) for name, var in out.variables.items()}
    out.attrs[STORE_ATTR] = store_attr_json(gen, written, manifest)
    try:
        out.to_zarr(path, mode="w", zarr_format=3, consolidated=False, encoding=encoding, write_empty_chunks=True)
    except Exception as exc:
        raise StoreError(f"writing subject {sid!r} to {path} failed: {type(exc).__name__}: {exc}") from exc
    fsync_tree(path)


def _make_generation_dir(path: str) -> None:
    for _ in range(10):
        try:
            os.makedirs(path)
            break
        except FileNotFoundError:  # gc removed an empty subject directory meanwhile
            continue


def _zarr_ready(ds):
    """A shallow copy of ``ds`` to write: no bookkeeping attribute, software version, strings as objects."""
    out = ds.copy(deep=False)
    out.attrs = {k: v for k, v in ds.attrs.items() if k != STORE_ATTR}
    if "software_version" not in provenance(out):
        set_provenance(out, software_version=__version__)
    for name in list(out.variables):
        var = out.variables[name]
        if var.dtype.kind in "UST":
            obj = out[name].copy(data=np.asarray(var.values).astype(object))
            out = out.assign_coords({name: obj}) if name in out.coords else out.assign({name: obj})
    return out


def zarr_encoding(ds) -> dict:
    """The ``to_zarr`` encoding of a subject: map chunks of :data:`MAP_CHUNK_ROWS` rows, Blosc for floats.

    Resets every variable's own ``encoding`` (in place) so only this one applies.

    Parameters
    ----------
    ds : xarray.Dataset
        The Dataset about to be written.

    Returns
    -------
    dict
        ``{variable: {"chunks": ..., "compressors": ...}}`` for the variables that need either.
    """
    from zarr.codecs import BloscCodec

    encoding = {}
    for name, var in ds.variables.items():
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
    return encoding


def abandon_generations(root, written) -> None:
    """Clean up after a failed write: delete the generations the index does not reference, drop their locks.

    An interrupt may land after the commit, so the index is re-read and a
    generation it references is never deleted.

    Parameters
    ----------
    root : str
        The store directory.
    written : list of tuple
        ``(sid, gen, lock, ...)`` of the generations reserved.
    """
    try:
        current = read_index_file(root)["subjects"]
    except (StoreError, OSError):
        current = {}
    for sid, gen, lock, *_ in written:
        if current.get(sid, {}).get("generation") != gen:
            shutil.rmtree(os.path.join(root, generation_rel(sid, gen)), ignore_errors=True)
        drop_writer_lock(lock)


def remove_generation(root, sid: str, gen: str) -> None:
    """Delete an unreferenced generation: rename it aside (atomic), then remove it.

    A generation that cannot be renamed (already gone) is left alone.

    Parameters
    ----------
    root : str
        The store directory.
    sid, gen : str
        Subject id and generation.
    """
    src = os.path.join(root, generation_rel(sid, gen))
    dst = os.path.join(root, SUBJECTS, sid, f"{TRASH_PREFIX}{gen}")
    try:
        os.rename(src, dst)
    except OSError:
        return
    shutil.rmtree(dst, ignore_errors=True)
