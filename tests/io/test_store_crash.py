"""Crash injection: a writer SIGKILLed at random moments never leaves half a subject.

The writer is a forked child of the test process (so each cycle costs no
interpreter start-up; zarr resets its I/O thread after a fork).  It rewrites
subjects in a loop (single writes, batches, map and sample subjects, a delete
and re-create, an occasional gc) with increasing seeds recorded in the
provenance.  After each SIGKILL the store must open, validate, and every
indexed subject must read intact and equal the version its provenance names;
no committed subject may vanish or go back to an older version.
"""

import functools
import os
import random
import signal
import time

import numpy as np
import pytest

from facestats.io import open_store
from facestats.io.schema import provenance, set_provenance
from tests.helpers import make_map_subject, make_sample_subject

MAP_IDS = ("C1", "C2", "C3")
SAMPLE_IDS = ("CS1", "CS2")
N_KILLS = 30


def version(sid, seed):
    """The Dataset the writer writes for (sid, seed)."""
    if sid in SAMPLE_IDS:
        ds = make_sample_subject(sid, seed=seed, n_per_region=5)
        return set_provenance(ds, seed=seed)
    return make_map_subject(sid, seed=seed, size=24)


@functools.lru_cache(maxsize=None)
def _truth(sid, seed):
    """:func:`version` of ``(sid, seed)``, made once per process: :func:`check_store` compares every subject after
    every kill, and the writer's seeds rarely change between two kills (only the checks read these Datasets)."""
    return version(sid, seed)


def writer_loop(path, start, progress):
    st = open_store(path, mode="a", lock_timeout=30)
    seed = start
    while True:
        os.write(progress, b".")  # one byte per finished iteration
        seed += 1
        step = seed % 7
        if step == 0:
            st.write_subjects([version("C1", seed), version("CS1", seed)], overwrite=True)
        elif step == 3 and "CS2" in st:
            st.delete_subject("CS2")
        elif step == 5:
            st.gc()
        else:
            sid = (MAP_IDS + SAMPLE_IDS)[seed % 5]
            st.write_subject(version(sid, seed), overwrite=True)


def fork_writer(path, start, progress):
    pid = os.fork()
    if pid == 0:  # child: never return into pytest
        code = 0
        try:
            writer_loop(path, start, progress)
        except BaseException:  # pragma: no cover - reported through the exit code
            import traceback

            traceback.print_exc()
            code = 3
        finally:
            os._exit(code)
    return pid


def _same_row(a, b):
    return all((a.get(k) is None and (v is None or v != v)) or a.get(k) == v for k, v in b.items())


def check_store(path, seen, orphans=None, full=True):
    """Open the store and read back everything; return {sid: seed}.

    Every indexed subject must read intact (checksums, schema), equal the
    version its provenance names, and have an index entry equal to its
    summary.  ``full`` also runs ``Store.validate``.
    """
    from facestats.io.summary import albedo_histogram, summarise_subject

    with open_store(path) as st:
        if full:
            report = st.validate()
            assert report.ok, report.problems
        entries = st.index_entries()
        seeds = {}
        for sid in st.ids():
            ds = st.subject(sid)
            seed = provenance(ds)["seed"]
            truth = _truth(sid, seed)
            for name in truth.data_vars:
                np.testing.assert_array_equal(ds[name].values, truth[name].values, err_msg=f"{sid} {name}")
            assert _same_row(entries[sid]["row"], summarise_subject(ds)), sid
            assert entries[sid]["albedo_hist"] == albedo_histogram(ds).tolist()
            seeds[sid] = seed
        if orphans is not None:  # an interrupted write leaves an unreferenced generation or lock
            live = {e["generation"] for e in entries.values()}
            gens = {p.name for p in (path / "subjects").glob("*/g*")}
            orphans.append(bool(gens - live) or bool(os.listdir(path / ".writers")))
    for sid, old in seen.items():
        if sid != "CS2":  # CS2 is deleted and re-created on purpose
            assert sid in seeds, f"committed subject {sid} vanished"
            assert seeds[sid] >= old, f"{sid} went back from version {old} to {seeds[sid]}"
    return seeds


