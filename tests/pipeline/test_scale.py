"""Population builds at scale: distributed runs, the build journal, retries and reports, store locations."""

import json
import os
import re

import numpy as np
import pytest

from facestats import FacestatsError, open_store
from facestats.acquire.capture import open_capture
from facestats.acquire.synthetic.population import synthesize_population
from facestats.acquire.synthetic.simulate import DomeSimulator
from facestats.errors import FitError, StoreError, ValidationError
from facestats.face.procedural import procedural_face
from facestats.pipeline import FitSettings, fit_population, fit_subject
from facestats.pipeline import build as build_module
from facestats.pipeline.cluster import SCHEDULER_VARIABLE, scheduler_address, store_directory
from facestats.pipeline.journal import JOURNAL_DIR, BuildJournal, build_status
from tests.helpers import run_cli

SIZE = 16
QUICK = FitSettings(micro_normals=False, block=128)


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    root = tmp_path_factory.mktemp("captures")
    pop = synthesize_population(map_size=SIZE, geometry=procedural_face(SIZE), conditions=False)
    sim = DomeSimulator(procedural_face(SIZE))
    return [sim.simulate(pop[i]).to_zarr(root / f"{i}.zarr", chunk=128) for i in (0, 1, 2)]


def test_scheduler_address_from_argument_or_environment(monkeypatch):
    monkeypatch.delenv(SCHEDULER_VARIABLE, raising=False)
    assert scheduler_address() is None
    assert scheduler_address("tcp://10.0.0.5:8786") == "tcp://10.0.0.5:8786"
    monkeypatch.setenv(SCHEDULER_VARIABLE, "tls://head:8786")
    assert scheduler_address() == "tls://head:8786"
    assert scheduler_address("tcp://other:1") == "tcp://other:1"  # the argument wins
    with pytest.raises(FacestatsError, match="scheduler must be a Dask scheduler address"):
        scheduler_address("head:8786")
    monkeypatch.setenv(SCHEDULER_VARIABLE, "nonsense")
    with pytest.raises(FacestatsError, match="DASK_SCHEDULER_ADDRESS must be a Dask scheduler address"):
        scheduler_address()
    assert scheduler_address("local") is None  # this machine, whatever the variable says


def test_the_default_store_is_built_on_this_machine_whatever_the_environment_says(monkeypatch, tmp_path, capsys):
    """build_default builds in a local temporary directory that a cluster's workers could not see."""
    from facestats.cli import main

    monkeypatch.setenv(SCHEDULER_VARIABLE, "tcp://10.255.255.1:8786")
    seen = {}

    def recorded(path, **kwargs):
        seen.update(kwargs)
        raise KeyboardInterrupt  # stop before any work

    monkeypatch.setattr(build_module, "build_store", recorded)
    with pytest.raises(KeyboardInterrupt):
        build_module.build_default(out=tmp_path / "default.zip")
    assert scheduler_address(seen["scheduler"]) is None
    assert main(["build", "--default", "--scheduler", "tcp://10.255.255.1:8786"]) == 2
    assert "--default builds the embedded store on this machine" in capsys.readouterr().err
    assert not (tmp_path / "default.zip").exists()
    # every option --default would ignore is refused before anything runs (--retries once rebuilt the store)
    for extra in (["--retries", "3"], ["--seed", "5"], ["--size", "16"], ["--face", "procedural"], ["--no-conditions"]):
        assert main(["build", "--default", *extra]) == 2
        assert f"it takes no {extra[0]}" in capsys.readouterr().err
    assert main(["build", "--status", str(tmp_path), "--default", "--seed", "5"]) == 2
    assert "--status reports on a store; it takes no --seed, --default" in capsys.readouterr().err


