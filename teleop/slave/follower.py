"""The follower's QP: its workspace, filled in place every tick, and how it is solved.

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
(weight rho >> 1) keeps the problem feasible when fixtures conflict with the joint limits. The
rows' multipliers y, times an impedance (N s/m), are the fixture forces (N or N*m).

Without the bounds, the QP's optimality conditions are a linear system in (y, qd), with
Hq = J'WJ + (lam + w_post) I, gq = -(WJ)' nu* - w_post k_post (q_post - q), Aq = G J and
b = -k_h h:

    [-I / rho  Aq] [y ]   [ b ]
    [ Aq'      Hq] [qd] = [-gq],      s = -y / rho.

When its qd lies within the bounds it is the QP's exact solution (no bound is active).

Fixtures first. With a bound active, the weighted slack trades fixture for tracking: the QP's
optimum relaxes the rows by about (tracking residual) / rho, a few um/s whenever the arm cannot
follow its target (a target moving faster than the joints' acceleration box allows). The rows
are meant to be hard whenever the bounds admit them, so when the solution's slack exceeds
``cfg.relaxed_tol_mps`` the follower solves two more exact (DAQP) problems, lexicographically:

1. the least fixture violation the bounds admit:
   minimize 1/2 |s|^2 + 1/2 eps |qd - qd0|^2  s.t.  A qd + s = b, lb <= qd <= ub
   (qd0 the first solution, eps = FIXTURE_FIRST_EPS: a tie-break only), giving s1;
2. the original QP with the slack pinned to s1 (bounds s1 <= s <= s1): the best tracking among
   the joint velocities that hold the fixture as well as the bounds allow.

The rows stay relaxed only by what the bounds force (s1), and tracking gives way instead.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from teleop.dynamics.rows import RowStack
from teleop.slave import kernels
from teleop.slave.solvers import make_solver

#: the tie-break weight on |qd - qd0|^2 (per (rad/s)^2) in the fixture-first stage, against 1 per
#: (m/s)^2 of fixture violation: small enough that the violation found is the least one to ~1e-9
#: of its own size, large enough to keep the stage's Hessian positive definite
FIXTURE_FIRST_EPS = 1e-9


def compute_target_twist(p, R, p_t, R_t, v_t, w_t, k: float) -> tuple[np.ndarray, np.ndarray]:
    """(nu*, e): target twist (6,) (m/s, rad/s) and pose error e = (p_t - p, log(R_t R')) (m, rad)."""
    e = np.empty(6)
    e[:3] = p_t - p
    e[3:] = pin.log3(R_t @ R.T)
    nu = k * e
    nu[:3] += v_t
    nu[3:] += w_t
    return nu, e


class FollowerQP:
    """Workspace and solver of the follower for one arm and one fixed set of fixture constraints.

    ``build`` fills the linear system above in place (one compiled call,
    :func:`teleop.slave.kernels.build_system`, on the rows of :class:`teleop.dynamics.rows.RowStack`, the same rows the
    master evaluates). ``solve`` solves it when ``cfg.kkt_shortcut`` is set (one compiled LU solve of
    size m + nv) and keeps its solution when within the bounds; otherwise the persistent QP solver
    ``cfg.solver`` runs on the full problem, which ``problem()`` writes.
    """

    def __init__(self, nv: int, constraints, cfg):
        self.nv = nv
        self.rows = RowStack(constraints)
        self.constraints = self.rows.constraints
        self.m = m = self.rows.m
        n = nv + m
        self.cfg = cfg
        rho = cfg.slack_weight
        self.position_error_m = 0.0  # |p_t - p| (m) at the last build
        # the linear system in (y, qd), its right-hand side (b, -gq), and views of its blocks
        self._K = np.zeros((n, n))
        self._K[:m, :m] = -np.eye(m) / rho
        self._Aq, self._Hq = self._K[:m, m:], self._K[m:, m:]
        self._rhs = np.zeros(n)
        self.b, self._mgq = self._rhs[:m], self._rhs[m:]
        self._e = np.zeros(6)
        self._p, self._R = np.zeros(3), np.zeros((3, 3))
        self._lbq = self._ubq = np.zeros(nv)
        self.bound_margin = 0.0  # after a successful solve: min over joints of (qd - lb, ub - qd)
        self._minus_inv_rho = -1.0 / rho
        W = np.array([cfg.weight_position] * 3 + [cfg.weight_orientation] * 3)
        self._kernel_consts = (float(cfg.k_fixture_1ps), W, float(cfg.k_task_1ps),
                               cfg.weight_posture * cfg.k_posture_1ps, float(cfg.damping + cfg.weight_posture),
                               float(cfg.lm_damping * cfg.weight_position),
                               float(cfg.lm_damping * cfg.weight_orientation))
        c = self._kernel_consts  # packed (12,) for kernels.bounded_system
        self._consts = np.array([c[0], *W, *c[2:]], dtype=float)
        self._presolved = False  # build_within solved the bound-free system already (its margin kept)
        self._margin = np.nan
        # the full problem in x = (qd, s), for the QP solver
        self._H = np.zeros((n, n))
        self._H[nv:, nv:] = rho * np.eye(m)
        self._g = np.zeros(n)
        self._A = np.zeros((m, n))
        self._A[:, nv:] = np.eye(m)
        self._lb = np.full(n, -np.inf)
        self._ub = np.full(n, np.inf)
        self.solver = make_solver(cfg.solver, n, m, eps=cfg.eps, max_iter=cfg.max_iter)
        # An iterative solver (OSQP) can stop at its iteration cap on this problem's conditioning
        # (the slack weight against the damping: cond(H) ~ 1e10) when a tight acceleration box
        # binds; then the same problem goes to DAQP, a dense active-set solver that ends at the
        # exact solution in finitely many steps. Only when both fail does the arm fall back.
        self.exact = (None if cfg.solver == "daqp"
                      else make_solver("daqp", n, m, eps=cfg.eps, max_iter=max(cfg.max_iter, 1000)))
        self.used_solver = False  # whether the last solve() ran the QP solver
        self.used_fixtures_first = False  # whether the last solve() took the fixture-first stages
        self.retries = 0  # solves the exact solver finished after cfg.solver failed
        self.fixture_first = 0  # solves whose slack the fixture-first stage lowered
        self._first = make_solver("daqp", n, m, eps=cfg.eps, max_iter=max(cfg.max_iter, 1000))
        self._H1 = np.zeros((n, n))
        self._H1[:nv, :nv] = FIXTURE_FIRST_EPS * np.eye(nv)
        self._H1[nv:, nv:] = np.eye(m)
        self._g1 = np.zeros(n)
        self._lb2, self._ub2 = np.full(n, -np.inf), np.full(n, np.inf)
        self._z = np.zeros(n)

    def build_within(self, limits, q, qd_prev, dt: float, J, T, p_t, R_t, v_t, w_t, q_post):
        """:meth:`build` with the joint velocity bounds of the tick made here
        (``limits.compute_velocity_bounds(q, qd_prev, dt)``, rad/s). On compiled rows, one call
        (:func:`teleop.slave.kernels.bounded_system`) that with ``cfg.kkt_shortcut`` also solves
        the system without its bounds, which :meth:`solve` then takes. Returns (e or None as
        :meth:`build` does, lb, ub)."""
        rows = self.rows
        if rows.python_rows:
            lb, ub = limits.compute_velocity_bounds(q, qd_prev, dt)
            return self.build(q, J, T, p_t, R_t, v_t, w_t, q_post, lb, ub), lb, ub
        bounds = np.empty((2, self.nv))
        shortcut = bool(self.cfg.kkt_shortcut)
        ep2, margin = kernels.bounded_system(
            rows.table, rows.params, *rows.workspaces, limits.packed, float(limits.margin_rad),
            np.asarray(q, dtype=float), np.asarray(qd_prev, dtype=float), float(dt), J, T, p_t, R_t, v_t, w_t,
            q_post, self._consts, self._K, self._rhs, self._e, bounds, self._z, shortcut)
        lb, ub = bounds[0], bounds[1]
        if ep2 < 0.0:
            self._presolved = False
            return None, lb, ub
        self.position_error_m = math.sqrt(ep2)
        self._lbq, self._ubq = lb, ub
        self._presolved, self._margin = shortcut, margin
        return self._e, lb, ub

    def build(self, q, J, T, p_t, R_t, v_t, w_t, q_post, lb, ub):
        """Fill the linear system from the state (q rad, J, the tool's pose matrix T (4, 4)) and the
        target; keep the bounds lb, ub (nv,) rad/s. Returns the pose error e (6,), a buffer valid
        until the next build, or None when the target is not finite (the system is then unusable).
        The target is C-ordered float arrays of shapes (3,), (3, 3), (3,), (3,), as
        ``SlaveArm.step`` makes it: the kernel indexes them unchecked."""
        rows = self.rows
        self._presolved = False
        if rows.python_rows:  # a user's row: the stack evaluated in Python, then the system
            self._p[:] = T[:3, 3]  # contiguous copies: the rows' kernel runs its fastest specialisation
            self._R[:] = T[:3, :3]
            G, _, h = rows.evaluate(self._p, self._R)
            ep2 = kernels.build_system(q, J, T, p_t, R_t, v_t, w_t, q_post, G, h, *self._kernel_consts,
                                       self._K, self._rhs, self._e)
        else:  # every row compiled: rows and system in one call
            ep2 = kernels.build_system_on_rows(rows.table, rows.params, *rows.workspaces, q, J, T, p_t, R_t, v_t,
                                               w_t, q_post, *self._kernel_consts, self._K, self._rhs, self._e)
        if ep2 < 0.0:
            return None
        self.position_error_m = math.sqrt(ep2)
        self._lbq, self._ubq = lb, ub
        return self._e

    def problem(self):
        """(H, g, A, b, lb, ub) of the built QP in x = (qd, s), for a QP solver; buffers that the
        next call overwrites."""
        nv = self.nv
        self._H[:nv, :nv] = self._Hq
        np.negative(self._mgq, out=self._g[:nv])
        self._A[:, :nv] = self._Aq
        self._lb[:nv] = self._lbq
        self._ub[:nv] = self._ubq
        return self._H, self._g, self._A, self.b, self._lb, self._ub

    def solve(self):
        """Solve the built QP: (qd, slack, y_eq, ok), new arrays. When ok, qd is finite and within
        the bounds, and ``bound_margin`` (rad/s) is its least distance to them."""
        lb, ub, m = self._lbq, self._ubq, self.m
        if self.cfg.kkt_shortcut:
            z = self._z
            if self._presolved:  # build_within solved it
                margin, self._presolved = self._margin, False
            else:
                margin = kernels.solve_unbounded(self._K, self._rhs, self.nv, lb, ub, z)
            if margin >= 0.0:  # no bound is active: this is the QP's solution (NaN: singular)
                self.bound_margin, self.used_solver = margin, False
                y = z[:m].copy()
                return z[m:].copy(), y * self._minus_inv_rho, y, True
        self.used_solver = True
        self.used_fixtures_first = False
        problem = self.problem()
        r = self.solver.solve(*problem)
        if not r.ok and self.exact is not None:
            r = self.exact.solve(*problem)
            self.retries += r.ok
        nv = self.nv
        if r.ok and m and max(np.abs(r.x[nv:]).tolist()) > self.cfg.relaxed_tol_mps:
            r = self._fixtures_first(problem, r)
        qd = np.minimum(np.maximum(r.x[:nv], lb), ub)  # solver tolerance only
        self.bound_margin = min(np.minimum(qd - lb, ub - qd).tolist())
        return qd, r.x[nv:], r.y_eq, r.ok and math.isfinite(np.vdot(qd, qd))

    def _fixtures_first(self, problem, r):
        """The two exact stages of the module docstring from the solution ``r`` (a QPResult) of
        ``problem``; ``r`` itself when a stage fails or does not lower the slack."""
        nv = self.nv
        H, g, A, b, lb, ub = problem
        self._g1[:nv] = -FIXTURE_FIRST_EPS * r.x[:nv]
        r1 = self._first.solve(self._H1, self._g1, A, b, lb, ub)
        if not r1.ok:
            return r
        s1 = b - A[:, :nv] @ np.minimum(np.maximum(r1.x[:nv], lb[:nv]), ub[:nv])
        if not np.abs(s1).max() < np.abs(r.x[nv:]).max():
            return r
        self._lb2[:nv], self._ub2[:nv] = lb[:nv], ub[:nv]
        self._lb2[nv:], self._ub2[nv:] = s1, s1
        r2 = self.exact_solver().solve(H, g, A, b, self._lb2, self._ub2)
        if not r2.ok:
            return r
        self.fixture_first += 1
        self.used_fixtures_first = True
        return r2

    def exact_solver(self):
        """The dense active-set solver (DAQP) of the exact stages."""
        return self.exact if self.exact is not None else self.solver

    def compute_fallback(self, J, e, lb, ub, hold: bool, qd_prev) -> np.ndarray:
        """Damped least squares toward the target (or a stop), clipped into the bounds (rad/s)."""
        stop = np.clip(np.zeros(self.nv), lb, ub)
        if hold or not np.all(np.isfinite(e)):
            return stop
        nu = self.cfg.k_task_1ps * e
        JJt = J @ J.T + (1e-4 + float(e @ e)) * np.eye(6)
        qd = np.clip(J.T @ np.linalg.solve(JJt, nu), lb, ub)
        return qd if np.all(np.isfinite(qd)) else stop
