"""Subject export refuses, by name and before writing anything: bad meshes, inputs inside ``out``, options of
another format, sample subjects, glTF names that are not file stems."""

from __future__ import annotations

import json
import os

import pytest

from facestats.errors import FormatError, ValidationError
from facestats.io.mesh import read_triangle_mesh, subject_mesh
from facestats.io.subject_export import EXPORT_FORMATS, export_subject

NAN_VERTEX_OBJ = "v 0 0 nan\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"


@pytest.fixture(scope="module")
def subject(default_subject):
    return default_subject


@pytest.fixture(scope="module")
def merl_store(tmp_path_factory):
    """A store of region-sample subjects, as ``facestats import-merl`` makes them."""
    from facestats.io.merl import import_merl
    from tests.helpers import merl_dict, save_mat

    tmp = tmp_path_factory.mktemp("merl")
    import_merl(save_mat(tmp, merl_dict()), tmp / "merl.zarr")
    return tmp / "merl.zarr"


@pytest.mark.parametrize("fmt", EXPORT_FORMATS)
def test_a_mesh_with_a_non_finite_vertex_is_refused_by_every_format(tmp_path, subject, fmt):
    scan = tmp_path / "nanv.obj"
    scan.write_text(NAN_VERTEX_OBJ)
    with pytest.raises(FormatError, match=r"nanv\.obj must be finite, got \[0\.0, 0\.0, nan\] at vertex 0"):
        export_subject(subject, tmp_path / "out", fmt, mesh=scan)
    assert sorted(os.listdir(tmp_path)) == ["nanv.obj"]


def test_vertices_are_checked_where_the_mesh_is_read(tmp_path):
    scan = tmp_path / "tri.obj"
    scan.write_text(NAN_VERTEX_OBJ.replace("nan", "0"))
    verts, faces = read_triangle_mesh(scan)
    assert verts.shape == (3, 3) and faces.tolist() == [[0, 1, 2]]
    scan.write_text(NAN_VERTEX_OBJ.replace("nan", "1e400"))  # beyond float64: inf
    with pytest.raises(FormatError, match=r"tri\.obj must be finite, got \[0\.0, 0\.0, inf\] at vertex 0"):
        read_triangle_mesh(scan)


@pytest.mark.parametrize("name", ["mesh", "probe"])
def test_inputs_inside_out_are_refused_and_kept_even_with_overwrite(tmp_path, subject, name):
    out = tmp_path / "out"
    export_subject(subject, out, "mitsuba")
    inside = out / ("scan.obj" if name == "mesh" else "my_probe.exr")
    inside.write_bytes((out / ("mesh.obj" if name == "mesh" else "probe.exr")).read_bytes())
    before = sorted(os.listdir(out))
    with pytest.raises(ValidationError, match=f"{name} must lie outside out: {name} '.*', out '.*out'"):
        export_subject(subject, out, "mitsuba", overwrite=True, **{name: inside})
    assert sorted(os.listdir(out)) == before and inside.exists()
    assert sorted(os.listdir(tmp_path)) == ["out"]


def test_the_mesh_path_is_recorded_absolute(tmp_path, subject, monkeypatch):
    export_subject(subject, tmp_path / "a", "exr")
    os.replace(tmp_path / "a" / "mesh.obj", tmp_path / "scan.obj")
    monkeypatch.chdir(tmp_path)
    export_subject(subject, "b", "exr", mesh="scan.obj")
    geometry = json.loads((tmp_path / "b" / "manifest.json").read_text())["geometry"]
    assert geometry["path"] == str(tmp_path / "scan.obj") and geometry["name"] == "scan.obj"
    assert subject_mesh(subject, "scan.obj").geometry["path"] == os.path.join(os.getcwd(), "scan.obj")


def test_mitsuba_refuses_a_ply_mesh_by_name(tmp_path, subject):
    from facestats.io.mitsuba import write_mitsuba_scene

    with pytest.raises(ValidationError, match="mesh_format must be 'obj' for a Mitsuba scene .*, got 'ply'"):
        export_subject(subject, tmp_path / "m", "mitsuba", mesh_format="ply")
    assert os.listdir(tmp_path) == []
    with pytest.raises(ValidationError, match="mesh_format must be 'obj' for a Mitsuba scene"):
        write_mitsuba_scene(subject, tmp_path, mesh_format="ply")
    assert os.listdir(tmp_path) == []
    res = export_subject(subject, tmp_path / "m", "mitsuba", mesh_format="obj")
    assert "mesh.obj" in res["files"] and 'type="obj"' in (tmp_path / "m" / "scene.xml").read_text()


def test_unknown_options_and_options_of_another_format_are_refused(tmp_path, subject):
    with pytest.raises(ValidationError, match=r"export options must be among \['mesh', .*\], got \['widht', 'sp'\]"):
        export_subject(subject, tmp_path / "o", "mitsuba", widht=64, sp=3)
    with pytest.raises(ValidationError) as err:
        export_subject(
            subject, tmp_path / "o", "gltf", probe="nan.exr", width=5, material="subsurface", mesh_format="ply"
        )
    assert str(err.value) == (
        "options must apply to format 'gltf', got probe='nan.exr' (--probe: mitsuba only), width=5 (--width: "
        "mitsuba only), material='subsurface' (--material: mitsuba only), mesh_format='ply' (--mesh-format: exr, "
        "mitsuba only)"
    )
    with pytest.raises(ValidationError, match=r"got spp=4 \(--spp: mitsuba only\)"):
        export_subject(subject, tmp_path / "o", "exr", spp=4)
    assert os.listdir(tmp_path) == []
    # None is "not given" (what the command line passes for options left out)
    res = export_subject(subject, tmp_path / "o", "gltf", probe=None, width=None, mesh_format=None, material=None)
    assert "face.gltf" in res["files"]


@pytest.mark.parametrize("fmt", EXPORT_FORMATS)
def test_sample_subjects_are_refused_for_what_they_are(tmp_path, merl_store, fmt):
    what = {"exr": "an EXR texture set", "mitsuba": "a Mitsuba scene", "gltf": "a glTF asset"}[fmt]
    with pytest.raises(ValidationError) as err:
        export_subject("merl-001", tmp_path / "x", fmt, store=merl_store)
    assert str(err.value) == f"subject 'merl-001' holds region samples, not maps: {what} needs a map subject"
    assert os.listdir(tmp_path) == []


def test_gltf_name_must_be_a_plain_file_stem(tmp_path, subject):
    from facestats.io.gltf import write_gltf

    out = tmp_path / "api4"
    out.mkdir()
    for name in ("../evil", "sub/x", "", ".hidden", "a b", "x" * 65, 3):
        with pytest.raises(ValidationError, match=f"name must be a plain file stem .*got {name!r}"):
            write_gltf(subject, out, name=name)
    assert os.listdir(out) == [] and sorted(os.listdir(tmp_path)) == ["api4"]
    write_gltf(subject, out, name="S001.v2")
    assert {"S001.v2.gltf", "S001.v2.bin", "base_color.png"} <= set(os.listdir(out))