def test_object_stores_are_refused_before_anything_runs(tmp_path, captures):
    with pytest.raises(StoreError, match=r"'s3://bucket/pop.zarr' is on an object store"):
        build_module.build_store("s3://bucket/pop.zarr", map_size=SIZE, workers=1)
    with pytest.raises(StoreError, match="object store"):
        fit_population(captures[:1], QUICK, scheduler="synchronous", store="gs://bucket/pop.zarr")
    assert store_directory(f"file://{tmp_path}/x.zarr") == f"{tmp_path}/x.zarr"
    assert not (tmp_path / "x.zarr").exists()


def test_store_locations_are_absolute_as_the_system_opens_them_and_odd_urls_are_refused(tmp_path, monkeypatch):
    """Workers resolved relative paths in their own folders; `file://host/x` lost its host, `s3:/x` and `FILE:///x`
    made local folders `s3:` and `FILE:` (a red team); `link/../x` was normalised to beside the link (a review)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "real" / "deep").mkdir(parents=True)
    (tmp_path / "link").symlink_to(tmp_path / "real" / "deep")
    assert store_directory("pop.zarr") == str(tmp_path / "pop.zarr")
    through = store_directory("link/../pop.zarr")  # the system opens real/pop.zarr there
    assert os.path.realpath(os.path.dirname(through)) == str(tmp_path / "real")
    assert store_directory("FILE:///tmp/x.zarr") == store_directory("file:/tmp/x.zarr") == "/tmp/x.zarr"
    for bad, said in (("file://tmp/x.zarr", "it names the host 'tmp'"), ("s3:/bucket/x", "did you mean s3://"),
                      ("file://", "must name a file or folder"), ("simplecache::/tmp/x", "chained URL")):  # fmt: skip
        with pytest.raises(ValidationError, match=re.escape(said)):
            store_directory(bad)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "real"]  # nothing made


def test_population_fit_into_a_store_on_a_distributed_cluster_from_capture_urls(tmp_path, captures):
    distributed = pytest.importorskip("distributed")
    urls = [f"file://{p}" for p in captures]  # captures at fsspec URLs
    store = tmp_path / "pop.zarr"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as lc:
        ids, stra = fit_population(urls, QUICK, scheduler=lc.scheduler_address, store=store)
    assert sorted(ids) == sorted(open_capture(p).metadata["subject_id"] for p in captures)
    st = open_store(store)
    assert sorted(st.ids()) == sorted(ids)
    assert not (store / JOURNAL_DIR).exists()  # every record removed, the folder pruned
    # The same subject as a plain in-process fit with that σtrAvg.
    ref = fit_subject(captures[1], stra, QUICK, sensor_fit=None)
    got = st.subject(ref.attrs["subject_id"])
    np.testing.assert_array_equal(got.ts_m.values, ref.ts_m.values)


@pytest.mark.slow
def test_relative_paths_mean_the_callers_files_on_workers_elsewhere(tmp_path, captures, monkeypatch):
    """Workers resolved a relative capture path or store in their own working directory: a worker fitted another
    subject's capture that lay under the same name there and the caller was told its subject was stored; a
    relative store made a stray one in the worker's folder (a red team on the distributed path)."""
    import shutil

    distributed = pytest.importorskip("distributed")
    client_dir, worker_dir = tmp_path / "client", tmp_path / "worker"
    shutil.copytree(captures[0], client_dir / "caps" / "S.zarr")
    shutil.copytree(captures[1], worker_dir / "caps" / "S.zarr")  # another subject under the same name
    monkeypatch.chdir(worker_dir)  # worker processes start here
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as lc:
        monkeypatch.chdir(client_dir)
        ids, _ = fit_population(["caps/S.zarr"], QUICK, scheduler=lc.scheduler_address, store="pop.zarr")
    want = open_capture(captures[0]).metadata["subject_id"]
    assert ids == [want] and open_store(client_dir / "pop.zarr").ids() == [want]
    assert not (worker_dir / "pop.zarr").exists()


