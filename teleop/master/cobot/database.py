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
from pathlib import Path
from typing import NamedTuple

import cantools
import numpy as np

from teleop.master.cobot import frame_kernels as FK
from teleop.master.cobot.codec import MessageCodec, layout_tables
from teleop.util.crc32 import crc32_continue
from teleop.util.errors import CanError

#: The protocol shipped with the package.
DEFAULT_DBC = Path(__file__).with_name("protocol.dbc")
#: bytes of the CRC at the end of a protected frame
CRC_BYTES = FK.CRC_BYTES


def compute_crc32(frame_id: int, data: bytes) -> int:
    """CRC-32/ISO-HDLC (crccheck's ``Crc32``; computed by :func:`teleop.util.crc32.crc32_continue`) of
    the frame id (2 bytes, little-endian) then ``data``. tests/unit/test_can_database.py checks it
    against crccheck on random frames."""
    head = crc32_continue(0, frame_id.to_bytes(2, "little"), 2)
    return int(crc32_continue(head, bytes(data), len(data)))


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


#: check_frame's rejections by name
_REASONS = {FK.UNKNOWN_ID: "unknown_id", FK.ID_TYPE: "id_type", FK.FD_FLAG: "fd_flag", FK.LENGTH: "length",
            FK.CHECKSUM: "checksum"}


class FrameDatabase:
    """The DBC plus the encode/decode rules of the protocol (checksums, ranges).

    Every message is encoded and decoded by the compiled frame codec (:mod:`.frame_kernels`) over
    the layout tables :func:`.codec.layout_tables` reads from the DBC (cantools' own codec for a
    layout they cannot hold); :attr:`codecs` holds each message's :class:`.codec.MessageCodec`.
    """

    def __init__(self, path: str | Path = DEFAULT_DBC):
        try:
            self.db = cantools.database.load_file(str(path))
        except (OSError, cantools.database.UnsupportedDatabaseFormatError) as e:
            raise CanError(f"can database {path}: cannot load: {e}") from None
        messages = list(self.db.messages)
        if len({m.frame_id for m in messages}) != len(messages):
            raise CanError(f"can database {path}: two messages share a frame id")
        self.by_name = {m.name: m for m in messages}
        self.codecs = {m.name: MessageCodec(m) for m in messages}
        self.checksum = {m.name: next((s.name for s in m.signals if s.name.endswith("Checksum")), None)
                         for m in messages}
        for name, ck in self.checksum.items():
            sig = ck and self.by_name[name].get_signal_by_name(ck)
            if ck is not None and (self.codecs[name].names[-1] != ck or sig.length != 8 * CRC_BYTES
                                   or sig.start != 8 * (self.by_name[name].length - CRC_BYTES)):
                raise CanError(f"can database {path}: {name}.{ck} must be a 32-bit CRC in the frame's last 4 bytes")
        #: the compiled codec's tables of every message (a record: frame_kernels' msgs, sig_i, sig_f, ids, order)
        self.tables = layout_tables(messages, crc_of_id=lambda fid: compute_crc32(fid, b""))
        self.row = {m.name: i for i, m in enumerate(messages)}
        self._codec_by_row = [self.codecs[m.name] for m in messages]
        self._vals = np.empty(self.tables[0]["sig_f"].shape[1])

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
        codec = self.codecs[name]
        if len(signals) != len(codec.names) or not all(n in signals for n in codec.names):
            codec.encode(signals)  # raises, naming the missing and unknown signals
        return msg.frame_id, self._encode(name, [signals[n] for n in codec.names]), bool(msg.is_fd)

    def encode_ordered(self, name: str, values) -> tuple[int, bytes, bool]:
        """:meth:`encode` with the values in the order of ``codecs[name].names`` without the
        checksum (for the per-period frames: no mapping to build)."""
        codec = self.codecs.get(name) or self.message(name)
        if self.checksum[name] is not None:
            values = (*values, 0)
        return codec.frame_id, self._encode(name, values), bool(codec.message.is_fd)

    def _encode(self, name: str, values) -> bytes:
        """The payload of ``values`` (codec order, the checksum's slot 0), sealed with its CRC-32
        (compute_crc32(frame id, body)) when the layout has a checksum."""
        return self.codecs[name].encode_ordered(values, seal=True, tables=self.tables, row=self.row[name])

    def decode(self, frame_id: int, data: bytes, timestamp: float = 0.0, is_extended_id: bool = False,
               is_fd: bool = True) -> Decoded | Rejected:
        """Decode and check one frame: a :class:`Decoded` in SI units, or a :class:`Rejected`.
        ``is_extended_id`` and ``is_fd`` are the frame's flags as received (every shipped message
        is a standard-id CAN FD frame)."""
        vals = self._vals
        verdict, row = FK.check_frame(self.tables, int(frame_id), bool(is_extended_id), bool(is_fd), bytes(data), vals)
        return self.verdict(verdict, row, frame_id, data, timestamp, vals)

    def verdict(self, verdict: int, row: int, frame_id: int, data, timestamp: float, vals) -> Decoded | Rejected:
        """The :class:`Decoded` or :class:`Rejected` of a :func:`.frame_kernels.check_frame` verdict
        on message ``row`` with the decoded ``vals``."""
        if verdict in _REASONS:
            return Rejected(frame_id, _REASONS[verdict], timestamp)
        codec = self._codec_by_row[row]
        if verdict == FK.NOT_COMPILED:  # cantools' codec, then the same range check
            try:
                values = codec.decode(bytes(data))
            except Exception:  # cantools raises several types on malformed payloads
                return Rejected(frame_id, "decode", timestamp)
            vals = np.array(values, dtype=float)
            sig_f = self.tables[0]["sig_f"][row]
            bad = [i for i, v in enumerate(vals) if not sig_f[i, FK.S_DLO] <= v <= sig_f[i, FK.S_DHI]]
            verdict = FK.RANGE + bad[0] if bad else FK.OK
        if verdict >= FK.RANGE:
            i = verdict - FK.RANGE
            bad = codec.signals[i].is_float and not math.isfinite(vals[i])
            return Rejected(frame_id, f"{'nonfinite' if bad else 'range'}:{codec.names[i]}", timestamp)
        values = codec.values_from(vals)
        return Decoded(codec.name, dict(zip(codec.names, values)), timestamp, values)

    def decode_message(self, msg) -> Decoded | Rejected:
        """:meth:`decode` of a :class:`can.Message` (its id, data, timestamp and flags)."""
        return self.decode(msg.arbitration_id, msg.data, msg.timestamp, msg.is_extended_id, msg.is_fd)
