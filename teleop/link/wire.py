"""Versioned binary wire format of the link's frames, authenticated (no pickle).

One frame, all little-endian::

    offset size  field
    0      4     magic      b"TLNK"
    4      1     version    u8, WIRE_VERSION (bumped on any layout change, incl. SLAVE_STATUSES)
    5      1     type       u8, 1 ToolCommand, 2 ContactFeedback, 16-20 pairing (teleop.link.pairing)
    6      2     length     u16, payload bytes
    8      8     session    u64, the pairing's session id (0 in pairing frames)
    16     8     counter    u64, the sender's frame number in the session, from 1 (0 in pairing frames)
    24     8     seq        u64, the message's sequence number (< 2^63)
    32     8     sent_s     f64, the sender's clock when it sealed the frame (s; 0 in pairing frames)
    40     n     payload    (below)
    40+n   32    tag        HMAC-SHA256 over bytes [0, 40+n), keyed per session and direction

ToolCommand payload (209 bytes): t_s f64 (s), p_m 3 f64 (m), R 9 f64 row-major, v_m_s 3 f64 (m/s),
w_rad_s 3 f64 (rad/s), clutch u8, energy_J 6 f64 (J), wall_N f64 (N: the master's contact wall).
ContactFeedback payload (417 bytes): t_s f64 (s), wrench_P 6 f64 (N, N*m), status u8 (index in
SLAVE_STATUSES), command_seq i64, energy_J 6 f64 (J), damping_P 21 f64 (the upper triangle, row by
row: N*s/m, N*s, N*m*s/rad), twist_P 6 f64 (m/s, rad/s), plane_P 8 f64 (the estimated contact
plane: unit normal, anchor m, stiffness N/m, confidence), then the stamps of the command it
answered (s, :class:`~teleop.link.latency.Stamps`): its send time as the master stamped it, and
when the slave received it and when its tick applied it (the slave's clock; all 0: none).

Version 7 added the command's ``wall_N`` (model-mediated rendering, :mod:`teleop.contact.wall_model`);
version 6 the contact plane (model-mediated rendering, :mod:`teleop.contact.estimate`);
version 5 the send time and the reply's echo of its command's stamps (the latency accounting
of :mod:`teleop.link.latency`); version 4 the session and counter fields and the tag in place of
a CRC-32: a frame whose tag does not verify under the receiver's key is refused before anything
in it is read (any changed bit, and any frame made without the key). The HMAC is
``cryptography``'s (OpenSSL's), a keyed copy per frame (:class:`Mac`). :data:`PLAIN` is the MAC
under a public all-zero key, for tools and tests that need a frame and no peer: an integrity check
only, which no link accepts (their keys are derived per session, :mod:`teleop.link.pairing`).

:func:`decode` checks magic, version, type, length, tag, sequence range and the values (finite,
the stamps too; a known clutch byte and status), in that order, and raises
:class:`~teleop.tick.messages.MessageError` naming the reason (``str(e)`` starts ``wire: bad MAC``
for a failed tag). :func:`stamps` reads a checked frame's stamps.
"""

from __future__ import annotations

import math
import struct
from typing import NamedTuple

import numpy as np
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, hmac

from teleop.link.latency import NO_STAMPS, Stamps
from teleop.tick.messages import SLAVE_STATUSES, ContactFeedback, MessageError, ToolCommand

MAGIC = b"TLNK"
WIRE_VERSION = 7
TYPE_COMMAND = 1
TYPE_FEEDBACK = 2
TYPE_HELLO, TYPE_WELCOME, TYPE_REFUSE, TYPE_CONFIRM, TYPE_ACCEPT = 16, 17, 18, 19, 20
TAG_SIZE = 32
MAX_SEQ = 2**63

