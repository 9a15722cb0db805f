import warnings

import numpy as np
import pytest

from facestats import FacestatsError
from facestats.model.fresnel import diffuse_fresnel_reflectance, fresnel_reflectance, fresnel_transmittance


@pytest.mark.parametrize("eta", [1.3, 1.38, 1.5, 2.0, 1 / 1.38])
def test_normal_incidence(eta):
    assert fresnel_reflectance(1.0, eta) == pytest.approx(((eta - 1) / (eta + 1)) ** 2, rel=1e-12)


def test_glass_45_degrees_textbook_value():
    # Air to glass (n = 1.5) at 45°: Rs = 0.0920, Rp = 0.0085 (Hecht, Optics, Fig. 4.50).
    assert fresnel_reflectance(np.cos(np.pi / 4), 1.5) == pytest.approx((0.092013 + 0.008466) / 2, abs=2e-5)


def test_transmittance_is_one_minus_reflectance(rng):
    c = rng.uniform(0, 1, 1000)
    eta = rng.uniform(0.5, 2.5, 1000)
    np.testing.assert_allclose(fresnel_transmittance(c, eta), 1 - fresnel_reflectance(c, eta), atol=1e-15)


def test_grazing_and_total_internal_reflection():
    assert fresnel_reflectance(0.0, 1.38) == 1.0
    crit = np.sqrt(1 - (1 / 1.38) ** 2)  # cos of the critical angle inside skin
    assert np.all(fresnel_reflectance(np.linspace(0, crit - 1e-6, 50), 1 / 1.38) == 1.0)
    assert np.all(fresnel_reflectance(np.linspace(crit + 1e-3, 1, 50), 1 / 1.38) < 1.0)


def test_reflectance_monotone_in_angle():
    c = np.linspace(0, 1, 500)
    r = fresnel_reflectance(c, 1.38)
    assert np.all(np.diff(r) <= 1e-15)  # brighter towards grazing (θ up, cos down)


def test_dtype_preserved():
    assert fresnel_reflectance(np.float32([0.5, 0.7]), 1.38).dtype == np.float32
    assert fresnel_transmittance(np.float32([0.5, 0.7]), 1.38).dtype == np.float32
    # A scalar gives a 0-d array from both (the transmittance was a numpy scalar: an API red team).
    assert type(fresnel_reflectance(0.5)) is type(fresnel_transmittance(0.5)) is np.ndarray
    assert fresnel_reflectance(np.array([0.5]), 1.38).dtype == np.float64


def test_diffuse_fresnel_reflectance_matches_internal_integral():
    mu = np.linspace(0, 1, 200001)
    for eta in (1.2, 1.3, 1.38, 1.5, 1.6):
        numeric = 2 * np.trapezoid(fresnel_reflectance(mu, 1 / eta) * mu, mu)
        assert diffuse_fresnel_reflectance(eta) == pytest.approx(numeric, rel=3e-3)
    assert diffuse_fresnel_reflectance(1.38) == pytest.approx(0.5141, abs=1e-4)


def test_diffuse_fresnel_range_and_monotone():
    eta = np.linspace(1.0, 3.0, 400)
    f = diffuse_fresnel_reflectance(eta)
    assert np.all((f > 0) & (f < 1))
    assert np.all(np.diff(f) > 0)


def test_errors_name_argument_and_value():
    with pytest.raises(FacestatsError, match=r"cos_theta must lie in \[0, 1\], got 1.5"):
        fresnel_reflectance(1.5, 1.38)
    with pytest.raises(FacestatsError, match=r"cos_theta must lie in \[0, 1\], got 1.001"):
        fresnel_reflectance(1.001, 1.38)  # beyond the 1e-6 rounding tolerance
    assert fresnel_reflectance(1 + 1e-7, 1.38) == fresnel_reflectance(1.0, 1.38)  # rounding overshoot: clipped
    with pytest.raises(FacestatsError, match="eta"):
        fresnel_reflectance(0.5, -1.0)
    with pytest.raises(FacestatsError, match="cos_theta must be finite"):
        fresnel_reflectance(np.nan, 1.38)
    with pytest.raises(FacestatsError, match=r"eta must lie in \[1, 3\]"):
        diffuse_fresnel_reflectance(0.8)
    with pytest.raises(ValueError):  # ValidationError is also a ValueError
        fresnel_reflectance("x", 1.38)


def test_a_huge_index_reflects_everything_without_overflow_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert fresnel_reflectance(0.5, 1e300) == 1.0 and fresnel_transmittance(0.0, 1e300) == 0.0
        assert fresnel_reflectance(np.float32(0.5), np.float32(1e30)) == 1.0
