"""The driver against the device simulator, back to back on python-can's virtual bus."""

import uuid

import can
import numpy as np
import pytest

from teleop.master.cobot.database import FrameDatabase
from teleop.master.cobot.driver import CobotDriver
from teleop.master.cobot.simulator import CobotSimulator
from teleop.master.cobot.driver import CAN_ERR_BUSOFF
from teleop.master.cobot.model import CobotModel
from teleop.master.cobot.plant import CobotPlant, DeviceParams


class Link:
    """A driver and a simulated device on one private virtual channel, in simulated time."""

    def __init__(self, **driver_kw):
        ch = f"test-{uuid.uuid4().hex}"
        self.t = 0.0
        self.host = can.Bus(interface="virtual", channel=ch, fd=True, preserve_timestamps=True)
        self.dev_bus = can.Bus(interface="virtual", channel=ch, fd=True, preserve_timestamps=True)
        self.model = CobotModel()
        self.joints0 = np.array([0.01, -0.02, 0.03, 0.2, 1.4, -3.1])
        self.device = CobotPlant(self.model, DeviceParams(force_noise_N=0, torque_noise_Nm=0, force_bias_N=(0, 0, 0),
                                                           torque_bias_Nm=(0, 0, 0)), self.joints0,
                                  np.random.default_rng(0))
        self.sim = CobotSimulator(self.dev_bus, self.device, np.random.default_rng(1))
        self.driver = CobotDriver(self.host, FrameDatabase(), clock=lambda: self.t, own_bus=True, **driver_kw)

    def cycle(self, qd=np.zeros(6)):
        self.driver.send_sync()
        self.driver.send_heartbeat()
        self.t += 3e-4
        self.sim.advance_to(self.t)
        n = self.driver.read()
        fault = self.driver.end_cycle()
        self.driver.send_command(qd)
        self.t += 7e-4
        self.sim.advance_to(self.t)
        return n, fault

    def close(self):
        self.driver.close()
        self.dev_bus.shutdown()


def test_back_to_back_feedback_in_si_units():
    link = Link()
    link.driver.start(link.joints0)
    link.device.hand_wrench_W = np.array([1.0, -2.0, 3.0, 0.01, 0.02, -0.03])
    n, fault = link.cycle()
    assert n >= 2 and fault is None
    d = link.driver
    assert np.allclose(d.joints_rad_m, link.joints0, atol=2.6e-4)  # encoder quantum / 2 (+ unwrap)
    assert d.joints_rad_m[5] == pytest.approx(-3.1, abs=3e-4)
    _, R = link.model.compute_handle_pose(link.joints0)
    expected = link.device.hand_wrench_W + link.model.compute_distal_wrench_W(R, np.zeros(3), np.zeros(3), np.zeros(3))
    assert np.allclose(d.wrench_S[:3], R.T @ expected[:3], atol=0.006)
    assert np.allclose(d.wrench_S[3:], R.T @ expected[3:], atol=3e-4)
    link.close()


def test_velocity_commands_move_the_device_and_angles_unwrap():
    link = Link()
    link.driver.start(link.joints0)
    qd = np.array([0.05, 0.0, -0.02, 0.0, 0.0, -2.0])
    for _ in range(200):
        link.cycle(qd)
    assert link.sim.state == 2  # running
    assert link.device.joints[0] == pytest.approx(0.01 + 0.05 * 0.2, abs=1e-3)
    # the continuous joint crossed -pi: the driver unwraps the wrapped encoder angle
    assert link.driver.joints_rad_m[5] == pytest.approx(link.device.joints[5], abs=0.01)
    assert link.driver.joints_rad_m[5] < -np.pi
    link.close()


def test_nonfinite_command_sends_zero_and_close_is_safe_twice():
    link = Link()
    with link.driver:
        link.driver.joints_rad_m = link.joints0.copy()
        link.cycle(np.array([0.1, 0, 0, 0, 0, 0]))
        link.cycle(np.array([np.nan, 0, 0, 0, 0, 0]))
        link.cycle(np.array([np.nan, 0, 0, 0, 0, 0]))
        assert np.all(link.device.qd_cmd == 0.0)
    link.driver.close()
    link.close()


def test_silent_device_trips_the_watchdog_in_three_cycles():
    link = Link(stale_cycles=3)
    link.driver.start(link.joints0)
    link.cycle()
    link.sim.faults = type(link.sim.faults)(silent_after_s=link.t)
    faults = [link.cycle()[1] for _ in range(3)]
    assert faults[:2] == [None, None] and faults[2] == "watchdog"
    assert link.driver.watchdog_trips == 1
    link.cycle(np.ones(6) * 0.1)  # after the fault only zero velocity goes out
    assert np.all(link.device.qd_cmd == 0.0)
    link.close()


def test_garbage_and_error_frames_are_counted_not_applied():
    link = Link()
    link.driver.start(link.joints0)
    link.cycle()
    before = link.driver.joints_rad_m.copy()
    link.dev_bus.send(can.Message(arbitration_id=0x180, data=bytes(16), is_fd=True, is_extended_id=False))
    link.dev_bus.send(can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False))
    link.driver.read()
    assert link.driver.stats()["can_frames_rejected"] == 2
    assert np.array_equal(link.driver.joints_rad_m, before)
    link.dev_bus.send(can.Message(arbitration_id=CAN_ERR_BUSOFF, is_error_frame=True, data=bytes(8)))
    link.driver.read()
    assert link.driver.fault == "bus_off"
    link.close()


def test_device_stops_without_host_heartbeat():
    link = Link()
    link.driver.start(link.joints0)
    for _ in range(5):
        link.cycle(np.array([0.02, 0, 0, 0, 0, 0]))
    for _ in range(80):  # commands keep coming, heartbeats stop
        link.driver.send_sync()
        link.driver.send_command(np.array([0.02, 0, 0, 0, 0, 0]))
        link.t += 1e-3
        link.sim.advance_to(link.t)
    assert link.sim.state == 3 and np.all(link.device.qd_cmd == 0.0)
    link.close()
