"""What a runner keeps of each tick: one row per side per tick (:mod:`teleop.app.rows`), captured
by a hook of the side, read by the run's log, its metrics and its record. Each is a hook of the
side it captures, so one process and two keep the same columns.

:class:`MasterRecorder` and :class:`SlaveRecorder` join their side's tick into a row in one
copy (in the tick, some 6 µs the master's, reading its virtual tool as the tick begins included,
and 2.5 µs the slave's); the log's columns, the metrics and the MCAP record are read from the
rows, never from the side again.
"""

from __future__ import annotations

import struct
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from teleop.app.rows import ROW_CHUNK, RowLayout, TickRows
from teleop.tick.ports import Hook

if TYPE_CHECKING:  # the record's writer process imports this module, and nothing of the tick
    from teleop.tick.master_side import MasterSide
    from teleop.tick.slave_side import SlaveSide

#: ticks of log reserved at first and added each time it fills (the log grows, never preallocated)
LOG_CHUNK = ROW_CHUNK
#: the master row's scalars: tick, run time (s), wall clock (Unix s), status code, gain, heartbeat
#: lost, peer lost, tick CPU (ns), command errors, the tool's own time (s), CAN frames lost
_MASTER_HEAD = struct.Struct("<11d")
_MASTER_SCALARS = ("i", "t", "wall", "status", "gain", "lost", "peer_lost", "tick_ns", "cmd_err", "tool_t", "can_lost")
#: the slave row's: tick, run time, wall clock, status code, heartbeat lost, tick CPU (ns), the
#: newest command's seq, ticks without a command, commands skipped
_SLAVE_HEAD = struct.Struct("<9d")
_SLAVE_SCALARS = ("i", "t", "wall", "status", "lost", "tick_ns", "last_seq", "without", "skipped")
_now = time.time


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


def master_layout(side: MasterSide) -> RowLayout:
    """The master row's columns for ``side``: its scalars; the tool as the tick left it (``p``,
    ``R``, ``V``: m, -, m/s and rad/s); the hand's, the felt and the channel's next wrench (N,
    N*m, M); the tool's coordinates ``q_r``, multipliers ``lam`` and constraint wrench ``con``
    (world); the virtual tool as the tick began (``v_p0``, ``v_R0``, ``v_V0``); with a device, its
    joints and the virtual tool as the tick ended (``joints``, ``dev_p``, ``dev_R``); with the
    passivity guard, its port (``gW``, ``gE`` J, ``gA``)."""
    c = RowLayout()
    for k in _MASTER_SCALARS:
        c.add(k)
    tool = side.tool
    for k, n in (("p", 3), ("R", 9), ("V", 6), ("hand", 6), ("felt", 6), ("fb", 6), ("q_r", np.size(tool.q)),
                 ("lam", np.size(tool.lam)), ("con", 6), ("v_p0", 3), ("v_R0", 9), ("v_V0", 6)):
        c.add(k, n)
    joints = side.master.joints()
    if joints is not None:
        c.add("joints", len(joints))
        c.add("dev_p", 3)
        c.add("dev_R", 9)
    if side.guard is not None:
        for k in ("gW", "gE", "gA"):
            c.add(k, 6)
    return c


class MasterRecorder(Hook):
    """The master side's capture: one row a tick (:func:`master_layout`), joined as the tick ends
    (its status set). ``n``: the ticks expected. :meth:`log` the run's per-tick log by its
    ``log.npz`` names, :attr:`nan` whether the tool went non-finite."""

    def __init__(self, side: MasterSide, n: int = LOG_CHUNK) -> None:
        self.side = side
        self.rows = TickRows(master_layout(side), n)
        c = self.rows.layout
        self._device = "joints" in c
        self._guard = "gW" in c
        self._v0: tuple = ()

    @property
    def n(self) -> int:
        return self.rows.n

    def before_tick(self, i: int, t_s: float, side: MasterSide) -> None:
        m = side.master
        self._v0 = (*m.virtual_pose(), *m.virtual_twist())  # what the encoders measure as it starts

    def after_tick(self, i: int, t_s: float, side: MasterSide) -> None:
        st, tool, m, rows = side.state, side.tool, side.master, self.rows
        v0 = self._v0 or (*m.virtual_pose(), *m.virtual_twist())  # (made after the tick began: as it ends)
        code = rows.code(side.status)
        dev: tuple = ()
        lost = 0
        if self._device:
            lost = m.stats().get("can_frames_lost", 0)
            dev = (m.joints(), *m.virtual_pose())
        if self._guard:
            port = side.guard.port  # type: ignore[union-attr]  # _guard: the side has one
            dev += (port.W, port.E_diss, port.action)
        rows.put(i, (_MASTER_HEAD.pack(i, t_s, _now(), code, side.gain, side.heart.lost, side.peer_lost,
                                       side.tick_ns, side.command_errors, tool.t, lost),
                     st.p, st.R, st.V, side.hand_W, side.felt_W, side.feedback_W, tool.q, tool.lam,
                     tool.constraint_wrench_W, *v0, *dev))

    @property
    def nan(self) -> bool:
        """True if the reference tool's coordinates or the virtual tool's position went non-finite
        on any tick captured (read from the rows at the end, not checked in the tick)."""
        return not (np.isfinite(self.rows.column("q_r")).all() and np.isfinite(self.rows.column("v_p0")).all())

    def log(self, steps: int | None = None) -> dict:
        """The first ``steps`` ticks (default: all) by their ``log.npz`` names: ``t`` (the tool's
        time, s), ``q_r``, ``q_v_p``, ``p_r``, ``R_r``, ``R_v``, ``lam``, ``operator_W``,
        ``felt_W``, ``constraint_W``, ``master_q`` and ``can_frames_lost`` (zeros without a
        device), ``master_tick_us``; with the guard, ``tdpa_W_master_J``, ``tdpa_diss_master_J``,
        ``tdpa_alpha``."""
        r = self.rows
        n = r.n if steps is None else min(int(steps), r.n)
        col = r.column
        out = {"t": col("tool_t", n), "q_r": col("q_r", n), "q_v_p": col("v_p0", n), "p_r": col("p", n),
               "R_r": col("R", n, (3, 3)), "R_v": col("v_R0", n, (3, 3)), "lam": col("lam", n),
               "operator_W": col("hand", n), "felt_W": col("felt", n),
               "master_q": col("joints", n) if self._device else np.zeros((n, 6)),
               "can_frames_lost": col("can_lost", n).astype(np.int64), "constraint_W": col("con", n),
               "master_tick_us": col("tick_ns", n) * 1e-3}
        if self._guard:
            out.update(tdpa_W_master_J=col("gW", n), tdpa_diss_master_J=col("gE", n), tdpa_alpha=col("gA", n))
        return out


