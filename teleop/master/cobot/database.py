"""The cobot's frame database: the DBC read with cantools, strict encoding and checked decoding.

Device units live only in the DBC (scale, offset, range); everything here is SI. Frames whose
layout has a ``*Checksum`` signal carry a CRC-8 (SAE J1850, poly 0x1D) of the other bytes in
their last byte; a mismatch, a wrong length, an unknown id or a value outside the DBC range is a
rejected frame with a reason (:class:`Rejected`), never an exception in the control loop.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import cantools

from teleop.master.cobot.codec import MessageCodec
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


class Decoded(NamedTuple):
    """A valid frame: message name, signals in SI units, timestamp (s), and the same values in the
    order of the message codec's ``names`` (for readers that index them)."""

    name: str
    signals: dict
    timestamp: float
    values: tuple = ()


class Rejected(NamedTuple):
    """A frame that never reaches the math: its id, and why (``unknown_id``, ``length``,
    ``checksum``, ``range:<signal>``, ``nonfinite:<signal>``, ``decode``)."""

    frame_id: int
    reason: str
    timestamp: float


def _slack(signal) -> float:
    """Tolerance (physical units) of a decoded value against the DBC range: half a raw step for
    integer signals, round-off for floats."""
    return 1e-9 + (0.0 if signal.is_float else 0.5 * abs(signal.conversion.scale))


class FrameDatabase:
    """The DBC plus the encode/decode rules of the protocol (checksums, ranges).

    Each message is encoded and decoded by a :class:`~teleop.master.cobot.codec.MessageCodec` compiled from
    its DBC layout (cantools' values, without cantools' per-call overhead).
    """

    def __init__(self, path: str | Path = DEFAULT_DBC):
        try:
            self.db = cantools.database.load_file(str(path))
        except (OSError, cantools.database.UnsupportedDatabaseFormatError) as e:
            raise CanError(f"can database {path}: cannot load: {e}") from None
        self.by_name = {m.name: m for m in self.db.messages}
        self.codecs = {m.name: MessageCodec(m) for m in self.db.messages}
        self._codec_by_id = {m.frame_id: self.codecs[m.name] for m in self.db.messages}
        self.checksum = {m.name: next((s.name for s in m.signals if s.name.endswith("Checksum")), None)
                         for m in self.db.messages}
        self._fd = {m.name: bool(m.is_fd) for m in self.db.messages}
        for name, ck in self.checksum.items():
            if ck is not None and (self.codecs[name].names[-1] != ck
                                   or self.by_name[name].get_signal_by_name(ck).start // 8 != self.by_name[name].length - 1):
                raise CanError(f"can database {path}: {name}.{ck} must be the last byte of the frame")
        # decode checks, in codec order: (index, signal, min, max, float signal). The DBC writes
        # its limits at physical resolution (0.99996 for raw 32767 x 2^-15), so an integer signal
        # may decode up to half a step past them: whatever strict encoding accepts, decoding does.
        self._checks = {
            c.frame_id: tuple((i, s.name, -math.inf if s.minimum is None else s.minimum - _slack(s),
                               math.inf if s.maximum is None else s.maximum + _slack(s), s.is_float)
                              for i, s in enumerate(c.signals) if not s.name.endswith("Checksum"))
            for c in self.codecs.values()
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
        if ck is not None:
            signals = dict(signals)
            signals[ck] = 0
        return msg.frame_id, self._seal(name, self.codecs[name].encode(signals)), bool(msg.is_fd)

    def encode_ordered(self, name: str, values) -> tuple[int, bytes, bool]:
        """:meth:`encode` with the values in the order of ``codecs[name].names`` without the
        checksum (for the per-period frames: no mapping to build)."""
        codec = self.codecs[name]
        if self.checksum[name] is not None:
            values = (*values, 0)
        return codec.frame_id, self._seal(name, codec.encode_ordered(values)), self._fd[name]

    def _seal(self, name: str, data: bytes) -> bytes:
        """The payload with its CRC-8 in the last byte, when the layout has a checksum."""
        if self.checksum[name] is None:
            return data
        return data[:-1] + bytes((compute_crc8(data[:-1]),))

    def decode(self, frame_id: int, data: bytes, timestamp: float = 0.0) -> Decoded | Rejected:
        """Decode and check one frame: a :class:`Decoded` in SI units, or a :class:`Rejected`."""
        codec = self._codec_by_id.get(frame_id)
        if codec is None:
            return Rejected(frame_id, "unknown_id", timestamp)
        if len(data) != codec.length:
            return Rejected(frame_id, "length", timestamp)
        data = bytes(data)
        if self.checksum[codec.name] is not None and compute_crc8(data[:-1]) != data[-1]:
            return Rejected(frame_id, "checksum", timestamp)
        try:
            values = codec.decode(data)
        except Exception:  # cantools raises several types on malformed payloads
            return Rejected(frame_id, "decode", timestamp)
        for i, sig, lo, hi, is_float in self._checks[frame_id]:
            v = values[i]
            if not lo <= v <= hi:
                bad = is_float and not math.isfinite(v)
                return Rejected(frame_id, f"{'nonfinite' if bad else 'range'}:{sig}", timestamp)
        return Decoded(codec.name, dict(zip(codec.names, values)), timestamp, values)
