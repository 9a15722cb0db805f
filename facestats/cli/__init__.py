"""The ``facestats`` command line.

Thin by design: each command parses its arguments, makes one API call and
prints.  Heavy modules are imported inside the commands so that ``facestats
--help`` and ``facestats query`` start quickly.
"""

from __future__ import annotations

import argparse
import os
import sys

from facestats.cli.analyze import add_analyze
from facestats.cli.edit import add_edit
from facestats.core.version import __version__
from facestats.errors import FacestatsError

__all__ = ["main", "build_parser"]


# -- demo ------------------------------------------------------------------------
def _cmd_demo(args) -> int:
    from facestats.model.demo import physics_demo

    report = physics_demo(albedo=args.albedo, sigma_tr=args.sigma_tr, eta=args.eta, plot=args.plot)
    print(report.to_text())
    if args.plot:
        print(f"\nwrote {args.plot}")
    return 0


def _add_demo(sub):
    p = sub.add_parser(
        "demo",
        help="physics demo: scattering coefficients and dipole profiles from a skin albedo",
        description=(
            "Given a skin albedo (total diffuse reflectance per channel) and σtr, print σa, σ's, σtr, ℓd and "
            "the total diffuse reflectance per channel (Weyrich et al. 2006 §5.4) and plot the dipole profiles."
        ),
    )
    p.add_argument(
        "--albedo",
        nargs=3,
        type=float,
        metavar=("R", "G", "B"),
        default=None,
        help="albedo per channel in (0, 1); default: the ColorChecker 'light skin' patch in linear sRGB",
    )
    p.add_argument(
        "--sigma-tr",
        nargs=3,
        type=float,
        metavar=("R", "G", "B"),
        default=None,
        help="σtr in 1/mm; default: Weyrich's σtrAvg = 0.5508 0.9791 1.5497",
    )
    p.add_argument("--eta", type=float, default=1.38, help="relative index of refraction (default 1.38)")
    p.add_argument("--plot", default="dipole_profiles.png", help="where to write the plot (PNG/SVG/PDF); '' for none")
    p.set_defaults(func=_cmd_demo)


# -- store commands ----------------------------------------------------------------
def _store_option(p):
    p.add_argument(
        "--store",
        default=None,
        metavar="PATH",
        help="a store directory (X.zarr) or zip; default: the store embedded in facestats",
    )


def _can_encode(text: str) -> bool:
    try:
        text.encode(sys.stdout.encoding or "ascii")
        return True
    except (UnicodeEncodeError, LookupError):
        return False


def _cmd_query(args) -> int:
    from facestats.io.store import open_store

    with open_store(args.store) as store:
        result = store.query(
            skin_type=args.skin_type, gender=args.gender, age=args.age, condition=args.condition, region=args.region
        )
    if args.format == "json":
        print(result.to_json())
    elif args.format == "csv":
        sys.stdout.write(result.to_csv())
    else:
        sys.stdout.write(result.to_table(ascii=not _can_encode("σ±█⁻¹")))
    if result.count == 0:
        if args.format != "table":
            print("facestats: no subject matches these filters", file=sys.stderr)
        return 1
    return 0


def _add_query(sub):
    p = sub.add_parser(
        "query",
        help="population statistics of the subjects matching skin type, gender, age, condition",
        description=(
            "How many subjects match, the mean and spread across them of the per-region Torrance-Sparrow and "
            "Blinn-Phong parameters, σa, σ's and σtr per channel (per subject and per sensor site) and the "
            "albedo, and the albedo histograms (the interactive applet of Weyrich et al. 2006 §7). Skin types "
            "I and II are grouped, as in the paper. Exit status 1 when nothing matches."
        ),
    )
    p.add_argument("--skin-type", metavar="TYPE", help="Fitzpatrick type I-VI or 1-6 (I and II match both)")
    p.add_argument("--gender", metavar="M|F", help="M or F")
    p.add_argument("--age", metavar="RANGE", help="20s, 30s, 40s, 50s+, MIN-MAX or one age in years")
    p.add_argument("--condition", metavar="NAME", help="one of: " + ", ".join(_conditions()))
    p.add_argument("--region", metavar="NAME|N", help="report the BRDF of one face region (1-10 or a name)")
    _store_option(p)
    p.add_argument(
        "--format",
        choices=("table", "json", "csv"),
        default="table",
        help="table (text, histograms drawn), json (documented, stable) or csv",
    )
    p.set_defaults(func=_cmd_query)


