"""Damaged and hostile input files give a named error (a fuzzing red team of the readers, 2026-12-06).

Each case below was a silently wrong result, a hang, a huge allocation or a raw exception before.
"""

import json
import os
import pathlib
import struct
import threading

import numpy as np
import pytest
import scipy.io

from facestats.errors import FacestatsError, FormatError, ValidationError
from facestats.io.images import ImageFormatError, decode_integer_image, read_image, read_npy
from tests.helpers import merl_dict, save_mat


def _write(path, data):
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


# -- OBJ and PLY meshes ----------------------------------------------------------------------------------------
def test_obj_lines_with_too_few_numbers_and_bad_face_indices_are_named(tmp_path):
    from facestats.io.mesh_sequence import read_obj

    # Past 1000 lines, a 'v' line of four numbers then one of two shifted values between rows, silently.
    lines = [f"v {i} {i} {i}" for i in range(1000)] + ["v 1000 1000 1000 1", "v 1001 1001", "f 1 2 3"]
    with pytest.raises(FormatError, match=r"'v' lines must hold at least 3 numbers, got 'v 1001 1001' \(line 1002"):
        read_obj(_write(tmp_path / "a.obj", "\n".join(lines)))
    mesh = read_obj(_write(tmp_path / "w.obj", "\n".join(lines[:1000] + ["v 1 2 3 0.5", "f 1 2 3"])))
    assert mesh.vertices.shape == (1001, 3) and mesh.vertices[-1].tolist() == [1, 2, 3]  # w ignored, rows intact
    cases = {
        "v 0 0\nv 1 0\nv 0 1\nf 1 2 3\n": r"'v' lines must hold at least 3 numbers",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0\nvt 1\nvt 1\nf 1/1 2/2 3/3\n": r"'vt' lines must hold at least 2 numbers",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1.0 2 3\n": r"face 0 must hold integer indices",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/x 2 3\n": r"face 0 must hold integer indices",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 2 3\n": r"face 0 holds the index 0 \(OBJ indices start at 1\)",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n": r"face indices must be at most 2\*\*63 - 1",
    }
    for k, (text, match) in enumerate(cases.items()):
        with pytest.raises(FormatError, match=match):
            read_obj(_write(tmp_path / f"c{k}.obj", text))


_PLY = (
    "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n{uv}"
    "element face 1\nproperty list uchar int vertex_indices\nend_header\n{rows}3 {face}\n"
)


@pytest.mark.filterwarnings("ignore:invalid value encountered in cast")  # trimesh's own, on the NaN texture coordinate
def test_meshes_read_through_trimesh_are_checked_like_obj_files(tmp_path):
    from facestats.io.mesh import read_triangle_mesh
    from facestats.io.mesh_sequence import read_mesh

    # trimesh dropped z of every vertex for one 'v' line of two numbers, and read the index 0 as vertex 1.
    with pytest.raises(FormatError, match=r"'v' lines must hold at least 3 numbers, got 'v 1 0'"):
        read_triangle_mesh(_write(tmp_path / "a.obj", "v 0 0 5\nv 1 0\nv 0 1 5\nf 1 2 3\n"))
    with pytest.raises(FormatError, match=r"holds the index 0"):
        read_triangle_mesh(_write(tmp_path / "b.obj", "v 10 0 0\nv 0 20 0\nv 0 0 30\nf 0 2 3\n"))
    # A PLY face index -1 was kept (numpy then took the last vertex); a NaN texture coordinate was kept.
    ply = _write(tmp_path / "c.ply", _PLY.format(n=4, uv="", rows="10 0 0\n0 20 0\n0 0 30\n40 40 40\n", face="-1 1 2"))
    for read in (read_triangle_mesh, read_mesh):
        with pytest.raises(FormatError, match=r"faces of .*c\.ply must index its 4 vertices, got indices -1\.\.2"):
            read(ply)
    uv = "property float s\nproperty float t\n"
    ply = _write(tmp_path / "d.ply", _PLY.format(n=3, uv=uv, rows="0 0 0 0 0\n1 0 0 1 0\n0 1 0 nan 1\n", face="0 1 2"))
    with pytest.raises(FormatError, match=r"texture coordinates of .*d\.ply must be finite"):
        read_mesh(ply)
    good = _write(tmp_path / "e.ply", _PLY.format(n=3, uv=uv, rows="0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n", face="0 1 2"))
    mesh = read_mesh(good)
    assert mesh.triangles.tolist() == [[0, 1, 2]] and mesh.uv[:, 1].tolist() == [1, 1, 0]  # v flipped


