"""The store commands of the installed ``facestats`` console script, run in a subprocess.

Each test runs the console script end to end at least once; the refusals and repeats around it call
:func:`facestats.cli.main` in the test's process (:func:`tests.helpers.run_main`), which the console script runs.
"""

import csv
import io
import json
import re

import numpy as np
import pytest
import scipy.io

from facestats.io import open_store, pack_store
from facestats.io.store import default_store_path
from tests.helpers import make_map_subject, make_sample_subject, merl_dict, run_cli, run_main

POP = [
    ("P1", 4, "M", 24),
    ("P2", 4, "F", 35),
    ("P3", 4, "M", 52),
    ("P4", 3, "M", 28),
    ("P5", 2, "F", 41),
    ("P6", 1, "M", 22),
]


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    path = root / "pop.zarr"
    with open_store(path, mode="a") as st:
        st.write_subjects(
            [make_map_subject(s, skin_type=t, gender=g, age=a, seed=k) for k, (s, t, g, a) in enumerate(POP)]
            + [make_sample_subject("M1", skin_type=4)]
        )
    return path, pack_store(path, root / "pop.zip")


def test_query_table(stores):
    r = run_cli("query", "--skin-type", "IV", "--store", stores[1])
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "skin type IV" in out and "matching subjects: 4" in out
    assert "gender     M 2, F 2" in out
    assert " 6 nose" in out and "σtr cheek" in out and "albedo" in out
    bars = [line for line in out.splitlines() if line[:4] in ("R  |", "G  |", "B  |")]
    assert len(bars) == 3 and all(len(b) == 4 + 32 + 1 for b in bars)


def test_query_json_matches_the_api(stores):
    r = run_cli(
        "query", "--skin-type", "4", "--gender", "M", "--age", "20-60", "--store", stores[1], "--format", "json"
    )
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    with open_store(stores[1]) as st:
        api = st.query(skin_type="IV", gender="M", age="20-60").to_dict()
    assert doc == api
    assert doc["count"] == 2 and doc["subject_ids"] == ["P1", "P3"]
    assert doc["filters"] == {
        "skin_type": [4],
        "gender": "M",
        "age": [20, 60],
        "condition": "normal",
        "region": None,
        "edits": False,
    }
    assert len(doc["albedo_histogram"]["R"]) == 256 and sum(doc["albedo_histogram"]["R"]) == pytest.approx(1)


def test_query_grouping_of_types_one_and_two_and_region(stores):
    r = run_cli("query", "--skin-type", "II", "--region", "nose", "--store", stores[0], "--format", "json")
    doc = json.loads(r.stdout)
    assert r.returncode == 0 and sorted(doc["subject_ids"]) == ["P5", "P6"]
    assert [x["region"] for x in doc["regions"]] == [6]


def test_query_csv(stores):
    r = run_cli("query", "--gender", "F", "--store", stores[1], "--format", "csv")
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(io.StringIO(r.stdout)))
    assert next(x for x in rows if x["quantity"] == "count")["n"] == "3"
    hist = [x for x in rows if x["section"] == "histogram"]
    assert [h["channel"] for h in hist] == ["R", "G", "B"]
    assert all(len(h["values"].split()) == 256 for h in hist)


def test_query_no_match_and_bad_values(stores):
    r = run_cli("query", "--skin-type", "VI", "--store", stores[1])
    assert r.returncode == 1 and "no subject matches" in r.stdout
    r = run_main("query", "--skin-type", "VI", "--store", stores[1], "--format", "json")
    assert r.returncode == 1 and json.loads(r.stdout)["count"] == 0
    for args, msg in (
        (("--skin-type", "VII"), "--skin-type must be I-VI or 1-6, got 'VII'"),  # the options, not the API's names
        (("--gender", "X"), "--gender must be M or F (or 0 = M, 1 = F), got 'X'"),
        (("--age", "old"), "--age must be 20s, 30s, 40s, 50s+, MIN-MAX or an age in years, got 'old'"),
        (("--age", "50-20"), "--age must satisfy 0 <= MIN <= MAX <= 200, got '50-20'"),  # was "age range must"
        (("--condition", "wet"), "--condition must be one of ['normal', 'cold', 'hot', 'sweaty', "),
        (("--region", "ear"), "--region must be 1-10 or one of ["),
    ):
        r = run_main("query", *args, "--store", stores[1])
        assert r.returncode == 2 and r.stderr.startswith(f"facestats: error: {msg}"), r.stderr
    r = run_main("query", "--store", stores[0].parent / "nope.zarr")
    assert r.returncode == 2 and "does not exist" in r.stderr


