import numpy as np
import pytest
from scipy.integrate import quad

from facestats import FacestatsError
from facestats.core import published
from facestats.model import dipole


def test_profile_positive_and_decreasing():
    r = np.linspace(0, 50, 5001)
    for s, a in [(0.74, 0.032), (2.29, 0.003), (1.5, 0.3), (0.5, 1.2)]:
        p = dipole.dipole_profile(r, s, a, 1.38)
        assert np.all(p > 0)
        assert np.all(np.diff(p) < 0)


@pytest.mark.parametrize(
    "s,a,eta", [(0.74, 0.032, 1.3), (2.29, 0.003, 1.3), (1.69, 0.17, 1.38), (1.0, 1.0, 1.38), (3.0, 0.5, 1.5)]
)
def test_numerical_integral_equals_total_reflectance(s, a, eta):
    num, _ = quad(
        lambda r: 2 * np.pi * r * dipole.dipole_profile(r, s, a, eta), 0, np.inf, epsabs=1e-14, epsrel=1e-12, limit=500
    )
    assert num == pytest.approx(float(dipole.total_diffuse_reflectance(s, a, eta)), abs=1e-8)
    assert float(dipole.dipole_radial_energy(np.inf, s, a, eta)) == pytest.approx(num, abs=1e-8)


def test_radial_energy_is_the_cumulative_integral():
    r = np.linspace(0.0, 8.0, 9)
    e = dipole.dipole_radial_energy(r, 1.2, 0.1)
    for ri, ei in zip(r, e):
        num, _ = quad(lambda x: 2 * np.pi * x * dipole.dipole_profile(x, 1.2, 0.1), 0, ri, epsabs=1e-13)
        assert ei == pytest.approx(num, abs=1e-10)


def test_reduced_albedo_round_trip():
    alpha = np.linspace(0.01, 0.99, 9801)
    total = dipole.total_diffuse_reflectance(alpha, 1 - alpha)  # σ't = 1 mm⁻¹: α' = σ's
    back = dipole.reduced_albedo(total, 1.38)
    np.testing.assert_allclose(back, alpha, atol=1e-9, rtol=0)
    t = np.linspace(0.01, 0.99, 999)
    np.testing.assert_allclose(dipole.total_diffuse_reflectance(*_sa(dipole.reduced_albedo(t))), t, atol=1e-9)


def _sa(alpha):
    return alpha, 1 - alpha


def test_reduced_albedo_rejects_outside_unit_interval():
    for bad in (0.0, 1.0, -0.1, 1.2):
        with pytest.raises(FacestatsError, match=r"total_reflectance must lie in \(0, 1\)"):
            dipole.reduced_albedo(bad)


def test_scattering_from_albedo_reproduces_sigma_tr_and_albedo(rng):
    albedo = rng.uniform(0.02, 0.9, (500, 3))
    sigma_tr = rng.uniform(0.2, 3.0, (500, 3))
    s, a = dipole.scattering_from_albedo(albedo, sigma_tr, 1.38)
    np.testing.assert_allclose(dipole.transport_coefficient(a, s), sigma_tr, rtol=1e-12)
    np.testing.assert_allclose(dipole.total_diffuse_reflectance(s, a, 1.38), albedo, atol=1e-10)
    assert np.all(s > 0) and np.all(a > 0)


def test_published_jensen_total_reflectance():
    # Suzuki Fig. 3 parameters (Jensen et al. 2001, red channel, η = 1.3) and the
    # diffuse reflectance R_d that Jensen et al. tabulate for them.
    for mat in (published.JENSEN_SKIN1, published.JENSEN_APPLE):
        rd = dipole.total_diffuse_reflectance(mat["sigma_s_prime"], mat["sigma_a"], mat["eta"])
        assert rd == pytest.approx(mat["Rd"], abs=0.005)


def test_published_sigma_tr_avg_is_mean_of_cheek_and_forehead():
    # Weyrich §5.4: σtrAvg is the mean over subjects of the cheek and forehead
    # measurements; with equal counts it is the mean of the two Table 1 means.
    avg = (published.TABLE1_MEAN["cheek"] + published.TABLE1_MEAN["forehead"]) / 2
    np.testing.assert_allclose(avg, published.SIGMA_TR_AVG, atol=1e-4)


