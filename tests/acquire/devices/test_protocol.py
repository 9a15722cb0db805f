"""The device protocol (framing, CRC, detection of damaged frames) and the emulated firmware, without a port."""

import numpy as np
import pytest

from facestats.acquire.devices.cameras import Trigger
from facestats.acquire.devices.emulator import DomeDevice, Faults, SensorDevice
from facestats.acquire.devices.protocol import (
    TERMINATOR,
    FrameError,
    FrameReader,
    ProtocolViolation,
    Reply,
    Request,
    crc16,
    parse_reply,
    parse_request,
)
from facestats.errors import DeviceError, FacestatsError, ValidationError


def _crc16_bitwise(data: bytes) -> int:
    """CRC-16/CCITT-FALSE bit by bit (Williams 1993): an independent check of :func:`crc16`."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def test_crc16_has_the_catalogued_check_value_and_agrees_with_a_bitwise_implementation():
    assert crc16(b"123456789") == 0x29B1  # CRC catalogue, CRC-16/CCITT-FALSE (IBM-3740)
    rng = np.random.default_rng(0)
    for n in (0, 1, 7, 64, 301):
        data = bytes(rng.integers(0, 256, n, dtype=np.uint8))
        assert crc16(data) == _crc16_bitwise(data)


def test_requests_round_trip_and_bad_requests_get_their_error_numbers():
    req = Request("sc", (255, 200, 0), 1048577)
    line = req.encode()
    assert line.startswith(b"sc.255.200.0 #1048577*") and line.endswith(b"\n")
    assert parse_request(line[:-1]) == req
    assert parse_request(b"l.37\r") == Request("l", (37,), 0)  # typed at a terminal
    bad = bytearray(line[:-1])
    bad[3] ^= 0x01  # one flipped bit in the body
    with pytest.raises(ProtocolViolation) as exc:
        parse_request(bytes(bad))
    assert exc.value.code == 2  # bad checksum
    assert "of 'sc.355.200.0 #1048577*" in str(exc.value)  # quoted as text, not as a Python bytes repr (b'...')
    with pytest.raises(ProtocolViolation, match=r"malformed request '\\xff\\x00zz'"):  # others escaped: ASCII
        parse_request(b"\xff\x00zz")
    for text, code in ((b"L.37", 7), (b"l.3x", 7), (b"l." + b"1" * 300, 7)):
        with pytest.raises(ProtocolViolation) as exc:
            parse_request(text)
        assert exc.value.code == code
    with pytest.raises(DeviceError, match="command arguments must be integers"):
        Request("l", ("37",))
    assert isinstance(ProtocolViolation("x", 1), FacestatsError)


def test_every_single_bit_error_and_every_truncation_of_a_frame_is_detected():
    payload = "frame=9 led=37 exposure=1 brightness=255 colour=255,255,255"
    frame = Reply(4711, 123456, "OK", payload).encode()
    body = len(frame) - len(TERMINATOR)
    assert FrameReader().feed(frame) == [Reply(4711, 123456, "OK", payload)]
    for i in range(body):  # CRC-16 detects every single-bit error; a damaged '@' or '*' breaks the syntax
        for bit in range(8):
            items = FrameReader().feed(frame[:i] + bytes([frame[i] ^ (1 << bit)]) + frame[i + 1 :])
            assert items and all(isinstance(x, FrameError) for x in items), (i, bit)
    for cut in range(1, len(frame)):  # a frame cut short yields nothing but pending bytes reported as truncated
        reader = FrameReader()
        assert reader.feed(frame[:cut]) == []
        assert reader.flush().kind == "truncated"


def test_a_truncated_frame_followed_by_a_whole_one_gives_both_items():
    a, b = Reply(1, 7, "OK", "x=1").encode(), Reply(2, 8, "E04", "LED 151 out of range 0..149").encode()
    items = FrameReader().feed(a[:6] + b)
    assert isinstance(items[0], FrameError) and items[0].kind == "truncated"
    assert items[1] == Reply(2, 8, "E04", "LED 151 out of range 0..149") and items[1].error_code == 4
    assert Reply(3, 9, "OK", "leds=150 colour=1,2,3 ready").fields() == {"leds": "150", "colour": "1,2,3", "ready": ""}


def test_junk_before_a_frame_does_not_hide_a_short_frame_after_it():
    """The offset of the junk's '@' was reused as the search offset for the next terminator: a short frame after a
    long junk prefix was missed, kept pending and at last reported truncated (a reviewer)."""
    a, b = Reply(1, 7, "OK", "x=1").encode(), Reply(2, 8, "OK", "y=2").encode()
    junk = b"noise " * 20 + b"@17 4"  # 125 bytes of a frame cut short: longer than frame b
    assert len(junk) > len(b)
    items = FrameReader().feed(junk + a + b)
    assert [type(i) for i in items] == [FrameError, Reply, Reply] and items[0].kind == "truncated"
    assert items[1:] == [Reply(1, 7, "OK", "x=1"), Reply(2, 8, "OK", "y=2")]
    for cut in (len(junk) + len(a), len(junk) + len(a) + 3, len(junk) + len(a) + len(b) - 1):
        reader, data = FrameReader(), junk + a + b
        items = reader.feed(data[:cut]) + reader.feed(data[cut:])
        assert items[1:] == [Reply(1, 7, "OK", "x=1"), Reply(2, 8, "OK", "y=2")], cut
        assert reader.pending == b"" and reader.flush() is None


def _ask(device, name, *args, rid=0):
    items = FrameReader().feed(device.handle(Request(name, args, rid).encode()[:-1]))
    assert len(items) == 1
    return items[0]


def test_the_dome_firmware_answers_each_request_id_once_and_reports_its_state():
    triggers = []
    dev = DomeDevice(150, 16, [1 / 60, 1 / 8], on_trigger=triggers.append)
    assert _ask(dev, "ver").payload.startswith("facestats-dome")
    assert _ask(dev, "l", 37, rid=5).ok and _ask(dev, "se", 1, rid=6).ok
    line = Request("tr", (99,), 7).encode()[:-1]
    first = dev.handle(line)
    assert dev.handle(line) == first  # a retried trigger is answered from the stored frame…
    assert triggers == [Trigger(99, 37, 1, 255, (255, 255, 255), lines=65535)]  # …and takes no second picture
    assert Trigger.from_fields(parse_reply(first[: -len(TERMINATOR)]).fields()) == triggers[0]
    assert _ask(dev, "l", 150).error_code == 4 and _ask(dev, "zz").error_code == 1 and _ask(dev, "l").error_code == 3
    st = _ask(dev, "st").fields()
    assert (st["leds"], st["led"], st["exposure"], st["exposure_us"]) == ("150", "37", "1", "16667,125000")
    assert _ask(dev, "tm", 5).ok and _ask(dev, "tm", 65536).error_code == 4
    masked = Trigger.from_fields(_ask(dev, "tr", 100, rid=8).fields())
    assert masked.lines == 5 and [masked.fires(c) for c in range(4)] == [True, False, True, False]
    boot = parse_reply(dev.boot()[: -len(TERMINATOR)])
    assert (boot.seq, boot.status) == (1, "BOOT") and _ask(dev, "st").fields()["led"] == "-1"  # state lost
    assert _ask(dev, "st").seq == 3  # sequence numbers restarted


def test_the_sensor_firmware_and_a_miswired_dome():
    dev = SensorDevice(28, 1e-3 * 2.0 ** (2 / 3 * np.arange(23)), (233, 17))
    for cmd, arg in (("pos", 2), ("se", 22), ("lamp", 1), ("sh", 1)):
        assert _ask(dev, cmd, arg).ok
    trig = Trigger.from_fields(_ask(dev, "tr", 5).fields())
    assert (trig.site, trig.exposure, trig.lamp, trig.shutter) == (2, 22, 1, 1)
    assert _ask(dev, "x").ok and _ask(dev, "st").fields()["lamp"] == "0"
    assert _ask(dev, "pos", 3).error_code == 4
    miswired = DomeDevice(150, 16, [1 / 60, 1 / 8], wired_leds=149)
    assert _ask(miswired, "st").fields()["leds"] == "149" and _ask(miswired, "l", 149).error_code == 4


def test_fault_settings_are_checked():
    with pytest.raises(ValidationError, match="garble must lie in"):
        Faults(garble=1.5)
    with pytest.raises(ValidationError, match="must not exceed 1"):
        Faults(drop=0.6, garble=0.6)
    with pytest.raises(ValidationError, match="reboot_after"):
        Faults(reboot_after=(0,))
    assert not Faults().any and Faults(disconnect_after=(3,)).any


def test_a_trigger_reply_without_its_frame_or_with_garbage_is_a_device_error():
    assert Trigger.from_fields({"frame": "3", "led": "1"}) == Trigger(3, led=1)
    with pytest.raises(DeviceError, match=r"trigger reply without the field\(s\) \['frame'\]"):
        Trigger.from_fields({"led": "1", "exposure": "0"})
    with pytest.raises(DeviceError, match="trigger reply with a malformed field frame='x'"):
        Trigger.from_fields({"frame": "x"})


def test_trigger_replies_are_held_to_what_the_device_must_report():
    """A red team's firmware: missing fields were filled with defaults that passed the plan's state check, `0_2` was
    read as 2, a repeated key kept its last value, and a reply naming the previous frame was filed under it."""
    from facestats.acquire.devices.dome import DOME_TRIGGER_FIELDS
    from facestats.acquire.devices.protocol import Reply

    full = {"frame": "5", "led": "2", "exposure": "1", "brightness": "10", "colour": "255,255,255"}
    assert Trigger.from_fields(full, DOME_TRIGGER_FIELDS, 5) == Trigger(5, led=2, exposure=1, brightness=10)
    with pytest.raises(DeviceError, match=r"without the field\(s\) \['exposure', 'brightness', 'colour'\]"):
        Trigger.from_fields({"frame": "5", "led": "2"}, DOME_TRIGGER_FIELDS, 5)  # exposure 0, brightness 255 before
    for bad in ({"led": "0_2"}, {"led": " 2"}, {"colour": "1,2"}):
        with pytest.raises(DeviceError, match="malformed field"):
            Trigger.from_fields({**full, **bad}, DOME_TRIGGER_FIELDS, 5)
    with pytest.raises(DeviceError, match="trigger reply for frame 4, the host asked for frame 5"):
        Trigger.from_fields({**full, "frame": "4"}, DOME_TRIGGER_FIELDS, 5)
    with pytest.raises(DeviceError, match="names the field 'led' twice"):
        Reply(1, 5, "OK", "frame=5 led=0 led=2").fields()


def test_the_frame_reader_keeps_a_bounded_tail_and_finds_a_frame_after_megabytes_of_noise():
    """Unterminated bytes were kept whole and searched again on every read (4 MB in 4 KiB reads: 1.8 s; a red
    team); a reply frame also ended in a stray LF (``$`` matched before it)."""
    import time

    from facestats.acquire.devices.protocol import MAX_PENDING

    reader, noise = FrameReader(), bytes(range(256)).replace(b"\n", b"x") * 16  # 4 KiB without a frame end
    t0 = time.monotonic()
    items = [item for _ in range(1024) for item in reader.feed(noise)]
    assert time.monotonic() - t0 < 1.0 and len(reader.pending) == MAX_PENDING
    assert items and all(isinstance(i, FrameError) and i.kind == "truncated" for i in items)  # skipped, not garbled
    frame = Reply(3, 7, "OK", "a=1").encode()
    assert reader.feed(frame)[-1] == Reply(3, 7, "OK", "a=1")  # the reply after the noise is still read
    with pytest.raises(FrameError):
        parse_reply(frame[: -len(TERMINATOR)] + b"\n")  # '@3 7 OK a=1*CRC' followed by a LF is no frame
