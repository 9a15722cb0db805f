import numpy as np
import pytest
from scipy.integrate import quad

from facestats import FacestatsError
from facestats.model import dipole, skin
from facestats.model.fresnel import fresnel_transmittance

SIGMA_S = np.array([2.42, 1.69, 1.83])
SIGMA_A = np.array([0.041, 0.172, 0.364])


def _plane(h, half_width):
    x = np.arange(-half_width + h / 2, half_width, h)
    xx, yy = np.meshgrid(x, x, indexing="ij")
    pos = np.stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)], -1)
    return pos, np.full(len(pos), h * h)


def test_flat_patch_diffuse_equals_total_reflectance_with_fresnel():
    pos, area = _plane(0.5, 12.0)
    normals = np.tile([0.0, 0.0, 1.0], (len(pos), 1))
    transport = skin.SubsurfaceTransport(SIGMA_S, SIGMA_A, 1.38, positions=pos, areas=area, radius=6.0)
    th_i, th_o = np.radians(35), np.radians(50)
    wi_dir = np.array([[np.sin(th_i), 0, np.cos(th_i)]])
    cams = np.array([[np.sin(th_o) * 1e6, 0, np.cos(th_o) * 1e6]])
    wi, e = skin.directional_lights(normals, wi_dir, [2.0])
    wo = skin.view_directions(pos, cams)
    spec, diff = skin.skin_radiance(
        normals,
        wi,
        e,
        wo,
        rho_s=0.0,
        roughness=0.3,
        modulation=np.ones((len(pos), 3)),
        subsurface=transport,
        components=True,
    )
    assert np.all(spec == 0)
    centre = np.argmin(np.linalg.norm(pos, axis=1))
    rd = dipole.total_diffuse_reflectance(SIGMA_S, SIGMA_A, 1.38)
    expected = (
        rd / np.pi * fresnel_transmittance(np.cos(th_i)) * fresnel_transmittance(np.cos(th_o)) * 2.0 * np.cos(th_i)
    )
    np.testing.assert_allclose(diff[centre, 0, 0], expected, rtol=1e-6)
    # The local (flat-patch) mode gives the same everywhere.
    local = skin.skin_radiance(
        normals,
        wi,
        e,
        wo,
        rho_s=0.0,
        roughness=0.3,
        modulation=np.ones((len(pos), 3)),
        subsurface=skin.SubsurfaceTransport(SIGMA_S, SIGMA_A, 1.38),
    )
    np.testing.assert_allclose(local[centre, 0, 0], expected, rtol=1e-6)


def _half_plane_response(x, s, a):
    """Exitance at signed distance x from the edge of a half-plane lit with unit flux (x > 0: dark side).

    In polar coordinates about the probe, the lit points at distance r lie on an arc of length
    2r·arccos(|x|/r) (the part of the circle beyond the edge line), so the far-side integral is one
    1-D quadrature, ∫_|x|^∞ R_d(r) 2r arccos(|x|/r) dr; the near side is R_d minus that.  (It equals
    the nested strip integral ∫_x^∞ 2∫_0^∞ R_d(√(u² + y²)) dy du to 1e-8 and is 30× cheaper.)
    """
    d = abs(x)
    far = quad(lambda r: float(dipole.dipole_profile(r, s, a)) * 2 * r * np.arccos(d / r), d, np.inf, limit=200)[0]
    return far if x >= 0 else float(dipole.total_diffuse_reflectance(s, a)) - far


