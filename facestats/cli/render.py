"""``facestats render``: a fitted subject rendered beside its capture (:mod:`facestats.pipeline.validation`).

Under an LED the render is compared with the capture: ``--capture``, or, for a subject of the synthetic
population (the embedded default, or a store ``facestats build`` wrote), its capture re-simulated from the
recorded provenance (:func:`facestats.pipeline.validation.default_capture`; ``--seed``: the build's).  Under a
probe nothing is compared: without ``--capture``, the lumitexels of the face the subject records (an edit: its
source's), or of ``--mesh`` (the scan of a subject ingested from photographs, which also shadows a render with
``--capture``), are rendered for the default dome (:func:`facestats.pipeline.validation.face_view`).  File names carry
the camera and the light, ``ID-cam05-led020-rendered.exr`` or ``ID-cam05-probe-STEM-rendered.exr``, so renders
under other lights sit side by side.
"""

from __future__ import annotations

import math
import pathlib

from facestats.cli.options import (
    add_mesh_scale_option,
    add_store_option,
    ascii_int,
    check_apart_from_store,
    named_options,
    non_empty,
    open_store_option,
)

__all__ = ["add_render", "DEFAULT_CAMERA", "DEFAULT_LIGHT"]

#: Camera of a render by default: the default dome's camera on the face's axis (azimuth 0°, 18° above).
DEFAULT_CAMERA = 11

#: LED of an LED render by default: the default dome's frontal LED (on the axis of the head).  With camera 11 it
#: sees 96.3-96.5 % of the default store's lumitexels lit (S001, S003, S030, S100); camera 5 and LED 20, the
#: defaults until 2026-12-08, 9.6-10.0 % (LED 20 lights the face from behind, above and to the side).
DEFAULT_LIGHT = 0


def _stem(subject_id, args) -> str:
    """``ID-camCC-ledLLL`` or ``ID-camCC-probe-STEM``: what was rendered, for the file names."""
    light = f"probe-{pathlib.Path(args.probe).stem}" if args.probe else f"led{args.light:03d}"
    return f"{subject_id}-cam{args.camera:02d}-{light}"


def _check_options(args) -> None:
    """Refuse options that do not apply together, and set ``--light``'s default, before any work."""
    from facestats.errors import ValidationError

    if args.seed is not None and (args.capture or args.probe):
        raise ValidationError(
            "--seed applies to the LED render without --capture (the population seed of its re-simulated capture)"
        )
    if args.probe and args.light is not None:
        raise ValidationError("--light names an LED to render under, --probe renders under a probe instead: got both")
    args.light = DEFAULT_LIGHT if args.light is None else args.light
    if args.mesh is not None and not args.probe:
        raise ValidationError(
            "--mesh applies to a render under a light probe (--probe FILE); an LED render compares with the capture "
            "it was fitted to (--capture PATH), which holds the scan's lumitexels"
        )
    if args.mesh is not None and not pathlib.Path(args.mesh).is_file():
        raise ValidationError(f"--mesh must be an OBJ/PLY file with UVs, got {args.mesh!r} (not a file)")
    from facestats.io.mesh import check_mesh_scale

    with named_options(mesh_scale="--mesh-scale"):  # as export-subject and relight check it
        args.mesh_scale = check_mesh_scale(args.mesh_scale, args.mesh)
    if args.seed is not None and args.seed < 0:
        raise ValidationError(f"--seed must be a population seed >= 0, got {args.seed}")
    if args.probe_lights is not None and not args.probe:
        raise ValidationError("--probe-lights applies to a render under a light probe (--probe FILE)")
    if args.probe_lights is not None:
        from facestats.pipeline.validation import MAX_PROBE_LIGHTS

        text = args.probe_lights
        shown = text if len(text) <= 40 else text[:40] + "..."
        parts = text.lower().split("x")
        # at most 9 digits each before int(): no 5,000-digit conversion (Python refuses those with a ValueError)
        if (
            not (len(parts) in (1, 2) and all(p.isascii() and p.isdigit() and len(p) <= 9 for p in parts))
            or min(int(p) for p in parts) < 2
        ):
            raise ValidationError(
                f"--probe-lights must be N (median cut) or ROWSxCOLUMNS (blocks), integers >= 2 (e.g. 512 or 16x32), "
                f"got {shown!r}"
            )
        numbers = [int(p) for p in parts]
        args.probe_lights = numbers[0] if len(numbers) == 1 else tuple(numbers)
        if math.prod(numbers) > MAX_PROBE_LIGHTS:  # before the probe is read
            raise ValidationError(f"--probe-lights must make at most {MAX_PROBE_LIGHTS} lights, got {shown!r}")


