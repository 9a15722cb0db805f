"""``facestats relight``: a store subject or a reflectance field relit under a light probe (Debevec et al. 2000).

One API call — :func:`facestats.relight.stage.relight_subject` for a subject of
the store (through the virtual light stage) or
:func:`facestats.relight.relighting.relight` for a field store (``*.zarr`` written by
:func:`facestats.relight.field.write_field`) — then the linear image is written
as OpenEXR and a tone-mapped sRGB PNG next to it.  Both output paths are
checked before any work; the files are written under unique temporary names
and renamed into place together (:class:`facestats.core.outputs.OutputSet`):
a failed command leaves nothing behind and replaces nothing.

``--turntable N`` renders N frames with the environment turned by 360°/N between them.  By default each frame is
the dense relight of eq. 4, the same image a single relight at that angle gives: the field (for a subject, its
virtual light stage field, streamed to a temporary zarr store in float32) is read once per batch of frames
(:func:`facestats.relight.relighting.relight_frames`; frames in batches of at most :data:`BATCH_BYTES` of images).
Reading the field costs about as much as one relight and each further frame a matrix product, so this is faster than
compressing the field for any number of frames the option takes (docs/relighting.md, ``bench_relight.bench_turntable``).
With ``--ratio`` the frames go through the compressed field instead (:func:`facestats.relight.compression.compress`;
Debevec et al. 2000 §3.3): the field is compressed once and each frame is one compressed relight, and the error this
incurs is measured and printed: up to four frames spread over the turn are relit densely as well, in one pass, and
compared over the face (:func:`facestats.relight.compression.relative_errors`, against at least
:data:`RATIO_FLOOR` of the frame's face mean); above :data:`RATIO_WARN` at the 99th
percentile of the face's pixel channels a warning says so.  Frames are written as ``OUT_000.exr`` … with their PNGs
(one exposure for all frames, from the first), all or none.

The EXR holds the face mask as its alpha channel (A = 1 on the face's pixels, 0 elsewhere; RGB as relit) when the
source has one: every subject, and field stores with a ``mask``; the PNG preview is RGB.

A subject is rendered on the face its provenance records (an edit: its source's;
:func:`facestats.relight.camera.subject_geometry`); a subject ingested from photographs records its scan's file
name, which is passed again as ``--mesh``.  Subjects of region samples (``import-merl``) have no maps to relight.

Registered in :mod:`facestats.cli` with :func:`add_relight`.
"""

from __future__ import annotations

import math
import pathlib

