"""Process life: whether a process that left something behind is known to be gone, SIGTERM as Ctrl-C, and the
memory a process can still take.

The liveness test of crash clean-ups (:func:`process_gone`).  A process is *known to be gone* only when it ran on this
host and ``kill(pid, 0)`` says there is no such process; on another host, or when the answer is unclear
(a live process of another user, a malformed pid), it is assumed alive, so nothing it may still use is
removed.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import threading

__all__ = ["available_memory", "process_gone", "sigterm_as_interrupt"]


@contextlib.contextmanager
def sigterm_as_interrupt():
    """Turn SIGTERM into :class:`KeyboardInterrupt` (as SIGINT is) in the main thread while the block runs.

    The code that cleans up after Ctrl-C (temporary folders, a builder's half-written files, a rig's lights)
    then cleans up after ``kill`` too; the previous handler is restored afterwards.  In another thread, where
    no handler can be set, the block runs unchanged.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise KeyboardInterrupt(f"stopped by signal {signum}")

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def process_gone(pid, host: str | None = None) -> bool:
    """True when process ``pid`` of ``host`` (default: this machine) is known to have ended.

    Parameters
    ----------
    pid : int or str
        The process id that was recorded.
    host : str, optional
        The host name that was recorded with it (``socket.gethostname()``); another host's process
        cannot be checked and counts as alive.

    Returns
    -------
    bool
        True only when the process is known to have ended (False when unsure).
    """
    if host is not None and host != socket.gethostname():
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return True
    except (PermissionError, OSError, ValueError, TypeError, OverflowError):  # another user's, or no usable pid
        return False
    return False


def available_memory(root="/") -> float | None:
    """Bytes of memory available now: the least of Linux's ``MemAvailable`` and the room left under the memory
    limits of this process's control groups; else the physical memory; else None (unknown).

    For checks made before large work (a build's simulated captures, a relight's visibility table): a
    refusal that names the need and this figure is clearer than the out-of-memory killer.  In a container
    ``MemAvailable`` is the host's: a 2 GiB limit on a 64 GiB machine let a build of 10 GiB start, and the
    kernel killed it.  The room under a limit is ``limit − (usage − inactive file cache)`` (the cache the
    kernel reclaims before it kills: the working set of ``docker stats`` and the kubelet), for the process's
    group and each group above it (cgroup v2 ``memory.max``/``memory.current``; v1
    ``memory.limit_in_bytes``/``memory.usage_in_bytes``); files that are missing or unreadable mean no limit.

    Parameters
    ----------
    root : str or os.PathLike
        The file system root ``/proc`` and ``/sys/fs/cgroup`` are read under (default ``/``; another for tests).

    Returns
    -------
    float or None
    """
    have = []
    try:
        with open(os.path.join(root, "proc", "meminfo")) as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    have.append(float(line.split()[1]) * 1024)
                    break
    except (OSError, ValueError, IndexError):  # no /proc, or a line that is no number of kB
        pass
    have.extend(_cgroup_room(root))
    if have:
        return max(0.0, min(have))
    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


#: (controller name in /proc/self/cgroup, mount point, limit file, usage file, inactive file cache in memory.stat)
_CGROUP_MEMORY = (
    ("", "sys/fs/cgroup", "memory.max", "memory.current", "inactive_file"),  # v2 (line "0::/path")
    ("memory", "sys/fs/cgroup/memory", "memory.limit_in_bytes", "memory.usage_in_bytes", "total_inactive_file"),
)


def _cgroup_room(root) -> list[float]:
    """Bytes left under each memory limit of this process's control groups (:func:`available_memory`)."""
    try:
        with open(os.path.join(root, "proc", "self", "cgroup")) as fh:
            lines = fh.read().splitlines()
    except OSError:
        return []
    room = []
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        for controller, mount, limit_file, usage_file, cache_key in _CGROUP_MEMORY:
            v2 = parts[0] == "0" and parts[1] == ""
            if (v2 and not controller) or (controller and controller in parts[1].split(",")):
                for folder in _cgroup_folders(os.path.join(root, mount), parts[2]):
                    left = _room_in(folder, limit_file, usage_file, cache_key)
                    if left is not None:
                        room.append(left)
    return room


def _cgroup_folders(mount, path) -> list[str]:
    """The group's folder under ``mount`` and those of the groups above it, up to the mount itself.

    In a container with its own cgroup namespace the path named in /proc/self/cgroup may not exist under the
    mount (which then is the container's group): the mount alone is read.
    """
    folder = os.path.join(mount, path.strip("/"))
    if not os.path.isdir(folder):
        return [mount]
    folders = [folder]
    while os.path.normpath(folder) != os.path.normpath(mount):
        folder = os.path.dirname(folder)
        folders.append(folder)
    return folders


def _room_in(folder, limit_file, usage_file, cache_key) -> float | None:
    """``limit − (usage − inactive file cache)`` of one group, or None (no limit, or files missing)."""
    try:
        with open(os.path.join(folder, limit_file)) as fh:
            limit = fh.read().strip()
        with open(os.path.join(folder, usage_file)) as fh:
            usage = float(fh.read().strip())
        if limit == "max" or float(limit) >= 2.0**62:  # v2 "max"; v1 writes no limit as a page-rounded 2^63 - 1
            return None
        cache = 0.0
        try:
            with open(os.path.join(folder, "memory.stat")) as fh:
                for line in fh:
                    key, _, value = line.partition(" ")
                    if key == cache_key:
                        cache = float(value)
                        break
        except (OSError, ValueError):
            pass
        return float(limit) - max(0.0, usage - cache)
    except (OSError, ValueError):
        return None
