"""The driver against the device simulator, back to back on python-can's virtual bus."""

import uuid

import can
import numpy as np
import pytest

from teleop.master.cobot.database import FrameDatabase
from teleop.master.cobot.driver import CAN_ERR_ACK, CAN_ERR_BUSOFF, CAN_ERR_CNT, CAN_ERR_PROT, CobotDriver
from teleop.master.cobot.model import CobotModel
from teleop.master.cobot.plant import CobotPlant, DeviceParams
from teleop.master.cobot.simulator import CobotSimulator

STILL = np.zeros(6)  # the joint rates a cycle commands unless told


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

    def cycle(self, qd=STILL):
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
    link.dev_bus.send(can.Message(arbitration_id=0x040, data=bytes(20), is_fd=True, is_extended_id=False))
    link.dev_bus.send(can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False))
    link.driver.read()
    assert link.driver.stats()["can_frames_rejected"] == 2
    assert link.driver.rejected["checksum"] == 1 and link.driver.rejected["unknown_id"] == 1
    assert np.array_equal(link.driver.joints_rad_m, before)
    # one error frame, even one that says bus-off, latches nothing: it is one count
    link.dev_bus.send(can.Message(arbitration_id=CAN_ERR_BUSOFF, is_error_frame=True, data=bytes(8)))
    link.driver.read()
    assert link.driver.fault is None and link.driver.errors.tec == 8
    link.close()


def test_a_valid_frame_with_the_wrong_id_type_or_fd_flag_is_rejected():
    link = Link()
    link.driver.start(link.joints0)
    link.cycle()
    fid, data, _ = link.driver.db.encode("DEV_EMERGENCY", {"EmcyCode": 1, "EmcyCounter": 0})
    link.dev_bus.send(can.Message(arbitration_id=fid, data=data, is_fd=True, is_extended_id=True))
    link.dev_bus.send(can.Message(arbitration_id=fid, data=data, is_fd=False, is_extended_id=False))
    link.driver.read()
    assert link.driver.fault is None
    assert link.driver.rejected["id_type"] == 1 and link.driver.rejected["fd_flag"] == 1
    link.dev_bus.send(can.Message(arbitration_id=fid, data=data, is_fd=True, is_extended_id=False))
    link.driver.read()
    assert link.driver.fault == "device_emergency"  # the same frame, well-formed
    link.close()


def test_error_counters_follow_iso_11898_fault_confinement():
    """Receive errors (+1 REC) never take the host off the bus; transmit errors (+8 TEC) make it
    error-passive at 128 (it keeps running) and bus-off at 256 (latched); valid traffic counts
    down. Reference: ISO 11898-1 fault confinement, hand-counted."""
    link = Link()
    link.driver.start(link.joints0)
    link.cycle()

    def err(eid, d=bytes(8)):
        return can.Message(arbitration_id=eid, is_error_frame=True, data=d)

    for _ in range(200):  # receive errors: 200 error frames from other nodes
        link.dev_bus.send(err(CAN_ERR_PROT))
    link.driver.max_frames_per_read = 1000
    link.driver.read()
    d = link.driver
    assert d.errors.rec == 200 and d.errors.state == "error_passive" and d.fault is None
    _n, fault = link.cycle()  # valid frames: REC from above 127 drops back to 127, then counts down
    assert fault is None and d.errors.rec < 127
    for _ in range(15):  # 15 transmit errors (no ACK): TEC 120, error-active
        link.dev_bus.send(err(CAN_ERR_ACK))
    d.read()
    tec = d.errors.tec
    assert 100 <= tec <= 120 and d.fault is None
    for _ in range(2):
        link.dev_bus.send(err(CAN_ERR_ACK))
    d.read()
    assert d.errors.state == "error_passive" and d.fault is None and d.stats()["can_error_state"] == "error_passive"
    for _ in range(17):
        link.dev_bus.send(err(CAN_ERR_ACK))
    d.read()
    assert d.errors.tec == 256 and d.fault == "bus_off"
    link.close()


