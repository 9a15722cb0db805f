"""The synthetic population against the published statistics (Weyrich et al. 2006, Tables 1-2, §5.4, §7)."""

import numpy as np
import pytest

from facestats import FacestatsError
from facestats.acquire.synthetic.population import default_population, synthesize_population
from facestats.core import published
from facestats.core.conventions import SITES, age_group
from facestats.model.skin_colour import skin_albedo


@pytest.fixture(scope="module")
def pop():
    return default_population(map_size=32)


def _normal(p):
    return [s for s in p.subjects if s.condition == "normal"]


def _series(p):
    """The records of the person measured under the conditions of §7, by condition."""
    person = next(s.person_id for s in p.subjects if s.condition == "lotion")
    return {s.condition: s for s in p.subjects if s.person_id == person}


def test_counts_match_table2_and_section7(pop):
    subs = _normal(pop)
    assert len(subs) == published.N_SUBJECTS
    for st, (m, f) in published.TABLE2_COUNTS.items():
        types = (1, 2) if st == 2 else (st,)
        assert sum(s.skin_type in types and s.gender == "M" for s in subs) == m
        assert sum(s.skin_type in types and s.gender == "F" for s in subs) == f
    assert sum(s.skin_type == 1 for s in subs) == 2  # "only two individuals of skin type I"
    for grp, (m, f) in published.AGE_COUNTS.items():
        assert sum(age_group(s.age) == grp and s.gender == "M" for s in subs) == m
        assert sum(age_group(s.age) == grp and s.gender == "F" for s in subs) == f
    # §7 "we also measured one male subject under several external conditions": one of the 149 (a type III man),
    # his normal record among them, six more records of the same person (a 150th person made 50 type III men).
    series = _series(pop)
    assert sorted(series) == sorted(published_conditions())
    assert series["normal"] in subs and series["normal"].skin_type == 3 and series["normal"].gender == "M"
    assert len(pop.subjects) == published.N_SUBJECTS + 6
    assert {s.subject_id for s in series.values()} == {"S008"} | {f"S008-{c}" for c in published_conditions()[1:]}
    for cond, s in series.items():  # the same person: his face, texture and translucency in every condition
        assert (s.age, s.gender, s.skin_type) == (34, "M", 3)
        np.testing.assert_array_equal(s.site_sigma_tr, series["normal"].site_sigma_tr)


def published_conditions():
    from facestats.core.conventions import CONDITIONS

    return CONDITIONS


def test_same_seed_bit_identical_and_seed_matters():
    a = synthesize_population(seed=7, map_size=16)
    b = synthesize_population(seed=7, map_size=16)
    c = synthesize_population(seed=8, map_size=16)
    for sa, sb in zip(a.subjects, b.subjects):
        for f in ("albedo", "ts_rho_s", "ts_m", "bp_exponent", "site_sigma_tr"):
            assert np.array_equal(getattr(sa, f), getattr(sb, f))
        assert (sa.age, sa.gender, sa.skin_type) == (sb.age, sb.gender, sb.skin_type)
    assert not np.array_equal(a.subjects[0].albedo, c.subjects[0].albedo)


def test_sigma_tr_matches_table1(pop):
    subs = _normal(pop)
    tr = np.stack([s.site_sigma_tr for s in subs])  # (n, site, channel)
    n = len(subs)
    for k, site in enumerate(SITES):
        mean, spread = published.TABLE1_MEAN[site], published.TABLE1_VAR[site]
        # "Var." read as a standard deviation (see facestats.acquire.synthetic.population).
        assert np.all(np.abs(tr[:, k].mean(0) - mean) < 4 * spread / np.sqrt(n))
        np.testing.assert_allclose(tr[:, k].std(0, ddof=1), spread, rtol=0.3)
    np.testing.assert_allclose(pop.sigma_tr_avg, published.SIGMA_TR_AVG, atol=0.06)
    # Fig. 11: the extreme subjects' ℓd (cheek and forehead averaged), red channel.
    ell = 1 / tr[:, :2, 0].mean(1)
    assert 0.8 < ell.min() < 1.4 and 2.2 < ell.max() < 4.0


def test_variance_reading_option_changes_spread():
    p = synthesize_population(seed=3, map_size=16, table1_spread="variance", conditions=False)
    red_cheek = np.array([s.site_sigma_tr[0, 0] for s in p.subjects])
    assert red_cheek.std(ddof=1) == pytest.approx(np.sqrt(published.TABLE1_VAR["cheek"][0]), rel=0.35)


