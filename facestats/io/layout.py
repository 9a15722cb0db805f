"""Where things live in a directory store, how generations are named, and durable writes of its files.

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

A generation is named ``g<time in ns, 16 hex digits>-<pid>-<6 random hex digits>``,
so names sort by creation time and never collide between processes; its writer
holds ``.writers/<id>~<generation>.lock`` while it writes.  Generations being
deleted are first renamed to ``subjects/<id>/.trash-<generation>``.

Small files the store replaces (group metadata) are written atomically and
durably by :func:`write_json_atomic`; whole directories are flushed with
:func:`fsync_tree`.  Only the standard library is needed here.
"""

from __future__ import annotations

import json
import os
import re
import secrets
import time

from facestats.io.locking import FileLock

__all__ = [
    "SUBJECTS",
    "LOCK_NAME",
    "WRITERS",
    "ROOT_META",
    "TRASH_PREFIX",
    "GENERATION_PATTERN",
    "new_generation",
    "generation_rel",
    "writer_lock_path",
    "store_lock",
    "is_meta_temp",
    "group_meta",
    "fsync_path",
    "fsync_tree",
    "write_json_atomic",
]

#: Folder of the subject groups.
SUBJECTS = "subjects"
#: The store lock file.
LOCK_NAME = ".lock"
#: Folder of the writer locks.
WRITERS = ".writers"
#: Zarr v3 group metadata file (of the root, ``subjects/`` and every subject).
ROOT_META = "zarr.json"
#: Prefix a generation is renamed to before it is deleted.
TRASH_PREFIX = ".trash-"
#: Names :func:`new_generation` makes.
GENERATION_PATTERN = re.compile(r"^g[0-9a-f]{16}-\d+-[0-9a-f]{6}$")
_META_TEMP = ROOT_META + ".tmp-"


def new_generation() -> str:
    """A fresh generation name (see the module docstring)."""
    return f"g{time.time_ns():016x}-{os.getpid()}-{secrets.token_hex(3)}"


def generation_rel(sid: str, gen: str) -> str:
    """The folder of generation ``gen`` of subject ``sid``, relative to the store root."""
    return f"{SUBJECTS}/{sid}/{gen}"


def writer_lock_path(root, sid: str, gen: str) -> str:
    """The writer lock file of generation ``gen`` of subject ``sid`` in the store at ``root``."""
    return os.path.join(root, WRITERS, f"{sid}~{gen}.lock")


def store_lock(root, timeout: float) -> FileLock:
    """The (not yet acquired) store lock of the store at ``root``."""
    return FileLock(os.path.join(root, LOCK_NAME), timeout=timeout)


def is_meta_temp(name: str) -> bool:
    """True for the temporary files :func:`write_json_atomic` leaves beside a ``zarr.json``."""
    return name.startswith(_META_TEMP)


def group_meta(attributes=None) -> dict:
    """The ``zarr.json`` document of a Zarr v3 group with ``attributes``."""
    return {"zarr_format": 3, "node_type": "group", "attributes": dict(attributes or {})}


def fsync_path(path, directory: bool = False) -> None:
    """Flush a file (or, with ``directory=True``, a directory entry list) to disk."""
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_tree(path) -> None:
    """Flush every file and directory under ``path`` to disk."""
    for root, _, files in os.walk(path):
        for f in files:
            fsync_path(os.path.join(root, f))
        fsync_path(root, directory=True)


def write_json_atomic(path, obj) -> None:
    """Replace ``path`` by ``obj`` as indented JSON: temporary file, ``fsync``, ``os.replace``."""
    tmp = f"{path}.tmp-{os.getpid()}-{secrets.token_hex(3)}"
    with open(tmp, "w") as fh:
        json.dump(obj, fh, indent=2)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