@pytest.mark.slow
def test_sigkill_at_random_moments_never_corrupts_the_store(tmp_path):
    path = tmp_path / "crash.zarr"
    with open_store(path, mode="a") as st:
        st.write_subjects([version(sid, 0) for sid in MAP_IDS + SAMPLE_IDS])
    rng = random.Random(20060731)
    seen = check_store(path, {})
    start = 0
    changed = 0
    orphans = []  # per kill: did it leave an interrupted write behind?
    loop_time = 0.1  # running estimate of one writer iteration (s)
    for kill in range(N_KILLS):
        start += 1000
        r, w = os.pipe()
        pid = fork_writer(path, start, w)
        os.close(w)
        # let the writer finish 0-1 iterations (however loaded the machine), then kill it at a
        # random moment of the next one
        t = time.monotonic()
        need = rng.randint(0, 1)
        for _ in range(need + 1):  # the first byte comes before any write
            assert os.read(r, 1) == b"."
        if need:
            loop_time = 0.7 * loop_time + 0.3 * (time.monotonic() - t) / need
        time.sleep(rng.uniform(0, 1.3 * loop_time))
        os.kill(pid, signal.SIGKILL)
        os.close(r)
        _, status = os.waitpid(pid, 0)
        assert os.WIFSIGNALED(status), f"the writer stopped by itself (status {status})"
        seeds = check_store(path, seen, orphans, full=kill % 4 == 3)
        changed += sum(seeds.get(s) != seen.get(s) for s in seeds)
        seen = seeds
    # kills landed both in the middle of writes and after commits
    assert sum(orphans) >= 5 and changed >= N_KILLS // 2, (sum(orphans), changed)
    # leftovers of the killed writers are collected; nothing referenced is touched
    with open_store(path, mode="r+") as st:
        st.gc()
        report = st.validate()
        assert report.ok and not report.notes
        assert os.listdir(path / ".writers") == []
        for sid in st.ids():
            assert len(list((path / "subjects" / sid).iterdir())) == 2  # zarr.json + the current generation
    check_store(path, seen)


def _die():
    os.kill(os.getpid(), signal.SIGKILL)


@pytest.mark.parametrize("point", ["after_data", "before_index_replace", "after_commit", "during_delete"])
def test_sigkill_at_each_critical_point(tmp_path, point):
    """Deterministic crash points of a replacing write: old or new version, then gc leaves no trace."""
    from facestats.io import index as index_mod
    from facestats.io import store as store_mod

    path = tmp_path / "crash.zarr"
    with open_store(path, mode="a") as st:
        st.write_subjects([version("C1", 1), version("CS1", 1)])
    pid = os.fork()
    if pid == 0:
        try:
            if point == "after_data":
                store_mod.Store._commit = lambda self, mutate: _die()
            elif point == "before_index_replace":
                real = index_mod.os.replace

                def replace(src, dst):
                    if str(dst).endswith("index.json"):
                        _die()
                    real(src, dst)

                index_mod.os.replace = replace
            elif point == "after_commit":
                store_mod.Store._remove_generation = lambda self, sid, gen: _die()
            else:  # renamed aside and partly deleted

                def remove(self, sid, gen):
                    trash = path / "subjects" / sid / f".trash-{gen}"
                    os.rename(path / "subjects" / sid / gen, trash)
                    os.remove(trash / "zarr.json")
                    _die()

                store_mod.Store._remove_generation = remove
            with open_store(path, mode="r+") as st:
                st.write_subjects([version("C1", 2), version("CS1", 2)], overwrite=True)
        finally:
            os._exit(0)
    _, status = os.waitpid(pid, 0)
    assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL
    seeds = check_store(path, {})
    expected = 1 if point in ("after_data", "before_index_replace") else 2
    assert seeds == {"C1": expected, "CS1": expected}  # the batch is atomic too
    with open_store(path, mode="r+") as st:
        assert st.gc()  # something was left behind, and is collected
        report = st.validate()
        assert report.ok and not report.notes
    assert os.listdir(path / ".writers") == []
    assert seeds == check_store(path, {})
