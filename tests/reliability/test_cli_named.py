"""The CLI cases issue #12 names, through the installed ``facestats`` console script (a real process).

Each must exit with a clear message (no traceback on stderr) that names the thing, and leave no side
effect: no store created by a command that failed, no ``.lock`` in a directory that is not a store,
no subject committed by an edit whose image folder is unusable.  The cases run in parallel threads
(each in its own process) to keep the suite short.

Two commands are checked on their own: ``calibrate leds`` and ``ingest`` given a FIFO as the
calibration must fail at once (a subprocess timeout catches a command that blocks on it), and an
``ingest`` that fails halfway through a real (tiny) capture must leave no store and no work folder it
created, keep the folders that existed, and leave an existing store as it was.
"""

import json
import os
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import scipy.io

from tests.helpers import merl_dict, run_cli

from .helpers import make_store, snapshot


def _dir_at(rel):
    def change(path):
        (path / rel).unlink()
        (path / rel).mkdir()

    return change


def _file_at(rel):
    def change(path):
        shutil.rmtree(path / rel)
        (path / rel).write_text("a file")

    return change


def _row(field, value=None, raw=None):
    """Tamper with the index row of R1 (``raw`` replaces the text of its age instead)."""

    def change(path):
        ix = json.loads((path / "index.json").read_text())
        entry = ix["subjects"]["R1"]
        entry["row"]["age"] = 28
        if field == "albedo_hist":
            entry["albedo_hist"][1].pop()
        elif field == "row":
            entry["row"] = {}
        elif raw is None:
            entry["row"][field] = value
        text = json.dumps(ix)
        (path / "index.json").write_text(text.replace('"age": 28', raw) if raw else text)

    return change


VARIANTS = {
    "zarr-dir": _dir_at("zarr.json"),
    "index-dir": _dir_at("index.json"),
    "age-text": _row("age", "thirty"),
    "age-nan": _row("age", raw='"age": NaN'),
    "ragged": _row("albedo_hist"),
    "empty-row": _row("row"),
    "writers-file": _file_at(".writers"),
    "subjects-file": _file_at("subjects"),
}


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    root = tmp_path_factory.mktemp("named")
    store = make_store(root / "s.zarr")
    os.mkfifo(root / "fifo")
    (root / "existing.txt").write_text("x")
    (root / "foreign").mkdir()
    (root / "foreign" / "mine.txt").write_text("someone's")
    scipy.io.savemat(root / "ts_data.mat", merl_dict(n=2, k=20, ka=10, albedo_cols=0))
    stores = {}
    for name, change in VARIANTS.items():
        stores[name] = root / f"{name}.zarr"
        shutil.copytree(store, stores[name])
        change(stores[name])
    return root, store, stores


