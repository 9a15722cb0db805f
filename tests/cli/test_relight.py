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
    # A field store has its camera and lights: the subject's render options are refused, not ignored.
    r = run_cli("relight", tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", "--size", "999", "--lights", "0x0",
                "--out", tmp_path / "g.exr")  # fmt: skip
    assert r.returncode == 2 and "--size, --lights apply to a subject" in r.stderr
    assert not (tmp_path / "g.exr").exists()


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


def test_outputs_are_checked_first_and_replaced_together(tmp_path):
    f, _, _ = lambertian_field(4, 4)
    write_field(tmp_path / "f.zarr", f)
    write_light_probe(tmp_path / "sky.pfm", sky_probe(8))
    src, probe = tmp_path / "f.zarr", tmp_path / "sky.pfm"
    (tmp_path / "a.exr").write_text("keep")
    (tmp_path / "a.png").mkdir()  # the PNG target is a folder: nothing may be replaced
    r = run_cli("relight", src, "--probe", probe, "--out", tmp_path / "a.exr", "--overwrite")
    assert r.returncode == 2 and "--png must be a file" in r.stderr and "a.png" in r.stderr
    assert (tmp_path / "a.exr").read_text() == "keep"
    for png in ("c.exr", "d.jpg"):  # a PNG under another name, or the EXR's own name
        r = run_cli("relight", src, "--probe", probe, "--out", tmp_path / "c.exr", "--png", tmp_path / png)
        assert r.returncode == 2 and "--png must end in one of ['.png']" in r.stderr
    # Temporaries are unique: files or links under the old fixed names are neither used nor followed.
    (tmp_path / "victim.txt").write_text("mine")
    (tmp_path / ".o.png.tmp.png").symlink_to(tmp_path / "victim.txt")
    (tmp_path / ".o.exr.tmp.exr").write_text("also mine")
    r = run_cli("relight", src, "--probe", probe, "--out", tmp_path / "o.exr", "--rotate", "1.7e308")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "victim.txt").read_text() == "mine" and (tmp_path / ".o.exr.tmp.exr").read_text() == "also mine"
    assert read_image(tmp_path / "o.png").shape == (4, 4, 3)
    r = run_cli("relight", src, "--probe", probe, "--out", tmp_path / "new" / "n.exr", "--rotate", "nan")
    assert r.returncode == 2 and "--rotate must be a finite angle" in r.stderr and not (tmp_path / "new").exists()
    r = run_cli("relight", src, "--probe", probe, "--out", tmp_path / "new" / "n.exr", "--rotate", "1e20")
    assert r.returncode == 0 and (tmp_path / "new" / "n.png").is_file()  # folders created on success
    ref = relight(f, probe=sky_probe(8), rotate=np.radians(1e20 % 360))  # 280°, not the unrotated image
    assert np.allclose(read_image(tmp_path / "new" / "n.exr"), ref, rtol=1e-5, atol=1e-7)


def test_turntable_relights_the_compressed_field_frame_by_frame(tmp_path):
    from facestats.io.probes import read_light_probe
    from facestats.relight.compression import compress
    from facestats.relight.relighting import lighting_for
    from tests.relight.fields import ts_lambert_field

    f, _, _ = ts_lambert_field(10, 10, n_theta=16, n_phi=8)
    write_field(tmp_path / "f.zarr", f)
    write_light_probe(tmp_path / "sky.hdr", sky_probe(16))
    probe = read_light_probe(tmp_path / "sky.hdr")
    r = run_cli("relight", tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", "--turntable", "4", "--rotate", "30",
                "--ratio", "3", "--out", tmp_path / "t.exr")  # fmt: skip
    assert r.returncode == 0, r.stderr
    names = sorted(p.name for p in tmp_path.iterdir() if p.suffix in (".exr", ".png"))
    assert names == [f"t_{k:03d}.{e}" for k in range(4) for e in ("exr", "png")]
    comp = compress(f, ratio=3)
    m = f["mask"].values
    for k in range(4):  # frame k: the environment turned by 30° + 90° k, through the compressed field
        img = read_image(tmp_path / f"t_{k:03d}.exr")
        angle = np.radians(30 + 90 * k)
        assert np.allclose(img, comp.relight(probe=probe, rotate=angle), rtol=1e-5, atol=1e-7)
        dense = relight(f, probe=probe, rotate=angle)
        bound = comp.error_bound(lighting_for(f, probe, rotate=angle))  # residual x |L| (Cauchy-Schwarz)
        assert np.all(np.abs(img - dense)[m] <= bound[m] * (1 + 1e-4) + 1e-6)
        assert read_exr(tmp_path / f"t_{k:03d}.exr")[1]["rotate_deg"] == repr(float(30 + 90 * k))
    assert not np.allclose(read_image(tmp_path / "t_000.exr"), read_image(tmp_path / "t_002.exr"))
    # one existing frame stops the command before any work; nothing is written or replaced
    (tmp_path / "u_002.png").write_text("keep")
    r = run_cli("relight", tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", "--turntable", "4",
                "--out", tmp_path / "u.exr")  # fmt: skip
    assert r.returncode == 2 and "u_002.png" in r.stderr and "exists" in r.stderr
    assert not any(p.name.startswith("u_") and p.name != "u_002.png" for p in tmp_path.iterdir())
    for bad, message in ((("--turntable", "0"), "--turntable"), (("--turntable", "2", "--ratio", "-1"), "--ratio"),
                         (("--ratio", "5"), "--ratio applies to --turntable")):  # fmt: skip
        r = run_cli("relight", tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", *bad, "--out", tmp_path / "v.exr")
        assert r.returncode == 2 and message in r.stderr and not any(p.name.startswith("v") for p in tmp_path.iterdir())
    r = run_cli("relight", "S001", "--probe", tmp_path / "sky.hdr", "--size", "12", "--lights", "8x4",
                "--turntable", "2", "--ratio", "2", "--out", tmp_path / "s.exr")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert read_image(tmp_path / "s_001.exr").shape == (12, 12, 3) and "2 frames every 180°" in r.stdout
