"""``facestats build``: simulate and fit a synthetic population into a store (:mod:`facestats.pipeline.build`)."""

from __future__ import annotations

import sys

from facestats.cli.interrupts import is_interrupt
from facestats.cli.options import ascii_int, check_store_to_write, named_options, non_empty
from facestats.core.conventions import DEFAULT_FACE, DEFAULT_MAP_SIZE, DEFAULT_SEED

__all__ = ["add_build"]


def _cmd_build(args) -> int:
    try:
        return _build_command(args)
    except BaseException as exc:  # a Ctrl-C may come back from compiled code as another error (cli.interrupts)
        if not is_interrupt(exc):
            raise
        print(
            "facestats: build interrupted; the subjects finished so far are stored (each write is atomic): rerun "
            "the same command to resume",
            file=sys.stderr,
        )
        return 130


#: dest -> (option, its default) of the options that shape a population build: --default (the embedded store's
#: fixed population, built here) and --status (a report) take none of them.
_BUILD_OPTIONS = {
    "store": ("--store", None),
    "scheduler": ("--scheduler", None),
    "retries": ("--retries", 2),
    "seed": ("--seed", DEFAULT_SEED),
    "size": ("--size", DEFAULT_MAP_SIZE),
    "subjects": ("--subjects", None),
    "face": ("--face", DEFAULT_FACE),
    "no_conditions": ("--no-conditions", False),
    "specular": ("--specular", "torrance_sparrow"),
    "no_micro_normals": ("--no-micro-normals", False),
}


def _ignored(args, mode: str, also=()) -> bool:
    """Print an error and return True when ``args`` set an option that ``mode`` would ignore (nothing run)."""
    given = [flag for dest, (flag, default) in _BUILD_OPTIONS.items() if getattr(args, dest) != default]
    given += [flag for dest, flag in also if getattr(args, dest)]
    if given:
        print(f"facestats: error: {mode}; it takes no {', '.join(given)}", file=sys.stderr)
    return bool(given)


def _build_command(args) -> int:
    from facestats.pipeline import build as _build

    if args.status:
        if _ignored(args, "--status reports on a store", also=[("default", "--default"), ("workers", "--workers")]):
            return 2
        from facestats.pipeline.journal import build_status

        status = build_status(args.status)
        print(status.to_text())
        return 1 if status.failed or status.unfinished else 0
    if args.default:
        mode = (
            f"--default builds the embedded store on this machine (seed {DEFAULT_SEED}, {DEFAULT_MAP_SIZE}² maps, "
            f"the {DEFAULT_FACE} face)"
        )
        if _ignored(args, mode):
            return 2
        with named_options(workers="--workers"):
            report = _build.build_default(workers=args.workers, progress=not args.quiet)
    else:
        if not args.store:
            print("facestats: error: pass --store PATH (a directory store) or --default", file=sys.stderr)
            return 2
        check_store_to_write(args.store, "--store")
        with named_options(
            map_size="--size",
            seed="--seed",
            retries="--retries",
            workers="--workers",
            subjects="--subjects",
            subject_id="--subjects",  # one id of --subjects that is no id at all ('')
            scheduler="--scheduler",
        ):
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
                scheduler=args.scheduler,
                retries=args.retries,
                face=args.face,
            )
    print(report.to_text())
    return 1 if report.failed else 0


def add_build(sub):
    """Register ``facestats build`` (population build, ``--default``, ``--status``).

    Parameters
    ----------
    sub : argparse._SubParsersAction
        What ``add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    None
        The handler (``func``) returns 0, or 1 if a subject failed (with ``--status``: if one failed or a build stopped
        before its end), 2 for conflicting options or neither ``--store`` nor ``--default``, 130 when interrupted; a
        :class:`~facestats.errors.FacestatsError` raised becomes exit status 2 in :func:`facestats.cli.main`.
    """
    p = sub.add_parser(
        "build",
        help="simulate and fit a synthetic population into a store (resumable)",
        description=(
            "Draw the synthetic population (published statistics of Weyrich et al. 2006), simulate every subject's "
            "dome and contact-sensor captures, fit the skin model and write each subject to the store as soon as it "
            "is fitted. Rerunning skips subjects already in the store. --default regenerates the store embedded in "
            "the package. Failed subjects are retried, then reported (exit status 1); --status STORE shows what "
            "is done, running and failed."
        ),
    )
    p.add_argument("--default", action="store_true", help="regenerate the embedded default store")
    p.add_argument(
        "--status",
        type=non_empty,
        metavar="STORE",
        help=(
            "report what builds into STORE have done, what is running, what failed and what a build that stopped "
            "before its end did not start (exit 1 if any failed or a build stopped before its end)"
        ),
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        default=None,
        help="run on the Dask distributed scheduler at ADDRESS (tcp://host:8786; default $DASK_SCHEDULER_ADDRESS "
        "when set; 'local': this machine whatever the variable says); its workers must see --store on a shared POSIX "
        "file system",
    )
    p.add_argument(
        "--retries", type=ascii_int, default=2, help="retries of a subject that fails before it is reported (default 2)"
    )
    p.add_argument("--store", metavar="PATH", help="directory store to build into (created if missing)")
    p.add_argument(
        "--seed",
        type=ascii_int,
        default=DEFAULT_SEED,
        help=f"population seed (default {DEFAULT_SEED}, the embedded default's)",
    )
    p.add_argument(
        "--size",
        type=ascii_int,
        default=DEFAULT_MAP_SIZE,
        help=f"UV map / lumitexel grid size (default {DEFAULT_MAP_SIZE})",
    )
    p.add_argument("--subjects", nargs="+", metavar="ID", help="only these subject ids")
    p.add_argument(
        "--face",
        choices=("ict", "procedural"),
        default=DEFAULT_FACE,
        help="the face the population lives on: ict, the face area of ICT-FaceKit's neutral head (a real face, "
        f"MIT licence), or procedural, a parametric head (default {DEFAULT_FACE}, as the embedded store)",
    )
    p.add_argument("--no-conditions", action="store_true", help="leave out the subject measured under seven conditions")
    p.add_argument(
        "--specular",
        choices=("torrance_sparrow", "blinn_phong"),
        default="torrance_sparrow",
        help="BRDF the simulator renders highlights with",
    )
    p.add_argument("--no-micro-normals", action="store_true", help="do not store per-camera micro-normal maps")
    p.add_argument("--workers", type=ascii_int, default=None, help="worker processes (default: number of cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_build)
