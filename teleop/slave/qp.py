"""The QP follower: every tick, joint velocities that track a tool target under limits and fixtures.

Decision variables x = (qd, s): joint velocities qd (rad/s, nv) and one slack s per fixture row
(row units per second: m/s or rad/s). With J the tool frame's LOCAL_WORLD_ALIGNED Jacobian (6, nv)
and the target twist nu* = (v_t + k e_p, w_t + k e_R) (feedforward plus proportional pose error,
e_R = log(R_t R'), world frame):

    minimize   1/2 |J qd - nu*|^2_W + 1/2 lam |qd|^2 + 1/2 w_post |qd - k_post (q_post - q)|^2
               + 1/2 rho |s|^2
    subject to G J qd + s = -k_h h(p, R)   (holonomic fixture rows; nonholonomic rows: = 0)
               lb <= qd <= ub               (joint position, velocity and acceleration limits)

lam = damping + lm_damping * |e|^2_W is a Levenberg-Marquardt damping that grows with the pose
error, so an unreachable target or a singular pose cannot ask for wild joint velocities. The slack
(weight rho >> 1) keeps the problem feasible when fixtures conflict with the joint limits; its size
is reported as the status "fixtures_relaxed". The rows' multipliers, times an impedance (N s/m),
are the fixture forces (N or N*m).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from teleop.slave.solvers import make_solver

STATUSES = ("ok", "saturated", "tracking_error", "fixtures_relaxed", "infeasible_fallback", "invalid_target")


def compute_target_twist(p, R, p_t, R_t, v_t, w_t, k: float) -> tuple[np.ndarray, np.ndarray]:
    """(nu*, e): target twist (6,) (m/s, rad/s) and pose error e = (p_t - p, log(R_t R')) (m, rad)."""
    e = np.empty(6)
    e[:3] = p_t - p
    e[3:] = pin.log3(R_t @ R.T)
    nu = np.empty(6)
    nu[:3] = v_t
    nu[3:] = w_t
    nu += k * e
    return nu, e


class FollowerQP:
    """Workspace and solver of the follower for one arm and one fixed set of fixture constraints."""

    def __init__(self, nv: int, constraints, cfg, dt: float):
        self.nv = nv
        self.constraints = tuple(constraints)
        self.m = sum(c.rows for c in self.constraints)
        self.n = nv + self.m
        self.cfg, self.dt = cfg, float(dt)
        self.W = np.array([cfg.weight_position] * 3 + [cfg.weight_orientation] * 3)
        self._slices = []
        i = 0
        for c in self.constraints:
            self._slices.append((c, slice(i, i + c.rows)))
            i += c.rows
        self.H = np.zeros((self.n, self.n))
        self.g = np.zeros(self.n)
        self.A = np.zeros((self.m, self.n))
        self.A[:, nv:] = np.eye(self.m)
        self.b = np.zeros(self.m)
        self.G = np.zeros((self.m, 6))
        self.lb = np.full(self.n, -np.inf)
        self.ub = np.full(self.n, np.inf)
        self.H[nv:, nv:] = cfg.slack_weight * np.eye(self.m)
        self.solver = make_solver(cfg.solver, self.n, self.m, eps=cfg.eps, max_iter=cfg.max_iter)

    def compute_fixture_rows(self, p, R, k_h: float):
        """Fill G (m, 6) and the right-hand side b (m,) = -k_h h (holonomic) or 0; return (G, b)."""
        for c, sl in self._slices:
            self.G[sl] = c.jacobian(p, R)
            self.b[sl] = -k_h * c.residual(p, R) if c.holonomic else 0.0
        return self.G, self.b

    def build(self, q, J, p, R, p_t, R_t, v_t, w_t, q_post, lb, ub):
        """Fill H, g, A, b, lb, ub from the state and the target; returns the pose error e (6,)."""
        cfg, nv = self.cfg, self.nv
        nu, e = compute_target_twist(p, R, p_t, R_t, v_t, w_t, cfg.k_task_1ps)
        WJ = self.W[:, None] * J
        lam = cfg.damping + cfg.lm_damping * float(e @ (self.W * e)) + cfg.weight_posture
        Hq = J.T @ WJ
        Hq.flat[:: nv + 1] += lam
        self.H[:nv, :nv] = Hq
        qd_post = cfg.k_posture_1ps * (q_post - q)
        self.g[:nv] = -(WJ.T @ nu) - cfg.weight_posture * qd_post
        if self.m:
            G, _ = self.compute_fixture_rows(p, R, cfg.k_fixture_1ps)
            self.A[:, :nv] = G @ J
        self.lb[:nv] = lb
        self.ub[:nv] = ub
        return e

    def solve(self):
        """Solve the built QP: (qd, slack, y_eq, ok)."""
        r = self.solver.solve(self.H, self.g, self.A, self.b, self.lb, self.ub)
        return r.x[: self.nv], r.x[self.nv :], r.y_eq, r.ok

    def compute_fallback(self, J, e, lb, ub, hold: bool, qd_prev) -> np.ndarray:
        """Damped least squares toward the target (or a stop), clipped into the bounds (rad/s)."""
        stop = np.clip(np.zeros(self.nv), lb, ub)
        if hold or not np.all(np.isfinite(e)):
            return stop
        nu = self.cfg.k_task_1ps * e
        JJt = J @ J.T + (1e-4 + float(e @ e)) * np.eye(6)
        qd = np.clip(J.T @ np.linalg.solve(JJt, nu), lb, ub)
        return qd if np.all(np.isfinite(qd)) else stop


class SlaveArm:
    """The slave arm and its follower: joint state q (rad), qd (rad/s), tau (N*m), the tool frame E.

    ``step(p_t, R_t, v_t, w_t)`` runs one tick of ``dt_s`` and returns a status from ``STATUSES``.
    """

    def __init__(self, cfg, fixture_constraints=(), dt_s: float = 1e-3):
        from teleop.errors import ConfigError
        from teleop.slave.arm import build_model

        if not np.isfinite(dt_s) or dt_s <= 0:
            raise ConfigError(f"slave.dt_s: expected a positive period, got {dt_s}")
        if cfg.k_task_1ps * dt_s >= 1.0 or cfg.k_fixture_1ps * dt_s >= 1.0:
            raise ConfigError(f"slave.k_task_1ps: gains times dt must stay below 1 (dt = {dt_s} s)")
        self.cfg, self.dt = cfg, float(dt_s)
        am = build_model(cfg)
        self.model, self.frame_E, self.limits = am.model, am.frame_E, am.limits
        self.data = self.model.createData()
        self.nv = self.model.nv
        self.q_post = am.q0.copy()
        self.qp = FollowerQP(self.nv, fixture_constraints, cfg, dt_s)
        self.fixture_constraints = self.qp.constraints
        self._alpha = dt_s / (cfg.servo_lag_s + dt_s)
        self.status = "ok"
        self.slack = np.zeros(self.qp.m)
        self.fixture_forces = np.zeros(self.qp.m)
        self._set_state(am.q0.copy())

    # -- state ------------------------------------------------------------------------------
    def _set_state(self, q):
        self.q = np.asarray(q, dtype=float).copy()
        self.qd = np.zeros(self.nv)
        self.qd_cmd = np.zeros(self.nv)
        self.qdd = np.zeros(self.nv)
        self._kinematics()
        self.tau = pin.rnea(self.model, self.data, self.q, self.qd, self.qdd).copy()

    def _kinematics(self):
        self.J = pin.computeFrameJacobian(self.model, self.data, self.q, self.frame_E, pin.LOCAL_WORLD_ALIGNED)
        M = self.data.oMf[self.frame_E]
        self.p, self.R = M.translation.copy(), M.rotation.copy()

    def tool_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(p (3,) m, R_WE (3, 3)) of the tool frame E."""
        return self.p.copy(), self.R.copy()

    def tool_twist(self) -> tuple[np.ndarray, np.ndarray]:
        """(v m/s, w rad/s) of the tool frame E, LOCAL_WORLD_ALIGNED."""
        nu = self.J @ self.qd
        return nu[:3], nu[3:]

    def fixture_residual(self) -> np.ndarray:
        """Holonomic fixture residuals at the current tool pose (m or rad)."""
        from teleop.dynamics.constraints import stack_residual

        return stack_residual(self.fixture_constraints, self.p, self.R)

    # -- ticks ------------------------------------------------------------------------------
    def reset(self, target_pose=None, q=None, iters: int = 400, tol: float = 1e-9) -> str:
        """Put the tool at ``target_pose`` = (p, R) by IK from q0 (or ``q``), at rest.

        Gauss-Newton with LM damping inside the joint limits; the fixtures hold at the end when the
        target satisfies them. Returns "ok" or "ik_not_converged" (error above ``tol`` m/rad).
        """
        q = self.q_post.copy() if q is None else np.asarray(q, dtype=float).copy()
        self._set_state(q)
        if target_pose is None:
            self.status = "ok"
            return self.status
        p_t, R_t = np.asarray(target_pose[0], float), np.asarray(target_pose[1], float)
        for _ in range(iters):
            _, e = compute_target_twist(self.p, self.R, p_t, R_t, np.zeros(3), np.zeros(3), 0.0)
            err = float(e @ e)
            if err < tol**2:
                break
            Jt = self.J
            H = Jt.T @ Jt + (1e-6 + err) * np.eye(self.nv)
            dq = np.linalg.solve(H, Jt.T @ e)
            step = min(1.0, 0.2 / max(np.abs(dq).max(), 1e-12))
            q = self.limits.clip_position(pin.integrate(self.model, self.q, step * dq))
            self.q = q
            self._kinematics()
        self._set_state(self.q)
        _, e = compute_target_twist(self.p, self.R, p_t, R_t, np.zeros(3), np.zeros(3), 0.0)
        self.status = "ok" if float(np.abs(e).max()) <= max(tol, 1e-7) else "ik_not_converged"
        return self.status

    def step(self, p_target, R_target, v_target=None, w_target=None, F_tip_W=None) -> str:
        """Advance one tick toward the target pose (m, R_WE) with feedforward twist (m/s, rad/s).

        ``F_tip_W``: an optional contact wrench (N, N*m) on the tool at the tip, world axes, that
        the motors resist; it enters the reported torques ``tau`` (N*m).
        """
        cfg, dt = self.cfg, self.dt
        v_t = np.zeros(3) if v_target is None else v_target
        w_t = np.zeros(3) if w_target is None else w_target
        lb, ub = self.limits.compute_velocity_bounds(self.q, self.qd_cmd, dt)
        qp = self.qp
        finite = np.isfinite(np.sum(p_target) + np.sum(R_target) + np.sum(v_t) + np.sum(w_t))
        if not finite:  # never let a bad target near the solver: stop within the bounds
            p_target, R_target, v_t, w_t = self.p, self.R, np.zeros(3), np.zeros(3)
        e = qp.build(self.q, self.J, self.p, self.R, p_target, R_target, v_t, w_t, self.q_post, lb, ub)
        qd, s, y, ok = qp.solve()
        if not finite:
            qd = qp.compute_fallback(self.J, e, lb, ub, True, self.qd_cmd)
            self.slack, self.fixture_forces = np.zeros(qp.m), np.zeros(qp.m)
            status = "invalid_target"
        elif ok and np.all(np.isfinite(qd)):
            qd = np.clip(qd, lb, ub)  # solver tolerance only
            self.slack = s
            self.fixture_forces = -cfg.impedance_Ns_per_m * y
            if np.abs(s).max(initial=0.0) > cfg.relaxed_tol_mps:
                status = "fixtures_relaxed"
            elif float(np.linalg.norm(e[:3])) > cfg.tracking_alarm_m:
                status = "tracking_error"
            elif np.any(np.minimum(qd - lb, ub - qd) <= 1e-9):
                status = "saturated"
            else:
                status = "ok"
        else:
            qd = qp.compute_fallback(self.J, e, lb, ub, cfg.fallback == "hold", self.qd_cmd)
            self.slack = np.zeros(qp.m)
            self.fixture_forces = np.zeros(qp.m)
            status = "infeasible_fallback"
        self.qd_cmd = qd
        qd_new = self.qd + self._alpha * (qd - self.qd) if cfg.servo_lag_s > 0 else qd.copy()
        self.qdd = (qd_new - self.qd) / dt
        self.qd = qd_new
        self.q = pin.integrate(self.model, self.q, qd_new * dt)
        self._kinematics()
        self.tau = pin.rnea(self.model, self.data, self.q, self.qd, self.qdd)
        if F_tip_W is not None:
            self.tau = self.tau - self.J.T @ np.asarray(F_tip_W, dtype=float)
        self.status = status
        return status
