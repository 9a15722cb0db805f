"""Rendering a sequence (zarr/EXR, resumable), reading user maps, and the ``facestats microstructure`` command."""

import json
import re

import numpy as np
import pytest
import tifffile
import zarr

from facestats.acquire.synthetic.microstructure import procedural_microstructure
from facestats.cli import main
from facestats.errors import FacestatsError, FacestatsWarning, QuantisationWarning, ValidationError
from facestats.io.displacement import read_displacement, write_displacement
from facestats.io.ict_facekit import read_ict_facekit
from facestats.io.images import read_exr, write_exr, write_image
from facestats.io.mesh_sequence import BlendshapeSequence
from facestats.pipeline.microstructure import render_sequence
from tests.helpers import TEST_DATA

DATA = TEST_DATA / "ict-facekit"
MAP = (16384, 16384)  # the paper's 16K texture: ICT-FaceKit texels are about 15 um there
WINDOW = (9050, 4200, 96, 128)  # the cheek beside the right mouth corner


@pytest.fixture(scope="module")
def smile():
    neutral, targets = read_ict_facekit(DATA, ["mouthSmile_L", "mouthSmile_R"])
    w = np.linspace(0, 1, 4)
    return BlendshapeSequence(neutral, targets, np.stack([w, w], 1))


@pytest.fixture(scope="module")
def neutral_map():
    return procedural_microstructure((WINDOW[2], WINDOW[3]), 15.0, seed=4)


def test_tile_halos_bound_the_reach_of_both_passes_near_each_tile(smile):
    """Each tile's halo covers both passes at σ = 100 µm over the texels around it, and no more than needed
    far from the mesh's smallest texels (one halo for the whole mesh made a 2,048² window 8x slower)."""
    from facestats.model.microstructure.kernel import SIGMA_RANGE_UM, TRUNCATE
    from facestats.model.strain import MeshStrain
    from facestats.pipeline.microstructure import tile_halo

    face = smile.neutral
    ms = MeshStrain(face.vertices, face.triangles, face.uv, face.uv_triangles)

    def reach(region):  # texels one pass reads from the region's texels (taps plus the bilinear footprint)
        strain = ms.texels_strain(ms.rest, MAP, region)
        ok = strain.valid
        smallest = min(strain.texel_um_s[ok].min(), strain.texel_um_t[ok].min())  # µm per texel step, both axes
        return int(np.ceil(TRUNCATE * SIGMA_RANGE_UM[1] / smallest)) + 2

    whole = tile_halo(ms, MAP)
    for tile in [(9050, 4200, 64, 64), (9046, 6077, 512, 512), (9558, 7101, 512, 512)]:
        halo = tile_halo(ms, MAP, tile)
        r0, c0, h, w = tile
        first = reach(tile)  # the second pass at the tile's texels reads first-pass values this far away
        second = reach((r0 - first, c0 - first, h + 2 * first, w + 2 * first))  # which read the map this far
        assert halo >= first + second + 2
        assert halo <= whole
    assert tile_halo(ms, MAP, (9558, 7101, 512, 512)) < whole / 4  # far from the small texels: 138 against 680


class _Interrupt(Exception):
    pass


class _Failing:
    """A sequence whose frame ``fail_at`` raises when it is read to be rendered (an interrupted run).

    The first read of every frame is the inputs' fingerprint (before any output); the second, the render.
    """

    def __init__(self, seq, fail_at):
        self.seq, self.fail_at, self.neutral = seq, fail_at, seq.neutral
        self.reads = [0] * len(seq)

    def __len__(self):
        return len(self.seq)

    def frame(self, i):
        self.reads[i] += 1
        if i == self.fail_at and self.reads[i] == 2:
            raise _Interrupt
        return self.seq.frame(i)

    def frame_names(self):
        return self.seq.frame_names()


