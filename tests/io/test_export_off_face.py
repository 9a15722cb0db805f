"""Renderer textures off the measured face: the nearest measured texel's value, never black (EXR set, Mitsuba, glTF).

The default store's ``ict-48`` mesh covers 83,683 mm², 61.6 % of it on texels of region 0 (scalp, ears, neck):
before, those texels were written as black base colour and roughness 1 (glTF), diffuse, α and specular 0
(Mitsuba), 0 in the EXR set's colour and BRDF maps.
"""

from __future__ import annotations

import numpy as np
import pytest

from facestats.errors import ValidationError
from facestats.face.geometry import uv_to_texel
from facestats.io.exr_set import FILLED_MAPS, FaceFill, write_exr_set
from facestats.io.images import read_exr, read_image, write_image
from facestats.io.mesh import subject_mesh


@pytest.fixture(scope="module")
def subject(default_subject):
    return default_subject


@pytest.fixture(scope="module")
def mesh(subject):
    return subject_mesh(subject)


def _assert_nearest_filled(image, measured):
    """Every texel not ``measured`` holds the value of one of the measured texels nearest to it (ties allowed)."""
    img = np.asarray(image).reshape(measured.shape + (-1,))
    mv, mu = np.nonzero(measured)
    ov, ou = np.nonzero(~measured)
    d2 = (ov[:, None] - mv[None, :]) ** 2 + (ou[:, None] - mu[None, :]) ** 2
    nearest = d2 == d2.min(axis=1, keepdims=True)  # (off texels, measured texels)
    same = np.all(img[ov, ou][:, None, :] == img[mv, mu][None, :, :], axis=-1)
    assert np.all(np.any(nearest & same, axis=1)), "a filled texel differs from every nearest measured texel"


def _channels(path):
    ch, _ = read_exr(path)
    return np.stack([ch[c] for c in "RGB"], -1) if "R" in ch else ch["Y"]


def _texels_under_mesh(mesh, size):
    """The (v, u) texels at the mesh's vertices and triangle centroids."""
    uv = np.concatenate([mesh.uv, mesh.uv[mesh.faces].mean(axis=1)])
    return uv_to_texel(uv, size)


def test_the_default_mesh_lies_mostly_off_the_measured_face(subject, mesh):
    t = _texels_under_mesh(mesh, 48)
    off = subject["region"].values[t[:, 0], t[:, 1]] == 0
    assert off.mean() > 0.4  # what made 62 % of the rendered head black


def test_exr_set_colour_and_brdf_maps_are_filled_and_region_marks_the_measured_texels(tmp_path, subject, mesh):
    write_exr_set(subject, tmp_path, mesh=mesh)
    face = subject["region"].values > 0
    assert set(FILLED_MAPS) == {"albedo", "modulation", "ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent"}
    under = _texels_under_mesh(mesh, 48)
    for name in FILLED_MAPS:
        got = _channels(tmp_path / f"{name}.exr")
        if name == "modulation":
            want = (subject["albedo"] / subject["albedo_avg"]).values
        else:
            want = subject[name].values
        # measured texels: exactly what the writer stored before (half or float32 of the value)
        np.testing.assert_array_equal(got[face], want[face].astype(got.dtype))
        _assert_nearest_filled(got, face)
        values = got[under[:, 0], under[:, 1]].reshape(len(under), -1)
        assert np.all(np.isfinite(values)) and np.all(values > 0), name  # no black texel under the mesh
    # the region map (and the flags) stay 0 off the face: they say which texels are measured
    np.testing.assert_array_equal(_channels(tmp_path / "region.exr"), subject["region"].values)
    assert np.all(_channels(tmp_path / "ts_flag.exr")[~face] == 0)
    # data maps keep 0 off the face
    assert np.all(_channels(tmp_path / "ts_error.exr")[~face] == 0)


def test_exr_set_normals_off_the_face_are_the_mesh_normal(tmp_path, subject, mesh):
    write_exr_set(subject, tmp_path, mesh=mesh)
    face = subject["region"].values > 0
    n = _channels(tmp_path / "normal.exr").astype(np.float64)
    mesh_normal = mesh.tangent_frames(48)[2]
    np.testing.assert_allclose(n[~face], mesh_normal[~face], atol=1e-3)  # half precision
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1, atol=2e-3)  # no zero normal anywhere
    want = subject["normal"].values[face]
    np.testing.assert_array_equal(n[face], (want / np.linalg.norm(want, axis=-1, keepdims=True)).astype(np.float16))
    nt = _channels(tmp_path / "normal_tangent.exr")
    assert np.all(nt[~face] == np.array([0, 0, 1], np.float16))


