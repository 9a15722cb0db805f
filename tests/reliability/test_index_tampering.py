"""Tampered index rows and index files: clear errors naming the subject and field, and a repair that loses nothing.

Every case edits ``index.json`` of a copy of a small store, then: ``query``, ``info`` and ``validate``
exit 1 or 2 naming what is wrong (never a ``TypeError``/``StopIteration`` traceback), a commit
(``import-merl`` into the store) is refused without writing anything, and ``validate --repair
--yes`` brings the store back with every subject's data intact (a recomputable entry is recomputed,
an unusable one dropped and its committed data added back from their record).  The sentinel tree
beside the store is compared after every command: nothing outside the store is touched.
"""

import json

import numpy as np
import pytest
import scipy.io

from .helpers import copy_store, make_store, run, snapshot, subject_digests


def _row(field, value):
    def change(ix):
        ix["subjects"]["R1"]["row"][field] = value

    return change


def _entry(field, value):
    def change(ix):
        ix["subjects"]["R1"][field] = value

    return change


def _hist(change_hist):
    def change(ix):
        change_hist(ix["subjects"]["R1"]["albedo_hist"])

    return change


#: name -> (change of the parsed index, or raw text; words the failing commands must print)
ROW_CASES = {
    "age-text": (_row("age", "thirty"), ("'R1'", "age")),
    "age-null": (_row("age", None), ("'R1'", "age")),
    "age-float": (_row("age", 30.5), ("'R1'", "age")),
    "age-negative": (_row("age", -3), ("'R1'", "age")),
    "age-bool": (_row("age", True), ("'R1'", "age")),
    "skin-type-roman": (_row("skin_type", "IV"), ("'R1'", "skin_type")),
    "gender": (_row("gender", "X"), ("'R1'", "gender")),
    "condition": (_row("condition", "bogus"), ("'R1'", "condition")),
    "kind": (_row("kind", "photos"), ("'R1'", "kind")),
    "subject-id-mismatch": (_row("subject_id", "R2"), ("'R1'", "subject_id")),
    "number-as-text": (_row("ts_m_mean_r6", "0.3"), ("'R1'", "ts_m_mean_r6")),
    "number-as-list": (_row("albedo_mean_R", [0.1]), ("'R1'", "albedo_mean_R")),
    "empty-row": (_entry("row", {}), ("'R1'", "row")),
    "row-list": (_entry("row", []), ("'R1'", "row")),
    "no-row": (lambda ix: ix["subjects"]["R1"].pop("row"), ("'R1'", "row")),
    "ragged-histogram": (_hist(lambda h: h[1].pop()), ("'R1'", "albedo_hist")),
    "histogram-2-rows": (_hist(lambda h: h.pop()), ("'R1'", "albedo_hist")),
    "histogram-negative": (_hist(lambda h: h[0].__setitem__(3, -1)), ("'R1'", "albedo_hist")),
    "histogram-float": (_hist(lambda h: h[0].__setitem__(3, 0.5)), ("'R1'", "albedo_hist")),
    "histogram-bool": (_hist(lambda h: h[2].__setitem__(0, True)), ("'R1'", "albedo_hist")),
    "histogram-null": (_hist(lambda h: h[1].__setitem__(255, None)), ("'R1'", "albedo_hist")),
    "histogram-beyond-2**53": (_hist(lambda h: h[0].__setitem__(7, 2**53 + 1)), ("'R1'", "albedo_hist")),
    "generation-path": (_entry("generation", "../../x"), ("'R1'", "generation")),
    "generation-null": (_entry("generation", None), ("'R1'", "generation")),
    "written-number": (_entry("written", 5), ("'R1'", "written")),
    "entry-text": (lambda ix: ix["subjects"].__setitem__("R1", "x"), ("'R1'",)),
}
FILE_CASES = {
    "nan-literal": (lambda text: text.replace('"age": 28', '"age": NaN', 1), ("index.json", "NaN")),
    "infinity-literal": (lambda text: text.replace('"age": 28', '"age": Infinity', 1), ("index.json",)),
    "truncated": (lambda text: text[: len(text) // 2], ("index.json", "JSON")),
    "empty": (lambda text: "", ("index.json",)),
    "not-an-object": (lambda text: "[1, 2, 3]", ("index.json", "subjects")),
    "subjects-list": (lambda text: '{"format": 1, "subjects": []}', ("index.json", "subjects")),
    "format-2": (lambda text: text.replace('"format": 1', '"format": 2', 1), ("index.json", "format")),
    "revision-text": (
        lambda text: text.replace('"revision": ', '"revision": "x", "r": ', 1),
        ("index.json", "revision"),
    ),
    "deep-nesting": (lambda text: "[" * 100000 + "]" * 100000, ("index.json",)),
    "binary": (lambda text: "\x00\xff\xfe" * 50, ("index.json",)),
}


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    path = make_store(tmp_path_factory.mktemp("tamper") / "s.zarr")
    return path, subject_digests(path)


def _mat(tmp_path):
    rng = np.random.default_rng(3)
    p = tmp_path / "ts_data.mat"
    scipy.io.savemat(
        p,
        {
            "s_count": np.array([[2.0]]),
            "subj_age": np.array([[30.0], [40.0]]),
            "subj_gen": np.array([[0.0], [1.0]]),
            "subj_skintype": np.array([[3.0], [4.0]]),
            "ts": np.column_stack([rng.uniform(0.2, 0.5, 20), rng.uniform(0.05, 0.4, 20)]),
            "ts_region": rng.integers(1, 11, (20, 1)).astype(float),
            "ts_subjec": np.repeat([[1.0], [2.0]], 10, axis=0),
        },
    )
    return p


def _tamper(store, case):
    text = (store / "index.json").read_text()
    if case in ROW_CASES:
        ix = json.loads(text)
        ix["subjects"]["R1"]["row"]["age"] = 28  # known value the file cases can find
        ROW_CASES[case][0](ix)
        text = json.dumps(ix)
    else:
        ix = json.loads(text)
        ix["subjects"]["R1"]["row"]["age"] = 28
        text = FILE_CASES[case][0](json.dumps(ix))
    (store / "index.json").write_text(text)


@pytest.mark.parametrize("case", list(ROW_CASES) + list(FILE_CASES))
def test_tampered_index(base, tmp_path, case):
    store = copy_store(base[0], tmp_path)
    sentinel = tmp_path / "sentinel"
    _tamper(store, case)
    mat = _mat(tmp_path)
    outside = snapshot(sentinel)
    words = (ROW_CASES.get(case) or FILE_CASES[case])[1]
    for argv in (("query", "--skin-type", "III"), ("info",), ("validate",)):
        code, out = run(*argv, "--store", store)
        assert code in (1, 2) and all(w in out for w in words), (argv, code, out)
        assert snapshot(sentinel) == outside, argv
    layout = snapshot(store)
    code, out = run("import-merl", mat, "--store", store)  # a commit must refuse, writing nothing
    assert code == 2 and "index.json" in out, out
    assert snapshot(store) == layout and snapshot(sentinel) == outside
    code, out = run("validate", "--store", store, "--repair", "--yes")
    assert code == 0 and "store is valid" in out, out
    assert snapshot(sentinel) == outside
    assert subject_digests(store) == base[1]  # every subject back, with its data
    code, out = run("query", "--skin-type", "III", "--store", store)
    assert code == 0, out
