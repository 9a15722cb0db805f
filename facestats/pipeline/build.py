"""Build a parameter store from a synthetic population: simulate every capture, fit it, store it.

This is how the embedded default is made (Weyrich et al. 2006 pipeline, Fig. 3,
run on the synthetic population of :mod:`facestats.acquire.synthetic.population`):

1. draw the population (seeded);
2. simulate every subject's contact-sensor profiles and fit the dipole to them
   (cheap), giving the population's σtrAvg over the normal-condition subjects,
   cheek and forehead (§5.4);
3. for every subject, in parallel on Dask's local process scheduler (or a
   ``distributed`` cluster, :mod:`facestats.pipeline.cluster`; worker processes
   keep their simulator and population between subjects): simulate the dome
   capture, run the fit pipeline with that σtrAvg, and write the subject to the
   store at once — so an interrupted build keeps what it finished, and a rerun
   skips subjects already stored.  A subject that fails is retried, then
   reported (:class:`BuildReport`, ``facestats build --status``), never skipped
   silently: the build journal (:mod:`facestats.pipeline.journal`) records what
   is running and what failed;
4. for the default, pack the store into ``facestats/data/default_store.zip``.

Everything is deterministic for a seed: the simulator draws its noise from each
subject's seed and the fit has no randomness, so a rebuild reproduces the same
subjects (tested in ``tests/pipeline/test_default_store.py``).

Interruption and worker lifetime (issue #12): local worker processes die with
the build — each sets the Linux parent-death signal (SIGKILL) and watches its
parent and a stop event every 0.25 s — so a build killed with SIGKILL leaves no
worker committing subjects behind it; SIGINT and SIGTERM stop a build cleanly
(the workers are stopped, what they were writing is never committed, and the
call raises :class:`KeyboardInterrupt`).  Every write is atomic, so a killed
build leaves only whole subjects, and rerunning it resumes: subjects already
stored are skipped and the leftovers of the killed writers are collected first
(:meth:`facestats.io.Store.gc`).  Sizes whose memory would exceed the machine
are refused before anything starts (:func:`estimated_memory`).
"""

from __future__ import annotations

import ctypes
import json
import multiprocessing
import os
import shutil
import signal
import tempfile
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facestats.acquire.synthetic.population import synthesize_population
from facestats.acquire.synthetic.simulate import DomeSimulator
from facestats.core.conventions import DEFAULT_FACE, DEFAULT_MAP_SIZE, DEFAULT_SEED, SITES
from facestats.core.processes import available_memory, sigterm_as_interrupt
from facestats.core.validate import check_choice, check_integer
from facestats.errors import ValidationError
from facestats.face.named import FACES, face_geometry
from facestats.io.ids import check_subject_id
from facestats.io.packing import pack_store
from facestats.io.store import default_store_path, open_store
from facestats.model.fitting import TranslucencyFit, fit_translucency, population_sigma_tr_avg
from facestats.model.fitting.engine import resolve_engine
from facestats.model.skin import SPECULAR_MODELS
from facestats.pipeline import FitSettings, fit_subject
from facestats.pipeline.cluster import LOCAL, connect, run_tasks, scheduler_address, store_directory
from facestats.pipeline.journal import BuildJournal, gathered, run_journalled
from facestats.pipeline.progress import TaskProgress, subject_bar

__all__ = ["BuildReport", "build_store", "build_default", "estimated_memory", "DEFAULT_SEED", "DEFAULT_MAP_SIZE"]


_WORKER_CACHE: dict = {}

#: Peak memory of one worker simulating and fitting one subject: a fixed part and a part per texel of
#: the map_size² grid (bytes), measured with ``ru_maxrss`` at map sizes 16-96 (203, 316, 775 and 1549 MB;
#: the capture is simulated in memory, about 2,400 samples per lumitexel).
_MEMORY_FIXED = 160e6
_MEMORY_PER_TEXEL = 0.16e6