def test_mitsuba_textures_are_filled_off_the_face(tmp_path, subject, mesh):
    from facestats.io.mitsuba import plastic_reflectance_scale, write_mitsuba_scene

    write_mitsuba_scene(subject, tmp_path, mesh=mesh)
    face = subject["region"].values > 0
    under = _texels_under_mesh(mesh, 48)
    for name, want in (  # blend weight 0.5: c α/(1 − w), 4ρs/w
        ("mitsuba_diffuse", subject["albedo"].values.astype(np.float32) * np.float32(2 * plastic_reflectance_scale())),
        ("mitsuba_specular", 8 * subject["ts_rho_s"].values.astype(np.float32)),
        ("ts_m", subject["ts_m"].values.astype(np.float32)),  # the lobe's alpha texture
    ):
        got = _channels(tmp_path / f"{name}.exr")
        np.testing.assert_array_equal(got[face], want[face])
        _assert_nearest_filled(got, face)
        values = got[under[:, 0], under[:, 1]]
        assert np.all(np.isfinite(values)) and np.all(values > 0), name


def test_gltf_base_colour_roughness_and_specular_are_filled_off_the_face(tmp_path, subject, mesh):
    from facestats.io.gltf import beckmann_to_gltf_roughness, write_gltf

    write_gltf(subject, tmp_path, mesh=mesh)
    face = subject["region"].values > 0
    under = _texels_under_mesh(mesh, 48)
    base = read_image(tmp_path / "base_color.png")
    # measured texels: the same 8-bit codes as the albedo written directly
    write_image(tmp_path / "ref_base.png", subject["albedo"].values.astype(np.float64), srgb=True)
    np.testing.assert_array_equal(base[face], read_image(tmp_path / "ref_base.png")[face])
    _assert_nearest_filled(base, face)
    assert np.all(base[under[:, 0], under[:, 1]].min(axis=-1) > 0.2)  # skin, not black
    mr = read_image(tmp_path / "metallic_roughness.png")
    rough = beckmann_to_gltf_roughness(subject["ts_m"].values)
    write_image(tmp_path / "ref_mr.png", np.stack([np.zeros_like(rough), rough, np.zeros_like(rough)], -1))
    np.testing.assert_array_equal(mr[face], read_image(tmp_path / "ref_mr.png")[face])
    _assert_nearest_filled(mr, face)
    assert mr[..., 1].max() < 0.9 and mr[..., 0].max() == 0 and mr[..., 2].max() == 0  # roughness 1 was the fill
    for name in ("specular.png", "specular_color.png"):  # KHR_materials_specular's weight and colour (from rho_s)
        _assert_nearest_filled(read_image(tmp_path / name), face)


def test_face_fill_takes_the_nearest_finite_face_texel():
    region = np.zeros((6, 7), np.uint8)
    region[1:4, 2:5] = 3
    values = np.arange(42, dtype=np.float32).reshape(6, 7)
    values[2, 3] = np.nan  # a face texel without a value is filled too
    values[0, 0] = 99.0  # off the face: replaced
    out = FaceFill(region)(values)
    assert out.dtype == np.float32 and out.shape == values.shape
    measured = (region > 0) & np.isfinite(values)
    np.testing.assert_array_equal(out[measured], values[measured])
    assert out[0, 0] == values[1, 2] and out[5, 6] == values[3, 4]  # the corners' nearest face texels
    assert out[2, 0] == values[2, 2] and out[2, 3] in (values[1, 3], values[2, 2], values[2, 4], values[3, 3])
    _assert_nearest_filled(out, measured)
    rgb = FaceFill(region)(np.stack([values] * 3, -1))
    np.testing.assert_array_equal(rgb[..., 1], out)
    # nothing measured: nothing to fill from, non-finite values as 0
    empty = FaceFill(np.zeros((3, 3), np.uint8))(np.full((3, 3), np.nan, np.float32))
    np.testing.assert_array_equal(empty, np.zeros((3, 3)))
    with pytest.raises(ValidationError, match=r"values must have shape \(6, 7\)"):
        FaceFill(region)(np.zeros((5, 5)))
