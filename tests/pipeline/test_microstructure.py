"""Rendering a sequence (zarr/EXR, resumable), reading user maps, and the ``facestats microstructure`` command."""

import numpy as np
import pytest
import zarr

from facestats.acquire.synthetic.microstructure import procedural_microstructure
from facestats.cli import main
from facestats.errors import FacestatsError
from facestats.io.displacement import read_displacement, write_displacement
from facestats.io.ict_facekit import read_ict_facekit
from facestats.io.images import read_exr, write_image
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


class _Interrupt(Exception):
    pass


class _Failing:
    """A sequence whose frame ``fail_at`` raises (an interrupted run)."""

    def __init__(self, seq, fail_at):
        self.seq, self.fail_at, self.neutral = seq, fail_at, seq.neutral

    def __len__(self):
        return len(self.seq)

    def frame(self, i):
        if i == self.fail_at:
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


def test_bad_render_input(tmp_path, smile, neutral_map):
    with pytest.raises(FacestatsError, match="neutral_map must be finite"):
        render_sequence(smile, np.full(neutral_map.shape, np.nan, np.float32), tmp_path / "a.zarr", progress=False)
    with pytest.raises(FacestatsError, match="neutral_map must be a 2-D float32/float64 map"):
        render_sequence(smile, neutral_map.astype(np.int32), tmp_path / "b.zarr", progress=False)
    with pytest.raises(FacestatsError, match="neutral_map must cover the window"):
        render_sequence(smile, neutral_map, tmp_path / "c.zarr", map_shape=MAP, window=(0, 0, 10, 10), progress=False)
    assert not (tmp_path / "c.zarr").exists()


def test_command_line_generates_and_renders(tmp_path, capsys):
    assert (
        main(["microstructure", "generate", "--out", str(tmp_path / "n.exr"), "--size", "64", "--subject", "S003"]) == 0
    )
    (tmp_path / "w.csv").write_text("mouthSmile_L,mouthSmile_R\n0,0\n1,1\n")
    args = ["microstructure", "render", "--neutral", str(DATA), "--weights", str(tmp_path / "w.csv"),
            "--map", str(tmp_path / "n.exr"), "--size", "16384", "--window", "9050", "4200", "64", "64",
            "--out", str(tmp_path / "o.zarr"), "--quiet"]  # fmt: skip
    assert main(args) == 0
    assert "2 frames" in capsys.readouterr().out
    assert zarr.open_group(str(tmp_path / "o.zarr"), mode="r")["done"][:].all()
    bad = [a.replace("o.zarr", "p.zarr").replace("n.exr", "missing.exr") for a in args]
    assert main(bad) == 2
    assert "path must name an existing image file" in capsys.readouterr().err
    assert not (tmp_path / "p.zarr").exists()
