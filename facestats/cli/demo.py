"""``facestats demo``: scattering coefficients and dipole profiles from a skin albedo (Weyrich et al. 2006 §5.4).

The options are checked here, against the domain the demo computes over, before any work, each message naming
the option, its domain and the value as given:

* ``--albedo`` in [1e-10, 1): eq. 16 is inverted for α' by a root finder that matches the total reflectance to
  about 1e-17 absolute, so an albedo loses a relative 1e-17/albedo (at 1e-10 the round trip is within 2e-7; below
  about 1e-14 the digits are gone and σ's came out negative, -7e-17 mm⁻¹ for 1e-300);
* ``--sigma-tr`` in [1e-100, 1e80] mm⁻¹: σ't ranges from σtr/√3 (albedo → 0) to about 10^16.4 σtr (albedo → 1)
  and the dipole profile R_d(0) ~ α' σ't² on the plot's 0-10 mm must stay in the float range (below 1e-100 it
  underflows to an empty plot, from about 1e90 the profile overflows; σtr = 1e-300 ended in "sigma_tr must lie in
  (0, inf] mm^-1, got 0.0", its square underflowed);
* ``--eta`` in [1, 3], the range of the polynomial for F_dr (:func:`facestats.model.dipole.check_dipole_eta`).

``--plot`` is checked as every plot of the CLI is (:func:`facestats.core.outputs.check_output_file`, .png, .svg
or .pdf); like ``translucency --plot`` and ``calibrate response --plot``, no plot is drawn unless it is given.
"""

from __future__ import annotations

from facestats.cli.options import ascii_float, non_empty
from facestats.core.published import ETA_SKIN

__all__ = ["add_demo"]

#: Domains of the options (module docstring): (low, high, high included, unit).
ALBEDO = (1e-10, 1.0, False, None)
SIGMA_TR = (1e-100, 1e80, True, "mm^-1")
ETA = (1.0, 3.0, True, None)
PLOT_SUFFIXES = (".png", ".svg", ".pdf")


def _check(values, option: str, domain) -> None:
    """Refuse a value of ``option`` outside ``domain`` (NaN and ±inf included), naming the option and the domain."""
    from facestats.core.validate import as_finite

    low, high, high_inclusive, unit = domain
    as_finite(values, option, low, high, high_inclusive=high_inclusive, unit=unit)


def _cmd_demo(args) -> int:
    plot = None
    if args.plot is not None:  # before any work, as every plot of the CLI ('' is refused by argparse)
        from facestats.core.outputs import check_output_file

        plot = check_output_file(args.plot, "--plot", PLOT_SUFFIXES, overwrite=args.overwrite)
    if args.albedo is not None:
        _check(args.albedo, "--albedo", ALBEDO)
    if args.sigma_tr is not None:
        _check(args.sigma_tr, "--sigma-tr", SIGMA_TR)
    _check([args.eta], "--eta", ETA)

    from facestats.model.demo import physics_demo

    report = physics_demo(albedo=args.albedo, sigma_tr=args.sigma_tr, eta=args.eta, plot=plot)
    print(report.to_text())
    if plot is not None:
        print(f"\nwrote {args.plot}")
    return 0


def add_demo(sub):
    """Register ``facestats demo``.

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
        "demo",
        help="physics demo: scattering coefficients and dipole profiles from a skin albedo",
        description=(
            "Given a skin albedo (total diffuse reflectance per channel) and σtr, print σa, σ's, σtr, ℓd and "
            "the total diffuse reflectance per channel (Weyrich et al. 2006 §5.4); with --plot, plot the dipole "
            "profiles."
        ),
    )
    p.add_argument(
        "--albedo",
        nargs=3,
        type=ascii_float,
        metavar=("R", "G", "B"),
        default=None,
        help="albedo per channel in [1e-10, 1) (below 1e-10 the inversion of eq. 16 loses its digits); "
        "default: the ColorChecker 'light skin' patch in linear sRGB",
    )
    p.add_argument(
        "--sigma-tr",
        nargs=3,
        type=ascii_float,
        metavar=("R", "G", "B"),
        default=None,
        help="σtr in 1/mm, in [1e-100, 1e80]; default: Weyrich's σtrAvg = 0.5508 0.9791 1.5497",
    )
    p.add_argument(
        "--eta", type=ascii_float, default=ETA_SKIN, help=f"relative index of refraction in [1, 3] (default {ETA_SKIN})"
    )
    p.add_argument(
        "--plot",
        type=non_empty,
        default=None,
        metavar="PATH",
        help="write the dipole profiles here (.png, .svg or .pdf); default: no plot",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing --plot file")
    p.set_defaults(func=_cmd_demo)
