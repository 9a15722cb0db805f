"""facestats.core.crc32: the CRC-32 of a concatenation from its parts, against zlib."""

import zlib

import numpy as np
import pytest

from facestats.core.crc32 import crc32_combine


@pytest.mark.parametrize("la, lb", [(0, 0), (0, 1), (1, 0), (1, 1), (7, 13), (1000, 4096), (3, 65537)])
def test_combine_equals_the_crc_of_the_concatenation(la, lb):
    rng = np.random.default_rng(la * 100003 + lb)
    a, b = rng.bytes(la), rng.bytes(lb)
    assert crc32_combine(zlib.crc32(a), zlib.crc32(b), lb) == zlib.crc32(a + b)


def test_combining_many_parts_in_order_and_long_zero_runs():
    rng = np.random.default_rng(0)
    parts = [rng.bytes(int(n)) for n in rng.integers(0, 3000, 40)]
    crc = 0  # the CRC of no bytes
    for p in parts:
        crc = crc32_combine(crc, zlib.crc32(p), len(p))
    assert crc == zlib.crc32(b"".join(parts))
    zeros = bytes(5_000_000)  # a length with many bits set in binary is the squaring's worst case
    assert crc32_combine(zlib.crc32(b"x"), zlib.crc32(zeros), len(zeros)) == zlib.crc32(b"x" + zeros)
    assert crc32_combine(0x12345678, zlib.crc32(b"abc"), 3) != crc32_combine(0x12345679, zlib.crc32(b"abc"), 3)


def test_negative_length_is_refused():
    with pytest.raises(ValueError, match="length2 must be >= 0, got -1"):
        crc32_combine(0, 0, -1)
