"""The lockstep bus's polling fast path gives what python-can's ``BusABC.recv`` gives: the same
frames in order (an empty payload included) and filters still applied."""

import uuid

import can
import pytest

from teleop.can.lockstep import LockstepBus


def _frames():
    return [can.Message(arbitration_id=0x180 + i, data=bytes(range(i)), is_extended_id=False) for i in (3, 0, 8, 1)]


def _drain(bus, recv):
    out = []
    for _ in range(6):
        msg = recv(bus)
        out.append(None if msg is None else (msg.arbitration_id, bytes(msg.data)))
    return out


@pytest.mark.parametrize("filters", [None, [{"can_id": 0x188, "can_mask": 0x7FF}]])
def test_poll_matches_the_base_class(filters):
    results = []
    for recv in (lambda b: b.recv(timeout=0.0), lambda b: can.BusABC.recv(b, timeout=0.0)):
        ch = f"t-{uuid.uuid4().hex}"
        tx, rx = LockstepBus(ch), LockstepBus(ch, can_filters=filters)
        for msg in _frames():
            tx.send(msg)
        results.append(_drain(rx, recv))
        tx.shutdown()
        rx.shutdown()
    assert results[0] == results[1]
    got = [r for r in results[0] if r is not None]
    assert got == ([(0x188, bytes(range(8)))] if filters else [(0x183, bytes(range(3))), (0x180, b""),
                                                                (0x188, bytes(range(8))), (0x181, bytes(range(1)))])
