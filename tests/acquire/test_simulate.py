"""The dome and contact-sensor simulator (Weyrich et al. 2006 §5, §5.4) and captures on disk."""

import dataclasses
import os
import shutil

import numpy as np
import pytest

from facestats.acquire.capture import ALL_CHUNKS_ATTR, open_capture
from facestats.acquire.dome import Dome, default_dome, look_at
from facestats.acquire.hdr import CameraResponse
from facestats.acquire.synthetic.population import SubjectTruth, synthesize_population
from facestats.acquire.synthetic.simulate import DomeSimulator
from facestats.errors import FormatError, ValidationError
from facestats.face.geometry import FaceGeometry
from facestats.face.procedural import procedural_face
from facestats.model import brdf, dipole
from facestats.model.fresnel import fresnel_reflectance, fresnel_transmittance


@pytest.fixture(scope="module")
def pop32():
    return synthesize_population(map_size=32, geometry=procedural_face(32), conditions=False)


@pytest.fixture(scope="module")
def sim32():
    return DomeSimulator(procedural_face(32))


def test_same_seed_gives_bit_identical_captures(pop32, sim32):
    a = sim32.simulate(pop32[3])
    b = sim32.simulate(pop32[3])
    c = sim32.simulate(pop32[3], seed=99)
    for k in a.arrays:
        assert a.array(k).tobytes() == b.array(k).tobytes(), k
    assert a.array("radiance").tobytes() != c.array("radiance").tobytes()


def test_valid_samples_per_lumitexel_match_the_paper():
    # §5: "about 900 BRDF samples per color channel, with many lumitexels having up to 1,200".
    sim = DomeSimulator(procedural_face(64))
    n = sim.samples_per_lumitexel()
    assert 850 <= np.median(n) <= 1000
    assert np.percentile(n, 90) <= 1300
    frontal = np.abs(sim.geometry.normal[:, 2]) > 0.9
    assert 850 <= np.median(n[frontal]) <= 1100


def test_noise_free_radiance_is_the_skin_model(pop32):
    from facestats.model import skin

    g = procedural_face(32)
    sim = DomeSimulator(g, noise=False, block=100)  # several blocks: local (flat-patch) transport
    truth = pop32[5]
    cap = sim.simulate(truth)
    lt = cap.lumitexels(200, 260)
    tex = g.texel_index(32)[200:260]
    alb = truth.albedo[tex[:, 0], tex[:, 1]]
    sp, sa = truth.scattering
    normal = g.normal[200:260]
    wi, e_perp = sim.dome.incident(g.position[200:260])
    cos_i = np.einsum("nk,nlk->nl", normal, wi)
    model = skin.skin_radiance(
        normal,
        wi,
        e_perp * np.maximum(cos_i, 0)[..., None],
        lt.wo.astype(float),
        rho_s=truth.ts_rho_s[tex[:, 0], tex[:, 1]],
        roughness=truth.ts_m[tex[:, 0], tex[:, 1]],
        modulation=alb / truth.albedo_avg,
        subsurface=skin.SubsurfaceTransport(sp, sa),
    )
    valid = lt.valid
    assert valid.sum() > 20000
    np.testing.assert_allclose(lt.radiance[valid], model[valid], rtol=2e-3, atol=1e-7)  # float16 storage


def _flat_patch_geometry():
    x = np.arange(-2, 3, 1.0)
    xx, yy = np.meshgrid(x, x)
    pos = np.stack([xx.ravel(), yy.ravel(), np.zeros(25)], 1)
    verts = np.array([[-60.0, -60, 0], [60, -60, 0], [60, 60, 0], [-60, 60, 0]])
    return FaceGeometry(
        position=pos,
        normal=np.tile([0, 0, 1.0], (25, 1)),
        area=np.ones(25),
        uv=(pos[:, :2] + 2.5) / 5,
        region=np.full(25, 7),
        map_size=4,
        mesh_vertices=verts,
        mesh_faces=np.array([[0, 1, 2], [0, 2, 3]]),
        region_map=np.full((4, 4), 7, np.uint8),
        meta={"mesh_grid": 32},
    )


