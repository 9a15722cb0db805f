"""The store defects a red team reproduced at f88ed10, each reproduced first, then the fixed behaviour asserted.

Data lost to a gc racing a repair, outputs and new stores written inside a store, store creation written
through a planted link, deletions reached through a link inside the store, a rebuilt index deleting an
intact generation, unchecked chunk checksums, malformed bookkeeping crashing maintenance, an unnamed
missing subject folder blocking commits, leftovers of failed commands, and four argument checks.
"""

import errno
import json
import os
import shutil

import numpy as np
import pytest
import scipy.io

from facestats.errors import FormatError, StoreError, ValidationError
from facestats.io import maintenance as maintenance_mod
from facestats.io import open_store
from facestats.io import store as store_mod
from facestats.io.ids import check_subject_id
from facestats.io.layout import confined, store_lock
from facestats.io.merl import import_merl, read_merl
from facestats.io.repair import apply_repair
from tests.helpers import make_map_subject, merl_dict

from .helpers import (
    flip_albedo_bit,
    generation_dir,
    quarantined_generations,
    run,
    snapshot,
    subject_digests,
)


@pytest.fixture(scope="module")
def mat(tmp_path_factory):
    path = tmp_path_factory.mktemp("merl") / "ts_data.mat"
    scipy.io.savemat(path, merl_dict())
    return path


def _record(store, sid, gen):
    return store / ".records" / f"{sid}~{gen}.json"


def _edit_json(path, change):
    doc = json.loads(path.read_text())
    doc = change(doc) or doc
    path.write_text(json.dumps(doc))


def _edit_manifest(gen_dir, change):
    """Replace the manifest in a generation's bookkeeping attribute by ``change(manifest)``."""
    meta = gen_dir / "zarr.json"
    doc = json.loads(meta.read_text())
    attr = json.loads(doc["attributes"]["facestats_store"])
    attr["manifest"] = change(attr["manifest"])
    doc["attributes"]["facestats_store"] = json.dumps(attr)
    meta.write_text(json.dumps(doc))


def _albedo(**fields):
    """A manifest change: the albedo entry with ``fields`` set (None: the field removed)."""

    def change(m):
        entry = {k: v for k, v in m["albedo"].items() if fields.get(k, 0) is not None}
        entry.update({k: v for k, v in fields.items() if v is not None})
        return {**m, "albedo": entry}

    return change


def _flip_first_chunk_crc(m):
    crcs = list(m["albedo"]["chunk_crc32"])
    crcs[0] = (crcs[0] + 1) % 2**32
    return _albedo(chunk_crc32=crcs)(m)


def _overwrite_keeping_old(store, monkeypatch, sid="R1"):
    """Overwrite ``sid`` crashing before the old version is removed; ``(old, new)`` generations."""
    with open_store(store, mode="r+") as st:
        old = st.index_entries()[sid]["generation"]
        monkeypatch.setattr(store_mod.Store, "_remove_generation", lambda self, s, g: None)
        st.write_subject(make_map_subject(sid, size=16, seed=9), overwrite=True)
        new = st.index_entries()[sid]["generation"]
    monkeypatch.undo()
    return old, new


# -- 1. gc racing a repair ------------------------------------------------------------------------------
def test_gc_never_deletes_a_generation_a_concurrent_repair_recovers(store, monkeypatch):
    """gc decided under the lock and deleted after it: a repair committed in between (recovering R1 from the
    retired generation gc had doomed) and was left naming deleted data.  Doomed generations are now renamed
    aside under the lock, so the repair finds the source gone and skips that step."""
    old, new = _overwrite_keeping_old(store, monkeypatch)
    flip_albedo_bit(store / "subjects" / "R1" / new)
    with open_store(store, mode="r+") as st:
        plan = st.plan_repair()
        assert any(a.kind == "recover" and a.source == old for a in plan.actions), plan.to_text()
        original, done = maintenance_mod._remove, []

        def repair_in_between(root, *args):  # runs once gc has released the store lock
            done.extend(apply_repair(root, plan, label="race", lock=store_lock(root, 5), root_attrs=st.root_attrs)[0])
            return original(root, *args)

        monkeypatch.setattr(maintenance_mod, "_remove", repair_in_between)
        st.gc()
        monkeypatch.undo()
        named = st.index_entries()["R1"]["generation"]
    assert done
    assert named != old or (store / "subjects" / "R1" / old).is_dir(), "the index names a generation gc deleted"
    assert any(d.startswith("skipped (the store changed meanwhile): recover subject 'R1'") for d in done), done


