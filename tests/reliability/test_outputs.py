"""``facestats.core.outputs.OutputSet``: several files replaced together or not at all."""

import os

import pytest

from facestats.core import outputs
from facestats.core.outputs import OutputSet
from facestats.errors import FacestatsError, ValidationError


def test_a_failed_rename_puts_every_target_back(tmp_path, monkeypatch):
    (tmp_path / "a.txt").write_text("old a")
    elsewhere = tmp_path / "other" / "deep"
    real_replace = os.replace

    def failing(src, dst):  # the second file cannot be placed (e.g. a full disk on its folder)
        if str(dst).endswith("b.txt"):
            raise OSError(28, "No space left on device", str(dst))
        return real_replace(src, dst)

    monkeypatch.setattr(outputs.os, "replace", failing)
    with pytest.raises(FacestatsError, match="No space left on device; nothing was written"):
        with OutputSet(tmp_path) as out:
            out.path("a.txt").write_text("new a")
            out.path(elsewhere / "b.txt").write_text("new b")
    assert (tmp_path / "a.txt").read_text() == "old a"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]  # no temporaries, backups or new folders


def test_a_failed_rename_leaves_no_backup_of_the_targets_not_yet_replaced(tmp_path, monkeypatch):
    """Each existing target is kept under a hard link before the renames; a target not yet replaced when one fails
    is still the old file, and renaming its link back onto it does nothing (POSIX rename of two names of one
    file), so the links stayed as hidden .old- files (``facestats edit --overwrite`` whose images could not be
    moved into place left nine)."""
    for name in "abc":
        (tmp_path / f"{name}.txt").write_text(f"old {name}")
    real_replace = os.replace

    def failing(src, dst):  # a is placed, b cannot be, c is not reached
        if str(dst).endswith("b.txt") and ".tmp-" in os.path.basename(src):
            raise OSError(13, "Permission denied", str(dst))
        return real_replace(src, dst)

    monkeypatch.setattr(outputs.os, "replace", failing)
    with pytest.raises(FacestatsError, match="Permission denied; nothing was written"):
        with OutputSet(tmp_path) as out:
            for name in "abc":
                out.path(f"{name}.txt").write_text(f"new {name}")
    assert {p.name: p.read_text() for p in tmp_path.iterdir()} == {"a.txt": "old a", "b.txt": "old b", "c.txt": "old c"}


def test_temporaries_are_unique_and_names_are_not_reused(tmp_path):
    (tmp_path / "link").symlink_to(tmp_path / "victim")
    with OutputSet(tmp_path) as out:
        p = out.path("x.txt")
        assert p.exists() and not p.is_symlink() and p.name.startswith(".x.txt.tmp-")
        p.write_text("x")
        with pytest.raises(ValidationError, match="named twice"):
            out.path("x.txt")
    assert (tmp_path / "x.txt").read_text() == "x" and not (tmp_path / "victim").exists()
    assert out.written == [tmp_path / "x.txt"]


def test_output_checks_write_to_know_a_folder_is_writable(tmp_path, monkeypatch):
    """os.access says "writable" to root in /proc and on some read-only mounts: an edit checked --images /proc/x,
    committed the edited subject, then failed to save its images (a fresh-user red team).  The checks now create
    and remove an empty folder where the output will go; a refusal names the argument, and nothing is left."""
    real_mkdtemp = outputs.tempfile.mkdtemp
    refused = tmp_path / "refuses"
    refused.mkdir()

    def mkdtemp(prefix="", dir=None):
        if os.fspath(dir) == os.fspath(refused):
            raise OSError(30, "Read-only file system")
        return real_mkdtemp(prefix=prefix, dir=dir)

    monkeypatch.setattr(outputs.tempfile, "mkdtemp", mkdtemp)
    assert os.access(refused, os.W_OK)  # what the checks relied on
    with pytest.raises(ValidationError, match=r"--images must be a path that can be created, got .*Read-only"):
        outputs.check_output_dir(refused / "images", "--images")
    with pytest.raises(ValidationError, match=r"--images must be a path that can be written in, got .*Read-only"):
        outputs.check_output_dir(refused, "--images")
    (refused / "plot.png").write_text("old")
    with pytest.raises(ValidationError, match=r"--plot must be a path that can be replaced, got .*Read-only"):
        outputs.check_output_file(refused / "plot.png", "--plot")
    with pytest.raises(ValidationError, match=r"--out must be a path that can be created"):
        outputs.check_output_file(refused / "new.exr", "--out")
    ok = tmp_path / "fine"
    assert outputs.check_output_dir(ok / "a" / "b", "--images") == ok / "a" / "b"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["refuses"] and sorted(os.listdir(refused)) == ["plot.png"]


