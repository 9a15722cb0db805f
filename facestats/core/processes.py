"""Whether a process that left something behind (a journal record, a temporary folder) is known to be gone.

One job: the liveness test of crash clean-ups.  A process is *known to be gone* only when it ran on this
host and ``kill(pid, 0)`` says there is no such process; on another host, or when the answer is unclear
(a live process of another user, a malformed pid), it is assumed alive, so nothing it may still use is
removed.
"""

from __future__ import annotations

import os
import socket

__all__ = ["process_gone"]


def process_gone(pid, host: str | None = None) -> bool:
    """True when process ``pid`` of ``host`` (default: this machine) is known to have ended.

    Parameters
    ----------
    pid : int or str
        The process id that was recorded.
    host : str, optional
        The host name that was recorded with it (``socket.gethostname()``); another host's process
        cannot be checked and counts as alive.
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
