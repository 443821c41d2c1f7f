"""CRC-32 (zlib's, as MCAP defines it): `crc32`, the fastest implementation installed, and the CRC of
a concatenation from the CRCs of its parts, `combine`.

`crc32` is ISA-L's (the `isal` package: carry-less multiplication, about 9.5 GB/s here against
zlib's 2.0 GB/s, the same function and values) when it can be imported, else zlib's. Every CRC the
recorder writes or checks goes through it (docs/recording_costs.md, "CRCs").

The MCAP writer checksums every record twice: into its chunk's CRC (the records, uncompressed)
and into the data section's (every byte of the file's data section). With chunks stored
uncompressed the data section's CRC over a chunk's records is `combine`d from the chunk's CRC and
their length instead of being computed again over the same bytes (docs/recording.md, "CRCs").

The math (CRC-32 is reflected, polynomial P = 0xEDB88320 with x^0 as the top bit): for byte
strings A and B, crc(A + B) = crc(A) * x^(8 |B|) mod P xor crc(B), where the pre- and
post-conditioning of zlib's CRC cancel between the two terms. x^(8 |B|) mod P is a product of
powers of x from a table built at import (x^(8 d 16^i) for each hexadecimal digit d at each place
i). Cost: one multiplication mod P (at most 32 shifts) per nonzero hexadecimal digit of the
length, at most 8: 11-37 us here, against zlib.crc32's 21 us for 64 KiB and 460 us for 1 MiB
(COMBINE_FROM: below it, checksumming the bytes again is cheaper).
"""

from __future__ import annotations

import zlib
from typing import Any, Protocol


class Crc32(Protocol):
    def __call__(self, data: Any, value: int = 0, /) -> int: ...


try:
    from isal import isal_zlib  # type: ignore[import-untyped,unused-ignore]

    crc32: Crc32 = isal_zlib.crc32
    CRC_IMPLEMENTATION = "isal"
except ImportError:  # pragma: no cover - isal is a dependency; zlib gives the same values
    crc32 = zlib.crc32
    CRC_IMPLEMENTATION = "zlib"
# Below this many bytes checksumming them again is cheaper than `combine` (11-37 us): 64 KiB
# with zlib (21 us), 256 KiB with ISA-L (about 28 us).
COMBINE_FROM = 1 << 18 if CRC_IMPLEMENTATION == "isal" else 1 << 16  # bytes
_POLY = 0xEDB88320
_ONE = 1 << 31  # x^0, reflected


def _mul(a: int, b: int) -> int:
    """a * b mod P, both reflected 32-bit polynomials."""
    m = _ONE
    p = 0
    while True:
        if a & m:
            p ^= b
            if a & (m - 1) == 0:
                return p
        m >>= 1
        if m == 0:
            return p
        b = (b >> 1) ^ _POLY if b & 1 else b >> 1


def _digit_powers() -> list[list[int]]:
    """x^(8 d 16^i) mod P for each hexadecimal digit d = 0 .. 15 of a length at place i = 0 .. 7."""
    table = []
    base = _mul(_mul(_ONE >> 1, _ONE >> 1), _mul(_ONE >> 1, _ONE >> 1))  # x^4
    base = _mul(base, base)  # x^8: one byte
    for _ in range(8):
        row = [_ONE]
        for _ in range(15):
            row.append(_mul(row[-1], base))
        table.append(row)
        base = _mul(row[15], base)  # x^(8 * 16^(i + 1))
    return table


_DIGITS = _digit_powers()


def x_to_8n(n: int) -> int:
    """x^(8 n) mod P: the shift a CRC undergoes when n more bytes follow it (n < 2^32: one
    multiplication per nonzero hexadecimal digit of n)."""
    if not 0 <= n < 1 << 32:
        raise ValueError(f"a length from 0 to 2^32 - 1 bytes, got {n}")
    p = _ONE
    for row in _DIGITS:
        d = n & 15
        if d:
            p = _mul(row[d], p)
        n >>= 4
        if not n:
            break
    return p


def combine(crc_a: int, crc_b: int, len_b: int) -> int:
    """zlib.crc32(A + B) from zlib.crc32(A), zlib.crc32(B) and len(B)."""
    if len_b < 0:
        raise ValueError(f"len_b must be >= 0, got {len_b}")
    return _mul(x_to_8n(len_b), crc_a) ^ crc_b
