"""The polar rule over a patch's disk (facestats.model.disk_quadrature) against independent integrals."""

import numpy as np
import pytest

from facestats.errors import ValidationError
from facestats.model.dipole import dipole_profile, dipole_radial_energy
from facestats.model.disk_quadrature import DISK_RULE, disk_node_distances, disk_rule

TABLE1 = (2.19, 0.0021, 1.3)  # Suzuki Table 1's medium (sigma_s', sigma_a in 1/mm, eta)


def test_the_rule_is_an_area_average_exact_for_low_degree_moments():
    s, phi, w = disk_rule()
    assert s.size == phi.size == w.size == DISK_RULE[0] * DISK_RULE[1]
    assert w.sum() == pytest.approx(1, abs=1e-14) and (w > 0).all()
    x, y = s * np.cos(phi), s * np.sin(phi)
    # area means over the unit disk: <x> = <y> = 0, <r^2> = 1/2, <r^4> = 1/3, <x^2 y^2> = 1/24
    assert w @ x == pytest.approx(0, abs=1e-14) and w @ y == pytest.approx(0, abs=1e-14)
    assert w @ s**2 == pytest.approx(1 / 2, rel=1e-13) and w @ s**4 == pytest.approx(1 / 3, rel=1e-13)
    assert w @ (x * x * y * y) == pytest.approx(1 / 24, rel=1e-12)


@pytest.mark.parametrize("d", [1.0, np.sqrt(2), 0.3])
def test_the_dipole_over_a_disk_matches_an_adaptive_quadrature(d):
    """A 1 mm^2 disk seen from its neighbours' centres (and from inside it): within 5e-6 of scipy's dblquad."""
    from scipy.integrate import dblquad

    rho = np.sqrt(1 / np.pi)
    r, w = disk_node_distances([d], [rho])
    got = np.pi * rho**2 * (dipole_profile(r[0], *TABLE1) @ w)

    def integrand(t, u):  # polar coordinates (u radius, t angle) about the disk's centre, point at (d, 0)
        return dipole_profile(np.sqrt(d * d + u * u - 2 * d * u * np.cos(t)), *TABLE1) * u

    ref, err = dblquad(integrand, 0, rho, 0, 2 * np.pi, epsabs=0, epsrel=1e-10)
    assert got == pytest.approx(ref, rel=5e-6)  # measured 1.8e-6 at d = 1 mm


def test_from_the_centre_the_rule_gives_the_closed_form_radial_energy():
    rho = np.array([0.2, 0.56, 1.0])
    r, w = disk_node_distances(np.zeros(3), rho)
    got = np.pi * rho**2 * (dipole_profile(r, *TABLE1) @ w)
    np.testing.assert_allclose(got, dipole_radial_energy(rho, *TABLE1), rtol=1e-5)  # measured 3.9e-6 at 1 mm


def test_bad_distances_are_named():
    with pytest.raises(ValidationError, match="distance"):
        disk_node_distances([-1.0], [0.5])
    with pytest.raises(ValidationError, match="radius"):
        disk_node_distances([1.0], [np.nan])


def test_distances_and_radii_must_pair_up():
    with pytest.raises(ValidationError, match="distance and radius must be 1-D of one length"):
        disk_node_distances([1.0, 2.0], [0.5, 0.5, 0.5])
