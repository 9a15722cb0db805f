import numpy as np
import pytest

from facestats import FacestatsError
from facestats.model import brdf, dipole
from facestats.model.fresnel import fresnel_reflectance
from tests.helpers import random_hemisphere

N = np.array([0.0, 0.0, 1.0])


def _hemisphere_albedo(f, theta_i, n=400):
    th = np.linspace(0, np.pi / 2, n)
    ph = np.linspace(0, 2 * np.pi, 2 * n)
    t, p = np.meshgrid(th, ph, indexing="ij")
    wo = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)
    wi = np.array([np.sin(theta_i), 0, np.cos(theta_i)])
    v = f(N, wi, wo) * np.cos(t) * np.sin(t)
    return np.trapezoid(np.trapezoid(v, ph, axis=1), th)


@pytest.mark.parametrize("model", ["ts", "bp"])
def test_helmholtz_reciprocity(rng, model):
    n = 5000
    normal = random_hemisphere(rng, n, (0.2, -0.1, 1.0), min_cos=0.5)
    wi = random_hemisphere(rng, n)
    wo = random_hemisphere(rng, n)
    rho = rng.uniform(0.05, 0.4, n)
    if model == "ts":
        p = rng.uniform(0.1, 0.6, n)
        a, b = brdf.torrance_sparrow(normal, wi, wo, rho, p), brdf.torrance_sparrow(normal, wo, wi, rho, p)
    else:
        p = rng.uniform(1, 200, n)
        a, b = brdf.blinn_phong(normal, wi, wo, rho, p), brdf.blinn_phong(normal, wo, wi, rho, p)
    assert np.count_nonzero(a) > n // 2
    np.testing.assert_allclose(a, b, rtol=1e-10, atol=0)


@pytest.mark.parametrize("theta_i, theta_o", [(30, 50), (80, 20), (20, 80)])
def test_torrance_sparrow_against_independent_angles(theta_i, theta_o):
    # Azimuths opposite: H, δ and all terms by hand.  At 80°/20° the V-groove term of the grazing direction
    # (eq. 13, 0.468) is the smallest of the three, so G < 1 and the minimum must pick the smaller cosine.
    ti, to = np.radians(theta_i), np.radians(theta_o)
    wi = np.array([np.sin(ti), 0, np.cos(ti)])
    wo = np.array([-np.sin(to), 0, np.cos(to)])
    h = (wi + wo) / np.linalg.norm(wi + wo)
    delta = np.arccos(h[2])
    m, rho, eta = 0.3, 0.2, 1.38
    d = np.exp(-((np.tan(delta) / m) ** 2)) / (m**2 * np.cos(delta) ** 4)
    c = wo @ h
    g = min(1, 2 * h[2] * wo[2] / c, 2 * h[2] * wi[2] / c)
    assert (g < 1) == (max(theta_i, theta_o) == 80)
    f = rho / np.pi * d * g / (wi[2] * wo[2]) * fresnel_reflectance(c, eta)
    assert brdf.torrance_sparrow(N, wi, wo, rho, m, eta) == pytest.approx(f, rel=1e-12)
    assert brdf.v_groove_shadowing(h[2], wi[2], wo[2], c) == pytest.approx(g, rel=1e-12)


