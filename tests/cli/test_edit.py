"""``facestats edit`` of the installed console script, run in a subprocess.

Each test runs the console script end to end at least once; the refusals and repeats around it call
:func:`facestats.cli.main` in the test's process (:func:`tests.helpers.run_main`), which the console script runs.
"""

import errno
import os
import pathlib
import shutil

import numpy as np
import pytest
from matplotlib.image import imread

from facestats.edit import TextureStatistics
from facestats.io import open_store
from facestats.io.schema import provenance
from tests.helpers import make_map_subject, run_cli, run_main

SIZE = 24
#: The maps a skin-type edit draws before and after (albedo and the four BRDF maps).
MAPS = ("albedo", "ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent")
WHEN = ("before", "after")


@pytest.fixture(scope="module")
def pop(tmp_path_factory):
    """A small directory store: a type III face, two type V faces, a lotion record."""
    path = tmp_path_factory.mktemp("cli_edit") / "pop.zarr"
    with open_store(path, mode="a") as st:
        st.write_subjects(
            [
                make_map_subject("F3", size=SIZE, skin_type=3, seed=1),
                make_map_subject("F5a", size=SIZE, skin_type=5, seed=2, rho_shift=0.06),
                make_map_subject("F5b", size=SIZE, skin_type=5, seed=3, rho_shift=0.07),
                make_map_subject(
                    "F3-lotion", size=SIZE, skin_type=3, seed=4, condition="lotion", rho_shift=0.1, person_id="F3"
                ),
            ]
        )
    return path


def _new_id(stdout):
    return stdout.splitlines()[0].strip()


def test_skin_type_writes_a_new_subject_and_images(pop, tmp_path):
    r = run_cli("edit", "skin-type", "F3", "V", "--store", pop, "--images", tmp_path / "img")
    assert r.returncode == 0, r.stderr
    sid = _new_id(r.stdout)
    assert sid.startswith("F3.skin-V-") and f"wrote subject {sid} to store {pop}" in r.stdout
    assert "target: 2 subject(s): F5a, F5b" in r.stdout
    with open_store(pop) as st:
        new, src = st.subject(sid), st.subject("F3")
        p = provenance(new)
    assert new.attrs["skin_type"] == 5
    assert p["source_subject"] == "F3" and p["edit"]["name"] == "change_skin_type"
    assert p["edit"]["parameters"]["skin_type"] == 5 and p["edit"]["target"]["subjects"] == ["F5a", "F5b"]
    face = src["region"].values > 0
    assert np.all(new["albedo"].values[face].mean(0) < 0.9 * src["albedo"].values[face].mean(0))
    for name in ("albedo_before", "albedo_after", "ts_rho_s_before", "ts_rho_s_after", "bp_exponent_after", "summary"):
        f = tmp_path / "img" / f"{sid}_{name}.png"
        assert f.is_file() and f.name in r.stdout
    # each map's PNG has no colour bar: its scale is printed beside its name and held in its text chunks
    from PIL import Image

    for var in MAPS[1:]:
        for when in WHEN:
            name = f"{sid}_{var}_{when}.png"
            text = Image.open(tmp_path / "img" / name).text
            lo, hi = float(text["facestats:vmin"]), float(text["facestats:vmax"])
            assert f"  {name}: viridis from {lo:.4g} (dark purple) to {hi:.4g} (yellow), dimensionless\n" in r.stdout
    assert f"  {sid}_albedo_before.png: linear 0 (black) to 1 (white) per channel, sRGB-encoded" in r.stdout
    assert f"  {sid}_summary.png: before, after and difference of each map, with colour bars" in r.stdout
    before = imread(tmp_path / "img" / f"{sid}_albedo_before.png")
    after = imread(tmp_path / "img" / f"{sid}_albedo_after.png")
    assert before.shape[:2] == (264, 264)  # 24 x 11 pixels
    inside = np.kron(face, np.ones((11, 11), bool))
    assert after[inside, :3].mean() < before[inside, :3].mean()  # darker skin in the after image
    # The same edit again: refused (the id exists; --overwrite would replace it).
    r2 = run_main("edit", "skin-type", "F3", "V", "--store", pop, "--images", tmp_path / "img")
    assert r2.returncode == 2 and f"subject {sid!r} already exists" in r2.stderr and "overwrite" in r2.stderr


