"""Issue #12, "must never happen again": each case reproduced first, then the fixed behaviour asserted.

Also the defects found when the store was split (rebuild reviving uncommitted data, no re-check under
the lock, a passing read error deleting data, no retry on a concurrent replacement, gc and validate
disagreeing, lock checks creating files, generation folders failing silently).
"""

import errno
import json
import os
import shutil

import numpy as np
import pytest
import zarr

from facestats.errors import SchemaError, StoreError, ValidationError
from facestats.io import open_store
from facestats.io import store as store_mod
from facestats.io.generations import reserve_generation
from facestats.io.locking import FileLock, is_locked
from facestats.io.maintenance import ValidationReport, check_subjects
from tests.helpers import make_map_subject

from .helpers import (
    digest_dataset,
    flip_albedo_bit,
    generation_dir,
    quarantined_generations,
    run,
    snapshot,
    subject_digests,
)


# -- 1. deleting outside the store ----------------------------------------------------------------
def test_links_under_subjects_are_never_followed(store, base, tmp_path):
    sentinel = tmp_path / "sentinel"
    (store / "subjects" / "X1").symlink_to(sentinel)  # the issue's `ln -s /some/dir X.zarr/subjects/X1`
    gen_link = store / "subjects" / "R1" / "g0000000000000002-1-bbbbbb"
    gen_link.symlink_to(sentinel / "g0000000000000001-1-aaaaaa")  # a "generation" that leads out
    (store / ".records" / "R1~g0000000000000002-1-bbbbbb.json").symlink_to(sentinel / "notes.txt")
    before = snapshot(sentinel)
    code, out = run("validate", "--store", store)
    assert code == 0 and "not created by facestats were left alone" in out
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0, out
    with open_store(store, mode="r+") as st:
        st.gc()
    assert snapshot(sentinel) == before  # nothing outside the store touched
    assert (store / "subjects" / "X1").is_symlink() and gen_link.is_symlink()  # nor the links themselves
    assert subject_digests(store) == base[1]


def test_a_link_planted_as_a_subject_folder_is_never_written_through(store, tmp_path):
    sentinel = tmp_path / "sentinel"
    (store / "subjects" / "NEW").symlink_to(sentinel)
    before = snapshot(sentinel)
    with open_store(store, mode="r+") as st:
        with pytest.raises(StoreError, match=r"subjects/NEW.*(symbolic link|outside the store)"):
            st.write_subject(make_map_subject("NEW", size=16))
    assert snapshot(sentinel) == before


def test_a_subject_folder_linked_out_stops_repair_without_leaving_a_quarantine(store, base, tmp_path):
    sid = sorted(p.name for p in (store / "subjects").iterdir() if p.is_dir())[0]
    outside = tmp_path / "outside"
    outside.mkdir()
    shutil.move(store / "subjects" / sid, outside / sid)
    (store / "subjects" / sid).symlink_to(outside / sid)
    before = snapshot(outside)
    code, out = run("validate", "--store", store)
    assert code == 1 and f"subjects/{sid} is a symbolic link" in out
    code, out = run("validate", "--store", store, "--repair")  # the plan says so, and proposes nothing
    assert code == 2 and f"refusing to repair {store}: subjects/{sid} is a symbolic link" in out
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 2 and "is a symbolic link" in out
    assert not (store / "quarantine").exists() and snapshot(outside) == before


def test_a_linked_index_is_a_problem_for_validate_as_for_repair(store, tmp_path):
    (tmp_path / "victim").mkdir()
    shutil.move(store / "index.json", tmp_path / "victim" / "index.json")
    (store / "index.json").symlink_to(tmp_path / "victim" / "index.json")
    code, out = run("validate", "--store", store)
    assert code == 1 and "index.json must be a regular file of the store, but it is a symbolic link" in out


