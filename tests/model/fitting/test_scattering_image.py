"""Translucency from one image (Suzuki, Mukaigawa & Yagi): eq. 36 fit, Table 3, noise, auto width, rank, bad input."""

import warnings

import numpy as np
import pytest

from facestats.acquire.synthetic.scenes import pyramid_scene
from facestats.core.published import SUZUKI_TABLE1, SUZUKI_TABLE3
from facestats.errors import FacestatsError, FitError, QuantisationWarning, ValidationError
from facestats.model.dipole import dipole_profile
from facestats.model.fitting import fit_scattering_image
from facestats.model.fitting.profile_grid import TABLE2_GRID, ProfileGrid, fit_profile_grid, profile_cost
from facestats.model.fitting.scattering_image import SELF_TERMS
from facestats.pipeline.suzuki_studies import noise_study, render_scene, table3

TRUTH = (SUZUKI_TABLE1["sigma_s_prime"], SUZUKI_TABLE1["sigma_a"])
#: The issue's tolerance on the Table 1 scene.
TOL_S, TOL_A = 0.05, 0.0003


@pytest.fixture(scope="module")
def edge():
    """Table 1's pyramid under edge-like light (+x face lit, the rest shadowed), point-kernel truth."""
    return render_scene(pyramid_scene(1.8, "edge"))


@pytest.fixture(scope="module")
def oblique():
    return render_scene(pyramid_scene(2.5, "oblique"))


def _fit(r, l=None, **kw):
    p = r.patches
    return fit_scattering_image(p.centre, p.area, r.irradiance, r.exitance if l is None else l, visible=r.visible, **kw)


def test_table2_grid_is_the_papers():
    g = TABLE2_GRID
    assert g.shape == (300, 30) and g.shape[0] * g.shape[1] == 9000
    assert (g.sigma_s_prime[0], g.sigma_s_prime[-1], g.sigma_a[0], g.sigma_a[-1]) == (0.01, 3.0, 0.0001, 0.003)
    np.testing.assert_allclose(np.diff(g.sigma_s_prime), 0.01)
    np.testing.assert_allclose(np.diff(g.sigma_a), 0.0001)


def test_grid_cost_matches_eq_36_evaluated_model_by_model():
    d = np.linspace(0, 20, 40)
    prof = dipole_profile(d, 1.37, 0.0012, 1.3) * np.exp(0.01 * np.sin(d))
    cost = profile_cost(d, np.log(prof), TABLE2_GRID, 1.3)
    for i, j in [(0, 0), (136, 11), (299, 29), (57, 3)]:  # independent evaluation of eq. 36
        s, a = TABLE2_GRID.sigma_s_prime[i], TABLE2_GRID.sigma_a[j]
        ref = sum((np.log(prof[k]) - np.log(dipole_profile(d[k], s, a, 1.3))) ** 2 for k in range(d.size))
        assert cost[i, j] == pytest.approx(ref, rel=1e-9)


def test_grid_fit_finds_grid_models_and_refinement_finds_the_rest():
    d = np.arange(0, 30, 0.25)
    fit = fit_profile_grid(d, dipole_profile(d, 2.19, 0.0021, 1.3), eta=1.3)
    assert (fit.sigma_s_prime, fit.sigma_a) == (2.19, 0.0021)
    off = fit_profile_grid(d, dipole_profile(d, 1.234, 0.00173, 1.3), eta=1.3, refine=True)
    assert off.sigma_s_prime == pytest.approx(1.234, rel=1e-5) and off.sigma_a == pytest.approx(0.00173, rel=1e-5)
    assert abs(off.grid_sigma_s_prime - 1.234) <= 0.01 + 1e-9 and abs(off.grid_sigma_a - 0.00173) <= 1e-4 + 1e-12
    skin = fit_profile_grid(
        d[:40], dipole_profile(d[:40], 0.94, 0.0875, 1.38), grid=ProfileGrid.log_spaced(), eta=1.38, refine=True
    )
    assert skin.sigma_s_prime == pytest.approx(0.94, rel=1e-4) and skin.sigma_a == pytest.approx(0.0875, rel=1e-4)


