"""The cobot's frame database: the DBC read with cantools, strict encoding and checked decoding.

Device units live only in the DBC (scale, offset, range); everything here is SI. Frames whose
layout has a ``*Checksum`` signal carry a CRC-8 (SAE J1850, poly 0x1D) of the other bytes in
their last byte; a mismatch, a wrong length, an unknown id or a value outside the DBC range is a
rejected frame with a reason (:class:`Rejected`), never an exception in the control loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cantools

from teleop.errors import CanError

#: The protocol shipped with the package.
DEFAULT_DBC = Path(__file__).with_name("protocol.dbc")


def _crc8_table(poly: int = 0x1D) -> tuple:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


CRC8_TABLE = _crc8_table()


def compute_crc8(data: bytes) -> int:
    """CRC-8 SAE J1850 (init 0xFF, final xor 0xFF) of ``data``."""
    crc = 0xFF
    for b in data:
        crc = CRC8_TABLE[crc ^ b]
    return crc ^ 0xFF


@dataclass(frozen=True)
class Decoded:
    """A valid frame: message name, signals in SI units, timestamp (s)."""

    name: str
    signals: dict
    timestamp: float


@dataclass(frozen=True)
class Rejected:
    """A frame that never reaches the math: its id, and why (``unknown_id``, ``length``,
    ``checksum``, ``range:<signal>``, ``nonfinite:<signal>``, ``decode``)."""

    frame_id: int
    reason: str
    timestamp: float


class FrameDatabase:
    """The DBC plus the encode/decode rules of the protocol (checksums, ranges)."""

    def __init__(self, path: str | Path = DEFAULT_DBC):
        try:
            self.db = cantools.database.load_file(str(path))
        except (OSError, cantools.database.UnsupportedDatabaseFormatError) as e:
            raise CanError(f"can database {path}: cannot load: {e}") from None
        self.by_name = {m.name: m for m in self.db.messages}
        self.by_id = {m.frame_id: m for m in self.db.messages}
        self.checksum = {m.name: next((s.name for s in m.signals if s.name.endswith("Checksum")), None)
                         for m in self.db.messages}
        self.ranges = {
            m.frame_id: tuple((s.name, s.minimum, s.maximum) for s in m.signals if not s.name.endswith("Checksum"))
            for m in self.db.messages
        }

    def message(self, name: str):
        try:
            return self.by_name[name]
        except KeyError:
            raise CanError(f"can database: unknown message {name!r}; known: {sorted(self.by_name)}") from None

    def encode(self, name: str, signals: dict) -> tuple[int, bytes, bool]:
        """(frame id, payload, is_fd) of message ``name``; values in SI units.

        strict: a value outside its DBC range raises :class:`CanError` naming the signal. The
        checksum signal, when the layout has one, is computed here and need not be given.
        """
        msg = self.message(name)
        ck = self.checksum[name]
        values = dict(signals)
        if ck is not None:
            values[ck] = 0
        for key, v in values.items():
            if not math.isfinite(float(v)):
                raise CanError(f"can encode {name}.{key}: non-finite value {v}")
        try:
            data = bytearray(msg.encode(values, strict=True, scaling=True))
        except (cantools.database.EncodeError, KeyError, ValueError) as e:
            raise CanError(f"can encode {name}: {e}") from None
        if ck is not None:
            data[-1] = compute_crc8(bytes(data[:-1]))
        return msg.frame_id, bytes(data), bool(msg.is_fd)

    def decode(self, frame_id: int, data: bytes, timestamp: float = 0.0) -> Decoded | Rejected:
        """Decode and check one frame: a :class:`Decoded` in SI units, or a :class:`Rejected`."""
        msg = self.by_id.get(frame_id)
        if msg is None:
            return Rejected(frame_id, "unknown_id", timestamp)
        if len(data) != msg.length:
            return Rejected(frame_id, "length", timestamp)
        if self.checksum[msg.name] is not None and compute_crc8(bytes(data[:-1])) != data[-1]:
            return Rejected(frame_id, "checksum", timestamp)
        try:
            values = msg.decode(bytes(data), decode_choices=False, scaling=True)
        except Exception:  # cantools raises several types on malformed payloads
            return Rejected(frame_id, "decode", timestamp)
        for sig, lo, hi in self.ranges[frame_id]:
            v = float(values[sig])
            if not math.isfinite(v):
                return Rejected(frame_id, f"nonfinite:{sig}", timestamp)
            if (lo is not None and v < lo - 1e-9) or (hi is not None and v > hi + 1e-9):
                return Rejected(frame_id, f"range:{sig}", timestamp)
        return Decoded(msg.name, values, timestamp)