# -- 2. writing outside the store ------------------------------------------------------------------
@pytest.mark.parametrize("bad", ["../../victim", "S9\n", "a/b", "..", ".hidden", "x" * 65, ""])
def test_ids_read_from_the_index_are_validated(store, tmp_path, bad):
    index = json.loads((store / "index.json").read_text())
    index["subjects"][bad] = dict(index["subjects"]["R1"])
    (store / "index.json").write_text(json.dumps(index))
    outside = snapshot(tmp_path)
    for argv in (("query", "--store", store), ("info", "--store", store)):
        code, out = run(*argv)
        assert code == 2 and repr(bad) in out and "invalid subject id" in out, out
    with open_store(store, mode="r+") as st:  # the next commit refuses: it would write where the id points
        with pytest.raises(StoreError, match="invalid subject id"):
            st.write_subject(make_map_subject("R9", size=16))
    assert {k: v for k, v in snapshot(tmp_path).items() if not k.startswith("s.zarr")} == {
        k: v for k, v in outside.items() if not k.startswith("s.zarr")
    }
    assert not (tmp_path.parent / "victim").exists() and not (tmp_path / "victim").exists()
    code, out = run("validate", "--store", store, "--repair", "--yes")  # the entry is dropped (kept in quarantine)
    assert code == 0 and "drop subject" in out, out
    dropped = json.loads(next(store.glob("quarantine/*/dropped-entries.json")).read_text())
    assert bad in dropped


@pytest.mark.parametrize("bad", ["../../victim", "S9\n", "a b", "é"])
def test_ids_from_the_api_cli_and_merl_prefixes_follow_one_rule(store, tmp_path, bad):
    ds = make_map_subject("R9", size=16)
    ds.attrs["subject_id"] = bad
    with open_store(store, mode="r+") as st:
        with pytest.raises(ValidationError, match="subject_id must be"):
            st.write_subject(ds)
        with pytest.raises(ValidationError, match="subject_id must be"):
            st.delete_subject(bad)
    from facestats.io.merl import read_merl

    with pytest.raises(ValidationError, match="prefix must make subject ids"):
        read_merl(tmp_path / "missing.mat", prefix=bad)
    code, out = run("import-merl", tmp_path / "missing.mat", "--store", tmp_path / "new.zarr", "--prefix", bad)
    assert code == 2 and "prefix" in out and not (tmp_path / "new.zarr").exists()
    code, out = run(
        "edit", "colour", "R1", "--store", store, "--target", "R2", "--id", bad, "--out-store", tmp_path / "e.zarr"
    )
    assert code == 2 and "--id must be" in out and not (tmp_path / "e.zarr").exists()  # named by the option


# -- 3. repair that destroys --------------------------------------------------------------------------
def test_repair_refuses_an_unmounted_or_half_present_store(store, base, tmp_path):
    shutil.move(store / "subjects", tmp_path / "away")
    index_before = (store / "index.json").read_bytes()
    code, out = run("validate", "--store", store)
    assert code == 1 and "subjects/ folder is missing" in out
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 2 and "refusing to repair" in out and "unmounted" in out
    (store / "subjects").mkdir()  # an empty mount point
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 2 and "refusing to repair" in out and "half-present" in out
    assert (store / "index.json").read_bytes() == index_before  # the index was not emptied
    (store / "subjects").rmdir()
    shutil.move(tmp_path / "away", store / "subjects")  # the volume comes back: everything is there
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0 and subject_digests(store) == base[1]


def test_repair_recovers_the_newest_intact_generation(store, monkeypatch):
    with open_store(store, mode="r+") as st:
        old = st.index_entries()["R1"]["generation"]
        old_digest = digest_dataset(st.subject("R1"))
        monkeypatch.setattr(store_mod.Store, "_remove_generation", lambda self, sid, gen: None)  # crash before removal
        st.write_subject(make_map_subject("R1", size=16, seed=9), overwrite=True)
        new = st.index_entries()["R1"]["generation"]
    monkeypatch.undo()
    shutil.rmtree(store / "subjects" / "R1" / new)  # the generation the index names goes missing
    code, out = run("validate", "--store", store)
    assert code == 1 and f"subjects/R1/{new} is missing" in out and "kept for repair to judge" in out
    with open_store(store, mode="r+") as st:
        assert not any("R1" in p for p in st.gc())  # gc alone does not delete the recovery candidate
    code, out = run("validate", "--store", store, "--repair")
    assert code == 1 and f"recover subject 'R1' from generation {old}" in out
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0, out
    with open_store(store) as st:
        assert st.index_entries()["R1"]["generation"] == old and digest_dataset(st.subject("R1")) == old_digest


