"""Every CLI command × malformed arguments: exit 1 or 2, a message naming the argument, no side effect.

The corpus is generated below (:data:`CASES`): for each command a valid base invocation and, per
option, values a hostile user would try (non-numbers, NaN, infinities, superscript digits and
other scripts' digits, paths under ``/dev/null``, FIFOs, files where folders are due and the
reverse, ids with path separators or newlines, out-of-range numbers).  Each case runs in this
process in an empty working directory and must: exit 1 or 2 (exactly 2 for the commands of
:data:`EXIT_2`; never 0, never 3 — the "unexpected exception" code — and never raise), print a
message containing one of the option's names, leave the working directory empty, create no store,
and leave the input store and the tree of things beside it byte for byte as they were.

The cases of the device, rendering and server commands (:data:`EXIT_2`) use only arguments that
fail before any work starts (no server is started, no frame rendered); :data:`KNOWN_FAILURES`
are cases that still fail the rules, marked strict xfail until the code they name is fixed.
"""

import argparse
import os
import pathlib

import pytest
import scipy.io

from facestats.cli import build_parser
from facestats.cli.options import ascii_float, ascii_int
from tests.helpers import merl_dict

from .helpers import make_store, run, snapshot

NUMBERS = ["abc", "nan", "inf", "-inf", "1e999", "²", "٣", "", "0x10"]
INTS = NUMBERS + ["-1", "1.5", "99999999999999999999999"]
IDS = ["../../x", "S9\n", "", "nope", "²", "a/b"]
STORES = ["/dev/null", "{fifo}", "", "{file}", "{emptydir}", "{missing}"]
OUT_DIRS = ["/dev/null/x", "{file}", "{fifo}", ""]
OUT_FILES = ["/dev/null/x.png", "{emptydir}", "{fifo}", ""]


def _case(command, option, values, names, base=()):
    return [(command, option, v, names, base) for v in values]


