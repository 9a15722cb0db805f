"""``facestats build --workers 2`` killed with SIGKILL, SIGTERM or SIGINT: no worker survives, nothing is committed
after, and the build resumes.

The three builds run at once (different stores) through the console script, tagged with an environment
variable that every worker inherits, so their processes can be found in ``/proc`` whoever their
parent is afterwards.  Each is killed once it has committed a subject (its workers are then
simulating and fitting); within 3 s of the build's end no tagged process may be left, the index must
not change over the following 1.5 s, and rerunning the same command must complete the store.
"""

import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from tests.helpers import facestats_exe, run_main

from .helpers import run, subject_digests

#: Enough that work is left when the first subject is committed: with five, a build whose kernels were
#: already compiled could finish before the signal arrived (a SIGINT'd build then exited 0, done).
SUBJECTS = [f"S{k:03d}" for k in range(1, 11)]


def _tagged(tag: str) -> list[int]:
    """Pids of the processes whose environment carries ``FACESTATS_TEST_TAG=tag`` (not this one)."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            env = (entry / "environ").read_bytes()
            state = (entry / "stat").read_text().split(")")[-1].split()[0]
        except OSError:
            continue
        if f"FACESTATS_TEST_TAG={tag}".encode() in env.split(b"\0") and state != "Z":
            out.append(int(entry.name))
    return out


def _count(store: Path) -> int:
    try:
        return len(json.loads((store / "index.json").read_text())["subjects"])
    except (OSError, ValueError):
        return 0


def _start(store: Path, tag: str):
    env = dict(os.environ, FACESTATS_TEST_TAG=tag, MPLBACKEND="Agg")
    argv = [*facestats_exe(), "build", "--store", str(store), "--size", "8", "--workers", "2", "--quiet"]
    argv += ["--no-conditions", "--subjects", *SUBJECTS]
    # SIGINT as in a terminal: a shell ignores it in the commands it starts in the background (``pytest &``),
    # and a Python started with SIGINT ignored keeps ignoring it (the build would then, correctly, run on).
    # A default disposition survives exec, so a small launcher restores it and becomes the console script.
    launcher = (
        "import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); os.execv(sys.argv[1], sys.argv[1:])"
    )
    argv = [sys.executable, "-c", launcher, *argv]
    return subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs /proc to find the worker processes")
def test_killed_build_leaves_no_worker_and_resumes(tmp_path):
    signals = (signal.SIGKILL, signal.SIGTERM, signal.SIGINT)
    runs = {sig: (tmp_path / f"{sig.name}.zarr", uuid.uuid4().hex) for sig in signals}
    procs = {sig: _start(store, tag) for sig, (store, tag) in runs.items()}
    try:
        deadline = time.monotonic() + 600
        pending = dict(procs)
        while pending and time.monotonic() < deadline:
            for sig in list(pending):
                if _count(runs[sig][0]) >= 1 and len(_tagged(runs[sig][1])) >= 3:  # working: parent + 2 workers
                    pending.pop(sig).send_signal(sig)
            time.sleep(0.05)
        assert not pending, "the builds did not get going"
        outputs = {sig: p.communicate(timeout=120) for sig, p in procs.items()}
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
    gone = time.monotonic() + 3  # every worker must be gone within 3 s of its build's end
    while any(_tagged(tag) for _, tag in runs.values()) and time.monotonic() < gone:
        time.sleep(0.05)
    for sig, (_, tag) in runs.items():
        assert _tagged(tag) == [], f"{sig.name}: worker processes survived their build"
    assert all(_count(store) < len(SUBJECTS) for store, _ in runs.values()), "a build finished before its signal"
    for sig in (signal.SIGTERM, signal.SIGINT):  # both stop the build cleanly, with advice and no traceback
        assert procs[sig].returncode == 130 and "rerun the same command to resume" in outputs[sig][1], sig.name
        assert "Traceback" not in outputs[sig][1], sig.name
        assert "leaked semaphore" not in outputs[sig][1], sig.name  # the workers' Blosc locks (a walkthrough)
    assert procs[signal.SIGKILL].returncode == -signal.SIGKILL
    counts = {sig: _count(store) for sig, (store, _) in runs.items()}
    time.sleep(1.5)
    assert counts == {sig: _count(store) for sig, (store, _) in runs.items()}, "subjects were committed after the kill"
    # a killed build resumes: the same command completes the store, skipping what is there
    store = runs[signal.SIGKILL][0]
    before = subject_digests(store)
    # in this process (the command's own code, parsed by its own parser): the process boundary was the kill's
    r = run_main("build", "--store", store, "--size", "8", "--workers", "1", "--quiet", "--no-conditions",
                  "--subjects", *SUBJECTS, timeout=900)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    after = subject_digests(store)
    assert sorted(after) == SUBJECTS and all(after[s] == d for s, d in before.items())
    assert f"{len(before)} already present" in r.stdout


def test_build_workers_stopped_at_once_leave_no_named_semaphore():
    """Ctrl-C during a build printed "resource_tracker: There appear to be 2 leaked semaphore objects" (a
    walkthrough): each worker's first Blosc compression (numcodecs) makes a multiprocessing lock, a named semaphore
    under the spawn method, which a worker stopped by ``os._exit`` never unlinked.  The build's own pool, its
    workers stopped as an interrupted build stops them, leaves none."""
    script = (
        "import time, numcodecs, numpy as np\n"
        "from facestats.pipeline.build import _local_pool\n"
        "pool, stop = _local_pool(2)\n"
        "sizes = list(pool.map(numcodecs.Blosc(cname='zstd').encode, [np.zeros(1000)] * 8))\n"
        "stop.value = True\n"  # as after Ctrl-C: the workers leave by os._exit within 0.25 s
        "time.sleep(1.0)\n"
        "pool.shutdown(wait=True, cancel_futures=True)\n"
        "print('encoded', len(sizes))\n"
    )
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "encoded 8", r.stdout + r.stderr
    assert "leaked semaphore" not in r.stderr and "resource_tracker" not in r.stderr, r.stderr


#: Installed through PYTHONPATH in the build's processes: the worker that builds $FACESTATS_TEST_DIE_ON kills itself
#: with SIGKILL, as the out-of-memory killer would (the spawned workers import it too, before any task).
_DYING_WORKER = """
import os
import signal

