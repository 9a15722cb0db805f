"""``facestats relight``: a store subject or a reflectance field relit under a light probe (Debevec et al. 2000).

One API call — :func:`facestats.relight.stage.relight_subject` for a subject of
the store (through the virtual light stage) or
:func:`facestats.relight.relighting.relight` for a field store (``*.zarr`` written by
:func:`facestats.relight.field.write_field`) — then the linear image is written
as OpenEXR and a tone-mapped sRGB PNG next to it.  Both output paths are
checked before any work; the files are written under unique temporary names
and renamed into place together (:class:`facestats.core.outputs.OutputSet`):
a failed command leaves nothing behind and replaces nothing.

``--turntable N`` renders N frames with the environment turned by 360°/N between them, through the
compressed path (:func:`facestats.relight.compression.compress`, ``--ratio``; Debevec et al. 2000 §3.3: relight
from compressed reflectance functions): the field (for a subject, its virtual light stage field, streamed to
a temporary zarr store) is compressed once and each frame is one compressed relight.  Frames are written as
``OUT_000.exr`` … with their PNGs (one exposure for all frames, from the first), all or none.  Without
``--ratio`` the ratio is 20, or half the largest a field of few lights can hold (:func:`_ratio`, with a note).

A subject is rendered on the face its provenance records (an edit: its source's;
:func:`facestats.relight.camera.subject_geometry`); a subject ingested from photographs records its scan's file
name, which is passed again as ``--mesh``.  Subjects of region samples (``import-merl``) have no maps to relight.

Registered in :mod:`facestats.cli` with :func:`add_relight`.
"""

from __future__ import annotations

import math
import pathlib

from facestats.cli.options import (
    add_store_option,
    ascii_float,
    ascii_int,
    ascii_number,
    check_apart_from_store,
    named_options,
    non_empty,
    open_store_option,
)

__all__ = ["add_relight"]


#: Options of a subject rendered through the virtual stage, with their defaults: a field store has its camera,
#: lights and surface already.
_SUBJECT_OPTIONS = {"size": 256, "azimuth": 0.0, "elevation": 0.0, "lights": "64x32", "mesh": None}

#: The turntable's compression ratio when ``--ratio`` is not given (lowered for fields of few lights: _ratio).
DEFAULT_RATIO = 20.0


def _check_subject_options(args):
    """A field store source with options that only a subject's render uses: a ValidationError naming them."""
    from facestats.errors import ValidationError

    given = [f"--{k}" for k, v in _SUBJECT_OPTIONS.items() if getattr(args, k) != v]
    if given and pathlib.Path(args.source).is_dir():
        verb = "applies" if len(given) == 1 else "apply"
        raise ValidationError(
            f"{', '.join(given)} {verb} to a subject rendered through the virtual stage; {args.source!r} is a "
            "field store, whose camera and lights are fixed (leave them out)"
        )


#: Coarsest light-stage grid ``--lights`` takes (θ × φ): a white Lambertian under a uniform probe then gets
#: 0.92-1.08 of its albedo whatever its normal (4x2: 0.71-1.41; docs/relighting.md, bench_relight.bench_lights_grid).
MIN_LIGHTS = (8, 4)


def _lights(text):
    """``(n_theta, n_phi)`` of a ``--lights`` value ``NxM``, checked before any array of the grid is made: ASCII whole
    numbers, at least :data:`MIN_LIGHTS`, at most :data:`facestats.io.images.MAX_IMAGE_PIXELS` lights in all, the
    most pixels of a light probe facestats reads (the grid is a lat-long image the probe is resampled to, one light
    per cell: a finer grid only splits the probe's pixels), and a grid whose own arrays fit in the memory available
    (:func:`facestats.relight.stage.check_light_grid`: at the limit its directions alone take 6 GiB, 2^28 x 3
    float64, built before the visibility table's memory check refused it; 100000x100000 failed late asking
    74.5 GiB)."""
    from facestats.errors import ValidationError
    from facestats.io.images import MAX_IMAGE_PIXELS
    from facestats.relight.stage import check_light_grid

    sizes = [ascii_number(x, int) for x in text.lower().split("x")]
    if len(sizes) != 2 or None in sizes or min(sizes) < 1:
        raise ValidationError(
            f"--lights must be N_THETAxN_PHI, two whole numbers >= 1 in ASCII digits such as 64x32, got {text!r}"
        )
    if sizes[0] * sizes[1] > MAX_IMAGE_PIXELS:
        side = math.isqrt(MAX_IMAGE_PIXELS)
        raise ValidationError(
            f"--lights must make at most {MAX_IMAGE_PIXELS} lights ({side} x {side}, the most "
            f"pixels of a light probe facestats reads: a finer grid only splits its pixels), got {text!r} = "
            f"{sizes[0] * sizes[1]} lights"
        )
    if sizes[0] < MIN_LIGHTS[0] or sizes[1] < MIN_LIGHTS[1]:  # 1x1 lit the face from behind only: a black image
        raise ValidationError(
            f"--lights must be at least {MIN_LIGHTS[0]}x{MIN_LIGHTS[1]}: a coarser grid relights a white Lambertian "
            "under a uniform probe 29 % dark to 41 % bright (4x2), or black (1x1), got "
            f"{text!r} (docs/relighting.md)"
        )
    check_light_grid(*sizes, name="--lights", value=text)
    return tuple(sizes)