def test_one_flipped_bit_moves_the_generation_to_the_quarantine(store, base):
    gen = generation_dir(store, "R2")
    chunk = gen / "albedo" / "c" / "0" / "0" / "0"
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0x10
    chunk.write_bytes(bytes(data))
    whole = snapshot(store)
    code, out = run("validate", "--store", store, "--repair")  # a dry run: the plan, nothing changed
    assert code == 1 and f"move subjects/R2/{gen.name} to the quarantine" in out and "dry run" in out
    assert snapshot(store) == whole
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0 and "store is valid" in out and "quarantine: 1 folder(s)" in out, out
    assert gen.name in quarantined_generations(store)  # moved, not deleted: the damaged bytes are still there
    assert next(store.glob(f"quarantine/*/subjects/R2/{gen.name}/albedo/c/0/0/0")).read_bytes() == bytes(data)
    assert subject_digests(store) == {k: v for k, v in base[1].items() if k != "R2"}
    code, out = run("validate", "--store", store, "--purge")
    assert code == 0 and "dry run" in out and quarantined_generations(store)
    code, out = run("validate", "--store", store, "--purge", "--yes")
    assert code == 0 and not quarantined_generations(store)
    code, out = run("validate", "--store", store)
    assert code == 0 and "quarantine" not in out


def _overwrite_without_removal(store, monkeypatch, times: int) -> list[str]:
    """Overwrite R1 ``times`` times, each crashing before the old version is removed; the generations, oldest first."""
    gens = []
    with open_store(store, mode="r+") as st:
        gens.append(st.index_entries()["R1"]["generation"])
        monkeypatch.setattr(store_mod.Store, "_remove_generation", lambda self, sid, gen: None)
        for k in range(times):
            st.write_subject(make_map_subject("R1", size=16, seed=9 + k), overwrite=True)
            gens.append(st.index_entries()["R1"]["generation"])
    monkeypatch.undo()
    return gens


def test_the_plan_lists_the_folder_of_a_subject_its_repair_leaves_empty(store, base):
    """The only generation of R1 damaged: the repair quarantines it and drops R1, and the garbage collection after it
    removes the emptied subjects/R1 folder.  The plan did not list that (it surveyed the store with the damaged
    generation still in place, an adoptable committed one under the new index); the docs audit found it."""
    gen = generation_dir(store, "R1")
    flip_albedo_bit(gen)
    code, out = run("validate", "--store", store, "--repair")
    assert code == 1 and "drop subject 'R1'" in out and "remove 1 leftover item(s): subjects/R1" in out, out
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0 and "removed 1 leftover item(s)" in out, out
    assert not (store / "subjects" / "R1").exists() and quarantined_generations(store) == {gen.name}


def test_a_damaged_earlier_generation_is_quarantined_not_deleted(store, base, monkeypatch):
    """The index names a missing generation and the only earlier one is damaged: the subject is dropped, and its
    damaged data go to the quarantine (the plan says so) instead of being collected as leftovers."""
    old, new = _overwrite_without_removal(store, monkeypatch, 1)
    shutil.rmtree(store / "subjects" / "R1" / new)
    damaged = flip_albedo_bit(store / "subjects" / "R1" / old)
    whole = snapshot(store)
    code, out = run("validate", "--store", store, "--repair")
    assert code == 1 and f"move subjects/R1/{old} to the quarantine: damaged" in out, out
    assert "drop subject 'R1'" in out and "remove 2 leftover item(s)" in out, out
    assert snapshot(store) == whole  # a dry run
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0 and "store is valid" in out and "removed 2 leftover item(s)" in out, out
    assert quarantined_generations(store) == {old}
    assert next(store.glob(f"quarantine/*/subjects/R1/{old}/albedo/c/0/0/0")).read_bytes() == damaged
    assert next(store.glob(f"quarantine/*/.records/R1~{old}.json")).is_file()
    assert subject_digests(store) == {k: v for k, v in base[1].items() if k != "R1"}


