"""The cobot's frame database: the DBC read with cantools, strict encoding and checked decoding.

Device units live only in the DBC (scale, offset, range); everything here is SI. Frames whose
layout has a ``*Checksum`` signal carry, in their last four bytes, a CRC-32/ISO-HDLC of the frame
id (two bytes, little-endian, never sent: a frame copied under another id fails, as the data id of
the AUTOSAR E2E profiles does) followed by the payload before the CRC; with the frame's own
counter (``*Counter``, checked by the driver) this is the counter + CRC scheme of safety protocols
on CAN. A frame is rejected with a reason (:class:`Rejected`), never an exception in the control
loop, for: an unknown id, the wrong id type (extended/standard) or FD flag, a wrong length, a CRC
mismatch, or a value outside the DBC range.

Residual probability: a random payload on a known id, with the right id type, FD flag and length,
passes the CRC with probability 2^-32 = 2.3e-10 (CRC-32 has Hamming distance 6 at these lengths,
so any 1..5 flipped bits are always caught); tools/can_residual.py measures it.
"""

from __future__ import annotations

import math
import operator
import zlib
from pathlib import Path
from typing import NamedTuple

import cantools
from crccheck.crc import Crc32

from teleop.master.cobot.codec import MessageCodec
from teleop.errors import CanError

#: The protocol shipped with the package.
DEFAULT_DBC = Path(__file__).with_name("protocol.dbc")
#: bytes of the CRC at the end of a protected frame
CRC_BYTES = 4


def compute_crc32(frame_id: int, data: bytes) -> int:
    """CRC-32/ISO-HDLC (crccheck's ``Crc32``) of the frame id (2 bytes, little-endian) then
    ``data``. Computed with :func:`zlib.crc32`: crccheck is pure Python (~42 us per 20-byte frame
    here, ~9 frames per 1 kHz tick), zlib ~0.3 us; tests/unit/test_can_database.py checks that
    both give the same value."""
    return zlib.crc32(data, zlib.crc32(frame_id.to_bytes(2, "little"))) & 0xFFFFFFFF


# the one definition of the wire CRC is crccheck's; zlib must compute that same CRC (check value)
if not zlib.crc32(b"123456789") == Crc32.calc(b"123456789") == 0xCBF43926:
    raise CanError("zlib.crc32 differs from crccheck's CRC-32/ISO-HDLC")


class Decoded(NamedTuple):
    """A valid frame: message name, signals in SI units, timestamp (s), and the same values in the
    order of the message codec's ``names`` (for readers that index them)."""

    name: str
    signals: dict
    timestamp: float
    values: tuple = ()


class Rejected(NamedTuple):
    """A frame that never reaches the math: its id, and why (``unknown_id``, ``id_type``,
    ``fd_flag``, ``length``, ``checksum``, ``range:<signal>``, ``nonfinite:<signal>``, ``decode``)."""

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
        self._format = {m.frame_id: (bool(m.is_extended_frame), bool(m.is_fd)) for m in self.db.messages}
        for name, ck in self.checksum.items():
            sig = ck and self.by_name[name].get_signal_by_name(ck)
            if ck is not None and (self.codecs[name].names[-1] != ck or sig.length != 8 * CRC_BYTES
                                   or sig.start != 8 * (self.by_name[name].length - CRC_BYTES)):
                raise CanError(f"can database {path}: {name}.{ck} must be a 32-bit CRC in the frame's last 4 bytes")
        # decode checks, in codec order: (index, signal, min, max, float signal). The DBC writes
        # its limits at physical resolution (0.99996 for raw 32767 x 2^-15), so an integer signal
        # may decode up to half a step past them: whatever strict encoding accepts, decoding does.
        self._checks = {
            c.frame_id: tuple((i, s.name, -math.inf if s.minimum is None else s.minimum - _slack(s),
                               math.inf if s.maximum is None else s.maximum + _slack(s), s.is_float)
                              for i, s in enumerate(c.signals) if not s.name.endswith("Checksum"))
            for c in self.codecs.values()
        }
        self._id_crc = {c.name: compute_crc32(c.frame_id, b"") if self.checksum[c.name] else None
                        for c in self.codecs.values()}
        # per frame id, what decode needs, looked up once: (codec, extended, fd, length, CRC of the
        # id or None when unprotected, the range's lower and upper bounds per value (a checksum's
        # unbounded: its check is the CRC))
        self._rx = {}
        for c in self.codecs.values():
            lo, hi = [-math.inf] * len(c.names), [math.inf] * len(c.names)
            for i, _, a, b, _ in self._checks[c.frame_id]:
                lo[i], hi[i] = a, b
            self._rx[c.frame_id] = (c, *self._format[c.frame_id], c.length, self._id_crc[c.name], tuple(lo),
                                    tuple(hi))

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
        """The payload with its CRC-32 in the last four bytes, when the layout has a checksum:
        compute_crc32(frame id, body), continued from the id's CRC computed once."""
        id_crc = self._id_crc[name]
        if id_crc is None:
            return data
        body = data[:-CRC_BYTES]
        return body + (zlib.crc32(body, id_crc) & 0xFFFFFFFF).to_bytes(CRC_BYTES, "little")

    def decode(self, frame_id: int, data: bytes, timestamp: float = 0.0, is_extended_id: bool = False,
               is_fd: bool = True) -> Decoded | Rejected:
        """Decode and check one frame: a :class:`Decoded` in SI units, or a :class:`Rejected`.
        ``is_extended_id`` and ``is_fd`` are the frame's flags as received (every shipped message
        is a standard-id CAN FD frame)."""
        rx = self._rx.get(frame_id)
        if rx is None:
            return Rejected(frame_id, "unknown_id", timestamp)
        codec, extended, fd, length, id_crc, lo, hi = rx
        if bool(is_extended_id) != extended:
            return Rejected(frame_id, "id_type", timestamp)
        if bool(is_fd) != fd:
            return Rejected(frame_id, "fd_flag", timestamp)
        if len(data) != length:
            return Rejected(frame_id, "length", timestamp)
        data = bytes(data)
        # compute_crc32(frame_id, body), continued from the id's CRC
        if id_crc is not None and zlib.crc32(data[:-CRC_BYTES], id_crc) != int.from_bytes(data[-CRC_BYTES:], "little"):
            return Rejected(frame_id, "checksum", timestamp)
        try:
            values = codec.decode(data)
        except Exception:  # cantools raises several types on malformed payloads
            return Rejected(frame_id, "decode", timestamp)
        if not (all(map(operator.le, lo, values)) and all(map(operator.le, values, hi))):  # in C; NaN fails
            for i, sig, lo_i, hi_i, is_float in self._checks[frame_id]:
                v = values[i]
                if not lo_i <= v <= hi_i:
                    bad = is_float and not math.isfinite(v)
                    return Rejected(frame_id, f"{'nonfinite' if bad else 'range'}:{sig}", timestamp)
        return Decoded(codec.name, dict(zip(codec.names, values)), timestamp, values)

    def decode_message(self, msg) -> Decoded | Rejected:
        """:meth:`decode` of a :class:`can.Message` (its id, data, timestamp and flags)."""
        return self.decode(msg.arbitration_id, msg.data, msg.timestamp, msg.is_extended_id, msg.is_fd)
