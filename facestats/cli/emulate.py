"""``facestats emulate dome|sensor``: an emulated controller on a pseudo-terminal
(:mod:`facestats.acquire.devices.lab`)."""

from __future__ import annotations

import signal
import sys
import threading

from facestats.cli.options import ascii_float, ascii_int, named_options
from facestats.core.conventions import DEFAULT_EMULATED_SUBJECT
from facestats.core.processes import sigterm_as_interrupt

__all__ = ["add_emulate"]

#: The options of :func:`facestats.acquire.devices.lab.emulated_dome`'s and ``emulated_sensor``'s parameters
#: (``subject_id``: also :func:`facestats.acquire.synthetic.population.check_population_id`'s, of ``--subject``).
_NAMES = dict(
    subject_id="--subject",
    hot_folder="--hot-folder",
    lab="--lab",
    store="--store",
    map_size="--map-size",
    link="--link",
    seed="--seed",
    resolution="--resolution",
    leds="--leds",
    cameras="--cameras",
    wired_leds="--wired-leds",
    workers="--workers",
    cache="--cache",
)


def _faults(args):
    """The fault injection of the options, each checked with a message naming it (before any work)."""
    from facestats.acquire.devices.emulator import Faults
    from facestats.core.validate import as_finite, check_integer
    from facestats.errors import ValidationError

    for name in ("drop", "garble", "truncate", "duplicate", "stall"):
        as_finite(getattr(args, name), f"--{name}", 0, 100, unit="%")
    replies = args.drop + args.garble + args.truncate + args.duplicate  # each reply gets one fault at most
    if replies > 100:
        raise ValidationError(
            f"--drop + --garble + --truncate + --duplicate must not exceed 100 % (per cent of the replies), got "
            f"{args.drop:g} + {args.garble:g} + {args.truncate:g} + {args.duplicate:g} = {replies:g} %"
        )
    as_finite(args.stall_seconds, "--stall-seconds", 0, None, unit="s")
    for name in ("disconnect_after", "reboot_after"):
        for k in getattr(args, name):
            check_integer(k, "--" + name.replace("_", "-"), 1)
    check_integer(args.fault_seed, "--fault-seed", 0)
    return Faults(
        drop=args.drop / 100,
        garble=args.garble / 100,
        truncate=args.truncate / 100,
        duplicate=args.duplicate / 100,
        stall=args.stall / 100,
        stall_s=args.stall_seconds,
        disconnect_after=tuple(args.disconnect_after),
        reboot_after=tuple(args.reboot_after),
        seed=args.fault_seed,
    )


def _check_duration(duration) -> None:
    """``--duration``: None (serve until Ctrl-C) or a finite number of seconds > 0, checked before any work."""
    import math

    from facestats.errors import ValidationError

    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise ValidationError(
            f"--duration must be a finite number of seconds > 0 (leave it out to serve until Ctrl-C), got {duration!r}"
        )


def _serve(server, args, what):
    """Print where the device is, serve until Ctrl-C, SIGTERM or --duration, print what happened."""
    print(what)
    print(f"port: {server.slave_name}")
    if args.link:
        print(f"link: {args.link} (follows reconnections)")
    print(f"hot folder: {server.hot_folder}")
    print(f"lab files: {server.lab}")
    print("ready (Ctrl-C to stop)", flush=True)
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *a: done.set())
    done.wait(args.duration)
    server.stop()
    injected = {k: v for k, v in server.injected.items() if v}
    print(
        f"stopped after {server.commands} commands; frames written {server.writer.written}; faults {injected or 'none'}"
    )
    if args.hot_folder is None or args.lab is None:  # the files must outlive the emulator: capture and ingest read them
        kept = [str(p) for p, given in ((server.hot_folder, args.hot_folder), (server.lab, args.lab)) if given is None]
        print(f"kept in a temporary folder (remove it when done): {', '.join(kept)}")
    return 0


def _log(args):
    return None if args.quiet else (lambda line: print(f"[emulator] {line}", file=sys.stderr, flush=True))


def _cmd_dome(args) -> int:
    from facestats.acquire.devices.lab import emulated_dome

    _check_duration(args.duration)
    # building takes minutes: a kill then removes the half-built folders as Ctrl-C does
    with sigterm_as_interrupt(), named_options(**_NAMES):
        server = emulated_dome(
            args.subject,
            args.hot_folder,
            args.lab,
            store=args.store,
            map_size=args.map_size,
            resolution=args.resolution,
            leds=args.leds,
            cameras=args.cameras,
            faults=_faults(args),
            link=args.link,
            wired_leds=args.wired_leds,
            realtime=args.realtime,
            seed=args.seed,
            workers=args.workers,
            cache=args.cache,
            progress=not args.quiet,
            log=_log(args),
        )
    dome = server.scene.dome
    w, h = dome.image_size[0]
    what = f"dome emulator for {args.subject}: {dome.n_leds} LEDs, {dome.n_cameras} cameras, {w}×{h} px frames"
    return _serve(server, args, what)


def _cmd_sensor(args) -> int:
    from facestats.acquire.devices.lab import emulated_sensor

    _check_duration(args.duration)
    with sigterm_as_interrupt(), named_options(**_NAMES):
        server = emulated_sensor(
            args.subject,
            args.hot_folder,
            args.lab,
            store=args.store,
            map_size=args.map_size,
            faults=_faults(args),
            link=args.link,
            realtime=args.realtime,
            seed=args.seed,
            log=_log(args),
        )
    s = server.scene.sensor
    what = f"contact-sensor emulator for {args.subject}: {s.n_fibers} fibres, {s.n_exposures}-image bracket"
    return _serve(server, args, what)


