"""The ICT-FaceKit face under the synthetic population: shipped mesh, lumitexels, regions, a build on it."""

import json

import numpy as np
import pytest

import facestats
from facestats.errors import ValidationError
from facestats.face.ict import FRONTAL_LIMIT_DEG, ICT_OFFSET_MM, ict_face, ict_face_mesh, ict_regions
from facestats.face.named import face_geometry, named_face
from facestats.face.procedural import SITE_CENTRES
from facestats.io.ict_facekit import read_ict_facekit
from tests.helpers import TEST_DATA


@pytest.fixture(scope="module")
def face48():
    return ict_face(48)


def test_shipped_mesh_is_the_face_area_of_the_ict_facekit_sample():
    mesh, _ = read_ict_facekit(TEST_DATA / "ict-facekit", expressions=[])
    vertices, triangles, uv, uv_triangles = ict_face_mesh()
    np.testing.assert_allclose(vertices - np.asarray(ICT_OFFSET_MM), mesh.vertices, atol=1e-5 * 165)  # float32
    np.testing.assert_array_equal(triangles, mesh.triangles)
    np.testing.assert_array_equal(uv_triangles, mesh.uv_triangles)
    np.testing.assert_allclose(uv, mesh.uv, atol=1e-7)
    assert vertices.shape == (9409, 3) and not vertices.flags.writeable


def test_lumitexels_lie_on_the_mesh_facing_out(face48):
    g = face48
    assert 850 < g.n_points < 1100 and g.name == "ict-48" and g.meta["kind"] == "ict-facekit"
    assert np.all(np.abs(np.linalg.norm(g.normal, axis=1) - 1) < 1e-9)
    assert np.all(np.einsum("kd,kd->k", g.normal, g.position) > 0)  # outward from the head's centre
    assert g.normal[np.argmax(g.position[:, 2])][2] > 0.9  # the nose tip looks at the frontal camera
    # On the mesh: every lumitexel is within a hair of a vertex-interpolated point (its nearest vertex < 5 mm).
    from scipy.spatial import cKDTree

    d, _ = cKDTree(ict_face_mesh()[0]).query(g.position)
    assert d.max() < 5.0
    texels = g.grid_index
    assert np.array_equal(g.region, g.region_map[texels[:, 0], texels[:, 1]])


def test_texel_areas_integrate_the_surface():
    # The area a texel represents is the triangle's 3-D area over its UV area: the face's total converges.
    a96, a192 = ict_face(96).area.sum(), ict_face(192).area.sum()
    assert abs(a96 / a192 - 1) < 0.02
    assert 250e2 < a192 < 450e2  # an adult face: 250-450 cm²


def test_regions_follow_fig_15(face48):
    g = ict_face(48, map_size=256)
    counts = np.bincount(g.region_map.ravel(), minlength=11)
    assert np.all(counts[1:] > 0)  # all ten regions painted
    assert counts[7] == max(counts[1:])  # cheeks are the largest region
    # Left-right symmetric labels: mirror texels (u -> 1 - u) carry the same region almost everywhere.
    assert np.mean(g.region_map == g.region_map[:, ::-1]) > 0.97
    # The contact-sensor sites lie in their regions.
    assert ict_regions(*SITE_CENTRES["cheek"]) == 7 and ict_regions(*SITE_CENTRES["forehead"]) == 2
    # Above the eyes forehead, below the mouth chin.
    assert ict_regions(0.0, 80.0) == 2 and ict_regions(0.0, -64.0) == 9 and ict_regions(0.0, -34.0) == 8
    assert ict_regions(0.0, -150.0) == 0  # the neck is not face


def test_faces_by_name():
    assert face_geometry("ict", 16).name == "ict-16"
    assert face_geometry("procedural", 16).name == "procedural-16"
    with pytest.raises(ValidationError, match="face must be one of"):
        face_geometry("mannequin", 16)
    # A recorded name rebuilds the same face, at another map size if asked.
    for face in ("ict", "procedural"):
        g, back = face_geometry(face, 16), named_face(f"{face}-16")
        np.testing.assert_array_equal(back.position, g.position)
        np.testing.assert_array_equal(back.region_map, g.region_map)
        assert named_face(f"{face}-16", 32).region_map.shape == (32, 32)
    assert len(named_face("procedural-16", mesh_grid=24).mesh_vertices) == 24 * 24
    for bad in ("scan.obj", "ict-", "procedural-x", ""):
        with pytest.raises(ValidationError, match="'procedural-N' or 'ict-N'"):
            named_face(bad)


def test_the_face_area_stops_at_80_degrees_from_the_front(face48):
    assert FRONTAL_LIMIT_DEG == 80.0
    assert face48.normal[:, 2].min() > np.cos(np.radians(80.0))
    # What it leaves out is under the jaw and chin (and behind the eyeballs), not the front of the face.
    from facestats.face import ict as module

    pos, nrm, _, row, col = module._surface(48)
    model = pos - np.asarray(ICT_OFFSET_MM)
    painted = (ict_regions(model[:, 0], model[:, 1]) > 0) & (model[:, 2] > 40) & (nrm[:, 2] > 0)
    dropped = painted & (nrm[:, 2] <= np.cos(np.radians(80.0)))
    assert 0.03 < dropped.sum() / painted.sum() < 0.15
    assert np.median(nrm[dropped, 1]) < -0.5  # facing down


