"""Host-side driver of the cobot over any python-can bus (virtual, socketcan, pcan, ...).

``read`` takes at most ``max_frames_per_read`` frames off the bus (a flood cannot hold the cycle:
what is left waits for the next read, and stale feedback trips the watchdog) and decodes them into
SI values; ``send_*`` encode and transmit. Every frame that fails its id, id type, FD flag,
length, CRC, counter or DBC range is rejected, counted by reason and logged; only finite, in-range
values reach :attr:`joints_rad_m` and :attr:`wrench_S`. Error frames feed the host's own error
counters (:mod:`teleop.can.confinement`: TEC/REC, error-passive at 128, bus-off at 256), never a
fault by themselves. The watchdog latches a fault (``watchdog`` for stale feedback, ``heartbeat``,
``bus_off``, ``device_emergency``, ``encoder_fault``, ``send_failed``); after a fault
:meth:`send_command` sends zero velocity only.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter

import can
import numpy as np

from teleop.can.confinement import BUS_OFF, ErrorCounters
from teleop.master.cobot.database import Decoded, FrameDatabase
from teleop.errors import CanError

#: SocketCAN error classes in an error frame's id (linux/can/error.h) and the protocol-error
#: type bit "on transmission" in data[2]
CAN_ERR_TX_TIMEOUT, CAN_ERR_PROT, CAN_ERR_ACK, CAN_ERR_BUSOFF, CAN_ERR_BUSERROR, CAN_ERR_CNT = (
    0x1, 0x8, 0x20, 0x40, 0x80, 0x200)
CAN_ERR_PROT_TX = 0x80
#: frames one read takes off the bus at most (a 1 kHz cycle carries 2-4)
MAX_FRAMES_PER_READ = 64
JOINT_SIGNALS = ("PosX", "PosY", "PosZ", "AngA", "AngB", "AngC")
WRENCH_SIGNALS = ("ForceX", "ForceY", "ForceZ", "TorqueX", "TorqueY", "TorqueZ")
CMD_SIGNALS = ("CmdVelX", "CmdVelY", "CmdVelZ", "CmdRateA", "CmdRateB", "CmdRateC")
#: frames the driver encodes or reads by position every period, and the signal order it assumes
ORDERED_FRAMES = {"SYNC": ("SyncCounter",), "HOST_CMD": (*CMD_SIGNALS, "CmdMode", "CmdCounter"),
                  "DEV_JOINTS": (*JOINT_SIGNALS, "DevState", "JointsCounter"),
                  "DEV_WRENCH": (*WRENCH_SIGNALS, "WrenchCounter")}
#: the HOST_CMD ranges of the DBC (m/s x3, rad/s x3)
CMD_RANGE = (0.99996,) * 3 + (16.0,) * 3


class CobotDriver:
    """The host end of the link. ``clock()`` gives the time (s): simulated in lockstep runs.

    stale_cycles: cycles without fresh joints or wrench that trip the watchdog.
    heartbeat_period_s: host heartbeat period; heartbeat_timeout_s: device heartbeat timeout.
    own_bus: shut the bus down in :meth:`close`. max_frames_per_read: the read bound.
    encoder_step_max (6,): the largest change of a joint reading (m, rad) per SYNC the device can
    make (its velocity limit times the period, plus a count); a larger one latches
    ``encoder_fault`` (None: not checked).
    """

    def __init__(self, bus: can.BusABC, db: FrameDatabase | None = None, clock=time.monotonic,
                 stale_cycles: int = 3, heartbeat_period_s: float = 0.01,
                 heartbeat_timeout_s: float = 0.05, own_bus: bool = False,
                 max_frames_per_read: int = MAX_FRAMES_PER_READ, encoder_step_max=None):
        self.bus, self.db, self.clock = bus, db or FrameDatabase(), clock
        for name, order in ORDERED_FRAMES.items():  # the per-period frames are encoded by position
            if self.db.codecs[name].names[: len(order)] != order:
                raise CanError(f"can database: {name} must lay out {order} in that order, "
                               f"found {self.db.codecs[name].names}")
        self.stale_cycles = int(stale_cycles)
        self.hb_period, self.hb_timeout = float(heartbeat_period_s), float(heartbeat_timeout_s)
        self.own_bus = own_bus
        self.log = logging.getLogger(__name__)
        self.joints_rad_m = np.zeros(6)  # 3 gantry positions (m), 3 unwrapped wrist angles (rad)
        self.wrench_S = np.zeros(6)  # load cell (N, N*m) in the load-cell frame
        self.joints_counter = self.wrench_counter = -1
        self.fresh_joints = self.fresh_wrench = False
        self.cycles_since_joints = self.cycles_since_wrench = 0
        self.device_state = 0
        self.last_device_hb_s: float | None = None
        self.fault: str | None = None
        self.rejected: Counter = Counter()
        self.errors = ErrorCounters()
        self.error_frames = self.read_bound_hits = 0
        self.max_frames_per_read = int(max_frames_per_read)
        self.encoder_step_max = None if encoder_step_max is None else np.asarray(encoder_step_max, float).tolist()
        self.frames_rx = self.frames_late = self.send_errors = self.watchdog_trips = 0
        self._sync = self._cmd = self._hb = 0
        self._next_hb_s = -math.inf
        self._lim_key, self._lim = None, list(CMD_RANGE)
        self.started = self.closed = False

    # -- life cycle ---------------------------------------------------------------------------------
    def start(self, joints0_rad_m=None) -> None:
        """Announce the host and seed the angle unwrapping with the expected joints (6,)."""
        if joints0_rad_m is not None:
            self.joints_rad_m = np.array(joints0_rad_m, dtype=float)
        self.started = True
        self.last_device_hb_s = self.clock()
        self.send_heartbeat(force=True)

    def close(self) -> None:
        """Zero velocity, host state 0 and (if owned) bus shutdown; safe to call twice."""
        if self.closed:
            return
        self.closed = True
        if self.started:
            self._send("HOST_CMD", (0.0,) * 6 + (0, self._cmd % 256))  # zero velocity, mode 0
            self._send("HOST_HEARTBEAT", {"HostState": 0, "HostHbCounter": self._hb % 256})
        if self.own_bus:
            self.bus.shutdown()

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.close()

    # -- sending ------------------------------------------------------------------------------------
    def _send(self, name: str, signals) -> bool:
        """Encode and send; ``signals`` a mapping, or the values in codec order (no checksum)."""
        if isinstance(signals, dict):
            frame_id, data, fd = self.db.encode(name, signals)
        else:
            frame_id, data, fd = self.db.encode_ordered(name, signals)
        msg = can.Message(arbitration_id=frame_id, data=data, is_extended_id=False, is_fd=fd,
                          bitrate_switch=fd, timestamp=self.clock())
        try:
            self.bus.send(msg)
            self.errors.tx_ok()
            return True
        except can.CanError as e:
            self.send_errors += 1
            self._trip("send_failed", f"send {name}: {e}")
            return False

    def send_sync(self) -> int:
        """SYNC with the next counter; returns the counter (0..255)."""
        c = self._sync % 256
        self._sync += 1
        self._send("SYNC", (c,))
        return c

    def send_heartbeat(self, force: bool = False) -> None:
        now = self.clock()
        if force or now >= self._next_hb_s:
            self._next_hb_s = now + self.hb_period - 1e-9
            state = 2 if self.fault is None else 1
            self._send("HOST_HEARTBEAT", {"HostState": state, "HostHbCounter": self._hb % 256})
            self._hb += 1

    def send_command(self, qd_cmd, limits=None) -> None:
        """Joint velocity commands (6,: m/s x3, rad/s x3), clipped to ``limits`` (6,) and the DBC
        range; zero velocity with mode 0 after a fault or for non-finite input."""
        qd = np.asarray(qd_cmd, dtype=float)
        vals = qd.tolist() if qd.shape == (6,) else None  # six floats: scalar arithmetic is cheapest
        mode = 1
        if self.fault is not None or vals is None or not all(map(math.isfinite, vals)):
            vals, mode = [0.0] * 6, 0
        lim = CMD_RANGE if limits is None else self._limits(limits)
        self._send("HOST_CMD", (*[min(max(v, -m), m) for v, m in zip(vals, lim)], mode, self._cmd % 256))
        self._cmd += 1

    def _limits(self, limits) -> list:
        """min(limits, the DBC's HOST_CMD range) (6,), kept for the last ``limits`` object given
        (pass a new array to change the limits; one changed in place is not seen)."""
        if limits is not self._lim_key:
            self._lim_key = limits
            self._lim = [min(a, b) for a, b in zip(np.asarray(limits, float).tolist(), CMD_RANGE)]
        return self._lim

    # -- receiving ----------------------------------------------------------------------------------
    def read(self) -> int:
        """Take up to ``max_frames_per_read`` frames off the bus without blocking; returns the
        number of valid frames decoded."""
        n = 0
        recv, decode = self.bus.recv, self.db.decode
        for _ in range(self.max_frames_per_read):
            msg = recv(timeout=0.0)
            if msg is None:
                break
            self.frames_rx += 1
            if msg.is_error_frame:
                self._on_error_frame(msg)
                continue
            out = decode(msg.arbitration_id, msg.data, msg.timestamp, msg.is_extended_id, msg.is_fd)
            if not isinstance(out, Decoded):
                self.rejected[out.reason] += 1
                level = logging.WARNING if sum(self.rejected.values()) <= 10 else logging.DEBUG
                self.log.log(level, "rejected CAN frame 0x%03X: %s", out.frame_id, out.reason)
                continue
            n += 1
            self.errors.rx_ok()
            self._apply(out)
        else:
            self.read_bound_hits += 1
        return n

    def _on_error_frame(self, msg: can.Message) -> None:
        """An error frame (SocketCAN's error classes in its id) through the error counters: the
        controller's own counters when it reports them, else +8 TEC for an error on this node's
        transmission (no ACK, TX timeout, a protocol error flagged TX, bus-off), +1 REC for any
        other. Error-passive is logged; bus-off latches the fault."""
        self.error_frames += 1
        eid, data = msg.arbitration_id, bytes(msg.data).ljust(8, b"\0")
        before = self.errors.state
        if eid & CAN_ERR_CNT:
            state = self.errors.set(data[6], data[7])
        elif (eid & (CAN_ERR_ACK | CAN_ERR_TX_TIMEOUT | CAN_ERR_BUSOFF)
              or (eid & CAN_ERR_PROT and data[2] & CAN_ERR_PROT_TX)):
            state = self.errors.tx_error()
        else:
            state = self.errors.rx_error()
        if state != before:
            self.log.warning("CAN error state %s (TEC %d, REC %d)", state, self.errors.tec, self.errors.rec)
        if state == BUS_OFF:
            self._trip("bus_off", f"TEC {self.errors.tec} >= 256")

    @staticmethod
    def _newer(counter: int, last: int) -> bool:
        return last < 0 or 0 < (counter - last) % 256 < 128

    def _from_future(self, counter: int) -> bool:
        """A counter the host has not sent yet (a corrupted or foreign frame)."""
        return self._sync == 0 or (self._sync - 1 - counter) % 256 >= 128

    def _apply(self, d: Decoded) -> None:
        s, name = d.signals, d.name
        if name == "DEV_JOINTS" or name == "DEV_WRENCH":
            counter = int(d.values[7 if name == "DEV_JOINTS" else 6])  # ORDERED_FRAMES: the counter after
            if self._from_future(counter):
                self.rejected["counter"] += 1
                return
        if name == "DEV_JOINTS":
            if not self._newer(counter, self.joints_counter):
                self.frames_late += 1
                return
            meas = list(d.values[:6])  # ORDERED_FRAMES: the six joints first
            prev = self.joints_rad_m.tolist()
            for i in range(3, 6):  # unwrap the wrist angles next to the previous reading
                meas[i] = prev[i] + (meas[i] - prev[i] + math.pi) % (2.0 * math.pi) - math.pi
            if self.encoder_step_max is not None and self.joints_counter >= 0:
                gap = (counter - self.joints_counter) % 256
                jump = [abs(a - b) - gap * m for a, b, m in zip(meas, prev, self.encoder_step_max)]
                if max(jump) > 0.0:
                    i = jump.index(max(jump))
                    self.rejected["encoder_jump"] += 1
                    self._trip("encoder_fault", f"joint {i} moved {abs(meas[i] - prev[i]):.4g} in {gap} "
                                                f"cycle(s), beyond what the device can")
                    return
            self.joints_rad_m = np.array(meas, dtype=float)
            self.joints_counter = counter
            self.device_state = int(d.values[6])
            self.fresh_joints = True
            self.cycles_since_joints = 0
        elif name == "DEV_WRENCH":
            if not self._newer(counter, self.wrench_counter):
                self.frames_late += 1
                return
            self.wrench_S = np.array(d.values[:6], dtype=float)
            self.wrench_counter = counter
            self.fresh_wrench = True
            self.cycles_since_wrench = 0
        elif name == "DEV_HEARTBEAT":
            self.last_device_hb_s = self.clock()
            self.device_state = int(s["DevHbState"])
        elif name == "DEV_EMERGENCY" and int(s["EmcyCode"]) != 0:
            self._trip("device_emergency", f"device emergency code {int(s['EmcyCode'])}")

    # -- watchdog -----------------------------------------------------------------------------------
    def end_cycle(self) -> str | None:
        """Age the feedback by one cycle and check the watchdog; returns the latched fault or None."""
        if not self.fresh_joints:
            self.cycles_since_joints += 1
        if not self.fresh_wrench:
            self.cycles_since_wrench += 1
        self.fresh_joints = self.fresh_wrench = False
        if max(self.cycles_since_joints, self.cycles_since_wrench) >= self.stale_cycles:
            self._trip("watchdog", f"no fresh feedback for {self.stale_cycles} cycles")
        if self.last_device_hb_s is not None and self.clock() - self.last_device_hb_s > self.hb_timeout:
            self._trip("heartbeat", f"no device heartbeat for {self.hb_timeout} s")
        return self.fault

    def latch_fault(self, fault: str, why: str) -> None:
        """Latch a host-side fault (from then on zero velocity, mode 0), logged with ``why``."""
        self._trip(fault, why)

    def _trip(self, fault: str, why: str) -> None:
        if self.fault is None:
            self.fault = fault
            self.watchdog_trips += fault in ("watchdog", "heartbeat")
            self.log.warning("cobot link fault latched: %s (%s)", fault, why)

    def stats(self) -> dict:
        return {
            "can_frames_rx": self.frames_rx,
            "can_frames_rejected": int(sum(self.rejected.values())),
            "can_rejected_by_reason": dict(self.rejected),
            "can_frames_late": self.frames_late,
            "can_send_errors": self.send_errors,
            "watchdog_trips": self.watchdog_trips,
            "can_error_frames": self.error_frames,
            "can_tec": self.errors.tec,
            "can_rec": self.errors.rec,
            "can_error_state": self.errors.state,
            "can_read_bound_hits": self.read_bound_hits,
            "link_fault": self.fault,
        }
