"""Store commands: ``facestats query``, ``info``, ``validate``, ``export`` and ``import-merl``.

Each parses its arguments, makes one call to :mod:`facestats.io` and prints.
"""

from __future__ import annotations

import json
import os
import sys

from facestats.cli.options import (
    QUERY_FILTER_OPTIONS,
    add_store_option,
    check_store_to_write,
    named_options,
    non_empty,
    open_store_option,
    store_path_option,
)

__all__ = ["add_query", "add_info", "add_validate", "add_export", "add_import_merl"]


def _can_encode(text: str) -> bool:
    try:
        text.encode(sys.stdout.encoding or "ascii")
        return True
    except (UnicodeEncodeError, LookupError):
        return False


def _cmd_query(args) -> int:

    with open_store_option(args.store) as store, named_options(region="--region", **QUERY_FILTER_OPTIONS):
        result = store.query(
            skin_type=args.skin_type,
            gender=args.gender,
            age=args.age,
            condition=args.condition,
            region=args.region,
            edits=args.edits,
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


def add_query(sub):
    """Register ``facestats query``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        What ``add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    None
        The handler (``func``) returns 0, or 1 when no subject matches the filters; a
        :class:`~facestats.errors.FacestatsError` raised becomes exit status 2 in :func:`facestats.cli.main`.
    """
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
    p.add_argument(
        "--skin-type",
        metavar="TYPE",
        help="Fitzpatrick type I-VI or 1-6, or several separated by commas (V,VI); I and II match both",
    )
    p.add_argument("--gender", metavar="M|F", help="M or F (also male/female, or 0 = M, 1 = F)")
    p.add_argument("--age", metavar="RANGE", help="20s, 30s, 40s, 50s+, MIN-MAX or one age in years")
    p.add_argument(
        "--condition",
        metavar="NAME",
        default="normal",
        help="one of: " + ", ".join(_conditions()) + "; or 'any' to pool every condition (default: normal, the "
        "population as the paper analyses it; one person measured under several conditions would otherwise count "
        "once per condition)",
    )
    p.add_argument("--region", metavar="NAME|N", help="report the BRDF of one face region (1-10 or a name)")
    p.add_argument(
        "--edits",
        action="store_true",
        help="also count subjects written by 'facestats edit' (default: measured subjects only, as 'analyze' does)",
    )
    add_store_option(p)
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

    with open_store_option(args.store) as store:
        info = store.info()
    if args.format == "json":
        print(json.dumps(info, indent=2))
        return 0
    # what the store allows, not the mode `info` opened it in (read-only, to change nothing)
    writable = info["kind"] == "directory" and os.access(info["store"], os.W_OK)
    print(f"store:           {info['store']} ({info['kind']}, {'writable' if writable else 'read-only'})")
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


def add_info(sub):
    """Register ``facestats info``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        What ``add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    None
        The handler (``func``) returns 0; a :class:`~facestats.errors.FacestatsError` raised becomes exit status 2 in
        :func:`facestats.cli.main`.
    """
    p = sub.add_parser(
        "info",
        help="schema and writer versions, subject counts and size of a store",
        description="Describe a parameter store: versions, subject counts by skin type, gender, "
        "age group, condition and kind, and its size on disk.",
    )
    add_store_option(p)
    p.add_argument(
        "--format",
        choices=("text", "json"),
        default="text",
        help="text (default) or json (the same fields, for scripts)",
    )
    p.set_defaults(func=_cmd_info)


def _cmd_validate(args) -> int:
    from facestats.errors import StoreError

    if args.repair and args.purge:
        raise StoreError("--repair and --purge are separate steps: run one, check the result, then the other")
    if (args.yes or args.allow_missing) and not (args.repair or args.purge):
        raise StoreError("--yes and --allow-missing go with --repair (or --yes with --purge)")
    writes = (args.repair or args.purge) and args.yes
    path = store_path_option(args.store) if args.store is not None else None
    if writes and (path is None or os.path.isfile(path)):
        what = "--repair --yes" if args.repair else "--purge --yes"
        raise StoreError(
            f"store {args.store or '(the embedded default)'} is a read-only zip store: {what} needs a directory "
            "store (unpack it, repair the directory, pack it again with facestats.io.pack_store)"
        )
    if path is not None and not os.path.lexists(path):  # a typo, not a damaged store: exit 2 as every command
        raise StoreError(f"store {args.store} does not exist")
    try:
        store = open_store_option(args.store, mode="r+" if writes else "r")
    except StoreError as exc:  # includes SchemaError: an unopenable store is invalid
        print(f"problem: {exc}\nstore is INVALID (1 problem(s))")
        return 1
    with store:
        if args.purge:
            return _purge(store, args.yes)
        if args.repair and not args.yes:
            plan = store.plan_repair(allow_missing=args.allow_missing, progress=not args.quiet)
            sys.stdout.write(plan.to_text())
            return 1 if plan.fixes_problems or plan.problems else 0
        if args.repair:
            report = store.repair(allow_missing=args.allow_missing, progress=not args.quiet)
        else:
            report = store.validate(progress=not args.quiet)
    sys.stdout.write(report.to_text())
    return 0 if report.ok else 1


def _purge(store, yes: bool) -> int:
    """List the quarantine (dry run) or delete it (``--yes``)."""
    entries = store.quarantine()
    if not entries:
        print(f"store {store.label}: the quarantine is empty")
        return 0
    for e in entries:
        if e["valid"]:
            state = ""
        elif e.get("problem"):
            state = f" (its QUARANTINE.json {e['problem']}: never purged; fix the file or remove the folder yourself)"
        else:
            state = " (no QUARANTINE.json: not created by a repair, never purged)"
        print(f"quarantine/{e['name']}: {len(e['items'])} item(s), {e['bytes'] / 1e6:.1f} MB{state}")
        for item in e["items"][:10]:
            print(f"  {item['path']}: {item['why']}")
    if not yes:
        print("dry run: nothing was deleted; add --yes to delete the quarantine for good")
        return 0
    removed = store.purge_quarantine()
    print(f"deleted {len(removed)} quarantine folder(s)")
    return 0


def add_validate(sub):
    """Register ``facestats validate``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        What ``add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    None
        The handler (``func``) returns 0 for a valid store, 1 for problems or a store that exists but cannot be
        opened (with ``--repair`` without ``--yes``: 1 if the plan finds anything to fix); a
        :class:`~facestats.errors.FacestatsError` raised (a store path that does not exist, among them) becomes exit
        status 2 in :func:`facestats.cli.main`.
    """
    p = sub.add_parser(
        "validate",
        help="check every subject of a store and the index (exit 1 if invalid); repair with a plan first",
        description="Open and check every subject (group present, dims, checksums, schema, physical domains) and "
        "compare the population index with the data. Exit 0 if valid, 1 if not. --repair prints what a repair "
        "would do, step by step (nothing is changed); --repair --yes does it: damaged data are moved to the "
        "store's quarantine/ folder (never deleted; each move is listed in the plan), subjects are recovered from "
        "their newest intact committed version, stale index rows recomputed, a lost index rebuilt, leftovers of "
        "interrupted writes removed. --purge --yes deletes the quarantine.",
    )
    add_store_option(p)
    p.add_argument("--repair", action="store_true", help="plan a repair of a directory store (a dry run without --yes)")
    p.add_argument("--purge", action="store_true", help="list the quarantine (delete it with --yes)")
    p.add_argument("--yes", action="store_true", help="apply the repair (or the purge) instead of printing the plan")
    p.add_argument(
        "--allow-missing",
        action="store_true",
        help="repair even if most subject folders are missing (otherwise the store looks unmounted and repair refuses)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_validate)


def _cmd_export(args) -> int:
    from facestats.io.export import export_statistics

    formats = ("csv", "json") if args.format == "both" else (args.format,)
    with open_store_option(args.store) as store:
        with named_options(out_dir="--out"):
            files = export_statistics(store, args.out, formats=formats, overwrite=args.overwrite)
        n = len(store)
    print(f"exported the statistics of {n} subjects:")
    for f in files:
        print(f"  {f}")
    return 0


def add_export(sub):
    """Register ``facestats export``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        What ``add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    None
        The handler (``func``) returns 0; a :class:`~facestats.errors.FacestatsError` raised becomes exit status 2 in
        :func:`facestats.cli.main`.
    """
    p = sub.add_parser(
        "export",
        help="write the per-subject statistics release (CSV/JSON)",
        description="Per subject: metadata, per-region Torrance-Sparrow and Blinn-Phong coefficients, "
        "σa, σ's and σtr per channel and albedo histograms (Weyrich et al. 2006 §7).",
    )
    add_store_option(p)
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    p.add_argument("--format", choices=("csv", "json", "both"), default="both")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="write into a non-empty folder: replace an earlier release there (its files of the other format are "
        "removed), or, in a folder that holds none, replace files of the release's names and remove nothing",
    )
    p.set_defaults(func=_cmd_export)


def _cmd_import_merl(args) -> int:
    from facestats.io.merl import import_merl

    out = check_store_to_write(args.store, "--store")
    with named_options(prefix="--prefix", path="--store"):  # path: open_store's name for the store
        data = import_merl(args.path, out, prefix=args.prefix, overwrite=args.overwrite)
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


def add_import_merl(sub):
    """Register ``facestats import-merl``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        What ``add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    None
        The handler (``func``) returns 0; a :class:`~facestats.errors.FacestatsError` raised becomes exit status 2 in
        :func:`facestats.cli.main`.
    """
    p = sub.add_parser(
        "import-merl",
        help="import a MERL/ETH ts_data.mat file into a store",
        description="Import the Torrance-Sparrow (and albedo) samples of the MERL/ETH Skin "
        "Reflectance Database file ts_data.mat as sample subjects merl-001 ...",
    )
    p.add_argument("path", type=non_empty, metavar="PATH", help="the ts_data.mat file")
    p.add_argument("--store", required=True, metavar="OUT", help="store directory to write (created if missing)")
    p.add_argument("--prefix", default="merl", help="subject id prefix (default merl)")
    p.add_argument("--overwrite", action="store_true", help="replace subjects of the same ids")
    p.set_defaults(func=_cmd_import_merl)
