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
        ch = self.ch = f"test-{uuid.uuid4().hex}"
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


def crc_of(frame_id: int, body: bytes, sync: int) -> int:
    """The wire CRC of a frame tied to a SYNC, by crccheck (not the project's CRC): CRC-32/ISO-HDLC
    of the frame id (2 bytes LE), the payload before the CRC and the full SYNC count (4 bytes LE)."""
    from crccheck.crc import Crc32
    return Crc32.calc(frame_id.to_bytes(2, "little") + body + sync.to_bytes(4, "little"))


class Wire:
    """The driver on a lockstep channel with a bare device end whose frames are built by cantools
    and crccheck (not by the project's codec)."""

    def __init__(self, step_max=0.01, wrench_step_max=None):
        ch = f"wire-{uuid.uuid4().hex}"
        self.db = FrameDatabase()
        self.driver = CobotDriver(can.Bus(interface="teleop_lockstep", channel=ch), self.db, clock=lambda: 0.0,
                                  own_bus=True, encoder_step_max=[step_max] * 6, wrench_step_max=wrench_step_max)
        self.dev = can.Bus(interface="teleop_lockstep", channel=ch)

    def device_bytes(self, name, sync, **signals) -> bytes:
        """A device frame answering the SYNC of full count ``sync``: its counter the low byte, its
        CRC over the full count."""
        msg = self.db.message(name)
        ck = next(s.name for s in msg.signals if s.name.endswith("Checksum"))
        ctr = next(s.name for s in msg.signals if s.name.endswith("Counter"))
        body = msg.encode({**signals, ctr: sync % 256, ck: 0}, strict=True)[:-4]
        return body + crc_of(msg.frame_id, body, sync).to_bytes(4, "little")

    def send(self, name, data: bytes):
        self.dev.send(can.Message(arbitration_id=self.db.message(name).frame_id, data=data, is_fd=True,
                                  is_extended_id=False))

    def device_frame(self, name, sync, **signals):
        self.send(name, self.device_bytes(name, sync, **signals))

    def joints(self, sync, x=0.01):
        self.device_frame("DEV_JOINTS", sync, PosX=x, PosY=0.0, PosZ=0.0, AngA=0.0, AngB=0.0, AngC=3.1, DevState=2)

    def wrench_bytes(self, sync, fx=0.0) -> bytes:
        return self.device_bytes("DEV_WRENCH", sync, ForceX=fx, ForceY=0.0, ForceZ=0.0, TorqueX=0.0, TorqueY=0.0,
                                 TorqueZ=0.0)

    def host_frames(self, name=None):
        """The host's frames since the last call (those of message ``name``), decoded by cantools;
        with their payloads."""
        out = []
        while (m := self.dev.recv(timeout=0.0)) is not None:
            if name is None or m.arbitration_id == self.db.message(name).frame_id:
                out.append((self.db.db.decode_message(m.arbitration_id, bytes(m.data), decode_choices=False),
                            bytes(m.data)))
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
    w.device_frame("DEV_JOINTS", 2, PosX=0.01, PosY=0.0, PosZ=0.0, AngA=0.0, AngB=0.0, AngC=-3.14, DevState=2)
    w.driver.read()
    assert w.driver.joints_rad_m[5] == pytest.approx(2 * np.pi - 3.14, abs=1e-3)  # not -3.14: unwrapped
    assert w.driver.fault is None
    w.close()