def test_captures_from_an_in_memory_fsspec_location(captures):
    cap = open_capture(captures[0])
    url = cap.to_zarr("memory://facestats-test/cap.zarr", chunk=128)
    datasets, _ = fit_population([url], QUICK, scheduler="synchronous")
    ref = fit_subject(captures[0], settings=QUICK)
    np.testing.assert_array_equal(datasets[0].ts_rho_s.values, ref.ts_rho_s.values)


@pytest.mark.slow
def test_failed_subjects_are_retried_then_reported_never_skipped(tmp_path, monkeypatch):
    calls = {}
    real = build_module._build_one

    def flaky(*args):
        sid = args[5]
        calls[sid] = calls.get(sid, 0) + 1
        if sid == "S002" or (sid == "S003" and calls[sid] == 1):  # S002 always fails, S003 once
            raise RuntimeError(f"simulated failure of {sid}")
        return real(*args)

    monkeypatch.setattr(build_module, "_build_one", flaky)
    store = tmp_path / "b.zarr"
    report = build_module.build_store(
        store, map_size=SIZE, subjects=["S001", "S002", "S003"], workers=1, retries=1, micro_normals=False
    )
    assert report.written == ["S001", "S003"] and list(report.failed) == ["S002"]
    assert calls == {"S001": 1, "S002": 2, "S003": 2}
    assert "simulated failure of S002" in report.failed["S002"] and "1 FAILED" in report.to_text()
    rec = json.loads((store / JOURNAL_DIR / "S002.json").read_text())
    assert rec["state"] == "failed" and rec["attempts"] == 2 and "RuntimeError" in rec["error"]
    status = build_status(store)
    assert status.done == ["S001", "S003"] and list(status.failed) == ["S002"] and not status.running
    # The command line: --status lists the failure and exits 1.
    res = run_cli("build", "--status", str(store))
    assert res.returncode == 1 and "failed       S002  after 2 attempt(s): RuntimeError" in res.stdout
    # an edit written into the store is not a build that is done
    res = run_cli("edit", "brdf", "S001", "--target", "S003", "--store", str(store), "--images", str(tmp_path / "i"))
    assert res.returncode == 0, res.stderr
    status = build_status(store)
    assert status.done == ["S001", "S003"] and len(status.others) == 1 and status.others[0].startswith("S001.brdf-")
    assert "2 done, 0 running, 0 interrupted, 1 failed (and 1 edited or imported subject(s), not built)" in (
        status.to_text()
    )


def test_status_reports_running_and_interrupted_subjects(tmp_path):
    store = tmp_path / "s.zarr"
    open_store(store, mode="a").close()
    journal = BuildJournal(store)
    journal.start("S010", 1)  # this process: alive
    journal.start("S011", 1)
    rec = json.loads((store / JOURNAL_DIR / "S011.json").read_text())
    rec["pid"] = 2**22 + 12345  # no such process on this host
    (store / JOURNAL_DIR / "S011.json").write_text(json.dumps(rec))
    status = build_status(store)
    assert status.running == ["S010"] and status.interrupted == ["S011"] and status.done == []
    assert "interrupted  S011" in status.to_text()
    journal.finish("S010")
    assert build_status(store).running == []


