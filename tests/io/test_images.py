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


def test_rgbe_exposure_and_colour_correction_are_divided_out(tmp_path):
    # Radiance's EXPOSURE= and COLORCORR= record multipliers already applied to the pixels, cumulatively
    img = _bright()
    raw = images.write_rgbe(tmp_path / "x.hdr", img).read_bytes()
    stored = images.read_rgbe(tmp_path / "x.hdr")
    head = b"FORMAT=32-bit_rle_rgbe\n"
    (tmp_path / "e.hdr").write_bytes(raw.replace(head, head + b"EXPOSURE= 2\nCOLORCORR=1 2 4\nEXPOSURE=0.25\n"))
    back = images.read_rgbe(tmp_path / "e.hdr")
    np.testing.assert_allclose(back, stored / (0.5 * np.array([1, 2, 4])), rtol=1e-6)
    for bad in (b"EXPOSURE=0", b"EXPOSURE=inf", b"EXPOSURE=two", b"COLORCORR=1 2"):
        (tmp_path / "b.hdr").write_bytes(raw.replace(head, head + bad + b"\n"))
        with pytest.raises(images.ImageFormatError, match=bad.split(b"=")[0].decode()):
            images.read_rgbe(tmp_path / "b.hdr")


def test_a_radiance_header_with_crlf_line_ends_is_read(tmp_path):
    """A header written on Windows (CRLF) was "no end of header (empty line)" (a user's real-data run)."""
    img = _bright()
    raw = images.write_rgbe(tmp_path / "x.hdr", img).read_bytes()
    cut = raw.index(b"\n\n") + 2
    size_end = raw.index(b"\n", cut) + 1
    header = raw[:size_end].replace(b"\n", b"\r\n")
    (tmp_path / "crlf.hdr").write_bytes(header + raw[size_end:])
    np.testing.assert_array_equal(images.read_rgbe(tmp_path / "crlf.hdr"), images.read_rgbe(tmp_path / "x.hdr"))
    long = raw.replace(b"\n\n", b"\n#" + b"c" * 70_000 + b"\n\n", 1)  # a comment line of 70 KiB is read (a review)
    (tmp_path / "long.hdr").write_bytes(long)
    np.testing.assert_array_equal(images.read_rgbe(tmp_path / "long.hdr"), images.read_rgbe(tmp_path / "x.hdr"))
    (tmp_path / "none.hdr").write_bytes(raw[: raw.index(b"\n\n")] + b"\n" + b"#" * (1 << 21))
    with pytest.raises(images.ImageFormatError, match="has no end of header .an empty line. within its first"):
        images.read_rgbe(tmp_path / "none.hdr")


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


def test_exr_integer_channels_out_of_the_uint32_range_are_refused(tmp_path):
    ok = {"region": np.array([[0, 2**32 - 1]], np.int64), "mask": np.array([[True, False]])}
    images.write_exr(tmp_path / "ok.exr", ok)
    back, _ = images.read_exr(tmp_path / "ok.exr")
    assert back["region"].tolist() == [[0, 2**32 - 1]] and back["mask"].tolist() == [[1, 0]]
    for value in (-1, 2**33):  # stored as 4294967295 and 0 before
        with pytest.raises(ValidationError, match=rf"channel 'region' for .*must hold integers in \[0, 4294967295\] "
                           rf"\(stored as uint32\), got {value}"):  # fmt: skip
            images.write_exr(tmp_path / "bad.exr", {"region": np.array([[1, value]], np.int64)})
        assert not (tmp_path / "bad.exr").exists()


def test_write_exr_takes_named_channels_and_refuses_an_image_array_by_name(tmp_path):
    """write_exr(path, ndarray) raised numpy's "truth value of an array ... is ambiguous" (a user's run): an image
    array is refused naming the argument and what it takes, and write_image writes it as Y or R, G, B[, A]."""
    rgba = np.random.default_rng(1).random((3, 5, 4)).astype(np.float32)
    for bad, said in ((rgba, r"got ndarray of shape \(3, 5, 4\); write an \(H, W\[, C\]\) image with write_image"),
                      ([rgba[..., 0]], "got list"), (None, "got NoneType")):  # fmt: skip
        with pytest.raises(
            ValidationError, match=r"^channels must be a dict of channel name to \(H, W\) array.*" + said
        ):
            images.write_exr(tmp_path / "a.exr", bad)
    for name in ("", 3):
        with pytest.raises(ValidationError, match=f"channels must be named by non-empty strings, got {name!r}"):
            images.write_exr(tmp_path / "a.exr", {name: rgba[..., 0]})
    assert not (tmp_path / "a.exr").exists()
    images.write_image(tmp_path / "rgba.exr", rgba)  # the array form: channels named R, G, B, A
    back, _ = images.read_exr(tmp_path / "rgba.exr")
    assert sorted(back) == ["A", "B", "G", "R"] and np.array_equal(back["A"], rgba[..., 3])
    assert np.array_equal(images.read_image(tmp_path / "rgba.exr"), rgba)


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


