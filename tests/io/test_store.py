"""The parameter store: round trips, index, queries, integrity checks, zip stores, gc."""

import csv
import io
import json
import os
import pathlib
import re
import zipfile

import numpy as np
import pandas as pd
import pytest

import facestats
from facestats.analysis.population import region_samples as store_region_samples
from facestats.core.conventions import CHANNELS, REGIONS, SITES
from facestats.errors import SchemaError, StoreError, ValidationError
from facestats.io import QueryResult, open_store, pack_store
from facestats.io import store as store_mod
from facestats.io.schema import SCHEMA_VERSION, provenance, set_provenance, validate_subject
from facestats.io.summary import albedo_histogram, region_samples, summarise_subject
from tests.helpers import make_map_subject, make_sample_subject, with_micro_normals

# A small population: (id, skin type, gender, age, condition).
POP = [
    ("A01", 1, "M", 23, "normal"),
    ("A02", 2, "F", 27, "normal"),
    ("A03", 3, "M", 31, "normal"),
    ("A04", 3, "M", 45, "normal"),
    ("A05", 3, "F", 52, "normal"),
    ("A06", 4, "M", 24, "normal"),
    ("A07", 4, "M", 38, "normal"),
    ("A08", 4, "F", 29, "normal"),
    ("A09", 5, "M", 41, "normal"),
    ("A10", 6, "F", 60, "normal"),
    ("A11", 4, "M", 24, "lotion"),
]


def population():
    out = [
        make_map_subject(
            sid,
            skin_type=t,
            gender=g,
            age=a,
            condition=c,
            seed=k,
            rho_shift=0.01 * k,
            person_id="A06" if sid == "A11" else None,
        )
        for k, (sid, t, g, a, c) in enumerate(POP)
    ]
    out.append(make_sample_subject("M001", skin_type=4, gender="F", age=33, seed=3))
    return out


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    path = tmp_path_factory.mktemp("store") / "pop.zarr"
    subjects = population()
    with open_store(path, mode="a") as st:
        st.write_subjects(subjects)
    return path, {ds.attrs["subject_id"]: ds for ds in subjects}


def _copy_store(src, dst):
    import shutil

    shutil.copytree(src, dst)
    return dst


def _nan_equal(a, b):
    if isinstance(a, float) and isinstance(b, float):
        return (np.isnan(a) and np.isnan(b)) or a == b
    return a == b


# -- round trips -----------------------------------------------------------------------
def test_map_subject_round_trip_values_attrs_units_and_chunks(tmp_path):
    ds = make_map_subject("R1", size=80, seed=5)
    with open_store(tmp_path / "s.zarr", mode="a") as st:
        assert st.write_subject(ds) == "R1"
        back = st.subject("R1")
    assert set(back.variables) == set(ds.variables)
    for name in ds.variables:
        assert back[name].dtype == ds[name].dtype, name
        assert back[name].dims == ds[name].dims, name
        np.testing.assert_array_equal(back[name].values, ds[name].values, err_msg=name)
        assert back[name].attrs == ds[name].attrs, name
    assert back["site_sigma_a"].attrs["units"] == "mm-1"
    assert back["sensor_profile"].attrs["units"] == "mm-2"
    assert list(back["channel"].values) == list(CHANNELS)
    for key in ("subject_id", "person_id", "age", "gender", "skin_type", "condition"):
        assert back.attrs[key] == ds.attrs[key]
    assert provenance(back) == dict(provenance(ds), software_version=facestats.__version__)
    assert store_mod.STORE_ATTR not in back.attrs
    assert back.encoding[store_mod.STORE_ATTR]["schema"] == SCHEMA_VERSION
    assert back.sel(channel="G")["albedo"].shape == (80, 80)
    # maps are chunked in 64-row bands of v
    meta = json.loads(
        (tmp_path / "s.zarr" / "subjects" / "R1").glob("g*").__next__().joinpath("albedo", "zarr.json").read_text()
    )
    assert meta["chunk_grid"]["configuration"]["chunk_shape"] == [64, 80, 3]
    assert meta["dimension_names"] == ["v", "u", "channel"]
    root = json.loads((tmp_path / "s.zarr" / "zarr.json").read_text())["attributes"]
    assert root["facestats_schema"] == SCHEMA_VERSION and root["facestats_version"] == facestats.__version__


def test_the_written_dataset_is_not_modified(tmp_path):
    ds = make_map_subject("R2")
    before = dict(ds.attrs)
    with open_store(tmp_path / "s.zarr", mode="a") as st:
        st.write_subject(ds)
    assert ds.attrs == before and ds["channel"].dtype.kind == "U"


def test_sample_subjects_round_trip_including_empty_ones(tmp_path):
    ds = make_sample_subject("M1", seed=4)
    empty = make_sample_subject("M2").isel(sample=slice(0, 0), albedo_sample=slice(0, 0))
    with open_store(tmp_path / "s.zarr", mode="a") as st:
        st.write_subjects([ds, empty])
        back, back_empty = st.subject("M1"), st.subject("M2")
        df = st.subjects()
    for name in ds.variables:
        np.testing.assert_array_equal(back[name].values, ds[name].values)
    assert back_empty.sizes["sample"] == 0 and back_empty.sizes["albedo_sample"] == 0
    assert df.loc["M2", "n_ts_r3"] == 0 and np.isnan(df.loc["M2", "ts_m_mean_r3"])
    assert df.loc["M1", "kind"] == "samples"


def test_lazy_read_of_one_band_reads_only_its_chunks(tmp_path):
    ds = make_map_subject("L1", size=128, seed=2)
    path = tmp_path / "s.zarr"
    with open_store(path, mode="a") as st:
        st.write_subject(ds)
    gen = next((path / "subjects" / "L1").glob("g*"))
    (gen / "ts_m" / "c" / "1" / "0").unlink()  # the second band of rows (v = 64..127)
    with open_store(path) as st:
        lazy = st.subject("L1", lazy=True)
        np.testing.assert_array_equal(lazy["ts_m"].isel(v=slice(0, 64)).values, ds["ts_m"].values[:64])
        with pytest.raises(SchemaError, match="'L1'.*'ts_m'.*checksum"):
            st.subject("L1")


def test_micro_normals_are_chunked_per_camera_and_verified_per_band(tmp_path):
    """A Zarr chunk of a micro-normal map holds one camera's band of 64 rows (facestats.io.generations.map_chunks:
    zarr-python decodes ~10 chunks at once, and 25 MB chunks of all 16 cameras held ~480 MB beside a 2048² subject);
    the manifest's checksums stay those of whole bands across cameras, and of the whole variable in C order, computed
    band by band (io.integrity.manifest_entry)."""
    from facestats.io.integrity import digest

    ds = with_micro_normals(make_map_subject("MN1", size=70, seed=3), cameras=3)
    path = tmp_path / "s.zarr"
    with open_store(path, mode="a") as st:
        st.write_subject(ds)
    gen = next((path / "subjects" / "MN1").glob("g*"))
    meta = json.loads((gen / "micro_normal" / "zarr.json").read_text())
    assert meta["chunk_grid"]["configuration"]["chunk_shape"] == [1, 64, 70, 3]
    manifest = json.loads(json.loads((gen / "zarr.json").read_text())["attributes"][store_mod.STORE_ATTR])["manifest"]
    want = ds["micro_normal"].values
    entry = manifest["micro_normal"]
    assert entry["crc32"] == digest(want)[1] and entry["chunk_rows"] == 64
    assert entry["chunk_crc32"] == [digest(want[:, :64])[1], digest(want[:, 64:])[1]]
    (gen / "micro_normal" / "c" / "2" / "1" / "0" / "0").unlink()  # camera 2, rows 64..69
    with open_store(path) as st:
        lazy = st.subject("MN1", lazy=True)
        np.testing.assert_array_equal(lazy["micro_normal"].isel(v=slice(0, 64)).values, want[:, :64])
        with pytest.raises(SchemaError, match=r"'MN1'.*'micro_normal'.*checksum, chunk\(s\) \[1\]"):
            lazy["micro_normal"].isel(v=slice(60, 70)).values
        with pytest.raises(SchemaError, match="'MN1'.*'micro_normal'.*checksum"):
            st.subject("MN1")