def _tree(path):
    """``{relative path: bytes}`` of every file under ``path`` (folders as None): what a failed command must leave."""
    return {
        str(p.relative_to(path)): None if p.is_dir() else p.read_bytes() for p in sorted(pathlib.Path(path).rglob("*"))
    }


@pytest.fixture
def own(pop, tmp_path):
    """A copy of the population store the test may write into, and a folder of the user's holding one PNG."""
    store = tmp_path / "pop.zarr"
    shutil.copytree(pop, store)
    img = tmp_path / "img"
    img.mkdir()
    (img / "mine.png").write_bytes(b"mine")
    return store, img


def _skin_type(store, img, *more):
    return ["edit", "skin-type", "F3", "V", "--store", str(store), "--images", str(img), *map(str, more)]


def test_images_of_the_same_name_are_kept_without_overwrite(own, capsys):
    """A red team: a user's X1_summary.png was replaced without --overwrite (refused now, before any work)."""
    from facestats.cli import main

    store, img = own
    (img / "X1_summary.png").write_bytes(b"mine")
    assert main(_skin_type(store, img, "--id", "X1")) == 2
    err = capsys.readouterr().err
    assert f"--images folder {str(img)!r} already holds X1_summary.png: pass --overwrite" in err
    assert (img / "X1_summary.png").read_bytes() == b"mine"
    with open_store(store) as st:
        assert "X1" not in st  # refused before the edit


def test_images_of_the_default_id_are_kept_without_overwrite(own, capsys):
    """The default id (``<subject>.<edit>-<digest>``) is known only after the edit: its images are checked then,
    before anything is written (a helper found them replaced without --overwrite when the subject was not stored)."""
    from facestats.cli import main

    store, img = own
    assert main(_skin_type(store, img, "--out-store", img.parent / "a.zarr")) == 0
    sid = next(p.name[: -len("_summary.png")] for p in img.glob("*_summary.png"))
    (img / f"{sid}_summary.png").write_bytes(b"mine")
    before = _tree(img.parent / "pop.zarr")
    assert main(_skin_type(store, img, "--out-store", img.parent / "b.zarr")) == 2  # another store: id is free
    err = capsys.readouterr().err
    assert f"already holds {sid}_albedo_before.png and 10 more of this edit's images: pass --overwrite" in err, err
    assert (img / f"{sid}_summary.png").read_bytes() == b"mine"
    assert not (img.parent / "b.zarr").exists() and _tree(img.parent / "pop.zarr") == before
    assert main(_skin_type(store, img, "--out-store", img.parent / "b.zarr", "--overwrite")) == 0
    assert (img / f"{sid}_summary.png").read_bytes() != b"mine"