# -- 2. outputs and new stores inside a store -------------------------------------------------------------
def test_outputs_inside_the_store_are_refused_before_any_work(store, tmp_path, mat):
    whole = snapshot(store)
    gen = generation_dir(store, "R1").relative_to(store)
    cases = [
        ("render", "R1", "--store", store, "--out", store / "renders"),
        ("relight", "R1", "--store", store, "--probe", tmp_path / "p.hdr", "--out", store / "r.exr"),
        (
            "relight",
            "R1",
            "--store",
            store,
            "--probe",
            tmp_path / "p.hdr",
            "--out",
            tmp_path / "r.exr",
            "--png",
            store / "subjects" / "r.png",
        ),  # fmt: skip
        ("edit", "stats", "R1", "--store", store, "--out", store / "stats.npz"),
        ("import-merl", mat, "--store", store / gen / "new.zarr"),
    ]
    for argv in cases:
        code, out = run(*argv)
        assert code == 2 and ("must lie outside the store" in out or "lies inside the store" in out), (argv, out)
    assert snapshot(store) == whole


def test_edit_images_inside_the_output_store_are_refused(store, tmp_path):
    out_store = tmp_path / "edits.zarr"
    open_store(out_store, mode="a").close()
    whole = snapshot(out_store)
    code, out = run(
        "edit", "colour", "R1", "--target", "R2", "--store", store,
        "--out-store", out_store, "--images", out_store / "subjects",
    )  # fmt: skip
    assert code == 2 and "--images must lie outside the output store" in out, out
    assert snapshot(out_store) == whole


def test_a_new_store_inside_a_store_is_refused(store, mat):
    inner = generation_dir(store, "R1") / "new.zarr"
    whole = snapshot(store)
    with pytest.raises(StoreError, match="lies inside the store"):
        open_store(inner, mode="a")
    with pytest.raises(StoreError, match="lies inside the store"):
        import_merl(mat, store / "quarantine" / "q.zarr")
    assert snapshot(store) == whole


def test_pack_store_never_writes_inside_its_store(store):
    from facestats.io.packing import pack_store

    index = (store / "index.json").read_bytes()
    with pytest.raises(ValidationError, match="zip_path must lie outside the source store"):
        pack_store(store, store / "index.json", overwrite=True)
    assert (store / "index.json").read_bytes() == index


def test_files_put_inside_a_generation_are_reported_and_never_deleted(store, monkeypatch):
    old, new = _overwrite_keeping_old(store, monkeypatch)
    (store / "subjects" / "R1" / old / "notes.txt").write_text("mine")
    (store / "subjects" / "R1" / new / "albedo" / "c" / "extra.bin").write_bytes(b"x")
    code, out = run("validate", "--store", store)
    assert code == 0 and "2 item(s) inside generation folders were not written by facestats" in out, out
    with open_store(store, mode="r+") as st:
        st.gc()
        st.write_subject(make_map_subject("R1", size=16, seed=11), overwrite=True)  # supersedes `new`
    assert (store / "subjects" / "R1" / old / "notes.txt").read_text() == "mine"
    assert (store / "subjects" / "R1" / new / "albedo" / "c" / "extra.bin").is_file()


# -- 3. store creation through a planted link ----------------------------------------------------------------
def test_store_creation_never_writes_through_a_planted_link(tmp_path, mat):
    (tmp_path / "out2").mkdir()
    (tmp_path / "new2.zarr").mkdir()
    (tmp_path / "new2.zarr" / "subjects").symlink_to("../out2")
    code, out = run("import-merl", mat, "--store", tmp_path / "new2.zarr")
    assert code == 2 and "symbolic link" in out, out
    assert os.listdir(tmp_path / "out2") == []
    assert os.listdir(tmp_path / "new2.zarr") == ["subjects"]


# -- 4. deleting through a link inside the store ------------------------------------------------------------
def test_a_link_to_another_subject_never_leads_repair_or_gc_to_its_data(store, base):
    gen = generation_dir(store, "R2").name
    (store / "subjects" / "X").symlink_to("R2")  # subjects/X -> R2, inside the store
    rec = {"facestats_generation": 1, "subject": "X", "generation": gen, "state": "writing"}
    _record(store, "X", gen).write_text(json.dumps(rec))  # a stale record makes R2's generation "X's leftover"
    code, out = run("validate", "--store", store, "--repair", "--yes")
    with open_store(store, mode="r+") as st:
        st.gc()
    assert (store / "subjects" / "R2" / gen).is_dir() and subject_digests(store) == base[1]
    assert code == 0 and "not created by facestats were left alone (e.g. subjects/X)" in out, out
    with pytest.raises(StoreError, match="symbolic link"):
        confined(store, store / "subjects" / "X" / gen)


