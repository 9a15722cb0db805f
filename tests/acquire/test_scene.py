"""Suzuki et al. S1: patches, per-patch irradiance (eq. 16) and exitance (eq. 15), lights, camera, images, renderer."""

import json

import numpy as np
import pytest
from scipy.integrate import quad

from facestats.acquire.camera import PinholeCamera
from facestats.acquire.dome import default_dome
from facestats.acquire.lights import (
    DirectionalLight,
    EnvironmentLight,
    PointLight,
    load_lights,
    patch_irradiance,
    save_lights,
)
from facestats.acquire.patches import Patches, mesh_patches, read_mesh_patches
from facestats.acquire.scene import camera_sees, patch_radiance, read_radiance_image, write_radiance_image
from facestats.acquire.synthetic.patch_image import render_patch_image
from facestats.acquire.synthetic.scenes import pyramid_scene, square_pyramid
from facestats.acquire.synthetic.subsurface import cutoff_radius, render_exitance
from facestats.errors import FacestatsError, FormatError, ValidationError
from facestats.model.dipole import dipole_profile, dipole_radial_energy, total_diffuse_reflectance
from facestats.model.fresnel import fresnel_transmittance
from facestats.model.irradiance import (
    directional_light_irradiance,
    environment_irradiance,
    exitance_from_radiance,
    point_light_irradiance,
    radiance_from_exitance,
)


def _plane(n=20, size=2.0, z=0.0):
    x = np.linspace(-size / 2, size / 2, n)
    xx, yy = np.meshgrid(x, -x)
    v = np.stack([xx.ravel(), yy.ravel(), np.full(n * n, z)], 1)
    from facestats.face.geometry import grid_triangles

    return v, grid_triangles(np.ones((n, n), bool))


def test_mesh_patches_are_equal_area_and_cover_the_mesh():
    v, f = square_pyramid(50, 25)
    p = mesh_patches(v, f[:4], spacing=5.0)
    tri = v[f[:4]]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert p.area.sum() == pytest.approx(area, rel=1e-12)
    assert np.ptp(p.area) < 1e-12  # congruent faces: all patches equal
    assert np.allclose(np.linalg.norm(p.normal, axis=1), 1) and np.all(p.normal[:, 2] > 0)
    c = p.corners
    np.testing.assert_allclose(c.mean(1), p.centre)
    assert np.all(np.einsum("mk,mk->m", np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), p.normal) > 0)
    with pytest.raises(ValidationError, match="normal must have the shape of centre"):
        Patches(p.centre, p.normal[:-1], p.area)
    with pytest.raises(ValidationError, match="area must lie in"):
        Patches(p.centre, p.normal, np.where(np.arange(len(p)) == 0, 0.0, p.area))


def test_mesh_files_become_patches(tmp_path):
    import trimesh

    v, f = square_pyramid(50, 25)
    path = tmp_path / "pyramid.obj"
    trimesh.Trimesh(v, f, process=False).export(path)
    p = read_mesh_patches(path, spacing=5.0)
    q = mesh_patches(v, f, spacing=5.0)
    np.testing.assert_allclose(np.sort(p.area), np.sort(q.area))
    assert p.has_mesh and len(p) == len(q)
    ply = tmp_path / "pyramid.ply"
    trimesh.Trimesh(v * 1e-3, f, process=False).export(ply)
    assert read_mesh_patches(ply, spacing=5.0, scale=1000).area.sum() == pytest.approx(q.area.sum(), rel=1e-6)