def test_recovery_past_a_damaged_middle_generation_quarantines_it(store, monkeypatch):
    with open_store(store) as st:
        oldest_digest = digest_dataset(st.subject("R1"))
    oldest, middle, newest = _overwrite_without_removal(store, monkeypatch, 2)
    shutil.rmtree(store / "subjects" / "R1" / newest)
    flip_albedo_bit(store / "subjects" / "R1" / middle)
    code, out = run("validate", "--store", store, "--repair")
    assert code == 1 and f"move subjects/R1/{middle} to the quarantine" in out, out
    assert f"recover subject 'R1' from generation {oldest}" in out, out
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0 and "store is valid" in out, out
    assert quarantined_generations(store) == {middle}
    with open_store(store) as st:
        assert st.index_entries()["R1"]["generation"] == oldest and digest_dataset(st.subject("R1")) == oldest_digest


def test_a_lost_index_of_an_empty_store_is_rebuilt(tmp_path):
    path = tmp_path / "e.zarr"
    open_store(path, mode="a").close()
    (path / "index.json").unlink()
    code, out = run("validate", "--store", path)
    assert code == 1 and "has no index.json" in out
    code, out = run("validate", "--store", path, "--repair")
    assert code == 1 and "write a new index.json" in out and "the new index is empty" in out, out
    assert not (path / "index.json").exists()
    code, out = run("validate", "--store", path, "--repair", "--yes")
    assert code == 0 and "store is valid" in out, out
    code, out = run("validate", "--store", path)
    assert code == 0 and "store is valid" in out, out


def test_a_lost_index_on_an_unmounted_volume_is_refused(store, base, tmp_path):
    (store / "index.json").unlink()
    shutil.move(store / "subjects", tmp_path / "away")
    (store / "subjects").mkdir()  # an empty mount point; .records/ still says what was committed
    whole = snapshot(store)
    for extra in ((), ("--yes",)):
        code, out = run("validate", "--store", store, "--repair", *extra)
        assert code == 2 and "refusing to repair" in out and "half-present" in out, out
        assert snapshot(store) == whole  # no subjects/zarr.json written onto the bare mount point
    (store / "subjects").rmdir()
    shutil.move(tmp_path / "away", store / "subjects")
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0 and subject_digests(store) == base[1], out


# -- 4. using corrupt data -----------------------------------------------------------------------
@pytest.mark.parametrize("damage", ["re-encoded", "flipped"])
def test_edits_never_use_corrupt_targets(store, tmp_path, damage):
    gen = generation_dir(store, "R2")
    if damage == "re-encoded":  # valid chunk, other values: only the checksum can tell
        arr = zarr.open_array(str(gen / "albedo"), mode="r+")
        arr[0, 0, 0] = np.float32(0.123)
        arr[8, 8, 1] = np.float32(0.456)
    else:
        chunk = gen / "albedo" / "c" / "0" / "0" / "0"
        data = bytearray(chunk.read_bytes())
        data[-9] ^= 0x01
        chunk.write_bytes(bytes(data))
    out_store = tmp_path / "edits.zarr"
    code, out = run(
        "edit",
        "colour",
        "R1",
        "--store",
        store,
        "--target",
        "R2",
        "--out-store",
        out_store,
        "--images",
        tmp_path / "img",
    )
    assert code == 2 and "subject 'R2'" in out and "'albedo'" in out, out
    assert not out_store.exists() and not (tmp_path / "img").exists()  # no side effect
    with open_store(store) as st:
        lazy = st.subject("R2", lazy=True)
        with pytest.raises(SchemaError, match="'R2'.*'albedo'"):
            lazy["albedo"].values  # every read path verifies, lazy ones when the chunk is loaded