def _check_subject_values(args):
    """The values of a subject's render options, checked by their flags before any work (a subject source)."""
    from facestats.errors import ValidationError

    _lights(args.lights)
    if not 1 <= args.size <= 8192:
        raise ValidationError(f"--size must be an image side in [1, 8192] pixels, got {args.size}")
    if not math.isfinite(args.azimuth):
        raise ValidationError(f"--azimuth must be a finite angle in degrees, got {args.azimuth!r}")
    if not -90 <= args.elevation <= 90:  # NaN fails too
        raise ValidationError(f"--elevation must be an angle in [-90, 90] degrees, got {args.elevation!r}")
    if args.mesh is not None and not pathlib.Path(args.mesh).is_file():
        raise ValidationError(f"--mesh must be an OBJ/PLY file with UVs, got {args.mesh!r} (not a file)")


def _subject_and_camera(args):
    """The store subject ``args.source`` (loaded), its face geometry (``--mesh``, else the one its provenance
    names: :func:`facestats.relight.camera.subject_geometry`) and the stage camera of ``--azimuth``,
    ``--elevation``, ``--size``."""
    from facestats.relight.camera import stage_camera, subject_geometry

    with open_store_option(args.store) as store:
        subject = store.subject(args.source, exclude=["micro_normal"])  # rendering uses the diffuse normal
    geometry = subject_geometry(subject, args.mesh)
    return subject, geometry, stage_camera(args.azimuth, args.elevation, size=args.size)


def _ratio(args, directions):
    """The turntable's compression ratio for a field of these light directions (L, 3), checked before any work.

    No ratio at or above :func:`facestats.relight.compression.ratio_bound` leaves room for a component (with
    ``compress``'s default sectors and parts).  An explicit ``--ratio`` there is refused naming it; without
    ``--ratio``, the default 20 is lowered to half that bound (the other half left for components) with a note.
    """
    import numpy as np

    from facestats.errors import ValidationError
    from facestats.relight.compression import ratio_bound

    bound, n = ratio_bound(directions), int(np.prod(np.shape(directions)[:-1]))  # lights of an (…, 3) array
    if args.ratio is not None:
        if args.ratio >= bound:
            per_pixel = 3 * n / bound  # values per face pixel besides the components
            raise ValidationError(
                f"--ratio {args.ratio:g} cannot be met by a field of {n} lights: besides its components it stores "
                f"{per_pixel:g} values per face pixel, so the ratio must stay below 3 x {n} / {per_pixel:g} = "
                f"{bound:.4g}; pass a smaller --ratio"
            )
        return args.ratio
    if DEFAULT_RATIO <= bound / 2:
        return DEFAULT_RATIO
    print(
        f"note: --ratio not given and the default {DEFAULT_RATIO:g} does not fit a field of {n} lights (below "
        f"{bound:.4g} with room for no component): compressing at ratio {bound / 2:.4g}"
    )
    return bound / 2


def _frame(path, k, frames):
    """``path`` with ``_kkk`` before its suffix when there are several frames."""
    return path if frames is None else path.with_name(f"{path.stem}_{k:03d}{path.suffix}")


def _check_apart(args, out, png) -> None:
    """The outputs never lie inside the field store relit or the store of the subject (files mixed into a store)."""
    from facestats.core.outputs import check_apart

    for name, p in (("--out", out), ("--png", png)):
        if pathlib.Path(args.source).is_dir():
            check_apart(p, args.source, name, "the field store")
        else:
            check_apart_from_store(p, name, args.store)


def _check_numbers(args) -> None:
    """The one-number options, each by its flag: --turntable, --ratio, --rotate, --exposure."""
    from facestats.errors import ValidationError

    if args.turntable is not None and not 1 <= args.turntable <= 3600:
        raise ValidationError(f"--turntable must be a number of frames in [1, 3600], got {args.turntable}")
    if args.ratio is not None and args.turntable is None:
        raise ValidationError("--ratio applies to --turntable (a single relight uses the dense field)")
    if args.ratio is not None and not (math.isfinite(args.ratio) and args.ratio > 0):
        raise ValidationError(f"--ratio must be a finite number > 0, got {args.ratio!r}")
    if not math.isfinite(args.rotate):
        raise ValidationError(f"--rotate must be a finite angle in degrees, got {args.rotate!r}")
    if args.exposure is not None and not (math.isfinite(args.exposure) and 0 < args.exposure <= 1e12):
        raise ValidationError(f"--exposure must be a factor in (0, 1e12], got {args.exposure!r}")