def test_images_that_cannot_be_saved_leave_no_subject_and_the_folders_as_they_were(own, tmp_path, monkeypatch):
    """The images are saved (under temporary names) before the subject is committed: a full disk while saving
    them used to fail the command after the subject was written; now nothing is written, in the store, in the
    --images folder, or as a folder the command made (an --out-store, an --images path)."""
    import matplotlib.image

    store, img = own
    real, calls = matplotlib.image.imsave, []

    def full_disk(path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 3:  # two images written, the third finds the disk full
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real(path, *args, **kwargs)

    monkeypatch.setattr(matplotlib.image, "imsave", full_disk)
    before, folder = _tree(store), _tree(img)
    r = run_main(*_skin_type(store, img, "--id", "X2"))
    assert r.returncode == 2 and len(calls) == 3
    assert f"cannot write the output files in {img} ({calls[2]}): No space left on device; nothing was" in r.stderr
    assert "X2" not in r.stdout and "written to store" not in r.stderr
    assert _tree(store) == before and _tree(img) == folder  # no subject X2, no image, no temporary
    calls.clear()
    new = tmp_path / "new"
    r = run_main(*_skin_type(store, new / "a" / "img", "--id", "X2", "--out-store", new / "out.zarr"))
    assert r.returncode == 2 and "No space left on device" in r.stderr
    assert not new.exists() and _tree(store) == before  # the store and the folders it made are gone


@pytest.mark.parametrize("failure", ["interrupted", "id taken", "OSError"])
def test_a_commit_that_fails_leaves_no_images(own, tmp_path, monkeypatch, failure):
    """The subject is committed after its images are staged and before they are renamed into place: a commit that
    fails (Ctrl-C, another writer taking the id, an OSError) removes them, and a folder made for them."""
    from facestats.io.store import Store

    store, img = own
    real, written = Store.write_subject, []

    def write_subject(self, ds, **kwargs):
        written.append(len([p for p in images.iterdir() if ".tmp-" in p.name]))  # staged under temporary names
        if failure == "interrupted":
            raise KeyboardInterrupt
        if failure == "OSError":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(self, make_map_subject("X3", size=SIZE, seed=9))  # another writer, between the edit and its commit
        return real(self, ds, **kwargs)

    monkeypatch.setattr(Store, "write_subject", write_subject)
    before, folder = _tree(store), _tree(img)
    for images in (img, tmp_path / "new"):
        r = run_main(*_skin_type(store, images, "--id", "X3"))
        assert written[-1] == 11, written  # albedo and 4 BRDF maps before and after, the summary
        if failure == "interrupted":
            assert r.returncode == 130 and r.stderr.strip() == "facestats: interrupted"
        elif failure == "OSError":
            assert r.returncode == 2
            assert f"cannot write subject 'X3' to store {store}: No space left on device; nothing was" in r.stderr
        else:
            assert r.returncode == 2 and "['X3'] already exist in the store" in r.stderr
        assert _tree(img) == folder and not (tmp_path / "new").exists()
        if failure == "id taken":
            with open_store(store) as st:
                assert provenance(st.subject("X3"))["source"] == "tests.helpers"  # the other writer's subject
            with open_store(store, mode="r+") as st:
                st.delete_subject("X3")
        else:
            assert _tree(store) == before


def test_an_interrupt_after_the_store_committed_says_the_subject_was_written(own, monkeypatch):
    """A Ctrl-C inside write_subject after its commit landed (a red team's window): the subject is in the store,
    so the message says so and how to make the images (exit 130), as for an interrupt while renaming them; it
    said only "interrupted", and a rerun then found the id taken."""
    from facestats.io.store import Store

    store, img = own
    real = Store.write_subject

    def write_subject(self, ds, **kwargs):
        real(self, ds, **kwargs)
        raise KeyboardInterrupt  # after the commit, before write_subject returns

    monkeypatch.setattr(Store, "write_subject", write_subject)
    folder = _tree(img)
    r = run_main(*_skin_type(store, img, "--id", "X5"))
    assert r.returncode == 130
    assert r.stderr.startswith(f"facestats: interrupted: the edited subject 'X5' was written to store {store}, ")
    assert _tree(img) == folder  # the images were not moved in: the message says how to make them
    with open_store(store) as st:
        assert "X5" in st
    monkeypatch.setattr(Store, "write_subject", real)
    r = run_main(*_skin_type(store, img, "--id", "X5", "--overwrite"))  # what the message says to run
    assert r.returncode == 0, r.stderr
    assert (img / "X5_summary.png").is_file()


def test_an_id_taken_by_another_writer_during_the_commit_is_not_reported_as_written(own, monkeypatch):
    """Another writer commits the same --id while this edit writes (a red team's race): the store refuses this
    write (the id exists), and the new generation in the index is the other writer's.  It was taken as this
    edit's (committed True): the message said the subject was written and advised --overwrite, which would have
    replaced the other writer's subject."""
    from facestats.io.store import Store

    store, img = own
    real = Store.write_subject
    with open_store(store) as st:
        theirs = st.subject("F5a")
    theirs.attrs["subject_id"] = "X7"

    def write_subject(self, ds, **kwargs):
        with open_store(store, mode="a") as other:  # the other writer commits first
            real(other, theirs)
        return real(self, ds, **kwargs)

    monkeypatch.setattr(Store, "write_subject", write_subject)
    folder = _tree(img)
    r = run_main(*_skin_type(store, img, "--id", "X7"))
    assert r.returncode == 2
    assert "already exist" in r.stderr and "was written" not in r.stderr
    assert _tree(img) == folder
    with open_store(store) as st:
        assert provenance(st.subject("X7")) == provenance(theirs)


def test_images_that_cannot_be_moved_after_the_commit_are_put_back_and_the_message_says_what_is_where(own, monkeypatch):
    """Once the subject is committed, the staged images are renamed into place (os.replace); if a rename fails or
    is interrupted, the images folder is put back as it was (a user's files of the same names, replaced with
    --overwrite, come back byte for byte) and the message says the subject was written and how to make the
    images.  Without a fault, the same command writes both, and no temporary is left."""
    import facestats.core.outputs as outputs

    store, img = own
    r = run_main(*_skin_type(store, img, "--id", "X4"))  # the normal path: the subject and its 11 images
    assert r.returncode == 0, r.stderr
    names = sorted(p.name for p in img.iterdir())
    assert names == sorted(["mine.png", "X4_summary.png", *[f"X4_{m}_{w}.png" for m in MAPS for w in WHEN]])
    with open_store(store) as st:
        generation = st.index_entries()["X4"]["generation"]
    for name in names:  # the user's files now, to be replaced by --overwrite
        (img / name).write_bytes(name.encode())
    folder = _tree(img)
    real, renames = os.replace, []

    def replace(src, dst, fault=None):
        if os.path.dirname(dst) == str(img) and ".tmp-" in os.path.basename(src):  # a staged image
            renames.append(dst)
            if len(renames) == 3:  # two images in place, the third cannot be
                raise fault
        return real(src, dst)

    for fault, code, message in (
        (OSError(errno.EACCES, os.strerror(errno.EACCES)), 2, "facestats: error: the edited subject 'X4' was written"),
        (KeyboardInterrupt(), 130, "facestats: interrupted: the edited subject 'X4' was written"),
    ):
        renames.clear()
        monkeypatch.setattr(outputs.os, "replace", lambda s, d, f=fault: replace(s, d, f))
        r = run_main(*_skin_type(store, img, "--id", "X4", "--overwrite"))
        monkeypatch.setattr(outputs.os, "replace", real)
        assert r.returncode == code and len(renames) == 3
        assert r.stderr.startswith(f"{message} to store {store}, ")
        assert (
            f"moved into {img}, which is as it was" in r.stderr
            and "rerun the same command with --overwrite" in r.stderr
        )
        if code == 2:
            assert "Permission denied; nothing was written" in r.stderr
        assert _tree(img) == folder  # the user's files back, byte for byte; no temporary, no backup left
        with open_store(store) as st:  # the new subject is committed, as the message says
            assert st.index_entries()["X4"]["generation"] != generation
            generation = st.index_entries()["X4"]["generation"]
    r = run_main(*_skin_type(store, img, "--id", "X4", "--overwrite"))
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in img.iterdir()) == names
    for name in names:
        assert ((img / name).read_bytes() == name.encode()) == (name == "mine.png"), name


