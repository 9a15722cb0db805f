"""Faults: SIGKILL at random moments of build, import, edit and repair (20 times each), two concurrent writers, a
full disk on a small tmpfs, and a store whose ``subjects/`` folder is unavailable.

Each killed operation runs in a forked child (no interpreter start-up per cycle) and is killed at a
uniformly random moment of 1.1 times its measured duration (a build that finished first sets it anew).
After every kill the store must open, hold only whole subjects whose data read back intact, keep every
subject committed before the kill, and leave the sentinel tree beside it untouched; the operation, run
again, must complete (a killed build resumes, a killed repair is repaired).
"""

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from facestats.errors import StoreError
from facestats.io import open_store
from tests.helpers import make_map_subject, merl_dict

from .helpers import copy_store, make_sentinel, make_store, quarantined_generations, snapshot, subject_digests

N_KILLS = 20


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    path = make_store(tmp_path_factory.mktemp("faults") / "s.zarr")
    return path, subject_digests(path)


def _fork(action):
    pid = os.fork()
    if pid == 0:
        code = 0
        try:
            action()
        except BaseException:  # pragma: no cover - reported through the exit code
            import traceback

            traceback.print_exc()
            code = 3
        finally:
            os._exit(code)
    return pid


def _duration(action) -> float:
    """Seconds ``action`` takes in a forked child (run to the end once)."""
    t = time.monotonic()
    pid = _fork(action)
    _, status = os.waitpid(pid, 0)
    assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0
    return time.monotonic() - t


def _kill_during(action, rng, duration):
    """Run ``action`` in a child and SIGKILL it at a uniformly random moment of [0, 1.1 ``duration``].

    Returns ``(killed, seconds)``: whether it was killed before finishing, and how long it ran (to
    within 5 ms when it finished first: its own duration this time).
    """
    pid = _fork(action)
    t0 = time.monotonic()
    deadline = t0 + rng.uniform(0, 1.1 * duration)
    while time.monotonic() < deadline:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0, status
            return False, time.monotonic() - t0
        time.sleep(min(0.005, max(0.0, deadline - time.monotonic())))
    os.kill(pid, signal.SIGKILL)
    _, status = os.waitpid(pid, 0)
    assert os.WIFSIGNALED(status) or os.WEXITSTATUS(status) == 0, status
    return os.WIFSIGNALED(status), time.monotonic() - t0


def _check_intact(store, committed: dict) -> dict:
    """The store opens, every indexed subject reads intact, and none of ``committed`` changed or vanished."""
    now = subject_digests(store)
    with open_store(store) as st:
        assert set(now) == set(st.ids()), "an indexed subject does not read back intact"
    for sid, digest in committed.items():
        assert now.get(sid) == digest, f"committed subject {sid} changed or vanished"
    return now


@pytest.mark.slow
def test_sigkill_during_build(tmp_path):
    from facestats.pipeline.build import build_store

    ids = ["S001", "S002"]
    ref = tmp_path / "ref.zarr"
    build_store(ref, map_size=8, subjects=ids, workers=1, conditions=False)  # warms this process's caches too
    reference = subject_digests(ref)
    rng = random.Random(12)
    sentinel_root = tmp_path / "k"
    sentinel = snapshot(make_sentinel(sentinel_root / "sentinel"))
    # The fastest of two builds into fresh stores: one build slowed by the other test worker would put
    # most kills after the end (CI: 9 of 20 builds killed).
    duration = min(
        _duration(lambda t=t: build_store(t, map_size=8, subjects=ids, workers=1, conditions=False))
        for t in (tmp_path / "t1.zarr", tmp_path / "t2.zarr")
    )
    # A build that finishes before its kill (this run's builds faster than the estimate's, e.g. once
    # the other test worker's load went away) sets the window to its own duration, and the loop runs
    # until N_KILLS builds were really killed: a fixed count of attempts killed only 6 of 20 builds on a
    # loaded CI host.
    killed = attempts = partial = 0
    while killed < N_KILLS and attempts < 3 * N_KILLS:
        store = sentinel_root / f"b{attempts}.zarr"

        def action(store=store):
            build_store(store, map_size=8, subjects=ids, workers=1, conditions=False)

        was_killed, seconds = _kill_during(action, rng, duration)
        killed += was_killed
        if not was_killed:
            duration = min(duration, seconds)
        attempts += 1
        if store.exists() and (store / "zarr.json").exists():
            partial += was_killed
            now = _check_intact(store, {})
            assert all(reference[s] == d for s, d in now.items())  # whole, deterministic subjects only
        if was_killed and killed % 5 == 0:  # a killed build resumes: the same call completes the store
            build_store(store, map_size=8, subjects=ids, workers=1, conditions=False)
            assert subject_digests(store) == reference
            with open_store(store) as st:
                assert st.validate().ok and not st.validate().notes  # the killed writers' leftovers were collected
    assert killed == N_KILLS, f"{killed} of {attempts} builds killed before they finished"
    assert partial >= N_KILLS // 4, f"only {partial} of {killed} kills came after the store was created"
    assert snapshot(sentinel_root / "sentinel") == sentinel