from facestats.cli.options import (
    add_mesh_scale_option,
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
_SUBJECT_OPTIONS = {"size": 256, "azimuth": 0.0, "elevation": 0.0, "lights": "64x32", "mesh": None,
                    "mesh_scale": None}  # fmt: skip

#: Bytes of relit frames a dense turntable holds at once (one pass over the field per batch): 341 frames at 256²,
#: 21 at 1024², one at a time from 3,000².
BATCH_BYTES = 1 << 28

#: 99th percentile of the relative error of the face's pixel channels above which a compressed turntable warns
#: (the 3 % of docs/relighting.md's targets).
RATIO_WARN = 0.03

#: Frames of a compressed turntable checked against the dense relight (spread over the turn; one pass over the field).
RATIO_CHECKS = 4

#: Fraction of a checked frame's face mean (per channel) below which a pixel channel's error is measured against
#: that fraction, not its own dense value: 0 where the face turns away from a small source, which made the figures
#: 1e30 % (:func:`facestats.relight.compression.relative_errors`' ``floor``).
RATIO_FLOOR = 0.01


def _check_subject_options(args):
    """A field store source with options that only a subject's render uses: a ValidationError naming them."""
    from facestats.errors import ValidationError

    given = [f"--{k.replace('_', '-')}" for k, v in _SUBJECT_OPTIONS.items() if getattr(args, k) != v]
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
    _mesh_scale(args)


def _mesh_scale(args) -> float:
    """``--mesh-scale`` checked as export-subject checks it (:func:`facestats.io.mesh.check_mesh_scale`); 1 if not
    given."""
    from facestats.io.mesh import check_mesh_scale

    with named_options(mesh_scale="--mesh-scale"):
        return check_mesh_scale(args.mesh_scale, args.mesh)


def _subject_and_camera(args):
    """The store subject ``args.source`` (loaded), its face geometry (``--mesh``, else the one its provenance
    names: :func:`facestats.relight.camera.subject_geometry`) and the stage camera of ``--azimuth``,
    ``--elevation``, ``--size``."""
    from facestats.relight.camera import stage_camera, subject_geometry

    with open_store_option(args.store) as store:
        subject = store.subject(args.source, exclude=["micro_normal"])  # rendering uses the diffuse normal
    with named_options(mesh="--mesh"):  # a scan in m read as mm: "--mesh FILE is 0.2365 mm across ..."
        geometry = subject_geometry(subject, args.mesh, scale=_mesh_scale(args))
    return subject, geometry, stage_camera(args.azimuth, args.elevation, size=args.size)


def _ratio(args, directions):
    """``--ratio`` checked for a field of these light directions (L, 3) before any work.

    No ratio at or above :func:`facestats.relight.compression.ratio_bound` leaves room for a component (with
    ``compress``'s default sectors and parts): such a ``--ratio`` is refused naming it.
    """
    import numpy as np

    from facestats.errors import ValidationError
    from facestats.relight.compression import ratio_bound

    bound, n = ratio_bound(directions), int(np.prod(np.shape(directions)[:-1]))  # lights of an (…, 3) array
    if args.ratio >= bound:
        per_pixel = 3 * n / bound  # values per face pixel besides the components
        raise ValidationError(
            f"--ratio {args.ratio:g} cannot be met by a field of {n} lights: besides its components it stores "
            f"{per_pixel:g} values per face pixel, so the ratio must stay below 3 x {n} / {per_pixel:g} = "
            f"{bound:.4g}; pass a smaller --ratio"
        )
    return args.ratio


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


def _exr_image(image, mask):
    """The EXR's channels: R, G, B and the face mask as A (1 on the face) when there is a mask."""
    import numpy as np

    return image if mask is None else np.concatenate([image, mask[..., None].astype(image.dtype)], axis=-1)


def _face_mean(image, mask) -> str:
    """The mean radiance of the face's pixels (of every pixel without a mask, or with an empty one), as printed."""
    lum = image.mean(-1)
    if mask is None:
        return f"mean radiance {float(lum.mean()):.4g}"
    if not mask.any():  # a field store's empty mask: no face mean to give (it was NaN, with numpy's warnings)
        return f"mean radiance {float(lum.mean()):.4g} (the field's mask is empty: over the whole image)"
    return f"mean radiance {float(lum[mask].mean()):.4g}"


def _cmd_relight(args) -> int:
    """``facestats relight``; SIGTERM (``kill``) is Ctrl-C here, so that a turntable's temporary stage field and the
    outputs' temporary files are removed then too (:func:`facestats.core.processes.sigterm_as_interrupt`)."""
    from facestats.core.processes import sigterm_as_interrupt

    with sigterm_as_interrupt():
        return _relight(args)


def _relight(args) -> int:
    from facestats.core.outputs import check_output_file
    from facestats.io.probes import read_light_probe

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
    scale = _write_frames(args, targets, [args.rotate], mask, [(0, image)], {"method": "Debevec et al. 2000 eq. 4"})
    print(f"relit {args.source} under {args.probe} (rotated {args.rotate:g}°): {image.shape[1]} x {image.shape[0]}, "
          f"{_face_mean(image, mask)}, PNG exposure x{scale:.4g}")  # fmt: skip
    print(f"wrote {out}\nwrote {png}")
    return 0


def _turntable_field(args, tmp):
    """The field a turntable relights: the field store, or the subject's stage field streamed into ``tmp`` (float32,
    as a single relight renders it); ``--ratio`` checked against its lights before the field is rendered."""
    source = pathlib.Path(args.source)
    if source.is_dir():
        from facestats.relight.field import light_table, open_field

        field = open_field(source)
        if args.ratio is not None:
            _ratio(args, light_table(field)[0])
        return field
    from facestats.model.sphere import light_stage_directions
    from facestats.relight.stage import light_stage_field

    subject, geometry, camera = _subject_and_camera(args)
    d, _ = light_stage_directions(*_lights(args.lights))
    if args.ratio is not None:
        _ratio(args, d)  # before the field is rendered
    with named_options(lights="--lights"):  # more lights than the memory holds
        return light_stage_field(subject, camera, geometry=geometry, directions=d, out=pathlib.Path(tmp) / "field.zarr",
                                 dtype="float32", progress=not args.quiet)  # fmt: skip


def _turntable(args, probe, targets) -> int:
    """Frames of the environment turning about +y: dense relights, or through the compressed field (``--ratio``)."""
    import tempfile

    from facestats.relight.relighting import lighting_for, relight_frames

    step = 360.0 / len(targets)
    start = math.fmod(args.rotate, 360.0)  # first, as a single relight: 1e20 + 90 == 1e20
    angles = [math.fmod(start + k * step, 360.0) for k in range(len(targets))]
    with tempfile.TemporaryDirectory(prefix="facestats-stage-") as tmp:
        field = _turntable_field(args, tmp)
        mask = field["mask"].values if "mask" in field.data_vars else None

        def lightings(ks):
            return [lighting_for(field, probe, layout=args.layout, rotate=math.radians(angles[k])) for k in ks]

        if args.ratio is None:
            h, w = field.sizes["y"], field.sizes["x"]
            batch = max(1, BATCH_BYTES // (12 * h * w))  # frames of (h, w, 3) float32 per pass over the field

            def batches():
                for start in range(0, len(targets), batch):
                    ks = range(start, min(start + batch, len(targets)))
                    yield from zip(ks, relight_frames(field, lightings(ks), progress=not args.quiet))

            how = "dense relights (Debevec et al. 2000 eq. 4)"
            attrs = {"method": "Debevec et al. 2000 eq. 4"}
            scale = _write_frames(args, targets, angles, mask, batches(), attrs)
        else:
            comp, how, attrs = _compressed(args, field, mask, angles, lightings)
            frames = ((k, comp.relight(probe=probe, layout=args.layout, rotate=math.radians(a)))
                      for k, a in enumerate(angles))  # fmt: skip
            scale = _write_frames(args, targets, angles, mask, frames, attrs)
    print(f"turntable of {args.source} under {args.probe}: {len(targets)} frames every {step:g}° from "
          f"{args.rotate:g}°, {how}, PNG exposure x{scale:.4g}")  # fmt: skip
    print(f"wrote {targets[0][0]} ... {targets[-1][1]}")
    return 0


def _compressed(args, field, mask, angles, lightings):
    """The compressed field of a ``--ratio`` turntable, what it is (printed) and its EXR attributes, after measuring
    its error against dense relights of up to :data:`RATIO_CHECKS` frames spread over the turn (warning above
    :data:`RATIO_WARN`)."""
    import warnings

    import numpy as np

    from facestats.relight.compression import compress, relative_errors
    from facestats.relight.relighting import relight_frames

    with named_options(ratio="--ratio"):  # a ratio whose budget cannot hold the first component
        comp = compress(field, ratio=args.ratio, progress=not args.quiet)
    n = len(angles)
    checks = sorted({k * n // RATIO_CHECKS for k in range(RATIO_CHECKS)})
    dense = relight_frames(field, lightings(checks), progress=not args.quiet)
    face = mask if mask is not None and mask.any() else np.ones(dense.shape[1:3], bool)
    rel, mean = [], []
    for k, ref in zip(checks, dense):
        img = comp.relight(lightings([k])[0])
        rel.append(relative_errors(img, ref, face, floor=RATIO_FLOOR * ref[face].mean(0, dtype=np.float64)))
        got, want = float(img[face].mean()), float(ref[face].mean())
        mean.append(0.0 if got == want else abs(got - want) / want if want > 0 else math.inf)  # black both ways: 0
    rel = np.concatenate(rel)
    p99, worst = float(np.percentile(rel, 99)), float(rel.max())
    at = ", ".join(f"{angles[k]:g}°" for k in checks)
    error = (f"face mean within {100 * max(mean):.2g} %, 99th percentile of its pixel channels {100 * p99:.3g} %, "
             f"worst {100 * worst:.3g} % against the dense relight at {at}")  # fmt: skip
    if p99 > RATIO_WARN:
        warnings.warn(
            f"the compressed turntable (--ratio {args.ratio:g}) errs by more than {100 * RATIO_WARN:g} % on more than "
            f"1 % of the face's pixel channels ({100 * p99:.3g} % at the 99th percentile, worst {100 * worst:.3g} %); "
            "leave out --ratio for dense frames (exact, and faster in the measurements of docs/relighting.md), or "
            "pass a smaller --ratio",
            stacklevel=2,
        )
    how = f"compressed {comp.ratio:.1f}x ({comp.clusters} clusters, {comp.components} components): {error}"
    attrs = {"compression_ratio": f"{comp.ratio:.4g}", "compression_error": error,
             "method": "Debevec et al. 2000 eq. 4, compressed field (facestats.relight.compress)"}  # fmt: skip
    return comp, how, attrs


def _write_frames(args, targets, angles, mask, frames, attrs) -> float:
    """Write the frames (k, image), in order, as EXR (with the mask as alpha) + PNG, all or none; one PNG exposure,
    ``--exposure`` or the first frame's (:func:`facestats.relight.display.exposure_scale`).  Returns the exposure."""
    import numpy as np

    from facestats.core.outputs import OutputSet
    from facestats.io.images import write_image
    from facestats.relight.display import exposure_scale

    scale = args.exposure
    with OutputSet(targets[0][0].parent) as files:  # every frame or none
        for k, image in frames:
            if scale is None:  # a field store's empty mask: over the whole image
                scale = exposure_scale(image, mask if mask is not None and mask.any() else None)
            exr, png = targets[k]
            header = {"source": str(args.source), "probe": str(args.probe), "rotate_deg": repr(angles[k]),
                      "units": "radiance in the probe's unit", **attrs}  # fmt: skip
            if mask is not None:
                header["alpha"] = "face mask (1 on the face's pixels)"
            write_image(files.path(exr.absolute()), _exr_image(image, mask), attributes=header)
            write_image(files.path(png.absolute()), np.clip(image * scale, 0, 1), srgb=True)
    return scale


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
            "OpenEXR (RGB, and the face mask as alpha) and a tone-mapped sRGB PNG."
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
                   help="N frames, the environment turned by 360/N degrees between them, each a dense relight "
                   "(OUT_000.exr, OUT_000.png, ...)")  # fmt: skip
    p.add_argument("--ratio", type=ascii_float, default=None,
                   help="relight the turntable's frames through the field compressed at this minimum ratio instead "
                        "(default: dense, exact; the error against dense relights of up to 4 frames is printed, with "
                        "a warning above 3 %% at the face's 99th percentile)")  # fmt: skip
    p.add_argument("--mesh", metavar="PATH",
                   help="OBJ/PLY scan (with UVs) a subject's maps belong to, for a subject ingested from photographs "
                        "(default: the face its provenance records)")  # fmt: skip
    add_mesh_scale_option(p)
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_store_option(p)
    p.set_defaults(func=_cmd_relight)
