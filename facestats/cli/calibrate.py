"""``facestats calibrate response``: a camera's response from a bracket of photographs
(:func:`facestats.acquire.bracket.calibrate_response`); ``facestats calibrate leds``: LED intensities
and beams from photographs of a diffuse target (:func:`facestats.acquire.calibration.calibrate_leds`)."""

from __future__ import annotations

import contextlib
import os
import pathlib
import sys

from facestats.cli.options import ascii_float, ascii_int, named_options, non_empty
from facestats.errors import ValidationError

__all__ = ["add_calibrate"]


def _check_outputs(outputs) -> list:
    """Check each output ``(path or None, option, suffixes)`` with :func:`facestats.core.outputs.check_output_file`.

    Returns ``(os.stat_result, path, option)`` of the outputs that exist already, for :func:`_refuse_inputs`.
    """
    from facestats.core.outputs import check_output_file

    existing = []
    for path, option, suffixes in outputs:
        if path is not None:  # before the fit: a bad output path must not cost a calibration
            p = check_output_file(path, option, suffixes)  # ~ expanded, as the files are written
            if os.path.exists(p):
                existing.append((os.stat(p), path, option))
    return existing


def _refuse_inputs(existing, inputs, overwrite: bool) -> None:
    """Refuse, before any work, an output that is one of the command's inputs ``(path, what)``, then (without
    ``overwrite``, ``--overwrite``) any output that exists.

    ``existing`` is what :func:`_check_outputs` returned.  An output is an input when both name
    the same file (:func:`os.path.samestat`: the same device and inode, whatever links or
    relative spellings lead there): writing it would replace a photograph, a manifest or the
    calibration being read.
    """
    if not existing:
        return
    for source, what in inputs:  # one stat per input
        try:
            st = os.stat(pathlib.Path(source).expanduser())
        except OSError:
            continue  # a missing input is refused when it is read
        for out, path, option in existing:
            if os.path.samestat(out, st):
                raise ValidationError(
                    f"{option} must not be one of the inputs, got {os.fspath(path)!r}, which is {what} "
                    "(writing it would replace it)"
                )
    if not overwrite:
        _, path, option = existing[0]
        raise ValidationError(f"{option} {os.fspath(path)!r} exists (pass --overwrite to replace it)")


def _write_all(writers) -> None:
    """Write every ``(path, write(tmp_path), message)`` together (:class:`facestats.core.outputs.OutputSet`)."""
    from facestats.core.outputs import OutputSet

    writers = [w for w in writers if w[0]]
    if not writers:
        return
    with OutputSet(".") as files:  # all files or none: a failure replaces nothing
        for path, write, _ in writers:
            write(files.path(pathlib.Path(path).expanduser().absolute()))  # as check_output_file read it
    for _, _, message in writers:
        print(message)


def _cmd_leds(args) -> int:
    from facestats.acquire.calibration import MAX_GRID, calibrate_leds
    from facestats.acquire.dome import Dome
    from facestats.acquire.photographs import MANIFEST, open_folder
    from facestats.core.validate import check_integer

    check_integer(args.grid, "--grid", 2, MAX_GRID)  # before any work: a huge grid would exhaust the memory
    if args.black_level is not None:  # its upper bound, 2**bits / 2, once the bits are known
        check_integer(args.black_level, "--black-level", 0)
    _check_white_level(args.white_level, None)
    existing = _check_outputs(((args.output, "--output", None), (args.write_calibration, "--write-calibration", None)))
    calibration = args.calibration or str(pathlib.Path(args.target_dir) / "dome.json")
    dome = Dome.load(calibration)  # a FIFO, a directory or a device is refused without blocking
    folder = open_folder(args.target_dir)  # the manifest and the frames it lists (stat only)
    _check_white_level(args.white_level, folder.bits)
    frames = [folder.path / f for f in folder.files.reshape(-1) if f is not None]
    _refuse_inputs(
        existing,
        [(calibration, f"--calibration {calibration!r}"), (folder.path / MANIFEST, "the target folder's manifest")]
        + [(f, f"the target photograph {str(f)!r}") for f in frames],
        args.overwrite,
    )
    with named_options(grid="--grid", reference_camera="--reference-camera", black_level="--black-level",
                       white_level="--white-level"):  # fmt: skip
        result = calibrate_leds(
            folder,
            dome,
            grid=args.grid,
            reference_camera=args.reference_camera,
            black_level=args.black_level,
            white_level=args.white_level,
        )
    print(result.to_text())
    _warn_leds(result, args)
    applied = result.apply(dome) if args.write_calibration else None  # any error before any file is written
    _write_all([
        (args.output, lambda p: result.save(p, dome), f"LED calibration written to {args.output}"),
        (args.write_calibration, applied.save if applied is not None else None,
         f"calibration with the fitted LEDs written to {args.write_calibration}"),
    ])  # fmt: skip
    # A calibration written with LEDs left at their previous photometry is incomplete: say so in the exit
    # status too (1, as `build` does for a partial result), for the scripts that run the lab's calibration.
    return 1 if args.write_calibration and result.uncalibrated.size else 0


