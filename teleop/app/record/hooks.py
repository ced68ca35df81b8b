"""The recorder's hooks: each side's tick copied into its ring, for the writer to write.

    writer = RecordWriter(folder / "record.mcap", metadata={"scene": scene.name})
    master.side.add_hooks(MasterRecorderMcap(writer, side=master.side))    # a master-side hook
    slave.side.add_hooks(SlaveRecorderMcap(writer, side=slave.side))       # a slave-side hook
    ... run ...
    writer.close()

or, on the in-process loop, one loop hook for both: ``run_scene(scene, hooks=[LoopRecorderMcap(writer)])``.

A side's row is its scalars (``struct``) and its arrays' bytes joined and copied into the next row
of a preallocated ring in memory shared with the writer, once the tick is over; in one process the
slave's hook writes both sides' rows after the slave's tick, the master's hook only notes that its
tick ended (``tools/record_bench.py`` measures what it costs the tick). A hook reads, it never
changes the physics. The channels (frames: ``patient``
is the slave's world, ``master`` the master's workspace, placed in ``patient`` on ``/tf_static`` by
the registration's rotation and offset; its scale, master:slave, is not a transform and is left out):

=========================  ==============================  ============================================
topic                      schema                          what
=========================  ==============================  ============================================
/master/tool_pose          geometry_msgs/msg/PoseStamped   the reference tool (``master``)
/master/hand_wrench        geometry_msgs/msg/WrenchStamped the operator's hand on it (``reference_tool_M``)
/master/felt_wrench        geometry_msgs/msg/WrenchStamped the slave's wrench it stepped under
/master/joints             sensor_msgs/msg/JointState      a device's joints (the cobot; m x3, rad x3)
/master/tf                 tf2_msgs/msg/TFMessage          reference_tool, reference_tool_M, device
/master/state              JSON teleop.MasterTick          status, gain, heartbeat, guard, tick CPU time,
                                                           twist, the channel's force for the next step
/master/can                JSON teleop.CanFrame            the cobot's CAN frames (simulated bus)
/slave/tool_pose           geometry_msgs/msg/PoseStamped   the slave tool (``patient``)
/slave/target_pose         geometry_msgs/msg/PoseStamped   its target, on the fixture
/slave/contact             geometry_msgs/msg/WrenchStamped the tissue's wrench at the tip (``blade_tip``)
/slave/joints              sensor_msgs/msg/JointState      the arm's joints (position, velocity)
/slave/tf                  tf2_msgs/msg/TFMessage          slave_tool, slave_target, blade_tip
/slave/state               JSON teleop.SlaveTick           status, heartbeat, commands, tracking errors,
                                                           twist, guard
/tf_static                 tf2_msgs/msg/TFMessage          patient -> master (the registration)
/link/events               JSON teleop.LinkEvent           what :meth:`RecordWriter.link_event` was given
/master/link, /slave/link  JSON teleop.LinkTick            a two-process side's link per tick: the
                                                           delivery schedule and the time stamps
                                                           (:class:`LinkRecorderMcap`)
/operator/keys             JSON teleop.OperatorKeys        a keyboard session's reads, by tick
=========================  ==============================  ============================================

``reference_tool_M`` and ``blade_tip`` are frames at the tool's position and the blade tip with
the ``master`` and ``patient`` axes: the wrenches are expressed in those axes and drawn there.
"""

from __future__ import annotations

import struct
import time
from typing import Any

import numpy as np

from teleop.app.record.emit import Columns
from teleop.app.record.writer import RecordWriter, Source
from teleop.tick.ports import Hook

#: a row's first nine numbers (the side's scalars)
_HEAD = struct.Struct("<9d")
#: what a non-contiguous array raises when joined (then the row is filled the slow way, with numpy's
#: casting, as it is when the joined bytes are not the row's size)
_COPY_ERRORS = (BufferError, ValueError, TypeError, IndexError, struct.error)
_JOIN = b"".join
_MASTER_FIXED = ("i", "t", "wall", "status", "gain", "lost", "peer_lost", "tick_ns", "cmd_err", "p", "R", "V",
                 "hand", "felt", "fb")