def test_brdf_lotion_half_way_from_the_default_store(tmp_path):
    out = tmp_path / "edits.zarr"
    r = run_cli(
        "edit",
        "brdf",
        "S008",
        "--condition",
        "lotion",
        "--t",
        "0.5",
        "--out-store",
        out,
        "--id",
        "S008-half-lotion",
        "--images",
        tmp_path,
    )
    assert r.returncode == 0, r.stderr
    assert _new_id(r.stdout) == "S008-half-lotion" and "target: 1 subject(s): S008-lotion" in r.stdout
    with open_store(out) as st:
        new = st.subject("S008-half-lotion")
    p = provenance(new)
    assert p["source_store"] == "default" and p["source_subject"] == "S008"
    assert p["edit"]["parameters"]["t"] == 0.5 and p["edit"]["target"]["query"] == {"condition": "lotion"}
    with open_store(None) as default:
        src, lot = default.subject("S008"), default.subject("S008-lotion")
    reg = src["region"].values
    sel = reg == 2
    b = src["ts_rho_s"].values[sel].mean()
    tgt = lot["ts_rho_s"].values[sel & (lot["ts_flag"].values == 0)].mean()
    assert abs(new["ts_rho_s"].values[sel].mean() - 0.5 * (b + tgt)) < 0.05 * abs(tgt - b)
    np.testing.assert_array_equal(new["albedo"].values, src["albedo"].values)
    assert (tmp_path / "S008-half-lotion_ts_m_before.png").is_file()