def _warn_leds(result, args) -> None:
    """Warn on stderr about the LEDs without a fit (what the outputs hold for them) and poorly determined beams."""
    text = result.uncalibrated_text()
    if text:
        held = []
        if args.write_calibration:
            held.append("--write-calibration keeps their previous intensity and beam")
        if args.output:
            held.append("--output records null for them")
        print(f"facestats: warning: {text}" + (f"; {', '.join(held)}" if held else ""), file=sys.stderr)
    for line in result.poorly_determined_text():
        print(f"facestats: warning: {line}", file=sys.stderr)
    if result.noisy_text():
        print(f"facestats: warning: {result.noisy_text()}", file=sys.stderr)


@contextlib.contextmanager
def _level_options(args):
    """Re-raise the API's ``black_level`` / ``white_level`` refusals as the command's options, with a hint when the
    bit depth came from the files (e.g. 14-bit codes in 16-bit files need ``--bits 14``)."""
    try:
        yield
    except ValidationError as exc:
        text = str(exc)
        for name in ("white_level", "black_level"):
            if text.startswith(name):
                hint = "" if args.bits is not None else " (the files set the bit depth: pass --bits N for N-bit codes)"
                raise ValidationError("--" + name.replace("_", "-") + text[len(name) :] + hint) from None
        raise


def _cmd_response(args) -> int:
    from facestats.acquire.bracket import calibrate_response
    from facestats.acquire.response import MAX_SMOOTHNESS
    from facestats.core.validate import as_finite, check_integer

    if args.smoothness is not None:  # before the photographs are read: an out-of-range λ ends in an overflow
        as_finite(args.smoothness, "--smoothness", 0, MAX_SMOOTHNESS)
    check_integer(args.black_level, "--black-level", 0)  # its upper bound, 2**bits / 2, once the bits are known
    _check_white_level(args.white_level, args.bits)
    for option, given, what in (
        ("--cameras", args.cameras, "the cameras that get this response in the written calibration"),
        ("--calibration", args.calibration, "the calibration the response is put into"),
    ):
        if given is not None and not args.write_calibration:  # it would be ignored
            raise ValidationError(f"{option} needs --write-calibration ({option} names {what})")
    outputs = (
        (args.output, "--output", None),
        (args.plot, "--plot", (".png", ".svg", ".pdf")),
        (args.write_calibration, "--write-calibration", None),
    )
    inputs = [(f, f"IMAGE {os.fspath(f)!r}") for f in args.images]
    if args.calibration:
        inputs.append((args.calibration, f"--calibration {args.calibration!r}"))
    _refuse_inputs(_check_outputs(outputs), inputs, args.overwrite)
    if args.write_calibration and not args.calibration:
        raise ValidationError("--write-calibration needs --calibration (the dome calibration to put the response into)")
    dome = None
    if args.calibration:
        from facestats.acquire.dome import Dome

        dome = Dome.load(args.calibration)  # read before the fit: a bad calibration must not cost one
        _check_apply(dome, args)
    options = named_options(exposure_times="--times", bits="--bits", smoothness="--smoothness", samples="--samples")
    with options, _level_options(args):  # the levels' bounds known only from the files: name the options
        result = calibrate_response(
            args.images,
            args.times,
            bits=args.bits,
            smoothness=args.smoothness,
            samples=args.samples,
            black_level=args.black_level,
            white_level=args.white_level,
        )
    print(result.to_text())
    for line in result.warnings():
        print(f"facestats: warning: {line}", file=sys.stderr)
    # Everything that can fail before any file is written (a file replaced by a failed command is lost).
    applied = result.apply(dome, args.cameras) if args.write_calibration else None
    figure = None
    if args.plot:
        from facestats.acquire.plots import plot_response

        figure = plot_response(result.log_response)
    which = "every camera" if args.cameras is None else f"camera(s) {', '.join(map(str, args.cameras or []))}"
    _write_all([
        (args.output, result.save, f"response written to {args.output}"),
        (args.plot, lambda p: figure.savefig(p, dpi=120), f"plot written to {args.plot}"),
        (args.write_calibration, applied.save if applied is not None else None,
         f"calibration with this response for {which} written to {args.write_calibration}"),
    ])  # fmt: skip
    return 0