CASES = (
    _case("query", "--skin-type", ["²", "VII", "0", "abc", "", "٣"], ["--skin-type"])
    + _case("query", "--region", ["³", "11", "0", "nose2", ""], ["--region"])
    + _case("query", "--age", ["²", "abc", "30-20", "-5", "300", "", "1e3"], ["--age"])
    + _case("query", "--gender", ["X", "²", ""], ["--gender"])
    + _case("query", "--condition", ["bogus", ""], ["--condition"])
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
    + _case("import-merl", "--prefix", IDS[:2] + ["", "x" * 70, "a b"], ["--prefix"])
    + _case("import-merl", "--store", ["/dev/null/x", "{file}", "{fifo}", ""], ["store", "path"])
    + _case("import-merl", "--store", ["{emptydir}/../file/x"], ["store", "path"])
    + _case("build", "--seed", INTS[:-1], ["seed"], base=("--size", "8"))
    + _case("build", "--size", INTS + ["100000", "7"], ["size", "map_size"])
    + _case("build", "--workers", ["0", "-1", "abc"], ["workers"], base=("--size", "8"))
    + _case("build", "--subjects", ["../x", "S9\n", "nope"], ["--subjects"], base=("--size", "8"))
    + _case("build", "--store", ["", "/dev/null/x", "{file}", "{fifo}"], ["store", "path"], base=("--size", "8"))
    + _case("analyze pca", "--out", OUT_DIRS, ["out"])
    + _case("analyze pca", "--format", ["bogus", "xyz"], ["--format"])
    + _case("analyze pca", "--store", STORES, ["store", "path"])
    + _case("analyze cca", "--seed", ["abc", "-1", "1.5"], ["--seed"])
    + _case("analyze posterior", "--subject", [i for i in IDS if i], ["subject"])
    + _case("analyze posterior", "--site", ["bogus", "²"], ["--site"], base=("--subject", "R1"))
    + _case("edit skin-type R1", "TYPE", ["²", "VII", "0", "abc", ""], ["TYPE"])
    + _case("edit skin-type", "SUBJECT", IDS, ["subject"], base=("IV",))
    + _case("edit skin-type R1 IV", "--t", ["-0.5", "1.5", "nan", "abc", "inf"], ["t"])
    + _case("edit skin-type R1 IV", "--out-store", ["/dev/null/x", "{file}", "{fifo}", ""], ["store", "path", "out"])
    + _case("edit skin-type R1 IV", "--images", OUT_DIRS, ["images"])
    + _case("edit skin-type R1 IV", "--seed", ["-1", "abc", "1.5"], ["seed"])
    + _case("edit skin-type R1 IV", "--id", IDS[:2] + ["", "a b"], ["subject_id", "new_id", "id"])
    + _case("edit brdf R1", "--model", ["bogus"], ["--model"], base=("--target", "R2"))
    + _case("edit brdf R1", "--regions", ["³", "11", "0", "nose2", ""], ["--regions"], base=("--target", "R2"))
    + _case("edit brdf R1", "--target", IDS, ["target", "subject"])
    + _case("edit brdf R1", "--age", ["²", "abc"], ["--age"])
    + _case("edit colour R1", "--feather", ["-1", "nan", "abc", "inf"], ["feather"], base=("--target", "R2"))
    + _case("edit colour R1", "--stats", ["{missing}", "{file}", "{fifo}", "{emptydir}"], ["stat", "file", "FILE"])
    + _case("edit colour R1", "--skin-type", ["²", "VII"], ["--skin-type"])
    + _case("edit texture R1", "--levels", ["-1", "99", "abc"], ["--levels"], base=("--target", "R2"))
    + _case("edit texture R1", "--bins", ["0", "1000000000", "abc"], ["bins"], base=("--target", "R2"))
    + _case("edit texture R1", "--iterations", ["-1", "abc"], ["iterations"], base=("--target", "R2"))
    + _case("edit texture R1", "--noise", ["-1", "nan", "inf"], ["noise"], base=("--target", "R2"))
    + _case("edit texture R1", "--seed", ["-1", "abc"], ["seed"], base=("--target", "R2"))
    + _case("edit stats R1", "--out", ["/dev/null/x", "", "{file}/x"], ["--out"])
    + _case("edit stats R1", "--bins", ["0", "1000000000", "abc"], ["--bins"], base=("--out", "{new}"))
    + _case("edit stats R1", "--levels", ["-1", "99"], ["--levels"], base=("--out", "{new}"))
    + _case("demo", "--albedo", [("1.5", "0.3", "0.2"), ("nan", "0.3", "0.2"), ("abc", "1", "1")], ["albedo"])
    + _case("demo", "--sigma-tr", [("-1", "1", "1"), ("0", "0", "0"), ("inf", "1", "1")], ["sigma"])
    + _case("demo", "--eta", ["0.5", "nan", "abc", "1e999", "١.٤"], ["eta"])
    + _case("demo", "--plot", [""], ["argument --plot: must not be empty"])
    + _case("analyze posterior", "--subject", [""], ["argument --subject: must not be empty"])
    + _case("analyze posterior", "--site", [""], ["argument --site: must not be empty"], base=("--subject", "R1"))
    + _case("analyze scatter", "--site", [""], ["argument --site: must not be empty"])
    + _case("import-merl", "PATH", [""], ["argument PATH: must not be empty"])
    + _case("build", "--status", [""], ["argument --status: must not be empty"])
    + _case("edit brdf R1", "--condition", [""], ["argument --condition: must not be empty"])
    + _case("edit brdf R1", "--gender", [""], ["argument --gender: must not be empty"], base=("--skin-type", "IV"))
    + _case("edit colour R1", "--stats", [""], ["argument --stats: must not be empty"])
    + _case("demo", "--plot", ["/dev/null/x.png", "{emptydir}", "{fifo}", "x.xyz", "{file}.txt"], ["plot"])
)

