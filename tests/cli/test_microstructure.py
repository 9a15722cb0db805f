"""``facestats microstructure render``: a mesh file that is missing or not .obj/.ply is named by its option."""

from tests.helpers import run_main

OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"


def test_a_bad_mesh_file_is_named_by_its_option_and_value(tmp_path):
    """ "mesh file must be .obj or .ply" did not say whether --neutral, --frames or --targets (a red team); every
    file is checked before any is read, the message naming the option and the file, and nothing is written."""
    (tmp_path / "neutral.obj").write_text(OBJ)
    (tmp_path / "frame.txt").write_text(OBJ)
    (tmp_path / "w.csv").write_text("frame\n1\n")
    tail = ("--map", tmp_path / "missing.exr", "--out", tmp_path / "o.zarr", "--quiet")
    neutral = ("--neutral", tmp_path / "neutral.obj")
    for argv, message in (
        (("--neutral", tmp_path / "frame.txt", "--frames", tmp_path / "neutral.obj"),
         f"--neutral must be .obj or .ply, got '{tmp_path / 'frame.txt'}'"),
        (("--neutral", tmp_path / "none.obj", "--frames", tmp_path / "neutral.obj"),
         f"--neutral must name an existing .obj or .ply file, got '{tmp_path / 'none.obj'}'"),
        ((*neutral, "--frames", tmp_path / "neutral.obj", tmp_path / "frame.txt"),
         f"--frames must be .obj or .ply, got '{tmp_path / 'frame.txt'}'"),
        ((*neutral, "--frames", tmp_path / "none.obj"),  # was "paths must name existing frame files"
         f"--frames must name an existing .obj or .ply file, got '{tmp_path / 'none.obj'}'"),
        ((*neutral, "--targets", tmp_path / "frame.txt", "--weights", tmp_path / "w.csv"),
         f"--targets must be .obj or .ply, got '{tmp_path / 'frame.txt'}'"),
    ):  # fmt: skip
        r = run_main("microstructure", "render", *argv, *tail)
        assert r.returncode == 2 and f"facestats: error: {message}" in r.stderr, (argv, r.stderr)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["frame.txt", "neutral.obj", "w.csv"], argv


def test_a_folder_that_is_no_ict_facekit_checkout_is_named_as_neutral(tmp_path):
    """A folder given as --neutral is read as an ICT-FaceKit checkout; one that is not was "root must be ..." (the
    API's parameter, a red team)."""
    (tmp_path / "empty").mkdir()
    (tmp_path / "w.csv").write_text("jawOpen\n0.5\n")
    r = run_main("microstructure", "render", "--neutral", tmp_path / "empty", "--weights", tmp_path / "w.csv",
                 "--map", tmp_path / "missing.exr", "--out", tmp_path / "o.zarr", "--quiet")  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert "facestats: error: --neutral must be an ICT-FaceKit checkout" in r.stderr and "empty" in r.stderr, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "w.csv"]
