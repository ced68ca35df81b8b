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
from teleop.slave.side import SlaveSide

DT = 1e-3
LIM = JointLimits(q_min=[-1.0, -2.0, 0.0], q_max=[1.0, 0.5, 3.0], v_max=[2.0, 1.0, 3.0], a_max=[10.0, 10.0, 10.0],
                  margin_rad=0.05)


def test_at_limit_by_hand():
    # joint 0: room above = 1 - 0.05 - q; one tick at 2 rad/s is 2 mrad
    assert not LIM.at_limit(np.array([0.9479, 0.0, 1.0]), DT)  # 2.1 mrad of room
    assert LIM.at_limit(np.array([0.9481, 0.0, 1.0]), DT)  # 1.9 mrad
    assert LIM.at_limit(np.array([0.0, -1.9495, 1.0]), DT)  # joint 1: 0.5 mrad above its floor, 1 mrad a tick
    assert LIM.at_limit(np.array([0.0, 0.0, 3.2]), DT)  # past the limit
    assert not LIM.at_limit(np.zeros(3) + [0.0, 0.0, 1.5], DT)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3))
def test_at_limit_is_the_kernels_position_cap_below_the_velocity_limit(u):
    """The kernel's bounds with qd_prev = 0 and a huge a_max (only the position and velocity caps
    left): a joint is at its limit exactly when a cap falls below v_max."""
    lo, hi = LIM.q_min - 0.01, LIM.q_max + 0.01
    q = lo + (np.asarray(u) + 1.0) / 2.0 * (hi - lo)
    free = replace(LIM, a_max=np.full(3, 1e12))
    lb, ub = free.compute_velocity_bounds(q, np.zeros(3), DT)
    capped = bool(np.any(ub < LIM.v_max * (1 - 1e-12)) or np.any(-lb < LIM.v_max * (1 - 1e-12)))
    assert LIM.at_limit(q, DT) == capped


def _side():
    cons = fixtures.scalpel(plane_origin=np.array([0.5, 0.0, 0.2]), depth=0.005).constraints
    arm = SlaveArm(SlaveConfig.from_dict({}, "slave"), cons, DT)
    R_cut = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    assert arm.reset((np.array([0.47, 0.0, 0.195]), R_cut)) == "ok"
    return SlaveSide(arm, Registration(np.zeros(3), np.eye(3)))


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