def _merl_file(path, version):
    d = merl_dict(rng=np.random.default_rng(version), n=6, k=120, ka=60)
    scipy.io.savemat(path, d)
    return path


def test_sigkill_during_import(base, tmp_path):
    store = copy_store(base[0], tmp_path)
    mats = [_merl_file(tmp_path / f"v{v}.mat", v) for v in (1, 2)]
    from facestats.io.merl import import_merl

    sentinel = snapshot(tmp_path / "sentinel")
    duration = _duration(lambda: import_merl(mats[0], tmp_path / "warm.zarr"))
    rng = random.Random(34)
    committed = dict(base[1])
    for k in range(N_KILLS):
        _kill_during(lambda k=k: import_merl(mats[k % 2], store, overwrite=True), rng, duration)
        now = _check_intact(store, committed)
        with open_store(store) as st:
            merl = [sid for sid in st.ids() if sid.startswith("merl-")]
            assert len(merl) in (0, 6)  # one atomic commit: all subjects or none
            sources = {st.index_entries()[sid]["row"]["source"] for sid in merl}
            assert len(sources) <= 1, "a killed import mixed two versions"
        committed = {s: d for s, d in now.items() if not s.startswith("merl-")}
    assert snapshot(tmp_path / "sentinel") == sentinel


def test_sigkill_during_edit(base, tmp_path):
    from facestats.edit import transfer_colour_subject

    store = copy_store(base[0], tmp_path)
    sentinel = snapshot(tmp_path / "sentinel")

    def edit(new_id):
        with open_store(store, mode="r+") as st:
            transfer_colour_subject(st, "R1", "R2", new_id=new_id, out_store=st)

    duration = _duration(lambda: edit("WARM"))
    rng = random.Random(56)
    committed = subject_digests(store)
    for k in range(N_KILLS):
        _kill_during(lambda k=k: edit(f"E{k:02d}"), rng, duration)
        committed = _check_intact(store, committed)  # the edit is whole or absent; nothing else changed
    assert subject_digests(store)["R1"] == base[1]["R1"]  # the source is never modified
    assert snapshot(tmp_path / "sentinel") == sentinel


def _damage(store, k):
    """A store that needs repair: a damaged chunk of R2 and a stale row of R1, or (every other time) no index."""
    if k % 2:
        (store / "index.json").unlink()
        return
    gen = next((store / "subjects" / "R2").glob("g*"))
    chunk = gen / "ts_m" / "c" / "0" / "0"
    chunk.write_bytes(chunk.read_bytes()[:9])
    ix = json.loads((store / "index.json").read_text())
    ix["subjects"]["R1"]["row"]["ts_m_mean_r6"] = 9.0
    (store / "index.json").write_text(json.dumps(ix))


