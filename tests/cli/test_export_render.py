"""``facestats export-subject``, ``render`` and ``serve`` on the command line."""

import os

import pytest

from facestats.cli import main


def test_export_subject_writes_the_set_and_reports_errors_like_every_command(tmp_path, capsys):
    out = tmp_path / "S004"
    assert main(["export-subject", "S004", "--out", str(out), "--format", "exr", "--mesh-format", "ply"]) == 0
    text = capsys.readouterr().out
    assert "exported S004 as exr" in text and "mesh.ply" in text and (out / "manifest.json").exists()
    assert main(["export-subject", "S004", "--out", str(out)]) == 2
    assert "is not empty" in capsys.readouterr().err
    assert main(["export-subject", "S404", "--out", str(tmp_path / "x")]) == 2
    assert capsys.readouterr().err.strip() == "facestats: error: subject 'S404' is not in store default (156 subjects)"
    assert not (tmp_path / "x").exists()


def test_export_subject_refuses_options_of_another_format_by_their_flags(tmp_path, capsys):
    args = ["export-subject", "S001", "--format", "gltf", "--out", str(tmp_path / "gp")]
    bad = ["--probe", "nan.exr", "--width", "5", "--material", "subsurface", "--mesh-format", "ply"]
    assert main(args + bad) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("facestats: error: options must apply to format 'gltf', got mesh_format='ply' (--mesh-format")
    for flag in ("--probe", "--width", "--material"):
        assert f"({flag}: mitsuba only)" in err
    mitsuba = ["export-subject", "S001", "--format", "mitsuba", "--mesh-format", "ply", "--out", str(tmp_path / "m")]
    assert main(mitsuba) == 2
    assert "mesh_format must be 'obj' for a Mitsuba scene" in capsys.readouterr().err
    assert os.listdir(tmp_path) == []
    assert main(args) == 0  # the options' defaults are not passed as options
    assert "face.gltf" in capsys.readouterr().out


@pytest.mark.slow  # re-simulates a default capture (about 10 s); tests/pipeline/test_validation.py covers the API
def test_render_prints_the_relative_rmse_and_writes_images(tmp_path, capsys):
    assert main(["render", "S003", "--out", str(tmp_path), "--camera", "5", "--light", "20"]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    assert float(line.split("relative ")[1].split(" %")[0]) < 5
    assert sorted(os.listdir(tmp_path)) == [
        "S003-cam05-capture.exr", "S003-cam05-error.exr", "S003-cam05-rendered.exr", "S003-cam05.png",
    ]  # fmt: skip


def test_render_checks_its_outputs_before_rendering(tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    assert main(["render", "S003", "--out", str(tmp_path / "afile")]) == 2
    assert "--out must be a directory, got" in capsys.readouterr().err
    assert main(["render", "S003", "--out", ""]) == 2
    assert "--out must be a file system path, got ''" in capsys.readouterr().err
    (tmp_path / "r" / "S003-cam05.png").mkdir(parents=True)  # one target is a folder: nothing is written
    assert main(["render", "S003", "--out", str(tmp_path / "r")]) == 2
    assert "S003-cam05.png" in capsys.readouterr().err and os.listdir(tmp_path / "r") == ["S003-cam05.png"]
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "S003-cam05-error.exr").write_bytes(b"an earlier render")  # replaced only with --overwrite
    assert main(["render", "S003", "--out", str(tmp_path / "s")]) == 2
    assert "S003-cam05-error.exr' exists (pass --overwrite" in capsys.readouterr().err
    assert (tmp_path / "s" / "S003-cam05-error.exr").read_bytes() == b"an earlier render"


def test_render_refuses_a_subject_not_fitted_from_the_default_capture(tmp_path, capsys):
    """Without --capture, a subject of another store is never compared with the default's re-simulation."""
    import json

    import facestats

    with facestats.open_store() as st:
        ds = st.subject("S003").load()
    prov = json.loads(ds.attrs["provenance"])
    prov["capture_provenance"]["seed"] = 7  # fitted from another capture of S003
    ds.attrs["provenance"] = json.dumps(prov)
    with facestats.open_store(tmp_path / "other.zarr", mode="a") as other:
        other.write_subject(ds)
    out = tmp_path / "images"
    assert main(["render", "S003", "--store", str(tmp_path / "other.zarr"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "was not fitted from the default simulation of that subject" in err and "'seed': 7" in err
    assert "--capture PATH" in err and not out.exists()


def test_serve_refuses_a_port_it_cannot_bind(capsys):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert main(["serve", "--port", str(port)]) == 2
    assert f"cannot listen on 127.0.0.1:{port}" in capsys.readouterr().err
