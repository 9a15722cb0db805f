"""Image readers and writers: round trips, orientation (one bright pixel), RGBE decoding, errors."""

import numpy as np
import pytest

from facestats.errors import ValidationError
from facestats.io import images


def _bright(h=5, w=7, c=3, row=1, col=5):
    img = np.zeros((h, w, c), np.float32)
    img[row, col] = [2.5, 0.25, 0.0625][:c] if c <= 3 else 1
    return img


@pytest.mark.parametrize("ext", [".exr", ".pfm", ".hdr"])
def test_hdr_round_trip_keeps_orientation_and_values(tmp_path, ext):
    img = _bright()
    back = images.read_image(images.write_image(tmp_path / f"x{ext}", img))
    assert back.shape == img.shape and back.dtype == np.float32
    assert np.unravel_index(np.argmax(back[..., 0]), back.shape[:2]) == (1, 5)  # row 0 is the top
    # RGBE keeps 8 bits of mantissa per pixel (relative to the brightest channel).
    np.testing.assert_allclose(back, img, rtol=0, atol=2.5 / 128 if ext == ".hdr" else 0)


def test_exr_half_channels_and_attributes(tmp_path):
    rng = np.random.default_rng(0)
    chans = {
        "albedo.R": rng.random((4, 6)),
        "sigma_a.R": rng.random((4, 6)) * 0.01,
        "region": np.arange(24).reshape(4, 6),
    }
    images.write_exr(tmp_path / "t.exr", chans, half=True, attributes={"units": "mm^-1", "colour_space": "linear sRGB"})
    back, attrs = images.read_exr(tmp_path / "t.exr")
    assert attrs["units"] == "mm^-1" and attrs["colour_space"] == "linear sRGB"
    assert back["albedo.R"].dtype == np.float16 and back["region"].dtype == np.uint32
    np.testing.assert_allclose(back["albedo.R"], chans["albedo.R"], rtol=1e-3)
    np.testing.assert_array_equal(back["region"], chans["region"])


def test_pfm_is_stored_bottom_up_little_endian(tmp_path):
    img = _bright(c=1)[..., 0]
    raw = images.write_pfm(tmp_path / "g.pfm", img).read_bytes()
    assert raw.startswith(b"Pf\n7 5\n-1.0\n")
    data = np.frombuffer(raw[len(b"Pf\n7 5\n-1.0\n") :], "<f4").reshape(5, 7)
    assert data[5 - 1 - 1, 5] == np.float32(2.5)  # row 1 from the top is row 3 from the bottom
    # A big-endian file (positive scale) reads the same.
    (tmp_path / "b.pfm").write_bytes(b"Pf\n7 5\n1.0\n" + data.astype(">f4").tobytes())
    np.testing.assert_array_equal(images.read_pfm(tmp_path / "b.pfm")[..., 0], img)


def _rle_encode(channel):
    """An independent run-length encoder of one component of a scanline (runs of 3+, literals otherwise)."""
    out, x, n = bytearray(), 0, len(channel)
    while x < n:
        run = 1
        while x + run < n and run < 127 and channel[x + run] == channel[x]:
            run += 1
        if run >= 3:
            out += bytes([128 + run, channel[x]])
            x += run
        else:
            end = x
            while (
                end < n and end - x < 128 and not (end + 2 < n and channel[end] == channel[end + 1] == channel[end + 2])
            ):
                end += 1
            out += bytes([end - x]) + bytes(channel[x:end])
            x = end
    return bytes(out)


def test_rgbe_run_length_decoding_against_an_independent_encoder(tmp_path):
    rng = np.random.default_rng(1)
    h, w = 4, 40
    rgbe = rng.integers(0, 256, (h, w, 4), dtype=np.uint8)
    rgbe[:, 10:30] = rgbe[:, 10:11]  # long runs
    rgbe[..., 3] = rng.integers(120, 140, (h, w))
    body = b"".join(
        b"\x02\x02" + w.to_bytes(2, "big") + b"".join(_rle_encode(rgbe[r, :, c].tolist()) for c in range(4))
        for r in range(h)
    )
    path = tmp_path / "rle.hdr"
    path.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 40\n" + body)
    got = images.read_rgbe(path)
    want = (rgbe[..., :3] + 0.5) * np.ldexp(1.0, rgbe[..., 3].astype(int) - 136)[..., None]  # Radiance colr_color
    np.testing.assert_allclose(got, want, rtol=1e-6)