_SLAVE_FIXED = ("i", "t", "wall", "status", "lost", "tick_ns", "last_seq", "without", "skipped", "p_t", "R_t",
                "p", "R", "v", "w", "tip", "contact")


def _names(model: Any, n: int, prefix: str) -> list[str]:
    names = [str(x) for x in list(getattr(model, "names", ()))[1:]] if model is not None else []
    return names if len(names) == n else [f"{prefix}{k}" for k in range(n)]


class _CanTee:
    """Stands in for the simulated bus's capture: every frame to the record, and to the capture it
    replaces (if any). In the tick (the bus runs there): one tuple appended, no more."""

    def __init__(self, prev: Any, source: Source) -> None:
        self.prev, self.frames = prev, source.can_frames

    def write(self, msg: Any, t_s: float, is_rx: bool = True) -> None:
        data = bytes(msg.data)
        self.frames.append((t_s, msg.arbitration_id, is_rx, msg.is_fd, msg.is_error_frame, msg.dlc, len(data), data))
        if self.prev is not None:
            self.prev.write(msg, t_s, is_rx)

    def close(self) -> None:
        if self.prev is not None:
            self.prev.close()


def _master_source(writer: RecordWriter, side: Any, prefix: str, can: bool) -> Source:
    c = Columns()
    for k in ("i", "t", "wall", "status", "gain", "lost", "peer_lost", "tick_ns", "cmd_err"):
        c.add(k)
    for k, n in (("p", 3), ("R", 9), ("V", 6), ("hand", 6), ("felt", 6), ("fb", 6)):
        c.add(k, n)
    joints = side.master.joints()
    nj = 0 if joints is None else len(joints)
    if nj:
        c.add("joints", nj)
        c.add("dev_p", 3)
        c.add("dev_R", 9)
    guarded = side.guard is not None
    if guarded:
        for k in ("gW", "gE", "gA"):
            c.add(k, 6)
    reg = getattr(side.feedback, "reg", None)
    meta = {"prefix": prefix, "nj": nj, "guarded": guarded, "can_t0": None,
            "joint_names": _names(getattr(getattr(side.master, "model", None), "model", None), nj, "joint"),
            "registration": None if reg is None else (np.array(reg.X_PM_p, float), np.array(reg.X_PM_R, float))}
    return Source(writer, "master", c, meta, can=can)


