"""The statistics release (``facestats export``): never deletes or overwrites files it did not write; the README and
``statistics.json`` describe every column of ``subjects.csv``."""

from __future__ import annotations

import csv
import json
import os
import re

import pytest

from facestats.errors import ValidationError
from facestats.io.export import RELEASE_TITLE, export_statistics


@pytest.fixture(scope="module")
def store():
    import facestats

    with facestats.open_store() as st:
        yield st


def test_a_folder_that_is_not_a_release_is_refused_and_left_alone(tmp_path, store):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "statistics.json").write_text("my own statistics")
    (out / "README.txt").write_text("my own readme")
    with pytest.raises(ValidationError) as err:
        export_statistics(store, out, formats=("csv",))
    assert str(err.value).startswith("out_dir must be a new or empty folder (overwrite=True, --overwrite: replace")
    assert "which holds 2 entries ('README.txt', 'statistics.json')" in str(err.value)
    assert sorted(os.listdir(out)) == ["README.txt", "statistics.json"]
    assert (out / "statistics.json").read_text() == "my own statistics"
    assert (out / "README.txt").read_text() == "my own readme"
    # overwrite=True writes the release's files there and removes nothing
    written = export_statistics(store, out, formats=("csv",), overwrite=True)
    assert sorted(p.name for p in written) == ["README.txt", "albedo_histograms.csv", "subjects.csv"]
    assert sorted(os.listdir(out)) == ["README.txt", "albedo_histograms.csv", "statistics.json", "subjects.csv"]
    assert (out / "statistics.json").read_text() == "my own statistics"
    assert (out / "README.txt").read_text().splitlines()[0] == RELEASE_TITLE


def test_an_earlier_release_is_replaced_with_the_other_format_and_other_files_kept(tmp_path, store):
    out = tmp_path / "release"
    export_statistics(store, out, formats=("json",))  # a new folder
    assert sorted(os.listdir(out)) == ["README.txt", "statistics.json"]
    (out / "notes.txt").write_text("mine")
    before = {name: (out / name).read_bytes() for name in os.listdir(out)}
    with pytest.raises(ValidationError, match="which holds an earlier statistics release"):
        export_statistics(store, out, formats=("csv",))  # replacing a release needs overwrite, as everywhere
    assert {name: (out / name).read_bytes() for name in os.listdir(out)} == before
    export_statistics(store, out, formats=("csv",), overwrite=True)
    assert sorted(os.listdir(out)) == ["README.txt", "albedo_histograms.csv", "notes.txt", "subjects.csv"]
    readme = (out / "README.txt").read_text()
    assert "subjects.csv" in readme and "statistics.json" not in readme  # it describes the files written
    export_statistics(store, out, overwrite=True)
    assert sorted(os.listdir(out)) == [
        "README.txt", "albedo_histograms.csv", "notes.txt", "statistics.json", "subjects.csv",
    ]  # fmt: skip
    empty = tmp_path / "empty"
    empty.mkdir()
    assert len(export_statistics(store, empty, formats=("json",))) == 2


def _json_value(subject, col):
    """The value of the ``subjects.csv`` column ``col`` in a subject of ``statistics.json``."""
    models = {"ts": "torrance_sparrow", "bp": "blinn_phong"}
    keys = {"ts_rho_s": ("ts", "rho_s"), "ts_m": ("ts", "m"), "bp_rho_s": ("bp", "rho_s"),
            "bp_exponent": ("bp", "exponent")}  # fmt: skip
    if col in subject:
        return subject[col]
    if m := re.fullmatch(r"n_(ts|bp)_r(\d+)", col):
        return subject["brdf"][models[m[1]]][int(m[2]) - 1]["n"]
    if m := re.fullmatch(r"(ts|bp)_cov_r(\d+)", col):
        return subject["brdf"][models[m[1]]][int(m[2]) - 1]["cov"]
    if m := re.fullmatch(r"(\w+?)_(mean|std|se|mean_se)_r(\d+)", col):
        model, key = keys[m[1]]
        item = subject["brdf"][models[model]][int(m[3]) - 1]
        assert item["region"] == int(m[3])
        return item[key][m[2]]
    if m := re.fullmatch(r"site_(\w+)_(cheek|forehead|neck)_([RGB])", col):
        return subject["sites"][m[2]][m[1]][m[3]]
    if m := re.fullmatch(r"albedo_(mean|std)_([RGB])", col):
        return subject["albedo"][m[1]][m[2]]
    if m := re.fullmatch(r"(sigma_a|sigma_s_prime|sigma_tr)_([RGB])", col):
        return subject["scattering"][m[1]][m[2]]
    raise AssertionError(f"column {col} of subjects.csv is not in statistics.json")


def test_statistics_json_and_the_readme_carry_every_csv_column(tmp_path, store):
    export_statistics(store, tmp_path)
    rows = list(csv.DictReader((tmp_path / "subjects.csv").open()))
    doc = json.loads((tmp_path / "statistics.json").read_text())
    assert [s["subject_id"] for s in doc["subjects"]] == [r["subject_id"] for r in rows]
    cov_columns = [c for c in rows[0] if "_cov_r" in c]
    assert len(cov_columns) == 20
    for row, subject in zip(rows, doc["subjects"]):
        for col, text in row.items():
            value = _json_value(subject, col)
            if text == "":
                assert value is None, col
            elif isinstance(value, str):
                assert value == text, col
            else:
                assert value == float(text), col  # the same number, not rounded
    s3 = doc["subjects"][[r["subject_id"] for r in rows].index("S003")]
    nose = s3["brdf"]["torrance_sparrow"][5]
    assert nose["region"] == 6 and nose["cov"] == store.subjects().loc["S003", "ts_cov_r6"] and nose["cov"] != 0
    readme = (tmp_path / "README.txt").read_text()
    assert "ts_cov_r*, bp_cov_r*" in readme and "sample covariance (ddof 1)" in readme
    assert "statistics.json" in readme and "subjects.csv" in readme