def test_a_name_too_long_for_the_file_system_is_refused_by_the_check_and_leaves_no_folder(tmp_path):
    """``--images new/<300 bytes>`` passed check_output_dir (its probe creates one short name), the edit did its
    work, then OutputSet failed to make the folder ("File name too long") and left ``new`` behind.  The check now
    compares each name to create with the file system's NAME_MAX; OutputSet removes the folders it made before a
    failure of its own."""
    longest = os.pathconf(tmp_path, "PC_NAME_MAX")
    long = tmp_path / "new" / ("x" * (longest + 1))
    for check in (outputs.check_output_dir, outputs.check_output_file):
        with pytest.raises(ValidationError, match=rf"--images must be a path that can be created, got .*a name of "
                           rf"{longest + 1} bytes, xxxxxxxxxxxxxxxxxxxx…; the file system of {tmp_path} allows at "
                           rf"most {longest}\)"):  # fmt: skip
            check(long, "--images")
        with pytest.raises(ValidationError, match=f"a name of {longest + 1} bytes"):
            check(long / "a", "--images")  # a name further down
    assert outputs.check_output_dir(tmp_path / "new" / ("x" * longest), "--images").name == "x" * longest
    with pytest.raises(ValidationError, match="cannot create the output folder .*: File name too long"):
        with OutputSet(long):
            pass
    with pytest.raises(ValidationError, match="cannot create the output folder .*: File name too long"):
        with OutputSet(tmp_path / "ok") as out:
            out.path(tmp_path / "other" / ("y" * (longest + 1)) / "a.png")
    assert os.listdir(tmp_path) == []  # neither new/, nor ok/, nor other/


@pytest.mark.parametrize("links", [True, False])
@pytest.mark.parametrize("when", ["before the renames", "while renaming"])
def test_without_overwrite_a_file_that_appeared_is_kept_and_nothing_is_placed(tmp_path, monkeypatch, links, when):
    """OutputSet(overwrite=False) places each target by a hard link, which fails on an existing name; where links
    are not possible, by a rename after a check.  A file that appears before or during the renames is kept, the
    targets placed before it are removed, and the failure names it."""
    real_link, real_lexists = os.link, os.path.lexists

    def theirs(path):  # another process writes c.txt after the names were checked
        if os.path.basename(path) == "c.txt" and when == "while renaming" and not real_lexists(path):
            with open(path, "w") as fh:
                fh.write("theirs")

    def link(src, dst, **kwargs):
        theirs(dst)
        if not links:
            raise PermissionError(1, "Operation not permitted")
        return real_link(src, dst, **kwargs)

    def lexists(path):  # the check just before the rename, where links are not possible
        if not links and ".tmp-" not in os.fspath(path):
            theirs(path)
        return real_lexists(path)

    with OutputSet(tmp_path, overwrite=False) as out:
        out.path("a.txt").write_text("a")
    assert (tmp_path / "a.txt").read_text() == "a" and out.written == [tmp_path / "a.txt"]
    (tmp_path / "a.txt").unlink()
    monkeypatch.setattr(outputs.os, "link", link)
    with pytest.raises(FacestatsError, match=r"\(.*c\.txt\): File exists; nothing was written"):
        with OutputSet(tmp_path, overwrite=False) as out:
            for name in ("a.txt", "b.txt", "c.txt"):
                out.path(name).write_text(name)
            if when == "before the renames":
                (tmp_path / "c.txt").write_text("theirs")
            else:
                monkeypatch.setattr(outputs.os.path, "lexists", lexists)
    monkeypatch.undo()
    assert sorted(os.listdir(tmp_path)) == ["c.txt"] and (tmp_path / "c.txt").read_text() == "theirs"