def estimated_memory(map_size: int, workers: int = 1) -> float:
    """Bytes a build of ``map_size``² maps needs with ``workers`` processes (:data:`_MEMORY_PER_TEXEL`).

    Parameters
    ----------
    map_size : int
        Side of the UV maps (and of the lumitexel grid) in texels.
    workers : int
        Worker processes, each holding one subject's fit.

    Returns
    -------
    float
        Estimated peak bytes: ``workers`` × (a fixed part + a part per texel), measured constants.
    """
    return workers * (_MEMORY_FIXED + _MEMORY_PER_TEXEL * float(map_size) ** 2)


def _check_memory(map_size: int, workers: int) -> None:
    need, have = estimated_memory(map_size, workers), available_memory()
    if have is not None and need > have:
        raise ValidationError(
            f"map_size {map_size} needs about {need / 2**30:.1f} GiB with {workers} worker(s) (the capture of "
            f"every subject is simulated in memory: {_MEMORY_PER_TEXEL / 1e6:.2f} MB per texel), but this machine "
            f"has {have / 2**30:.1f} GiB available; use a smaller --size or fewer --workers"
        )


def _set_parent_death_signal() -> None:
    """Ask Linux to SIGKILL this process when its parent dies (prctl PR_SET_PDEATHSIG); no-op elsewhere."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def _watch_parent(parent: int, stop) -> None:
    """Exit this worker as soon as the build asks (``stop``, a shared flag) or its parent is gone.

    ``stop`` is a lock-free shared byte polled every 0.25 s, not a ``multiprocessing.Event``: setting an
    Event notifies its waiters and blocks until each has woken, so a worker killed while it waited (the
    out-of-memory killer) made the build hang for ever when it stopped the others (a red team).
    """
    while not stop.value:
        if os.getppid() != parent:
            break
        time.sleep(0.25)
    os._exit(1)


def _anonymous_locks() -> None:
    """Make the ``multiprocessing`` locks that libraries create in this worker anonymous semaphores.

    numcodecs' Blosc codec (every float map the worker writes) creates a ``multiprocessing.Lock`` on first use.
    Under the spawn start method the workers inherit, that is a named POSIX semaphore registered with the build's
    resource tracker and unlinked when the process exits normally; a worker stopped by ``os._exit`` (an interrupted
    build, :func:`_watch_parent`) or killed never unlinks it, and the tracker warned at the build's end
    "resource_tracker: There appear to be 2 leaked semaphore objects to clean up at shutdown" (Ctrl-C, 2 workers).
    The fork method's locks are unlinked as they are made, so nothing is left whatever the worker's end; this
    worker starts no process of its own.
    """
    if "fork" in multiprocessing.get_all_start_methods():
        multiprocessing.set_start_method("fork", force=True)


def _worker_init(parent: int, stop) -> None:
    """Initializer of a local build worker: die with the parent and on request (module docstring), leaving no named
    semaphore behind (:func:`_anonymous_locks`)."""
    _set_parent_death_signal()
    if os.getppid() != parent:  # the parent died before this worker started
        os._exit(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides; Ctrl-C reaches the whole group
    _anonymous_locks()
    threading.Thread(target=_watch_parent, args=(parent, stop), daemon=True).start()


def _local_pool(n_workers: int):
    """``(pool, stop)``: a spawn process pool of ``n_workers`` build workers (:func:`_worker_init`) and the shared
    flag that makes them leave at once (``stop.value = True``)."""
    ctx = multiprocessing.get_context("spawn")
    stop = ctx.RawValue(ctypes.c_bool, False)
    pool = ProcessPoolExecutor(n_workers, mp_context=ctx, initializer=_worker_init, initargs=(os.getpid(), stop))
    return pool, stop


def _pool_round(args, retries, n_workers: int, progress: bool) -> list:
    """One run of :func:`_build_task` over ``args`` on a local process pool whose workers die with this process
    (module docstring); raises ``BrokenProcessPool`` when a worker dies."""

    import dask

    pool, stop = _local_pool(n_workers)
    tasks = [dask.delayed(_build_task, pure=False)(retries, *a) for a in args]
    try:
        with TaskProgress(len(tasks), enabled=progress):
            return list(dask.compute(*tasks, scheduler="processes", pool=pool))
    except BaseException:
        stop.value = True  # the workers exit within 0.25 s; nothing they were writing gets committed
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _run_local(args, retries, n_workers: int, progress: bool) -> list:
    """Run the build tasks on local worker processes; a subject whose worker process dies is retried, then reported.

    A task's own errors are retried inside it (:func:`facestats.pipeline.journal.run_journalled`); a worker that
    dies (killed by a signal: the out-of-memory killer) breaks the whole pool and loses the results of that round.
    Then the store and the journal say what happened to each subject: stored ones are done, ones that failed
    every attempt are failed, and ones whose record says *running* were on a worker when the pool broke. Each of
    those runs again alone on a one-worker pool, so that a subject is blamed only for its own death; after
    ``retries`` + 1 deaths it is reported failed. Subjects not started run again on a new pool of ``n_workers``.
    """
    from concurrent.futures.process import BrokenProcessPool

    rounds = _Rounds(pending=list(args))
    while rounds.pending or rounds.alone:
        batch, workers = rounds.next_batch(n_workers)
        began = time.time()
        try:
            for sid, state, err in _pool_round(batch, retries, min(workers, len(batch)), progress):
                rounds.results[sid] = (state, err)
        except BrokenProcessPool:
            rounds.broken(batch, _fates(batch, retries, began), retries)
    return [(a[5], *rounds.results[a[5]]) for a in args]


@dataclass
class _Rounds:
    """The bookkeeping of :func:`_run_local`: what runs next, what is settled, how often workers died."""

    pending: list
    alone: list = field(default_factory=list)
    results: dict = field(default_factory=dict)
    deaths: dict = field(default_factory=dict)
    blind: int = 0  # rounds whose pool broke before any subject began

    def next_batch(self, n_workers):
        """The next round: one subject that was running when a pool broke, alone; else every pending one."""
        if self.alone:
            return [self.alone.pop(0)], 1
        batch, self.pending = self.pending, []
        return batch, n_workers

    def broken(self, batch, fates, retries):
        """Sort out a round whose pool broke from the subjects' fates (:func:`_fates`)."""
        if all(f[0] == "not started" for f in fates):  # no subject began: workers that die on their own
            self.blind += 1
        for a, fate in zip(batch, fates):
            sid = a[5]
            if fate[0] in ("done", "failed"):
                self.results[sid] = fate
            elif fate[0] == "running":  # on a worker when the pool broke
                self.deaths[sid] = self.deaths.get(sid, 0) + 1
                if self.deaths[sid] > retries:
                    why = f"its worker process died on each of {self.deaths[sid]} attempts"
                    self.results[sid] = _died(a, why, self.deaths[sid])
                else:
                    self.alone.append(a)
            elif self.blind > retries:
                why = f"the worker processes died {self.blind} times before any subject began"
                self.results[sid] = _died(a, why, self.blind)
            else:
                self.pending.append(a)