def _cmd_merge(args) -> int:
    import json

    import numpy as np

    from facestats.acquire.bracket import merge_bracket
    from facestats.io.images import write_image

    existing = _check_outputs([(args.out, "--out", (".exr", ".hdr", ".pfm"))])
    inputs = [(f, f"IMAGE {os.fspath(f)!r}") for f in args.images] + [(args.response, "--response")]
    _refuse_inputs(existing, inputs, args.overwrite)
    with named_options(exposure_times="--times"):
        merged = merge_bracket(args.images, args.response, args.times, saturated=args.saturated)
    radiance, saturated = merged.radiance, merged.saturated_pixels
    attrs = {"units": "exp(g)/s (the response's)", "response": os.fspath(args.response),
             "frames": json.dumps([os.fspath(f) for f in args.images]), "saturated_fill": args.saturated,
             "exposure_times_s": json.dumps([float(t) for t in merged.exposure_times]),
             "method": "Debevec & Malik 1997 eq. 6 (facestats.acquire.response.merge_photographs)"}  # fmt: skip
    h, w = radiance.shape[:2]
    values = radiance.reshape(h * w, -1)  # what is written, per channel (a mean over channels hid their ranges)
    low, high, mid = values.min(0), values.max(0), np.median(values, axis=0)
    ranges = ", ".join(f"{ch} {lo:.4g} to {hi:.4g} (median {md:.4g})" for ch, lo, hi, md in zip("RGB", low, high, mid))
    print(f"merged {len(args.images)} photographs: {w} x {h}, radiance written per channel: {ranges}")
    print(f"  in the response's units (exp(g)/s); overall {float(low.min()):.4g} to {float(high.max()):.4g}")
    if saturated:
        print(
            f"facestats: warning: {saturated} pixel(s) saturated in every exposure ({saturated / (h * w):.2%}); "
            + ("given the lower bound of their radiance (--saturated clip)" if args.saturated == "clip"
               else "set to 0 (--saturated zero)")
            + ": add a shorter exposure to measure them",
            file=sys.stderr,
        )  # fmt: skip

    for line in merged.warnings():
        print(f"facestats: warning: {line}", file=sys.stderr)
    attrs_only = attrs if args.out.lower().endswith(".exr") else None
    _write_all([(args.out, lambda p: write_image(p, radiance, attributes=attrs_only), f"wrote {args.out}")])
    return 0


def _check_white_level(white_level, bits) -> None:
    """Refuse a ``--white-level`` (DN, the Z_max of Debevec & Malik 1997 eq. 4) that is no code of ``bits`` bits
    above mid-range, (2**bits / 2, 2**bits − 1] (g is pinned at 2**bits / 2, below the white level); without
    ``bits`` yet, one that is no code above mid-range at any bit depth up to 16."""
    from facestats.core.validate import check_integer

    if white_level is None:
        return
    if bits is None or isinstance(bits, bool) or not isinstance(bits, int) or not 1 <= bits <= 16:
        check_integer(white_level, "--white-level", 2, 2**16 - 1)  # bits checked where they are used
        return
    check_integer(white_level, "--white-level", 2 ** (bits - 1) + 1, 2**bits - 1)


