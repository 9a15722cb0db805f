"""Huffman-only deflate of image rows: one dynamic-Huffman block, no string matching.

The emulated dome writes 4,800 16-bit PNG frames a session, mostly read noise: string matching
(LZ77) finds almost nothing to match in them, and what compresses is the skew of the byte values
(high bytes nearly always 0; low bytes of dark pixels a few values).  A Huffman code over the
bytes captures exactly that.  libdeflate at level 1 spends 27-33 ms a 1024² × 3 frame searching
for matches; this encoder builds the code from the byte histogram of 64 of the frame's rows and
packs it in about 11 ms (compiled), into files about 5 % smaller (``benchmarks/bench_devices.py``).

Format (RFC 1950 zlib container around RFC 1951 deflate):

* zlib header ``78 01`` (deflate, 32 KiB window, no dictionary, fastest-compression flag), the
  deflate stream, then the Adler-32 of the uncompressed data, big-endian (RFC 1950 §2.2).
* One final block (BFINAL = 1) of dynamic Huffman codes (BTYPE = 2, RFC 1951 §3.2.7):
  HLIT = 257 literal/length codes (the 256 byte values and end-of-block: no lengths are used),
  HDIST = 1 distance code (never used; one code of length 1, which RFC 1951 §3.2.7 allows),
  HCLEN = 19 code-length codes, of which the 16 lengths 0-15 get 4-bit codes (a complete code)
  and the run-length symbols 16-18 none.  Each literal's code length is then written as its
  4-bit code-length code.
* Huffman codes are packed most-significant bit first into a stream filled from the
  least-significant bit of each byte (RFC 1951 §3.1.1); header fields least-significant bit first.
  :func:`canonical_codes` therefore returns codes with their bits reversed, ready to be OR-ed into
  a little-endian bit accumulator.

The data are the rows of an image each preceded by one prefix byte (PNG's filter-type byte,
ISO/IEC 15948 §9), 16-bit samples big-endian: a 16-bit sample v is the two literals v >> 8 then
v & 255, whose codes are joined in one table entry of at most 30 bits indexed by v.
Any inflater reads the result (tested against zlib and OpenCV); the compiled and numpy packers
give the same bytes (tested).
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from facestats.core.compiled import resolve_backend
from facestats.core.validate import check_integer
from facestats.errors import ValidationError

__all__ = ["MAX_CODE_BITS", "huffman_code_lengths", "canonical_codes", "prefixed_rows", "deflate_rows"]

#: Longest Huffman code deflate allows for literals (RFC 1951 §3.2.7).
MAX_CODE_BITS = 15

#: End-of-block literal/length symbol (RFC 1951 §3.2.5).
_END_OF_BLOCK = 256

#: The order in which the code-length code lengths are written (RFC 1951 §3.2.7).
_CODE_LENGTH_ORDER = (16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15)


def huffman_code_lengths(counts, limit: int = MAX_CODE_BITS) -> np.ndarray:
    """Code length of every symbol of a Huffman code for ``counts``, no code longer than ``limit``.

    Huffman's construction by two queues (van Leeuwen 1976): the symbols sorted by count (ties by
    symbol), merged in order with the subtrees made so far, a leaf taken first on equal counts
    (which keeps the deepest leaf shallowest among optimal codes); the result is deterministic.
    Where the longest code exceeds ``limit``, the counts are halved (kept ≥ 1) and the code rebuilt
    until it fits: the code stays complete and prefix-free, slightly longer on average than the
    optimal length-limited code (package-merge), which matters only for the rare symbols that forced it.

    Parameters
    ----------
    counts : array_like of int, shape (n,)
        Occurrences of each symbol; 0: the symbol gets no code (length 0).
    limit : int
        Longest code allowed, bits.

    Returns
    -------
    ndarray of int64, shape (n,)
        A single used symbol gets length 1 (deflate needs at least one bit per code).
    """
    counts = np.asarray(counts, np.int64).copy()
    if counts.ndim != 1 or np.any(counts < 0) or not np.any(counts > 0):
        raise ValidationError("counts must be a 1-D array of non-negative integers with at least one above 0")
    used = np.flatnonzero(counts)
    if used.size > 2**limit:
        raise ValidationError(f"{used.size} symbols cannot have codes of at most {limit} bits")
    lengths = np.zeros(counts.size, np.int64)
    if used.size == 1:
        lengths[used] = 1
        return lengths
    while True:
        lengths[used] = _huffman_depths(counts, used)
        if lengths.max() <= limit:
            return lengths
        counts[used] = np.maximum(counts[used] >> 1, 1)


def _huffman_depths(counts, used) -> list:
    """Depth of each symbol of ``used`` (≥ 2 symbols) in Huffman's tree by two queues (see above)."""
    order = np.argsort(counts[used], kind="stable")  # ascending count, ties by symbol
    leaf_weight = counts[used][order].tolist()
    n = len(leaf_weight)
    node_weight = []
    leaf_parent, node_parent = [0] * n, [0] * (n - 1)
    i = j = 0  # next leaf, next internal node
    for k in range(n - 1):
        total = 0
        for _ in range(2):
            if i < n and (j >= k or leaf_weight[i] <= node_weight[j]):
                leaf_parent[i] = k
                total += leaf_weight[i]
                i += 1
            else:
                node_parent[j] = k
                total += node_weight[j]
                j += 1
        node_weight.append(total)
    depth = [0] * (n - 1)  # the root is the last node; parents come after their children
    for k in range(n - 3, -1, -1):
        depth[k] = depth[node_parent[k]] + 1
    out = [0] * n
    for rank, symbol_index in enumerate(order.tolist()):
        out[symbol_index] = depth[leaf_parent[rank]] + 1
    return out