def _died(args, why, attempts):
    """``("failed", error)`` of a subject whose worker process died (recorded in the journal with its ``attempts``)."""
    error = _WorkerDied(f"{why} (killed by a signal: out of memory?)")
    BuildJournal(args[0]).fail(args[5], attempts, error)
    return "failed", f"{type(error).__name__}: {error}"


class _WorkerDied(RuntimeError):
    """A build worker process died (killed by a signal) while it worked on a subject."""


def _fates(batch, retries, began) -> list:
    """After a broken pool: per argument tuple, ``("done", None)``, ``("failed", error)``, ``("running", None)``
    (on a worker when it broke) or ``("not started", None)``, from the store's index and the build journal
    (records written before the round ``began``, time.time(), are an earlier build's: not started)."""
    store_path = batch[0][0]
    with open_store(store_path, mode="r") as store:
        stored = set(store.ids())
    journal = BuildJournal(store_path)
    out = []
    for a in batch:
        written = journal.written_at(a[5])
        rec = journal.read(a[5]) if written is not None and written >= began else None
        if a[5] in stored:
            out.append(("done", None))
        elif rec is not None and rec.get("state") == "failed" and rec.get("attempts") == retries + 1:
            out.append(("failed", rec.get("error")))
        elif rec is not None:  # running, or failed with attempts left: its task did not finish
            out.append(("running", None))
        else:
            out.append(("not started", None))
    return out