#: ``facestats.format`` of a render's EXR images (their header attributes: :func:`_header`).
RENDER_FORMAT = "facestats.render/1"

#: What each EXR image of a render holds (``facestats.quantity``).
_QUANTITIES = {
    "rendered": "radiance the fitted skin model gives towards the camera (Weyrich et al. 2006 eq. 6)",
    "capture": "radiance the capture recorded (the photograph, or its simulation)",
    "error": "rendered minus captured radiance",
}


def _header(ds, res, args, variable) -> dict:
    """The ``facestats.*`` EXR header attributes of one image of a render (the EXR set's, ``exr_header``): the
    subject, what the image holds, its units and colour space, the camera, the light, the geometry, the
    image's layout and, under an LED, the error figures."""
    from facestats import __version__
    from facestats.io.exr_set import COLOUR_SPACE, exr_header
    from facestats.io.mesh import recorded_geometry

    if args.probe:
        light = {"light": f"probe {pathlib.Path(args.probe).name}", "probe": str(pathlib.Path(args.probe).resolve()),
                 "probe_lights": "512 (median cut)" if args.probe_lights is None else args.probe_lights}  # fmt: skip
        units = "the probe's radiance unit (the probe file's values, per sr)"
    else:
        light = {"light": f"LED {args.light}"}
        units = "dome units / sr (the capture's radiance unit)"
    if args.mesh is not None:
        geometry = str(pathlib.Path(args.mesh).resolve())
    else:
        geometry = recorded_geometry(ds) or "unknown"
    extra = {"camera": res.camera, **light, "geometry": geometry}
    if args.capture:
        extra["capture"] = str(pathlib.Path(args.capture).resolve())
    extra["image"] = "row 0 at the top; pixels where no lumitexel projects are 0"
    if res.relative_rmse is not None:
        extra.update(rmse=repr(float(res.rmse)), relative_rmse=repr(float(res.relative_rmse)))
    extra["software"] = f"facestats {__version__}"
    return exr_header(ds, file_format=RENDER_FORMAT, variable=variable, quantity=_QUANTITIES[variable], units=units,
                      colour_space=COLOUR_SPACE, **extra)  # fmt: skip


def _cmd_render(args) -> int:
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    from facestats.acquire.capture import open_capture
    from facestats.core.conventions import DEFAULT_SEED
    from facestats.core.outputs import OutputSet, check_apart, check_output_dir, check_output_file
    from facestats.core.validate import check_integer
    from facestats.io.exr_set import check_map_subject
    from facestats.io.images import write_image
    from facestats.io.subject_export import store_subject
    from facestats.pipeline.validation import check_micro_normals, default_capture, render_led, render_probe

    _check_options(args)
    if args.size is not None:  # before any work
        check_integer(args.size, "--size", 16, 2048)
    out = check_output_dir(args.out, "--out")  # before rendering: a bad folder must not cost a render
    check_apart_from_store(out, "--out", args.store)  # never images mixed into the store
    if args.capture:  # nor into the capture compared with
        check_apart(out, args.capture, "--out", "the capture")
    with open_store_option(args.store) as st, named_options(subject_id="ID"):
        ds = store_subject(st, args.subject_id)
    check_map_subject(ds, "a validation render")
    with named_options(**{"micro_normals=True": "--micro-normals"}):  # before a capture is simulated
        check_micro_normals(ds, args.micro_normals)
    stem = _stem(ds.attrs.get("subject_id", args.subject_id), args)
    names = [f"{stem}-rendered.exr", f"{stem}-capture.exr", f"{stem}-error.exr", f"{stem}.png"]
    written = names[:1] + names[3:] if args.probe else names
    for name in written:
        check_output_file(out / name, "--out", overwrite=args.overwrite)
    if args.capture:
        cap = open_capture(args.capture)
    elif args.probe:
        cap = None  # nothing to compare with: the subject's face suffices
    else:
        cap = default_capture(ds, seed=DEFAULT_SEED if args.seed is None else args.seed)
    # the options, not the API's names ("light probe 'x' ..." is --probe's, not --light's)
    with named_options(
        samples="--probe-lights",
        camera="--camera",
        light="--light",
        size="--size",
        mesh="--mesh",
        **{"light probe": "--probe"},
    ):
        if args.probe:
            res = render_probe(ds, cap, args.camera, args.probe, mesh=args.mesh, scale=args.mesh_scale,
                               samples=args.probe_lights, micro_normals=args.micro_normals, size=args.size)  # fmt: skip
        else:
            # a pair that sees too little of the face is refused (check_led_view), naming the options
            res = render_led(ds, cap, args.camera, args.light, micro_normals=args.micro_normals, size=args.size,
                             names=("--camera", "--light"))  # fmt: skip
    with OutputSet(out) as files:  # every file or none
        write_image(files.path(names[0]), np.nan_to_num(res.rendered).clip(0),
                    attributes=_header(ds, res, args, "rendered"))  # fmt: skip
        if res.reference is not None:
            write_image(files.path(names[1]), np.nan_to_num(res.reference).clip(0),
                        attributes=_header(ds, res, args, "capture"))  # fmt: skip
            write_image(files.path(names[2]), np.nan_to_num(res.error), attributes=_header(ds, res, args, "error"))
        res.figure().savefig(files.path(names[3]), dpi=120)
    if res.relative_rmse is not None:
        print(
            f"{args.subject_id} camera {args.camera} {res.light}: "
            f"RMSE {res.rmse:.4g}, relative {100 * res.relative_rmse:.2f} %"
        )
    print(f"wrote {out / names[3]} and the EXR images beside it")
    return 0


