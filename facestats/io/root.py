"""The root group of a store: creating an empty directory store, and checking the root of any store.

The root ``zarr.json`` is a Zarr v3 group whose attributes say it is a
facestats store: ``facestats_schema`` (:data:`facestats.io.schema.SCHEMA_VERSION`),
``facestats_version`` (the facestats that last wrote) and ``created``.  It is
written last when a store is created, so its presence marks a complete store.
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

from facestats.core.version import __version__
from facestats.errors import SchemaError, StoreError
from facestats.io.index import INDEX_NAME, empty_index, is_index_temp, read_index_file, utc_now, write_index_file
from facestats.io.layout import (
    LOCK_NAME,
    RECORDS,
    ROOT_META,
    SUBJECTS,
    WRITERS,
    fsync_path,
    group_meta,
    is_meta_temp,
    is_plain_dir,
    is_plain_file,
    remove_tree,
    sorted_names,
    write_json_atomic,
)
from facestats.io.locking import FileLock
from facestats.io.schema import SCHEMA_VERSION

__all__ = ["create_store", "enclosing_store", "read_root_attrs", "remove_empty_store", "new_store_guard"]

_CREATION_LEFTOVERS = {LOCK_NAME, WRITERS, RECORDS, SUBJECTS, INDEX_NAME}


def create_store(p: Path) -> None:
    """Create an empty directory store at ``p`` (safe against concurrent creators).

    Parameters
    ----------
    p : pathlib.Path
        A missing or empty directory (or one left by an interrupted creation).

    Raises
    ------
    StoreError
        ``p`` cannot be created, lies inside another store (:func:`enclosing_store`), or holds
        files that are not a store's (or links among a store's names: nothing is written through
        them).  The contents of an existing directory are checked *before* anything is written
        to it, so a foreign directory never gets a lock file; a creation that fails (e.g. a full
        disk) removes what it made.
    """
    outer = enclosing_store(p)
    if outer is not None:
        raise StoreError(
            f"cannot create a store at {p}: it lies inside the store {outer}, whose maintenance would take it for "
            "files it did not create; choose a folder outside every store"
        )
    _refuse_foreign(p)
    made = _missing_folders(p)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StoreError(f"cannot create store directory {p}: {exc.strerror}") from None
    had_lock = os.path.lexists(p / LOCK_NAME)
    try:
        with FileLock(p / LOCK_NAME):
            try:
                if (p / ROOT_META).exists():
                    return
                _refuse_foreign(p)
                before = set(os.listdir(p))
                try:
                    _populate(p)
                except BaseException:
                    _undo_populate(p, before)
                    raise
            except BaseException:
                if not had_lock:  # still held: a creator waiting for it finds no half-made store
                    _unlink(p / LOCK_NAME)
                raise
    except (OSError, StoreError) as exc:
        _remove_folders(made)
        if isinstance(exc, StoreError):
            raise
        raise StoreError(f"cannot create store {p}: {exc.strerror or exc}; nothing was left behind") from None
    except BaseException:
        _remove_folders(made)
        raise


def enclosing_store(p) -> Path | None:
    """The facestats directory store that ``p`` lies inside (itself excluded, links resolved), or None.

    A folder is a store if its ``zarr.json`` is a Zarr group with the ``facestats_schema`` attribute
    (:func:`read_root_attrs`' test); every folder above ``p`` is looked at.

    Parameters
    ----------
    p : str or os.PathLike
        A path (it need not exist).

    Returns
    -------
    pathlib.Path or None
        The innermost such store folder.
    """
    here = Path(os.path.realpath(os.fspath(p)))
    for folder in here.parents:
        meta = folder / ROOT_META
        try:
            if not meta.is_file():
                continue
            doc = json.loads(meta.read_bytes()[:1_000_000])
        except (OSError, ValueError, UnicodeDecodeError, RecursionError):
            continue
        attrs = doc.get("attributes") if isinstance(doc, dict) else None
        if isinstance(attrs, dict) and "facestats_schema" in attrs:
            return folder
    return None


def _missing_folders(p: Path) -> list[Path]:
    """The folders of ``p`` (itself included) that do not exist yet, innermost first."""
    out = []
    q = Path(os.path.abspath(p))
    while not os.path.lexists(q) and q != q.parent:
        out.append(q)
        q = q.parent
    return out


def _undo_populate(p: Path, before: set) -> None:
    """Remove what :func:`_populate` made in ``p`` (the names not in ``before``); the caller holds the lock."""
    for name in sorted(set(sorted_names(p)) - before - {LOCK_NAME}):
        target = p / name
        try:
            if target.is_dir() and not target.is_symlink():
                for inner in sorted_names(target):  # only what _populate writes there: subjects/zarr.json
                    if inner == ROOT_META or is_meta_temp(inner):
                        (target / inner).unlink()
                target.rmdir()
            elif name in _CREATION_LEFTOVERS or name == ROOT_META or is_index_temp(name) or is_meta_temp(name):
                target.unlink()
        except OSError:
            pass


def _unlink(path: Path) -> None:
    try:
        path.unlink()
    except OSError:
        pass


def _remove_folders(made: list) -> None:
    """Remove the folders a failed creation made (innermost first), as long as they are empty."""
    for folder in made:
        try:
            folder.rmdir()
        except OSError:
            break


#: What each name of a store's own may be: its folders, its files.
_KINDS = {WRITERS: "dir", RECORDS: "dir", SUBJECTS: "dir", LOCK_NAME: "file", INDEX_NAME: "file"}


def _refuse_foreign(p: Path) -> None:
    """:class:`StoreError` if ``p`` exists and is not a directory, or holds anything but store-creation leftovers.

    Leftovers count only as what the store makes (real folders, regular files; no link): a creation
    never writes through a link planted among them (``subjects -> /elsewhere``).
    """
    if not p.exists() and not p.is_symlink():
        return
    if not p.is_dir():
        raise StoreError(f"cannot create a store at {p}: it exists and is not a directory")
    try:
        names = os.listdir(p)
    except OSError as exc:
        raise StoreError(f"cannot create a store at {p}: {exc.strerror}") from None
    if ROOT_META in names:
        return
    extra = [n for n in names if n not in _CREATION_LEFTOVERS and not is_index_temp(n) and not is_meta_temp(n)]
    if extra:
        raise StoreError(f"{p} exists, is not empty and is not a facestats store (contains {sorted(extra)[:5]})")
    for name in sorted(names):
        kind = _KINDS.get(name, "file")
        ok = is_plain_dir(p / name) if kind == "dir" else is_plain_file(p / name)
        if not ok:
            what = "a symbolic link" if os.path.islink(p / name) else f"not a {'folder' if kind == 'dir' else 'file'}"
            raise StoreError(
                f"cannot create a store at {p}: {p / name} is {what}, so it was not left by facestats; nothing was "
                "written: remove it or choose another folder"
            )


def _populate(p: Path) -> None:
    """Write the folders, the empty index and (last) the root group of a new store at ``p``."""
    (p / WRITERS).mkdir(exist_ok=True)
    (p / RECORDS).mkdir(exist_ok=True)
    (p / SUBJECTS).mkdir(exist_ok=True)
    write_json_atomic(p / SUBJECTS / ROOT_META, group_meta())
    if not (p / INDEX_NAME).exists():
        write_index_file(p, empty_index(SCHEMA_VERSION, __version__))
    attrs = {"facestats_schema": SCHEMA_VERSION, "facestats_version": __version__, "created": utc_now()}
    write_json_atomic(p / ROOT_META, group_meta(attrs))  # last: its presence marks a complete store
    fsync_path(p, directory=True)


def read_root_attrs(backend, label: str) -> dict:
    """The attributes of the root group, checked.

    Parameters
    ----------
    backend : facestats.io.backends.DirectoryBackend or ZipBackend
        The store's files.
    label : str
        The store's name in messages.

    Returns
    -------
    dict
        The root group's attributes.

    Raises
    ------
    StoreError
        No root ``zarr.json``, invalid JSON, or a Zarr group that is not a facestats store.
    SchemaError
        Not a Zarr v3 group, or a schema version this facestats cannot read.
    """
    try:
        meta = json.loads(backend.read(ROOT_META))
    except FileNotFoundError:
        raise StoreError(f"{label} is not a facestats store: no root {ROOT_META}") from None
    except OSError as exc:
        raise StoreError(
            f"{label}: cannot read the root {ROOT_META} ({exc.strerror or exc}); it must be a regular file"
        ) from None
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise StoreError(f"{label}: root {ROOT_META} is not valid JSON ({exc})") from None
    if not isinstance(meta, dict) or meta.get("zarr_format") != 3 or meta.get("node_type") != "group":
        raise SchemaError(
            f"{label}: the root is not a Zarr v3 group (zarr.json: zarr_format "
            f"{meta.get('zarr_format') if isinstance(meta, dict) else '?'!r})"
        )
    attrs = meta.get("attributes") or {}
    if not isinstance(attrs, dict) or "facestats_schema" not in attrs:
        raise StoreError(f"{label} is a Zarr group but not a facestats store (no facestats_schema attribute)")
    v = attrs["facestats_schema"]
    if v != SCHEMA_VERSION:
        hint = " (written by a newer facestats: upgrade facestats)" if isinstance(v, int) and v > SCHEMA_VERSION else ""
        raise SchemaError(
            f"store {label} has schema version {v!r}; facestats {__version__} reads schema version "
            f"{SCHEMA_VERSION}{hint}"
        )
    return attrs


def remove_empty_store(p, *, keep_folder: bool = False) -> bool:
    """Remove the store at ``p`` if it is exactly an empty store (no subject, nothing but its own files).

    Used to undo the creation of a store by a command that then failed.

    Parameters
    ----------
    p : str or os.PathLike
        The store directory.
    keep_folder : bool
        Keep the folder itself (it existed, empty, before the store was made in it).

    Returns
    -------
    bool
        True if it was removed; False if it is not such a store, or an OSError or StoreError stopped it.
    """
    p = Path(p)
    own = {ROOT_META, INDEX_NAME, LOCK_NAME, WRITERS, RECORDS, SUBJECTS}
    try:
        names = set(os.listdir(p))
        if not names <= own or not (p / ROOT_META).is_file():
            return False
        with FileLock(p / LOCK_NAME, timeout=1):
            if (p / INDEX_NAME).exists() and read_index_file(p)["subjects"]:
                return False
            for folder in (WRITERS, RECORDS):
                if (p / folder).exists() and os.listdir(p / folder):
                    return False
            if (p / SUBJECTS).exists() and set(os.listdir(p / SUBJECTS)) - {ROOT_META}:
                return False
            for name in names - {LOCK_NAME}:
                target = p / name
                remove_tree(target) if target.is_dir() and not target.is_symlink() else target.unlink()
        (p / LOCK_NAME).unlink()
        if not keep_folder:
            p.rmdir()
    except (OSError, StoreError):
        return False
    return True


@contextlib.contextmanager
def new_store_guard(path):
    """Undo the creation of the store at ``path`` if the block creates it and then fails while it is still empty.

    A command that fails must leave no side effects; a store it created and
    wrote nothing into is one (e.g. ``facestats edit ... --out-store NEW``
    with an invalid argument found late, or ``facestats import-merl`` on a
    full disk).  A store made in a folder that existed empty is emptied again,
    the folder kept.

    Parameters
    ----------
    path : str or os.PathLike or None
        Where the block may create a store (None: the guard does nothing).

    Yields
    ------
    None
    """
    created = []  # the store folder and the missing folders above it, innermost first
    was_empty = False
    if path is not None:
        p = Path(os.fspath(path)).absolute()
        created = _missing_folders(p)
        if not created:
            was_empty = is_plain_dir(p) and not sorted_names(p)
    try:
        yield
    except BaseException:
        if created and remove_empty_store(created[0]):
            for folder in created[1:]:
                try:
                    folder.rmdir()
                except OSError:
                    break
        elif was_empty:
            remove_empty_store(p, keep_folder=True)
        raise
