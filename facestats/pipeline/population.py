"""The fit pipeline on a population: σtrAvg from every subject's sensor fits (§5.4), then every subject."""

from __future__ import annotations

import numpy as np

from facestats.core.conventions import SITES
from facestats.core.validate import check_choice, check_integer
from facestats.errors import FitError, ValidationError
from facestats.model import fitting
from facestats.pipeline.settings import FitSettings
from facestats.pipeline.subject import fit_sensor, fit_subject

__all__ = ["fit_population"]


def _fit_capture_task(capture, sigma_tr_avg, settings, sensor_fit):
    return fit_subject(capture, sigma_tr_avg, settings, sensor_fit=sensor_fit)


def fit_population(
    captures,
    settings: FitSettings | None = None,
    *,
    client=None,
    scheduler="processes",
    num_workers=None,
    progress=False,
):
    """Fit many captures: σtrAvg from the sensor fits (§5.4), then every subject (in parallel).

    σtrAvg is the mean cheek and forehead σtr over the captures of condition
    "normal" (:func:`facestats.model.fitting.population_sigma_tr_avg`).

    Parameters
    ----------
    captures : sequence of Capture or str
        Captures or paths of captures on disk.
    settings : FitSettings, optional
    client : dask.distributed.Client, optional
        Run subjects on a distributed cluster (captures must be paths, readable by
        the workers).
    scheduler : {"processes", "threads", "synchronous"}
        Dask's local scheduler when no client is given.
    num_workers : int, optional
        Local workers (default: number of cores).
    progress : bool
        Show a progress bar over subjects.

    Returns
    -------
    datasets : list of xarray.Dataset
    sigma_tr_avg : ndarray, shape (3,)
    """
    from facestats.acquire.capture import Capture, open_capture

    check_choice(scheduler, "scheduler", ("processes", "threads", "synchronous"))
    if num_workers is not None:
        check_integer(num_workers, "num_workers", 1)
    st = settings or FitSettings()
    caps = [c if isinstance(c, Capture) else open_capture(c) for c in captures]
    if not caps:
        raise ValidationError("captures must contain at least one capture, got none")
    fits = [fit_sensor(c, st.eta) for c in caps]
    sites = list(SITES)
    condition_normal = [i for i, c in enumerate(caps) if c.attrs.get("condition", "normal") == "normal"]
    if not condition_normal:
        raise ValidationError(
            "captures must include at least one subject of condition 'normal' (σtrAvg is their mean), got none"
        )
    tr = np.stack([fits[i].sigma_tr for i in condition_normal])
    stra = fitting.population_sigma_tr_avg(tr, sites)
    if client is not None:
        futs = [
            client.submit(_fit_capture_task, c.path if c.path else c, stra, st, f, pure=False)
            for c, f in zip(caps, fits)
        ]
        if progress:
            from distributed import progress as dprogress

            dprogress(futs)
        return client.gather(futs), stra
    if scheduler == "synchronous" or len(caps) == 1:
        it = zip(caps, fits)
        if progress:
            from tqdm.auto import tqdm

            it = tqdm(list(it), desc="fit", unit="subject")
        return [fit_subject(c, stra, st, sensor_fit=f) for c, f in it], stra
    import dask

    tasks = [dask.delayed(_fit_capture_task)(c.path if c.path else c, stra, st, f) for c, f in zip(caps, fits)]
    if progress:
        from dask.diagnostics import ProgressBar

        with ProgressBar():
            out = dask.compute(*tasks, scheduler=scheduler, num_workers=num_workers)
    else:
        out = dask.compute(*tasks, scheduler=scheduler, num_workers=num_workers)
    if any(o is None for o in out):
        raise FitError("a subject fit returned nothing")
    return list(out), stra