@pytest.mark.slow
def test_render_is_resumable_and_tiling_free(tmp_path, smile, neutral_map):
    opts = dict(map_shape=MAP, window=WINDOW, progress=False)
    ref = render_sequence(smile, neutral_map, tmp_path / "ref.zarr", tile=512, **opts)
    assert ref.rendered == [0, 1, 2, 3]
    g = zarr.open_group(str(tmp_path / "ref.zarr"), mode="r")
    d = g["displacement"][:]
    assert np.array_equal(d[0], neutral_map)  # neutral frame: identity kernels
    assert np.abs(d[3] - neutral_map).max() > 0.3 and np.all(np.isfinite(g["normal"][:]))
    stretch = g["stretch"][:]
    assert stretch[3, 2] > 1.01 and stretch[3, 3] < 0.95  # r_s up, r_t down at the mouth corner
    # Interrupt at frame 2: frames 0 and 1 are finished and stay; the rerun does the rest.
    run = tmp_path / "run.zarr"
    with pytest.raises(_Interrupt):
        render_sequence(_Failing(smile, 2), neutral_map, run, tile=48, exr_dir=tmp_path / "exr", **opts)
    g2 = zarr.open_group(str(run), mode="r")
    assert g2["done"][:].tolist() == [True, True, False, False]
    assert sorted(p.name for p in (tmp_path / "exr").iterdir()) == [
        "displacement.00000.exr", "displacement.00001.exr", "normal.00000.exr", "normal.00001.exr",
    ]  # fmt: skip
    again = render_sequence(smile, neutral_map, run, tile=48, exr_dir=tmp_path / "exr", **opts)
    assert again.skipped == [0, 1] and again.rendered == [2, 3]
    out = zarr.open_group(str(run), mode="r")["displacement"][:]
    assert np.abs(out - d).max() <= 1e-4  # tiles of 48 and 512 texels agree (up to rounding)
    channels, attrs = read_exr(tmp_path / "exr" / "displacement.00003.exr")
    assert attrs["units"] == "um" and np.array_equal(channels["Y"], out[3])
    # Other inputs at the same path are refused, nothing is overwritten.
    with pytest.raises(FacestatsError, match="holds a render of other inputs"):
        render_sequence(smile, neutral_map * 2, run, tile=48, **opts)
    assert np.array_equal(zarr.open_group(str(run), mode="r")["displacement"][:], out)


def test_user_maps_round_trip(tmp_path):
    h = np.random.default_rng(0).normal(0, 5, (32, 40)).astype(np.float32)
    write_displacement(tmp_path / "h.exr", h)
    assert np.array_equal(read_displacement(tmp_path / "h.exr"), h)
    code = (h - h.min()) / (h.max() - h.min())
    write_image(tmp_path / "h.png", code, bits=16)
    back = read_displacement(tmp_path / "h.png", height_range_um=float(h.max() - h.min()), midpoint=0.0) + h.min()
    assert np.abs(back - h).max() < (h.max() - h.min()) / 65535
    write_image(tmp_path / "h.tif", code, bits=16)
    assert np.abs(read_displacement(tmp_path / "h.tif", height_range_um=1.0, midpoint=0.0) - code).max() < 1e-4
    with pytest.raises(FacestatsError, match="height_range_um must be given"):
        read_displacement(tmp_path / "h.png")
    write_image(tmp_path / "rgb.png", np.random.default_rng(1).uniform(size=(8, 8, 3)), bits=16)
    with pytest.raises(FacestatsError, match="must have one channel"):
        read_displacement(tmp_path / "rgb.png", height_range_um=10)
    tifffile.imwrite(tmp_path / "f.tif", h)  # a float TIFF holds heights in um, as an EXR does
    assert np.array_equal(read_displacement(tmp_path / "f.tif"), h)
    write_image(tmp_path / "h8.png", code, bits=8)
    with pytest.warns(QuantisationWarning, match="8-bit codes: 256 height levels"):
        read_displacement(tmp_path / "h8.png", height_range_um=10)


def test_bad_render_input(tmp_path, smile, neutral_map):
    with pytest.raises(FacestatsError, match="neutral_map must be finite"):
        render_sequence(smile, np.full(neutral_map.shape, np.nan, np.float32), tmp_path / "a.zarr", progress=False)
    with pytest.raises(FacestatsError, match="neutral_map must be a 2-D float32/float64 map"):
        render_sequence(smile, neutral_map.astype(np.int32), tmp_path / "b.zarr", progress=False)
    with pytest.raises(FacestatsError, match="neutral_map must cover the window"):
        render_sequence(smile, neutral_map, tmp_path / "c.zarr", map_shape=MAP, window=(0, 0, 10, 10), progress=False)
    h, w = neutral_map.shape
    for kw, match in (
        (dict(map_shape=MAP, window=(16380, 0, h, w)), "window must lie inside the 16384 x 16384 map"),
        (dict(map_shape=MAP, window=(-10, 0, h, w)), "window row0 must be an integer in"),
        (dict(map_shape=(0, 0)), "map_shape height must be an integer in"),
        (dict(map_shape=MAP, window=WINDOW, table="cheek"), "table must be one of"),
        (dict(map_shape=MAP, window=WINDOW, backend="gpu"), "backend must be one of"),
    ):
        with pytest.raises(FacestatsError, match=match):
            render_sequence(smile, neutral_map, tmp_path / "c.zarr", progress=False, **kw)
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # checked before any output