def test_a_refined_estimate_lies_inside_its_interval():
    """The cost's narrow diagonal valley put the refined optimum several grid steps from the best grid model, outside
    that model's interval (found by an audit: sigma_s' 2.192 against [2.008, 2.165] here; 8-9 of 25 media)."""
    from facestats.pipeline.image_translucency import GRIDS

    rs = render_scene(pyramid_scene(1.8, "edge"), 2.19, 0.01)
    fit = _fit(rs, width="auto", grid=GRIDS["skin"], refine=True)
    pf = fit.profile_fit
    assert abs(pf.grid_sigma_s_prime - fit.sigma_s_prime) > 0.1  # the best grid model is far along the valley
    (s0, s1), (a0, a1) = fit.sigma_s_prime_interval, fit.sigma_a_interval
    assert s0 <= fit.sigma_s_prime <= s1 and a0 <= fit.sigma_a <= a1
    assert s0 <= 2.19 <= s1 and a0 <= 0.01 <= a1  # noise-free: the truth too
    assert s0 <= pf.grid_sigma_s_prime <= s1  # and the grid's own optimum


def test_table3_row_025_is_reproduced_exactly(edge):
    (row,) = table3(edge, widths=(0.25,))
    assert row["paper"] == SUZUKI_TABLE3[0.25] == TRUTH
    assert row["monotone"] == TRUTH  # exactly the Table 2 grid model of the truth
    assert row["pinv"] is not None  # the paper's solve runs (its estimate is reported, not asserted)


def test_quantised_truth_is_recovered_exactly_and_so_is_the_point_kernel(edge):
    q = render_scene(pyramid_scene(1.8, "edge"), kernel="quantised", width=0.42089689356342)
    fit = _fit(q, width=0.42089689356342)
    assert (fit.sigma_s_prime, fit.sigma_a) == TRUTH
    # Model mismatch: the truth rendered with the point kernel R(d_jk), not the quantised model.
    mism = _fit(edge, width="auto")
    assert abs(mism.sigma_s_prime - TRUTH[0]) <= TOL_S and abs(mism.sigma_a - TRUTH[1]) <= TOL_A


@pytest.mark.parametrize("scene", ["edge", "oblique"])
@pytest.mark.slow
def test_one_percent_noise_over_20_seeds_with_auto_width(scene, request):
    st = noise_study(request.getfixturevalue(scene), noise=0.01, seeds=20, width="auto")
    s = st.summary()
    assert s["max_abs_error_sigma_s_prime"] <= TOL_S and s["max_abs_error_sigma_a"] <= TOL_A, s
    assert s["coverage"] >= 0.85, s  # the interval covers the truth in ≥ 85 % of noisy trials
    assert s["std_sigma_s_prime"] < 0.03


def test_plain_pseudo_inverse_fails_under_noise(edge):
    rng = np.random.default_rng(5)
    l = edge.exitance * (1 + 0.01 * rng.standard_normal(edge.exitance.size))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QuantisationWarning)
        fit = _fit(edge, l, width=0.25, method="pinv")
    assert np.any(fit.profile < 0)  # negative R': log undefined, levels left out
    assert fit.profile_fit.n_nonpositive > 0 and any("R' ≤ 0" in n for n in fit.notes)
    assert abs(fit.sigma_s_prime - TRUTH[0]) > TOL_S or abs(fit.sigma_a - TRUTH[1]) > TOL_A


def test_auto_width_avoids_the_papers_failing_widths(edge):
    fit = _fit(edge, width="auto")
    assert 0.25 <= fit.width <= 1.0 and fit.notes[0].startswith("width='auto' chose")
    rows = table3(edge, widths=(8.0, 2.0), methods=("pinv",))
    for row in rows:  # the paper's solve at coarse widths misses; auto does not
        assert row["pinv"] is None or abs(row["pinv"][0] - TRUTH[0]) > TOL_S
    assert abs(fit.sigma_s_prime - TRUTH[0]) <= TOL_S and abs(fit.sigma_a - TRUTH[1]) <= TOL_A


def test_widths_finer_than_the_spacing_merge_unsupported_levels_with_a_warning(edge):
    with pytest.warns(QuantisationWarning, match="supported by fewer than 30 patch pairs"):
        fit = _fit(edge, width=0.1)
    assert len(fit.merged_levels) > 0 and min(fit.merged_levels) < edge.patches.spacing
    assert np.all(np.diff(fit.levels) > 0) and fit.levels[0] == 0


