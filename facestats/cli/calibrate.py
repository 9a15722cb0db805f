"""``facestats calibrate leds``: LED intensities and beams from photographs of a diffuse target
(:func:`facestats.acquire.calibration.calibrate_leds`)."""

from __future__ import annotations

import pathlib

from facestats.cli.options import ascii_int

__all__ = ["add_calibrate"]


def _cmd_leds(args) -> int:
    from facestats.acquire.calibration import calibrate_leds
    from facestats.acquire.dome import Dome
    from facestats.core.outputs import check_output_file

    for path, option in ((args.output, "--output"), (args.write_calibration, "--write-calibration")):
        if path is not None:  # before the fit: a bad output path must not cost a calibration
            check_output_file(path, option)
    calibration = args.calibration or str(pathlib.Path(args.target_dir) / "dome.json")
    dome = Dome.load(calibration)  # a FIFO, a directory or a device is refused without blocking
    result = calibrate_leds(args.target_dir, dome, grid=args.grid, reference_camera=args.reference_camera)
    print(result.to_text())
    if args.output:
        result.save(args.output, dome)
        print(f"LED calibration written to {args.output}")
    if args.write_calibration:
        result.apply(dome).save(args.write_calibration)
        print(f"calibration with the fitted LEDs written to {args.write_calibration}")
    return 0


def add_calibrate(sub):
    p = sub.add_parser("calibrate", help="calibrate the dome from photographs (LEDs from a diffuse target)")
    csub = p.add_subparsers(title="what", metavar="WHAT")
    leds = csub.add_parser(
        "leds",
        help="fit every LED's intensity and beam polynomial from photographs of a white diffuse target",
        description=(
            "Read a target folder (manifest.json of kind 'target': photographs of a planar Lambertian target of "
            "known albedo at known poses under every LED), merge the HDR frames, and fit each LED's RGB intensity "
            "and bi-variate 2nd-degree beam polynomial, plus the cameras' relative gains (Weyrich et al. 2006 §5). "
            "Prints the fitted LEDs with their RMS relative residuals."
        ),
    )
    leds.add_argument("target_dir", metavar="TARGET_DIR", help="target folder with manifest.json")
    leds.add_argument("--calibration", help="dome calibration JSON with the cameras (default TARGET_DIR/dome.json)")
    leds.add_argument("--grid", type=ascii_int, default=24, help="target points per side per pose (default 24)")
    leds.add_argument(
        "--reference-camera", type=ascii_int, default=None, help="camera whose gain is 1 (default: most data)"
    )
    leds.add_argument("--output", help="write the LED calibration file (facestats.led-calibration/1)")
    leds.add_argument("--write-calibration", metavar="PATH", help="write the dome calibration with the fitted LEDs")
    leds.set_defaults(func=_cmd_leds)
    p.set_defaults(func=lambda args: p.print_help() or 2)
