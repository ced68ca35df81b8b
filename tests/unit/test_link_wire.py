"""The binary wire format: round trip, sizes, the tag (HMAC-SHA256) under its key only, corrupted
frames refused; the project's CRC (the CAN frames') against crccheck."""

import struct

import numpy as np
import pytest
from crccheck.crc import Crc32
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from teleop.link import wire
from teleop.link.latency import Stamps
from teleop.tick.messages import SLAVE_STATUSES, ContactFeedback, MessageError, ToolCommand
from teleop.util.crc32 import crc32

finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
energy = st.floats(0.0, 1e6, allow_nan=False, allow_infinity=False)
seqs = st.integers(0, 2**63 - 1)


@st.composite
def commands(draw):
    q = draw(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: sum(x * x for x in q) > 1e-3))
    return ToolCommand(seq=draw(seqs), t_s=draw(finite), p_m=draw(st.lists(finite, min_size=3, max_size=3)),
                       R=Rotation.from_quat(q).as_matrix(), v_m_s=draw(st.lists(finite, min_size=3, max_size=3)),
                       w_rad_s=draw(st.lists(finite, min_size=3, max_size=3)), clutch=draw(st.booleans()),
                       energy_J=draw(st.lists(energy, min_size=6, max_size=6)), wall_N=draw(energy))


@st.composite
def feedbacks(draw):
    A = np.array(draw(st.lists(finite, min_size=36, max_size=36))).reshape(6, 6)
    D = None if draw(st.booleans()) else np.triu(A) + np.triu(A, 1).T  # symmetric (the layout sends 21)
    return ContactFeedback(seq=draw(seqs), t_s=draw(finite), wrench_P=draw(st.lists(finite, min_size=6, max_size=6)),
                           status=draw(st.sampled_from(SLAVE_STATUSES)), command_seq=draw(st.integers(-1, 2**63 - 1)),
                           energy_J=draw(st.lists(energy, min_size=6, max_size=6)), damping_P=D,
                           twist_P=draw(st.lists(finite, min_size=6, max_size=6)))


def _same(a, b):
    assert type(a) is type(b)
    for name in a.__slots__:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y)
        else:
            assert x == y, name


@settings(max_examples=200, deadline=None)
@given(st.one_of(commands(), feedbacks()))
def test_round_trip_is_exact(msg):
    data = wire.encode(msg)
    assert len(data) == wire.encoded_size(msg)
    _same(wire.decode(data), msg)


@settings(max_examples=200, deadline=None)
@given(st.one_of(commands(), feedbacks()), st.lists(finite, min_size=3, max_size=3))
def test_the_payload_is_the_documented_layout(msg, echo):
    """What pack_message writes reads back field by field with ``struct`` and the documented
    layouts (not with the decoder), in their order: the bytes on the wire, not only the round trip."""
    stamps = Stamps(0.0, *echo)
    kind, body = wire.pack_message(msg, stamps)
    if isinstance(msg, ToolCommand):
        v = struct.unpack("<19dB7d", body)
        want = (msg.t_s, *msg.p_m, *msg.R.reshape(-1), *msg.v_m_s, *msg.w_rad_s, int(msg.clutch), *msg.energy_J,
                msg.wall_N)
        assert kind == wire.TYPE_COMMAND
    else:
        v = struct.unpack("<7dBq44d", body)
        D = msg.damping_P
        want = (msg.t_s, *msg.wrench_P, SLAVE_STATUSES.index(msg.status), msg.command_seq, *msg.energy_J,
                *(D[i, j] for i in range(6) for j in range(i, 6)), *msg.twist_P, *msg.plane_P, *echo)
        assert kind == wire.TYPE_FEEDBACK
    assert v == tuple(float(x) if isinstance(x, (float, np.floating)) else x for x in want)


@settings(max_examples=100, deadline=None)
@given(st.binary(min_size=0, max_size=300))
def test_crc_is_crccheck_crc32(data):
    assert crc32(data) == Crc32.calc(data)


@settings(max_examples=50, deadline=None)
@given(st.one_of(commands(), feedbacks()), st.integers(0, 2**64 - 1), st.integers(0, 2**64 - 1))
def test_a_frame_verifies_under_its_key_only(msg, session, counter):
    key, other = wire.Mac(bytes(range(32))), wire.Mac(bytes(range(1, 33)))
    data = wire.encode(msg, key, session, counter)
    assert wire.parse(data) == (wire.pack_message(msg)[0], session, counter, msg.seq)
    _same(wire.decode(data, key), msg)
    for mac in (other, wire.PLAIN):
        with pytest.raises(MessageError, match="bad MAC"):
            wire.decode(data, mac)


def _cmd():
    return ToolCommand(seq=7, t_s=0.5, p_m=[0.1, 0.2, 0.3], R=np.eye(3), v_m_s=[1, 2, 3], w_rad_s=[0, 0, 1])


def _refit(data: bytes) -> bytes:
    """Recompute the tag so a deliberately malformed frame passes the MAC check."""
    body = data[:-wire.TAG_SIZE]
    return body + wire.PLAIN.tag(body)


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_any_flipped_bit_is_refused(data):
    frame = bytearray(wire.encode(_cmd()))
    i = data.draw(st.integers(0, len(frame) - 1))
    frame[i] ^= 1 << data.draw(st.integers(0, 7))
    with pytest.raises(MessageError, match="wire"):
        wire.decode(bytes(frame))


@pytest.mark.parametrize("mangle, reason", [
    (lambda f: b"XLNK" + f[4:], "magic"),
    (lambda f: _refit(f[:4] + bytes([9]) + f[5:]), "version"),
    (lambda f: _refit(f[:5] + bytes([3]) + f[6:]), "type"),
    (lambda f: f[:-1], "length"),
    (lambda f: f + b"\0", "length"),
    (lambda f: _refit(f[:5] + bytes([2]) + f[6:]), "length"),
    (lambda f: f[:-4] + bytes(4), "MAC"),
    (lambda f: _refit(f[:32] + struct.pack("<d", float("nan")) + f[40:]), "non-finite"),
    (lambda f: _refit(f[:40] + struct.pack("<d", float("inf")) + f[48:]), "non-finite"),
    (lambda f: _refit(f[:24] + struct.pack("<Q", 2**63) + f[32:]), "sequence"),
    (lambda f: b"", "short"),
])
def test_corrupted_frames_name_the_reason(mangle, reason):
    with pytest.raises(MessageError, match=reason):
        wire.decode(mangle(wire.encode(_cmd())))


def test_a_negative_wall_force_is_refused_by_name():
    """wire v7's last command field (the master's contact wall, N): a frame carrying a negative
    one, correctly tagged, is still not a command a master makes."""
    frame = wire.encode(_cmd())
    n = len(frame) - wire.TAG_SIZE
    with pytest.raises(MessageError, match="wall_N"):
        wire.decode(_refit(frame[:n - 8] + struct.pack("<d", -1.0) + frame[n:]))


def test_encode_refuses_other_objects():
    with pytest.raises(MessageError):
        wire.encode(object())