_HEADER = struct.Struct("<4sBBHQQQd")
HEADER_SIZE = _HEADER.size
_SENT_AT = 32  # the header's sent_s
_COMMAND = struct.Struct("<19dB7d")
_FEEDBACK = struct.Struct("<7dBq44d")
_ECHO = struct.Struct("<3d")  # the last 24 bytes of a feedback payload
_D = struct.Struct("<d")
_STATUS_SEQ = struct.Struct("<Bq")  # a feedback payload's status and command_seq, after t_s and wrench_P
_cat = np.concatenate
_UPPER = np.triu_indices(6)
_PAYLOAD = {TYPE_COMMAND: _COMMAND, TYPE_FEEDBACK: _FEEDBACK}
#: payload sizes of the pairing frames (teleop.link.pairing packs them)
PAIRING_SIZES = {TYPE_HELLO: 96, TYPE_WELCOME: 200, TYPE_REFUSE: 200, TYPE_CONFIRM: 0, TYPE_ACCEPT: 0}
_SIZES = {**{k: v.size for k, v in _PAYLOAD.items()}, **PAIRING_SIZES}

#: frame sizes in bytes (header + payload + tag)
COMMAND_SIZE = HEADER_SIZE + _COMMAND.size + TAG_SIZE
FEEDBACK_SIZE = HEADER_SIZE + _FEEDBACK.size + TAG_SIZE


class Mac:
    """HMAC-SHA256 under one key (``cryptography``): each frame's tag is a copy of the keyed
    state, so the key is set up once."""

    __slots__ = ("_h",)

    def __init__(self, key: bytes):
        if len(key) < 16:
            raise ValueError("wire.Mac: a key of at least 16 bytes")
        self._h = hmac.HMAC(key, hashes.SHA256())

    def tag(self, data: bytes) -> bytes:
        """The 32-byte tag of ``data``."""
        h = self._h.copy()
        h.update(data)
        return h.finalize()

    def ok(self, data: bytes | memoryview, tag: bytes | memoryview) -> bool:
        """True when ``tag`` is the tag of ``data`` (compared in constant time)."""
        h = self._h.copy()
        h.update(data)
        try:
            h.verify(bytes(tag))
            return True
        except InvalidSignature:
            return False


#: the MAC under the public all-zero key: integrity only, for tools and tests (no link takes it)
PLAIN = Mac(bytes(32))


class Header(NamedTuple):
    """The fields of a frame's header that :func:`parse` checked."""

    kind: int
    session: int
    counter: int
    seq: int


def seal(kind: int, session: int, counter: int, seq: int, payload: bytes, mac: Mac,
         sent_s: float = 0.0) -> bytes:
    """One frame: the header (``sent_s``: the send time, s), ``payload`` and the tag under ``mac``."""
    head = _HEADER.pack(MAGIC, WIRE_VERSION, kind, len(payload), session, counter, seq, sent_s) + payload
    return head + mac.tag(head)


def parse(data: bytes) -> Header:
    """The header of a frame whose layout is right (magic, version, a known type, its length);
    MessageError("wire: <reason>") if not. The tag is not checked here (:func:`verified`)."""
    if len(data) < HEADER_SIZE + TAG_SIZE:
        raise MessageError(f"wire: frame too short ({len(data)} bytes)")
    magic, version, kind, length, session, counter, seq, _ = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise MessageError(f"wire: bad magic {magic!r}")
    if version != WIRE_VERSION:
        raise MessageError(f"wire: unsupported version {version} (this side speaks {WIRE_VERSION})")
    size = _SIZES.get(kind)
    if size is None:
        raise MessageError(f"wire: unknown message type {kind}")
    if length != size or len(data) != HEADER_SIZE + length + TAG_SIZE:
        raise MessageError(f"wire: bad length (header says {length}, type {kind} needs "
                           f"{size}, frame has {len(data)} bytes)")
    return Header(kind, session, counter, seq)


def verified(data: bytes, mac: Mac) -> bool:
    """True when the frame's tag verifies under ``mac`` (the layout :func:`parse`'d first)."""
    n = len(data) - TAG_SIZE
    view = memoryview(data)
    return mac.ok(view[:n], view[n:])


def payload(data: bytes) -> bytes:
    """The payload bytes of a parsed frame."""
    return data[HEADER_SIZE: len(data) - TAG_SIZE]