def add_render(sub):
    """Register ``facestats render``.

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
        "render",
        help="validation render of a fitted subject beside its capture, with the error image and RMSE",
        description=(
            "Render a fitted subject with the skin model (specular with the fitted normal, or with the per-view "
            "micro-normals under --micro-normals; diffuse through the spatial dipole transport) for one dome "
            "camera under one LED (with the capture's radiance, the error image and the RMSE) or under a lat-long"
            " light probe. Without --capture, subjects of the synthetic population (the embedded default, or a "
            "store written by facestats build) are re-simulated from their recorded provenance for an LED; under "
            "a probe nothing is compared and the face the subject records suffices (for a subject ingested from "
            "photographs: --mesh, its scan). Files: ID-camCC-ledLLL-*.exr or ID-camCC-probe-NAME-*.exr."
        ),
    )
    p.add_argument("subject_id", metavar="ID")
    p.add_argument("--out", required=True, metavar="DIR", help="directory for the images")
    p.add_argument(
        "--camera",
        type=ascii_int,
        default=DEFAULT_CAMERA,
        help=f"dome camera (default {DEFAULT_CAMERA}, the one facing the face, 18 degrees above its axis)",
    )
    p.add_argument(
        "--light",
        type=ascii_int,
        default=None,
        help=f"dome LED (default {DEFAULT_LIGHT}, the frontal LED; not with --probe). A camera and LED that see "
        f"fewer than 50 lumitexels lit are refused, naming the pair that sees the most",
    )
    p.add_argument(
        "--size",
        type=ascii_int,
        default=None,
        help="image side in pixels, 16-2048 (default 4 sqrt(n) for the n lumitexels in the camera's frame, "
        "64-1024: 117 for the default store's 857)",
    )
    p.add_argument(
        "--probe", type=non_empty, metavar="FILE", help="render under this lat-long HDR probe instead of an LED"
    )
    p.add_argument(
        "--probe-lights",
        metavar="N|ROWSxCOLUMNS",
        default=None,
        help="with --probe: the directional lights the probe is summed into, N regions of a median cut "
        "(default 512, about 4 s at 48²) or ROWSxCOLUMNS equal blocks dividing the probe's size; at most 2048 "
        "lights. Lambertian irradiance against the full probe at the 99th percentile / worst: median cut 512 "
        "0.5-4.5 %% / 0.9-6.0 %% under the Probulator, park, lobby and studio probes; 16x32 blocks up to "
        "13.6 / 25.7 %% (a studio's small softbox)",
    )
    p.add_argument(
        "--capture",
        type=non_empty,
        metavar="PATH",
        help="the subject's capture (zarr); default: re-simulate a subject of the synthetic population",
    )
    p.add_argument(
        "--mesh",
        metavar="PATH",
        help="with --probe: the OBJ/PLY scan (with UVs) of a subject ingested from photographs, which shadows the "
        "render and, without --capture, gives the lumitexels (default: the face the subject's provenance records)",
    )
    add_mesh_scale_option(p)
    p.add_argument(
        "--seed",
        type=ascii_int,
        default=None,
        help="population seed of the re-simulated capture: the --seed of the facestats build that wrote the store "
        "(default 2006, build's default)",
    )
    p.add_argument(
        "--micro-normals",
        action="store_true",
        help="evaluate the specular lobe with the camera's stored micro-normals (Weyrich et al. 2006 Fig. 6c) instead "
        "of the fitted normal; they are the half vector of each view's brightest sample, on the LED grid",
    )
    p.add_argument("--overwrite", action="store_true", help="replace existing images of the same names")
    add_store_option(p)
    p.set_defaults(func=_cmd_render)
