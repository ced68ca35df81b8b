"""The follower QP: its rows against finite differences, and its solution against other solvers."""

import numpy as np
import pinocchio as pin
import pytest
import qpsolvers

from teleop.dynamics import constraints as C
from teleop.dynamics import fixtures
from teleop.slave import SlaveArm, SlaveConfig, compute_target_twist, installed_solvers

PLANE_O = np.array([0.5, 0.0, 0.2])
R_CUT = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


def _arm(solver="osqp", cons=None):
    cons = fixtures.scalpel(plane_origin=PLANE_O, depth=0.005).constraints if cons is None else cons
    arm = SlaveArm(SlaveConfig.from_dict({"solver": solver}, "slave"), cons, 1e-3)
    assert arm.reset((PLANE_O + [-0.03, 0.0, -0.005], R_CUT)) == "ok"
    return arm


def test_target_twist_is_feedforward_plus_error():
    R_t = pin.exp3(np.array([0.0, 0.0, 0.1])) @ R_CUT
    nu, e = compute_target_twist(np.zeros(3), R_CUT, np.array([0.01, 0, 0]), R_t, np.ones(3), np.zeros(3), 10.0)
    assert np.allclose(e, [0.01, 0, 0, 0, 0, 0.1]) and np.allclose(nu, [1.1, 1, 1, 0, 0, 1.0])


def test_fixture_rows_match_finite_differences_through_the_arm():
    """d/dt h(pose(q)) along a joint velocity equals G J qd (rows of the holonomic fixtures)."""
    rcm = C.RemoteCenter(center=PLANE_O + [0, 0, 0.05], point_B=(0, 0, 0), axis_B=(0, 0, 1))
    cons = fixtures.scalpel(plane_origin=PLANE_O, depth=0.005).holonomic + (rcm,)
    arm = _arm(cons=cons)
    rng = np.random.default_rng(1)
    qd = rng.normal(size=arm.nv)
    G, _ = arm.qp.compute_fixture_rows(arm.p, arm.R, 0.0)
    h = 1e-6
    res = []
    for sgn in (1.0, -1.0):
        q = pin.integrate(arm.model, arm.q, sgn * h * qd)
        pin.framesForwardKinematics(arm.model, arm.data, q)
        M = arm.data.oMf[arm.frame_E]
        res.append(C.stack_residual(cons, M.translation, M.rotation))
    fd = (res[0] - res[1]) / (2 * h)
    assert np.allclose(G @ arm.J @ qd, fd, atol=1e-6)


@pytest.mark.parametrize("solver", ["osqp", "daqp", "proxqp", "quadprog"])
def test_solution_matches_independent_solver(solver):
    """Build the QP at a tick with an active joint bound, solve it with the persistent solver, and
    compare with qpsolvers' daqp and quadprog on the same matrices (1e-6)."""
    assert solver in installed_solvers()
    arm = _arm(solver)
    p, R = arm.tool_pose()
    lb, ub = arm.limits.compute_velocity_bounds(arm.q, arm.qd_cmd, arm.dt)
    qp = arm.qp
    args = (arm.q, arm.J, p, R, p + [0.002, 0.0, 0.0], R, np.array([0.01, 0, 0]), np.zeros(3), arm.q_post)
    qp.build(*args, lb, ub)
    qd, s, y, ok = qp.solve()
    j = int(np.argmax(np.abs(qd)))  # make this joint's bound active: half its free velocity
    lb[j], ub[j] = (0.5 * qd[j], ub[j]) if qd[j] < 0 else (lb[j], 0.5 * qd[j])
    bound = 0.5 * qd[j]
    qp.build(*args, lb, ub)
    qd, s, y, ok = qp.solve()
    assert ok
    for ref in ("daqp", "quadprog"):
        x = qpsolvers.solve_qp(qp.H, qp.g, A=qp.A, b=qp.b, lb=qp.lb, ub=qp.ub, solver=ref)
        assert np.allclose(np.concatenate([qd, s]), x, atol=1e-6, rtol=0), (ref, np.abs(x[: arm.nv] - qd).max())
    assert np.isclose(qd[j], bound, atol=1e-7)
    # duals: stationarity H x + g + A'y + (multipliers of the active bounds only) = 0
    r = qp.H @ np.concatenate([qd, s]) + qp.g + qp.A.T @ y
    active = np.isclose(qd, qp.lb[: arm.nv], atol=1e-7) | np.isclose(qd, qp.ub[: arm.nv], atol=1e-7)
    assert active[j] and not active.all()
    r[: arm.nv][active] = 0.0
    assert np.abs(r).max() < 1e-5


def test_step_tracks_and_reports_forces_from_the_rows():
    arm = _arm()
    p, R = arm.tool_pose()
    assert arm.step(p + [1e-4, 0, 0], R, np.array([0.01, 0, 0]), np.zeros(3)) in ("ok", "saturated")
    assert arm.fixture_forces.shape == (4,) and np.all(np.isfinite(arm.fixture_forces))
    # asking to leave the depth: the depth row pushes back (its multiplier is non-zero)
    arm.reset((p, R))
    for _ in range(50):
        arm.step(p + [0.0, 0.0, 0.002], R)
    assert abs(arm.fixture_forces[0]) > 1e-3
    assert abs(arm.fixture_residual()[0]) < 1e-6
    tau = arm.tau.copy()
    arm.step(p, R, F_tip_W=np.array([0, 0, 5.0, 0, 0, 0]))
    assert not np.allclose(tau, arm.tau)


def test_servo_lag_slows_the_response():
    cons = ()
    fast = SlaveArm(SlaveConfig.from_dict({}, "s"), cons, 1e-3)
    slow = SlaveArm(SlaveConfig.from_dict({"servo_lag_s": 0.05}, "s"), cons, 1e-3)
    p, R = fast.tool_pose()
    for _ in range(20):
        fast.step(p + [0.01, 0, 0], R)
        slow.step(p + [0.01, 0, 0], R)
    assert np.linalg.norm(slow.tool_pose()[0] - p) < np.linalg.norm(fast.tool_pose()[0] - p)
