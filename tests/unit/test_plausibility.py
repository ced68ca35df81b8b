"""Plausibility at each end (issue 22): a message no real peer sends is refused and counted, the
side holds in its safe state, and the run says why. Each is sent on an in-process link that
tampers with one message of a real run (the sides are those every run composes)."""

from dataclasses import replace

import numpy as np
import pytest

from teleop.app.assembly import build_master, build_slave
from teleop.app.session import Session
from teleop.link import LockstepLink
from teleop.scenario.schema import load_scene
from teleop.tick.loop import BilateralLoop
from teleop.tick.messages import ContactFeedback, ToolCommand

TAMPER_TICK = 300


class Tamper(LockstepLink):
    """A lockstep link that replaces the command or the reply of TAMPER_TICK with ``forge(msg)``."""

    def __init__(self, way: str, forge):
        super().__init__()
        self.way, self.forge, self.n = way, forge, {"command": 0, "feedback": 0}

    def send_command(self, msg: ToolCommand) -> None:
        self.n["command"] += 1
        super().send_command(self.forge(msg) if self.way == "command" and self.n["command"] == TAMPER_TICK else msg)

    def send_feedback(self, msg: ContactFeedback) -> None:
        self.n["feedback"] += 1
        super().send_feedback(self.forge(msg) if self.way == "feedback" and self.n["feedback"] == TAMPER_TICK else msg)


def _run(way, forge, seconds=0.6):
    scene = load_scene("straight_incision", sets=[f"duration_s={seconds}"])
    n = round(seconds / scene.dt_s)
    mb, sb = build_master(scene, n, np.random.default_rng(scene.seed)), build_slave(scene, n)
    loop = BilateralLoop(mb.side, sb.side, Tamper(way, forge))
    run = Session.of(loop, scene.duration_s, mb.recorder).run_ticks()
    return Session.result(run, {**mb.result(), **sb.result()}).summary, mb.side, sb.side


def _cmd(m: ToolCommand, **kw) -> ToolCommand:
    f = dict(seq=m.seq, t_s=m.t_s, p_m=m.p_m, R=m.R, v_m_s=m.v_m_s, w_rad_s=m.w_rad_s, clutch=m.clutch,
             energy_J=m.energy_J, wall_N=m.wall_N)
    f.update(kw)
    return ToolCommand(**f)


@pytest.mark.parametrize("forge, reason", [
    (lambda m: _cmd(m, p_m=m.p_m + [1000.0, 0, 0]), "out_of_reach"),
    (lambda m: _cmd(m, p_m=m.p_m + [0.3, 0, 0]), "jump_too_far"),  # 100 mm at the slave in one tick: 100 m/s
    (lambda m: _cmd(m, R=m.R @ np.array([[1.0, 0.5, 0], [0, 1, 0], [0, 0, 1]])), "not_a_rotation"),  # det 1
    (lambda m: _cmd(m, energy_J=np.full(6, 1e300)), "energy_too_fast"),
    (lambda m: _cmd(m, t_s=m.t_s - 0.1), "time_ran_backwards"),
    (lambda m: _cmd(m, wall_N=1e6), "wall_force_too_large"),  # a wall no slave could have reported
], ids=["1 km target", "jump", "sheared rotation", "energy 1e300", "time backwards", "wall 1 MN"])
def test_a_command_no_real_master_sends_is_refused_and_the_arm_holds(forge, reason):
    s, _, _slave = _run("command", forge)
    assert s["commands_refused"] == {reason: 1}
    assert s["status"] == "slave_implausible_command", s["status_reason"]
    assert s["slave_statuses"]["implausible_command"] >= 1
    assert s["metrics"]["tip_tracking_max_m"] < 1e-3  # the arm held where it was: no motion toward it


def test_a_reply_no_real_slave_sends_ends_the_run_with_the_tool_held():
    s, master, _ = _run("feedback", lambda m: replace(m, wrench_P=np.array([1e4, 0, 0, 0, 0, 0])))
    assert s["status"] == "implausible_feedback" and s["replies_refused"] == {"wrench_too_large": 1}
    assert s["steps"] == TAMPER_TICK + 1  # the master felt nothing of it and stopped the run
    assert not np.any(master.tool.qd) and not np.any(master.feedback_W)  # held, nothing fed on


def test_a_reply_whose_energy_jumps_is_refused_before_the_guard_sees_it():
    s, _, _ = _run("feedback", lambda m: replace(m, energy_J=np.full(6, 1e300)))
    assert s["status"] == "implausible_feedback" and s["replies_refused"] == {"energy_too_fast": 1}


def test_a_clean_run_refuses_nothing():
    s, _, _ = _run("none", lambda m: m)
    assert s["status"] == "ok" and s["commands_refused"] == {} and s["replies_refused"] == {}


@pytest.mark.parametrize("push", [1e300, np.inf, np.nan, 2e4], ids=["1e300", "inf", "nan", "past a hand"])
def test_a_push_no_hand_makes_is_not_applied_and_the_run_says_so(push, recwarn):
    from teleop.api import IdealMaster, ReferenceTool, RigidBody
    from teleop.dynamics import fixtures

    tool = ReferenceTool(RigidBody(0.25, [0.0025] * 3), fixtures.free(), [], integrator="parametric")
    tool.reset()

    class Hand:
        clutch_engaged = True

        def wrench(self, t, p, R, v, w):
            return np.array([push if t > 0.1 else 1.0, 0, 0, 0, 0, 0])

    s = Session(tool, IdealMaster(tool, 1e-3), Hand(), 1e-3, 0.3).run().summary
    assert s["status"] == "push_refused" and s["pushes_refused"] == 199 and not s["nan"]
    assert np.all(np.isfinite(tool.q)) and not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
