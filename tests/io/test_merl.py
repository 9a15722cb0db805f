"""The MERL/ETH ts_data.mat importer, on files written with scipy.io.savemat."""

import hashlib

import numpy as np
import pytest
import scipy.io

from facestats.analysis.population import region_samples as store_region_samples
from facestats.errors import FormatError
from facestats.io import open_store
from facestats.io.merl import import_merl, read_merl
from facestats.io.schema import provenance, validate_subject
from tests.helpers import merl_dict, save_mat


def test_import_round_trip_and_index(tmp_path):
    d = merl_dict()
    mat = save_mat(tmp_path, d)
    data = import_merl(mat, tmp_path / "m.zarr")
    assert data.ids == ["merl-001", "merl-002", "merl-003", "merl-004"]
    assert data.n_ts == 200 and data.n_albedo == 120 and data.albedo_channels == 3 and data.empty == []
    sha = hashlib.sha256(mat.read_bytes()).hexdigest()
    ts, reg, subj = d["ts"], d["ts_region"].ravel(), d["ts_subjec"].ravel()
    with open_store(tmp_path / "m.zarr") as st:
        df = st.subjects()
        for i, sid in enumerate(data.ids, start=1):
            ds = st.subject(sid)
            assert validate_subject(ds) == "samples"
            assert ds.attrs["age"] == 21 + 9 * (i - 1)
            assert ds.attrs["gender"] == ("M" if (i - 1) % 2 == 0 else "F")  # 0 = male, 1 = female
            assert ds.attrs["skin_type"] == (i - 1) % 5 + 2
            sel = subj == i
            np.testing.assert_array_equal(ds["ts_sample_m"].values, ts[sel, 0])  # column 0 is m
            np.testing.assert_array_equal(ds["ts_sample_rho_s"].values, ts[sel, 1])  # column 1 is rho_s
            np.testing.assert_array_equal(ds["ts_sample_region"].values, reg[sel])
            asel = d["albedo_subjec"].ravel() == i
            np.testing.assert_array_equal(ds["albedo_sample"].values, d["albedo"][asel])
            p = provenance(ds)
            assert p["source"] == str(mat.resolve()) and p["source_sha256"] == sha and p["subject_index"] == i
            for r in (2, 6, 9):
                rs = sel & (reg == r)
                if rs.sum():
                    assert df.loc[sid, f"ts_m_mean_r{r}"] == pytest.approx(ts[rs, 0].mean(), rel=1e-12)
                    assert df.loc[sid, f"ts_rho_s_mean_r{r}"] == pytest.approx(ts[rs, 1].mean(), rel=1e-12)
                    assert df.loc[sid, f"n_ts_r{r}"] == rs.sum()
            assert df.loc[sid, "albedo_mean_G"] == pytest.approx(d["albedo"][asel, 1].mean(), rel=1e-12)
        q = st.query(gender="F")
        assert q.count == 2 and q.subject_ids == ("merl-002", "merl-004")
        means = [df.loc[s, "ts_m_mean_r6"] for s in q.subject_ids]
        assert q.regions[5]["ts_m"].mean == pytest.approx(np.nanmean(means), rel=1e-12)
        assert q.regions[5]["bp_exponent"].n == 0  # no Blinn-Phong data in the file
        samples = store_region_samples(st, "ts")
        assert len(samples) == 200
        np.testing.assert_allclose(np.sort(samples.lobe.values), np.sort(ts[:, 0]))
    with pytest.raises(Exception, match="already exist"):
        import_merl(mat, tmp_path / "m.zarr")
    import_merl(mat, tmp_path / "m.zarr", overwrite=True)


def test_liberal_shapes_and_codes(tmp_path):
    base = merl_dict()
    d = dict(base)
    d["s_count"] = 4  # a plain scalar
    d["subj_age"] = base["subj_age"].ravel()  # row vector
    d["subj_gen"] = "MFMF"  # one char per subject
    d["subj_skintype"] = np.array(["II", "III", "IV", "V"], dtype=object)  # cell array of Roman numerals
    d["ts"] = base["ts"].T  # 2×K
    d["ts_region"] = base["ts_region"].ravel()
    d["albedo"] = base["albedo"].T  # 3×K'
    a = read_merl(save_mat(tmp_path, d))
    ref = read_merl(save_mat(tmp_path, base, "ref.mat"))
    for x, y in zip(a.datasets, ref.datasets):
        for name in ("ts_sample_m", "ts_sample_rho_s", "ts_sample_region", "albedo_sample"):
            np.testing.assert_array_equal(x[name].values, y[name].values)
        for key in ("age", "gender", "skin_type"):
            assert x.attrs[key] == y.attrs[key]
    for gen in (
        np.array(["male", "female", "m", "F"], dtype=object),
        np.array(["M", "F", "M", "F"]),
        np.array([[0, 1, 0, 1]]),
    ):
        d2 = dict(base, subj_gen=gen)
        assert [ds.attrs["gender"] for ds in read_merl(save_mat(tmp_path, d2)).datasets] == ["M", "F", "M", "F"]


