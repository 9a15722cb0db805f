"""The fit pipeline on a population: σtrAvg from every subject's sensor fits (§5.4), then every subject.

Subjects run in parallel: on Dask's local scheduler, or on a ``distributed``
cluster (a client, or a scheduler address / ``$DASK_SCHEDULER_ADDRESS``,
:mod:`facestats.pipeline.cluster`).  With a ``store`` every subject is written
to it by the worker that fitted it, as soon as it is fitted (captures and store
on storage every worker reaches); a subject that fails is retried, and the
subjects that still fail are reported together at the end, after every other
subject is stored (:class:`facestats.errors.FitError`), never skipped silently.
"""

from __future__ import annotations

import contextlib

import numpy as np

from facestats.acquire.capture import Capture, open_capture
from facestats.core.conventions import SITES
from facestats.core.validate import check_integer
from facestats.errors import FitError, ValidationError
from facestats.io.ids import check_subject_id
from facestats.io.store import open_store
from facestats.model import fitting
from facestats.pipeline.cluster import connect, is_url, local_path, run_tasks, scheduler_address, store_directory
from facestats.pipeline.journal import BuildJournal, gathered, run_journalled
from facestats.pipeline.progress import TaskProgress, subject_bar
from facestats.pipeline.settings import FitSettings, checked_settings
from facestats.pipeline.subject import fit_sensor, fit_subject

__all__ = ["fit_population"]

_LOCAL = ("processes", "threads", "synchronous")


def _fit_capture_task(sid, capture, sigma_tr_avg, settings, sensor_fit, store, retries):
    """Fit one capture (with retries), write it to ``store`` if given: ``(id, "done"/"failed", dataset/id/error)``."""

    def run():
        if store is not None:
            with open_store(store, mode="r") as st:
                if sid in st:  # committed by this task before its worker was lost (Dask resubmitted it)
                    return sid
        cap = capture if isinstance(capture, Capture) else open_capture(capture)
        if check_subject_id(cap.metadata["subject_id"]) != sid:  # a worker that sees other files than the caller
            raise FitError(f"capture {cap.path} holds subject {cap.metadata['subject_id']!r} here, not {sid!r}")
        ds = fit_subject(cap, sigma_tr_avg, settings, sensor_fit=sensor_fit)
        if store is None:
            return ds

        with open_store(store, mode="r+") as st:
            return st.write_subject(ds, overwrite=True)

    journal = None if store is None else BuildJournal(store)
    state, result = run_journalled(journal, sid, run, retries)
    return sid, state, result


