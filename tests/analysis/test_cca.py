"""CCA (Weyrich Fig. 16) against published values and independent computations."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from sklearn.cross_decomposition import CCA as SklearnCCA
from sklearn.datasets import load_linnerud

from facestats.analysis import brdf_cca, cca
from facestats.errors import ValidationError
from tests.helpers import make_population

# SAS/STAT User's Guide, PROC CANCORR Example "Canonical Correlation Analysis of Fitness Club Data"
# (Linnerud data: Weight, Waist, Pulse against Chins, Situps, Jumps).
SAS_CORRELATIONS = [0.795608, 0.200556, 0.072570]
SAS_LIKELIHOOD_RATIO = [0.35039053, 0.95472266, 0.99473355]


@pytest.fixture(scope="module")
def linnerud():
    d = load_linnerud(as_frame=True)
    return d.target, d.data  # physiological (X), exercises (Y)


def _direct_cca(x, y):
    """Canonical correlations from the covariance blocks: sqrt of eig(Σxx⁻¹ Σxy Σyy⁻¹ Σyx)."""
    p = x.shape[1]
    s = np.cov(np.hstack([x, y]).T)
    sxx, sxy, syy = s[:p, :p], s[:p, p:], s[p:, p:]
    m = np.linalg.solve(sxx, sxy) @ np.linalg.solve(syy, sxy.T)
    ev = np.sort(np.linalg.eigvals(m).real)[::-1][: min(p, y.shape[1])]
    return np.sqrt(np.clip(ev, 0, 1))


def _structured(rng, n=149, p=20, q=3):
    """A BRDF-like block driven by two latent factors that also drive the first two Y variables."""
    z = rng.standard_normal((n, 2))
    y = np.c_[z[:, 0] + 0.6 * rng.standard_normal(n), z[:, 1] + 1.0 * rng.standard_normal(n), rng.standard_normal(n)]
    load = rng.standard_normal((2, p))
    x = z @ load + 1.5 * rng.standard_normal((n, p))
    return x, y


def test_linnerud_matches_sas(linnerud):
    res = cca(*linnerud)
    np.testing.assert_allclose(res.correlations, SAS_CORRELATIONS, atol=1e-6)
    np.testing.assert_allclose(res.wilks_lambda, SAS_LIKELIHOOD_RATIO, atol=1e-8)
    assert res.x_names == ("Weight", "Waist", "Pulse") and res.y_names == ("Chins", "Situps", "Jumps")


def test_linnerud_matches_sklearn(linnerud):
    x, y = linnerud
    res = cca(x, y)
    model = SklearnCCA(n_components=3, max_iter=5000, tol=1e-12).fit(x, y)
    u, v = model.transform(x, y)
    sk = [abs(np.corrcoef(u[:, i], v[:, i])[0, 1]) for i in range(3)]
    np.testing.assert_allclose(res.correlations, sk, atol=1e-6)
    # the same canonical directions up to sign and scale
    for i in range(3):
        assert abs(abs(np.corrcoef(res.projections[:, i], u[:, i])[0, 1]) - 1) < 1e-5


def test_transform_takes_a_dataframe_s_columns_by_name_and_checks_an_array_s_count(linnerud):
    x, y = linnerud
    res = cca(x, y)
    reordered = x[["Pulse", "Weight", "Waist"]].assign(extra=1.0)  # was taken by position: Pulse as Weight
    np.testing.assert_allclose(res.transform(reordered), res.projections, atol=1e-10)
    u, v = res.transform(reordered, y[["Jumps", "Chins", "Situps"]])
    np.testing.assert_allclose(v, res.y_projections, atol=1e-10)
    np.testing.assert_allclose(res.transform(x.to_numpy()), res.projections, atol=1e-10)
    with pytest.raises(ValidationError, match=r"X must have the fitted columns .*missing \['Pulse'\]"):
        res.transform(x.drop(columns="Pulse"))
    with pytest.raises(ValidationError, match=r"X must have 3 columns .*got shape \(20, 2\)"):
        res.transform(x.to_numpy()[:, :2])  # was numpy's bare matmul ValueError
    with pytest.raises(ValidationError, match=r"Y must have 3 columns .*got shape \(20, 4\)"):
        res.transform(x.to_numpy(), np.c_[y.to_numpy(), y.to_numpy()[:, :1]])  # numpy broadcast ValueError before


def test_against_covariance_blocks_and_projection_properties(rng):
    x, y = _structured(rng)
    res = cca(x, y)
    np.testing.assert_allclose(res.correlations, _direct_cca(x, y), atol=1e-10)
    assert np.all(np.diff(res.correlations) <= 0)
    n = len(x)
    cu = np.cov(res.projections.T)
    cv = np.cov(res.y_projections.T)
    np.testing.assert_allclose(cu, np.eye(3), atol=1e-10)  # unit variance, uncorrelated
    np.testing.assert_allclose(cv, np.eye(3), atol=1e-10)
    cross = res.projections.T @ res.y_projections / (n - 1)
    np.testing.assert_allclose(cross, np.diag(res.correlations), atol=1e-10)
    # structure correlations are correlations with the own canonical variate
    np.testing.assert_allclose(res.x_loadings[4, 0], np.corrcoef(x[:, 4], res.projections[:, 0])[0, 1], atol=1e-10)
    np.testing.assert_allclose(res.transform(x), res.projections, atol=1e-10)


def test_direct_correlations_are_multiple_correlations(rng):
    x, y = _structured(rng)
    res = cca(x, y)
    design = np.c_[np.ones(len(x)), x]
    for j in range(3):
        beta = np.linalg.lstsq(design, y[:, j], rcond=None)[0]
        resid = y[:, j] - design @ beta
        r2 = 1 - resid @ resid / np.sum((y[:, j] - y[:, j].mean()) ** 2)
        assert res.direct_correlations[j] == pytest.approx(np.sqrt(r2), abs=1e-10)
        assert res.direct_correlations[j] == pytest.approx(cca(x, y[:, j]).correlations[0], abs=1e-12)
        f = (r2 / 20) / ((1 - r2) / (len(x) - 21))
        from scipy.stats import f as f_dist

        assert res.direct_p_value[j] == pytest.approx(f_dist.sf(f, 20, len(x) - 21), rel=1e-8)
    assert res.correlations[0] >= res.direct_correlations.max() - 1e-12  # CCA cannot do worse than one variable


def test_bartlett_and_permutation_tests(rng):
    x, y = _structured(rng)
    res = cca(x, y, n_permutations=499, seed=1)
    n, p, q = 149, 20, 3
    lam0 = np.prod(1 - res.correlations**2)
    chi2 = -(n - 1 - (p + q + 1) / 2) * np.log(lam0)
    from scipy.stats import chi2 as chi2_dist

    assert res.chi2[0] == pytest.approx(chi2, rel=1e-12)
    assert res.df.tolist() == [60, 38, 18]
    assert res.p_value[0] == pytest.approx(chi2_dist.sf(chi2, 60), rel=1e-10)
    assert res.p_value[0] < 1e-6 and res.permutation_p[0] == pytest.approx(1 / 500)
    # Later dimensions have no permutation p: permuting Y tests them against full independence, which their
    # null does not hold (anti-conservative: 47.5 % false rejections at 0.05 in an audit's simulation).
    assert np.isnan(res.permutation_p[1:]).all() and "p = 0.002 (dimension 1;" in res.to_text()
    assert res.p_value[2] > 0.01  # the third Y variable is noise
    # under independence the permutation and asymptotic p-values agree
    x0, y0 = rng.standard_normal((300, 5)), rng.standard_normal((300, 3))
    null = cca(x0, y0, n_permutations=2000, seed=2)
    assert abs(null.permutation_p[0] - null.p_value[0]) < 0.05
    again = cca(x0, y0, n_permutations=2000, seed=2)
    np.testing.assert_array_equal(null.permutation_p, again.permutation_p)  # seeded
    table = null.summary()
    assert list(table.columns) == ["correlation", "wilks_lambda", "chi2", "df", "p_value", "permutation_p"]


def test_regularization_limits(rng):
    x, y = _structured(rng, n=80, p=6)
    np.testing.assert_allclose(cca(x, y, regularization=0.0).correlations, _direct_cca(x, y), atol=1e-10)
    # λ = 1: both covariances become diagonal, so K is the X-Y correlation matrix
    full = cca(x, y, regularization=1.0, n_permutations=199)
    rxy = np.corrcoef(np.hstack([x, y]).T)[:6, 6:]
    np.testing.assert_allclose(full.correlations, np.linalg.svd(rxy, compute_uv=False), atol=1e-10)
    assert full.correlations[0] > 1  # a regularised criterion, not a correlation
    assert np.isnan(full.p_value).all() and full.permutation_p[0] == pytest.approx(1 / 200)
    with pytest.raises(ValidationError, match="regularization"):
        cca(x, y, regularization=1.5)


def test_dataframes_missing_rows_and_degenerate_blocks(rng):
    x, y = _structured(rng, n=60, p=4)
    xf = pd.DataFrame(x, index=[f"s{i}" for i in range(60)], columns=list("abcd"))
    yf = pd.DataFrame(y, index=xf.index, columns=["skin_type", "gender", "age"])
    a, b = cca(x, y), cca(xf, yf)
    np.testing.assert_allclose(a.correlations, b.correlations, atol=1e-12)
    assert b.index[0] == "s0" and b.y_data.columns.tolist() == ["skin_type", "gender", "age"]
    xf.iloc[3, 1] = np.nan
    with pytest.raises(ValidationError, match="missing"):
        cca(xf, yf)
    c = cca(xf, yf, missing="drop")
    assert c.dropped == ("s3",) and c.n == 59
    np.testing.assert_allclose(c.correlations, _direct_cca(np.delete(x, 3, 0), np.delete(y, 3, 0)), atol=1e-10)
    # a constant Y variable has no canonical dimension and no direct correlation
    yc = y.copy()
    yc[:, 2] = 1.0
    d = cca(x, yc)
    assert d.correlations.size == 2 and np.isnan(d.direct_correlations[2])
    with pytest.raises(ValidationError, match="same number of rows"):
        cca(x, y[:-1])


def test_brdf_cca_on_store():
    store = make_population(n=60, seed=3)
    res = brdf_cca(store, n_permutations=199)
    assert len(res.x_names) == 20 and res.x_names[:2] == ("rho_s_r1", "m_r1")
    assert res.y_names == ("skin_type", "gender", "age")
    idx = store.subjects()
    normal = idx[idx["condition"] == "normal"]
    assert res.n == len(normal)
    # coding: gender 0 = M, 1 = F; skin type I grouped into II
    y = res.y_data.loc[normal.index]
    np.testing.assert_array_equal(y["gender"], (normal["gender"] == "F").astype(float))
    np.testing.assert_array_equal(y["skin_type"], np.maximum(normal["skin_type"], 2))
    assert y["skin_type"].min() == 2 and (normal["skin_type"] == 1).any()
    # ρs rises with skin type (and gender) in the stand-in; age plays no part
    direct = res.direct_table()
    assert direct.loc["skin_type", "direct_correlation"] > 0.9 and direct.loc["skin_type", "p_value"] < 1e-10
    assert direct.loc["age", "p_value"] > 0.01  # R of a noise variable against 20 predictors is large but insignificant
    assert res.correlations[0] > 0.9 and res.permutation_p[0] < 0.01
    assert res.y_loadings[0, 0] > 0.9  # the first dimension is skin type, oriented positively
    np.testing.assert_allclose(
        res.correlations,
        _direct_cca(
            normal[[f"ts_{p}_mean_r{r}" for r in range(1, 11) for p in ("rho_s", "m")]].to_numpy(), y.to_numpy()
        ),
        atol=1e-8,
    )


def test_to_frame_holds_each_subjects_canonical_variates(rng):
    """Only RegionPCA had ``to_frame()`` (a walkthrough): one row per subject used, the X and Y variates and the Y
    variables; each pair of variates correlates by its canonical correlation, and the first two X columns are the
    projections of ``to_dict()``."""
    x, y = _structured(rng, n=60, p=4)
    xf = pd.DataFrame(x, index=[f"s{i}" for i in range(60)], columns=list("abcd"))
    yf = pd.DataFrame(y, index=xf.index, columns=["skin_type", "gender", "age"])
    xf.iloc[3, 1] = np.nan
    res = cca(xf, yf, missing="drop")
    frame = res.to_frame()
    k = res.correlations.size
    dims = [f"dimension_{i + 1}" for i in range(k)]
    assert list(frame.columns) == dims + [f"y_{d}" for d in dims] + ["skin_type", "gender", "age"]
    assert frame.index.name == "subject_id" and "s3" not in frame.index and len(frame) == res.n == 59
    proj = res.to_dict()["projections"]
    assert proj["subject_id"] == list(frame.index)
    np.testing.assert_allclose(frame[["dimension_1", "dimension_2"]].to_numpy().T, [proj["dimension_1"],
                               proj["dimension_2"]], rtol=1e-12)  # fmt: skip
    r = [np.corrcoef(frame[d], frame[f"y_{d}"])[0, 1] for d in dims]
    np.testing.assert_allclose(r, res.correlations, atol=1e-10)
    np.testing.assert_allclose(frame[dims].std(ddof=1), 1.0, rtol=1e-10)  # unit variance
    np.testing.assert_array_equal(frame[["skin_type", "gender", "age"]], yf.drop(index="s3"))


def test_too_few_subjects_for_the_variables_is_refused_not_a_perfect_fit():
    rng = np.random.default_rng(3)
    X, Y = rng.standard_normal((12, 18)), rng.standard_normal((12, 3))  # noise: a plain CCA would give r = 1
    with pytest.raises(ValidationError, match=r"12 rows for 18 \+ 3 variables .*ranks 11 \+ 3.*need at least 22 rows"):
        cca(X, Y)
    res = cca(X, Y, regularization=0.5)  # shrinkage keeps the problem well posed; no parametric tests then
    assert np.isfinite(res.correlations).all() and np.isnan(res.p_value).all()


@pytest.mark.parametrize("n", [12, 15, 23])
def test_the_rows_needed_are_stated_from_the_variables_not_from_the_ranks_the_rows_allow(n):
    """20 BRDF variables and 3 experimental ones need 24 rows, whatever the rows at hand; the hint took the
    variables' count after whitening (rank <= n - 1) and asked for 15 rows of 12, then 18 of 15 (a walkthrough
    of a 10-region MERL import).  24 rows are accepted and 23 are not: the need stated is the need."""
    rng = np.random.default_rng(n)
    X, Y = rng.standard_normal((n, 20)), rng.standard_normal((n, 3))
    with pytest.raises(ValidationError, match=rf"{n} rows for 20 \+ 3 variables .*need at least 24 rows"):
        cca(X, Y)
    X, Y = rng.standard_normal((24, 20)), rng.standard_normal((24, 3))
    assert cca(X, Y).correlations.size == 3
    # a constant variable carries nothing at any number of rows: 19 + 3 + 1 rows suffice
    X[:, 4] = 0.7
    assert cca(X[:23], Y[:23]).correlations.size == 3
    with pytest.raises(ValidationError, match=r"22 rows for 19 \+ 3 variables .*need at least 23 rows"):
        cca(X[:22], Y[:22])


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"rcond": np.nan}, "rcond must be finite"),  # gave an empty set of correlations
        ({"rcond": 2.0}, r"rcond must lie in \[0, 1\)"),
        ({"rcond": -1e-3}, r"rcond must lie in \[0, 1\)"),
        ({"regularization": (0.1, 0.2, 0.3)}, r"regularization must be one value or \(value for X"),  # numpy error
        ({"n_permutations": 2.5}, "n_permutations must be an integer, got 2.5"),  # numpy TypeError
    ],
)
def test_bad_settings_are_named(kw, match):
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(40, 3)), rng.normal(size=(40, 2))
    with pytest.raises(ValidationError, match=match):
        cca(x, y, **kw)


def test_correlations_do_not_depend_on_the_units_of_a_variable(rng):
    """Each variable is scaled by its largest magnitude first: `rcond` compared eigenvalues across variables, so a
    variable in metres beside one in millimetres was dropped as collinear, and values near 1e±160 gave an IndexError
    (a red team)."""
    z = rng.standard_normal(200)
    x = np.c_[z + 0.5 * rng.standard_normal(200), rng.standard_normal(200)]
    y = np.c_[z + 0.5 * rng.standard_normal(200), rng.standard_normal(200)]
    ref = cca(x, y)
    for sx, sy in (((1e-6, 1.0), (1.0, 1.0)), ((1e-160, 1e-160), (1.0, 1.0)), ((1e155, 3.0), (1e-150, 1.0))):
        res = cca(x * np.array(sx), y * np.array(sy))
        np.testing.assert_allclose(res.correlations, ref.correlations, rtol=1e-9)
        np.testing.assert_allclose(res.direct_correlations, ref.direct_correlations, rtol=1e-9)
        np.testing.assert_allclose(res.x_weights * np.array(sx)[:, None], ref.x_weights, rtol=1e-9)  # own units
        np.testing.assert_allclose(res.projections, ref.projections, rtol=1e-9, atol=1e-12)
    with pytest.raises(ValidationError, match="Y must hold at least one variable"):
        cca(x, np.zeros((200, 0)))
    with pytest.raises(ValidationError, match="variables must name one or more"):
        brdf_cca(make_population(n=12, seed=4), variables=())


@pytest.mark.parametrize("value", [0.1, 0.25, 7.3, -1e-3])
def test_a_constant_variable_is_dropped_whatever_its_value(rng, value):
    """Centring 0.1 left a residual of -4e-17 that the unit scaling made a column of -1: a fourth variable in the
    degrees of freedom and p-values (6 -> 8), while 0.25 (an exact mean) was dropped (a red team)."""
    x = rng.standard_normal((40, 3))
    y = rng.standard_normal((40, 2)) + 0.5 * x[:, :2]
    base, with_constant = cca(x, y), cca(np.c_[x, np.full(40, value)], y)
    np.testing.assert_allclose(with_constant.correlations, base.correlations, rtol=1e-12)
    assert with_constant.df.tolist() == base.df.tolist() == [6, 2]
    np.testing.assert_allclose(with_constant.p_value, base.p_value, rtol=1e-9)
    np.testing.assert_allclose(with_constant.direct_p_value, base.direct_p_value, rtol=1e-9)