class MasterRecorderMcap(Hook):
    """A master-side hook recording the :class:`~teleop.tick.master_side.MasterSide` into
    ``writer`` under ``prefix`` (see the module docstring for the channels). The side sets its
    status after its hooks, so tick i's row is written once the tick is over: by the slave-side
    hook of the same writer right after the slave's tick i (the in-process loop: one hook, one
    pass for both rows), else as tick i + 1 begins (before the tick changes anything), or at
    ``writer.close()``; the wall clock is read as tick i ends either way. ``can``: on a simulated
    cobot, record the bus's frames (the simulated device's capture point is teed while
    recording). ``side``: the side, to make the ring now rather than at the first tick (its
    memory is then laid out before the clock starts)."""

    def __init__(self, writer: RecordWriter, prefix: str = "/master", can: bool = True, side: Any = None) -> None:
        self.writer, self.prefix, self.can = writer, prefix, can
        self.source: Source | None = None
        self._side: Any = None
        self._begun = self._tap = self._extra = False
        self._tee: tuple[Any, _CanTee] | None = None
        #: the tick whose row is not written yet (-1: none): its time (s), the wall clock as it ended
        #: (Unix time, s) and its side
        self._pend = -1
        self._pend_t = self._wall = 0.0
        self._pend_side: Any = None
        writer._master_hooks.append(self)
        if side is not None:
            self._make(side)

    @property
    def dropped(self) -> int:
        return 0 if self.source is None else self.source.dropped

    def _make(self, side: Any) -> Source:
        sim = getattr(side.master, "sim", None)
        self._tap = bool(self.can and sim is not None and hasattr(sim, "capture") and hasattr(side.master, "t"))
        src = self.source = _master_source(self.writer, side, self.prefix, self._tap)
        assert list(src.cols.at)[:len(_MASTER_FIXED)] == list(_MASTER_FIXED) and src.cols.at["fb"][1] == 45
        self._extra = src.cols.width > 45
        src.finalize = self.finalize  # type: ignore[method-assign]
        self._side = side
        return src

    def _begin(self, i: int, t_s: float, side: Any, before: bool) -> Source:
        """The first tick: the ring (unless made already), the bus's capture teed."""
        src = self.source or self._make(side)
        self._begun, self._side = True, side
        sim = getattr(side.master, "sim", None)
        if self._tap and sim is not None:
            tee = _CanTee(sim.capture, src)
            sim.capture = tee
            self._tee = (sim, tee)
            # the bus's clock when tick i starts (before) or ends (after), less the run's: the offset
            can_t0 = float(side.master.t) - t_s - (0.0 if before else side.dt)
            self.writer._send(("meta", src.sid, {"can_t0": can_t0}))
        return src

    def before_tick(self, i: int, t_s: float, side: Any) -> None:
        if self._pend >= 0:  # tick i - 1's row, not written by a slave's hook: now, before this tick changes it
            self._write()
        elif not self._begun:
            self._begin(i, t_s, side, before=True)

    def after_tick(self, i: int, t_s: float, side: Any) -> None:
        if not self._begun:
            self._begin(i, t_s, side, before=False)
        elif self._pend >= 0:  # a tick with no before_tick: its predecessor's values are gone, not recorded
            self._pend = -1
            if self.source is not None:
                self.source.ring.dropped += self.source.live
        self._pend = i
        self._pend_t = t_s
        self._wall = time.time()
        self._pend_side = side

    def _write(self, status: str | None = None) -> None:
        """The pending tick's row, from its side as the tick left it, with the status it ended in
        (the side's now, or ``status``), copied into the ring and handed to the writer."""
        side, src, i = self._pend_side, self.source, self._pend
        self._pend = -1
        if src is None:
            return
        s = side.status if status is None else status
        try:
            code = src._codes[s]
        except KeyError:
            code = src.code(s)
        ring = src.ring
        w = ring.w
        if not src.live or (w - ring.r >= ring.cap and not ring.room()):
            ring.dropped += src.live
            return
        st = side.state
        parts = (_HEAD.pack(i, self._pend_t, self._wall, code, side.gain, side.heart.lost, side.peer_lost,
                            side.tick_ns, side.command_errors), st.p, st.R, st.V, side.hand_W, side.felt_W,
                 side.feedback_W)
        o = ring.data + (w % ring.cap) * ring.row_bytes
        try:  # the arrays' bytes, joined, into the shared row in one copy (_MASTER_FIXED's order)
            src.region[o:o + ring.row_bytes] = _JOIN(parts + self._extras(side) if self._extra else parts)
        except _COPY_ERRORS:  # an array not contiguous float64: numpy's casting
            self._fill_slow(src.row(w), i, side, code)
        ring.w = w = w + 1  # published (Source.publish, inline: this is the tick's time)
        ring.hdr[0] = w
        if src.can_frames:
            src._publish_can()
        if w - ring.r >= src.high and not src.realtime:
            src.high_water()

    def _extras(self, side: Any) -> tuple:
        out: tuple = ()
        if self.source is not None and "joints" in self.source.cols.at:
            m = side.master
            pv, Rv = m.virtual_pose()
            out += (m.joints(), pv, Rv)
        if side.guard is not None:
            port = side.guard.port
            out += (port.W, port.E_diss, port.action)
        return out

    def _fill_slow(self, row: np.ndarray, i: int, side: Any, code: int) -> None:
        st = side.state
        np.concatenate([(i, self._pend_t, self._wall, code, side.gain, side.heart.lost, side.peer_lost, side.tick_ns,
                         side.command_errors), np.ravel(st.p), np.ravel(st.R), np.ravel(st.V), np.ravel(side.hand_W),
                        np.ravel(side.felt_W), np.ravel(side.feedback_W), *map(np.ravel, self._extras(side))], out=row)

    def commit(self, status: str) -> None:
        """Hand the pending row to the writer with the status its tick ended in."""
        if self._pend >= 0:
            self._write(status)

    def record(self, i: int, t_s: float, side: Any) -> None:
        """Tick i's row handed over at once with the side's status as it is now (a loop hook, which
        runs after the side has set its status)."""
        self.after_tick(i, t_s, side)
        self._write()

    def finalize(self) -> None:
        """The last row (its status as the side holds it now); the bus's capture given back."""
        if self._pend >= 0:
            self._write()
        if self._tee is not None:
            sim, tee = self._tee
            if sim.capture is tee:
                sim.capture = tee.prev
            self._tee = None


