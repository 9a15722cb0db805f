"""Progress bars of population runs: one tick per subject, with the ETA tqdm estimates from the rate so far.

The bars follow :mod:`facestats.core.progress` (shown when asked for, hidden by ``FACESTATS_PROGRESS=0``).
"""

from __future__ import annotations

from facestats.core.progress import progress_bar

__all__ = ["subject_bar", "TaskProgress"]


def subject_bar(items, total, enabled, desc="build"):
    """``items`` through a bar over ``total`` subjects (with ETA) when ``enabled``.

    Parameters
    ----------
    items : iterable
        What the loop iterates over (one item per subject).
    total : int
        Number of subjects (the bar's length).
    enabled : bool
        Show the bar (unless ``FACESTATS_PROGRESS=0``, :func:`facestats.core.progress.bars_enabled`).
    desc : str
        The bar's label (default ``"build"``).

    Returns
    -------
    tqdm.auto.tqdm or facestats.core.progress.QuietBar
        An iterable over ``items`` (:func:`facestats.core.progress.progress_bar`).
    """
    return progress_bar(items, enabled=enabled, total=total, desc=desc, unit="subject")


class TaskProgress:
    """A bar advanced by Dask's local scheduler as tasks finish.

    Use as a context manager around ``dask.compute`` of ``total`` subject tasks.

    Parameters
    ----------
    total : int
        Tasks expected: the bar's total (one step per task that finishes).
    enabled : bool
        Whether the caller asks for a bar (:func:`facestats.core.progress.progress_bar`; default True).
    desc : str
        The bar's label (default ``"build"``).
    """

    def __init__(self, total, enabled=True, desc="build"):
        self.total, self.enabled, self.desc = total, enabled, desc

    def __enter__(self):
        from dask.callbacks import Callback

        bar = progress_bar(enabled=self.enabled, total=self.total, desc=self.desc, unit="subject")

        class _Tick(Callback):
            def _posttask(self, key, result, dsk, state, id):
                bar.update(1)

        self.bar, self.cb = bar, _Tick()
        self.cb.__enter__()
        return self

    def __exit__(self, *exc):
        self.cb.__exit__(*exc)
        self.bar.close()
