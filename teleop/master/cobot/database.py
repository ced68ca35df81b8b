"""The cobot's frame database: the DBC read with cantools, strict encoding and checked decoding.

Device units live only in the DBC (scale, offset, range); everything here is SI. Frames whose
layout has a ``*Checksum`` signal carry, in their last four bytes, a CRC-32/ISO-HDLC of the frame
id (two bytes, little-endian, never sent: a frame copied under another id fails, as the data id of
the AUTOSAR E2E profiles does) followed by the payload before the CRC; with the frame's own
counter (``*Counter``, checked by the driver) this is the counter + CRC scheme of safety protocols
on CAN. A frame is rejected with a reason (:class:`Rejected`), never an exception in the control
loop, for: an unknown id, the wrong id type (extended/standard) or FD flag, a wrong length, a CRC
mismatch (``checksum``), a replayed frame (``stale``, below), or a value outside the DBC range.

Freshness a counter wrap cannot defeat (AUTOSAR SecOC's freshness value, kept implicit): the SYNC
carries the host's full 32-bit count of SYNCs sent (``SyncCounter``; the device refuses one that
does not advance), and the CRC of every message tied to a SYNC (DBC attribute ``SyncFreshness``
1: HOST_CMD, DEV_JOINTS, DEV_WRENCH) continues over the full count it answers, four bytes
little-endian after the payload, never sent: only its low byte is on the wire, in the frame's
8-bit counter. The receiver rebuilds the full count from its own (the host: the last SYNC it
sent; the device: the last SYNC it took; ``sync_ref`` of :meth:`FrameDatabase.decode`) and that
byte, the one nearest its own, and checks the CRC with it. A frame recorded 256 (512, ...) SYNCs
earlier and replayed has the right low byte and the wrong full count: the two differ only in those
four implicit bytes, a burst of at most 32 bits, which CRC-32 always detects, so the replay is
refused with certainty, not with probability 1 - 2^-32 (``stale`` when its CRC holds for the count
a whole number of wraps back, up to :data:`.frame_kernels.STALE_WRAPS`; ``checksum`` beyond). The
count wraps after 2^32 SYNCs (49.7 days at 1 kHz); the host refuses to send past it.

Residual probability: a random payload on a known id, with the right id type, FD flag and length,
passes the CRC with probability 2^-32 = 2.3e-10 (CRC-32 has Hamming distance 6 at these lengths,
so any 1..5 flipped bits are always caught); tools/can_residual.py measures it, and that no replay
passes.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import cantools
import numpy as np

from teleop.master.cobot import frame_kernels as FK
from teleop.master.cobot.codec import MessageCodec, layout_tables, sync_counter
from teleop.util.crc32 import crc32_continue
from teleop.util.errors import CanError

#: The protocol shipped with the package.
DEFAULT_DBC = Path(__file__).with_name("protocol.dbc")
#: bytes of the CRC at the end of a protected frame
CRC_BYTES = FK.CRC_BYTES


def compute_crc32(frame_id: int, data: bytes, count: int | None = None) -> int:
    """CRC-32/ISO-HDLC (crccheck's ``Crc32``; computed by :func:`teleop.util.crc32.crc32_continue`) of
    the frame id (2 bytes, little-endian) then ``data``, then, for a frame tied to a SYNC, its full
    SYNC ``count`` (4 bytes, little-endian). tests/unit/test_can_database.py checks it against
    crccheck on random frames."""
    head = crc32_continue(0, frame_id.to_bytes(2, "little"), 2)
    crc = crc32_continue(head, bytes(data), len(data))
    return int(crc if count is None else FK.crc32_count(crc, count))


class Decoded(NamedTuple):
    """A valid frame: message name, signals in SI units, timestamp (s), the same values in the
    order of the message codec's ``names`` (for readers that index them), and for a frame tied to
    a SYNC the full SYNC count its CRC holds for (-1: a frame tied to none)."""

    name: str
    signals: dict
    timestamp: float
    values: tuple = ()
    count: int = -1


class Rejected(NamedTuple):
    """A frame that never reaches the math: its id, and why (``unknown_id``, ``id_type``,
    ``fd_flag``, ``length``, ``checksum``, ``stale`` (a frame tied to a SYNC, replayed whole
    counter wraps later), ``range:<signal>``, ``nonfinite:<signal>``, ``decode``)."""

    frame_id: int
    reason: str
    timestamp: float


#: check_frame's rejections by name
_REASONS = {FK.UNKNOWN_ID: "unknown_id", FK.ID_TYPE: "id_type", FK.FD_FLAG: "fd_flag", FK.LENGTH: "length",
            FK.CHECKSUM: "checksum", FK.STALE: "stale"}
#: the reference of a decoder with no SYNC of its own (:meth:`FrameDatabase.decode`): a frame tied
#: to a SYNC is then checked with its counter as its full count (a frame of the first 256 SYNCs)
_NO_REF = 127


def _integer(v) -> int:
    """``v`` as an int when it is an integral number, else -1."""
    try:
        return int(v) if v == int(v) else -1
    except (TypeError, ValueError, OverflowError):
        return -1


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
        #: the index (in the codec's order) of the counter of each message tied to a SYNC
        self.counter = {m.name: self.codecs[m.name].names.index(sync_counter(m).name)
                        for m in messages if self.checksum[m.name] is not None and sync_counter(m) is not None}
        self._codec_by_row = [self.codecs[m.name] for m in messages]
        self._vals = np.empty(self.tables[0]["sig_f"].shape[1])

    def message(self, name: str):
        try:
            return self.by_name[name]
        except KeyError:
            raise CanError(f"can database: unknown message {name!r}; known: {sorted(self.by_name)}") from None

    def encode(self, name: str, signals: dict, sync_count: int | None = None) -> tuple[int, bytes, bool]:
        """(frame id, payload, is_fd) of message ``name``; values in SI units.

        strict: a value outside its DBC range raises :class:`CanError` naming the signal. The
        checksum signal, when the layout has one, is computed here and need not be given. For a
        message tied to a SYNC, ``sync_count`` is the full SYNC count it answers, whose low byte
        its counter must hold (None: the counter is the count, a frame of the first 256 SYNCs).
        """
        msg = self.message(name)
        ck = self.checksum[name]
        if ck is not None:
            signals = dict(signals)
            signals[ck] = 0
        codec = self.codecs[name]
        if len(signals) != len(codec.names) or not all(n in signals for n in codec.names):
            codec.encode(signals)  # raises, naming the missing and unknown signals
        return msg.frame_id, self._encode(name, [signals[n] for n in codec.names], sync_count), bool(msg.is_fd)

    def encode_ordered(self, name: str, values, sync_count: int | None = None) -> tuple[int, bytes, bool]:
        """:meth:`encode` with the values in the order of ``codecs[name].names`` without the
        checksum (for the per-period frames: no mapping to build)."""
        codec = self.codecs.get(name) or self.message(name)
        if self.checksum[name] is not None:
            values = (*values, 0)
        return codec.frame_id, self._encode(name, values, sync_count), bool(codec.message.is_fd)

    def _encode(self, name: str, values, sync_count: int | None = None) -> bytes:
        """The payload of ``values`` (codec order, the checksum's slot 0), sealed with its CRC-32
        (compute_crc32(frame id, body[, full SYNC count])) when the layout has a checksum."""
        count = -1
        i = self.counter.get(name)
        if i is not None and sync_count is None:  # the counter is the count (a bad one: the codec names it)
            count = _integer(values[i])
            count = count if 0 <= count < 256 else 0
        elif i is not None:
            if not (isinstance(sync_count, (int, np.integer)) and 0 <= sync_count < FK.COUNT_MOD):
                raise CanError(f"can encode {name}: SYNC count {sync_count!r} is not an integer in [0, 2^32)")
            count = int(sync_count)
            if _integer(values[i]) != count % 256:
                raise CanError(f"can encode {name}.{self.codecs[name].names[i]}: {values[i]!r} is not the low byte "
                               f"of the SYNC count {count}")
        return self.codecs[name].encode_ordered(values, seal=True, tables=self.tables, row=self.row[name],
                                                count=int(count))

    def decode(self, frame_id: int, data: bytes, timestamp: float = 0.0, is_extended_id: bool = False,
               is_fd: bool = True, sync_ref: int | None = None) -> Decoded | Rejected:
        """Decode and check one frame: a :class:`Decoded` in SI units, or a :class:`Rejected`.
        ``is_extended_id`` and ``is_fd`` are the frame's flags as received (every shipped message
        is a standard-id CAN FD frame). ``sync_ref``: the receiver's latest full SYNC count (the
        device: the last SYNC it took); a frame tied to a SYNC is checked with the full count
        nearest it whose low byte its counter holds (None: its counter is its count). The
        freshness rules on that count (newer than the last applied) are the receiver's."""
        vals = self._vals
        ref = _NO_REF if sync_ref is None else int(sync_ref)
        verdict, row, count = FK.check_frame(self.tables, int(frame_id), bool(is_extended_id), bool(is_fd),
                                             bytes(data), vals, ref)
        return self.verdict(verdict, row, frame_id, data, timestamp, vals, int(count))

    def verdict(self, verdict: int, row: int, frame_id: int, data, timestamp: float, vals,
                count: int = -1) -> Decoded | Rejected:
        """The :class:`Decoded` or :class:`Rejected` of a :func:`.frame_kernels.check_frame` verdict
        on message ``row`` with the decoded ``vals`` (and the full SYNC ``count`` of a frame tied to
        one)."""
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
        return Decoded(codec.name, dict(zip(codec.names, values)), timestamp, values, count)

    def decode_message(self, msg, sync_ref: int | None = None) -> Decoded | Rejected:
        """:meth:`decode` of a :class:`can.Message` (its id, data, timestamp and flags)."""
        return self.decode(msg.arbitration_id, msg.data, msg.timestamp, msg.is_extended_id, msg.is_fd, sync_ref)