@dataclass
class BuildReport:
    """What a build did (:func:`build_store`).

    Attributes
    ----------
    store : str
        The store directory.
    written : list of str
        Subjects this build wrote, sorted.
    skipped : list of str
        Subjects asked for that the store already held (not rebuilt).
    sigma_tr_avg : ndarray, shape (3,)
        σtrAvg (mm⁻¹, R, G, B) every fit used: the cheek and forehead mean of the population's sensor fits.
    seconds : float
        Wall-clock time of the build.
    workers : int
        Local worker processes, or the cluster's workers.
    failed : dict of str to str
        Maps the subjects that failed every attempt to their last error.
    sigma_tr_subjects : int
        How many subjects ``sigma_tr_avg`` averages: the drawn population's subjects under normal conditions,
        whichever of them this build wrote (every fit uses the same value, so partial builds agree).
    """

    store: str
    written: list
    skipped: list
    sigma_tr_avg: np.ndarray
    seconds: float
    workers: int
    failed: dict = field(default_factory=dict)
    sigma_tr_subjects: int = 0

    def to_text(self) -> str:
        """One line for the command line, then one line per failed subject."""
        text = (
            f"store {self.store}: {len(self.written)} subject(s) written, {len(self.skipped)} already present"
            + (f", {len(self.failed)} FAILED" if self.failed else "")
            + f"; {self.seconds:.1f} s with {self.workers} worker(s)\n"
            f"sigma_trAvg used by every fit = {np.round(self.sigma_tr_avg, 4).tolist()} mm^-1 (R, G, B), the "
            f"cheek and forehead mean over all {self.sigma_tr_subjects} subjects of the drawn population under "
            "normal conditions, not only those written"
        )
        return "\n".join([text] + [f"  failed {sid}: {err}" for sid, err in sorted(self.failed.items())])


def _geometry(map_size: int, face: str):
    """One face geometry per process, shared by the simulator and the population."""
    key = ("geometry", map_size, face)
    if key not in _WORKER_CACHE:
        _WORKER_CACHE[key] = face_geometry(face, map_size)
    return _WORKER_CACHE[key]


def _simulator(map_size: int, specular: str, face: str = DEFAULT_FACE):
    """One simulator per process (shadow maps and geometry are reused across subjects)."""
    key = (map_size, specular, face)
    if key not in _WORKER_CACHE:
        _WORKER_CACHE[key] = DomeSimulator(_geometry(map_size, face), specular=specular)
    return _WORKER_CACHE[key]


def _population(seed: int, map_size: int, conditions: bool, face: str = DEFAULT_FACE):
    """One population per process (drawn once, reused across subjects)."""
    key = ("population", seed, map_size, conditions, face)
    if key not in _WORKER_CACHE:
        _WORKER_CACHE[key] = synthesize_population(
            seed=seed, map_size=map_size, geometry=_geometry(map_size, face), conditions=conditions
        )
    return _WORKER_CACHE[key]


def _settings(micro_normals: bool):
    """The fit settings of a build: the defaults, with or without micro-normal maps."""

    return FitSettings(micro_normals=micro_normals)


def sensor_fits(population, map_size: int, specular: str = "torrance_sparrow", face: str = DEFAULT_FACE):
    """Stage 6 for every subject from its simulated sensor profiles (the same draws as the full simulation).

    Returns
    -------
    dict
        ``subject_id`` -> :class:`facestats.model.fitting.TranslucencyFit` of shape (site, channel).
    """

    sim = _simulator(map_size, specular, face)
    ids, profiles, stds = [], [], []
    for truth in population.subjects:  # loop over subjects: their sensor draws
        _, rng_sensor, _ = sim._streams(truth.seed, 1)
        prof, std = sim._sensor(truth, rng_sensor)
        ids.append(truth.subject_id)
        profiles.append(np.moveaxis(prof, 1, 2))  # (site, channel, fiber)
        stds.append(np.moveaxis(std, 1, 2))
    if not ids:
        return {}
    # One fit for all subjects (each profile converges on its own, so this is what per-subject fits give).
    prof, std = np.stack(profiles), np.stack(stds)
    has = np.any(std > 0, axis=(1, 2, 3))
    out = {}
    for group, with_std in ((has, True), (~has, False)):  # subjects with and without a noise model
        if group.any():
            fit = fit_translucency(sim.sensor.fiber_distance, prof[group], std[group] if with_std else None)
            for k, i in enumerate(np.nonzero(group)[0]):
                out[ids[i]] = TranslucencyFit(**{name: value[k] for name, value in vars(fit).items()})
    return out