def _check_apply(dome, args) -> None:
    """Refuse, before the fit, what :meth:`ResponseCalibration.apply` would refuse after it, where the options
    tell already: cameras the calibration lacks, some cameras of a calibration without responses or with another
    black or white level, a ``--white-level`` out of the range of the calibration's responses, a ``--bits`` whose
    levels differ from the calibration's responses (else the files' bits decide)."""
    n_cam = dome.n_cameras
    cameras = list(range(n_cam)) if args.cameras is None else args.cameras
    bad = [c for c in cameras if not 0 <= c < n_cam]
    if bad:
        raise ValidationError(f"--cameras must be in [0, {n_cam}), got {bad}: --calibration has {n_cam} cameras")
    every = sorted(set(cameras)) == list(range(n_cam))
    current = dome.camera_log_response
    if current is None and not every:
        raise ValidationError(
            f"--cameras must be every camera (0-{n_cam - 1}): --calibration has no camera responses yet, got {cameras}"
        )
    if current is not None and not every and dome.camera_black_level != args.black_level:
        raise ValidationError(
            f"--black-level must be the calibration's camera_black_level ({dome.camera_black_level}) when only "
            f"--cameras {' '.join(map(str, cameras))} take this response (the cameras share one), got "
            f"{args.black_level}"
        )
    levels = None if current is None else current.shape[1]
    if levels is not None and args.bits is None:
        _check_white_level(args.white_level, levels.bit_length() - 1)
    if current is not None and not every:
        top = levels - 1
        have = top if dome.camera_white_level is None else dome.camera_white_level
        if have != (top if args.white_level is None else args.white_level):
            raise ValidationError(
                f"--white-level must be the calibration's camera_white_level ({have}) when only --cameras "
                f"{' '.join(map(str, cameras))} take this response (the cameras share one), got "
                f"{'none (the top code)' if args.white_level is None else args.white_level}"
            )
    if levels is not None and args.bits is not None and levels != 2 ** min(args.bits, 64):
        raise ValidationError(
            f"--bits must be {levels.bit_length() - 1} to match the calibration's responses ({levels} levels), "
            f"got {args.bits}"
        )