# -- 5. a lost index and a committed generation whose record lags --------------------------------------------
def test_rebuilding_a_lost_index_quarantines_an_intact_generation_marked_writing(store, base):
    gen = generation_dir(store, "R1").name
    record = json.loads(_record(store, "R1", gen).read_text())  # as the crash between the index's replacement
    record = {k: v for k, v in record.items() if "revision" not in k}  # and the record's update leaves it
    _record(store, "R1", gen).write_text(json.dumps({**record, "state": "writing"}))
    (store / "index.json").unlink()
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0 and f"move subjects/R1/{gen} to the quarantine" in out, out
    assert gen in quarantined_generations(store)
    assert subject_digests(store) == {k: v for k, v in base[1].items() if k != "R1"}


# -- 6. chunk checksums ----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "change, field",
    [
        (_flip_first_chunk_crc, "chunk_crc32[0]"),
        (_albedo(chunk_crc32=["a"]), "chunk_crc32"),
        (_albedo(chunk_crc32=[]), "chunk_crc32"),
        (_albedo(chunk_rows=0), "chunk_rows"),
    ],
)
def test_validate_checks_the_chunk_checksums(store, change, field):
    gen = generation_dir(store, "R1")
    _edit_manifest(gen, change)
    code, out = run("validate", "--store", store)
    assert code == 1 and "subject 'R1'" in out and field in out, out
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0 and gen.name in quarantined_generations(store), out


# -- 7. malformed bookkeeping -------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "change, words",
    [
        (lambda m: {**m, "albedo": "x"}, ("variable 'albedo'", "must be an object")),
        (_albedo(dims=None), ("variable 'albedo'", "field 'dims'")),
        (_albedo(crc32=None), ("variable 'albedo'", "field 'crc32'")),
        (_albedo(crc32="x"), ("variable 'albedo'", "field 'crc32'")),
        (lambda m: list(m), ("must be an object of variables",)),
        (lambda m: None, ("must be an object of variables, got None",)),
    ],
)
def test_a_malformed_manifest_is_damage_and_quarantined(store, change, words):
    gen = generation_dir(store, "R1")
    _edit_manifest(gen, change)
    code, out = run("validate", "--store", store)
    assert code == 1 and f"subjects/R1/{gen.name}/zarr.json" in out and all(w in out for w in words), out
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0 and gen.name in quarantined_generations(store), out


@pytest.mark.parametrize("value", ["abc", None, -1, 1.5])
def test_a_malformed_record_is_damage_named_and_repaired(store, monkeypatch, value):
    old, new = _overwrite_keeping_old(store, monkeypatch)
    for gen in (old, new):  # the retired generation's record and the one the index names
        _edit_json(_record(store, "R1", gen), lambda r: r.__setitem__("committed_revision", value))
    for argv in (("validate",), ("validate", "--purge", "--yes"), ("query",)):
        code, out = run(*argv, "--store", store)
        assert code in (0, 1), (argv, out)
    code, out = run("validate", "--store", store)
    assert code == 1 and f".records/R1~{new}.json is malformed: field 'committed_revision'" in out, out
    with open_store(store, mode="r+") as st:
        st.gc()  # no crash, nothing of R1 removed
    assert (store / "subjects" / "R1" / old).is_dir()
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0 and "store is valid" in out, out
    assert old in quarantined_generations(store) and (store / "subjects" / "R1" / new).is_dir()


@pytest.mark.parametrize(
    "items, words",
    [(["x"], "items[0] must be an object"), ([{"path": "subjects/Q"}], "field 'why' of items[0]"), (None, "'items'")],
)
def test_a_malformed_quarantine_manifest_is_damage_and_never_purged(store, items, words):
    folder = store / "quarantine" / "20260101T000000Z-abcdef"
    folder.mkdir(parents=True)
    (folder / "data.bin").write_bytes(b"kept")
    (folder / "QUARANTINE.json").write_text(json.dumps({"format": 1, "reason": "r", "items": items}))
    code, out = run("validate", "--store", store)
    assert code == 1 and "QUARANTINE.json" in out and words in out, out
    for argv in (("validate", "--purge"), ("validate", "--purge", "--yes")):
        code, out = run(*argv, "--store", store)
        assert code == 0 and words in out, (argv, out)
    assert (folder / "data.bin").read_bytes() == b"kept"