def _conditions():
    from facestats.core.conventions import CONDITIONS

    return CONDITIONS


def _fmt_bytes(n: int) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return str(n)  # pragma: no cover


def _cmd_info(args) -> int:
    from facestats.io.store import open_store

    with open_store(args.store) as store:
        info = store.info()
    if args.format == "json":
        import json

        print(json.dumps(info, indent=2))
        return 0
    print(f"store:           {info['store']} ({info['kind']}, {'read-only' if info['read_only'] else 'read-write'})")
    print(f"schema version:  {info['schema_version']}")
    print(f"written by:      facestats {info['writer_version']}")
    print(f"index revision:  {info['index_revision']} (updated {info['updated']})")
    print(f"subjects:        {info['n_subjects']} ({info['n_persons']} persons)")
    for key, title in (
        ("by_skin_type", "skin type"),
        ("by_gender", "gender"),
        ("by_age_group", "age"),
        ("by_condition", "condition"),
        ("by_kind", "kind"),
    ):
        if info[key]:
            print(f"  {title:<14} " + ", ".join(f"{k} {v}" for k, v in info[key].items()))
    print(f"size on disk:    {_fmt_bytes(info['size_bytes'])}")
    return 0


def _add_info(sub):
    p = sub.add_parser(
        "info",
        help="schema and writer versions, subject counts and size of a store",
        description="Describe a parameter store: versions, subject counts by skin type, gender, "
        "age group, condition and kind, and its size on disk.",
    )
    _store_option(p)
    p.add_argument("--format", choices=("text", "json"), default="text")
    p.set_defaults(func=_cmd_info)


def _cmd_validate(args) -> int:
    from facestats.errors import StoreError
    from facestats.io.store import open_store

    try:
        store = open_store(args.store, mode="r+" if args.repair else "r")
    except StoreError as exc:  # includes SchemaError: an unopenable store is invalid
        print(f"problem: {exc}\nstore is INVALID (1 problem(s))")
        return 1
    with store:
        report = store.validate(repair=args.repair)
    sys.stdout.write(report.to_text())
    return 0 if report.ok else 1


def _add_validate(sub):
    p = sub.add_parser(
        "validate",
        help="check every subject of a store and the index (exit 1 if invalid)",
        description="Open and check every subject (group present, dims, checksums, schema) and "
        "compare the population index with the data. Exit 0 if valid, 1 if not.",
    )
    _store_option(p)
    p.add_argument(
        "--repair",
        action="store_true",
        help="rebuild a lost index, drop broken subjects from it, recompute stale rows and remove what "
        "interrupted writers left (directory stores)",
    )
    p.set_defaults(func=_cmd_validate)


def _cmd_export(args) -> int:
    from facestats.io.export import export_statistics
    from facestats.io.store import open_store

    formats = ("csv", "json") if args.format == "both" else (args.format,)
    with open_store(args.store) as store:
        files = export_statistics(store, args.out, formats=formats)
        n = len(store)
    print(f"exported the statistics of {n} subjects:")
    for f in files:
        print(f"  {f}")
    return 0