def test_region_orderings_of_section7(pop):
    subs = _normal(pop)
    rho = {r: np.concatenate([s.ts_rho_s[s.region_map == r] for s in subs]) for r in range(1, 11)}
    m = {r: np.concatenate([s.ts_m[s.region_map == r] for s in subs]) for r in range(1, 11)}
    mean_m = {r: v.mean() for r, v in m.items()}
    assert min(mean_m, key=mean_m.get) == published.SMALLEST_M
    mean_rho = {r: v.mean() for r, v in rho.items()}
    assert set(sorted(mean_rho, key=mean_rho.get)[-5:]) == set(published.HIGHEST_RHO_S)
    total_var = {r: np.var(rho[r]) + np.var(m[r]) for r in rho}
    assert set(sorted(total_var, key=total_var.get)[-5:]) == set(published.LARGEST_VARIANCE)


def test_facial_hair_regions_noisier_for_men(pop):
    subs = _normal(pop)
    for r in (1, 3, 9, 10):
        cv = {
            g: np.mean(
                [s.ts_m[s.region_map == r].std() / s.ts_m[s.region_map == r].mean() for s in subs if s.gender == g]
            )
            for g in "MF"
        }
        assert cv["M"] > 1.3 * cv["F"]


def test_cca_of_region_means_reproduces_fig16(pop):
    from facestats.analysis.cca import cca

    subs = _normal(pop)
    x = np.array(
        [
            [v for r in range(1, 11) for v in (s.ts_rho_s[s.region_map == r].mean(), s.ts_m[s.region_map == r].mean())]
            for s in subs
        ]
    )
    y = np.array([[max(s.skin_type, 2), s.gender == "F", s.age] for s in subs], float)
    principal = cca(x, y).correlations[:2]
    direct = [cca(x, y[:, [j]]).correlations[0] for j in range(3)]
    # One draw of 149 subjects: the spread over seeds is about 0.02-0.03.
    np.testing.assert_allclose(principal, published.CCA_PRINCIPAL, atol=0.08)
    np.testing.assert_allclose(direct, [published.CCA_DIRECT[k] for k in ("skin_type", "gender", "age")], atol=0.09)
    assert direct[0] == max(direct)  # skin type is the strongest predictor


def test_fig14_darker_types_absorb_more_and_scatter_less(pop):
    subs = _normal(pop)
    sp = {s.subject_id: s.scattering for s in subs}
    light = [sp[s.subject_id] for s in subs if s.skin_type <= 3]
    dark = [sp[s.subject_id] for s in subs if s.skin_type >= 5]
    for c in range(3):
        assert np.mean([d[1][c] for d in dark]) > np.mean([l[1][c] for l in light])  # σa
        assert np.mean([d[0][c] for d in dark]) < np.mean([l[0][c] for l in light])  # σ's


def test_skin_colour_anchored_in_colorchecker_patches():
    import warnings

    import colour

    # Independent path: colour-science's own spectral integration of the measured patches
    # (it warns that it aligns and trims the spectra to the observer's range, as intended).
    for t, name in ((0.0, "light skin"), (1.0, "dark skin")):
        sd = colour.characterisation.SDS_COLOURCHECKERS["BabelColor Average"][name]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", colour.utilities.ColourRuntimeWarning)
            xyz = colour.sd_to_XYZ(sd, illuminant=colour.SDS_ILLUMINANTS["D65"]) / 100
        ref = colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_encoding=False)
        np.testing.assert_allclose(skin_albedo(t), ref, atol=3e-3)
    rgb = skin_albedo(np.array([-0.25, 0.15, 0.45, 0.85, 1.25]))
    assert np.all(np.diff(rgb, axis=0) < 0)  # darker with melanin in every channel
    assert np.all((rgb > 0) & (rgb < 1))