def test_energy_conservation_of_simulated_radiance():
    """Reflected flux over a dense hemisphere of cameras equals (and never exceeds) the incident flux × albedo."""
    n_cam = 900
    k = np.arange(n_cam) + 0.5
    z = 1 - k / n_cam  # equal-area bands over the upper hemisphere
    phi = np.pi * (1 + 5**0.5) * k
    dirs = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], 1)
    cam_pos = 2000.0 * dirs
    th = np.radians(40.0)
    led = np.array([[1000 * np.sin(th), 0.0, 1000 * np.cos(th)]])
    f = 64.0
    dome = Dome(
        led_position=led,
        led_axis=-led / 1000,
        led_intensity=np.array([[1e6, 1e6, 1e6]]),
        led_beam=np.array([[1.0, 0, 0, 0, 0, 0]]),
        camera_position=cam_pos,
        camera_rotation=look_at(cam_pos, [0, 0, 0]),
        camera_matrix=np.tile([[f, 0, 32], [0, f, 32], [0, 0, 1]], (n_cam, 1, 1)),
        image_size=np.full((n_cam, 2), 64),
        exposure_times=np.array([1.0]),
        camera_scale=1.0,
        response=CameraResponse(),
    )
    g = _flat_patch_geometry()
    albedo = np.array([0.5, 0.3, 0.2])
    full = np.ones((4, 4))
    truth = SubjectTruth(
        subject_id="E",
        person_id="E",
        age=30,
        gender="M",
        skin_type=3,
        condition="normal",
        region_map=g.region_map,
        albedo=(full[..., None] * albedo).astype(np.float32),
        ts_rho_s=(0.25 * full).astype(np.float32),
        ts_m=(0.3 * full).astype(np.float32),
        bp_rho_s=full.astype(np.float32),
        bp_exponent=full.astype(np.float32),
        site_sigma_tr=np.ones((3, 3)),
        site_albedo=np.tile(albedo, (3, 1)),
        sigma_tr=np.array([0.55, 0.98, 1.55]),
    )
    sim = DomeSimulator(g, dome, noise=False, scan_normal_noise_deg=0, shadow_resolution=64)
    cap = sim.simulate(truth)
    lt = cap.lumitexels(12, 13)  # the centre point
    rad = lt.radiance[0, :, 0, :]  # (camera, channel)
    e = lt.irradiance[0, 0] * np.cos(th)
    cos_o = dirs[:, 2]
    seen = np.isfinite(rad[:, 0])
    assert seen.sum() > 0.97 * n_cam
    flux = np.nansum(rad * cos_o[:, None], axis=0) * (2 * np.pi / n_cam) / e  # reflected / incident
    mu = np.linspace(0, 1, 20001)
    f_ext = 2 * np.trapezoid(fresnel_reflectance(mu, 1.38) * mu, mu)
    diffuse = albedo * fresnel_transmittance(np.cos(th)) * (1 - f_ext)
    wo = dirs
    spec = (
        np.sum(brdf.torrance_sparrow([0, 0, 1.0], [np.sin(th), 0, np.cos(th)], wo, 0.25, 0.3) * cos_o)
        * 2
        * np.pi
        / n_cam
    )
    np.testing.assert_allclose(flux, diffuse + spec, rtol=0.03)
    assert np.all(flux < 1)


def test_capture_round_trip_through_zarr(tmp_path, pop32, sim32):
    cap = sim32.simulate(pop32[1])
    path = cap.to_zarr(tmp_path / "cap.zarr", chunk=300)
    back = open_capture(path)
    for k in cap.arrays:
        np.testing.assert_array_equal(back.array(k), cap.array(k), err_msg=k)
    assert back.metadata == cap.metadata and back.dome.n_leds == 150 and back.sensor.n_fibers == 28
    a, b = cap.lumitexels(100, 400), back.lumitexels(100, 400)
    np.testing.assert_array_equal(a.radiance, b.radiance)
    np.testing.assert_array_equal(a.valid, b.valid)