def slave_layout(side: SlaveSide) -> RowLayout:
    """The slave row's columns for ``side``: its scalars; its target (``p_t``, ``R_t``), tool
    (``p``, ``R``, ``v``, ``w``: patient frame, m, -, m/s, rad/s), blade tip ``tip`` (m), the
    tissue's wrench ``contact`` (N, N*m), joints ``q``, ``qd``; with the passivity guard, its port
    (``gW``, ``gE`` J, ``gD`` the pose offset)."""
    c = RowLayout()
    for k in _SLAVE_SCALARS:
        c.add(k)
    nv = len(side.arm.q)
    for k, n in (("p_t", 3), ("R_t", 9), ("p", 3), ("R", 9), ("v", 3), ("w", 3), ("tip", 3), ("contact", 6),
                 ("q", nv), ("qd", nv)):
        c.add(k, n)
    if side.guard is not None:
        for k in ("gW", "gE", "gD"):
            c.add(k, 6)
    return c


class SlaveRecorder(Hook):
    """The slave side's capture: one row a tick (:func:`slave_layout`), joined as the tick ends
    (the side has set its status by then). ``n``: the ticks expected."""

    def __init__(self, side: SlaveSide, n: int = LOG_CHUNK) -> None:
        self.side = side
        self.rows = TickRows(slave_layout(side), n)
        self._guard = "gW" in self.rows.layout

    @property
    def n(self) -> int:
        return self.rows.n

    def after_tick(self, i: int, t_s: float, side: SlaveSide) -> None:
        s, arm, rows = side.state, side.arm, self.rows
        code = rows.code(s.status)
        parts = (_SLAVE_HEAD.pack(i, t_s, _now(), code, side.heart.lost, side.tick_ns, side.last_seq,
                                  side.without_command, side.skipped),
                 s.p_t, s.R_t, s.p, s.R, s.v, s.w, s.tip, s.contact_P, arm.q, arm.qd)
        if self._guard:
            port = side.guard.port  # type: ignore[union-attr]  # _guard: the side has one
            parts += (port.W, port.E_diss, port.offset)
        rows.put(i, parts)

    def log(self, steps: int | None = None) -> dict:
        """The first ``steps`` ticks (default: all): ``slave_tick_us``; with the guard,
        ``tdpa_W_slave_J``, ``tdpa_diss_slave_J``, ``tdpa_drift_M``."""
        r = self.rows
        n = r.n if steps is None else min(int(steps), r.n)
        out = {"slave_tick_us": r.column("tick_ns", n) * 1e-3}
        if self._guard:
            out.update(tdpa_W_slave_J=r.column("gW", n), tdpa_diss_slave_J=r.column("gE", n),
                       tdpa_drift_M=r.column("gD", n))
        return out


def capture_of(side: Any, kind: type, before: Any = None) -> Any:
    """The side's capture hook of ``kind`` (:class:`MasterRecorder` or :class:`SlaveRecorder`);
    if it has none, one is added: just before ``before`` among its hooks, else last."""
    for h in side.hooks:
        if isinstance(h, kind):
            return h
    cap = kind(side)
    at = next((k for k, h in enumerate(side.hooks) if h is before), None)
    if at is None:
        side.add_hooks(cap)
    else:
        side.hooks.insert(at, cap)
    return cap
