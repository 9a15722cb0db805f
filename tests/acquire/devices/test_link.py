"""The serial link and the drivers over a real pseudo-terminal: faults are detected, retried and counted."""

import contextlib
import os
import pty
import re
import select
import socket
import stat
import threading
import time

import pytest

from facestats.acquire.devices.dome import DomeController
from facestats.acquire.devices.emulator import DomeDevice, Faults, PtyServer, SensorDevice
from facestats.acquire.devices.protocol import parse_request
from facestats.acquire.devices.serial_link import SerialLink
from facestats.errors import DeviceError, DeviceReplyError, DeviceTimeout

EXPOSURES = [1 / 60, 1 / 8]


@contextlib.contextmanager
def _device_on_pty(serve):
    """A pseudo-terminal whose master ``serve(master, stop)`` handles in a thread; yields the slave's path.

    On leaving, ``stop`` is set, the thread joined, and only then both ends closed: a thread of a finished test
    that read or wrote a descriptor number after its close could reach whatever reused it (a later test's
    pseudo-terminal took the request meant for its own device: "0 bytes received", once in CI).  The master is
    non-blocking; ``serve`` waits with :func:`_ready` before each read and writes with :func:`_write_all`.
    """
    master, slave = pty.openpty()
    os.set_blocking(master, False)
    stop = threading.Event()
    thread = threading.Thread(target=serve, args=(master, stop), daemon=True)
    thread.start()
    try:
        yield os.ttyname(slave)
    finally:
        stop.set()
        thread.join(10)
        os.close(slave)
        os.close(master)
    assert not thread.is_alive(), "the device thread did not stop"


def _ready(fd, stop, write=False) -> bool:
    """Wait until ``fd`` can be read (``write``: written) or ``stop`` is set; True if it can."""
    while not stop.is_set():
        r, w, _ = select.select([] if write else [fd], [fd] if write else [], [], 0.05)
        if r or w:
            return True
    return False


def _write_all(fd, data, stop) -> bool:
    """Write all of ``data`` to the non-blocking ``fd`` in order (as a blocking write would); False if stopped."""
    while data:
        if not _ready(fd, stop, write=True):
            return False
        try:
            data = data[os.write(fd, data) :]
        except BlockingIOError:
            continue
    return True


def _server(faults=Faults(), link=None, **device):
    return PtyServer(DomeDevice(150, 16, EXPOSURES, **device), faults, link=link, reconnect_delay=0.1).start()


def _sweep(c, n, retakes=0):
    """n steps of light + trigger, each checked against the state the device reports.

    A step whose trigger reports another state (a reboot lost it between the light and the
    trigger) is taken again, at most ``retakes`` times in all, as a session does.
    """
    for i in range(n):
        while True:
            c.ensure(i % 150, i % 2)
            trig = c.trigger(i)
            if (trig.led, trig.exposure) == (i % 150, i % 2):
                break
            assert retakes > 0, (i, trig)
            retakes -= 1
            c.forget()


@pytest.mark.parametrize(
    "kind, faults",
    [
        ("garbled", Faults(garble=0.15, seed=1)),
        ("truncated", Faults(truncate=0.15, seed=2)),
        ("duplicates", Faults(duplicate=0.15, seed=3)),
        ("timeouts", Faults(drop=0.15, seed=4)),
    ],
)
@pytest.mark.slow
def test_each_kind_of_damaged_reply_is_detected_counted_and_retried(kind, faults):
    server = _server(faults)
    try:
        with DomeController(server.port, timeout=0.15, backoff=0.005) as c:
            _sweep(c, 40)
            c.link.request("st")  # the duplicate of the last reply, if any, is seen on the next request
            stats = c.link.stats
        injected = {"garbled": "garble", "truncated": "truncate", "duplicates": "duplicate", "timeouts": "drop"}[kind]
        assert server.injected[injected] >= 5
        if kind == "timeouts":  # a reply late under heavy load also counts as a timeout
            assert stats.timeouts >= server.injected[injected]
        else:
            assert getattr(stats, kind) == server.injected[injected]  # every damaged reply detected, none invented
        if kind != "duplicates":
            assert stats.retries >= server.injected[injected]  # a retry per damaged reply, answered from the cache
    finally:
        server.stop()


@pytest.mark.slow
def test_late_replies_after_a_stall_are_discarded_as_out_of_order():
    server = _server(Faults(stall=0.1, stall_s=0.3, seed=5))
    try:
        with DomeController(server.port, timeout=0.1, backoff=0.005) as c:
            _sweep(c, 20)
            for _ in range(5):
                c.link.request("st")
            assert server.injected["stall"] >= 2
            assert c.link.stats.timeouts >= server.injected["stall"]
            assert c.link.stats.out_of_order + c.link.stats.duplicates >= server.injected["stall"]
    finally:
        server.stop()