def test_sigkill_during_repair(base, tmp_path):
    rng = random.Random(78)
    warm = copy_store(base[0], tmp_path / "warm")
    _damage(warm, 0)

    def repair(path):
        with open_store(path, mode="r+") as st:
            st.repair()

    duration = _duration(lambda: repair(warm))
    for k in range(N_KILLS):
        work = tmp_path / f"r{k}"
        work.mkdir()
        store = copy_store(base[0], work)
        gen_r2 = next((store / "subjects" / "R2").glob("g*")).name
        _damage(store, k)
        sentinel = snapshot(work / "sentinel")
        _kill_during(lambda store=store: repair(store), rng, duration)
        repair(store)  # a killed repair is repaired by the next one
        with open_store(store) as st:
            assert st.validate().ok
        now = subject_digests(store)
        assert {s: now.get(s) for s in ("R1", "RM")} == {s: base[1][s] for s in ("R1", "RM")}
        if k % 2 == 0:  # the damaged generation is moved to the quarantine, never deleted
            assert gen_r2 in quarantined_generations(store) and "R2" not in now
        else:
            assert now == base[1]
        assert snapshot(work / "sentinel") == sentinel
        shutil.rmtree(work)


def test_two_concurrent_writers(base, tmp_path):
    store = copy_store(base[0], tmp_path)
    with open_store(store) as st:
        rev0 = st.revision

    def writer(k):
        with open_store(store, mode="r+") as st:
            for r in range(4):
                st.write_subject(make_map_subject(f"W{k}", size=16, seed=10 * k + r), overwrite=True)
                st.write_subject(make_map_subject("SHARED", size=16, seed=100 + 10 * k + r), overwrite=True)

    pids = [_fork(lambda k=k: writer(k)) for k in range(2)]
    for pid in pids:
        _, status = os.waitpid(pid, 0)
        assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0
    with open_store(store) as st:
        report = st.validate()
        assert report.ok and not report.notes, (report.problems, report.notes)
        assert st.revision == rev0 + 16  # no commit lost
        assert {"W0", "W1", "SHARED"} <= set(st.ids())
    assert {k: v for k, v in subject_digests(store).items() if k in base[1]} == base[1]


def test_subjects_folder_unavailable(base, tmp_path):
    store = copy_store(base[0], tmp_path)
    shutil.move(store / "subjects", tmp_path / "unmounted")
    with open_store(store, mode="r+") as st:
        assert st.query(skin_type="III").count == 2  # the index still answers queries
        with pytest.raises(StoreError, match="R1.*missing"):
            st.subject("R1")
        assert not st.validate().ok
        with pytest.raises(StoreError, match="refusing to repair"):
            st.repair()
        with pytest.raises(StoreError, match="subjects/ folder is missing"):
            st.write_subject(make_map_subject("N", size=16))  # nothing is written onto the bare mount point
        assert st.gc() == []
    assert not (store / "subjects").exists()
    shutil.move(tmp_path / "unmounted", store / "subjects")
    assert subject_digests(store) == base[1]


def _can_mount_tmpfs(tmp_path) -> bool:
    if shutil.which("unshare") is None:
        return False
    probe = tmp_path / "probe"
    probe.mkdir()
    r = subprocess.run(["unshare", "-rm", "sh", "-c", f"mount -t tmpfs -o size=1m tmpfs {probe}"], capture_output=True)
    return r.returncode == 0


def test_full_disk(base, tmp_path):
    if not _can_mount_tmpfs(tmp_path):
        pytest.skip("this machine does not allow a private tmpfs mount (unshare -rm), needed to fill a disk safely")
    disk = tmp_path / "disk"
    disk.mkdir()
    repo = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=str(repo), MPLBACKEND="Agg")
    script = f"mount -t tmpfs -o size=6m tmpfs {disk} && exec {sys.executable} -m tests.reliability.full_disk "
    script += f"{disk} {base[0]}"
    r = subprocess.run(
        ["unshare", "-rm", "sh", "-c", script], capture_output=True, text=True, env=env, cwd=repo, timeout=600
    )
    assert r.returncode == 0, r.stderr[-3000:]
    results = [json.loads(line) for line in r.stdout.splitlines() if line.startswith("{")]
    assert [x["name"] for x in results] == [
        "export", "repair", "delete", "write", "edit", "import", "import-new"
    ], r.stdout  # fmt: skip
    for x in results:
        assert x["code"] == 2, x  # a clear error (exit status 2 / a FacestatsError), not a traceback
        assert "No space left on device" in x["message"] or "no space" in x["message"].lower(), x
        assert all(x["checks"].values()), x
    assert "Traceback" not in r.stderr
