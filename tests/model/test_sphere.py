"""Spherical geometry of light probes and light stages: directions, exact solid angles, rotation, Voronoi cells."""

import numpy as np
import pytest

from facestats.errors import ValidationError
from facestats.model import sphere
from tests.helpers import TEST_DATA


def test_latlong_solid_angles_are_exact_cells_summing_to_four_pi():
    for h, w in ((1, 2), (32, 64), (7, 10), (128, 256)):
        sa = sphere.latlong_solid_angles(h, w)
        assert sa.shape == (h, w)
        assert sa.sum() == pytest.approx(4 * np.pi, rel=1e-13)
    sa = sphere.latlong_solid_angles(32, 64)
    assert sa[:16].sum() == pytest.approx(2 * np.pi, rel=1e-13)  # upper hemisphere: rows split at the equator
    # Row 0 is the cap φ ∈ [0, π/32]: 2π(1 − cos(π/32)) shared by 64 cells.
    assert sa[0, 0] == pytest.approx(2 * np.pi * (1 - np.cos(np.pi / 32)) / 64, rel=1e-13)


def test_debevec_delta_a_is_the_first_order_cell_area():
    # Debevec §3.3: δA(θ, φ) = sin φ, up to the constant ΔθΔφ; exact cells differ by O(Δφ²).
    h, w = 32, 64
    phi = np.pi * (np.arange(h) + 0.5) / h
    ratio = sphere.latlong_solid_angles(h, w)[:, 0] / ((2 * np.pi / w) * (np.pi / h) * np.sin(phi))
    assert np.allclose(ratio, 1, atol=(np.pi / h) ** 2 / 20)
    assert not np.allclose(ratio, 1, atol=1e-6)


def test_latlong_direction_convention():
    d = sphere.latlong_directions(32, 64)
    assert d.shape == (32, 64, 3)
    assert np.allclose(np.linalg.norm(d, axis=-1), 1)
    assert d[0, 0, 1] > 0.99 and d[-1, 0, 1] < -0.99  # row 0 at +y
    centre = 0.5 * (d[15, 31] + d[16, 32])  # the centre of the image looks at −z
    assert np.allclose(centre / np.linalg.norm(centre), [0, 0, -1], atol=0.01)
    assert d[16, 48, 0] > 0.99  # a quarter turn to the right of the centre: +x
    edge = 0.5 * (d[16, 0] + d[16, -1])
    assert edge[2] > 0.99  # the left/right edges: +z, the frontal camera


def test_latlong_coordinates_invert_the_directions(rng):
    d = sphere.latlong_directions(16, 32)
    r, c = sphere.latlong_coordinates(d, 16, 32)
    rr, cc = np.mgrid[0:16, 0:32]
    assert np.allclose(r, rr) and np.allclose(c, cc)
    phi, theta = sphere.angles_from_direction(d)
    assert np.allclose(sphere.direction_from_angles(phi, theta), d)


