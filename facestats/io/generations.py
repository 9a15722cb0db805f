"""Generations of a subject in a directory store: reserve one, write it durably, remove it.

Each write of a subject creates a *fresh generation* directory
``subjects/<id>/<generation>/`` (:mod:`facestats.io.layout`).  Its writer first
takes the writer lock ``.writers/<id>~<generation>.lock`` and writes the
generation's record (state ``writing``, :mod:`facestats.io.records`: the mark
that the generation is the store's own) (:func:`reserve_generation`), then
writes the Dataset as Zarr v3 with its manifest and ``fsync``-s it
(:func:`write_generation`); the store commits it by replacing the index, then
drops the lock (:func:`drop_writer_lock`).  Garbage collection never deletes a
generation whose writer lock is held.  Every folder a writer creates or enters
is checked to be a real folder inside the store (:func:`facestats.io.layout.confined`),
so a symbolic link planted in the store cannot make it write elsewhere.

Map variables are chunked in blocks of :data:`MAP_CHUNK_ROWS` rows of ``v``
(all of ``u`` and the trailing dims), so a texel range of any map can be read
alone.  Float variables are compressed with Blosc (zstd, byte shuffle), others
with Zarr's default zstd.  zarr is imported when a generation is written.
"""

from __future__ import annotations

import os

import numpy as np

from facestats.core.version import __version__
from facestats.errors import StoreError
from facestats.io.index import read_index_file
from facestats.io.integrity import STORE_ATTR, manifest_entry, store_attr_json
from facestats.io.layout import (
    MAP_CHUNK_ROWS,
    RECORDS,
    SUBJECTS,
    TRASH_PREFIX,
    WRITERS,
    confined,
    fsync_tree,
    generation_rel,
    generation_strays,
    is_plain_dir,
    map_chunk_rows,
    new_generation,
    remove_tree,
    writer_lock_path,
)
from facestats.io.locking import create_locked
from facestats.io.records import record_path, write_record
from facestats.io.schema import provenance, set_provenance

__all__ = [
    "MAP_CHUNK_ROWS",
    "store_folder",
    "reserve_generation",
    "drop_writer_lock",
    "write_generation",
    "zarr_encoding",
    "map_chunks",
    "abandon_generations",
    "remove_generation",
]


def store_folder(root, rel: str) -> str:
    """The folder ``rel`` of the store at ``root``, created if missing.

    Raises :class:`StoreError` unless it is a real folder inside the store (not
    a file, not a symbolic link, not reached through one).

    Parameters
    ----------
    root : str or os.PathLike
        The store directory.
    rel : str
        The folder, relative to ``root`` (e.g. ``subjects/<id>``); its parent must exist.

    Returns
    -------
    str
        ``os.path.join(root, rel)``.
    """
    path = os.path.join(root, rel)
    confined(root, path)
    for _ in range(10):  # gc may remove an empty subject folder between our mkdir and our check: create it again
        try:
            os.mkdir(path)
        except FileExistsError:
            pass
        except OSError as exc:
            raise StoreError(f"cannot create {path}: {exc.strerror}") from None
        if is_plain_dir(path):
            return path
        if os.path.lexists(path):
            raise StoreError(f"{path} must be a folder of the store, but it is not a directory (or is a symbolic link)")
    raise StoreError(f"cannot create {path}: it was removed again each time (a concurrent gc)")


def reserve_generation(root, sid: str, when: str = ""):
    """Pick a new generation name for ``sid``, take its writer lock and write its record (before any data exist).

    A failure (e.g. a full disk) leaves nothing behind: the subject folder made for it (if it was
    missing) is removed again with the lock.

    Parameters
    ----------
    root : str
        The store directory.
    sid : str
        The subject id (not checked here: callers check it, it names folders).
    when : str
        The write time, recorded as the record's ``created``.

    Returns
    -------
    gen : str
    lock : facestats.io.locking.FileLock
        The held writer lock.

    Raises
    ------
    StoreError
        ``subjects/``, ``subjects/<sid>/`` or ``.writers/`` is not a real folder
        inside the store, or no lock or record could be created.
    """
    if not is_plain_dir(os.path.join(root, SUBJECTS)):
        raise StoreError(
            f"store {root}: its {SUBJECTS}/ folder is missing or not a folder (an unmounted volume?); nothing written"
        )
    store_folder(root, RECORDS)
    writers = store_folder(root, WRITERS)
    sdir = os.path.join(root, SUBJECTS, sid)
    made = not os.path.lexists(sdir)
    try:
        for _ in range(10):
            store_folder(root, f"{SUBJECTS}/{sid}")  # again each time: gc may remove an empty subject folder meanwhile
            gen = new_generation()
            try:
                lock = create_locked(writer_lock_path(root, sid, gen))
            except (FileNotFoundError, StoreError):
                continue  # raced with gc removing a temporary lock file: try another name
            except OSError as exc:
                raise StoreError(f"cannot create a writer lock in {writers}: {exc.strerror or exc}") from None
            try:
                write_record(root, sid, gen, "writing", created=when)
            except FileNotFoundError:
                drop_writer_lock(lock)
                continue
            except OSError as exc:
                drop_writer_lock(lock)
                raise StoreError(
                    f"cannot write the record of a new generation of {sid!r}: {exc.strerror or exc}"
                ) from None
            return gen, lock
        raise StoreError(f"cannot create a writer lock in {writers}")
    except BaseException:
        if made:  # the (empty) folder made for this write: nothing else may be left of it
            try:
                os.rmdir(confined(root, sdir))
            except (OSError, StoreError):
                pass
        raise


