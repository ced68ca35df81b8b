"""The slave's compiled follower (teleop.slave.kernels) against independent oracles: the QP's own
definition (its objective and rows written as sums of squares from Pinocchio and the constraint
classes), daqp and quadprog on the built problem, and the KKT conditions checked directly."""

import numpy as np
import pinocchio as pin
import pytest
import qpsolvers
from hypothesis import example, given, settings
from hypothesis import strategies as st

from teleop.dynamics import constraints as C
from teleop.dynamics import fixtures
from teleop.slave import SlaveArm, SlaveConfig, compute_target_twist

PLANE_O = np.array([0.5, 0.0, 0.2])
R_CUT = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
STACKS = {
    "none": (),
    "scalpel": fixtures.scalpel(plane_origin=PLANE_O, depth=0.005).constraints,
    "laparoscopic": fixtures.laparoscopic(plane_origin=PLANE_O, trocar=PLANE_O + [0, 0, 0.075]).constraints,
    "sphere": fixtures.sphere(PLANE_O, 0.05).constraints,
}
_ARMS = {}


def _arm(stack):
    """An arm (daqp) with the fixtures of ``stack``, built once per stack."""
    if stack not in _ARMS:
        _ARMS[stack] = SlaveArm(SlaveConfig.from_dict({"solver": "daqp"}, "slave"), STACKS[stack], 1e-3)
    return _ARMS[stack]


def _state(arm, rng):
    q = rng.uniform(arm.limits.q_min, arm.limits.q_max)
    pin.forwardKinematics(arm.model, arm.data, q)
    J = pin.computeFrameJacobian(arm.model, arm.data, q, arm.frame_E, pin.LOCAL_WORLD_ALIGNED)
    T = pin.updateFramePlacement(arm.model, arm.data, arm.frame_E).homogeneous
    return q, J, T


def _objective(arm, q, J, T, target, x):
    """The follower's objective at x = (qd, s), written as in teleop.slave.follower's docstring."""
    cfg, nv = arm.cfg, arm.nv
    qd, s = x[:nv], x[nv:]
    nu, e = compute_target_twist(T[:3, 3], T[:3, :3], *target, cfg.k_task_1ps)
    W = np.array([cfg.weight_position] * 3 + [cfg.weight_orientation] * 3)
    lam = cfg.damping + cfg.lm_damping * (W @ e**2)
    r = J @ qd - nu
    post = qd - cfg.k_posture_1ps * (arm.q_post - q)
    return 0.5 * (r @ (W * r) + lam * qd @ qd + cfg.weight_posture * post @ post + cfg.slack_weight * s @ s)


@settings(max_examples=60, deadline=None)
@given(stack=st.sampled_from(sorted(STACKS)), seed=st.integers(0, 2**32 - 1),
       angle=st.sampled_from([1e-9, 1e-3, 0.5, 3.0, np.pi - 1e-6]), bound=st.floats(0.01, 3.0))