def test_a_deleted_capture_chunk_is_refused_while_an_all_invalid_one_reads(tmp_path, pop32, sim32):
    """zarr leaves out chunks of fill values; a capture keeps them, so a missing chunk is damage, not NaNs."""
    cap = sim32.simulate(pop32[1])
    cap.arrays["radiance"] = cap.array("radiance").copy()
    cap.arrays["radiance"][:300] = np.nan  # the first chunk: no valid sample at all
    path = cap.to_zarr(tmp_path / "cap.zarr", chunk=300)
    back = open_capture(path)
    assert back.attrs[ALL_CHUNKS_ATTR] is True
    assert np.isnan(back.lumitexels(0, 300).radiance).all()  # read as written
    np.testing.assert_array_equal(back.array("radiance"), cap.array("radiance"))
    chunks = sorted(os.listdir(tmp_path / "cap.zarr" / "radiance" / "c"))
    assert chunks[0] == "0"  # the all-NaN chunk is on disk
    shutil.rmtree(tmp_path / "cap.zarr" / "radiance" / "c" / "1")
    with pytest.raises(FormatError, match=r"array 'radiance' has \d+ of its \d+ chunks on disk"):
        open_capture(path)


def test_a_capture_names_a_missing_sensor_key_and_the_part_it_could_not_read(pop32, sim32):
    """``Capture.sensor`` let a KeyError through; an unreadable array's message said "lumitexels None:None" for a
    whole read and hit an AttributeError for an index that is not a slice (a reviewer)."""
    import json

    from facestats.acquire.capture import Capture

    cap = sim32.simulate(pop32[1])
    sensor = json.loads(cap.attrs["sensor"])
    del sensor["n_exposures"]
    with pytest.raises(FormatError, match="contact sensor description is missing the key 'n_exposures'"):
        Capture(dict(cap.arrays), {**cap.attrs, "sensor": json.dumps(sensor)}).sensor

    class Damaged:
        shape = cap.arrays["radiance"].shape

        def __getitem__(self, sl):
            raise RuntimeError("error during blosc decompression: -1")

    n = cap.n_lumitexels
    cap.arrays["radiance"] = Damaged()
    for sl, part in (
        (slice(None), f"lumitexels 0:{n}"),
        (slice(100, 400), "lumitexels 100:400"),
        (slice(-5, None), f"lumitexels {n - 5}:{n}"),
        (7, "lumitexels index 7"),
        ([1, 2], r"lumitexels index \[1, 2\]"),
    ):
        with pytest.raises(FormatError, match=f"array 'radiance', {part}, cannot be read .*blosc"):
            cap.array("radiance", sl)


def test_streaming_simulation_equals_in_memory(tmp_path, pop32):
    sim = DomeSimulator(procedural_face(32), block=256)
    path = sim.simulate_to_zarr(pop32[2], tmp_path / "s.zarr")
    mem = sim.simulate(pop32[2])
    disk = open_capture(path)
    for k in mem.arrays:
        assert disk.array(k).tobytes() == mem.array(k).tobytes(), k


def test_sensor_site_profiles_are_the_dipole(pop32):
    sim = DomeSimulator(procedural_face(32), noise=False)
    truth = pop32[7]
    cap = sim.simulate(truth)
    sp, sa = truth.site_scattering
    r = cap.array("fiber_distance")
    expect = dipole.dipole_profile(r[None, :, None], sp[:, None, :], sa[:, None, :])
    np.testing.assert_allclose(cap.array("sensor_profile"), expect, rtol=1e-12)