def test_dask_backed_variables_are_written_in_this_thread_and_a_failed_write_leaves_nothing(tmp_path):
    """Store.write_subjects computes dask arrays one task at a time in the calling thread whatever scheduler is the
    default (a thread pool held a band per thread and, after a failure, kept writing chunks into the abandoned
    generation: a red team's stray folders); a failure in a band leaves no generation, record or index entry."""
    import threading

    import dask
    import dask.array as da

    ds = with_micro_normals(make_map_subject("MN3", size=150, seed=5), cameras=2)
    want = ds["micro_normal"].values
    threads = set()

    def band(block, block_info=None):
        threads.add(threading.get_ident())
        if fail and block_info[0]["chunk-location"][1] == 1:  # the second band of rows
            raise OSError("disk gone")
        return block

    lazy = da.from_array(want, chunks=(2, 64, 150, 3)).map_blocks(band, dtype=want.dtype)
    path = tmp_path / "s.zarr"
    with open_store(path, mode="a") as st, dask.config.set(scheduler="threads"):
        fail = True
        with pytest.raises(OSError, match="disk gone"):
            st.write_subject(ds.assign(micro_normal=(ds["micro_normal"].dims, lazy)))
        assert "MN3" not in st.subjects()
        assert not list((path / "subjects").glob("MN3/g*")) and not list((path / ".records").glob("MN3~*"))
        fail = False
        st.write_subject(ds.assign(micro_normal=(ds["micro_normal"].dims, lazy)))
        assert threads == {threading.get_ident()}
        np.testing.assert_array_equal(st.subject("MN3")["micro_normal"].values, want)
        assert dask.config.get("scheduler") == "threads"  # the caller's choice is back


def test_two_threads_writing_lazy_subjects_at_once_each_compute_in_their_own_thread(tmp_path):
    """dask.config.set is process-wide: the first of two concurrent writers to finish restored the thread pool under
    the other, and the last left "synchronous" for good (a red team).  The setting is now shared: each writer's bands
    run in its own thread and the caller's configuration is back afterwards."""
    import threading
    import time

    import dask
    import dask.array as da

    seen = {}

    def lazy_subject(sid, delay):
        ds = with_micro_normals(make_map_subject(sid, size=150, seed=5), cameras=2)
        want = ds["micro_normal"].values

        def band(block):
            seen.setdefault(sid, set()).add(threading.current_thread().name)
            time.sleep(delay)
            return block

        meta = np.empty((0,) * 4, want.dtype)  # given: map_blocks would call band here to infer it
        lazy = da.from_array(want, chunks=(2, 64, 150, 3)).map_blocks(band, dtype=want.dtype, meta=meta)
        return ds.assign(micro_normal=(ds["micro_normal"].dims, lazy)), want

    path = tmp_path / "s.zarr"
    open_store(path, mode="a").close()
    (a, want_a), (b, want_b) = lazy_subject("SA", 0.01), lazy_subject("SB", 0.1)

    def write(ds):
        with open_store(path, mode="r+") as st:
            st.write_subject(ds)

    with dask.config.set(scheduler="threads"):
        threads = [threading.Thread(target=write, args=(ds,), name=f"writer-{ds.attrs['subject_id']}") for ds in (a, b)]
        threads[0].start()
        time.sleep(0.05)  # A starts first and finishes first, while B still writes
        threads[1].start()
        for t in threads:
            t.join()
        assert dask.config.get("scheduler") == "threads"
    assert seen == {"SA": {"writer-SA"}, "SB": {"writer-SB"}}
    with open_store(path) as st:
        np.testing.assert_array_equal(st.subject("SA")["micro_normal"].values, want_a)
        np.testing.assert_array_equal(st.subject("SB")["micro_normal"].values, want_b)


def test_a_lazy_read_of_a_whole_variable_makes_no_copy_of_it(tmp_path):
    """A lazily read variable read whole (``.values``) is the verified band itself, not a copy of it (np.take made
    one: 1.6 GB peak for a 2048² 16-camera micro-normal map of 805 MB); strided and reversed reads stay right."""
    import tracemalloc

    ds = with_micro_normals(make_map_subject("MN2", size=160, seed=4), cameras=8)
    with open_store(tmp_path / "s.zarr", mode="a") as st:
        st.write_subject(ds)
        lazy = st.subject("MN2", lazy=True)
        want = ds["micro_normal"].values
        tracemalloc.start()
        try:
            got = lazy["micro_normal"].values
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        np.testing.assert_array_equal(got, want)
        assert peak < 2 * want.nbytes, (peak, want.nbytes)  # the band and its copy: at least 2x
        np.testing.assert_array_equal(lazy["micro_normal"].isel(v=slice(3, 150, 7)).values, want[:, 3:150:7])
        np.testing.assert_array_equal(lazy["micro_normal"].isel(v=slice(150, 3, -5)).values, want[:, 150:3:-5])
        np.testing.assert_array_equal(lazy["albedo"].isel(v=100).values, ds["albedo"].values[100])


def test_manifest_of_a_variable_read_band_by_band_equals_that_of_the_whole_array():
    """manifest_entry reads maps one band of rows at a time and joins one running CRC per index of the dims before
    ``v`` (facestats.core.crc32): the same entry as the whole array's digest, for any dims order, byte order, a
    last partial band and empty dims."""
    import xarray as xr

    from facestats.io.integrity import _band, digest, manifest_entry

    rng = np.random.default_rng(0)
    cases = [
        ((5, 130, 7, 3), ("camera", "v", "u", "component"), "<f4"),
        ((130, 7, 3), ("v", "u", "channel"), ">f4"),
        ((2, 3, 70, 4), ("a", "b", "v", "u"), "<f8"),
        ((70, 9), ("v", "u"), "?"),
        ((0, 5, 4), ("camera", "v", "u"), "u1"),
        ((3, 0, 4), ("camera", "v", "u"), "<i2"),
    ]
    for shape, dims, dtype in cases:
        a = (100 * rng.standard_normal(shape)).astype(dtype)
        entry = manifest_entry(xr.Variable(dims, a))
        axis = dims.index("v")
        assert entry["dtype"] == digest(a)[0] and entry["crc32"] == digest(a)[1], (shape, dtype)
        assert entry["chunk_crc32"] == [digest(_band(a, axis, lo, lo + 64))[1] for lo in range(0, shape[axis], 64)]
        assert entry["dims"] == list(dims) and entry["shape"] == list(shape)


def test_domain_errors_of_maps_checked_band_by_band_name_the_first_value_and_the_total_count(tmp_path):
    """Maps are validated one band of rows at a time (schema.face_bands): the message still gives the first value
    outside the domain in row-major texel order and the count over the whole face."""
    ds = with_micro_normals(make_map_subject("MN3", size=150, seed=6), cameras=2)
    face = np.argwhere(ds["region"].values > 0)
    (v1, u1), (v2, u2) = face[10], face[-10]  # in the first and the last band of 64 rows
    assert v1 < 64 <= 128 <= v2
    micro = ds["micro_normal"].values.copy()
    micro[1, v1, u1, 2], micro[0, v2, u2, 0], micro[0, v2, u2, 1] = 1.5, -3.0, 2.0
    bad = ds.assign(micro_normal=(ds["micro_normal"].dims, micro))
    with open_store(tmp_path / "s.zarr", mode="a") as st:
        with pytest.raises(SchemaError, match=r"'micro_normal' must lie in .*got 1.5 \(3 value\(s\) outside\)"):
            st.write_subject(bad)
        albedo = ds["albedo"].values.copy()
        albedo[v2, u2, 1] = np.nan
        with pytest.raises(SchemaError, match="'albedo' has 1 non-finite face texel"):
            st.write_subject(ds.assign(albedo=(ds["albedo"].dims, albedo)))
        assert st.ids() == []


# -- index ------------------------------------------------------------------------------
def test_index_rows_and_histograms_equal_the_summaries(built):
    path, subjects = built
    with open_store(path) as st:
        df = st.subjects()
        hists = st.albedo_histograms()
    assert list(df.index) == sorted(subjects)
    assert hists.shape == (len(subjects), 3, 256)
    for k, sid in enumerate(df.index):
        row = summarise_subject(subjects[sid])
        for key, val in row.items():
            if key == "subject_id":
                continue
            assert _nan_equal(df.loc[sid, key], val), (sid, key)
        np.testing.assert_array_equal(hists[k], albedo_histogram(subjects[sid]))
    assert df["age"].dtype == np.int64 and df["skin_type"].dtype == np.int64
    assert np.isfinite(df.loc["M001", "albedo_mean_R"])  # sample subjects have albedo samples


