"""``facestats relight``: a subject or a field store under a probe → EXR + PNG; bad input leaves nothing."""

import numpy as np

from facestats.io.images import read_exr, read_image, write_pfm
from facestats.io.probes import write_light_probe
from facestats.relight.field import write_field
from facestats.relight.lighting import sky_probe
from facestats.relight.relighting import relight
from tests.helpers import run_cli
from tests.relight.fields import lambertian_field


def test_relight_a_field_store_and_a_subject(tmp_path):
    probe = sky_probe(32)
    write_light_probe(tmp_path / "sky.hdr", probe)
    f, _, inside = lambertian_field(6, 6)
    write_field(tmp_path / "f.zarr", f)
    r = run_cli("relight", tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", "--rotate", "90",
                "--out", tmp_path / "f.exr")  # fmt: skip
    assert r.returncode == 0, r.stderr
    img = read_image(tmp_path / "f.exr")
    from facestats.io.probes import read_light_probe

    expect = relight(f, probe=read_light_probe(tmp_path / "sky.hdr"), rotate=np.pi / 2)
    assert np.allclose(img, expect, rtol=1e-5, atol=1e-7)
    assert read_exr(tmp_path / "f.exr")[1]["rotate_deg"] == "90.0"
    png = read_image(tmp_path / "f.png")
    assert png.shape == (6, 6, 3) and png[inside].max() > 0.5
    r = run_cli("relight", "S001", "--probe", tmp_path / "sky.hdr", "--size", "16", "--lights", "16x8",
                "--out", tmp_path / "s.exr", "--png", tmp_path / "s_preview.png")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert read_image(tmp_path / "s.exr").shape == (16, 16, 3) and (tmp_path / "s_preview.png").exists()
    assert "wrote" in r.stdout


def test_bad_probe_or_existing_output_leaves_no_side_effect(tmp_path):
    bad = np.ones((8, 16, 3), np.float32)
    bad[1, 2, 0] = np.nan
    write_pfm(tmp_path / "bad.pfm", bad)
    r = run_cli("relight", "S001", "--probe", tmp_path / "bad.pfm", "--size", "8", "--out", tmp_path / "o.exr")
    assert r.returncode == 2 and "bad.pfm" in r.stderr and "finite" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.pfm"]
    (tmp_path / "o.exr").write_text("keep me")
    write_light_probe(tmp_path / "sky.pfm", sky_probe(8))
    r = run_cli("relight", "S001", "--probe", tmp_path / "sky.pfm", "--size", "8", "--out", tmp_path / "o.exr")
    assert r.returncode == 2 and "exists" in r.stderr and (tmp_path / "o.exr").read_text() == "keep me"
    r = run_cli("relight", "NOPE", "--probe", tmp_path / "sky.pfm", "--out", tmp_path / "n.exr")
    assert r.returncode == 2 and not (tmp_path / "n.exr").exists()
