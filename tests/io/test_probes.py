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

# Real probes: the committed Poly Haven sample (CC0, resampled; tests/data/polyhaven-probes/README.md), or any
# directory of lat-long Radiance probes named by FACESTATS_PROBES (e.g. kayru/Probulator's Data/Probes).
SAMPLE = TEST_DATA / "polyhaven-probes"
PROBES = pathlib.Path(os.environ.get("FACESTATS_PROBES", SAMPLE))
REAL_PROBES = sorted(PROBES.glob("*.hdr")) or [
    pytest.param(None, marks=pytest.mark.skip(reason=f"no real .hdr probes in {PROBES} (FACESTATS_PROBES)"))
]


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


@pytest.mark.parametrize("path", REAL_PROBES, ids=lambda p: getattr(p, "stem", "none"))
def test_real_probes_read_as_opencv_decodes_them(path):
    import cv2

    p = read_light_probe(path)
    h, w, _ = p.shape
    assert p.dtype == np.float32 and w == 2 * h  # lat-long
    ref = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[..., ::-1]  # an independent RGBE decoder (BGR)
    assert ref.shape == p.shape
    # OpenCV decodes a mantissa m as m·2^(e−136), Radiance (and facestats) as (m + ½)·2^(e−136): half a code.
    assert np.all(np.abs(p - ref) <= ref.max(-1, keepdims=True) / 128 + 1e-6)
    assert np.all(p >= ref)  # … and never below OpenCV's value: the same codes, the half code added
    # Radiance, never normalised: light sources far above the median scene radiance (more than five stops).
    assert p.min() >= 0 and p.max() > 1 and p.max() > 32 * np.median(p)


@pytest.mark.parametrize("ext", [".hdr", ".exr", ".pfm"])
@pytest.mark.parametrize("path", REAL_PROBES, ids=lambda p: getattr(p, "stem", "none"))
def test_real_probes_survive_every_writer_unchanged(tmp_path, path, ext):
    p = read_light_probe(path)
    back = read_light_probe(write_light_probe(tmp_path / f"copy{ext}", p))
    # EXR and PFM keep float32 exactly; a decoded RGBE value, (m + ½)·2^(e−136), encodes back to the same (m, e).
    np.testing.assert_array_equal(back, p)


def test_outdoor_probe_has_its_sun_above_the_horizon_and_its_sky_above_the_ground():
    """``park.hdr`` of the committed sample: daylight, the sun in view (its README)."""
    p = read_light_probe(SAMPLE / "park.hdr").astype(np.float64)
    h, w, _ = p.shape
    lum = p @ [0.2126, 0.7152, 0.0722]
    d = sphere.latlong_directions(h, w)
    sun = np.unravel_index(np.argmax(lum), lum.shape)
    assert d[sun][1] > 0  # +y is up: row 0 of the file is the zenith
    assert lum[sun] > 1000 * np.median(lum)  # the sun's disc, orders of magnitude above the sky
    power = lum * sphere.latlong_solid_angles(h, w)
    assert power[: h // 2].sum() > 2 * power[h // 2 :].sum()  # the sky half gives more light than the ground half


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
    with pytest.raises(ValidationError, match=r"square\.pfm.*twice as wide as high, got 8 x 8 .*--layout angular"):
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