def test_query_default_store():
    r = run_cli("query", "--skin-type", "IV")
    if default_store_path().exists():
        assert r.returncode in (0, 1) and "facestats query" in r.stdout
        # every subject's σtr is σtrAvg: no spread, exactly (it printed 0.5517 ± 1.1e-16, the sums' rounding), and
        # labelled a population constant, not "mean ± std across subjects" of "0.5517 ± 0" (a walkthrough)
        assert re.search(r"σtr \(population\) +0\.5517 +0\.9801 +1\.559\n", r.stdout), r.stdout
        doc = json.loads(run_main("query", "--skin-type", "IV", "--format", "json").stdout)
        assert [doc["scattering"]["sigma_tr"][c]["std"] for c in "RGB"] == [0, 0, 0]
        assert [doc["scattering"]["sigma_tr"][c]["constant"] for c in "RGB"] == [True, True, True]
        assert [doc["scattering"]["sigma_a"][c]["constant"] for c in "RGB"] == [False, False, False]
    else:
        assert r.returncode == 2 and "default store has not been built" in r.stderr


def test_info(stores):
    r = run_cli("info", "--store", stores[1])
    assert r.returncode == 0, r.stderr
    assert "schema version:  1" in r.stdout and "subjects:        7" in r.stdout
    assert "skin type      I 1, II 1, III 1, IV 4" in r.stdout
    assert "(zip, read-only)" in r.stdout
    r = run_main("info", "--store", stores[0])  # a directory store: what it allows, not how info opened it
    assert r.returncode == 0 and "(directory, writable)" in r.stdout, r.stderr
    r = run_main("info", "--store", stores[0], "--format", "json")
    info = json.loads(r.stdout)
    assert info["by_gender"] == {"M": 4, "F": 3} and info["by_kind"] == {"maps": 6, "samples": 1}


def test_validate_and_repair(stores, tmp_path):
    import shutil

    r = run_main("validate", "--store", stores[1])
    assert r.returncode == 0 and "store is valid" in r.stdout and "subject/s" in r.stderr  # its progress bar
    r = run_cli("validate", "--store", stores[1], "--quiet")  # a process: nothing at all on its stderr
    assert r.returncode == 0 and "store is valid" in r.stdout and r.stderr == ""
    path = shutil.copytree(stores[0], tmp_path / "c.zarr")
    gen = next((path / "subjects" / "P2").glob("g*"))
    chunk = gen / "ts_m" / "c" / "0" / "0"
    chunk.write_bytes(chunk.read_bytes()[:10])
    r = run_main("validate", "--store", path)
    assert r.returncode == 1 and "problem: subject 'P2': variable 'ts_m' cannot be read" in r.stdout
    r = run_main("validate", "--store", path, "--repair")  # a dry run: the plan, nothing changed
    assert r.returncode == 1 and "drop subject 'P2' from the index" in r.stdout and "dry run" in r.stdout
    assert (path / "subjects" / "P2").exists()
    r = run_main("validate", "--store", path, "--repair", "--yes")  # damaged data go to the quarantine
    assert r.returncode == 0 and "drop subject 'P2' from the index" in r.stdout and "store is valid" in r.stdout
    assert len(list((path / "quarantine").glob("*/subjects/P2/g*"))) == 1
    r = run_main("validate", "--store", tmp_path / "missing")  # a typo is no damage: exit 2, as every command
    assert r.returncode == 2 and "does not exist" in r.stderr and "INVALID" not in r.stdout
    (tmp_path / "file.zarr").write_text("not a store")  # exists, cannot be opened: invalid
    r = run_main("validate", "--store", tmp_path / "file.zarr")
    assert r.returncode == 1 and "INVALID" in r.stdout
    r = run_main("validate", "--store", stores[1], "--purge", "--yes")  # a valid zip store is not "INVALID"
    assert r.returncode == 2 and "is a read-only zip store: --purge --yes needs a directory store" in r.stderr


