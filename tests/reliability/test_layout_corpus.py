"""Malformed stores: every file and folder of the layout replaced by garbage, a folder, a link out, a FIFO, or missing.

For each of the 14 items × 5 damages (70 stores), the commands that read a store (``info``, ``query``,
``validate``) and the one that changes it (``validate --repair --yes``) run in this process and must:
exit 0, 1 or 2 (3 is the CLI's "unexpected exception"; an exception escaping is a traceback), name
the damaged item when they fail, leave the sentinel tree beside the store untouched, and lose no
intact data (the subjects the damage does not touch read back equal; a damaged generation is either
in place or in the quarantine, never deleted).
"""

import os
import shutil

import pytest

from .helpers import copy_store, make_store, run, snapshot, subject_digests

KINDS = ("garbage", "folder", "link-out", "fifo", "missing")


def _items(store):
    gen = next(p.name for p in (store / "subjects" / "R1").iterdir() if p.name.startswith("g"))
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
}


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    path = make_store(tmp_path_factory.mktemp("corpus") / "s.zarr")
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
    for argv in (("info",), ("query",), ("validate",), ("validate", "--repair", "--yes")):
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