def test_the_command_frame_is_clipped_as_cantools_reads_it():
    """Each command answers the cycle's SYNC: its counter the SYNC's low byte, its CRC (crccheck's)
    over the full count."""
    w = Wire()
    w.driver.start()
    w.host_frames()
    w.driver.send_sync()
    w.driver.send_command(np.array([2.0, -0.5, 0.25, -20.0, 3.0, 0.0]), np.array([0.3, 0.3, 0.3, 10.0, 10.0, 10.0]))
    w.driver.send_sync()
    w.driver.send_command(np.array([np.nan, 0, 0, 0, 0, 0]))
    (first, data0), (second, data1) = w.host_frames("HOST_CMD")
    assert [first[k] for k in ("CmdVelX", "CmdVelY", "CmdVelZ", "CmdRateA", "CmdRateB", "CmdRateC")] == \
        pytest.approx([0.3, -0.3, 0.25, -10.0, 3.0, 0.0], abs=3.1e-5)
    assert first["CmdMode"] == 1 and first["CmdCounter"] == 0
    assert second["CmdMode"] == 0 and second["CmdVelX"] == 0 and second["CmdCounter"] == 1  # non-finite: zero
    for sync, data in ((0, data0), (1, data1)):
        assert int.from_bytes(data[-4:], "little") == crc_of(0x030, data[:-4], sync)
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


# -- freshness a counter wrap cannot defeat, plausibility of each value against the last (issue 22) --

def joints_bytes(w, sync, x=0.01) -> bytes:
    return w.device_bytes("DEV_JOINTS", sync, PosX=x, PosY=0.0, PosZ=0.0, AngA=0.0, AngB=0.0, AngC=3.1, DevState=2)


def syncs_to(w, count):
    """The host sends SYNCs until its last one has the full count ``count``."""
    while w.driver._sync <= count:
        w.driver.send_sync()


@pytest.mark.parametrize("wraps", [1, 2])
def test_a_frame_recorded_and_replayed_whole_counter_wraps_later_is_stale(wraps):
    """A DEV_JOINTS frame of SYNC 3, replayed 256 (512) SYNCs later, has the counter of the SYNC just
    sent: with an 8-bit counter alone it passed as new. Its CRC covers the full count 3, the host
    checks it with 259 (515): refused as stale, counted, the reading not applied. A replay 40 SYNCs
    past the wrap is stale too; the device's own frame for the SYNC is then applied."""
    w = Wire(step_max=0.1)
    w.driver.start(np.zeros(6) + [0, 0, 0, 0, 0, 3.1])
    syncs_to(w, 3)
    recorded = joints_bytes(w, 3, x=0.01)
    w.send("DEV_JOINTS", recorded)
    w.driver.read()
    assert w.driver.joints_sync == 3 and w.driver.joints_rad_m[0] == pytest.approx(0.01, abs=3e-5)
    syncs_to(w, 3 + 256 * wraps)
    w.send("DEV_JOINTS", recorded)
    assert w.driver.read() == 0
    assert w.driver.rejected == {"stale": 1} and w.driver.joints_sync == 3
    syncs_to(w, 3 + 256 * wraps + 40)
    w.send("DEV_JOINTS", recorded)
    w.driver.read()
    assert w.driver.stats()["can_rejected_by_reason"] == {"stale": 2}
    w.joints(3 + 256 * wraps + 40, x=0.02)
    w.driver.read()
    assert w.driver.joints_sync == 3 + 256 * wraps + 40 and w.driver.joints_rad_m[0] == pytest.approx(0.02, abs=3e-5)
    assert w.driver.fault is None
    w.close()


def test_a_duplicate_or_an_older_frame_is_dropped_as_late():
    """The same frame twice, and a frame of an older SYNC after a newer one: neither applied,
    both counted late (a delayed frame is the common case, so late is not a rejection)."""
    w = Wire(step_max=0.1)
    w.driver.start(np.zeros(6) + [0, 0, 0, 0, 0, 3.1])
    syncs_to(w, 6)
    older = joints_bytes(w, 5, x=0.01)
    newer = joints_bytes(w, 6, x=0.02)
    for data in (newer, newer, older):
        w.send("DEV_JOINTS", data)
    w.driver.read()
    assert w.driver.joints_sync == 6 and w.driver.joints_rad_m[0] == pytest.approx(0.02, abs=3e-5)
    assert w.driver.frames_late == 2 and not w.driver.rejected
    w.close()


#: the load-cell limits of the default cobot at 1 kHz: 50 N, 3 N*m a SYNC (CobotConfig.wrench_rate_max)
WRENCH_STEP = [50.0] * 3 + [3.0] * 3


