"""``facestats capture dome|sensor``: a resumable capture session on the lab's devices
(:mod:`facestats.acquire.devices.capture`)."""

from __future__ import annotations

import sys

from facestats.cli.options import ascii_float, ascii_int, named_options, non_empty, number_option
from facestats.core.processes import sigterm_as_interrupt

__all__ = ["add_capture"]

#: The option of each subject-record field (a field read from ``--metadata`` keeps its JSON name in messages).
_RECORD_OPTIONS = {
    "person_id": "--person",
    "age": "--age",
    "gender": "--gender",
    "skin_type": "--skin-type",
    "condition": "--condition",
}


def _subject(args) -> dict:
    from facestats.acquire.devices.capture import read_subject_record
    from facestats.acquire.devices.plans import subject_record
    from facestats.errors import ValidationError

    record = read_subject_record(args.metadata) if args.metadata else {}
    record = {k: v for k, v in record.items() if k in ("person_id", "age", "gender", "skin_type", "condition")}
    for key in ("person_id", "age", "gender", "skin_type", "condition"):
        if getattr(args, key) is not None:
            record[key] = getattr(args, key)
    missing = [k for k in ("age", "gender", "skin_type") if k not in record]
    if missing:
        raise ValidationError(
            f"the capture folder's manifest needs the subject's {', '.join(missing)}: pass --age, --gender and "
            "--skin-type, or --metadata FILE (a JSON subject record)"
        )
    given = {key: option for key, option in _RECORD_OPTIONS.items() if getattr(args, key) is not None}
    with named_options(subject_id="--subject", **given):
        return subject_record(args.subject, **record)


def _run(args, plan, calibration, on_site=None) -> int:
    from facestats.acquire.devices.capture import capture

    if args.dry_run:
        print(plan.describe())
        return 0
    link = dict(
        baudrate=args.baudrate,
        bytesize=args.bytesize,
        parity=args.parity,
        stopbits=args.stopbits,
        timeout=args.timeout,
        retries=args.retries,
    )
    from tqdm.auto import tqdm

    echo = None if args.quiet else (lambda line: tqdm.write(f"[session] {line}", file=sys.stderr))
    names = dict(frame_timeout="--frame-timeout", pattern="--pattern", timeout="--timeout", retries="--retries")
    names.update(baudrate="--baudrate", bytesize="--bytesize", parity="--parity", stopbits="--stopbits")
    # the driver's context manager switches the lights off
    with sigterm_as_interrupt(), named_options(**names):
        report = capture(
            plan,
            calibration,
            args.port,
            args.out,
            args.hot_folder,
            resume=args.resume,
            link_options=link,
            pattern=args.pattern,
            frame_timeout=args.frame_timeout,
            durable=not args.no_fsync,
            verify=args.verify,
            progress=not args.quiet,
            on_site=on_site,
            echo=echo,
        )
    print(report.to_text())
    return 0


def _cmd_dome(args) -> int:
    from facestats.acquire.devices.capture import dome_plan

    colour = tuple(number_option(v, int, "--colour") for v in args.colour.split(","))
    subject = _subject(args)
    with named_options(brightness="--brightness", colour="--colour", frame_interval_s="--frame-interval"):
        plan, calibration = dome_plan(
            args.calibration, subject, brightness=args.brightness, colour=colour, frame_interval_s=args.frame_interval
        )
    return _run(args, plan, calibration)


def _cmd_sensor(args) -> int:
    from facestats.acquire.devices.capture import sensor_plan

    subject = _subject(args)
    with named_options(readout_s="--readout"):
        plan, calibration = sensor_plan(args.calibration, subject, readout_s=args.readout)

    def place(site):
        print(f"place the sensor head on the {site}" + ("" if args.yes else " and press Enter"), file=sys.stderr)
        if not args.yes and sys.stdin.isatty():
            input()

    return _run(args, plan, calibration, on_site=place)


