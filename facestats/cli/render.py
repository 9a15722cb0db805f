"""``facestats render``: a fitted subject rendered beside its capture (:mod:`facestats.pipeline.validation`)."""

from __future__ import annotations

import os

from facestats.cli.options import add_store_option, ascii_int, open_store_option

__all__ = ["add_render"]


def _cmd_render(args) -> int:
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    from facestats.acquire.capture import open_capture
    from facestats.io.images import write_image
    from facestats.io.subject_export import store_subject
    from facestats.pipeline.validation import default_capture, render_led, render_probe

    with open_store_option(args.store) as st:
        ds = store_subject(st, args.subject_id)
    cap = open_capture(args.capture) if args.capture else default_capture(ds)
    if args.probe:
        res = render_probe(ds, cap, args.camera, args.probe)
    else:
        res = render_led(ds, cap, args.camera, args.light)
    os.makedirs(args.out, exist_ok=True)
    stem = os.path.join(args.out, f"{args.subject_id}-cam{args.camera:02d}")
    write_image(stem + "-rendered.exr", np.nan_to_num(res.rendered).clip(0))
    if res.reference is not None:
        write_image(stem + "-capture.exr", np.nan_to_num(res.reference).clip(0))
        write_image(stem + "-error.exr", np.nan_to_num(res.error))
    res.figure().savefig(stem + ".png", dpi=120)
    if res.relative_rmse is not None:
        print(
            f"{args.subject_id} camera {args.camera} {res.light}: "
            f"RMSE {res.rmse:.4g}, relative {100 * res.relative_rmse:.2f} %"
        )
    print(f"wrote {stem}.png and the EXR images beside it")
    return 0


def add_render(sub):
    p = sub.add_parser(
        "render",
        help="validation render of a fitted subject beside its capture, with the error image and RMSE",
        description=(
            "Render a fitted subject with the skin model (specular with per-view micro-normals where stored, "
            "diffuse through the spatial dipole transport) for one dome camera under one LED (with the capture's "
            "radiance, the error image and the RMSE) or under a lat-long light probe. Without --capture, subjects "
            "of the embedded default store are re-simulated."
        ),
    )
    p.add_argument("subject_id", metavar="ID")
    p.add_argument("--out", required=True, metavar="DIR", help="directory for the images")
    p.add_argument("--camera", type=ascii_int, default=5, help="dome camera (default 5)")
    p.add_argument("--light", type=ascii_int, default=20, help="dome LED (default 20)")
    p.add_argument("--probe", metavar="FILE", help="render under this lat-long HDR probe instead of an LED")
    p.add_argument(
        "--capture", metavar="PATH", help="the subject's capture (zarr); default: re-simulate a default subject"
    )
    add_store_option(p)
    p.set_defaults(func=_cmd_render)