def test_export_of_an_empty_store_writes_headers_and_no_rows(tmp_path):
    from facestats.io.summary import IDENTITY_COLUMNS

    store = tmp_path / "empty.zarr"
    open_store(store, mode="a").close()
    out = tmp_path / "release"
    r = run_cli("export", "--store", store, "--out", out)
    assert r.returncode == 0, r.stderr
    lines = (out / "subjects.csv").read_text().splitlines()
    assert lines == [",".join(IDENTITY_COLUMNS)]
    assert (out / "albedo_histograms.csv").read_text().splitlines()[0].startswith("subject_id,channel,bin_000")
    assert json.loads((out / "statistics.json").read_text())["subjects"] == []


def test_export(stores, tmp_path):
    out = tmp_path / "release"
    r = run_cli("export", "--store", stores[1], "--out", out)
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader((out / "subjects.csv").open()))
    assert [x["subject_id"] for x in rows] == ["M1", "P1", "P2", "P3", "P4", "P5", "P6"]
    with open_store(stores[1]) as st:
        df = st.subjects()
        hists = st.albedo_histograms()
    assert float(rows[1]["ts_m_mean_r6"]) == df.loc["P1", "ts_m_mean_r6"]
    assert float(rows[1]["site_sigma_tr_neck_B"]) == df.loc["P1", "site_sigma_tr_neck_B"]
    assert rows[0]["site_sigma_tr_neck_B"] == ""  # the sample subject has no sensor data
    hrows = list(csv.reader((out / "albedo_histograms.csv").open()))
    assert hrows[0][:3] == ["subject_id", "channel", "bin_000"] and len(hrows) == 1 + 7 * 3
    np.testing.assert_array_equal([int(v) for v in hrows[1 + 3 * 2 + 1][2:]], hists[2, 1])  # P2, G
    doc = json.loads((out / "statistics.json").read_text())
    assert doc["format"] == "facestats.export/1" and len(doc["subjects"]) == 7
    p1 = doc["subjects"][1]
    assert p1["subject_id"] == "P1" and p1["skin_type_roman"] == "IV"
    nose = p1["brdf"]["torrance_sparrow"][5]
    assert nose["region"] == 6 and nose["m"]["mean"] == df.loc["P1", "ts_m_mean_r6"]
    assert p1["brdf"]["blinn_phong"][5]["exponent"]["std"] == df.loc["P1", "bp_exponent_std_r6"]
    assert p1["scattering"]["sigma_a"]["G"] == df.loc["P1", "sigma_a_G"]
    assert p1["albedo_histogram"]["B"] == hists[1, 2].tolist()
    assert doc["subjects"][0]["sites"]["cheek"]["sigma_tr"]["R"] is None
    assert (out / "README.txt").exists()
    r = run_main("export", "--store", stores[1], "--out", tmp_path / "j", "--format", "json")
    assert r.returncode == 0 and sorted(p.name for p in (tmp_path / "j").iterdir()) == ["README.txt", "statistics.json"]
    (out / "notes.txt").write_text("mine")  # a release in the other format replaces the first, and only it
    r = run_main("export", "--store", stores[0], "--out", out, "--format", "json")
    assert r.returncode == 2 and "which holds an earlier statistics release" in r.stderr  # only with --overwrite
    r = run_main("export", "--store", stores[0], "--out", out, "--format", "json", "--overwrite")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["README.txt", "notes.txt", "statistics.json"]
    before = sorted(p.name for p in (stores[0] / "subjects").iterdir())
    r = run_main("export", "--store", stores[0], "--out", stores[0] / "subjects")  # never into the store
    assert r.returncode == 2 and "--out must lie outside the store" in r.stderr
    assert sorted(p.name for p in (stores[0] / "subjects").iterdir()) == before


