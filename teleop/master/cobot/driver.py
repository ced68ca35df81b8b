"""Host-side driver of the cobot over any python-can bus (virtual, socketcan, pcan, ...).

``read`` takes at most ``max_frames_per_read`` frames off the bus (a flood cannot hold the cycle:
what is left waits for the next read, and stale feedback trips the watchdog) and decodes them into
SI values; ``send_*`` encode and transmit. Each frame's bytes go through one compiled call
(:func:`.frame_kernels.rx_period_frame`: the checks, the decoding, and for the period's two device
frames the counter checks, the wrist unwrapping and the encoder check into the driver's state
record); each frame sent is encoded and sealed by one (:func:`.frame_kernels.pack_frame`). Every
frame that fails its id, id type, FD flag, length, CRC, counter or DBC range is rejected, counted by
reason (:attr:`CobotDriver.rejected`, ``can_rejected_by_reason`` in :meth:`CobotDriver.stats`) and
logged; only finite, in-range values reach :attr:`joints_rad_m` and :attr:`wrench_S`.

The trust rules at this boundary (issue 22): the SYNC carries the host's full 32-bit count and the
CRC of each frame tied to a SYNC covers the full count it answers (:mod:`.database`), so a device
frame recorded 256 (512, ...) SYNCs earlier and replayed is refused (``stale``), one no newer than
the last applied is dropped (late, a duplicate too: ``can_frames_late``), one answering a SYNC not
sent yet is refused (``counter``). Each decoded value is checked against the last: a joint that
moved more than the device can since the last reading latches ``encoder_fault``
(``encoder_jump``); a load-cell reading that changed faster than the load cell can since the last
applied one is refused and counted (``wrench_jump``), the last one kept. A refused reading is not
fresh: it ages the feedback as a lost frame does, so a load cell that stays implausible for
``stale_cycles`` SYNCs latches ``wrench_fault`` through the stale-feedback watchdog, while an
isolated spike costs one reading and a real fast step is taken as soon as the allowance, which
grows with every SYNC since the last applied reading, covers it.

Error frames feed the host's own error counters (:mod:`teleop.can.confinement`: TEC/REC,
error-passive at 128, bus-off at 256), never a fault by themselves. The watchdog latches a fault
(``watchdog`` for stale feedback, ``wrench_fault`` for a load cell refused that long,
``heartbeat``, ``bus_off``, ``device_emergency``, ``encoder_fault``, ``send_failed``); after a
fault :meth:`send_command` sends zero velocity only.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter

import can
import numpy as np

from teleop.can.confinement import BUS_OFF, ErrorCounters
from teleop.master.cobot import frame_kernels as FK
from teleop.master.cobot.database import FrameDatabase
from teleop.util.errors import CanError
from teleop.util.views import view

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
#: (all but SYNC tied to a SYNC: their CRC covers its full count)
ORDERED_FRAMES = {"SYNC": ("SyncCounter",), "HOST_CMD": (*CMD_SIGNALS, "CmdMode", "CmdCounter"),
                  "DEV_JOINTS": (*JOINT_SIGNALS, "DevState", "JointsCounter"),
                  "DEV_WRENCH": (*WRENCH_SIGNALS, "WrenchCounter")}
#: the HOST_CMD ranges of the DBC (m/s x3, rad/s x3)
CMD_RANGE = (0.99996,) * 3 + (16.0,) * 3
_CMD_RANGE = np.array(CMD_RANGE)
_ZERO6 = np.zeros(6)


class CobotDriver:
    """The host end of the link. ``clock()`` gives the time (s): simulated in lockstep runs.

    stale_cycles: cycles without fresh joints or wrench that trip the watchdog.
    heartbeat_period_s: host heartbeat period; heartbeat_timeout_s: device heartbeat timeout.
    own_bus: shut the bus down in :meth:`close`. max_frames_per_read: the read bound.
    encoder_step_max (6,): the largest change of a joint reading (m, rad) per SYNC the device can
    make (its velocity limit times the period, plus a count); a larger one latches
    ``encoder_fault`` (None: not checked).
    wrench_step_max (6,): the largest change of a load-cell reading (N x3, N*m x3) per SYNC the
    load cell can make (:attr:`teleop.master.config.CobotConfig.wrench_rate_max` times the period,
    plus its noise); a larger change since the last applied reading is refused (``wrench_jump``)
    and the last reading kept (None: not checked).
    """

    def __init__(self, bus: can.BusABC, db: FrameDatabase | None = None, clock=time.monotonic,
                 stale_cycles: int = 3, heartbeat_period_s: float = 0.01,
                 heartbeat_timeout_s: float = 0.05, own_bus: bool = False,
                 max_frames_per_read: int = MAX_FRAMES_PER_READ, encoder_step_max=None, wrench_step_max=None):
        self.bus, self.db, self.clock = bus, db or FrameDatabase(), clock
        for name, order in ORDERED_FRAMES.items():  # the per-period frames are encoded by position
            if self.db.codecs[name].names[: len(order)] != order:
                raise CanError(f"can database: {name} must lay out {order} in that order, "
                               f"found {self.db.codecs[name].names}")
            if not self.db.codecs[name].compiled:
                raise CanError(f"can database: {name} must be a byte-aligned layout (the driver decodes and "
                               f"encodes it compiled), found bit fields or a non-linear conversion")
            if (name != "SYNC") != (name in self.db.counter):
                raise CanError(f"can database: {name} must {'not ' if name == 'SYNC' else ''}be tied to a SYNC "
                               f"(its SyncFreshness attribute {'0' if name == 'SYNC' else '1'})")
        self.stale_cycles = int(stale_cycles)
        self.hb_period, self.hb_timeout = float(heartbeat_period_s), float(heartbeat_timeout_s)
        self.own_bus = own_bus
        self.log = logging.getLogger(__name__)
        #: the receive state the compiled frame kernel updates (frame_kernels.DRIVER_STATE); the
        #: attributes joints_rad_m, wrench_S, the counters and the fresh flags are its fields
        self._ds = np.zeros(1, FK.DRIVER_STATE)
        self._rs = self._ds[0]
        self._ds["jc"] = self._ds["wc"] = self._ds["jf"] = self._ds["wf"] = -1
        self._ds["step_max"] = self._ds["wslew"] = -1.0  # no encoder check, no load-cell check
        self._tables = self.db.tables
        self._vals = np.empty(self._tables[0]["sig_f"].shape[1])
        self._tx_vals = np.empty(self._tables[0]["sig_f"].shape[1])
        self._ds["rows"] = self.db.row["DEV_JOINTS"], self.db.row["DEV_WRENCH"]
        self._row_cmd = self.db.row["HOST_CMD"]
        self._cmd_id, self._cmd_fd, self._len_cmd = self._frame_format("HOST_CMD")
        self._sync_id, self._sync_fd, self._len_sync = self._frame_format("SYNC")
        self._row_sync = self.db.row["SYNC"]
        self._sync = 0  # SYNCs sent (the next SYNC's full count)
        self.last_device_hb_s: float | None = None
        self.fault: str | None = None
        self.rejected: Counter = Counter()
        self.errors = ErrorCounters()
        self.error_frames = self.read_bound_hits = 0
        self.max_frames_per_read = int(max_frames_per_read)
        self.encoder_step_max = encoder_step_max
        self.wrench_step_max = wrench_step_max
        self.frames_rx = self.send_errors = self.watchdog_trips = 0
        self._hb = 0
        self._next_hb_s = -math.inf
        self._lim_key, self._lim = None, _CMD_RANGE
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
            count = self._cycle_count()
            self._send("HOST_CMD", (0.0,) * 6 + (0, count % 256), count)  # zero velocity, mode 0
            self._send("HOST_HEARTBEAT", {"HostState": 0, "HostHbCounter": self._hb % 256})
        if self.own_bus:
            self.bus.shutdown()

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.close()

    def _frame_format(self, name: str) -> tuple[int, bool, int]:
        """(frame id, FD, length) of message ``name``."""
        row = self._tables[0]["msgs"][self.db.row[name]]
        return int(row[FK.M_ID]), bool(row[FK.M_FD]), int(row[FK.M_LEN])

    # -- the receive state (fields of the record the compiled frame kernel updates) -----------------
    joints_rad_m = view("_rs", "joints", "the last joint reading (6,: 3 gantry positions m, 3 unwrapped wrist "
                        "angles rad); a view the next valid reading overwrites")
    wrench_S = view("_rs", "wrench", "the last load-cell reading (6,: N, N*m, load-cell frame); a view")
    joints_counter = view("_rs", "jc", "the SYNC counter (0..255) of the last joint reading applied (-1: none yet)",
                          int)
    wrench_counter = view("_rs", "wc", "the SYNC counter (0..255) of the last load-cell reading applied (-1: none "
                          "yet)", int)
    joints_sync = view("_rs", "jf", "the full SYNC count of the last joint reading applied (-1: none yet)", int)
    wrench_sync = view("_rs", "wf", "the full SYNC count of the last load-cell reading applied (-1: none yet)", int)
    wrench_refused = view("_rs", "wrefused", "load-cell readings refused (wrench_jump) since the last applied one",
                          int)
    fresh_joints = view("_rs", "fresh_j", "a joint reading arrived in this cycle (cleared by end_cycle)", bool)
    fresh_wrench = view("_rs", "fresh_w", "a load-cell reading arrived in this cycle (cleared by end_cycle)", bool)
    cycles_since_joints = view("_rs", "since_j", "cycles since the last fresh joint reading", int)
    cycles_since_wrench = view("_rs", "since_w", "cycles since the last fresh load-cell reading", int)
    device_state = view("_rs", "dev_state", "the device's state, from its last joints or heartbeat frame", int)
    frames_late = view("_rs", "late", "valid device frames older than the last applied one (dropped)", int)

    @property
    def encoder_step_max(self):
        """The encoder check's limits (6,: m, rad per SYNC), or None: not checked."""
        sm = self._rs["step_max"]
        return None if sm[0] < 0.0 else sm.copy()

    @encoder_step_max.setter
    def encoder_step_max(self, value) -> None:
        self._rs["step_max"][:] = -1.0 if value is None else np.broadcast_to(np.asarray(value, float), 6)

    @property
    def wrench_step_max(self):
        """The load-cell check's limits (6,: N x3, N*m x3 per SYNC), or None: not checked."""
        sm = self._rs["wslew"]
        return None if sm[0] < 0.0 else sm.copy()

    @wrench_step_max.setter
    def wrench_step_max(self, value) -> None:
        self._rs["wslew"][:] = -1.0 if value is None else np.broadcast_to(np.asarray(value, float), 6)

    # -- sending ------------------------------------------------------------------------------------
    def _send(self, name: str, signals, sync_count: int | None = None) -> bool:
        """Encode and send; ``signals`` a mapping, or the values in codec order (no checksum);
        ``sync_count``: the full SYNC count of a frame tied to one."""
        if isinstance(signals, dict):
            frame_id, data, fd = self.db.encode(name, signals, sync_count)
        else:
            frame_id, data, fd = self.db.encode_ordered(name, signals, sync_count)
        return self._transmit(name, frame_id, data, fd)

    def _transmit(self, name: str, frame_id: int, data, fd: bool) -> bool:
        """Put one encoded frame on the bus (a new ``data`` object per frame: a sent frame is
        never changed); a failed send latches ``send_failed``."""
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
        """SYNC with the next full count (the SYNCs sent before it); returns its low byte (0..255),
        the counter the device's answers carry. Past 2^32 SYNCs (49.7 days at 1 kHz) the count
        would repeat: :class:`CanError` (the host's period holds the device)."""
        count = self._sync
        self._tx_vals[0] = count
        out = bytearray(self._len_sync)
        if FK.pack_frame(self._tables, self._row_sync, self._tx_vals, out, True, -1) >= 0:
            raise CanError(f"can encode SYNC: count {count} outside the DBC's SyncCounter range (2^32 SYNCs sent: "
                           f"restart the session)")
        self._sync += 1
        self._transmit("SYNC", self._sync_id, out, self._sync_fd)
        return count % 256

    def _cycle_count(self) -> int:
        """The full count of the cycle's SYNC (the last sent; 0 before the first), which HOST_CMD
        answers."""
        return max(self._sync - 1, 0)

    def send_heartbeat(self, force: bool = False) -> None:
        now = self.clock()
        if force or now >= self._next_hb_s:
            self._next_hb_s = now + self.hb_period - 1e-9
            state = 2 if self.fault is None else 1
            self._send("HOST_HEARTBEAT", {"HostState": state, "HostHbCounter": self._hb % 256})
            self._hb += 1

    def send_command(self, qd_cmd, limits=None) -> None:
        """Joint velocity commands (6,: m/s x3, rad/s x3), clipped to ``limits`` (6,) and the DBC
        range; zero velocity with mode 0 after a fault or for non-finite input
        (:func:`.frame_kernels.pack_command`). The frame answers the last SYNC sent (its counter,
        and its full count in the CRC)."""
        qd = qd_cmd if type(qd_cmd) is np.ndarray and qd_cmd.dtype == np.float64 else np.asarray(qd_cmd, float)
        run = self.fault is None and qd.shape == (6,)
        if not run:
            qd = _ZERO6
        lim = _CMD_RANGE if limits is None else self._limits(limits)
        out = bytearray(self._len_cmd)
        if FK.pack_command(self._tables, self._row_cmd, qd, lim, run, self._cycle_count(), self._tx_vals, out) < 0:
            raise CanError("can encode HOST_CMD: a clipped command outside the DBC's ranges (check CMD_RANGE)")
        self._transmit("HOST_CMD", self._cmd_id, out, self._cmd_fd)

    def _limits(self, limits) -> np.ndarray:
        """min(limits, the DBC's HOST_CMD range) (6,), kept for the last ``limits`` object given
        (pass a new array to change the limits; one changed in place is not seen)."""
        if limits is not self._lim_key:
            self._lim_key = limits
            self._lim = np.minimum(np.asarray(limits, float), _CMD_RANGE)
        return self._lim

    # -- receiving ----------------------------------------------------------------------------------
    def read(self) -> int:
        """Take up to ``max_frames_per_read`` frames off the bus without blocking; returns the
        number of valid frames decoded."""
        n = 0
        recv, rx = self.bus.recv, FK.rx_period_frame
        tab, ds, vals = self._tables, self._ds, self._vals
        for _ in range(self.max_frames_per_read):
            msg = recv(timeout=0.0)
            if msg is None:
                break
            self.frames_rx += 1
            if msg.is_error_frame:
                self._on_error_frame(msg)
                continue
            verdict, row = rx(tab, ds, self._sync, msg.arbitration_id, msg.is_extended_id, msg.is_fd, msg.data, vals)
            if verdict == FK.APPLIED or verdict == FK.LATE:
                n += 1
                self.errors.rx_ok()
                continue
            if verdict == FK.FUTURE or verdict == FK.ENCODER_JUMP or verdict == FK.WRENCH_JUMP:
                n += 1
                self.errors.rx_ok()
                self._reject_counted(verdict)
                continue
            d = self.db.verdict(verdict if verdict != FK.OTHER else FK.OK, row, msg.arbitration_id, msg.data,
                                msg.timestamp, vals)
            if hasattr(d, "reason"):
                self.rejected[d.reason] += 1
                level = logging.WARNING if sum(self.rejected.values()) <= 10 else logging.DEBUG
                self.log.log(level, "rejected CAN frame 0x%03X: %s", d.frame_id, d.reason)
                continue
            n += 1
            self.errors.rx_ok()
            self._apply_other(d)
        else:
            self.read_bound_hits += 1
        return n

    def _reject_counted(self, verdict: int) -> None:
        """A valid frame the period's checks refused: a counter not sent yet, a load-cell jump (the
        last reading kept), or an encoder jump (the fault latched)."""
        if verdict == FK.FUTURE:
            self.rejected["counter"] += 1
            return
        if verdict == FK.WRENCH_JUMP:
            self.rejected["wrench_jump"] += 1
            if self.rejected["wrench_jump"] <= 10:
                i, size, gap = self._rs["wjump"].tolist()
                self.log.warning("load-cell reading refused: axis %d changed %.4g in %d SYNC(s), faster than the "
                                 "load cell can", int(i), size, int(gap))
            return
        self.rejected["encoder_jump"] += 1
        i, size, gap = self._rs["jump"].tolist()
        self._trip("encoder_fault",
                   f"joint {int(i)} moved {size:.4g} in {int(gap)} cycle(s), beyond what the device can")

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

    def _apply_other(self, d) -> None:
        """A valid frame other than the period's two: the device's heartbeat or emergency."""
        s = d.signals
        if d.name == "DEV_HEARTBEAT":
            self.last_device_hb_s = self.clock()
            self.device_state = int(s["DevHbState"])
        elif d.name == "DEV_EMERGENCY" and int(s["EmcyCode"]) != 0:
            self._trip("device_emergency", f"device emergency code {int(s['EmcyCode'])}")

    # -- watchdog -----------------------------------------------------------------------------------
    def end_cycle(self) -> str | None:
        """Age the feedback by one cycle and check the watchdog; returns the latched fault or None.
        (:class:`.host.CobotMaster` ages it inside its compiled ``sense`` and calls the two checks.)"""
        if FK.end_cycle_counts(self._ds, self.stale_cycles):
            self.trip_stale()
        self.check_heartbeat()
        return self.fault

    def check_heartbeat(self) -> None:
        """Latch ``heartbeat`` when the device's heartbeat is older than its timeout."""
        if self.last_device_hb_s is not None and self.clock() - self.last_device_hb_s > self.hb_timeout:
            self._trip("heartbeat", f"no device heartbeat for {self.hb_timeout} s")

    def trip_stale(self) -> None:
        """Latch ``watchdog``: the feedback is ``stale_cycles`` old; ``wrench_fault`` when it is
        the load cell's alone, its readings arriving and refused (``wrench_jump``)."""
        rs = self._rs
        if rs["wrefused"] > 0 and rs["since_w"] >= self.stale_cycles > rs["since_j"]:
            i, size, gap = rs["wjump"].tolist()
            self._trip("wrench_fault", f"{int(rs['wrefused'])} load-cell readings refused, the last: axis {int(i)} "
                       f"changed {size:.4g} in {int(gap)} SYNC(s), faster than the load cell can")
            return
        self._trip("watchdog", f"no fresh feedback for {self.stale_cycles} cycles")

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
