"""The quantised-distance system of Suzuki et al. eq. 22-35 (facestats.model.fitting.quantised)."""

import tracemalloc

import numpy as np
import pytest

from facestats.errors import FacestatsError, ValidationError
from facestats.model.fitting.quantised import (
    conditioning,
    dependent_levels,
    disk_hat_integrals,
    interpolation_matrix,
    merge_levels,
    normal_equations,
    quantised_system,
    solve_monotone,
    solve_pinv,
    uniform_levels,
)


def _dense_w(points, weights, rows, levels):
    """Straightforward reference: the full distance matrix, eq. 25-27 per pair, np.add.at into W (eq. 33)."""
    d = np.linalg.norm(points[rows][:, None, :] - points[None, :, :], axis=-1)
    i = np.searchsorted(levels, d, side="right") - 1
    beta = (levels[i + 1] - d) / (levels[i + 1] - levels[i])
    w = np.zeros((rows.size, levels.size))
    jj = np.broadcast_to(np.arange(rows.size)[:, None], d.shape)
    cw = np.broadcast_to(weights[None, :], d.shape)
    np.add.at(w, (jj, i), cw * beta)
    np.add.at(w, (jj, i + 1), cw * (1 - beta))
    return w


@pytest.fixture
def cloud():
    rng = np.random.default_rng(3)
    p = rng.uniform(0, 6, (300, 3))
    p[:, 2] *= 0.1
    c = rng.uniform(0.2, 1.0, 300) * (rng.uniform(size=300) < 0.6)
    rows = np.sort(rng.choice(300, 200, replace=False))
    return p, c, rows


@pytest.mark.parametrize("block_bytes", [2**20, 64 * 2**20])
def test_streamed_w_equals_the_dense_reference(cloud, block_bytes):
    p, c, rows = cloud
    s = quantised_system(p, c, rows, width=0.25, block_bytes=block_bytes)
    ref = _dense_w(p, c, rows, s.levels)
    np.testing.assert_allclose(s.matrix, ref, rtol=1e-12, atol=1e-12)
    # eq. 23: the last level lies beyond the largest distance, the one before does not.
    assert s.levels[-1] > s.max_distance >= s.levels[-2]
    assert s.n_pairs == rows.size * int(np.sum(c > 0))
    # Each (visible, lit) pair's hat weights sum to one: the support adds up to the pair count.
    assert s.support.sum() == pytest.approx(s.n_pairs, rel=1e-12)


def test_explicit_levels_and_their_checks(cloud):
    p, c, rows = cloud
    s = quantised_system(p, c, rows, width=0.5)
    lev = np.concatenate([[0, 0.3, 0.7], np.arange(1.0, s.levels[-1] + 1.0, 0.5)])
    e = quantised_system(p, c, rows, levels=lev)
    np.testing.assert_allclose(e.matrix, _dense_w(p, c, rows, lev), rtol=1e-12, atol=1e-12)
    with pytest.raises(
        ValidationError, match=r"levels must extend beyond the largest patch distance \(Suzuki eq. 23\)"
    ):
        quantised_system(p, c, rows, levels=[0.0, 0.5, 1.0])
    with pytest.raises(ValidationError, match=r"levels must start at 0 \(Suzuki eq. 22\)"):
        quantised_system(p, c, rows, levels=[0.1, 0.5, 20.0])
    with pytest.raises(ValidationError, match="width must lie in"):
        quantised_system(p, c, rows, width=0.0)
    with pytest.raises(ValidationError, match="no patch is lit"):
        quantised_system(p, np.zeros(300), rows, width=0.5)
    with pytest.raises(ValidationError, match="rows must select at least one"):
        quantised_system(p, c, np.array([], int), width=0.5)


def test_a_patch_and_itself_support_only_the_first_level():
    p = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    s = quantised_system(p, np.array([1.0, 0.0]), np.array([0, 1]), width=0.4)
    # pairs: (0,0) at d = 0 -> level 0 only; (1,0) at d = 1 = 2.5 w -> levels 2 and 3, half each.
    np.testing.assert_allclose(s.support, [1, 0, 0.5, 0.5])
    np.testing.assert_allclose(s.matrix, [[1, 0, 0, 0], [0, 0, 0.5, 0.5]])


