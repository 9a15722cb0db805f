"""The EXIF exposure reader against Pillow and on JPEG, PNG and TIFF files; corrupt input."""

import re

import numpy as np
import pytest

from facestats import FacestatsError
from facestats.io.exif import embed_exif, exif_payload, read_exif, read_exposure_time


def _png16(tmp_path, exif=None):
    import cv2

    ok, buf = cv2.imencode(".png", np.arange(48, dtype=np.uint16).reshape(4, 4, 3) * 80)
    data = buf.tobytes() if exif is None else embed_exif(buf.tobytes(), exif)
    p = tmp_path / "f.png"
    p.write_bytes(data)
    return p


def test_png16_round_trip_and_pillow_reads_what_we_write(tmp_path):
    from PIL import Image

    from facestats.io.images import read_integer_image

    p = _png16(tmp_path, exif_payload(1 / 60, f_number=5.6, iso=200, make="facestats", model="dome"))
    tags = read_exif(p)
    assert tags == {
        "Make": "facestats",
        "Model": "dome",
        "ExposureTime": 1 / 60,
        "FNumber": 5.6,
        "ISOSpeedRatings": 200,
    }
    im = Image.open(p)
    im.load()
    assert im.getexif().get_ifd(0x8769)[0x829A] == pytest.approx(1 / 60)  # an independent reader agrees
    img, bits = read_integer_image(p)  # the pixels are untouched
    assert bits == 16 and img.shape == (4, 4, 3) and int(img.max()) == 47 * 80


def test_jpeg_written_by_pillow_and_by_us(tmp_path):
    from PIL import Image, TiffImagePlugin

    exif = Image.Exif()
    exif.get_ifd(0x8769)[0x829A] = TiffImagePlugin.IFDRational(1, 250)
    Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(tmp_path / "pil.jpg", exif=exif)
    assert read_exposure_time(tmp_path / "pil.jpg") == pytest.approx(0.004)
    import cv2

    ok, buf = cv2.imencode(".jpg", np.full((8, 8, 3), 100, np.uint8))
    (tmp_path / "ours.jpg").write_bytes(embed_exif(buf.tobytes(), exif_payload(2.5)))
    assert read_exposure_time(tmp_path / "ours.jpg") == 2.5
    assert Image.open(tmp_path / "ours.jpg").getexif().get_ifd(0x8769)[0x829A] == 2.5


def test_big_endian_tiff_with_the_tag_in_ifd0(tmp_path):
    tifffile = pytest.importorskip("tifffile")
    p = tmp_path / "f.tif"
    tifffile.imwrite(p, np.zeros((4, 4, 3), np.uint16), byteorder=">", extratags=[(33434, 5, 1, (1, 30), True)])
    assert read_exposure_time(p) == pytest.approx(1 / 30)


def test_files_without_exif_and_corrupt_files(tmp_path):
    assert read_exposure_time(_png16(tmp_path)) is None
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"\xff\xd8\xff\xe1\x00\x20Exif\x00\x00II*\x00\xff\xff\xff\x00" + b"\x00" * 20)
    with pytest.raises(FacestatsError, match=r"EXIF data of .*bad\.jpg is corrupt"):
        read_exif(bad)
    txt = tmp_path / "notes.txt"
    txt.write_text("hello")
    with pytest.raises(FacestatsError, match=r"notes\.txt is not a JPEG, TIFF or PNG file"):
        read_exif(txt)
    with pytest.raises(FacestatsError, match="cannot read EXIF data"):
        read_exif(tmp_path / "missing.png")


def _one_tag_tiff(typ, count, payload):
    """A little-endian TIFF whose IFD0 holds one ExposureTime entry of the given type, count and bytes."""
    import struct

    inline = len(payload) <= 4
    field = payload.ljust(4, b"\0") if inline else struct.pack("<I", 8 + 2 + 12 + 4)
    ifd = struct.pack("<H", 1) + struct.pack("<HHI", 0x829A, typ, count) + field + struct.pack("<I", 0)
    return b"II*\0" + struct.pack("<I", 8) + ifd + (b"" if inline else payload)


def test_malformed_exposure_times_are_refused_by_tag_and_value():
    import struct

    from facestats.errors import FormatError
    from facestats.io.exif import parse_exif

    assert parse_exif(_one_tag_tiff(5, 1, struct.pack("<II", 1, 60)), "f.tif")["ExposureTime"] == 1 / 60
    for data, shown in (
        (_one_tag_tiff(2, 5, b"1/60\0"), "'1/60'"),  # ASCII instead of a rational
        (_one_tag_tiff(5, 2, struct.pack("<IIII", 1, 60, 1, 30)), "[0.01666"),  # two values
        (_one_tag_tiff(5, 1, struct.pack("<II", 1, 0)), "nan"),  # zero denominator
        (_one_tag_tiff(5, 0, b""), "[]"),  # no value
    ):
        with pytest.raises(FormatError, match=r"f.tif is corrupt: EXIF ExposureTime must be one positive number, got "
                           + re.escape(shown)):  # fmt: skip
            parse_exif(data, "f.tif")