def test_status_counts_what_a_build_killed_early_did_not_start(tmp_path):
    """Killed before its first subject started, a build left a store that --status reported as "0 done, 0 running,
    0 interrupted, 0 failed" with exit 0, as if finished (a red team): a build records its plan first now."""
    from facestats.pipeline.journal import PLAN

    store = tmp_path / "p.zarr"
    open_store(store, mode="a").close()
    BuildJournal(store).begin(["S001", "S002", "S003"])
    (path,) = (store / JOURNAL_DIR).glob(PLAN)
    plan = json.loads(path.read_text())
    plan["pid"] = 2**22 + 12345  # the killed build's process: gone
    path.write_text(json.dumps(plan))
    BuildJournal(store).start("S002", 1)  # this process: alive
    status = build_status(store)
    assert status.not_started == ["S001", "S003"] and status.running == ["S002"] and status.unfinished
    res = run_cli("build", "--status", str(store))
    assert res.returncode == 1 and "0 done, 1 running, 0 interrupted, 0 failed, 2 not started" in res.stdout
    assert "build of 3 subject(s) begun" in res.stdout and "rerun the same command to resume" in res.stdout
    # the rerun removes the killed build's plan; a build that returns, or fails with an error, leaves no plan
    rerun = ["S001", "S002", "S003"]
    build_module.build_store(store, map_size=8, subjects=rerun, workers=1, conditions=False, micro_normals=False)
    assert BuildJournal(store).plans() == [] and build_status(store).not_started == []
    with pytest.raises(FacestatsError, match="built with other parameters"):
        build_module.build_store(store, map_size=8, seed=7, subjects=["S001"], workers=1, conditions=False)
    assert BuildJournal(store).plans() == []


def test_builds_that_share_a_store_keep_a_plan_each(tmp_path):
    """One shared plan file was replaced by the next build's and removed by whichever returned first: a build
    killed beside another one vanished from --status, which exited 0 (a red team)."""
    store = tmp_path / "p.zarr"
    open_store(store, mode="a").close()
    long_build, short_build = BuildJournal(store), BuildJournal(store)
    long_build.begin(["S001", "S002", "S003", "S004"])
    short_build.begin(["S005"])
    short_build.end()  # the short build returned: only its own plan goes
    (plan,) = build_status(store).plans
    assert plan["subjects"] == ["S001", "S002", "S003", "S004"]
    from facestats.pipeline.journal import PLAN

    (path,) = (store / JOURNAL_DIR).glob(PLAN)  # the long build is killed: its process is gone
    path.write_text(json.dumps(dict(plan, pid=2**22 + 12345)))
    status = build_status(store)
    assert status.unfinished and status.not_started == ["S001", "S002", "S003", "S004"]
    assert status.to_dict()["builds"][0]["state"] == "stopped"
    other = BuildJournal(store)
    other.begin(["S020"])  # a build of other subjects leaves the killed build's plan (a review)
    assert build_status(store).unfinished
    other.end()
    BuildJournal(store).begin(["S001", "S002", "S003", "S004"])  # the rerun: the killed build's plan goes
    status = build_status(store)
    assert not status.unfinished and [len(p["subjects"]) for p in status.plans] == [4]


def test_the_plan_file_of_an_older_build_is_read_and_resumed(tmp_path):
    """Before per-build plans a build kept `.build/.plan.json`: after an upgrade, a killed build's plan there was
    ignored and never removed (a review)."""
    from facestats.pipeline.journal import LEGACY_PLAN

    store = tmp_path / "p.zarr"
    open_store(store, mode="a").close()
    (store / JOURNAL_DIR).mkdir()
    old = {"subjects": ["S001", "S002"], "host": os.uname().nodename, "pid": 2**22 + 12345, "started": "2026-12-05"}
    (store / JOURNAL_DIR / LEGACY_PLAN).write_text(json.dumps(old))
    status = build_status(store)
    assert status.unfinished and status.not_started == ["S001", "S002"]
    BuildJournal(store).begin(["S001", "S002"])
    assert not (store / JOURNAL_DIR / LEGACY_PLAN).exists()


