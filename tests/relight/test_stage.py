"""The virtual light stage: the skin model per sample, stage field relit = direct render, camera and geometry."""

import numpy as np
import pytest

import facestats
from facestats.errors import ValidationError
from facestats.model.skin import SubsurfaceTransport, skin_radiance
from facestats.model.sphere import light_stage_directions
from facestats.relight import stage
from facestats.relight.field import open_field
from facestats.relight.lighting import resample_probe, sky_probe
from facestats.relight.relighting import relight
from facestats.relight.shadows import disagreement_causes, shadow_agreement, threshold_shadow_maps
from tests.helpers import random_hemisphere

SIZE = 24  # image side of the small stage renders
LIGHTS = (16, 8)  # n_theta, n_phi


@pytest.fixture(scope="module")
def subject():
    with facestats.open_store() as store:
        return store.subject("S001").load()


@pytest.fixture(scope="module")
def geometry(subject):
    return stage.subject_geometry(subject, mesh_grid=32)


@pytest.fixture(scope="module")
def stage_field(subject, geometry):
    d, _ = light_stage_directions(*LIGHTS)
    return stage.light_stage_field(subject, stage.stage_camera(size=SIZE), geometry=geometry, directions=d,
                                   visibility=True)  # fmt: skip


@pytest.mark.parametrize("model", ["torrance_sparrow", "blinn_phong"])
def test_factored_evaluation_equals_skin_radiance_sample_by_sample(rng, model):
    n_pix, n_l = 40, 25
    normal = random_hemisphere(rng, n_pix)
    view = random_hemisphere(rng, n_pix, min_cos=0.3)
    lights = rng.normal(size=(n_l, 3))
    lights /= np.linalg.norm(lights, axis=1, keepdims=True)
    mod = rng.uniform(0.5, 1.5, (n_pix, 3))
    rho = rng.uniform(0.05, 0.4, n_pix)
    rough = rng.uniform(0.15, 0.5, n_pix) if model == "torrance_sparrow" else rng.uniform(5, 60, n_pix)
    vis = rng.uniform(0, 1, (n_pix, n_l))
    transport = SubsurfaceTransport([1.0, 0.8, 0.9], [0.09, 0.3, 0.55])
    sh = stage.SubjectShading.from_parameters(normal, view, mod, rho, rough, transport, specular=model)
    spec, shape = sh.factors(lights, view, vis)
    ours = spec[..., None] + shape[..., None] * sh.colour[:, None, :]
    cos = np.clip(normal @ lights.T, 0, None) * vis
    ref = skin_radiance(normal, np.broadcast_to(lights, (n_pix, n_l, 3)), np.repeat(cos[..., None], 3, -1),
                        view[:, None, :], rho_s=rho, roughness=rough, modulation=mod, subsurface=transport,
                        specular=model)[:, 0]  # fmt: skip
    assert np.allclose(ours, ref, rtol=2e-5, atol=1e-7)


def test_stage_field_relit_equals_the_direct_render(subject, geometry, stage_field, tmp_path):
    d, _ = light_stage_directions(*LIGHTS)
    cam = stage.stage_camera(size=SIZE)
    field = stage_field
    assert field["reflectance"].shape == (8, 16, SIZE, SIZE, 3)
    m = field["mask"].values
    assert 0.2 < m.mean() < 0.6
    lw = resample_probe(sky_probe(32), d)
    direct, mask = stage.render_subject(subject, lw, d, cam, geometry=geometry)
    assert np.array_equal(mask, m)
    relit = relight(field, lw)
    rel = np.abs(relit - direct)[m] / direct[m]
    assert rel.max() <= 1e-3
    # The same field streamed tile by tile into zarr (float32) is the same to the last bits (the products
    # run over tiles of other sizes, so a few values may round differently).
    on_disk = stage.light_stage_field(subject, cam, geometry=geometry, directions=d, out=tmp_path / "s.zarr", tile=8)
    np.testing.assert_allclose(
        open_field(tmp_path / "s.zarr")["reflectance"].values, field["reflectance"].values, rtol=1e-6, atol=1e-8
    )
    assert np.allclose(relight(on_disk, lw), relit, rtol=1e-6)