@example(stack="scalpel", seed=1141, angle=1e-3, bound=0.25)  # fixtures against the bounds: relaxed
def test_the_follower_solves_the_qp_it_is_defined_by(stack, seed, angle, bound):
    """At random states, targets up to a half-turn away and bounds that bind or not:

    * the built problem is the QP of the follower's definition: its objective equals the sum of
      squares up to a constant (at random points), its rows are G J qd + s = -k h with G, h the
      constraint classes' own and J Pinocchio's;
    * its solution (the compiled unbounded solve, or the QP solver when a bound binds) is the
      solution daqp and quadprog find (feasible, the same objective), and meets the KKT conditions.
    """
    rng = np.random.default_rng(seed)
    arm = _arm(stack)
    qp, nv, m = arm.qp, arm.nv, arm.qp.m
    q, J, T = _state(arm, rng)
    axis = rng.normal(size=3)
    R_t = pin.exp3(angle * axis / np.linalg.norm(axis)) @ T[:3, :3]
    target = (T[:3, 3] + rng.normal(size=3) * 0.01, R_t, rng.normal(size=3) * 0.01, rng.normal(size=3) * 0.1)
    lb, ub = -bound * np.ones(nv), bound * np.ones(nv)
    e = qp.build(q, J, T, *target, arm.q_post, lb, ub)
    assert np.allclose(e, compute_target_twist(T[:3, 3], T[:3, :3], *target, 0.0)[1], atol=1e-12, rtol=0)
    assert np.isclose(qp.position_error_m, np.linalg.norm(target[0] - T[:3, 3]), rtol=1e-12, atol=1e-15)
    qd, s, y, ok = qp.solve()
    H, g, A, b, lbx, ubx = (a.copy() for a in qp.problem())
    # the problem, from the definition
    f0 = _objective(arm, q, J, T, target, np.zeros(nv + m))
    for _ in range(3):
        x = rng.normal(size=nv + m)
        f = _objective(arm, q, J, T, target, x) - f0
        assert abs(0.5 * x @ H @ x + g @ x - f) <= 1e-9 * (1.0 + abs(f) + abs(f0))
    cons = STACKS[stack]
    if m:
        p, R = T[:3, 3], T[:3, :3]
        h = np.concatenate([c.residual(p, R) if c.holonomic else np.zeros(c.rows) for c in cons])
        assert np.allclose(A, np.hstack([C.stack_jacobian(cons, p, R) @ J, np.eye(m)]), atol=1e-12, rtol=0)
        assert np.allclose(b, -arm.cfg.k_fixture_1ps * h, atol=1e-9, rtol=0)
    assert np.array_equal(lbx[:nv], lb) and np.array_equal(ubx[:nv], ub)
    # the solution: feasible, optimal as daqp and quadprog find it, and a KKT point
    assert ok
    x = np.concatenate([qd, s])
    assert np.all(qd >= lb - 1e-9) and np.all(qd <= ub + 1e-9)
    assert np.abs(A @ x - b).max(initial=0.0) <= 1e-6 * (1.0 + np.abs(b).max(initial=0.0))
    if qp.used_fixtures_first:  # relaxed against the bounds: the fixture-first stages' problems
        _check_fixtures_first(qp, nv, m, H, g, A, b, lbx, ubx, qd, s, y)
        return
    fx = 0.5 * x @ H @ x + g @ x
    for ref in ("daqp", "quadprog"):
        xr = qpsolvers.solve_qp(H, g, A=A if m else None, b=b if m else None, lb=lbx, ub=ubx, solver=ref)
        if xr is None and ref == "daqp" and qp.used_solver:
            continue  # qpsolvers' daqp (default settings) gives up on some relaxed, ill-conditioned cases
        fr = 0.5 * xr @ H @ xr + g @ xr
        # the slack weight (1e6) leaves the minimiser determined to ~1e-6 when fixtures fight the
        # bounds: compare the objective there, the point elsewhere
        assert abs(fx - fr) <= 1e-9 * (1.0 + abs(fr)), (ref, fx, fr)
        if not qp.used_solver:
            assert np.allclose(x, xr, atol=1e-6, rtol=0), ref
    if not qp.used_solver:  # the unbounded solve: stationarity to rounding, no bound active
        assert qp.bound_margin >= 0.0
        assert np.abs(H @ x + g + A.T @ y).max() <= 1e-8 * (1.0 + np.abs(g).max() + np.abs(H).max() * np.abs(x).max())
        assert np.allclose(s, -y / arm.cfg.slack_weight, atol=1e-15, rtol=1e-12)
    else:  # the bounds' multipliers mu = H x + g + A'y: zero off the bounds, >= 0 on lb, <= 0 on ub
        mu = H @ x + g + A.T @ y
        scale = 1e-5 * (1.0 + np.abs(g).max() + np.abs(H @ x).max())
        assert np.abs(mu[nv:]).max(initial=0.0) <= scale  # the slack has no bounds
        at_lb, at_ub = np.isclose(qd, lb, atol=1e-7), np.isclose(qd, ub, atol=1e-7)
        free = ~(at_lb | at_ub)
        assert np.abs(mu[:nv][free]).max(initial=0.0) <= scale
        assert np.all(mu[:nv][at_lb & ~at_ub] >= -scale) and np.all(mu[:nv][at_ub & ~at_lb] <= scale)


