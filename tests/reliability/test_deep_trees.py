"""Folder trees nested deeper than Python's recursion limit inside a store (hostile input).

Python 3.11's ``os.walk``, ``shutil.rmtree``, ``shutil.copytree`` and ``Path.rglob`` recurse once per folder
level. A tree of about 1,100 nested folders planted in a generation or a chunk tree made ``facestats validate``
exit 3 ("a bug in facestats") with a RecursionError, and a gc or a purge could not remove such a tree.
Every walk of a store now goes through :func:`facestats.io.layout.walk`, which keeps its own stack.
"""

import errno
import os
import pathlib
import subprocess
import sys

import pytest

from facestats.io import open_store
from facestats.io.layout import HELD_LEVELS, copy_tree, remove_tree, walk
from tests.helpers import run_cli

from .helpers import generation_dir, subject_digests

#: Nested folders: beyond the recursion limit (1,000), and a path still under Linux's PATH_MAX (4,096).
DEPTH = 1300
assert DEPTH > sys.getrecursionlimit()


def _nest(top, name="d", depth=DEPTH):
    """``top/name/name/...`` ``depth`` folders deep (made relative to each folder: no long path is needed);
    the deepest folder's path."""
    top = os.fspath(top)
    fd = os.open(top, os.O_RDONLY | os.O_DIRECTORY)
    try:
        for _ in range(depth):
            os.mkdir(name, dir_fd=fd)
            sub = os.open(name, os.O_RDONLY | os.O_DIRECTORY, dir_fd=fd)
            os.close(fd)
            fd = sub
    finally:
        os.close(fd)
    return os.path.join(top, *[name] * depth)


@pytest.fixture(autouse=True)
def _cleaned(tmp_path):
    """Remove each test's folder with ``rm -rf``: pytest's own clean-up recurses and would fail on these trees."""
    yield
    subprocess.run(["rm", "-rf", str(tmp_path)], check=True)


def test_walk_is_os_walk_without_recursion(tmp_path):
    (tmp_path / "a" / "b").mkdir(parents=True)
    (tmp_path / "a" / "f").write_text("x")
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "g").write_text("y")
    (tmp_path / "link").symlink_to(tmp_path / "a")  # listed with the folders, not followed
    want = [(b, sorted(d), sorted(f)) for b, d, f in os.walk(tmp_path)]
    got = [(b, sorted(d), sorted(f)) for b, d, f in walk(tmp_path)]
    assert sorted(got) == sorted(want)
    deepest = _nest(tmp_path / "c")
    assert sum(1 for _ in walk(tmp_path)) == len(want) + DEPTH
    assert any(base == deepest for base, _, _ in walk(tmp_path))
    with pytest.raises(RecursionError):  # what the standard library does here (Python 3.11)
        list(os.walk(tmp_path))


def test_pruned_folders_are_not_entered(tmp_path):
    _nest(tmp_path, "skip", 3)
    (tmp_path / "keep").mkdir()
    seen = []
    for base, dirs, _ in walk(tmp_path):
        seen.append(os.path.relpath(base, tmp_path))
        dirs[:] = [d for d in dirs if d != "skip"]
    assert sorted(seen) == [".", "keep"]


def test_remove_and_copy_a_deep_tree_keep_links_as_links(tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "keep").write_text("never removed")
    top = tmp_path / "top"
    top.mkdir()
    deepest = _nest(top)
    os.symlink(outside, os.path.join(deepest, "link"))
    with open(os.path.join(deepest, "f"), "w") as fh:
        fh.write("deep")
    copy_tree(top, tmp_path / "copy")
    copied = os.path.join(tmp_path / "copy", os.path.relpath(deepest, top))
    assert open(os.path.join(copied, "f")).read() == "deep"
    assert os.readlink(os.path.join(copied, "link")) == os.fspath(outside)
    remove_tree(top)
    remove_tree(tmp_path / "copy")
    assert not top.exists() and not (tmp_path / "copy").exists()
    assert (outside / "keep").read_text() == "never removed"
    os.symlink(outside, tmp_path / "to-outside")
    for link in (tmp_path / "to-outside", f"{tmp_path / 'to-outside'}/", f"{tmp_path / 'to-outside'}/."):
        with pytest.raises(OSError):
            remove_tree(link)
    assert (outside / "keep").exists()
    with pytest.raises(NotADirectoryError):
        remove_tree(outside / "keep")
    remove_tree(tmp_path / "missing")  # nothing to do


def _open_fds() -> int:
    return len(os.listdir("/proc/self/fd")) if os.path.isdir("/proc/self/fd") else 0


