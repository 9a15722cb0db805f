"""``facestats translucency``: dipole σ's and σa of a homogeneous object from one HDR image (Suzuki et al.)."""

from __future__ import annotations

import json
import sys
import warnings

from facestats.cli.options import ascii_float, named_options, non_empty, number_option
from facestats.errors import FacestatsError, QuantisationWarning, ValidationError

__all__ = ["add_translucency"]


def _checked_options(args):
    """``(json path, plot path, max distance)`` after checking them, ``--eta`` and ``--max-distance`` (before the
    fit: bad options must not cost one)."""
    from facestats.core.outputs import check_output_file
    from facestats.core.validate import check_choice
    from facestats.model.dipole import check_dipole_eta
    from facestats.model.fitting.quantised import SELF_TERMS

    check_choice(args.self_term, "--self-term", SELF_TERMS)

    out_json = plot = None
    if args.json is not None:
        out_json = check_output_file(args.json, "--json", (".json",), overwrite=args.overwrite)
    if args.plot is not None:
        plot = check_output_file(args.plot, "--plot", (".png", ".svg", ".pdf"), overwrite=args.overwrite)
    if out_json is not None and plot is not None and out_json.absolute() == plot.absolute():
        raise ValidationError(f"--plot must differ from --json, got {str(plot)!r} for both")
    if args.eta is not None:
        with named_options(eta="--eta"):
            check_dipole_eta(args.eta)
    max_distance = _max_distance(args.max_distance)
    if args.method == "exitance" and max_distance != "auto":
        raise ValidationError(
            f"--max-distance selects the levels of eq. 36 (--method monotone or pinv); --method exitance fits every "
            f"row through W, got --max-distance {args.max_distance}"
        )
    return out_json, plot, max_distance


