"""Subject export refuses, by name and before writing anything: bad meshes, inputs inside ``out``, options of
another format, sample subjects, glTF names that are not file stems."""

from __future__ import annotations

import json
import os

import numpy as np
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
        "options given that do not apply to format 'gltf': probe='nan.exr' (--probe applies to mitsuba only), "
        "width=5 (--width applies to mitsuba only), material='subsurface' (--material applies to mitsuba only), "
        "mesh_format='ply' (--mesh-format applies to exr and mitsuba only)"
    )
    with pytest.raises(ValidationError, match=r"spp=4 \(--spp applies to mitsuba only\)"):
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


# -- a red team's findings on the export writers (2026-12-06, evening) ------------------------------------------
def _loaded(subject):
    return subject.load().copy(deep=True)


@pytest.mark.parametrize("fmt", EXPORT_FORMATS)
def test_a_dataset_the_store_would_refuse_is_refused_by_every_format(tmp_path, subject, fmt):
    """A Dataset given to the API was exported unchecked: rho_s = -0.3 became a specular reflectance of -2.87."""
    from facestats.errors import SchemaError

    ds = _loaded(subject)
    v, u = map(int, next(zip(*(ds["region"].values > 0).nonzero())))
    ds["ts_rho_s"].values[v, u] = -0.3
    with pytest.raises(SchemaError, match=r"subject 'S001'.*ts_rho_s.*-0\.3"):
        export_subject(ds, tmp_path / "out", fmt)
    assert os.listdir(tmp_path) == []


def test_albedo_avg_must_be_positive_and_a_modulation_beyond_half_floats_is_named(tmp_path, subject):
    """albedo_avg = 0 made M infinite on the face, written as 0 without a word; 1e-6 failed on a half-float overflow
    of "channel 'B'" in a temporary folder that was gone by then."""
    from facestats.errors import SchemaError
    from facestats.io.schema import validate_subject

    ds = _loaded(subject)
    ds["albedo_avg"].values[2] = 0.0
    with pytest.raises(SchemaError, match=r"albedo_avg.*0"):
        validate_subject(ds)
    ds["albedo_avg"].values[2] = 1e-6
    with pytest.raises(ValidationError) as err:
        export_subject(ds, tmp_path / "out", "exr")
    msg = str(err.value)
    assert "modulation must lie within the half-float range (|x| <= 65504) for modulation.exr" in msg
    assert "in channel 'B' (M = albedo / albedo_avg, albedo_avg = [" in msg and "1e-06]" in msg
    assert "export-" not in msg and os.listdir(tmp_path) == []  # no temporary path, nothing left


def test_a_map_named_like_a_file_of_the_export_is_refused(tmp_path, subject):
    """An extra map `normal_tangent` overwrote the set's tangent-space normals; `probe` the Mitsuba light probe,
    whose manifest entry then named a channel the file lacked."""
    ds = _loaded(subject)
    ds["normal_tangent"] = ds["normal"] * 0 + 7.0
    with pytest.raises(ValidationError, match=r"variable 'normal_tangent' would be written to normal_tangent\.exr"):
        export_subject(ds, tmp_path / "a", "exr")
    ds = _loaded(subject).assign(probe=subject["ts_m"] * 0 + 1.0)
    export_subject(ds, tmp_path / "b", "exr")  # the EXR set alone has no probe: fine
    with pytest.raises(ValidationError, match=r"variable 'probe' would be exported as probe\.exr, a file the "):
        export_subject(ds, tmp_path / "c", "mitsuba")
    assert sorted(os.listdir(tmp_path)) == ["b"]


def test_a_subsurface_medium_needs_extinction_in_every_channel(tmp_path, subject):
    """sigma_a = sigma_s' = 0 in a channel gave the medium an albedo of 0/0: NaN in scene.xml and a bare NaN in
    scene.json, which Mitsuba renders as NaN pixels without complaint."""
    from facestats.io.mitsuba import check_medium

    ds = _loaded(subject)
    ds["sigma_a"].values[2] = ds["sigma_s_prime"].values[2] = 0.0
    with pytest.raises(ValidationError, match=r"sigma_t = sigma_a \+ sigma_s_prime > 0 .*got sigma_a = 0\.0, "):
        export_subject(ds, tmp_path / "m", "mitsuba", material="subsurface")
    assert os.listdir(tmp_path) == []
    export_subject(ds, tmp_path / "s", "mitsuba")  # the surface material has no medium
    sa, sp = check_medium([0.0, 0.1, 0.2], [1.0, 0.0, 0.5])  # one of the two is enough
    assert sa.tolist() == [0.0, 0.1, 0.2] and sp.tolist() == [1.0, 0.0, 0.5]
    with pytest.raises(ValidationError, match="sigma_a must be finite"):
        check_medium([float("nan"), 1, 1], [1, 1, 1])


def test_an_empty_out_folder_keeps_its_permissions_and_long_names_work(tmp_path, subject):
    """The empty folder was replaced by the export's temporary (0755): a private 0700 folder became world-readable.
    A 240-byte name failed: the temporary's name went beyond 255 bytes."""
    import stat

    private = tmp_path / "private"
    private.mkdir(mode=0o700)
    os.chmod(private, 0o700)
    export_subject(subject, private, "gltf")
    assert stat.S_IMODE(os.stat(private).st_mode) == 0o700 and "face.gltf" in os.listdir(private)
    os.chmod(private, 0o750)
    export_subject(subject, private, "gltf", overwrite=True)
    assert stat.S_IMODE(os.stat(private).st_mode) == 0o750
    long = tmp_path / ("é" * 120)  # 240 bytes in UTF-8
    res = export_subject(subject, long, "gltf")
    assert res["out"] == str(long) and sorted(os.listdir(tmp_path)) == sorted(["private", "é" * 120])


@pytest.mark.parametrize(
    "raw, scale, unit, want",
    [
        (0.25, 1.0, "m", 1000),  # a scan in m read as mm
        (0.25, 0.5, "m", 1000),  # said "in m, pass scale 500"
        (0.25, 1e6, "m", 1000),  # said "in µm, pass scale 1000"
        (0.25, 1e-30, "m", 1000),  # said only "pass the factor from its unit to mm"
        (250.0, 1000.0, "mm", 1),  # a scan in mm given --mesh-scale 1000: said only "pass the factor ..."
        (25.0, 1.0, "cm", 10),
        (2.5e5, 1.0, "µm", 0.001),
    ],
)
def test_the_scale_a_misfit_mesh_is_told_to_pass_is_for_the_unit_it_names(raw, scale, unit, want):
    """The suggestion is the power of ten (mm per unit of the file) that brings the file's extent to a face's size,
    and the unit named is that scale's, whatever scale the mesh was read with: with scale 1e6 on a 0.25-unit scan it
    said "if the file is in µm, pass scale 1000" (1000 is m's scale)."""
    from facestats.io.mesh import face_extent_problem

    verts = np.array([[0.0, 0.0, 0.0], [raw, 0.4 * raw, 0.3 * raw]]) * scale
    said = face_extent_problem(verts, "scan.obj", scale)
    assert said.endswith(
        f"outside a face's 50-1000 mm: if the file is in {unit}, pass scale {want:g} (--mesh-scale {want:g} on the "
        "command line, the factor from its unit to mm)"
    ), said
    assert face_extent_problem(verts / scale * want, "scan.obj", want) is None  # the suggestion fits
