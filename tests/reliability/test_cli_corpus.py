"""Every CLI command × malformed arguments: exit 1 or 2, a message naming the argument, no side effect.

The corpus is generated below (:data:`CASES`): for each command a valid base invocation and, per
option, values a hostile user would try (non-numbers, NaN, infinities, superscript digits, paths
under ``/dev/null``, FIFOs, files where folders are due and the reverse, ids with path separators
or newlines, out-of-range numbers).  Each case runs in this process in an empty working directory
and must: exit 1 or 2 (never 0, never 3 — the "unexpected exception" code — and never raise),
print a message containing one of the option's names, leave the working directory empty, create
no store, and leave the input store byte for byte as it was.
"""

import os

import pytest
import scipy.io

from tests.helpers import merl_dict

from .helpers import make_store, run, snapshot

NUMBERS = ["abc", "nan", "inf", "-inf", "1e999", "²", "", "0x10"]
INTS = NUMBERS + ["-1", "1.5", "99999999999999999999999"]
IDS = ["../../x", "S9\n", "", "nope", "²", "a/b"]
STORES = ["/dev/null", "{fifo}", "", "{file}", "{emptydir}", "{missing}"]
OUT_DIRS = ["/dev/null/x", "{file}", "{fifo}", ""]
OUT_FILES = ["/dev/null/x.png", "{emptydir}", "{fifo}", ""]


def _case(command, option, values, names, base=()):
    return [(command, option, v, names, base) for v in values]


CASES = (
    _case("query", "--skin-type", ["²", "VII", "0", "abc", "", "٣"], ["skin type"])
    + _case("query", "--region", ["³", "11", "0", "nose2", ""], ["region"])
    + _case("query", "--age", ["²", "abc", "30-20", "-5", "300", "", "1e3"], ["age"])
    + _case("query", "--gender", ["X", "²", ""], ["gender"])
    + _case("query", "--condition", ["bogus", ""], ["condition"])
    + _case("query", "--format", ["bogus"], ["--format"])
    + _case("query", "--store", STORES, ["store", "path"])
    + _case("info", "--store", STORES, ["store", "path"])
    + _case("info", "--format", ["bogus"], ["--format"])
    + _case("validate", "--store", STORES, ["store", "path"])
    + _case("export", "--out", OUT_DIRS, ["out"])
    + _case("export", "--store", STORES, ["store", "path"], base=("--out", "{new}"))
    + _case("export", "--format", ["bogus", ""], ["--format"], base=("--out", "{new}"))
    + _case(
        "import-merl", "PATH", ["{missing}", "{emptydir}", "{fifo}", "{file}", "/dev/null"], ["ts_data", "/", "file"]
    )
    + _case("import-merl", "--prefix", IDS[:2] + ["", "x" * 70, "a b"], ["prefix"])
    + _case("import-merl", "--store", ["/dev/null/x", "{file}", "{fifo}", ""], ["store", "path"])
    + _case("import-merl", "--store", ["{emptydir}/../file/x"], ["store", "path"])
    + _case("build", "--seed", INTS[:-1], ["seed"], base=("--size", "8"))
    + _case("build", "--size", INTS + ["100000", "7"], ["size", "map_size"])
    + _case("build", "--workers", ["0", "-1", "abc"], ["workers"], base=("--size", "8"))
    + _case("build", "--subjects", ["../x", "S9\n", "nope"], ["subjects", "subject_id"], base=("--size", "8"))
    + _case("build", "--store", ["", "/dev/null/x", "{file}", "{fifo}"], ["store", "path"], base=("--size", "8"))
    + _case("analyze pca", "--out", OUT_DIRS, ["out"])
    + _case("analyze pca", "--format", ["bogus", "xyz"], ["--format"])
    + _case("analyze pca", "--store", STORES, ["store", "path"])
    + _case("analyze cca", "--seed", ["abc", "-1", "1.5"], ["seed"])
    + _case("analyze posterior", "--subject", [i for i in IDS if i], ["subject"])
    + _case("analyze posterior", "--site", ["bogus", "²"], ["site"], base=("--subject", "R1"))
    + _case("edit skin-type R1", "TYPE", ["²", "VII", "0", "abc", ""], ["skin type"])
    + _case("edit skin-type", "SUBJECT", IDS, ["subject"], base=("IV",))
    + _case("edit skin-type R1 IV", "--t", ["-0.5", "1.5", "nan", "abc", "inf"], ["t"])
    + _case("edit skin-type R1 IV", "--out-store", ["/dev/null/x", "{file}", "{fifo}", ""], ["store", "path", "out"])
    + _case("edit skin-type R1 IV", "--images", OUT_DIRS, ["images"])
    + _case("edit skin-type R1 IV", "--seed", ["-1", "abc", "1.5"], ["seed"])
    + _case("edit skin-type R1 IV", "--id", IDS[:2] + ["", "a b"], ["subject_id", "new_id", "id"])
    + _case("edit brdf R1", "--model", ["bogus"], ["--model"], base=("--target", "R2"))
    + _case("edit brdf R1", "--regions", ["³", "11", "0", "nose2", ""], ["region"], base=("--target", "R2"))
    + _case("edit brdf R1", "--target", IDS, ["target", "subject"])
    + _case("edit brdf R1", "--age", ["²", "abc"], ["age"])
    + _case("edit colour R1", "--feather", ["-1", "nan", "abc", "inf"], ["feather"], base=("--target", "R2"))
    + _case("edit colour R1", "--stats", ["{missing}", "{file}", "{fifo}", "{emptydir}"], ["stat", "file", "FILE"])
    + _case("edit colour R1", "--skin-type", ["²", "VII"], ["skin type"])
    + _case("edit texture R1", "--levels", ["-1", "99", "abc"], ["levels"], base=("--target", "R2"))
    + _case("edit texture R1", "--bins", ["0", "1000000000", "abc"], ["bins"], base=("--target", "R2"))
    + _case("edit texture R1", "--iterations", ["-1", "abc"], ["iterations"], base=("--target", "R2"))
    + _case("edit texture R1", "--noise", ["-1", "nan", "inf"], ["noise"], base=("--target", "R2"))
    + _case("edit texture R1", "--seed", ["-1", "abc"], ["seed"], base=("--target", "R2"))
    + _case("edit stats R1", "--out", ["/dev/null/x", "", "{file}/x"], ["out", "path"])
    + _case("edit stats R1", "--bins", ["0", "1000000000", "abc"], ["bins"], base=("--out", "{new}"))
    + _case("edit stats R1", "--levels", ["-1", "99"], ["levels"], base=("--out", "{new}"))
    + _case("demo", "--albedo", [("1.5", "0.3", "0.2"), ("nan", "0.3", "0.2"), ("abc", "1", "1")], ["albedo"])
    + _case("demo", "--sigma-tr", [("-1", "1", "1"), ("0", "0", "0"), ("inf", "1", "1")], ["sigma"])
    + _case("demo", "--eta", ["0.5", "nan", "abc", "1e999"], ["eta"])
    + _case("demo", "--plot", ["/dev/null/x.png", "{emptydir}", "{fifo}", "x.xyz", "{file}.txt"], ["plot"])
)

