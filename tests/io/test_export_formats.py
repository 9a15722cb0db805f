"""Subject export: EXR texture set, mesh with UVs, glTF 2.0, Mitsuba 3 scenes (rendered when Mitsuba is installed)."""

from __future__ import annotations

import json
import os
import sys

import numpy as np
import pytest

from facestats.errors import DependencyError, FacestatsError
from facestats.io.exr_set import COLOUR_SPACE, write_exr_set
from facestats.io.images import read_exr, read_image, srgb_to_linear, write_exr
from facestats.io.mesh import load_face_mesh, subject_mesh
from facestats.io.subject_export import export_subject


@pytest.fixture(scope="module")
def subject():
    import facestats

    with facestats.open_store() as st:
        ds = st.subject("S003")
    ds["ts_rho_s_std"] = ds["ts_rho_s"] * 0.05  # a *_std map, as issue 19 adds
    ds["ts_rho_s_std"].attrs = {"units": "1", "long_name": "standard error of ts_rho_s"}
    return ds


@pytest.fixture(scope="module")
def mesh(subject):
    return subject_mesh(subject, mesh_grid=64)


def test_exr_set_round_trips_every_map_with_units_and_colour_space(tmp_path, subject, mesh):
    man = write_exr_set(subject, tmp_path, mesh=mesh)
    assert man["geometry"]["name"] == "procedural-48" and man["geometry"]["kind"] == "procedural"
    for var in ("albedo", "ts_rho_s", "ts_m", "bp_exponent", "region", "ts_flag", "bp_flag", "ts_rho_s_std"):
        ch, attrs = read_exr(tmp_path / f"{var}.exr")
        want = np.asarray(subject[var].values)
        got = np.stack([ch[c] for c in "RGB"], -1) if "R" in ch else ch["Y"]
        if var in ("region", "ts_flag", "bp_flag"):
            assert got.dtype == np.uint32 and np.array_equal(got, want)
        elif var == "albedo":
            assert got.dtype == np.float16 and np.allclose(got, want, rtol=1e-3, atol=1e-4)
        else:
            assert got.dtype == np.float32 and np.array_equal(got, want.astype(np.float32))
        assert attrs["facestats.units"] == subject[var].attrs["units"]
        assert attrs["facestats.variable"] == var and attrs["facestats.subject_id"] == "S003"
    assert read_exr(tmp_path / "albedo.exr")[1]["facestats.colour_space"] == COLOUR_SPACE
    sa, attrs = read_exr(tmp_path / "sigma_a.exr")
    assert attrs["facestats.units"] == "mm-1"
    np.testing.assert_allclose([sa[c][0, 0] for c in "RGB"], subject["sigma_a"].values, rtol=1e-6)
    assert set(man["textures"]) >= {"albedo", "modulation", "normal", "normal_tangent", "sigma_s_prime", "sigma_tr"}
    assert json.loads((tmp_path / "manifest.json").read_text())["textures"]["ts_rho_s_std"]["type"] == "float"
    mod = np.stack([read_exr(tmp_path / "modulation.exr")[0][c] for c in "RGB"], -1)
    face = subject["region"].values > 0
    np.testing.assert_allclose(mod[face], (subject["albedo"].values / subject["albedo_avg"].values)[face], rtol=2e-3)


def test_tangent_space_normals_decode_to_the_object_space_normals(tmp_path, subject, mesh):
    write_exr_set(subject, tmp_path, mesh=mesh)
    nt = read_image(tmp_path / "normal_tangent.exr").astype(np.float64)
    t, b, n = mesh.tangent_frames(48)
    for a, c in ((t, n), (b, n), (t, b)):
        assert np.abs(np.einsum("vuk,vuk->vu", a, c)).max() < 1e-9  # orthonormal frames
    back = nt[..., :1] * t + nt[..., 1:2] * b + nt[..., 2:3] * n
    face = subject["region"].values > 0
    obj = subject["normal"].values[face]
    assert np.abs(back[face] - obj).max() < 3e-3  # half precision
    # +Y up the texture: the bitangent points to +y (towards the forehead) in the middle of the face.
    assert b[24, 24, 1] > 0.9 and t[24, 24, 0] > 0.9


def test_mesh_files_carry_uvs_read_back_by_load_face_mesh(tmp_path, subject):
    for fmt in ("obj", "ply"):
        out = tmp_path / fmt
        out.mkdir()
        m = subject_mesh(subject, mesh_grid=48)
        write_exr_set(subject, out, mesh=m, mesh_format=fmt)
        g = load_face_mesh(out / f"mesh.{fmt}", subject["region"].values)
        assert len(g.mesh_vertices) == len(m.vertices)
        np.testing.assert_allclose(g.mesh_vertices, m.vertices, atol=1e-3 if fmt == "ply" else 1e-6)
        # The mesh grid equals the map grid: every labelled vertex sits on its own texel centre.
        np.testing.assert_allclose(g.uv, m.uv[np.isin(np.arange(len(m.uv)), _kept(m, subject))], atol=1e-6)