def test_uniform_light_is_refused_by_eq_36_and_its_w_still_reported_rank_deficient():
    """The pyramid lit from above (four faces alike) has no light edge: eq. 36 from patch positions is refused
    before W is built, naming the remedy; W's own diagnostics (fit_scattering_system, no positions) still report its
    rank; the exitance fit, which needs no R' level by level, runs and says where its information came from."""
    from facestats.model.fitting.quantised import quantised_system
    from facestats.model.fitting.scattering_image import fit_scattering_system

    r = render_scene(pyramid_scene(1.8, "uniform"))
    for method in ("monotone", "pinv"):
        with pytest.raises(FitError, match=r"nearly uniform where the camera sees: 3136 of 3136 .*method='exitance'"):
            _fit(r, width=0.42, method=method)
    p, rows = r.patches, np.nonzero(r.visible)[0]
    system = quantised_system(p.centre, r.irradiance * p.area, rows, width=0.42)
    with pytest.warns(QuantisationWarning, match="numerical rank"):
        fit = fit_scattering_system(system, r.exitance[rows], width=0.42)
    assert fit.rank_deficient and any("numerical rank" in n for n in fit.notes)
    assert fit.summary()["rank"] == fit.rank <= fit.n_levels
    with pytest.warns(QuantisationWarning, match="the light is nearly uniform"):
        fit = _fit(r, width=0.42, method="exitance")
    assert fit.notes[-1].startswith("the light is nearly uniform") and "rim" in fit.notes[-1]


def test_a_too_narrow_spot_leaves_levels_unsupported(edge):
    p = edge.patches
    lit = np.linalg.norm(p.centre - p.centre[np.argmax(edge.irradiance)], axis=1) < 1.0
    c = np.where(lit, edge.irradiance, 0)
    with pytest.warns(QuantisationWarning, match="supported by fewer"):
        fit_scattering_image(p.centre, p.area, c, edge.exitance, width=0.2, visible=edge.visible)


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(radiance="nan"), "radiance must be finite"),
        (dict(radiance="negative"), "radiance must lie in"),
        (dict(irradiance="negative"), "irradiance must lie in"),
        (dict(irradiance="nan"), "irradiance must be finite"),
        (dict(areas="zero"), "areas must be > 0"),
        (dict(areas="negative"), "areas must be > 0"),
        (dict(areas="nan"), "areas must be finite"),
        (dict(points="short"), "areas must have one value per point"),
        (dict(visible="none"), "no visible rows.*the camera sees none of the mesh"),
        (dict(width=0.0), "width must lie in"),
        (dict(width=-1.0), "width must lie in"),
        (dict(width="fine"), "width must be one of"),
        (dict(method="svd"), "method must be one of"),
        (dict(max_distance=1e4), "max_distance must not exceed the largest patch distance"),
    ],
)
def test_bad_input_names_the_argument(edge, change, match):
    p = edge.patches
    args = dict(points=p.centre, areas=p.area, irradiance=edge.irradiance, radiance=edge.exitance)
    kw = dict(width=1.0, visible=edge.visible)
    for k, v in change.items():
        if v == "nan":
            args[k] = np.where(np.arange(len(p)) == 3, np.nan, args[k])
        elif v == "negative":
            args[k] = np.where(np.arange(len(p)) == 3, -1.0, args[k])
        elif v == "zero":
            args[k] = np.where(np.arange(len(p)) == 3, 0.0, args[k])
        elif v == "short":
            args[k] = args[k][:-1]
        elif v == "none":
            kw["visible"] = np.zeros(len(p), bool)
        else:
            kw[k] = v
    with pytest.raises(FacestatsError, match=match):
        fit_scattering_image(args["points"], args["areas"], args["irradiance"], args["radiance"], **kw)


def test_too_few_levels_is_a_fit_error(edge):
    p = edge.patches
    with pytest.raises((FitError, ValidationError)):
        fit_scattering_image(p.centre, p.area, edge.irradiance, edge.exitance, width=60.0, visible=edge.visible)


def test_the_point_kernel_exitance_is_the_dense_sum():
    from facestats.model.fitting.quantised import point_kernel_exitance

    rng = np.random.default_rng(3)
    p = rng.uniform(-10, 10, (400, 3))
    w = np.where(rng.random(400) < 0.5, rng.uniform(0, 2, 400), 0.0)
    rows = rng.choice(400, 50, replace=False)
    d = np.linalg.norm(p[rows, None] - p[None], axis=-1)
    want = (dipole_profile(d, *TRUTH, 1.3) * w).sum(1)  # a patch and itself at d = 0
    got = point_kernel_exitance(p, w, rows, lambda r: dipole_profile(r, *TRUTH, 1.3), block_bytes=2**20)
    np.testing.assert_allclose(got, want, rtol=1e-12)