def test_point_and_directional_irradiance_follow_eq_16():
    pts = np.array([[0.0, 0, 0], [3.0, 0, 0], [0, 0, 0]])
    nrm = np.array([[0.0, 0, 1], [0, 0, 1], [0, 0, -1]])
    c = point_light_irradiance(pts, nrm, [[0.0, 0, 10]], 100.0, eta=1.3)
    for k, expect_lit in enumerate([True, True, False]):
        d = np.array([0.0, 0, 10]) - pts[k]
        cos = max(nrm[k] @ d / np.linalg.norm(d), 0)
        ref = 100 * cos / (d @ d) * float(fresnel_transmittance(cos, 1.3)) if expect_lit else 0.0
        np.testing.assert_allclose(c[k], ref, rtol=1e-12)
    w = np.array([1.0, 0, 1]) / np.sqrt(2)
    cd = directional_light_irradiance(nrm, w[None], [[2.0, 1.0, 0.5]], eta=1.3)
    np.testing.assert_allclose(cd[0], np.array([2, 1, 0.5]) * w[2] * float(fresnel_transmittance(w[2], 1.3)))
    assert np.all(cd[2] == 0)
    with pytest.raises(ValidationError, match="normals must have the shape of points"):
        point_light_irradiance(pts, nrm[:2], [[0.0, 0, 10]], 1.0)
    with pytest.raises(ValidationError, match="visible must have shape"):
        directional_light_irradiance(nrm, w[None], 1.0, visible=np.ones((2, 1), bool))


def test_uniform_sky_irradiance_matches_the_hemispherical_integral():
    # L = 1 over the upper hemisphere, quadrature by equal-area directions: c = 2π ∫ F_t(μ) μ dμ.
    n = 200_000
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d[:, 2] = np.abs(d[:, 2])
    c = environment_irradiance(np.array([[0.0, 0, 1]]), d, np.full(n, 2 * np.pi / n), eta=1.3)
    ref = 2 * np.pi * quad(lambda mu: float(fresnel_transmittance(mu, 1.3)) * mu, 0, 1)[0]
    assert c[0, 0] == pytest.approx(ref, rel=5e-3)
    # One direction of an environment is a directional light.
    one = environment_irradiance(np.array([[0.0, 0, 1]]), d[:1], [[1.0, 1, 1]])
    np.testing.assert_allclose(one, directional_light_irradiance(np.array([[0.0, 0, 1]]), d[:1], 1.0))