def test_shipped_colour_tables_are_colour_sciences_and_give_its_xyz_to_rgb_bit_for_bit():
    """facestats/model/skin_colour_tables.py holds what colour-science computes now, and skin_albedo gives, bit for bit,
    what the same spectral integration followed by colour-science's own ``XYZ_to_RGB`` gives (the implementation
    before the tables were shipped)."""
    import colour

    from facestats.model.skin_colour import colour_science_tables
    from facestats.model.skin_colour_tables import TABLES

    live = colour_science_tables()
    shipped = TABLES
    assert shipped.keys() == live.keys()
    for key in live:
        if key != "colour_science":
            assert np.array_equal(np.asarray(shipped[key]), np.asarray(live[key])), key
    t = np.linspace(-0.3, 1.3, 41)
    rl = np.maximum(np.asarray(live["light_skin"]), 1e-4)
    rd = np.maximum(np.asarray(live["dark_skin"]), 1e-4)
    spectra = np.exp((1 - t[:, None]) * np.log(rl) + t[:, None] * np.log(rd))
    w = np.asarray(live["cmfs"]) * np.asarray(live["d65"])[:, None]
    xyz = spectra @ w / w[:, 1].sum()
    ref = colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_encoding=False)
    assert np.array_equal(skin_albedo(t), np.clip(ref, 0.005, 0.95))
    assert np.array_equal(skin_albedo(0.4), skin_albedo(np.array([0.4]))[0])
    grid = t[:40].reshape(2, 4, 5)  # any shape, as documented (a 2-D index failed to broadcast before)
    assert np.array_equal(skin_albedo(grid), skin_albedo(t[:40]).reshape(2, 4, 5, 3))


def test_conditions_effects(pop):
    cond = _series(pop)
    face = cond["normal"].region_map > 0
    mean = {k: (v.ts_rho_s[face].mean(), v.ts_m[face].mean()) for k, v in cond.items()}
    for shiny in ("lotion", "hot"):
        assert mean[shiny][0] > mean["normal"][0] and mean[shiny][1] < mean["normal"][1]
    for matte in ("powder", "cold"):
        assert mean[matte][0] < mean["normal"][0] and mean[matte][1] > mean["normal"][1]


def test_subject_subset_is_the_same_draw_and_unknown_ids_are_rejected():
    full = synthesize_population(seed=5, map_size=16)
    part = synthesize_population(seed=5, map_size=16, subjects=["S002", "S030-lotion"])  # seed 5: S030's series
    assert [s.subject_id for s in part.subjects] == ["S002", "S030-lotion"]
    for s in part.subjects:
        np.testing.assert_array_equal(s.albedo, full[s.subject_id].albedo)
        np.testing.assert_array_equal(s.ts_m, full[s.subject_id].ts_m)
    np.testing.assert_array_equal(part.sigma_tr_avg, full.sigma_tr_avg)
    with pytest.raises(FacestatsError, match=r"subjects must be ids of the population .*got unknown \['S150'\]"):
        synthesize_population(seed=5, map_size=16, subjects=["S001", "S150"])
    with pytest.raises(FacestatsError, match="got unknown"):
        synthesize_population(seed=5, map_size=16, conditions=False, subjects=["S030-lotion"])
    # The 149 subjects' draws do not depend on whether the series is drawn (they did: one more σtr row).
    alone = synthesize_population(seed=5, map_size=16, conditions=False, subjects=["S002"])["S002"]
    np.testing.assert_array_equal(alone.site_sigma_tr, full["S002"].site_sigma_tr)
    np.testing.assert_array_equal(alone.ts_m, full["S002"].ts_m)
    with pytest.raises(FacestatsError, match="subjects must be a collection of subject ids, got the string"):
        synthesize_population(seed=5, map_size=16, subjects="S001")
    with pytest.raises(FacestatsError, match=r"freckle_fraction must lie in \[0, 0.57\]"):
        synthesize_population(seed=5, map_size=16, freckle_fraction=0.8)


@pytest.mark.parametrize(
    "shape, sigma", [((300, 200), 10.0), ((512, 512), 51.2), ((64, 40), 30.0), ((97, 101), 8.2), ((48, 48), 4.8)]
)
def test_wrap_gaussian_is_scipys_wrap_filter(shape, sigma):
    """The FFT path of the population's smooth noise (kernels wider than DIRECT_TAPS) equals scipy's direct wrap-mode
    filter to rounding, also where the kernel is longer than the map (64 x 40 at sigma 30); narrower kernels are
    scipy's own call, bit for bit (the default store's 48^2 albedo, sigma 4.8).  The direct filter took 50 s at
    4096^2 (sigma 409.6; the speed red team), the FFT about 1-2 s."""
    from scipy.ndimage import gaussian_filter

    from facestats.acquire.synthetic.texture import DIRECT_TAPS, wrap_gaussian

    x = np.random.default_rng(3).standard_normal(shape)
    ref = gaussian_filter(x, sigma, mode="wrap")
    got = wrap_gaussian(x, sigma)
    if 2 * int(4 * sigma + 0.5) + 1 <= DIRECT_TAPS:
        np.testing.assert_array_equal(got, ref)
    else:
        assert np.abs(got - ref).max() < 1e-15