def _slave_source(writer: RecordWriter, side: Any, prefix: str) -> Source:
    c = Columns()
    for k in ("i", "t", "wall", "status", "lost", "tick_ns", "last_seq", "without", "skipped"):
        c.add(k)
    nv = len(side.arm.q)
    for k, n in (("p_t", 3), ("R_t", 9), ("p", 3), ("R", 9), ("v", 3), ("w", 3), ("tip", 3), ("contact", 6),
                 ("q", nv), ("qd", nv)):
        c.add(k, n)
    guarded = side.guard is not None
    if guarded:
        for k in ("gW", "gE", "gD"):
            c.add(k, 6)
    reg = side.reg
    meta = {"prefix": prefix, "guarded": guarded, "joint_names": _names(getattr(side.arm, "model", None), nv, "joint"),
            "registration": (np.array(reg.X_PM_p, float), np.array(reg.X_PM_R, float))}
    return Source(writer, "slave", c, meta)


class SlaveRecorderMcap(Hook):
    """A slave-side hook recording the :class:`~teleop.tick.slave_side.SlaveSide` into
    ``writer`` under ``prefix`` (see the module docstring for the channels); ``side`` as for
    :class:`MasterRecorderMcap`. When the writer has one master-side hook and its tick i is over
    but not written (the in-process loop: the master's tick i, then the slave's), this hook
    writes the master's row of tick i too, in the same pass: the master's side is not touched
    between its tick and the slave's. A writer's hooks are called from one thread, as the runs
    do."""

    def __init__(self, writer: RecordWriter, prefix: str = "/slave", side: Any = None) -> None:
        self.writer, self.prefix = writer, prefix
        self.source: Source | None = None
        self._master: MasterRecorderMcap | None = None
        if side is not None:
            self._make(side)

    def _make(self, side: Any) -> Source:
        src = self.source = _slave_source(self.writer, side, self.prefix)
        assert list(src.cols.at)[:len(_SLAVE_FIXED)] == list(_SLAVE_FIXED) and src.cols.col("q") == 48
        masters = self.writer._master_hooks
        self._master = masters[0] if len(masters) == 1 else None
        return src

    @property
    def dropped(self) -> int:
        return 0 if self.source is None else self.source.dropped

    def after_tick(self, i: int, t_s: float, side: Any) -> None:
        src = self.source or self._make(side)
        m = self._master
        if m is not None and m._pend == i:  # the master's tick i, over and not written yet
            m._write()
        ring = src.ring
        w = ring.w
        if not src.live or (w - ring.r >= ring.cap and not ring.room()):
            ring.dropped += src.live
            return
        s, arm, guard = side.state, side.arm, side.guard
        try:
            code = src._codes[s.status]
        except KeyError:
            code = src.code(s.status)
        parts = (_HEAD.pack(i, t_s, time.time(), code, side.heart.lost, side.tick_ns, side.last_seq,
                            side.without_command, side.skipped),
                 s.p_t, s.R_t, s.p, s.R, s.v, s.w, s.tip, s.contact_P, arm.q, arm.qd)
        o = ring.data + (w % ring.cap) * ring.row_bytes
        try:  # the arrays' bytes, joined, into the shared row in one copy (_SLAVE_FIXED's order)
            src.region[o:o + ring.row_bytes] = _JOIN(
                parts if guard is None else (*parts, guard.port.W, guard.port.E_diss, guard.port.offset))
        except _COPY_ERRORS:  # an array not contiguous float64: numpy's casting
            slow = [(i, t_s, time.time(), code, side.heart.lost, side.tick_ns, side.last_seq, side.without_command,
                     side.skipped), s.p_t, s.R_t, s.p, s.R, s.v, s.w, s.tip, s.contact_P, arm.q, arm.qd]
            if guard is not None:
                slow += (guard.port.W, guard.port.E_diss, guard.port.offset)
            np.concatenate([np.ravel(a) for a in slow], out=src.row(w))
        ring.w = w = w + 1  # published (Source.publish, inline: this is the tick's time)
        ring.hdr[0] = w
        if w - ring.r >= src.high and not src.realtime:
            src.high_water()