def test_half_vector_is_the_unit_bisector(rng):
    wi, wo = random_hemisphere(rng, 200), random_hemisphere(rng, 200)
    h = brdf.half_vector(wi, wo)
    np.testing.assert_allclose(np.linalg.norm(h, axis=-1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.sum(h * wi, -1), np.sum(h * wo, -1), atol=1e-12)  # equal angles to ωi and ωo
    np.testing.assert_allclose(np.cross(h, wi + wo), 0.0, atol=1e-12)  # along ωi + ωo
    assert np.all(np.sum(h * (wi + wo), -1) > 0)


def test_blinn_phong_against_formula():
    wi = np.array([0.6, 0.0, 0.8])
    wo = np.array([0.0, 0.6, 0.8])
    h = (wi + wo) / np.linalg.norm(wi + wo)
    assert brdf.blinn_phong(N, wi, wo, 0.3, 20.0) == pytest.approx(0.3 * 22 / (2 * np.pi) * h[2] ** 20, rel=1e-12)


def test_zero_below_horizon(rng):
    wi = random_hemisphere(rng, 100)
    wo = -random_hemisphere(rng, 100)  # all below
    assert np.all(brdf.torrance_sparrow(N, wi, wo, 0.3, 0.3) == 0)
    assert np.all(brdf.blinn_phong(N, wo, wi, 0.3, 10) == 0)


def test_blinn_phong_lobe_normalised_over_half_vectors():
    # Weyrich eq. 11: (n+2)/2π makes the cosine lobe integrate to one (over ω_H).
    d = np.linspace(0, np.pi / 2, 200001)
    for n in (1, 10, 100):
        integral = 2 * np.pi * np.trapezoid(brdf.blinn_phong_lobe(np.cos(d), n) * np.cos(d) * np.sin(d), d)
        assert integral == pytest.approx(1.0, rel=1e-6)


def test_blinn_phong_albedo_exceeds_rho_s_as_documented():
    a5 = _hemisphere_albedo(lambda n, i, o: brdf.blinn_phong(n, i, o, 1.0, 5.0), 0.0)
    a100 = _hemisphere_albedo(lambda n, i, o: brdf.blinn_phong(n, i, o, 1.0, 100.0), 0.0)
    assert a5 == pytest.approx(2.30, abs=0.02)
    assert a100 == pytest.approx(3.85, abs=0.03)
    # the closed form of blinn_phong_albedo against the integral, and oblique incidence reflects less
    for n in (0.0, 5.0, 100.0, 400.0):
        num = _hemisphere_albedo(lambda nn, i, o: brdf.blinn_phong(nn, i, o, 1.0, n), 0.0, n=1200)
        assert brdf.blinn_phong_albedo(n) == pytest.approx(num, rel=2e-3), n
        for th in (20, 50):
            assert _hemisphere_albedo(lambda nn, i, o: brdf.blinn_phong(nn, i, o, 1.0, n), np.radians(th)) < num
    assert brdf.blinn_phong_albedo(0.0) == pytest.approx(1.0, rel=1e-15)
    assert np.all(np.diff(brdf.blinn_phong_albedo(np.linspace(0, 5000, 101))) > 0)
    assert brdf.blinn_phong_albedo(5000.0) == pytest.approx(4.0, rel=2e-3)


@pytest.mark.parametrize("m", [0.15, 0.3, 0.5])
def test_torrance_sparrow_energy(m):
    # ρs = 1/4 is the physical Cook-Torrance BRDF: its albedo at normal incidence is
    # the Fresnel reflectance of the facets, and it never exceeds 1.
    a0 = _hemisphere_albedo(lambda n, i, o: brdf.torrance_sparrow(n, i, o, 0.25, m), 0.0)
    assert a0 == pytest.approx(fresnel_reflectance(1.0, 1.38), rel=0.1)
    for th in (30, 60, 80):
        assert _hemisphere_albedo(lambda n, i, o: brdf.torrance_sparrow(n, i, o, 0.25, m), np.radians(th)) < 1


def test_beckmann_peak_and_monotone():
    c = np.cos(np.linspace(0, 1.4, 300))
    d = brdf.beckmann_distribution(c, 0.3)
    assert d[0] == pytest.approx(1 / 0.09)
    assert np.all(np.diff(d) < 0)


def test_dtype_and_broadcasting(rng):
    wi = random_hemisphere(rng, 12).astype(np.float32).reshape(3, 4, 3)
    wo = random_hemisphere(rng, 4).astype(np.float32)
    f = brdf.torrance_sparrow(N.astype(np.float32), wi, wo, np.float32(0.2), np.float32(0.3))
    assert f.shape == (3, 4) and f.dtype == np.float32
    g = brdf.blinn_phong(N, wi.astype(float), wo.astype(float), 0.2, 10.0)
    assert g.dtype == np.float64


def test_validation_messages():
    with pytest.raises(FacestatsError, match="wi must hold unit vectors"):
        brdf.torrance_sparrow(N, [0, 0, 2.0], N, 0.2, 0.3)
    with pytest.raises(FacestatsError, match=r"m must lie in \(0, inf\], got -0.1"):
        brdf.torrance_sparrow(N, N, N, 0.2, -0.1)
    with pytest.raises(FacestatsError, match=r"normal must have shape \(\.\.\., 3\)"):
        brdf.blinn_phong([0, 1.0], N, N, 0.2, 3)
    with pytest.raises(FacestatsError, match="rho_s must be finite"):
        brdf.blinn_phong(N, N, N, np.nan, 3)


def test_the_unit_vector_check_has_one_rule_in_both_modes():
    """``check_unit_vectors`` compares squared norms (fast) unless asked for the norms; both give one rule."""
    from facestats.core.validate import check_unit_vectors
    from facestats.errors import ValidationError

    inside = np.array([[0.0, 0.0, 1.0009], [0.0, 0.9991, 0.0]])
    outside = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0011]])
    for norms in (False, True):
        check_unit_vectors(inside, "v", 1e-3, norms=norms)
        with pytest.raises(
            ValidationError, match=r"v must hold unit vectors \(norm 1 ± 0.001\), got a vector of norm 1.0011$"
        ):
            check_unit_vectors(outside, "v", 1e-3, norms=norms)
        check_unit_vectors(np.zeros((2, 3)), "v", allow_zero=True, norms=norms)
    assert np.array_equal(check_unit_vectors(inside, "v", norms=True), np.linalg.norm(inside, axis=-1))


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: dipole.dipole_profile(np.ones(3), np.ones(2), 0.1),
         r"r, sigma_s_prime, sigma_a, eta must broadcast .* r \(3,\), sigma_s_prime \(2,\)"),
        (lambda: brdf.torrance_sparrow(np.tile(N, (3, 1)), N, N, np.full(2, 0.1), 0.3),
         r"normal, wi, wo, rho_s, m, eta must broadcast .* normal \(3,\), wi \(\), wo \(\), rho_s \(2,\)"),
        (lambda: brdf.blinn_phong(np.tile(N, (3, 1)), N, N, 0.1, np.full(2, 20.0)),
         r"exponent \(2,\)"),
        (lambda: fresnel_reflectance(np.full(3, 0.5), np.full(2, 1.3)),
         r"cos_theta, eta must broadcast .* cos_theta \(3,\), eta \(2,\)"),
        (lambda: brdf.torrance_sparrow_geometry(N, np.array([0.0, 1.0]), N), r"wi must have shape \(\.\.\., 3\)"),
        (lambda: brdf.half_vector(np.ones((4, 2)), np.ones((4, 2))), r"wi must have shape \(\.\.\., 3\)"),
        (lambda: brdf.half_vector(np.tile(N, (4, 1)), np.tile(N, (5, 1))), r"wi, wo must broadcast .* wi \(4, 3\)"),
    ],
)  # fmt: skip
def test_shapes_that_do_not_broadcast_are_named(call, match):
    """numpy's "Mismatch is between arg 0 and arg 1" or an IndexError named no argument (an API red team)."""
    with pytest.raises(FacestatsError, match=match):
        call()