#: Variables the default store leaves out because they are derived from others:
#: the modulation texture M = α/α_avg (:func:`facestats.io.schema.modulation`).
DERIVED = ("modulation",)


def _check_same_build(store, pop, present, geometry, specular, micro_normals=None, keep_derived=None, limit=None):
    """Refuse to add to a store whose simulated subjects came from another seed, size, face, specular model or
    maps kept.

    Resuming is by subject id: a subject already present is skipped, so a build with other parameters would
    count another person as present and mix two populations (and two σtrAvg) in one store.  Each present
    subject's capture provenance records its seed, geometry and specular model, and its variables say whether
    it keeps micro-normal maps (``micro_normals``, ``--no-micro-normals``) and the derived modulation
    (``keep_derived``); None leaves one out. Imported subjects (no simulator provenance) are left out of the
    comparison. ``present`` is checked in its order, up to ``limit`` simulated subjects (None: all).
    """
    seeds = {t.subject_id: t.seed for t in pop.subjects}
    checked = 0
    for sid in present:  # the attributes and variable names only: no map is read
        if limit is not None and checked >= limit:
            return
        ds = store.subject(sid, lazy=True)
        try:
            prov = json.loads(ds.attrs.get("provenance", "{}"))
        except (ValueError, TypeError):
            continue
        cap = prov.get("capture_provenance") or {}
        if cap.get("source") != "facestats simulator":
            continue
        checked += 1
        ours = {"geometry": geometry, "specular": specular}
        stored = {k: cap.get(k) for k in ours}
        if sid in seeds:
            ours["seed"], stored["seed"] = int(seeds[sid]), cap.get("seed")
        for key, var, wanted in (("micro-normal maps", "micro_normal", micro_normals),
                                 ("modulation map", "modulation", keep_derived)):  # fmt: skip
            if wanted is not None:
                ours[key], stored[key] = bool(wanted), var in ds.data_vars
        differ = {k: (stored[k], v) for k, v in ours.items() if stored[k] != v}
        if differ:
            what = "; ".join(
                "another --seed (the store keeps the subject seed drawn from it, "
                f"{old!r}; this build's --seed draws {new!r})"
                if k == "seed"
                else f"{k} {old!r} stored, {new!r} in this build"
                for k, (old, new) in differ.items()
            )
            raise ValidationError(
                f"store {store.label} holds {sid} built with other parameters ({what}): a resumed build must use "
                "the same --seed, --size, --face, --specular and --no-micro-normals; build into another store"
            )


def _build_one(
    store_path,
    seed,
    map_size,
    conditions,
    specular,
    subject_id,
    sigma_tr_avg,
    sensor_fit,
    micro_normals,
    keep_derived=True,
    face=DEFAULT_FACE,
):
    """Simulate, fit and store one subject (runs in a worker process)."""

    pop = _population(seed, map_size, conditions, face)
    store = open_store(store_path, mode="r+")
    same = (pop, _geometry(map_size, face).name, specular, micro_normals, keep_derived)
    _check_still_same_build(store, subject_id, *same)  # a retry after a refusal fails before the work
    if subject_id in store:  # committed by this task before its worker was lost (Dask resubmits it), or meanwhile
        return subject_id  # by a concurrent build of the same parameters
    truth = pop[subject_id]
    capture = _simulator(map_size, specular, face).simulate(truth)
    ds = fit_subject(capture, sigma_tr_avg, _settings(micro_normals), sensor_fit=sensor_fit)
    if not keep_derived:
        ds = ds.drop_vars([v for v in DERIVED if v in ds.data_vars])
    store.write_subject(ds, overwrite=True, precondition=lambda st: _check_still_same_build(st, subject_id, *same))
    return subject_id