#: Base arguments of the device and rendering commands: inputs that do not exist, outputs in the work folder.
_EXPORT = ("R1", "--out", "{new}")
_MITSUBA = _EXPORT + ("--format", "mitsuba")
_RELIT = ("R1", "--out", "{new}.exr")
_PROBE = ("--probe", "{missing}.hdr")
_MICRO_INPUTS = ("--frames", "{missing}", "--map", "{missing}", "--out", "{new}.zarr")
_MICRO = ("--neutral", "{missing}") + _MICRO_INPUTS
_GENERATE = ("--out", "{new}.exr")
_SCENE_FILES = ("--camera", "{missing}", "--image", "{missing}")
_SCENE = ("{missing}", "--lights", "{missing}") + _SCENE_FILES
_INGEST_INPUTS = ("{emptydir}", "--mesh", "{missing}", "--calibration", "{missing}")
_INGEST = _INGEST_INPUTS + ("--store", "{new}.zarr")
_INGEST_NO_MESH = ("{emptydir}", "--calibration", "{missing}", "--store", "{new}.zarr", "--subject", "X1")
_EMULATE_DIRS = ("--quiet", "--hot-folder", "{new}/hot", "--lab", "{new}/lab")
_EMULATE = ("--duration", "0.1") + _EMULATE_DIRS
_EMULATE_LAB = ("--duration", "0.1", "--quiet", "--lab", "{new}/lab")  # cases of --hot-folder
_EMULATE_HOT = ("--duration", "0.1", "--quiet", "--hot-folder", "{new}/hot")  # cases of --lab
_LINE = ("--port", "{missing}", "--out", "{new}", "--hot-folder", "{new}/hot")
_RECORD = ("--age", "30", "--gender", "F", "--skin-type", "3")  # cases of --age and --skin-type leave theirs out
_CALIBRATION = ("--calibration", "{missing}")
_X1 = ("--subject", "X1")
_CAPTURE = _LINE + _X1 + _CALIBRATION + _RECORD
_TARGET = ("{emptydir}",)
_UNIS = tuple(
    str(p) for p in sorted((pathlib.Path(__file__).resolve().parents[1] / "data" / "unis-bracket").glob("*.jpg"))
)
_UNIS_DOME = _UNIS + ("--write-calibration", "{new}")

