"""The hot-folder camera backend on its own: waiting, timeouts, checksums, sizes, cleanup."""

import hashlib
import re
import threading
import time

import numpy as np
import pytest

from facestats.acquire.devices.cameras import HotFolderCameras, Trigger
from facestats.errors import DeviceError, DeviceTimeout
from facestats.io.png import encode_png


def _png(width, height):
    return encode_png(np.arange(width * height * 3, dtype=np.uint16).reshape(height, width, 3) % 4096)


def _drop(cams, camera, frame, data, sidecar=None):
    p = cams.path(camera, frame)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(data)
    if sidecar is not None:
        p.with_name(p.name + ".sha256").write_text(sidecar)
    return p


def test_a_camera_that_delivers_nothing_times_out_with_advice(tmp_path):
    cams = HotFolderCameras(tmp_path, [0, 1])
    _drop(cams, 0, 7, _png(8, 6))
    t0 = time.monotonic()
    with pytest.raises(
        DeviceTimeout, match=r"camera 1 delivered no frame 000000000007\.png .* within 0\.3 s.*--frame-timeout"
    ):
        cams.collect(Trigger(7), timeout=0.3)
    assert 0.3 <= time.monotonic() - t0 < 2.0  # waits the timeout, not forever


def test_a_frame_written_late_is_waited_for_and_read_whole(tmp_path):
    cams = HotFolderCameras(tmp_path, [0], settle=0.05)
    data = _png(16, 12)

    def vendor():  # writes the file in two parts, late
        time.sleep(0.1)
        p = cams.path(0, 3)
        p.parent.mkdir(parents=True, exist_ok=True)
        with open(p, "wb") as f:
            f.write(data[:100])
            f.flush()
            time.sleep(0.02)
            f.write(data[100:])

    th = threading.Thread(target=vendor)
    th.start()
    (frame,) = cams.collect(Trigger(3), timeout=5.0)
    th.join()
    assert frame.data == data and frame.sha256 == hashlib.sha256(data).hexdigest() and frame.camera == 0


def test_a_writer_pausing_longer_than_settle_is_not_read_half_written(tmp_path):
    """Without a sidecar a file was taken once its size held for ``settle``: a writer pausing 0.3 s gave a frame of
    its first 100 bytes, checksummed and journalled as if whole (a red team). A PNG is complete at its IEND chunk."""
    cams = HotFolderCameras(tmp_path, [0], settle=0.05)
    data = _png(16, 12)

    def vendor():
        p = cams.path(0, 4)
        p.parent.mkdir(parents=True, exist_ok=True)
        with open(p, "wb") as f:
            f.write(data[:100])
            f.flush()
            time.sleep(0.3)  # six times settle
            f.write(data[100:])

    th = threading.Thread(target=vendor)
    th.start()
    (frame,) = cams.collect(Trigger(4), timeout=5.0)
    th.join()
    assert frame.data == data


def test_links_fifos_and_folders_in_place_of_a_frame_are_refused(tmp_path):
    import os

    cams = HotFolderCameras(tmp_path, [0])
    outside = tmp_path.parent / f"{tmp_path.name}-outside.png"
    outside.write_bytes(_png(4, 4))
    cams.path(0, 1).parent.mkdir(parents=True)
    os.symlink(outside, cams.path(0, 1))  # read through before, then moved into the capture folder as a link
    os.symlink("/dev/zero", cams.path(0, 2))  # read until memory ran out, past the frame timeout
    os.mkfifo(cams.path(0, 3))  # blocked the read for ever
    for frame in (1, 2, 3):
        t0 = time.monotonic()
        with pytest.raises(DeviceError, match="is not a regular file"):
            cams.collect(Trigger(frame), timeout=2.0)
        assert time.monotonic() - t0 < 1.0


def test_wrong_resolution_is_refused_naming_both_sizes(tmp_path):
    cams = HotFolderCameras(tmp_path, [0], sizes={0: (64, 48)})
    _drop(cams, 0, 1, _png(32, 24))
    with pytest.raises(
        DeviceError, match=r"is 32×24 pixels, the calibration's camera 0 is 64×48.*calibrated resolution"
    ):
        cams.collect(Trigger(1), timeout=1.0)


def test_checksum_sidecars_are_verified_and_release_removes_both_files(tmp_path):
    cams = HotFolderCameras(tmp_path, [0, 1], require_checksum=True)
    good, bad = _png(8, 8), _png(8, 8)
    p0 = _drop(cams, 0, 2, good, f"{hashlib.sha256(good).hexdigest()} {len(good)}")
    _drop(cams, 1, 2, bad[:-5], f"{hashlib.sha256(bad).hexdigest()} {len(bad)}")  # truncated in transfer
    with pytest.raises(DeviceError, match=r"does not match its checksum file 000000000002\.png\.sha256.*--resume"):
        cams.collect(Trigger(2), timeout=1.0)
    cams.release(Trigger(2))
    assert not list(tmp_path.rglob("*.png")) and not list(tmp_path.rglob("*.sha256"))
    p0 = _drop(cams, 0, 4, good)  # no sidecar while one is required: waited for, then a timeout
    with pytest.raises(DeviceTimeout):
        cams.collect(Trigger(4, lines=1), timeout=0.2)
    p0.with_name(p0.name + ".sha256").write_text(f"{hashlib.sha256(good).hexdigest()} {len(good)}")
    (frame,) = cams.collect(Trigger(4, lines=1), timeout=1.0)  # trigger line of camera 0 only
    assert frame.data == good


def test_a_missing_folder_or_pattern_is_a_clear_error(tmp_path):
    with pytest.raises(DeviceError, match="hot folder .* does not exist: point --hot-folder"):
        HotFolderCameras(tmp_path / "absent", [0]).prepare()
    with pytest.raises(DeviceError, match="hot-folder pattern .* is invalid"):
        HotFolderCameras(tmp_path, [0], pattern="cam{cam}/{frame}{ext}")


@pytest.mark.parametrize(
    "pattern, first",
    [
        ("../x{camera}{frame}{ext}", "../x00.png"),
        ("cam{camera}/../../{frame}{ext}", "cam0/../../0.png"),
        ("/tmp/x{camera}_{frame}{ext}", "/tmp/x0_0.png"),
        ("~/x{camera}_{frame}{ext}", "~/x0_0.png"),
    ],
)
def test_a_pattern_that_leaves_the_hot_folder_is_refused(tmp_path, pattern, first):
    """Frames are moved out of (and released frames deleted from) where the pattern points: only inside the folder."""
    with pytest.raises(
        DeviceError, match=rf"hot-folder pattern .* must name a file inside the hot folder .*got '{re.escape(first)}'"
    ):
        HotFolderCameras(tmp_path, [0, 1], pattern=pattern)
    ok = HotFolderCameras(tmp_path, [0, 1], pattern="cam{camera}..{frame}{ext}")  # '..' inside a name is a name
    assert ok.path(1, 7) == tmp_path / "cam1..7.png"