def _common(p):
    p.add_argument(
        "--subject", default=DEFAULT_EMULATED_SUBJECT, help=f"subject to emulate (default {DEFAULT_EMULATED_SUBJECT})"
    )
    p.add_argument(
        "--store", help="take the subject from this store ('default': the embedded one); default: the synthetic truth"
    )
    p.add_argument("--map-size", type=ascii_int, default=16, help="map side of a synthetic subject (default 16)")
    p.add_argument("--hot-folder", help="where the emulated cameras drop frames (default: a new temporary directory)")
    p.add_argument("--lab", help="where the calibration, mesh and subject record are written (default: temporary)")
    p.add_argument("--link", help="a symlink kept pointing at the pty (stable across injected disconnects)")
    p.add_argument("--realtime", action="store_true", help="answer triggers only after the exposure time")
    p.add_argument("--seed", type=ascii_int, default=0, help="seed of the frames' noise, >= 0 (default 0)")
    p.add_argument(
        "--duration", type=ascii_float, default=None, help="stop after this many seconds, > 0 (default: Ctrl-C)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar, no fault log")
    f = p.add_argument_group("fault injection (fractions in per cent of replies or commands)")
    f.add_argument("--drop", type=ascii_float, default=0.0, metavar="PCT", help="replies not sent")
    f.add_argument("--garble", type=ascii_float, default=0.0, metavar="PCT", help="replies with one byte changed")
    f.add_argument("--truncate", type=ascii_float, default=0.0, metavar="PCT", help="replies cut short")
    f.add_argument("--duplicate", type=ascii_float, default=0.0, metavar="PCT", help="replies sent twice")
    f.add_argument(
        "--stall", type=ascii_float, default=0.0, metavar="PCT", help="commands before which the device freezes"
    )
    f.add_argument("--stall-seconds", type=ascii_float, default=1.5, help="length of a stall (default 1.5 s)")
    f.add_argument(
        "--disconnect-after", type=ascii_int, nargs="*", default=[], metavar="K", help="drop the line after command K"
    )
    f.add_argument("--reboot-after", type=ascii_int, nargs="*", default=[], metavar="K", help="reboot at command K")
    f.add_argument("--fault-seed", type=ascii_int, default=0, help="seed of the fault draws (default 0)")


def add_emulate(sub):
    """Register ``facestats emulate`` and its ``dome`` and ``sensor`` devices.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        What ``add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    None
        The handlers (``func``) return 0 when the emulator stops; ``emulate`` alone prints its help and returns 2; a
        :class:`~facestats.errors.FacestatsError` raised becomes exit status 2 in :func:`facestats.cli.main`.
    """
    p = sub.add_parser(
        "emulate",
        help="emulate the dome or the contact sensor on a pseudo-terminal (for capture without hardware)",
        description=(
            "Open a pseudo-terminal and speak the facestats device protocol on it as the dome's LED/trigger controller "
            "or the contact sensor would, with emulated cameras that render the subject (synthetic population or a "
            "store subject) for the state the controller is in and drop the frames into a hot folder. Prints the "
            "port to pass to `facestats capture --port`; writes the lab's calibration, mesh and subject record. "
            "Faults can be injected into the replies."
        ),
    )
    esub = p.add_subparsers(title="device", metavar="DEVICE")
    dome = esub.add_parser(
        "dome",
        help="the dome: LEDs, camera triggers, two exposure settings",
        description="Emulate the dome's LED and trigger controller on a pseudo-terminal, its cameras writing each "
        "trigger's frames into the hot folder, and the lab's calibration, face mesh and subject record; serve until "
        "Ctrl-C, SIGTERM or --duration. `facestats capture dome` takes frames from it.",
    )
    _common(dome)
    dome.add_argument(
        "--resolution", type=ascii_int, default=None, help="frame side in pixels (default: the rig's 1024)"
    )
    dome.add_argument(
        "--leds", type=ascii_int, default=None, help="a smaller rig: keep N LEDs evenly spread (default 150)"
    )
    dome.add_argument("--cameras", type=ascii_int, default=None, help="a smaller rig: keep N cameras (default 16)")
    dome.add_argument("--wired-leds", type=ascii_int, default=None, help="a mis-wired controller reporting N LEDs")
    dome.add_argument("--workers", type=ascii_int, default=2, help="threads rendering frames (default 2)")
    dome.add_argument("--cache", help="directory keeping the cameras' pixel maps between runs")
    dome.set_defaults(func=_cmd_dome)
    sensor = esub.add_parser(
        "sensor",
        help="the contact sensor: lamp, shutter, 23-image bracket",
        description="Emulate the contact sensor (Weyrich et al. 2006 §4.2) on a pseudo-terminal: its lamp, shutter and "
        "camera writing each exposure bracket into the hot folder, and the lab's sensor calibration and subject "
        "record; serve until Ctrl-C, SIGTERM or --duration. `facestats capture sensor` takes brackets from it.",
    )
    _common(sensor)
    sensor.set_defaults(func=_cmd_sensor)
    p.set_defaults(func=lambda args: p.print_help() or 2)