#: Commands that read ``--store`` (the shared input store) unless the case replaces it.
_READS_STORE = ("query", "info", "validate", "export", "analyze", "edit")


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    store = make_store(root / "s.zarr")
    things = root / "things"
    things.mkdir()
    (things / "file").write_text("not a store")
    (things / "file.txt").write_text("a file")
    (things / "emptydir").mkdir()
    os.mkfifo(things / "fifo")
    mat = root / "ts_data.mat"
    scipy.io.savemat(mat, merl_dict(n=2, k=20, ka=10, albedo_cols=0))
    return store, things, mat


def _fill(value, things, work):
    if isinstance(value, tuple):
        return list(value)
    value = (
        value.replace("{fifo}", str(things / "fifo"))
        .replace("{file}", str(things / "file"))
        .replace("{emptydir}", str(things / "emptydir"))
        .replace("{missing}", str(work / "missing"))
        .replace("{new}", str(work / "new"))
    )
    return [value]


@pytest.mark.parametrize("command, option, value, names, base", CASES, ids=lambda x: repr(x)[:40])
def test_malformed_argument(env, tmp_path, command, option, value, names, base):
    store, things, mat = env
    work = tmp_path / "work"
    work.mkdir()
    argv = command.split()
    if option in ("PATH", "TYPE", "SUBJECT"):
        argv += _fill(value, things, work)
    else:
        argv += [option, *_fill(value, things, work)]
    argv += [x for b in base for x in _fill(b, things, work)]
    if argv[0] in _READS_STORE and "--store" not in argv:
        argv += ["--store", str(store)]
    if argv[0] == "import-merl" and "--store" not in argv:
        argv += ["--store", str(work / "m.zarr")]
    if argv[0] == "import-merl" and option != "PATH":
        argv.insert(1, str(mat))
    if argv[0] == "build" and "--store" not in argv:
        argv += ["--store", str(work / "b.zarr")]
    if argv[0] == "edit" and argv[1] != "stats":
        for opt, default in (("--out-store", work / "e.zarr"), ("--images", work / "img")):
            if opt not in argv:
                argv += [opt, str(default)]
    before, things_before = snapshot(store), snapshot(things)
    code, out = run(*argv, cwd=work, timeout=90)
    assert code in (1, 2), (argv, code, out)
    assert "unexpected" not in out and "Traceback" not in out, out
    assert any(n in out for n in names), (argv, out)
    assert os.listdir(work) == [], (argv, os.listdir(work))  # no store, no file, no folder created
    assert snapshot(store) == before and snapshot(things) == things_before
