"""Where things live in a directory store, how its own files are named, confinement checks and durable writes.

Layout of a directory store ``X.zarr/``::

    X.zarr/
      zarr.json                    root group; attributes: facestats_schema (= schema.SCHEMA_VERSION),
                                   facestats_version (the facestats that last wrote), created
      index.json                   population index and commit point (facestats.io.index)
      .lock                        store lock (facestats.io.locking)
      .writers/                    one lock file per generation being written
      .records/<id>~<generation>.json   each generation's record: its owner mark and commit state
                                        (facestats.io.records)
      quarantine/                  what repair moved aside (facestats.io.quarantine), removed only by a purge
      subjects/zarr.json           group
      subjects/<id>/zarr.json      group
      subjects/<id>/<generation>/  the subject: an xarray Dataset written by ``to_zarr`` (Zarr v3)

A generation is named ``g<time in ns, 16 hex digits>-<pid>-<6 random hex digits>``,
so names sort by creation time and never collide between processes; its writer
holds ``.writers/<id>~<generation>.lock`` while it writes.  Generations being
deleted are first renamed to ``subjects/<id>/.trash-<generation>``.

**Ownership.** Maintenance (gc, repair) only ever deletes or moves what this
module's names describe *and* what is proven to be facestats' own: a
generation by its name and its record, a temporary file by its name, a lock by
its name and folder.  Before touching a path it checks, with :func:`confined`,
that the path is not a symbolic link and that its parent resolves inside the
store root without passing through a link, so a link planted under
``subjects/`` can never lead maintenance out of the store or to another of its
folders; a generation holding files Zarr did not write
(:func:`generation_strays`) is never deleted.

Small files the store replaces (group metadata, records) are written
atomically by :func:`write_json_atomic`; whole directories are flushed with
:func:`fsync_tree`.  Only the standard library is needed here.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import functools
import json
import os
import re
import secrets
import shutil
import stat
import time

from facestats.errors import StoreError
from facestats.io.locking import FileLock

__all__ = [
    "sorted_names",
    "walk",
    "copy_tree",
    "SUBJECTS",
    "LOCK_NAME",
    "WRITERS",
    "RECORDS",
    "ROOT_META",
    "TRASH_PREFIX",
    "QUARANTINE",
    "BUILD_JOURNAL",
    "GENERATION_PATTERN",
    "MAP_CHUNK_ROWS",
    "map_chunk_rows",
    "is_generation",
    "new_generation",
    "generation_rel",
    "writer_lock_path",
    "store_lock",
    "is_meta_temp",
    "is_plain_dir",
    "is_plain_file",
    "confined",
    "generation_strays",
    "read_regular_file",
    "open_regular_file",
    "remove_tree",
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
#: Folder of the generation records.
RECORDS = ".records"
#: Zarr v3 group metadata file (of the root, ``subjects/`` and every subject).
ROOT_META = "zarr.json"
#: Prefix a generation is renamed to before it is deleted.
TRASH_PREFIX = ".trash-"
#: Folder (under the root) of what repair moved aside.
QUARANTINE = "quarantine"
#: Folder (under the root) of a build's per-subject journal (:mod:`facestats.pipeline.journal`).
BUILD_JOURNAL = ".build"
#: Names :func:`new_generation` makes (always matched in full: a trailing newline is not a name).
GENERATION_PATTERN = re.compile(r"g[0-9a-f]{16}-[0-9]{1,10}-[0-9a-f]{6}")
#: Temporary files of :func:`write_json_atomic` beside a ``zarr.json`` or a generation record.
_JSON_TEMP = re.compile(
    r"(?:zarr\.json|[A-Za-z0-9._-]{1,64}~g[0-9a-f]{16}-[0-9]{1,10}-[0-9a-f]{6}\.json)\.tmp-[0-9]{1,10}-[0-9a-f]{6}"
)
#: Temporary files Zarr's local store writes before renaming a chunk or a ``zarr.json`` into place
#: (``Path.with_suffix(".<uuid hex>.partial")``); an interrupted write leaves them.
_ZARR_PARTIAL = re.compile(r"(?:zarr|c|[0-9]+)\.[0-9a-f]{32}\.partial")
#: Rows of ``v`` per chunk of a map variable.
MAP_CHUNK_ROWS = 64


def map_chunk_rows(dims, shape) -> int | None:
    """Rows of ``v`` per chunk of a variable with ``dims`` and ``shape``: None unless it is a map (``v`` and ≥ 2 dims).

    Map variables are chunked along ``v`` only (all of ``u`` and the trailing dims in each chunk).

    Parameters
    ----------
    dims : sequence of str
        The variable's dims.
    shape : sequence of int
        The variable's shape.

    Returns
    -------
    int or None
        ``min(MAP_CHUNK_ROWS, rows of v)``, at least 1; None for a variable that is not a map.
    """
    dims = tuple(dims)
    if "v" not in dims or len(dims) < 2:
        return None
    return max(1, min(MAP_CHUNK_ROWS, int(shape[dims.index("v")])))


def is_generation(name: str) -> bool:
    """True if ``name`` is a generation name (:data:`GENERATION_PATTERN`, matched in full).

    Parameters
    ----------
    name : str
        A folder name.

    Returns
    -------
    bool
    """
    return GENERATION_PATTERN.fullmatch(name) is not None


def new_generation() -> str:
    """A fresh generation name (see the module docstring)."""
    return f"g{time.time_ns():016x}-{os.getpid()}-{secrets.token_hex(3)}"


def generation_rel(sid: str, gen: str) -> str:
    """The folder of generation ``gen`` of subject ``sid``, relative to the store root.

    Parameters
    ----------
    sid, gen : str
        Subject id and generation name (not checked).

    Returns
    -------
    str
        ``subjects/<sid>/<gen>``, with ``/`` separators.
    """
    return f"{SUBJECTS}/{sid}/{gen}"


def writer_lock_path(root, sid: str, gen: str) -> str:
    """The writer lock file of generation ``gen`` of subject ``sid`` in the store at ``root``.

    Parameters
    ----------
    root : str or os.PathLike
        The store directory.
    sid, gen : str
        Subject id and generation name (not checked).

    Returns
    -------
    str
        ``<root>/.writers/<sid>~<gen>.lock``.
    """
    return os.path.join(root, WRITERS, f"{sid}~{gen}.lock")


def store_lock(root, timeout: float) -> FileLock:
    """The (not yet acquired) store lock of the store at ``root``.

    Parameters
    ----------
    root : str or os.PathLike
        The store directory.
    timeout : float
        Seconds to wait for the lock before :class:`StoreError`.

    Returns
    -------
    facestats.io.locking.FileLock
        On ``<root>/.lock`` (created when acquired if missing).
    """
    return FileLock(os.path.join(root, LOCK_NAME), timeout=timeout)


def is_meta_temp(name: str) -> bool:
    """True for the temporary files :func:`write_json_atomic` leaves beside a ``zarr.json`` or a record.

    Parameters
    ----------
    name : str
        A file name (not a path).

    Returns
    -------
    bool
    """
    return _JSON_TEMP.fullmatch(name) is not None


def is_plain_dir(path) -> bool:
    """True if ``path`` is a directory and not a symbolic link (``lstat``).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    bool
        False also when ``path`` is missing or cannot be examined.
    """
    try:
        return stat.S_ISDIR(os.lstat(path).st_mode)
    except OSError:
        return False


def is_plain_file(path) -> bool:
    """True if ``path`` is a regular file and not a symbolic link (``lstat``).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    bool
        False also when ``path`` is missing or cannot be examined.
    """
    try:
        return stat.S_ISREG(os.lstat(path).st_mode)
    except OSError:
        return False


def open_regular_file(path, *, follow_links: bool = True):
    """The regular file ``path`` opened for reading (binary, buffered), refusing anything else without blocking.

    Opens without blocking and checks the type first, so a FIFO or a device
    planted where a file should be raises :class:`OSError` (EINVAL, "not a
    regular file") instead of hanging or reading forever; a directory raises
    :class:`IsADirectoryError`, a missing file :class:`FileNotFoundError`.  With
    ``follow_links`` False a symbolic link at ``path`` (its last component)
    raises :class:`OSError` (ELOOP) instead of being followed.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    follow_links : bool
        Follow a symbolic link at ``path``.

    Returns
    -------
    io.BufferedReader
        The open file (the caller closes it, e.g. with ``with``).

    Raises
    ------
    OSError
        ``path`` cannot be opened or is not a regular file.
    """
    flags = os.O_RDONLY | os.O_NONBLOCK | (0 if follow_links else os.O_NOFOLLOW)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        if exc.errno == errno.ELOOP and not follow_links:
            raise OSError(errno.ELOOP, "a symbolic link (a store's files are never links)", os.fspath(path)) from None
        raise
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise IsADirectoryError(errno.EISDIR, "is a directory", os.fspath(path))
        if not stat.S_ISREG(mode):
            raise OSError(errno.EINVAL, "not a regular file (a FIFO, socket or device?)", os.fspath(path))
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_regular_file(path, limit: int | None = None, *, follow_links: bool = True) -> bytes:
    """The bytes of the regular file ``path``; its first ``limit`` bytes if ``limit`` is given.

    With ``follow_links`` False a symbolic link at ``path`` (its last component)
    raises :class:`OSError` (ELOOP) instead of being followed: a store's own files
    are never links, and one planted there could lead a read out of the store.

    Opens without blocking and checks the type first (:func:`open_regular_file`),
    so a FIFO or a device planted where a store file should be raises
    :class:`OSError` (EINVAL, "not a regular file") instead of hanging or reading
    forever; a directory raises :class:`IsADirectoryError`, a missing file
    :class:`FileNotFoundError`.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    limit : int, optional
        Most bytes to read (default: all).
    follow_links : bool
        Follow a symbolic link at ``path``.

    Returns
    -------
    bytes
    """
    with open_regular_file(path, follow_links=follow_links) as fh:
        return fh.read() if limit is None else fh.read(limit)


def walk(top):
    """``(folder, dirs, files)`` for ``top`` and every folder under it, like :func:`os.walk`, without recursion.

    Top-down; ``dirs`` lists sub-folders and links to folders, ``files`` everything
    else; links are listed but never followed; a folder that cannot be read is
    skipped (as :func:`os.walk` does).  A caller may prune ``dirs`` in place to
    skip sub-folders.  Python 3.11's :func:`os.walk`, :func:`shutil.rmtree`,
    :func:`shutil.copytree` and :meth:`pathlib.Path.rglob` recurse once per
    folder level, so a store holding a tree of about a thousand nested folders
    (hostile input) made validate, repair and gc fail with ``RecursionError``;
    every walk of a store goes through here instead.

    Parameters
    ----------
    top : str or os.PathLike
        The folder to walk (a link at ``top`` itself is followed).

    Yields
    ------
    folder : str
        The folder's path (``top`` joined with the names below it).
    dirs, files : list of str
        Names in it, in listing order.
    """
    stack = [os.fspath(top)]
    while stack:
        base = stack.pop()
        try:
            with os.scandir(base) as it:
                entries = list(it)
        except OSError:
            continue
        dirs, files = [], []
        for entry in entries:
            try:
                is_dir = entry.is_dir()
            except OSError:
                is_dir = False
            (dirs if is_dir else files).append(entry.name)
        yield base, dirs, files
        for name in reversed(dirs):  # depth first, in listing order
            sub = os.path.join(base, name)
            if not os.path.islink(sub):
                stack.append(sub)


#: How :func:`remove_tree` opens a folder: read-only, a folder, and not through a symbolic link.
_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW

#: Folder levels of :func:`remove_tree` whose handles stay open while it works below them (one file descriptor
#: each, well inside the usual limit of 1,024); deeper levels are left through ``..`` (see there).
HELD_LEVELS = 128


def remove_tree(path) -> None:
    """Delete the folder ``path`` and everything in it, without following links and without recursion.

    Works through folder handles: each folder is read once and opened relative to its parent with
    ``O_NOFOLLOW``, so a folder swapped for a link meanwhile is not followed, and neither the depth of the
    tree (Python's recursion limit) nor the length of its paths (``PATH_MAX``) limits it.  The handles of the
    :data:`HELD_LEVELS` levels nearest ``path`` stay open while the walk is below them, and the walk returns
    to them, as :func:`shutil.rmtree` does: a folder moved out of the tree meanwhile is emptied where it went
    (its handle was open) and the walk goes on in the tree.  Deeper levels are left through ``..``, which
    must be the folder the walk came down from (same device and inode), else the removal stops with
    :class:`OSError` (``ESTALE``) instead of going on in the folder the moved one went to.  That check alone
    can be fooled on file systems that reuse a freed inode number at once (ext4): a concurrent process would
    have to move a folder out more than :data:`HELD_LEVELS` levels down, remove its parent and make a folder
    that receives the parent's number, all while the walk is below it.  Links are removed as links.  Entries
    that vanish meanwhile (another process removing the same leftover), or a missing ``path``, are fine; any
    other failure raises :class:`OSError`, and so do ``path`` being a link (also written ``L/`` or ``L/.``)
    and ``path`` not being a folder.  Links *above* ``path`` are followed, as by :func:`shutil.rmtree`:
    callers check them (:func:`confined`).  Whether the folder is gone afterwards is the caller's to check.

    Parameters
    ----------
    path : str or os.PathLike
        The folder to delete.
    """
    path = os.path.normpath(os.fspath(path))  # "L/", "L/." and "L/x/.." name the link L itself
    if os.path.islink(path):
        raise OSError(errno.ELOOP, "will not remove a tree through a symbolic link", path)
    try:
        fd = os.open(path, _DIR_FLAGS)
    except FileNotFoundError:
        return
    # Per level above ``fd``: the sub-folders still to remove there, the one ``fd`` holds, and the level's
    # open handle (within HELD_LEVELS) or its (device, inode) to check ``..`` against.
    above = []
    try:
        pending = _unlink_files(fd)
        while True:
            if pending:  # go down into the next sub-folder
                sub = pending.pop()
                held = len(above) < HELD_LEVELS
                parent = fd if held else _identity(fd)
                try:
                    child = os.open(sub, _DIR_FLAGS, dir_fd=fd)
                except FileNotFoundError:
                    continue
                above.append((pending, sub, parent))
                if not held:
                    os.close(fd)
                fd = child
                pending = _unlink_files(fd)
                continue
            if not above:  # ``path`` itself is empty
                break
            pending, done, parent = above.pop()
            fd = _climb(fd, parent)
            if fd is None:  # ``..`` was not the folder the walk came down from: ``fd`` closed
                moved = f"a folder of the tree was moved out of it while {done!r} was removed"
                raise OSError(errno.ESTALE, moved, path)
            with contextlib.suppress(FileNotFoundError):  # removed by another process meanwhile
                os.rmdir(done, dir_fd=fd)
    finally:
        _close_walk(above, fd)
    with contextlib.suppress(FileNotFoundError):
        os.rmdir(path)


def _close_walk(above: list, fd: int | None) -> None:
    """Close the walk's open folder ``fd`` (if any) and the handles held in ``above``."""
    for held in (entry[2] for entry in above if isinstance(entry[2], int)):
        os.close(held)
    if fd is not None:
        os.close(fd)


def _climb(fd: int, parent) -> int | None:
    """From the folder ``fd`` (closed here) back to its parent: the parent's held handle (an int), or its
    ``..`` when that is the folder of identity ``parent`` (device, inode), else None."""
    if isinstance(parent, int):
        os.close(fd)
        return parent
    up = os.open("..", _DIR_FLAGS, dir_fd=fd)
    os.close(fd)
    if _identity(up) == parent:
        return up
    os.close(up)
    return None


def _identity(fd: int) -> tuple[int, int]:
    """(device, inode) of the open folder ``fd``."""
    st = os.fstat(fd)
    return st.st_dev, st.st_ino


def _unlink_files(fd: int) -> list[str]:
    """Remove the entries of the folder ``fd`` that are not folders (links included); its sub-folders' names."""
    folders = []
    with os.scandir(fd) as entries:
        for entry in entries:
            if entry.is_dir(follow_symlinks=False):
                folders.append(entry.name)
                continue
            try:
                os.unlink(entry.name, dir_fd=fd)
            except FileNotFoundError:
                pass
    return folders


def copy_tree(src, dst) -> None:
    """Copy the folder ``src`` to the new folder ``dst`` without recursion: files with their times, links as links.

    A folder's permissions and times are copied after its contents, as :func:`shutil.copytree` does (a
    read-only folder can be filled, and its time is not changed by the filling).

    Parameters
    ----------
    src : str or os.PathLike
        The folder to copy.
    dst : str or os.PathLike
        The copy; must not exist (:class:`FileExistsError` otherwise), its parent must.
    """
    src, dst = os.fspath(src), os.fspath(dst)
    folders = []
    for base, dirs, files in walk(src):
        target = os.path.normpath(os.path.join(dst, os.path.relpath(base, src)))
        os.mkdir(target)
        folders.append((base, target))
        for name in files + [d for d in dirs if os.path.islink(os.path.join(base, d))]:
            shutil.copy2(os.path.join(base, name), os.path.join(target, name), follow_symlinks=False)
    for base, target in reversed(folders):  # deepest first
        shutil.copystat(base, target, follow_symlinks=False)


def confined(root, path, *, through_links: bool = False) -> str:
    """``path``, after checking it is safe for the store at ``root`` to change or remove.

    The path must not be a symbolic link itself, its parent must resolve (all
    links followed) to the store root or a folder inside it, and no folder
    between the root and the path may be a symbolic link either: a link planted
    in the store (``subjects/X -> R2``) must not lead maintenance to another of
    the store's own folders any more than out of the store.  What the path
    names need not exist.

    Parameters
    ----------
    root : str or os.PathLike
        The store directory (itself may be reached through a link).
    path : str or os.PathLike
        A path inside it (``os.path.join(root, rel)``).
    through_links : bool
        Allow links among the folders between the root and the path, as long as
        they resolve inside the store (reads only: they never change anything).

    Returns
    -------
    str
        ``path``, checked.

    Raises
    ------
    StoreError
        Naming the path and what leads out of the store (or through a link).
    """
    path = os.fspath(path)
    real_root = os.path.realpath(root)
    parent = os.path.realpath(os.path.dirname(path) or ".")
    if parent != real_root and not parent.startswith(real_root + os.sep):
        raise StoreError(
            f"refusing to touch {path}: it resolves to {parent}, outside the store {real_root} (a symbolic link?)"
        )
    if os.path.islink(path):
        raise StoreError(f"refusing to touch {path}: it is a symbolic link, not something the store created")
    if not through_links:
        base = os.path.abspath(root)
        rel = os.path.relpath(os.path.abspath(os.path.dirname(path) or "."), base)
        if rel != os.curdir and not rel.startswith(os.pardir):
            for part in rel.split(os.sep):
                base = os.path.join(base, part)
                if os.path.islink(base):
                    raise StoreError(
                        f"refusing to touch {path}: {base} is a symbolic link (not a folder the store created); "
                        "facestats never changes or removes anything reached through a link"
                    )
    return path


def generation_strays(path) -> list[str]:
    """Entries inside the generation folder ``path`` that Zarr did not write, relative to it (links not followed).

    A generation holds its group's ``zarr.json`` and one folder per variable
    with the array's ``zarr.json`` and its chunks under ``c`` (folders and files
    named by chunk indices, or a file ``c`` for a 0-d array), and, after an
    interrupted write, Zarr's temporary ``*.<hex>.partial`` files.  Anything
    else (a note, a file where a variable's folder is due, a link, a FIFO) was
    put there by someone else: maintenance never deletes a generation holding such
    entries.  A missing or unreadable folder gives an empty list.

    Parameters
    ----------
    path : str or os.PathLike
        The generation folder.

    Returns
    -------
    list of str
        Paths relative to ``path`` (e.g. ``notes.txt``, ``<variable>/c/x``); empty when it holds only Zarr's.
    """
    out = []
    for name in sorted_names(path):
        p = os.path.join(path, name)
        if _ZARR_PARTIAL.fullmatch(name) and is_plain_file(p):
            continue
        if name == ROOT_META:
            if not is_plain_file(p):
                out.append(name)
        elif not is_plain_dir(p):
            out.append(name)
        else:
            out += [f"{name}/{s}" for s in _variable_strays(p)]
    return out


def sorted_names(path) -> list[str]:
    """The names in folder ``path``, sorted; none if it is missing or unreadable.

    Parameters
    ----------
    path : str or os.PathLike
        The folder.

    Returns
    -------
    list of str
    """
    try:
        return sorted(os.listdir(path))
    except OSError:
        return []


def _variable_strays(path) -> list[str]:
    """Entries of one variable folder other than its ``zarr.json`` and its chunk tree ``c``."""
    out = []
    for name in sorted_names(path):
        p = os.path.join(path, name)
        if (name in (ROOT_META, "c") or _ZARR_PARTIAL.fullmatch(name)) and is_plain_file(p):
            continue
        if name != "c" or not is_plain_dir(p):
            out.append(name)
            continue
        out += _chunk_strays(path, p)
    return out


def _chunk_strays(var: str, top: str) -> list[str]:
    """Entries of the chunk tree ``top`` of the variable folder ``var`` not named by chunk indices (relative to it)."""
    out = []
    for base, dirs, files in walk(top):
        for n in dirs + files:
            q = os.path.join(base, n)
            chunk = n.isascii() and n.isdigit() and (is_plain_dir(q) if n in dirs else is_plain_file(q))
            if not chunk and not (n in files and _ZARR_PARTIAL.fullmatch(n) and is_plain_file(q)):
                out.append(os.path.relpath(q, var))
        dirs[:] = [d for d in dirs if d.isascii() and d.isdigit() and is_plain_dir(os.path.join(base, d))]
    return out


def group_meta(attributes=None) -> dict:
    """The ``zarr.json`` document of a Zarr v3 group with ``attributes``.

    Parameters
    ----------
    attributes : dict, optional
        The group's attributes (copied; default none).

    Returns
    -------
    dict
        ``{"zarr_format": 3, "node_type": "group", "attributes": {...}}``.
    """
    return {"zarr_format": 3, "node_type": "group", "attributes": dict(attributes or {})}


def fsync_path(path, directory: bool = False) -> None:
    """Flush a file (or, with ``directory=True``, a directory entry list) to disk.

    A file is opened without blocking and must be a regular file (:func:`open_regular_file`): a FIFO planted where
    a file should be raises instead of blocking the open.

    Parameters
    ----------
    path : str or os.PathLike
        The file or directory (opened read-only).
    directory : bool
        ``path`` is a directory (opened with ``O_DIRECTORY``: anything else raises :class:`NotADirectoryError`).

    Raises
    ------
    OSError
        ``path`` cannot be opened, is not a regular file (``directory=False``), or the flush fails.
    """
    if not directory:
        with open_regular_file(path) as f:
            os.fsync(f.fileno())
        return
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@functools.cache
def _syncfs():
    """The C library's ``syncfs(2)`` (Linux), or None where there is none."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).syncfs
    except (OSError, AttributeError):
        return None
    fn.argtypes, fn.restype = [ctypes.c_int], ctypes.c_int
    return fn


def fsync_tree(path) -> None:
    """Flush every file and directory under ``path`` to disk.

    On Linux one ``syncfs(2)`` call on ``path`` flushes the whole filesystem that
    holds it, data and directory entries alike: one journal commit instead of
    one per file (a generation of the default store has about 170 files; on
    ext4 this took 12-19 ms against 53-364 ms for ``fsync`` file by file).
    Since Linux 5.8 it reports write-back errors like ``fsync`` does.  Where
    there is no ``syncfs`` (or it fails for want of support), every regular file
    and directory is ``fsync``-ed in turn; anything else under ``path`` (a FIFO,
    socket, device or symbolic link) is skipped, never opened, so a FIFO planted
    in the tree cannot block the flush.

    Parameters
    ----------
    path : str or os.PathLike
        A folder (or a file: ``syncfs`` is then called on its folder; without it the file and its folder are
        ``fsync``-ed).

    Raises
    ------
    OSError
        ``syncfs`` fails for another reason than missing support, or a file-by-file ``fsync`` fails.
    """
    fn = _syncfs()
    if fn is not None:
        where = path if os.path.isdir(path) else (os.path.dirname(os.fspath(path)) or ".")  # never open a FIFO
        fd = os.open(where, os.O_RDONLY | os.O_DIRECTORY)
        try:
            failed = fn(fd) != 0
            err = ctypes.get_errno()
        finally:
            os.close(fd)
        if not failed:
            return
        if err not in (errno.ENOSYS, errno.EINVAL):
            raise OSError(err, f"syncfs failed: {os.strerror(err)}", os.fspath(path))
    if not os.path.isdir(path):  # a file: it and its folder (walk would list nothing)
        _fsync_regular(path)
        fsync_path(os.path.dirname(os.fspath(path)) or ".", directory=True)
        return
    for root, _, files in walk(path):
        for f in files:
            _fsync_regular(os.path.join(root, f))
        fsync_path(root, directory=True)


def _fsync_regular(path) -> None:
    """``fsync`` the file ``path`` if it is a regular file; a FIFO, socket, device or link is left alone.

    Opened by :func:`open_regular_file` (without blocking and without following a link), whose refusals of
    anything but a regular file (EINVAL, ELOOP, EISDIR) mean "leave it alone" here, as does a file gone since
    it was listed (ENOENT).
    """
    try:
        with open_regular_file(path, follow_links=False) as f:
            os.fsync(f.fileno())
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.ELOOP, errno.EISDIR, errno.ENOENT):
            raise


def write_json_atomic(path, obj, *, durable: bool = True) -> None:
    """Replace ``path`` by ``obj`` as indented JSON: temporary file, ``fsync`` (if ``durable``), ``os.replace``.

    A failure (e.g. a full disk) removes the temporary file and leaves ``path`` as it was.

    Parameters
    ----------
    path : str or os.PathLike
        The file to replace (or create); the temporary file ``<path>.tmp-<pid>-<6 hex>`` is made beside it.
    obj : object
        A JSON-serialisable document.
    durable : bool
        ``fsync`` the temporary file before the rename (the folder itself is not ``fsync``-ed).
    """
    tmp = f"{path}.tmp-{os.getpid()}-{secrets.token_hex(3)}"
    try:
        with open(tmp, "w") as fh:
            json.dump(obj, fh, indent=2)
            fh.flush()
            if durable:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise
