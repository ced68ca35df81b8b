"""Hard cases for the slave: unreachable targets, singularities, joint limits, conflicting fixtures,
solver failure. Never NaN, joint velocities within limits, a reported status."""

import numpy as np
import pytest

from teleop.dynamics import constraints as C
from teleop.dynamics import fixtures
from teleop.slave import STATUSES, SlaveArm, SlaveConfig

R_CUT = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


def _run(arm, p_t, R_t, n=300):
    statuses = []
    for _ in range(n):
        statuses.append(arm.step(p_t, R_t))
        assert np.all(np.isfinite(arm.q)) and np.all(np.isfinite(arm.qd)) and np.all(np.isfinite(arm.tau))
        assert np.all(np.abs(arm.qd) <= arm.limits.v_max + 1e-9)
        assert np.all(arm.q >= arm.limits.q_min - 1e-9) and np.all(arm.q <= arm.limits.q_max + 1e-9)
        assert statuses[-1] in STATUSES
    return statuses


@pytest.mark.parametrize("arm_name", ["panda", "ur5"])
def test_target_outside_the_workspace(arm_name):
    arm = SlaveArm(SlaveConfig.from_dict({"arm": arm_name}, "slave"), (), 1e-3)
    st = _run(arm, np.array([3.0, 0.0, 0.2]), R_CUT, n=1500)
    assert st[-1] in ("tracking_error", "saturated")
    assert np.linalg.norm(arm.qd) < 10.0


def test_at_a_singularity():
    """UR5 with the elbow straight and wrist 1 and 3 aligned: J (6x6) loses rank twice."""
    q = [0.0, -1.571, 0.0, -1.571, 0.0, 0.0]
    arm = SlaveArm(SlaveConfig.from_dict({"arm": "ur5", "q0": q}, "slave"), (), 1e-3)
    s = np.linalg.svd(arm.J, compute_uv=False)
    assert s[-1] < 1e-10
    p, R = arm.tool_pose()
    R_t = np.array([[1.0, 0, 0], [0, np.cos(0.3), -np.sin(0.3)], [0, np.sin(0.3), np.cos(0.3)]]) @ R
    st = _run(arm, p + np.array([0.0, 0.0, 0.05]), R_t, n=300)  # up along the stretched arm, twisted
    assert "infeasible_fallback" not in st
    assert np.linalg.norm(arm.qd) < 10.0


def test_joints_at_their_limits():
    am = SlaveArm(SlaveConfig.from_dict({}, "slave"), (), 1e-3)
    q = am.limits.q_max.copy()  # every joint on its upper limit
    arm = SlaveArm(SlaveConfig.from_dict({"q0": q.tolist()}, "slave"), (), 1e-3)
    p, R = arm.tool_pose()
    st = _run(arm, p + np.array([0.005, 0.005, -0.005]), R, n=300)
    assert "saturated" in st
    far = SlaveArm(SlaveConfig.from_dict({"q0": q.tolist()}, "slave"), (), 1e-3)
    assert set(_run(far, p + np.array([0.2, 0.2, 0.2]), R_CUT, n=300)) <= {"saturated", "tracking_error"}


def test_fixtures_conflicting_with_joint_limits_are_relaxed_not_failed():
    """A depth plane far below reach: the fixture cannot hold, the slack absorbs it."""
    fx = fixtures.scalpel(plane_origin=(0.5, 0.0, -0.8), depth=0.005)
    arm = SlaveArm(SlaveConfig.from_dict({}, "slave"), fx.constraints, 1e-3)
    p, R = arm.tool_pose()
    st = _run(arm, p, R, n=400)
    assert "fixtures_relaxed" in st and np.all(np.isfinite(arm.fixture_forces))


def test_contradictory_fixtures_are_relaxed():
    a = C.PlaneHeight(origin=(0, 0, 0.3), normal=(0, 0, 1), height=0.0, name="a")
    b = C.PlaneHeight(origin=(0, 0, 0.35), normal=(0, 0, 1), height=0.0, name="b")
    arm = SlaveArm(SlaveConfig.from_dict({"solver": "daqp"}, "slave"), (a, b), 1e-3)
    p, R = arm.tool_pose()
    st = _run(arm, p, R, n=100)
    assert st[-1] == "fixtures_relaxed"


@pytest.mark.parametrize("fallback", ["dls", "hold"])
def test_solver_failure_falls_back(fallback):
    """One OSQP iteration cannot meet 1e-7 and the exact retry fails too (here: the same capped
    OSQP in its place): the follower falls back and says so."""
    arm = SlaveArm(SlaveConfig.from_dict({"max_iter": 1, "fallback": fallback}, "slave"), (), 1e-3)
    arm.qp.exact = arm.qp.solver
    p, R = arm.tool_pose()
    st = _run(arm, p + np.array([0.01, 0.0, 0.0]), R, n=50)
    assert "infeasible_fallback" in st
    if fallback == "hold":
        assert np.allclose(arm.qd, 0.0)
    else:
        assert np.linalg.norm(arm.tool_pose()[0] - p) > 1e-4


def test_nan_target_never_reaches_the_joints():
    arm = SlaveArm(SlaveConfig.from_dict({"solver": "quadprog"}, "slave"), (), 1e-3)
    p, R = arm.tool_pose()
    st = _run(arm, p * np.nan, R, n=5)
    assert set(st) == {"invalid_target"} and np.allclose(arm.qd, 0.0)