# -- defects of the split: rebuild, re-checks, read errors ---------------------------------------------
def _die_before_commit(store, datasets):
    """Write ``datasets`` in a forked child killed before its commit: data on disk, never committed."""
    pid = os.fork()
    if pid == 0:
        try:
            store_mod.Store._commit = lambda self, mutate: os.kill(os.getpid(), 9)
            with open_store(store, mode="r+") as st:
                st.write_subjects(datasets, overwrite=True)
        finally:
            os._exit(0)
    os.waitpid(pid, 0)


def test_a_lost_index_is_rebuilt_from_committed_generations_only(store, base, monkeypatch):
    with open_store(store, mode="r+") as st:
        st.write_subject(make_map_subject("GONE", size=16, seed=5))
        monkeypatch.setattr(store_mod.Store, "_remove_generation", lambda self, sid, gen: None)
        st.delete_subject("GONE")  # deleted; its data stay on disk (crash before the removal)
        monkeypatch.undo()
        revision = st.revision
    _die_before_commit(store, [make_map_subject("R1", size=16, seed=7)])  # a crashed overwrite
    _die_before_commit(store, [make_map_subject("B1", size=16, seed=1), make_map_subject("B2", size=16, seed=2)])
    assert len(list((store / "subjects" / "R1").glob("g*"))) == 2 and (store / "subjects" / "B1").exists()
    (store / "index.json").unlink()
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0, out
    with open_store(store) as st:
        assert sorted(st.ids()) == sorted(base[1])  # no deleted subject, no crashed batch came back
        assert st.revision > revision  # the revision count continues
        assert subject_digests(store) == base[1]  # the committed R1, not the crashed overwrite


def test_repair_rechecks_under_the_lock(store):
    (store / "index.json").unlink()
    with open_store(store, mode="r+") as st:
        plan = st.plan_repair()
        assert plan.index_lost
        st.repair()  # another process repairs meanwhile
        revision = st.revision
        with pytest.raises(StoreError, match="changed while the repair was planned.*nothing was changed"):
            st.repair(plan)
        assert st.revision == revision


def test_checksum_checks_run_without_the_store_lock(store):
    gen = generation_dir(store, "R1")
    (gen / "ts_m" / "c" / "0" / "0").write_bytes(b"garbage")
    with open_store(store, mode="r+", lock_timeout=0.2) as st, FileLock(store / ".lock"):  # a writer commits
        plan = st.plan_repair()  # reads and checks everything without waiting for the lock
        assert any(a.kind == "quarantine-generation" for a in plan.actions)
        with pytest.raises(StoreError, match="timed out"):
            st.repair(plan)
    assert gen.exists()


def test_a_passing_read_error_changes_nothing(store, base, monkeypatch):
    from zarr.storage import _local

    real = _local._get
    target = str(generation_dir(store, "R1") / "albedo" / "c")

    def flaky(path, prototype, byte_range):
        if str(path).startswith(target):
            raise OSError(errno.EIO, "Input/output error", str(path))
        return real(path, prototype, byte_range)

    monkeypatch.setattr(_local, "_get", flaky)
    with open_store(store, mode="r+") as st:
        report = st.validate()
        assert not report.ok and "could not be read just now" in report.problems[0] and "'R1'" in report.problems[0]
        plan = st.plan_repair()
        assert not [a for a in plan.actions if a.subject == "R1"] and plan.problems
        st.repair(plan)
    monkeypatch.undo()
    assert subject_digests(store) == base[1]  # the subject was neither dropped nor moved


def test_a_subject_replaced_while_it_is_checked_is_checked_again(store):
    with open_store(store, mode="r+") as st, open_store(store, mode="r+") as other:
        index = json.loads((store / "index.json").read_text())
        calls = []

        def open_generation(sid, gen):
            if sid == "R1" and not calls:
                calls.append(gen)
                other.write_subject(make_map_subject("R1", size=16, seed=3), overwrite=True)  # replaced meanwhile
            return st._open_generation(sid, gen)

        report = ValidationReport(path=str(store))
        checked = check_subjects(index, open_generation, report, reread=lambda: st.index_entries())
        assert report.ok, report.problems
        assert checked.current["R1"] != calls[0]