def _check_still_same_build(store, subject_id, pop, geometry, specular, micro_normals, keep_derived):
    """:func:`_check_same_build` in a worker, before its work and under the store's commit lock at its commit:
    another build (other parameters, started before any subject was stored) may have written into the store since
    this build checked it.  The subject itself (a concurrent build's) and one other stand for the store: each was
    checked when it was committed, under the same lock, so no build commits between a check and its commit."""
    present = store.ids()
    order = [subject_id] * (subject_id in present) + [s for s in present if s != subject_id]
    _check_same_build(store, pop, order, geometry, specular, micro_normals, keep_derived, limit=2)


def _build_task(retries, *args):
    """:func:`_build_one` with retries, journalled in the store: ``(subject_id, "done" | "failed", error)``."""

    sid = args[5]
    state, info = run_journalled(BuildJournal(args[0]), sid, lambda: _build_one(*args), retries)
    return sid, state, None if state == "done" else info


def build_store(
    store_path,
    *,
    seed: int = DEFAULT_SEED,
    map_size: int = DEFAULT_MAP_SIZE,
    conditions: bool = True,
    specular: str = "torrance_sparrow",
    subjects=None,
    workers: int | None = None,
    client=None,
    micro_normals: bool = True,
    keep_derived: bool = True,
    progress: bool = False,
    scheduler: str | None = None,
    retries: int = 2,
    face: str = DEFAULT_FACE,
) -> BuildReport:
    """Simulate and fit a synthetic population into a directory store (resumable).

    Parameters
    ----------
    store_path : str or path-like
        Directory store; created if missing.  Subjects it already holds are skipped.
    seed, map_size, conditions
        Population settings (:func:`facestats.acquire.synthetic.population.synthesize_population`);
        ``map_size`` ≥ 8 is also the lumitexel grid of the face.
    specular : {"torrance_sparrow", "blinn_phong"}
        BRDF the simulator renders highlights with.
    subjects : sequence of str, optional
        Only these subject ids (σtrAvg still comes from the whole population).
    workers : int, optional
        Local worker processes, ≥ 1 (default: the number of cores); 1 runs in-process.
    client : dask.distributed.Client, optional
        Run on a cluster instead (workers must see ``store_path``).
    micro_normals : bool
        Keep per-camera micro-normal maps (the default store drops them to stay small).
    keep_derived : bool
        Keep variables derived from others (:data:`DERIVED`; the default store drops them).
    progress : bool
        Show a progress bar with ETA.
    scheduler : str, optional
        Address of a Dask scheduler (``tcp://host:8786``) to run on instead; default
        ``$DASK_SCHEDULER_ADDRESS`` when set (:mod:`facestats.pipeline.cluster`); ``"local"``:
        this machine whatever the variable says.
    retries : int
        Attempts after the first for a subject that fails (≥ 0); it is then reported in
        :attr:`BuildReport.failed` and the journal (``facestats build --status``).
    face : {"ict", "procedural"}
        The face the population lives on (:func:`facestats.face.named.face_geometry`):
        ICT-FaceKit's real face (the embedded default's, :data:`DEFAULT_FACE`) or the procedural head.

    Returns
    -------
    BuildReport
    """

    check_integer(seed, "seed", 0)
    check_choice(face, "face", FACES)
    check_integer(map_size, "map_size", 8)
    check_integer(retries, "retries", 0)
    store_path = store_directory(store_path)
    address = scheduler_address(scheduler) if client is None else None
    check_choice(specular, "specular", SPECULAR_MODELS)
    if workers is not None:
        check_integer(workers, "workers", 1)
    n_workers = workers or os.cpu_count() or 1
    if client is None and address is None:  # a cluster's workers have their own memory
        _check_memory(map_size, n_workers)
    if isinstance(subjects, str):
        raise ValidationError(f"subjects must be a sequence of subject ids, got the string {subjects!r}")
    for sid in subjects or ():  # the id rule first: cheap, before the population is drawn
        check_subject_id(sid)
    t0 = time.perf_counter()
    pop = _population(seed, map_size, conditions, face)
    wanted = [s.subject_id for s in pop.subjects] if subjects is None else list(dict.fromkeys(subjects))  # once each
    ids = {t.subject_id for t in pop.subjects}
    unknown = [s for s in wanted if s not in ids]
    if unknown:
        raise ValidationError(f"subjects must be ids of the population, got unknown {unknown[:5]}")
    resolve_engine(None)  # $FACESTATS_ENGINE, which every task's fit reads, checked once here
    own = connect(address) if address is not None else None  # an unreachable scheduler leaves no store
    journal = BuildJournal(store_path)
    try:
        store = open_store(store_path, mode="a")  # only now: bad arguments leave no empty store behind
        with journal.planned(wanted):  # until the build returns: `--status` counts what was not started
            store.gc()  # the leftovers of a killed build, if any (never a live writer's data)
            key = ("sensor_fits", seed, map_size, conditions, specular, face)
            if key not in _WORKER_CACHE:  # the same draws every time: computed once per process
                _WORKER_CACHE[key] = sensor_fits(pop, map_size, specular, face)
            fits = _WORKER_CACHE[key]
            normal = [s.subject_id for s in pop.subjects if s.condition == "normal"]
            stra = population_sigma_tr_avg(np.stack([fits[s].sigma_tr for s in normal]), SITES)
            present = set(store.ids())
            _check_same_build(  # every stored subject: a store may have been mixed by an older build or a script
                store, pop, sorted(present), _geometry(map_size, face).name, specular, micro_normals, keep_derived
            )
            todo = [s for s in wanted if s not in present]
            skipped = [s for s in wanted if s in present]
            for sid in skipped:  # committed by a build killed before it removed the record: the record goes
                journal.finish(sid)
            common = (micro_normals, keep_derived, face)
            args = [
                (str(store_path), seed, map_size, conditions, specular, sid, stra, fits[sid], *common) for sid in todo
            ]
            with sigterm_as_interrupt():
                results = _run_tasks(args, retries, own or client, n_workers, progress)
            size = n_workers if own is None and client is None else len((own or client).scheduler_info()["workers"])
    finally:
        if own is not None:
            own.close()
    return BuildReport(
        store=str(store_path),
        written=sorted(sid for sid, state, _ in results if state == "done"),
        skipped=skipped,
        sigma_tr_avg=stra,
        sigma_tr_subjects=len(normal),
        seconds=time.perf_counter() - t0,
        workers=size,
        failed={sid: err for sid, state, err in results if state != "done"},
    )


