"""``facestats edit`` of the installed console script, run in a subprocess.

Each test runs the console script end to end at least once; the refusals and repeats around it call
:func:`facestats.cli.main` in the test's process (:func:`tests.helpers.run_main`), which the console script runs.
"""

import numpy as np
import pytest
from matplotlib.image import imread

from facestats.edit import TextureStatistics
from facestats.io import open_store
from facestats.io.schema import provenance
from tests.helpers import make_map_subject, run_cli, run_main

SIZE = 24


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
    before = imread(tmp_path / "img" / f"{sid}_albedo_before.png")
    after = imread(tmp_path / "img" / f"{sid}_albedo_after.png")
    assert before.shape[:2] == (264, 264)  # 24 x 11 pixels
    inside = np.kron(face, np.ones((11, 11), bool))
    assert after[inside, :3].mean() < before[inside, :3].mean()  # darker skin in the after image
    # The same edit again: refused (the id exists; --overwrite would replace it).
    r2 = run_main("edit", "skin-type", "F3", "V", "--store", pop, "--images", tmp_path / "img")
    assert r2.returncode == 2 and f"subject {sid!r} already exists" in r2.stderr and "overwrite" in r2.stderr


def test_images_of_the_same_name_are_kept_without_overwrite_and_an_interruption_says_what_was_written(
    pop, tmp_path, monkeypatch, capsys
):
    """A red team: a user's X1_summary.png was replaced without --overwrite (refused now, before any work), and
    Ctrl-C while the images were saved said only "interrupted" though the subject was committed."""
    import shutil

    import facestats.edit.plots
    from facestats.cli import main

    store = tmp_path / "pop.zarr"
    shutil.copytree(pop, store)
    img = tmp_path / "img"
    img.mkdir()
    (img / "X1_summary.png").write_bytes(b"mine")
    args = ["edit", "skin-type", "F3", "V", "--store", str(store), "--images", str(img), "--id", "X1"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert f"--images folder {str(img)!r} already holds X1_summary.png: pass --overwrite" in err
    assert (img / "X1_summary.png").read_bytes() == b"mine"
    with open_store(store) as st:
        assert "X1" not in st  # refused before the edit

    def interrupted(edit, directory):
        raise KeyboardInterrupt

    monkeypatch.setattr(facestats.edit.plots, "save_edit_images", interrupted)
    assert main([*args[:-1], "X2"]) == 130
    err = capsys.readouterr().err
    assert f"interrupted: the edited subject 'X2' was written to store {store}, its images were not saved" in err
    with open_store(store) as st:
        assert "X2" in st


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