def test_a_journal_that_cannot_be_written_fails_the_subject_not_the_build(tmp_path, monkeypatch):
    """On a full disk the record of a starting subject could not be written: the error left run_journalled and
    aborted the whole build, naming no subject, and left 0-byte temporaries in .build/ (a red team)."""
    import errno
    import pathlib

    from facestats.pipeline.journal import run_journalled

    store = tmp_path / "s.zarr"
    open_store(store, mode="a").close()
    real = pathlib.Path.write_text

    def full(self, text, *args, **kwargs):
        if self.name.startswith(".S005.json.tmp-"):
            real(self, "", *args, **kwargs)  # the file is made, its bytes do not fit
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, text, *args, **kwargs)

    monkeypatch.setattr(pathlib.Path, "write_text", full)
    calls = []
    state, error = run_journalled(BuildJournal(store), "S005", lambda: calls.append(1), retries=2)
    assert (state, calls) == ("failed", [])  # reported, not raised; the work never began without its record
    assert error == "OSError: [Errno 28] No space left on device"
    assert os.listdir(store / JOURNAL_DIR) == []  # no temporaries left
    assert run_journalled(BuildJournal(store), "S006", lambda: "ok", retries=0) == ("done", "ok")


@pytest.mark.parametrize("retries", [-1, 1.5, True])
def test_run_journalled_refuses_a_negative_or_non_integer_retry_count_before_any_record(tmp_path, retries):
    """``retries=-1`` made no attempt and raised UnboundLocalError of the unset error text."""
    from facestats.pipeline.journal import run_journalled

    store = tmp_path / "s.zarr"
    open_store(store, mode="a").close()
    calls = []
    with pytest.raises(ValidationError, match="retries must be an integer"):
        run_journalled(BuildJournal(store), "S005", lambda: calls.append(1), retries)
    assert calls == [] and not (store / JOURNAL_DIR).exists()


def test_a_record_left_by_a_build_killed_after_its_commit_goes_on_resume(tmp_path):
    """Killed between a subject's commit and its record's removal, a build leaves a ``running`` record of a
    stored subject; the resumed build skips the subject and removes the record (and the empty journal)."""
    store = tmp_path / "k.zarr"
    build_module.build_store(store, map_size=8, subjects=["S001"], workers=1, conditions=False, micro_normals=False)
    BuildJournal(store).start("S001", 1)  # as the killed build left it
    assert (store / JOURNAL_DIR / "S001.json").exists()
    report = build_module.build_store(
        store, map_size=8, subjects=["S001"], workers=1, conditions=False, micro_normals=False
    )
    assert report.skipped == ["S001"] and not (store / JOURNAL_DIR).exists()
    with open_store(store) as st:
        assert st.validate().ok and not st.validate().notes


@pytest.mark.slow
def test_build_on_a_distributed_cluster_given_by_the_environment(tmp_path, monkeypatch):
    distributed = pytest.importorskip("distributed")
    store = tmp_path / "d.zarr"
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as lc:
        monkeypatch.setenv(SCHEDULER_VARIABLE, lc.scheduler_address)
        report = build_module.build_store(store, map_size=SIZE, subjects=["S004", "S005"], micro_normals=False)
    assert report.written == ["S004", "S005"] and report.workers == 1 and not report.failed
    assert sorted(open_store(store).ids()) == ["S004", "S005"]
    assert os.listdir(store).count(JOURNAL_DIR) == 0


def test_fit_population_reports_subjects_that_keep_failing(tmp_path, captures):
    broken = _broken_capture(tmp_path, captures[0])
    with pytest.raises(FitError, match=r"1 of 2 subject\(s\) failed after 1 retries: S\d+: FormatError: capture "):
        fit_population([captures[1], broken], QUICK, scheduler="synchronous", retries=1)
    with pytest.raises(FacestatsError, match=r"array 'radiance', lumitexels 0:128, cannot be read \(a damaged"):
        fit_subject(broken, settings=QUICK)


def _broken_capture(tmp_path, source):
    """A copy of ``source`` whose radiance chunks are garbage: its sensor data read, its dome fit fails."""
    import shutil

    path = tmp_path / "broken.zarr"
    shutil.copytree(source, path)
    for root, _, files in os.walk(path / "radiance" / "c"):
        for f in files:
            with open(os.path.join(root, f), "wb") as fh:
                fh.write(b"not a blosc frame")
    return str(path)