CASES += (
    _case("export-subject", "ID", ["../../x", "S9\n", "nope"], ["ID must", "subject 'nope'"], base=("--out", "{new}"))
    + _case("export-subject", "--out", ["/dev/null/x", "{file}", "{fifo}"], ["out", "/dev/null"], base=("R1",))
    + _case("export-subject", "--width", ["abc", "١٦", "1e9"], ["width"], base=_MITSUBA)
    + _case("export-subject", "--spp", ["1.5"], ["spp"], base=_MITSUBA)
    + _case("export-subject", "--mesh", ["{missing}", "{fifo}"], ["mesh"], base=_EXPORT)
    + _case("export-subject", "--probe", ["{missing}", "{fifo}"], ["probe"], base=_MITSUBA)
    + _case("export-subject", "--format", ["bogus"], ["--format"], base=_EXPORT)
    + _case("render", "ID", ["../../x", "nope"], ["ID must", "subject 'nope'"], base=("--out", "{new}"))
    + _case("render", "--camera", ["abc", "١"], ["camera"], base=("R1", "--out", "{new}"))
    + _case("render", "--light", ["2e3"], ["light"], base=("R1", "--out", "{new}"))
    + _case("render", "--capture", ["{missing}", "{fifo}"], ["capture"], base=("R1", "--out", "{new}"))
    + _case("relight", "--probe", ["{missing}", "{fifo}", "{file}.txt"], ["probe"], base=_RELIT)
    + _case("relight", "--out", ["x.png", ""], ["out"], base=("R1",) + _PROBE)
    + _case("relight", "--size", ["١"], ["size"], base=_RELIT + _PROBE)
    + _case("relight", "SOURCE", [""], ["argument SOURCE: must not be empty"], base=("--out", "{new}.exr") + _PROBE)
    + _case("relight", "--png", [""], ["argument --png: must not be empty"], base=_RELIT + _PROBE)
    + _case("relight", "--lights", ["100000x100000"], ["--lights must make at most 268435456"], base=_RELIT + _PROBE)
    + _case("relight", "--rotate", ["abc"], ["rotate"], base=_RELIT + _PROBE)
    + _case("relight", "--layout", ["bogus"], ["--layout"], base=_RELIT + _PROBE)
    + _case("relight", "--turntable", ["abc", "١", "0", "-3", "100000"], ["turntable"], base=_RELIT + _PROBE)
    + _case("relight", "--ratio", ["abc", "0", "nan", "-1"], ["ratio"], base=_RELIT + _PROBE + ("--turntable", "2"))
    + _case("serve", "--port", ["abc", "-1", "70000", "١", "1.5"], ["--port"])
    + _case("serve", "--store", ["{fifo}", "{missing}", ""], ["store", "path"])
    + _case("microstructure generate", "--size", ["abc", "١"], ["size"], base=_GENERATE)
    + _case("microstructure generate", "--size", ["0", "1", "-5", "100000"], ["--size"], base=_GENERATE)
    + _case("microstructure generate", "--texel-um", ["0", "nan"], ["texel"], base=_GENERATE)
    + _case("microstructure generate", "--texel-um", ["-1", "inf", "2000"], ["--texel-um"], base=_GENERATE)
    + _case("microstructure generate", "--out", ["x.xyz"], ["out", ".exr"])
    + _case("microstructure generate", "--out", ["/dev/null/x.exr", "{emptydir}", "{fifo}", "{file}", ""], ["--out"])
    + _case("microstructure generate", "--seed", ["-1"], ["--seed"], base=_GENERATE)
    + _case(
        "microstructure render", "--neutral", ["{missing}"], ["--neutral must name an existing"], base=_MICRO_INPUTS
    )
    + _case(
        "microstructure render", "--neutral", ["{emptydir}"], ["--neutral must be an ICT-FaceKit"], base=_MICRO_INPUTS
    )
    + _case(
        "microstructure render", "--neutral", ["{file}.txt"], ["--neutral must be .obj or .ply"], base=_MICRO_INPUTS
    )
    + _case("microstructure render", "--tile", ["١"], ["tile"], base=_MICRO)
    + _case("microstructure render", "--window", [("1", "2", "3", "x")], ["window"], base=_MICRO)
    + _case("translucency", "--lights", ["{missing}", "{emptydir}"], ["light"], base=_SCENE[:1] + _SCENE_FILES)
    + _case("translucency", "--spacing", ["١"], ["spacing"], base=_SCENE)
    + _case("translucency", "--eta", ["١.٤"], ["eta"], base=_SCENE)
    + _case("translucency", "--method", ["bogus"], ["--method"], base=_SCENE)
    + _case("translucency", "--json", [""], ["argument --json: must not be empty"], base=_SCENE)
    + _case("translucency", "--plot", [""], ["argument --plot: must not be empty"], base=_SCENE)
    + _case("ingest", "--subject", ["../x", "S9\n"], ["--subject"], base=_INGEST)
    + _case("ingest", "--subject", ["X1"], ["mesh"], base=_INGEST)  # the store is created after the inputs' checks
    + _case("ingest", "--mesh", ["{fifo}", "{emptydir}", "{file}"], ["mesh"], base=_INGEST_NO_MESH)
    + _case("ingest", "--work", ["/dev/null/x", "{file}", "{fifo}"], ["work"], base=_INGEST + _X1)
    + _case("ingest", "--workers", ["١"], ["workers"], base=_INGEST + _X1)
    + _case("ingest", "--workers", ["0", "-1"], ["--workers"], base=_INGEST + _X1)
    + _case("ingest", "--motion-tolerance", ["abc"], ["motion-tolerance"], base=_INGEST + _X1)
    + _case("ingest", "--motion-tolerance", ["0", "-1", "nan", "inf"], ["--motion-tolerance"], base=_INGEST + _X1)
    + _case("ingest", "--min-footprint", ["-1", "nan"], ["--min-footprint"], base=_INGEST + _X1)
    + _case("ingest", "--store", ["/dev/null/x", "{fifo}", "{file}", ""], ["store", "path"], base=_INGEST_INPUTS + _X1)
    + _case("calibrate leds", "TARGET_DIR", ["{missing}", "{file}"], ["calibration"])
    + _case("calibrate leds", "--grid", ["١"], ["grid"], base=_TARGET)
    + _case("calibrate leds", "--reference-camera", ["abc"], ["reference-camera"], base=_TARGET)
    + _case("calibrate leds", "--calibration", ["{file}", "{emptydir}"], ["calibration"], base=_TARGET)
    + _case("calibrate leds", "--calibration", ["{fifo}", "/dev/null"], ["calibration"], base=_TARGET)  # no blocking
    + _case("calibrate leds", "--output", ["/dev/null/x", "{emptydir}", "{fifo}", ""], ["--output"], base=_TARGET)
    + _case("calibrate leds", "--write-calibration", ["/dev/null/x"], ["--write-calibration"], base=_TARGET)
    + _case(
        "calibrate response",
        "IMAGE",
        ["{missing}", "{emptydir}", "{fifo}", "/dev/null"],
        ["photograph"],
        base=_UNIS[:1],
    )
    + _case("calibrate response", "IMAGE", ["{file}"], ["EXIF"], base=_UNIS[:1])
    + _case(
        "calibrate response",
        "--times",
        [("nan", "1", "2"), ("-1", "1", "2"), ("0", "1", "2")],
        ["--times must"],  # the option, not the API's exposure_times
        base=("--",) + _UNIS,
    )
    + _case("calibrate response", "--times", ["abc", "١"], ["times"], base=("--",) + _UNIS)
    + _case("calibrate response", "--bits", ["0", "17", "abc"], ["bits"], base=_UNIS)
    + _case("calibrate response", "--bits", ["7"], ["bit"], base=_UNIS)
    + _case("calibrate response", "--smoothness", ["-1", "nan", "inf", "abc"], ["smoothness"], base=_UNIS)
    + _case("calibrate response", "--samples", ["bogus", "-5", "1"], ["samples"], base=_UNIS)
    + _case("calibrate response", "--output", ["/dev/null/x", "{emptydir}", "{fifo}", ""], ["--output"], base=_UNIS)
    + _case("calibrate response", "--plot", ["x.gif", "/dev/null/x.png", "{emptydir}"], ["--plot"], base=_UNIS)
    + _case("calibrate response", "--calibration", ["{file}", "{fifo}", "{missing}"], ["calibration"], base=_UNIS_DOME)
    + _case("calibrate response", "--write-calibration", ["/dev/null/x", "{new}"], ["--write-calibration"], base=_UNIS)
    + _case("emulate dome", "--map-size", ["١"], ["map-size"], base=_EMULATE)
    + _case("emulate dome", "--map-size", ["0", "1", "-3"], ["--map-size"], base=_EMULATE)
    + _case("emulate sensor", "--map-size", ["0"], ["--map-size"], base=_EMULATE)
    + _case("emulate dome", "--drop", ["-1", "nan"], ["drop"], base=_EMULATE)
    + _case("emulate dome", "--drop", ["200", "inf"], ["--drop"], base=_EMULATE)
    + _case("emulate dome", "--seed", ["abc"], ["seed"], base=_EMULATE)
    + _case("emulate dome", "--seed", ["-1"], ["--seed"], base=_EMULATE)  # before the start-up (seconds to minutes)
    + _case("emulate sensor", "--seed", ["-1"], ["--seed"], base=_EMULATE)
    + _case("emulate dome", "--fault-seed", ["-1"], ["--fault-seed"], base=_EMULATE)
    + _case("emulate dome", "--disconnect-after", ["x"], ["disconnect-after"], base=_EMULATE)
    + _case("emulate dome", "--disconnect-after", ["0"], ["--disconnect-after"], base=_EMULATE)
    + _case("emulate dome", "--reboot-after", ["-1"], ["--reboot-after"], base=_EMULATE)
    + _case("emulate dome", "--stall-seconds", ["-1"], ["stall"], base=_EMULATE)
    + _case("emulate dome", "--duration", ["-1", "nan", "inf", "-inf", "0"], ["--duration"], base=_EMULATE_DIRS)
    + _case("emulate sensor", "--duration", ["-1", "nan"], ["--duration"], base=_EMULATE_DIRS)
    + _case("emulate dome", "--workers", ["0", "-2"], ["--workers"], base=_EMULATE)
    + _case("emulate dome", "--wired-leds", ["0"], ["--wired-leds"], base=_EMULATE)
    + _case("emulate dome", "--leds", ["0", "151"], ["--leds"], base=_EMULATE)
    + _case("emulate dome", "--cameras", ["0", "17"], ["--cameras"], base=_EMULATE)
    + _case("emulate dome", "--resolution", ["4", "100000"], ["--resolution"], base=_EMULATE)
    + _case("emulate dome", "--subject", ["nope", "../x"], ["--subject"], base=_EMULATE)
    + _case("emulate dome", "--store", ["{missing}", "{fifo}", "{emptydir}"], ["store"], base=_EMULATE)
    + _case("emulate dome", "--link", ["{file}", "{emptydir}", "/dev/null/x"], ["link"], base=_EMULATE)
    + _case("emulate dome", "--cache", ["{file}", "/dev/null/x"], ["cache"], base=_EMULATE)
    + _case("emulate dome", "--hot-folder", ["{file}", "/dev/null/x", "{fifo}"], ["--hot-folder"], base=_EMULATE_LAB)
    + _case("emulate sensor", "--lab", ["{file}", "/dev/null/x"], ["lab"], base=_EMULATE_HOT)
    + _case("emulate sensor", "--garble", ["200"], ["garble"], base=_EMULATE)
    + _case("emulate sensor", "--duration", ["abc"], ["duration"], base=_EMULATE_DIRS)
    + _case("capture dome", "--colour", ["٢,1,1", "a,b,c"], ["colour"], base=_CAPTURE)
    + _case("capture dome", "--brightness", ["١"], ["brightness"], base=_CAPTURE)
    + _case("capture dome", "--baudrate", ["abc"], ["baudrate"], base=_CAPTURE)
    + _case("capture dome", "--bytesize", ["9"], ["bytesize"], base=_CAPTURE)
    + _case("capture dome", "--stopbits", ["3"], ["stopbits"], base=_CAPTURE)
    + _case("capture sensor", "--timeout", ["abc"], ["timeout"], base=_CAPTURE)
    + _case("capture sensor", "--port", [""], ["argument --port: must not be empty"], base=_CAPTURE[2:])
    + _case("capture sensor", "--out", [""], ["argument --out: must not be empty"], base=_CAPTURE[:2] + _CAPTURE[4:])
    + _case("capture sensor", "--person", [""], ["argument --person: must not be empty"], base=_CAPTURE)
    + _case("capture sensor", "--age", ["١", "300"], ["age"], base=_LINE + _X1 + _CALIBRATION + _RECORD[2:])
    + _case(
        "capture sensor",
        "--skin-type",
        ["٣", "7"],
        ["--skin-type"],
        base=_LINE + _X1 + _CALIBRATION + _RECORD[:4],
    )
    + _case("capture sensor", "--subject", ["../x", "S9\n"], ["--subject"], base=_LINE + _CALIBRATION + _RECORD)
    + _case("capture sensor", "--calibration", ["{missing}", "{file}"], ["calibration"], base=_LINE + _X1 + _RECORD)
    + _case(
        "capture sensor", "--metadata", ["{missing}", "{emptydir}"], ["subject record"], base=_LINE + _X1 + _CALIBRATION
    )
)