def test_region_samples_long_frame(built):
    path, subjects = built
    with open_store(path) as st:
        for model in ("ts", "bp"):
            df = store_region_samples(st, model, subjects=["A03", "M001"])
            assert list(df.columns) == ["subject_id", "region", "rho_s", "lobe"]
            for sid in ("A03", "M001"):
                truth = region_samples(subjects[sid], model)
                for r, (rho, lobe) in truth.items():
                    sel = df[(df.subject_id == sid) & (df.region == r)]
                    np.testing.assert_array_equal(sel.rho_s.values, rho)
                    np.testing.assert_array_equal(sel.lobe.values, lobe)
        everyone = store_region_samples(st)
        assert set(everyone.subject_id) == set(subjects)
        with pytest.raises(ValidationError, match="model"):
            store_region_samples(st, "phong")
        with pytest.raises(StoreError, match="no subject 'nope'"):
            store_region_samples(st, subjects=["nope"])


# -- queries ----------------------------------------------------------------------------
def _direct(subjects, ids):
    """Summary rows of the original Datasets (not the store) as a DataFrame."""
    return pd.DataFrame([summarise_subject(subjects[i]) for i in ids]).set_index("subject_id")


def test_query_statistics_match_a_direct_computation(built):
    path, subjects = built
    with open_store(path) as st:
        res = st.query(skin_type="III")
    ids = [sid for sid, ds in subjects.items() if ds.attrs["skin_type"] == 3]
    assert isinstance(res, QueryResult)
    assert res.count == 3 and sorted(res.subject_ids) == sorted(ids)
    df = _direct(subjects, ids)
    for r in res.regions:
        for p in ("ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent"):
            col = df[f"{p}_mean_r{r['region']}"]
            assert r[p].n == 3
            assert r[p].mean == pytest.approx(col.mean(), rel=1e-12)
            assert r[p].std == pytest.approx(col.std(ddof=1), rel=1e-12)
            assert r[p].within_std == pytest.approx(df[f"{p}_std_r{r['region']}"].mean(), rel=1e-12)
    for p in ("sigma_a", "sigma_s_prime", "sigma_tr"):
        for ch in CHANNELS:
            assert res.scattering[p][ch].mean == pytest.approx(df[f"{p}_{ch}"].mean(), rel=1e-12)
            for site in SITES:
                col = df[f"site_{p}_{site}_{ch}"]
                assert res.sites[site][p][ch].mean == pytest.approx(col.mean(), rel=1e-12)
                assert res.sites[site][p][ch].std == pytest.approx(col.std(ddof=1), rel=1e-12)
    for ch in CHANNELS:
        assert res.albedo[ch].mean == pytest.approx(df[f"albedo_mean_{ch}"].mean(), rel=1e-12)
    h = np.array([albedo_histogram(subjects[i]) for i in ids], float)
    h /= h.sum(axis=2, keepdims=True)
    np.testing.assert_allclose(res.albedo_histogram, h.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(res.albedo_histogram.sum(axis=1), 1.0)


def test_query_filters(built):
    path, subjects = built
    with open_store(path) as st:
        # the paper groups I and II: either matches both
        assert set(st.query(skin_type="I").subject_ids) == {"A01", "A02"}
        assert set(st.query(skin_type=2).subject_ids) == {"A01", "A02"}
        iv = st.query(skin_type="iv", condition="any")
        assert set(iv.subject_ids) == {"A06", "A07", "A08", "A11", "M001"}
        assert iv.n_persons == 4  # A11 is A06 under lotion
        assert iv.breakdown["condition"] == {"normal": 4, "lotion": 1}
        assert iv.breakdown["kind"] == {"maps": 4, "samples": 1}
        # by default the normal condition only (as analysis): A11 is not counted twice with A06
        assert set(st.query(skin_type="iv").subject_ids) == {"A06", "A07", "A08", "M001"}
        assert st.query(skin_type="iv", condition=None).subject_ids == iv.subject_ids  # None: any, too
        assert set(st.query(skin_type="IV", gender="male", condition="any").subject_ids) == {"A06", "A07", "A11"}
        assert set(st.query(age="20s", condition="ANY").subject_ids) == {"A01", "A02", "A06", "A08", "A11"}
        assert set(st.query(age="50s+").subject_ids) == {"A05", "A10"}
        assert set(st.query(age="30-41").subject_ids) == {"A03", "A07", "A09", "M001"}
        assert st.query(condition="lotion").subject_ids == ("A11",)
        # several skin types: a union (I and II still grouped)
        both = st.query(skin_type="I,IV", condition="any")
        assert set(both.subject_ids) == {"A01", "A02"} | set(iv.subject_ids)
        assert both.filters["skin_type"] == [1, 2, 4]
        assert st.query(skin_type=["iv", 2]).filters["skin_type"] == [1, 2, 4]
        one = st.query(region="nose", condition="any")
        assert [r["region"] for r in one.regions] == [6] and one.count == len(subjects)
        # the sample subject has Torrance-Sparrow samples only
        assert one.regions[0]["ts_m"].n == len(subjects) and one.regions[0]["bp_exponent"].n == len(subjects) - 1
        for bad, msg in (
            (dict(skin_type="VII"), "skin type"),
            (dict(skin_type="IV,VII"), "skin type"),
            (dict(skin_type=[]), "skin type"),
            (dict(gender="X"), "gender"),
            (dict(age="old"), "age"),
            (dict(condition="wet"), "condition"),
            (dict(region="ear"), "region"),
        ):
            with pytest.raises(ValidationError, match=msg):
                st.query(**bad)
        # the messages name the whole value of an item that fails, and "any" among the conditions
        for bad, msg in (
            (dict(skin_type="IV,"), r"^skin type must be I-VI or 1-6, got '' \(an item of 'IV,'\)$"),
            (dict(skin_type=["V", "x"]), r"^skin type must be I-VI or 1-6, got 'x' \(an item of \['V', 'x'\]\)$"),
            (dict(skin_type="VII"), r"^skin type must be I-VI or 1-6, got 'VII'$"),
            (dict(condition="all"), r"^condition must be one of \[.*\], got 'all' \(or 'any' for every condition\)$"),
        ):
            with pytest.raises(ValidationError, match=msg):
                st.query(**bad)


def test_query_with_no_match_gives_an_empty_valid_document(built):
    path, _ = built
    with open_store(path) as st:
        res = st.query(skin_type="VI", gender="M")
    assert res.count == 0 and res.albedo_histogram is None
    doc = json.loads(res.to_json())
    assert doc["format"] == "facestats.query/1" and doc["count"] == 0 and doc["subject_ids"] == []
    assert doc["filters"] == {
        "skin_type": [6],
        "gender": "M",
        "age": None,
        "condition": "normal",  # the default: the population as the paper analyses it
        "region": None,
        "edits": False,
    }
    empty = {"mean": None, "std": None, "n": 0, "within_std": None, "mean_se": None, "texel_se": None}
    assert all(r["ts_m"] == empty for r in doc["regions"])
    assert doc["albedo_histogram"]["R"] is None
    assert "no subject matches" in res.to_table()


def test_query_documents_json_csv_and_table(built):
    path, subjects = built
    with open_store(path) as st:
        res = st.query(gender="F")
    doc = json.loads(res.to_json())
    assert set(doc) == {
        "format",
        "store",
        "n_edits_left_out",
        "n_store_subjects",
        "filters",
        "count",
        "n_persons",
        "subject_ids",
        "breakdown",
        "units",
        "regions",
        "scattering",
        "sites",
        "albedo",
        "albedo_histogram",
    }
    assert doc["count"] == 5 and len(doc["regions"]) == 10
    assert doc["regions"][5]["name"] == REGIONS[6]
    assert len(doc["albedo_histogram"]["G"]) == 256
    assert doc["scattering"]["sigma_tr"]["R"]["mean"] == pytest.approx(res.scattering["sigma_tr"]["R"].mean)
    import csv
    import io

    rows = list(csv.DictReader(io.StringIO(res.to_csv())))
    count = next(r for r in rows if r["quantity"] == "count")
    assert int(count["n"]) == 5
    nose = next(r for r in rows if r["quantity"] == "ts_m" and r["region"] == "6")
    assert float(nose["mean"]) == res.regions[5]["ts_m"].mean
    hist = next(r for r in rows if r["section"] == "histogram" and r["channel"] == "B")
    np.testing.assert_allclose([float(x) for x in hist["values"].split()], res.albedo_histogram[2])
    text = res.to_table()
    assert "matching subjects: 5" in text and "R  |" in text and "σtr cheek" in text
    assert "+-" in res.to_table(ascii=True) and "σ" not in res.to_table(ascii=True)


def test_the_table_says_why_sigma_tr_does_not_vary_between_subjects():
    """Every subject's maps use the population's average σtr (Weyrich §5.4): "0.5517 ± 0" read like a fault (a
    fresh-user red team); the table says why, in both alphabets, and only where it is so."""
    with open_store() as st:
        res = st.query(skin_type="IV")
    assert all(res.scattering["sigma_tr"][ch].std == 0 for ch in CHANNELS)
    text = res.to_table()
    assert "σtr (population): one value shared by every subject, the population's average σtrAvg" in text
    assert "± 0 " not in text and not re.search(r"± 0$", text, re.M)  # no "± 0" under "mean ± std across subjects"
    assert "sigma_tr (population): one value shared by every subject" in res.to_table(ascii=True)
    assert res.to_table(ascii=True).isascii()
    # the JSON and the CSV say the same: a constant, beside the measured quantities that are not
    doc = res.to_dict()["scattering"]
    assert all(doc["sigma_tr"][ch]["constant"] is True and doc["sigma_tr"][ch]["std"] == 0 for ch in CHANNELS)
    assert all(doc[p][ch]["constant"] is False for p in ("sigma_a", "sigma_s_prime") for ch in CHANNELS)
    assert "constant" not in res.to_dict()["sites"]["cheek"]["sigma_tr"]["R"]
    rows = list(csv.DictReader(io.StringIO(res.to_csv())))
    flags = {(r["quantity"], r["channel"]): r["constant"] for r in rows if r["section"] == "scattering"}
    assert flags[("sigma_tr", "G")] == "true" and flags[("sigma_a", "G")] == "false"
    assert all(r["constant"] == "" for r in rows if r["section"] != "scattering")
    tr = dict(res.scattering["sigma_tr"])
    res.scattering["sigma_tr"]["G"] = res.scattering["sigma_tr"]["G"].__class__(0.98, 0.01, 40, constant=False)
    res.scattering["sigma_tr"]["R"] = res.scattering["sigma_tr"]["R"].__class__(0.55, 0.02, 40, constant=False)
    res.scattering["sigma_tr"]["B"] = res.scattering["sigma_tr"]["B"].__class__(1.5, 0.03, 40, constant=False)
    assert "one value shared" not in res.to_table() and "(population)" not in res.to_table()
    res.scattering["sigma_tr"].update(tr)


def test_one_subject_shows_no_population_constant():
    """One subject shares its σtr with nobody: no "(population)" label and no ``constant`` claim (n = 1)."""
    with open_store() as st:
        res = st.query(skin_type="VI", gender="F")
    assert res.count == 1
    s = res.scattering["sigma_tr"]["R"]
    assert s.n == 1 and s.constant is False and res.to_dict()["scattering"]["sigma_tr"]["R"]["constant"] is False
    assert "(population)" not in res.to_table() and "one value shared" not in res.to_table()


# -- writes -----------------------------------------------------------------------------
def test_invalid_subjects_are_refused_without_touching_the_store(tmp_path):
    path = tmp_path / "s.zarr"
    with open_store(path, mode="a") as st:
        st.write_subject(make_map_subject("OK"))
        rev = st.revision
        listing = sorted(p.relative_to(path) for p in path.rglob("*"))
        bad = make_map_subject("BAD")
        bad.attrs["skin_type"] = 9
        with pytest.raises(SchemaError, match="skin_type"):
            st.write_subject(bad)
        bad = make_map_subject("BAD2")
        bad["ts_m"] = bad["ts_m"].transpose("u", "v")
        with pytest.raises(SchemaError, match="ts_m"):
            st.write_subject(bad)
        bad = make_map_subject("../evil")
        with pytest.raises(ValidationError, match="subject_id"):
            st.write_subject(bad)
        with pytest.raises(ValidationError, match="xarray.Dataset"):
            st.write_subject({"subject_id": "x"})
        bad = make_map_subject("BAD3")
        bad.attrs["provenance"] = "source: camera"
        with pytest.raises(SchemaError, match="provenance must be a JSON"):
            st.write_subject(bad)
        bad = make_map_subject("BAD4")
        bad["region"] = bad["region"].astype("float64") + 0.5 * (bad["region"] == 2)  # 2.5: in no region
        with pytest.raises(SchemaError, match="region labels must be integers 0-10, got dtype float64"):
            st.write_subject(bad)
        bad = make_map_subject("BAD5").assign_coords(site=["cheek", "cheek", "neck"])  # a TypeError in the index row
        with pytest.raises(
            SchemaError, match=r"site coords must name each site once, got \['cheek', 'cheek', 'neck'\]"
        ):
            st.write_subject(bad)
        bad = make_map_subject("BAD6")
        bad = bad.assign_coords(u=bad["u"].values[::-1])  # the maps are read by index: left and right would swap
        with pytest.raises(
            SchemaError, match=r"u coords must be .* strictly increasing inside \(0, 1\), got 0.9375 at"
        ):
            st.write_subject(bad)
        bad = make_map_subject("BAD7")
        r = bad["fiber_distance"].values.copy()
        r[3] = np.nan  # the σ posterior fits the profile against these distances
        with pytest.raises(SchemaError, match=r"fiber_distance must be .* strictly increasing .* got nan at index 3"):
            st.write_subject(bad.assign_coords(fiber_distance=("fiber", r)))
        assert st.revision == rev
        assert sorted(p.relative_to(path) for p in path.rglob("*")) == listing
    ok = make_map_subject("F32")  # float32 coordinates, a crop and a strided copy keep their texels' UV positions
    validate_subject(ok.assign_coords(u=ok["u"].astype(np.float32), v=ok["v"].astype(np.float32)), name="F32")
    validate_subject(ok.isel(u=slice(3, 20), v=slice(None, None, 4)), name="F32")
    with open_store() as st:  # normals are read by index: x, y, z relabelled would contradict them
        ds = st.subject("S001")
    with pytest.raises(SchemaError, match=r"component coords must be \('x', 'y', 'z'\), got \['z', 'y', 'x'\]"):
        validate_subject(ds.assign_coords(component=["z", "y", "x"]), name="S001")


def test_a_scalar_label_coordinate_is_refused_by_name():
    """A scalar ``component`` or ``channel`` coordinate (``assign_coords(component="x")``, what ``isel`` of one
    label leaves) failed validate_subject with a bare TypeError ("iteration over a 0-d array")."""
    ok = make_map_subject("C1")
    with pytest.raises(SchemaError, match=r"subject 'C1': component coords must be \('x', 'y', 'z'\), got a 0-D "
                       r"coordinate 'x'"):  # fmt: skip
        validate_subject(ok.assign_coords(component="x"))
    samples = make_sample_subject("C2").drop_vars(["albedo_sample", "albedo_sample_region"])
    with pytest.raises(SchemaError, match=r"channel coords must be \('R', 'G', 'B'\), got a 0-D coordinate 'R'"):
        validate_subject(samples.isel(channel=0))
    assert validate_subject(samples) == "samples"


def test_fibre_distances_must_be_the_fiber_dimensions_coordinate():
    """A subject whose sensor_profile had no fiber_distance, or had it on another dimension (3 values along site
    for 28 fibres), passed the schema; the σ posterior then failed with a bare KeyError, or said "profile must have
    shape (3,) or (3, K) to match r", about a stored subject it was never given."""
    from facestats.analysis.posterior.profile import site_sigma_posterior

    ok = make_map_subject("D1")
    assert validate_subject(ok) == "maps"
    with pytest.raises(SchemaError, match=r"subject 'D1': fiber_distance must be the coordinate of the fiber "
                       r"dimension .*, got none$"):  # fmt: skip
        validate_subject(ok.drop_vars("fiber_distance"))
    with pytest.raises(KeyError):  # what the schema let through
        site_sigma_posterior(ok.drop_vars("fiber_distance"), "cheek")
    moved = ok.drop_vars("fiber_distance").assign_coords(fiber_distance=("site", [1.0, 2.0, 3.0]))
    with pytest.raises(SchemaError, match=r"fiber_distance must be the coordinate .*, got dims \('site',\)$"):
        validate_subject(moved)
    samples = make_sample_subject("D2")
    assert validate_subject(samples) == "samples"  # no fibres, no distances: nothing to check


def test_overwrite_and_edits(tmp_path):
    with open_store(tmp_path / "s.zarr", mode="a") as st:
        st.write_subject(make_map_subject("S1", seed=1))
        with pytest.raises(StoreError, match="already exist.*overwrite=True"):
            st.write_subject(make_map_subject("S1", seed=2))
        np.testing.assert_array_equal(st.subject("S1")["ts_m"].values, make_map_subject("S1", seed=1)["ts_m"].values)
        st.write_subject(make_map_subject("S1", seed=2), overwrite=True)
        np.testing.assert_array_equal(st.subject("S1")["ts_m"].values, make_map_subject("S1", seed=2)["ts_m"].values)
        assert len(list((tmp_path / "s.zarr" / "subjects" / "S1").glob("g*"))) == 1  # superseded one deleted
        edited = make_map_subject("S1-edit", seed=3)
        set_provenance(edited, source_subject="S1", edit={"kind": "skin_type", "to": "V"})
        st.write_subject(edited)
        p = provenance(st.subject("S1-edit"))
        assert p["source_subject"] == "S1" and p["edit"] == {"kind": "skin_type", "to": "V"}
        st.delete_subject("S1")
        assert "S1" not in st and st.ids() == ["S1-edit"]
        assert not (tmp_path / "s.zarr" / "subjects" / "S1").exists() or not list(
            (tmp_path / "s.zarr" / "subjects" / "S1").glob("g*")
        )
        with pytest.raises(StoreError, match="no subject 'S1'"):
            st.subject("S1")


def test_batch_write_is_all_or_nothing(tmp_path):
    with open_store(tmp_path / "s.zarr", mode="a") as st:
        st.write_subject(make_map_subject("B2"))
        with pytest.raises(StoreError, match="B2"):
            st.write_subjects([make_map_subject("B1"), make_map_subject("B2")])
        assert st.ids() == ["B2"]
        with pytest.raises(ValidationError, match="twice"):
            st.write_subjects([make_map_subject("B3"), make_map_subject("B3")])
        assert not (tmp_path / "s.zarr" / "subjects" / "B1").exists() or not list(
            (tmp_path / "s.zarr" / "subjects" / "B1").glob("g*")
        )


def test_a_precondition_runs_under_the_commit_lock_and_aborts_the_write(tmp_path):
    """``precondition`` is the check a build makes before it commits: it must run while no other writer can
    commit (the store's lock is held: a second lock on the file fails), see the store as it is, and a refusal
    must leave the store as it was, with no generation of the refused subject left behind."""
    from facestats.io.locking import FileLock

    path = tmp_path / "s.zarr"
    seen = []

    def check(store):
        probe = FileLock(path / ".lock", timeout=0)
        seen.append((probe.acquire(blocking=False), store.ids()))

    with open_store(path, mode="a") as st:
        st.write_subject(make_map_subject("P1"))
        assert st.write_subject(make_map_subject("P2"), precondition=check) == "P2"
        assert seen == [(False, ["P1"])]  # the lock was held; P2 not yet in the index

        def refuse(store):
            raise ValidationError("another build wrote P1")

        with pytest.raises(ValidationError, match="another build wrote P1"):
            st.write_subjects([make_map_subject("P3"), make_map_subject("P1")], overwrite=True, precondition=refuse)
        assert st.ids() == ["P1", "P2"]
        assert not list((path / "subjects" / "P3").glob("g*"))
        assert len(list((path / "subjects" / "P1").glob("g*"))) == 1
        assert st.validate().ok


# -- bad stores -------------------------------------------------------------------------
def _gen_dir(path, sid):
    return next((path / "subjects" / sid).glob("g*"))


def test_wrong_schema_version_and_not_a_store(built, tmp_path):
    path = _copy_store(built[0], tmp_path / "c.zarr")
    meta = json.loads((path / "zarr.json").read_text())
    meta["attributes"]["facestats_schema"] = SCHEMA_VERSION + 1
    (path / "zarr.json").write_text(json.dumps(meta))
    with pytest.raises(SchemaError, match=f"schema version {SCHEMA_VERSION + 1}.*upgrade facestats"):
        open_store(path)
    meta["attributes"]["facestats_schema"] = "zero"
    (path / "zarr.json").write_text(json.dumps(meta))
    with pytest.raises(SchemaError, match="schema version 'zero'"):
        open_store(path)
    del meta["attributes"]["facestats_schema"]
    (path / "zarr.json").write_text(json.dumps(meta))
    with pytest.raises(StoreError, match="not a facestats store"):
        open_store(path)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "data.txt").write_text("x")
    with pytest.raises(StoreError, match="not a facestats store"):
        open_store(tmp_path / "other")
    with pytest.raises(StoreError, match="not empty and is not a facestats store"):
        open_store(tmp_path / "other", mode="a")
    with pytest.raises(StoreError, match="does not exist"):
        open_store(tmp_path / "missing.zarr")
    (tmp_path / "f.txt").write_text("hello")
    with pytest.raises(StoreError, match="neither a store directory nor a zip"):
        open_store(tmp_path / "f.txt")
    with pytest.raises(ValidationError, match="mode"):
        open_store(tmp_path / "x.zarr", mode="w")


