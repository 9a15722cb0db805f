"""Malformed stores: every file and folder of the layout replaced by garbage, a folder, a link out, a FIFO, or missing.

The store holds a quarantine (a damaged subject ``Q1`` moved aside by a repair when the store is made),
so the quarantine's folder, a repair's folder in it, its ``QUARANTINE.json`` and a quarantined
generation are items too.  For each of the 18 items × 5 damages (90 stores), the commands that read
a store (``info``, ``query``, ``validate``) and those that change it (``validate --repair --yes``; for
the quarantine's items also ``validate --purge --yes``) run in this process and must:
exit 0, 1 or 2 (3 is the CLI's "unexpected exception"; an exception escaping is a traceback), name
the damaged item when they fail, leave the sentinel tree beside the store untouched, and lose no
intact data (the subjects the damage does not touch read back equal; a damaged generation is either
in place or in the quarantine, never deleted).
"""

import os
import shutil

import pytest

from facestats.io import open_store
from tests.helpers import make_map_subject

from .helpers import copy_store, flip_albedo_bit, generation_dir, make_store, run, snapshot, subject_digests

KINDS = ("garbage", "folder", "link-out", "fifo", "missing")


def _items(store):
    gen = next(p.name for p in (store / "subjects" / "R1").iterdir() if p.name.startswith("g"))
    folder = next((store / "quarantine").iterdir()).name
    qgen = next((store / "quarantine" / folder / "subjects" / "Q1").iterdir()).name
    return {
        "zarr.json": "zarr.json",
        "index.json": "index.json",
        ".lock": ".lock",
        ".writers": ".writers",
        ".records": ".records",
        "subjects": "subjects",
        "subjects/zarr.json": "subjects/zarr.json",
        "subject folder": "subjects/R1",
        "subject group": "subjects/R1/zarr.json",
        "generation": f"subjects/R1/{gen}",
        "generation group": f"subjects/R1/{gen}/zarr.json",
        "array metadata": f"subjects/R1/{gen}/albedo/zarr.json",
        "chunk": f"subjects/R1/{gen}/albedo/c/0/0/0",
        "record": f".records/R1~{gen}.json",
        "quarantine": "quarantine",
        "quarantine folder": f"quarantine/{folder}",
        "quarantine manifest": f"quarantine/{folder}/QUARANTINE.json",
        "quarantined generation": f"quarantine/{folder}/subjects/Q1/{qgen}",
    }


#: What a failing command must name for each item (any of these words).
NAMES = {
    "zarr.json": ("zarr.json",),
    "index.json": ("index.json",),
    ".lock": (".lock",),
    ".writers": (".writers",),
    ".records": (".records", "record"),
    "subjects": ("subjects",),
    "subjects/zarr.json": ("subjects/zarr.json",),
    "subject folder": ("R1",),
    "subject group": ("R1",),
    "generation": ("R1",),
    "generation group": ("R1",),
    "array metadata": ("R1",),
    "chunk": ("R1",),
    "record": ("R1", "record"),
    "quarantine": ("quarantine",),
    "quarantine folder": ("quarantine",),
    "quarantine manifest": ("quarantine", "QUARANTINE.json"),
    "quarantined generation": ("quarantine", "Q1"),
}


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    path = make_store(tmp_path_factory.mktemp("corpus") / "s.zarr")
    with open_store(path, mode="r+") as st:  # a quarantine: Q1 damaged, moved aside by a repair
        st.write_subject(make_map_subject("Q1", size=16, seed=7))
        flip_albedo_bit(generation_dir(path, "Q1"))
        st.repair()
    return path, subject_digests(path)


def damage(store, rel, kind, sentinel):
    path = store / rel
    was_dir = path.is_dir()
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif os.path.lexists(path):
        path.unlink()
    if kind == "garbage":
        path.write_bytes(b"\x00\xffnot what it should be\x13\x37" * 3)
    elif kind == "folder":
        path.mkdir()
        (path / "stray").write_text("x")
    elif kind == "link-out":
        path.symlink_to(sentinel / ("g0000000000000001-1-aaaaaa" if was_dir else "index.json"))
    elif kind == "fifo":
        os.mkfifo(path)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("item", list(NAMES))
def test_damaged_layout(base, tmp_path, item, kind):
    store = copy_store(base[0], tmp_path)
    sentinel = tmp_path / "sentinel"
    rel = _items(store)[item]
    untouched = {sid: snapshot(store / "subjects" / sid) for sid in ("R2", "RM")}
    damage(store, rel, kind, sentinel)
    before = snapshot(sentinel)
    commands = [("info",), ("query",), ("validate",), ("validate", "--repair", "--yes")]
    if item.startswith("quarantine"):
        commands += [("validate", "--purge"), ("validate", "--purge", "--yes")]
    for argv in commands:
        code, out = run(*argv, "--store", store)
        assert code in (0, 1, 2), (argv, code, out)
        if code != 0:
            assert any(name in out for name in NAMES[item]), (argv, out)
        assert snapshot(sentinel) == before, argv
    if item != "subjects":
        for sid, snap in untouched.items():  # the other subjects' data are where they were, unchanged
            assert snapshot(store / "subjects" / sid) == snap, sid
    digests = subject_digests(store)
    assert all(digests[s] == base[1][s] for s in digests), "a subject reads back different data"
    if item in ("generation", "generation group", "array metadata", "chunk") and kind != "missing":
        gen = rel.split("/")[2]
        assert (store / "subjects" / "R1" / gen).exists() or list(store.glob(f"quarantine/*/subjects/R1/{gen}"))