def _add_export(sub):
    p = sub.add_parser(
        "export",
        help="write the per-subject statistics release (CSV/JSON)",
        description="Per subject: metadata, per-region Torrance-Sparrow and Blinn-Phong coefficients, "
        "σa, σ's and σtr per channel and albedo histograms (Weyrich et al. 2006 §7).",
    )
    _store_option(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    p.add_argument("--format", choices=("csv", "json", "both"), default="both")
    p.set_defaults(func=_cmd_export)


def _cmd_import_merl(args) -> int:
    from facestats.io.merl import import_merl

    data = import_merl(args.path, args.store, prefix=args.prefix, overwrite=args.overwrite)
    ids = data.ids
    print(f"imported {len(ids)} subjects ({ids[0]} ... {ids[-1]}) from {data.path} into {args.store}")
    print(
        f"  {data.n_ts} Torrance-Sparrow samples, {data.n_albedo} albedo samples"
        + (f" ({data.albedo_channels} channel(s))" if data.albedo_channels else " (no albedo data)")
    )
    if data.empty:
        print(
            f"  {len(data.empty)} subject(s) without samples (imported with empty statistics): "
            + ", ".join(data.empty[:10])
            + (" ..." if len(data.empty) > 10 else "")
        )
    return 0


def _add_import_merl(sub):
    p = sub.add_parser(
        "import-merl",
        help="import a MERL/ETH ts_data.mat file into a store",
        description="Import the Torrance-Sparrow (and albedo) samples of the MERL/ETH Skin "
        "Reflectance Database file ts_data.mat as sample subjects merl-001 ...",
    )
    p.add_argument("path", help="the ts_data.mat file")
    p.add_argument("--store", required=True, metavar="OUT", help="store directory to write (created if missing)")
    p.add_argument("--prefix", default="merl", help="subject id prefix (default merl)")
    p.add_argument("--overwrite", action="store_true", help="replace subjects of the same ids")
    p.set_defaults(func=_cmd_import_merl)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="facestats",
        description="Measure, analyse and edit the appearance of human facial skin (Weyrich et al. 2006).",
    )
    parser.add_argument("--version", action="version", version=f"facestats {__version__}")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND")
    for add in _COMMANDS:
        add(sub)
    return parser


# -- build -----------------------------------------------------------------------------
def _cmd_build(args) -> int:
    from facestats.pipeline import build as _build

    if args.default:
        if args.store:
            print("facestats: error: --default writes the embedded store; do not pass --store", file=sys.stderr)
            return 2
        report = _build.build_default(workers=args.workers, progress=not args.quiet)
    else:
        if not args.store:
            print("facestats: error: pass --store PATH (a directory store) or --default", file=sys.stderr)
            return 2
        report = _build.build_store(
            args.store,
            seed=args.seed,
            map_size=args.size,
            conditions=not args.no_conditions,
            specular=args.specular,
            subjects=args.subjects,
            workers=args.workers,
            micro_normals=not args.no_micro_normals,
            progress=not args.quiet,
        )
    print(report.to_text())
    return 0


def _add_build(sub):
    p = sub.add_parser(
        "build",
        help="simulate and fit a synthetic population into a store (resumable)",
        description=(
            "Draw the synthetic population (published statistics of Weyrich et al. 2006), simulate every subject's "
            "dome and contact-sensor captures, fit the skin model and write each subject to the store as soon as it "
            "is fitted. Rerunning skips subjects already in the store. --default regenerates the store embedded in "
            "the package."
        ),
    )
    p.add_argument("--default", action="store_true", help="regenerate the embedded default store")
    p.add_argument("--store", metavar="PATH", help="directory store to build into (created if missing)")
    p.add_argument("--seed", type=int, default=2006, help="population seed (default 2006, the embedded default's)")
    p.add_argument("--size", type=int, default=48, help="UV map / lumitexel grid size (default 48)")
    p.add_argument("--subjects", nargs="+", metavar="ID", help="only these subject ids")
    p.add_argument("--no-conditions", action="store_true", help="leave out the subject measured under seven conditions")
    p.add_argument(
        "--specular",
        choices=("torrance_sparrow", "blinn_phong"),
        default="torrance_sparrow",
        help="BRDF the simulator renders highlights with",
    )
    p.add_argument("--no-micro-normals", action="store_true", help="do not store per-camera micro-normal maps")
    p.add_argument("--workers", type=int, default=None, help="worker processes (default: number of cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_build)


_COMMANDS = [
    _add_demo,
    _add_query,
    _add_info,
    _add_validate,
    _add_export,
    _add_import_merl,
    _add_build,
    add_analyze,
    add_edit,
]


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        parser.print_help()
        return 0
    try:
        return int(args.func(args) or 0)
    except FacestatsError as exc:
        print(f"facestats: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # pragma: no cover - interactive
        print("facestats: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into e.g. `head`, which closed early
        try:
            sys.stdout = open(os.devnull, "w")
        except OSError:  # pragma: no cover
            pass
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
