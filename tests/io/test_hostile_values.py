"""Stored values of the wrong kind: refused when written, or written as valid JSON (red-team review, 2026-12-05)."""

import json

import numpy as np
import pytest

import facestats
from facestats.core.outputs import json_ready
from facestats.errors import SchemaError
from facestats.io.exr_set import write_exr_set


@pytest.fixture(scope="module")
def subject():
    with facestats.open_store() as store:
        return store.subject("S001").load()


def test_maps_that_are_not_numbers_are_refused_by_the_schema(subject, tmp_path):
    store = facestats.open_store(tmp_path / "x.zarr", mode="a")
    for bad, dtype in (((subject["ts_m_std"] - 5).astype(str), "<U"), (subject["ts_m_std"] * (1 + 0j), "complex")):
        ds = subject.copy()
        ds["ts_m_std"] = bad
        with pytest.raises(SchemaError, match=f"'ts_m_std' must be numeric .*got dtype {dtype}"):
            store.write_subject(ds)
    assert store.ids() == []


def test_non_finite_attributes_are_written_as_json_null(subject, tmp_path):
    ds = subject.copy()
    ds.attrs.update(weight=float("nan"), gain=float("inf"))
    manifest = write_exr_set(ds, tmp_path)
    text = (tmp_path / "manifest.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert manifest["subject"]["weight"] is None and json.loads(text)["subject"]["gain"] is None
    ready = json_ready({"a": [np.float32(np.nan), (1.5, -np.inf)], "b": np.int64(3)})
    assert ready == {"a": [None, [1.5, None]], "b": 3}


def test_standard_errors_of_huge_or_partial_maps(subject):
    from facestats.io.summary import summarise_subject

    base = summarise_subject(subject)
    ds = subject.copy()
    ds["ts_m_std"] = ds["ts_m_std"].astype(np.float64).where(ds["region"] == 0, 1e200)  # its square overflows
    ds["ts_m"] = ds["ts_m"].astype(np.float64).where(ds["region"] == 0, 2e200)  # determined: σ <= |value|
    row = summarise_subject(ds)
    assert row["ts_m_se_r2"] == pytest.approx(1e200) and row["ts_m_mean_se_r2"] > 0
    partial = subject.drop_vars("ts_m_std")  # each standard-error map is optional on its own
    row = summarise_subject(partial)
    assert row["ts_rho_s_se_r2"] == base["ts_rho_s_se_r2"] and np.isnan(row["ts_m_se_r2"])


def test_undetermined_texels_are_left_out_of_the_standard_errors(subject):
    """A texel whose standard error exceeds its value says only that the value is open: it must not outweigh the
    region's determined texels (one with σ = 1e4 × m made the region's RMS 1e2 times larger before)."""
    from facestats.io.summary import summarise_subject

    sel = (subject["region"].values == 2) & (subject["ts_flag"].values == 0)
    m, sd = subject["ts_m"].values[sel].astype(np.float64), subject["ts_m_std"].values[sel].astype(np.float64)
    assert sel.sum() > 10 and np.all(sd <= np.abs(m))  # all determined to start with
    ds = subject.copy(deep=True)
    v, u = np.argwhere(sel)[0]
    ds["ts_m_std"].values[v, u] = 1e4 * abs(float(ds["ts_m"].values[v, u]))
    row = summarise_subject(ds)
    keep = np.ones(sd.size, bool)
    keep[0] = False  # the texel made undetermined (argwhere and boolean indexing share the row-major order)
    assert row["ts_m_se_r2"] == pytest.approx(np.sqrt(np.mean(sd[keep] ** 2)), rel=1e-9)
    assert row["ts_m_mean_se_r2"] == pytest.approx(np.sqrt(np.sum(sd[keep] ** 2)) / keep.sum(), rel=1e-9)


def test_undetermined_texels_are_counted_per_region(subject):
    """The index's ``_se`` columns leave out the texels the fit does not determine, its ``_mean`` and ``_std`` keep
    them, and nothing in the row said how many (a walkthrough: 6 % of S013's nose): region_undetermined counts them
    over the row's own texels."""
    from facestats.io.summary import determined, region_undetermined, summarise_subject

    sel = (subject["region"].values == 2) & (subject["ts_flag"].values == 0)
    rho, sd_rho = (subject[n].values[sel].astype(np.float64) for n in ("ts_rho_s", "ts_rho_s_std"))
    base = region_undetermined(subject)
    assert base[2] == {"n": int(sel.sum()), "ts_rho_s": int((sd_rho > np.abs(rho)).sum()), "ts_m": 0}
    ds = subject.copy(deep=True)
    v, u = np.argwhere(sel)[:3].T
    ds["ts_m_std"].values[v[0], u[0]] = 1e4 * abs(float(ds["ts_m"].values[v[0], u[0]]))  # open
    ds["ts_m_std"].values[v[1], u[1]] = np.nan  # no error at all: not determined either
    ds["ts_m_std"].values[v[2], u[2]] = abs(float(ds["ts_m"].values[v[2], u[2]]))  # σ = |m|: still determined
    got = region_undetermined(ds)
    assert got[2]["ts_m"] == 2 and got[2]["n"] == base[2]["n"] == summarise_subject(ds)["n_ts_r2"]
    assert {r: c for r, c in got.items() if r != 2} == {r: c for r, c in base.items() if r != 2}
    np.testing.assert_array_equal(determined([0.1, 0.2, np.inf, np.nan, 0.3], [0.2, -0.2, 1, 1, 0.29]),
                                  [True, True, False, False, False])  # fmt: skip
    bp = (subject["region"].values == 2) & (subject["bp_flag"].values == 0)
    assert region_undetermined(subject, "bp")[2]["n"] == int(bp.sum())
    assert region_undetermined(subject.drop_vars(["ts_rho_s_std", "ts_m_std"])) is None


def test_store_subjects_documents_its_three_kinds_of_std():
    """help(store.subjects) did not say that ``_std_r`` is a spread, ``_se_r`` the RMS of the ``*_std`` maps over
    determined texels only (a walkthrough): it says so now, with the numbers of the shipped store's S013 nose."""
    from facestats.io.summary import region_undetermined

    doc = facestats.io.Store.subjects.__doc__
    for phrase in ("spread of the values", "standard error of one texel", "determines", "region_undetermined",
                   "standard error of the region mean"):  # fmt: skip
        assert phrase in doc, phrase
    with facestats.open_store() as store:
        row, ds = store.subjects().loc["S013"], store.subject("S013")
    nose = (ds["region"].values == 6) & (ds["ts_flag"].values == 0)
    sd = ds["ts_rho_s_std"].values[nose].astype(np.float64)
    whole = float(np.sqrt(np.mean(sd**2)))
    assert f"{whole:.2f} over all {int(nose.sum())} texels, {row['ts_rho_s_se_r6']:.3f} here" in doc
    assert region_undetermined(ds)[6]["ts_rho_s"] == 3 and f"the three it leaves out up to {sd.max():.1f}" in doc
