"""Device control (issue 17): protocol round trips over a pty, and the emulated full dome and sensor sessions.

* ``round_trips``: request/reply round trips per second between
  :class:`facestats.acquire.devices.serial_link.SerialLink` and an emulated dome
  controller serving a pty from another process (target ≥ 1,000/s), beside the
  baseline of pyserial's own ``read_until`` (which reads one byte per call) on
  the same link and device.
* ``dome_session``: the whole dome sequence — 150 LEDs × 16 cameras × 2
  exposures at the default 1024² resolution, 4,800 frames — captured from
  ``facestats emulate dome`` (another process rendering and writing the frames
  into a hot folder) by :func:`facestats.acquire.devices.capture.capture` with the
  defaults (fsync of every frame and journal line); target ≤ 120 s, beside the
  paper's 25 s on the real dome (Weyrich et al. 2006 §5).  The emulator's
  start-up is timed apart (its cameras' pixel maps are cached in the benchmark
  directory); the CPU seconds of both processes during the session and their sum
  over two cores (the session's length on two otherwise idle cores, when the
  machine is shared); peak resident memory of both processes and the data volume.
* ``sensor_session``: the contact-sensor sequence (3 sites × 23 exposures).
* ``frame_encode``: writing one emulated frame (1024² × 3 12-bit codes: read noise of the dome's
  camera, a lit graded patch over a third of it) as a 16-bit PNG: facestats' Huffman-only deflate
  (:mod:`facestats.io.deflate`, compiled and numpy) beside libdeflate level 1 (the writer before it)
  and OpenCV's PNG writer at its fastest setting; milliseconds per frame and file size.
"""

from __future__ import annotations

import os
import pathlib
import resource
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
TARGET_ROUND_TRIPS = 1000.0
TARGET_SESSION_S = 120.0
PAPER_SESSION_S = 25.0

_SERVE = """
import sys, time
from facestats.acquire.devices.emulator import DomeDevice, PtyServer
server = PtyServer(DomeDevice(150, 16, [1 / 60, 1 / 8])).start()
print(server.port, flush=True)
sys.stdin.readline()
server.stop()
"""


def _python(code):
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(pathlib.Path(HERE).parent), os.environ.get("PYTHONPATH", "")])
    )
    return subprocess.Popen(
        [sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env
    )


def bench_round_trips(n=5000):
    from facestats.acquire.devices.protocol import TERMINATOR, Request, parse_reply
    from facestats.acquire.devices.serial_link import SerialLink, open_port

    proc = _python(_SERVE)
    port = proc.stdout.readline().strip()
    try:
        link = SerialLink(port)
        link.request("st")
        t0 = time.perf_counter()
        for _ in range(n):
            link.request("st")
        ours = n / (time.perf_counter() - t0)
        link.close()
        ser = open_port(port)  # the baseline: pyserial's read_until on the same device
        ser.timeout = 1.0
        m = max(n // 5, 50)
        t0 = time.perf_counter()
        for i in range(m):
            ser.write(Request("st", (), i + 1).encode())
            parse_reply(ser.read_until(TERMINATOR)[: -len(TERMINATOR)])
        baseline = m / (time.perf_counter() - t0)
        ser.close()
    finally:
        proc.stdin.write("\n")
        proc.stdin.close()
        proc.wait(timeout=30)
    return {
        "round_trips_per_s": ours,
        "target_per_s": TARGET_ROUND_TRIPS,
        "pyserial_read_until_per_s": baseline,
        "vs_baseline": ours / baseline,
    }


def _cpu_s(pid):
    """User + system CPU seconds of process ``pid`` so far (Linux /proc)."""
    try:
        fields = pathlib.Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


def _peak_kib(pid):
    try:
        for line in pathlib.Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1])
    except OSError:
        pass
    return float("nan")


def _emulate(kind, root, extra):
    """Start ``facestats emulate KIND`` in a subprocess; (process, port, start-up seconds)."""
    args = [sys.executable, "-m", "facestats", "emulate", kind, "--hot-folder", str(root / f"{kind}-hot")]
    args += ["--lab", str(root / "lab"), "--quiet", *map(str, extra)]
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(pathlib.Path(HERE).parent), os.environ.get("PYTHONPATH", "")])
    )
    t0 = time.perf_counter()
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    port = None
    for line in proc.stdout:
        if line.startswith("port: "):
            port = line.split()[1]
        if line.startswith("ready"):
            break
    if port is None:
        raise RuntimeError(f"facestats emulate {kind} did not start")
    return proc, port, time.perf_counter() - t0