def test_texture_with_regions_and_saved_stats(pop, tmp_path):
    r = run_cli("edit", "stats", "F5a", "--store", pop, "--regions", "cheeks", "--out", tmp_path / "f5a")
    assert r.returncode == 0, r.stderr
    stats = TextureStatistics.load(tmp_path / "f5a.npz")
    assert stats.levels == 2 and stats.bins == 256 and str(tmp_path / "f5a.npz") in r.stdout
    before = (tmp_path / "f5a.npz").read_bytes()
    again = ("edit", "stats", "F3", "--store", pop, "--out", tmp_path / "f5a")
    r = run_main(*again)  # another subject's statistics over the file: refused without --overwrite
    assert r.returncode == 2 and "f5a.npz' exists (pass --overwrite to replace it)" in r.stderr
    assert (tmp_path / "f5a.npz").read_bytes() == before
    assert run_main(*again, "--overwrite").returncode == 0 and (tmp_path / "f5a.npz").read_bytes() != before
    r = run_main(
        "edit", "stats", "F5a", "--store", pop, "--regions", "cheeks", "--out", tmp_path / "f5a", "--overwrite"
    )
    assert r.returncode == 0 and (tmp_path / "f5a.npz").read_bytes() == before
    out = tmp_path / "out.zarr"
    common = ("--store", pop, "--out-store", out, "--images", tmp_path / "img", "--iterations", "2", "--seed", "5")
    r1 = run_cli("edit", "texture", "F3", "--target", "F5a", "--regions", "forehead", "6", "7", "--id", "T1", *common)
    r3 = run_main("edit", "texture", "F3", "--stats", tmp_path / "f5a.npz", "--regions", "7", "--id", "T3", *common)
    for r in (r1, r3):
        assert r.returncode == 0, r.stderr
    assert "histogram distance to the target" in r1.stdout
    # statistics fix the bins: another --bins was ignored (the summary said bins=256); now refused, nothing written
    r = run_main("edit", "texture", "F3", "--stats", tmp_path / "f5a.npz", "--bins", "16", "--id", "T4", *common)
    assert r.returncode == 2 and "--bins must be the target statistics' 256 (they fix the pyramid" in r.stderr
    with open_store(out) as st, open_store(pop) as src_store:
        src = src_store.subject("F3")
        t1, t3 = st.subject("T1"), st.subject("T3")
    reg = src["region"].values
    out1, out3 = ~np.isin(reg, [2, 6, 7]), reg != 7
    np.testing.assert_array_equal(t1["albedo"].values[out1], src["albedo"].values[out1])
    np.testing.assert_array_equal(t3["albedo"].values[out3], src["albedo"].values[out3])
    with open_store(out) as st:
        assert "T4" not in st.ids()
    p1, p3 = provenance(t1)["edit"], provenance(t3)["edit"]
    assert p1["target"] == {"subject": "F5a"} and p1["parameters"]["regions"] == [2, 6, 7]
    assert p3["target"]["file"] == str(tmp_path / "f5a.npz")
    assert (tmp_path / "img" / "T3_albedo_after.png").is_file()