def wrench_cycle(w, sync, fx):
    """One period on the wire: SYNC ``sync``, the device's joints and a wrench of ForceX ``fx``
    N, read, the cycle's end. Returns the read's count and the fault."""
    syncs_to(w, sync)
    w.joints(sync)
    w.send("DEV_WRENCH", w.wrench_bytes(sync, fx))
    n = w.driver.read()
    return n, w.driver.end_cycle()


def test_a_wrench_jump_of_160_N_in_one_sync_is_refused_and_counted():
    """0 to 159.9 N (the cell's range) in one SYNC: refused (50 N a SYNC is what the load cell can),
    counted as wrench_jump, the last reading kept; the run goes on."""
    w = Wire(wrench_step_max=WRENCH_STEP)
    w.driver.start(np.zeros(6) + [0, 0, 0, 0, 0, 3.1])
    assert wrench_cycle(w, 0, 0.0)[1] is None
    _, fault = wrench_cycle(w, 1, 159.9)
    assert fault is None and w.driver.wrench_S[0] == 0.0 and w.driver.wrench_sync == 0
    assert w.driver.stats()["can_rejected_by_reason"] == {"wrench_jump": 1} and w.driver.wrench_refused == 1
    _, fault = wrench_cycle(w, 2, 0.5)  # the next reading, near the kept one: taken, the spike cost one reading
    assert fault is None and w.driver.wrench_S[0] == pytest.approx(0.5) and w.driver.wrench_refused == 0
    w.close()


def test_the_same_step_spread_over_the_syncs_the_load_cell_needs_is_taken():
    w = Wire(wrench_step_max=WRENCH_STEP)
    w.driver.start(np.zeros(6) + [0, 0, 0, 0, 0, 3.1])
    for sync, fx in enumerate((0.0, 40.0, 80.0, 120.0, 159.9)):
        assert wrench_cycle(w, sync, fx)[1] is None
        assert w.driver.wrench_S[0] == pytest.approx(fx, abs=0.003)
    assert not w.driver.rejected and w.driver.fault is None
    w.close()


def test_the_allowance_grows_with_the_syncs_since_the_last_applied_reading():
    """A real 90 N step: refused at the first SYNC (50 N allowed), taken at the second (100 N
    allowed since the kept reading): the loop never latches on a step the cell can make."""
    w = Wire(wrench_step_max=WRENCH_STEP)
    w.driver.start(np.zeros(6) + [0, 0, 0, 0, 0, 3.1])
    wrench_cycle(w, 0, 0.0)
    wrench_cycle(w, 1, 90.0)
    assert w.driver.wrench_S[0] == 0.0 and w.driver.rejected["wrench_jump"] == 1
    _, fault = wrench_cycle(w, 2, 90.0)
    assert fault is None and w.driver.wrench_S[0] == pytest.approx(90.0, abs=0.003)
    assert w.driver.wrench_sync == 2 and w.driver.cycles_since_wrench == 0
    w.close()


def test_a_load_cell_refused_for_stale_cycles_latches_wrench_fault():
    """A refused reading is not fresh: three refused in a row (stale_cycles 3; 150 N allowed by the
    third) age the wrench like lost frames, and the watchdog latches wrench_fault, named."""
    w = Wire(wrench_step_max=WRENCH_STEP)
    w.driver.start(np.zeros(6) + [0, 0, 0, 0, 0, 3.1])
    wrench_cycle(w, 0, 0.0)
    faults = [wrench_cycle(w, s, 159.9)[1] for s in (1, 2, 3)]
    assert faults == [None, None, "wrench_fault"]
    assert w.driver.rejected == {"wrench_jump": 3} and w.driver.watchdog_trips == 0
    w.close()