if os.environ.get("FACESTATS_TEST_DIE_AT_START"):  # every worker dies in its initializer, before any subject
    import facestats.pipeline.build as build

    def _die(*args):
        os.kill(os.getpid(), signal.SIGKILL)

    build._worker_init = _die

if os.environ.get("FACESTATS_TEST_DIE_ON"):
    import facestats.pipeline.build as build

    _build_one = build._build_one

    def _dying(*args, **kwargs):
        if args[5] == os.environ["FACESTATS_TEST_DIE_ON"]:
            os.kill(os.getpid(), signal.SIGKILL)
        return _build_one(*args, **kwargs)

    build._build_one = _dying
"""


def _build(store, subjects, **env):
    argv = [*facestats_exe(), "build", "--store", str(store), "--size", "8", "--workers", "2", "--quiet"]
    argv += ["--no-conditions", "--subjects", *subjects]
    return subprocess.Popen(argv, env=dict(os.environ, MPLBACKEND="Agg", **env), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip


@pytest.mark.slow
def test_a_worker_killed_mid_subject_is_survived_and_the_subject_redone(tmp_path):
    """A dead worker broke the process pool, and stopping the others then waited for ever on the dead one's
    Event: the build hung at 0 % CPU (a red team). Now the round's subjects are sorted out from the store and
    the journal, and the one that was running is built again (alone)."""
    store, subjects = tmp_path / "s.zarr", SUBJECTS[:6]
    proc = _build(store, subjects)
    try:
        deadline = time.monotonic() + 300
        record = None
        while record is None and time.monotonic() < deadline:
            found = sorted((store / ".build").glob("S*.json")) if (store / ".build").is_dir() else []
            try:
                record = json.loads(found[0].read_text()) if found else None
            except (OSError, ValueError):  # replaced as we read it
                record = None
            time.sleep(0.02)
        assert record is not None, "no subject got going"
        os.kill(record["pid"], signal.SIGKILL)
        out, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "6 subject(s) written" in out and _count(store) == 6
    code, status = run("build", "--status", store)  # the journal as the build left it, read in this process
    assert code == 0 and "6 done, 0 running, 0 interrupted, 0 failed" in status, status


@pytest.mark.slow
def test_a_subject_whose_worker_always_dies_is_reported_failed_and_the_others_are_built(tmp_path):
    """Retried alone (so that only its own deaths count), then reported failed: exit 1, the journal says why."""
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(_DYING_WORKER)
    store, subjects = tmp_path / "s.zarr", SUBJECTS[:4]
    path = os.pathsep.join([str(hook), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    tag = uuid.uuid4().hex
    proc = _build(store, subjects, FACESTATS_TEST_DIE_ON="S002", PYTHONPATH=path, FACESTATS_TEST_TAG=tag)
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 1, err
    assert "3 subject(s) written" in out and "1 FAILED" in out
    assert "failed S002: _WorkerDied: its worker process died on each of 3 attempts" in out
    code, status = run("build", "--status", store)  # the journal as the build left it, read in this process
    assert "3 done, 0 running, 0 interrupted, 1 failed" in status and "S002" in status, status
    assert json.loads((store / ".build" / "S002.json").read_text())["attempts"] == 3  # was 1 (the first death)
    gone = time.monotonic() + 3
    while _tagged(tag) and time.monotonic() < gone:
        time.sleep(0.05)
    assert _tagged(tag) == [], "worker processes survived the build"


@pytest.mark.slow
def test_workers_that_die_before_any_subject_end_the_build_with_every_subject_reported(tmp_path):
    """Workers that die on their own (here in their initializer) would break every new pool before any subject
    began: without a bound the build would start pools for ever."""
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(_DYING_WORKER)
    store = tmp_path / "s.zarr"
    path = os.pathsep.join([str(hook), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    proc = _build(store, SUBJECTS[:3], FACESTATS_TEST_DIE_AT_START="1", PYTHONPATH=path)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 1, err
    assert "0 subject(s) written" in out and "3 FAILED" in out
    assert out.count("the worker processes died 3 times before any subject began") == 3


@pytest.mark.slow
def test_on_a_cluster_a_subject_sharing_a_worker_with_one_that_kills_it_is_built_alone(tmp_path, monkeypatch):
    """Dask counts a worker's death against every task the worker held, so a subject that shared a worker with
    one that killed it was reported ``KilledWorker`` too (a red team). A lost task now runs again alone. Two
    threads on one worker make S001 share it with S002, whose task kills its process; with
    ``allowed-failures`` 0 the scheduler gives up on every task the worker held at its first death."""
    import dask
    import distributed

    from facestats.pipeline.build import build_store
    from facestats.pipeline.journal import build_status

    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(_DYING_WORKER)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(hook), os.environ.get("PYTHONPATH", "")]).rstrip(":"))
    monkeypatch.setenv("FACESTATS_TEST_DIE_ON", "S002")
    store = tmp_path / "s.zarr"
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=True, dashboard_address=None) as lc:
            with distributed.Client(lc) as client:
                report = build_store(store, map_size=8, conditions=False, subjects=SUBJECTS[:2], client=client)
    assert report.written == ["S001"]
    assert list(report.failed) == ["S002"] and "KilledWorker" in report.failed["S002"]
    assert set(build_status(store).failed) == {"S002"}
