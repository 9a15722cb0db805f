"""Huffman-only deflate: any inflater reads the rows back exactly; codes are complete, canonical, length-limited."""

import zlib

import numpy as np
import pytest

from facestats.errors import ValidationError
from facestats.io.deflate import MAX_CODE_BITS, canonical_codes, deflate_rows, huffman_code_lengths, prefixed_rows


def _kraft(lengths):
    used = lengths[lengths > 0]
    return float(np.sum(2.0 ** -used.astype(float)))


def test_canonical_codes_match_rfc1951_example():
    # RFC 1951 §3.2.2: lengths (3, 3, 3, 3, 3, 2, 4, 4) for A-H give 010 011 100 101 110 00 1110 1111
    want = ["010", "011", "100", "101", "110", "00", "1110", "1111"]
    lengths = np.array([3, 3, 3, 3, 3, 2, 4, 4])
    got = canonical_codes(lengths)
    for code, n, w in zip(got, lengths, want):
        assert format(int(code), f"0{n}b")[::-1] == w  # returned bits are reversed for LSB-first packing


def test_huffman_lengths_are_optimal_when_unconstrained():
    counts = np.array([45, 13, 12, 16, 9, 5])  # the textbook example (CLRS §16.3): lengths 1, 3, 3, 3, 4, 4
    np.testing.assert_array_equal(huffman_code_lengths(counts), [1, 3, 3, 3, 4, 4])
    rng = np.random.default_rng(1)
    counts = rng.integers(1, 10_000, 200)
    lengths = huffman_code_lengths(counts)
    p = counts / counts.sum()
    entropy = -np.sum(p * np.log2(p))
    assert _kraft(lengths) == 1.0  # complete
    assert entropy <= np.sum(p * lengths) < entropy + 1  # Shannon's bounds for an optimal prefix code


def test_huffman_lengths_respect_the_limit():
    counts = 2 ** np.arange(30)[::-1]  # geometric: the unconstrained code would be 29 bits deep
    assert huffman_code_lengths(counts, limit=60).max() == 29
    lengths = huffman_code_lengths(counts)
    assert lengths.max() == MAX_CODE_BITS
    assert _kraft(lengths) == 1.0
    assert np.all(np.diff(lengths) >= 0)  # rarer symbols never get shorter codes
    single = huffman_code_lengths([0, 0, 7, 0])
    np.testing.assert_array_equal(single, [0, 0, 1, 0])


@pytest.mark.parametrize("backend", ["numba", "numpy"])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("kind", ["uniform", "geometric", "constant", "one-row", "one-column", "read-noise"])
def test_zlib_inflates_the_exact_rows(dtype, kind, backend, rng):
    top = np.iinfo(dtype).max + 1
    shape = {"one-row": (1, 301), "one-column": (257, 1)}.get(kind, (61, 93))
    if kind == "geometric":  # byte values with probabilities 2^-k: forces the 15-bit limit
        a = np.minimum(rng.geometric(0.5, shape) - 1, top - 1).astype(dtype)
    elif kind == "constant":
        a = np.full(shape, top - 1, dtype)
    elif kind == "read-noise":  # a dark 12-bit frame: codes near 0, a lit patch
        a = np.clip(np.rint(rng.normal(4, 3, shape)), 0, 4095).astype(dtype)
        a[20:40, 30:60] = rng.integers(0, min(top, 4096), (20, 30))
    else:
        a = rng.integers(0, top, shape, dtype=dtype)
    for prefix in (0, 4):
        data = deflate_rows(a, prefix=prefix, backend=backend)
        assert zlib.decompress(data) == prefixed_rows(a, prefix).tobytes()
        assert data[:2] == b"\x78\x01" and int.from_bytes(data[:2], "big") % 31 == 0  # RFC 1950 header check


def test_compiled_and_numpy_give_the_same_bytes(rng):
    a = np.clip(np.rint(rng.normal(6, 4, (128, 3 * 160))), 0, 4095).astype(np.uint16)
    a[::7] = rng.integers(0, 4096, a[::7].shape)
    assert deflate_rows(a, backend="numba") == deflate_rows(a, backend="numpy")


def test_the_stream_holds_exactly_the_coded_bits(rng):
    # header (3 + 5 + 5 + 4 + 19·3 + 258·4 bits) + Σ count·length, padded to a byte, + 2 + 4 container bytes
    a = np.clip(np.rint(rng.normal(3, 2, (50, 70))), 0, 255).astype(np.uint8)
    counts = np.bincount(a.ravel(), minlength=257)
    counts[0] += 50
    counts[256] = 1
    lengths = huffman_code_lengths(counts)
    bits = 3 + 5 + 5 + 4 + 19 * 3 + 258 * 4 + int(np.sum(counts * lengths))
    assert len(deflate_rows(a)) == 2 + (bits + 7) // 8 + 4


def test_noisy_frames_compress_to_their_byte_entropy(rng):
    a = np.clip(np.rint(rng.normal(8, 5, (256, 768))), 0, 4095).astype(np.uint16)
    rows = prefixed_rows(a).ravel()
    p = np.bincount(rows, minlength=256) / rows.size
    p = p[p > 0]
    entropy_bytes = rows.size * -np.sum(p * np.log2(p)) / 8
    assert entropy_bytes <= len(deflate_rows(a)) < 1.01 * entropy_bytes + 700


@pytest.mark.parametrize(
    "samples, kw, match",
    [
        (np.zeros((4, 4), np.float32), {}, "samples must be a 2-D uint8 or uint16 array, got float32"),
        (np.zeros((4, 4, 3), np.uint16), {}, r"got uint16 of shape \(4, 4, 3\)"),
        (np.zeros((3, 0), np.uint8), {}, r"samples must hold at least one sample, got shape \(3, 0\)"),
        (np.zeros((4, 4), np.uint8), {"prefix": 256}, r"prefix must be a byte value in \[0, 255\], got 256"),
        (np.zeros((4, 4), np.uint8), {"backend": "gpu"}, "backend"),
    ],
)
def test_bad_input_names_the_field(samples, kw, match):
    with pytest.raises(ValidationError, match=match):
        deflate_rows(samples, **kw)


def test_bad_counts():
    with pytest.raises(ValidationError, match="counts must be a 1-D array of non-negative integers"):
        huffman_code_lengths([0, 0])
    with pytest.raises(ValidationError, match="300 symbols cannot have codes of at most 8 bits"):
        huffman_code_lengths(np.ones(300), limit=8)


def test_a_code_from_sampled_rows_costs_almost_nothing(rng):
    # a dark frame with a lit, graded patch in some rows only: the sampled code must still fit the whole
    a = np.clip(np.rint(rng.normal(5, 3, (512, 3 * 256))), 0, 4095).astype(np.uint16)
    a[100:300, 200:500] = np.clip(np.rint(rng.normal(np.linspace(200, 3000, 300), 40)), 0, 4095)
    sampled, exact = deflate_rows(a, sample_rows=64), deflate_rows(a, sample_rows=512)
    assert zlib.decompress(sampled) == prefixed_rows(a).tobytes()
    assert len(exact) <= len(sampled) <= 1.002 * len(exact)