def test_validate_reports_exactly_what_gc_removes(store):
    with open_store(store, mode="r+") as st:
        gen, lock = reserve_generation(str(store), "R1")  # a dead writer's generation
        (store / "subjects" / "R1" / gen).mkdir()
        lock.release()
        (store / "subjects" / "zarr.json.tmp-12-abcdef").write_text("{")  # interrupted root creation
        (store / "zarr.json.tmp-13-abcdef").write_text("{")
        (store / "index.json.tmp-14-deadbeef").write_text("{")
        (store / ".writers" / ".tmp-15-R2~g0000000000000009-1-cccccc.lock").write_text("")
        notes = st.validate().notes
        n = int(notes[0].split()[0])
        removed = st.gc()
        assert len(removed) == n == 7 and not st.validate().notes


def test_validate_counts_the_folder_of_a_new_subject_whose_write_was_interrupted(store):
    """An interrupted build: a new subject's generation, record and writer lock (a dead writer). ``validate`` said
    "3 leftover item(s)" where the repair plan removes 4, the subject folder they leave empty (a walkthrough)."""
    gen, lock = reserve_generation(str(store), "R9")
    (store / "subjects" / "R9" / gen).mkdir(parents=True)
    lock.release()
    code, out = run("validate", "--store", store, "--quiet")
    assert code == 0 and f"4 leftover item(s) of interrupted writes (e.g. .writers/R9~{gen}.lock)" in out, out
    code, out = run("validate", "--store", store, "--repair", "--quiet")
    assert "remove 4 leftover item(s): " in out and out.rstrip().endswith(", subjects/R9"), out
    code, out = run("validate", "--store", store, "--repair", "--yes", "--quiet")
    assert code == 0 and "removed 4 leftover item(s)" in out and "note:" not in out, out
    assert not (store / "subjects" / "R9").exists()


def _deny_writes_under(monkeypatch, root):
    """Make ``os.access`` say this process may not write under ``root`` (a store read-only to its user: root, which
    runs these tests, bypasses file permissions)."""
    real, root = os.access, os.fspath(root)

    def access(path, mode, **kw):
        inside = os.fspath(path) == root or os.fspath(path).startswith(root + os.sep)
        return False if inside and mode & os.W_OK else real(path, mode, **kw)

    monkeypatch.setattr(os, "access", access)


def _refuse_lock_files(monkeypatch):
    """Locking any lock file fails as opening one this user may not write does."""

    def denied(self, blocking=True):
        raise StoreError(f"cannot open lock file {self.path}: Permission denied")

    monkeypatch.setattr(FileLock, "acquire", denied)


def test_a_repair_with_nothing_to_do_takes_no_lock(store, monkeypatch):
    """``validate --repair --yes`` of a store this user may only read, with nothing to repair, said "store is valid"
    and then exited 2 with "Permission denied" on the store lock (a walkthrough): nothing to do, no lock."""
    _refuse_lock_files(monkeypatch)
    code, out = run("validate", "--store", store, "--repair", "--yes", "--quiet")
    assert code == 0 and "store is valid" in out and "Permission denied" not in out, out


def test_a_repair_this_user_may_not_write_fails_before_anything(store, monkeypatch):
    """Something to repair in a store read-only to this user: refused before the lock, naming the place, with no
    "store is valid" and nothing changed (with the lock file writable, the removals failed silently and the store
    was reported valid, leftovers and all)."""
    gen, lock = reserve_generation(str(store), "R9")
    (store / "subjects" / "R9" / gen).mkdir(parents=True)
    lock.release()
    whole = snapshot(store)
    _deny_writes_under(monkeypatch, store)
    code, out = run("validate", "--store", store, "--repair", "--quiet")  # the plan is shown: it writes nothing
    assert code == 0 and "remove 4 leftover item(s)" in out, out
    code, out = run("validate", "--store", store, "--repair", "--yes", "--quiet")
    assert code == 2 and "store is valid" not in out and "removed" not in out, out
    assert f"store {store} cannot be repaired by this user: no write permission on .lock and 4 other place(s)" in out
    assert "nothing was changed" in out and snapshot(store) == whole