def test_a_neutral_map_beyond_the_displacement_limit_is_refused_by_name_before_any_output(tmp_path, smile):
    """A float64 map of 1e39 um passed "finite", became ±inf in the cast to float32 and was refused by the first
    tile as "displacement must be finite"; one of 1e37 as "displacement must lie in" (a name the caller never
    gave), after the output was opened.  Both are refused as neutral_map (--map) before any work; a map at the
    limit renders."""
    from facestats.model.microstructure.convolve import displacement_limit

    limit = displacement_limit(np.float32)
    base = np.zeros((WINDOW[2], WINDOW[3]))
    base[5, 7] = -1.0
    for scale, shown in ((1e39, "1e+39"), (1e37, "1e+37"), (limit * 1.001, f"{limit * 1.001:.4g}")):
        for dtype in (np.float64, np.float32):
            if scale > float(np.finfo(dtype).max):
                continue
            with pytest.raises(ValidationError, match=rf"neutral_map must hold displacements within ±5\.708e\+36 um "
                               rf"\(displacement_limit of float32.*got \|{re.escape(shown)}\| um$"):  # fmt: skip
                render_sequence(smile, (base * scale).astype(dtype), tmp_path / "a.zarr", map_shape=MAP,
                                window=WINDOW, progress=False)  # fmt: skip
    path = tmp_path / "d.exr"
    write_displacement(path, base * 1e37)
    with pytest.raises(ValidationError, match=rf"got \|1e\+37\| um in {re.escape(repr(str(path)))}"):
        render_sequence(smile, path, tmp_path / "a.zarr", map_shape=MAP, window=WINDOW, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.exr"]  # nothing opened
    report = render_sequence(smile, (base * limit).astype(np.float32), tmp_path / "b.zarr", map_shape=MAP,
                             window=WINDOW, progress=False)  # fmt: skip
    assert report.rendered == [0, 1, 2, 3]


class _Edited:
    """``seq`` with frame ``index`` moved by 0.1 mm (an edited input between two runs)."""

    def __init__(self, seq, index):
        self.seq, self.index, self.neutral = seq, index, seq.neutral

    def __len__(self):
        return len(self.seq)

    def frame(self, i):
        return self.seq.frame(i) + (0.1 if i == self.index else 0.0)

    def frame_names(self):
        return self.seq.frame_names()


def test_outputs_are_safe(tmp_path, smile, neutral_map):
    opts = dict(map_shape=MAP, window=WINDOW, progress=False)
    # A folder that is not a render is neither written into nor deleted, even with overwrite.
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "notes.txt").write_text("keep me")
    for overwrite in (False, True):
        with pytest.raises(FacestatsError, match="is not a microstructure render; facestats neither writes into"):
            render_sequence(smile, neutral_map, victim, overwrite=overwrite, **opts)
    assert [p.name for p in victim.iterdir()] == ["notes.txt"]
    # A resumed render of edited inputs (a middle frame) is refused; with overwrite the EXR files follow the zarr.
    run, exr = tmp_path / "run.zarr", tmp_path / "exr"
    render_sequence(smile, neutral_map, run, exr_dir=exr, **opts)
    with pytest.raises(FacestatsError, match=r"holds a render of other inputs \(differing: \['sequence_sha256'\]\)"):
        render_sequence(_Edited(smile, 1), neutral_map, run, exr_dir=exr, **opts)
    other = neutral_map[::-1].copy()
    render_sequence(smile, other, run, exr_dir=exr, overwrite=True, **opts)
    d = zarr.open_group(str(run), mode="r")["displacement"][:]
    for i in range(len(smile)):
        assert np.array_equal(read_exr(exr / f"displacement.{i:05d}.exr")[0]["Y"], d[i])
    assert np.array_equal(d[0], other)
    # EXR files follow the zarr whenever a folder is given later, and frames beyond the sequence are refused.
    later, exr2 = tmp_path / "later.zarr", tmp_path / "exr2"
    render_sequence(smile, neutral_map, later, **opts)
    exr2.mkdir()
    (exr2 / "displacement.00000.exr").write_bytes(b"stale")
    render_sequence(smile, neutral_map, later, exr_dir=exr2, **opts)  # all frames done: only the EXR files
    d = zarr.open_group(str(later), mode="r")["displacement"][:]
    assert np.array_equal(read_exr(exr2 / "displacement.00000.exr")[0]["Y"], d[0])
    assert len(list(exr2.iterdir())) == 2 * len(smile)
    # Two renders sharing the folder, a deleted file: the next run of each puts its own frames back.
    render_sequence(smile, other, tmp_path / "b.zarr", exr_dir=exr2, **opts)
    (exr2 / "normal.00001.exr").unlink()
    assert render_sequence(smile, neutral_map, later, exr_dir=exr2, **opts).rendered == []
    n_later = zarr.open_group(str(later), mode="r")["normal"][:]
    for i in range(len(smile)):
        assert np.array_equal(read_exr(exr2 / f"displacement.{i:05d}.exr")[0]["Y"], d[i])
        channels, header = read_exr(exr2 / f"normal.{i:05d}.exr")
        assert np.array_equal(channels["B"], n_later[i, ..., 2])
        # G up the texture, as the export's tangent-space maps (it was n_v, down the map: a user's run)
        assert np.array_equal(channels["G"], -n_later[i, ..., 1]) and "glTF/OpenGL +Y up" in header["normal_space"]
        assert header["units"] == "1" and json.loads(header["window"])[2:] == list(n_later.shape[1:3])
    # A normal file of before the flip (G down, no normal_space) is written again, not kept (a review)
    channels, header = read_exr(exr2 / "normal.00002.exr")
    old = {k: v for k, v in header.items() if k in ("frame", "facestats_render")}
    write_exr(exr2 / "normal.00002.exr", dict(channels, G=-channels["G"]), attributes=old)
    render_sequence(smile, neutral_map, later, exr_dir=exr2, **opts)
    assert read_exr(exr2 / "normal.00002.exr")[1].get("normal_space", "").startswith("tangent space")
    (exr2 / "normal.00009.exr").write_bytes(b"old")
    with pytest.raises(FacestatsError, match="holds frame files beyond this sequence's 4 frames .normal.00009.exr"):
        render_sequence(smile, neutral_map, tmp_path / "x.zarr", exr_dir=exr2, **opts)
    with pytest.raises(FacestatsError, match="exr_dir must be a folder, got .* which exists and is not a folder"):
        render_sequence(smile, neutral_map, tmp_path / "x.zarr", exr_dir=victim / "notes.txt", **opts)
    # A render recorded by an older facestats (no fingerprint) says so and how to render it again.
    meta = later / "zarr.json"
    record = json.loads(meta.read_text())
    config = json.loads(record["attributes"]["config"])
    del config["sequence_sha256"]
    record["attributes"]["config"] = json.dumps(config)
    meta.write_text(json.dumps(record))
    with pytest.raises(FacestatsError, match=r"from an older facestats .*missing \['sequence_sha256'\]"):
        render_sequence(smile, neutral_map, later, **opts)
    # Nothing behind a symbolic link is replaced; an empty path is refused; an empty folder is used.
    (tmp_path / "link.zarr").symlink_to(run)
    with pytest.raises(FacestatsError, match="is a symbolic link to a render of other inputs"):
        render_sequence(smile, neutral_map, tmp_path / "link.zarr", overwrite=True, **opts)
    assert np.array_equal(zarr.open_group(str(run), mode="r")["displacement"][0], other)
    with pytest.raises(FacestatsError, match="out must be a non-empty path"):
        render_sequence(smile, neutral_map, "", **opts)
    (tmp_path / "empty.zarr").mkdir()
    assert render_sequence(smile, neutral_map, tmp_path / "empty.zarr", **opts).rendered == [0, 1, 2, 3]
    assert not (tmp_path / "x.zarr").exists()
    # A run killed while creating its group leaves only the temporary name, which the next run replaces.
    (tmp_path / ".new.zarr.creating").mkdir()
    (tmp_path / ".new.zarr.creating" / "zarr.json").write_text("{}")
    assert render_sequence(smile, neutral_map, tmp_path / "new.zarr", **opts).rendered == [0, 1, 2, 3]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "b.zarr", "empty.zarr", "exr", "exr2", "later.zarr", "link.zarr", "new.zarr", "run.zarr", "victim",
    ]  # fmt: skip


