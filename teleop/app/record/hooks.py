"""The recorder's hooks: each side's captured row handed to the writer, for it to write.

    writer = RecordWriter(folder / "record.mcap", metadata={"scene": scene.name})
    master.side.add_hooks(MasterRecorderMcap(writer, side=master.side))    # a master-side hook
    slave.side.add_hooks(SlaveRecorderMcap(writer, side=slave.side))       # a slave-side hook
    ... run ...
    writer.close()

or, on the in-process loop, one loop hook for both: ``run_scene(scene, hooks=[LoopRecorderMcap(writer)])``.

A side's tick is captured once, by its capture hook (:class:`~teleop.app.recorders.MasterRecorder`,
:class:`~teleop.app.recorders.SlaveRecorder`: one row of numbers a tick, which the run's log and
metrics read too; a side without one is given one). Here the rows are handed over as they are:
every :data:`HAND_S` of the run's time (10 ms), the rows captured since are copied in one copy
into a preallocated ring in memory shared with the writer, and published
(``tools/record_bench.py`` measures what it costs the tick). A hook reads, it never changes the
physics. The channels (frames: ``patient`` is the slave's world, ``master`` the master's
workspace, placed in ``patient`` on ``/tf_static`` by the registration's rotation and offset;
its scale, master:slave, is not a transform and is left out):

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
from typing import Any

import numpy as np

from teleop.app.record.writer import RecordWriter, Source
from teleop.app.recorders import MasterRecorder, SlaveRecorder, capture_of
from teleop.app.rows import RowLayout
from teleop.tick.ports import Hook


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


#: the run's time (s) a side's captured rows wait before they are handed to the writer together
HAND_S = 0.01


class _Handover:
    """A capture's rows handed to ``src``'s ring in batches of ``every`` ticks: in the tick, one
    comparison; every ``every`` ticks, one copy of the rows' bytes as they are (two where the
    ring wraps). A row is never written again once captured, so a row handed later is the row
    the tick left. Crash safety: a run killed loses the rows not handed yet, ``every`` ticks at
    most (:data:`HAND_S` of the run), besides the writer's open chunk."""

    def __init__(self, src: Source, capture: Any, dt_s: float) -> None:
        self.src, self.capture, self.rows = src, capture, capture.rows
        self.every = max(1, min(src.ring.cap // 4, round(HAND_S / max(float(dt_s), 1e-9))))
        self.done = 0  # rows [0, done) handed over (or dropped)

    def tick_ended(self, i: int, t_s: float, side: Any) -> int:
        """Tick ``i`` of ``side`` is over: its row (captured now if the capture was given this
        tick, after the side's hooks ran) and those before it handed over. Returns the next tick
        whose end hands rows over."""
        if self.rows.n <= i:
            self.capture.after_tick(i, t_s, side)
        self.hand(i + 1)
        return i + self.every

    def hand(self, upto: int) -> None:
        """Rows [done, ``upto``) copied into the ring and published (no room, as a run paced to
        the wall clock may find: dropped and counted)."""
        a, src = self.done, self.src
        k = upto - a
        if k <= 0:
            return
        self.done = upto
        ring = src.ring
        if not src.live or not ring.room(k):
            ring.dropped += k * src.live
            return
        rows = self.rows
        if src.told < len(rows.names):
            src.tell(rows.names)
        rb, cap, w, region = ring.row_bytes, ring.cap, ring.w, src.region
        for seg in rows.segments(a, upto):  # one, or two where the rows span two of their blocks
            m = len(seg) // rb
            at = w % cap
            first = min(m, cap - at)
            o = ring.data + at * rb
            region[o:o + first * rb] = seg[:first * rb]
            if first < m:  # the ring wraps
                region[ring.data:ring.data + (m - first) * rb] = seg[first * rb:]
            w += m
        ring.w = w  # published (Source.publish, inline)
        ring.hdr[0] = w
        if src.can_frames:
            src._publish_can()
        if w - ring.r >= src.high and not src.realtime:
            src.high_water()


class MasterRecorderMcap(Hook):
    """A master-side hook recording the :class:`~teleop.tick.master_side.MasterSide` into
    ``writer`` under ``prefix`` (see the module docstring for the channels): each tick, the row
    of the side's capture (:class:`~teleop.app.recorders.MasterRecorder`), handed over as the
    tick ends. ``can``: on a simulated cobot, record the bus's frames (the simulated device's
    capture point is teed while recording). ``side``: the side, to make the ring now rather than
    at the first tick (its memory is then laid out before the clock starts)."""

    def __init__(self, writer: RecordWriter, prefix: str = "/master", can: bool = True, side: Any = None) -> None:
        self.writer, self.prefix, self.can = writer, prefix, can
        self.source: Source | None = None
        self.capture: MasterRecorder | None = None
        self._begun = self._tap = False
        self._tee: tuple[Any, _CanTee] | None = None
        self.handover: _Handover | None = None
        self._due = -1  # the next tick whose end hands rows over
        if side is not None:
            self._make(side)

    @property
    def dropped(self) -> int:
        return 0 if self.source is None else self.source.dropped

    def _make(self, side: Any) -> Source:
        cap = self.capture = capture_of(side, MasterRecorder, before=self)
        sim = getattr(side.master, "sim", None)
        self._tap = bool(self.can and sim is not None and hasattr(sim, "capture") and hasattr(side.master, "t"))
        layout = cap.rows.layout
        nj = layout.at["joints"][1] - layout.at["joints"][0] if "joints" in layout else 0
        reg = getattr(side.feedback, "reg", None)
        meta = {"prefix": self.prefix, "nj": nj, "guarded": "gW" in layout, "can_t0": None,
                "joint_names": _names(getattr(getattr(side.master, "model", None), "model", None), nj, "joint"),
                "registration": None if reg is None else (np.array(reg.X_PM_p, float), np.array(reg.X_PM_R, float))}
        src = self.source = Source(self.writer, "master", layout, meta, can=self._tap)
        self.handover = _Handover(src, cap, side.dt)
        src.finalize = self.finalize  # type: ignore[method-assign]  # the ring's last rows are this hook's to hand over
        return src

    def _begin(self, i: int, t_s: float, side: Any, before: bool) -> Source:
        """The first tick: the ring (unless made already), the bus's capture teed."""
        src = self.source or self._make(side)
        self._begun = True
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
        if not self._begun:
            self._begin(i, t_s, side, before=True)

    def after_tick(self, i: int, t_s: float, side: Any) -> None:
        if i >= self._due:
            self._hand(i, t_s, side)

    def _hand(self, i: int, t_s: float, side: Any) -> None:
        """Rows up to tick i's handed over (the first tick: the ring and the capture if need be)."""
        if not self._begun:
            self._begin(i, t_s, side, before=False)
        assert self.handover is not None
        self._due = self.handover.tick_ended(i, t_s, side)

    def finalize(self) -> None:
        """The rows not handed over yet, handed over, and the bus's frames since (a device
        stopped as the run ends: they are on the bus too); the bus's capture given back."""
        if self.handover is not None:
            self.handover.hand(self.handover.rows.n)
        src = self.source
        if src is not None and src.can_frames and src.live:
            src._publish_can()
        if self._tee is not None:
            sim, tee = self._tee
            if sim.capture is tee:
                sim.capture = tee.prev
            self._tee = None


class SlaveRecorderMcap(Hook):
    """A slave-side hook recording the :class:`~teleop.tick.slave_side.SlaveSide` into
    ``writer`` under ``prefix`` (see the module docstring for the channels): each tick, the row
    of the side's capture (:class:`~teleop.app.recorders.SlaveRecorder`), handed over as the
    tick ends; ``side`` as for :class:`MasterRecorderMcap`."""

    def __init__(self, writer: RecordWriter, prefix: str = "/slave", side: Any = None) -> None:
        self.writer, self.prefix = writer, prefix
        self.source: Source | None = None
        self.capture: SlaveRecorder | None = None
        self.handover: _Handover | None = None
        self._due = -1  # the next tick whose end hands rows over
        if side is not None:
            self._make(side)

    def _make(self, side: Any) -> Source:
        cap = self.capture = capture_of(side, SlaveRecorder, before=self)
        layout = cap.rows.layout
        reg = side.reg
        meta = {"prefix": self.prefix, "guarded": "gW" in layout,
                "joint_names": _names(getattr(side.arm, "model", None), len(side.arm.q), "joint"),
                "registration": (np.array(reg.X_PM_p, float), np.array(reg.X_PM_R, float))}
        src = self.source = Source(self.writer, "slave", layout, meta)
        self.handover = _Handover(src, cap, side.arm.dt)
        src.finalize = self.finalize  # type: ignore[method-assign]  # the ring's last rows are this hook's to hand over
        return src

    def finalize(self) -> None:
        """The rows not handed over yet, handed over."""
        if self.handover is not None:
            self.handover.hand(self.handover.rows.n)

    @property
    def dropped(self) -> int:
        return 0 if self.source is None else self.source.dropped

    def after_tick(self, i: int, t_s: float, side: Any) -> None:
        if i < self._due:
            return
        if self.source is None:
            self._make(side)
        assert self.handover is not None
        self._due = self.handover.tick_ended(i, t_s, side)


class LoopRecorderMcap(Hook):
    """A loop hook for the in-process :class:`~teleop.tick.loop.BilateralLoop`: both sides into
    one ``writer``, their rows handed over once both sides' ticks are over. ``loop``: the loop,
    to make the rings now rather than at the first tick."""

    def __init__(self, writer: RecordWriter, can: bool = True, loop: Any = None) -> None:
        self.writer = writer
        self.master = MasterRecorderMcap(writer, can=can, side=None if loop is None else loop.master_side)
        self.slave = SlaveRecorderMcap(writer, side=None if loop is None or loop.slave_side is None
                                       else loop.slave_side)

    def before_tick(self, i: int, t_s: float, loop: Any) -> None:
        self.master.before_tick(i, t_s, loop.master_side)

    def after_tick(self, i: int, t_s: float, loop: Any) -> None:
        self.master.after_tick(i, t_s, loop.master_side)
        if loop.slave_side is not None:
            self.slave.after_tick(i, t_s, loop.slave_side)


_LINK_ROW = struct.Struct("<13d")


class LinkRecorderMcap(Hook):
    """A side hook recording its link's answers tick by tick on ``<prefix>/link``: ``tap`` (a
    :class:`~teleop.link.schedule.ScheduleTap`, the link the side ticks on) is reset before each
    tick and read after it. What a two-process run needs to be run again
    (:class:`~teleop.link.schedule.ScheduleLink`), and its latency per tick."""

    def __init__(self, writer: RecordWriter, tap: Any, prefix: str) -> None:
        from teleop.link.schedule import COLUMNS

        c = RowLayout()
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