@pytest.mark.slow  # copies, validates and repairs a store per case (2 s each); tests/reliability has more
@pytest.mark.parametrize(
    "damage, pattern",
    [
        ("missing_group", r"subject 'A03': group subjects/A03/g\S+ is missing"),
        ("deleted_chunk", r"subject 'A03': variable 'albedo' does not match its checksum"),
        ("truncated_chunk", r"subject 'A03': variable 'ts_rho_s' cannot be read \(truncated or corrupt chunk\)"),
        ("wrong_dims", r"subject 'A03': variable 'ts_m' has dims \('u', 'v'\), expected \('v', 'u'\)"),
        ("wrong_shape", r"subject 'A03': cannot open group .*conflicting sizes for dimension 'v'.*'bp_flag'"),
        ("missing_variable", r"subject 'A03': variable\(s\) \['region'\] missing"),
        ("no_manifest", r"subject 'A03': group .* lacks the 'facestats_store' attribute"),
    ],
)
def test_damaged_subjects_give_clear_errors(built, tmp_path, damage, pattern):
    import shutil

    path = _copy_store(built[0], tmp_path / "c.zarr")
    gen = _gen_dir(path, "A03")
    if damage == "missing_group":
        shutil.rmtree(gen)
    elif damage == "deleted_chunk":
        (gen / "albedo" / "c" / "0" / "0" / "0").unlink()
    elif damage == "truncated_chunk":
        f = gen / "ts_rho_s" / "c" / "0" / "0"
        f.write_bytes(f.read_bytes()[:20])
    elif damage in ("wrong_dims", "wrong_shape"):
        name = "ts_m" if damage == "wrong_dims" else "bp_flag"
        meta = json.loads((gen / name / "zarr.json").read_text())
        if damage == "wrong_dims":
            meta["dimension_names"] = ["u", "v"]
        else:
            meta["shape"] = [12, 24]
        (gen / name / "zarr.json").write_text(json.dumps(meta))
    elif damage == "missing_variable":
        shutil.rmtree(gen / "region")
    elif damage == "no_manifest":
        meta = json.loads((gen / "zarr.json").read_text())
        del meta["attributes"]["facestats_store"]
        (gen / "zarr.json").write_text(json.dumps(meta))
    with open_store(path) as st:
        with pytest.raises(SchemaError, match=pattern):
            st.subject("A03")
        st.subject("A04")  # the others are fine
        report = st.validate()
    assert not report.ok and len(report.problems) == 1
    assert re_search(pattern, report.problems[0])
    # repair drops the broken subject from the index; the rest validates
    with open_store(path, mode="r+") as st:
        report = st.validate(repair=True)
        assert report.ok, report.problems
        assert any("A03" in r for r in report.repaired)
        assert "A03" not in st and len(st) == len(built[1]) - 1