def test_import_merl(tmp_path):
    mat = tmp_path / "ts_data.mat"
    scipy.io.savemat(mat, merl_dict())
    out = tmp_path / "merl.zarr"
    r = run_cli("import-merl", mat, "--store", out)
    assert r.returncode == 0, r.stderr
    assert "imported 4 subjects (merl-001 ... merl-004)" in r.stdout
    r = run_main("query", "--store", out, "--gender", "F", "--format", "json")
    assert r.returncode == 0 and json.loads(r.stdout)["subject_ids"] == ["merl-002", "merl-004"]
    r = run_main("import-merl", mat, "--store", out)
    assert r.returncode == 2 and "already exist" in r.stderr
    assert run_main("import-merl", mat, "--store", out, "--overwrite").returncode == 0
    bad = tmp_path / "bad.mat"
    d = merl_dict()
    d["ts_region"][3, 0] = 12
    scipy.io.savemat(bad, d)
    r = run_main("import-merl", bad, "--store", tmp_path / "bad.zarr")
    assert r.returncode == 2 and "ts_region[4] must be a region 1-10, got 12" in r.stderr
    zp = pack_store(out, tmp_path / "m.zip")
    r = run_main("import-merl", mat, "--store", zp)
    assert r.returncode == 2 and "read-only" in r.stderr
    r = run_main("import-merl", mat, "--store", tmp_path / "p.zarr", "--prefix", "a/b")  # the option, not `prefix`
    assert r.returncode == 2 and r.stderr.startswith("facestats: error: --prefix must make subject ids")
    assert "got 'a/b'" in r.stderr and not (tmp_path / "p.zarr").exists()
    r = run_main("import-merl", "", "--store", tmp_path / "e.zarr", cwd=tmp_path)  # was "<cwd>: not a readable ..."
    assert r.returncode == 2 and "import-merl: error: argument PATH: must not be empty, got ''" in r.stderr, r.stderr
    assert not (tmp_path / "e.zarr").exists()


def test_export_into_a_folder_of_other_files_needs_overwrite_and_removes_nothing(stores, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "statistics.json").write_text('{"my": 1}')
    r = run_cli("export", "--store", stores[1], "--out", out, "--format", "csv")
    assert r.returncode == 2 and "--overwrite: replace an earlier release, or write into any folder" in r.stderr
    assert "'statistics.json'" in r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["statistics.json"]
    r = run_main("export", "--store", stores[1], "--out", out, "--format", "csv", "--overwrite")
    assert r.returncode == 0, r.stderr
    assert (out / "statistics.json").read_text() == '{"my": 1}'  # a file of the other format is not removed
    assert sorted(p.name for p in out.iterdir()) == [
        "README.txt",
        "albedo_histograms.csv",
        "statistics.json",
        "subjects.csv",
    ]


def test_errors_name_the_commands_options_not_the_api_parameters(tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "mine.txt").write_text("mine")
    res = run_cli("export", "--out", str(tmp_path / "full"))
    assert res.returncode == 2 and "error: --out must be a new or empty folder" in res.stderr
    res = run_main("build", "--store", str(tmp_path / "x.zarr"), "--size", "2")
    assert res.returncode == 2 and "error: --size must be an integer in [8, inf], got 2" in res.stderr
    res = run_main("build", "--store", str(tmp_path / "x.zarr"), "--size", "8", "--subjects", "S999")
    assert res.returncode == 2 and "error: --subjects must be ids of the population, got unknown ['S999']" in res.stderr
    res = run_main("build", "--store", str(tmp_path / "x.zarr"), "--size", "8", "--subjects", "S001", "")
    assert res.returncode == 2 and "error: --subjects must be 1-64 characters of letters" in res.stderr  # subject_id
    assert res.stderr.rstrip().endswith("got ''"), res.stderr
    res = run_main("build", "--status", "", cwd=tmp_path)  # was "pass --store PATH (a directory store) or --default"
    assert res.returncode == 2 and "build: error: argument --status: must not be empty, got ''" in res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["full"]  # nothing written


def test_the_build_report_says_what_sigma_tr_avg_averages(tmp_path):
    res = run_cli("build", "--store", str(tmp_path / "s.zarr"), "--size", "8", "--subjects", "S001", "--quiet")
    assert res.returncode == 0, res.stderr
    assert "1 subject(s) written" in res.stdout
    assert "the cheek and forehead mean over all 149 subjects of the drawn population under normal" in res.stdout