def _renamed(tmp_path, source, sid):
    """A copy of capture ``source`` whose subject id is ``sid`` (written into its zarr.json as it stands)."""
    import shutil

    path = tmp_path / f"renamed-{abs(hash(sid))}.zarr"
    shutil.copytree(source, path)
    meta = json.loads((path / "zarr.json").read_text())
    meta["attributes"]["subject_id"] = sid
    (path / "zarr.json").write_text(json.dumps(meta))
    return str(path)


def test_a_subject_id_that_is_a_path_writes_nothing_anywhere(tmp_path, captures):
    bad = _renamed(tmp_path, captures[0], "/../../escaped")
    store = tmp_path / "p.zarr"
    with pytest.raises(FacestatsError, match="escaped"):
        fit_population([bad], QUICK, scheduler="synchronous", store=store)
    assert not store.exists() and not list(tmp_path.rglob("escaped*"))
    with pytest.raises(FacestatsError):
        BuildJournal(store).start("../x", 1)  # the journal's own guard
    twice = _renamed(tmp_path, captures[1], open_capture(captures[0]).metadata["subject_id"])
    with pytest.raises(FacestatsError, match="each subject once"):
        fit_population([captures[0], twice], QUICK, scheduler="synchronous", store=store)
    assert not store.exists()


def test_a_rerun_into_a_store_skips_the_stored_subjects(tmp_path, captures, monkeypatch):
    from facestats.pipeline import population

    store = tmp_path / "r.zarr"
    ids, _ = fit_population(captures[:1], QUICK, scheduler="synchronous", store=store)
    before = open_store(store).subject(ids[0]).ts_m.values

    def refit(*args, **kwargs):
        raise AssertionError("a stored subject was fitted again")

    monkeypatch.setattr(population, "fit_subject", refit)
    again, _ = fit_population(captures[:1], QUICK, scheduler="synchronous", store=store)
    assert again == ids
    np.testing.assert_array_equal(open_store(store).subject(ids[0]).ts_m.values, before)


def _service(reply):
    """A TCP service on 127.0.0.1 that accepts connections and sends ``reply`` (None: nothing), and its address."""
    import socket
    import threading

    server = socket.create_server(("127.0.0.1", 0))
    held = []

    def serve():
        while True:
            try:
                conn, _ = server.accept()
            except OSError:  # closed
                return
            held.append(conn)
            if reply is not None:
                conn.sendall(reply)

    threading.Thread(target=serve, daemon=True).start()
    return server, f"tcp://127.0.0.1:{server.getsockname()[1]}"


def test_an_address_where_no_scheduler_listens_is_named_not_waited_for():
    """Dask's dashboard port (a web server) given for the scheduler's: a silent service hung the build past
    300 s, an HTTP reply ended in "out of memory (Unable to allocate 3.07 EiB)", a refused connection waited the
    whole timeout, and a port beyond 65535 too (a red team)."""
    import time

    distributed = pytest.importorskip("distributed")
    from facestats.pipeline.cluster import connect

    for reply, said in ((None, "did not answer within 2 s"), (b"HTTP/1.1 400 Bad Request\r\n\r\n",
                        "is not one: it answered 'HTTP/1.1', not Dask's handshake")):  # fmt: skip
        server, address = _service(reply)
        start = time.monotonic()
        with pytest.raises(ValidationError, match=f"the Dask scheduler at '{address}' {said}"):
            connect(address, timeout=2)
        assert time.monotonic() - start < 5
        server.close()
    import socket

    with socket.socket() as unused:  # a port bound for a moment, never listened on
        unused.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{unused.getsockname()[1]}"
    start = time.monotonic()
    with pytest.raises(ValidationError, match="cannot be reached: Connection refused"):
        connect(address, timeout=30)
    with pytest.raises(ValidationError, match="port 99999 is not in 1..65535"):
        connect("tcp://127.0.0.1:99999", timeout=30)
    assert time.monotonic() - start < 5
    # A real scheduler passes the probe (which reads Dask's framing: a change of it would show here).
    with distributed.LocalCluster(n_workers=0, processes=False, protocol="tcp", dashboard_address=None) as lc:
        assert lc.scheduler_address.startswith("tcp://")
        client = connect(lc.scheduler_address, timeout=10)
        assert client.scheduler_info()["address"] == lc.scheduler_address
        client.close()


