"""The quarantine of a directory store: where repair puts what it takes out of the store, instead of deleting it.

Repair never deletes data.  What it must take away — a damaged generation, an
unreadable index file, the index entries it drops — goes into one folder per
repair under ``quarantine/`` in the store::

    quarantine/<UTC time>-<6 hex>/
      QUARANTINE.json              what is here and why (format 1)
      subjects/<id>/<generation>/  a moved generation, with its record <generation>.json
      index.json                   a moved index file
      dropped-entries.json         index entries repair removed ({id: entry})

Items are moved with :func:`os.rename` (atomic, no copy); if the data live on
another volume than the store root (``subjects/`` a mount point) they are
copied, flushed and listed in ``QUARANTINE.json``, and only then removed from
their place (a failed copy is removed from the quarantine again; a removal that
fails leaves the whole copy in the quarantine and says what is left in the
store).  ``facestats
validate`` lists the quarantine; only an explicit purge (``facestats validate
--purge --yes``, :meth:`facestats.io.store.Store.purge_quarantine`) removes
it, and it removes only folders that carry a valid ``QUARANTINE.json``.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import secrets
import shutil
import time

from facestats.errors import StoreError
from facestats.io.layout import (
    QUARANTINE,
    confined,
    copy_tree,
    fsync_tree,
    is_plain_dir,
    read_regular_file,
    remove_tree,
    walk,
    write_json_atomic,
)

__all__ = [
    "MANIFEST",
    "open_quarantine",
    "quarantine_move",
    "write_quarantine_json",
    "list_quarantine",
    "purge_quarantine",
    "manifest_problem",
]

#: The description file of a quarantine folder.
MANIFEST = "QUARANTINE.json"
_FOLDER = re.compile(r"[0-9]{8}T[0-9]{6}Z-[0-9a-f]{6}")


def open_quarantine(root, reason: str) -> str:
    """Create a new quarantine folder in the store at ``root`` and describe it; its path.

    Parameters
    ----------
    root : str
        The store directory.
    reason : str
        Why (recorded in ``QUARANTINE.json``).

    Returns
    -------
    str
        ``<root>/quarantine/<YYYYMMDDTHHMMSSZ>-<6 hex>`` (absolute only if ``root`` is).

    Raises
    ------
    StoreError
        It cannot be created (e.g. a full disk): nothing was moved yet.
    """
    base = os.path.join(root, QUARANTINE)
    name = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime()) + "-" + secrets.token_hex(3)
    path = os.path.join(base, name)
    try:
        confined(root, base)
        os.makedirs(path)
        if not is_plain_dir(base):
            raise StoreError(f"{base} must be a folder of the store")
        write_json_atomic(
            os.path.join(path, MANIFEST), {"format": 1, "created": name[:16], "reason": reason, "items": []}
        )
    except OSError as exc:
        raise StoreError(f"cannot create a quarantine folder in {base}: {exc.strerror}; nothing was changed") from None
    return path


def quarantine_move(root, qdir: str, rel: str, why: str) -> None:
    """Move ``rel`` (a path of the store) into the quarantine folder ``qdir``, keeping its relative path.

    Parameters
    ----------
    root : str
        The store directory.
    qdir : str
        A folder made by :func:`open_quarantine`.
    rel : str
        The path to move, relative to ``root`` (e.g. ``subjects/S001/<generation>``).
    why : str
        Listed with the item in ``QUARANTINE.json``.

    Raises
    ------
    StoreError
        It could not be moved (it stays where it was; a partial copy across volumes is removed from the
        quarantine), or, moved across volumes, its whole copy is in the quarantine (and listed) but removing
        the original failed: the message names the copy and says what is left of the original in the store.
    """
    src = confined(root, os.path.join(root, rel))
    dst = os.path.join(qdir, rel)
    folder = is_plain_dir(src)
    try:
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        try:
            os.rename(src, dst)
            copied = False
        except OSError as exc:
            if exc.errno != errno.EXDEV:
                raise
            _copy(src, dst, folder)
            copied = True
    except OSError as exc:
        raise StoreError(f"cannot move {rel} into the quarantine: {exc.strerror}; it was left in place") from None
    _add_item(qdir, rel, why)  # across volumes: the whole copy is listed before the original goes
    if not copied:
        return
    try:
        if folder:
            remove_tree(src)
        else:
            os.remove(src)
    except OSError as exc:
        left = "only partly removed (what is left of it is incomplete)" if folder else "left in place as well"
        raise StoreError(
            f"cannot finish moving {rel} into the quarantine: it was copied whole to {dst} (another volume), "
            f"but removing the original failed ({exc.strerror}): {src} was {left}"
        ) from None


def _copy(src: str, dst: str, folder: bool) -> None:
    """Copy ``src`` (a folder if ``folder``) to ``dst`` on another volume, links kept as links, and flush the copy.

    ``dst`` must not exist; a copy that fails is removed again (the original is whole, a partial copy is no use).
    """
    if os.path.lexists(dst):
        raise FileExistsError(errno.EEXIST, "the quarantine already holds that name", dst)
    try:
        if folder:
            copy_tree(src, dst)
            fsync_tree(dst)
        else:
            shutil.copy2(src, dst, follow_symlinks=False)
            fsync_tree(os.path.dirname(dst))
    except OSError:
        with contextlib.suppress(OSError):
            if folder:
                remove_tree(dst)
            else:
                os.remove(dst)
        raise


def write_quarantine_json(qdir: str, name: str, obj, why: str) -> None:
    """Save ``obj`` as ``<qdir>/<name>`` (e.g. the index entries a repair dropped) and list it.

    Parameters
    ----------
    qdir : str
        A folder made by :func:`open_quarantine`.
    name : str
        The file name inside it.
    obj : object
        A JSON-serialisable document.
    why : str
        Listed with the item in ``QUARANTINE.json``.

    Raises
    ------
    StoreError
        The file could not be written.
    """
    try:
        write_json_atomic(os.path.join(qdir, name), obj)
    except OSError as exc:
        raise StoreError(f"cannot save {name} in the quarantine: {exc.strerror}") from None
    _add_item(qdir, name, why)


def _manifest(qdir: str) -> dict | None:
    """The valid ``QUARANTINE.json`` of ``qdir``, or None."""
    return _read_manifest(qdir)[0]


def _read_manifest(qdir: str) -> tuple[dict | None, str | None]:
    """``(document, problem)`` of the ``QUARANTINE.json`` of ``qdir``.

    ``problem`` says what is wrong with a manifest that is there but malformed (naming the field and the
    value); a missing manifest is no problem (a folder not created by a repair): ``(None, None)``.
    """
    path = os.path.join(qdir, MANIFEST)
    if not os.path.lexists(path):
        return None, None
    if os.path.islink(path):
        return None, "is a symbolic link, not a file a repair wrote"
    try:
        doc = json.loads(read_regular_file(path))
    except OSError as exc:
        return None, f"cannot be read ({exc.strerror or exc})"
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        return None, f"is not valid JSON ({exc})"
    problem = manifest_problem(doc)
    return (None, problem) if problem else (doc, None)


def manifest_problem(doc) -> str | None:
    """What is wrong with a ``QUARANTINE.json`` document (naming the field and the value), or None if it is valid.

    Parameters
    ----------
    doc : object
        The document as decoded from JSON.

    Returns
    -------
    str or None
    """

    def show(v) -> str:
        text = repr(v)
        return text if len(text) <= 80 else text[:77] + "..."

    if not isinstance(doc, dict):
        return f"must be a JSON object, got {type(doc).__name__}"
    if doc.get("format") != 1:
        return f"field 'format' must be 1, got {show(doc.get('format'))}"
    if not isinstance(doc.get("reason", ""), str):
        return f"field 'reason' must be a string, got {show(doc.get('reason'))}"
    items = doc.get("items")
    if not isinstance(items, list):
        return f"field 'items' must be a list, got {show(items)}"
    for k, item in enumerate(items):
        if not isinstance(item, dict):
            return f"items[{k}] must be an object with the strings 'path' and 'why', got {show(item)}"
        for key in ("path", "why"):
            if not isinstance(item.get(key), str):
                return f"field {key!r} of items[{k}] must be a string, got {show(item.get(key))}"
    return None


def _add_item(qdir: str, rel: str, why: str) -> None:
    doc = _manifest(qdir) or {"format": 1, "items": []}
    doc["items"].append({"path": rel, "why": why})
    try:
        write_json_atomic(os.path.join(qdir, MANIFEST), doc)
    except OSError:
        pass  # the item is in the folder all the same


def _size(path: str) -> int:
    total = 0
    for base, _, files in walk(path):
        for f in files:
            try:
                total += os.lstat(os.path.join(base, f)).st_size
            except OSError:
                pass
    return total


def list_quarantine(root) -> list[dict]:
    """The quarantine folders of the store at ``root``, oldest first.

    Parameters
    ----------
    root : str
        The store directory.

    Returns
    -------
    list of dict
        ``{"name", "reason", "items": [{"path", "why"}], "bytes", "valid", "problem"}``; ``valid`` is False
        for a folder without a valid ``QUARANTINE.json`` (listed, never purged); ``problem`` says what is
        wrong with a ``QUARANTINE.json`` that is there but malformed (None otherwise).
    """
    base = os.path.join(root, QUARANTINE)
    if not is_plain_dir(base):
        return []
    out = []
    for name in sorted(os.listdir(base)):
        path = os.path.join(base, name)
        doc, problem = _read_manifest(path) if _FOLDER.fullmatch(name) and is_plain_dir(path) else (None, None)
        out.append(
            {
                "name": name,
                "reason": (doc or {}).get("reason", ""),
                "items": (doc or {}).get("items", []),
                "bytes": _size(path) if is_plain_dir(path) else 0,
                "valid": doc is not None,
                "problem": problem,
            }
        )
    return out


def purge_quarantine(root, names=None) -> list[str]:
    """Delete quarantine folders (all, or those in ``names``) that carry a valid ``QUARANTINE.json``.

    Parameters
    ----------
    root : str
        The store directory.
    names : collection of str, optional
        Names of the folders to remove (as :func:`list_quarantine` gives them); default all.

    Returns
    -------
    list of str
        The folders removed, relative to the store root.
    """
    removed = []
    for entry in list_quarantine(root):
        if not entry["valid"] or (names is not None and entry["name"] not in names):
            continue
        path = os.path.join(root, QUARANTINE, entry["name"])
        try:
            remove_tree(confined(root, path))
        except OSError as exc:
            raise StoreError(f"cannot remove {path}: {exc.strerror}") from None
        removed.append(f"{QUARANTINE}/{entry['name']}")
    return removed