def _samples(text: str):
    """``--samples``: ``histogram``, ``stratified`` or a number of histogram samples."""
    import argparse

    if text in ("histogram", "stratified"):
        return text
    try:
        return ascii_int(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(
            f"must be histogram, stratified or a number of samples (ASCII digits 0-9), got {text!r}"
        ) from None


def add_calibrate(sub):
    """Register ``facestats calibrate`` and its ``leds``, ``response`` and ``merge`` commands.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        What ``add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    None
        The handlers (``func``) return 0, or 1 from ``leds`` when ``--write-calibration`` kept LEDs uncalibrated;
        ``calibrate`` alone prints its help and returns 2; a :class:`~facestats.errors.FacestatsError` raised becomes
        exit status 2 in :func:`facestats.cli.main`.
    """
    p = sub.add_parser(
        "calibrate",
        help="calibrate cameras and LEDs from photographs (response from a bracket, LEDs from a diffuse target)",
        description=(
            "Calibrate a dome from photographs: 'response' recovers a camera's response curve g(Z) from an exposure "
            "bracket (Debevec & Malik 1997), 'merge' merges a bracket into linear HDR radiance with it, 'leds' fits "
            "every LED's intensity and beam from photographs of a white diffuse target (docs/photographs.md)."
        ),
    )
    csub = p.add_subparsers(title="what", metavar="WHAT")
    leds = csub.add_parser(
        "leds",
        help="fit every LED's intensity and beam polynomial from photographs of a white diffuse target",
        description=(
            "Read a target folder (manifest.json of kind 'target': photographs of a planar Lambertian target of "
            "known albedo at known poses under every LED), merge the HDR frames, and fit each LED's RGB intensity "
            "and bi-variate 2nd-degree beam polynomial, plus the cameras' relative gains (Weyrich et al. 2006 §5). "
            "Prints the fitted LEDs with their RMS relative residuals. LEDs with fewer than 12 usable observations "
            "are not calibrated: a warning names them, --output records null for them, --write-calibration keeps "
            "their previous intensity and beam and the command then exits with status 1. A warning also names "
            "each LED whose beam is extrapolated beyond its observations (its standard error on the target above "
            "the RMS residual of one observation; docs/photographs.md)."
        ),
    )
    leds.add_argument("target_dir", metavar="TARGET_DIR", help="target folder with manifest.json")
    leds.add_argument(
        "--calibration", type=non_empty, help="dome calibration JSON with the cameras (default TARGET_DIR/dome.json)"
    )
    leds.add_argument("--grid", type=ascii_int, default=24, help="target points per side per pose, 2-100 (default 24)")
    leds.add_argument(
        "--reference-camera", type=ascii_int, default=None, help="camera whose gain is 1 (default: most data)"
    )
    leds.add_argument(
        "--black-level",
        type=ascii_int,
        default=None,
        metavar="DN",
        help="the cameras' pedestal: codes at and below it get no weight in the merge (default: the calibration's "
        "camera_black_level, 0 if none)",
    )
    leds.add_argument(
        "--white-level",
        type=ascii_int,
        default=None,
        metavar="DN",
        help="the code at and above which the cameras clip, above mid-range: codes at and above it get no weight in "
        "the merge (default: the calibration's camera_white_level, the top code if none)",
    )
    leds.add_argument("--output", help="write the LED calibration file (facestats.led-calibration/1)")
    leds.add_argument("--write-calibration", metavar="PATH", help="write the dome calibration with the fitted LEDs")
    leds.add_argument("--overwrite", action="store_true", help="replace existing output files")
    leds.set_defaults(func=_cmd_leds)
    merge = csub.add_parser(
        "merge",
        help="merge a bracket of photographs into one radiance image with a recovered response",
        description=(
            "Read photographs of one static scene at several exposure times (as 'calibrate response' does; times "
            "from EXIF unless given) and merge them with a response file written by 'calibrate response --output' "
            "(Debevec & Malik 1997 eq. 6, the response's black and white levels). Pixels saturated in every "
            "exposure have no measured radiance: --saturated clip (default) gives them the lower bound of their "
            "radiance, exp(g(white level)) / the shortest time, zero gives them 0; pixels dark in the short "
            "exposures and clipped in the long ones get the geometric mean of their bounds. Warnings count both. "
            "Writes OpenEXR (.exr), Radiance (.hdr) or PFM."
        ),
    )
    merge.add_argument("images", metavar="IMAGE", nargs="+", help="the bracket's photographs, any order")
    merge.add_argument("--response", required=True, metavar="FILE.json", help="response file (calibrate response)")
    merge.add_argument(
        "--times", type=ascii_float, nargs="+", metavar="SECONDS", help="exposure times, one per IMAGE (default EXIF)"
    )
    merge.add_argument("--out", required=True, metavar="FILE", help="radiance image: .exr, .hdr or .pfm")
    merge.add_argument("--saturated", choices=("clip", "zero"), default="clip",
                       help="fill of pixels saturated in every exposure: clip, the lower bound of their radiance "
                            "(default); zero")  # fmt: skip
    merge.add_argument("--overwrite", action="store_true", help="replace existing output files")
    merge.set_defaults(func=_cmd_merge)
    resp = csub.add_parser(
        "response",
        help="recover a camera's response curve from a bracket of photographs (Debevec & Malik 1997)",
        description=(
            "Read photographs of one static scene at several exposure times (JPEG, PNG or TIFF; times from EXIF "
            "unless given), recover the camera's response g = ln f^-1 per channel (Debevec & Malik 1997, "
            "histogram samples), and print how well it makes consecutive exposures agree. Use three or more "
            "exposures, with unequal steps where possible (docs/photographs.md)."
        ),
    )
    resp.add_argument("images", metavar="IMAGE", nargs="+", help="the bracket's photographs, any order")
    resp.add_argument(
        "--times", type=ascii_float, nargs="+", metavar="SECONDS", help="exposure times, one per IMAGE (default EXIF)"
    )
    resp.add_argument("--bits", type=ascii_int, help="bit depth of the codes (default 8 or 16 from the files)")
    resp.add_argument("--smoothness", type=ascii_float, help="lambda of the smoothness term (default 10*sqrt(N/70))")
    resp.add_argument("--samples", type=_samples, help="histogram (default), stratified, or a number of samples")
    resp.add_argument(
        "--black-level",
        type=ascii_int,
        default=0,
        metavar="DN",
        help="the sensor's pedestal: codes at and below it get no weight, g is recovered above it (default 0); "
        "--write-calibration records it as the calibration's camera_black_level, which the ingest merges with",
    )
    resp.add_argument(
        "--white-level",
        type=ascii_int,
        default=None,
        metavar="DN",
        help="the code at and above which the sensor clips (e.g. 15000 for a 14-bit raw), above mid-range: codes "
        "at and above it get no weight, g is recovered below it (default the top code 2^bits - 1); "
        "--write-calibration records it as the calibration's camera_white_level, which the ingest merges with",
    )
    resp.add_argument("--output", help="write the response (JSON, facestats.camera-response/1)")
    resp.add_argument("--plot", help="draw g(z) per channel (.png, .svg or .pdf)")
    resp.add_argument(
        "--calibration",
        type=non_empty,
        help="dome calibration JSON to put the response into (with --write-calibration)",
    )
    resp.add_argument(
        "--cameras",
        type=ascii_int,
        nargs="+",
        metavar="C",
        help="cameras that get this response in --write-calibration (default all)",
    )
    resp.add_argument("--write-calibration", metavar="PATH", help="write the dome calibration with this response")
    resp.add_argument("--overwrite", action="store_true", help="replace existing output files")
    resp.set_defaults(func=_cmd_response)
    p.set_defaults(func=lambda args: p.print_help() or 2)