def test_a_reboot_and_a_disconnect_mid_sequence_are_survived(tmp_path):
    link = tmp_path / "dome.tty"
    server = _server(Faults(reboot_after=(25,), disconnect_after=(50,)), link=link)
    logged = []
    server.log = logged.append
    try:
        with DomeController(str(link), timeout=0.3, backoff=0.01) as c:
            _sweep(
                c, 60, retakes=1
            )  # every trigger under the planned LED and exposure; one retake if the reboot hit it
            assert (c.epoch, c.link.stats.reboots, c.link.stats.reconnects) == (1, 1, 1)
            assert server.injected["reboot"] == 1 and server.injected["disconnect"] == 1
            # the lost command quoted as text, as the protocol's errors quote bytes (it showed b'...')
            assert any(re.fullmatch(r"fault: reboot at command 25 \('[a-z]+[ .0-9#*A-F]*' lost\)", ln) for ln in logged)
    finally:
        server.stop()


def test_the_driver_switches_the_lights_off_on_leaving_even_after_an_error():
    server = _server()
    try:
        with pytest.raises(RuntimeError, match="operator"):
            with DomeController(server.port) as c:
                c.light(42)
                assert server.device.led == 42
                raise RuntimeError("operator pressed the wrong key")
        assert server.device.led == -1
    finally:
        server.stop()


def test_a_device_that_never_answers_times_out_with_advice():
    master, slave = pty.openpty()  # nobody serves the master
    try:
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match=r"did not answer 'ver' after 3 attempt\(s\) .*check its power"):
            SerialLink(os.ttyname(slave), timeout=0.1, retries=2, backoff=0.01).request("ver")
        assert time.monotonic() - t0 < 2.0  # bounded: 3 × 0.1 s plus 0.03 s of backoff
    finally:
        os.close(master)
        os.close(slave)


def _line_device(answer):
    """A device for :func:`_device_on_pty` that writes ``answer(line)`` (bytes) for every line it reads."""

    def serve(master, stop):
        buf = b""
        while _ready(master, stop):
            try:
                buf += os.read(master, 1024)
            except BlockingIOError:
                continue
            except OSError:
                return
            while b"\n" in buf:
                line, _, buf = buf.partition(b"\n")
                if not _write_all(master, answer(line), stop):
                    return

    return serve


def test_a_device_of_another_protocol_is_named_as_such():
    with _device_on_pty(_line_device(lambda line: b"OK\r\n")) as port:  # another protocol
        with pytest.raises(DeviceTimeout, match="not facestats protocol frames .*: it speaks another protocol"):
            DomeController(port, timeout=0.1, retries=1)
    with pytest.raises(DeviceTimeout, match="another protocol"):  # pyserial URL: the request comes back unanswered
        DomeController("loop://", timeout=0.1, retries=1)


def test_another_kind_of_device_and_a_miswired_dome_are_refused():
    sensor = PtyServer(SensorDevice(28, [1e-3, 2e-3], (233, 17))).start()
    try:
        with pytest.raises(DeviceError, match="identifies itself as 'facestats-sensor.*not as a facestats dome"):
            DomeController(sensor.port)
    finally:
        sensor.stop()
    server = _server(wired_leds=149)
    try:
        with DomeController(server.port) as c:
            with pytest.raises(DeviceError, match="reports 149 LEDs, the calibration has 150: fix the wiring"):
                c.check(150, 16, EXPOSURES)
            with pytest.raises(
                DeviceError, match=r"exposes for \[0.016667, 0.125\] s, the calibration for \[0.033333, 0.125\]"
            ):
                c.check(149, 16, [1 / 30, 1 / 8])
            with pytest.raises(DeviceReplyError, match=r"error 4 \(argument out of range\)") as exc:
                c.light(149)
            assert exc.value.code == 4
            assert c.check(149, 16, EXPOSURES).n_leds == 149
    finally:
        server.stop()


def test_ports_that_cannot_be_opened_say_why(tmp_path):
    with pytest.raises(DeviceError, match="no such device.*list_ports"):
        SerialLink(str(tmp_path / "ttyUSB9"))
    plain = tmp_path / "notes.txt"
    plain.write_text("hello")
    with pytest.raises(DeviceError, match="not a serial port"):
        SerialLink(str(plain))
    with pytest.raises(DeviceError, match="loop://, socket://, rfc2217://"):
        SerialLink("rfc2217://127.0.0.1:9")  # nothing listens on the discard port
    master, slave = pty.openpty()
    name = os.ttyname(slave)
    try:
        if os.geteuid() != 0:
            os.chmod(name, stat.S_IRUSR)
            with pytest.raises(DeviceError, match="permission denied.*dialout"):
                SerialLink(name)
        else:  # root opens anything: raise what pyserial raises for EACCES (serialposix.Serial.open)
            import serial

            def refuse(url, **kw):
                raise serial.SerialException(13, f"could not open port {url}: [Errno 13] Permission denied: {url!r}")

            with pytest.MonkeyPatch.context() as mp:
                mp.setattr(serial, "serial_for_url", refuse)
                with pytest.raises(DeviceError, match="permission denied.*dialout"):
                    SerialLink(name)
    finally:
        os.close(master)
        os.close(slave)