@pytest.mark.slow
def test_shadow_edge_blur_matches_half_plane_integral():
    h = 0.25
    pos, area = _plane(h, 6.0)
    transport = skin.SubsurfaceTransport(SIGMA_S, SIGMA_A, 1.38, positions=pos, areas=area, radius=6.0)
    flux = np.where(pos[:, :1] < 0, 1.0, 0.0) * np.ones((1, 3))
    out = transport.apply(flux)
    row = np.abs(pos[:, 1] - h / 2) < 1e-9
    xs, vals = pos[row, 0], out[row]
    for x_probe in (-1.125, -0.125, 0.125, 0.375):
        i = np.argmin(np.abs(xs - x_probe))
        for c in range(3):
            ref = _half_plane_response(xs[i], SIGMA_S[c], SIGMA_A[c])
            assert vals[i, c] == pytest.approx(ref, rel=0.03)
    # Symmetry: the two columns at the edge sum to the total reflectance.
    i0, i1 = np.argmin(np.abs(xs + h / 2)), np.argmin(np.abs(xs - h / 2))
    np.testing.assert_allclose(vals[i0] + vals[i1], dipole.total_diffuse_reflectance(SIGMA_S, SIGMA_A), rtol=0.01)


def test_energy_conservation_flat_patch(rng):
    pos, area = _plane(0.5, 10.0)
    transport = skin.SubsurfaceTransport(SIGMA_S, SIGMA_A, 1.38, positions=pos, areas=area)
    flux = rng.uniform(0, 1, (len(pos), 4, 3))
    out = transport.apply(flux)
    # Every weight is non-negative and each row sums to R_d: total exitance ≤ entering flux.
    assert np.all(out >= 0)
    np.testing.assert_allclose(
        out.sum(0) / flux.sum(0), np.broadcast_to(dipole.total_diffuse_reflectance(SIGMA_S, SIGMA_A), (4, 3)), rtol=0.05
    )


def test_specular_component_is_brdf_times_irradiance(rng):
    n = 50
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    pos = np.c_[rng.uniform(-5, 5, (n, 2)), np.zeros(n)]
    lights = np.array([[100.0, 0, 500], [-200, 50, 400]])
    cams = np.array([[0.0, 0, 600], [150, -100, 500], [0, 300, 300]])
    wi, e = skin.point_lights(pos, normals, lights, [[1e5, 9e4, 8e4], [5e4, 5e4, 5e4]])
    wo = skin.view_directions(pos, cams)
    rho, m = rng.uniform(0.1, 0.3, n), rng.uniform(0.2, 0.5, n)
    for model in skin.SPECULAR_MODELS:
        r = rho if model == "torrance_sparrow" else rho
        p = m if model == "torrance_sparrow" else 1 / m**2
        spec, _ = skin.skin_radiance(
            normals,
            wi,
            e,
            wo,
            rho_s=r,
            roughness=p,
            modulation=np.ones((n, 3)),
            subsurface=skin.SubsurfaceTransport(SIGMA_S, SIGMA_A),
            specular=model,
            components=True,
        )
        f = skin.specular_brdf(
            model, normals[:, None, None], wi[:, None], wo[:, :, None], r[:, None, None], p[:, None, None]
        )
        np.testing.assert_allclose(spec, f[..., None] * e[:, None], rtol=1e-12)
        assert spec.shape == (n, 3, 2, 3)


def test_modulation_texture_eq7():
    albedo = np.array([[[0.4, 0.2, 0.1], [0.6, 0.3, 0.2]], [[0.5, 0.25, 0.15], [0.9, 0.9, 0.9]]])
    mask = np.array([[True, True], [True, False]])
    m, avg = skin.modulation_texture(albedo, mask)
    np.testing.assert_allclose(avg, [0.5, 0.25, 0.15])
    np.testing.assert_allclose(m[0, 0], [0.8, 0.8, 2 / 3])
    assert np.all(m[1, 1] == 0)
    np.testing.assert_allclose(m[mask].mean(0), 1.0)


def test_point_light_inverse_square():
    wi, e = skin.point_lights([[0, 0, 0.0]], [[0, 0, 1.0]], [[0, 0, 100.0], [0, 0, 200.0]], [1.0, 1.0])
    assert e[0, 0, 0] / e[0, 1, 0] == pytest.approx(4.0)
    np.testing.assert_allclose(wi[0, 0], [0, 0, 1])