def re_search(pattern, text):
    import re

    return re.search(pattern, text) is not None


def test_stale_index_row_is_reported_and_repaired(built, tmp_path):
    path = _copy_store(built[0], tmp_path / "c.zarr")
    index = json.loads((path / "index.json").read_text())
    index["subjects"]["A05"]["row"]["ts_m_mean_r6"] += 0.1
    (path / "index.json").write_text(json.dumps(index))
    with open_store(path, mode="r+") as st:
        report = st.validate()
        assert not report.ok and "A05" in report.problems[0] and "ts_m_mean_r6" in report.problems[0]
        assert st.validate(repair=True).ok
        assert st.subjects().loc["A05", "ts_m_mean_r6"] == summarise_subject(built[1]["A05"])["ts_m_mean_r6"]


def test_index_rows_agree_within_last_bits_but_not_beyond(built, tmp_path):
    """A row written by a version that rounded differently is current; a value moved by 1e-6 is not."""
    path = _copy_store(built[0], tmp_path / "c.zarr")
    index = json.loads((path / "index.json").read_text())
    row = index["subjects"]["A05"]["row"]
    key = next(k for k, v in sorted(row.items()) if isinstance(v, float) and np.isfinite(v) and v != 0)
    row[key] = float(np.nextafter(row[key], np.inf)) * (1 + 1e-12)
    (path / "index.json").write_text(json.dumps(index))
    with open_store(path) as st:
        assert st.validate().ok
    row[key] *= 1 + 1e-6
    (path / "index.json").write_text(json.dumps(index))
    with open_store(path) as st:
        report = st.validate()
        assert not report.ok and key in report.problems[0]


