"""The follower QP: its rows against finite differences, and its solution against other solvers."""

import numpy as np
import pinocchio as pin
import pytest
import qpsolvers

from teleop.dynamics import constraints as C
from teleop.dynamics import fixtures
from teleop.slave import SlaveArm, SlaveConfig, compute_target_twist, installed_solvers
from tests.user_rows import SineRow

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
    """d/dt h(pose(q)) along a joint velocity, by central differences of Pinocchio's placement of E,
    equals the QP's row block A[:, :nv] qd = G J qd (rows of the holonomic fixtures)."""
    rcm = C.RemoteCenter(center=PLANE_O + [0, 0, 0.05], point_B=(0, 0, 0), axis_B=(0, 0, 1))
    cons = (*fixtures.scalpel(plane_origin=PLANE_O, depth=0.005).holonomic, rcm)
    arm = _arm(cons=cons)
    rng = np.random.default_rng(1)
    qd = rng.normal(size=arm.nv)
    lb, ub = -arm.limits.v_max, arm.limits.v_max
    arm.qp.build(arm.q, arm.J, arm.T_WE, arm.p, arm.R, np.zeros(3), np.zeros(3), arm.q_post, lb, ub)
    A = arm.qp.problem()[2][:, : arm.nv]
    h = 1e-6
    res = []
    for sgn in (1.0, -1.0):
        q = pin.integrate(arm.model, arm.q, sgn * h * qd)
        pin.framesForwardKinematics(arm.model, arm.data, q)
        M = arm.data.oMf[arm.frame_E]
        res.append(C.stack_residual(cons, M.translation, M.rotation))
    fd = (res[0] - res[1]) / (2 * h)
    assert np.allclose(A @ qd, fd, atol=1e-6)


@pytest.mark.parametrize("solver", ["osqp", "daqp", "proxqp", "quadprog"])
def test_solution_matches_independent_solver(solver):
    """Build the QP at a tick with an active joint bound, solve it with the persistent solver, and
    compare with qpsolvers' daqp and quadprog on the same matrices (1e-6)."""
    assert solver in installed_solvers()
    arm = _arm(solver)
    p, R = arm.tool_pose()
    lb, ub = arm.limits.compute_velocity_bounds(arm.q, arm.qd_cmd, arm.dt)
    qp = arm.qp
    args = (arm.q, arm.J, arm.T_WE, p + [0.002, 0.0, 0.0], R, np.array([0.01, 0, 0]), np.zeros(3), arm.q_post)
    qp.build(*args, lb, ub)
    qd, s, y, ok = qp.solve()
    j = int(np.argmax(np.abs(qd)))  # make this joint's bound active: half its free velocity
    lb[j], ub[j] = (0.5 * qd[j], ub[j]) if qd[j] < 0 else (lb[j], 0.5 * qd[j])
    bound = 0.5 * qd[j]
    qp.build(*args, lb, ub)
    qd, s, y, ok = qp.solve()
    assert ok and qp.used_solver  # a bound binds: the QP solver ran
    H, g, A, b, lb, ub = (a.copy() for a in qp.problem())
    for ref in ("daqp", "quadprog"):
        x = qpsolvers.solve_qp(H, g, A=A, b=b, lb=lb, ub=ub, solver=ref)
        assert np.allclose(np.concatenate([qd, s]), x, atol=1e-6, rtol=0), (ref, np.abs(x[: arm.nv] - qd).max())
    assert np.isclose(qd[j], bound, atol=1e-7)
    # duals: stationarity H x + g + A'y + (multipliers of the active bounds only) = 0
    r = H @ np.concatenate([qd, s]) + g + A.T @ y
    active = np.isclose(qd, lb[: arm.nv], atol=1e-7) | np.isclose(qd, ub[: arm.nv], atol=1e-7)
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


