"""``facestats ingest``: a folder of dome photographs into a fitted subject (:mod:`facestats.pipeline.photographs`)."""

from __future__ import annotations

from facestats.cli.options import ascii_float, ascii_int, check_store_to_write, named_options

__all__ = ["add_ingest"]

#: The options of :func:`facestats.pipeline.photographs.ingest_subject`'s parameters (``path``: the store's, as
#: :func:`facestats.open_store` names it).
_NAMES = dict(
    photo_dir="PHOTO_DIR",
    mesh="--mesh",
    calibration="--calibration",
    store="--store",
    path="--store",
    subject_id="--subject",
    regions="--regions",
    work="--work",
    workers="--workers",
    motion_tolerance="--motion-tolerance",
    min_footprint_px="--min-footprint",
)


def _cmd_ingest(args) -> int:
    from facestats.pipeline.photographs import ingest_subject

    with named_options(**_NAMES):
        report = ingest_subject(
            args.photo_dir,
            args.mesh,
            args.calibration,
            check_store_to_write(args.store, "--store"),
            args.subject,
            regions=args.regions,
            work=args.work,
            workers=args.workers,
            motion_tolerance=args.motion_tolerance,
            min_footprint_px=args.min_footprint,
            progress=not args.quiet,
        )
    print(report.to_text())
    return 0


def add_ingest(sub):
    """Register ``facestats ingest``.

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
        "ingest",
        help="turn a folder of dome photographs into a fitted subject in a store (resumable)",
        description=(
            "Read a capture folder (manifest.json, format facestats.capture-folder/1: per camera, LED and exposure "
            "one photograph), merge each frame's exposures with the calibrated camera response, sample the "
            "lumitexels of the face mesh in every calibrated camera, fit the skin model and write the subject to the "
            "store. The capture is kept in a work directory filled camera by camera: rerunning resumes at the first "
            "unfinished camera, and the subject reaches the store only when everything is done."
        ),
    )
    p.add_argument("photo_dir", metavar="PHOTO_DIR", help="capture folder with manifest.json")
    p.add_argument("--mesh", required=True, help="face mesh (OBJ/PLY with UVs, mm, world frame)")
    p.add_argument("--calibration", required=True, help="dome calibration JSON (cameras K, dist, R, t; LEDs; response)")
    p.add_argument("--store", required=True, help="directory store to write the subject into (created if missing)")
    p.add_argument("--subject", required=True, metavar="ID", help="subject id in the store")
    p.add_argument(
        "--regions",
        help="face-region label image, PNG, TIFF or .npy (default: <mesh stem>.regions.png|.npy|.tif next to the mesh)",
    )
    p.add_argument("--work", help="where the capture is kept (default: <store>.ingest/<ID>/capture.zarr)")
    p.add_argument("--workers", type=ascii_int, default=2, help="threads decoding photographs (default 2)")
    p.add_argument(
        "--motion-tolerance",
        type=ascii_float,
        default=None,
        help="head-motion threshold: fraction of face pixels whose two exposures disagree by > e^0.5 (default 0.001)",
    )
    p.add_argument(
        "--min-footprint",
        type=ascii_float,
        default=None,
        help="pixels a lumitexel must span along its foreshortened axis to give a sample (default 2)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_ingest)