def test_informative_tags_out_of_their_domain_are_dropped_not_fatal():
    import struct

    from facestats.io.exif import parse_exif

    ifd = struct.pack("<H", 2)
    ifd += struct.pack("<HHI", 0x829A, 5, 1) + struct.pack("<I", 8 + 2 + 24 + 4)  # ExposureTime 1/60
    ifd += struct.pack("<HHI", 0x829D, 5, 1) + struct.pack("<I", 8 + 2 + 24 + 4 + 8)  # FNumber 0/0 (manual lens)
    data = b"II*\0" + struct.pack("<I", 8) + ifd + struct.pack("<I", 0)
    data += struct.pack("<II", 1, 60) + struct.pack("<II", 0, 0)
    assert parse_exif(data, "f.tif") == {"ExposureTime": 1 / 60}


def _tiff_with_ifds_at_the_end(path, make="dome", exposure=(1, 125), make_count=None):
    """A grey 8-bit TIFF of 1.5 MiB laid out as libtiff (and so OpenCV) writes it: the header, the image data,
    then IFD0 (Make) and the Exif IFD (ExposureTime), past the first MiB."""
    import struct

    h, w = 1024, 1536
    pixels = np.arange(h * w, dtype=np.uint32).astype(np.uint8).tobytes()
    ifd0_at = 8 + len(pixels)
    text = make.encode("latin-1") + b"\0"
    short = lambda v: struct.pack("<HH", v, 0)  # noqa: E731
    long = lambda v: struct.pack("<I", v)  # noqa: E731
    entries = [
        (256, 4, 1, long(w)),
        (257, 4, 1, long(h)),
        (258, 3, 1, short(8)),
        (259, 3, 1, short(1)),
        (262, 3, 1, short(1)),
        (271, 2, make_count or len(text), None),  # Make, after IFD0
        (273, 4, 1, long(8)),
        (277, 3, 1, short(1)),
        (278, 4, 1, long(h)),
        (279, 4, 1, long(len(pixels))),
        (0x8769, 4, 1, None),  # the Exif IFD, after Make
    ]
    make_at = ifd0_at + 2 + 12 * len(entries) + 4
    exif_at = make_at + len(text) + len(text) % 2
    value_at = exif_at + 2 + 12 + 4
    ifd0 = struct.pack("<H", len(entries))
    for tag, typ, count, field in entries:
        field = field or long(make_at if tag == 271 else exif_at)
        ifd0 += struct.pack("<HHI", tag, typ, count) + field
    ifd0 += long(0) + text + b"\0" * (len(text) % 2)
    sub = struct.pack("<H", 1) + struct.pack("<HHII", 0x829A, 5, 1, value_at) + long(0) + struct.pack("<II", *exposure)
    path.write_bytes(b"II*\0" + long(ifd0_at) + pixels + ifd0 + sub)
    return path


def test_tiff_whose_ifds_follow_the_image_data_past_the_first_mib(tmp_path):
    from PIL import Image

    p = _tiff_with_ifds_at_the_end(tmp_path / "end.tif")
    with Image.open(p) as im:  # an independent reader agrees: a valid TIFF, its Exif IFD past the first MiB
        assert im.size == (1536, 1024) and im.getexif()[271] == "dome"
        assert im.getexif().get_ifd(0x8769)[0x829A] == pytest.approx(1 / 125)
    assert read_exif(p) == {"Make": "dome", "ExposureTime": 1 / 125}  # "IFD offset ... beyond the end" before
    assert read_exposure_time(p) == 1 / 125


def test_tiff_written_by_opencv_has_its_ifd_at_the_end(tmp_path):
    import struct

    import cv2

    p = tmp_path / "cv.tif"
    noise = np.random.default_rng(0).integers(0, 1 << 16, (512, 512, 3), dtype=np.uint16)  # 1.5 MiB, LZW or not
    cv2.imwrite(str(p), noise)
    assert struct.unpack("<I", p.read_bytes()[4:8])[0] > 1 << 20  # libtiff writes IFD0 after the image data
    assert read_exif(p) == {} and read_exposure_time(p) is None  # no EXIF in it: a FormatError before


def test_tiff_values_past_the_first_mib_are_bounded(tmp_path, monkeypatch):
    from facestats.io import exif

    huge = _tiff_with_ifds_at_the_end(tmp_path / "huge.tif", make_count=0xFFFFFFF0)
    with pytest.raises(FacestatsError, match=r"huge\.tif is corrupt: TIFF entry points beyond the end of its data"):
        read_exif(huge)
    long_make = _tiff_with_ifds_at_the_end(tmp_path / "long.tif", make="x" * 9000)
    assert read_exif(long_make)["Make"] == "x" * 9000
    monkeypatch.setattr(exif, "_MAX_READ", 4096)  # a value (or an IFD) is read only up to a size, never the file
    with pytest.raises(FacestatsError, match=r"long\.tif is corrupt: TIFF field of 9001 bytes at offset \d+ is too"):
        read_exif(long_make)