def test_another_index_of_refraction_keeps_the_albedo_and_is_recorded(pop32):
    """(σ's, σa) came from the truth's albedo at skin's η = 1.38 whatever η the simulator rendered with, so at
    η = 1.3 the sensor's profiles integrated to 1.02-1.05 × the site albedo, and η was not recorded (an audit)."""
    import json

    from facestats.model.fitting import fit_translucency

    truth = pop32[7]
    cap = DomeSimulator(procedural_face(32), noise=False, eta=1.3).simulate(truth)
    fit = fit_translucency(cap.array("fiber_distance"), np.moveaxis(cap.array("sensor_profile"), 1, 2), eta=1.3)
    rd = dipole.total_diffuse_reflectance(fit.sigma_s_prime, fit.sigma_a, 1.3)
    np.testing.assert_allclose(rd, truth.site_albedo, rtol=1e-3)
    assert json.loads(cap.attrs["provenance"])["eta"] == 1.3


def test_head_motion_perturbs_the_samples(pop32):
    g = procedural_face(32)
    still = DomeSimulator(g, noise=False).simulate(pop32[0]).array("radiance").astype(float)
    moved = DomeSimulator(g, noise=False, head_motion_deg=0.5).simulate(pop32[0]).array("radiance").astype(float)
    both = np.isfinite(still) & np.isfinite(moved) & (still > 1e-3)
    rel = np.abs(moved[both] / still[both] - 1)
    assert 1e-4 < np.median(rel) < 0.05


def test_dome_calibration_round_trip(tmp_path):
    d = default_dome()
    d.save(tmp_path / "dome.json")
    e = Dome.load(tmp_path / "dome.json")
    np.testing.assert_allclose(e.led_position, d.led_position)
    np.testing.assert_allclose(e.camera_matrix, d.camera_matrix)
    assert d.n_leds == 150 and d.n_cameras == 16


@pytest.mark.slow
def test_float32_directions_are_the_rounded_float64_ones_with_either_backend():
    """Dome.directions32: the compiled pass and numpy give the float64 unit vectors rounded, bit for bit."""
    dome = default_dome()
    pts = np.random.default_rng(3).normal(scale=60.0, size=(500, 3))
    want = (dome.light_directions(pts).astype(np.float32), dome.view_directions(pts).astype(np.float32))
    for backend in ("numba", "numpy"):
        for got, ref in zip(dome.directions32(pts, backend=backend), want):
            assert got.dtype == np.float32
            np.testing.assert_array_equal(got, ref, strict=True)
    np.testing.assert_allclose(np.linalg.norm(want[0], axis=-1), 1, atol=1e-6)
    at_led = dome.led_position[:1]  # a point at an LED: no direction (NaN) with either backend
    for backend in ("numba", "numpy"):
        with np.errstate(invalid="ignore"):  # numpy's 0/0
            assert np.isnan(dome.directions32(at_led, backend=backend)[0][0, 0]).all()
        with pytest.raises(ValidationError, match="points"):
            dome.directions32(pts[:, :2], backend=backend)


def test_real_mesh_loader_round_trip(tmp_path):
    from facestats.io.mesh import load_face_mesh, save_face_mesh

    g = procedural_face(48, mesh_grid=48)
    save_face_mesh(g, tmp_path / "face.obj", tmp_path / "regions.npy")
    h = load_face_mesh(tmp_path / "face.obj", tmp_path / "regions.npy")
    assert h.n_points == g.n_points and h.map_size == 48
    from scipy.spatial import cKDTree

    dist, match = cKDTree(g.position).query(h.position)
    assert dist.max() < 1e-4 and np.unique(match).size == h.n_points
    np.testing.assert_array_equal(h.region, g.region[match])
    ang = np.degrees(np.arccos(np.clip(np.sum(h.normal * g.normal[match], 1), -1, 1)))
    assert np.median(ang) < 2.0
    np.testing.assert_allclose(h.area.sum(), g.area.sum(), rtol=0.1)
    # and it can be simulated
    pop = synthesize_population(map_size=48, conditions=False, geometry=h)
    cap = DomeSimulator(h).simulate(pop[0])
    assert np.isfinite(cap.array("radiance")).mean() > 0.2


