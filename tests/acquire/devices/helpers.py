"""Emulated labs and capture runs shared by the device tests."""

import hashlib
import json
import pathlib

from facestats.acquire.devices.capture import capture, dome_plan, sensor_plan
from facestats.acquire.devices.plans import subject_record


def tree(folder, skip=("log.txt",)):
    """{relative path: SHA-256} of every file under ``folder`` except ``skip`` names."""
    folder = pathlib.Path(folder)
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name not in skip
    }


def record(lab):
    return subject_record(**json.loads((pathlib.Path(lab) / "subject.json").read_text()))


def run_capture(server, lab, hot, out, kind="dome", **kw):
    """Capture from an emulator with the lab's calibration and subject record (quick link settings)."""
    lab = pathlib.Path(lab)
    make = dome_plan if kind == "dome" else sensor_plan
    name = "dome.json" if kind == "dome" else "sensor-calibration.json"
    plan, calibration = make(lab / name, record(lab))
    kw.setdefault("durable", False)
    kw.setdefault("progress", False)
    link = dict(timeout=0.3, backoff=0.005, **kw.pop("link_options", {}))
    return capture(plan, calibration, server.port, out, hot, link_options=link, **kw)