def _with_notes(fit, *args, **kwargs):
    """``fit(*args, **kwargs)`` with its quantisation warnings held back: they are each fit's notes, printed as
    "note:" lines with the result, or on stderr before a failure's error (each once: the channels of an image
    share W and repeat its warnings); other warnings pass on, each once."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", QuantisationWarning)
        try:
            result = fit(*args, **kwargs)
        except FacestatsError:
            for message in dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, QuantisationWarning)):
                print(f"note: {message}", file=sys.stderr)
            raise
    others = {(str(w.message), w.category): w for w in caught if not issubclass(w.category, QuantisationWarning)}
    for w in others.values():
        warnings.warn(w.message, w.category, stacklevel=2)
    return result


def _notes_once(names, fits):
    """``[(channels, note)]``: each distinct note of the fits once, in order of first appearance, with the names of
    the channels whose fit has it (a grey light gives R, G and B the same notes)."""
    where = {}
    for name, fit in zip(names, fits):
        for note in fit.notes:
            where.setdefault(note, []).append(name)
    return [(channels, note) for note, channels in where.items()]


def _radiance_scale(text, image):
    """``--radiance-scale``: one factor, or one per channel of ``image``, each a finite number > 0, as an array that
    multiplies the image (broadcast over its last axis)."""
    import numpy as np

    values = [number_option(v.strip(), float, "--radiance-scale") for v in text.split(",")]
    channels = 1 if image.ndim == 2 else image.shape[2]
    if len(values) not in (1, channels) or not all(np.isfinite(v) and v > 0 for v in values):
        raise ValidationError(
            f"--radiance-scale must be one number > 0, or one per channel of the image ({channels}), got {text!r}"
        )
    return np.asarray(values) if image.ndim == 3 else values[0]


def _max_distance(text):
    """``--max-distance``: 'auto', 'all' (None: every level, the paper's eq. 36) or a distance in mm."""
    if text in ("auto", "all"):
        return None if text == "all" else "auto"
    value = number_option(text, float, "--max-distance")
    if not value > 0:
        raise ValidationError(f"--max-distance must be 'auto', 'all' or a distance > 0 mm, got {text!r}")
    return value


def _cmd_translucency(args) -> int:
    from facestats.core.outputs import OutputSet
    from facestats.pipeline.image_translucency import fit_image_translucency, load_scene_inputs

    out_json, plot, max_distance = _checked_options(args)
    with named_options(spacing="--spacing", scale="--scale", image="--image"):
        patches, lights, eta, camera, image = load_scene_inputs(
            args.mesh, args.lights, args.camera, args.image, spacing=args.spacing, scale=args.scale
        )
    eta = args.eta if args.eta is not None else eta
    width = args.width if args.width == "auto" else number_option(args.width, float, "--width")
    scale = None if args.radiance_scale is None else _radiance_scale(args.radiance_scale, image)
    if scale is not None:
        image = image * scale
    with named_options(width="--width", max_distance="--max-distance"):
        fits = _with_notes(
            fit_image_translucency,
            patches,
            lights,
            camera,
            image,
            eta=eta,
            width=width,
            method=args.method,
            grid=args.grid,
            refine=args.refine,
            self_term=args.self_term,
            max_distance=max_distance,
            progress=not args.quiet,
        )
    names = ["R", "G", "B"] if len(fits) == 3 else [f"channel {k}" for k in range(len(fits))]
    print(
        f"patches: {len(patches)} (--spacing {args.spacing:g} mm: sub-triangle edges at most {args.spacing:g} mm; "
        f"neighbouring centres {patches.spacing:.4g} mm apart, median), eta {eta:g}, method {args.method}"
        + ("" if args.self_term == "point" else f", self term {args.self_term}")
        + ("" if scale is None else f", radiance scale {args.radiance_scale}")
    )
    for name, fit in zip(names, fits):
        s = fit.summary()
        (s0, s1), (a0, a1) = s["sigma_s_prime_interval"], s["sigma_a_interval"]
        print(
            f"{name}: sigma_s' = {s['sigma_s_prime']:.4g} [{s0:.4g}, {s1:.4g}] 1/mm, "
            f"sigma_a = {s['sigma_a']:.4g} [{a0:.4g}, {a1:.4g}] 1/mm, sigma_tr = {s['sigma_tr']:.4g} 1/mm "
            f"({int(100 * s['interval_level'])} % interval)"
        )
        print(
            f"   width {s['width_mm']:.4g} mm, {s['n_levels']} levels, rank {s['rank']}, "
            f"condition {s['condition']:.3g}, {len(s['merged_levels_mm'])} level(s) merged, "
            f"fit up to {s['max_distance_mm']:.4g} mm, {s['n_rows']} rows"
        )
    for channels, note in _notes_once(names, fits):
        print(f"note ({', '.join(channels)}): {note}")
    figure = None
    if plot is not None:
        from facestats.pipeline.translucency_plots import plot_profile_fit

        figure = plot_profile_fit(fits, names)
    with OutputSet(".") as files:  # both files or neither
        if out_json is not None:
            files.path(out_json.absolute()).write_text(
                json.dumps({name: fit.summary() for name, fit in zip(names, fits)}, indent=1)
            )
        if figure is not None:
            figure.savefig(files.path(plot.absolute()), dpi=120)
    for path in (out_json, plot):
        if path is not None:
            print(f"wrote {path}")
    return 0


def add_translucency(sub):
    """Register ``facestats translucency``.

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
        "translucency",
        help="dipole scattering coefficients of a homogeneous object from one HDR image (Suzuki et al.)",
        description=(
            "Estimate the dipole's reduced scattering and absorption coefficients of a homogeneous translucent "
            "object from one linear HDR image under known light (Suzuki, Mukaigawa & Yagi): patches of the mesh, "
            "irradiance from the lights, exitance from the image, the quantised-distance solve and the log-space "
            "dipole fit; prints the estimate per channel with its interval and the rank diagnostics."
        ),
    )
    p.add_argument("mesh", metavar="MESH", help="object mesh (OBJ or PLY), in mm unless --scale")
    p.add_argument("--lights", required=True, help="light description (JSON, see docs/translucency_from_image.md)")
    p.add_argument("--camera", required=True, help="pinhole camera (JSON: matrix, rotation, position_mm, image_size)")
    p.add_argument(
        "--image",
        required=True,
        help="linear radiance image (.exr, .pfm, or .npz with 'radiance'), in the lights' unit per sr (else "
        "--radiance-scale)",
    )
    p.add_argument(
        "--spacing",
        type=ascii_float,
        default=1.0,
        help=(
            "longest patch edge in mm (default 1): each mesh triangle is split into k*k sub-triangles, "
            "k = ceil(longest triangle edge / SPACING); neighbouring patch centres lie closer, about half "
            "SPACING (their median distance is printed)"
        ),
    )
    p.add_argument("--scale", type=ascii_float, default=1.0, help="mesh units to mm (default 1)")
    p.add_argument("--width", default="auto", help="quantisation width in mm, or 'auto' (default)")
    p.add_argument(
        "--method",
        choices=("monotone", "pinv", "exitance"),
        default="monotone",
        help="solve (default monotone); 'exitance' fits the dipole to the image through W (with --self-term surface "
        "for continuous surfaces; docs/translucency_from_image.md)",
    )
    p.add_argument(
        "--max-distance",
        default="auto",
        metavar="auto|all|MM",
        help="levels eq. 36 fits: 'auto' (default: up to where the image determines R' to 25 %%; with --method "
        "pinv every level), 'all' (the paper's), or up to a distance in mm; not with --method exitance",
    )
    p.add_argument(
        "--radiance-scale",
        default=None,
        metavar="K[,K,K]",
        help="factor(s) turning the image's values into radiance in the lights' unit per sr (e.g. the merge's "
        "exp(g)/s; docs/translucency_from_image.md, Absolute radiance); default: the image holds it already",
    )
    p.add_argument("--grid", choices=("table2", "skin"), default="table2", help="eq. 36 grid (default Table 2)")
    p.add_argument("--refine", action="store_true", help="refine the grid optimum by continuous least squares")
    p.add_argument(
        "--self-term",
        default="point",
        metavar="{point,footprint,surface}",
        help="a patch's own light: 'point' (Suzuki eq. 17, R(0) c A; default) or 'footprint' (the dipole "
        "integrated over the patch's disk); 'surface' also integrates the nearest patches over theirs "
        "(see docs/translucency_from_image.md, Limits)",
    )
    p.add_argument("--eta", type=ascii_float, default=None, help="relative index (default: the light file's, else 1.3)")
    p.add_argument("--json", type=non_empty, default=None, help="also write the estimates and diagnostics as JSON here")
    p.add_argument(
        "--plot", type=non_empty, default=None, help="write the Fig. 5 style plot (measured R' and fitted dipole) here"
    )
    p.add_argument("--overwrite", action="store_true", help="replace existing --json and --plot files")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_translucency)