#: Commands whose malformed arguments must exit with status 2 exactly (argparse's, or a facestats error).
EXIT_2 = (
    "export-subject",
    "render",
    "relight",
    "serve",
    "microstructure",
    "translucency",
    "ingest",
    "calibrate",
    "emulate",
    "capture",
)

#: Cases that still break the rules, each for a reason in code outside the CLI, as
#: ``pytest.param(*case, marks=pytest.mark.xfail(strict=True, reason=...))`` (strict: fixing it fails the test,
#: and the mark goes).  None at present: the last three (``microstructure generate --out /dev/null/x.exr``,
#: ``ingest`` creating its store before checking the mesh, ``emulate dome --map-size 0`` creating its folders
#: first) are ordinary cases above, as are the cases that used to block (``calibrate leds --calibration FIFO``)
#: or start the emulator before failing (``emulate dome --seed -1``).
KNOWN_FAILURES = []

#: Commands that read ``--store`` (the shared input store) unless the case replaces it.
_READS_STORE = (
    "query",
    "info",
    "validate",
    "export",
    "analyze",
    "edit",
    "export-subject",
    "render",
    "relight",
    "serve",
)


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


@pytest.mark.parametrize("command, option, value, names, base", CASES + KNOWN_FAILURES, ids=lambda x: repr(x)[:40])
def test_malformed_argument(env, tmp_path, command, option, value, names, base):
    store, things, mat = env
    work = tmp_path / "work"
    work.mkdir()
    argv = command.split()
    if option.isupper():  # a positional argument (PATH, TYPE, SUBJECT, ID, TARGET_DIR)
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
    assert code == 2 if argv[0] in EXIT_2 else code in (1, 2), (argv, code, out)
    assert "unexpected" not in out and "Traceback" not in out, out
    assert any(n in out for n in names), (argv, out)
    assert os.listdir(work) == [], (argv, os.listdir(work))  # no store, no file, no folder created
    assert snapshot(store) == before and snapshot(things) == things_before


def _actions(parser):
    """Every argument of ``parser`` and of its subcommands, recursively."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _actions(sub)
        else:
            yield action


def test_every_numeric_option_takes_ascii_digits_only():
    """``type=int``/``float`` take other scripts' digits ('١.٤' is 1.4): every numeric option uses the ASCII types."""
    actions = list(_actions(build_parser()))
    plain = sorted({a.option_strings[0] if a.option_strings else a.dest for a in actions if a.type in (int, float)})
    assert plain == [], f"numeric options parsed with int/float: {plain}"
    numeric = [a for a in actions if a.type in (ascii_int, ascii_float)]
    assert len(numeric) > 50
    for a in numeric:
        for text in ("١.٤", "٣", "²", "１"):
            with pytest.raises(argparse.ArgumentTypeError, match="ASCII"):
                a.type(text)
    assert ascii_int("-12") == -12 and ascii_float("1.5e3") == 1500.0