def _cmd_relight(args) -> int:
    import numpy as np

    from facestats.core.outputs import OutputSet, check_output_file
    from facestats.io.images import write_image
    from facestats.io.probes import read_light_probe
    from facestats.relight.display import exposure_scale

    # Outputs first: a bad path must not cost a relight, and nothing is replaced unless all are written.
    _check_numbers(args)
    frames = args.turntable
    out = check_output_file(args.out, "--out", (".exr",))
    png = check_output_file(args.png if args.png is not None else out.with_suffix(".png"), "--png", (".png",))
    _check_subject_options(args)
    if not pathlib.Path(args.source).is_dir():
        _check_subject_values(args)
    targets = [(_frame(out, k, frames), _frame(png, k, frames)) for k in range(frames or 1)]
    for pair in targets:
        for name, p in zip(("--out", "--png"), pair):
            check_output_file(p, name, (p.suffix.lower(),), overwrite=args.overwrite)
    _check_apart(args, out, png)
    probe = read_light_probe(args.probe, args.layout)
    if frames is not None:
        return _turntable(args, probe, targets)
    rotate = math.radians(math.fmod(args.rotate, 360.0))  # fmod first: exact for any finite angle
    source = pathlib.Path(args.source)
    if source.is_dir():
        from facestats.relight.field import open_field
        from facestats.relight.relighting import relight

        field = open_field(source)
        image = relight(field, probe=probe, layout=args.layout, rotate=rotate, progress=not args.quiet)
        mask = field["mask"].values if "mask" in field.data_vars else None
    else:
        from facestats.relight.stage import relight_subject

        subject, geometry, camera = _subject_and_camera(args)
        with named_options(lights="--lights"):  # more lights than the memory holds
            image, mask = relight_subject(subject, probe, layout=args.layout, rotate=rotate, camera=camera,
                                          lights=_lights(args.lights), geometry=geometry,
                                          progress=not args.quiet)  # fmt: skip
    scale = exposure_scale(image, mask) if args.exposure is None else args.exposure
    attrs = {"source": str(args.source), "probe": str(args.probe), "rotate_deg": str(args.rotate),
             "units": "radiance in the probe's unit", "method": "Debevec et al. 2000 eq. 4"}  # fmt: skip
    with OutputSet(out.parent) as files:  # both files or neither
        write_image(files.path(out.name), image, attributes=attrs)
        write_image(files.path(png.absolute()), np.clip(image * scale, 0, 1), srgb=True)
    lum = image.mean(-1)
    sel = lum[mask] if mask is not None else lum
    print(f"relit {args.source} under {args.probe} (rotated {args.rotate:g}°): {image.shape[1]} x {image.shape[0]}, "
          f"mean radiance {float(sel.mean()):.4g}, PNG exposure x{scale:.4g}")  # fmt: skip
    print(f"wrote {out}\nwrote {png}")
    return 0


def _turntable(args, probe, targets) -> int:
    """Frames of the environment turning about +y, relit through the compressed field (module docstring)."""
    import tempfile

    import numpy as np

    from facestats.core.outputs import OutputSet
    from facestats.io.images import write_image
    from facestats.relight.compression import compress
    from facestats.relight.display import exposure_scale
    from facestats.relight.field import open_field

    with tempfile.TemporaryDirectory(prefix="facestats-stage-") as tmp:
        source = pathlib.Path(args.source)
        if source.is_dir():
            from facestats.relight.field import light_table

            field = open_field(source)
            ratio = _ratio(args, light_table(field)[0])
        else:
            from facestats.model.sphere import light_stage_directions
            from facestats.relight.stage import light_stage_field

            subject, geometry, camera = _subject_and_camera(args)
            d, _ = light_stage_directions(*_lights(args.lights))
            ratio = _ratio(args, d)  # before the field is rendered
            with named_options(lights="--lights"):  # more lights than the memory holds
                field = light_stage_field(subject, camera, geometry=geometry, directions=d,
                                          out=pathlib.Path(tmp) / "field.zarr", dtype="float16",
                                          progress=not args.quiet)  # fmt: skip
        mask = field["mask"].values if "mask" in field.data_vars else None
        with named_options(ratio="--ratio"):  # a ratio whose budget cannot hold the first component
            comp = compress(field, ratio=ratio, progress=not args.quiet)
    step = 360.0 / len(targets)
    angles = [math.fmod(args.rotate + k * step, 360.0) for k in range(len(targets))]

    def frame(angle):
        return comp.relight(probe=probe, layout=args.layout, rotate=math.radians(angle))

    first = frame(angles[0])
    scale = exposure_scale(first, mask) if args.exposure is None else args.exposure
    with OutputSet(targets[0][0].parent) as files:  # every frame or none; one frame in memory at a time
        for k, ((exr, png), angle) in enumerate(zip(targets, angles)):
            image = first if k == 0 else frame(angle)
            attrs = {"source": str(args.source), "probe": str(args.probe), "rotate_deg": repr(angle),
                     "units": "radiance in the probe's unit", "compression_ratio": f"{comp.ratio:.4g}",
                     "method": "Debevec et al. 2000 eq. 4, compressed field (facestats.relight.compress)"}  # fmt: skip
            write_image(files.path(exr.absolute()), image, attributes=attrs)
            write_image(files.path(png.absolute()), np.clip(image * scale, 0, 1), srgb=True)
    print(f"turntable of {args.source} under {args.probe}: {len(targets)} frames every {step:g}° from "
          f"{args.rotate:g}°, compressed {comp.ratio:.1f}x ({comp.clusters} clusters, {comp.components} components), "
          f"PNG exposure x{scale:.4g}")  # fmt: skip
    print(f"wrote {targets[0][0]} ... {targets[-1][1]}")
    return 0


