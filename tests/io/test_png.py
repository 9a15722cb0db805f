"""The PNG writer: any decoder reads back the exact samples; chunks are well formed."""

import struct
import zlib

import cv2
import numpy as np
import pytest

from facestats.errors import ValidationError
from facestats.io.exif import exif_payload, parse_exif
from facestats.io.png import PNG_SIGNATURE, encode_png, png_chunk


def _chunks(data):
    """[(type, data)] of a PNG file, every CRC checked."""
    assert data[:8] == PNG_SIGNATURE
    out, i = [], 8
    while i < len(data):
        (n,) = struct.unpack(">I", data[i : i + 4])
        tag, body = data[i + 4 : i + 8], data[i + 8 : i + 8 + n]
        (crc,) = struct.unpack(">I", data[i + 8 + n : i + 12 + n])
        assert crc == zlib.crc32(tag + body) & 0xFFFFFFFF, tag
        out.append((tag, body))
        i += 12 + n
    return out


@pytest.mark.parametrize("compression", ["auto", "huffman", "libdeflate"])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("channels", [None, 1, 3, 4])
def test_opencv_decodes_the_exact_samples(dtype, channels, compression, rng):
    shape = (37, 53) if channels is None else (37, 53, channels)
    img = rng.integers(0, np.iinfo(dtype).max + 1, shape, dtype=dtype)
    img[0, 0] = np.iinfo(dtype).max  # both byte halves of 16-bit samples matter
    back = cv2.imdecode(np.frombuffer(encode_png(img, compression=compression), np.uint8), cv2.IMREAD_UNCHANGED)
    want = img.reshape(37, 53) if channels in (None, 1) else img[..., [2, 1, 0, 3][:channels]]  # OpenCV: BGR(A)
    assert back.dtype == dtype
    np.testing.assert_array_equal(back, want)


def test_layout_chunks_and_exif(rng):
    codes = rng.integers(0, 4096, (16, 24, 3), dtype=np.uint16)
    payload = exif_payload(1 / 8, make="facestats", model="test")
    data = encode_png(codes[:, ::-1], chunks=[(b"eXIf", payload)])  # a non-contiguous view is fine
    chunks = _chunks(data)
    assert [t for t, _ in chunks] == [b"IHDR", b"eXIf", b"IDAT", b"IEND"]
    assert struct.unpack(">IIBBBBB", chunks[0][1]) == (24, 16, 16, 2, 0, 0, 0)
    rows = np.frombuffer(zlib.decompress(chunks[2][1]), np.uint8).reshape(16, 1 + 24 * 6)
    assert np.all(rows[:, 0] == 0)  # filter type None on every row
    np.testing.assert_array_equal(rows[:, 1:].view(">u2").reshape(16, 24, 3), codes[:, ::-1])
    assert float(parse_exif(data)["ExposureTime"]) == pytest.approx(1 / 8)
    assert png_chunk(b"IEND", b"") == b"\x00\x00\x00\x00IEND\xaeB`\x82"  # the constant every PNG ends with


@pytest.mark.parametrize(
    "image, kw, match",
    [
        (np.zeros((4, 4), np.float32), {}, "image must hold uint8 or uint16 samples, got dtype float32"),
        (np.zeros((4, 4, 2), np.uint8), {}, r"image must have shape \(H, W\) or \(H, W, 1\|3\|4\), got \(4, 4, 2\)"),
        (np.zeros((0, 4), np.uint8), {}, "image must have shape"),
        (np.zeros((4, 4), np.uint8), {"level": 0}, "level must be an integer in"),
        (np.zeros((4, 4), np.uint8), {"compression": "lzma"}, "compression"),
    ],
)
def test_bad_input_names_the_field(image, kw, match):
    with pytest.raises(ValidationError, match=match):
        encode_png(image, **kw)


def test_auto_compression_picks_by_size(rng):
    small = rng.integers(0, 4096, (64, 64, 3), dtype=np.uint16)  # 12,288 samples: libdeflate
    large = rng.integers(0, 4096, (160, 160, 3), dtype=np.uint16)  # 76,800 samples: Huffman-only
    for img, method in ((small, "libdeflate"), (large, "huffman")):
        assert _chunks(encode_png(img)) == _chunks(encode_png(img, compression=method))


def test_big_endian_samples_are_encoded_and_a_str_chunk_type_is_named():
    codes = (np.arange(12, dtype=">u2") * 5000).reshape(3, 4)  # refused as "dtype >u2" before
    out = cv2.imdecode(np.frombuffer(encode_png(codes), np.uint8), cv2.IMREAD_UNCHANGED)
    assert out.dtype == np.uint16 and out.tolist() == codes.tolist()
    with pytest.raises(ValidationError, match="a PNG chunk type has 4 bytes, got 'IHDR'"):  # a TypeError before
        png_chunk("IHDR", b"")


def test_text_chunks_read_back_with_pillow_latin_1_as_text_and_the_rest_as_itxt(rng):
    """Text chunks (the scale of the web app's map images) inserted after IHDR of another encoder's file: Pillow reads
    every key back; Latin-1 values are tEXt, others (σ) iTXt; the samples are untouched."""
    import io

    from PIL import Image

    from facestats.io.png import add_chunks, text_chunks

    img = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    ok, buf = cv2.imencode(".png", img[..., ::-1])
    text = {"facestats:vmin": "0.25", "Description": "ts_m (Beckmann m): viridis, é", "facestats:units": "σ mm-1"}
    chunks = text_chunks(text)
    assert [tag for tag, _ in chunks] == [b"tEXt", b"tEXt", b"iTXt"]
    data = add_chunks(buf.tobytes(), chunks)
    png = Image.open(io.BytesIO(data))
    assert png.text == text
    np.testing.assert_array_equal(np.asarray(png), img)
    assert data.index(b"IHDR") < data.index(b"tEXt") < data.index(b"IDAT")
    for bad in ({"": "x"}, {" lead": "x"}, {"a" * 80: "x"}, {"σ": "x"}, {"ok": "a\0b"}):
        with pytest.raises(ValidationError, match="PNG text"):
            text_chunks(bad)
    with pytest.raises(ValidationError, match="png must be a PNG file"):
        add_chunks(b"GIF89a" + bytes(40), chunks)
