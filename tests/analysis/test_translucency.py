"""Translucency statistics (Weyrich Table 1, §5.4) and absorption against scattering (Fig. 14)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from facestats.analysis import absorption_scattering, translucency_table
from facestats.core import published
from facestats.core.conventions import CHANNELS, SITES
from facestats.errors import ValidationError
from facestats.model import dipole
from tests.helpers import make_population


@pytest.fixture(scope="module")
def store():
    return make_population(n=30, seed=5)


def _site_values(store, site):
    """σtr of one site from the subject Datasets themselves (not the index), normal subjects only."""
    idx = store.subjects()
    ids = idx.index[idx["condition"] == "normal"]
    return ids, np.array([store.subject(s)["site_sigma_tr"].sel(site=site).values for s in ids])


def test_table_against_datasets(store):
    t = translucency_table(store)
    for site in SITES:
        _, vals = _site_values(store, site)
        np.testing.assert_allclose(t.mean(site), vals.mean(0), rtol=1e-12)
        np.testing.assert_allclose(t.var(site), vals.var(0, ddof=1), rtol=1e-10)
        np.testing.assert_allclose(t.table[(site, "std")], vals.std(0, ddof=1), rtol=1e-10)
        assert (t.table[(site, "n")] == len(vals)).all()
    assert translucency_table(store, ddof=0).var("neck") == pytest.approx(
        _site_values(store, "neck")[1].var(0), rel=1e-10
    )


def test_to_frame_is_table_1_one_row_per_site_and_channel(store):
    """Only RegionPCA had ``to_frame()`` (a walkthrough): Table 1 as a DataFrame, the rows of ``to_dict()["table"]``,
    its numbers those of the subjects' own site σtr."""
    t = translucency_table(store)
    frame = t.to_frame()
    assert frame.index.names == ["site", "channel"] and list(frame.index) == [(s, c) for s in SITES for c in CHANNELS]
    assert (
        list(frame.columns) == ["mean", "paper_mean", "var", "std", "paper_var", "n"] and frame["n"].dtype.kind == "i"
    )
    assert frame.reset_index().to_dict(orient="records") == t.to_dict()["table"]
    for site in SITES:
        _, vals = _site_values(store, site)
        np.testing.assert_allclose(frame.loc[site, "mean"], vals.mean(0), rtol=1e-12)
        np.testing.assert_allclose(frame.loc[site, "var"], vals.var(0, ddof=1), rtol=1e-10)
        np.testing.assert_allclose(frame.loc[site, "paper_mean"], published.TABLE1_MEAN[site])
        assert (frame.loc[site, "n"] == len(vals)).all()


def test_sigma_tr_avg_and_ell_d_extremes(store):
    t = translucency_table(store)
    ids, cheek = _site_values(store, "cheek")
    _, forehead = _site_values(store, "forehead")
    per_subject = (cheek + forehead) / 2
    np.testing.assert_allclose(t.sigma_tr_avg, per_subject.mean(0), rtol=1e-12)
    # with complete data σtrAvg is the mean of the cheek and forehead columns, as in the paper
    np.testing.assert_allclose(t.sigma_tr_avg, (t.mean("cheek") + t.mean("forehead")) / 2, rtol=1e-12)
    ell = 1 / per_subject
    lo, hi = np.argmin(ell.mean(1)), np.argmax(ell.mean(1))
    assert (t.min_subject, t.max_subject) == (ids[lo], ids[hi])
    np.testing.assert_allclose(t.ell_d_min, ell[lo], rtol=1e-12)
    np.testing.assert_allclose(t.ell_d_max, ell[hi], rtol=1e-12)
    red = translucency_table(store, rank_by="R")
    assert red.max_subject == ids[np.argmax(ell[:, 0])]
    # ℓd is the reciprocal of σtr (eq. 15) for every subject
    np.testing.assert_allclose(t.subjects["ell_d_G"], dipole.diffuse_mean_free_path(t.subjects["sigma_tr_G"]))


def test_published_table_reproduced_from_its_own_numbers():
    """A population whose cheek/forehead/neck σtr have exactly the Table 1 means gives Table 1 and σtrAvg."""
    rng = np.random.default_rng(0)
    devs = {site: 0.05 * rng.standard_normal((20, 3)) for site in SITES}
    rows = []
    for i in range(40):  # subjects 20-39 mirror 0-19, so the means are exact
        row = {"subject_id": f"T{i}", "age": 30, "gender": "M", "skin_type": 3, "condition": "normal"}
        for site in SITES:
            dev = devs[site][i % 20] * (1 if i < 20 else -1)
            for c, ch in enumerate(CHANNELS):
                row[f"site_sigma_tr_{site}_{ch}"] = published.TABLE1_MEAN[site][c] + dev[c]
        rows.append(row)
    frame = pd.DataFrame(rows).set_index("subject_id")
    t = translucency_table(frame)
    for site in SITES:
        np.testing.assert_allclose(t.mean(site), published.TABLE1_MEAN[site], atol=1e-12)
    np.testing.assert_allclose(t.sigma_tr_avg, published.SIGMA_TR_AVG, atol=6e-5)  # the paper rounds to 4 digits
    cmp = t.compare_published()
    assert cmp.shape[0] == 9
    np.testing.assert_allclose(cmp["mean"], cmp["paper_mean"], atol=1e-12)
    np.testing.assert_allclose(cmp["var"], cmp["std"] ** 2)