def test_rgbe_agrees_with_opencv_up_to_the_half_code_offset(tmp_path):
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(2)
    img = np.exp(rng.normal(0, 2, (16, 24, 3))).astype(np.float32)
    path = images.write_rgbe(tmp_path / "r.hdr", img)
    ours = images.read_rgbe(path)
    theirs = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[..., ::-1]  # OpenCV decodes m·2^(e−136), BGR
    e = np.frombuffer(path.read_bytes()[-16 * 24 * 4 :], np.uint8).reshape(16, 24, 4)[..., 3].astype(int)
    np.testing.assert_allclose(ours, theirs + 0.5 * np.ldexp(1.0, e - 136)[..., None], rtol=1e-6)
    # Within the 8-bit mantissa of each pixel's brightest channel (the exponent is shared).
    assert np.max(np.abs(ours - img) / img.max(axis=-1, keepdims=True)) < 1 / 128


@pytest.mark.parametrize("bits", [8, 16])
def test_integer_images_scale_and_srgb(tmp_path, bits):
    img = np.linspace(0, 1, 2 * 3 * 3).reshape(2, 3, 3)
    path = images.write_image(tmp_path / "x.png", img, bits=bits)
    raw, b = images.read_integer_image(path)
    assert b == bits and raw.dtype == (np.uint8 if bits == 8 else np.uint16)
    np.testing.assert_allclose(images.read_image(path), img, atol=0.5 / (2**bits - 1) + 1e-7)
    srgb = images.write_image(tmp_path / "s.png", img, bits=16, srgb=True)
    np.testing.assert_allclose(images.read_image(srgb, srgb=True), img, atol=2e-4)
    # The sRGB transfer function: 0.5 linear encodes to 0.7354 (IEC 61966-2-1).
    assert abs(float(images.linear_to_srgb(0.5)) - 0.735357) < 1e-5


def test_bad_files_and_arguments_name_the_problem(tmp_path):
    with pytest.raises(ValidationError, match="existing image file"):
        images.read_image(tmp_path / "missing.exr")
    (tmp_path / "a.xyz").write_bytes(b"x")
    with pytest.raises(ValidationError, match="unknown extension '.xyz'"):
        images.read_image(tmp_path / "a.xyz")
    (tmp_path / "bad.hdr").write_bytes(b"P6\n")
    with pytest.raises(ValidationError, match="must start with '#\\?RADIANCE'"):
        images.read_image(tmp_path / "bad.hdr")
    (tmp_path / "t.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 8\n\x02\x02\x00\x08\x88")
    with pytest.raises(ValidationError, match="truncated|bad run"):
        images.read_image(tmp_path / "t.hdr")
    (tmp_path / "o.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n+Y 2 +X 8\n")
    with pytest.raises(ValidationError, match="-Y H \\+X W"):
        images.read_image(tmp_path / "o.hdr")
    (tmp_path / "p.pfm").write_bytes(b"PF\n4 4\n-1.0\n" + b"\0" * 10)
    with pytest.raises(ValidationError, match="truncated"):
        images.read_image(tmp_path / "p.pfm")
    with pytest.raises(ValidationError, match="srgb must be False"):
        images.read_image(images.write_image(tmp_path / "h.pfm", np.ones((2, 2, 3))), srgb=True)
    with pytest.raises(ValidationError, match="finite and >= 0"):
        images.write_image(tmp_path / "n.hdr", np.full((2, 2, 3), np.nan))
    with pytest.raises(ValidationError, match="bits must be 8 or 16"):
        images.write_image(tmp_path / "j.jpg", np.ones((2, 2, 3)), bits=16)