def _grid_obj(path, size_mm, xy=lambda u, v: (u, v), n=3):
    """An n x n vertex planar quad mesh of side ``size_mm`` with UVs over [0, 1]², as OBJ text; ``xy(u, v)`` places
    each vertex (in units of the side: the identity is the flat square)."""
    uv = [(x / (n - 1), y / (n - 1)) for y in range(n) for x in range(n)]
    lines = [f"v {xy(u, v)[0] * size_mm} {xy(u, v)[1] * size_mm} 0" for u, v in uv] + [f"vt {u} {v}" for u, v in uv]
    for y in range(n - 1):
        for x in range(n - 1):
            a = y * n + x + 1
            lines.append(f"f {a}/{a} {a + 1}/{a + 1} {a + n + 1}/{a + n + 1} {a + n}/{a + n}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_frames_in_other_units_and_targets_with_frames_are_refused(tmp_path):
    from facestats.pipeline.microstructure import open_sequence

    _grid_obj(tmp_path / "n.obj", 100.0)  # mm
    _grid_obj(tmp_path / "f_cm.obj", 10.0)  # the same surface in cm
    seq = open_sequence(tmp_path / "n.obj", frames=[tmp_path / "f_cm.obj"])
    with pytest.raises(FacestatsError, match=r"f_cm.obj: its extent is 0.1 x the neutral's .*e\.g\. 10 for cm"):
        seq.frame(0)
    same = open_sequence(tmp_path / "n.obj", frames=[tmp_path / "n.obj"], scale=10).frame(0)
    assert np.ptp(same[:, 0]) == pytest.approx(1000.0)  # neutral and frames scaled alike (cm -> mm)
    with pytest.raises(FacestatsError, match="targets go with weights"):
        open_sequence(tmp_path / "n.obj", frames=[tmp_path / "f_cm.obj"], targets=[tmp_path / "f_cm.obj"])


def test_a_generated_map_of_another_texel_size_than_the_mesh_is_refused(tmp_path):
    """generate records its texel size: a 64-texel map of 15 um texels on a 30 mm plane (469 um per texel) would
    have 31x pores and kernels under a texel (no effect); refused, and accepted on the plane it was made for."""
    from facestats.model.strain import MeshStrain
    from facestats.pipeline.microstructure import generate_neutral_map, mesh_texel_um, render_files

    generate_neutral_map(tmp_path / "n.exr", 64, texel_um=15.0, seed=1)
    _grid_obj(tmp_path / "far.obj", 30.0)
    _grid_obj(tmp_path / "fit.obj", 64 * 0.015)  # 0.96 mm: 15 um per texel
    far = MeshStrain(*(lambda m: (m.vertices, m.triangles, m.uv, m.uv_triangles))(_read(tmp_path / "far.obj")))
    assert mesh_texel_um(far, (64, 64)) == pytest.approx(30000 / 64)
    with pytest.raises(ValidationError, match=r"generated at texel_um 15 um per texel, but the mesh maps a 64 x 64 "
                       r"map at 469 um per texel .*31x its size.*--texel-um 469"):  # fmt: skip
        render_files(tmp_path / "far.obj", tmp_path / "n.exr", tmp_path / "far.zarr",
                     frames=[tmp_path / "far.obj"], progress=False)  # fmt: skip
    assert not (tmp_path / "far.zarr").exists()
    report = render_files(tmp_path / "fit.obj", tmp_path / "n.exr", tmp_path / "fit.zarr",
                          frames=[tmp_path / "fit.obj"], progress=False)  # fmt: skip
    assert report.rendered == [0]


def test_a_render_that_fails_on_its_mesh_leaves_nothing_and_the_corrected_rerun_runs(tmp_path):
    """A render that failed after its checks (a mesh whose UVs overlap, a sliver, a NaN target) left its new group
    behind, and the corrected rerun was refused as "a render of other inputs" (a red team). Here a mesh of two
    sheets on the same UVs: refused by name, nothing written, and the one-sheet mesh then renders to the same path."""
    from facestats.pipeline.microstructure import generate_neutral_map, render_files

    generate_neutral_map(tmp_path / "n.exr", 64, texel_um=15.0, seed=1)
    one = _grid_obj(tmp_path / "one.obj", 64 * 0.015).read_text().splitlines()
    verts = [ln for ln in one if ln.startswith("v ")]
    faces = [ln for ln in one if ln.startswith("f ")]
    lifted = [" ".join(ln.split()[:3] + ["1.0"]) for ln in verts]  # the second sheet, 1 mm up
    shifted = ["f " + " ".join(f"{int(a) + len(verts)}/{b}" for a, b in (c.split("/") for c in ln.split()[1:]))
               for ln in faces]  # fmt: skip
    two = [ln for ln in one if not ln.startswith("f ")] + lifted + faces + shifted
    (tmp_path / "two.obj").write_text("\n".join(two) + "\n")
    with pytest.raises(ValidationError, match="UV triangles overlap"):
        render_files(tmp_path / "two.obj", tmp_path / "n.exr", tmp_path / "r.zarr", frames=[tmp_path / "two.obj"],
                     progress=False)  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["n.exr", "one.obj", "two.obj"]
    report = render_files(tmp_path / "one.obj", tmp_path / "n.exr", tmp_path / "r.zarr", frames=[tmp_path / "one.obj"],
                          progress=False)  # fmt: skip
    assert report.rendered == [0]


def test_targets_that_no_weight_column_names_are_refused(tmp_path):
    """``--targets jawOpen`` with a weights CSV of the smile's columns rendered the smile alone, silently (a red
    team): a target must be a column of the weights, for an ICT-FaceKit folder and for target files alike."""
    from facestats.pipeline.microstructure import open_sequence

    (tmp_path / "w.csv").write_text("frame,mouthSmile_L\n0,0.5\n")
    with pytest.raises(ValidationError, match=r"targets \['jawOpen'\] are not columns of the weights .*mouthSmile_L"):
        open_sequence(DATA, targets=["mouthSmile_L", "jawOpen"], weights=tmp_path / "w.csv")
    _grid_obj(tmp_path / "n.obj", 10.0)
    _grid_obj(tmp_path / "jawOpen.obj", 10.0)
    with pytest.raises(ValidationError, match=r"targets \['jawOpen'\] are not columns"):
        open_sequence(tmp_path / "n.obj", targets=[tmp_path / "jawOpen.obj"], weights=tmp_path / "w.csv")
    assert len(open_sequence(DATA, targets=["mouthSmile_L"], weights=tmp_path / "w.csv")) == 1
    neutral, targets = read_ict_facekit(DATA, ["mouthSmile_L"])  # a NaN in a target, named (it was found later,
    targets["mouthSmile_L"] = targets["mouthSmile_L"].copy()  # as deformed_vertices, after the render had begun)
    targets["mouthSmile_L"][17, 1] = np.nan
    with pytest.raises(ValidationError, match=r"target .mouthSmile_L. must hold finite vertices, .*nan.* vertex 17"):
        BlendshapeSequence(neutral, targets, np.ones((1, 1)))


def test_a_mesh_in_metres_is_named_as_such_when_its_texels_are_too_small_for_the_kernels(tmp_path):
    """A mesh in metres read as mm (or a sliver triangle) ended in "texel_um must be at least 0.028 um", a parameter
    the user never set (a red team); the message now says where and what to check."""
    from facestats.pipeline.microstructure import open_sequence

    _grid_obj(tmp_path / "m.obj", 64 * 0.003 / 1000)  # 0.19 mm written in metres: 0.003 um texels as mm
    _grid_obj(tmp_path / "s.obj", 64 * 0.003 / 1000, xy=lambda u, v: (1.2 * u, v))  # stretched by 1.2 along u
    seq = open_sequence(tmp_path / "m.obj", frames=[tmp_path / "s.obj"])
    neutral = procedural_microstructure((64, 64), 15.0, seed=4)
    with pytest.raises(ValidationError, match=r"frame 0: the mesh maps texels of the map rows 0-63, columns 0-63 to "
                       r"far less surface .*texel_um must be at least .*pass --scale, e.g. 1000 for m"):  # fmt: skip
        render_sequence(seq, neutral, tmp_path / "r.zarr", map_shape=(64, 64), progress=False)
    assert not (tmp_path / "r.zarr").exists()


def _read(path):
    from facestats.io.mesh_sequence import read_mesh

    return read_mesh(path).require_uv()


@pytest.mark.parametrize("scale", [float("nan"), -1.0, float("inf"), 0.0])
def test_a_bad_scale_is_refused_also_with_an_ict_facekit_folder(scale):
    """An ICT-FaceKit folder is read in mm, but frames given with it take ``scale``: it is checked either way."""
    from facestats.pipeline.microstructure import open_sequence

    with pytest.raises(ValidationError, match="scale"):
        open_sequence(DATA, weights="never-read.csv", scale=scale)


def test_command_line_generates_and_renders(tmp_path, capsys):
    generate = ["microstructure", "generate", "--out", str(tmp_path / "n.exr"), "--size", "16384",
                "--window", "9050", "4200", "64", "64", "--subject", "S003"]  # fmt: skip
    assert main(generate) == 0
    neutral = (tmp_path / "n.exr").read_bytes()
    assert main(generate[:-1] + ["S004"]) == 2  # an existing map is replaced only with --overwrite
    assert "n.exr' exists (pass --overwrite to replace it)" in capsys.readouterr().err
    assert (tmp_path / "n.exr").read_bytes() == neutral
    assert main(generate + ["--overwrite"]) == 0 and (tmp_path / "n.exr").read_bytes() == neutral  # same seed
    # --store default is the embedded store, as leaving it out; --store without --subject was ignored: refused
    assert main(generate + ["--overwrite", "--store", "default"]) == 0 and (tmp_path / "n.exr").read_bytes() == neutral
    assert main(generate[:-2] + ["--overwrite", "--store", str(tmp_path / "s.zarr")]) == 2
    assert "--store names the store of --subject; give --subject too" in capsys.readouterr().err
    assert main(["microstructure", "generate", "--out", str(tmp_path / ".exr")]) == 2
    assert "--out must end in one of ['.exr'] after a file name (e.g. out.exr)" in capsys.readouterr().err
    (tmp_path / "w.csv").write_text("mouthSmile_L,mouthSmile_R\n0,0\n1,1\n")
    args = ["microstructure", "render", "--neutral", str(DATA), "--weights", str(tmp_path / "w.csv"),
            "--map", str(tmp_path / "n.exr"), "--size", "16384", "--window", "9050", "4200", "64", "64",
            "--out", str(tmp_path / "o.zarr"), "--quiet"]  # fmt: skip
    assert main(args + ["--height-range-um", "50"]) == 2  # a float map is in um: the range would be ignored
    assert "--height-range-um applies to integer images only" in capsys.readouterr().err
    obj = tmp_path / "neutral.obj"  # a mesh file names no blendshapes: --weights needs --targets
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n")
    assert main(["microstructure", "render", "--neutral", str(obj), *args[4:]]) == 2
    assert "--weights need targets: the blendshape meshes their columns name" in capsys.readouterr().err
    assert not (tmp_path / "o.zarr").exists()
    assert main(args) == 0
    assert "2 frames" in capsys.readouterr().out
    assert zarr.open_group(str(tmp_path / "o.zarr"), mode="r")["done"][:].all()
    # the map holds S003's face in the window it was generated for: rendered at another, refused by name
    elsewhere = [a.replace("o.zarr", "q.zarr").replace("4200", "4264") for a in args]
    assert main(elsewhere) == 2
    assert "--map '" + str(tmp_path / "n.exr") + "' was generated for the window [9050, 4200, 64, 64] of a 16384 x "\
        "16384 map (facestats procedural microstructure of subject S003), but this render covers the window "\
        "[9050, 4264, 64, 64]" in capsys.readouterr().err  # fmt: skip
    assert not (tmp_path / "q.zarr").exists()
    bad = [a.replace("o.zarr", "p.zarr").replace("n.exr", "missing.exr") for a in args]
    assert main(bad) == 2
    assert "facestats: error: --map must name an existing image file, got '" in capsys.readouterr().err  # not `path`
    window = args.index("--window")
    for corner, message in [
        (["-1", "4200", "64", "64"], "--window row0 must be an integer in [0, 16383], got -1"),
        (["9050", "4200", "0", "64"], "--window height must be an integer in [1, inf], got 0"),
    ]:
        assert main(args[: window + 1] + corner + args[window + 5 :]) == 2
        assert f"facestats: error: {message}" in capsys.readouterr().err  # not the API's `window`
    assert not (tmp_path / "p.zarr").exists()


def test_absurd_blendshape_weights_are_refused_by_name():
    """A weight of 1e9 made the strain overflow into a raw numpy warning; weights beyond ±MAX_WEIGHT are refused."""
    from facestats.io.mesh_sequence import MAX_WEIGHT

    neutral, targets = read_ict_facekit(DATA, ["mouthSmile_L"])
    assert len(BlendshapeSequence(neutral, targets, np.array([[0.0], [MAX_WEIGHT], [-MAX_WEIGHT]]))) == 3
    with pytest.raises(ValidationError, match=r"weights must lie in \[-10, 10\], got 1000000000.0"):
        BlendshapeSequence(neutral, targets, np.array([[0.5], [1e9]]))


def test_a_collapsed_frame_reports_no_strain_measured_not_no_strain(tmp_path):
    """Every triangle of a frame squashed to zero area: its stretch percentiles read 1 (no strain) although nothing
    was measured (a red team); they are NaN now, with a warning, and the degenerate count stays."""
    from facestats.errors import FacestatsWarning
    from facestats.io.mesh_sequence import FrameSequence, read_obj

    neutral = read_obj(_grid_obj(tmp_path / "neutral.obj", 0.96, n=5))
    frames = [_grid_obj(tmp_path / "squeeze.obj", 0.96, lambda u, v: (0.6 * u, v), n=5),
              _grid_obj(tmp_path / "collapse.obj", 0.96, lambda u, v: (0.0, v), n=5)]  # fmt: skip
    seq = FrameSequence(neutral, frames)
    flat = procedural_microstructure((64, 64), 15.0, seed=1)
    with pytest.warns(FacestatsWarning, match=r"frame 1: no valid strain \(32 of 32 triangles degenerate"):
        render_sequence(seq, flat, tmp_path / "r.zarr", progress=False)
    stretch = zarr.open_group(str(tmp_path / "r.zarr"), mode="r")["stretch"][:]
    np.testing.assert_allclose(stretch[0, :6], [1, 1, 1, 0.6, 0.6, 0.6], rtol=1e-9)
    assert np.isnan(stretch[1, :6]).all() and stretch[1, 6] == 32


def test_a_sliver_in_the_neutral_mesh_is_masked_not_fatal(tmp_path):
    """A vertex of the neutral moved to 1e-5 of an edge from its neighbour makes two sliver triangles (their UV
    triangles of ordinary size over almost no surface).  Their UV per mm, 10^5 x the others', set the texel size of
    their texels and, through the UV-vertex averages, of their neighbours': the render was refused ("far less
    surface than a texel of the kernels needs").  They are masked now, with a warning, and the rest renders."""
    from facestats.model.strain import MeshStrain
    from facestats.pipeline.microstructure import open_sequence

    eps = 1e-5

    def sliver(u, v):
        return (5 / 8 - eps / 8, 4 / 8) if (u, v) == (4 / 8, 4 / 8) else (u, v)

    _grid_obj(tmp_path / "n.obj", 10.0, xy=sliver, n=9)
    _grid_obj(tmp_path / "s.obj", 10.0, xy=lambda u, v: (1.2 * sliver(u, v)[0], sliver(u, v)[1]), n=9)
    seq = open_sequence(tmp_path / "n.obj", frames=[tmp_path / "s.obj"])
    mesh = seq.neutral.require_uv()
    ms = MeshStrain(mesh.vertices, mesh.triangles, mesh.uv, mesh.uv_triangles)
    corners = [set(t) for t in mesh.triangles[ms.rest_slivers]]
    p, q = 4 * 9 + 4, 4 * 9 + 5  # the moved vertex and the neighbour it sits next to
    assert len(corners) == 2 and all({p, q} <= c for c in corners)  # the two triangles of the edge p-q
    strain = ms.texels_strain(seq.frame(0), (64, 64))
    texel = strain.texel_um_s[strain.valid]
    assert texel.min() > 0.3 * np.median(texel)  # no texel near the sliver shrinks to the sliver's scale
    neutral = procedural_microstructure((64, 64), 156.25, seed=4)
    with pytest.warns(FacestatsWarning, match=r"2 sliver triangle\(s\) .*masked like degenerate ones"):
        report = render_sequence(seq, neutral, tmp_path / "r.zarr", map_shape=(64, 64), progress=False)
    assert report.rendered == [0]


def test_mesh_texel_um_in_a_window_is_the_texel_size_of_the_triangles_there():
    """Two UV islands of one 64² map: the left half of UV on a 10 x 20 mm patch (312.5 um texels), the right half
    on a 40 x 20 mm one (1250 x 312.5 um, geometric mean 625 um); the whole map's median lies between."""
    from facestats.model.strain import MeshStrain
    from facestats.pipeline.microstructure import mesh_texel_um

    xyz = np.array([[0, 0, 0], [10, 0, 0], [10, 20, 0], [0, 20, 0], [20, 0, 0], [60, 0, 0], [60, 20, 0], [20, 20, 0]])
    uv = np.array([[0, 0], [0.5, 0], [0.5, 1], [0, 1], [0.5, 0], [1, 0], [1, 1], [0.5, 1]])
    tri = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    ms = MeshStrain(xyz.astype(float), tri, uv.astype(float))
    assert mesh_texel_um(ms, (64, 64), (0, 2, 64, 20)) == pytest.approx(312.5)
    assert mesh_texel_um(ms, (64, 64), (10, 40, 20, 20)) == pytest.approx(625.0)
    assert mesh_texel_um(ms, (64, 64)) == pytest.approx((312.5 + 625.0) / 2)


def test_generate_writes_the_window_of_the_subjects_face_a_render_covers(tmp_path):
    """A subject's map is its face: generate with a window writes that part of the whole map (its regions there,
    :func:`subject_microstructure` of the window) and records map_shape and window; a whole map whose texels
    are not the face's (512 texels of 15 um: the face squeezed into 7.7 mm, a look-dev artist's first run) and a
    window off the face are refused by name, before any file is written."""
    import facestats
    from facestats.acquire.synthetic.microstructure import subject_microstructure
    from facestats.io.images import read_exr_attributes
    from facestats.pipeline.microstructure import generate_neutral_map

    window = (9050, 4200, 64, 64)
    path = generate_neutral_map(tmp_path / "n.exr", 16384, texel_um=15.0, subject="S001", window=window)
    with facestats.open_store() as store:
        ds = store.subject("S001")
    np.testing.assert_array_equal(read_displacement(path), subject_microstructure(ds, 16384, 15.0, window=window))
    attrs = read_exr_attributes(path)
    assert json.loads(attrs["map_shape"]) == [16384, 16384] and json.loads(attrs["window"]) == list(window)
    with pytest.raises(ValidationError, match=r"texel_um 15 um does not fit the face of subject 'S001' \(ict-48\): "
                       r"its UV layout maps a 512 x 512 map at 579 um per texel .* 39x its size .*--texel-um 579.*"
                       r"--size about 19763, above the largest, 16384, at which they are 18.1 um"):  # fmt: skip
        generate_neutral_map(tmp_path / "w.exr", 512, texel_um=15.0, subject="S001")
    assert generate_neutral_map(tmp_path / "w.exr", 512, texel_um=579.0, subject="S001")  # the whole face, coarse
    with pytest.raises(ValidationError, match=r"window \[0, 0, 512, 512\] of a 16384 x 16384 map holds no face "
                       r"texel of subject 'S001'"):  # fmt: skip
        generate_neutral_map(tmp_path / "off.exr", 16384, subject="S001", window=(0, 0, 512, 512))
    with pytest.raises(ValidationError, match=r"window must lie inside the 1024 x 1024 map"):
        generate_neutral_map(tmp_path / "off.exr", 1024, subject="S001", window=(1000, 0, 64, 64))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["n.exr", "w.exr"]