def canonical_codes(lengths) -> np.ndarray:
    """The canonical Huffman code of every symbol (RFC 1951 §3.2.2), bits reversed for LSB-first packing.

    Codes of equal length are consecutive in symbol order, shorter codes numerically first.  The
    i-th code in that order is the Kraft sum of the codes before it at its own length,
    Σ_{j<i} 2^(L_i − L_j) (each shorter or equal code takes that share of the L_i-bit codes), which is
    RFC 1951's construction in closed form.  The returned value of a symbol of length L is its L-bit
    code read backwards, so that OR-ing it at the current bit position of a little-endian accumulator
    sends the code's most significant bit first, as deflate requires.  Symbols of length 0 get 0.

    Parameters
    ----------
    lengths : array_like of int, shape (n,)
        Code length of every symbol in bits (0: no code), e.g. from :func:`huffman_code_lengths`; not checked
        (lengths obeying Kraft's inequality, Σ 2^−L ≤ 1, are assumed).

    Returns
    -------
    ndarray of int64, shape (n,)
        Each symbol's code, its ``lengths[i]`` bits reversed; 0 where the length is 0.
    """
    lengths = np.asarray(lengths, np.int64)
    top = int(lengths.max())
    used = np.flatnonzero(lengths)
    order = used[np.argsort(lengths[used], kind="stable")]  # by length, then by symbol
    share = np.int64(1) << (top - lengths[order])  # each code's share of the top-length codes
    kraft_before = np.cumsum(share) - share
    codes = np.zeros(lengths.size, np.int64)
    codes[order] = kraft_before >> (top - lengths[order])
    out = np.zeros(lengths.size, np.int64)
    for bit in range(top):  # reverse the low `length` bits of each code
        has = lengths > bit
        out[has] |= ((codes[has] >> bit) & 1) << (lengths[has] - 1 - bit)
    return out


#: Code lengths of the code-length alphabet (symbols 0-18): 0-15 get 4 bits each, 16-18 none.
_CL_LENGTHS = np.r_[np.full(16, 4), 0, 0, 0]
_CL_CODES = canonical_codes(_CL_LENGTHS)