def test_errors_exit_2_with_clear_messages(pop, tmp_path):
    r = run_cli("edit", "skin-type", "F3", "V", "--store", pop, "--out-store", tmp_path / "e.zip")
    assert r.returncode == 2 and "--out-store must name a directory store (e.g. edits.zarr; a zip store" in r.stderr
    r = run_main("edit", "skin-type", "S008", "V", "--images", tmp_path)
    assert r.returncode == 2 and "embedded default store is read-only: pass --out-store PATH" in r.stderr
    r = run_main("edit", "brdf", "F3", "--store", pop, "--images", tmp_path)
    assert r.returncode == 2 and "give exactly one target" in r.stderr
    r = run_main("edit", "brdf", "F3", "--target", "F5a", "--condition", "lotion", "--store", pop)
    assert r.returncode == 2 and "give exactly one target" in r.stderr
    r = run_main("edit", "brdf", "F3", "--target", "nobody", "--store", pop, "--images", tmp_path)
    assert r.returncode == 2 and "target 'nobody' is not a subject of store" in r.stderr
    r = run_main("edit", "skin-type", "F3", "VII", "--store", pop, "--images", tmp_path)
    assert r.returncode == 2 and "facestats: error: TYPE must be I-VI or 1-6, got 'VII'" in r.stderr  # positional
    for option, value, message in (("--skin-type", "VII", "--skin-type must be I-VI or 1-6, got 'VII'"),
                                   ("--gender", "X", "--gender must be M or F (or 0 = M, 1 = F), got 'X'"),
                                   ("--age", "300", "--age must satisfy 0 <= MIN <= MAX <= 200, got '300'"),
                                   ("--condition", "wet", "--condition must be one of ['normal', ")):  # fmt: skip
        subset = () if option in ("--skin-type", "--condition") else ("--skin-type", "V")
        r = run_main("edit", "brdf", "F3", *subset, option, value, "--store", pop, "--images", tmp_path)
        assert r.returncode == 2 and f"facestats: error: {message}" in r.stderr, (option, r.stderr)
    for argv in (("brdf", "F3", "--target", "F5a", "--images", tmp_path), ("stats", "F3", "--out", tmp_path / "s")):
        r = run_main("edit", *argv, "--regions", "ear", "--store", pop)
        assert r.returncode == 2 and "facestats: error: --regions must be 1-10 or one of [" in r.stderr, r.stderr
        assert "got 'ear'" in r.stderr
    for option, value, message in (("--out", "", "--out must be a file system path, got ''"),  # was `path`
                                   ("--levels", "9", "--levels must be at most "),
                                   ("--bins", "1", "--bins must be an integer in [2, 65536], got 1")):  # fmt: skip
        out = () if option == "--out" else ("--out", tmp_path / "s.npz")
        r = run_main("edit", "stats", "F3", *out, option, value, "--store", pop)
        assert r.returncode == 2 and f"facestats: error: {message}" in r.stderr, (option, r.stderr)
        assert option != "--levels" or "got 9" in r.stderr
    assert not (tmp_path / "s.npz").exists()
    r = run_main("edit", "brdf", "F3", "--skin-type", "V", "--t", "2", "--store", pop, "--images", tmp_path)
    assert r.returncode == 2 and "facestats: error: --t must lie in [0, 1], got 2.0" in r.stderr  # the option's name
    for option, value, message in (("--id", "../x", "--id must be 1-64 characters"),
                                   ("--seed", "-1", "--seed must be an integer in [0, inf], got -1"),
                                   ("--feather", "-3", "--feather must lie in [0, inf] pixels, got -3.0")):  # fmt: skip
        command = "colour" if option == "--feather" else "skin-type"
        target = ["--skin-type", "V"] if command == "colour" else ["V"]
        r = run_main("edit", command, "F3", *target, option, value, "--store", pop, "--images", tmp_path)
        assert r.returncode == 2 and f"facestats: error: {message}" in r.stderr, (option, r.stderr)
    r = run_main("edit")
    assert r.returncode == 2 and "skin-type" in r.stdout
    r = run_main("edit", "skin-type", "F3", "V", "--store", pop, "--images", pop)  # images into the store
    assert r.returncode == 2 and "--images must lie outside the source store" in r.stderr
    r = run_main("edit", "skin-type", "F3", "V", "--store", pop, "--out-store", pop / "subjects" / "n.zarr")
    assert r.returncode == 2 and "--out-store must lie outside the source store" in r.stderr
    assert not (pop / "subjects" / "n.zarr").exists()
    with open_store(pop) as st:  # failed edits wrote nothing
        assert not [s for s in st.ids() if s.startswith("F3.brdf")]


