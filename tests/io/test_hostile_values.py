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