def test_merging_levels_equals_building_on_the_coarser_levels(cloud):
    p, c, rows = cloud
    fine = quantised_system(p, c, rows, width=0.25)
    keep = np.zeros(fine.n_levels, bool)
    keep[::2] = True
    merged = merge_levels(fine, keep)
    coarse = quantised_system(p, c, rows, levels=merged.levels)
    np.testing.assert_allclose(merged.matrix, coarse.matrix, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(merged.support, coarse.support, rtol=1e-10)
    assert len(merged.merged) == fine.n_levels - merged.n_levels
    # Normal equations merge exactly too: Pᵀ G P.
    l = np.abs(fine.matrix @ np.exp(-fine.levels)) + 1e-3
    pm = interpolation_matrix(fine.levels, merged.levels)
    a = normal_equations(fine, l).merged(pm)
    b = normal_equations(merged, l)
    np.testing.assert_allclose(a.gram, b.gram, rtol=1e-9)
    np.testing.assert_allclose(a.rhs, b.rhs, rtol=1e-9)


def test_quantised_data_are_solved_exactly(cloud):
    p, c, rows = cloud
    s = quantised_system(p, c, rows, width=0.6)
    s = merge_levels(s, s.support >= 5)
    r_true = 0.3 * np.exp(-0.8 * s.levels) / (1 + s.levels)  # positive, decreasing
    l = s.matrix @ r_true
    np.testing.assert_allclose(solve_pinv(s, l), r_true, rtol=1e-6, atol=1e-12)
    r, used = solve_monotone(s, l)
    assert used.all()
    np.testing.assert_allclose(r, r_true, rtol=1e-5)


def test_monotone_solution_is_non_negative_and_non_increasing(cloud):
    p, c, rows = cloud
    s = quantised_system(p, c, rows, width=0.5)
    s = merge_levels(s, s.support >= 5)
    rng = np.random.default_rng(0)
    l = (s.matrix @ (0.3 * np.exp(-s.levels))) * (1 + 0.2 * rng.standard_normal(rows.size))
    r, _ = solve_monotone(s, np.maximum(l, 0))
    assert np.all(r >= 0) and np.all(np.diff(r) <= 1e-15)
    # The pseudo-inverse of the same noisy data does not respect the physics.
    assert np.any(np.diff(solve_pinv(s, np.maximum(l, 0))) > 0)


def test_rank_and_dependent_levels_are_detected():
    rng = np.random.default_rng(1)
    from facestats.model.fitting.quantised import QuantisedSystem

    w = rng.uniform(size=(50, 6))
    w[:, 4] = 2 * w[:, 2] + 1e-12 * rng.uniform(size=50)  # level 4 repeats level 2
    s = QuantisedSystem(w, np.arange(6.0), np.arange(50), np.full(6, 10.0), 5.5, 300)
    neq = normal_equations(s, np.ones(50), weighted=False)
    cond = conditioning(neq, rcond=1e-6)
    assert cond.rank == 5 and cond.condition > 1e6
    assert set(dependent_levels(neq, rcond=1e-6)) & {2, 4}


def test_memory_is_bounded_by_the_block_size_not_by_m_squared():
    rng = np.random.default_rng(2)
    m = 3000
    p = rng.uniform(0, 30, (m, 3))
    c = np.ones(m)
    tracemalloc.start()
    s = quantised_system(p, c, np.arange(m), width=1.0, block_bytes=2**20)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    dense = m * m * 8  # one float64 m × m distance matrix: 72 MB
    assert peak < dense / 4, peak
    assert peak < 2**20 * 3 + s.matrix.nbytes * 3


def test_uniform_levels_follow_eq_22_to_24():
    lev = uniform_levels(0.25, 1.0)
    np.testing.assert_allclose(lev, [0, 0.25, 0.5, 0.75, 1.0, 1.25])
    with pytest.raises(FacestatsError, match="max_distance"):
        uniform_levels(0.25, -1)


def test_disk_hat_integrals_integrate_the_interpolated_profile_over_disks():
    """Sum_i H_i(rho) R(d'_i) is the integral of the piecewise-linear R over the disk: exact for a linear R, the
    disk's area for R = 1; explicit (non-uniform) levels too."""
    levels = np.array([0.0, 0.3, 0.5, 1.1, 2.0])
    rho = np.array([0.0, 0.1, 0.3, 0.42, 1.7, 5.0])  # 5 mm: beyond the last level, taken up to it
    h = disk_hat_integrals(levels, rho)
    r_in = np.minimum(rho, 2.0)
    np.testing.assert_allclose(h.sum(1), np.pi * r_in**2, rtol=1e-13, atol=1e-15)
    exact = 2 * np.pi * (3 * r_in**2 / 2 - r_in**3 / 3)  # R(r) = 3 - r, linear: interpolated exactly
    np.testing.assert_allclose(h @ (3 - levels), exact, rtol=1e-12, atol=1e-15)
    assert np.all(h >= 0) and np.all(h[rho <= 1.1, 4] == 0) and np.all(h[rho > 1.1, 4] > 0)  # hat 4: [1.1, 2]


def test_the_footprint_self_term_replaces_r0_c_a_by_the_disk_integral(cloud):
    """With areas, a lit row's own pair is c_j H(rho_j) over the levels instead of c_j A_j at level 0; every
    other pair, and unlit rows, are as before; the point-kernel exitance takes the same self term."""
    from facestats.model.dipole import dipole_profile, dipole_radial_energy
    from facestats.model.fitting.quantised import point_kernel_exitance

    p, c, rows = cloud
    area = np.full(len(p), 0.2)
    w = c * area
    plain = quantised_system(p, w, rows, width=0.25)
    own = quantised_system(p, w, rows, width=0.25, areas=area)
    diff = own.matrix - plain.matrix
    lit = c[rows] > 0
    assert np.all(diff[~lit] == 0)
    h = disk_hat_integrals(plain.levels, np.full(1, np.sqrt(0.2 / np.pi)))[0]
    expected = c[rows][lit, None] * h[None] - np.outer(w[rows][lit], np.eye(plain.levels.size)[0])
    np.testing.assert_allclose(diff[lit], expected, rtol=1e-12, atol=1e-14)
    assert own.areas is not None and plain.areas is None
    s, a = 2.19, 0.0021
    l_pt = point_kernel_exitance(p, w, rows, lambda d: dipole_profile(d, s, a, 1.3))
    l_fp = point_kernel_exitance(
        p, w, rows, lambda d: dipole_profile(d, s, a, 1.3), areas=area,
        energy=lambda r: dipole_radial_energy(r, s, a, 1.3),
    )  # fmt: skip
    self_fp = c[rows] * dipole_radial_energy(np.sqrt(0.2 / np.pi), s, a, 1.3)
    np.testing.assert_allclose(l_fp - l_pt, self_fp - w[rows] * dipole_profile(0.0, s, a, 1.3), rtol=1e-10)
    with pytest.raises(ValidationError, match="areas and energy go together"):
        point_kernel_exitance(p, w, rows, lambda d: dipole_profile(d, s, a, 1.3), areas=area)
    with pytest.raises(ValidationError, match=r"areas must lie in \(0, inf\] mm\^2, got 0.0"):
        quantised_system(p, w, rows, width=0.25, areas=np.zeros(len(p)))


def test_the_surface_self_term_takes_near_patches_over_their_disks(cloud):
    """With near=True, W's rows keep their sums (the hats partition unity) and, as hats reproduce a linear R exactly,
    W applied to R(d) = d equals the point-kernel exitance of that R with the near pairs over the disks' nodes; only
    rows with a lit patch within NEAR_RADII radii change."""
    from facestats.model.disk_quadrature import NEAR_RADII
    from facestats.model.fitting.quantised import point_kernel_exitance, self_term_keywords

    p, c, rows = cloud
    area = np.full(len(p), 0.2)
    w = c * area
    foot = quantised_system(p, w, rows, width=0.05, **self_term_keywords("footprint", area))
    surf = quantised_system(p, w, rows, width=0.05, **self_term_keywords("surface", area))
    assert (foot.self_term, surf.self_term) == ("footprint", "surface") and surf.near and not foot.near
    np.testing.assert_array_equal(surf.levels, foot.levels)
    np.testing.assert_allclose(surf.matrix.sum(1), foot.matrix.sum(1), rtol=1e-12)
    linear = point_kernel_exitance(
        p, w, rows, lambda d: d, areas=area, energy=lambda r: 2 * np.pi * r**3 / 3, near=True
    )  # fmt: skip
    np.testing.assert_allclose(surf.matrix @ surf.levels, linear, rtol=1e-10)
    d = np.linalg.norm(p[rows][:, None] - p[None], axis=-1)
    near = ((d < NEAR_RADII * np.sqrt(0.2 / np.pi)) & (d > 0) & (w[None] > 0)).any(1)
    changed = np.abs(surf.matrix - foot.matrix).max(1) > 1e-12
    assert near.any() and (~near).any()
    np.testing.assert_array_equal(changed, near)
    assert self_term_keywords("point", area) == {}
    with pytest.raises(ValidationError, match="near must be True or False, and True only with areas"):
        quantised_system(p, w, rows, width=0.05, near=True)
    with pytest.raises(ValidationError, match="self_term must be one of"):
        self_term_keywords("disk", area)


def test_near_disks_of_a_tiny_scene_converge_and_bad_input_is_named():
    """Two patches of 4 mm^2 1 mm apart: the near disk reaches beyond the pair distance, so the levels must too; W
    applied to the dipole then converges to the point-kernel exitance with the near pair over its disk as the width
    falls (a red team found it stuck at +19-23 % when the levels stopped at the pair's distance)."""
    from facestats.model.dipole import dipole_profile, dipole_radial_energy
    from facestats.model.fitting.quantised import planned_levels, point_kernel_exitance

    p = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    c, area = np.array([1.0, 0.0]), np.full(2, 4.0)
    medium = (2.19, 0.0021, 1.3)
    exact = point_kernel_exitance(
        p, c * area, [0, 1], lambda d: dipole_profile(d, *medium), areas=area,
        energy=lambda r: dipole_radial_energy(r, *medium), near=True,
    )  # fmt: skip
    errors = []
    for w in (0.1, 0.01):
        system = quantised_system(p, c * area, width=w, areas=area, near=True)
        assert system.n_levels <= planned_levels(p, c * area, width=w, areas=area, near=True)
        errors.append(np.abs(system.matrix @ dipole_profile(system.levels, *medium) / exact - 1).max())
    assert errors[0] < 0.01 and errors[1] < 1e-4, errors  # measured 4.4e-3 and 4.3e-5
    with pytest.raises(ValidationError, match="near must be True or False, got 'yes'"):
        point_kernel_exitance(p, c, [0], lambda d: d, areas=area, energy=lambda r: r, near="yes")
    with pytest.raises(ValidationError, match="near must be True or False, and True only with areas"):
        planned_levels(p, c * area, width=0.1, near=True)  # was a bare IndexError; quantised_system's message
    with pytest.raises(ValidationError, match="areas must have shape"):
        planned_levels(p, c * area, width=0.1, areas=area[:1], near=True)


def test_a_lit_patch_is_not_its_own_near_neighbour():
    """The surface self term integrates the *other* lit patches within NEAR_RADII radii over their disks; a patch's
    own light is the footprint already: a lone lit patch's row is that of the footprint self term."""
    from facestats.model.fitting.quantised import self_term_keywords

    p = np.array([[0.0, 0, 0], [5.0, 0, 0]])
    area, w, rows = np.array([0.2, 0.2]), np.array([1.0, 0.0]), np.array([0, 1])
    foot = quantised_system(p, w, rows, width=0.05, **self_term_keywords("footprint", area))
    surf = quantised_system(p, w, rows, width=0.05, **self_term_keywords("surface", area))
    np.testing.assert_array_equal(surf.matrix, foot.matrix)


def test_levels_ending_at_the_largest_distance_are_refused():
    """Eq. 23: d'_n > max d_jk, strictly (a pair at d'_n has no level beyond it to interpolate towards)."""
    p = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    with pytest.raises(ValidationError, match=r"levels must extend beyond the largest patch distance"):
        quantised_system(p, np.ones(2), np.arange(2), levels=[0.0, 0.5, 1.0])
    assert quantised_system(p, np.ones(2), np.arange(2), levels=[0.0, 0.5, 1.0 + 1e-9]).matrix.shape == (2, 3)


@pytest.mark.parametrize("weighted", [False, True])
def test_residual_and_covariance_of_the_normal_equations_match_a_direct_least_squares(cloud, weighted):
    """residual(r) = ‖A r − y‖² (A = W, y = l; weighted: A = W / l, y = 1 over the rows with l > 0) and the
    covariance s² (AᵀA)⁻¹ with s² = residual / (rows − levels), both computed here from A directly."""
    from facestats.model.fitting.quantised import profile_covariance

    p, c, rows = cloud
    s = quantised_system(p, c, rows, width=1.0)
    rng = np.random.default_rng(4)
    l = s.matrix @ np.linspace(1.0, 0.1, s.n_levels) * rng.uniform(0.9, 1.1, rows.size)
    l[:5] = 0.0  # rows the weighted problem leaves out
    use = l > 0 if weighted else np.ones(rows.size, bool)
    a = s.matrix[use] / l[use, None] if weighted else s.matrix
    y = np.ones(use.sum()) if weighted else l
    neq = normal_equations(s, l, weighted=weighted)
    r = np.linalg.lstsq(a, y, rcond=None)[0] * 1.01  # not the minimum: the residual's cross term counts
    direct = float(np.sum((a @ r - y) ** 2))
    assert neq.residual(r) == pytest.approx(direct, rel=1e-9)
    cov = np.sum((a @ r - y) ** 2) / (a.shape[0] - a.shape[1]) * np.linalg.inv(a.T @ a)
    np.testing.assert_allclose(profile_covariance(neq, r), cov, rtol=1e-6)


def test_rank_and_dependent_levels_use_rcond_on_singular_values_not_on_their_squares():
    """Scaled Gram [[1, c], [c, 1]]: singular values √(1 ± c).  c = 1 − 5e-7 gives s_min/s_max = 5.0e-4: full rank
    at rcond 1e-4 (its pivoted Cholesky's second pivot 1 − c² = 1e-6 is above rcond² = 1e-8), rank 1 at 1e-3."""
    from facestats.model.fitting.quantised import NormalEquations

    c = 1 - 5e-7
    neq = NormalEquations(np.array([[4.0, 2 * c], [2 * c, 1.0]]), np.zeros(2), 0.0, 10, False)  # scales 2 and 1
    np.testing.assert_allclose(conditioning(neq).singular_values, np.sqrt([1 + c, 1 - c]), rtol=1e-6)
    assert conditioning(neq, rcond=1e-4).rank == 2 and dependent_levels(neq, rcond=1e-4).size == 0
    assert conditioning(neq, rcond=1e-3).rank == 1 and dependent_levels(neq, rcond=1e-3).size == 1
    c = 1 - 2e-12  # s_min/s_max = 1e-6
    neq = NormalEquations(np.array([[1.0, c], [c, 1.0]]), np.zeros(2), 0.0, 10, False)
    assert conditioning(neq, rcond=1e-4).rank == 1 and conditioning(neq, rcond=1e-7).rank == 2