class LoopRecorderMcap(Hook):
    """A loop hook for the in-process :class:`~teleop.tick.loop.BilateralLoop`: both sides into
    one ``writer`` (the master's row handed over at once: the loop's hooks run after the side has
    set its status). ``loop``: the loop, to make the rings now rather than at the first tick."""

    def __init__(self, writer: RecordWriter, can: bool = True, loop: Any = None) -> None:
        self.writer = writer
        self.master = MasterRecorderMcap(writer, can=can, side=None if loop is None else loop.master_side)
        self.slave = SlaveRecorderMcap(writer, side=None if loop is None or loop.slave_side is None
                                       else loop.slave_side)

    def before_tick(self, i: int, t_s: float, loop: Any) -> None:
        self.master.before_tick(i, t_s, loop.master_side)

    def after_tick(self, i: int, t_s: float, loop: Any) -> None:
        if loop.slave_side is not None:
            self.master.after_tick(i, t_s, loop.master_side)
            self.slave.after_tick(i, t_s, loop.slave_side)  # the master's row too
        else:
            self.master.record(i, t_s, loop.master_side)


_LINK_ROW = struct.Struct("<13d")


class LinkRecorderMcap(Hook):
    """A side hook recording its link's answers tick by tick on ``<prefix>/link``: ``tap`` (a
    :class:`~teleop.link.schedule.ScheduleTap`, the link the side ticks on) is reset before each
    tick and read after it. What a two-process run needs to be run again
    (:class:`~teleop.link.schedule.ScheduleLink`), and its latency per tick."""

    def __init__(self, writer: RecordWriter, tap: Any, prefix: str) -> None:
        from teleop.link.schedule import COLUMNS

        c = Columns()
        c.add("i")
        c.add("t")
        for k in COLUMNS[:5]:
            c.add(k)
        c.add("chain", 6)
        assert c.width == _LINK_ROW.size // 8
        self.tap, self.source = tap, Source(writer, "link", c, {"prefix": prefix})

    def before_tick(self, i: int, t_s: float, side: Any) -> None:
        self.tap.begin()

    def after_tick(self, i: int, t_s: float, side: Any) -> None:
        src = self.source
        if not src.live:
            return
        o = src.next_row()
        if o >= 0:
            _LINK_ROW.pack_into(src.region, o, i, t_s, *self.tap.row())
            src.publish()
