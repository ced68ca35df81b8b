"""Per-tick records a runner keeps beside the tick: the master side's log, the passivity guard's
ports. Each is a hook of the side it records, so one process and two keep the same columns."""

from __future__ import annotations

import numpy as np

from teleop.tick.master_side import MasterSide
from teleop.tick.ports import Hook
from teleop.tick.slave_side import SlaveSide

#: ticks of log reserved at first and added each time it fills (the log grows, never preallocated)
LOG_CHUNK = 16_384


class Columns(dict):
    """Named per-tick arrays that grow in chunks of LOG_CHUNK ticks: ``ensure(i)`` before writing
    tick i, ``trimmed(n)`` the first n ticks. ``shapes`` maps a name to (trailing shape, dtype)."""

    def __init__(self, shapes: dict, expected: int = LOG_CHUNK):
        cap = max(1, min(int(expected), LOG_CHUNK))
        super().__init__({k: np.zeros((cap, *shape), dtype=dt) for k, (shape, dt) in shapes.items()})
        self.capacity = cap

    def ensure(self, i: int) -> None:
        if i < self.capacity:
            return
        grown = 2 * self.capacity if self.capacity < 8 * LOG_CHUNK else self.capacity + 8 * LOG_CHUNK
        cap = max(i + 1, grown)
        for k, a in self.items():
            b = np.zeros((cap, *a.shape[1:]), dtype=a.dtype)
            b[: self.capacity] = a
            self[k] = b
        self.capacity = cap

    def trimmed(self, n: int) -> dict:
        return {k: v[:n] for k, v in self.items()}


class MasterRecorder(Hook):
    """The master side's per-tick log: reference and virtual tool, multipliers, wrenches (the
    hand's, the constraint's, the slave's felt), the device's joints, the side's CPU time."""

    def __init__(self, tool, n: int):
        m, f = tool.model.m, float
        self.log = Columns({
            "t": ((), f), "q_r": ((6,), f), "q_v_p": ((3,), f), "p_r": ((3,), f), "R_r": ((3, 3), f),
            "R_v": ((3, 3), f), "lam": ((m,), f), "operator_W": ((6,), f), "felt_W": ((6,), f),
            "master_q": ((6,), f), "can_frames_lost": ((), np.int64), "constraint_W": ((6,), f),
            "master_tick_us": ((), f),
        }, n)
        self.n = 0
        self._pv = self._Rv = None

    @property
    def nan(self) -> bool:
        """True if the reference tool's coordinates or the virtual tool's position went non-finite
        on any tick logged (read from the log at the end, not checked in the tick)."""
        n = self.n
        return not (np.isfinite(self.log["q_r"][:n]).all() and np.isfinite(self.log["q_v_p"][:n]).all())

    def before_tick(self, i: int, t_s: float, side: MasterSide) -> None:
        self._pv, self._Rv = side.master.virtual_pose()  # what the encoders measure as it starts

    def after_tick(self, i: int, t_s: float, side: MasterSide) -> None:
        tool, log = side.tool, self.log
        log.ensure(i)
        log["t"][i] = tool.t
        log["q_r"][i] = tool.q
        log["q_v_p"][i] = self._pv
        log["R_v"][i] = self._Rv
        log["p_r"][i], log["R_r"][i] = side.state.p, side.state.R
        log["lam"][i] = tool.lam
        log["operator_W"][i] = side.hand_W
        log["felt_W"][i] = side.felt_W
        log["constraint_W"][i] = tool.constraint_wrench_W
        joints = side.master.joints()
        if joints is not None:  # a device: its encoders and the bus's running loss count
            log["master_q"][i] = joints
            log["can_frames_lost"][i] = side.master.stats().get("can_frames_lost", 0)
        log["master_tick_us"][i] = side.tick_ns * 1e-3
        self.n = i + 1


class SlaveRecorder(Hook):
    """The slave side's CPU time per tick (``slave_tick_us``)."""

    def __init__(self, n: int):
        self.log = Columns({"slave_tick_us": ((), float)}, n)
        self.n = 0

    def after_tick(self, i: int, t_s: float, side: SlaveSide) -> None:
        self.log.ensure(i)
        self.log["slave_tick_us"][i] = side.tick_ns * 1e-3
        self.n = i + 1


class GuardRecorder(Hook):
    """One port of the passivity guard, per tick: the observer ``tdpa_W_<side>_J`` and the
    dissipated energy ``tdpa_diss_<side>_J`` (n, 6) J cumulative; at the master the damping
    ``tdpa_alpha`` (n, 6), at the slave the pose offset ``tdpa_drift_M`` (n, 6: m, rad in M)."""

    def __init__(self, n: int, side: str):
        self.side = side
        last = "tdpa_alpha" if side == "master" else "tdpa_drift_M"
        self.log = Columns({k: ((6,), float) for k in (f"tdpa_W_{side}_J", f"tdpa_diss_{side}_J", last)}, n)
        self.n = 0

    def after_tick(self, i: int, t_s: float, side) -> None:
        port, log, k = side.guard.port, self.log, self.side
        log.ensure(i)
        log[f"tdpa_W_{k}_J"][i], log[f"tdpa_diss_{k}_J"][i] = port.W, port.E_diss
        if k == "master":
            log["tdpa_alpha"][i] = port.action
        else:
            log["tdpa_drift_M"][i] = port.offset
        self.n = i + 1