def test_the_plan_says_it_writes_a_missing_subjects_group_file(store):
    """The repair writes a missing ``subjects/zarr.json``: its plan says so, and is not empty (a plan with nothing
    to do is not applied, so that one would have been skipped)."""
    (store / "subjects" / "zarr.json").unlink()
    code, out = run("validate", "--store", store, "--repair", "--quiet")
    assert "write the missing subjects/zarr.json" in out and "nothing to repair" not in out, out
    code, out = run("validate", "--store", store, "--repair", "--yes", "--quiet")
    assert code == 0 and "wrote the missing subjects/zarr.json" in out, out
    assert json.loads((store / "subjects" / "zarr.json").read_text())["node_type"] == "group"
    code, out = run("validate", "--store", store, "--repair", "--quiet")
    assert "nothing to repair" in out, out


def test_a_dead_writers_lock_is_tested_in_a_store_this_user_may_only_read(store, monkeypatch):
    """``validate`` of a store read-only to this user holding a dead writer's lock exited 2: the lock was opened for
    writing to test it. ``flock`` needs no write access: it is tested through a read-only descriptor."""
    from facestats.io.locking import is_locked

    gen, lock = reserve_generation(str(store), "R9")  # held: a live writer
    path = store / ".writers" / f"R9~{gen}.lock"
    _deny_writes_under(monkeypatch, store)
    _refuse_lock_files(monkeypatch)
    assert is_locked(path)
    lock.release()  # the writer died
    assert not is_locked(path)
    monkeypatch.undo()
    (store / "subjects" / "R9" / gen).mkdir(parents=True)
    _deny_writes_under(monkeypatch, store)
    _refuse_lock_files(monkeypatch)
    code, out = run("validate", "--store", store, "--quiet")
    assert code == 0 and "4 leftover item(s)" in out, out


def test_lock_checks_never_create_files(tmp_path):
    path = tmp_path / "nothing.lock"
    assert not is_locked(path) and not path.exists()


def test_a_generation_folder_that_cannot_be_made_is_an_error(store, monkeypatch):
    from facestats.io import generations

    def no_mkdir(path, *a, **k):
        raise FileNotFoundError(errno.ENOENT, "vanished", str(path))

    with open_store(store, mode="r+") as st:
        monkeypatch.setattr(generations.os, "mkdir", no_mkdir)
        with pytest.raises(StoreError, match="cannot create"):
            st.write_subject(make_map_subject("NEW", size=16))
    monkeypatch.undo()
    assert not (store / "subjects" / "NEW").exists() and not list((store / ".records").glob("NEW~*"))


def test_a_writer_that_times_out_leaves_no_empty_folders(store):
    with open_store(store, mode="r+", lock_timeout=0.2) as st, FileLock(store / ".lock"):
        with pytest.raises(StoreError, match="timed out"):
            st.write_subject(make_map_subject("LATE", size=16))
    assert not (store / "subjects" / "LATE").exists()
    assert not list((store / ".records").glob("LATE~*")) and not list((store / ".writers").glob("LATE~*"))


def test_a_creation_killed_while_writing_the_root_group_resumes(tmp_path):
    """SIGKILL between the temporary root ``zarr.json`` and its rename left only that file: a rerun creates the
    store (the leftover is the store's own) and gc collects it."""
    p = tmp_path / "s.zarr"
    p.mkdir()
    (p / "zarr.json.tmp-5046-771628").write_text("{")
    (p / "subjects").mkdir()
    with open_store(p, mode="a") as st:
        assert st.ids() == []
        st.gc()
        assert st.validate().ok
    assert not (p / "zarr.json.tmp-5046-771628").exists()
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "notes.txt").write_text("mine")
    with pytest.raises(StoreError, match="is not a facestats store"):
        open_store(tmp_path / "foreign", mode="a")
