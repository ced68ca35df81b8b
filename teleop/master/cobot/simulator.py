"""The simulated cobot as a node on a python-can bus, in simulated time: the device's side of the
bus. It alone drives the plant (:class:`.plant.CobotPlant`); the host reaches it only through frames.

python-can's virtual bus delivers instantly, so the simulator keeps the wire's time itself: every
frame, the host's and the device's, goes through a :class:`BusModel` (frame time at the bit rate,
arbitration by id), then through the fault model (loss, corruption, latency, jitter, silence,
bus-off), and the device's frames reach the host bus only when simulated time passes their delivery
time. ``advance_to(t)`` is the lockstep: it processes everything up to t seconds.

Bus-off (``bus_off_at_s``): from then every transmission of the device fails, each with an error
frame on the wire; 32 failures (+8 TEC each, :mod:`teleop.can.confinement`) put the device
bus-off and it falls silent. The host sees 32 error frames as a receiver (+1 REC each: it stays
error-active) and then the silence (its watchdog).

Sensor faults (:meth:`inject_sensor_fault`, for fault campaigns): ``sensor_nan`` (the load cell
reads NaN), ``sensor_stuck`` (the load cell's converter stops delivering new samples),
``encoder_jump`` (a joint's encoder count jumps). The device's firmware checks its own samples
each SYNC: a non-finite one, or no new load-cell sample for ``STUCK_SYNCS`` SYNCs, is a sensor
fault: servos to zero, state fault, DEV_EMERGENCY code 4.

Device behaviour: on SYNC it samples encoders and load cell and answers DEV_JOINTS + DEV_WRENCH
(counters: the SYNC count's low byte; CRCs over its full count, :mod:`.database`); HOST_CMD sets
the servo velocities (mode 0 = zero); DEV_HEARTBEAT every ``heartbeat_period_s``; without a host
heartbeat for ``host_timeout_s`` or a command for ``cmd_timeout_s`` the device zeroes its servos
and sends DEV_EMERGENCY.

Freshness at the device (the host's SYNC count is the freshness value of the session): a SYNC
whose count does not advance past the last one taken (a replay, a duplicate: ``sync_stale``) or
jumps more than :data:`SYNC_WINDOW` ahead (``sync_future``) is refused and not answered. HOST_CMD
is checked with the full count nearest the last SYNC taken (a command replayed whole counter wraps
later fails its CRC: ``stale`` or ``checksum``), and one older than the last command applied, or
a second run command for the same SYNC, is refused (``command_late``; a hold is always taken).
Every refusal is counted by reason (``device_rejected_by_reason`` in :meth:`CobotSimulator.stats`).
The device forgets the host's count when the host has been silent (no heartbeat) for
``host_timeout_s``: a new host starts counting from 0.
"""

from __future__ import annotations

import heapq
from collections import Counter

import can
import numpy as np

from teleop.can.busmodel import BusModel, BusTiming, compute_frame_time_s
from teleop.can.capture import Capture
from teleop.can.confinement import BUS_OFF_LIMIT
from teleop.can.faults import Faults
from teleop.master.cobot.database import Decoded, FrameDatabase
from teleop.master.cobot.driver import CAN_ERR_BUSERROR, CAN_ERR_PROT, CMD_SIGNALS, JOINT_SIGNALS, WRENCH_SIGNALS

STATE_READY, STATE_RUNNING, STATE_FAULT = 1, 2, 3
EMCY_SENSOR_FAULT = 4
WRENCH_LIMITS = np.array([159.9] * 3 + [6.49] * 3)
#: SYNCs without a new load-cell sample that the firmware takes for a stuck sensor
STUCK_SYNCS = 3
SENSOR_FAULTS = ("sensor_nan", "sensor_stuck", "encoder_jump")
#: the most a SYNC's count may advance past the last one taken (SYNCs lost in between); a larger
#: jump is refused as not the host's (the host's watchdog trips long before 128 SYNCs are lost)
SYNC_WINDOW = 128