def _check_fixtures_first(qp, nv, m, H, g, A, b, lbx, ubx, qd, s, y):
    """The lexicographic answer when the bounds force the rows to relax (teleop.slave.follower,
    "Fixtures first"), against quadprog: (1) the slack is the least violation |A_q qd - b| any qd
    in the box admits; (2) among the qd that hold the rows to that slack, qd tracks best (the QP's
    objective, the slack pinned, meets its KKT conditions)."""
    H1 = np.zeros_like(H)
    H1[:nv, :nv] = 1e-9 * np.eye(nv)
    H1[nv:, nv:] = np.eye(m)
    x1 = qpsolvers.solve_qp(H1, np.zeros(nv + m), A=A, b=b, lb=lbx, ub=ubx, solver="quadprog")
    least = np.linalg.norm(x1[nv:])
    assert np.linalg.norm(s) <= least * (1.0 + 1e-6) + 1e-9, (np.linalg.norm(s), least)
    assert np.linalg.norm(s) < qp.cfg.relaxed_tol_mps or least > 0.0
    # the slack pinned, a convex QP in qd alone: A_q qd = b - s within the box, optimal by its
    # KKT conditions with the follower's multipliers y (when the rows are infeasible the pinned set
    # is a face of the box, too thin for quadprog to solve as a problem of its own)
    Hq, gq, Aq = H[:nv, :nv], g[:nv], A[:, :nv]
    assert np.abs(Aq @ qd + s - b).max() <= 1e-9 * (1.0 + np.abs(b).max())
    mu = Hq @ qd + gq + Aq.T @ y
    scale = 1e-5 * (1.0 + np.abs(gq).max() + np.abs(Hq @ qd).max())
    at_lb, at_ub = np.isclose(qd, lbx[:nv], atol=1e-7), np.isclose(qd, ubx[:nv], atol=1e-7)
    assert np.abs(mu[~(at_lb | at_ub)]).max(initial=0.0) <= scale
    assert np.all(mu[at_lb & ~at_ub] >= -scale) and np.all(mu[at_ub & ~at_lb] <= scale)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_target_that_is_not_finite_is_refused_by_both(bad):
    arm = _arm("scalpel")
    q, J, T = _state(arm, np.random.default_rng(0))
    lb, ub = -np.ones(arm.nv), np.ones(arm.nv)
    for k in range(3 + 9 + 3 + 3):  # each entry of the target: p, R, v, w
        target = [T[:3, 3].copy(), T[:3, :3].copy(), np.zeros(3), np.zeros(3)]
        flat = [a.reshape(-1) for a in target]
        sizes = np.cumsum([0, 3, 9, 3, 3])
        i = int(np.searchsorted(sizes, k, side="right") - 1)
        flat[i][k - sizes[i]] = bad
        assert arm.qp.build(q, J, T, *target, arm.q_post, lb, ub) is None, k


def test_plain_lists_and_transposed_views_are_converted_at_the_boundary():
    """Lists and non-contiguous rotations become C-ordered float arrays before the kernel (which
    indexes them unchecked); the tick runs compiled, with the same result as arrays."""
    fast = _arm("scalpel")
    out = []
    for convert in (np.array, list):
        fast.reset((PLANE_O + [-0.03, 0.0, -0.005], R_CUT))
        R = np.asfortranarray(R_CUT) if convert is np.array else R_CUT.tolist()
        status = fast.step(convert(PLANE_O + [-0.0299, 0.0, -0.005]), R, convert([0.01, 0.0, 0.0]), [0.0] * 3)
        out.append((status, fast.q.copy()))
    assert out[0][0] == out[1][0] and out[0][0] in ("ok", "saturated") and np.array_equal(out[0][1], out[1][1])


@pytest.mark.parametrize("bad", [dict(p=[0.5, 0.0]), dict(R=np.eye(2)), dict(v="fast"), dict(w=[[0.0] * 3])])
def test_a_misshapen_target_is_refused_without_raising(bad):
    fast = _arm("scalpel")
    fast.reset((PLANE_O + [-0.03, 0.0, -0.005], R_CUT))
    args = dict(p=PLANE_O + [-0.03, 0.0, -0.005], R=R_CUT, v=np.zeros(3), w=np.zeros(3)) | bad
    assert fast.step(args["p"], args["R"], args["v"], args["w"]) == "invalid_target"
    assert np.all(np.isfinite(fast.q)) and np.all(fast.qd_cmd == 0.0)


