"""Whether an exception is a Ctrl-C in disguise.

A KeyboardInterrupt raised while compiled code runs (numba) may come back as a
``SystemError`` ("... returned a result with an exception set") whose cause or
context is the interrupt; commands report it as an interrupt, not as a bug.
"""

from __future__ import annotations

__all__ = ["is_interrupt"]


def is_interrupt(exc: BaseException) -> bool:
    """True if ``exc`` is a KeyboardInterrupt or was raised while one was being handled (its chain holds one).

    Parameters
    ----------
    exc : BaseException or None
        The exception caught.

    Returns
    -------
    bool
        Whether a KeyboardInterrupt is ``exc`` or on its chain (each step follows ``__cause__``, else
        ``__context__``; a cycle ends the walk).
    """
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False