@pytest.fixture(scope="module")
def diffuse_field(subject, geometry):
    """The stage field of S001 without its specular (ρs = 0): every pixel's brightest light is a diffuse one."""
    matte = subject.copy()
    matte["ts_rho_s"] = matte["ts_rho_s"] * 0
    d, _ = light_stage_directions(*LIGHTS)
    return stage.light_stage_field(matte, stage.stage_camera(size=SIZE), geometry=geometry, directions=d,
                                   visibility=True)  # fmt: skip


def test_threshold_shadow_maps_equal_the_geometric_visibility_where_the_light_clears_the_threshold(diffuse_field):
    """D6 (Debevec §4.4). Without highlights a sample's reflectance is colour · F_t(N·l) N·l · V (Weyrich eq. 6,
    local transport) and its maximum at most colour · F_t(1) = 0.974 colour (η = 1.38), so at a 2 % threshold
    every unshadowed (V = 1) sample with N·l ≥ 0.07 (F_t N·l = 0.0245 > 0.02 × 0.974) is lit and every shadowed
    one (V = 0, reflectance 0) dark: there the map must equal the visibility sample for sample, at any image size
    and light grid.  Left out: partial visibility (0 < V < 1, a shadow edge across the pixel's triangle) and light
    within 4° of the horizon, which brightness cannot tell from shadow; with highlights, see the causes test."""
    field = diffuse_field
    v = field["visibility"].values
    visible = v > 0.5
    cos = np.einsum("pqk,yxk->pqyx", field["direction"].values, field["normal"].values)
    decidable = field["mask"].values & ((v == 0) | ((v == 1) & (cos >= 0.07)))
    assert decidable.sum() > 0.9 * decidable[:, :, field["mask"].values].size  # 18,356 of 19,968 samples
    raw = threshold_shadow_maps(field, 0.02, clean=0)
    np.testing.assert_array_equal(raw[decidable], visible[decidable])
    assert not threshold_shadow_maps(field, 0.04, clean=0)[decidable & visible].all()  # a threshold 2× too high
    # The cleaning (3 × 3 opening and closing) changes 46 of the 18,356 samples on the 16 × 8 grid, whose cells
    # are 22.5° wide (thin lit or dark regions of the light sphere); one light's visibility inverted changes 144+.
    assert (threshold_shadow_maps(field, 0.02) == visible)[decidable].mean() >= 0.995
    counts = decidable.sum((2, 3))
    wrong = visible.copy()
    wrong[np.unravel_index(np.argsort(counts, axis=None)[counts.size // 2], counts.shape)] ^= True  # the median light
    assert (threshold_shadow_maps(field, 0.02) == wrong)[decidable].mean() < 0.995


def test_every_shadow_disagreement_of_the_stage_field_has_its_cause(stage_field, diffuse_field):
    """With highlights a pixel's maximum can be a specular peak, which raises its 2 % threshold above the diffuse
    light of some unshadowed samples (docs/relighting.md D6). :func:`disagreement_causes` names it from the
    Fresnel-weighted cosine; the field without specular (ρs = 0) tells it independently: those samples are lit
    there."""
    field = stage_field
    v, mask = field["visibility"].values, field["mask"].values
    assert not (v[:, :, ~mask] > 0).any()
    assert not (field["reflectance"].values[(v == 0) & mask] > 0).any()  # no light reaches a shadowed sample
    code = disagreement_causes(field, 0.02, band=0)  # all samples: the band of 31.8° leaves no highlight here
    lit = threshold_shadow_maps(field, 0.02)
    totals = shadow_agreement(lit, v > 0.5, band=0, mask=mask)
    assert (code >= 0).sum() == totals["compared"]
    assert np.isin(code, [1, 2, 3, 4]).sum() == totals["false_shadow"]
    assert np.isin(code, [5, 6, 7]).sum() == totals["false_lit"]
    assert (code == 4).sum() > 0 and (code == 3).sum() > 0  # specular peaks and grazing light
    assert not (code == 7).any()  # no light in geometric shadow
    assert not np.isin(disagreement_causes(field, 0.02, band=1), [3, 4, 7]).any()  # the band holds them
    raw = threshold_shadow_maps(field, 0.02, clean=0)
    matte = threshold_shadow_maps(diffuse_field, 0.02, clean=0)
    full = v == 1
    np.testing.assert_array_equal((code == 4) & full, (code >= 0) & full & ~lit & ~raw & matte)


def test_camera_and_view_surface_conventions(geometry):
    cam = stage.stage_camera(size=32)
    assert np.allclose(cam.position, [0, 0, 1240])  # frontal camera on +z
    rays = cam.rays()
    centre = rays[15:17, 15:17].mean((0, 1))
    assert np.allclose(centre / np.linalg.norm(centre), [0, 0, -1], atol=1e-3)
    assert rays[16, 31, 0] > rays[16, 0, 0]  # image right is +x for the frontal camera
    assert rays[0, 16, 1] > rays[31, 16, 1]  # image top is +y
    surf = stage.view_surface(geometry, cam)
    assert np.allclose(np.linalg.norm(surf.view, axis=1), 1) and surf.view[:, 2].min() > 0.99
    assert surf.uv.min() >= 0 and surf.uv.max() <= 1
    assert np.allclose(surf.bary.sum(1), 1)
    side = stage.stage_camera(90, size=8)
    assert np.allclose(side.position, [1200, 0, 40])
    assert np.allclose(stage.stage_camera(-30, size=8).position[0], -600)  # negative azimuth: the subject's right


def test_several_cameras_give_one_field_each(subject, geometry):
    d, _ = light_stage_directions(8, 4)
    cams = [stage.stage_camera(-25, size=10), stage.stage_camera(25, size=10)]  # Debevec's left and right cameras
    left, right = stage.light_stage_field(subject, cams, geometry=geometry, directions=d, shadows=False)
    assert left["view"].values[5, 5, 0] < 0 < right["view"].values[5, 5, 0]
    assert left.attrs["camera_position_mm"] != right.attrs["camera_position_mm"]


def test_subjects_without_a_known_geometry_are_refused(subject):
    other = subject.copy()
    other.attrs["provenance"] = '{"capture_provenance": {"geometry": "scan-7"}}'
    with pytest.raises(ValidationError, match="'scan-7', not a face facestats can rebuild"):
        stage.subject_geometry(other)
    with pytest.raises(ValidationError, match="StageCamera"):
        stage.light_stage_field(subject, camera="front")
    with pytest.raises(ValidationError, match="one RGB weight per light"):
        stage.render_subject(subject, np.ones((5, 3)), camera=stage.stage_camera(size=8))
    with pytest.raises(ValidationError, match=r"shape \(L, 3\), got \(2048,\)"):
        stage.render_subject(subject, np.ones(2048), camera=stage.stage_camera(size=8))
    with pytest.raises(ValidationError, match="lighting must be within the float32 range"):
        stage.render_subject(subject, np.full((2048, 3), 1e39), camera=stage.stage_camera(size=8))
    for lights in ((8,), (8, 4, 2), 8):
        with pytest.raises(ValidationError, match=r"lights must be \(n_theta, n_phi\)"):
            stage.relight_subject(subject, sky_probe(16), lights=lights, camera=stage.stage_camera(size=8))


@pytest.mark.parametrize("clean", [1, 2, 3])
def test_shadow_map_cleaning_does_not_depend_on_where_azimuth_starts(rng, clean):
    """The azimuth wraps: turning the light grid turns the cleaned map. With c + 1 padded columns an opening or
    closing of c ≥ 2 steps (which reads 2c cells away) changed columns at the seam (an audit)."""
    values = np.repeat((rng.uniform(size=(32, 64, 4, 5, 1)) > 0.4).astype(float), 3, axis=-1)  # 20 binary maps
    lit = threshold_shadow_maps(values, 0.5, clean=clean)
    for k in (5, 32):
        turned = threshold_shadow_maps(np.roll(values, k, axis=1), 0.3, clean=clean)
        np.testing.assert_array_equal(turned, np.roll(lit, k, axis=1))
    # More cleaning than the grid is wide keeps the grid's shape (the pad of 2c + 1 columns cut it short).
    small = values[:4, :8]
    assert threshold_shadow_maps(small, 0.3, clean=4).shape == small.shape[:-1]


@pytest.mark.parametrize("lights", [(64, 32), (16, 8)])
def test_the_boundary_band_is_as_wide_on_the_sphere_near_the_poles(lights):
    """A matte pixel's reflectance F_t(N·l) N·l (Weyrich eq. 6) thresholded at 2 % of its maximum is dark within
    3.6° of its horizon (N·l < 0.062 for η = 1.38); the band of one step around the terminator must cover that
    everywhere.  A band of 3 × 3 cells did not next to the poles, where a cell is 0.27° wide in azimuth on the
    64 × 32 grid: normals near the horizontal plane put whole rows there at N·l < 0.049 (an audit, 2026-12-08)."""
    from facestats.model.fresnel import fresnel_reflectance

    d, _ = light_stage_directions(*lights)
    k = np.arange(200) + 0.5
    z = 1 - 2 * k / k.size
    normals = np.stack([np.sqrt(1 - z * z) * np.cos(np.pi * (3 - 5**0.5) * k), z,
                        np.sqrt(1 - z * z) * np.sin(np.pi * (3 - 5**0.5) * k)], -1)  # fmt: skip  # Fibonacci sphere
    cos = np.clip(np.einsum("pqk,nk->pqn", d, normals), 0, 1)[..., None]  # (n_phi, n_theta, 200, 1)
    values = np.repeat(((1 - fresnel_reflectance(cos)) * cos)[..., None], 3, axis=-1)
    lit = threshold_shadow_maps(values, 0.02, clean=0)
    assert shadow_agreement(lit, cos > 0, band=1)["agreement"] == 1.0
    assert shadow_agreement(lit, cos > 0, band=0)["agreement"] < 1.0


def test_the_lights_facing_the_surface_are_found_block_by_block():
    """The (pixels × lights) product was made whole to find them: 1.2 GB at 512² and 8,192 lights (a red team)."""
    from facestats.relight.stage import _lights_facing

    rng = np.random.default_rng(3)
    normals = rng.normal(size=(1000, 3)) * [0.2, 0.2, 0] + [0, 0, 1]  # a surface facing +z: lights well below
    # the horizon face none of it
    directions = rng.normal(size=(300, 3))
    want = (normals @ directions.T > 0).any(axis=0)
    assert 0 < want.sum() < 300
    for block in (1, 299, 300, 7_000, 1 << 22):  # one normal a block, ..., all at once
        np.testing.assert_array_equal(_lights_facing(normals, directions, block), want)


def test_a_light_grid_too_large_for_the_memory_is_refused_before_the_full_facing_pass(subject, monkeypatch):
    """The memory check of the visibility table came after the lights facing the surface were found among all its
    normals (pixels x lights products): 4096x2048 lights had not reached the refusal after 3 minutes.  A lower
    bound from a sample of the normals is checked first (4096x2048 refused in 9 s on 22 GB); and a render
    without shadows, whose table of ones is as large, is checked too (it was not)."""
    calls = []
    real = stage._lights_facing

    def lights_facing(normals, directions, *args):
        calls.append((len(normals), int(np.count_nonzero(facing := real(normals, directions, *args)))))
        return facing

    monkeypatch.setattr(stage, "_lights_facing", lights_facing)
    per_light = 4 * 468  # bytes: the 468 mesh vertices the 24-pixel camera sees
    monkeypatch.setattr(stage, "available_memory", lambda: 534.5 * per_light)
    camera = stage.stage_camera(size=SIZE)
    with pytest.raises(ValidationError, match=r"lights must be at most 534 on this machine: 1,9[0-9]{2} or more reach"):
        stage.relight_subject(subject, sky_probe(16), lights=(64, 32), camera=camera)
    assert len(calls) == 1 and calls[0][0] <= 2 * stage.VISIBILITY_SAMPLE  # the sample only
    calls.clear()
    monkeypatch.setattr(stage, "VISIBILITY_SAMPLE", 1)  # one normal: 1,024 lights, a bound that fits
    monkeypatch.setattr(stage, "available_memory", lambda: 1500.5 * per_light)
    with pytest.raises(ValidationError, match=r"lights must be at most 1,500 on this machine: 1,9[0-9]{2} reach the "):
        stage.relight_subject(subject, sky_probe(16), lights=(64, 32), camera=camera, shadows=False)
    assert calls[0] == (1, 1024) and calls[1][0] == 156 and len(calls) == 2  # then all 156 normals of the face
    stage._check_visibility_memory(468, 1500)  # fits: "at most", not "fewer than"
    with pytest.raises(ValidationError, match="at most 1,500"):
        stage._check_visibility_memory(468, 1501)


def test_a_light_grid_whose_arrays_exceed_the_memory_is_refused_before_any_of_them_is_made(
    subject, geometry, monkeypatch
):
    """A grid just under the cap of --lights (2^28 lights) built 6 GiB of directions and more before the visibility
    table's memory check refused it.  With 100 MiB available, 128 bytes a light fit 819,200 lights (1280x640): a
    2048x1024 grid (256 MiB) is refused before its directions are made, a fitting grid is not."""
    import tracemalloc

    made = []
    real = stage.light_stage_directions
    monkeypatch.setattr(stage, "light_stage_directions", lambda *a: made.append(a) or real(*a))
    monkeypatch.setattr(stage, "available_memory", lambda: 100 * 2**20)
    camera = stage.stage_camera(size=SIZE)
    tracemalloc.start()
    try:
        with pytest.raises(ValidationError) as err:
            stage.relight_subject(subject, sky_probe(16), lights=(2048, 1024), camera=camera, geometry=geometry)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert made == [] and peak < 2**20  # the grid's directions alone would be 48 MiB
    assert str(err.value) == (
        "lights must make at most 819,200 lights on this machine (the largest 2:1 grid that fits: 1280x640), got "
        "(2048, 1024) = 2,097,152 lights, whose directions, resampled probe and their temporaries need 256 MiB (128 "
        "bytes a light, before the shadow maps' visibility table), more than the 100 MiB available"
    )
    stage.check_light_grid(1280, 640)  # exactly the memory: fits
    with pytest.raises(ValidationError, match="at most 819,200 lights"):
        stage.check_light_grid(1281, 640)
    image, mask = stage.relight_subject(subject, sky_probe(16), lights=LIGHTS, camera=camera, geometry=geometry)
    assert made == [LIGHTS] and mask.any() and np.isfinite(image).all() and image[mask].max() > 0


def test_the_light_grid_bytes_bound_what_relight_subject_holds_per_light(subject, geometry, monkeypatch):
    """LIGHT_GRID_BYTES, counted from the code, against tracemalloc: the growth of the peak held up to the
    visibility table's check between two grids, per light added (117 bytes, 2026-12-08), stays within it, and is
    most of it (an estimate far above the need would refuse grids that fit).  Both grids have at least 65,536
    lights, so that the blocks of the lights-facing test hold their fixed 4 M products in both (below, a block
    holds fewer: 64 sampled normals x 32,768 lights are 2 M)."""
    import tracemalloc

    class Reached(Exception):
        pass

    def reached(*args, **kwargs):
        raise Reached

    monkeypatch.setattr(stage, "_check_visibility_memory", reached)
    camera, peaks = stage.stage_camera(size=SIZE), []
    for lights in ((512, 256), (1024, 512)):
        tracemalloc.start()
        try:
            with pytest.raises(Reached):
                stage.relight_subject(subject, sky_probe(16), lights=lights, camera=camera, geometry=geometry)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    per_light = (peaks[1] - peaks[0]) / (1024 * 512 - 512 * 256)
    assert 0.8 * stage.LIGHT_GRID_BYTES < per_light <= stage.LIGHT_GRID_BYTES, per_light


def test_the_boundary_band_is_the_lights_within_its_arc_found_block_by_block(monkeypatch):
    """The band of :func:`shadow_agreement` against the arcs between every pair of lights (arccos of their dot
    products): a sample is excluded iff a light within ``band`` steps of arc of its own has the other visibility,
    whatever the blocks of image samples the neighbours are counted in."""
    from facestats.relight import shadows

    rng = np.random.default_rng(5)
    want_one = None
    for lights in ((16, 8), (5, 3), (2, 1)):
        d, _ = light_stage_directions(*lights)
        n_phi, n_theta = d.shape[:2]
        arcs = np.arccos(np.clip(np.einsum("ik,jk->ij", d.reshape(-1, 3), d.reshape(-1, 3)), -1, 1))
        step = np.hypot(np.pi / n_phi, 2 * np.pi / n_theta)
        visible = rng.random((n_phi, n_theta, 3, 4)) < 0.7
        v = visible.reshape(n_phi * n_theta, -1)
        for band in (0, 1, 2):
            pairs = arcs <= band * step + 1e-9
            want = np.where(v, (pairs.astype(int) @ ~v) > 0, (pairs.astype(int) @ v) > 0).reshape(visible.shape)
            want_one = want if band == 1 else want_one
            for block in (1, 7, shadows.NEAR_BLOCK):
                monkeypatch.setattr(shadows, "NEAR_BLOCK", block)
                np.testing.assert_array_equal(shadows._near_boundary(visible, band), want)
        assert shadow_agreement(visible, visible, band=1)["excluded"] == want_one.sum()


def _light_angles(n_theta, n_phi):
    """Angles between every pair of lights (flat indices) of the grid, atan2 of |a × b| and a · b (accurate at 0
    and π alike): the brute force the band's row windows must equal."""
    d, _ = light_stage_directions(n_theta, n_phi)
    d = d.reshape(-1, 3)
    return np.arctan2(np.linalg.norm(np.cross(d[:, None], d[None]), axis=-1), d @ d.T)


def _within(angles, n_theta, n_phi, band):
    """Pairs of lights within ``band`` steps of arc (√(Δφ² + Δθ²) each), a hair more for rounding."""
    return angles <= band * np.hypot(np.pi / n_phi, 2 * np.pi / n_theta) + 1e-9


# Grids (n_theta, n_phi): square and 2:1 cells, odd sizes, one row or column, and ratios whose meridian pairs lie
# exactly a whole number of steps apart (12 x 8 at band 3: 5 rows; 24 x 16 at band 3) or whose arc reaches π.
BAND_GRIDS = [(8, 4), (9, 5), (7, 3), (12, 8), (16, 8), (13, 7), (24, 16), (20, 20), (32, 16), (1, 1), (5, 1), (1, 6)]


def test_the_rows_within_the_band_are_windows_of_columns_centred_on_the_light():
    """The band's neighbours of a light (i, j) in row r are the columns j − w[i, r] … j + w[i, r] (circularly; the
    whole row when 2w + 1 ≥ n_theta): the same set as every pair's angle within the arc, on every grid and band
    0 … 16 (arcs beyond π take every light)."""
    from facestats.relight import shadows

    reached = 0
    for n_theta, n_phi in BAND_GRIDS + [(64, 32)]:
        angles = _light_angles(n_theta, n_phi)
        cols = np.arange(n_theta)
        offset = (cols[None, :] - cols[:, None]) % n_theta
        circular = np.minimum(offset, n_theta - offset)  # (j, c): columns apart, circularly
        for band in range(17):
            want = _within(angles, n_theta, n_phi, band).reshape(n_phi, n_theta, n_phi, n_theta)
            half = shadows._band_half_widths(n_phi, n_theta, band)
            got = circular[None, :, None, :] <= half[:, None, :, None]
            np.testing.assert_array_equal(got, want, err_msg=f"{n_theta} x {n_phi}, band {band}")
            if band * np.hypot(np.pi / n_phi, 2 * np.pi / n_theta) >= np.pi:
                assert (half == n_theta // 2).all()  # the arc reaches over the sphere: every light
                reached += 1
    assert reached > 50


def _patterns(n_theta, n_phi, rng):
    """Visibilities (n_phi, n_theta, y, x) that test the band: random, all, none, single lights (at the seam of
    azimuth 0 / 2π, next to a pole, inside), columns either side of the seam, a polar cap, and half-spaces."""
    shape = (n_phi, n_theta)
    out = [rng.random(shape + (2, 3)) < p for p in (0.1, 0.5, 0.9)]
    out += [np.ones(shape + (1, 2), bool), np.zeros(shape + (1, 2), bool)]
    single = np.zeros(shape + (4, 1), bool)
    for s, (i, j) in enumerate([(0, 0), (n_phi - 1, n_theta - 1), (n_phi // 2, n_theta // 2), (0, n_theta // 3)]):
        single[i, j, s] = True
    seam = np.zeros(shape + (1, 3), bool)
    seam[:, 0, 0, 0] = seam[:, -1, 0, 1] = True
    seam[:, [0, -1], 0, 2] = True
    cap = np.zeros(shape + (1, 2), bool)
    cap[0, :, 0, 0] = cap[-1, :, 0, 1] = True
    d, _ = light_stage_directions(n_theta, n_phi)
    half_spaces = np.einsum("pqk,yxk->pqyx", d, rng.normal(size=(2, 2, 3))) > 0
    return [single, seam, cap, half_spaces] + out


def test_the_boundary_band_equals_the_brute_force_on_many_grids_bands_and_visibilities(monkeypatch):
    """The band's samples are those whose light has a light of the other visibility within the arc, counted
    over every pair's angle, for all grids of BAND_GRIDS, bands 0 … 16 and the visibilities of ``_patterns``, in
    blocks of one sample, of 7 lights' samples and whole."""
    from facestats.relight import shadows

    rng = np.random.default_rng(11)
    for n_theta, n_phi in BAND_GRIDS:
        patterns, angles = _patterns(n_theta, n_phi, rng), _light_angles(n_theta, n_phi)
        for band in range(17):
            pairs = _within(angles, n_theta, n_phi, band).astype(np.int64)
            for visible in patterns:
                v = visible.reshape(n_phi * n_theta, -1)
                want = np.where(v, pairs @ ~v > 0, pairs @ v > 0).reshape(visible.shape)
                for block in (1, 7 * n_theta * n_phi, shadows.NEAR_BLOCK) if band in (1, 3, 16) else (1 << 20,):
                    monkeypatch.setattr(shadows, "NEAR_BLOCK", block)
                    got = shadows._near_boundary(visible, band)
                    assert got.dtype == bool and got.shape == visible.shape
                    np.testing.assert_array_equal(got, want, err_msg=f"{n_theta} x {n_phi}, band {band}")


def test_the_boundary_band_wraps_in_azimuth_and_reaches_over_the_poles():
    """One visible light at (row 0, column 0) of the 16 × 8 grid (rows 22.5° apart, row 0 11.25° from the pole):
    its one-step band (31.8°) holds the light across the seam where the columns wrap (column 15, 4.4° away), the
    light across the pole in its row (column 8, 2 × 11.25° = 22.5°), the row's light a quarter turn away (column 4,
    15.8°) and the next row's (22.5°); not the light across the pole two rows down (row 2, column 8: 11.25° +
    56.25° = 67.5°) nor row 4's (90°)."""
    from facestats.relight import shadows

    visible = np.zeros((8, 16, 1, 1), bool)
    visible[0, 0] = True
    near = shadows._near_boundary(visible, 1)[..., 0, 0]
    assert near[0, 0] and near[0, 15] and near[0, 1] and near[0, 8] and near[0, 4] and near[1, 0]
    assert not near[2, 8] and not near[4, 0]
    assert near.sum() == _within(_light_angles(16, 8), 16, 8, 1)[0].sum()  # the light's own neighbours, nothing else


def test_the_boundary_band_memory_does_not_grow_with_the_band():
    """The kd-tree's sparse matrix held every pair of lights within the arc, so its size grew with the lights ×
    band²: on 128 × 64 lights with 8² image samples shadow_agreement traced 23 MiB at band 1 and 538 MiB at band
    16 (2 GB at 256 × 128).  The row windows hold blocks of NEAR_BLOCK samples whatever the band (5 MiB here)."""
    import tracemalloc

    from facestats.relight import shadows

    d, _ = light_stage_directions(128, 64)
    visible = np.einsum("pqk,yxk->pqyx", d, np.random.default_rng(0).normal(size=(8, 8, 3))) > 0
    peaks = []
    for band in (1, 16):
        tracemalloc.start()
        try:
            shadow_agreement(visible, visible, band=band)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    assert peaks[1] < 1.05 * peaks[0], peaks
    assert peaks[1] < 4 * shadows.NEAR_BLOCK + 8 * visible.nbytes, (peaks, visible.nbytes)


def test_the_boundary_band_holds_blocks_not_the_field_in_float64():
    """The neighbours of each light were counted for all image samples at once, in float64 (scipy's product of a
    float64 pair matrix and float32 visibilities), twice: shadow_agreement on the 64 × 32 stage at 48² traced a
    112 MiB peak for 4.5 MiB of visibility (42 MiB with the 3 × 3 cells of a59b93e); 34 MiB with float32 blocks and
    the kd-tree's pairs, 17 MiB with integer window sums along the rows (2026-12-08)."""
    import tracemalloc

    d, _ = light_stage_directions(64, 32)
    normals = np.random.default_rng(0).normal(size=(48, 48, 3))
    visible = np.einsum("pqk,yxk->pqyx", d, normals) > 0
    tracemalloc.start()
    try:
        agreement = shadow_agreement(visible, visible, band=1)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert agreement["agreement"] == 1.0 and 0 < agreement["excluded"] < visible.size
    assert peak < 10 * visible.nbytes, (peak, visible.nbytes)


def test_a_scan_in_another_unit_is_refused_naming_its_size_and_the_scale_to_pass(subject, geometry, tmp_path):
    """The ICT face saved in metres and passed as the scan rendered an all-black image and exited 0 with "mean
    radiance nan" (a walkthrough): the stage camera, placed in mm, saw nothing.  subject_geometry refuses a mesh of
    no face's size with the scale to pass; a geometry the camera does not see is refused by the stage itself."""
    from facestats.io.mesh import load_face_mesh, subject_mesh, write_mesh

    fm = subject_mesh(subject)  # the face S001's maps belong to, in mm
    for unit, factor in (("m", 1000), ("cm", 10)):
        path = tmp_path / f"face_{unit}.obj"
        write_mesh(path, fm.vertices / factor, fm.faces, fm.uv)
        across = np.ptp(fm.vertices, axis=0).max() / factor
        with pytest.raises(ValidationError) as err:
            stage.subject_geometry(subject, path)
        assert str(err.value) == (
            f"mesh {path} is {across:.4g} mm across with scale 1, outside a face's 50-1000 mm: if the file is in "
            f"{unit}, pass scale {factor} (--mesh-scale {factor} on the command line, the factor from its unit to mm)"
        )
        g = stage.subject_geometry(subject, path, scale=factor)
        assert np.allclose(g.mesh_vertices, fm.vertices, atol=1e-5 * factor)
    for bad in (0, -2, np.nan, 1e7):
        with pytest.raises(ValidationError, match=r"^scale must (lie in|be)"):
            stage.subject_geometry(subject, tmp_path / "face_m.obj", scale=bad)
    tiny = load_face_mesh(tmp_path / "face_m.obj", subject["region"].values)  # past the check: metres as mm
    cam = stage.stage_camera(size=16)
    said = (r"camera sees no pixel of the face of subject 'S001': its mesh 'face_m.obj' is 0\.\d+ mm across, 12\d\d mm "
            r"from the camera, whose 13° view is [\d.]+ mm wide there \(a mesh in another unit than mm")  # fmt: skip
    with pytest.raises(ValidationError, match=said):
        stage.light_stage_field(subject, cam, geometry=tiny, directions=light_stage_directions(8, 4)[0])
    with pytest.raises(ValidationError, match=said):
        stage.relight_subject(subject, sky_probe(16), camera=cam, lights=(8, 4), geometry=tiny)
    import dataclasses

    corner = dataclasses.replace(geometry, mesh_uv=np.full((len(geometry.mesh_vertices), 2), 0.001))  # off the face
    with pytest.raises(ValidationError, match=r"^camera sees \d+ pixels of the mesh of '.*' but none on a face texel"):
        stage.render_subject(subject, np.ones((32, 3)), light_stage_directions(8, 4)[0], cam, geometry=corner)
