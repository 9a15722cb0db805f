"""Progress bars: one rule for every long loop of facestats.

A bar is shown when the caller asks for it (``enabled``, the ``progress=``
argument of the public functions; the command line asks for it), on stderr,
whether or not stderr is a terminal, so that a log of a long job shows how far
it got.  Written to a file or a pipe, a bar is redrawn at most every
:data:`LOG_INTERVAL_S` seconds (its first and last states always), not ten times
a second: a log holds a line now and then, not hundreds of carriage-return
updates (a notebook's bar, a widget or text, stays live).
``FACESTATS_PROGRESS=0`` in the environment hides every bar, and so does a
missing stderr (``sys.stderr`` None, as under ``pythonw``).  Bars come from
:mod:`tqdm.auto`: a widget in a notebook, text elsewhere, with the rate and the
ETA tqdm estimates.

A hidden bar is not a tqdm at all but :class:`QuietBar`, which iterates,
updates and closes at no cost.  This matters beyond speed: every tqdm takes
tqdm's write lock, a multiprocessing lock shared with forked processes, and a
forked worker killed while holding it (a cancelled build) would leave every
later bar of the parent waiting for ever.  Processes that show no bar never
touch it.
"""

from __future__ import annotations

import os
import sys

__all__ = ["PROGRESS_ENV", "LOG_INTERVAL_S", "QuietBar", "progress_bar", "bars_enabled"]

#: Environment variable that hides every bar when set to ``0``.
PROGRESS_ENV = "FACESTATS_PROGRESS"
#: Seconds between two redraws of a bar whose stderr is not a terminal (a log file or a pipe).
LOG_INTERVAL_S = 30.0


def bars_enabled(enabled=True) -> bool:
    """Whether a bar the caller asked for (``enabled``) is shown: not when ``FACESTATS_PROGRESS=0``.

    Parameters
    ----------
    enabled : bool
        Whether the caller asks for a bar (any truthy value; default True).

    Returns
    -------
    bool
        ``enabled`` and the environment variable :data:`PROGRESS_ENV` is not ``0`` (blanks stripped).
    """
    return bool(enabled) and os.environ.get(PROGRESS_ENV, "").strip() != "0"


class QuietBar:
    """The hidden bar: iterates over ``iterable`` unchanged; ``update``, ``close`` and ``with`` do nothing else.

    Parameters
    ----------
    iterable : iterable, optional
        What to iterate over; None for a manual bar (which cannot be iterated).
    total : int, optional
        Number of steps expected: the bar's ``len`` (default ``len(iterable)``).
    initial : int
        Steps already done: the starting count ``n`` (default 0).
    """

    def __init__(self, iterable=None, total=None, initial=0):
        self.iterable, self.total, self.n = iterable, total, initial

    def __iter__(self):
        return iter(self.iterable)

    def __len__(self):
        return len(self.iterable) if self.total is None else self.total

    def update(self, n=1):
        """Count ``n`` more steps (nothing is shown).

        Parameters
        ----------
        n : int
            Steps done since the last update (default 1).
        """
        self.n += n

    def close(self):
        """Nothing to close: the bar shows nothing."""
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def progress_bar(iterable=None, *, enabled=True, desc=None, unit="it", total=None, initial=0, leave=True):
    """A tqdm bar over ``iterable`` (or a manual one, advanced with ``update``) if :func:`bars_enabled`, else a
    :class:`QuietBar`.

    Parameters
    ----------
    iterable : iterable, optional
        What to iterate over; None for a manual bar.
    enabled : bool
        Whether the caller asks for a bar (see :func:`bars_enabled`).
    desc : str, optional
        The bar's label.
    unit : str
        Name of one step (default ``"it"``).
    total : int, optional
        Number of steps expected (default ``len(iterable)`` where tqdm can take it).
    initial : int
        Steps already done (default 0).
    leave : bool
        Keep the finished bar on screen (tqdm's ``leave``).

    Returns
    -------
    tqdm.auto.tqdm or QuietBar
        The bar; both iterate, take ``update(n)`` and ``close()`` and work as context managers.
    """
    if not bars_enabled(enabled) or sys.stderr is None:  # None: no stderr to draw on (pythonw)
        return QuietBar(iterable, total, initial)
    from tqdm.auto import tqdm

    widget = any(c.__module__ == "tqdm.notebook" for c in tqdm.__mro__)  # a notebook's bar: not a log
    logged = {} if widget or _stderr_is_terminal() else {"mininterval": LOG_INTERVAL_S, "maxinterval": LOG_INTERVAL_S}
    return tqdm(iterable, total=total, initial=initial, desc=desc, unit=unit, leave=leave, **logged)


def _stderr_is_terminal() -> bool:
    """Whether stderr, where tqdm draws, is shown live: a terminal, or a Jupyter kernel's stream (a notebook renders
    the carriage returns of a text bar, drawn there when ipywidgets is missing); False for a file, a pipe, or a
    closed stream."""
    if type(sys.stderr).__module__.split(".")[0] == "ipykernel":  # its isatty() is False
        return True
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError, OSError):
        return False