def test_the_papers_seven_levels_from_a_fresh_install_with_the_texture_sample(tmp_path):
    env = {"FACESTATS_CACHE_DIR": str(tmp_path / "cache")}
    common = ("--out-store", tmp_path / "out.zarr", "--images", tmp_path / "img", "--seed", "1")
    r = run_main("edit", "texture", "S001", "--target", "S030", "--levels", "7", *common, env=env)
    assert r.returncode == 2 and "levels must be at most 3" in r.stderr and "--store texture-sample" in r.stderr
    assert not (tmp_path / "cache").exists()  # the default store's error builds nothing
    args = ("edit", "texture", "S001", "--target", "S030", "--levels", "7", "--store", "texture-sample", "--id", "T7")
    r = run_cli(*args, *common, env=env)
    assert r.returncode == 0, r.stderr
    assert "building the texture sample" in r.stderr and "levels=7" in r.stdout
    assert "of the distance above it removed" in r.stdout and "no measurable change" not in r.stdout
    with open_store(tmp_path / "out.zarr") as st:
        ds = st.subject("T7")
        assert ds["albedo"].shape == (512, 512, 3) and provenance(ds)["edit"]["parameters"]["levels"] == 7
    r = run_main("query", "--store", "texture-sample", "--skin-type", "VI", env=env)  # reused: built once
    assert r.returncode == 0 and "building" not in r.stderr and "matching subjects: 1" in r.stdout, r.stdout + r.stderr


@pytest.mark.parametrize(
    "command",
    [
        ("edit", "colour", "S001", "--target", "S006", "--out-store", "{name}"),
        ("build", "--store", "{name}", "--subjects", "S001"),
        ("import-merl", "ts_data.mat", "--store", "{name}"),
    ],
)
@pytest.mark.parametrize("name", ["default", "texture-sample"])
def test_a_store_to_write_may_not_be_named_as_an_embedded_store(tmp_path, command, name):
    """Every --store reads 'default' and 'texture-sample' as the embedded stores, so a folder written under such a
    name seemed to vanish (a fresh-user red team: `edit colour ... --out-store default` wrote ./default, which
    `info --store default` never showed).  Refused before any work; ./default is the spelling for such a folder."""
    r = run_cli(*[a.format(name=name) for a in command], cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert f"must name a directory store to write, got '{name}'" in r.stderr and f"pass ./{name}" in r.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "action, option",
    [("brdf", "--target"), ("brdf", "--skin-type"), ("brdf", "--condition"), ("brdf", "--gender"), ("brdf", "--age"),
     ("colour", "--target"), ("colour", "--stats"), ("texture", "--target"), ("texture", "--stats")],
)  # fmt: skip
def test_an_empty_target_or_filter_is_refused_by_name(pop, tmp_path, action, option):
    """``--target ''`` and the other target options given '' were taken for "not given" ("give exactly one target",
    or with another filter the subset unfiltered: ``--skin-type IV --gender ''`` edited a subject from every gender,
    a red team): argparse refuses them, naming the option, before a store is opened or created."""
    before = _tree(pop)
    subset = ("--skin-type", "V") if option in ("--gender", "--age") else ()
    r = run_main("edit", action, "F3", *subset, option, "", "--store", pop, "--out-store", tmp_path / "e.zarr",
                 "--images", tmp_path / "img", cwd=tmp_path)  # fmt: skip
    assert r.returncode == 2 and f"argument {option}: must not be empty, got ''" in r.stderr, r.stderr
    assert list(tmp_path.iterdir()) == [] and _tree(pop) == before  # no output store, no images, the input as it was


