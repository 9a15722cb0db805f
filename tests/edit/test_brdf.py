"""BRDF transfer per face region (Weyrich et al. 2006 §8, Matusik et al. 2005 interpolation)."""

import numpy as np
import pytest

from facestats.edit import Histogram, region_histograms, transfer_brdf
from facestats.errors import ValidationError
from tests.helpers import make_map_subject


def _maps(ds, model="ts"):
    second = "m" if model == "ts" else "exponent"
    return {"rho_s": ds[f"{model}_rho_s"].values, second: ds[f"{model}_{second}"].values}


@pytest.fixture(scope="module")
def faces():
    # Same region layout, different people: the target is shinier (rho_shift) and of another skin type.
    src = make_map_subject("S1", size=64, skin_type=3, seed=1)
    tgt = make_map_subject("S2", size=64, skin_type=4, seed=2, rho_shift=0.05)
    return src, tgt


def _spearman(a, b):
    ra = np.argsort(np.argsort(a)).astype(float)
    rb = np.argsort(np.argsort(b)).astype(float)
    return np.corrcoef(ra, rb)[0, 1]


def test_face_to_face_is_exact_per_region(faces):
    src, tgt = faces
    regions = src["region"].values
    out = transfer_brdf(_maps(src), regions, _maps(tgt), target_regions=tgt["region"].values)
    for name in ("rho_s", "m"):
        assert out[name].dtype == np.float32
        for r in range(1, 11):
            sel = regions == r
            # Equal region sizes: the region's values become exactly the target's values.
            np.testing.assert_array_equal(np.sort(out[name][sel]), np.sort(tgt[f"ts_{name}"].values[sel]))
        np.testing.assert_array_equal(out[name][regions == 0], src[f"ts_{name}"].values[regions == 0])


def test_rank_dependence_of_rho_s_and_m_is_kept(faces):
    src, tgt = faces
    regions = src["region"].values
    s = _maps(src)
    out = transfer_brdf(s, regions, _maps(tgt), target_regions=tgt["region"].values)
    for r in (2, 7, 9):
        sel = regions == r
        # Marginals matched independently by increasing maps: each parameter's ranks, hence the
        # Spearman correlation of (rho_s, m) inside the region, are the source's.
        np.testing.assert_array_equal(
            np.argsort(out["rho_s"][sel], kind="stable"), np.argsort(s["rho_s"][sel], kind="stable")
        )
        assert _spearman(out["rho_s"][sel], out["m"][sel]) == pytest.approx(
            _spearman(s["rho_s"][sel], s["m"][sel]), abs=1e-12
        )


def test_interpolation_endpoints_and_monotone_in_t(faces):
    src, tgt = faces
    regions = src["region"].values
    s, t_maps = _maps(src), _maps(tgt)
    kw = dict(target_regions=tgt["region"].values)
    zero = transfer_brdf(s, regions, t_maps, t=0.0, **kw)
    for k in s:
        np.testing.assert_array_equal(zero[k], s[k])
    full = transfer_brdf(s, regions, t_maps, t=1.0, **kw)
    ts = np.linspace(0, 1, 6)
    outs = [transfer_brdf(s, regions, t_maps, t=t, **kw)["rho_s"].astype(np.float64) for t in ts]
    x, q = s["rho_s"].astype(np.float64), full["rho_s"].astype(np.float64)
    for t, o in zip(ts, outs):
        # Q_t = (1 - t) Q_source + t Q_target, texel by texel (float32 rounding).
        np.testing.assert_allclose(o, (1 - t) * x + t * q, atol=1e-7)
    sel = regions == 2
    means = [o[sel].mean() for o in outs]
    assert np.all(np.diff(means) > 0)  # the shinier target pulls rho_s up monotonically
    np.testing.assert_allclose(means, (1 - ts) * x[sel].mean() + ts * q[sel].mean(), rtol=1e-6)
    quart = np.array([np.quantile(o[sel], [0.1, 0.5, 0.9]) for o in outs])
    assert np.all(np.diff(quart, axis=0) > 0)


def test_population_histograms_and_blinn_phong(faces):
    src, _ = faces
    regions = src["region"].values
    rng = np.random.default_rng(0)
    # A population subset given as per-region histograms (e.g. the "lotion" condition).
    lotion = {r: Histogram.from_data(rng.normal(3.0 + r, 0.5, 20_000), 128) for r in range(1, 11)}
    rho = {r: rng.uniform(0.3, 0.4, 500) for r in (2, 7)}
    out = transfer_brdf(_maps(src, "bp"), regions, {"rho_s": rho, "exponent": lotion})
    for r in (2, 7):
        sel = regions == r
        n = sel.sum()
        u = (np.arange(n) + 0.5) / n
        np.testing.assert_allclose(np.sort(out["exponent"][sel]), lotion[r].quantile(u), rtol=1e-6)
        np.testing.assert_allclose(np.sort(out["rho_s"][sel]), np.quantile(rho[r], u, method="hazen"), rtol=1e-6)
    # Regions the target does not cover (rho_s only has 2 and 7) are left alone.
    sel = (regions != 2) & (regions != 7)
    np.testing.assert_array_equal(out["exponent"][sel], src["bp_exponent"].values[sel])


