"""CRC-32 of a concatenation from the CRC-32s of its parts (:func:`crc32_combine`).

The store's manifest records the CRC-32 (:func:`zlib.crc32`, the reflected
polynomial 0xEDB88320 of ISO-HDLC / zip) of each variable's bytes in C order.
A variable streamed band by band along ``v`` (a map with a ``camera`` dim in
front of ``v``) does not arrive in that order; its CRC is assembled here from
one running CRC per camera instead of holding the whole variable.

The CRC register is linear over GF(2): appending ``n`` zero bytes to a message
maps its raw register by a fixed 32 × 32 bit matrix Z(n), and for messages A,
B (``len(B) = n``) the conditioned CRC obeys

    crc(A ‖ B) = Z(n) · crc(A)  ⊕  crc(B)

(the pre- and post-inversion of zlib's CRC cancel between the two terms; the
identity zlib's own ``crc32_combine`` rests on, M. Adler, zlib 1.2).  Z(1) is
eight applications of the one-bit step r ↦ (r >> 1) ⊕ (0xEDB88320 if r is odd),
and Z(n) is built by squaring, one square per bit of ``n``.  Checked against
:func:`zlib.crc32` of the concatenation in ``tests/test_crc32.py``.
"""

from __future__ import annotations

import functools

__all__ = ["crc32_combine"]

#: The reflected CRC-32 polynomial of zlib.
POLYNOMIAL = 0xEDB88320


def _times(matrix: tuple, vector: int) -> int:
    """GF(2) product of a 32 × 32 bit matrix (a tuple of its 32 columns) and a 32-bit vector."""
    out, k = 0, 0
    while vector:
        if vector & 1:
            out ^= matrix[k]
        vector >>= 1
        k += 1
    return out


def _product(a: tuple, b: tuple) -> tuple:
    """GF(2) product a · b of two 32 × 32 bit matrices (tuples of columns)."""
    return tuple(_times(a, column) for column in b)


@functools.lru_cache(maxsize=64)
def _zero_bytes(n: int) -> tuple:
    """Z(n): the matrix that appends ``n`` zero bytes to a raw CRC-32 register (module docstring)."""
    bit = (POLYNOMIAL,) + tuple(1 << k for k in range(31))  # one zero bit: column k is the step applied to 1 << k
    square = _product(_product(bit, bit), _product(bit, bit))
    power = _product(square, square)  # eight zero bits: one byte
    out = tuple(1 << k for k in range(32))  # identity
    while n:
        if n & 1:
            out = _product(power, out)
        n >>= 1
        if n:
            power = _product(power, power)
    return out


def crc32_combine(crc1: int, crc2: int, length2: int) -> int:
    """CRC-32 of ``A ‖ B`` from ``crc1`` = crc32(A), ``crc2`` = crc32(B) and ``length2`` = len(B) in bytes.

    Parameters
    ----------
    crc1, crc2 : int
        :func:`zlib.crc32` values (unsigned, < 2³²).
    length2 : int
        Bytes of the second part (≥ 0).

    Returns
    -------
    int
        ``zlib.crc32(A + B)`` (module docstring: the identity and its source).
    """
    if length2 < 0:
        raise ValueError(f"length2 must be >= 0, got {length2}")
    if not crc1:  # Z(n) · 0 = 0: no matrix to build (the first of parts joined in turn)
        return int(crc2)
    return _times(_zero_bytes(int(length2)), int(crc1)) ^ int(crc2)