def test_controller_counters_override_the_count():
    link = Link()
    link.driver.start(link.joints0)
    data = bytes([0, 0, 0, 0, 0, 0, 130, 5])  # SocketCAN CAN_ERR_CNT: TEC in data[6], REC in data[7]
    link.dev_bus.send(can.Message(arbitration_id=CAN_ERR_CNT, is_error_frame=True, data=data))
    link.driver.read()
    assert (link.driver.errors.tec, link.driver.errors.rec) == (130, 5) and link.driver.fault is None
    link.close()


def test_one_read_takes_at_most_the_bound_and_a_flood_trips_the_watchdog():
    """20 000 frames queued (a babbling node): a read takes 64; the feedback behind the flood is
    stale, so the watchdog trips within stale_cycles, in bounded time per cycle."""
    import time
    link = Link(stale_cycles=3)
    link.driver.start(link.joints0)
    link.cycle()
    junk = can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False)
    for _ in range(20_000):
        link.dev_bus.send(junk)
    t0 = time.perf_counter()
    faults = [link.cycle()[1] for _ in range(3)]
    per_cycle = (time.perf_counter() - t0) / 3
    assert link.driver.read_bound_hits == 3 and link.driver.frames_rx <= 4 + 3 * 64 + 10
    assert faults[-1] == "watchdog"
    assert per_cycle < 0.1  # 64 frames, not 20 000 (a bound, not a benchmark)
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


@pytest.mark.parametrize("kind, axis", [("sensor_nan", 2), ("sensor_stuck", 0)])
def test_device_refuses_a_bad_load_cell_with_emergency_code_4(kind, axis):
    """The firmware's own checks: a NaN sample at once, a load cell without new samples after 3
    SYNCs: servos to zero, state fault, DEV_EMERGENCY code 4, host fault device_emergency."""
    link = Link()
    link.driver.start(link.joints0)
    for _ in range(3):
        link.cycle(np.array([0.02, 0, 0, 0, 0, 0]))
    link.sim.inject_sensor_fault(kind, link.t, axis=axis)
    faults = [link.cycle(np.array([0.02, 0, 0, 0, 0, 0]))[1] for _ in range(5)]
    first = next(i for i, f in enumerate(faults) if f is not None)
    assert faults[first] == "device_emergency" and first <= (1 if kind == "sensor_nan" else 4)
    assert link.sim.state == 3 and np.all(link.device.qd_cmd == 0.0)
    link.close()


def test_an_encoder_jump_beyond_what_the_device_can_move_is_a_fault():
    """0.5 mm in one 1 ms period passes (0.5 m/s x 1 ms x 1.5 + 2 counts = 0.8 mm is the bound);
    2 mm latches encoder_fault and the jumped reading is not applied."""
    step_max = 1.5 * np.array([0.5] * 3 + [10.0] * 3) * 1e-3 + 2 * np.array([25e-6] * 3 + [5e-4] * 3)
    for size, fault in ((0.5e-3, None), (2e-3, "encoder_fault")):
        link = Link(encoder_step_max=step_max)
        link.driver.start(link.joints0)
        link.cycle()
        link.sim.inject_sensor_fault("encoder_jump", link.t, axis=1, size=size)
        _, got = link.cycle()
        assert got == fault
        if fault:
            assert link.driver.joints_rad_m[1] == pytest.approx(link.joints0[1], abs=3e-5)
        link.close()