def _session(kind, root, extra, durable=True):
    import json

    from facestats.acquire.devices.capture import capture, dome_plan, sensor_plan
    from facestats.acquire.devices.plans import subject_record

    proc, port, startup = _emulate(kind, root, extra)
    try:
        lab = root / "lab"
        record = subject_record(**json.loads((lab / "subject.json").read_text()))
        if kind == "dome":
            plan, calibration = dome_plan(lab / "dome.json", record)
        else:
            plan, calibration = sensor_plan(lab / "sensor-calibration.json", record)
        out = root / f"{kind}-capture"
        shutil.rmtree(out, ignore_errors=True)
        t0, e0, c0 = time.perf_counter(), _cpu_s(proc.pid), time.process_time()
        report = capture(plan, calibration, port, out, root / f"{kind}-hot", durable=durable, progress=False)
        wall = time.perf_counter() - t0
        cpu = (_cpu_s(proc.pid) - e0, time.process_time() - c0)
        emulator_kib = _peak_kib(proc.pid)
    finally:
        proc.terminate()
        proc.wait(timeout=60)
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    shutil.rmtree(out, ignore_errors=True)
    return report, wall, startup, emulator_kib, size, cpu


def bench_dome_session(resolution=1024, leds=150, cameras=16, durable=True):
    from inputs import bench_dir

    root = bench_dir() / "devices"
    root.mkdir(parents=True, exist_ok=True)
    extra = ["--resolution", resolution, "--leds", leds, "--cameras", cameras, "--cache", root / "pixel-maps"]
    report, wall, startup, emulator_kib, size, (emulator_cpu, capture_cpu) = _session("dome", root, extra, durable)
    return {
        "session_s": wall,
        "target_s": TARGET_SESSION_S,
        "paper_hardware_s": PAPER_SESSION_S,
        "frames": report.frames,
        "frames_per_s": report.frames / wall,
        "emulator_cpu_s": emulator_cpu,
        "capture_cpu_s": capture_cpu,
        "two_idle_cores_s": (emulator_cpu + capture_cpu) / 2,  # the same work on two otherwise idle cores
        "emulator_startup_s": startup,
        "capture_peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "emulator_peak_mib": emulator_kib / 1024,
        "data_gb": size / 1e9,
        "retries": report.link["retries"],
    }


def bench_sensor_session(durable=True):
    from inputs import bench_dir

    root = bench_dir() / "devices"
    root.mkdir(parents=True, exist_ok=True)
    report, wall, startup, _, size, _ = _session("sensor", root, [], durable)
    return {"session_s": wall, "frames": report.frames, "emulator_startup_s": startup, "data_mb": size / 1e6}


def bench_frame_encode(size=1024, repeats=10):
    import cv2
    import numpy as np

    from facestats.acquire.devices.scene import dark_code_table
    from facestats.acquire.dome import default_dome
    from facestats.acquire.response import ResponseCurve
    from facestats.io.png import encode_png

    dome = default_dome()
    camera = ResponseCurve(12, dome.response.full_well, dome.response.read_noise)
    rng = np.random.default_rng(2006)
    frame = dark_code_table(camera)[rng.integers(0, 65536, (size, size, 3))]
    lo, hi = size // 3, 2 * size // 3
    grade = np.linspace(200.0, 3000.0, hi - lo)[None, :, None]
    frame[lo:hi, lo:hi] = np.clip(np.rint(rng.normal(grade, 40.0, (hi - lo, hi - lo, 3))), 0, 4095)
    writers = {
        "huffman": lambda: encode_png(frame, compression="huffman"),
        "huffman_numpy": lambda: encode_png(frame, compression="huffman", backend="numpy"),
        "libdeflate1": lambda: encode_png(frame, compression="libdeflate", level=1),
        "opencv": lambda: cv2.imencode(".png", frame[..., ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 1])[1].tobytes(),
    }
    out = {}
    for name, write in writers.items():
        size_bytes = len(write())  # warm-up (compiles the kernels once)
        t0 = time.perf_counter()
        for _ in range(repeats):
            write()
        out[f"{name}_ms"] = 1e3 * (time.perf_counter() - t0) / repeats
        out[f"{name}_mb"] = size_bytes / 1e6
    out["vs_libdeflate1"] = out["libdeflate1_ms"] / out["huffman_ms"]
    out["vs_opencv"] = out["opencv_ms"] / out["huffman_ms"]
    return out


BENCHMARKS = [
    ("round_trips", bench_round_trips),
    ("dome_session", bench_dome_session),
    ("sensor_session", bench_sensor_session),
    ("frame_encode", bench_frame_encode),  # last: its frames would count in the capture's peak memory
]

#: Tiny sizes for the test suite (tests/test_benchmarks.py).
SMOKE = {
    "round_trips": {"n": 200},
    "frame_encode": {"size": 64, "repeats": 1},
    "dome_session": {"resolution": 32, "leds": 6, "cameras": 2, "durable": False},
    "sensor_session": {"durable": False},
}