def _cases(root, store, s):
    """(name, argv, words the output must contain, paths that must not exist afterwards)."""
    new = root / "new"
    return [
        ("query skin-type ²", ["query", "--skin-type", "²", "--store", store], ["--skin-type must", "'²'"], []),
        ("query region ³", ["query", "--region", "³", "--store", store], ["region", "'³'"], []),
        (
            "edit regions ²",
            [
                "edit",
                "brdf",
                "R1",
                "--target",
                "R2",
                "--regions",
                "²",
                "--store",
                store,
                "--out-store",
                new / "e1.zarr",
                "--images",
                new / "i1",
            ],
            ["region", "'²'"],
            [new / "e1.zarr", new / "i1"],
        ),
        ("store FIFO", ["query", "--store", root / "fifo"], ["fifo", "FIFO"], []),
        ("store /dev/null", ["info", "--store", "/dev/null"], ["/dev/null"], []),
        ("zarr.json a directory", ["info", "--store", s["zarr-dir"]], ["zarr.json"], []),
        ("index.json a directory", ["query", "--store", s["index-dir"]], ["index.json"], []),
        (
            "index.json a directory: repair",
            ["validate", "--repair", "--yes", "--store", s["index-dir"]],
            ["index.json"],
            [],
        ),
        ("age thirty", ["query", "--store", s["age-text"]], ["'R1'", "age", "thirty"], []),
        ("age NaN", ["info", "--store", s["age-nan"]], ["index.json", "NaN"], []),
        ("ragged histogram", ["query", "--store", s["ragged"]], ["'R1'", "albedo_hist"], []),
        ("empty row", ["info", "--store", s["empty-row"]], ["'R1'", "missing"], []),
        (
            ".writers a file",
            ["edit", "brdf", "R1", "--target", "R2", "--store", s["writers-file"], "--images", new / "i2"],
            [".writers"],
            [new / "i2"],
        ),
        ("subjects a file", ["validate", "--repair", "--yes", "--store", s["subjects-file"]], ["subjects"], []),
        ("plot under /dev/null", ["demo", "--plot", "/dev/null/x.png"], ["plot", "/dev/null"], []),
        ("export under /dev/null", ["export", "--store", store, "--out", "/dev/null/x"], ["out", "/dev/null"], []),
        ("stats under /dev/null", ["edit", "stats", "R1", "--store", store, "--out", "/dev/null/x"], ["/dev/null"], []),
        ("export onto a file", ["export", "--store", store, "--out", root / "existing.txt"], ["existing.txt"], []),
        ("plot extension", ["demo", "--plot", new / "p.xyz"], ["plot", ".xyz"], [new]),
        ("build seed -1", ["build", "--store", new / "b.zarr", "--seed", "-1", "--size", "8"], ["seed", "-1"], [new]),
        (
            "edit seed -1",
            [
                "edit",
                "texture",
                "R1",
                "--target",
                "R2",
                "--seed",
                "-1",
                "--store",
                store,
                "--out-store",
                new / "e3.zarr",
                "--images",
                new / "i3",
            ],
            ["seed", "-1"],
            [new],
        ),
        (
            "build size 100000",
            ["build", "--store", new / "b2.zarr", "--size", "100000"],
            ["--size 100000 needs about", "GiB"],
            [new],
        ),
        (
            "prefix",
            ["import-merl", root / "none.mat", "--store", new / "m.zarr", "--prefix", "../x"],
            ["prefix"],
            [new],
        ),
        (
            "id",
            [
                "edit",
                "brdf",
                "R1",
                "--target",
                "R2",
                "--id",
                "a/b",
                "--store",
                store,
                "--out-store",
                new / "e4.zarr",
                "--images",
                new / "i4",
            ],
            ["--id must be", "a/b"],  # the option, not the API's subject_id
            [new],
        ),
        (
            "images /dev/null",
            [
                "edit",
                "brdf",
                "R1",
                "--target",
                "R2",
                "--store",
                store,
                "--out-store",
                new / "e5.zarr",
                "--images",
                "/dev/null/x",
            ],
            ["images", "/dev/null/x"],
            [new / "e5.zarr"],
        ),
        (
            "store ''",
            ["edit", "brdf", "R1", "--target", "R2", "--store", store, "--out-store", "", "--images", new / "i6"],
            ["--out-store"],
            [new],
        ),
        ("store '' (query)", ["query", "--store", ""], ["--store must name a store", "''"], []),
        (
            "foreign directory",
            ["import-merl", root / "ts_data.mat", "--store", root / "foreign"],
            ["not a facestats store"],
            [],
        ),
        (
            "foreign directory (edit)",
            [
                "edit",
                "brdf",
                "R1",
                "--target",
                "R2",
                "--store",
                store,
                "--out-store",
                root / "foreign",
                "--images",
                new / "i7",
            ],
            ["not a facestats store"],
            [new],
        ),
    ]


def _own(arg, root, k):
    """``arg`` moved from ``root/new`` to case ``k``'s own ``root/new{k}`` (other arguments unchanged)."""
    if isinstance(arg, Path) and arg.is_relative_to(root / "new"):
        return root / f"new{k}" / arg.relative_to(root / "new")
    return arg