def test_settings_and_schedulers_that_cannot_work_are_refused_before_the_store_exists(tmp_path, captures, monkeypatch):
    store = tmp_path / "n.zarr"
    with pytest.raises(FacestatsError, match="settings.models must include"):
        fit_population(captures[:1], FitSettings(models=("torrance_sparrow",)), scheduler="synchronous", store=store)
    with pytest.raises(FacestatsError, match="settings must be a FitSettings, got dict"):
        fit_population(captures[:1], {"engine": "numpy"}, scheduler="synchronous", store=store)
    import dask

    before = dask.config.get("scheduler", None)
    for address in ("tcp://", "TCP://127.0.0.1:1", "tcp://[::1", "inproc://x"):
        with pytest.raises(FacestatsError, match="scheduler"):
            fit_population(captures[:1], QUICK, scheduler=address, store=store)
        with pytest.raises(FacestatsError, match="scheduler"):
            build_module.build_store(store, map_size=8, subjects=["S001"], scheduler=address, workers=1)
    # a failed connection leaves Dask's default scheduler as it was: later computations still run
    assert dask.config.get("scheduler", None) == before
    assert dask.compute(dask.delayed(sum)([1, 2]))[0] == 3
    monkeypatch.setenv("FACESTATS_ENGINE", "bogus")
    with pytest.raises(FacestatsError, match="FACESTATS_ENGINE must be one of"):
        fit_population(captures[:1], FitSettings(micro_normals=False), scheduler="synchronous", store=store)
    with pytest.raises(FacestatsError, match="FACESTATS_ENGINE must be one of"):
        build_module.build_store(store, map_size=8, subjects=["S001"], workers=1)
    assert not store.exists()


def test_a_task_lost_with_its_worker_is_reported_and_journalled(tmp_path):
    from facestats.pipeline.journal import gathered

    class Lost:
        def result(self):
            raise RuntimeError("KilledWorker: the worker died")

    store = tmp_path / "g.zarr"
    open_store(store, mode="a").close()
    assert gathered(Lost(), store, "S007") == ("S007", "failed", "RuntimeError: KilledWorker: the worker died")
    assert build_status(store).failed == {"S007": "RuntimeError: KilledWorker: the worker died"}


def test_a_failed_record_keeps_the_message_of_an_exception_with_notes(tmp_path):
    """The record's error was the last entry of traceback.format_exception_only, which for an exception with notes
    (add_note) is its last note: the message was lost from --status."""
    store = tmp_path / "n.zarr"
    open_store(store, mode="a").close()
    journal = BuildJournal(store)
    exc = RuntimeError("fit diverged\n at iteration 7")
    exc.add_note("while fitting S001")
    exc.add_note("camera 3\nsite forehead")
    journal.fail("S001", 1, exc)
    error = "RuntimeError: fit diverged at iteration 7 (while fitting S001; camera 3; site forehead)"
    assert journal.read("S001")["error"] == error and build_status(store).failed == {"S001": error}
    journal.fail("S002", 1, ValueError("no notes"))
    assert journal.read("S002")["error"] == "ValueError: no notes"
    try:
        compile("x = (", "f.py", "exec")
    except SyntaxError as syntax:
        syntax.add_note("in a plug-in")
        journal.fail("S003", 1, syntax)
    assert journal.read("S003")["error"] == "SyntaxError: '(' was never closed (in a plug-in)"