def test_srgb_transfer_agrees_with_colour_science_and_round_trips():
    """The IEC 61966-2-1 formulas written out in facestats.io.images against colour-science's, an independent
    implementation: negative and over-range encoded values, both knees and a dense grid between."""
    import colour

    v = np.concatenate([np.linspace(-0.2, 1.3, 20001), [0.04045, 0.040449936, 0.0031308, 0.0, 1.0]])
    theirs = colour.cctf_decoding(v, function="sRGB")
    # within float32 rounding, except between the two thresholds (0.040449936, 0.04045] (images.SRGB_DECODE_KNEE)
    np.testing.assert_allclose(images.srgb_to_linear(v), theirs, rtol=2e-7, atol=3e-9)
    linear = np.linspace(-0.5, 1.5, 20001)
    theirs = colour.cctf_encoding(np.clip(linear, 0, 1), function="sRGB")
    np.testing.assert_allclose(images.linear_to_srgb(linear), theirs, rtol=2e-7, atol=1e-9)
    grid = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(images.srgb_to_linear(images.linear_to_srgb(grid)), grid, rtol=1e-6, atol=1e-8)
    # continuous at both knees (a sign or constant typo would break one of them)
    for f, knee in ((images.srgb_to_linear, 0.04045), (images.linear_to_srgb, 0.0031308)):
        below, above = f(np.array([knee * (1 - 1e-7), knee * (1 + 1e-7)], np.float64))
        assert abs(above - below) < 1e-6 * max(abs(above), 1e-3)
    assert images.srgb_to_linear(np.ones((3, 2), np.float32)).dtype == np.float32


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
    head = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 256\n"
    for cut in (b"\x02", b"\x02\x02", b"\x02\x02\x01"):  # cut inside a run-length marker
        (tmp_path / "c.hdr").write_bytes(head + cut)
        with pytest.raises(ValidationError, match=r"c.hdr' is truncated: '-Y 4 \+X 256' needs at least"):
            images.read_image(tmp_path / "c.hdr")
    (tmp_path / "h.hdr").write_bytes(b"#?RADIANCE\n\n-Y 9999 +X 19998\n" + b"\0" * 100)
    with pytest.raises(ValidationError, match=r"h.hdr' is truncated: .* the file holds 100"):  # before allocating
        images.read_image(tmp_path / "h.hdr")
    # Beyond MAX_IMAGE_PIXELS the header alone is refused; a flat scanline of 2^30 pixels (no run-length encoding
    # at widths >= 32768) needed 4 GB where the old bound assumed run-length encoding (a fuzzing red team).
    (tmp_path / "w.hdr").write_bytes(b"#?RADIANCE\n\n-Y 1 +X 1073741824\n" + b"\0" * 100)
    with pytest.raises(ValidationError, match=r"w.hdr' declares 1073741824 x 1 pixels, more than the 268435456"):
        images.read_image(tmp_path / "w.hdr")
    (tmp_path / "f.hdr").write_bytes(b"#?RADIANCE\n\n-Y 2 +X 40000\n" + b"\0" * 100)  # flat rows: 4 bytes a pixel
    with pytest.raises(ValidationError, match=r"f.hdr' is truncated: '-Y 2 \+X 40000' needs at least 320000 bytes"):
        images.read_image(tmp_path / "f.hdr")
    (tmp_path / "z.hdr").write_bytes(b"#?RADIANCE\n\n-Y 0 +X 0\n")
    with pytest.raises(ValidationError, match=r"z.hdr' must have at least one pixel, got '-Y 0 \+X 0'"):
        images.read_image(tmp_path / "z.hdr")
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(ValidationError, match=r"empty.png' is empty \(0 bytes\)"):
        images.read_integer_image(tmp_path / "empty.png")
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


# -- TIFF layouts ------------------------------------------------------------------------------------------------------
def _rgb16(h=37, w=53):
    """Random 16-bit RGB codes with a constant blue channel of 30000 (decoders that misread planar data scramble it)."""
    rgb = np.random.default_rng(16).integers(0, 65536, (h, w, 3), dtype=np.uint16)
    rgb[..., 2] = 30000
    return rgb


def _planar(a):
    return np.ascontiguousarray(np.moveaxis(a, -1, 0))  # (H, W, S) -> (S, H, W), as tifffile writes separate planes


