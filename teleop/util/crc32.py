"""CRC-32/ISO-HDLC (the CRC of zlib, Ethernet and crccheck's ``Crc32``), compiled (numba) so that
it runs inside the compiled frame checks of the CAN codec (:mod:`teleop.master.cobot.frame_kernels`)
and the link's wire format: one table loop, continued from the CRC of what came before.

crccheck, the project's definition of the CRC, is pure Python (~42 us per 20-byte frame); the
table loop takes tens of nanoseconds. The check value is verified against crccheck at import, and
tests/property/test_can_codec.py holds the two equal on random data.
"""

from __future__ import annotations

import numpy as np
from crccheck.crc import Crc32
from numba import njit


def _crc_table() -> np.ndarray:
    """The 256-entry table of the reflected CRC-32 polynomial 0xEDB88320 (CRC-32/ISO-HDLC)."""
    t = np.empty(256, np.uint32)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0xEDB88320 if c & 1 else c >> 1
        t[i] = c
    return t


CRC_TABLE = _crc_table()


@njit(cache=True)
def crc32_continue(crc, data, n):
    """CRC-32/ISO-HDLC of the first n bytes of ``data`` continued from ``crc`` (the CRC of what
    came before; 0 for none), as ``zlib.crc32(data[:n], crc)``."""
    c = np.uint32(crc) ^ np.uint32(0xFFFFFFFF)
    for i in range(n):
        c = CRC_TABLE[(c ^ np.uint32(data[i])) & np.uint32(0xFF)] ^ (c >> np.uint32(8))
    return np.int64(c ^ np.uint32(0xFFFFFFFF))


def crc32(data) -> int:
    """CRC-32/ISO-HDLC of ``data`` (bytes-like)."""
    return int(crc32_continue(0, data, len(data)))


if crc32(b"123456789") != Crc32.calc(b"123456789"):  # the check value, 0xCBF43926
    raise ImportError("teleop.util.crc32: the compiled CRC-32 differs from crccheck's CRC-32/ISO-HDLC")