def test_status_reads_damaged_journal_records_without_failing(tmp_path):
    store = tmp_path / "j.zarr"
    open_store(store, mode="a").close()
    journal = BuildJournal(store)
    journal.start("S001", 1)
    root = store / JOURNAL_DIR
    for name, text in (("S002", "[]"), ("S003", '"x"'), ("S004", '{"state": "failed"}'), ("..bad", "{}")):
        (root / f"{name}.json").write_text(text)
    (root / "S005.json").write_text(json.dumps({"state": "running", "pid": 2**70, "host": os.uname().nodename}))
    status = build_status(store)
    assert status.failed == {"S004": None} and "S001" in status.running and "S005" in status.running
    assert set(journal.records()) == {"S001", "S004", "S005"}  # "..bad" is not a subject id: left out
    text = status.to_text()
    assert "failed       S004  after ? attempt(s)" in text
    res = run_cli("build", "--status", str(store))
    assert res.returncode == 1 and "Traceback" not in res.stderr


def test_settings_of_the_wrong_kind_are_refused_and_assigned_fields_checked_again(captures):
    for kwargs, message in (
        ({"bp_max_angle_deg": [70]}, "bp_max_angle_deg must be a number"),
        ({"eta": True}, "eta must be a number"),
        ({"micro_normals": "no"}, "micro_normals must be True or False"),
        ({"exclude_cameras": None}, "exclude_cameras must be a tuple"),
        ({"models": [["blinn_phong"]]}, "models must be a tuple of model names"),
    ):
        with pytest.raises(FacestatsError, match=message):
            FitSettings(**kwargs)
    st = FitSettings(micro_normals=False, block=128)
    st.bp_max_angle_deg = float("nan")  # a dataclass field assigned after construction
    with pytest.raises(FacestatsError, match="bp_max_angle_deg must be finite"):
        fit_subject(captures[0], settings=st)
    st.bp_max_angle_deg, st.exclude_cameras = 70.0, (-1,)
    with pytest.raises(FacestatsError, match="exclude_cameras must be"):
        fit_subject(captures[0], settings=st)


def test_status_of_a_store_given_as_a_file_url(tmp_path):
    store = tmp_path / "f.zarr"
    open_store(store, mode="a").close()
    BuildJournal(store).start("S009", 1)
    assert build_status(f"file://{store}").running == ["S009"]
    res = run_cli("build", "--status", f"file://{store}")
    assert res.returncode == 0 and "1 running" in res.stdout


def test_outcomes_hold_results_on_the_client_and_release_them_on_the_cluster():
    """run_tasks reruns a lost task alone; the worker it may kill must not take finished results with it (Dask
    recomputed them, beside the lone task, a review): each finished result is taken to the client first and its
    future released, and a loss is raised again by ``result()``."""
    import distributed

    from facestats.pipeline.cluster import Outcome

    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as lc:
        with distributed.Client(lc) as client:
            ok, bad = client.submit(sum, [1, 2], pure=False), client.submit(int, "x", pure=False)
            distributed.wait([ok, bad])
            key = ok.key
            done, lost = Outcome(ok), Outcome(bad)
            assert done.status == "finished" and done.result() == 3 and key not in client.refcount
            assert lost.status == "error"
            with pytest.raises(ValueError, match="invalid literal"):
                lost.result()


def test_a_build_larger_than_the_memory_available_is_refused_before_anything_runs(tmp_path, monkeypatch):
    """The estimate (workers × (fixed + per texel), measured constants) against the memory available now."""
    import facestats.pipeline.build as build

    need = build.estimated_memory(8, 1)
    monkeypatch.setattr(build, "available_memory", lambda: 0.5 * need)
    with pytest.raises(FacestatsError, match=r"map_size 8 needs about .* GiB with 1 worker\(s\) .* available"):
        build.build_store(tmp_path / "s.zarr", map_size=8, subjects=["S001"], workers=1, conditions=False)
    assert not (tmp_path / "s.zarr").exists()