def test_lights_behind_the_surface_give_no_irradiance():
    n = [[0.0, 0.0, 1.0]]
    _, e = skin.directional_lights(n, [[0.0, 0.0, -1.0], [0.6, 0.0, 0.8], [0.6, 0.0, -0.8]], [1.0, 1.0, 1.0])
    np.testing.assert_allclose(e[0, :, 0], [0.0, 0.8, 0.0], atol=1e-15)
    _, e = skin.point_lights([[0.0, 0.0, 0.0]], n, [[0.0, 0.0, -10.0], [0.0, 6.0, -8.0]], [1.0, 1.0])
    assert np.all(e == 0)


def _impulse_response(h, source_area_factor=1.0):
    """Exitance of a 16 x 16 plane of spacing h (mm) when one sample near the centre receives unit flux."""
    pos, area = _plane(h, 8 * h)
    src = np.argmin(np.linalg.norm(pos - [h / 2, h / 2, 0], axis=1))
    area[src] *= source_area_factor
    flux = np.zeros((len(pos), 3))
    flux[src] = 1.0
    out = skin.SubsurfaceTransport(SIGMA_S, SIGMA_A, 1.38, positions=pos, areas=area, radius=7.2 * h).apply(flux)
    along = [np.argmin(np.linalg.norm(pos - pos[src] - [k * h, 0, 0], axis=1)) for k in (1, 2, 3)]
    return out[along]


def test_surface_transport_is_the_dipole_kernel_times_the_source_area():
    """Weyrich eq. 6 by quadrature: a neighbour at distance r of a lit sample of area A receives R_d(r) A Φ.  At
    0.25 mm spacing the samples 1-3 spacings away get 0.95-1.06 of it (0.75 at one spacing if the footprint disk
    had radius √A instead of √(A/π)), and twice as much from a source of twice the area."""
    h = 0.25
    one = _impulse_response(h)
    kernel = dipole.dipole_profile(h * np.arange(1, 4)[:, None], SIGMA_S, SIGMA_A, 1.38) * h * h
    np.testing.assert_allclose(one / kernel, 1.0, atol=0.08)
    twice = _impulse_response(h, source_area_factor=2.0)
    np.testing.assert_allclose(twice[1:] / one[1:], 2.0, rtol=0.05)


def test_a_sample_without_neighbours_keeps_all_its_diffuse_energy():
    pos = [[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]]
    transport = skin.SubsurfaceTransport(SIGMA_S, SIGMA_A, 1.38, positions=pos, areas=[0.25, 0.25], radius=2.0)
    out = transport.apply(np.ones((2, 3)))
    np.testing.assert_allclose(out, np.tile(dipole.total_diffuse_reflectance(SIGMA_S, SIGMA_A), (2, 1)), rtol=1e-12)


def test_default_radius_is_capped_at_about_max_neighbors_samples():
    """The class docstring: at 0.25 mm spacing the cap of 128 neighbours makes the radius 0.25 √(128/π) = 1.60 mm
    (the red channel of these coefficients would need about 10 mm)."""
    pos, area = _plane(0.25, 3.0)
    transport = skin.SubsurfaceTransport(SIGMA_S, SIGMA_A, 1.38, positions=pos, areas=area)
    assert transport.radius == pytest.approx(0.25 * np.sqrt(128 / np.pi), rel=1e-12)
    assert transport.radius == pytest.approx(1.60, abs=0.005)


def test_validation():
    n = np.array([[0, 0, 1.0]])
    with pytest.raises(FacestatsError, match="specular must be one of"):
        skin.skin_radiance(
            n,
            n[:, None],
            np.ones((1, 1, 3)),
            n[:, None],
            rho_s=0.1,
            roughness=0.3,
            modulation=np.ones((1, 3)),
            subsurface=skin.SubsurfaceTransport(SIGMA_S, SIGMA_A),
            specular="phong",
        )
    with pytest.raises(FacestatsError, match="irradiance must lie in"):
        skin.skin_radiance(
            n,
            n[:, None],
            -np.ones((1, 1, 3)),
            n[:, None],
            rho_s=0.1,
            roughness=0.3,
            modulation=np.ones((1, 3)),
            subsurface=skin.SubsurfaceTransport(SIGMA_S, SIGMA_A),
        )
    with pytest.raises(FacestatsError, match="areas must lie in"):
        skin.SubsurfaceTransport(SIGMA_S, SIGMA_A, positions=np.zeros((2, 3)), areas=[1.0, 0.0])