def test_every_tick_of_an_incision_start_is_the_qps_solution():
    """300 ticks of an incision start (OSQP, the shortcut on; joint bounds bind on some ticks): each
    tick's commanded joint velocity is quadprog's solution of that tick's QP (1e-6 rad/s)."""
    arm = SlaveArm(SlaveConfig.from_dict({"solver": "osqp"}, "slave"), STACKS["scalpel"], 1e-3)
    arm.reset((PLANE_O + [-0.03, 0.0, -0.005], R_CUT))
    used = []
    for k in range(1, 301):
        arm.step(PLANE_O + [-0.03 + 1e-5 * k, 0.0, -0.005], R_CUT, np.array([0.01, 0, 0]), np.zeros(3))
        H, g, A, b, lb, ub = arm.qp.problem()
        x = qpsolvers.solve_qp(H, g, A=A, b=b, lb=lb, ub=ub, solver="quadprog")
        assert np.abs(arm.qd_cmd - x[: arm.nv]).max() < 1e-6, k
        used.append(arm.qp.used_solver)
    assert any(used) and not all(used)


@pytest.mark.parametrize("scene", ["straight_incision", "curved_incision", "laparoscopic_incision"])
def test_target_projection_lands_on_the_fixture(scene):
    """The compiled projection onto the patient-frame fixture, checked by the constraint classes'
    own residual and Jacobian: the pose is on the fixture (|h| <= 1e-10), the twist is admissible
    (|G nu| <= 1e-10), and for targets off by up to 5 mm / 0.05 rad the move is small."""
    from teleop.app.runtime import make_slave
    from teleop.dynamics.constraints import stack_jacobian, stack_residual
    from teleop.scenario.build import build_fixture, build_registration
    from teleop.scenario.schema import load_scene

    sc = load_scene(scene)
    cons = build_fixture(sc.fixture).constraints
    side = make_slave(sc, build_registration(sc), cons)
    hol = [c for c in cons if c.holonomic]
    rng = np.random.default_rng(7)
    p0, R0, _, _ = side.reg.target(np.zeros(3), np.eye(3), np.zeros(3), np.zeros(3))
    p0, R0, _, _ = side.project(p0, R0, np.zeros(3), np.zeros(3))
    for _ in range(50):
        p = p0 + rng.normal(size=3) * 0.005
        R = pin.exp3(rng.normal(size=3) * 0.05) @ R0
        v, w = rng.normal(size=3) * 0.01, rng.normal(size=3) * 0.1
        pp, RR, vv, ww = side.project(p, R, v, w)
        assert np.abs(stack_residual(hol, pp, RR)).max() <= 1e-10
        assert np.abs(stack_jacobian(cons, pp, RR) @ np.concatenate([vv, ww])).max() <= 1e-10
        assert np.linalg.norm(pp - p) < 0.05


def test_a_solve_osqp_leaves_unfinished_is_finished_exactly_by_daqp():
    """OSQP capped at 2 iterations cannot finish the ticks where a joint bound binds; the same
    problem then goes to DAQP, and the tick's joint velocity is still quadprog's solution of the
    QP (1e-6 rad/s): no fallback, and the retries are counted."""
    cfg = SlaveConfig.from_dict({"solver": "osqp", "max_iter": 2}, "slave")
    arm = SlaveArm(cfg, STACKS["scalpel"], 1e-3)
    arm.reset((PLANE_O + [-0.03, 0.0, -0.005], R_CUT))
    statuses = []
    for k in range(1, 301):
        statuses.append(arm.step(PLANE_O + [-0.03 + 1e-5 * k, 0.0, -0.005], R_CUT, np.array([0.01, 0, 0]), np.zeros(3)))
        if arm.qp.used_solver:
            H, g, A, b, lb, ub = arm.qp.problem()
            x = qpsolvers.solve_qp(H, g, A=A, b=b, lb=lb, ub=ub, solver="quadprog")
            assert np.abs(arm.qd_cmd - x[: arm.nv]).max() < 1e-6, k
    assert arm.qp.retries > 0 and "infeasible_fallback" not in statuses