def test_the_named_cli_cases(env):
    root, store, stores = env
    # Each case gets its own folder for the outputs it must not leave: run at once, one case's output folder could
    # hold another's parent folder while that one cleaned up, and the parent was then (rightly) left in place.
    cases = [
        (name, [_own(a, root, k) for a in argv], words, [_own(p, root, k) for p in absent])
        for k, (name, argv, words, absent) in enumerate(_cases(root, store, stores))
    ]
    before = {"store": snapshot(store), "foreign": snapshot(root / "foreign")}
    with ThreadPoolExecutor(4) as pool:
        results = list(pool.map(lambda c: run_cli(*c[1], cwd=root, timeout=300), cases))
    for (name, argv, words, absent), r in zip(cases, results):
        out = r.stdout + r.stderr
        assert r.returncode in (1, 2), (name, r.returncode, out)
        assert "Traceback" not in r.stderr and "unexpected" not in r.stderr, (name, r.stderr)
        assert all(w in out for w in words), (name, out)
        assert not [p for p in absent if os.path.exists(p)], (name, [p for p in absent if os.path.exists(p)])
    assert snapshot(store) == before["store"]  # the input store is untouched by every failed command
    assert snapshot(root / "foreign") == before["foreign"] and not (root / "foreign" / ".lock").exists()
    assert not (root / ".lock").exists() and not list(root.glob("*.lock"))


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_a_fifo_calibration_is_refused_at_once(tmp_path):
    """``calibrate leds``: the calibration given, or the default ``TARGET_DIR/dome.json``, a FIFO (no writer)."""
    target = tmp_path / "target"
    target.mkdir()
    os.mkfifo(tmp_path / "dome.json")
    os.mkfifo(target / "dome.json")
    for argv in (["--calibration", tmp_path / "dome.json"], []):
        start = time.monotonic()
        r = run_cli("calibrate", "leds", target, *argv, cwd=tmp_path, timeout=60)  # TimeoutExpired: it blocked
        assert r.returncode == 2, (argv, r.returncode, r.stderr)
        assert "Traceback" not in r.stderr and "unexpected" not in r.stderr, r.stderr
        assert "dome calibration" in r.stderr and "dome.json" in r.stderr and "not a regular file" in r.stderr
        assert time.monotonic() - start < 30
    assert sorted(os.listdir(tmp_path)) == ["dome.json", "target"] and os.listdir(target) == ["dome.json"]


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    """A capture folder: a 16-grid subject photographed by 4 cameras under 6 LEDs at 96² pixels (about 3 s)."""
    from facestats.acquire.dome import default_dome
    from facestats.acquire.synthetic.photographs import write_capture_photographs
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.face.procedural import procedural_face

    truth = synthesize_population(map_size=16, geometry=procedural_face(16), conditions=False, subjects=["S011"])[
        "S011"
    ]
    dome = default_dome().select(leds=[0, 1, 2, 5, 9, 14], cameras=[3, 4, 11, 12]).resized(96, 96)
    root = tmp_path_factory.mktemp("photos")
    pc = write_capture_photographs(truth, root / "photos", geometry=procedural_face(16), dome=dome, seed=1)
    return pc.folder.parent


def test_a_failed_ingest_leaves_no_store_and_no_work_folder(photos, tmp_path):
    """The last camera's last frame is damaged: the ingest fails after three cameras are on disk."""
    bad = tmp_path / "photos"
    shutil.copytree(photos, bad)
    last = sorted((bad / "cam03").glob("*.png"))[-1]
    last.write_bytes(last.read_bytes()[:100])
    runs = tmp_path / "runs"
    runs.mkdir()
    existing = make_store(runs / "existing.zarr")
    (runs / "kept").mkdir()
    os.mkfifo(runs / "fifo.json")
    before = snapshot(existing)

    def ingest(store, *extra, calibration=bad / "dome.json"):
        args = ["ingest", bad, "--mesh", bad / "face.obj", "--calibration", calibration, "--store", store]
        return run_cli(*args, "--subject", "X1", "--quiet", *extra, cwd=runs, timeout=300)

    cases = [
        (ingest(runs / "new.zarr"), ["cam03/", "checksum"]),  # the default work folder, <store>.ingest/X1
        (ingest(runs / "new.zarr", "--work", runs / "kept" / "capture.zarr"), ["cam03/", "checksum"]),
        (ingest(runs / "deep" / "er" / "new.zarr"), ["cam03/", "checksum"]),
        (ingest(existing), ["cam03/", "checksum"]),
        (ingest(runs / "new.zarr", calibration=runs / "fifo.json"), ["fifo.json", "not a regular file"]),
    ]
    for r, words in cases:
        assert r.returncode == 2, (r.returncode, r.stderr)
        assert "Traceback" not in r.stderr and "unexpected" not in r.stderr, r.stderr
        assert all(w in r.stderr for w in words), (words, r.stderr)
    # No new store, no work folder; the folder that existed stays (empty); the existing store is as it was.
    assert sorted(os.listdir(runs)) == ["existing.zarr", "fifo.json", "kept"], os.listdir(runs)
    assert os.listdir(runs / "kept") == []
    assert snapshot(existing) == before
