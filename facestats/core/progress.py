"""Progress bars: one rule for every long loop of facestats.

A bar is shown when the caller asks for it (``enabled``, the ``progress=``
argument of the public functions; the command line asks for it), on stderr,
whether or not stderr is a terminal, so that a log of a long job shows how far
it got.  ``FACESTATS_PROGRESS=0`` in the environment hides every bar (for logs
that should stay short).  Bars come from :mod:`tqdm.auto`: a widget in a
notebook, text elsewhere, with the rate and the ETA tqdm estimates.
"""

from __future__ import annotations

import os

__all__ = ["PROGRESS_ENV", "progress_bar", "bars_enabled"]

#: Environment variable that hides every bar when set to ``0``.
PROGRESS_ENV = "FACESTATS_PROGRESS"


def bars_enabled(enabled=True) -> bool:
    """Whether a bar the caller asked for (``enabled``) is shown: not when ``FACESTATS_PROGRESS=0``."""
    return bool(enabled) and os.environ.get(PROGRESS_ENV, "").strip() != "0"


def progress_bar(iterable=None, *, enabled=True, desc=None, unit="it", total=None, initial=0, leave=True):
    """A tqdm bar over ``iterable`` (or a manual one, advanced with ``update``), hidden unless :func:`bars_enabled`.

    A hidden bar is a disabled tqdm: it iterates, updates and closes like a shown one at no cost.
    """
    from tqdm.auto import tqdm

    return tqdm(
        iterable,
        total=total,
        initial=initial,
        desc=desc,
        unit=unit,
        leave=leave,
        disable=not bars_enabled(enabled),
    )