@pytest.fixture(scope="module")
def plate():
    """A flat plate of 0.5 mm patches lit over the strip x < −5 mm, point-kernel truth of Table 1's medium."""
    h = 0.5
    x = np.arange(-15, 15, h) + h / 2
    u, v = np.meshgrid(x, x)
    p = np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], 1)
    a = np.full(len(p), h * h)
    c = np.where(p[:, 0] < -5, 1.0, 0.0)
    l = (dipole_profile(np.linalg.norm(p[:, None] - p[None], axis=-1), *TRUTH, 1.3) * (c * a)).sum(1)
    return p, a, c, l


def test_a_width_too_coarse_for_the_medium_is_warned_about(plate):
    """At 1 mm (2.2 mean free paths) the plate's estimate is 11 % low with an interval excluding the truth: the
    quantisation check says so; at 0.25 mm the levels represent the fitted dipole within 1 % and nothing is said."""
    with pytest.warns(QuantisationWarning, match=r"at width 1 mm the levels misrepresent the fitted dipole by 1[0-4]"):
        coarse = fit_scattering_image(*plate, width=1.0)
    assert coarse.sigma_s_prime < 0.9 * TRUTH[0] and not coarse.sigma_s_prime_interval[1] >= TRUTH[0]
    assert 0.10 < coarse.quantisation_error < 0.15 and "misrepresent" in coarse.notes[-1]
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*misrepresent.*")
        fine = fit_scattering_image(*plate, width=0.25)
    assert fine.quantisation_error < 0.01 and abs(fine.sigma_s_prime - TRUTH[0]) <= TOL_S
    assert fine.summary()["quantisation_error"] == fine.quantisation_error


def test_the_footprint_self_term_fits_a_continuous_surface_closer_and_its_own_renders_exactly(edge, quadrature_plate):
    """Eq. 17's R(0) c A overstates a patch's own light about twice for 1 mm patches: an image of a continuous
    surface is fitted closer with self_term="footprint" (still biased by the neighbours' point kernel), and the
    footprint's own renders are recovered exactly at 0.25 mm."""
    centre, area, c, surface = quadrature_plate
    fits = {st: fit_scattering_image(centre, area, c, surface, width=0.25, self_term=st) for st in SELF_TERMS}
    err = {st: (abs(f.sigma_s_prime / TRUTH[0] - 1), abs(f.sigma_a / TRUTH[1] - 1)) for st, f in fits.items()}
    # measured: point 1.92 / 0.0030 (-12 % / +43 %), footprint 2.01 / 0.0027 (-8 % / +29 %)
    assert err["footprint"][0] < err["point"][0] - 0.02 and err["footprint"][1] < err["point"][1] - 0.05
    assert fits["footprint"].self_term == "footprint" and fits["footprint"].summary()["self_term"] == "footprint"
    own = render_scene(pyramid_scene(1.8, "edge"), self_term="footprint")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QuantisationWarning)
        fit = _fit(own, width=0.25, self_term="footprint")
    assert (fit.sigma_s_prime, fit.sigma_a) == TRUTH
    with pytest.raises(ValidationError, match="self_term must be one of"):
        _fit(edge, width=0.25, self_term="disk")


def test_a_medium_outside_table_2_is_told_to_use_a_wider_grid():
    """The default grid (Table 2, sigma_a <= 0.003) pins sigma_a = 0.03 at its edge; the note names the grid's range
    and the way out (an audit found only "the grid bounds it")."""
    rs = render_scene(pyramid_scene(1.8, "edge"), 2.19, 0.03)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QuantisationWarning)
        fit = _fit(rs, width=0.25)
        wide = _fit(rs, width=0.25, grid=ProfileGrid.log_spaced(), refine=True)
    assert fit.sigma_a == 0.003 and fit.profile_fit.at_grid_edge
    assert any("sigma_a 0.0001-0.003 1/mm): the grid bounds it" in n and "--grid skin" in n for n in fit.notes)
    assert wide.sigma_a == pytest.approx(0.03, rel=0.02) and not wide.profile_fit.at_grid_edge


@pytest.fixture(scope="module")
def quadrature_plate():
    """The flat plate of 1 mm patches lit over a half plane, its exitance by a quadrature of the surface."""
    from facestats.acquire.synthetic.subsurface import half_lit_plate

    return half_lit_plate(*TRUTH)