# -- FIFOs: every reader refuses them at once ----------------------------------------------------------------
def _finishes(call, seconds=10.0):
    """The exception ``call`` raised, asserting it returned within ``seconds`` (a FIFO blocked open() forever)."""
    out = {}

    def run():
        try:
            call()
        except Exception as exc:
            out["exc"] = exc

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), "the reader blocked on a FIFO"
    return out.get("exc")


@pytest.mark.parametrize(
    "name, reader",
    [
        ("f.obj", "facestats.io.mesh_sequence:read_obj"),
        ("f.jpg", "facestats.io.exif:read_exif"),
        ("f.csv", "facestats.io.mesh_sequence:read_weights"),
        ("f.npy", "facestats.io.mesh:read_region_image"),
        ("f.tif", "facestats.io.displacement:read_displacement"),
    ],
)
def test_readers_refuse_a_fifo_without_blocking(tmp_path, name, reader):
    import importlib

    module, func = reader.split(":")
    fifo = tmp_path / name
    os.mkfifo(fifo)
    exc = _finishes(lambda: getattr(importlib.import_module(module), func)(fifo))
    assert isinstance(exc, FacestatsError) and "not a regular file" in str(exc)


# -- TIFF, EXR, Radiance and .npy files ------------------------------------------------------------------------
def _tiff(entries):
    """A classic little-endian TIFF header and one IFD of ``(tag, type, count, 4-byte value)`` entries."""
    body = b"".join(struct.pack("<HHI", t, ty, c) + v for t, ty, c, v in sorted(entries))
    return b"II*\0" + struct.pack("<I", 8) + struct.pack("<H", len(entries)) + body + b"\0\0\0\0"


def test_tiff_tags_of_another_type_and_huge_declared_sizes_are_refused():
    short = lambda v: struct.pack("<HH", v, 0)  # noqa: E731
    base = [(256, 3, 1, short(4)), (257, 3, 1, short(4)), (262, 3, 1, short(1))]
    with pytest.raises(ImageFormatError, match=r"must hold a non-negative integer BitsPerSample \(tag 258\), got '8'"):
        decode_integer_image(_tiff(base + [(258, 2, 2, b"8\0\0\0")]), "b.tif")  # ASCII: a TypeError before
    huge = [(256, 4, 1, struct.pack("<I", 40000)), (257, 4, 1, struct.pack("<I", 40000)), *base[2:]]
    with pytest.raises(ImageFormatError, match=r"declares 40000 x 40000 pixels, more than the 268435456"):
        decode_integer_image(_tiff(huge + [(258, 3, 1, short(8))]), "x")  # 1.56 GB of RSS in libtiff before


def test_png_and_jpeg_headers_are_checked_before_decoding():
    import zlib

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", 20000, 20000, 8, 0, 0, 0, 0)  # 8-bit grey, 400 M pixels
    row = zlib.compress(b"\0" * 20001 * 64)  # a few rows of the zeros a bomb would hold
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", row) + chunk(b"IEND", b"")
    with pytest.raises(ImageFormatError, match=r"'bomb\.png' declares 20000 x 20000 pixels"):
        decode_integer_image(png, "bomb.png")  # OpenCV allocated the 400 MB image before
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 11, 8, 20000, 30000, 1) + b"\x01\x11\x00"
    with pytest.raises(ImageFormatError, match=r"'bomb\.jpg' declares 30000 x 20000 pixels"):
        decode_integer_image(b"\xff\xd8\xff\xe0\x00\x04ab" + sof + b"\xff\xd9", "bomb.jpg")
    real = (pathlib.Path(__file__).parents[1] / "data" / "unis-bracket" / "UNIS_EV0.jpg").read_bytes()
    assert decode_integer_image(real, "real.jpg")[0].shape == (768, 1024, 3)  # a real JPEG's header is found


