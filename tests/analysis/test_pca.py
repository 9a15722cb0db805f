"""Region PCA (Weyrich Fig. 15), population selection and condition differences."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from facestats.analysis import condition_differences, principal_axes, region_pca, select_population
from facestats.analysis.pca import pooled_moments
from facestats.analysis.population import region_samples as store_region_samples
from facestats.core.conventions import CONDITIONS, REGION_IDS
from facestats.errors import ValidationError
from facestats.io.summary import region_samples
from tests.helpers import make_population


@pytest.fixture(scope="module")
def store():
    return make_population()


def test_principal_axes_eigendecomposition_matches_svd(rng):
    x = rng.multivariate_normal([0.2, 0.35], [[4e-4, -1.5e-4], [-1.5e-4, 2.5e-4]], size=500)
    mean, w, v = principal_axes(x)
    xc = x - x.mean(0)
    _, s, vt = np.linalg.svd(xc, full_matrices=False)
    np.testing.assert_allclose(mean, x.mean(0), rtol=1e-12)
    np.testing.assert_allclose(w, s**2 / (len(x) - 1), rtol=1e-10)
    for i in range(2):  # same directions up to sign
        assert abs(abs(v[:, i] @ vt[i]) - 1) < 1e-10
    assert np.all(v[np.argmax(np.abs(v), axis=0), [0, 1]] > 0)
    np.testing.assert_allclose(v.T @ v, np.eye(2), atol=1e-12)


def test_principal_axes_recovers_known_covariance(rng):
    angle = np.radians(30)
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    cov = rot @ np.diag([0.04**2, 0.01**2]) @ rot.T
    x = rng.multivariate_normal([0.2, 0.4], cov, size=200_000)
    mean, w, v = principal_axes(x)
    np.testing.assert_allclose(mean, [0.2, 0.4], atol=3e-4)
    np.testing.assert_allclose(np.sqrt(w), [0.04, 0.01], rtol=0.01)
    assert abs(abs(v[:, 0] @ rot[:, 0]) - 1) < 1e-4


def test_region_pca_against_svd_of_pooled_samples(store):
    res = region_pca(store)
    ids = [s for s in store.subjects().index if s.startswith("S")]  # the normal-condition population
    assert res.n_subjects == len(ids) + 1  # + the normal measurement of the condition series
    ids.append("C0")
    for r in REGION_IDS:
        pooled = np.concatenate([np.stack(region_samples(store.subject(s), "ts")[r], 1) for s in ids])
        e = res[r]
        assert e.n == len(pooled)
        np.testing.assert_allclose(e.mean, pooled.mean(0), rtol=1e-10)
        _, s, vt = np.linalg.svd(pooled - pooled.mean(0), full_matrices=False)
        np.testing.assert_allclose(e.eigenvalues, s**2 / (len(pooled) - 1), rtol=1e-8)
        assert abs(abs(e.eigenvectors[:, 0] @ vt[0]) - 1) < 1e-8
    # the factories give the nose (6) the smallest mean m, as Weyrich observe
    assert min(res.regions, key=lambda r: res[r].mean[1]) == 6


def test_pooled_moments_equal_those_of_the_pooled_samples(rng):
    groups = [rng.normal([0.2, 0.4], [0.05, 0.02], size=(n, 2)) for n in (40, 1, 0, 7, 300)]
    counts = [len(g) for g in groups]
    means = [g.mean(0) if len(g) else [np.nan, np.nan] for g in groups]
    covs = [np.cov(g.T, ddof=1) if len(g) > 1 else np.full((2, 2), np.nan) for g in groups]
    pooled = np.concatenate(groups)
    for ddof in (0, 1):
        mean, cov, n = pooled_moments(counts, means, covs, ddof)
        assert n == len(pooled)
        np.testing.assert_allclose(mean, pooled.mean(0), rtol=1e-13)
        np.testing.assert_allclose(cov, np.cov(pooled.T, ddof=ddof), rtol=1e-12)
    with pytest.raises(ValidationError, match="more than ddof=1 samples, got 1"):
        pooled_moments([1, 0], [[0.1, 0.2], [np.nan, np.nan]], np.zeros((2, 2, 2)))


class _OldIndex:
    """A store whose index predates the per-region covariance columns."""

    def __init__(self, store):
        self._store = store

    def subjects(self):
        table = self._store.subjects()
        return table[[c for c in table.columns if "_cov_r" not in c]]

    def subject(self, sid, **kw):
        return self._store.subject(sid, **kw)


def test_store_pca_pools_the_index_moments_and_reads_samples_for_older_indexes(store):
    from_index, from_samples = region_pca(store, from_index=True), region_pca(store, from_index=False)
    old = _OldIndex(store)
    assert region_pca(old).n_subjects == from_index.n_subjects == from_samples.n_subjects
    for r in REGION_IDS:
        a, b, c = from_index[r], from_samples[r], region_pca(old)[r]
        assert a.n == b.n == c.n and a.n_subjects == b.n_subjects
        for x in (b, c):
            np.testing.assert_allclose(a.mean, x.mean, rtol=1e-12)
            np.testing.assert_allclose(a.eigenvalues, x.eigenvalues, rtol=1e-10)
            np.testing.assert_allclose(a.eigenvectors, x.eigenvectors, atol=1e-10)
    with pytest.raises(ValidationError, match="index has no per-region ts covariances"):
        region_pca(old, from_index=True)


def test_region_ellipse_geometry(store):
    e = region_pca(store)[8]
    pts = e.boundary(k=2.0, n_points=50)
    cov = e.eigenvectors @ np.diag(e.eigenvalues) @ e.eigenvectors.T
    d = pts - e.mean
    maha = np.sqrt(np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d))
    np.testing.assert_allclose(maha, 2.0, rtol=1e-10)
    np.testing.assert_allclose(e.half_axes(2.0), 2 * np.sqrt(e.eigenvalues))
    assert -np.pi / 2 < e.angle <= np.pi / 2
    frame = region_pca(store).to_frame()
    assert list(frame.index) == list(REGION_IDS)
    np.testing.assert_allclose(frame.loc[8, "std_1"], np.sqrt(e.eigenvalues[0]))


def test_region_pca_dataframe_and_blinn_phong(store):
    ids = list(select_population(store).index)
    df = store_region_samples(store, "ts", ids)
    a, b = region_pca(store), region_pca(df)
    for r in REGION_IDS:
        np.testing.assert_allclose(a[r].eigenvalues, b[r].eigenvalues, rtol=1e-12)
    bp = region_pca(store, model="bp")
    assert bp.parameters == ("rho_s", "exponent")
    # Blinn-Phong exponent of the factories is 2/m^2 - 2, far larger than m
    assert bp[7].mean[1] > 10


def test_select_population_and_errors(store):
    normal = select_population(store)
    assert set(normal["condition"]) == {"normal"}
    assert len(select_population(store, conditions=None)) == len(store.subjects())
    assert list(select_population(store, subjects=["S001", "S002"]).index) == ["S001", "S002"]
    with pytest.raises(ValidationError, match="unknown"):
        select_population(store, subjects=["nope"])
    with pytest.raises(ValidationError, match="none of the subjects named was measured under condition.s. cold"):
        select_population(store, subjects=["S001"], conditions=["cold"])
    # A store of edits only (a fresh-user red team got the selection's Python repr): says what was left out and why.
    frame = store.subjects().copy()
    frame["source"] = "facestats.edit"
    with pytest.raises(ValidationError, match=r"holds no measured subject \(\d+ edited subject\(s\) left out"):
        select_population(frame)
    with pytest.raises(ValidationError, match="source"):
        region_pca(42)
    with pytest.raises(ValidationError, match="model"):
        region_pca(store, model="lafortune")


def _pooled_distance(idx, rows, regions, model="ts", lobe="m"):
    """Independent computation of the condition distance (conditions.py's module docstring) from the index rows
    ``rows`` (one per condition, in order) over ``regions``: the spreads pooled over every (condition, region)
    cell with texels, s² = Σ (n − 1) s² / Σ (n − 1), and the regions weighted by their texels."""
    cells = [(c, r) for c in rows for r in REGION_IDS if idx.loc[c, f"n_{model}_r{r}"] > 0]
    spread = {}
    for p in ("rho_s", lobe):
        dof = np.array([idx.loc[c, f"n_{model}_r{r}"] - 1 for c, r in cells], float)
        var = np.array([idx.loc[c, f"{model}_{p}_std_r{r}"] ** 2 for c, r in cells])
        spread[p] = np.sqrt(np.sum(dof * var) / np.sum(dof))
    n = np.array([[idx.loc[c, f"n_{model}_r{r}"] for r in regions] for c in rows], float)
    w = n.sum(0) / n.sum()
    d = np.zeros((len(rows), len(rows)))
    for i, a in enumerate(rows):
        for j, b in enumerate(rows):
            for p in ("rho_s", lobe):
                diff = np.array(
                    [idx.loc[a, f"{model}_{p}_mean_r{r}"] - idx.loc[b, f"{model}_{p}_mean_r{r}"] for r in regions]
                )
                d[i, j] += np.sum(w * (diff / spread[p]) ** 2)
    return np.sqrt(d), spread, w


def _triangle_excess(dist):
    """max over all triples of d(a, c) − d(a, b) − d(b, c) (≤ 0, up to rounding, for a metric)."""
    d = np.asarray(dist)
    return float(np.max(d[:, None, :] - d[:, :, None] - d.T[None, :, :]))


def test_condition_differences_against_index(store):
    res = condition_differences(store)
    assert res.person_id == "P-cond"
    assert res.conditions == CONDITIONS
    idx = store.subjects()
    rows = [f"C{j}" for j in range(len(CONDITIONS))]
    want_dist, spread, w = _pooled_distance(idx, rows, REGION_IDS)
    assert res.spread["rho_s_std"] == pytest.approx(spread["rho_s"], rel=1e-12)
    assert res.spread["lobe_std"] == pytest.approx(spread["m"], rel=1e-12)
    np.testing.assert_allclose(res.weights.to_numpy(), w, rtol=1e-12)
    for j, cond in enumerate(CONDITIONS[1:], start=1):
        for r in (2, 6, 8):
            want = idx.loc[f"C{j}", f"ts_rho_s_mean_r{r}"] - idx.loc["C0", f"ts_rho_s_mean_r{r}"]
            assert res.differences.loc[(cond, r), "d_rho_s"] == pytest.approx(want, rel=1e-12)
            assert res.differences.loc[(cond, r), "z_rho_s"] == pytest.approx(want / spread["rho_s"], rel=1e-10)
    # rho_shift grows 0.03 per condition, so d_rho_s ≈ 0.03 j in every region
    d = res.differences["d_rho_s"].xs("powder", level="condition")
    np.testing.assert_allclose(d, 0.18, atol=0.01)
    dist = res.distance.to_numpy()
    np.testing.assert_allclose(dist, want_dist, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(dist, dist.T)
    assert np.all(np.diag(dist) == 0)
    assert dist[0, 6] > dist[0, 1] > 0  # powder (shift 0.18) is further from normal than cold (0.03)
    assert _triangle_excess(dist) <= 1e-12
    assert not res.left_out and "left out" not in res.to_text()
    assert "pooled within-region sd" in res.to_text()


def test_condition_distance_is_a_metric_when_the_spread_changes_with_the_condition(store):
    """Each pair standardised by its own spread sqrt((s_a² + s_b²)/2) broke the triangle inequality where two
    conditions have a small spread (a walkthrough: cold–lotion 62.0 against normal–cold 11.8 + normal–lotion 19.5
    on a 16² store); one pooled spread makes it a Euclidean distance, over every triple."""
    idx = store.subjects().copy()
    std = [c for c in idx.columns if c.startswith(("ts_rho_s_std_r", "ts_m_std_r"))]
    idx.loc[["C1", "C5"], std] *= 1e-3  # cold and lotion: texels nearly alike within each region
    res = condition_differences(idx)
    dist = res.distance.to_numpy()
    assert _triangle_excess(dist) <= 1e-12
    np.testing.assert_allclose(dist, _pooled_distance(idx, [f"C{j}" for j in range(7)], REGION_IDS)[0], rtol=1e-10)

    # the old figure, independently: cold–lotion far beyond cold–normal + normal–lotion
    def pairwise(a, b):
        z = [
            (idx.loc[a, f"ts_{p}_mean_r{r}"] - idx.loc[b, f"ts_{p}_mean_r{r}"])
            / np.sqrt((idx.loc[a, f"ts_{p}_std_r{r}"] ** 2 + idx.loc[b, f"ts_{p}_std_r{r}"] ** 2) / 2)
            for r in REGION_IDS
            for p in ("rho_s", "m")
        ]
        return np.sqrt(np.sum(np.square(z)) / len(REGION_IDS))

    assert pairwise("C1", "C5") > 10 * (pairwise("C1", "C0") + pairwise("C0", "C5"))


def test_a_region_of_few_texels_does_not_dominate_the_condition_distance(store):
    """Two texels per condition whose spread is near 0 (the eyelids of a 16² store) made 73 % of d² even with the
    regions weighted by texels, while the spread was the region's own: with one spread pooled over the regions and
    the region weighted by its texels, it moves the distances by about its share of the texels."""
    idx = store.subjects().copy()
    full = condition_differences(idx).distance.to_numpy()
    rows = [f"C{j}" for j in range(7)]
    idx.loc[rows, "n_ts_r4"] = 2
    idx.loc[rows, ["ts_rho_s_std_r4", "ts_m_std_r4"]] = 1e-5
    few = condition_differences(idx)
    off = ~np.eye(7, dtype=bool)
    np.testing.assert_allclose(few.distance.to_numpy()[off], full[off], rtol=0.1)
    assert few.weights[4] == pytest.approx(14 / idx.loc[rows, [f"n_ts_r{r}" for r in REGION_IDS]].to_numpy().sum())
    np.testing.assert_allclose(few.distance.to_numpy(), _pooled_distance(idx, rows, REGION_IDS)[0], rtol=1e-10)


def test_regions_without_texels_are_left_out_by_name(store):
    idx = store.subjects().copy()
    rows = [f"C{j}" for j in range(7)]
    region1 = [c for c in idx.columns if c.endswith("_r1") and c.startswith(("ts_", "n_ts"))]
    idx.loc[rows, region1] = np.nan
    idx.loc[rows, "n_ts_r1"] = 0
    res = condition_differences(idx)
    assert res.left_out == {1: "no texels"} and res.weights[1] == 0
    np.testing.assert_allclose(res.distance.to_numpy(), _pooled_distance(idx, rows, REGION_IDS[1:])[0], rtol=1e-10)
    assert "left out: region 1 mustache (no texels)" in res.to_text()
    doc = res.to_dict()
    assert doc["left_out"] == [{"region": 1, "name": "mustache", "reason": "no texels"}]
    assert doc["weights"]["1"] == 0 and doc["spread"]["dof"] == res.spread["dof"]
    # a region measured under some conditions only: its differences where it has values, no distance
    idx = store.subjects().copy()
    idx.loc["C1", [c for c in idx.columns if c.endswith("_r3") and c.startswith("ts_")]] = np.nan
    idx.loc["C1", "n_ts_r3"] = 0
    res = condition_differences(idx)
    assert res.left_out == {3: "no texels under cold"}
    assert np.isfinite(res.differences.loc[("hot", 3), "z_rho_s"])
    assert _triangle_excess(res.distance) <= 1e-12
    want, spread, _ = _pooled_distance(idx, rows, [r for r in REGION_IDS if r != 3])
    np.testing.assert_allclose(res.distance.to_numpy(), want, rtol=1e-10)  # region 3 out of the distance ...
    assert res.spread["rho_s_std"] == pytest.approx(spread["rho_s"], rel=1e-12)  # ... not out of the spread


def test_repeated_measurements_pool_to_the_sample_spread_of_all_their_values(store, rng):
    """Two measurements of the reference condition combine into the mean and the sample standard deviation (ddof 1,
    as the index's) of their values together; the pooling used ddof 0 for the within part (a review)."""
    idx = store.subjects()
    a, b = rng.normal(0.20, 0.03, 40), rng.normal(0.26, 0.05, 7)  # the texels of region 2 in two captures
    twice = idx.loc[["C0", "C0"]].copy()
    twice.index = ["C0", "C0-again"]
    for row, x in zip(twice.index, (a, b)):
        twice.loc[row, ["ts_rho_s_mean_r2", "ts_rho_s_std_r2", "n_ts_r2"]] = [x.mean(), x.std(ddof=1), x.size]
    frame = pd.concat([idx.drop(index="C0"), twice])
    res = condition_differences(frame, person_id="P-cond")
    both = np.concatenate([a, b])
    ref = res.values.loc[("normal", 2)]
    assert ref["rho_s"] == pytest.approx(both.mean(), rel=1e-12)
    assert ref["rho_s_std"] == pytest.approx(both.std(ddof=1), rel=1e-9)
    assert ref["n"] == both.size
    d = res.differences.loc[("cold", 2)]
    want_d = idx.loc["C1", "ts_rho_s_mean_r2"] - both.mean()
    assert d["d_rho_s"] == pytest.approx(want_d, rel=1e-12)
    assert d["z_rho_s"] == pytest.approx(want_d / res.spread["rho_s_std"], rel=1e-12)


def test_condition_differences_needs_a_series():
    plain = make_population(n=5, conditions=False)
    with pytest.raises(ValidationError, match="another condition"):
        condition_differences(plain)
    with pytest.raises(ValidationError, match="person_id"):
        condition_differences(make_population(n=5), person_id="nobody")


def test_edited_subjects_enter_population_statistics_only_by_name():
    import pandas as pd

    from facestats.core.conventions import EDIT_SOURCE

    index = pd.DataFrame(
        {
            "age": [30, 30, 40],
            "gender": ["F", "F", "M"],
            "skin_type": [2, 2, 3],
            "condition": ["normal"] * 3,
            "source": ["facestats simulator", EDIT_SOURCE, "facestats simulator"],
        },
        index=pd.Index(["S001", "S001.brdf-1234", "S002"], name="subject_id"),
    )
    assert list(select_population(index).index) == ["S001", "S002"]  # one measurement per person, as §7
    assert list(select_population(index, ["S001", "S001.brdf-1234"]).index) == ["S001", "S001.brdf-1234"]


@pytest.mark.parametrize("ddof", [-3, 1.5, True])
def test_ddof_must_be_a_non_negative_integer(ddof):
    """-3 and 1.5 were accepted silently (a covariance divided by n + 3 or n - 1.5)."""
    with pytest.raises(ValidationError, match="ddof must be an integer"):
        principal_axes(np.random.default_rng(0).normal(size=(20, 2)), ddof=ddof)


def test_condition_differences_leave_edited_subjects_out(store):
    """An edit keeps its source's person_id and condition: it was pooled with the measurements as a repeat (an audit:
    a BRDF transfer of P150-normal to lotion moved lotion's distance to normal from 4.94 to 1.34)."""
    import pandas as pd

    from facestats.core.conventions import EDIT_SOURCE

    idx = store.subjects()
    edited = idx.loc[["C0"]].rename(index={"C0": "C0.brdf-edit"})
    cols = [c for c in idx.columns if c.startswith("ts_rho_s_mean_r")]
    edited[cols] = idx.loc["C6", cols].to_numpy()  # normal made to look like powder
    edited["source"] = EDIT_SOURCE
    with_edit = condition_differences(pd.concat([idx, edited]).sort_index())
    alone = condition_differences(idx)
    np.testing.assert_array_equal(with_edit.distance.to_numpy(), alone.distance.to_numpy())
    assert with_edit.distance.to_numpy()[0, 6] > 0.1


def test_principal_axes_refuse_what_has_no_finite_covariance():
    x = np.random.default_rng(0).standard_normal((50, 2))
    with pytest.raises(ValidationError, match="at least one variable"):
        principal_axes(np.zeros((5, 0)))
    with pytest.raises(ValidationError, match=r"too large .* up to 2\.\d+e\+155"):  # was NaN eigenvalues
        principal_axes(x * 1e155)


@pytest.mark.parametrize("ddof", [-1, 2.5, "1", True])
def test_region_pca_checks_ddof_on_both_paths(ddof):
    store = make_population(n=8, seed=2)
    for from_index in ("auto", False):
        with pytest.raises(ValidationError, match="ddof must be an integer"):
            region_pca(store, ddof=ddof, from_index=from_index)


def test_ellipse_angle_range_and_smoothest_lobe_of_each_model():
    """A vertical major axis (along the lobe parameter) has angle π/2, the closed end of (−π/2, π/2]; the smoothest
    lobe is the smallest mean m (Torrance-Sparrow) but the largest mean exponent n (Blinn-Phong)."""
    from facestats.analysis.pca import RegionEllipse, RegionPCA

    def ellipse(region, mean, axes):
        return RegionEllipse(region, np.array(mean), np.array([2.0, 1.0]), np.array(axes), n=10, n_subjects=2)

    upright = ellipse(1, [0.1, 0.3], [[0.0, 1.0], [1.0, 0.0]])
    assert upright.angle == np.pi / 2
    assert ellipse(1, [0.1, 0.3], [[1.0, 0.0], [0.0, 1.0]]).angle == 0.0
    means = {1: [0.1, 0.30], 2: [0.2, 0.25], 3: [0.3, 0.40]}
    regions = {r: ellipse(r, m, np.eye(2)) for r, m in means.items()}
    assert RegionPCA("ts", ("rho_s", "m"), regions, 2).orderings()["smallest_lobe"] == 2
    assert RegionPCA("bp", ("rho_s", "exponent"), regions, 2).orderings()["smallest_lobe"] == 3


def test_regions_without_an_ellipse_are_named_and_the_orderings_compare_the_regions_present(store):
    """A 16² store has no mustache texels (region 1): the table left it out without a word, and the orderings
    were compared with the paper's sets, which hold region 1 ('largest variance: 3 9 10 8 4 (paper: 8 1 3 9 10)';
    a walkthrough)."""
    from facestats.analysis.plots import plot_region_pca
    from tests.helpers import MemoryStore

    datasets = [ds.assign(region=ds["region"].where(ds["region"] != 1, 2)) for ds in store.datasets()]
    no_mustache = MemoryStore(datasets)
    for res in (region_pca(no_mustache), region_pca(no_mustache, from_index=False)):
        assert 1 not in res.regions and res.left_out == {1: "no texels"}
        ours = res.orderings()
        cmp = res.compare_published()
        assert cmp.loc["largest_variance", "paper"] == [8, 3, 9, 10]  # the paper's ranking without region 1
        assert cmp.loc["largest_variance", "ours"] == ours["largest_variance"][:4]
        assert cmp.loc["highest_rho_s", "paper"] == [6, 3, 4, 8, 2] and len(cmp.loc["highest_rho_s", "ours"]) == 5
        text = res.to_text()
        assert "left out: region 1 mustache (no texels)" in text
        assert "orderings over the 9 regions present" in text and "(paper without 1: 8 3 9 10)" in text
        assert res.to_dict()["left_out"] == [{"region": 1, "name": "mustache", "reason": "no texels"}]
        assert "left out: region 1 mustache (no texels)" in plot_region_pca(res).axes[0].get_title()
    full = region_pca(store)
    assert full.left_out == {} and "left out" not in full.to_text() and "(paper: 8 1 3 9 10)" in full.to_text()
    assert full.compare_published().loc["largest_variance", "paper"] == [8, 1, 3, 9, 10]
    # too few samples for the covariance: named with the count
    samples = store_region_samples(store, "ts", subjects=["S000"])
    one = pd.concat([samples[samples["region"] != 5], samples[samples["region"] == 5].head(1)])
    res = region_pca(one)
    assert res.left_out == {5: "1 sample, a covariance with ddof=1 needs more"}
