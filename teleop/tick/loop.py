"""THE bilateral tick: one control period of the whole teleoperator, top to bottom.

Master side: the operator's hand pushes (``operator.wrench``), the master senses it (bus in, load
cell, φ: eq. 4), the reference tool steps under it plus the force fed back (§II, eqs. 8-11), the
master commands the device to follow the tool (FF + PID, eqs. 18-19, bus out) and sends the virtual
tool to the slave. Slave side: the newest command is followed under the fixture rows (QP) and the
contact wrench goes back, with the contact's local damping. Master again: the feedback is mapped and
filtered for the next step, where the damping is rendered at the tool's own twist
(:meth:`teleop.tick.feedback.FeedbackPath.render`), so no delay sits in that loop.
Master and slave share nothing but the two messages of :mod:`teleop.link`, so a link that delays,
drops or crosses a network changes nothing here.

With ``heartbeat_s`` each side watches the link as the two-process run does
(:mod:`teleop.tick.heartbeat`, one source): a side that hears nothing for longer goes to its safe
state (the master: tool held at zero velocity, remote force dropped; the slave: joints held,
replies ``link_lost``) and resumes when messages come again. The lockstep link never trips it.

Hooks see the tick before and after (metrics, logs, views); a hook never changes the physics.
The tick never raises on its inputs: every part reports a status, and :meth:`BilateralLoop.tick`
returns the first that is not "ok" on the master side; the slave's status is reported apart
(see :data:`SLAVE_STATUS_RANK`), because a slave that relaxed its fixtures has not failed the tick.
"""

from __future__ import annotations

from time import perf_counter_ns

import numpy as np

from teleop.util.errors import ConfigError
from teleop.link.base import Link, LockstepLink
from teleop.tick.heartbeat import HeartbeatState, follow_or_hold, hold_master
from teleop.tick.messages import MessageError, ToolCommand


class Hook:
    """Called around every tick with the loop (read its ``tool``, ``master``, ``slave``, ...)."""

    def before_tick(self, i: int, t_s: float, loop: "BilateralLoop") -> None:
        """Before the operator acts (the state the tick starts from)."""

    def after_tick(self, i: int, t_s: float, loop: "BilateralLoop") -> None:
        """After the feedback came back (the state the tick ends in)."""


class BilateralLoop:
    """``tool`` a ReferenceTool, ``master`` a master (ideal or cobot), ``operator`` with
    ``wrench(t, p, R, v, w)`` and ``clutch_engaged``; with a ``slave`` (a SlaveSide), a ``link``
    (lockstep by default) and a ``feedback`` path (FeedbackPath) to the master; ``guard`` a
    (MasterGuard, SlaveGuard) pair (:mod:`teleop.tick.guard`) puts the passivity guard at the two
    ends of the link; ``heartbeat_s`` (s, or None: off) the heartbeat's timeout on both sides
    (``master_heart``, ``slave_heart``)."""

    def __init__(self, tool, master, operator, dt_s: float, slave=None, link: Link | None = None,
                 feedback=None, hooks=(), guard=None, heartbeat_s: float | None = None):
        self.tool, self.master, self.operator, self.dt = tool, master, operator, float(dt_s)
        if slave is not None and feedback is None:
            raise ConfigError("BilateralLoop: a slave needs a feedback path to the master, e.g. "
                              "feedback=FeedbackPath(registration, cutoff_hz=20.0, dt_s=dt_s)")
        self.slave, self.feedback, self.hooks = slave, feedback, tuple(hooks)
        self.link = link if link is not None else LockstepLink()
        self.master_guard, self.slave_guard = guard if guard is not None else (None, None)
        self.hand_W = np.zeros(6)      # what the hand pushed with this tick (N, N*m)
        self.feedback_W = np.zeros(6)  # the channel's force for the next tool step (after the guard)
        self.felt_W = np.zeros(6)      # the slave's wrench the tool stepped under (rendered, N, N*m)
        self.status = "ok"
        self.command_errors = 0        # ticks whose command could not be made (non-finite)
        self.tick_ns = 0               # the last tick's physics, hooks excluded (ns, CPU clock)
        on = heartbeat_s is not None and slave is not None
        self.master_heart = HeartbeatState(heartbeat_s) if on else None
        self.slave_heart = HeartbeatState(heartbeat_s) if on else None
        self.peer_lost = False         # the newest reply says the slave hears nothing

    def tick(self, i: int) -> str:
        """One period; returns the master side's status ("ok" or what stopped it)."""
        t, master, tool = i * self.dt, self.master, self.tool
        for h in self.hooks:
            h.before_tick(i, t, self)
        t0 = perf_counter_ns()
        lost = self.master_heart is not None and self.master_heart.update(
            t, self.link.last_heard_s("master"), self.peer_lost)
        self.hand_W = self.operator.wrench(t, *master.hand_state())
        master.set_clutch(self.operator.clutch_engaged)
        f_v = master.sense(self.hand_W)                            # bus in, load cell, eq. 4
        p_r, R_r = tool.pose()
        if lost:                                                   # safe state: hold, no remote force
            st, st_m = "ok", hold_master(tool, master, self.feedback, p_r, R_r, self.master_guard)
            self.feedback_W = self.felt_W = np.zeros(6)
        else:
            v_r, w_r = tool.twist()
            if self.feedback is not None:                          # the contact's damping, here and now
                self.felt_W = self.feedback.render(self.feedback_W, tool, f_v, self.dt, (p_r, R_r, v_r, w_r))
            st = tool.step(self.dt, f_v + self.felt_W)             # §II: eqs. 8-11
            st_m = master.command(p_r, R_r, np.concatenate((v_r, w_r)), tool.acceleration_W)  # 18-19
        if self.slave is not None:
            self._send_command(i, t, lost)                          # master side ends here
            cmd = self.link.receive_command(t)                      # slave side
            lost_s = self.slave_heart is not None and self.slave_heart.update(t, self.link.last_heard_s("slave"))
            self.link.send_feedback(follow_or_hold(self.slave, self.slave_guard, cmd, t, lost_s))
            msg = self.link.receive_feedback(t)                                # master again
            if msg is not None:
                self.peer_lost = msg.status == "link_lost"
            if not lost:
                self._feel(msg, t)
        self.tick_ns = perf_counter_ns() - t0
        for h in self.hooks:
            h.after_tick(i, t, self)
        self.status = st if st != "ok" else st_m
        return self.status

    def _feel(self, msg, t: float) -> None:
        """The master's feedback path: the reply (or None) mapped and filtered for the next step."""
        self.feedback_W = self.feedback.update(msg)
        if self.master_guard is not None:                           # TDPA: damp what it felt
            self.feedback_W = self.master_guard.feedback(self.feedback_W, np.concatenate(self.tool.twist()), msg, t)

    def _send_command(self, i: int, t: float, lost: bool = False) -> None:
        """The virtual tool (the observer's estimate) to the slave, the clutch open while the link
        is ``lost`` (the command is then only the heartbeat); a master whose estimate is not
        finite sends nothing (the slave holds) and reports it."""
        try:
            mg = self.master_guard
            energy = None if mg is None else mg.energy_after(np.concatenate(self.tool.twist()))
            self.link.send_command(ToolCommand(i, t, *self.master.virtual_estimate(),
                                               self.operator.clutch_engaged and not lost, energy))
        except MessageError:
            self.command_errors += 1