def _exr(width, height, channels):
    """An uncompressed scanline EXR (OpenEXR file layout) of FLOAT channels ``(name, x sampling, y sampling)``."""

    def attr(name, kind, data):
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(data)) + data

    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, xs, ys) for n, xs, ys in channels) + b"\0"
    window = struct.pack("<4i", 0, 0, width - 1, height - 1)
    header = (
        attr("channels", "chlist", chlist)
        + attr("compression", "compression", b"\0")
        + attr("dataWindow", "box2i", window)
        + attr("displayWindow", "box2i", window)
        + attr("lineOrder", "lineOrder", b"\0")
        + attr("pixelAspectRatio", "float", struct.pack("<f", 1))
        + attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0))
        + attr("screenWindowWidth", "float", struct.pack("<f", 1))
        + b"\0"
    )
    head = b"\x76\x2f\x31\x01" + struct.pack("<I", 2) + header
    rows = []
    for y in range(height):
        data = b"".join(struct.pack("<f", 1.0) * (width // xs) for _, xs, ys in channels if y % ys == 0)
        rows.append(struct.pack("<ii", y, len(data)) + data)
    offsets = np.cumsum([len(head) + 8 * height] + [len(r) for r in rows[:-1]])
    return head + b"".join(struct.pack("<Q", int(o)) for o in offsets) + b"".join(rows)


def test_exr_channels_must_be_full_resolution(tmp_path):
    full = _write(tmp_path / "full.exr", _exr(16, 8, [("Y", 1, 1)]))
    assert read_image(full).shape == (8, 16, 1)  # the writer above makes files OpenEXR reads
    sub = _write(tmp_path / "sub.exr", _exr(16, 8, [("Y", 2, 2)]))  # was read as an 8 × 4 image of a 16 × 8 file
    with pytest.raises(
        ImageFormatError, match=r"must hold full-resolution channels, got \(x, y\) sampling \{'Y': \(2, 2\)\}"
    ):
        read_image(sub)


def test_radiance_headers_that_python_cannot_print_or_parse(tmp_path):
    bad = _write(tmp_path / "a.hdr", b"#?RADIANCE\nFORMAT=\xff\xfe\n\n-Y 1 +X 1\n\0\0\0\0")
    with pytest.raises(ImageFormatError, match=r"must be FORMAT=32-bit_rle_rgbe, got 'FORMAT=\\\\xff\\\\xfe'"):
        read_image(bad)  # a UnicodeDecodeError while building the message before
    digits = _write(tmp_path / "b.hdr", b"#?RADIANCE\n\n-Y " + b"9" * 5000 + b" +X 1\n")
    with pytest.raises(ImageFormatError, match=r"must have the resolution line '-Y H \+X W'"):
        read_image(digits)  # Python's int() refuses 5,000 digits: a ValueError before


def test_npy_files_are_checked_before_they_are_built(tmp_path):
    from facestats.io.mesh import read_region_image

    np.save(tmp_path / "ok.npy", np.full((4, 4), 3, np.uint8))
    assert read_region_image(tmp_path / "ok.npy").tolist() == [[3] * 4] * 4
    header = {"descr": "|u1", "fortran_order": False, "shape": (10**8, 10**8)}
    big = tmp_path / "big.npy"
    with open(big, "wb") as f:
        np.lib.format.write_array_header_1_0(f, header)
    with pytest.raises(FormatError, match=r"big\.npy is truncated: its header declares shape \(100000000, 100000000\)"):
        read_npy(big, "region image")
    np.save(tmp_path / "s.npy", np.array([["a"]]))
    np.savez(tmp_path / "z.npz", a=np.zeros(2))
    os.replace(tmp_path / "z.npz", tmp_path / "z.npy")
    _write(tmp_path / "e.npy", b"")
    np.save(tmp_path / "empty.npy", np.zeros((0, 0), np.uint8))
    np.save(tmp_path / "planes.npy", np.zeros((4, 4, 0), np.uint8))
    cases = {
        "s.npy": r"must hold a numeric \.npy array, got dtype <U1",
        "z.npy": r"as a \.npy array: the magic string is not correct",
        "e.npy": r"as a \.npy array: EOF",
        "empty.npy": r"must hold integer labels 0-10, got dtype uint8 and shape \(0, 0\)",
        "planes.npy": r"must hold integer labels 0-10, got dtype uint8 and shape \(4, 4, 0\)",
    }
    for name, match in cases.items():
        with pytest.raises(FormatError, match=match):
            read_region_image(tmp_path / name)


def test_ground_truth_normals_must_be_unit_or_zero(tmp_path):
    from facestats.relight.olat import read_ground_truth_normals

    n = np.zeros((4, 4, 3), np.float32)
    n[1:3, 1:3] = (0, 0, 1)  # unit on the object, zero off it (DiLiGenT)
    scipy.io.savemat(tmp_path / "Normal_gt.mat", {"Normal_gt": n})  # DiLiGenT's file, read in a child process
    np.testing.assert_array_equal(read_ground_truth_normals(tmp_path, (4, 4)), n)
    os.remove(tmp_path / "Normal_gt.mat")
    np.save(tmp_path / "normals.npy", n)
    assert read_ground_truth_normals(tmp_path, (4, 4)).shape == (4, 4, 3)
    for value, match in ((np.nan, r"got \[nan, 0.0, 1.0\] \(length nan\) at pixel \(2, 2\)"), (3.0, r"length 3.16")):
        n[2, 2] = (value, 0, 1)  # were accepted, and angular errors against them meant nothing
        np.save(tmp_path / "normals.npy", n)
        with pytest.raises(ValidationError, match=match):
            read_ground_truth_normals(tmp_path, (4, 4))


def test_float_tiff_displacement_maps_planar_corrupt_and_huge(tmp_path):
    import tifffile

    from facestats.io.displacement import read_displacement

    h = np.arange(64, dtype=np.float32).reshape(8, 8)
    tifffile.imwrite(tmp_path / "planar.tif", np.stack([h, h, h]), planarconfig="separate", photometric="rgb")
    np.testing.assert_array_equal(read_displacement(tmp_path / "planar.tif"), h)  # "got 8 channels" before
    data = bytearray((tmp_path / "planar.tif").read_bytes())
    _write(tmp_path / "cut.tif", bytes(data[:20]))
    with pytest.raises(FormatError, match=r"cut\.tif' is not a readable TIFF file"):
        read_displacement(tmp_path / "cut.tif")  # blamed a missing height_range_um, or a raw tifffile error
    tifffile.imwrite(tmp_path / "big.tif", np.zeros((8, 8), np.float32))
    with tifffile.TiffFile(tmp_path / "big.tif") as tif:
        tags = tif.pages.first.tags
        spots = [(tags[n].valueoffset, "<H" if tags[n].dtype == 3 else "<I") for n in ("ImageWidth", "ImageLength")]
    big = bytearray((tmp_path / "big.tif").read_bytes())
    for at, code in spots:  # the header now says 30000 x 30000 (TIFF type 3 SHORT or 4 LONG)
        big[at : at + struct.calcsize(code)] = struct.pack(code, 30000)
    _write(tmp_path / "bomb.tif", bytes(big))
    with pytest.raises(ImageFormatError, match=r"declares 30000 x 30000 pixels"):  # 3.6 GB asked for before
        read_displacement(tmp_path / "bomb.tif")


# -- EXIF, CSV, MATLAB and JSON -----------------------------------------------------------------------------
def test_a_negative_exif_pointer_is_refused():
    from facestats.io.exif import parse_exif

    tail = struct.pack("<H", 1) + struct.pack("<HHII", 0x829A, 4, 1, 30) + struct.pack("<I", 0)  # ExposureTime
    ifd0 = struct.pack("<H", 1) + struct.pack("<HHI", 0x8769, 9, 1) + struct.pack("<i", -len(tail)) + b"\0" * 4
    with pytest.raises(FormatError, match=r"TIFF IFD offset must be >= 0, got -18"):  # read from the end before
        parse_exif(b"II*\0" + struct.pack("<I", 8) + ifd0 + tail)


def test_weights_rows_longer_than_the_header_and_repeated_names(tmp_path):
    from facestats.io.mesh_sequence import read_weights

    with pytest.raises(FormatError, match=r"cannot read the weights .*Length of header or names does not match"):
        read_weights(_write(tmp_path / "a.csv", "jawOpen,mouthSmile_L\n0.1,0.2,0.3\n"))  # values shifted before
    with pytest.raises(FormatError, match=r"must name each target once, got \['jawOpen'\] more than once"):
        read_weights(_write(tmp_path / "b.csv", "jawOpen, jawOpen \n0.1,0.2\n"))
    names, w = read_weights(_write(tmp_path / "c.csv", "frame,jawOpen\n0,0.25\n1,0.5\n"))
    assert names == ["jawOpen"] and w[:, 0].tolist() == [0.25, 0.5]


def test_merl_cells_must_hold_one_number(tmp_path):
    from facestats.io.merl import read_merl

    d = merl_dict()
    cells = np.empty((len(d["ts_subjec"]), 1), dtype=object)
    cells[:, 0] = [np.array([[v]]) for v in d["ts_subjec"][:, 0]]
    d["ts_subjec"] = cells
    assert len(read_merl(save_mat(tmp_path, d)).datasets) == 4  # one number per cell: read as before
    cells[0, 0] = np.array([[1.0, 2.0]])
    scipy.io.savemat(tmp_path / "two.mat", d)
    with pytest.raises(FormatError, match=r"ts_subjec must hold one number per cell, got a cell of shape \(1, 2\)"):
        read_merl(tmp_path / "two.mat")  # its first number alone was read


def test_json_nesting_and_integers_beyond_float64(tmp_path):
    from facestats.acquire.bracket import read_response
    from facestats.core.validate import json_numbers

    _write(tmp_path / "r.json", "[" * 100_000 + "]" * 100_000)
    with pytest.raises(FormatError, match=r"cannot read the response file .*maximum recursion depth"):
        read_response(tmp_path / "r.json")
    with pytest.raises(ValidationError, match=r"intensity must be finite, got 1000000"):
        json_numbers(json.loads("1" + "0" * 400), "intensity")  # an OverflowError before


def test_a_capture_manifest_cannot_ask_for_a_billion_cameras(tmp_path):
    from facestats.acquire.photographs import FORMAT, MANIFEST, open_folder

    doc = {"format": FORMAT, "bits": 8, "n_cameras": 10**9, "n_leds": 1, "frames": []}
    _write(tmp_path / MANIFEST, json.dumps(doc))
    with pytest.raises(FormatError, match=r"field 'n_cameras' must be at most 1024, got 1000000000"):
        open_folder(tmp_path)  # a MemoryError after building range(10**9) before


def test_a_matlab_reader_that_crashes_is_a_named_error(tmp_path, monkeypatch):
    """Some damaged MATLAB files make SciPy's loadmat crash the interpreter (SIGSEGV); it runs in a child now."""
    import facestats.io.matlab as matlab
    from facestats.io.merl import read_merl

    path = save_mat(tmp_path, merl_dict())
    assert len(read_merl(path).datasets) == 4  # the child reads a valid file
    monkeypatch.setattr(matlab, "_CHILD", "import os, signal; os.kill(os.getpid(), signal.SIGSEGV)")
    with pytest.raises(FormatError, match=r"not a readable MATLAB file \(SciPy's loadmat ended with signal 11"):
        read_merl(path)