def test_single_channel_albedo_and_no_albedo(tmp_path):
    d = merl_dict(albedo_cols=1)
    data = read_merl(save_mat(tmp_path, d))
    ds = data.datasets[0]
    assert data.albedo_channels == 1 and provenance(ds)["albedo_channels"] == 1
    v = ds["albedo_sample"].values
    np.testing.assert_array_equal(v[:, 0], v[:, 2])
    data = read_merl(save_mat(tmp_path, merl_dict(albedo_cols=0)))
    assert data.albedo_channels == 0 and "albedo_sample" not in data.datasets[0]


def test_subject_without_samples_is_imported_and_reported(tmp_path):
    d = merl_dict(n=4)
    d["s_count"] = np.array([[5]])
    d["subj_age"] = np.vstack([d["subj_age"], [[55]]])
    d["subj_gen"] = np.vstack([d["subj_gen"], [[1]]])
    d["subj_skintype"] = np.vstack([d["subj_skintype"], [[3]]])
    data = import_merl(save_mat(tmp_path, d), tmp_path / "m.zarr")
    assert data.empty == ["merl-005"]
    with open_store(tmp_path / "m.zarr") as st:
        row = st.subjects().loc["merl-005"]
        assert row["n_ts_r2"] == 0 and np.isnan(row["ts_m_mean_r2"]) and np.isnan(row["albedo_mean_R"])
        assert st.subject("merl-005").sizes["sample"] == 0
        assert st.query(age="50s+").subject_ids == ("merl-005",)


@pytest.mark.parametrize(
    "change, pattern",
    [
        (lambda d: d["ts"].__setitem__((2, 0), -0.1), r"ts row 3: m \(column 0\) must be > 0, got -0.1"),
        (lambda d: d["ts"].__setitem__((5, 1), -1.0), r"ts row 6: rho_s \(column 1\) must be >= 0, got -1"),
        (lambda d: d["ts"].__setitem__((7, 1), np.nan), r"ts row 8 must be finite"),
        (lambda d: d["ts_region"].__setitem__((9, 0), 11), r"ts_region\[10\] must be a region 1-10, got 11"),
        (lambda d: d["ts_subjec"].__setitem__((4, 0), 5), r"ts_subjec\[5\] must be a subject index 1-4, got 5"),
        (lambda d: d["ts_subjec"].__setitem__((4, 0), 1.5), r"ts_subjec\[5\] must be a subject index 1-4, got 1.5"),
        (lambda d: d["albedo"].__setitem__((3, 2), 1.2), r"albedo row 4 must lie in \[0, 1\]"),
        (lambda d: d.__setitem__("albedo", d["albedo"][:, :2]), r"albedo must be a K×1/3 table, got shape \(120, 2\)"),
        (lambda d: d.__setitem__("ts_region", d["ts_region"][:-1]), r"ts_region must have 200 entries, got 199"),
        (lambda d: d.__setitem__("ts", d["ts"][:, :1]), r"ts must be a K×2 table"),
        (lambda d: d.pop("ts_subjec"), r"missing key 'ts_subjec'"),
        (lambda d: d.pop("albedo_region"), r"albedo data need all of"),
        (lambda d: d.__setitem__("subj_gen", np.array([[0], [1], [2], [0]])), r"subj_gen\[3\] must be 0/1, M/F"),
        (lambda d: d.__setitem__("subj_gen", "MFXF"), r"subj_gen\[3\] .* got 'X'"),
        (lambda d: d.__setitem__("subj_skintype", np.array([[2], [3], [7], [4]])), r"subj_skintype\[3\] must be"),
        (
            lambda d: d.__setitem__("subj_age", np.array([[20], [30.5], [40], [50]])),
            r"subj_age\[2\] must be an integer age",
        ),
        (lambda d: d.__setitem__("subj_age", np.array([[20], [30], [40]])), r"subj_age must have 4 entries, got 3"),
        (lambda d: d.__setitem__("s_count", np.array([[0]])), r"s_count must be one positive integer"),
        (lambda d: d.__setitem__("s_count", np.array([[4, 4]])), r"s_count must be one positive integer"),
        (lambda d: d.__setitem__("subj_age", np.ones((2, 2))), r"subj_age must be a vector"),
    ],
)
def test_bad_values_are_named(tmp_path, change, pattern):
    d = merl_dict()
    change(d)
    with pytest.raises(FormatError, match=pattern):
        import_merl(save_mat(tmp_path, d), tmp_path / "m.zarr")
    assert not (tmp_path / "m.zarr").exists()  # nothing written


def test_unreadable_files(tmp_path):
    bad = tmp_path / "bad.mat"
    bad.write_bytes(b"this is not a MATLAB file at all" * 10)
    with pytest.raises(FormatError, match="bad.mat: not a readable MATLAB file"):
        read_merl(bad)
    with pytest.raises(FormatError, match="no such file"):
        read_merl(tmp_path / "missing.mat")
    p = tmp_path / "text.mat"
    scipy.io.savemat(p, dict(merl_dict(), ts=np.array(["ab", "cd"])))
    with pytest.raises(FormatError, match="ts must be numeric"):
        read_merl(p)
