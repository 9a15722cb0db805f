"""Progress bars of population runs: one tick per subject, with the ETA tqdm estimates from the rate so far."""

from __future__ import annotations

__all__ = ["progress_bar", "TaskProgress"]


def progress_bar(items, total, enabled, desc="build"):
    """``items`` through a tqdm bar over ``total`` subjects (with ETA) when ``enabled``, else unchanged.

    The bar hides itself when the output is not a terminal (``disable=None``).
    """
    if not enabled:
        return items
    from tqdm.auto import tqdm

    return tqdm(items, total=total, desc=desc, unit="subject", disable=None)


class TaskProgress:
    """A tqdm bar advanced by Dask's local scheduler as tasks finish (silent when not on a terminal).

    Use as a context manager around ``dask.compute`` of ``total`` subject tasks.
    """

    def __init__(self, total, enabled=True, desc="build"):
        self.total, self.enabled, self.desc = total, enabled, desc

    def __enter__(self):
        if not self.enabled:
            return self
        from dask.callbacks import Callback
        from tqdm.auto import tqdm

        bar = tqdm(total=self.total, desc=self.desc, unit="subject", disable=None)

        class _Tick(Callback):
            def _posttask(self, key, result, dsk, state, id):
                bar.update(1)

        self.bar, self.cb = bar, _Tick()
        self.cb.__enter__()
        return self

    def __exit__(self, *exc):
        if self.enabled:
            self.cb.__exit__(*exc)
            self.bar.close()