def test_non_finite_and_unedited_texels_kept(faces):
    src, tgt = faces
    regions = src["region"].values
    s = {k: v.copy() for k, v in _maps(src).items()}
    s["m"][regions == 7] = np.where(np.arange((regions == 7).sum()) % 5 == 0, np.nan, s["m"][regions == 7])
    out = transfer_brdf(s, regions, _maps(tgt), target_regions=tgt["region"].values, edit_regions=[7, 9])
    nan = np.isnan(s["m"])
    assert nan.sum() > 0 and np.array_equal(np.isnan(out["m"]), nan)
    keep = ~np.isin(regions, [7, 9])
    np.testing.assert_array_equal(out["m"][keep], s["m"][keep])
    assert not np.array_equal(out["m"][regions == 9], s["m"][regions == 9])


def test_region_histograms(faces):
    src, _ = faces
    hs = region_histograms(src["ts_m"].values, src["region"].values, bins=32)
    assert sorted(hs) == list(range(1, 11))
    assert hs[6].total == (src["region"].values == 6).sum()


def test_validation(faces):
    src, tgt = faces
    regions = src["region"].values
    with pytest.raises(ValidationError, match="missing"):
        transfer_brdf(_maps(src), regions, {"rho_s": _maps(tgt)["rho_s"]}, target_regions=regions)
    with pytest.raises(ValidationError, match="target_regions must be given"):
        transfer_brdf(_maps(src), regions, _maps(tgt))
    with pytest.raises(ValidationError, match="no data for region 3"):
        transfer_brdf({"m": _maps(src)["m"]}, regions, {"m": {2: [0.3, 0.4]}}, edit_regions=[3])
    with pytest.raises(ValidationError, match="integer label map"):
        transfer_brdf(_maps(src), regions.astype(float), _maps(tgt), target_regions=regions)
    with pytest.raises(ValidationError, match="t must lie in"):
        transfer_brdf(_maps(src), regions, _maps(tgt), target_regions=regions, t=-0.1)


def test_target_samples_outside_a_parameters_domain_are_refused():
    """A target m of -1 gave an edited m of -1 (an API red team): rho_s >= 0, m > 0 and exponent >= 0."""
    src = {"rho_s": np.full((4, 4), 0.1), "m": np.full((4, 4), 0.3)}
    reg = np.ones((4, 4), int)
    with pytest.raises(ValidationError, match=r"target\['m'\]\[1\] must be > 0 \(m\), got -2.0"):
        transfer_brdf(src, reg, {"rho_s": {1: [0.1, 0.2]}, "m": {1: [-1.0, -2.0]}}, t=1.0)
    with pytest.raises(ValidationError, match=r"target\['rho_s'\] must be >= 0 \(rho_s\), got -0.5"):
        transfer_brdf(src, reg, {"rho_s": np.full((4, 4), -0.5), "m": np.full((4, 4), 0.2)}, target_regions=reg)
    out = transfer_brdf(src, reg, {"rho_s": {1: [0.1, 0.2]}, "m": {1: [0.2, 0.4]}}, t=1.0)
    assert np.all(out["m"] > 0)


def test_a_histogram_target_outside_the_parameters_domain_is_refused():
    """Sample and map targets were checked, Histogram targets were not: a transfer gave ρs = −0.56 (a red team)."""
    src = {"rho_s": np.full((2, 2), 0.1), "m": np.full((2, 2), 0.3)}
    lab = np.ones((2, 2), int)
    ok = {"rho_s": {1: Histogram([0.0, 0.5], [1])}, "m": {1: Histogram([0.0, 0.4], [1])}}  # m > 0 inside the bin
    out = transfer_brdf(src, lab, ok)
    assert out["rho_s"].min() > 0 and out["m"].min() > 0
    for name, hist in (("rho_s", Histogram([-1.0, -0.5], [1])), ("m", Histogram([-1.0, 0.0, 1.0], [1, 1]))):
        with pytest.raises(ValidationError, match=rf"target\['{name}'\]\[1\] must be .* starts at -1.0"):
            transfer_brdf(src, lab, {**ok, name: {1: hist}})
    empty_first = Histogram([-1.0, 0.0, 1.0], [0, 1])  # its first non-empty bin starts at 0: allowed
    assert transfer_brdf(src, lab, {**ok, "rho_s": {1: empty_first}})["rho_s"].min() >= 0