class CobotSimulator:
    """Plays ``plant`` (a :class:`~teleop.master.cobot.plant.CobotPlant`) on ``bus``. own_bus:
    :meth:`close` shuts the bus down."""

    def __init__(self, bus: can.BusABC, plant, rng: np.random.Generator, db: FrameDatabase | None = None,
                 timing: BusTiming | None = None, faults: Faults | None = None, capture: Capture | None = None,
                 heartbeat_period_s: float = 0.01, host_timeout_s: float = 0.05, cmd_timeout_s: float = 0.02,
                 own_bus: bool = False):
        self.bus, self.plant, self.rng, self.own_bus = bus, plant, rng, own_bus
        self.db = db or FrameDatabase()
        self.wire = BusModel(timing or BusTiming())
        self.faults = faults or Faults()
        self.capture = capture
        self.hb_period, self.host_timeout, self.cmd_timeout = heartbeat_period_s, host_timeout_s, cmd_timeout_s
        self.t = 0.0
        self.state = STATE_READY
        self.bus_off = False
        self.last_host_hb = self.last_cmd = 0.0
        self._next_hb = 0.0
        self._outbox: list = []
        self._seq = 0
        self._counters = {"hb": 0, "emcy": 0}
        self.lost = self.corrupted = self.device_rejected = self.delivered = 0
        #: the host frames the device refused, by reason
        self.rejected_by_reason: Counter = Counter()
        #: the full count of the last SYNC taken and of the last command applied (-1: none this session)
        self.sync_count = self.cmd_count = -1
        self.tec = 0  # the device's transmit error counter (bus-off fault)
        self.sensor_fault: tuple | None = None  # (kind, from_s, axis, size)
        self._stuck_wrench, self._stale_samples = None, 0

    def inject_sensor_fault(self, kind: str, at_s: float, axis: int = 0, size: float = 0.0) -> None:
        """From ``at_s`` (s): ``sensor_nan`` (load-cell ``axis`` reads NaN), ``sensor_stuck`` (the
        load cell stops delivering samples), ``encoder_jump`` (joint ``axis`` reads ``size`` m or
        rad off)."""
        if kind not in SENSOR_FAULTS:
            raise ValueError(f"sensor fault {kind!r}: expected one of {SENSOR_FAULTS}")
        self.sensor_fault = (kind, float(at_s), int(axis), float(size))

    # -- device transmissions -----------------------------------------------------------------------
    def _transmitting(self, t: float) -> bool:
        f = self.faults
        return not self.bus_off and (f.silent_after_s is None or t < f.silent_after_s)

    def _device_send(self, name: str, signals: dict, t: float, sync_count: int | None = None) -> None:
        if not self._transmitting(t):
            return
        if self.faults.loss_pct and self.rng.random() * 100.0 < self.faults.loss_pct:
            self.lost += 1
            return
        fid, data, fd = self.db.encode(name, signals, sync_count)
        msg = can.Message(arbitration_id=fid, data=data, is_extended_id=False, is_fd=fd, bitrate_switch=fd)
        self.wire.submit(t, fid, len(data), fd, ("device", msg))

    def _emergency(self, code: int, t: float) -> None:
        self._device_send("DEV_EMERGENCY", {"EmcyCode": code, "EmcyCounter": self._counters["emcy"] % 256}, t)
        self._counters["emcy"] += 1

    def _corrupt(self, msg: can.Message) -> can.Message:
        data = bytearray(msg.data)
        bit = int(self.rng.integers(0, 8 * len(data)))
        data[bit // 8] ^= 1 << (bit % 8)
        self.corrupted += 1
        return can.Message(arbitration_id=msg.arbitration_id, data=bytes(data), is_extended_id=False,
                           is_fd=msg.is_fd, bitrate_switch=msg.bitrate_switch)

    # -- host frames at the device ------------------------------------------------------------------
    def _on_host_frame(self, msg: can.Message, t: float) -> None:
        if self.bus_off:
            return
        if self.faults.corrupt_pct and self.rng.random() * 100.0 < self.faults.corrupt_pct:
            msg = self._corrupt(msg)
        d = self.db.decode(msg.arbitration_id, msg.data, t, msg.is_extended_id, msg.is_fd,
                           sync_ref=max(self.sync_count, 0))
        if not isinstance(d, Decoded):
            self._refuse(d.reason)
            return
        s, dev = d.signals, self.plant
        if d.name == "SYNC":
            c = int(s["SyncCounter"])
            if self.sync_count >= 0 and t - self.last_host_hb > self.host_timeout:
                self.sync_count = self.cmd_count = -1  # the host is gone: a new one counts from 0
            if self.sync_count >= 0 and not 0 < c - self.sync_count <= SYNC_WINDOW:
                self._refuse("sync_stale" if c <= self.sync_count else "sync_future")
                return
            self.sync_count = c
            dev.advance_to(t)
            enc, wrench = self._sample(t)
            if enc is None:
                return
            joints = dict(zip(JOINT_SIGNALS, (float(v) for v in enc)))
            joints.update(DevState=self.state, JointsCounter=c % 256)
            self._device_send("DEV_JOINTS", joints, t, c)
            w = dict(zip(WRENCH_SIGNALS, (float(v) for v in wrench)))
            w["WrenchCounter"] = c % 256
            self._device_send("DEV_WRENCH", w, t, c)
        elif d.name == "HOST_CMD":
            hold = int(s["CmdMode"]) != 1
            if d.count < self.cmd_count or (d.count == self.cmd_count and not hold):
                self._refuse("command_late")
                return
            self.cmd_count = d.count
            self.last_cmd = t
            run = int(s["CmdMode"]) == 1 and self.state != STATE_FAULT
            dev.set_command([s[k] for k in CMD_SIGNALS] if run else np.zeros(6), t)
            if self.state == STATE_READY and run:
                self.state = STATE_RUNNING
        elif d.name == "HOST_HEARTBEAT":
            self.last_host_hb = t
            if int(s["HostState"]) == 0 and self.state == STATE_RUNNING:
                dev.set_command(np.zeros(6), t)
                self.state = STATE_READY

    def _refuse(self, reason: str) -> None:
        self.device_rejected += 1
        self.rejected_by_reason[reason] += 1

    def _sample(self, t: float):
        """(encoders, load cell) at a SYNC, through the injected sensor fault and the firmware's
        checks; (None, None) after a sensor fault (servos stopped, emergency sent)."""
        if self.state == STATE_FAULT and self._stale_samples < 0:
            return None, None
        enc, wrench = self.plant.sample_encoders(), self.plant.sample_load_cell()
        fault = self.sensor_fault
        fresh = True
        if fault is not None and t >= fault[1]:
            kind, _, axis, size = fault
            if kind == "sensor_nan":
                wrench[axis] = np.nan
            elif kind == "sensor_stuck":
                self._stuck_wrench = wrench if self._stuck_wrench is None else self._stuck_wrench
                wrench, fresh = self._stuck_wrench.copy(), False
            else:
                enc[axis] += size
        self._stale_samples = 0 if fresh else self._stale_samples + 1
        if not (np.isfinite(enc).all() and np.isfinite(wrench).all()) or self._stale_samples >= STUCK_SYNCS:
            self.plant.set_command(np.zeros(6), t)
            self.state, self._stale_samples = STATE_FAULT, -1
            self._emergency(EMCY_SENSOR_FAULT, t)
            return None, None
        return enc, np.clip(wrench, -WRENCH_LIMITS, WRENCH_LIMITS)  # the cell saturates

    def _bus_off_errors(self, t0: float) -> None:
        """The device's failing transmissions from t0: one error frame each (a bus error seen by
        the other nodes as receivers), +8 TEC each, until bus-off."""
        # s between attempts: the failed frame (the longest, 20 bytes) and an error frame (error
        # flag, delimiter, intermission: 6 + 8 + 3 bits at worst 12 + 8 + 3) at the nominal rate
        gap = compute_frame_time_s(self.wire.timing, 20, True) + 23.0 / self.wire.timing.bitrate_bps
        n = 0
        while self.tec < BUS_OFF_LIMIT:
            self.tec += 8
            err = can.Message(arbitration_id=CAN_ERR_PROT | CAN_ERR_BUSERROR, is_error_frame=True, data=bytes(8),
                              is_extended_id=False, timestamp=t0 + n * gap)
            heapq.heappush(self._outbox, (t0 + n * gap, self._seq, err))
            self._seq += 1
            n += 1
        self.bus_off = True

    # -- lockstep -----------------------------------------------------------------------------------
    def advance_to(self, t_end: float) -> None:
        """Process bus traffic and device physics up to t_end (s, simulated)."""
        f = self.faults
        while (msg := self.bus.recv(timeout=0.0)) is not None:
            if msg.is_error_frame:
                continue
            if f.loss_pct and self.rng.random() * 100.0 < f.loss_pct:
                self.lost += 1
                continue
            self.wire.submit(max(msg.timestamp, self.t), msg.arbitration_id, len(msg.data), msg.is_fd, ("host", msg))
        if f.bus_off_at_s is not None and not self.bus_off and t_end >= f.bus_off_at_s:
            self._bus_off_errors(f.bus_off_at_s)
        while self._next_hb <= t_end:
            hb = {"DevHbState": self.state, "DevHbFault": 0, "DevHbCounter": self._counters["hb"] % 256}
            self._device_send("DEV_HEARTBEAT", hb, self._next_hb)
            self._counters["hb"] += 1
            self._next_hb += self.hb_period
        while (done := self.wire.next_done(t_end)) is not None:
            t_done, (src, msg) = done
            if self.capture is not None:  # the capture is the host's view: its own frames are tx
                self.capture.write(msg, t_done, is_rx=src != "host")
            if src == "host":
                self._on_host_frame(msg, t_done)
                continue
            if f.corrupt_pct and self.rng.random() * 100.0 < f.corrupt_pct:
                msg = self._corrupt(msg)
            delay = 1e-3 * (f.latency_ms + f.jitter_ms * self.rng.random())
            heapq.heappush(self._outbox, (t_done + delay, self._seq, msg))
            self._seq += 1
        while self._outbox and self._outbox[0][0] <= t_end:
            t_deliver, _, msg = heapq.heappop(self._outbox)
            msg.timestamp = t_deliver
            self.bus.send(msg)
            self.delivered += 1
        self._check_timeouts(t_end)
        self.plant.advance_to(t_end)
        self.t = t_end

    def _check_timeouts(self, t: float) -> None:
        if self.state == STATE_RUNNING and t - self.last_host_hb > self.host_timeout:
            self.plant.set_command(np.zeros(6), t)
            self.state = STATE_FAULT
            self._emergency(1, t)
        elif self.state == STATE_RUNNING and t - self.last_cmd > self.cmd_timeout:
            self.plant.set_command(np.zeros(6), t)
            self.state = STATE_READY
            self._emergency(2, t)

    # -- the physical world around the device -----------------------------------------------------
    def apply_hand_wrench(self, F_W) -> None:
        """The operator's hand pushes the handle with F_W (6,: N, N*m at H, world)."""
        self.plant.hand_wrench_W = np.asarray(F_W, dtype=float)

    def handle_state(self):
        """(joints (6,), joint rates (6,)) of the plant: the true handle a simulated hand holds."""
        return self.plant.joints, self.plant.qd

    def close(self) -> None:
        """Shut the device's bus down (if owned); safe to call twice."""
        if self.own_bus:
            self.own_bus = False
            self.bus.shutdown()

    def stats(self) -> dict:
        return {
            "can_bus_load_pct": self.wire.load_pct(self.t),
            "can_frames_on_wire": self.wire.frames,
            "can_frames_lost": self.lost,
            "can_frames_corrupted": self.corrupted,
            "device_frames_rejected": self.device_rejected,
            "device_rejected_by_reason": dict(self.rejected_by_reason),
            "device_tec": self.tec,
        }