def test_the_exitance_fit_with_the_surface_self_term_is_unbiased_on_a_continuous_surface(quadrature_plate):
    """Eq. 36 fits the plate's quadrature about 10 % low in sigma_s' with every self term (the levels below the
    patch spacing cannot be identified and are merged); the dipole fitted through W with the near patches over their
    disks recovers Table 1's medium, with width='auto' narrowed until the quantisation error is at most 0.25 %."""
    from facestats.model.fitting.scattering_image import EXITANCE_QUANTISATION

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QuantisationWarning)
        eq36 = fit_scattering_image(*quadrature_plate, width="auto", self_term="footprint")
        fit = fit_scattering_image(*quadrature_plate, width="auto", self_term="surface", method="exitance")
    assert eq36.sigma_s_prime < 0.93 * TRUTH[0]  # measured 1.98 (point term: 1.90)
    # measured 2.19 / 0.0021 (the grid model; refined 2.177 / 0.00212) at 0.106 mm
    assert abs(fit.sigma_s_prime / TRUTH[0] - 1) <= 0.01 and abs(fit.sigma_a / TRUTH[1] - 1) <= 0.05
    assert fit.sigma_s_prime_interval[0] <= TRUTH[0] <= fit.sigma_s_prime_interval[1]
    assert (fit.method, fit.self_term) == ("exitance", "surface")
    assert fit.quantisation_error <= EXITANCE_QUANTISATION and fit.width < 0.2
    assert "then narrowed it to" in fit.notes[1] and any("method='exitance'" in n for n in fit.notes)


def test_the_exitance_cost_is_the_sum_of_squared_relative_residuals(edge):
    """exitance_cost from the normal equations against the rows themselves, for a handful of grid models."""
    from facestats.model.fitting.profile_grid import exitance_cost
    from facestats.model.fitting.quantised import normal_equations, quantised_system

    p = edge.patches
    rows = np.nonzero(edge.visible)[0]
    system = quantised_system(p.centre, edge.irradiance * p.area, rows, width=0.5)
    l = edge.exitance[rows]
    neq = normal_equations(system, l, weighted=True)
    grid = ProfileGrid(np.array([1.0, 2.19, 2.9]), np.array([0.001, 0.0021]))
    cost = exitance_cost(system.levels, neq.gram, neq.rhs, neq.n_rows, grid, 1.3)
    use = l > 0
    for i, s in enumerate(grid.sigma_s_prime):
        for j, a in enumerate(grid.sigma_a):
            resid = system.matrix[use] @ dipole_profile(system.levels, s, a, 1.3) / l[use] - 1
            assert cost[i, j] == pytest.approx(resid @ resid, rel=1e-8, abs=1e-10)
    assert np.unravel_index(np.argmin(cost), cost.shape) == (1, 1)


def test_the_exitance_fit_round_trips_and_refuses_a_fit_range(edge):
    """A render and a fit with the same self term recover the medium exactly at 0.25 mm; refinement never raises
    the cost; a numeric max_distance (eq. 36's level range) is refused, naming it."""
    own = render_scene(pyramid_scene(1.8, "edge"), self_term="surface")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QuantisationWarning)
        fit = _fit(own, width=0.25, self_term="surface", method="exitance")
        refined = _fit(own, width=0.25, self_term="surface", method="exitance", refine=True)
        point = _fit(edge, width="auto", method="exitance")  # point render, point W: narrowed 0.42 -> 0.197 mm
    assert (fit.sigma_s_prime, fit.sigma_a) == TRUTH and (point.sigma_s_prime, point.sigma_a) == TRUTH
    assert refined.profile_fit.cost <= fit.profile_fit.cost
    assert abs(refined.sigma_s_prime / TRUTH[0] - 1) < 0.01  # measured 2.173 (eq. 28's interpolation at 0.25 mm)
    with pytest.raises(ValidationError, match="max_distance selects the levels of eq. 36"):
        _fit(edge, width=0.5, method="exitance", max_distance=10.0)