# name: (codes as read, array and keywords for tifffile.imwrite, bits)
_TIFF_LAYOUTS = {
    "planar_rgb16": (_rgb16(), lambda a: (_planar(a), dict(photometric="rgb", planarconfig="separate")), 16),
    "planar_rgb16_strips": (
        _rgb16(),
        lambda a: (_planar(a), dict(photometric="rgb", planarconfig="separate", rowsperstrip=5)),
        16,
    ),
    "big_endian_rgb16": (_rgb16(), lambda a: (a, dict(photometric="rgb", byteorder=">")), 16),
    "tiled_rgb16": (_rgb16(), lambda a: (a, dict(photometric="rgb", tile=(16, 16))), 16),
    "lzw_rgb16": (_rgb16(), lambda a: (a, dict(photometric="rgb", compression="lzw")), 16),
    "deflate_predictor_rgb16": (
        _rgb16(),
        lambda a: (a, dict(photometric="rgb", compression="zlib", predictor=True)),
        16,
    ),
    "packbits_rgb16": (_rgb16(), lambda a: (a, dict(photometric="rgb", compression="packbits")), 16),
    "planar_tiled_big_endian_deflate_rgb16": (
        _rgb16(),
        lambda a: (
            _planar(a),
            dict(photometric="rgb", planarconfig="separate", tile=(16, 16), byteorder=">", compression="zlib"),
        ),
        16,
    ),
    "bigtiff_planar_lzw_predictor_rgb16": (
        _rgb16(),
        lambda a: (
            _planar(a),
            dict(photometric="rgb", planarconfig="separate", bigtiff=True, compression="lzw", predictor=True),
        ),
        16,
    ),
    "planar_rgba16": (
        np.dstack([_rgb16(), _rgb16()[..., :1]]),
        lambda a: (_planar(a), dict(photometric="rgb", planarconfig="separate", extrasamples=["unassalpha"])),
        16,
    ),
    "grey16": (_rgb16()[..., :1], lambda a: (a[..., 0], dict(photometric="minisblack")), 16),
    "planar_rgb8": (
        (_rgb16() >> 8).astype(np.uint8),
        lambda a: (_planar(a), dict(photometric="rgb", planarconfig="separate")),
        8,
    ),
    "packed_12_bit_rgb": (_rgb16() >> 4, lambda a: (a, dict(photometric="rgb", bitspersample=12)), 12),
    "packed_12_bit_planar_rgb": (
        _rgb16() >> 4,
        lambda a: (_planar(a), dict(photometric="rgb", planarconfig="separate", bitspersample=12)),
        12,
    ),
}


@pytest.mark.parametrize("layout", sorted(_TIFF_LAYOUTS))
def test_tiff_layouts_decode_to_the_exact_codes(tmp_path, layout):
    """Every layout tifffile (an independent writer) produces reads back code for code, RGB(A) order, (H, W, C)."""
    tifffile = pytest.importorskip("tifffile")
    codes, writer, bits = _TIFF_LAYOUTS[layout]
    data, kwargs = writer(codes)
    path = tmp_path / f"{layout}.tif"
    tifffile.imwrite(path, data, **kwargs)
    raw, b = images.read_integer_image(path)
    assert b == bits and raw.dtype == (np.uint8 if bits == 8 else np.uint16)
    assert raw.shape == codes.shape and raw.flags.c_contiguous
    np.testing.assert_array_equal(raw, codes)
    if layout == "planar_rgb16":
        assert np.all(raw[..., 2] == 30000)  # constant blue: OpenCV decodes it wrong (bench_photos.bench_tiff)
    assert images.decode_integer_image(path.read_bytes(), path.name)[1] == bits
    np.testing.assert_array_equal(images.read_image(path), codes.astype(np.float32) / np.float32(2**bits - 1))


