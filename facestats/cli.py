"""The ``facestats`` command line.

Thin by design: each command parses its arguments, makes one API call and
prints.  Heavy modules are imported inside the commands so that ``facestats
--help`` and ``facestats query`` start quickly.
"""

from __future__ import annotations

import argparse
import sys

from . import __version__
from .errors import FacestatsError

__all__ = ["main", "build_parser"]


# -- demo ------------------------------------------------------------------------
def _cmd_demo(args) -> int:
    from .physics_demo import physics_demo

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
    p.add_argument("--albedo", nargs=3, type=float, metavar=("R", "G", "B"), default=None,
                   help="albedo per channel in (0, 1); default: the ColorChecker 'light skin' patch in linear sRGB")
    p.add_argument("--sigma-tr", nargs=3, type=float, metavar=("R", "G", "B"), default=None,
                   help="σtr in 1/mm; default: Weyrich's σtrAvg = 0.5508 0.9791 1.5497")
    p.add_argument("--eta", type=float, default=1.38, help="relative index of refraction (default 1.38)")
    p.add_argument("--plot", default="dipole_profiles.png", help="where to write the plot (PNG/SVG/PDF); '' for none")
    p.set_defaults(func=_cmd_demo)


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


_COMMANDS = [_add_demo]


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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