def test_a_folder_of_an_images_name_is_refused_before_the_commit(own, capsys):
    """With --overwrite, a folder named like one of the images (X5_summary.png/) let the edit commit the subject,
    then the rename onto the folder failed ("Is a directory"), and the advised rerun with --overwrite failed the
    same way.  OutputSet refuses a target that is a folder as it is staged: the command fails before the commit."""
    from facestats.cli import main

    store, img = own
    (img / "X5_summary.png").mkdir()
    before, folder = _tree(store), _tree(img)
    assert main(_skin_type(store, img, "--id", "X5", "--overwrite")) == 2
    err = capsys.readouterr().err
    assert f"facestats: error: output {str(img / 'X5_summary.png')!r} is a folder: move it away" in err, err
    assert "was written" not in err
    assert _tree(store) == before and _tree(img) == folder  # no subject X5, no image, no temporary


def test_an_image_that_appears_during_the_edit_is_kept_without_overwrite(own, monkeypatch):
    """Two edits of the same --id into one --images folder (another store each): both found the names free,
    and the second renamed its PNGs over the first's without --overwrite.  Without it, the images are now placed
    only where no file is: a file that appeared meanwhile is kept, none of this edit's images is placed, and the
    message says the subject was written."""
    from facestats.io.store import Store

    store, img = own
    real = Store.write_subject

    def write_subject(self, ds, **kwargs):  # another process writes its image while this edit commits
        (img / "X6_summary.png").write_bytes(b"theirs")
        return real(self, ds, **kwargs)

    monkeypatch.setattr(Store, "write_subject", write_subject)
    r = run_main(*_skin_type(store, img, "--id", "X6"))
    assert r.returncode == 2, r.stderr
    assert f"the edited subject 'X6' was written to store {store}, but its images could not be moved" in r.stderr
    assert "File exists" in r.stderr and "X6_summary.png" in r.stderr, r.stderr
    assert sorted(p.name for p in img.iterdir()) == ["X6_summary.png", "mine.png"]  # no image of ours, no temporary
    assert (img / "X6_summary.png").read_bytes() == b"theirs"
    with open_store(store) as st:
        assert "X6" in st


def test_a_texture_transfer_on_the_default_stores_small_regions_is_not_reported_as_a_change(tmp_path):
    """The README's example until 2026-12-08, which a look-dev artist followed: forehead, nose and cheeks of the
    48² default store hold 134, 56 and 312 texels, fewer than (or barely above) the 256 coefficients a 256-bin band
    histogram needs, so its distance moved 0.708 -> 0.703 inside its sampling noise and the nose came out blotchy.
    The transfer now warns, naming the regions, their texels, the map and what helps, and the report says that
    nothing measurable changed."""
    from facestats.errors import FacestatsWarning

    assert run_main("edit", "stats", "S007", "--out", tmp_path / "s007.npz").returncode == 0
    args = ("edit", "texture", "S058", "--stats", tmp_path / "s007.npz", "--regions", "2", "6", "7", "--seed", "1",
            "--out-store", tmp_path / "e.zarr", "--images", tmp_path / "img")  # fmt: skip
    with pytest.warns(FacestatsWarning) as record:
        r = run_main(*args)
    assert r.returncode == 0, r.stderr
    text = " ".join(str(w.message) for w in record)
    for part in ("region 2 (134 texels of the 48 x 48 map)", "region 6 (56 texels of the 48 x 48 map)",
                 "than their 256 bins", "Even the finest bands of region(s) 2, 6 hold fewer",
                 "--store texture-sample"):  # fmt: skip
        assert part in text, part
    line = next(x for x in r.stdout.splitlines() if x.startswith("histogram distance to the target"))
    assert "0.708 at the start, 0.703 after 5 iteration(s); sampling floor 0." in line
    assert "no measurable change" in line