def test_environment_irradiance_of_more_patches_than_one_block():
    """The environment sum runs in blocks of 4,096 patches: every patch of every block gets its light."""
    rng = np.random.default_rng(5)
    normals = rng.normal(size=(9000, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    d = rng.normal(size=(6, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    normals[4095:4097] = normals[8191:8193] = d[0]  # the patches at the blocks' ends face a light
    l_omega = rng.uniform(0.1, 1.0, (6, 3))
    c = environment_irradiance(normals, d, l_omega)
    np.testing.assert_allclose(c, directional_light_irradiance(normals, d, l_omega), rtol=1e-12, atol=0)
    assert np.all(c[[4095, 4096, 8191, 8192]] > 0)


def test_eq_15_exitance_and_its_inverse():
    lo = np.array([0.1, 0.2])
    cos = np.array([1.0, 0.5])
    l = exitance_from_radiance(lo, cos, 1.3)
    np.testing.assert_allclose(l, np.pi * lo / fresnel_transmittance(cos, 1.3))
    np.testing.assert_allclose(radiance_from_exitance(l, cos, 1.3), lo)
    # Seen edge-on (F_t,o = 0) a patch's exitance is unknown, not 0 (a review found radiance read as no light).
    assert np.isnan(exitance_from_radiance(np.array([0.3]), np.array([0.0]), 1.3)).all()


def test_lights_masks_shadows_and_json(tmp_path):
    v, f = _plane(30, 10.0)
    floor = mesh_patches(v, f, spacing=None)
    # An occluding square 2 mm above the floor's centre, with the light straight above: its shadow.
    ov = np.array([[-1.0, -1, 2], [1, -1, 2], [1, 1, 2], [-1, 1, 2]])
    of = np.array([[0, 1, 2], [0, 2, 3]])
    mesh_v = np.concatenate([v, ov])
    mesh_f = np.concatenate([f, of + len(v)])
    p = Patches(floor.centre, floor.normal, floor.area, floor.corners, mesh_v, mesh_f)
    light = PointLight([0.0, 0, 200], 200.0**2)
    c = patch_irradiance(p, [light], eta=1.3)
    under = np.all(np.abs(p.centre[:, :2]) < 0.8, axis=1)
    outside = np.any(np.abs(p.centre[:, :2]) > 1.3, axis=1)
    assert np.all(c[under] == 0) and np.all(c[outside] > 0)
    # An edge: the plane through the light with normal +x lights x ≥ 0 only.
    edge = PointLight([0.0, 0, 200], 1.0, ([1.0, 0, 0],))
    ce = patch_irradiance(p, [edge], shadows=False)
    assert np.all(ce[p.centre[:, 0] < -0.1] == 0) and np.all(ce[p.centre[:, 0] > 0.1] > 0)
    spot = PointLight([0.0, 0, 200], 1.0, (), ([0, 0, -1.0], np.arctan2(2.0, 200)))
    cs = patch_irradiance(p, [spot], shadows=False)
    assert np.all(cs[np.linalg.norm(p.centre[:, :2], axis=1) > 2.1] == 0)
    lights = [edge, spot, DirectionalLight([0, 1, 1], [1, 2, 3]), EnvironmentLight([[0, 0, 1.0]], [0.5])]
    path = tmp_path / "lights.json"
    save_lights(path, lights, eta=1.3)
    back, eta = load_lights(path)
    assert eta == 1.3 and [type(x) for x in back] == [type(x) for x in lights]
    np.testing.assert_allclose(patch_irradiance(p, back, shadows=False), patch_irradiance(p, lights, shadows=False))
    path.write_text(json.dumps({"lights": [{"type": "laser"}]}))
    with pytest.raises(FacestatsError, match="light type must be one of"):
        load_lights(path)
    path.write_bytes(b'{"eta": 1.3, "lights": ["\xff"]}')  # not UTF-8: raised UnicodeDecodeError
    with pytest.raises(FormatError, match="cannot read the light description"):
        load_lights(path)


def test_an_environment_light_keeps_its_shadows_setting_through_a_file(tmp_path):
    """``shadows=False`` was not written and came back True (a reviewer); old files without it keep the default."""
    from facestats.acquire.lights import lights_from_dict

    path = save_lights(tmp_path / "lights.json", [EnvironmentLight([[0, 0, 1.0]], [0.5], shadows=False)])
    (back,), _ = load_lights(path)
    assert back.shadows is False
    (old,), _ = lights_from_dict(
        {"lights": [{"type": "environment", "directions": [[0, 0, 1]], "radiance_solid_angle": [1]}]}
    )
    assert old.shadows is True
    with pytest.raises(FormatError, match="environment light's shadows must be true or false, got 'no'"):
        lights_from_dict(
            {
                "lights": [
                    {"type": "environment", "directions": [[0, 0, 1]], "radiance_solid_angle": [1], "shadows": "no"}
                ]
            }
        )


def test_camera_matches_the_dome_and_round_trips(tmp_path):
    dome = default_dome()
    cam = PinholeCamera.from_dome(dome, 3)
    pts = np.random.default_rng(1).uniform(-50, 50, (20, 3))
    _, in_frame, pix = dome.view(pts, cameras=[3])
    np.testing.assert_allclose(cam.project(pts)[0], pix[:, 0] + 0.5)  # pixel centres: dome integers, here + ½
    np.testing.assert_array_equal(cam.in_frame(pts), in_frame[:, 0])
    cam.save(tmp_path / "cam.json")
    back = PinholeCamera.load(tmp_path / "cam.json")
    np.testing.assert_allclose(back.project(pts)[0], cam.project(pts)[0])
    with pytest.raises(ValidationError, match="rotation must be a rotation matrix"):
        PinholeCamera(cam.matrix, 2 * cam.rotation, cam.position, cam.image_size)
    (tmp_path / "cam.json").write_bytes(b'{"matrix": "\xff"}')  # not UTF-8: raised UnicodeDecodeError
    with pytest.raises(FormatError, match="cannot read the camera file"):
        PinholeCamera.load(tmp_path / "cam.json")


def test_a_camera_from_the_dome_agrees_with_it_at_the_image_edges():
    """from_dome copied the dome's K (pixel centres at integers) into a camera with pixel centres at + ½: every
    projection was half a pixel off and points just inside or outside an edge were classed wrongly; the dome's lens
    distortion was dropped without a word (a reviewer)."""
    from dataclasses import replace

    dome = default_dome()
    cam = PinholeCamera.from_dome(dome, 3)
    w, h = dome.image_size[3]
    edges = [(-0.5 + e, h / 2) for e in (-1e-3, 1e-3)] + [(w - 0.5 + e, h / 2) for e in (-1e-3, 1e-3)]
    edges += [(w / 2, -0.5 + e) for e in (-1e-3, 1e-3)] + [(w / 2, h - 0.5 + e) for e in (-1e-3, 1e-3)]
    pts = dome.camera_position[3] + 400.0 * dome.pixel_rays(3, np.array(edges))
    _, in_frame, pix = dome.view(pts, cameras=[3])
    np.testing.assert_array_equal(in_frame[:, 0], [False, True, True, False] * 2)
    np.testing.assert_allclose(cam.project(pts)[0], pix[:, 0] + 0.5, atol=1e-6)
    np.testing.assert_array_equal(cam.in_frame(pts), in_frame[:, 0])
    dist = np.zeros((dome.n_cameras, 5))
    dist[3, 0] = 0.1
    distorted = replace(dome, camera_distortion=dist)
    with pytest.raises(ValidationError, match=r"dome camera 3 has lens distortion \[0.1, 0.0"):
        PinholeCamera.from_dome(distorted, 3)
    np.testing.assert_array_equal(PinholeCamera.from_dome(distorted, 2).matrix, PinholeCamera.from_dome(dome, 2).matrix)
    np.testing.assert_array_equal(PinholeCamera.from_dome(distorted, 3, ignore_distortion=True).matrix, cam.matrix)


@pytest.mark.parametrize("ext", [".npz", ".exr", ".pfm"])
def test_patch_radiance_reads_back_a_rendered_image(tmp_path, ext):
    scene = pyramid_scene(5.0, "edge", image_size=200)
    p = scene.patches
    rng = np.random.default_rng(2)
    lo = rng.uniform(0.5, 1.5, (len(p), 3))
    img = render_patch_image(scene.camera, p, lo)
    path = write_radiance_image(tmp_path / f"img{ext}", img)
    back = read_radiance_image(path)
    l, seen = patch_radiance(back, scene.camera, p, eta=1.3)
    assert seen.sum() > 0.9 * len(p) and np.array_equal(seen, seen & camera_sees(scene.camera, p))
    to_cam = scene.camera.position - p.centre
    cos = np.einsum("mk,mk->m", p.normal, to_cam) / np.linalg.norm(to_cam, axis=1)
    ref = exitance_from_radiance(lo[seen], cos[seen], 1.3)
    np.testing.assert_allclose(l[seen], ref, rtol=1e-3 if ext == ".exr" else 1e-5)
    with pytest.raises(ValidationError, match="to match the camera's image_size"):
        patch_radiance(back[:-1], scene.camera, p)
    k = int(np.flatnonzero(seen)[0])
    x, y = scene.camera.project(p.centre[k : k + 1])[0][0]
    dark = back.copy()
    dark[int(np.floor(y)) - 2 : int(np.floor(y)) + 3, int(np.floor(x)) - 2 : int(np.floor(x)) + 3] = -0.25
    # the value as a number and where it is (it was "got np.float64(-0.25)": a user's run)
    with pytest.raises(ValidationError, match=r"radiance ≥ 0 .*got -0\.25 at pixel \(x [0-9.]+, y [0-9.]+\) \(patch"):
        patch_radiance(dark, scene.camera, p)


def test_renderer_is_the_point_kernel_and_reciprocal():
    rng = np.random.default_rng(4)
    pts = rng.uniform(0, 5, (60, 3))
    area = rng.uniform(0.05, 0.2, 60)
    c = np.zeros(60)
    c[7] = 1.0
    l = render_exitance(pts, area, c, 1.1, 0.05, eta=1.38, radius=np.inf)
    d = np.linalg.norm(pts - pts[7], axis=1)
    np.testing.assert_allclose(l, dipole_profile(d, 1.1, 0.05, 1.38) * area[7], rtol=1e-10)
    c2 = np.zeros(60)
    c2[11] = 1.0
    l2 = render_exitance(pts, area, c2, 1.1, 0.05, eta=1.38, radius=np.inf)
    # Reciprocity: light from 7 seen at 11, per unit source area, equals light from 11 seen at 7.
    assert l[11] / area[7] == pytest.approx(l2[7] / area[11], rel=1e-12)


def test_renderer_conserves_energy_on_a_uniformly_lit_plane():
    v, f = _plane(121, 24.0)
    p = mesh_patches(v, f, spacing=None)
    c = np.ones(len(p))
    s, a = 1.2, 0.12
    centre = np.linalg.norm(p.centre[:, :2], axis=1) < 0.5
    l = render_exitance(p.centre, p.area, c, s, a, eta=1.38, rows=np.nonzero(centre)[0])
    total = float(total_diffuse_reflectance(s, a, 1.38))
    assert np.median(l) == pytest.approx(total, rel=0.03)  # point-kernel quadrature of ∫ R dA over the plane
    r = cutoff_radius(s, a, 1.38)
    assert float(dipole_radial_energy(r, s, a, 1.38)) == pytest.approx((1 - 1e-4) * total, rel=1e-9)


def test_the_renderer_is_exact_by_default_and_the_cut_off_starves_far_rows():
    """render_exitance's default radius was cutoff_radius: it drops 1e-4 of the light in total but all of a far row's,
    which spoilt the contactless simulator's translucent cheeks (up to 89 % in sigma_tr). The default is now exact."""
    v, f = _plane(61, 24.0)
    p = mesh_patches(v, f, spacing=None)
    c = (p.centre[:, 0] < -10).astype(np.float64)  # a strip along one edge lit
    s, a = 2.0, 0.3  # cut-off radius 5.9 mm
    exact = render_exitance(p.centre, p.area, c, s, a, eta=1.38)
    np.testing.assert_array_equal(exact, render_exitance(p.centre, p.area, c, s, a, eta=1.38, radius=np.inf))
    r = cutoff_radius(s, a, 1.38)
    cut = render_exitance(p.centre, p.area, c, s, a, eta=1.38, radius=r)
    far = p.centre[:, 0] > -10 + r  # every lit patch beyond the radius
    assert far.any() and np.all(cut[far] == 0) and np.all(exact[far] > 0)
    assert cut.sum() == pytest.approx(exact.sum(), rel=2e-4)  # the total bound holds
    with pytest.raises(ValidationError, match="radius must be > 0 mm"):
        render_exitance(p.centre, p.area, c, s, a, radius=0.0)


def test_an_environment_probe_lights_patches_as_its_directional_lights_do():
    """A probe dark but for one block is the directional light of that block's direction and Σ L δΩ."""
    from facestats.model.sphere import latlong_light_samples

    v, f = _plane(12, 10.0)
    p = mesh_patches(v, f, spacing=None)
    probe = np.zeros((16, 32, 3), np.float32)
    probe[4:6, 0:2] = [3.0, 2.0, 1.0]  # sky in front of the plane (columns at the edges look towards +z)
    env = EnvironmentLight.from_probe(probe, (8, 16))
    d, power = latlong_light_samples(probe, 8, 16)
    k = int(np.argmax(power[:, 0]))
    sun = DirectionalLight(d[k], power[k])
    c = patch_irradiance(p, [env], shadows=False)
    assert np.all(c > 0)
    np.testing.assert_allclose(c, patch_irradiance(p, [sun], shadows=False), rtol=1e-6)
    # a median cut (an int) gives the four lit pixels lights of their own: the same total irradiance here
    cut = EnvironmentLight.from_probe(probe, 64)
    assert len(cut.directions) == 64
    np.testing.assert_allclose(cut.radiance_solid_angle.sum(0), power.sum(0), rtol=1e-6)
    np.testing.assert_allclose(patch_irradiance(p, [cut], shadows=False), c, rtol=0.01)


def test_a_camera_looking_at_its_own_position_is_refused_by_name():
    from facestats.acquire.camera import look_at

    with pytest.raises(ValidationError, match=r"target must differ from its position, got position \[1.0, 2.0, 3.0\]"):
        look_at([1, 2, 3], [1, 2, 3])
    with pytest.raises(ValidationError, match=r"\(camera 1\)"):
        look_at(np.array([[0.0, 0, 0], [1, 1, 1]]), np.array([[0.0, 0, 1], [1, 1, 1]]))
    rot = look_at([0, 0, -5.0], [0, 0, 0])
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rot[2], [0, 0, 1])  # forward row points at the target


def test_the_footprint_self_term_against_a_quadrature_of_the_surface():
    """A patch's own light over the disk of its area: the lit half of a flat plate of 1 mm patches within 5 % of a
    quadrature of the surface (sub-patches of 1/4 mm), where eq. 17's R(0) c A is 21 % too bright; with the near
    patches over their disks too ("surface"), within 0.5 %."""
    from facestats.acquire.synthetic.subsurface import half_lit_plate, render_exitance

    centre, area, c, surface = half_lit_plate(2.19, 0.0021, n=31)
    lit = c > 0
    rel = {
        st: render_exitance(centre, area, c, 2.19, 0.0021, eta=1.3, radius=np.inf, self_term=st)[lit] / surface[lit] - 1
        for st in ("point", "footprint", "surface")
    }
    assert np.median(rel["point"]) > 0.15  # measured +21 %, up to +42 %
    assert abs(np.median(rel["footprint"])) < 0.05 and np.abs(rel["footprint"]).max() < 0.06  # -4.2 %, up to 4.8 %
    assert abs(np.median(rel["surface"])) < 0.005 and np.abs(rel["surface"]).max() < 0.005  # -0.36 %, up to 0.42 %


def test_the_half_lit_plate_is_centred_and_refuses_an_odd_subdivision():
    from facestats.acquire.synthetic.subsurface import half_lit_plate

    centres, areas, c, l = half_lit_plate(2.19, 0.0021, n=5, sub=2)
    assert centres.shape == (25, 3) and (areas == 1).all() and c.sum() == 10  # two of five columns lit (x < 0)
    np.testing.assert_array_equal(np.unique(centres[:, 0]), [-2, -1, 0, 1, 2])
    row = np.abs(centres[:, 1]) < 0.5
    # the lit strip [-2.5, -0.5] is symmetric about x = -1.5; beyond it the exitance falls away from the light
    assert l[row][0] == pytest.approx(l[row][1], rel=1e-12) and np.all(np.diff(l[row][1:]) < 0)
    with pytest.raises(ValidationError, match="sub must be even"):
        half_lit_plate(2.19, 0.0021, sub=3)


def test_a_fifo_planted_as_a_light_or_camera_file_is_refused_without_blocking(tmp_path):
    import os

    for name, read in (("lights.json", load_lights), ("camera.json", PinholeCamera.load)):
        os.mkfifo(tmp_path / name)  # opening it for reading would wait for a writer for ever
        with pytest.raises(FormatError, match="not a regular file"):
            read(tmp_path / name)


def _fresnel_transmittance_by_hand(cos_o, eta):
    """1 − (r_s² + r_p²)/2 of the Fresnel equations, written out here (independent of facestats.model.fresnel)."""
    cos_t = np.sqrt(1 - (1 - cos_o**2) / eta**2)
    r_s = (cos_o - eta * cos_t) / (cos_o + eta * cos_t)
    r_p = (eta * cos_o - cos_t) / (eta * cos_o + cos_t)
    return 1 - (r_s**2 + r_p**2) / 2


@pytest.mark.parametrize(("elevation_deg", "eta"), [(0.0, 1.3), (60.0, 1.38)])
def test_render_exitance_image_is_eq_15_per_pixel(elevation_deg, eta):
    """A flat 20 mm square of two triangle patches of known exitance, seen from straight above or 60° off its normal:
    every pixel wholly inside a triangle holds F_t,o(η, cos θo) l / π of that patch (cos θo at its centre, F_t,o by
    hand), in each channel; pixels off the square are NaN in every channel; the image has the camera's (H, W)."""
    from facestats.acquire.synthetic.patch_image import render_exitance_image

    v = np.array([[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])  # counter-clockwise from +z: normals +z
    patches = mesh_patches(v, f, spacing=None)
    el = np.radians(elevation_deg)
    position = 200.0 * np.array([0.0, np.sin(el), np.cos(el)])
    camera = PinholeCamera.looking_at(position, (0, 0, 0), focal_px=800.0, image_size=(120, 100))  # 0.25 mm pixels
    l = np.array([[1.0, 2.0, 3.0], [0.5, 4.0, 0.25]])  # W mm^-2, per patch and channel
    img = render_exitance_image(camera, patches, l, eta=eta)
    assert img.shape == (100, 120, 3) and img.dtype == np.float32
    # by hand: cos θo at each patch's centre (the triangle's centroid), and the pixels' corners on the plane z = 0
    centroid = v[f].mean(axis=1)
    to_cam = position - centroid
    cos_o = to_cam[:, 2] / np.linalg.norm(to_cam, axis=1)
    expected = _fresnel_transmittance_by_hand(cos_o, eta)[:, None] * l / np.pi
    if elevation_deg:
        assert 0.49 < cos_o.min() < cos_o.max() < 0.52  # a test of the angle, not only of the normal incidence
    cols, rows = np.meshgrid(np.arange(120), np.arange(100))

    def on_plane(u, w):  # pixel coordinates (u right, w down) → the point of z = 0 the ray through them meets
        ray = np.stack([u, w, np.ones_like(u)], -1) @ np.linalg.inv(camera.matrix).T @ camera.rotation
        return position + ray * (-position[2] / ray[..., 2:3])

    corners = np.stack([on_plane(cols + du, rows + dv) for du in (0, 1) for dv in (0, 1)], 0)  # (4, H, W, 3)
    x, y = corners[..., 0], corners[..., 1]
    inside_square = np.all((np.abs(x) < 10) & (np.abs(y) < 10), axis=0)
    first = inside_square & np.all(x > y, axis=0)  # triangle 0: below the diagonal y = x
    second = inside_square & np.all(x < y, axis=0)
    assert first.sum() > 1000 and second.sum() > 1000
    np.testing.assert_allclose(img[first], np.broadcast_to(expected[0], img[first].shape), rtol=1e-6)
    np.testing.assert_allclose(img[second], np.broadcast_to(expected[1], img[second].shape), rtol=1e-6)
    centre = on_plane(cols + 0.5, rows + 0.5)
    off = np.max(np.abs(centre[..., :2]), axis=-1) > 10.5  # pixel centres more than 2 pixels off the square
    assert off.sum() > 1000 and np.isnan(img[off]).all()
    assert np.array_equal(np.isnan(img[..., 0]), np.isnan(img).any(axis=-1))  # NaN in all channels or none
    # eq. 15 read back at the patches' centres (facestats.acquire.scene.patch_radiance): the exitance
    back, seen = patch_radiance(img, camera, patches, eta=eta)
    assert seen.all()
    np.testing.assert_allclose(back, l, rtol=1e-6)


def test_render_exitance_image_channels_and_errors():
    """(m,) exitance gives one channel; C channels are rendered alike (each the one-channel image of its column);
    exitance of another length, negative or not finite is refused naming it."""
    from facestats.acquire.synthetic.patch_image import render_exitance_image

    scene = pyramid_scene(5.0, "edge", image_size=120)
    p = scene.patches
    l = np.random.default_rng(7).uniform(0.1, 1.0, len(p))
    one = render_exitance_image(scene.camera, p, l, eta=1.3)
    assert one.shape == (120, 120, 1)
    two = render_exitance_image(scene.camera, p, np.stack([l, 3 * l], 1), eta=1.3)
    assert two.shape == (120, 120, 2)
    np.testing.assert_array_equal(two[..., :1], one)
    np.testing.assert_allclose(two[..., 1], 3 * one[..., 0], rtol=1e-6)
    # NaN outside the pyramid: the image's corners see no patch, its centre (the apex) does
    assert np.isnan(one[[0, 0, -1, -1], [0, -1, 0, -1]]).all() and np.isfinite(one[60, 60]).all()
    m = len(p)
    with pytest.raises(ValidationError, match=rf"exitance must have shape \({m},\) or \({m}, C\), got \(3,\)"):
        render_exitance_image(scene.camera, p, np.ones(3), eta=1.3)
    bad = l.copy()
    bad[4] = -1.0
    with pytest.raises(ValidationError, match="exitance"):
        render_exitance_image(scene.camera, p, bad, eta=1.3)
    bad[4] = np.nan
    with pytest.raises(ValidationError, match="exitance"):
        render_exitance_image(scene.camera, p, bad, eta=1.3)


def test_reference_radiance_scale_is_the_lambertian_targets_radiance_over_its_pixels():
    """A matte target of reflectance ρ at x with normal N under a point light of intensity I at y has radiance
    ρ I (N·ω) / (π d²) (ω = (y − x)/d, no interface); an image k × too bright over it gives the factor 1/k per
    channel, and a grey image the factor of the channels' mean."""
    from facestats.acquire.scene import reference_radiance_scale

    intensity = np.array([1e4, 2e4, 5e3])
    lights = [PointLight(np.array([30.0, -20.0, 300.0]), intensity)]
    point, normal = np.array([5.0, 3.0, 1.0]), np.array([0.3, 0.0, 1.0]) / np.hypot(0.3, 1.0)
    to_light = lights[0].position - point
    d = np.linalg.norm(to_light)
    rho = np.array([0.5, 0.4, 0.6])
    radiance = rho * intensity * (normal @ to_light / d) / (np.pi * d * d)  # independent evaluation
    k = np.array([2.0, 3.5, 0.25])
    image = np.full((20, 30, 3), np.nan)
    mask = np.zeros((20, 30), bool)
    mask[5:9, 10:20] = True
    image[mask] = k * radiance
    scale = reference_radiance_scale(image, mask, rho, lights, point, normal)
    np.testing.assert_allclose(scale, 1 / k, rtol=1e-12)
    grey = np.where(mask, 3.0, np.nan)  # a grey camera: the mean of the channels' radiance
    scale = reference_radiance_scale(grey, mask, rho, lights, point, normal)
    np.testing.assert_allclose(scale, [np.mean(radiance) / 3.0], rtol=1e-12)
    cut = [PointLight(lights[0].position, intensity, (np.array([-1.0, 0.0, 0.0]),))]  # lights only x ≤ 30
    far = point + np.array([40.0, 0.0, 0.0])
    for args, message in (
        ((image, mask, rho, cut, far, normal), r"point must be lit by the lights .* got \[0.0, 0.0, 0.0\]"),
        ((image, mask[:, :20], rho, lights, point, normal), "mask must be a bool array of the image's shape"),
        ((image, np.zeros_like(mask), rho, lights, point, normal), "mask must select the target's pixels"),
        ((np.where(mask[..., None], 0.0, image), mask, rho, lights, point, normal), "got 120 of 120 values"),
        ((image, mask, 1.5, lights, point, normal), "reflectance must lie in"),
        ((image, mask, [0.5, 0.5], lights, point, normal), "reflectance must be one value or one per R, G, B"),
    ):
        with pytest.raises(ValidationError, match=message):
            reference_radiance_scale(*args)


def test_reference_radiance_scale_of_a_grey_image_under_a_light_without_one_colour():
    """A grey image is fitted against the mean of the lights' R, G and B irradiance, so a light with no green (a
    magenta lamp) still gives its target a radiance, mean(ρ E) / π; the scale was refused ("irradiance > 0 in every
    channel"). An RGB image under that light has no green to scale and is refused, naming the channel."""
    from facestats.acquire.scene import reference_radiance_scale

    intensity = np.array([1e4, 0.0, 5e3])
    lights = [PointLight(np.array([0.0, 0.0, 200.0]), intensity)]
    point, normal = np.zeros(3), np.array([0.0, 0.0, 1.0])
    rho = np.array([0.5, 0.4, 0.6])
    mask = np.ones((4, 6), bool)
    radiance = rho * intensity / (np.pi * 200.0**2)  # facing the light at 200 mm
    grey = np.full((4, 6), 2.0)
    np.testing.assert_allclose(reference_radiance_scale(grey, mask, rho, lights, point, normal), [radiance.mean() / 2])
    with pytest.raises(
        ValidationError, match=r"irradiance > 0 in every channel of an RGB image .* got \[.*, 0\.0, .*\]"
    ):
        reference_radiance_scale(np.ones((4, 6, 3)), mask, rho, lights, point, normal)
