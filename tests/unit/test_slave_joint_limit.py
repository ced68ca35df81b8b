"""A joint at its position limit: ``JointLimits.at_limit`` against the velocity-bound kernel it
reads (the tick's no-crossing cap tighter than the velocity limit), and the slave side reporting
``joint_limit`` when a joint ends a tick at its stop."""

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop.control.mapping import Registration
from teleop.dynamics import fixtures
from teleop.slave import JointLimits, SlaveArm, SlaveConfig
from teleop.tick.slave_side import SlaveSide

DT = 1e-3
LIM = JointLimits(q_min=[-1.0, -2.0, 0.0], q_max=[1.0, 0.5, 3.0], v_max=[2.0, 1.0, 3.0], a_max=[10.0, 10.0, 10.0],
                  margin_rad=0.05)


def test_at_limit_by_hand():
    # joint 0: room above = 1 - 0.05 - q; one tick at 2 rad/s is 2 mrad
    assert not LIM.at_limit(np.array([0.9479, 0.0, 1.0]), DT).any()  # 2.1 mrad of room
    assert LIM.at_limit(np.array([0.9481, 0.0, 1.0]), DT).tolist() == [True, False, False]  # 1.9 mrad
    # joint 1: 0.5 mrad above its floor, 1 mrad a tick
    assert LIM.at_limit(np.array([0.0, -1.9495, 1.0]), DT).tolist() == [False, True, False]
    assert LIM.at_limit(np.array([0.0, 0.0, 3.2]), DT)[2]  # past the limit
    assert not LIM.at_limit(np.zeros(3) + [0.0, 0.0, 1.5], DT).any()


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3))
def test_at_limit_is_the_kernels_position_cap_below_the_velocity_limit(u):
    """The kernel's bounds with qd_prev = 0 and a huge a_max (only the position and velocity caps
    left): a joint is at its limit exactly when a cap falls below v_max."""
    lo, hi = LIM.q_min - 0.01, LIM.q_max + 0.01
    q = lo + (np.asarray(u) + 1.0) / 2.0 * (hi - lo)
    free = replace(LIM, a_max=np.full(3, 1e12))
    lb, ub = free.compute_velocity_bounds(q, np.zeros(3), DT)
    capped = (ub < LIM.v_max * (1 - 1e-12)) | (-lb < LIM.v_max * (1 - 1e-12))
    np.testing.assert_array_equal(LIM.at_limit(q, DT), capped)


def _side():
    cons = fixtures.scalpel(plane_origin=np.array([0.5, 0.0, 0.2]), depth=0.005).constraints
    arm = SlaveArm(SlaveConfig.from_dict({}, "slave"), cons, DT)
    R_cut = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    assert arm.reset((np.array([0.47, 0.0, 0.195]), R_cut)) == "ok"
    side = SlaveSide(arm, Registration(np.zeros(3), np.eye(3)))
    side._resting[:] = False  # placed by the arm's reset, not the side's: no joint starts on a stop
    return side


def test_the_slave_says_joint_limit_when_a_joint_is_at_its_stop():
    side = _side()
    for k in range(3):
        assert side.follow(None, k * DT).status in ("ok", "saturated")
    arm, j = side.arm, 3
    q_min, q_max = arm.limits.q_min.copy(), arm.limits.q_max.copy()
    q_max[j] = arm.q[j] + 1e-3  # the stop 1 mrad above joint 3 (2.175 rad/s: 2.2 mrad a tick)
    arm.limits = replace(arm.limits, q_min=q_min, q_max=q_max)
    fb = side.follow(None, 3 * DT)
    assert fb.status == "joint_limit" and side.state.status == "joint_limit"
    arm.limits = replace(arm.limits, q_max=q_max + 0.5)  # the stop gone: back to the solver's word
    assert side.follow(None, 4 * DT).status in ("ok", "saturated")


def test_a_stop_that_costs_the_fixture_holds_the_joints_until_the_clutch_opens():
    from teleop.link import ToolCommand

    side = _side()
    side.follow(None, 0.0)
    arm, j = side.arm, 3
    q_max = arm.limits.q_max.copy()
    q_max[j] = arm.q[j] + 1e-3
    arm.limits = replace(arm.limits, q_max=q_max)
    step, calls = arm.step, []

    def relaxed(*a, **k):  # the follower gave up fixture rows for the stop
        calls.append(1)
        step(*a, **k)
        return "fixtures_relaxed"

    arm.step = relaxed
    assert side.follow(None, DT).status == "joint_limit" and len(calls) == 1
    for k in range(2, 5):  # held: no QP, zero joint velocity commanded, still reported
        assert side.follow(None, k * DT).status == "joint_limit"
        assert not np.any(arm.qd_cmd)
    assert len(calls) == 1
    p, R = arm.tool_pose()
    side.follow(ToolCommand(1, 5 * DT, p, R, np.zeros(3), np.zeros(3), False), 5 * DT)  # clutch open
    assert len(calls) == 2  # the follower runs again


def test_a_joint_the_start_pose_put_on_its_stop_is_reported_only_after_it_leaves_it():
    side = _side()
    arm = side.arm
    q_min = arm.limits.q_min.copy()
    q_min[1] = arm.q[1] - 1e-4  # joint 1 starts on its stop (as stiff_contact's IK leaves it)
    arm.limits = replace(arm.limits, q_min=q_min)
    side._resting = arm.limits.at_limit(arm.q, DT)
    assert side._resting.tolist() == [False, True] + [False] * 5
    assert side.follow(None, 0.0).status in ("ok", "saturated")
    side._resting[:] = False  # it left the stop: from then on the stop is reported
    assert side.follow(None, DT).status == "joint_limit"