def test_the_shipped_default_store_validates():
    report = facestats.open_store().validate()
    assert report.ok, report.problems[:3]
    assert report.n_checked == len(facestats.open_store())


def test_lost_index_is_rebuilt_by_repair(built, tmp_path):
    path = _copy_store(built[0], tmp_path / "c.zarr")
    (path / "index.json").unlink()
    with open_store(path) as st:
        with pytest.raises(StoreError, match="no index.json.*--repair"):
            st.subjects()
        assert not st.validate().ok
    with open_store(path, mode="r+") as st:
        report = st.validate(repair=True)
        assert report.ok and len(st) == len(built[1])
        assert st.query(skin_type="IV", condition="any").count == 5


def test_corrupt_index_file(built, tmp_path):
    path = _copy_store(built[0], tmp_path / "c.zarr")
    (path / "index.json").write_text('{"format": 1, "subj')
    with open_store(path) as st:
        with pytest.raises(StoreError, match="index.json is not valid JSON.*--repair"):
            st.query()


# -- zip stores and the default ---------------------------------------------------------
def test_pack_store_to_zip_and_read_it(built, tmp_path):
    path, subjects = built
    z = pack_store(path, tmp_path / "pop.zip")
    z2 = pack_store(path, tmp_path / "pop2.zip")
    assert z.read_bytes() == z2.read_bytes()  # deterministic
    with zipfile.ZipFile(z) as zf:
        names = zf.namelist()
        infos = zf.infolist()
        # The fast path needs the root and index stored first; chunks are stored, JSON metadata deflated.
        assert [i.filename for i in infos[:2]] == ["zarr.json", "index.json"]
        assert all(i.compress_type == zipfile.ZIP_STORED for i in infos[:2])
        assert all(
            i.compress_type == (zipfile.ZIP_DEFLATED if i.filename.endswith("zarr.json") else zipfile.ZIP_STORED)
            for i in infos[2:]
        )
    assert "index.json" in names and "zarr.json" in names and not any(".lock" in n for n in names)
    with open_store(z) as st:
        assert st.kind == "zip" and st.read_only
        assert st.ids() == sorted(subjects)
        back = st.subject("A07")
        np.testing.assert_array_equal(back["albedo"].values, subjects["A07"]["albedo"].values)
        assert st.query(skin_type="IV", condition="any").count == 5
        with pytest.raises(StoreError, match="read-only zip store.*--store PATH"):
            st.write_subject(make_map_subject("new"))
        assert st.validate().ok
    with pytest.raises(StoreError, match="read-only"):
        open_store(z, mode="a")
    with pytest.raises(StoreError, match="exists"):
        pack_store(path, z)
    (tmp_path / "file").write_text("")  # a zip path that cannot be created: named, before any work (was an OSError)
    with pytest.raises(ValidationError, match=r"zip_path must be a path that can be created, got .*file/pop.zip"):
        pack_store(path, tmp_path / "file" / "pop.zip")


def test_a_zip_made_by_other_tools_opens_too(built, tmp_path):
    import shutil

    # compressed entries, any order, leftovers included: read through the zip directory
    zp = shutil.make_archive(str(tmp_path / "plain"), "zip", root_dir=built[0])
    with open_store(zp) as st:
        assert st.ids() == sorted(built[1])
        np.testing.assert_array_equal(st.subject("M001")["ts_sample_m"].values, built[1]["M001"]["ts_sample_m"].values)


def test_default_store(built, tmp_path, monkeypatch):
    missing = tmp_path / "data" / "default_store.zip"
    monkeypatch.setattr(store_mod, "default_store_path", lambda: missing)
    with pytest.raises(StoreError, match="default store has not been built"):
        facestats.open_store()
    pack_store(built[0], missing)
    with facestats.open_store() as st:
        assert st.label == "default" and len(st) == len(built[1])
        assert st.query(gender="F").store == "default"
    with pytest.raises(StoreError, match="read-only"):
        facestats.open_store(None, mode="a")


def test_real_default_store_path_is_inside_the_package():
    p = store_mod.default_store_path()
    assert p.name == "default_store.zip" and p.parent == pathlib.Path(facestats.__file__).parent / "data"
    if p.exists():  # once the lead has built it: it must open and stay small
        assert p.stat().st_size <= 20e6
        with facestats.open_store() as st:
            assert len(st) > 0


# -- info, gc ---------------------------------------------------------------------------
def test_info(built):
    with open_store(built[0]) as st:
        info = st.info()
    assert info["n_subjects"] == 12 and info["n_persons"] == 11
    assert info["by_skin_type"] == {"I": 1, "II": 1, "III": 3, "IV": 5, "V": 1, "VI": 1}
    assert info["by_gender"] == {"M": 7, "F": 5}
    assert info["by_condition"] == {"normal": 11, "lotion": 1}
    assert info["by_kind"] == {"maps": 11, "samples": 1}
    assert info["schema_version"] == SCHEMA_VERSION and info["size_bytes"] > 0


def test_gc_skips_a_stale_lock_its_writer_removes_meanwhile(tmp_path, monkeypatch):
    """A writer's lock file judged stale by the survey can vanish before gc locks it (the writer finished):
    gc goes on and removes the rest (a race seen in the concurrent-writers test)."""
    import facestats.io.maintenance as maintenance
    from facestats.io.generations import reserve_generation

    path = tmp_path / "s.zarr"
    with open_store(path, mode="a") as st:
        st.write_subject(make_map_subject("G1"))
        gen, lock = reserve_generation(str(path), "G1")
        lock.release()  # a dead writer's lock file
        (path / "index.json.tmp-99-deadbeef").write_text("partial")
        real = maintenance.try_lock

        def writer_finishes_first(target, **kw):
            if str(target).endswith(f"G1~{gen}.lock"):
                os.remove(lock.path)  # after the survey judged it stale, before gc opens it
            return real(target, **kw)

        monkeypatch.setattr(maintenance, "try_lock", writer_finishes_first)
        removed = st.gc()
        assert "index.json.tmp-99-deadbeef" in removed and not (path / "index.json.tmp-99-deadbeef").exists()
        assert st.subject("G1") is not None


def test_gc_removes_dead_writers_leftovers_but_not_live_ones(tmp_path):
    from facestats.io.generations import reserve_generation

    path = tmp_path / "s.zarr"
    with open_store(path, mode="a") as st:
        st.write_subject(make_map_subject("G1"))
        keep = _gen_dir(path, "G1")
        subj = path / "subjects" / "G1"
        # a dead writer: generation directory and record, its lock file unlocked
        gen, lock = reserve_generation(str(path), "G1")
        dead = subj / gen
        dead.mkdir()
        (dead / "zarr.json").write_text("{}")
        lock.release()
        # a crashed writer of a new subject, its lock file gone too
        gen9, lock9 = reserve_generation(str(path), "G9")
        (path / "subjects" / "G9" / gen9).mkdir(parents=True)
        os.remove(lock9.path)
        lock9.release()
        # a live writer: its lock is held
        live_gen, live_lock = reserve_generation(str(path), "G1")
        live = subj / live_gen
        live.mkdir()
        # a generation without a record is not provably the store's: it is left alone (issue #12)
        unowned = subj / "g0000000000000001-1-aaaaaa"
        unowned.mkdir()
        (path / "index.json.tmp-99-deadbeef").write_text("partial")
        notes = st.validate().notes
        # G9's folder counts too: it holds nothing once its generation goes ("6" before, and gc removed 7)
        assert len(notes) == 2 and "7 leftover item(s)" in notes[0] and "not created by facestats" in notes[1]
        assert len(st.plan_repair().garbage) == 7
        removed = st.gc()
        assert len(removed) == 7 and "subjects/G9" in removed
        assert not dead.exists() and not (path / "subjects" / "G9").exists()
        assert not (path / "index.json.tmp-99-deadbeef").exists()
        assert not (path / ".writers" / f"G1~{gen}.lock").exists()
        assert live.exists() and keep.exists() and unowned.exists()
        assert f"subjects/G1/{gen}" in removed and f".records/G1~{gen}.json" in removed
        live_lock.release()  # the writer died
        st.gc()
        assert not live.exists() and keep.exists() and unowned.exists()
        unowned.rmdir()
        assert st.validate().ok and not st.validate().notes
        assert sorted(os.listdir(path / ".writers")) == []


