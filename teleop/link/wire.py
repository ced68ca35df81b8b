"""Versioned binary wire format of the two link messages (no pickle).

One frame, all little-endian::

    offset size  field
    0      4     magic      b"TLNK"
    4      1     version    u8, WIRE_VERSION (bumped on any layout change, incl. SLAVE_STATUSES)
    5      1     type       u8, 1 ToolCommand, 2 ContactFeedback
    6      2     length     u16, payload bytes
    8      8     seq        u64, the message's sequence number
    16     n     payload    (below)
    16+n   4     crc        u32, CRC-32/ISO-HDLC over bytes [0, 16+n)

ToolCommand payload (209 bytes): t_s f64 (s), p_m 3 f64 (m), R 9 f64 row-major, v_m_s 3 f64 (m/s),
w_rad_s 3 f64 (rad/s), clutch u8, energy_J 6 f64 (J).
ContactFeedback payload (337 bytes): t_s f64 (s), wrench_P 6 f64 (N, N*m), status u8 (index in
SLAVE_STATUSES), command_seq i64, energy_J 6 f64 (J), damping_P 21 f64 (the upper triangle, row by
row: N*s/m, N*s, N*m*s/rad), twist_P 6 f64 (m/s, rad/s). Version 3 added the last two.

The CRC is CRC-32/ISO-HDLC (poly 0x04C11DB7 reflected, init and xorout 0xFFFFFFFF): crccheck's
``Crc32`` names it and is the reference the tests check against; it is computed by the project's
one compiled CRC, :func:`teleop.util.crc32.crc32` (the CAN frames' too), because crccheck is pure
Python, bit by bit (~0.45 ms per 200-byte frame here, half a 1 kHz tick).

:func:`decode` checks magic, version, type, length, CRC and finite values, in that order, and
raises :class:`~teleop.tick.messages.MessageError` naming the reason.
"""

from __future__ import annotations

import math
import struct

import numpy as np

from teleop.util.crc32 import crc32 as _crc32
from teleop.tick.messages import SLAVE_STATUSES, ContactFeedback, MessageError, ToolCommand

MAGIC = b"TLNK"
WIRE_VERSION = 3
TYPE_COMMAND = 1
TYPE_FEEDBACK = 2

_HEADER = struct.Struct("<4sBBHQ")
_CRC = struct.Struct("<I")
_COMMAND = struct.Struct("<19dB6d")
_FEEDBACK = struct.Struct("<7dBq33d")
_UPPER = np.triu_indices(6)
_PAYLOAD = {TYPE_COMMAND: _COMMAND, TYPE_FEEDBACK: _FEEDBACK}

#: frame sizes in bytes (header + payload + crc)
COMMAND_SIZE = _HEADER.size + _COMMAND.size + _CRC.size
FEEDBACK_SIZE = _HEADER.size + _FEEDBACK.size + _CRC.size


def crc32(data: bytes) -> int:
    """CRC-32/ISO-HDLC of ``data`` (same value as ``crccheck.crc.Crc32.calc``)."""
    return _crc32(data)


def _frame(kind: int, seq: int, payload: bytes) -> bytes:
    head = _HEADER.pack(MAGIC, WIRE_VERSION, kind, len(payload), seq) + payload
    return head + _CRC.pack(crc32(head))


def encode(msg: ToolCommand | ContactFeedback) -> bytes:
    """The frame of one message (bytes)."""
    if isinstance(msg, ToolCommand):
        payload = _COMMAND.pack(msg.t_s, *msg.p_m, *msg.R.reshape(-1), *msg.v_m_s, *msg.w_rad_s,
                                1 if msg.clutch else 0, *msg.energy_J)
        return _frame(TYPE_COMMAND, msg.seq, payload)
    if isinstance(msg, ContactFeedback):
        payload = _FEEDBACK.pack(msg.t_s, *msg.wrench_P, SLAVE_STATUSES.index(msg.status),
                                 msg.command_seq, *msg.energy_J, *msg.damping_P[_UPPER], *msg.twist_P)
        return _frame(TYPE_FEEDBACK, msg.seq, payload)
    raise MessageError(f"wire.encode: not a link message: {type(msg).__name__}")


def encoded_size(msg: ToolCommand | ContactFeedback) -> int:
    """Bytes on the wire of ``msg`` (frame only, no transport overhead)."""
    return COMMAND_SIZE if isinstance(msg, ToolCommand) else FEEDBACK_SIZE


def decode(data: bytes | bytearray | memoryview) -> ToolCommand | ContactFeedback:
    """The message of one frame; MessageError("wire: <reason>") if the frame is not valid."""
    data = bytes(data)
    if len(data) < _HEADER.size + _CRC.size:
        raise MessageError(f"wire: frame too short ({len(data)} bytes)")
    magic, version, kind, length, seq = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise MessageError(f"wire: bad magic {magic!r}")
    if version != WIRE_VERSION:
        raise MessageError(f"wire: unsupported version {version} (this side speaks {WIRE_VERSION})")
    layout = _PAYLOAD.get(kind)
    if layout is None:
        raise MessageError(f"wire: unknown message type {kind}")
    if length != layout.size or len(data) != _HEADER.size + length + _CRC.size:
        raise MessageError(f"wire: bad length (header says {length}, type {kind} needs "
                           f"{layout.size}, frame has {len(data)} bytes)")
    (crc,) = _CRC.unpack_from(data, _HEADER.size + length)
    if crc != crc32(data[: _HEADER.size + length]):
        raise MessageError("wire: CRC mismatch")
    if seq >= 2**63:
        raise MessageError(f"wire: sequence number out of range ({seq})")
    v = layout.unpack_from(data, _HEADER.size)
    floats = v[:19] + v[20:] if kind == TYPE_COMMAND else v[:7] + v[9:]
    if not all(math.isfinite(x) for x in floats):
        raise MessageError("wire: non-finite value in payload")
    if kind == TYPE_COMMAND:
        if v[19] > 1:
            raise MessageError(f"wire: bad clutch byte {v[19]}")
        return ToolCommand(seq=seq, t_s=v[0], p_m=np.array(v[1:4]), R=np.array(v[4:13]).reshape(3, 3),
                           v_m_s=np.array(v[13:16]), w_rad_s=np.array(v[16:19]), clutch=bool(v[19]),
                           energy_J=np.array(v[20:26]))
    if v[7] >= len(SLAVE_STATUSES):
        raise MessageError(f"wire: unknown status index {v[7]}")
    D = np.empty((6, 6))
    D[_UPPER] = v[15:36]
    D.T[_UPPER] = v[15:36]
    return ContactFeedback(seq=seq, t_s=v[0], wrench_P=np.array(v[1:7]), status=SLAVE_STATUSES[v[7]],
                           command_seq=v[8], energy_J=np.array(v[9:15]), damping_P=D, twist_P=np.array(v[36:42]))