def add_relight(sub):
    """Register ``facestats relight``.

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
        "relight",
        help="relight a subject or a reflectance field under a light probe (EXR + PNG)",
        description=(
            "Relight a subject of the store through the virtual light stage (Debevec et al. 2000: 64 x 32 light "
            "directions, eq. 4), or a reflectance field store (*.zarr), under a light probe (Radiance .hdr, OpenEXR, "
            "PFM; lat-long or angular), optionally rotated about the vertical axis. Writes the linear image as "
            "OpenEXR and a tone-mapped sRGB PNG."
        ),
    )
    p.add_argument(
        "source",
        type=non_empty,
        metavar="SOURCE",
        help="subject id in the store, or a reflectance field store directory (*.zarr)",
    )
    p.add_argument("--probe", required=True, metavar="FILE", help="light probe (.hdr/.exr/.pfm)")
    p.add_argument(
        "--layout",
        choices=("latlong", "angular"),
        default="latlong",
        help="probe layout: latlong (equirectangular, default) or angular (a light probe's angular map)",
    )
    p.add_argument("--rotate", type=ascii_float, default=0.0, metavar="DEG",
                   help="rotate the environment about +y by DEG degrees (right-handed)")  # fmt: skip
    p.add_argument("--out", required=True, metavar="FILE.exr", help="linear OpenEXR output")
    p.add_argument(
        "--png", type=non_empty, default=None, metavar="FILE.png", help="tone-mapped PNG (default: next to --out)"
    )
    p.add_argument(
        "--exposure",
        type=ascii_float,
        default=None,
        metavar="SCALE",
        help="PNG exposure: radiance times SCALE before the sRGB encoding (default: the 99th percentile of the face "
        "at 0.9, printed as 'PNG exposure xS'; pass one SCALE to compare relights)",
    )
    p.add_argument(
        "--size",
        type=ascii_int,
        default=_SUBJECT_OPTIONS["size"],
        help="image side for a subject, pixels (default 256)",
    )
    p.add_argument("--azimuth", type=ascii_float, default=_SUBJECT_OPTIONS["azimuth"], metavar="DEG",
                   help="camera azimuth in degrees (default 0: frontal)")  # fmt: skip
    p.add_argument("--elevation", type=ascii_float, default=_SUBJECT_OPTIONS["elevation"], metavar="DEG",
                   help="camera elevation in degrees, -90 to 90 (default 0)")  # fmt: skip
    p.add_argument(
        "--lights", default=_SUBJECT_OPTIONS["lights"], metavar="NxM", help="light stage theta x phi (default 64x32)"
    )
    p.add_argument("--turntable", type=ascii_int, default=None, metavar="N",
                   help="N frames, the environment turned by 360/N degrees between them, relit through the "
                   "compressed field (OUT_000.exr, OUT_000.png, ...)")  # fmt: skip
    p.add_argument("--ratio", type=ascii_float, default=None,
                   help="minimum compression ratio of the turntable's field (default 20, lowered with a note for a "
                        "field of too few lights to hold it; a ratio the field reaches with every component, e.g. "
                        "below 1, keeps them all: exact)")  # fmt: skip
    p.add_argument("--mesh", metavar="PATH",
                   help="OBJ/PLY scan (with UVs) a subject's maps belong to, for a subject ingested from photographs "
                        "(default: the face its provenance records)")  # fmt: skip
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_store_option(p)
    p.set_defaults(func=_cmd_relight)
