"""Several processes writing, collecting garbage and reading one store at the same time.

Four writer processes (forked children) start together and write disjoint ids
(``W<k>a``, ``W<k>b``) and overlapping ids (``SH0``, ``SH1``, ``SH2``), single
and batched, while a fifth process runs ``gc`` in a loop and a sixth reads and
checks every subject in a loop.  All six race from the first instant; all
must finish without an error, and at the end every subject is present, valid
and equal to a version one writer wrote (its last one, for disjoint ids), the
index agrees with the data, its revision counts every commit (no update was
lost) and nothing is left over.
"""

import json
import os
import time

import numpy as np
import pytest

from facestats.errors import StoreError
from facestats.io import open_store
from facestats.io.schema import provenance, set_provenance
from tests.helpers import make_map_subject, make_sample_subject

N_WRITERS = 4
ROUNDS = 5


def version(sid, seed):
    if sid.startswith("SH2"):
        return set_provenance(make_sample_subject(sid, seed=seed, n_per_region=5), seed=seed)
    return make_map_subject(sid, seed=seed, size=24)


def _seed(k, r):
    return 1000 * (k + 1) + r


def writer(path, k, out):
    st = open_store(path, mode="r+", lock_timeout=60)
    result = {"first": False, "commits": 0}
    try:
        st.write_subject(version("FIRST", _seed(k, 99)))  # all race to create it; one wins
        result["first"] = True
        result["commits"] += 1
    except StoreError as exc:
        assert "already exist" in str(exc)
    for r in range(ROUNDS):
        s = _seed(k, r)
        st.write_subject(version(f"W{k}a", s), overwrite=True)
        st.write_subject(version(f"SH{r % 2}", s), overwrite=True)
        st.write_subjects([version(f"W{k}b", s), version("SH2", s)], overwrite=True)
        result["commits"] += 3
    with open(out, "w") as fh:
        json.dump(result, fh)


def collector(path, stop):
    st = open_store(path, mode="r+")
    while not os.path.exists(stop):
        st.gc()
        time.sleep(0.005)


def reader(path, stop):
    st = open_store(path)
    n = 0
    while not os.path.exists(stop):
        for sid in st.ids():
            ds = st.subject(sid)
            truth = version(sid, provenance(ds)["seed"])
            for name in ("ts_m", "albedo", "ts_sample_rho_s"):
                if name in truth:
                    np.testing.assert_array_equal(ds[name].values, truth[name].values)
            n += 1
    assert n > 0


def spawn(fn, *args, gate):
    pid = os.fork()
    if pid == 0:
        code = 0
        try:
            os.read(gate, 1)  # wait for the start signal
            fn(*args)
        except BaseException:
            import traceback

            traceback.print_exc()
            code = 3
        finally:
            os._exit(code)
    return pid


@pytest.mark.slow
def test_concurrent_writers_gc_and_readers(tmp_path):
    path = tmp_path / "conc.zarr"
    stop = tmp_path / "stop"
    with open_store(path, mode="a") as st:
        st.write_subject(version("SH0", 1))
        rev0 = st.revision
    r_gate, w_gate = os.pipe()
    writers = [spawn(writer, path, k, tmp_path / f"w{k}.json", gate=r_gate) for k in range(N_WRITERS)]
    others = [spawn(collector, path, stop, gate=r_gate), spawn(reader, path, stop, gate=r_gate)]
    os.write(w_gate, b"x" * (N_WRITERS + 2))  # go
    deadline = time.monotonic() + 120
    codes = {}
    for pid in writers:
        codes[pid] = os.waitpid(pid, 0)[1]
    stop.write_text("")
    for pid in others:
        codes[pid] = os.waitpid(pid, 0)[1]
    assert time.monotonic() < deadline
    assert all(os.WIFEXITED(c) and os.WEXITSTATUS(c) == 0 for c in codes.values()), codes
    results = [json.loads((tmp_path / f"w{k}.json").read_text()) for k in range(N_WRITERS)]
    assert sum(r["first"] for r in results) == 1

    with open_store(path) as st:
        report = st.validate()
        assert report.ok, report.problems
        assert not report.notes  # no orphan: every superseded generation was deleted
        assert st.revision == rev0 + sum(r["commits"] for r in results)  # no lost update
        expected = {"FIRST"} | {"SH0", "SH1", "SH2"} | {f"W{k}{x}" for k in range(N_WRITERS) for x in "ab"}
        assert set(st.ids()) == expected
        for k in range(N_WRITERS):
            for x in "ab":
                assert provenance(st.subject(f"W{k}{x}"))["seed"] == _seed(k, ROUNDS - 1)
        winner = next(k for k, r in enumerate(results) if r["first"])
        assert provenance(st.subject("FIRST"))["seed"] == _seed(winner, 99)
        written = {_seed(k, r) for k in range(N_WRITERS) for r in range(ROUNDS)}
        for sid in ("SH0", "SH1", "SH2"):
            ds = st.subject(sid)
            seed = provenance(ds)["seed"]
            assert seed in written
            truth = version(sid, seed)
            for name in truth.data_vars:
                np.testing.assert_array_equal(ds[name].values, truth[name].values)
        # the shared batch partner SH2 was always written with W<k>b: one writer's batch, whole
        k_sh2 = provenance(st.subject("SH2"))["seed"] // 1000 - 1
        assert provenance(st.subject("SH2"))["seed"] == _seed(k_sh2, ROUNDS - 1)
    assert os.listdir(path / ".writers") == []
    for sid in expected:
        assert len([p for p in (path / "subjects" / sid).iterdir() if p.name != "zarr.json"]) == 1