def _run_tasks(args, retries, client, n_workers, progress):
    """Run :func:`_build_task` on every argument tuple: on ``client``, local processes or in-process."""
    if client is not None:  # task failures are retried inside the task, which never raises
        futures = run_tasks(client, _build_task, [(retries, *a) for a in args], progress)
        return [gathered(f, a[0], a[5]) for f, a in zip(futures, args)]
    if n_workers == 1 or len(args) <= 1:
        return [_build_task(retries, *a) for a in subject_bar(args, len(args), progress)]
    return _run_local(args, retries, n_workers, progress)


def build_default(*, workers: int | None = None, progress: bool = False, out=None) -> BuildReport:
    """Regenerate the embedded default store and pack it into the package (or ``out``).

    The default is the population of :data:`DEFAULT_SEED` at :data:`DEFAULT_MAP_SIZE`² on
    :data:`DEFAULT_FACE` (ICT-FaceKit's face), fitted without micro-normal maps (16 × 3 values
    per texel would triple its size) and stored without the derived modulation texture, so it
    stays under 20 MB.  It is built on this machine (``$DASK_SCHEDULER_ADDRESS`` is not read): the
    build goes to a local temporary directory that a cluster's workers could not see.

    Parameters
    ----------
    workers : int, optional
        Local worker processes, ≥ 1 (default: the number of cores), as :func:`build_store`.
    progress : bool
        Show a progress bar with ETA.
    out : path, optional
        Zip file to write instead of the package's embedded store.

    Returns
    -------
    BuildReport
        What the build wrote, skipped and failed, and where the store went.
    """

    target = Path(out) if out is not None else default_store_path()
    tmp = Path(tempfile.mkdtemp(prefix="facestats-default-"))
    try:
        report = build_store(
            tmp / "default.zarr",
            seed=DEFAULT_SEED,
            map_size=DEFAULT_MAP_SIZE,
            workers=workers,
            micro_normals=False,
            keep_derived=False,
            progress=progress,
            face=DEFAULT_FACE,
            scheduler=LOCAL,
        )
        pack_store(tmp / "default.zarr", target, overwrite=True)
        report.store = str(target)
        return report
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