def _kept(m, ds):
    from facestats.acquire.geometry import uv_to_texel

    t = uv_to_texel(m.uv, 48)
    return np.nonzero(ds["region"].values[t[:, 0], t[:, 1]] > 0)[0]


def test_geometry_without_provenance_asks_for_a_mesh(subject):
    ds = subject.copy()
    ds.attrs["provenance"] = "{}"
    with pytest.raises(FacestatsError, match="pass mesh=PATH"):
        subject_mesh(ds)


def test_beckmann_to_ggx_factor_is_the_least_squares_match():
    from scipy.optimize import minimize_scalar

    from facestats.io.gltf import GGX_PER_BECKMANN

    th = np.linspace(0, np.pi / 2 - 1e-3, 4000)
    w = np.sin(th) * np.cos(th)

    def beckmann(a):
        return np.exp(-(np.tan(th) ** 2) / a**2) / (np.pi * a**2 * np.cos(th) ** 4)

    def ggx(a):
        return a**2 / (np.pi * np.cos(th) ** 4 * (a**2 + np.tan(th) ** 2) ** 2)

    for m in (0.2, 0.3, 0.4):
        best = minimize_scalar(lambda k: np.sum(w * (beckmann(m) - ggx(k * m)) ** 2), bounds=(0.3, 2), method="bounded")
        assert abs(best.x - GGX_PER_BECKMANN) < 0.01


def test_gltf_reads_back_with_pygltflib_and_trimesh(tmp_path, subject, mesh):
    import trimesh

    from facestats.io.gltf import beckmann_to_gltf_roughness, read_gltf_summary, write_gltf

    path = write_gltf(subject, tmp_path, mesh=mesh)
    summary = read_gltf_summary(path)
    assert summary["n_vertices"] == len(mesh.vertices) and summary["n_triangles"] == len(mesh.faces)
    np.testing.assert_allclose(summary["bounds_m"][1], mesh.vertices.max(0) / 1000, rtol=1e-6)
    scene = trimesh.load(path)
    tm = next(iter(scene.geometry.values()))
    assert len(tm.faces) == len(mesh.faces)
    np.testing.assert_allclose(tm.visual.uv[:, 0], mesh.uv[:, 0], atol=1e-6)
    face = subject["region"].values > 0
    base = read_image(tmp_path / "base_color.png", srgb=True)
    np.testing.assert_allclose(base[face], subject["albedo"].values[face], atol=0.01)
    mr = read_image(tmp_path / "metallic_roughness.png")
    want = beckmann_to_gltf_roughness(subject["ts_m"].values)[face]
    assert np.abs(mr[..., 1][face] - want).max() <= 0.5 / 255 + 1e-6 and mr[..., 2].max() == 0
    nrm = read_image(tmp_path / "normal.png") * 2 - 1
    assert np.median(nrm[..., 2][face]) > 0.99  # fitted normals follow the mesh
    assert srgb_to_linear(1.0) == pytest.approx(1.0)


def test_export_subject_is_atomic_and_refuses_non_empty_directories(tmp_path, subject):
    out = tmp_path / "S003"
    with pytest.raises(FacestatsError, match="probe"):
        export_subject(subject, out, "mitsuba", probe=tmp_path / "missing.exr")
    assert not out.exists() and os.listdir(tmp_path) == []
    res = export_subject(subject, out, "gltf")
    assert "face.gltf" in res["files"] and oct(out.stat().st_mode & 0o777) == "0o755"
    with pytest.raises(FacestatsError, match="not empty"):
        export_subject(subject, out, "exr")
    export_subject(subject, out, "exr", overwrite=True)
    assert (out / "albedo.exr").exists() and not (out / "face.gltf").exists()
    assert sorted(os.listdir(tmp_path)) == ["S003"]


def test_missing_mitsuba_is_a_clear_error(monkeypatch):
    from facestats.io.mitsuba import require_mitsuba

    monkeypatch.setitem(sys.modules, "mitsuba", None)
    with pytest.raises(DependencyError, match="pip install mitsuba"):
        require_mitsuba()


def test_mitsuba_xml_is_written_without_mitsuba(tmp_path, subject, mesh):
    from facestats.io.mitsuba import write_mitsuba_scene

    spec = write_mitsuba_scene(subject, tmp_path, material="subsurface", mesh=mesh, width=32, height=32)
    xml = (tmp_path / "scene.xml").read_text()
    sp, sa = subject["sigma_s_prime"].values, subject["sigma_a"].values
    assert '<medium type="homogeneous" name="interior">' in xml
    assert spec["face"]["interior"]["scale"] == pytest.approx(float((sp + sa).max()))
    np.testing.assert_allclose(spec["face"]["interior"]["albedo"]["value"], sp / (sp + sa))
    assert 'name="int_ior" value="1.38"' in xml