class Wire:
    """The driver on a lockstep channel with a bare device end whose frames are built by cantools
    and crccheck (not by the project's codec)."""

    def __init__(self, step_max=0.01):
        ch = f"wire-{uuid.uuid4().hex}"
        self.db = FrameDatabase()
        self.driver = CobotDriver(can.Bus(interface="teleop_lockstep", channel=ch), self.db, clock=lambda: 0.0,
                                  own_bus=True, encoder_step_max=[step_max] * 6)
        self.dev = can.Bus(interface="teleop_lockstep", channel=ch)

    def device_frame(self, name, **signals):
        from crccheck.crc import Crc32
        msg = self.db.message(name)
        ck = next(s.name for s in msg.signals if s.name.endswith("Checksum"))
        body = msg.encode({**signals, ck: 0}, strict=True)[:-4]
        crc = Crc32.calc(msg.frame_id.to_bytes(2, "little") + body)
        self.dev.send(can.Message(arbitration_id=msg.frame_id, data=body + crc.to_bytes(4, "little"), is_fd=True,
                                  is_extended_id=False))

    def joints(self, counter, x=0.01):
        self.device_frame("DEV_JOINTS", PosX=x, PosY=0.0, PosZ=0.0, AngA=0.0, AngB=0.0, AngC=3.1, DevState=2,
                          JointsCounter=counter)

    def host_frames(self):
        out = []
        while (m := self.dev.recv(timeout=0.0)) is not None:
            out.append(self.db.db.decode_message(m.arbitration_id, bytes(m.data), decode_choices=False))
        return out

    def close(self):
        self.driver.close()
        self.dev.shutdown()


def test_period_frames_counters_late_future_and_unwrapping():
    """Joints of SYNC 1 then 0 (late: dropped), a counter never sent (rejected), a wrist angle
    across ±pi (unwrapped next to the last reading)."""
    w = Wire(step_max=0.1)
    w.driver.start(np.zeros(6) + [0, 0, 0, 0, 0, 3.1])
    for _ in range(2):
        w.driver.send_sync()
    w.joints(1)
    w.joints(0)
    w.joints(7)  # SYNC 7 was never sent
    assert w.driver.read() == 3
    assert w.driver.joints_counter == 1 and w.driver.frames_late == 1
    assert w.driver.stats()["can_rejected_by_reason"] == {"counter": 1}
    w.driver.send_sync()
    w.device_frame("DEV_JOINTS", PosX=0.01, PosY=0.0, PosZ=0.0, AngA=0.0, AngB=0.0, AngC=-3.14, DevState=2,
                   JointsCounter=2)
    w.driver.read()
    assert w.driver.joints_rad_m[5] == pytest.approx(2 * np.pi - 3.14, abs=1e-3)  # not -3.14: unwrapped
    assert w.driver.fault is None
    w.close()


def test_the_command_frame_is_clipped_as_cantools_reads_it():
    w = Wire()
    w.driver.start()
    w.host_frames()
    w.driver.send_command(np.array([2.0, -0.5, 0.25, -20.0, 3.0, 0.0]), np.array([0.3, 0.3, 0.3, 10.0, 10.0, 10.0]))
    w.driver.send_command(np.array([np.nan, 0, 0, 0, 0, 0]))
    first, second = w.host_frames()
    assert [first[k] for k in ("CmdVelX", "CmdVelY", "CmdVelZ", "CmdRateA", "CmdRateB", "CmdRateC")] == \
        pytest.approx([0.3, -0.3, 0.25, -10.0, 3.0, 0.0], abs=3.1e-5)
    assert first["CmdMode"] == 1 and first["CmdCounter"] == 0
    assert second["CmdMode"] == 0 and second["CmdVelX"] == 0 and second["CmdCounter"] == 1  # non-finite: zero
    w.close()


def test_an_encoder_jump_latches_the_fault_and_leaves_the_reading():
    w = Wire()
    w.driver.start(np.zeros(6) + [0, 0, 0, 0, 0, 3.1])
    w.driver.send_sync()
    w.joints(0, x=0.01)
    w.driver.read()
    w.driver.send_sync()
    w.joints(1, x=0.05)  # 40 mm in one SYNC, the limit 10 mm
    w.driver.read()
    assert w.driver.fault == "encoder_fault" and w.driver.joints_rad_m[0] == pytest.approx(0.01, abs=3e-5)
    assert w.driver.stats()["can_rejected_by_reason"] == {"encoder_jump": 1}
    w.close()
