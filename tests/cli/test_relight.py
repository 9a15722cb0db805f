"""``facestats relight``: a subject or a field store under a probe → EXR + PNG; bad input leaves nothing.

Refusals and repeated runs call :func:`facestats.cli.main` in the test's process (:func:`tests.helpers.run_main`,
or ``main`` itself), which the console script runs; the tests that ran the console script still run it.
"""

import numpy as np
import pytest

from facestats.errors import ValidationError
from facestats.io.images import read_exr, read_image, write_pfm
from facestats.io.probes import write_light_probe
from facestats.relight.field import write_field
from facestats.relight.lighting import sky_probe
from facestats.relight.relighting import relight
from tests.helpers import run_cli, run_main
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
    assert img.shape == (6, 6, 4) and np.allclose(img[..., :3], expect, rtol=1e-5, atol=1e-7)
    assert np.array_equal(img[..., 3], inside.astype(np.float32))  # the face mask as alpha
    assert read_exr(tmp_path / "f.exr")[1]["rotate_deg"] == "90.0"
    png = read_image(tmp_path / "f.png")
    assert png.shape == (6, 6, 3) and png[inside].max() > 0.5  # the preview stays RGB
    r = run_main("relight", "S001", "--probe", tmp_path / "sky.hdr", "--size", "16", "--lights", "16x8",
                 "--out", tmp_path / "s.exr", "--png", tmp_path / "s_preview.png")  # fmt: skip
    assert r.returncode == 0, r.stderr
    s_exr = read_image(tmp_path / "s.exr")
    assert s_exr.shape == (16, 16, 4) and (tmp_path / "s_preview.png").exists()
    assert set(np.unique(s_exr[..., 3])) == {0.0, 1.0} and np.all(s_exr[s_exr[..., 3] == 0, :3] == 0)
    assert "wrote" in r.stdout and "shadow maps:" in r.stderr  # the progress bars
    r = run_cli("relight", "S001", "--probe", tmp_path / "sky.hdr", "--size", "16", "--lights", "16x8",
                "--out", tmp_path / "q.exr", "--quiet")  # fmt: skip
    assert r.returncode == 0 and r.stderr == ""  # a process: nothing at all on its stderr
    # A field store has its camera and lights: the subject's render options are refused, not ignored.
    r = run_main("relight", tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", "--size", "999", "--lights", "0x0",
                 "--out", tmp_path / "g.exr")  # fmt: skip
    assert r.returncode == 2 and "--size, --lights apply to a subject" in r.stderr
    assert not (tmp_path / "g.exr").exists()


def test_one_png_exposure_for_relights_to_compare(tmp_path):
    """Each PNG took its own exposure, so a subject and its darker edit looked alike (a user's run: x13.8 and
    x20.2); --exposure fixes one."""
    probe = sky_probe(32)
    write_light_probe(tmp_path / "sky.hdr", probe)
    f, _, inside = lambertian_field(6, 6)
    write_field(tmp_path / "f.zarr", f)
    r = run_cli("relight", tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", "--out", tmp_path / "f.exr",
                "--exposure", "2.5")  # fmt: skip
    assert r.returncode == 0 and "PNG exposure x2.5" in r.stdout, r.stderr
    from facestats.io.images import srgb_to_linear

    png = srgb_to_linear(read_image(tmp_path / "f.png"))
    want = np.clip(read_image(tmp_path / "f.exr")[..., :3] * 2.5, 0, 1)
    np.testing.assert_allclose(png[inside], want[inside], atol=0.01)  # 8-bit sRGB codes
    for bad in ("0", "-1", "nan", "1e39"):  # 1e39 overflowed float32 and failed after the relight (a review)
        r = run_main("relight", tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", "--out", tmp_path / "g.exr",
                     "--exposure", bad)  # fmt: skip
        assert r.returncode == 2 and "--exposure must be a factor in (0, 1e12]" in r.stderr