def test_azimuth_stays_in_its_documented_range_for_signed_zeros():
    """θ ∈ (−π, π]: arctan2 gave −π for x = −0.0 with z ≥ 0 (and for an x too small to leave −π)."""
    d = np.array([[-0.0, 0.0, 1.0], [-1e-20, 0.0, 1.0], [-0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    _, theta = sphere.angles_from_direction(d)
    np.testing.assert_array_equal(theta, np.pi)
    _, one = sphere.angles_from_direction(d[0])
    assert one == np.pi and np.ndim(one) == 0


def test_light_stage_is_the_64_by_32_lat_long_grid():
    d, sa = sphere.light_stage_directions()
    assert d.shape == (32, 64, 3) and sa.shape == (32, 64)
    assert np.array_equal(d, sphere.latlong_directions(32, 64))
    assert sa.sum() == pytest.approx(4 * np.pi)


def test_angular_layout_centre_rim_and_solid_angles():
    d, inside = sphere.angular_directions(64)
    assert np.allclose(0.5 * (d[31, 31] + d[32, 32]) / np.linalg.norm(0.5 * (d[31, 31] + d[32, 32])), [0, 0, -1],
                       atol=1e-3)  # fmt: skip
    assert d[31, 63, 2] > 0.9  # near the right rim: towards +z (backwards)
    assert d[0, 31, 1] > 0 and d[63, 31, 1] < 0  # top of the image is +y
    assert np.isnan(d[0, 0]).all() and not inside[0, 0]
    sa = sphere.angular_solid_angles(64)
    assert sa.sum() == pytest.approx(4 * np.pi, rel=2e-4)
    r, c = sphere.angular_coordinates(d[inside], 64)
    rr, cc = np.mgrid[0:64, 0:64]
    assert np.allclose(r, rr[inside], atol=1e-9) and np.allclose(c, cc[inside], atol=1e-9)


def test_angular_solid_angles_match_a_fine_midpoint_rule_inside_and_on_the_rim():
    """Interior pixels take a lower Gauss order than rim pixels: both against 400² midpoints of dΩ = π sin(πr)/r."""
    size = 8
    sa = sphere.angular_solid_angles(size)
    m = 400
    t = (np.arange(m) + 0.5) / m  # midpoints across one pixel
    interior, rim = [(3, 3), (3, 4), (2, 2)], [(0, 3), (1, 1), (2, 0), (7, 5)]
    for row, col in interior + rim:
        u = 2 * (col + t[None, :]) / size - 1
        v = 1 - 2 * (row + t[:, None]) / size
        r = np.hypot(u, v)
        f = np.where(r <= 1, np.pi * np.sin(np.pi * np.minimum(r, 1)) / r, 0.0)
        brute = f.mean() * (2 / size) ** 2
        # interior: the midpoint rule's own error (1e-7); rim: the kink at r = 1 costs order 8 up to 3e-4
        assert sa[row, col] == pytest.approx(brute, rel=1e-6 if (row, col) in interior else 5e-4), (row, col)
    assert sa[0, 0] == 0.0  # wholly outside the disc


def test_rotation_about_y_is_right_handed_and_shifts_azimuth():
    rot = sphere.rotation_y(np.pi / 2)
    assert np.allclose(rot @ [0, 0, 1], [1, 0, 0])  # +z to +x: counter-clockwise seen from +y
    assert np.allclose(rot @ [0, 1, 0], [0, 1, 0])
    d = sphere.latlong_directions(8, 16)
    beta = 2 * np.pi / 16
    rd = sphere.rotate_directions(d, beta)
    _, theta = sphere.angles_from_direction(rd)
    _, theta0 = sphere.angles_from_direction(d)
    assert np.allclose(np.angle(np.exp(1j * (theta - (theta0 - beta)))), 0, atol=1e-12)  # θ → θ − β


def test_voronoi_cells_tile_the_sphere():
    octa = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    assert np.allclose(sphere.voronoi_solid_angles(octa), 4 * np.pi / 6)
    rng = np.random.default_rng(3)
    d = rng.normal(size=(150, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    assert sphere.voronoi_solid_angles(d).sum() == pytest.approx(4 * np.pi, rel=1e-9)
    # Sets SphericalVoronoi cannot tessellate are measured on a grid: one light owns the sphere; two
    # opposite lights own a hemisphere each; three on the equator a third each.
    assert sphere.voronoi_solid_angles([[0, 1.0, 0]]) == pytest.approx([4 * np.pi])
    assert np.allclose(sphere.voronoi_solid_angles([[0, 1.0, 0], [0, -1.0, 0]]), 2 * np.pi, rtol=1e-12)
    eq = sphere.direction_from_angles(np.pi / 2, np.array([0.1, 0.1 + 2 * np.pi / 3, 0.1 + 4 * np.pi / 3]))
    assert np.allclose(sphere.voronoi_solid_angles(eq), 4 * np.pi / 3, rtol=0.01)


def test_bad_directions_are_refused():
    with pytest.raises(ValidationError, match="unit vectors"):
        sphere.unit_directions([[0, 0, 2.0]])
    with pytest.raises(ValidationError, match="distinct"):
        sphere.voronoi_solid_angles([[1, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, -1]])
    with pytest.raises(ValidationError, match="height"):
        sphere.latlong_directions(0, 4)


def test_latlong_light_samples_conserve_power_and_give_pi_l_irradiance():
    """A uniform probe of radiance L carries 4π L; on any surface its blocks give E = π L (cosine integral)."""
    L = np.array([1.0, 2.0, 0.5])
    d, power = sphere.latlong_light_samples(np.broadcast_to(L, (32, 64, 3)), 16, 32)
    np.testing.assert_allclose(power.sum(0), 4 * np.pi * L, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=1e-12)
    for n in ([0.0, 0, 1], [0.0, 1, 0], [0.6, 0, -0.8]):
        e = np.clip(d @ np.array(n), 0, None) @ power
        np.testing.assert_allclose(e, np.pi * L, rtol=0.01)  # the blocks' cosine spread: < 1 % at 16 x 32


def _lambert_errors(probe, d, power, n=2000):
    """Largest relative error over channels of the Lambertian irradiance of ``n`` random normals under the
    lights (d, power), against every pixel of ``probe`` as its own light."""
    h, w = probe.shape[:2]
    normals = np.random.default_rng(0).normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    pix = (probe * sphere.latlong_solid_angles(h, w)[..., None]).reshape(-1, 3)
    ref = np.clip(normals @ sphere.latlong_directions(h, w).reshape(-1, 3).T, 0, None) @ pix
    got = np.clip(normals @ d.T, 0, None) @ power
    return (np.abs(got - ref) / ref).max(1)


def test_median_cut_conserves_power_and_gives_pi_l_irradiance():
    L = np.array([1.0, 2.0, 0.5])
    d, power = sphere.median_cut_light_samples(np.broadcast_to(L, (32, 64, 3)), 512)
    assert len(d) == 512
    np.testing.assert_allclose(power.sum(0), 4 * np.pi * L, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=1e-12)
    for n in ([0.0, 0, 1], [0.0, 1, 0], [0.6, 0, -0.8]):
        np.testing.assert_allclose(np.clip(d @ np.array(n), 0, None) @ power, np.pi * L, rtol=0.01)


def test_median_cut_measures_a_region_along_its_middle_parallel():
    """Debevec's median cut cuts a region across its longer side in angle, the width taken along the region's middle
    parallel.  A uniform 8 x 16 probe cut into 16 lights: after four rounds of column cuts and one of row cuts each
    4 x 4 block is π/2 tall and (π/2) sin 45° = 1.11 wide, so it is cut across its rows (measured without the
    sin φ its width would be π/2 and it would be cut across its columns): the lights lie at four polar angles."""
    d, power = sphere.median_cut_light_samples(np.ones((8, 16, 3)), 16)
    phi, _ = sphere.angles_from_direction(d)
    polar = np.unique(np.round(np.degrees(phi), 6))
    np.testing.assert_allclose(polar, [40.1454, 77.6189, 102.3811, 139.8546], atol=1e-4)
    np.testing.assert_allclose(power.sum(0), 4 * np.pi, rtol=1e-12)


@pytest.mark.parametrize("level", [1e307, 1e-300])
def test_light_samples_of_probes_near_the_float_limits(level, rng):
    """Probes near the float64 maximum gave lights of zero-length direction (their sums overflowed); both
    samplers now work on the probe scaled by a power of two, which keeps every other probe's bits."""
    probe = rng.uniform(0.5, 1.5, (8, 16, 3))
    for sample, args in ((sphere.median_cut_light_samples, (8,)), (sphere.latlong_light_samples, (4, 8))):
        ref_dirs, ref_power = sample(probe, *args)
        dirs, power = sample(probe * level, *args)
        assert np.allclose(np.linalg.norm(dirs, axis=1), 1, atol=1e-12) and np.allclose(dirs, ref_dirs, atol=1e-12)
        assert np.allclose(power, ref_power * level, rtol=1e-12)
        scaled_dirs, scaled_power = sample(probe * 2.0**40, *args)  # a power of two: the same bits
        assert np.array_equal(scaled_dirs, ref_dirs) and np.array_equal(scaled_power, ref_power * 2.0**40)
    with pytest.raises(ValidationError, match="float64 range"):  # the lights' power itself is not representable
        sphere.median_cut_light_samples(np.full((8, 16, 3), 1.7e308), 8)
    top = np.zeros((4, 8, 3))
    top[1, 2] = np.finfo(float).max  # its power (about 1e308 per channel) is representable
    for sample, args in ((sphere.median_cut_light_samples, (8,)), (sphere.latlong_light_samples, (2, 4))):
        dirs, power = sample(top, *args)
        assert np.all(np.isfinite(power)) and np.allclose(np.linalg.norm(dirs, axis=1), 1, atol=1e-12)
        assert np.allclose(power.sum(0), np.finfo(float).max * sphere.latlong_solid_angles(4, 8)[1, 2], rtol=1e-12)


def test_median_cut_gives_a_light_to_each_pixel_when_there_are_enough():
    """More lights than pixels: every pixel becomes its own light, at its centre: the exact irradiance."""
    probe = np.random.default_rng(3).uniform(0, 2, (4, 8, 3))
    d, power = sphere.median_cut_light_samples(probe, 100)
    assert len(d) == 32
    assert _lambert_errors(probe, d, power).max() < 1e-12
    with pytest.raises(ValidationError, match=r"lights must be an integer in \[2, inf\], got 1"):
        sphere.median_cut_light_samples(probe, 1)
    with pytest.raises(ValidationError, match="width 2 x height"):
        sphere.median_cut_light_samples(np.zeros((8, 8, 3)), 4)


def test_median_cut_lights_a_softbox_where_equal_blocks_miss_it():
    """The studio probe of the committed Poly Haven set (a small softbox): 512 lights by median cut against
    16 x 32 equal blocks (measured: worst 2.4 % against 25.7 %, 99th percentile 0.81 % against 13.6 %)."""
    from facestats.io.probes import read_light_probe

    probe = read_light_probe(TEST_DATA / "polyhaven-probes" / "studio.hdr")
    cut = _lambert_errors(probe, *sphere.median_cut_light_samples(probe, 512))
    blocks = _lambert_errors(probe, *sphere.latlong_light_samples(probe, 16, 32))
    assert cut.max() < 0.03 and np.percentile(cut, 99) < 0.01
    assert blocks.max() > 0.2 and np.percentile(blocks, 99) > 0.1


def test_latlong_light_samples_put_the_centre_column_behind_the_head():
    probe = np.zeros((16, 32, 3))
    probe[7:9, 15:17] = 1.0  # the four pixels around the image centre
    d, power = sphere.latlong_light_samples(probe, 8, 16)
    brightest = d[np.argmax(power[:, 0])]
    np.testing.assert_allclose(brightest, [0.0, 0.0, -1.0], atol=0.2)
    with pytest.raises(ValidationError, match="must divide"):
        sphere.latlong_light_samples(probe, 5, 16)
    with pytest.raises(ValidationError, match="width 2 x height"):
        sphere.latlong_light_samples(np.zeros((16, 16, 3)), 4, 4)


def test_latlong_light_samples_light_from_where_the_light_is(rng):
    """A block's light points along its power-weighted mean direction: a sun off the block's centre lights from the
    sun (the solid-angle weighted centre put it up to 11° away under the Probulator probes; an audit), and the
    Lambertian irradiance of a sky with a sun errs far less than from the blocks' centres."""
    h, w = 64, 128
    d = sphere.latlong_directions(h, w)
    probe = np.full((h, w, 3), 0.2)
    sun = d[9, 22]  # near a corner of block (1, 2) of the 8 x 16 blocks (rows 8-15, columns 16-23)
    probe[d @ sun > np.cos(np.radians(1.5))] = 4000.0
    dirs, power = sphere.latlong_light_samples(probe, 8, 16)
    block = np.argmax(power[:, 0])
    assert np.degrees(np.arccos(dirs[block] @ sun)) < 2.0  # 0.01°
    n = rng.normal(size=(500, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    power_px = probe.reshape(-1, 3) * sphere.latlong_solid_angles(h, w).reshape(-1, 1)
    full = np.maximum(n @ d.reshape(-1, 3).T, 0) @ power_px
    lit = full[:, 0] > 0.05 * full[:, 0].max()  # normals the sun reaches
    err = np.abs(np.maximum(n @ dirs.T, 0) @ power - full)[lit, 0] / full[lit, 0]
    area = sphere.latlong_solid_angles(h, w)[..., None] * d
    centres = area.reshape(8, 8, 16, 8, 3).sum((1, 3)).reshape(-1, 3)
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    err_centres = np.abs(np.maximum(n @ centres.T, 0) @ power - full)[lit, 0] / full[lit, 0]
    assert np.degrees(np.arccos(centres[block] @ sun)) > 5  # 8.7° from the block centre
    assert np.median(err) < 0.2 * np.median(err_centres)
