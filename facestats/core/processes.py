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


def available_memory() -> float | None:
    """Bytes of memory available now: Linux's ``MemAvailable``, else the physical memory, else None (unknown).

    For checks made before large work (a build's simulated captures, a relight's visibility table): a
    refusal that names the need and this figure is clearer than the out-of-memory killer.

    Returns
    -------
    float or None
    """
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None