def test_bad_probe_or_existing_output_leaves_no_side_effect(tmp_path):
    bad = np.ones((8, 16, 3), np.float32)
    bad[1, 2, 0] = np.nan
    write_pfm(tmp_path / "bad.pfm", bad)
    r = run_cli("relight", "S001", "--probe", tmp_path / "bad.pfm", "--size", "8", "--out", tmp_path / "o.exr")
    assert r.returncode == 2 and "bad.pfm" in r.stderr and "finite" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.pfm"]
    (tmp_path / "o.exr").write_text("keep me")
    write_light_probe(tmp_path / "sky.pfm", sky_probe(8))
    r = run_main("relight", "S001", "--probe", tmp_path / "sky.pfm", "--size", "8", "--out", tmp_path / "o.exr")
    assert r.returncode == 2 and "exists" in r.stderr and (tmp_path / "o.exr").read_text() == "keep me"
    r = run_main("relight", "NOPE", "--probe", tmp_path / "sky.pfm", "--out", tmp_path / "n.exr")
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
        r = run_main("relight", src, "--probe", probe, "--out", tmp_path / "c.exr", "--png", tmp_path / png)
        assert r.returncode == 2 and "--png must end in one of ['.png']" in r.stderr
    # Temporaries are unique: files or links under the old fixed names are neither used nor followed.
    (tmp_path / "victim.txt").write_text("mine")
    (tmp_path / ".o.png.tmp.png").symlink_to(tmp_path / "victim.txt")
    (tmp_path / ".o.exr.tmp.exr").write_text("also mine")
    r = run_main("relight", src, "--probe", probe, "--out", tmp_path / "o.exr", "--rotate", "1.7e308")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "victim.txt").read_text() == "mine" and (tmp_path / ".o.exr.tmp.exr").read_text() == "also mine"
    assert read_image(tmp_path / "o.png").shape == (4, 4, 3)
    r = run_main("relight", src, "--probe", probe, "--out", tmp_path / "new" / "n.exr", "--rotate", "nan")
    assert r.returncode == 2 and "--rotate must be a finite angle" in r.stderr and not (tmp_path / "new").exists()
    r = run_main("relight", src, "--probe", probe, "--out", tmp_path / "new" / "n.exr", "--rotate", "1e20")
    assert r.returncode == 0 and (tmp_path / "new" / "n.png").is_file()  # folders created on success
    ref = relight(f, probe=sky_probe(8), rotate=np.radians(1e20 % 360))  # 280°, not the unrotated image
    assert np.allclose(read_image(tmp_path / "new" / "n.exr")[..., :3], ref, rtol=1e-5, atol=1e-7)


