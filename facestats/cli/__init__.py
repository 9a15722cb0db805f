"""The ``facestats`` command line.

Thin by design: each command parses its arguments, makes one API call and
prints.  Heavy modules are imported inside the commands so that ``facestats
--help`` and ``facestats query`` start quickly.  One module per command group:

* :mod:`~facestats.cli.store` — ``query``, ``info``, ``validate``, ``export``, ``import-merl``;
* :mod:`~facestats.cli.build` — ``build``;
* :mod:`~facestats.cli.analyze` — ``analyze``;
* :mod:`~facestats.cli.edit` — ``edit``;
* :mod:`~facestats.cli.demo` — ``demo``;
* :mod:`~facestats.cli.relight` — ``relight``.
"""

from __future__ import annotations

import argparse
import os
import sys

from facestats.cli.analyze import add_analyze
from facestats.cli.build import add_build
from facestats.cli.demo import add_demo
from facestats.cli.edit import add_edit
from facestats.cli.relight import add_relight
from facestats.cli.store import add_export, add_import_merl, add_info, add_query, add_validate
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
    add_relight,
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="facestats",
        description="Measure, analyse and edit the appearance of human facial skin (Weyrich et al. 2006).",
    )
    parser.add_argument("--version", action="version", version=f"facestats {__version__}")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND")
    for add in COMMANDS:
        add(sub)
    return parser


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