def test_missing_sites_and_errors(store):
    frame = store.subjects()
    frame.loc["S003", [f"site_sigma_tr_forehead_{ch}" for ch in CHANNELS]] = np.nan
    frame.loc["S004", [f"site_sigma_tr_{s}_{ch}" for s in ("cheek", "forehead") for ch in CHANNELS]] = np.nan
    t = translucency_table(frame)
    assert t.table.loc["R", ("forehead", "n")] == t.table.loc["R", ("cheek", "n")] - 1
    assert "S004" not in t.subjects.index  # no cheek or forehead: no ℓd
    assert t.subjects.loc["S003", "sigma_tr_R"] == pytest.approx(frame.loc["S003", "site_sigma_tr_cheek_R"])
    with pytest.raises(ValidationError, match="rank_by"):
        translucency_table(store, rank_by="mean of all")
    empty = frame.copy()
    empty[[c for c in frame.columns if c.startswith("site_sigma_tr_")]] = np.nan
    with pytest.raises(ValidationError, match="cheek or forehead"):
        translucency_table(empty)


def test_mean_and_var_of_an_unknown_site_are_refused_naming_the_sites(store):
    t = translucency_table(store)
    for method in (t.mean, t.var):
        with pytest.raises(ValidationError, match=r"site must be one of \['cheek', 'forehead', 'neck'\], got 'nose'"):
            method("nose")  # was pandas' KeyError: ('nose', 'mean')


def test_absorption_scattering_fig14(store):
    res = absorption_scattering(store)
    idx = store.subjects()
    normal = idx[idx["condition"] == "normal"]
    assert len(res.data) == 3 * len(normal)
    g = res.data[res.data["channel"] == "G"].set_index("subject_id")
    np.testing.assert_allclose(g.loc[normal.index, "sigma_a"], normal["sigma_a_G"])
    np.testing.assert_allclose(g.loc[normal.index, "sigma_s_prime"], normal["sigma_s_prime_G"])
    # with one σtr for everybody, σ's rises and σa falls with the albedo: a perfect inverse rank order
    corr = res.correlations()
    np.testing.assert_allclose(corr["spearman"], -1.0)
    assert (corr["pearson_log"] < -0.95).all()
    # the factories darken albedo with skin type: higher types absorb more (Weyrich Fig. 14)
    by_type = res.by_skin_type()
    red = by_type.xs("R", level="channel")[("sigma_a", "mean")]
    assert red.loc[6] > red.loc[2]
    assert res.to_text().splitlines()[-1] == (
        "sigma_a falls as sigma_s_prime rises in every channel (negative correlations), as in the paper; "
        "darker skin types absorb more and scatter less, as in the paper"
    )
    # the conclusion follows the numbers: one subject has no correlation; reversed ranks contradict the paper
    one = type(res)(data=res.data[res.data["subject_id"] == res.data["subject_id"].iloc[0]], site=None)
    assert one.to_text().splitlines()[-1].startswith("correlations undefined (fewer than 3 subjects")
    flipped = res.data.assign(sigma_a=1.0 / res.data["sigma_a"], skin_type=7 - res.data["skin_type"])
    assert type(res)(data=flipped, site=None).to_text().splitlines()[-1] == (
        "unlike the paper, sigma_a does not fall as sigma_s_prime rises in channel(s) R, G, B; "
        "darker skin types do not both absorb more and scatter less in every channel, unlike the paper"
    )
    site = absorption_scattering(store, site="cheek")
    assert site.site == "cheek"
    np.testing.assert_allclose(
        site.data.query("channel == 'B'")["sigma_a"].to_numpy(), normal["site_sigma_a_cheek_B"].to_numpy()
    )
    with pytest.raises(ValidationError, match="site"):
        absorption_scattering(store, site="elbow")


def test_a_ddof_beyond_the_subjects_is_refused_not_a_nan_variance(store):
    n = int(translucency_table(store).table.loc["R", ("cheek", "n")])
    assert np.isfinite(translucency_table(store, ddof=n - 1).table.loc["R", ("cheek", "var")])
    with pytest.raises(ValidationError, match=rf"ddof must be less than the number of subjects .*\({n}\), got {n}"):
        translucency_table(store, ddof=n)
    with pytest.raises(ValidationError, match="ddof must be an integer"):
        translucency_table(store, ddof=-1)