def test_every_stored_variable_has_a_physical_domain():
    from facestats.io.schema import DOMAINS, VARIABLES

    assert set(DOMAINS) == set(VARIABLES)


def _tree(root):
    (root / "g" / "a").mkdir(parents=True)
    for name in ("g/zarr.json", "g/a/c0", "g/a/c1"):
        (root / name).write_bytes(b"x" * 100)
    return root / "g"


def test_fsync_tree_flushes_with_one_syncfs_where_there_is_one(tmp_path, monkeypatch):
    from facestats.io import layout

    calls, fsyncs = [], []
    monkeypatch.setattr(layout, "_syncfs", lambda: lambda fd: calls.append(fd) or 0)
    monkeypatch.setattr(layout, "fsync_path", lambda *a, **k: fsyncs.append(a))
    layout.fsync_tree(_tree(tmp_path))
    assert len(calls) == 1 and fsyncs == []
    layout.fsync_tree(tmp_path / "g" / "zarr.json")  # a file: its folder is flushed, the file is never opened
    assert len(calls) == 2


def test_fsync_tree_falls_back_to_every_file_and_reports_syncfs_errors(tmp_path, monkeypatch):
    import ctypes
    import errno

    from facestats.io import layout

    g, fsyncs = _tree(tmp_path), []
    real = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: fsyncs.append(fd) or real(fd))
    monkeypatch.setattr(layout, "_syncfs", lambda: None)
    layout.fsync_tree(g)
    assert len(fsyncs) == 5  # three files and two folders
    fsyncs.clear()
    layout.fsync_tree(g / "zarr.json")  # a file: it and its folder
    assert len(fsyncs) == 2

    def failing(err):
        def fn(fd):
            ctypes.set_errno(err)
            return -1

        return lambda: fn

    fsyncs.clear()
    monkeypatch.setattr(layout, "_syncfs", failing(errno.ENOSYS))  # not supported here: file by file
    layout.fsync_tree(g)
    assert len(fsyncs) == 5
    monkeypatch.setattr(layout, "_syncfs", failing(errno.EIO))  # a write-back error is an error
    with pytest.raises(OSError, match="syncfs failed"):
        layout.fsync_tree(g)


def test_fsync_tree_without_syncfs_skips_a_planted_fifo_instead_of_blocking(tmp_path, monkeypatch):
    import threading

    from facestats.io import layout

    g, fsyncs = _tree(tmp_path), []
    os.mkfifo(g / "a" / "fifo")  # opened read-only it would block until a writer came
    os.symlink(g / "a" / "fifo", g / "link")
    real = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: fsyncs.append(fd) or real(fd))
    monkeypatch.setattr(layout, "_syncfs", lambda: None)
    t = threading.Thread(target=layout.fsync_tree, args=(g,), daemon=True)
    t.start()
    t.join(5)
    assert not t.is_alive(), "fsync_tree blocked on a FIFO"
    assert len(fsyncs) == 5  # the three files and two folders; the FIFO and the link are left alone


def test_fsync_path_refuses_a_fifo_instead_of_blocking(tmp_path):
    """fsync_path opened a file with a plain blocking open: a FIFO there blocked until a writer came."""
    import threading

    from facestats.io.layout import fsync_path

    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "file").write_bytes(b"x")
    errors = []

    def run():
        try:
            fsync_path(tmp_path / "fifo")
        except OSError as exc:
            errors.append(exc)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(5)
    assert not t.is_alive(), "fsync_path blocked on a FIFO"
    assert len(errors) == 1 and "not a regular file" in str(errors[0])
    fsync_path(tmp_path / "file")  # a regular file and a directory still flush
    fsync_path(tmp_path, directory=True)
    with pytest.raises(NotADirectoryError):
        fsync_path(tmp_path / "file", directory=True)


def test_a_record_swapped_for_a_fifo_after_its_checks_is_refused_without_blocking(tmp_path, monkeypatch):
    import stat
    import threading

    from facestats.io import records
    from facestats.io.layout import RECORDS, new_generation

    root, gen = tmp_path / "s.zarr", new_generation()
    (root / RECORDS).mkdir(parents=True)
    records.write_record(root, "S001", gen, "writing")
    assert records.inspect_record(root, "S001", gen)[0]["state"] == "writing"
    path, real_lstat = records.record_path(root, "S001", gen), os.lstat
    regular = real_lstat(path)

    def lstat(p, *args, **kwargs):  # every lstat check sees the record, then a FIFO is put in its place
        if os.fspath(p) != path:
            return real_lstat(p, *args, **kwargs)
        if stat.S_ISREG(real_lstat(path).st_mode):
            os.remove(path)
            os.mkfifo(path)
        return regular

    monkeypatch.setattr(os, "lstat", lstat)
    out = []
    t = threading.Thread(target=lambda: out.append(records.inspect_record(root, "S001", gen)), daemon=True)
    t.start()
    t.join(5)
    assert not t.is_alive(), "inspect_record blocked on a FIFO"  # opened with open() after the lstat check before
    assert out == [(None, None)]


def test_a_store_opens_from_a_file_url_and_refuses_other_urls(tmp_path):
    open_store(tmp_path / "u.zarr", mode="a").close()
    with open_store(f"file://{tmp_path}/u.zarr") as st:  # as `facestats build --store file://…` writes it
        assert st.ids() == []
    for url in ("s3://bucket/u.zarr", "https://example.org/u.zarr"):
        with pytest.raises(StoreError, match="copy it to a local or shared disk"):
            open_store(url)


def test_domain_checks_of_large_float32_maps_are_chunked_and_exact():
    """Domain.outside converts DOMAIN_BLOCK values at a time to float64 (core.blocked.blockwise; a whole map at once
    doubled a subject in memory at every read, write and export); the mask is the one of the whole float64 array,
    NaN, inf and values a float32 rounding above a bound included."""
    from facestats.io.schema import DOMAIN_BLOCK, DOMAINS

    d = DOMAINS["ts_rho_s"]
    v = np.random.default_rng(0).uniform(-0.1, 2 * d.high, DOMAIN_BLOCK * 2 + 12345).astype(np.float32)
    v[[3, DOMAIN_BLOCK + 1, -1]] = [np.nan, np.inf, np.nextafter(np.float32(d.high), np.float32(np.inf))]
    v[DOMAIN_BLOCK] = np.float32(d.high) if np.float32(d.high) <= d.high else np.nextafter(np.float32(d.high), 0)
    expected = np.isinf(v) | np.isnan(v) | (v.astype(np.float64) < d.low) | (v.astype(np.float64) > d.high)
    got = d.outside(v.reshape(-1, 12345 + 2 * DOMAIN_BLOCK))
    np.testing.assert_array_equal(got.reshape(-1), expected)
    assert got[0, -1] and not got[0, DOMAIN_BLOCK]


def test_domain_violated_names_the_broken_bound_and_none_for_a_value_inside():
    """Domain.violated answered "finite" for a value inside the domain and the interval for an allowed NaN, and
    compared a float32 in float32 (inside, where outside() flags it); None for any value outside() does not flag."""
    from facestats.io.schema import Domain

    d, missing = Domain(0.0, 0.1, low_open=True), Domain(0.0, nan=True)
    for domain, value, bound in (
        (d, 0.05, None),
        (d, 0.1, None),
        (missing, float("nan"), None),
        (missing, 0.0, None),
        (d, 0.0, "> 0"),
        (missing, -1.0, ">= 0"),
        (d, np.float32(0.1), "<= 0.1"),  # 0.10000000149 in float64
        (d, float("nan"), "finite"),
        (missing, float("inf"), "finite"),
        (missing, -float("inf"), ">= 0"),
    ):
        assert domain.violated(value) == bound, (domain, value)
        assert bool(domain.outside(np.array([value]))[0]) == (bound is not None), (domain, value)