@pytest.mark.parametrize("held", [True, False], ids=["held-levels", "below-held-levels"])
def test_a_folder_moved_out_mid_removal_never_leads_the_walk_out_of_the_tree(tmp_path, monkeypatch, held):
    """A folder moved out of the tree while it is emptied. Left through its ``..``, the walk would land in the
    folder it was moved to and go on there with the old parent's pending names: it emptied a sibling-named
    folder outside the tree (the race earlier notes left alone). Within HELD_LEVELS the walk returns to the
    parent's open handle and finishes the tree; deeper, each ``..`` is checked against the folder the walk came
    down from and the removal stops (ESTALE). The move is made as the walk opens ``inner`` in the moved folder
    (``os.open`` wrapped), so the race is hit every time; no file descriptor is left open either way
    (the deep case raises with HELD_LEVELS handles open)."""
    top = tmp_path / "top"
    top.mkdir()
    parent = pathlib.Path(_nest(top, "d", 0 if held else HELD_LEVELS + 2)) / "a"  # the moved folder's parent
    for name in ("b", "x"):
        (parent / name / "inner").mkdir(parents=True)
        (parent / name / "inner" / "file").write_text("in the tree")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    opened, real_open = [], os.open

    def racing_open(path, flags, mode=0o777, *, dir_fd=None):
        if path == "inner" and not any(o.startswith("moved:") for o in opened):
            current = opened[-1]  # the folder the walk is in: move it out, and plant its sibling's name there
            os.rename(parent / current, elsewhere / current)
            sibling = ({"b", "x"} - {current}).pop()
            (elsewhere / sibling).mkdir()
            (elsewhere / sibling / "keep").write_text("not in the tree")
            opened.append("moved:" + current)
        elif path != "..":
            opened.append(os.path.basename(os.fspath(path)))
        return real_open(path, flags, mode, dir_fd=dir_fd)

    fds = _open_fds()
    monkeypatch.setattr(os, "open", racing_open)
    if held:
        remove_tree(top)
    else:
        with pytest.raises(OSError, match="moved out of it") as err:
            remove_tree(top)
    monkeypatch.undo()
    assert _open_fds() == fds
    moved = next(o for o in opened if o.startswith("moved:")).removeprefix("moved:")
    sibling = ({"b", "x"} - {moved}).pop()
    assert (elsewhere / sibling / "keep").read_text() == "not in the tree"  # outside the tree: left alone
    assert os.listdir(elsewhere / moved) == []  # the moved folder was emptied (its handle was open)
    if held:
        assert not top.exists()  # the walk went back to the parent's handle and finished the tree
    else:
        assert err.value.errno == errno.ESTALE and (parent / sibling / "inner" / "file").exists()  # it stopped
        remove_tree(top)  # and a second run removes the rest
        assert not top.exists()


def test_a_tree_longer_than_path_max_is_removed_and_its_quarantine_purged(tmp_path):
    """20 levels of 250-character names: paths of 5,000 characters, beyond Linux's PATH_MAX (4,096). The tree
    is removed through folder handles; a path-based removal left it, after the purge had already unlinked the
    quarantine's manifest, so the quarantine could never be purged (a red team)."""
    from facestats.io.quarantine import list_quarantine, open_quarantine, purge_quarantine

    root = tmp_path / "s.zarr"
    root.mkdir()
    folder = os.path.join(open_quarantine(root, "test"), "subjects", "R1", "g")
    os.makedirs(folder)
    _nest(folder, "d" * 250, 20)
    assert [e["valid"] for e in list_quarantine(root)] == [True]
    assert len(purge_quarantine(root)) == 1
    assert list_quarantine(root) == [] and os.listdir(root / "quarantine") == []
    top = tmp_path / "top"
    top.mkdir()
    _nest(top, "e" * 250, 20)
    remove_tree(top)
    assert not top.exists()


@pytest.mark.parametrize(
    "where, name, depth",
    [("generation", "d", DEPTH), ("chunks", "d", DEPTH), ("subject", "d", DEPTH), ("root", "d", DEPTH)]
    + [("generation", "d" * 250, 20)],  # paths beyond PATH_MAX: the subject was reported unreadable (a red team)
)
def test_validate_and_repair_report_a_deep_tree_and_leave_it(store, base, where, name, depth):
    gen = generation_dir(store, "R1")
    top = {"generation": gen, "chunks": gen / "albedo" / "c", "subject": gen.parent, "root": store}[where]
    deepest = _nest(top, name, depth)
    report = open_store(store).validate()
    assert report.ok, report.problems
    assert any("d" in note for note in report.notes)
    with open_store(store, mode="r+") as st:
        assert st.repair().ok
    assert os.path.isdir(deepest if len(deepest) < 4000 else os.path.join(top, name))  # left alone
    assert subject_digests(store) == base[1]


def test_the_command_line_names_the_deep_tree_instead_of_failing(store):
    gen = generation_dir(store, "R1")
    _nest(gen)
    r = run_cli("validate", "--store", store, "--quiet")
    assert r.returncode == 0, r.stderr
    assert "RecursionError" not in r.stderr
    assert f"{os.path.relpath(gen, store)}/d/d" in r.stdout and "store is valid" in r.stdout


def test_a_superseded_generation_with_a_deep_chunk_tree_is_removed(store, base):
    old = generation_dir(store, "R1")
    _nest(old / "albedo" / "c", "77")  # folders named like chunk indices: Zarr's own kind of tree
    with open_store(store, mode="r+") as st:
        st.write_subject(st.subject("R1"), overwrite=True)  # a new generation supersedes ``old``
        st.gc()
    assert not old.exists()
    assert generation_dir(store, "R1") != old and subject_digests(store) == base[1]