def test_neighbour_pairs_against_brute_force_and_validation(rng):
    pos = rng.uniform(0, 10, (300, 3))
    rows, cols, dist = skin.neighbour_pairs(pos, 1.5)
    full = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    want = np.argwhere((full < 1.5) & ~np.eye(300, dtype=bool))
    assert {tuple(p) for p in np.stack([rows, cols], 1)} == {tuple(p) for p in want}
    np.testing.assert_allclose(dist, full[rows, cols], rtol=1e-12)
    with pytest.raises(FacestatsError, match=r"radius must lie in \(0, inf\] mm, got 0"):
        skin.neighbour_pairs(pos, 0.0)
    with pytest.raises(FacestatsError, match=r"positions must have shape \(n, 3\)"):
        skin.neighbour_pairs(pos[:, :2], 1.0)


def test_per_point_parameters_and_default_radius_settings_are_checked():
    n = np.array([[0, 0, 1.0], [0, 0, 1.0]])
    sub = skin.SubsurfaceTransport(SIGMA_S, SIGMA_A)
    args = dict(modulation=np.ones((2, 3)), subsurface=sub)
    ok = skin.skin_radiance(n, n[:, None], np.ones((2, 1, 3)), n[:, None], rho_s=0.1, roughness=[0.3, 0.3], **args)
    same = skin.skin_radiance(n, n[:, None], np.ones((2, 1, 3)), n[:, None], rho_s=[0.1, 0.1], roughness=0.3, **args)
    np.testing.assert_array_equal(ok, same)  # a scalar is the same parameter at every point
    with pytest.raises(FacestatsError, match=r"roughness must be a scalar or have shape \(2,\), got shape \(3,\)"):
        skin.skin_radiance(n, n[:, None], np.ones((2, 1, 3)), n[:, None], rho_s=0.1, roughness=[0.3] * 3, **args)
    with pytest.raises(FacestatsError, match=r"tail must lie in \(0, 1\)"):
        skin.SubsurfaceTransport(SIGMA_S, SIGMA_A, positions=np.zeros((2, 3)), areas=[1.0, 1.0], tail=1.0)
    with pytest.raises(FacestatsError, match="max_neighbors must be an integer"):
        skin.SubsurfaceTransport(SIGMA_S, SIGMA_A, positions=np.zeros((2, 3)), areas=[1.0, 1.0], max_neighbors=0)


def test_subsurface_transport_takes_integer_flux_as_numbers_and_refuses_bad_flux():
    from facestats.errors import ValidationError

    t = skin.SubsurfaceTransport([1.0, 1, 1], [0.1, 0.1, 0.1])
    expect = t.apply(np.ones((2, 3)))
    assert np.all(expect > 0.2)
    np.testing.assert_array_equal(t.apply(np.ones((2, 3), int)), expect)  # was truncated to 0
    for bad in (np.ones((2, 3), bool), np.full((2, 3), np.nan), -np.ones((2, 3)), np.full((2, 3), np.inf)):
        with pytest.raises(ValidationError, match="flux"):
            t.apply(bad)


def test_light_irradiance_refuses_normals_that_are_not_unit():
    """E = I cos θi / d² takes N·ωi as cos θi: a normal of length 2 doubled E."""
    from facestats.errors import ValidationError

    _, e = skin.point_lights([[0, 0, 0]], [[0, 0, 1.0]], [[0, 0, 10.0]], [100.0])
    np.testing.assert_allclose(e, 1.0)
    with pytest.raises(ValidationError, match="normals must hold unit vectors"):
        skin.point_lights([[0, 0, 0]], [[0, 0, 2.0]], [[0, 0, 10.0]], [100.0])
    with pytest.raises(ValidationError, match="normals must hold unit vectors"):
        skin.directional_lights([[0, 0, 2.0]], [[0, 0, 1.0]], [1.0])


