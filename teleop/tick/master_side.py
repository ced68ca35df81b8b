"""The master side of the bilateral tick. It owns everything on the master's end of the link: the
reference tool (§II), the master device (§III), the operator's hand, the force-feedback path, the
passivity guard's master port, its heartbeat and its safe state. Every run composes it: the
in-process loop (:mod:`teleop.tick.loop`), the master process over Zenoh
(:mod:`teleop.app.netrun`), the keyboard session, the benches and the studies.

One tick, in order (:meth:`MasterSide.tick`):

1. the slave's newest reply, if one came since the last tick, is felt: mapped and filtered by the
   feedback path, then damped by the guard (one process feels it here too: the reply to the
   command of tick i - 1 is felt before step i, wherever the slave runs);
2. the heartbeat is checked (silence, or the slave's reply saying it hears nothing);
3. the hand pushes, the master senses it (bus in, load cell, eq. 4);
4. the tool steps under the hand's wrench plus the felt wrench, whose contact damping is rendered
   at the tool's own twist (eqs. 8-11), and the device is commanded to follow it (eqs. 18-19, bus
   out) -- or, while the link is lost, :meth:`MasterSide.hold`;
5. the tool's new state goes to the slave as a :class:`~teleop.tick.messages.ToolCommand`
   (clutch out while lost: it is then only the heartbeat).

The tool is read once per tick (a :class:`~teleop.tick.ports.ToolState`, kept to start the next
tick). After a lost link the slave's force comes back as a ramp: the channel's force is scaled
by a gain that moves by ``dt / RAMP_S`` a tick, down while held and up after (the contact's
damper, passive, is rendered whole, and the hand's wrench is scaled alike while the gain is
below one), so neither the loss nor the resume steps the force and the tool does not lurch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from time import perf_counter_ns
from typing import Any

import numpy as np

from teleop.tick.feedback import FeedbackPath
from teleop.tick.guard import MasterGuard
from teleop.tick.heartbeat import HeartbeatState
from teleop.tick.messages import ContactFeedback, MessageError, ToolCommand
from teleop.tick.plausible import ReplyCheck, ReplyLimits
from teleop.tick.ports import Hook, MasterEnd, Operator, ToolState

#: the heartbeat's timeout when none is given (s): ``[link] heartbeat_ms``'s default
HEARTBEAT_S = 0.02
#: the largest wrench a hand applies (N, N*m): a push past it, or not 6 finite numbers, is refused
PUSH_MAX = (1e4, 1e3)
#: the time the slave's force takes to fade out when the link is lost, and back in after (s)
RAMP_S = 0.2
_Z6 = np.zeros(6)
_Z6.flags.writeable = False


class MasterSide:
    """``tool`` a :class:`~teleop.dynamics.tool.ReferenceTool`, ``master`` a
    :class:`~teleop.master.base.Master` (ideal or the cobot), ``operator`` the hand; ``dt_s`` the
    period (s); ``feedback`` the path of the slave's force (None: no slave, nothing felt);
    ``guard`` the passivity guard's master port (None: unguarded); ``heartbeat_s`` the silence
    (s) after which the slave is lost; ``hooks`` see this side around each tick; ``limits`` what a
    real slave can send (:class:`~teleop.tick.plausible.ReplyLimits`): a reply past them is
    refused and counted, the tool is held and the side's status is ``implausible_feedback``.

    Read-outs for hooks: ``hand_W`` the hand's wrench this tick, ``felt_W`` the slave's wrench the
    tool stepped under, ``feedback_W`` the channel's force for the next step (after the guard),
    all (6,: N, N*m, M); ``state`` the tool as read at the end of the tick; ``status``."""

    def __init__(self, tool: Any, master: Any, operator: Operator, dt_s: float, feedback: FeedbackPath | None = None,
                 guard: MasterGuard | None = None, heartbeat_s: float = HEARTBEAT_S,
                 hooks: Sequence[Hook] = (), limits: ReplyLimits | None = None) -> None:
        self.tool, self.master, self.operator, self.dt = tool, master, operator, float(dt_s)
        self.feedback, self.guard, self.hooks = feedback, guard, list(hooks)
        self.heart = HeartbeatState(heartbeat_s)
        self.hand_W = np.zeros(6)
        self.felt_W = np.zeros(6)
        self.feedback_W = np.zeros(6)
        self.gain = 1.0                # the slave's force as rendered: 1, or ramping after a lost link
        self.status = "ok"
        self.peer_lost = False         # the newest reply says the slave hears nothing
        self.command_errors = 0        # ticks whose command could not be made (not finite)
        self.pushes_refused = 0        # ticks whose hand wrench could not be applied (see PUSH_MAX)
        self.tick_ns = 0               # the last tick's CPU time, hooks excluded (ns)
        self.slave_statuses: dict[str, int] = {}  # replies heard, per status
        self.reply_lag: dict[str, int] = {}  # ticks by how many ticks old the newest reply was ("none")
        self._ramp = self.dt / RAMP_S
        self._holding = False
        self._held_felt = _Z6          # the felt wrench at full gain when the hold began
        self.check = ReplyCheck(limits if limits is not None else ReplyLimits(), self.dt)
        self._refusing: str | None = None  # why a reply was refused: the side holds and says so
        self.state = self._read()

    def _read(self) -> ToolState:
        p, R = self.tool.pose()
        v, w = self.tool.twist()
        V = np.empty(6)
        V[:3], V[3:] = v, w
        self._q_ref, self._qd_ref = self.tool.state.q, self.tool.state.qd
        return ToolState(p, R, V)

    def tick(self, i: int, t_s: float, link: MasterEnd | None = None) -> str:
        """The master's half of tick ``i`` at time ``t_s`` (s), on ``link`` (None: no slave).
        Returns this side's status ("ok" or what stopped it)."""
        tool, master = self.tool, self.master
        for h in self.hooks:
            h.before_tick(i, t_s, self)
        t0 = perf_counter_ns()
        lost = False
        if link is not None:
            msg = link.receive_feedback(t_s - self.dt) if i > 0 else None  # what came in the last period
            if msg is not None and msg.t_s >= 0 and self._refusing is None:
                self._refusing = self.check.reason(msg)  # no real slave sends it: hold, end the run
            if self._refusing is not None:
                msg = None
            self._heard(i, msg)
            lost = self.heart.update(link.clock(t_s), link.last_heard_s("master"), self.peer_lost)
            if not lost and i > 0:
                self._feel(msg, t_s - self.dt)
        self.hand_W = self.operator.wrench(t_s, *master.hand_state())
        if not _applicable(self.hand_W):  # no hand pushes so: not applied, counted, said in the status
            self.pushes_refused += 1
            self.hand_W = _Z6
        master.set_clutch(self.operator.clutch_engaged)
        f_v = master.sense(self.hand_W)                               # bus in, load cell, eq. 4
        state = self.state if self._fresh() else self._read()
        if lost or self._refusing is not None:
            st, st_m = ("ok" if lost else "implausible_feedback"), self.hold(state)
        else:
            st, st_m = self._step(state, f_v)
        self.state = self._read()
        if link is not None:
            self._send(i, t_s, link, lost)
        self.tick_ns = perf_counter_ns() - t0
        self.heart.motion(self.state.p, math.hypot(*tool.qd.tolist()))
        self.status = st if st != "ok" else st_m
        for h in self.hooks:  # they see the tick as it ended, its status too
            h.after_tick(i, t_s, self)
        return self.status

    def _fresh(self) -> bool:
        """The kept read-out still describes the tool (nothing reset or moved it between ticks)."""
        return self._q_ref is self.tool.state.q and self._qd_ref is self.tool.state.qd

    def _step(self, state: ToolState, f_v: np.ndarray) -> tuple[str, str]:
        """The tool stepped under the hand and the slave's force; the device told to follow.
        While the gain ramps back after a hold, the hand's wrench is scaled with the channel's
        force: the tool comes back to life gently instead of lurching under a hand that kept
        pushing against the held device."""
        tool = self.tool
        self._holding = False
        g = self.gain = min(1.0, self.gain + self._ramp)
        f_in = f_v if g == 1.0 else g * f_v
        if self.feedback is not None:
            self.felt_W = self.feedback.render(self.feedback_W, tool, f_in, self.dt, state, g)
        st = tool.step(self.dt, f_in + self.felt_W)                   # §II: eqs. 8-11
        if self.guard is not None and self.guard.slows_motion:  # passive by construction: the motion slowed if need be
            v, w = tool.twist()
            sigma = self.guard.motion_scale(np.concatenate((v, w)))
            if sigma < 1.0:
                tool.scale_velocity(sigma)
        return st, self.master.command(state.p, state.R, state.V, tool.acceleration_W)  # eqs. 18-19

    def hold(self, state: ToolState) -> str:
        """The safe state for one tick (the slave is lost): the tool at zero velocity, not
        stepped; the slave's force dropped (nothing fed to the next step, the guard told nothing
        is rendered) and faded out of ``felt_W`` by the gain; the device commanded to hold the
        tool's pose. The feedback path keeps its last contact model, which the replies refresh
        after the resume while the gain brings the force back. Returns the device's status."""
        if not self._holding:
            self._holding = True
            self._held_felt = self.felt_W / self.gain if self.gain > 0.0 else _Z6
        self.gain = max(0.0, self.gain - self._ramp)
        self.felt_W = self.gain * self._held_felt
        self.feedback_W = np.zeros(6)
        self.tool.hold()
        if self.guard is not None:
            self.guard.drop_force()
        # the tool's twist and acceleration as a tick's are (writable arrays): a device's compiled
        # controller meets no new argument type in the hold (tests/integration/test_warm_up.py)
        return self.master.command(state.p, state.R, np.zeros(6), np.zeros(6))

    def _heard(self, i: int, msg: ContactFeedback | None) -> None:
        if msg is not None and msg.t_s >= 0:
            self.slave_statuses[msg.status] = self.slave_statuses.get(msg.status, 0) + 1
            self.peer_lost = msg.status == "link_lost"
        lag = "none" if msg is None or msg.command_seq < 0 else str(min(i - msg.command_seq, 5))
        self.reply_lag[lag] = self.reply_lag.get(lag, 0) + 1

    def _feel(self, msg: ContactFeedback | None, t_s: float) -> None:
        """The reply (or None: hold the last) mapped and filtered; damped by the guard."""
        if self.feedback is None:
            return
        self.feedback_W = self.feedback.update(msg, self.state)
        if self.guard is not None:
            self.feedback_W = self.guard.feedback(self.feedback_W, self.state.V, msg, t_s)

    def _send(self, i: int, t_s: float, link: MasterEnd, lost: bool) -> None:
        """The tool's new state to the slave (clutch out while lost); a state that is not finite
        is not sent (the slave holds) and is counted."""
        g, s, fb = self.guard, self.state, self.feedback
        energy = None if g is None else g.energy_J if lost else g.energy_after(s.V)
        wall = fb.wall_force(s) if fb is not None and fb.wall is not None and not lost else 0.0
        try:
            link.send_command(ToolCommand(i + 1, t_s, s.p, s.R, s.v, s.w, self.operator.clutch_engaged and not lost,
                                          energy, wall))
        except MessageError:
            self.command_errors += 1
        if g is not None:
            g.observe()

    def add_hooks(self, *hooks: Hook) -> None:
        """More hooks, after those given when the side was made."""
        self.hooks.extend(hooks)

    def summary(self) -> dict:
        """This side's part of a run's summary (:func:`teleop.tick.verdict.run_summary`)."""
        out = {"heartbeat": self.heart.summary(), "slave_statuses_heard": dict(self.slave_statuses),
               "reply_lag_ticks": dict(sorted(self.reply_lag.items())), "command_errors": self.command_errors,
               "replies_refused": dict(self.check.refused), "pushes_refused": self.pushes_refused,
               "engine": {"rank_min": int(self.tool.rank), "recharts": self.tool.recharts}}
        if self.feedback is not None:
            out["feedback_damping_refused"] = self.feedback.refused
            if self.feedback.wall is not None:
                out["wall_model"] = self.feedback.wall_summary()
        if self.guard is not None:
            out["passivity_master"] = self.guard.summary()
        return out


def _applicable(W: object) -> bool:
    """A hand wrench the tool can step under: 6 finite numbers within PUSH_MAX (NaN fails every
    comparison, so one pass on Python floats checks both)."""
    w = np.asarray(W, dtype=float)
    if w.shape != (6,):
        return False
    f, m = PUSH_MAX
    a, b, c, d, e, g = w.tolist()
    return -f <= a <= f and -f <= b <= f and -f <= c <= f and -m <= d <= m and -m <= e <= m and -m <= g <= m


class SetWrench:
    """An operator whose wrench the caller sets before each tick (``W``: (6,) N, N*m in M), for
    the benches, studies and tests that drive a master side directly."""

    clutch_engaged = True

    def __init__(self) -> None:
        self.W = np.zeros(6)

    def wrench(self, t_s: float, p: np.ndarray, R: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        return self.W