def test_turntable_frames_are_dense_relights_by_default(tmp_path):
    """Frames went through the field compressed at 20x, chosen for storage alone: on S001 under grace at 64² the
    worst 1 % of the face's pixels were 17-32 % off a single relight, and frame 0 of a 16 x 8 OLAT field 21 % dark
    (a walkthrough).  Each frame is now the dense relight at its angle, and the EXR carries the mask as alpha."""
    from facestats.io.probes import read_light_probe
    from tests.relight.fields import ts_lambert_field

    f, _, _ = ts_lambert_field(10, 10, n_theta=16, n_phi=8)
    write_field(tmp_path / "f.zarr", f)
    write_light_probe(tmp_path / "sky.hdr", sky_probe(16))
    probe = read_light_probe(tmp_path / "sky.hdr")
    r = run_cli("relight", tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", "--turntable", "4", "--rotate", "30",
                "--out", tmp_path / "t.exr")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "4 frames every 90° from 30°, dense relights (Debevec et al. 2000 eq. 4)" in r.stdout
    names = sorted(p.name for p in tmp_path.iterdir() if p.suffix in (".exr", ".png"))
    assert names == [f"t_{k:03d}.{e}" for k in range(4) for e in ("exr", "png")]
    m = f["mask"].values
    for k in range(4):  # frame k: the environment turned by 30° + 90° k, relit densely
        img = read_image(tmp_path / f"t_{k:03d}.exr")
        assert np.allclose(img[..., :3], relight(f, probe=probe, rotate=np.radians(30 + 90 * k)), rtol=1e-5, atol=1e-7)
        assert np.array_equal(img[..., 3], m.astype(np.float32))
        attrs = read_exr(tmp_path / f"t_{k:03d}.exr")[1]
        assert attrs["rotate_deg"] == repr(float(30 + 90 * k)) and "compression_ratio" not in attrs
    assert not np.allclose(read_image(tmp_path / "t_000.exr"), read_image(tmp_path / "t_002.exr"))
    # one existing frame stops the command before any work; nothing is written or replaced
    (tmp_path / "u_002.png").write_text("keep")
    r = run_main("relight", tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", "--turntable", "4",
                 "--out", tmp_path / "u.exr")  # fmt: skip
    assert r.returncode == 2 and "u_002.png" in r.stderr and "exists" in r.stderr
    assert not any(p.name.startswith("u_") and p.name != "u_002.png" for p in tmp_path.iterdir())
    for bad, message in ((("--turntable", "0"), "--turntable"), (("--turntable", "2", "--ratio", "-1"), "--ratio"),
                         (("--ratio", "5"), "--ratio applies to --turntable")):  # fmt: skip
        r = run_main("relight", tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", *bad, "--out", tmp_path / "v.exr")
        assert r.returncode == 2 and message in r.stderr and not any(p.name.startswith("v") for p in tmp_path.iterdir())
    # a subject: frame 1 of 2 is the single relight turned by 180°, to float32 rounding (its stage field is float32)
    common = ("S001", "--probe", tmp_path / "sky.hdr", "--size", "12", "--lights", "8x4")
    r = run_main("relight", *common, "--turntable", "2", "--out", tmp_path / "s.exr")
    assert r.returncode == 0, r.stderr
    assert "2 frames every 180°" in r.stdout and "dense relights" in r.stdout
    r = run_main("relight", *common, "--rotate", "180", "--out", tmp_path / "one.exr")
    assert r.returncode == 0, r.stderr
    one, frame = read_image(tmp_path / "one.exr"), read_image(tmp_path / "s_001.exr")
    assert frame.shape == (12, 12, 4) and np.allclose(frame, one, rtol=1e-5, atol=1e-6 * one.max())


def test_turntable_frames_turn_from_any_finite_rotate(tmp_path):
    """A single relight reduces --rotate modulo 360° first (exact for any finite angle), but the turntable added
    k · 360°/N before reducing: with --rotate 1e20 every frame was the same image at 280° (1e20 + 90 == 1e20)."""
    from facestats.io.probes import read_light_probe

    f, _, _ = lambertian_field(6, 6)
    write_field(tmp_path / "f.zarr", f)
    write_light_probe(tmp_path / "sky.hdr", sky_probe(16))
    probe = read_light_probe(tmp_path / "sky.hdr")
    r = run_main("relight", tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", "--turntable", "4", "--rotate",
                 "1e20", "--out", tmp_path / "t.exr", "--quiet")  # fmt: skip
    assert r.returncode == 0, r.stderr
    for k, angle in enumerate((280.0, 10.0, 100.0, 190.0)):  # 1e20 mod 360 = 280
        assert read_exr(tmp_path / f"t_{k:03d}.exr")[1]["rotate_deg"] == repr(angle)
        img = read_image(tmp_path / f"t_{k:03d}.exr")[..., :3]
        assert np.allclose(img, relight(f, probe=probe, rotate=np.radians(angle)), rtol=1e-5, atol=1e-7)


def test_turntable_with_ratio_relights_the_compressed_field_and_reports_its_error(tmp_path, capsys):
    """--ratio keeps the compressed path, and says what it costs: the face's error against dense relights of four
    frames spread over the turn (it printed "compressed 20.1x" alone), with a warning above 3 % at the 99th
    percentile."""
    from facestats.cli import main
    from facestats.io.probes import read_light_probe
    from facestats.relight.compression import compress
    from facestats.relight.relighting import lighting_for
    from tests.relight.fields import ts_lambert_field

    f, _, _ = ts_lambert_field(10, 10, n_theta=16, n_phi=8)
    write_field(tmp_path / "f.zarr", f)
    write_light_probe(tmp_path / "sky.hdr", sky_probe(16))
    probe = read_light_probe(tmp_path / "sky.hdr")
    with pytest.warns(UserWarning, match=r"the compressed turntable \(--ratio 3\) errs by more than 3 % on more than "
                      r"1 % of the face's pixel channels \([\d.]+ % at the 99th percentile"):  # fmt: skip
        code = main(["relight", str(tmp_path / "f.zarr"), "--probe", str(tmp_path / "sky.hdr"), "--turntable", "4",
                     "--rotate", "30", "--ratio", "3", "--out", str(tmp_path / "t.exr"), "--quiet"])  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0
    comp = compress(f, ratio=3)
    m = f["mask"].values
    rel, mean = [], []
    for k in range(4):  # frame k: the environment turned by 30° + 90° k, through the compressed field
        angle = np.radians(30 + 90 * k)
        img = read_image(tmp_path / f"t_{k:03d}.exr")[..., :3]
        assert np.allclose(img, comp.relight(probe=probe, rotate=angle), rtol=1e-5, atol=1e-7)
        dense = relight(f, probe=probe, rotate=angle)
        bound = comp.error_bound(lighting_for(f, probe, rotate=angle))  # residual x |L| (Cauchy-Schwarz)
        assert np.all(np.abs(img - dense)[m] <= bound[m] * (1 + 1e-4) + 1e-6)
        rel.append(np.abs(img - dense)[m].reshape(-1) / np.maximum(dense[m].reshape(-1), 1e-30))
        mean.append(abs(img[m].mean() / dense[m].mean() - 1))
    rel = np.concatenate(rel)
    said = (f"face mean within {100 * max(mean):.2g} %, 99th percentile of its pixel channels "
            f"{100 * np.percentile(rel, 99):.3g} %, worst {100 * rel.max():.3g} % against the dense relight at 30°, "
            "120°, 210°, 300°")  # fmt: skip
    assert f"compressed {comp.ratio:.1f}x ({comp.clusters} clusters, {comp.components} components): {said}" in out
    assert read_exr(tmp_path / "t_001.exr")[1]["compression_error"] == said
    # every component kept (a ratio below 1): the frames are the dense ones, and nothing is warned about
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code = main(["relight", str(tmp_path / "f.zarr"), "--probe", str(tmp_path / "sky.hdr"), "--turntable", "2",
                     "--ratio", "0.5", "--out", str(tmp_path / "e.exr"), "--quiet"])  # fmt: skip
    import re

    got = re.search(r"99th percentile of its pixel channels (\S+) %, worst (\S+) %", capsys.readouterr().out)
    assert code == 0 and float(got[1]) < 1e-3 and float(got[2]) < 1e-3, got[0]  # percent
    r = run_main("relight", "S001", "--probe", tmp_path / "sky.hdr", "--size", "12", "--lights", "8x4",
                 "--turntable", "2", "--ratio", "2", "--out", tmp_path / "s.exr")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert read_image(tmp_path / "s_001.exr").shape == (12, 12, 4) and "compressed" in r.stdout


def test_the_ratio_error_report_measures_shadows_against_the_frames_face_mean(tmp_path, capsys):
    """Under one small bright source the dense frames are black where the face turns away: with each pixel channel's
    error relative to its own dense value (0 there, counted as 1e-30) it printed "99th percentile of its pixel
    channels 4.28e+30 %, worst 1.05e+31 %", and "face mean within 1e+02 %" for a frame black both ways (the source
    behind the face).  A pixel channel darker than RATIO_FLOOR of the frame's face mean (of that channel) is measured
    against that fraction instead, and a frame black both ways is exact."""
    import re

    from facestats.cli import main
    from facestats.cli.relight import RATIO_FLOOR
    from facestats.io.probes import read_light_probe
    from facestats.relight.compression import compress
    from tests.relight.fields import ts_lambert_field

    f, _, _ = ts_lambert_field(10, 10, n_theta=16, n_phi=8)
    write_field(tmp_path / "f.zarr", f)
    sun = np.zeros((16, 32, 3), np.float32)
    sun[8, 16] = 1000.0  # one pixel on the horizon, in front of the face at 180°
    write_light_probe(tmp_path / "sun.hdr", sun)
    probe = read_light_probe(tmp_path / "sun.hdr")
    with pytest.warns(UserWarning, match="the compressed turntable"):
        code = main(["relight", str(tmp_path / "f.zarr"), "--probe", str(tmp_path / "sun.hdr"), "--turntable", "4",
                     "--ratio", "3", "--out", str(tmp_path / "t.exr"), "--quiet"])  # fmt: skip
    assert code == 0
    comp, m = compress(f, ratio=3), f["mask"].values
    rel, mean = [], []
    for k in range(4):
        dense = relight(f, probe=probe, rotate=np.radians(90 * k))[m]
        img = comp.relight(probe=probe, rotate=np.radians(90 * k))[m]
        floor = RATIO_FLOOR * dense.mean(0)
        rel.append((np.abs(img - dense) / np.maximum(np.maximum(dense, floor), 1e-30)).reshape(-1))
        mean.append(0.0 if img.mean() == dense.mean() else abs(img.mean() / dense.mean() - 1))
    assert np.all(relight(f, probe=probe)[m] == 0) and mean[0] == 0  # the source behind the face: black both ways
    rel = np.concatenate(rel)
    said = (f"face mean within {100 * max(mean):.2g} %, 99th percentile of its pixel channels "
            f"{100 * np.percentile(rel, 99):.3g} %, worst {100 * rel.max():.3g} % against the dense relight at 0°, "
            "90°, 180°, 270°")  # fmt: skip
    out = capsys.readouterr().out
    assert said in out, out
    got = re.search(r"face mean within (\S+) %, 99th percentile of its pixel channels (\S+) %, worst (\S+) %", out)
    assert all(float(x) < 1e4 for x in got.groups()), got[0]  # percent: finite figures of the errors


# -- subjects whose face is found by following their provenance, or given as --mesh ------------------------------------
def _copy_of_s001(path, subject_id, provenance):
    """S001 of the default store, written to the store ``path`` as ``subject_id`` with ``provenance`` (same maps)."""
    import json

    import facestats

    with facestats.open_store() as st:
        ds = st.subject("S001").load()
    ds.attrs["subject_id"] = subject_id
    ds.attrs["provenance"] = json.dumps(provenance(json.loads(ds.attrs["provenance"])))
    with facestats.open_store(path, mode="a") as dst:
        dst.write_subject(ds)
    return ds


def _relight(main, capsys, *args):
    code = main(["relight", *map(str, args)])
    return code, capsys.readouterr()


def _edit_of(prov, source="S001"):
    """The provenance ``facestats edit`` writes: no capture of its own, its source's under ``source_provenance``."""
    return {"source": "facestats.edit", "edit": {"name": "change_skin_type"}, "source_subject": source,
            "source_store": "default", "source_provenance": prov}  # fmt: skip


def test_an_edit_is_relit_and_exported_on_the_face_of_its_source(tmp_path, capsys):
    """An edit records no geometry of its own: its source's (through edits of edits) is the face it is rendered on."""
    from facestats.cli import main

    store = tmp_path / "edits.zarr"
    _copy_of_s001(store, "S001.edit-1", _edit_of)
    _copy_of_s001(store, "S001.edit-2", lambda p: _edit_of(_edit_of(p), source="S001.edit-1"))
    write_light_probe(tmp_path / "sky.hdr", sky_probe(16))
    common = ("--probe", tmp_path / "sky.hdr", "--size", "16", "--lights", "8x4")
    code, io = _relight(main, capsys, "S001", *common, "--out", tmp_path / "s.exr")
    assert code == 0, io.err
    for sid in ("S001.edit-1", "S001.edit-2"):
        code, io = _relight(main, capsys, sid, "--store", store, *common, "--out", tmp_path / f"{sid}.exr")
        assert code == 0, io.err  # same maps, same face: the same image as the source's
        assert np.array_equal(read_image(tmp_path / f"{sid}.exr"), read_image(tmp_path / "s.exr"))
    assert main(["export-subject", "S001.edit-2", "--store", str(store), "--out", str(tmp_path / "x")]) == 0, (
        capsys.readouterr().err
    )
    import json

    assert json.loads((tmp_path / "x" / "manifest.json").read_text())["geometry"]["name"] == "ict-48"


def test_a_subject_fitted_on_a_scan_is_relit_with_mesh(tmp_path, capsys):
    """Ingested subjects record their scan's file name: --mesh passes the scan, and the message names --mesh."""
    from facestats.cli import main
    from facestats.io.mesh import subject_mesh, write_mesh

    store = tmp_path / "scans.zarr"

    def ingested(prov):
        return dict(
            prov, source="facestats ingest", capture_provenance={"source": "photographs", "geometry": "face.obj"}
        )

    ds = _copy_of_s001(store, "X1", ingested)
    write_light_probe(tmp_path / "sky.hdr", sky_probe(16))
    common = ("--probe", tmp_path / "sky.hdr", "--size", "16", "--lights", "8x4")
    code, io = _relight(main, capsys, "X1", "--store", store, *common, "--out", tmp_path / "x.exr")
    assert code == 2 and io.err.strip() == (
        "facestats: error: subject 'X1' records geometry 'face.obj', not a face facestats can rebuild: pass the scan "
        "its maps belong to, an OBJ/PLY with UVs (--mesh PATH on the command line; mesh=PATH of "
        "facestats.relight.camera.subject_geometry in Python)"
    )
    assert "geometry=" not in io.err and not (tmp_path / "x.exr").exists()
    fm = subject_mesh(ds.assign_attrs(provenance='{"geometry": "ict-48"}'))  # the scan: the ICT face's mesh
    write_mesh(tmp_path / "face.obj", fm.vertices, fm.faces, fm.uv)
    code, io = _relight(main, capsys, "X1", "--store", store, *common, "--mesh", tmp_path / "face.obj",
                        "--out", tmp_path / "x.exr")  # fmt: skip
    assert code == 0, io.err
    code, io = _relight(main, capsys, "S001", *common, "--out", tmp_path / "s.exr")
    assert code == 0, io.err
    x, s = read_image(tmp_path / "x.exr"), read_image(tmp_path / "s.exr")
    assert np.allclose(x, s, rtol=1e-3, atol=1e-5 * s.max())  # the scan is the face S001 records (to the OBJ's digits)
    code, io = _relight(main, capsys, "X1", "--store", store, *common, "--mesh", tmp_path / "nope.obj",
                        "--out", tmp_path / "y.exr")  # fmt: skip
    assert code == 2 and "--mesh must be an OBJ/PLY file with UVs, got" in io.err and "nope.obj" in io.err
    f, _, _ = lambertian_field(4, 4)
    write_field(tmp_path / "f.zarr", f)
    code, io = _relight(main, capsys, tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", "--mesh",
                        tmp_path / "face.obj", "--out", tmp_path / "z.exr")  # fmt: skip
    assert code == 2 and "--mesh applies to a subject rendered through the virtual stage" in io.err
    assert not any((tmp_path / n).exists() for n in ("y.exr", "z.exr"))


def test_a_scan_in_metres_is_refused_naming_mesh_and_its_size_and_mesh_scale_relights_it(tmp_path, capsys, monkeypatch):
    """The ICT face saved in metres, passed as --mesh: an all-black EXR and PNG, "mean radiance nan", numpy's
    RuntimeWarnings and exit 0 (a walkthrough).  Now exit 2 before any file, naming --mesh, the mesh's size and the
    --mesh-scale to pass; --mesh-scale is export-subject's (checked by the same function) and render's too."""
    from facestats.cli import main
    from facestats.errors import ValidationError
    from facestats.io.mesh import subject_mesh, write_mesh

    with __import__("facestats").open_store() as st:
        fm = subject_mesh(st.subject("S001").load())
    metres = tmp_path / "face_m.obj"
    write_mesh(metres, fm.vertices / 1000, fm.faces, fm.uv)
    across = np.ptp(fm.vertices, axis=0).max() / 1000
    write_light_probe(tmp_path / "sky.hdr", sky_probe(16))
    common = ("S001", "--probe", tmp_path / "sky.hdr", "--size", "16", "--lights", "8x4")
    for extra in ((), ("--turntable", "2")):
        code, io = _relight(main, capsys, *common, "--mesh", metres, *extra, "--out", tmp_path / "m.exr")
        assert code == 2 and io.err.strip() == (
            f"facestats: error: --mesh {metres} is {across:.4g} mm across with scale 1, outside a face's 50-1000 mm: "
            "if the file is in m, pass scale 1000 (--mesh-scale 1000 on the command line, the factor from its unit to "
            "mm)"
        )
        assert "nan" not in io.out and not list(tmp_path.glob("m*.*"))
    code, io = _relight(main, capsys, *common, "--mesh", metres, "--mesh-scale", "1000", "--out", tmp_path / "m.exr")
    assert code == 0, io.err
    code, io = _relight(main, capsys, *common, "--out", tmp_path / "s.exr")
    assert code == 0, io.err
    m, ref = read_image(tmp_path / "m.exr"), read_image(tmp_path / "s.exr")
    assert np.allclose(m, ref, rtol=1e-3, atol=1e-5 * ref.max())  # the same face, to the OBJ's digits
    for extra, said in ((("--mesh-scale", "10"), "--mesh-scale applies only with a mesh (mesh=PATH; --mesh PATH on "
                                                 "the command line), and none is given"),
                        (("--mesh", metres, "--mesh-scale", "-1"), "--mesh-scale must lie in (0, 1e+06], got -1"),
                        (("--mesh", metres, "--mesh-scale", "nan"), "--mesh-scale must")):  # fmt: skip
        code, io = _relight(main, capsys, *common, *extra, "--out", tmp_path / "x.exr")
        assert code == 2 and io.err.startswith(f"facestats: error: {said}"), io.err
    f, _, _ = lambertian_field(4, 4)
    write_field(tmp_path / "f.zarr", f)
    code, io = _relight(main, capsys, tmp_path / "f.zarr", "--probe", tmp_path / "sky.hdr", "--mesh-scale", "10",
                        "--out", tmp_path / "x.exr")  # fmt: skip
    assert code == 2 and "--mesh-scale applies to a subject rendered through the virtual stage" in io.err
    assert not list(tmp_path.glob("x*"))
    # render takes --mesh-scale too, checked the same way and passed on as the scan's scale
    seen = {}

    def render_probe(*args, **kwargs):
        seen.update(kwargs)
        raise ValidationError("stopped here by the test")

    import facestats.pipeline.validation as validation

    monkeypatch.setattr(validation, "render_probe", render_probe)
    out = ("--out", tmp_path / "r")
    assert main(["render", "S001", "--probe", str(tmp_path / "sky.hdr"), "--mesh-scale", "10", *map(str, out)]) == 2
    assert "--mesh-scale applies only with a mesh (mesh=PATH; --mesh PATH" in capsys.readouterr().err
    code = main(["render", "S001", "--probe", str(tmp_path / "sky.hdr"), "--mesh", str(metres), "--mesh-scale", "1000",
                 *map(str, out)])  # fmt: skip
    assert code == 2 and "stopped here by the test" in capsys.readouterr().err
    assert seen["mesh"] == str(metres) and seen["scale"] == 1000.0


def test_a_subject_of_region_samples_has_no_maps_to_relight(tmp_path, capsys):
    from facestats.cli import main
    from facestats.io.merl import import_merl
    from tests.helpers import merl_dict, save_mat

    import_merl(save_mat(tmp_path, merl_dict()), tmp_path / "merl.zarr")
    write_light_probe(tmp_path / "sky.hdr", sky_probe(8))
    for extra in ((), ("--turntable", "2")):
        code, io = _relight(main, capsys, "merl-001", "--store", tmp_path / "merl.zarr", "--probe",
                            tmp_path / "sky.hdr", "--size", "8", *extra, "--out", tmp_path / "m.exr")  # fmt: skip
        assert code == 2 and io.err.strip() == (
            "facestats: error: subject 'merl-001' holds region samples, not maps: relighting needs a map subject"
        )
        assert "note:" not in io.out
    assert not list(tmp_path.glob("m*.exr"))


def test_a_ratio_a_field_of_few_lights_cannot_meet_is_refused_before_the_field_is_rendered(tmp_path, capsys):
    """3 L / 6 values per pixel bound the ratio: 16 for 8 x 4 lights.  Without --ratio a turntable is dense (until
    2026-12-08 the default 20 was lowered to 8 here with a note)."""
    from facestats.cli import main

    write_light_probe(tmp_path / "sky.hdr", sky_probe(16))
    common = ("S001", "--probe", tmp_path / "sky.hdr", "--size", "12", "--lights", "8x4", "--turntable", "2")
    code, io = _relight(main, capsys, *common, "--ratio", "20", "--out", tmp_path / "a.exr")
    assert code == 2 and io.err.strip() == (
        "facestats: error: --ratio 20 cannot be met by a field of 32 lights: besides its components it stores 6 "
        "values per face pixel, so the ratio must stay below 3 x 32 / 6 = 16; pass a smaller --ratio"
    )
    assert not list(tmp_path.glob("a_*"))
    code, io = _relight(main, capsys, *common, "--out", tmp_path / "t.exr")
    assert code == 0, io.err
    assert "note:" not in io.out and "dense relights" in io.out
    assert "compression_ratio" not in read_exr(tmp_path / "t_001.exr")[1]


@pytest.mark.parametrize("grid, low, high", [((4, 2), 0.70, 1.42), ((8, 4), 0.92, 1.09), ((64, 32), 0.998, 1.002)])
def test_the_coarsest_grid_relights_a_white_lambertian_within_its_stated_bounds(grid, low, high):
    """The bounds MIN_LIGHTS and the docs quote: Σ_cells δA max(N·l, 0) / π for a uniform unit probe, over 4000
    random normals (exact: 1 for every normal)."""
    from facestats.cli.relight import MIN_LIGHTS
    from facestats.model.sphere import light_stage_directions

    assert MIN_LIGHTS == (8, 4)
    n = np.random.default_rng(0).normal(size=(4000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d, a = light_stage_directions(*grid)
    e = (np.maximum(n @ d.reshape(-1, 3).T, 0) * a.ravel()).sum(1) / np.pi
    assert low <= e.min() and e.max() <= high and (e.min() < low + 0.02 or grid == (64, 32))


def test_stage_options_are_checked_by_their_flags_before_any_work(tmp_path, capsys):
    from facestats.cli import main

    write_light_probe(tmp_path / "sky.hdr", sky_probe(8))
    for bad, message in (
        (("--lights", "0x4"), "--lights must be N_THETAxN_PHI, two whole numbers >= 1 in ASCII digits such as "
                              "64x32, got '0x4'"),
        (("--lights", "8x-1"), "--lights must be N_THETAxN_PHI, two whole numbers >= 1"),
        (("--lights", "1x1"), "--lights must be at least 8x4: a coarser grid relights a white Lambertian"),
        (("--lights", "4x2"), "--lights must be at least 8x4"),
        (("--elevation", "95"), "--elevation must be an angle in [-90, 90] degrees, got 95.0"),
        (("--elevation", "nan"), "--elevation must be an angle in [-90, 90] degrees, got nan"),
        (("--azimuth", "inf"), "--azimuth must be a finite angle in degrees, got inf"),
        (("--size", "0"), "--size must be an image side in [1, 8192] pixels, got 0"),
    ):  # fmt: skip
        code, io = _relight(main, capsys, "S001", "--probe", tmp_path / "sky.hdr", *bad, "--out", tmp_path / "o.exr")
        assert code == 2 and io.err.strip().startswith(f"facestats: error: {message}"), (bad, io.err)
        assert "n_theta" not in io.err and "elevation_deg" not in io.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sky.hdr"]


def test_empty_paths_and_a_light_grid_beyond_the_limit_are_refused_by_name(tmp_path):
    """``relight ''`` said "field store '.' cannot be opened" ('' became the current folder) and ``--png ''`` was
    taken for "next to --out"; ``--lights 100000x100000`` failed late, out of memory (74.5 GiB): each is refused
    before any work, naming the option and the value, and nothing is written."""
    from facestats.io.images import MAX_IMAGE_PIXELS

    write_light_probe(tmp_path / "sky.hdr", sky_probe(8))
    common = ("--probe", tmp_path / "sky.hdr", "--out", tmp_path / "o.exr")
    for argv, message in (
        (("", *common), "argument SOURCE: must not be empty, got ''"),
        (("S001", *common, "--png", ""), "argument --png: must not be empty, got ''"),
        (("S001", *common, "--lights", "100000x100000"),
         f"facestats: error: --lights must make at most {MAX_IMAGE_PIXELS} lights (16384 x 16384, the most pixels of "
         "a light probe facestats reads: a finer grid only splits its pixels), got '100000x100000' = 10000000000 "
         "lights"),
        (("S001", *common, "--lights", "16385x16384"), "got '16385x16384' = 268451840 lights"),
    ):  # fmt: skip
        r = run_main("relight", *argv, cwd=tmp_path)
        assert r.returncode == 2 and message in r.stderr, (argv, r.stderr)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["sky.hdr"], argv
    assert MAX_IMAGE_PIXELS == 16384 * 16384  # the limit the message spells out


def test_more_lights_than_the_memory_holds_are_refused_before_the_shadow_maps(tmp_path, capsys, monkeypatch):
    """The visibility table (4 bytes per mesh vertex and light) is checked against the memory available before any
    shadow map: 100000x100000 failed late asking 74.5 GiB.  Here the machine is made to have 10 MB: 8x4 lights fit
    (32 reach S001's 4,392 vertices: 0.56 MB), 64x32 do not (2,048 lights: 36 MB), and the message says how many
    would."""
    import facestats.relight.stage as stage
    from facestats.cli import main

    monkeypatch.setattr(stage, "available_memory", lambda: 10e6)
    write_light_probe(tmp_path / "sky.hdr", sky_probe(8))
    args = ("S001", "--probe", tmp_path / "sky.hdr", "--out", tmp_path / "o.exr", "--quiet")
    code, io = _relight(main, capsys, *args, "--lights", "64x32")
    assert code == 2 and "facestats: error: --lights must be at most 569 on this machine: " in io.err, io.err
    assert "or more reach the face, and their visibility at its 4,392 mesh vertices needs " in io.err, io.err
    assert " MiB, more than the 10 MiB available" in io.err, io.err
    assert not any(tmp_path.glob("o.*"))
    with pytest.raises(ValidationError, match="lights must be at most 569 on this machine"):
        stage._check_visibility_memory(4392, 570)
    stage._check_visibility_memory(4392, 569)  # 9.99 MB: fits
    code, io = _relight(main, capsys, *args, "--lights", "8x4")
    assert code == 0 and (tmp_path / "o.exr").is_file(), io.err


def test_a_lights_grid_larger_than_the_memory_holds_is_refused_before_any_array_of_it(tmp_path, capsys, monkeypatch):
    """--lights is checked against the memory its grid's own arrays need (128 bytes a light) before the probe is read
    or any of them made: with 100 MiB available 2048x1024 (256 MiB) is refused naming the flag and the value, and
    the largest 2:1 grid that fits; 64x32 is not."""
    import facestats.relight.stage as stage
    from facestats.cli import main

    made = []
    real = stage.light_stage_directions
    monkeypatch.setattr(stage, "light_stage_directions", lambda *a: made.append(a) or real(*a))
    monkeypatch.setattr(stage, "available_memory", lambda: 100 * 2**20)
    write_light_probe(tmp_path / "sky.hdr", sky_probe(8))
    args = ("S001", "--probe", tmp_path / "sky.hdr", "--out", tmp_path / "o.exr", "--quiet", "--size", "24")
    code, io = _relight(main, capsys, *args, "--lights", "2048x1024")
    assert code == 2 and made == [], io.err
    assert (
        "facestats: error: --lights must make at most 819,200 lights on this machine (the largest 2:1 grid that "
        "fits: 1280x640), got '2048x1024' = 2,097,152 lights, whose directions, resampled probe and their "
        "temporaries need 256 MiB" in io.err
    ), io.err
    assert "more than the 100 MiB available" in io.err and not any(tmp_path.glob("o.*"))
    code, io = _relight(main, capsys, *args, "--lights", "64x32")
    assert code == 0 and made == [(64, 32)] and (tmp_path / "o.exr").is_file(), io.err


def test_a_turntable_stopped_by_sigterm_leaves_no_stage_field_and_no_frame(tmp_path):
    """The subject's stage field is streamed to a temporary store under the system's temporary folder (165 MB at
    256² and 64 x 32 lights); Ctrl-C removed it, but ``kill`` (SIGTERM: a job scheduler, a closed terminal's
    session) ended the process at once and left it, with the output folder's half-written frames.  SIGTERM is now
    Ctrl-C for the command (facestats.core.processes.sigterm_as_interrupt): exit 130, nothing left."""
    import os
    import subprocess
    import sys

    write_light_probe(tmp_path / "sky.hdr", sky_probe(16))
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    script = (
        "import os, signal, sys\n"
        "import facestats.relight.stage as stage\n"
        "rendered = stage.light_stage_field\n"
        "def light_stage_field(*args, **kwargs):\n"
        "    field = rendered(*args, **kwargs)\n"
        "    assert any(os.scandir(os.environ['TMPDIR']))  # the store is there\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "    return field\n"
        "stage.light_stage_field = light_stage_field\n"
        "from facestats.cli import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    args = ["relight", "S001", "--probe", str(tmp_path / "sky.hdr"), "--size", "12", "--lights", "8x4",
            "--turntable", "3", "--out", str(tmp_path / "out" / "t.exr"), "--quiet"]  # fmt: skip
    env = dict(os.environ, TMPDIR=str(tmp), PYTHONWARNINGS="ignore")
    r = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == 130 and "facestats: interrupted" in r.stderr, (r.returncode, r.stderr)
    assert not list(tmp.iterdir()) and not (tmp_path / "out").exists()