def test_multi_page_tiff_reads_its_first_image(tmp_path):
    tifffile = pytest.importorskip("tifffile")
    first = _rgb16()
    tifffile.imwrite(tmp_path / "pages.tif", np.stack([first, first // 2]), photometric="rgb")
    np.testing.assert_array_equal(images.read_integer_image(tmp_path / "pages.tif")[0], first)


def test_jpeg_compressed_tiff_decodes_to_8_bit_rgb_like_tifffile(tmp_path):
    tifffile = pytest.importorskip("tifffile")
    rgb8 = (_rgb16() >> 8).astype(np.uint8)
    tifffile.imwrite(tmp_path / "j.tif", rgb8, photometric="rgb", compression="jpeg")  # stored as YCbCr
    raw, bits = images.read_integer_image(tmp_path / "j.tif")
    assert bits == 8 and raw.dtype == np.uint8 and raw.shape == rgb8.shape
    np.testing.assert_array_equal(raw, tifffile.imread(tmp_path / "j.tif"))


_BAD_TIFFS = {
    "float32": (lambda: (_rgb16().astype(np.float32), dict(photometric="rgb")), r"SampleFormat \(tag 339\) = '3"),
    "int16": (lambda: (_rgb16().astype(np.int16), dict(photometric="rgb")), r"SampleFormat \(tag 339\) = '2"),
    "uint32": (lambda: (_rgb16().astype(np.uint32), dict(photometric="rgb")), r"BitsPerSample \(tag 258\) = 32"),
    "bilevel": (lambda: (_rgb16()[..., 0] > 30000, dict(photometric="minisblack")), r"BitsPerSample \(tag 258\) = 1"),
    "miniswhite": (
        lambda: (_rgb16()[..., 0], dict(photometric="miniswhite")),
        r"PhotometricInterpretation \(tag 262\) = '0 \(MinIsWhite\)'",
    ),
    "palette": (
        lambda: ((_rgb16()[..., 0] >> 8).astype(np.uint8), dict(photometric="palette", colormap=np.zeros((3, 256)))),
        r"PhotometricInterpretation \(tag 262\) = '3 \(Palette\)'",
    ),
    "cmyk": (
        lambda: (np.dstack([_rgb16(), _rgb16()[..., :1]]), dict(photometric="separated")),
        r"PhotometricInterpretation \(tag 262\) = '5 \(Separated \(CMYK\)\)'",
    ),
    "grey_with_extra_samples": (
        lambda: (_rgb16(), dict(photometric="minisblack", planarconfig="contig")),
        r"SamplesPerPixel \(tag 277\) = 3",
    ),
    "thumbnail_first": (lambda: (_rgb16(), dict(photometric="rgb", subfiletype=1)), r"NewSubfileType \(tag 254\) = 1"),
}


@pytest.mark.parametrize("case", sorted(_BAD_TIFFS))
def test_unsupported_tiffs_name_the_file_the_tag_and_the_value(tmp_path, case):
    tifffile = pytest.importorskip("tifffile")
    writer, message = _BAD_TIFFS[case]
    data, kwargs = writer()
    path = tmp_path / f"{case}.tif"
    tifffile.imwrite(path, data, **kwargs)
    with pytest.raises(images.ImageFormatError, match=rf"TIFF file '.*{case}\.tif' must hold .*{message}"):
        images.read_integer_image(path)


def test_truncated_tiffs_name_the_file(tmp_path):
    tifffile = pytest.importorskip("tifffile")
    tifffile.imwrite(tmp_path / "whole.tif", _rgb16(), photometric="rgb")
    data = (tmp_path / "whole.tif").read_bytes()
    with pytest.raises(ValidationError, match=r"TIFF file 'cut\.tif' could not be decoded by libtiff: .*strip"):
        images.decode_integer_image(data[: len(data) // 2], "cut.tif")
    with pytest.raises(ValidationError, match=r"TIFF file 'head\.tif' could not be decoded: .*corrupt"):
        images.decode_integer_image(data[:12], "head.tif")


@pytest.mark.parametrize("srgb, bits", [(True, 8), (False, 8), (False, 16), (True, 16)])
def test_integer_images_over_many_blocks_hold_the_codes_of_the_whole_image_formula(tmp_path, srgb, bits):
    """PNG codes are computed block by block (an image's float64 copies were four times its size): an image of
    several blocks, NaN-free, with values outside [0, 1], gets round(encode(clip(x)) * (2**bits - 1))."""
    import colour
    import cv2

    from facestats.io.images import SRGB_BLOCK, write_image

    rng = np.random.default_rng(5)
    img = rng.uniform(-0.1, 1.1, size=(SRGB_BLOCK // 300 + 7, 300, 3)).astype(np.float32)  # > one block
    path = write_image(tmp_path / "x.png", img, srgb=srgb, bits=bits)
    v = np.clip(img.astype(np.float64), 0, 1)
    v = colour.cctf_encoding(v, function="sRGB").astype(np.float32) if srgb else v
    codes = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[..., ::-1]  # OpenCV reads BGR
    assert codes.dtype == (np.uint8 if bits == 8 else np.uint16)
    np.testing.assert_array_equal(codes, np.round(v * (2**bits - 1)))
    img[3, 4, 1] = np.nan
    with pytest.raises(ValidationError, match="finite"):
        write_image(tmp_path / "y.png", img, srgb=srgb, bits=bits)
    assert not (tmp_path / "y.png").exists()