def pack_message(msg: ToolCommand | ContactFeedback, stamps: Stamps = NO_STAMPS) -> tuple[int, bytes]:
    """The type and payload of one message (a reply's with ``stamps``' echo of its command): the
    layouts :data:`_COMMAND` and :data:`_FEEDBACK`, the float runs written as arrays' bytes."""
    if isinstance(msg, ToolCommand):
        head = _D.pack(msg.t_s) + _cat((msg.p_m, msg.R.reshape(-1), msg.v_m_s, msg.w_rad_s)).tobytes()
        return TYPE_COMMAND, (head + (b"\x01" if msg.clutch else b"\x00") + msg.energy_J.tobytes()
                              + _D.pack(msg.wall_N))
    if isinstance(msg, ContactFeedback):
        tail = _cat((msg.energy_J, msg.damping_P[_UPPER], msg.twist_P, msg.plane_P,
                     (stamps.echo_sent_s, stamps.echo_received_s, stamps.echo_applied_s)))
        return TYPE_FEEDBACK, (_D.pack(msg.t_s) + msg.wrench_P.tobytes()
                               + _STATUS_SEQ.pack(SLAVE_STATUSES.index(msg.status), msg.command_seq) + tail.tobytes())
    raise MessageError(f"wire.encode: not a link message: {type(msg).__name__}")


def encode(msg: ToolCommand | ContactFeedback, mac: Mac = PLAIN, session: int = 0, counter: int = 0,
           stamps: Stamps = NO_STAMPS) -> bytes:
    """The frame of one message (bytes), tagged under ``mac``, carrying ``stamps`` (its send time;
    a reply's echo of its command's)."""
    kind, body = pack_message(msg, stamps)
    return seal(kind, session, counter, msg.seq, body, mac, stamps.sent_s)


def stamps(data: bytes) -> Stamps:
    """The stamps a message frame carries (:func:`decode` checked them finite)."""
    sent = struct.unpack_from("<d", data, _SENT_AT)[0]
    if data[5] == TYPE_FEEDBACK:
        return Stamps(sent, *_ECHO.unpack_from(data, len(data) - TAG_SIZE - _ECHO.size))
    return Stamps(sent)


def encoded_size(msg: ToolCommand | ContactFeedback) -> int:
    """Bytes on the wire of ``msg`` (frame only, no transport overhead)."""
    return COMMAND_SIZE if isinstance(msg, ToolCommand) else FEEDBACK_SIZE


def decode(data: bytes | bytearray | memoryview, mac: Mac = PLAIN) -> ToolCommand | ContactFeedback:
    """The message of one frame tagged under ``mac``; MessageError("wire: <reason>") if the frame
    is not valid."""
    data = bytes(data)
    head = parse(data)
    if not verified(data, mac):
        raise MessageError("wire: bad MAC (not made with this key, or changed on the way)")
    return unpack_message(head, data)


def unpack_message(head: Header, data: bytes) -> ToolCommand | ContactFeedback:
    """The message of a parsed and verified frame; MessageError if its values are not valid."""
    kind, seq = head.kind, head.seq
    layout = _PAYLOAD.get(kind)
    if layout is None:
        raise MessageError(f"wire: type {kind} is not a message")
    if seq >= MAX_SEQ:
        raise MessageError(f"wire: sequence number out of range ({seq})")
    v = layout.unpack_from(data, HEADER_SIZE)
    floats = v[:19] + v[20:] if kind == TYPE_COMMAND else v[:7] + v[9:]
    if not (all(math.isfinite(x) for x in floats) and math.isfinite(_D.unpack_from(data, _SENT_AT)[0])):
        raise MessageError("wire: non-finite value in payload")
    if kind == TYPE_COMMAND:
        if v[19] > 1:
            raise MessageError(f"wire: bad clutch byte {v[19]}")
        return ToolCommand(seq=seq, t_s=v[0], p_m=np.array(v[1:4]), R=np.array(v[4:13]).reshape(3, 3),
                           v_m_s=np.array(v[13:16]), w_rad_s=np.array(v[16:19]), clutch=bool(v[19]),
                           energy_J=np.array(v[20:26]), wall_N=v[26])
    if v[7] >= len(SLAVE_STATUSES):
        raise MessageError(f"wire: unknown status index {v[7]}")
    D = np.empty((6, 6))
    D[_UPPER] = v[15:36]
    D.T[_UPPER] = v[15:36]
    return ContactFeedback(seq=seq, t_s=v[0], wrench_P=np.array(v[1:7]), status=SLAVE_STATUSES[v[7]],
                           command_seq=v[8], energy_J=np.array(v[9:15]), damping_P=D, twist_P=np.array(v[36:42]),
                           plane_P=np.array(v[42:50]))