def test_an_index_count_out_of_range_is_refused_naming_it(store):
    index = json.loads((store / "index.json").read_text())
    row = index["subjects"]["RM"]["row"]
    key = next(k for k, v in row.items() if isinstance(v, int) and k not in ("age", "skin_type"))
    row[key] = 10**30
    (store / "index.json").write_text(json.dumps(index))
    for argv in (("query",), ("info",)):
        code, out = run(*argv, "--store", store)
        assert code == 2 and repr(key) in out and "RM" in out, (argv, out)
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0 and "store is valid" in out, out


# -- 8. a missing subject folder blocks commits: named ------------------------------------------------------
def test_a_missing_subject_folder_names_the_subject_and_the_repair(store):
    shutil.rmtree(store / "subjects" / "R1")
    with open_store(store, mode="r+") as st:
        with pytest.raises(StoreError, match=r"subject 'R1' \(subjects/R1\) is missing.*validate --repair"):
            st.write_subject(make_map_subject("NEW", size=16))
    assert not (store / "subjects" / "NEW").exists()


# -- 9. failed commands leave nothing behind ---------------------------------------------------------------
def _enospc(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")


@pytest.mark.parametrize("where", ["write_record", "create_locked"])
def test_a_full_disk_while_reserving_leaves_no_subject_folder(store, monkeypatch, where):
    from facestats.io import generations

    whole = snapshot(store)
    monkeypatch.setattr(generations, where, _enospc)
    with open_store(store, mode="r+") as st:
        with pytest.raises(StoreError, match="No space left"):
            st.write_subject(make_map_subject("NEW", size=16))
    assert snapshot(store) == whole


def test_a_failed_import_into_an_empty_folder_leaves_it_empty(tmp_path, mat, monkeypatch):
    (tmp_path / "empty.zarr").mkdir()
    monkeypatch.setattr(store_mod.Store, "write_subjects", lambda self, *a, **k: _enospc())
    with pytest.raises(OSError):
        import_merl(mat, tmp_path / "empty.zarr")
    assert os.listdir(tmp_path / "empty.zarr") == []


def test_a_store_creation_that_fails_leaves_nothing(tmp_path, monkeypatch):
    from facestats.io import root

    monkeypatch.setattr(root, "write_index_file", _enospc)
    with pytest.raises(StoreError, match="No space left"):
        open_store(tmp_path / "a" / "new.zarr", mode="a")
    assert os.listdir(tmp_path) == []
    (tmp_path / "empty.zarr").mkdir()
    with pytest.raises(StoreError, match="No space left"):
        open_store(tmp_path / "empty.zarr", mode="a")
    assert os.listdir(tmp_path / "empty.zarr") == []


# -- 10. argument checks ------------------------------------------------------------------------------------
def test_reserved_names_are_not_subject_ids(store):
    for bad in ("zarr.json", "zarr.json.tmp-1-abcdef"):
        with pytest.raises(ValidationError, match="subject_id must not be 'zarr.json'"):
            check_subject_id(bad)
    with open_store(store, mode="r+") as st:
        with pytest.raises(ValidationError, match="zarr.json"):
            st.write_subject(make_map_subject("zarr.json", size=16))
    assert check_subject_id("zarr.json2") == "zarr.json2"


@pytest.mark.parametrize("value", [float("nan"), "abc", -5, True, float("inf"), None])
def test_lock_timeout_is_checked(store, value):
    with pytest.raises(ValidationError, match="lock_timeout must be a number of seconds"):
        open_store(store, mode="r+", lock_timeout=value)


def test_variables_must_be_a_list_of_names(store):
    with open_store(store) as st:
        with pytest.raises(ValidationError, match="variables must be a list of variable names, got the string"):
            st.subject("R1", lazy=True, variables="albedo")
        with pytest.raises(ValidationError, match="variables must be a list"):
            st.subject("R1", lazy=True, variables=[1])
        ds = st.subject("R1", lazy=True, variables=("albedo",))
        assert np.isfinite(ds["albedo"].values).any()


def test_a_logical_merl_key_is_refused_naming_it(tmp_path):
    d = merl_dict()
    d["ts_subjec"] = d["ts_subjec"] > 0
    scipy.io.savemat(tmp_path / "b.mat", d)
    with pytest.raises(FormatError, match="ts_subjec must be numeric, got logical"):
        read_merl(tmp_path / "b.mat")