def test_a_users_own_constraint_enters_the_qp_and_holds():
    """The QP's rows and right-hand side are every constraint's own G J and -k_fixture h (a user's
    constraint next to built-in ones), and the arm, pulled off the user's row, stays on it while it
    follows the rest of the target."""
    start = PLANE_O + [-0.03, 0.0, -0.005]
    cons = (*fixtures.scalpel(plane_origin=PLANE_O, depth=0.005).holonomic, SineRow(start[0]))
    arm = _arm("daqp", cons=cons)
    qp = arm.qp
    lb, ub = -arm.limits.v_max, arm.limits.v_max
    p, R = arm.tool_pose()
    p_off = p + [1e-3, 1e-3, 2e-4]  # off the user's row and the depth row
    for at in (p, p_off):  # h = 0 and h != 0: the rows at the arm's pose, as the constraints give them
        arm.reset((at, R))
        qp.build(arm.q, arm.J, arm.T_WE, p, R, np.zeros(3), np.zeros(3), arm.q_post, lb, ub)
        _, _, A, b, _, _ = qp.problem()
        G = C.stack_jacobian(cons, arm.p, arm.R)
        h = C.stack_residual(cons, arm.p, arm.R)
        assert np.allclose(A[:, : arm.nv], G @ arm.J, atol=1e-12, rtol=0)
        assert np.allclose(b, -arm.cfg.k_fixture_1ps * h, atol=1e-12, rtol=0)
    arm.reset((p, R))
    for _ in range(300):  # pulled along +x and +y: the user's row holds x, the arm follows y
        arm.step(p + [0.002, 0.002, 0.0], R)
    assert abs(arm.fixture_residual()[-1]) < 1e-6 and abs(arm.p[0] - p[0]) < 1e-6
    assert abs(arm.p[1] - p[1] - 0.002) < 1e-4


def test_kkt_shortcut_is_the_qp_solution_when_no_bound_binds():
    """Wide bounds: the follower solves the linear system, not the QP solver, and the result is
    the QP's solution (independent solvers, 1e-6) with stationary duals."""
    arm = _arm("osqp")
    p, R = arm.tool_pose()
    qp = arm.qp
    lb, ub = -arm.limits.v_max, arm.limits.v_max
    v_t = np.array([0.01, 0.0, 0.0])
    qp.build(arm.q, arm.J, arm.T_WE, p + [2e-5, 1e-5, 0.0], R, v_t, np.zeros(3), arm.q_post, lb, ub)
    qd, s, y, ok = qp.solve()
    assert ok and not qp.used_solver and qp.bound_margin > 0.0
    H, g, A, b, lb_, ub_ = (a.copy() for a in qp.problem())
    x = np.concatenate([qd, s])
    for ref in ("daqp", "quadprog"):
        x_ref = qpsolvers.solve_qp(H, g, A=A, b=b, lb=lb_, ub=ub_, solver=ref)
        assert np.allclose(x, x_ref, atol=1e-6, rtol=0)
    r = qp.solver.solve(H, g, A, b, lb_, ub_)  # the persistent solver itself
    assert r.ok and np.allclose(x, r.x, atol=1e-6, rtol=0)
    assert np.allclose(y, r.y_eq, atol=1e-4 * (1 + np.abs(y).max()))
    assert np.abs(H @ x + g + A.T @ y).max() < 1e-8 and np.abs(A @ x - b).max() < 1e-12


@pytest.mark.parametrize("solver", ["osqp", "daqp"])
def test_shortcut_and_solver_follow_the_same_path(solver):
    """An incision start (bounds active for some ticks, then free): with and without the
    shortcut the arm takes the same steps and reports the same statuses."""
    runs = []
    for shortcut in (True, False):
        cons = fixtures.scalpel(plane_origin=PLANE_O, depth=0.005).constraints
        cfg = SlaveConfig.from_dict({"solver": solver, "kkt_shortcut": shortcut}, "slave")
        arm = SlaveArm(cfg, cons, 1e-3)
        arm.reset((PLANE_O + [-0.03, 0.0, -0.005], R_CUT))
        qs, statuses, used = [], [], []
        for k in range(1, 301):
            p_t = PLANE_O + [-0.03 + 1e-5 * k, 0.0, -0.005]
            statuses.append(arm.step(p_t, R_CUT, np.array([0.01, 0, 0]), np.zeros(3)))
            qs.append(arm.q.copy())
            used.append(arm.qp.used_solver)
        runs.append((np.array(qs), statuses, used))
    (q1, st1, used1), (q2, st2, used2) = runs
    assert any(used1) and not all(used1) and all(used2)
    assert st1 == st2 and "saturated" in st1 and "ok" in st1
    assert np.abs(q1 - q2).max() < 1e-9
