"""Advisory file locks for the parameter store (zarr itself has no locking).

The store uses two kinds of lock, both POSIX ``flock`` locks on small files:

* the **store lock** (``<store>/.lock``): held exclusively while a writer
  commits a new version of the population index, and while garbage collection
  decides what to delete.  It is held for milliseconds, never while subject
  data are written.
* a **writer lock** per generation being written
  (``<store>/.writers/<subject>~<generation>.lock``): held by the writing
  process from before it creates the generation directory until after the
  commit.  Garbage collection never deletes an unreferenced generation whose
  writer lock is still held, so it cannot remove the half-written data of a
  live writer; the lock of a killed process is released by the kernel, so
  its leftovers can be collected.

``flock`` locks belong to an open file description: two threads or two
processes that open the file separately exclude each other, and a process
killed with ``SIGKILL`` releases its locks.  They are not reliable on some
network file systems (older NFS); keep stores on local disks.
"""

from __future__ import annotations

import errno
import fcntl
import os
import time

from facestats.errors import StoreError

__all__ = ["FileLock", "is_locked", "try_lock", "create_locked", "is_lock_temp"]


class FileLock:
    """An exclusive ``flock`` on ``path`` (created if missing, never through a symbolic link), with a timeout.

    Use as a context manager::

        with FileLock(root / ".lock", timeout=60):
            ...  # commit

    Parameters
    ----------
    path : str or os.PathLike
        The lock file.
    timeout : float
        Seconds to wait for the lock before raising :class:`StoreError`.
    create : bool
        Create the lock file if it is missing (otherwise a missing file raises
        :class:`FileNotFoundError`, which :func:`is_locked` relies on).
    """

    def __init__(self, path, timeout: float = 60.0, *, create: bool = True):
        self.path = os.fspath(path)
        self.timeout = float(timeout)
        self.create = create
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self, blocking: bool = True) -> bool:
        """Take the lock; return False (non-blocking) or raise :class:`StoreError` (timeout) if busy.

        Parameters
        ----------
        blocking : bool
            Wait up to :attr:`timeout` seconds for the lock (default); False: try once.

        Returns
        -------
        bool
            True once the lock is held; False if it is busy and ``blocking`` is False.

        Raises
        ------
        StoreError
            The lock is already held by this object; the file cannot be opened (a symbolic link, its folder
            missing with ``create=True``); ``flock`` fails; or the timeout passes while it is busy.
        """
        if self._fd is not None:
            raise StoreError(f"lock {self.path} is already held by this object")
        flags = os.O_RDWR | os.O_NOFOLLOW | (os.O_CREAT if self.create else 0)
        try:
            fd = os.open(self.path, flags, 0o644)
        except FileNotFoundError:
            if not self.create:
                raise
            raise StoreError(f"cannot open lock file {self.path}: its folder does not exist") from None
        except OSError as exc:
            what = "it is a symbolic link" if exc.errno == errno.ELOOP else exc.strerror
            raise StoreError(f"cannot open lock file {self.path}: {what}") from None
        deadline = time.monotonic() + self.timeout
        delay = 0.0005
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                self._fd = fd
                return True
            except OSError as exc:
                if exc.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                    os.close(fd)
                    raise StoreError(f"cannot lock {self.path}: {exc.strerror}") from exc
            if not blocking:
                os.close(fd)
                return False
            if time.monotonic() >= deadline:
                os.close(fd)
                raise StoreError(
                    f"timed out after {self.timeout:g} s waiting for the lock {self.path} "
                    "(another process is writing to the store)"
                )
            time.sleep(delay)
            delay = min(delay * 2, 0.02)

    def release(self) -> None:
        """Release the lock (no-op if not held)."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            try:
                fcntl.flock(fd, fcntl.LOCK_UN)
            finally:
                os.close(fd)

    def __enter__(self):
        self.acquire()
        return self

    def __exit__(self, *exc):
        self.release()
        return False

    def __del__(self):  # pragma: no cover - safety net
        self.release()


def try_lock(path, *, create: bool = True) -> FileLock | None:
    """Take the lock on ``path`` without waiting; the held :class:`FileLock`, or None if busy.

    With ``create=False`` a missing file raises :class:`FileNotFoundError` instead of being created.

    Parameters
    ----------
    path : str or os.PathLike
        The lock file.
    create : bool
        Create ``path`` if it is missing.

    Returns
    -------
    FileLock or None

    Raises
    ------
    StoreError
        ``path`` cannot be opened (a symbolic link, its folder missing with ``create=True``) or ``flock`` fails.
    """
    lock = FileLock(path, timeout=0, create=create)
    return lock if lock.acquire(blocking=False) else None


def is_locked(path) -> bool:
    """True if another open file description holds a lock on the existing file ``path``.

    Never creates ``path``: a file that is missing (or vanishes while it is
    checked) is not locked.

    Parameters
    ----------
    path : str or os.PathLike
        The lock file.

    Returns
    -------
    bool

    Raises
    ------
    StoreError
        ``path`` exists but cannot be opened (a symbolic link, no read permission) or ``flock`` fails.

    Notes
    -----
    A lock file this process may read but not write (a store read-only to this user) is tested through a read-only
    descriptor: ``flock`` needs no write access on a local file system (``validate`` of such a store holding a
    dead writer's lock stopped at "Permission denied").  Where it does (NFS, whose ``flock`` is a ``fcntl``
    lock), the test fails with a :class:`StoreError` as before.
    """
    try:
        lock = try_lock(path, create=False)
    except FileNotFoundError:
        return False
    except StoreError:
        if os.path.islink(path) or not os.access(path, os.R_OK) or os.access(path, os.W_OK):
            raise  # not a matter of write permission
        return _locked_read_only(path)
    if lock is None:
        return True
    lock.release()
    return False


def _locked_read_only(path) -> bool:
    """:func:`is_locked` through a read-only descriptor (a lock file this process may not write)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    except FileNotFoundError:
        return False
    except OSError as exc:
        raise StoreError(f"cannot open lock file {path}: {exc.strerror}") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError as exc:
        raise StoreError(f"cannot lock {path}: {exc.strerror}") from None
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return False
    finally:
        os.close(fd)


def create_locked(path) -> FileLock:
    """Create the lock file ``path`` already locked, and return the held lock.

    The file is created under a temporary name, locked, then renamed into
    place, so no other process can ever observe ``path`` unlocked while its
    creator is alive (garbage collection relies on this).  Raises
    :class:`StoreError` if ``path`` already exists.

    Parameters
    ----------
    path : str or os.PathLike
        The lock file to create; its folder must exist.

    Returns
    -------
    FileLock
        Held, its ``path`` set to ``path``.
    """
    path = os.fspath(path)
    folder, name = os.path.split(path)
    tmp = os.path.join(folder, f".tmp-{os.getpid()}-{name}")
    lock = FileLock(tmp, timeout=0)
    if not lock.acquire(blocking=False):  # pragma: no cover - tmp names are unique per process
        raise StoreError(f"cannot lock {tmp}")
    try:
        if os.path.exists(path):
            raise StoreError(f"lock file {path} already exists")
        os.rename(tmp, path)
    except BaseException:
        try:
            os.remove(tmp)
        except OSError:
            pass
        lock.release()
        raise
    lock.path = path
    return lock


def is_lock_temp(name: str) -> bool:
    """True for the temporary names :func:`create_locked` uses.

    Parameters
    ----------
    name : str
        A file name (not a path).

    Returns
    -------
    bool
    """
    return name.startswith(".tmp-")