def test_transport_coefficient_and_mean_free_path():
    assert dipole.transport_coefficient(0.032, 0.74) == pytest.approx(np.sqrt(3 * 0.032 * 0.772))
    np.testing.assert_allclose(dipole.diffuse_mean_free_path(published.SIGMA_TR_AVG), 1 / published.SIGMA_TR_AVG)
    # The published extreme subjects bracket σtrAvg in the red channel.
    assert 1 / published.ELL_D_MAX[0] < published.SIGMA_TR_AVG[0] < 1 / published.ELL_D_MIN[0]


def test_profile_shape_depends_on_sigma_tr():
    # Larger σtr (more absorption) => steeper decay far from the source.
    r = np.array([5.0, 10.0])
    p1 = dipole.dipole_profile(r, 1.0, 0.01)
    p2 = dipole.dipole_profile(r, 1.0, 0.1)
    assert p1[1] / p1[0] > p2[1] / p2[0]


def test_dtype_float32():
    p = dipole.dipole_profile(np.float32([0.5, 1.0]), np.float32(1.0), np.float32(0.1))
    assert p.dtype == np.float32
    assert dipole.reduced_albedo(np.float32(0.4)).dtype == np.float32


def test_validation():
    with pytest.raises(FacestatsError, match="r must lie in"):
        dipole.dipole_profile(-1, 1, 0.1)
    with pytest.raises(FacestatsError, match="sigma_a must lie in"):
        dipole.dipole_profile(1, 1, -0.1)
    with pytest.raises(FacestatsError, match="neither scatters nor absorbs"):
        dipole.total_diffuse_reflectance(0, 0)
    with pytest.raises(FacestatsError, match="sigma_tr must lie in"):
        dipole.scattering_from_albedo(0.5, 0.0)


def test_boundary_coefficient_matches_fresnel_and_validates():
    from facestats.model.fresnel import diffuse_fresnel_reflectance

    fdr = diffuse_fresnel_reflectance(1.38)
    assert dipole.boundary_coefficient(1.38) == pytest.approx((1 + fdr) / (1 - fdr), rel=1e-15)
    assert dipole.boundary_coefficient(1.38) == pytest.approx(3.116, abs=2e-3)  # F_dr = 0.5141
    with pytest.raises(FacestatsError, match=r"eta must lie in \[1, 3\], got 0.9"):
        dipole.boundary_coefficient(0.9)
    with pytest.raises(FacestatsError, match="radius must be a number of mm"):
        dipole.dipole_radial_energy(np.nan, 1.0, 0.1)
    assert dipole.dipole_radial_energy(np.inf, 1.0, 0.1) == pytest.approx(
        dipole.total_diffuse_reflectance(1.0, 0.1), rel=1e-12
    )


def test_coefficients_whose_sum_overflows_keep_their_reduced_albedo():
    """σ's + σa = inf gave α' = 0 and a total reflectance of 0 (a red team); the ratio alone is kept there."""
    ref = dipole.total_diffuse_reflectance(1.0, 1.0)
    assert dipole.total_diffuse_reflectance(1e308, 1e308) == ref
    assert dipole.total_diffuse_reflectance(np.float32(2e38), np.float32(2e38)) == pytest.approx(ref, rel=1e-6)
    # Unequal coefficients whose sum overflows (1.5e308 + 0.5e308; 1e308 + 0.5e308 did not): α' = 3/4, not 1/4.
    assert dipole.total_diffuse_reflectance(1.5e308, 0.5e308) == pytest.approx(
        dipole.total_diffuse_reflectance(3.0, 1.0), rel=1e-15
    )
    assert dipole.reduced_albedo_unchecked(np.array([0.74, 1e308]), np.array([0.032, 1e308]))[0] == 0.74 / 0.772
    with pytest.raises(FacestatsError, match="dipole_radial_energy is not finite"):  # was NaN, as dipole_profile
        dipole.dipole_radial_energy(1.0, 1e308, 1e308)