def fit_population(
    captures,
    settings: FitSettings | None = None,
    *,
    client=None,
    scheduler=None,
    num_workers=None,
    progress=False,
    store=None,
    retries: int = 2,
):
    """Fit many captures: σtrAvg from the sensor fits (§5.4), then every subject (in parallel).

    σtrAvg is the mean cheek and forehead σtr over the captures of condition
    "normal" (:func:`facestats.model.fitting.population_sigma_tr_avg`).

    Parameters
    ----------
    captures : sequence of Capture or str
        Captures, or paths or URLs (any location zarr opens through fsspec) of captures.
    settings : FitSettings, optional
    client : dask.distributed.Client, optional
        Run subjects on a distributed cluster (captures must be paths or URLs the
        workers can read).
    scheduler : str, optional
        ``"processes"``, ``"threads"`` or ``"synchronous"`` (Dask's local schedulers),
        or the address of a distributed scheduler (``tcp://host:8786``), or ``"local"``
        (``"processes"`` whatever ``$DASK_SCHEDULER_ADDRESS`` says).  Default:
        ``$DASK_SCHEDULER_ADDRESS`` if set, else ``"processes"``.
    num_workers : int, optional
        Local workers (default: number of cores).
    progress : bool
        Show a progress bar over subjects, with ETA.
    store : str or path-like, optional
        A directory store (created if missing) every worker can write: each subject is
        written there as soon as it is fitted, and the datasets are not returned.  Subjects
        the store already holds are skipped, not refitted (a rerun resumes).  ``settings.models``
        must then include both models (the store's schema holds both).
        Object-store URLs are refused (:func:`facestats.pipeline.cluster.store_directory`).
    retries : int
        Attempts after the first for a subject that fails (≥ 0).

    Returns
    -------
    datasets : list of xarray.Dataset, or list of str
        The subjects' Datasets in the order of ``captures``; with ``store``, their ids (each now in the store).
    sigma_tr_avg : ndarray, shape (3,)

    Raises
    ------
    FitError
        If some subjects still fail after their retries (raised after every other
        subject is done, and stored when ``store`` is given), naming each with its error.
    """

    local, address = _where(scheduler, client)
    if num_workers is not None:
        check_integer(num_workers, "num_workers", 1)
    check_integer(retries, "retries", 0)
    st = _settings(settings, store)
    caps, ids = _captures(captures)
    if store is not None:
        store = store_directory(store)
    fits = [fit_sensor(c, st.eta) for c in caps]
    condition_normal = [i for i, c in enumerate(caps) if c.attrs.get("condition", "normal") == "normal"]
    if not condition_normal:
        raise ValidationError(
            "captures must include at least one subject of condition 'normal' (σtrAvg is their mean), got none"
        )
    stra = fitting.population_sigma_tr_avg(np.stack([fits[i].sigma_tr for i in condition_normal]), list(SITES))
    own = connect(address) if address is not None else None  # an unreachable scheduler leaves no store
    try:
        present = set()
        if store is not None:
            with open_store(store, mode="a") as stored:
                present = set(stored.ids())
        # until the run returns: `facestats build --status` counts what was not started
        with BuildJournal(store).planned(ids) if store is not None else contextlib.nullcontext():
            tasks = [(sid, _location(c.path) if c.path else c, stra, st, f, store, retries)
                     for sid, c, f in zip(ids, caps, fits)]  # fmt: skip
            results = _run([t for t in tasks if t[0] not in present], own or client, local, num_workers, progress)
    finally:
        if own is not None:
            own.close()
    failed = {sid: err for sid, state, err in results if state != "done"}
    if failed:
        lines = "; ".join(f"{sid}: {err}" for sid, err in failed.items())
        raise FitError(f"{len(failed)} of {len(results)} subject(s) failed after {retries} retries: {lines}")
    if store is not None:
        journal = BuildJournal(store)
        for sid in present & set(ids):  # committed by a run killed before it removed the record
            journal.finish(sid)
        journal.prune()
        return ids, stra
    return [res for _, _, res in results], stra


def _captures(captures):
    """The captures opened, and their subject ids: valid ids (they name files), each once."""
    caps = [c if isinstance(c, Capture) else open_capture(_location(c)) for c in captures]
    if not caps:
        raise ValidationError("captures must contain at least one capture, got none")
    ids = [check_subject_id(c.metadata["subject_id"]) for c in caps]
    twice = sorted({sid for sid in ids if ids.count(sid) > 1})
    if twice:
        raise ValidationError(f"captures must hold each subject once, got {twice} more than once")
    return caps, ids


def _location(path) -> str:
    """A capture's location as every worker resolves it alike: a URL as given, a local path made absolute
    (:func:`facestats.pipeline.cluster.local_path`)."""
    return str(path) if is_url(path) else local_path(path, "capture")


def _settings(settings, store):
    """``settings`` (default :class:`FitSettings`) checked before any work (:func:`checked_settings`), and with a
    ``store`` the models its schema stores."""
    st = checked_settings(settings)
    missing = [m for m in ("torrance_sparrow", "blinn_phong") if m not in st.models]
    if store is not None and missing:
        raise ValidationError(
            f"settings.models must include {missing} to write to a store (a stored subject holds both models' "
            f"maps), got {st.models!r}"
        )
    return st


def _where(scheduler, client):
    """(local Dask scheduler name or None, distributed address or None) of the arguments."""
    if scheduler is not None and str(scheduler) in _LOCAL:
        return str(scheduler), None
    if client is not None:
        if scheduler is not None:
            raise ValidationError("pass either client or a scheduler address, not both")
        return None, None
    address = scheduler_address(scheduler)  # "local": None whatever $DASK_SCHEDULER_ADDRESS says
    return ("processes" if address is None else None), address


def _run(tasks, client, local, num_workers, progress):
    """Every subject task on the client, or Dask's local scheduler, in the order of ``tasks``."""
    if client is not None:
        futures = run_tasks(client, _fit_capture_task, tasks, progress, desc="fit")
        return [gathered(f, t[5], t[0]) for f, t in zip(futures, tasks)]
    if local == "synchronous" or len(tasks) == 1:
        return [_fit_capture_task(*t) for t in subject_bar(tasks, len(tasks), progress, desc="fit")]
    import dask

    delayed = [dask.delayed(_fit_capture_task, pure=False)(*t) for t in tasks]
    with TaskProgress(len(delayed), enabled=progress, desc="fit"):
        return list(dask.compute(*delayed, scheduler=local, num_workers=num_workers))
