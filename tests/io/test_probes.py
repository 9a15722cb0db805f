"""Light-probe files: one bright texel through every reader and writer, real probes, bad files."""

import os
import pathlib

import numpy as np
import pytest

from facestats.errors import ValidationError
from facestats.io import read_light_probe
from facestats.io.probes import write_light_probe
from facestats.model import sphere
from tests.helpers import TEST_DATA

EXTERNAL = pathlib.Path(os.environ.get("FACESTATS_TEST_DATA", TEST_DATA / "external"))
PROBULATOR = EXTERNAL / "probulator"
REAL_PROBES = ("pisa", "ennis", "wells")


@pytest.mark.parametrize("ext", [".hdr", ".exr", ".pfm"])
@pytest.mark.parametrize("layout", ["latlong", "angular"])
def test_one_bright_texel_keeps_its_direction_through_write_and_read(tmp_path, ext, layout):
    h = 16
    shape = (h, 2 * h, 3) if layout == "latlong" else (2 * h, 2 * h, 3)
    probe = np.full(shape, 0.25, np.float32)
    i, j = (3, 21) if layout == "latlong" else (9, 22)
    probe[i, j] = [40.0, 20.0, 10.0]
    path = write_light_probe(tmp_path / f"p{ext}", probe, layout)
    back = read_light_probe(path, layout)
    assert back.shape == shape and back.dtype == np.float32
    assert np.unravel_index(np.argmax(back[..., 0]), shape[:2]) == (i, j)
    # RGBE keeps 8 mantissa bits of the pixel's largest channel (a shared exponent).
    tol = probe.max(-1, keepdims=True) / 128 if ext == ".hdr" else 1e-7 * probe
    assert np.all(np.abs(back - probe) <= tol)
    if layout == "latlong":
        d = sphere.latlong_directions(h, 2 * h)[i, j]
        phi, theta = sphere.angles_from_direction(d)
        assert phi == pytest.approx(np.pi * 3.5 / h) and theta == pytest.approx(2 * np.pi * 21.5 / (2 * h) - np.pi)
    else:
        d, _ = sphere.angular_directions(2 * h)
        r, c = sphere.angular_coordinates(d[i, j], 2 * h)
        assert (r, c) == pytest.approx((i, j))


@pytest.mark.skipif(not PROBULATOR.is_dir(), reason=f"real probes absent: copy kayru/Probulator Data/Probes/*.hdr "
                    f"to {PROBULATOR} (or set FACESTATS_TEST_DATA)")  # fmt: skip
@pytest.mark.parametrize("name", REAL_PROBES)
def test_real_probes_read_as_opencv_decodes_them(name):
    import cv2

    path = PROBULATOR / f"{name}.hdr"
    p = read_light_probe(path)
    assert p.shape == (128, 256, 3)
    ref = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[..., ::-1]  # an independent RGBE decoder (BGR)
    # OpenCV decodes a mantissa m as m·2^(e−136), Radiance (and facestats) as (m + ½)·2^(e−136): half a code.
    assert np.all(np.abs(p - ref) <= ref.max(-1, keepdims=True) / 128 + 1e-6)
    assert p.min() >= 0 and p.max() > 1  # high dynamic range, never normalised


def test_bad_probe_files_name_file_field_and_value(tmp_path):
    from facestats.io.images import write_exr, write_pfm

    img = np.ones((8, 16, 3), np.float32)
    img[2, 5, 0] = np.inf
    write_pfm(tmp_path / "inf.pfm", img)
    with pytest.raises(ValidationError, match=r"inf\.pfm.*finite, got inf at row 2, column 5, channel 0"):
        read_light_probe(tmp_path / "inf.pfm")
    neg = np.ones((8, 16), np.float32)
    neg[1, 1] = -2
    write_exr(tmp_path / "neg.exr", {"R": neg, "G": neg, "B": neg})
    with pytest.raises(ValidationError, match=r"neg\.exr.*>= 0, got -2\.0 at row 1, column 1"):
        read_light_probe(tmp_path / "neg.exr")
    write_pfm(tmp_path / "square.pfm", np.ones((8, 8, 3), np.float32))
    with pytest.raises(ValidationError, match=r"square\.pfm.*twice as wide as high, got 8 x 8"):
        read_light_probe(tmp_path / "square.pfm")
    assert read_light_probe(tmp_path / "square.pfm", "angular").shape == (8, 8, 3)
    with pytest.raises(ValidationError, match="layout must be one of"):
        read_light_probe(tmp_path / "square.pfm", "cube")
    with pytest.raises(ValidationError, match=r"\.png'"):
        read_light_probe(tmp_path / "probe.png")
    with pytest.raises(ValidationError, match="does not exist"):
        read_light_probe(tmp_path / "missing.hdr")
    with pytest.raises(ValidationError, match="twice as wide"):
        write_light_probe(tmp_path / "w.exr", np.ones((4, 4, 3)))
    assert not (tmp_path / "w.exr").exists()