def test_the_default_population_lives_on_the_ict_face():
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator, simulate_capture
    from facestats.core.conventions import DEFAULT_FACE
    from facestats.face.procedural import procedural_face

    assert DEFAULT_FACE == "ict"
    truth = synthesize_population(map_size=16, conditions=False, subjects=["S001"])["S001"]
    assert truth.geometry == "ict-16" and truth.to_dataset().attrs["geometry"] == "ict-16"
    np.testing.assert_array_equal(truth.region_map, ict_face(16).region_map)
    capture = simulate_capture(truth)  # on the face the truth was drawn on
    np.testing.assert_allclose(capture.array("position"), ict_face(16).position, atol=1e-4)  # float32 mm
    with pytest.raises(ValidationError, match="drawn on 'ict-16', the simulator's face is 'procedural-16'"):
        DomeSimulator(procedural_face(16)).simulate(truth)


def test_the_ict_face_is_written_and_read_back_as_a_lab_mesh(tmp_path, face48):
    from facestats.face.geometry import uv_to_texel
    from facestats.io.mesh import load_face_mesh, save_face_mesh

    path = save_face_mesh(face48, tmp_path / "face.obj", tmp_path / "regions.npy")
    lab = load_face_mesh(path, tmp_path / "regions.npy")
    tex = uv_to_texel(lab.uv, 48)
    np.testing.assert_array_equal(lab.region, face48.region_map[tex[:, 0], tex[:, 1]])
    assert 4000 < lab.n_points < 6000  # every labelled mesh vertex is a lumitexel
    from scipy.spatial import cKDTree

    d, _ = cKDTree(ict_face_mesh()[0]).query(lab.position)
    assert d.max() < 1e-3  # the vertices as shipped (mm, OBJ text)


def test_contactless_windows_land_in_their_regions_on_the_ict_face(face48):
    from facestats.acquire.synthetic.contactless import modulation_face, patch_modulation
    from facestats.acquire.synthetic.scenes import face_site_scene

    labels = face48.region_map[..., None].astype(float)
    for site, region in (("cheek", 7), ("forehead", 2)):
        patches = face_site_scene(site).patches
        assert np.all(patch_modulation(patches, labels, modulation_face("ict-48")) == region)
    assert modulation_face("procedural-48") is None and modulation_face("scan.obj") is None
    # The lumitexels patch_modulation reads do not depend on the maps' size: the face is built at its grid.
    from facestats.face.named import named_face

    big = named_face("ict-48", 160)
    small = modulation_face("ict-48")
    assert small.map_size == 48
    np.testing.assert_array_equal(small.position, big.position)
    np.testing.assert_array_equal(small.uv, big.uv)


@pytest.mark.slow
def test_a_population_builds_and_fits_on_the_real_face(tmp_path):
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.pipeline.build import build_store

    report = build_store(tmp_path / "ict.zarr", map_size=24, subjects=["S001"], workers=1, conditions=False, face="ict")
    assert report.written == ["S001"] and not report.failed
    with facestats.open_store(tmp_path / "ict.zarr") as st:
        ds = st.subject("S001")
    np.testing.assert_array_equal(ds["region"].values, ict_face(24).region_map)
    assert json.loads(ds.attrs["provenance"])["capture_provenance"]["geometry"] == "ict-24"
    truth = synthesize_population(map_size=24, geometry=ict_face(24), conditions=False, subjects=["S001"])["S001"]
    face = ds["region"].values > 0
    rel = np.abs(ds["albedo"].values[face] / truth.albedo[face] - 1)
    assert np.median(rel) < 0.02  # the fit recovers the truth on the real face as on the procedural one
    # Export rebuilds the ICT face from the provenance: one vertex per UV vertex, normals out of the face.
    from facestats.face.ict import ict_face_mesh
    from facestats.io.gltf import read_gltf_summary
    from facestats.io.mesh import subject_mesh
    from facestats.io.subject_export import export_subject

    mesh = subject_mesh(ds)
    _, triangles, uv, _ = ict_face_mesh()
    assert mesh.geometry["name"] == "ict-24" and len(mesh.vertices) == len(uv) and len(mesh.faces) == len(triangles)
    assert (
        np.all((mesh.uv >= 0) & (mesh.uv <= 1)) and np.median(mesh.normals[:, 2]) > 0.3
    )  # 0.51; reversed winding: -0.51
    out = export_subject(ds, tmp_path / "gltf", "gltf")
    summary = read_gltf_summary(tmp_path / "gltf" / next(f for f in out["files"] if f.endswith((".gltf", ".glb"))))
    assert summary["n_vertices"] == len(uv) and summary["n_triangles"] == len(triangles)