def drop_writer_lock(lock) -> None:
    """Delete a writer lock file, then release the lock.

    Parameters
    ----------
    lock : facestats.io.locking.FileLock
        A held writer lock (:func:`reserve_generation`); a file already gone is no error.
    """
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
    _make_generation_dir(root, sid, path)
    out = _zarr_ready(ds)
    encoding = zarr_encoding(out)
    manifest = {name: manifest_entry(var) for name, var in out.variables.items()}
    out.attrs[STORE_ATTR] = store_attr_json(gen, written, manifest)
    try:
        out.to_zarr(path, mode="w", zarr_format=3, consolidated=False, encoding=encoding, write_empty_chunks=True)
        fsync_tree(path)
    except Exception as exc:
        raise StoreError(f"writing subject {sid!r} to {path} failed: {type(exc).__name__}: {exc}") from None


def _make_generation_dir(root, sid: str, path: str) -> None:
    """Create the (new) generation folder ``path``; :class:`StoreError` if that keeps failing."""
    err = None
    for _ in range(10):
        try:
            store_folder(root, f"{SUBJECTS}/{sid}")
            os.mkdir(confined(root, path))
            return
        except FileNotFoundError as exc:  # gc removed an empty subject directory meanwhile: create it again
            err = exc
        except OSError as exc:
            raise StoreError(f"cannot create the generation folder {path}: {exc.strerror}") from None
    raise StoreError(f"cannot create the generation folder {path}: {err}")


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
        rows = map_chunk_rows(var.dims, var.shape)
        if rows is not None:
            enc["chunks"] = map_chunks(var.dims, var.shape, rows)
        if var.dtype.kind == "f":  # byte shuffle + zstd: ~20 % smaller than plain zstd on smooth maps
            enc["compressors"] = [BloscCodec(cname="zstd", clevel=5, shuffle="shuffle")]
        if enc:
            encoding[name] = enc
    return encoding


def map_chunks(dims, shape, rows: int) -> tuple:
    """Zarr chunk shape of a map variable: ``rows`` rows of ``v``, one index of each dim before it, all of the rest.

    A chunk of the per-camera micro-normal map (``camera``, ``v``, ``u``, ``component``) thus holds one camera's
    band: 1.5 MB at 2048² instead of 25 MB for all 16 cameras.  zarr-python decodes and encodes about ten chunks
    at once, so the 25 MB chunks held some 480 MB beside the variable at every read and write of such a subject
    (measured with tracemalloc; 30 MB with per-camera chunks, at the same speed).  The unit a lazy read verifies
    stays the band of ``rows`` rows across all cameras (:func:`facestats.io.integrity.manifest_entry`).

    Parameters
    ----------
    dims : sequence of str
        The variable's dims; must include ``v``.
    shape : sequence of int
        The variable's shape.
    rows : int
        Rows of ``v`` per chunk (:func:`facestats.io.layout.map_chunk_rows`).

    Returns
    -------
    tuple of int
        One chunk size per dim (size-0 dims after ``v`` get 1).
    """
    iv = list(dims).index("v")
    return tuple(rows if i == iv else 1 if i < iv else max(1, s) for i, s in enumerate(shape))


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
        current = None  # cannot tell what was committed: keep every generation (gc decides later)
    for sid, gen, lock, *_ in written:
        if current is None:
            drop_writer_lock(lock)
            continue
        if current.get(sid, {}).get("generation") != gen:
            _delete_generation(root, sid, gen)
            try:  # the folder of a subject that never existed, now empty (no group metadata yet)
                os.rmdir(confined(root, os.path.join(root, SUBJECTS, sid)))
            except (OSError, StoreError):
                pass
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
    _delete_generation(root, sid, gen)


def _delete_generation(root, sid: str, gen: str) -> None:
    """Rename a generation to trash, delete it, then its record (each step checked to stay inside the store).

    A generation holding items Zarr did not write (:func:`facestats.io.layout.generation_strays`) is left
    in place: ``facestats validate`` reports them.
    """
    src = os.path.join(root, generation_rel(sid, gen))
    dst = os.path.join(root, SUBJECTS, sid, f"{TRASH_PREFIX}{gen}")
    try:
        if generation_strays(confined(root, src)):
            return  # holds what someone else put there: kept (and reported by validate), never deleted with it
        if is_plain_dir(src):
            os.rename(src, confined(root, dst))
        if is_plain_dir(dst):
            remove_tree(dst)
        if not os.path.lexists(src) and not os.path.lexists(dst):  # the record goes last: it proves ownership
            os.remove(confined(root, record_path(root, sid, gen)))
    except (OSError, StoreError):
        return  # already gone, or not ours to touch: left for gc to judge
