"""CRC-32C (Castagnoli), the checksum of TFRecord framing.

The maintained ``crc32c`` package (hardware CRC instructions where the CPU has them) is used
when it is installed, which it is as a core dependency. Where it cannot be installed, a
numpy fallback computes the same checksum table-driven: the data is cut into equal chunks
whose CRC registers advance together, one byte of every chunk per step, and the chunk
registers are then shifted into place with precomputed GF(2) operators. See
``benchmarks/bench_womd_crc.py`` for the speed of both.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ["CRC_IMPLEMENTATION", "crc32c", "crc32c_numpy", "masked_crc32c"]

POLY = 0x82F63B78
"""CRC-32C polynomial, bit-reflected."""
MASK_DELTA = 0xA282EAD8
"""TFRecord's mask constant: masked = rotr15(crc) + MASK_DELTA."""
_CHUNK = 64
"""Bytes per chunk in the numpy fallback; shorter inputs go through the scalar loop."""
_SCALAR_BELOW = 4096


def _byte_table() -> np.ndarray:
    table = np.arange(256, dtype=np.uint32)
    for _ in range(8):
        table = np.where(table & 1, (table >> 1) ^ np.uint32(POLY), table >> 1).astype(np.uint32)
    return table


_TABLE = _byte_table()
_TABLE_LIST = [int(v) for v in _TABLE]


def _scalar(register: int, data: bytes | memoryview) -> int:
    table = _TABLE_LIST
    for byte in bytes(data):
        register = table[(register ^ byte) & 0xFF] ^ (register >> 8)
    return register


class _Operator:
    """A GF(2)-linear map on 32-bit CRC registers, applied through four byte tables."""

    def __init__(self, columns: list[int]):
        self.columns = columns  # image of each of the 32 unit vectors
        self.tables = np.zeros((4, 256), dtype=np.uint32)
        for part in range(4):
            for bit in range(8):
                column = np.uint32(columns[8 * part + bit])
                has_bit = (np.arange(256) >> bit) & 1 == 1
                self.tables[part, has_bit] ^= column

    def __call__(self, register: int) -> int:
        t = self.tables
        return int(t[0, register & 0xFF] ^ t[1, (register >> 8) & 0xFF]
                   ^ t[2, (register >> 16) & 0xFF] ^ t[3, register >> 24])

    def apply(self, registers: np.ndarray) -> np.ndarray:
        t = self.tables
        return (t[0][registers & 0xFF] ^ t[1][(registers >> 8) & 0xFF]
                ^ t[2][(registers >> 16) & 0xFF] ^ t[3][registers >> 24])

    def then(self, other: _Operator) -> _Operator:
        """The map ``other(self(r))``."""
        return _Operator([other(c) for c in self.columns])


@lru_cache(maxsize=64)
def _zeros_operator(n_bytes: int) -> _Operator:
    """The map that feeding ``n_bytes`` zero bytes makes on a register."""
    result = _Operator([1 << i for i in range(32)])
    power = _Operator([_scalar(1 << i, b"\0") for i in range(32)])
    while n_bytes:
        if n_bytes & 1:
            result = result.then(power)
        n_bytes >>= 1
        if n_bytes:
            power = power.then(power)
    return result


def crc32c_numpy(data: bytes | bytearray | memoryview, value: int = 0) -> int:
    """CRC-32C of ``data`` without the ``crc32c`` package (numpy, table-driven).

    Args:
        data: the bytes to check.
        value: the CRC of the preceding bytes, to continue a running checksum.

    Returns:
        The CRC-32C as an unsigned 32-bit int; ``crc32c_numpy(b"123456789") == 0xE3069283``.
    """
    register = value ^ 0xFFFFFFFF
    n = len(data)
    if n < _SCALAR_BELOW:
        return _scalar(register, data) ^ 0xFFFFFFFF
    k = n // _CHUNK
    body = np.frombuffer(data, dtype=np.uint8, count=k * _CHUNK).reshape(k, _CHUNK)
    regs = np.zeros(k, dtype=np.uint32)
    for j in range(_CHUNK):
        regs = _TABLE[(regs ^ body[:, j]) & 0xFF] ^ (regs >> 8)
    # Chunk i's register still has to see the (k - 1 - i) chunks after it as zero bytes.
    shift = np.arange(k - 1, -1, -1)
    bit = 0
    while (k - 1) >> bit:
        sel = ((shift >> bit) & 1).astype(bool)
        regs[sel] = _zeros_operator(_CHUNK << bit).apply(regs[sel])
        bit += 1
    register = _zeros_operator(k * _CHUNK)(register) ^ int(np.bitwise_xor.reduce(regs))
    register = _scalar(register, memoryview(data)[k * _CHUNK:])
    return register ^ 0xFFFFFFFF


try:
    from crc32c import crc32c as _crc32c_package
except ImportError:  # pragma: no cover - the package is a core dependency
    _crc32c_package = None

if _crc32c_package is not None:
    crc32c = _crc32c_package
    CRC_IMPLEMENTATION = "crc32c package"
else:  # pragma: no cover
    crc32c = crc32c_numpy
    CRC_IMPLEMENTATION = "numpy table fallback"


def masked_crc32c(data: bytes | bytearray | memoryview) -> int:
    """TFRecord's masked CRC-32C of ``data``: rotate right by 15 bits, add 0xa282ead8."""
    crc = crc32c(data)
    return (((crc >> 15) | (crc << 17)) + MASK_DELTA) & 0xFFFFFFFF