def test_the_exitance_fit_stands_where_r_prime_cannot_be_solved_and_warns_only_about_the_width_kept():
    """A red team's cases: on a 4 x 4 plate no R' can be solved (2 supported levels), yet the exitance fit needs none;
    under width='auto' the warnings are those of the narrowed fit, not of the candidate it replaced, and the
    candidates' note is kept."""
    from facestats.acquire.synthetic.subsurface import half_lit_plate
    from facestats.model.fitting.quantised import quantised_system
    from facestats.model.fitting.scattering_image import EXITANCE_QUANTISATION, fit_scattering_system

    centres, areas, c, l = half_lit_plate(*TRUTH, n=4, sub=8)
    system = quantised_system(centres, c * areas, width=0.1, areas=areas, near=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit = fit_scattering_system(system, l, method="exitance")
        with pytest.raises(FitError, match="only 2 supported levels remain"):
            fit_scattering_system(system, l, method="monotone")
    assert any("R' was not solved" in str(w.message) for w in caught)
    assert np.isfinite(fit.sigma_s_prime) and np.isnan(fit.profile).all()
    assert any("R' was not solved" in n for n in fit.notes) and not fit.rank_deficient
    with pytest.raises(ValidationError, match="max_distance selects the levels of eq. 36"):
        fit_scattering_system(system, l, method="exitance", max_distance=np.array([3.0, 4.0]))
    centres, areas, c, l = half_lit_plate(5.0, 0.02, n=21, sub=4)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit = fit_scattering_image(
            centres, areas, c, l, width="auto", self_term="surface", method="exitance", grid=ProfileGrid.log_spaced()
        )
    said = [str(w.message) for w in caught]
    assert fit.width < 0.1 and fit.quantisation_error <= EXITANCE_QUANTISATION  # measured 0.046 mm, 0.21 %
    assert not any("misrepresent" in m for m in said)  # the 0.5 mm candidate's 12 % is not warned about
    assert not any(m.startswith("method='exitance'") for m in said)  # an explanation, not a warning
    assert fit.notes[0].startswith("width='auto' chose 0.5 mm (candidates") and "narrowed it to" in fit.notes[1]
    assert abs(fit.sigma_s_prime / 5.0 - 1) < 0.08 and abs(fit.sigma_a / 0.02 - 1) < 0.15  # measured 4.70, 0.0219


def test_fit_scattering_system_names_its_exitance_argument():
    """A bad ``exitance`` given straight to fit_scattering_system is reported under that name, not ``radiance``."""
    from facestats.acquire.synthetic.subsurface import half_lit_plate
    from facestats.model.fitting.quantised import quantised_system
    from facestats.model.fitting.scattering_image import fit_scattering_system

    centres, areas, c, l = half_lit_plate(*TRUTH, n=4, sub=8)
    system = quantised_system(centres, c * areas, width=0.1, areas=areas, near=True)
    with pytest.raises(ValidationError, match="exitance must lie in"):
        fit_scattering_system(system, -l, method="exitance")
    with pytest.raises(ValidationError, match="exitance must have shape"):
        fit_scattering_system(system, l[:-1], method="exitance")


def test_each_channel_warns_about_the_width_it_keeps_and_warnings_point_at_the_caller():
    """Two channels under width='auto', method='exitance': one keeps its candidate, one is narrowed; the warnings
    are those of the widths kept (a second red team saw the narrowed channel's discarded 12 % candidate replayed),
    attributed to the caller's line, as the default path's are."""
    from facestats.acquire.synthetic.subsurface import half_lit_plate
    from facestats.model.fitting import fit_scattering_channels

    centres, areas, c, low = half_lit_plate(0.3, 0.003, n=21, sub=4)
    high = half_lit_plate(5.0, 0.02, n=21, sub=4)[3]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fits = fit_scattering_channels(
            centres, areas, c, np.c_[low, high], width="auto", self_term="surface", method="exitance",
            grid=ProfileGrid.log_spaced(),
        )  # fmt: skip
    assert fits[0].width == 0.5 and fits[1].width < 0.1  # measured 0.5 and 0.046 mm
    said = [str(w.message) for w in caught]
    assert not any("misrepresent" in m for m in said)
    assert sum("at 0.5 mm" in m for m in said) == 1  # channel 0's one merge note, once
    assert {w.filename for w in caught} == {__file__}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit_scattering_image(centres, areas, c, low, width="auto")
    assert caught and {w.filename for w in caught} == {__file__}


def test_a_capped_w_narrows_as_far_as_the_cap_allows(monkeypatch):
    """With W capped at 1 MiB the narrowing stops at the finest width the cap allows, and says so."""
    from facestats.acquire.synthetic.subsurface import half_lit_plate
    from facestats.model.fitting import scattering_image

    monkeypatch.setattr(scattering_image, "EXITANCE_W_BYTES", 2**20)
    centres, areas, c, l = half_lit_plate(5.0, 0.02, n=21, sub=4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QuantisationWarning)
        fit = fit_scattering_image(
            centres, areas, c, l, width="auto", self_term="surface", method="exitance", grid=ProfileGrid.log_spaced()
        )
    # measured: 0.098 mm (441 rows x at most 297 levels), quantisation error 0.92 % against 12.3 % at 0.5 mm
    assert 0.05 < fit.width < 0.2 and fit.quantisation_error < 0.02
    assert any("a finer W would exceed" in n for n in fit.notes)


def test_a_window_of_the_real_ict_face_mesh_is_fitted_through_w_with_the_surface_term():
    """Real, curved, irregular patches: a 12 mm window of the shipped ICT-FaceKit face (2,342 patches of 0.16-0.28
    mm^2, spacing 1 mm), half lit, rendered with the surface term; exitance + surface recovers the medium, eq. 36 with
    the point or footprint term does not (2.178 / 0.00214 against 2.096 / 0.00246 and 2.400 / 0.00146)."""
    from facestats.acquire.patches import mesh_patches
    from facestats.acquire.synthetic.subsurface import render_exitance
    from facestats.face.ict import ict_face_mesh

    v, f = ict_face_mesh()[:2]
    centroid = v[f].mean(1)
    target = v.mean(0) + np.array([30.0, -10.0, 20.0])  # the subject's left cheek
    middle = centroid[np.argmin(np.linalg.norm(centroid - target, axis=1))]
    window = f[np.linalg.norm(centroid - middle, axis=1) < 12]
    used = np.unique(window)
    index = np.full(len(v), -1)
    index[used] = np.arange(used.size)
    patches = mesh_patches(v[used], index[window], spacing=1.0, occluder=False)
    c = (patches.centre[:, 0] < middle[0]).astype(float)
    l = render_exitance(patches.centre, patches.area, c, *TRUTH, eta=1.3, radius=np.inf, self_term="surface")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", QuantisationWarning)
        fits = {
            st: fit_scattering_image(
                patches.centre, patches.area, c, l, width="auto", self_term=st, method=m, refine=True
            )
            for st, m in (("point", "monotone"), ("footprint", "monotone"), ("surface", "exitance"))
        }
    assert len(patches) == 2342
    err = {st: (fit.sigma_s_prime / TRUTH[0] - 1, fit.sigma_a / TRUTH[1] - 1) for st, fit in fits.items()}
    assert abs(err["surface"][0]) < 0.015 and abs(err["surface"][1]) < 0.05  # measured -0.5 %, +1.9 %
    assert abs(err["point"][0]) > 0.03 and abs(err["point"][1]) > 0.1  # measured -4.3 %, +17 %
    assert abs(err["footprint"][0]) > 0.05 and abs(err["footprint"][1]) > 0.2  # measured +9.6 %, -30 %


def test_sigma_tr_of_the_exact_fit_and_the_pinv_conditioning_of_unweighted_rows(edge):
    """σtr = √(3 σa (σa + σ's)) (Suzuki eq. 10-11): √(3 · 0.0021 · 2.2021) = 0.117785 mm⁻¹ for the (2.2, 0.0021)
    that W at 1 mm gives (Table 1's truth is 2.19, 0.0021; the point kernel at 1 mm errs by a grid step).  The
    paper's solve (pinv) weighs no row, so its rank and condition are those of W itself (columns scaled), not of
    diag(1/l) W as the monotone solve's are (811 against 2203 at 0.25 mm here)."""
    from facestats.model.fitting import fit_scattering_system
    from facestats.model.fitting.quantised import conditioning, merge_levels, normal_equations, quantised_system
    from facestats.model.fitting.scattering_image import DEFAULT_RCOND

    p = edge.patches
    rows = np.nonzero(edge.visible)[0]
    system = quantised_system(p.centre, edge.irradiance * p.area, rows, width=1.0)
    l = edge.exitance[rows]
    mono = fit_scattering_system(system, l)
    assert (mono.sigma_s_prime, mono.sigma_a) == (2.2, 0.0021) and mono.sigma_tr == pytest.approx(0.117785, rel=1e-5)
    pinv = fit_scattering_system(system, l, method="pinv")
    for fit, weighted in ((pinv, False), (mono, True)):
        merged = merge_levels(system, np.isin(system.levels, fit.levels))  # the unsupported far levels
        cond = conditioning(normal_equations(merged, l, weighted=weighted), DEFAULT_RCOND)
        assert fit.condition == pytest.approx(cond.condition, rel=1e-9) and fit.rank == cond.rank
    assert pinv.condition < 0.8 * mono.condition
    # One visible row without light is left out of the weighted solve, and said so
    dark = l.copy()
    dark[7] = 0.0
    notes = fit_scattering_system(system, dark).notes
    assert "1 visible row(s) with zero radiance left out of the weighted solve" in notes
    # At 1 mm the levels misrepresent the fitted dipole by 7.2 % (> QUANTISATION_WARNING = 5 %): noted and warned
    with pytest.warns(QuantisationWarning, match=r"misrepresent the fitted dipole by 7\.2"):
        assert _fit(edge, width=1.0).quantisation_error == pytest.approx(0.072, abs=0.001)
    # The fit range may reach the farthest pair (69.03 mm here), not beyond
    fit_scattering_system(system, l, max_distance=0.99 * system.max_distance)
    with pytest.raises(ValidationError, match="max_distance must not exceed the largest patch distance 69.03"):
        fit_scattering_system(system, l, max_distance=1.05 * system.max_distance)


def test_an_ill_conditioned_w_is_noted():
    """Condition numbers above CONDITION_WARNING = 1e4 carry a note (and a warning); a W of condition ~1e5 (two
    nearly parallel columns, still of full rank at rcond 1e-6) does, one of ~1e2 does not."""
    from facestats.model.fitting import fit_scattering_system
    from facestats.model.fitting.quantised import QuantisedSystem

    rng = np.random.default_rng(2)
    levels = np.arange(8.0)
    base = np.exp(-(np.subtract.outer(rng.uniform(0, 8, 400), levels) ** 2)) + 0.05 * rng.uniform(size=(400, 8))
    notes = {}
    for eps in (1e-1, 3e-5):
        w = base.copy()
        w[:, 4] = w[:, 3] + eps * rng.uniform(size=400)
        system = QuantisedSystem(w, levels, np.arange(400), np.full(8, 1e3), 7.5, 4000)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", QuantisationWarning)
            fit = fit_scattering_system(system, w @ dipole_profile(levels, *TRUTH, 1.3))
        notes[eps] = (fit.condition, any("ill-conditioned" in n for n in fit.notes))
    assert notes[1e-1][0] < 1e3 and not notes[1e-1][1], notes
    assert 1e4 < notes[3e-5][0] < 1e6 and notes[3e-5][1], notes


def test_auto_width_notes_the_finer_widths_whose_fit_failed(oblique, monkeypatch):
    """A FitError at a finer candidate width moved width='auto' on silently; the width kept now names it."""
    from facestats.model.fitting import scattering_image

    real = scattering_image.fit_scattering_system
    first = []

    def failing_first(system, exitance, **kw):
        first.append(kw["width"])
        if kw["width"] == first[0]:
            raise FitError("only 2 supported levels remain")
        return real(system, exitance, **kw)

    monkeypatch.setattr(scattering_image, "fit_scattering_system", failing_first)
    fit = _fit(oblique, width="auto")
    assert fit.width > first[0] and not fit.rank_deficient
    assert fit.notes[1].startswith(
        f"width='auto' skipped finer widths: {first[0]:.4g} mm (failed: only 2 supported levels remain)"
    )


def test_the_grid_edge_note_advises_a_wider_grid_only_when_one_is_wider():
    """σa = 0.0005 mm⁻¹ lies below both the skin grid (from 0.001) and a narrow grid: the narrow grid's note advises
    the skin grid; the skin grid's note (it was used) does not advise it again."""
    r = render_scene(pyramid_scene(2.5, "edge"), 2.19, 0.0005)
    narrow = ProfileGrid.log_spaced((0.5, 5.0), (0.001, 0.01), (40, 20))
    skin = ProfileGrid.log_spaced(n=(80, 80))
    notes = {}
    for name, grid in (("narrow", narrow), ("skin", skin)):
        with pytest.warns(QuantisationWarning):
            fit = _fit(r, width="auto", grid=grid)
        notes[name] = next(n for n in fit.notes if n.startswith("the interval reaches the edge of the grid"))
        assert "at sigma_a 0.001 (lowest)" in notes[name], notes[name]
    assert "--grid skin on the command line" in notes["narrow"] and "medium may lie outside" in notes["narrow"]
    assert "--grid skin" not in notes["skin"] and "already spans the skin grid's" in notes["skin"]
    assert "which the command line does not offer" in notes["skin"]