def test_a_lost_wrench_is_still_the_watchdog():
    """No refusal, only silence from the load cell: the fault is the watchdog's, as before."""
    w = Wire(wrench_step_max=WRENCH_STEP)
    w.driver.start(np.zeros(6) + [0, 0, 0, 0, 0, 3.1])
    wrench_cycle(w, 0, 0.0)
    faults = []
    for sync in (1, 2, 3):
        syncs_to(w, sync)
        w.joints(sync)
        w.driver.read()
        faults.append(w.driver.end_cycle())
    assert faults == [None, None, "watchdog"]
    w.close()


class Spy:
    """A third node on a Link's channel: sees every frame, can put any back on the wire."""

    def __init__(self, link):
        self.bus = can.Bus(interface="virtual", channel=link.ch, fd=True, preserve_timestamps=True)
        self.db = link.driver.db

    def frames(self, name):
        fid = self.db.message(name).frame_id
        out = []
        while (m := self.bus.recv(timeout=0.0)) is not None:
            if m.arbitration_id == fid:
                out.append(m)
        return out

    def replay(self, msg):
        self.bus.send(can.Message(arbitration_id=msg.arbitration_id, data=bytes(msg.data), is_fd=True,
                                  is_extended_id=False, bitrate_switch=True))

    def close(self):
        self.bus.shutdown()


def test_the_device_refuses_a_sync_that_does_not_advance():
    """The device takes the host's full count from each SYNC: one that repeats the last (a
    duplicate, a replay) or jumps more than 128 ahead is refused, counted, and not answered."""
    link = Link()
    link.driver.start(link.joints0)
    for _ in range(3):
        link.cycle()
    spy = Spy(link)
    last = link.driver._sync - 1
    for count in (last, last - 1, last + 1000):
        fid, data, fd = link.driver.db.encode("SYNC", {"SyncCounter": count})
        spy.bus.send(can.Message(arbitration_id=fid, data=data, is_fd=fd, is_extended_id=False))
    link.t += 3e-4
    link.sim.advance_to(link.t)
    assert link.sim.stats()["device_rejected_by_reason"] == {"sync_stale": 2, "sync_future": 1}
    assert link.sim.sync_count == last and not spy.frames("DEV_JOINTS")  # not answered
    link.cycle()
    assert link.sim.sync_count == last + 1 and link.driver.fault is None
    spy.close()
    link.close()


def test_a_command_replayed_256_syncs_later_is_refused_by_the_device():
    """A run command recorded at one SYNC and replayed 256 SYNCs later carries the counter of the
    SYNC the device just took: its CRC (over the full count) fails, the device refuses it as stale
    and keeps the host's command."""
    link = Link()
    link.driver.start(link.joints0)
    spy = Spy(link)
    link.cycle(np.array([0.05, 0, 0, 0, 0, 0]))
    recorded = spy.frames("HOST_CMD")[-1]
    for _ in range(256):
        link.cycle()
    spy.frames("HOST_CMD")
    link.driver.send_sync()
    link.t += 3e-4
    link.sim.advance_to(link.t)
    spy.replay(recorded)
    link.t += 3e-4
    link.sim.advance_to(link.t)
    assert link.sim.stats()["device_rejected_by_reason"] == {"stale": 1}
    assert np.all(link.device.qd_cmd == 0.0)  # the host's last command (still) stands, not the replay's
    spy.close()
    link.close()


def test_device_frames_replayed_a_wrap_later_are_stale_at_the_host():
    """The same through the simulated device: its DEV_JOINTS and DEV_WRENCH of one SYNC, replayed
    256 SYNCs later, are both refused as stale at the host; the run goes on."""
    link = Link()
    link.driver.start(link.joints0)
    spy = Spy(link)
    link.cycle()
    recorded = spy.frames("DEV_JOINTS")[-1:]
    link.cycle()
    recorded += spy.frames("DEV_WRENCH")[-1:]  # the device's answer to the next SYNC
    for _ in range(255):
        link.cycle()
    for msg in recorded:
        spy.replay(msg)
    _n, fault = link.cycle()
    assert fault is None and link.driver.rejected == {"stale": 2}
    spy.close()
    link.close()