def test_uv_to_texel_is_the_map_cell_containing_the_uv():
    from facestats.face.geometry import uv_to_texel

    uv = np.array([[0.0, 0.0], [0.999, 0.0], [1.0, 1.0], [0.26, 0.74], [0.5, 0.25]])
    np.testing.assert_array_equal(uv_to_texel(uv, 4), [[0, 0], [0, 3], [3, 3], [2, 1], [1, 2]])  # (v, u)
    g = procedural_face(16)
    np.testing.assert_array_equal(g.texel_index(), g.grid_index)  # lumitexels sit at texel centres


def test_simulator_and_calibration_reject_bad_arguments():
    from facestats import FacestatsError

    g = procedural_face(16)
    with pytest.raises(FacestatsError, match=r"block must be an integer in \[1, inf\], got 0"):
        DomeSimulator(g, block=0)
    with pytest.raises(FacestatsError, match=r"subsurface_radius must lie in \(0, inf\] mm, got -1"):
        DomeSimulator(g, subsurface_radius=-1.0)
    with pytest.raises(FacestatsError, match="head_motion_deg must lie in"):
        DomeSimulator(g, head_motion_deg=-0.5)
    with pytest.raises(FacestatsError, match=r"eta must lie in \[1, 3\]"):
        DomeSimulator(g, eta=0.7)
    with pytest.raises(FacestatsError, match="geometry must be a FaceGeometry, got ndarray"):
        DomeSimulator(np.zeros((3, 3)))
    with pytest.raises(FacestatsError, match="specular must be one of"):
        DomeSimulator(g, specular="phong")
    d = default_dome().to_dict()
    d["led_axis"][0] = [0.0, 0.0, 2.0]
    with pytest.raises(FacestatsError, match="led_axis must hold unit vectors .*norm 2"):
        Dome.from_dict(d)
    d = default_dome().to_dict()
    d["led_intensity"][5][1] = -1.0
    with pytest.raises(FacestatsError, match=r"led_intensity must lie in \[0, inf\], got -1"):
        Dome.from_dict(d)
    d = default_dome().to_dict()
    d["cameras"][2]["R"] = np.diag([1.0, 1.0, 2.0]).tolist()
    with pytest.raises(FacestatsError, match="camera_rotation must hold rotation matrices .*camera 2"):
        Dome.from_dict(d)


def test_maps_finer_than_the_lumitexel_grid_simulate_and_fit():
    """Issue 19 item 0: with maps finer than the lumitexel grid, some lumitexels' own texels lie off the face
    (zero truth there); they read the nearest face texel instead of producing NaN radiance."""
    from facestats.pipeline import FitSettings, fit_subject

    geom = procedural_face(24, map_size=96)
    tex, snapped = geom.texel_index(), geom.face_texel_index()
    off = geom.region_map[tex[:, 0], tex[:, 1]] == 0
    assert off.sum() > 0  # the case exists at this size
    assert np.all(geom.region_map[snapped[:, 0], snapped[:, 1]] > 0)
    np.testing.assert_array_equal(snapped[~off], tex[~off])
    assert np.all(np.abs(snapped[off] - tex[off]).max(1) <= 2)  # the nearest face texel is a neighbour
    pop = synthesize_population(map_size=96, geometry=geom, conditions=False, subjects=["S001"])
    cap = DomeSimulator(geom).simulate(pop[0])
    rad = cap.array("radiance").astype(np.float32)
    n_finite = np.isfinite(rad).all(-1).sum((1, 2))
    assert np.all(n_finite[off] > 100)
    ds = fit_subject(cap, np.array([0.55, 0.98, 1.55]), FitSettings(micro_normals=False))
    face = ds.region.values > 0
    assert np.all(np.isfinite(ds.ts_m.values[face])) and np.all(ds.ts_m.values[face] > 0)


def test_truth_without_skin_at_a_lumitexel_is_a_clear_error(pop32):
    from facestats.errors import ValidationError

    g = procedural_face(32)
    truth = pop32[0]
    bad = dataclasses.replace(truth, ts_m=np.zeros_like(truth.ts_m))
    with pytest.raises(ValidationError, match=rf"ts_m > 0.*; {g.n_points} lumitexel\(s\) read .*ts_m=0\.0"):
        DomeSimulator(g).simulate(bad)
