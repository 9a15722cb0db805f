"""``facestats demo``: scattering coefficients and dipole profiles from a skin albedo (Weyrich et al. 2006 §5.4)."""

from __future__ import annotations

from facestats.cli.options import ascii_float
from facestats.core.published import ETA_SKIN

__all__ = ["add_demo"]


def _cmd_demo(args) -> int:
    from facestats.model.demo import physics_demo

    report = physics_demo(albedo=args.albedo, sigma_tr=args.sigma_tr, eta=args.eta, plot=args.plot)
    print(report.to_text())
    if args.plot:
        print(f"\nwrote {args.plot}")
    return 0


def add_demo(sub):
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
        type=ascii_float,
        metavar=("R", "G", "B"),
        default=None,
        help="albedo per channel in (0, 1); default: the ColorChecker 'light skin' patch in linear sRGB",
    )
    p.add_argument(
        "--sigma-tr",
        nargs=3,
        type=ascii_float,
        metavar=("R", "G", "B"),
        default=None,
        help="σtr in 1/mm; default: Weyrich's σtrAvg = 0.5508 0.9791 1.5497",
    )
    p.add_argument(
        "--eta", type=ascii_float, default=ETA_SKIN, help=f"relative index of refraction (default {ETA_SKIN})"
    )
    p.add_argument("--plot", default="dipole_profiles.png", help="where to write the plot (PNG/SVG/PDF); '' for none")
    p.set_defaults(func=_cmd_demo)
