"""The embedded default store: what ships, and that `facestats build --default` regenerates it."""

import json
import os

import numpy as np
import pytest

import facestats
from facestats.core import published
from facestats.io.schema import SCHEMA_VERSION
from facestats.io.store import default_store_path
from facestats.pipeline.build import DEFAULT_MAP_SIZE, DEFAULT_SEED, build_store


@pytest.fixture(scope="module")
def shipped():
    return facestats.open_store()


def test_shipped_default_is_small_complete_and_current(shipped):
    assert default_store_path().stat().st_size <= 20e6
    info = shipped.info()
    assert info["schema_version"] == SCHEMA_VERSION
    table = shipped.subjects()
    assert len(table) == published.N_SUBJECTS + 6  # the 149 and S008 under the six other conditions of §7
    normal = table[table.condition == "normal"]
    counts = normal.groupby(["skin_type", "gender"]).size()  # the normal-condition sample is Table 2's
    for st, (men, women) in published.TABLE2_COUNTS.items():
        types = [1, 2] if st == 2 else [st]
        assert int(counts.loc[types, "M"].sum()) == men and int(counts.loc[types, "F"].sum()) == women
    # The maps hold the fitted model: no flagged texel left unfilled, finite everywhere on the face.
    ds = shipped.subject("S001")
    face = ds.region.values > 0
    for var in ("albedo", "ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent"):
        assert np.all(np.isfinite(ds[var].values[face]))
    prov = json.loads(ds.attrs["provenance"])
    assert prov["source"] == "facestats simulator" and prov["fit_settings"]["micro_normals"] is False


def _compare(a, b):
    assert a.attrs["subject_id"] == b.attrs["subject_id"]
    for key in ("age", "gender", "skin_type", "condition", "person_id"):
        assert a.attrs[key] == b.attrs[key], key
    pa, pb = json.loads(a.attrs["provenance"]), json.loads(b.attrs["provenance"])
    assert pa == pb
    assert set(a.data_vars) == set(b.data_vars)
    face = a.region.values > 0
    for var in a.data_vars:
        x, y = np.asarray(a[var].values), np.asarray(b[var].values)
        if x.dtype.kind in "iub":
            np.testing.assert_array_equal(x, y, err_msg=var)
        elif var.startswith("bp_"):
            # Blinn-Phong on Torrance-Sparrow captures has flat minima in a few texels, where
            # last-bit differences of float32 sums (CPU-dependent SIMD) move the optimum slightly.
            rel = np.abs(x[face] - y[face]) / np.maximum(np.abs(y[face]), 1e-12)
            assert np.median(rel) < 1e-5 and np.percentile(rel, 99) < 0.02, var
        else:
            np.testing.assert_allclose(x, y, rtol=2e-4, atol=1e-9, err_msg=var)


def _cross_section(table):
    """Ids of a cross-section of the default store: the first subject of every skin type × gender, the youngest
    and the oldest, and the condition series (S008 under the six other conditions)."""
    normal = table[table.condition == "normal"]
    ids = set(normal.groupby(["skin_type", "gender"]).head(1).index)
    series = table.condition != "normal"
    ids |= {normal.age.idxmin(), normal.age.idxmax()} | set(table.index[series]) | set(table.person_id[series])
    return sorted(ids)


@pytest.mark.slow
def test_regeneration_equals_what_ships(tmp_path, shipped):
    """`facestats build --default` = build_store(seed, size, no micro-normals, no derived maps) + pack, on a
    cross-section of the store (20 of its 155 records): every record goes through the same code, and the
    population-level inputs (σtrAvg, the draws) come from the whole drawn population whatever is written, so a
    change of the fit shows in each. Rebuilding all 155 took 97-123 s of the suite's 10 minutes on 2 cores;
    ``facestats build --default`` rebuilds the whole store in about 50 s."""
    ids = _cross_section(shipped.subjects())
    assert len(ids) == 20 and {"S008", "S008-lotion"} <= set(ids)
    report = build_store(
        tmp_path / "regen.zarr",
        seed=DEFAULT_SEED,
        map_size=DEFAULT_MAP_SIZE,
        micro_normals=False,
        keep_derived=False,
        workers=min(2, os.cpu_count() or 1),
        subjects=ids,
    )
    assert sorted(report.written) == ids
    regen = facestats.open_store(tmp_path / "regen.zarr")
    for sid in ids:
        _compare(regen.subject(sid), shipped.subject(sid))
    # The index (what `facestats query` answers from) agrees too.
    a, b = regen.subjects().sort_index(), shipped.subjects().loc[ids].sort_index()
    num = [c for c in a.columns if a[c].dtype.kind == "f" and not c.startswith(("bp_", "n_bp"))]
    np.testing.assert_allclose(a[num].to_numpy(), b[num].to_numpy(), rtol=1e-3, atol=1e-9, equal_nan=True)