#: The fixed head of the block header: BFINAL 1, BTYPE 2, HLIT 257 − 257, HDIST 1 − 1, HCLEN 19 − 4, then
#: the 19 code-length code lengths (3 bits each, in RFC 1951's order); as (value, width) pairs.
_HEADER_HEAD = [(1, 1), (2, 2), (0, 5), (0, 5), (15, 4)] + [(int(_CL_LENGTHS[s]), 3) for s in _CODE_LENGTH_ORDER]


def _block_header(lengths) -> tuple[bytes, int, int]:
    """The block header bits (module docstring) as whole bytes plus the leftover (value, bit count).

    Fields are written least-significant bit first; the 257 literal/length code lengths and the one
    distance code length (1) follow the fixed head as 4-bit code-length codes.
    """
    values = np.array([v for v, _ in _HEADER_HEAD] + _CL_CODES[np.r_[lengths, 1]].tolist(), np.int64)
    widths = np.array([w for _, w in _HEADER_HEAD] + [4] * (len(lengths) + 1), np.int64)
    bits = ((values[:, None] >> np.arange(5)) & 1)[np.arange(5) < widths[:, None]]  # LSB first, field by field
    whole = bits.size // 8
    head = np.packbits(bits[: 8 * whole], bitorder="little").tobytes()
    rest = bits[8 * whole :]
    return head, int(np.sum(rest << np.arange(rest.size))), int(rest.size)


