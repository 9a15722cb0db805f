"""Byte access to the files of a store: a directory, or a read-only zip of one.

A backend answers the few questions :class:`facestats.io.store.Store` asks of
the storage (read a file, does it exist, has the index changed, where does Zarr
open a group, how big is the store) so the store logic is the same for both
kinds.  Paths are relative to the store root, with ``/`` separators.

Zip stores (:func:`facestats.io.packing.pack_store`) hold the root
``zarr.json`` and ``index.json`` first and uncompressed: they are read straight
from the head of the file (:func:`read_leading_entries`), without parsing the
zip directory of every chunk, so ``facestats query`` on the embedded default
stays fast; subject groups are opened through ``zarr.storage.ZipStore``.
"""

from __future__ import annotations

import os
import stat
import struct
import zipfile
import zlib

from facestats.errors import StoreError
from facestats.io.index import INDEX_NAME
from facestats.io.layout import ROOT_META, confined, read_regular_file, walk

__all__ = ["DirectoryBackend", "ZipBackend", "read_leading_entries"]


class DirectoryBackend:
    """The files of a directory store.

    Parameters
    ----------
    root : str
        The store directory.
    """

    kind = "directory"

    def __init__(self, root: str):
        self.root = root

    def read(self, rel: str) -> bytes:
        """The bytes of the regular file ``rel`` (:class:`OSError` if missing, a link or not a regular file).

        Parameters
        ----------
        rel : str
            The file's path relative to the store root, ``/``-separated.

        Returns
        -------
        bytes
        """
        return read_regular_file(os.path.join(self.root, rel), follow_links=False)

    def exists(self, rel: str) -> bool:
        """True if ``rel`` exists.

        Parameters
        ----------
        rel : str
            The path relative to the store root (a file or a folder; links are followed).

        Returns
        -------
        bool
        """
        return os.path.exists(os.path.join(self.root, rel))

    def index_key(self):
        """A value that changes whenever ``index.json`` is replaced (None if there is no index)."""
        try:
            st = os.stat(os.path.join(self.root, INDEX_NAME))
        except FileNotFoundError:
            return None
        return (st.st_ino, st.st_mtime_ns, st.st_size)

    def zarr_target(self, rel: str):
        """``(store, group)`` arguments for :func:`xarray.open_zarr` of the group ``rel``.

        Parameters
        ----------
        rel : str
            The group's folder relative to the store root.

        Returns
        -------
        tuple
            ``(path, None)``: the group's folder, opened as a store of its own.
        """
        return os.path.join(self.root, rel), None

    def strange_entry(self, rel: str) -> str | None:
        """The first entry under the group ``rel`` that is neither a regular file nor a folder, or None.

        A FIFO planted where a chunk should be would make Zarr block forever on
        reading it, and a link could lead reads out of the store; such entries
        are found (without following links) before the group is opened.

        Parameters
        ----------
        rel : str
            The group's folder relative to the store root.

        Returns
        -------
        str or None
            The entry's path relative to the store root; ``rel`` itself if the group, or a folder above it, is a
            link leading out of the store.
        """
        top = os.path.join(self.root, rel)
        try:
            confined(self.root, top, through_links=True)  # the group, or a folder above it, is a link out of the store
        except StoreError:
            return rel
        for base, dirs, files in walk(top):
            for name in dirs + files:
                try:
                    mode = os.lstat(os.path.join(base, name)).st_mode
                except OSError:  # e.g. a path beyond PATH_MAX: Zarr, which reads by path, cannot reach it either
                    continue
                if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
                    return os.path.relpath(os.path.join(base, name), self.root)
        return None

    def size(self) -> int:
        """Bytes on disk of every file of the store."""
        total = 0
        for root, _, files in walk(self.root):
            for f in files:
                try:
                    total += os.path.getsize(os.path.join(root, f))
                except OSError:
                    pass
        return total

    def close(self):
        """Nothing to release."""


def read_leading_entries(path: str, names) -> dict:
    """Read the stored entries ``names`` from the start of a zip without parsing its central directory.

    :func:`facestats.io.packing.pack_store` writes ``zarr.json`` and
    ``index.json`` first, uncompressed, so ``facestats query`` can read them
    with two small reads instead of parsing the directory of every chunk file.
    Stops at the first entry that is not one of ``names`` or is compressed;
    the caller falls back to :class:`zipfile.ZipFile` for whatever was not
    found.  CRCs are checked.

    Parameters
    ----------
    path : str
        The zip file.
    names : collection of str
        The entry names wanted (e.g. ``("zarr.json", "index.json")``).

    Returns
    -------
    dict
        ``{name: bytes}`` of the entries found.
    """
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


class ZipBackend:
    """The files of a zip store (read-only).

    Parameters
    ----------
    path : str
        The zip file.
    """

    kind = "zip"

    def __init__(self, path: str):
        self.root = path
        try:
            self._lead = read_leading_entries(path, (ROOT_META, INDEX_NAME))
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
        """The bytes of the entry ``rel`` (:class:`FileNotFoundError` if missing).

        Parameters
        ----------
        rel : str
            The entry's name: its path relative to the store root, ``/``-separated.

        Returns
        -------
        bytes

        Raises
        ------
        StoreError
            If the zip file cannot be opened (an entry not read from its head needs its directory).
        """
        if rel in self._lead:
            return self._lead[rel]
        try:
            return self._zf().read(rel)
        except KeyError:
            raise FileNotFoundError(rel) from None

    def exists(self, rel: str) -> bool:
        """True if the zip has the entry ``rel``.

        Parameters
        ----------
        rel : str
            The entry's name, relative to the store root.

        Returns
        -------
        bool

        Raises
        ------
        StoreError
            If the zip file cannot be opened (an entry not read from its head needs its directory).
        """
        if rel in self._lead:
            return True
        self._zf()
        return rel in self._names

    def index_key(self):
        """``"zip"`` if the zip has an index (it never changes), else None."""
        return "zip" if self.exists(INDEX_NAME) else None

    def strange_entry(self, rel: str) -> None:
        """Entries of a zip are bytes: never a FIFO or a link (None).

        Parameters
        ----------
        rel : str
            The group, relative to the store root (not looked at).

        Returns
        -------
        None
        """
        return None

    def zarr_target(self, rel: str):
        """``(store, group)`` arguments for :func:`xarray.open_zarr` of the group ``rel``.

        Parameters
        ----------
        rel : str
            The group's path inside the zip.

        Returns
        -------
        tuple
            ``(zarr.storage.ZipStore, rel)``: the read-only zip store (opened once, shared) and the group in it.
        """
        if self._zarr is None:
            from zarr.storage import ZipStore

            self._zarr = ZipStore(self.root, mode="r")
        return self._zarr, rel

    def size(self) -> int:
        """Bytes of the zip file."""
        return os.path.getsize(self.root)

    def close(self):
        """Close the zip file and the Zarr zip store if they were opened."""
        if self._zip is not None:
            self._zip.close()
            self._zip = None
        if self._zarr is not None:
            self._zarr.close()
            self._zarr = None
