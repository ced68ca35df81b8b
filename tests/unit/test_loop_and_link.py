"""The bilateral tick's seams: messages checked on creation, the lockstep link's order, the run's
status covering the slave, and the loop driven by stand-in sides."""

import types

import numpy as np
import pytest

from teleop.link import ContactFeedback, LockstepLink, MessageError, ToolCommand
from teleop.tick.loop import BilateralLoop
from teleop.tick.master_side import MasterSide
from teleop.tick.ports import Hook
from teleop.tick.verdict import SLAVE_FAULTS, run_status


def _cmd(seq, p=(0.0, 0.0, 0.0), R=None):
    return ToolCommand(seq, seq * 1e-3, p, np.eye(3) if R is None else R, np.zeros(3), np.zeros(3))


def test_tool_command_is_checked_and_frozen():
    c = _cmd(3, p=[1, 2, 3])
    assert c.p_m.tolist() == [1.0, 2.0, 3.0] and c.R.shape == (3, 3)
    with pytest.raises(ValueError):
        c.p_m[0] = 5.0  # read-only views
    with pytest.raises(MessageError, match="p_m: not finite"):
        _cmd(1, p=[np.nan, 0, 0])
    with pytest.raises(MessageError, match="R: not a rotation"):
        _cmd(1, R=np.zeros((3, 3)))
    with pytest.raises(MessageError, match="v_m_s: expected 3"):
        ToolCommand(1, 0.0, np.zeros(3), np.eye(3), np.zeros(2), np.zeros(3))
    with pytest.raises(MessageError, match="seq"):
        _cmd(-1)


def test_contact_feedback_is_checked():
    assert ContactFeedback(1, 0.0, np.ones(6), "ok", 0).wrench_P.sum() == 6.0
    with pytest.raises(MessageError, match="status"):
        ContactFeedback(1, 0.0, np.zeros(6), "fine")
    with pytest.raises(MessageError, match="not finite"):
        ContactFeedback(1, 0.0, [0, 0, np.inf, 0, 0, 0], "ok")


def test_lockstep_link_delivers_newest_in_order_and_drops_old():
    link = LockstepLink()
    assert link.receive_command(0.0) is None
    link.send_command(_cmd(2))
    link.send_command(_cmd(1))  # older than the pending one: dropped
    assert link.receive_command(0.0).seq == 2
    link.send_command(_cmd(2))  # a duplicate of what was delivered: dropped
    assert link.receive_command(0.0) is None
    link.send_command(_cmd(5))
    assert link.receive_command(0.0).seq == 5


def test_run_status_covers_both_sides():
    assert run_status("ok", 100, {"ok": 100}) == "ok"
    assert run_status("ok", 100, {"ok": 90, "saturated": 10}) == "ok"
    assert run_status("ok", 100, {"ok": 50, "infeasible_fallback": 50}) == "slave_infeasible_fallback"
    assert run_status("ok", 100, {"fixtures_relaxed": 1, "hold": 3}) == "slave_fixtures_relaxed"
    assert run_status("tracking_error", 100, {"infeasible_fallback": 3}) == "tracking_error"
    assert run_status("ok", 0, None) == "no_ticks"
    assert set(SLAVE_FAULTS) <= set(__import__("teleop.link", fromlist=["x"]).SLAVE_STATUSES)


class _Tool:
    """A point that integrates the wrench it is given (unit mass): enough to see the tick's order."""

    def __init__(self):
        self.p, self.v, self.t = np.zeros(3), np.zeros(3), 0.0
        self.acceleration_W = np.zeros(6)
        self.state = types.SimpleNamespace(q=np.zeros(6), qd=np.zeros(6))
        self.rank, self.recharts = 0, 0
        self.seen = []

    @property
    def qd(self):
        return self.state.qd

    def pose(self):
        return self.p.copy(), np.eye(3)

    def twist(self):
        return self.v.copy(), np.zeros(3)

    def step(self, h, F):
        self.seen.append(np.array(F))
        self.v = self.v + h * F[:3]
        self.p = self.p + h * self.v
        self.t += h
        self.state = types.SimpleNamespace(q=np.r_[self.p, 0, 0, 0], qd=np.r_[self.v, 0, 0, 0])
        return "ok"

    def hold(self):
        self.v = np.zeros(3)


class _Master:
    status = "ok"

    def __init__(self, tool):
        self.tool = tool

    def hand_state(self):
        return (*self.tool.pose(), *self.tool.twist())

    def set_clutch(self, engaged):
        pass

    def sense(self, F):
        return np.asarray(F, dtype=float)

    def command(self, p, R, nu, a):
        return "ok"


class _Operator:
    clutch_engaged, stop = True, False

    def wrench(self, t, p, R, v, w):
        return np.array([1.0, 0, 0, 0, 0, 0])


class _Slave:
    """A slave side that pushes back with -10 N along x whenever it follows a command; records the
    commands it received."""

    def __init__(self):
        self.got, self.tick_ns = [], 0

    def tick(self, i, t, link):
        cmd = link.receive_command(t)
        self.got.append(None if cmd is None else cmd.seq)
        link.send_feedback(ContactFeedback(len(self.got), t, [-10.0, 0, 0, 0, 0, 0], "ok",
                                           -1 if cmd is None else cmd.seq))


class _Feedback:
    refused = 0
    wall = None  # no model-mediated wall

    def update(self, msg, state=None):
        return np.zeros(6) if msg is None else np.asarray(msg.wrench_P)

    def render(self, wrench, tool, f_other, dt, state=None, gain=1.0):  # no contact damping to render
        return gain * wrench

    def reset(self):
        pass


def _loop(tool, slave, hooks=(), master=None):
    side = MasterSide(tool, master or _Master(tool), _Operator(), 1e-3, feedback=_Feedback())
    return BilateralLoop(side, slave, LockstepLink(), hooks)


def test_loop_feeds_the_slave_force_back_at_the_next_step_and_calls_hooks_in_order():
    calls = []

    class Rec(Hook):
        def before_tick(self, i, t, loop):
            calls.append(("before", i))

        def after_tick(self, i, t, loop):
            calls.append(("after", i))

    tool, slave = _Tool(), _Slave()
    loop = _loop(tool, slave, hooks=[Rec()])
    for i in range(3):
        assert loop.tick(i) == "ok"
    assert slave.got == [1, 2, 3]  # command i + 1 sent at tick i
    assert tool.seen[0][0] == 1.0                      # no feedback yet on the first step
    assert tool.seen[1][0] == pytest.approx(1.0 - 10.0)  # then the slave's force, one tick late
    assert calls == [("before", 0), ("after", 0), ("before", 1), ("after", 1), ("before", 2), ("after", 2)]
    assert loop.tick_ns > 0


def test_loop_sends_nothing_when_the_tool_is_not_finite():
    tool, slave = _Tool(), _Slave()
    tool.step = lambda h, F: setattr(tool, "p", np.array([np.nan, 0, 0])) or "ok"
    loop = _loop(tool, slave)
    assert loop.tick(0) == "ok"
    assert slave.got == [None] and loop.master_side.command_errors == 1