def _byte_counts(samples, prefix, sample_rows, backend):
    """Occurrences of the 257 literal/length symbols in the rows (module docstring), from every k-th row.

    With k > 1 (more than ``sample_rows`` rows) the counts are those of rows 0, k, 2k, ... scaled to
    all rows, plus one for every byte value, so that a byte the sample missed still has a code.
    """
    h = samples.shape[0]
    step = max(1, -(-h // sample_rows))
    part = samples[::step]
    if backend == "numba":
        from facestats.io.deflate_numba import sample_histogram

        by_sample = np.zeros(np.iinfo(samples.dtype).max + 1, np.int64)
        sample_histogram(part, by_sample)
    else:
        by_sample = np.bincount(part.ravel(), minlength=np.iinfo(samples.dtype).max + 1)
    counts = np.zeros(257, np.int64)
    if samples.dtype == np.uint16:
        grid = by_sample.reshape(256, 256)  # [high byte, low byte]
        counts[:256] = grid.sum(axis=1) + grid.sum(axis=0)
    else:
        counts[:256] = by_sample
    if step > 1:
        counts[:256] = counts[:256] * step + 1
    counts[int(prefix)] += h
    counts[_END_OF_BLOCK] = 1
    return counts


def _pack_numpy(samples, code, length, prefix_code, prefix_length, tail, start, start_bits):
    """The numpy twin of :func:`facestats.io.deflate_numba.pack_rows`: the same bytes.

    Every code gets its bit offset from a cumulative sum; codes never share bits, so a word's bits
    are the sum of the parts landing in it, computed exactly in float64 by ``numpy.bincount``
    (32-bit words, each code part below 2³²).
    """
    h, n = samples.shape
    c = np.empty((h, n + 1), np.uint64)
    b = np.empty((h, n + 1), np.int64)
    c[:, 0], b[:, 0] = prefix_code, prefix_length
    c[:, 1:], b[:, 1:] = code[samples], length[samples]
    c = np.r_[np.uint64(start), c.ravel(), np.uint64(tail[0])]
    b = np.r_[start_bits, b.ravel(), tail[1]]
    end = np.cumsum(b)
    offset = end - b
    word, shift = offset >> 5, (offset & 31).astype(np.uint64)
    part = c << shift
    words = int(end[-1] + 31) // 32 + 1
    low = np.bincount(word, (part & np.uint64(0xFFFFFFFF)).astype(np.float64), words)
    high = np.bincount(word + 1, (part >> np.uint64(32)).astype(np.float64), words)
    return (low + high).astype("<u4").view(np.uint8)[: (int(end[-1]) + 7) // 8].tobytes()


def prefixed_rows(samples, prefix: int = 0) -> np.ndarray:
    """The bytes :func:`deflate_rows` compresses: each row ``prefix`` then its samples, 16-bit samples big-endian
    (PNG's filtered scanlines with filter type ``prefix``).

    Parameters
    ----------
    samples : array_like, shape (H, N)
        The rows' samples (uint8 or uint16 for :func:`deflate_rows`; not checked here).
    prefix : int
        The byte before every row (PNG's filter type; 0 = None).

    Returns
    -------
    ndarray of uint8, shape (H, 1 + N·itemsize)
    """
    a = np.asarray(samples)
    h = a.shape[0]
    rows = np.empty((h, 1 + a[0].size * a.itemsize), np.uint8)
    rows[:, 0] = prefix
    rows[:, 1:] = a.astype(a.dtype.newbyteorder(">"), copy=False).reshape(h, -1).view(np.uint8)
    return rows


def deflate_rows(samples, *, prefix: int = 0, sample_rows: int = 64, backend: str = "auto") -> bytes:
    """A zlib stream of the rows of ``samples``, each preceded by the byte ``prefix`` (module docstring).

    Parameters
    ----------
    samples : ndarray, shape (H, N), uint8 or uint16
        The rows' samples; 16-bit samples are written big-endian (PNG's byte order).
    prefix : int
        The byte before every row (PNG: the filter type; 0 = None).
    sample_rows : int
        The Huffman code is built from the byte counts of about this many evenly spaced rows (all rows
        of a smaller image): a 1024-row frame's code from 64 rows compresses within 0.1 % of the code
        from all of them, in a twentieth of the time.
    backend : {"auto", "numba", "numpy"}
        Histogram and bit packing compiled (:mod:`facestats.io.deflate_numba`) or with numpy: the same bytes.

    Returns
    -------
    bytes
        ``zlib.decompress`` of it gives the H rows of ``1 + N·itemsize`` bytes.
    """
    a = np.asarray(samples)
    if a.dtype not in (np.uint8, np.uint16) or a.ndim != 2:
        raise ValidationError(f"samples must be a 2-D uint8 or uint16 array, got {a.dtype} of shape {a.shape}")
    if a.size == 0:
        raise ValidationError(f"samples must hold at least one sample, got shape {a.shape}")
    if not 0 <= int(prefix) <= 255:
        raise ValidationError(f"prefix must be a byte value in [0, 255], got {prefix}")
    check_integer(sample_rows, "sample_rows", 1)
    backend = resolve_backend(backend)
    a = np.ascontiguousarray(a)
    h, n = a.shape
    counts = _byte_counts(a, prefix, int(sample_rows), backend)
    lengths = huffman_code_lengths(counts)
    codes = canonical_codes(lengths)
    v = np.arange(int(a.max()) + 1)  # table entries for the values present (a 12-bit frame: 4,096)
    if a.dtype == np.uint16:  # high byte first, then the low byte: one entry of at most 30 bits
        hi, lo = v >> 8, v & 255
        table_code = (codes[hi] | (codes[lo] << lengths[hi])).astype(np.uint64)
        table_length = lengths[hi] + lengths[lo]
    else:
        table_code, table_length = codes.astype(np.uint64)[v], lengths[v]
    head, start, start_bits = _block_header(lengths)
    p, tail = int(prefix), (int(codes[_END_OF_BLOCK]), int(lengths[_END_OF_BLOCK]))
    if backend == "numba":
        from facestats.io.deflate_numba import pack_rows

        out = np.empty(h * (n + 1) * 4 + 16, np.uint8)  # at most 30 bits per sample, 15 per prefix
        used, adler = pack_rows(a, table_code, table_length, p, codes[p], lengths[p], *tail, start, start_bits, out)
        body = out[:used].tobytes()
    else:
        body = _pack_numpy(a, table_code, table_length, codes[p], lengths[p], tail, start, start_bits)
        adler = zlib.adler32(prefixed_rows(a, p)) & 0xFFFFFFFF
    return b"\x78\x01" + head + body + struct.pack(">I", adler)