def test_exclude_leaves_optional_variables_unread(tmp_path):
    """``Store.subject(exclude=[...])`` leaves optional variables out and never reads them (a damaged one does not
    matter); the rest is loaded, verified and validated as in a full read; required variables cannot be left out."""
    ds = with_micro_normals(make_map_subject("EX", size=70, seed=8), cameras=2)
    path = tmp_path / "s.zarr"
    with open_store(path, mode="a") as st:
        st.write_subjects([ds, make_sample_subject("EXS")])
    gen = next((path / "subjects" / "EX").glob("g*"))
    (gen / "micro_normal" / "c" / "1" / "0" / "0" / "0").unlink()
    with open_store(path) as st:
        with pytest.raises(SchemaError, match="'EX'.*'micro_normal'.*checksum"):
            st.subject("EX")
        got = st.subject("EX", exclude=["micro_normal", "modulation"])
        assert "micro_normal" not in got.variables
        assert set(got.variables) == set(ds.variables) - {"micro_normal"}
        for name in ("albedo", "ts_m", "sensor_profile"):
            np.testing.assert_array_equal(got[name].values, ds[name].values)
        lazy = st.subject("EX", lazy=True, exclude=["micro_normal"])
        np.testing.assert_array_equal(lazy["bp_exponent"].values, ds["bp_exponent"].values)
        assert "ts_sample_m" in st.subject("EXS", exclude=["micro_normal"])
        (gen / "albedo" / "c" / "0" / "0" / "0").unlink()
        with pytest.raises(SchemaError, match="'EX'.*'albedo'.*checksum"):
            st.subject("EX", exclude=["micro_normal"])
        for bad, message in (
            (["albedo"], "exclude may name optional variables only .*got 'albedo'"),
            ("micro_normal", "exclude must be a list of variable names, got the string 'micro_normal'"),
            ([3], "exclude must be a list of variable names \\(strings\\), got 3"),
        ):
            with pytest.raises(ValidationError, match=message):
                st.subject("EX", exclude=bad)
        for kwargs, message in (
            ({"exclude": ["fiber_distance"]}, "exclude may name data variables only, got the coordinate"),
            ({"on_disk": ["u"]}, "on_disk may name data variables only, got the coordinate 'u'"),
            ({"lazy": True, "on_disk": ["micro_normal"]}, "on_disk requires lazy=False"),
            ({"lazy": True, "variables": ["ts_error"], "exclude": ["ts_error"]}, "exclude and variables both name"),
            ({"on_disk": ["micro_normal"], "exclude": ["micro_normal"]}, "exclude and on_disk both name"),
        ):
            with pytest.raises(ValidationError, match=message):
                st.subject("EX", **kwargs)


# -- The quarantine across volumes ------------------------------------------------------------------------
def _across_volumes(monkeypatch):
    """``os.rename`` into a quarantine fails with EXDEV, as when ``subjects/`` is another volume's mount point."""
    import errno

    real = os.rename

    def rename(src, dst, *args, **kwargs):
        if f"{os.sep}quarantine{os.sep}" in os.fspath(dst):
            raise OSError(errno.EXDEV, os.strerror(errno.EXDEV))
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "rename", rename)


def _remove_partly(path):
    """``remove_tree`` that removes one file of the tree, then fails."""
    import errno

    os.remove(os.path.join(path, "zarr.json"))
    raise OSError(errno.EIO, os.strerror(errno.EIO), path)


def _files(top):
    return sorted(p.relative_to(top).as_posix() for p in pathlib.Path(top).rglob("*") if p.is_file())


def test_quarantine_across_volumes_copies_then_says_what_is_where_when_a_step_fails(tmp_path, monkeypatch):
    from facestats.io import quarantine as q

    root, rel = tmp_path / "s.zarr", "subjects/S1/g0000000000000001-1-aaaaaa"
    (root / rel / "a").mkdir(parents=True)
    for name in ("zarr.json", "a/c0", "a/c1"):
        (root / rel / name).write_bytes(name.encode())
    _across_volumes(monkeypatch)
    qdir = q.open_quarantine(str(root), "test")
    real_copy = q.copy_tree

    def copy_partly(src, dst):
        real_copy(src, dst)
        raise OSError(28, os.strerror(28), dst)  # a full disk at the last file

    monkeypatch.setattr(q, "copy_tree", copy_partly)
    with pytest.raises(StoreError, match=rf"cannot move {rel} into the quarantine: No space left on device; it was le"):
        q.quarantine_move(str(root), qdir, rel, "damaged")
    assert _files(root / rel) == ["a/c0", "a/c1", "zarr.json"] and not os.path.lexists(os.path.join(qdir, rel))
    assert q.list_quarantine(root)[0]["items"] == []  # the partial copy was removed again, nothing listed
    monkeypatch.setattr(q, "copy_tree", real_copy)
    monkeypatch.setattr(q, "remove_tree", _remove_partly)
    with pytest.raises(StoreError) as info:  # "it was left in place" before: the original had lost a file
        q.quarantine_move(str(root), qdir, rel, "damaged")
    assert str(info.value) == (
        f"cannot finish moving {rel} into the quarantine: it was copied whole to {os.path.join(qdir, rel)} (another "
        f"volume), but removing the original failed (Input/output error): {root / rel} was only partly removed "
        "(what is left of it is incomplete)"
    )
    assert _files(os.path.join(qdir, rel)) == ["a/c0", "a/c1", "zarr.json"] and _files(root / rel) == ["a/c0", "a/c1"]
    [folder] = q.list_quarantine(root)
    assert folder["valid"] and folder["items"] == [{"path": rel, "why": "damaged"}]  # the whole copy is listed


def test_quarantine_across_volumes_moves_a_file_and_a_folder_whole(tmp_path, monkeypatch):
    from facestats.io import quarantine as q

    root, rel = tmp_path / "s.zarr", "subjects/S1/g0000000000000001-1-aaaaaa"
    (root / rel / "a").mkdir(parents=True)
    for name in ("zarr.json", "a/c0", "index.json"):
        (root / (name if name == "index.json" else f"{rel}/{name}")).write_bytes(name.encode())
    _across_volumes(monkeypatch)
    qdir = q.open_quarantine(str(root), "test")
    q.quarantine_move(str(root), qdir, rel, "damaged")
    q.quarantine_move(str(root), qdir, "index.json", "unreadable")
    assert _files(qdir) == ["QUARANTINE.json", "index.json", f"{rel}/a/c0", f"{rel}/zarr.json"]
    assert not (root / rel).exists() and not (root / "index.json").exists()
    assert [i["path"] for i in q.list_quarantine(root)[0]["items"]] == [rel, "index.json"]


def test_a_repair_stopped_after_copying_across_volumes_keeps_the_quarantine_manifest(tmp_path, monkeypatch):
    from facestats.io import quarantine as q

    path = tmp_path / "r.zarr"
    with open_store(path, mode="a") as st:
        st.write_subject(make_map_subject("R1", size=16))
        gen = path / "subjects" / "R1" / st.index_entries()["R1"]["generation"]
    chunk = gen / "albedo" / "c" / "0" / "0" / "0"
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0x10
    chunk.write_bytes(bytes(data))
    _across_volumes(monkeypatch)
    monkeypatch.setattr(q, "remove_tree", _remove_partly)
    with open_store(path, mode="r+") as st:
        with pytest.raises(StoreError, match=r"repair of .* stopped: cannot finish moving .* was only partly removed"):
            st.repair()
        [folder] = st.quarantine()  # its QUARANTINE.json was removed before: the copy neither listed nor purgeable
    rel = f"subjects/R1/{gen.name}"
    assert folder["valid"] and folder["items"] == [{"path": rel, "why": folder["items"][0]["why"]}]
    copy = path / "quarantine" / folder["name"] / rel
    assert (copy / "albedo" / "c" / "0" / "0" / "0").read_bytes() == bytes(data) and (copy / "zarr.json").is_file()


def test_a_missing_store_named_like_an_embedded_one_says_how_python_opens_that(tmp_path, monkeypatch):
    """``--store default`` and ``--store texture-sample`` name the embedded stores on the command line; in Python
    the same words are paths, and a missing one says what opens the embedded store instead."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(StoreError, match=r"store default does not exist; the command line's --store default is "
                       r"open_store\(\) with no path \(the embedded store\)$"):  # fmt: skip
        facestats.open_store("default")
    with pytest.raises(StoreError, match=r"store texture-sample does not exist; .*open_store\(texture_sample\(\)\)"):
        facestats.open_store("texture-sample")
    with pytest.raises(StoreError, match=r"store other does not exist$"):
        facestats.open_store("other")