def test_a_channel_that_only_absorbs_leaves_the_default_radius_to_the_others():
    """σ's = 0 in one channel (allowed) made the default radius 0, refused as "radius must lie in (0, inf]"."""
    pts = np.random.default_rng(0).random((60, 3))
    areas = np.full(60, 0.01)
    mixed = skin.SubsurfaceTransport([0.0, 1.0, 1.0], [0.1, 0.1, 0.1], positions=pts, areas=areas)
    alike = skin.SubsurfaceTransport([1.0, 1.0, 1.0], [0.1, 0.1, 0.1], positions=pts, areas=areas)
    assert mixed.radius == alike.radius > 0
    out = mixed.apply(np.ones((60, 1, 3)))
    assert np.all(out[..., 0] == 0) and np.allclose(out[..., 1:], alike.apply(np.ones((60, 1, 3)))[..., 1:])
    none = skin.SubsurfaceTransport([0.0, 0.0, 0.0], [0.1, 0.1, 0.1], positions=pts, areas=areas)
    assert none.radius == pytest.approx(0.1) and np.all(none.apply(np.ones((60, 1, 3))) == 0)


@pytest.mark.parametrize("specular", ["torrance_sparrow", "blinn_phong"])
@pytest.mark.parametrize("eta, message", [(np.nan, "finite"), (None, "numeric"), (-1.0, "eta must lie"),
                                          ([1.3, 1.4], "eta must be one number")])  # fmt: skip
def test_skin_radiance_checks_eta_whatever_the_specular_model(specular, eta, message):
    """Blinn-Phong never reads eta, but the diffuse transmittances do: NaN made them 0, an array the shape wrong."""
    st = skin.SubsurfaceTransport([1.0, 1.0, 1.0], [0.1, 0.1, 0.1])
    rough = 0.3 if specular == "torrance_sparrow" else 10.0
    args = (np.array([[0, 0, 1.0]]), np.array([[[0.6, 0, 0.8]]]), np.ones((1, 1, 3)), np.array([[[-0.6, 0, 0.8]]]))
    with pytest.raises(FacestatsError, match=message):
        skin.skin_radiance(*args, rho_s=0.1, roughness=rough, modulation=np.ones((1, 3)), subsurface=st,
                           specular=specular, eta=eta)  # fmt: skip


def test_modulation_texture_takes_a_boolean_mask_only():
    albedo = np.full((2, 3), 0.5)
    assert skin.modulation_texture(albedo, np.array([1, 0]))[0][1].tolist() == [0, 0, 0]  # 0/1 integers are fine
    with pytest.raises(FacestatsError, match="mask must hold booleans"):  # NaN and 0.5 read as True before
        skin.modulation_texture(albedo, np.array([np.nan, 0.0]))


def test_lights_and_cameras_too_far_for_a_squared_distance_are_refused_not_zero_directions():
    """|d|² overflowed past ~1e154 mm: the unit direction d/|d| came out 0 with an overflow warning (a red team)."""
    pos, nor = np.zeros((2, 3)), np.tile([0.0, 0.0, 1.0], (2, 1))
    with pytest.raises(FacestatsError, match="light_positions must lie within about 1e154 mm.*directional_lights"):
        skin.point_lights(pos, nor, np.array([[0.0, 0.0, 1e155]]), np.ones((1, 3)))
    with pytest.raises(FacestatsError, match="camera_positions must lie within about 1e154 mm"):
        skin.view_directions(pos, np.array([[0.0, 0.0, 1e155]]))
    np.testing.assert_allclose(skin.view_directions(pos, np.array([[0.0, 0.0, 1e150]]))[0, 0], [0, 0, 1])