mitsuba = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (pip install mitsuba; in the test extra)")


def test_mitsuba_surface_scene_renders_albedo_under_uniform_light(tmp_path, subject, mesh):
    from facestats.io.mitsuba import render_scene, write_mitsuba_scene

    probe = tmp_path / "white.exr"
    write_exr(probe, {c: np.ones((8, 16), np.float32) for c in "RGB"})
    flat = subject.copy()
    flat["ts_rho_s"] = flat["ts_rho_s"] * 0  # diffuse only: a Lambertian under radiance 1 reflects L = α
    flat["albedo"] = flat["albedo"] * 0 + np.array([0.6, 0.4, 0.2], np.float32)
    out = tmp_path / "scene"
    out.mkdir()
    spec = write_mitsuba_scene(flat, out, probe=probe, mesh=mesh, width=64, height=64, spp=32, max_depth=2)
    img = render_scene(spec, base_dir=out)
    img_xml = render_scene(out / "scene.xml")
    np.testing.assert_allclose(img, img_xml, atol=1e-5)  # the XML and the dict are one scene
    face = np.abs(img - 1).max(-1) > 1e-3  # background: the probe itself, radiance 1
    assert face.sum() > 300
    np.testing.assert_allclose(np.median(img[face], axis=0), [0.6, 0.4, 0.2], rtol=0.08)


def test_mitsuba_sees_the_probe_in_facestats_lat_long_convention(tmp_path, subject, mesh):
    """Light from behind the head (−z, the centre column of a facestats probe) is what the frontal camera's
    background shows; in Mitsuba's own convention (centre column at +z) the background would be black."""
    from facestats.io.mitsuba import render_scene, write_mitsuba_scene
    from facestats.io.probes import write_light_probe
    from facestats.model.sphere import latlong_directions

    d = latlong_directions(32, 64)
    back = np.where((d[..., 2] < -0.3)[..., None], 1.0, 0.0) * np.ones(3)
    probe = write_light_probe(tmp_path / "back.exr", back.astype(np.float32))
    out = tmp_path / "scene"
    out.mkdir()
    spec = write_mitsuba_scene(subject, out, probe=probe, mesh=mesh, width=48, height=48, spp=4, max_depth=2)
    for img in (render_scene(spec, base_dir=out), render_scene(out / "scene.xml")):
        corners = np.concatenate([img[:6, :6], img[:6, -6:], img[-6:, :6], img[-6:, -6:]]).reshape(-1, 3)
        np.testing.assert_allclose(corners, 1.0, atol=1e-3)


def test_mitsuba_subsurface_scene_renders(tmp_path, subject, mesh):
    from facestats.io.mitsuba import render_scene, write_mitsuba_scene

    spec = write_mitsuba_scene(subject, tmp_path, material="subsurface", mesh=mesh, width=64, height=64, spp=4)
    img = render_scene(spec, base_dir=tmp_path)
    assert img.shape == (64, 64, 3) and np.all(np.isfinite(img)) and img.min() >= 0
    centre = img[24:40, 24:40].mean(axis=(0, 1))
    assert centre[0] > centre[2] > 0  # skin: red diffuses most, blue least


def _khronos_validator():
    """The Khronos glTF-Validator's module folder and ``node``, or None (the README's test command installs
    it with npm into ``.gltf-validator/`` where npm is available)."""
    import pathlib
    import shutil

    node = shutil.which("node")
    root = pathlib.Path(__file__).resolve().parents[2]
    default = root / ".gltf-validator" / "node_modules" / "gltf-validator"
    module = pathlib.Path(os.environ.get("FACESTATS_GLTF_VALIDATOR", default))
    return (node, module) if node and (module / "package.json").exists() else None


@pytest.mark.parametrize("grid", [64, 256])
def test_gltf_passes_the_khronos_validator(tmp_path, subject, grid):
    """An independent check of the glTF file: the Khronos glTF-Validator reports no error and no warning
    (infos such as non-power-of-two 48² textures are allowed by glTF 2.0)."""
    import subprocess

    from facestats.io.gltf import write_gltf

    found = _khronos_validator()
    if found is None:
        pytest.skip("Khronos glTF-Validator absent: `npm install --prefix .gltf-validator gltf-validator` (needs node)")
    node, module = found
    path = write_gltf(subject, tmp_path, mesh=subject_mesh(subject, mesh_grid=grid))
    script = os.path.join(os.path.dirname(__file__), "gltf_validate.js")
    res = subprocess.run([node, script, str(module), str(path)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    issues = report["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]
    assert report["info"]["version"] == "2.0" and report["info"]["generator"] == "facestats"
    assert report["info"]["totalVertexCount"] > (grid + 1) ** 2 // 2  # the mesh was read, not just the JSON
