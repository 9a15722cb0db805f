"""The ``facestats`` command line.

Thin by design: each command parses its arguments, makes one API call and
prints.  Heavy modules are imported inside the commands so that ``facestats
--help`` and ``facestats query`` start quickly.  One module per command group:

* :mod:`~facestats.cli.store` — ``query``, ``info``, ``validate``, ``export``, ``import-merl``;
* :mod:`~facestats.cli.build` — ``build``;
* :mod:`~facestats.cli.analyze` — ``analyze``;
* :mod:`~facestats.cli.edit` — ``edit``;
* :mod:`~facestats.cli.demo` — ``demo``;
* :mod:`~facestats.cli.export` — ``export-subject``;
* :mod:`~facestats.cli.serve` — ``serve``;
* :mod:`~facestats.cli.render` — ``render``;
* :mod:`~facestats.cli.microstructure` — ``microstructure render``, ``microstructure generate``;
* :mod:`~facestats.cli.translucency` — ``translucency``;
* :mod:`~facestats.cli.ingest` — ``ingest``;
* :mod:`~facestats.cli.calibrate` — ``calibrate response``, ``calibrate leds``, ``calibrate merge``;
* :mod:`~facestats.cli.emulate` — ``emulate dome|sensor``;
* :mod:`~facestats.cli.capture` — ``capture dome|sensor``;
* :mod:`~facestats.cli.relight` — ``relight``.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings

from facestats.cli.analyze import add_analyze
from facestats.cli.build import add_build
from facestats.cli.calibrate import add_calibrate
from facestats.cli.capture import add_capture
from facestats.cli.demo import add_demo
from facestats.cli.edit import add_edit
from facestats.cli.emulate import add_emulate
from facestats.cli.export import add_export_subject
from facestats.cli.ingest import add_ingest
from facestats.cli.interrupts import is_interrupt
from facestats.cli.microstructure import add_microstructure
from facestats.cli.options import Parser
from facestats.cli.relight import add_relight
from facestats.cli.render import add_render
from facestats.cli.serve import add_serve
from facestats.cli.store import add_export, add_import_merl, add_info, add_query, add_validate
from facestats.cli.translucency import add_translucency
from facestats.core.version import __version__
from facestats.errors import FacestatsError

__all__ = ["main", "build_parser"]

#: The command groups, in the order ``facestats --help`` lists them.
COMMANDS = [
    add_demo,
    add_query,
    add_info,
    add_validate,
    add_export,
    add_import_merl,
    add_build,
    add_analyze,
    add_edit,
    add_export_subject,
    add_serve,
    add_render,
    add_microstructure,
    add_translucency,
    add_ingest,
    add_calibrate,
    add_emulate,
    add_capture,
    add_relight,
]


def build_parser() -> argparse.ArgumentParser:
    """The ``facestats`` argument parser with ``--version`` and every command of :data:`COMMANDS`.

    Returns
    -------
    facestats.cli.options.Parser
        An :class:`argparse.ArgumentParser` whose single-valued options may be given once; each command sets
        ``func`` to its handler.
    """
    parser = Parser(
        prog="facestats",
        description="Measure, analyse and edit the appearance of human facial skin (Weyrich et al. 2006).",
    )
    parser.add_argument("--version", action="version", version=f"facestats {__version__}")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND")
    for add in COMMANDS:
        add(sub)
    return parser


def main(argv=None) -> int:
    """Run the ``facestats`` command line; every error becomes one ``facestats: error: …`` line on stderr.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after the program name (default ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit code: the command's own (0 on success; also 0 when no command is given, after printing the
        help, and when stdout's reader closed early), 2 for a :class:`~facestats.errors.FacestatsError`, an
        OSError, a MemoryError or a missing module of another package, 130 when interrupted, 3 for any other
        error (a bug; ``FACESTATS_DEBUG=1`` raises it instead).  argparse itself exits (``SystemExit``) for
        ``--help``, ``--version`` and a malformed command line (status 2).
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        parser.print_help()
        return 0
    shown = warnings.formatwarning
    warnings.formatwarning = _one_line_warning  # "facestats: warning: …", not a source line of facestats
    try:
        return int(args.func(args) or 0)
    except FacestatsError as exc:
        print(f"facestats: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("facestats: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into e.g. `head`, which closed early
        try:
            sys.stdout = open(os.devnull, "w")
        except OSError:  # pragma: no cover
            pass
        return 0
    except Exception as exc:  # the last line of defence: no command ends in a traceback
        if is_interrupt(exc):  # Ctrl-C inside compiled code
            print("facestats: interrupted", file=sys.stderr)
            return 130
        if os.environ.get("FACESTATS_DEBUG"):
            raise
        print(f"facestats: error: {_describe_failure(exc)}", file=sys.stderr)
        return 2 if isinstance(exc, (OSError, MemoryError)) or _foreign_module(exc) else 3
    finally:
        warnings.formatwarning = shown


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    """A warning as the command line shows it: ``facestats: warning: <message>`` (its category when not a plain
    UserWarning), without the file and source line of the code that raised it."""
    kind = "" if category is UserWarning else f" ({category.__name__})"
    return f"facestats: warning{kind}: {message}\n"


#: What to install for an import name: packages called otherwise on PyPI, and facestats' extras.
_PIP_NAMES = {
    "cv2": "opencv-python-headless",
    "serial": "pyserial",
    "colour": "colour-science",
    "yaml": "pyyaml",
    "distributed": "'facestats[distributed]'",
    "flask": "'facestats[web]'",
    "mitsuba": "'facestats[render]'",
}


def _foreign_module(exc: BaseException) -> str | None:
    """The top-level name of the module another package's ModuleNotFoundError names (None for facestats' own,
    a bug, and for any other error)."""
    if not isinstance(exc, ModuleNotFoundError) or not exc.name:
        return None
    top = exc.name.split(".")[0]
    return None if top == "facestats" else top


def _missing_package(exc: BaseException) -> str | None:
    """The top-level name of a package that is not installed (a dependency: a damaged environment or an install
    with ``--no-deps``), or None: a missing module of facestats itself is a bug, and a missing module of an
    installed package is a broken installation of it (:func:`_describe_failure`)."""
    top = _foreign_module(exc)
    if top is None:
        return None
    import importlib.util

    try:
        found = importlib.util.find_spec(top) is not None
    except (ImportError, ValueError):
        found = False
    return None if found and top != exc.name else top


def _describe_failure(exc: BaseException) -> str:
    """One line about an error no command turned into a FacestatsError."""
    if isinstance(exc, OSError):
        where = f": {exc.filename}" if exc.filename else ""
        return f"{exc.strerror or exc}{where}"
    if isinstance(exc, MemoryError):
        return f"out of memory ({exc or 'the computation needs more memory than this machine has'})"
    missing = _missing_package(exc)
    if missing:
        return (
            f"the package {missing!r} is not installed, and facestats needs it here: "
            f"pip install {_PIP_NAMES.get(missing, missing)} (or reinstall facestats with its dependencies)"
        )
    top = _foreign_module(exc)
    if top is not None:
        return (
            f"the package {top!r} is installed but its module {exc.name!r} cannot be found: the installation is "
            f"broken; reinstall it (pip install --force-reinstall {_PIP_NAMES.get(top, top)})"
        )
    return (
        f"unexpected {type(exc).__name__}: {exc} — this is a bug in facestats; rerun with FACESTATS_DEBUG=1 "
        "for the traceback and report it"
    )


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