def test_socket_urls_reach_a_device_over_tcp():
    dev = DomeDevice(150, 16, EXPOSURES)
    srv = socket.create_server(("127.0.0.1", 0))

    def serve():
        conn, _ = srv.accept()
        buf = b""
        while data := conn.recv(1024):
            buf += data
            while b"\n" in buf:
                line, _, buf = buf.partition(b"\n")
                conn.sendall(dev.handle(line) or b"")
        conn.close()

    threading.Thread(target=serve, daemon=True).start()
    try:
        with DomeController(f"socket://127.0.0.1:{srv.getsockname()[1]}") as c:
            c.ensure(7, 1)
            assert c.trigger(3).led == 7 and c.dome_status().exposure == 1
        assert dev.led == -1  # switched off on leaving
    finally:
        srv.close()
    assert parse_request(b"x").name == "x"


def test_a_port_that_opens_and_drops_at_once_ends_the_request():
    """A device that accepts each connection and drops it at once: every drop reopened the port and retried without
    counting an attempt, for ever (33 reconnects in 10 s; a red team)."""
    srv = socket.create_server(("127.0.0.1", 0))

    def drop_every_connection():
        while True:
            try:
                conn, _ = srv.accept()
            except OSError:
                return
            conn.close()

    threading.Thread(target=drop_every_connection, daemon=True).start()
    try:
        t0 = time.monotonic()
        link = SerialLink(f"socket://127.0.0.1:{srv.getsockname()[1]}", timeout=0.2, retries=1, reconnect_timeout=0.5)
        with pytest.raises(DeviceError, match=r"dropped the connection 3 times while 'ver' was sent"):
            link.request("ver")
        assert time.monotonic() - t0 < 5.0
    finally:
        srv.close()


def test_a_flood_of_stray_frames_is_counted_not_logged_line_by_line():
    """Valid frames answering other requests: one log line each wrote 105,355 lines in 2 s, and the error called
    them "not facestats protocol frames" (a red team)."""
    from facestats.acquire.devices.protocol import Reply
    from facestats.acquire.devices.serial_link import MAX_NOTES

    def flood(master, stop):
        k = 0
        while _write_all(master, b"".join(Reply(1000 + k + i, 999_999, "OK", "x").encode() for i in range(200)), stop):
            k += 200

    lines = []
    with _device_on_pty(flood) as port:
        link = SerialLink(port, timeout=0.3, retries=1, backoff=0.01, log=lines.append)
        try:
            with pytest.raises(DeviceTimeout, match=r"answered 'ver' only with \d+ frames for other requests"):
                link.request("ver")
        finally:
            link.close()
    summary = [ln for ln in lines if "more frames discarded while waiting for 'ver'" in ln]
    # The first MAX_NOTES one line each, then the count; a few more lines: a truncated frame at each attempt's end.
    assert len(summary) == 1 and MAX_NOTES < len(lines) < MAX_NOTES + 8


def test_a_request_id_beyond_the_hosts_range_is_an_e07_and_the_emulator_lives_on():
    """`x #3000000000` raised a plain DeviceError in the emulator's request parser, which killed its server thread."""
    dev = DomeDevice(150, 16, EXPOSURES)
    assert b" E07 request id must lie in [0, 2^31), got 3000000000" in dev.handle(b"x #3000000000")
    assert b" OK " in dev.handle(b"ver")


def test_a_garbled_line_before_each_valid_reply_does_not_hide_the_reply():
    """The attempt ended at the garbled line and the retry threw the reply that came with it away as late, so a
    device that sends one noise line before every intact reply was never understood (a red team)."""
    from facestats.acquire.devices.protocol import TERMINATOR, Reply

    seq = iter(range(1, 1000))

    def noisy(line):  # a noise line and the reply, in one write
        return b"noise" + TERMINATOR + Reply(next(seq), parse_request(line).id, "OK", "facestats-dome test").encode()

    lines = []
    with _device_on_pty(_line_device(noisy)) as port:
        link = SerialLink(port, timeout=0.5, retries=3, log=lines.append)
        try:
            assert link.request("ver").payload == "facestats-dome test"
        finally:
            link.close()
    assert link.stats.garbled >= 1
    # The log quotes the line as text, as the errors do, not as a Python bytes repr (b'noise').
    assert any(re.fullmatch(r"garbled reply frame while waiting for request \d+: 'noise'", ln) for ln in lines)