def _common(p, calibration_help):
    p.add_argument(
        "--port", required=True, type=non_empty, help="serial device or pyserial URL (loop://, socket://, rfc2217://)"
    )
    p.add_argument("--subject", required=True, metavar="ID", help="subject id written into the manifest")
    p.add_argument(
        "--out", required=True, type=non_empty, metavar="CAPTURE_DIR", help="capture directory (new, or with --resume)"
    )
    p.add_argument("--calibration", required=True, help=calibration_help)
    p.add_argument(
        "--hot-folder", required=True, type=non_empty, help="directory the camera software drops frames into"
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue the session in CAPTURE_DIR; frames deleted from a finished one are taken again",
    )
    p.add_argument("--dry-run", action="store_true", help="print the plan and its duration; touch nothing")
    s = p.add_argument_group("subject record (or --metadata FILE)")
    s.add_argument(
        "--metadata", type=non_empty, help="JSON subject record (person_id, age, gender, skin_type, condition)"
    )
    s.add_argument("--person", dest="person_id", type=non_empty, help="person id (default: the subject id)")
    s.add_argument("--age", type=ascii_int)
    s.add_argument("--gender", choices=("M", "F"))
    s.add_argument("--skin-type", type=ascii_int, help="Fitzpatrick skin type 1-6")
    s.add_argument("--condition", help="normal, cold, hot, sweaty, makeup, lotion or powder (default normal)")
    line = p.add_argument_group("serial line")
    line.add_argument("--baudrate", type=ascii_int, default=115200, help="default 115200")
    line.add_argument("--bytesize", type=ascii_int, default=8, choices=(5, 6, 7, 8), help="default 8")
    line.add_argument("--parity", default="N", choices=("N", "E", "O", "M", "S"), help="default N")
    line.add_argument("--stopbits", type=ascii_float, default=1, choices=(1, 1.5, 2), help="default 1")
    line.add_argument("--timeout", type=ascii_float, default=1.0, help="seconds to wait for a reply (default 1)")
    line.add_argument("--retries", type=ascii_int, default=5, help="attempts after the first (default 5)")
    p.add_argument(
        "--pattern",
        default="cam{camera:02d}/{frame:012d}{ext}",
        help="frame file name in the hot folder (relative, without '..')",
    )
    p.add_argument("--frame-timeout", type=ascii_float, default=60.0, help="seconds to wait for a frame (default 60)")
    p.add_argument("--no-fsync", action="store_true", help="do not fsync frames and journal (faster, not power-safe)")
    p.add_argument("--verify", action="store_true", help="on --resume, also check the checksum of every stored frame")
    p.add_argument("--quiet", action="store_true", help="no progress bar, no session log on stderr")


def add_capture(sub):
    """Register ``facestats capture`` and its ``dome`` and ``sensor`` sequences.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        What ``add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    None
        The handlers (``func``) return 0; ``capture`` alone prints its help and returns 2; a
        :class:`~facestats.errors.FacestatsError` raised becomes exit status 2 in :func:`facestats.cli.main`.
    """
    p = sub.add_parser(
        "capture",
        help="run the dome's or the contact sensor's capture sequence on the lab's devices (resumable)",
        description=(
            "Drive the dome (every LED × every camera × two exposure settings, Weyrich et al. 2006 §5) or the contact "
            "sensor (3 sites × 23-image bracket, §5.4) over a serial port, collect the cameras' frames from their hot "
            "folder and write a capture folder that `facestats ingest` reads. Each completed step is journaled; "
            "--resume continues after a crash, a kill or a disconnect, and the finished folder is identical to an "
            "uninterrupted one."
        ),
    )
    csub = p.add_subparsers(title="device", metavar="DEVICE")
    dome = csub.add_parser("dome", help="the dome's sequence")
    _common(dome, "dome calibration JSON (LEDs, cameras, exposure times, response)")
    dome.add_argument("--brightness", type=ascii_int, default=255, help="LED brightness 0-255 (default 255)")
    dome.add_argument("--colour", default="255,255,255", help="LED colour R,G,B 0-255 (default 255,255,255)")
    dome.add_argument(
        "--frame-interval",
        type=ascii_float,
        default=1 / 12,
        help="cameras' frame interval for the duration estimate, s",
    )
    dome.set_defaults(func=_cmd_dome)
    sensor = csub.add_parser("sensor", help="the contact sensor's sequence")
    _common(sensor, "sensor calibration JSON (facestats.sensor-calibration/1)")
    sensor.add_argument(
        "--readout", type=ascii_float, default=0.8, help="frame readout time for the estimate (default 0.8 s)"
    )
    sensor.add_argument("--yes", action="store_true", help="do not wait for Enter before each site")
    sensor.set_defaults(func=_cmd_sensor)
    p.set_defaults(func=lambda args: p.print_help() or 2)
