"""The simulated cobot is a python-can interface plugin: ``can.Bus(interface="teleop_cobot")``."""

import can
import numpy as np
import pytest

from teleop.master.cobot.database import Decoded, FrameDatabase
from teleop.master.cobot.plugin import CobotBus


def test_entry_point_registered():
    assert "teleop_cobot" in can.interfaces.VALID_INTERFACES
    assert can.interfaces.BACKENDS["teleop_cobot"] == ("teleop.master.cobot.plugin", "CobotBus")


def test_device_answers_sync_through_can_bus():
    db = FrameDatabase()
    with can.Bus(interface="teleop_cobot", channel="cobot0", seed=3) as bus:
        assert isinstance(bus, CobotBus)
        assert bus.protocol == can.CanProtocol.CAN_FD  # every frame of the protocol is CAN FD
        fid, data, fd = db.encode("SYNC", {"SyncCounter": 5})
        bus.send(can.Message(arbitration_id=fid, data=data, is_fd=fd, bitrate_switch=fd, is_extended_id=False))
        got = {}
        for _ in range(50):  # simulated polls of 0.1 ms each
            msg = bus.recv(timeout=0.0)
            if msg is not None:
                out = db.decode_message(msg)
                assert isinstance(out, Decoded)
                got[out.name] = out
        assert {"DEV_JOINTS", "DEV_WRENCH", "DEV_HEARTBEAT"} <= set(got)
        joints = got["DEV_JOINTS"]
        assert joints.signals["JointsCounter"] == 5
        assert joints.signals["AngB"] == pytest.approx(np.pi / 2, abs=5e-4)
        assert 0.0 < joints.timestamp < 5e-3  # simulated seconds


def test_simulated_time_is_deterministic():
    def run(seed):
        db = FrameDatabase()
        with can.Bus(interface="teleop_cobot", seed=seed) as bus:
            fid, data, fd = db.encode("SYNC", {"SyncCounter": 1})
            bus.send(can.Message(arbitration_id=fid, data=data, is_fd=fd, bitrate_switch=fd, is_extended_id=False))
            frames = (bus.recv(0.0) for _ in range(30))
            return [(m.arbitration_id, bytes(m.data), m.timestamp) for m in frames if m is not None]
    assert run(7) == run(7)
