"""The slave arm's tick: joint limits -> follower QP (teleop.slave.follower) -> servo -> state.

``SlaveArm.step`` computes the joint velocity bounds of the tick, builds and solves the follower's
QP toward the target pose and twist, classifies the outcome (``STATUSES``), falls back to damped
least squares (or a stop) when the solver fails, and integrates the joint state through the servo
lag, with the kinematics and joint torques of the new state.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from teleop.dynamics.constraints import stack_residual
from teleop.slave.arm import build_model
from teleop.slave.follower import FollowerQP, compute_target_twist
from teleop.slave.kernels import advance_joints
from teleop.util.errors import ConfigError

__all__ = ["STATUSES", "FollowerQP", "SlaveArm", "compute_target_twist"]

STATUSES = ("ok", "saturated", "tracking_error", "fixtures_relaxed", "infeasible_fallback", "invalid_target")
_ZERO3, _ZERO6 = np.zeros(3), np.zeros(6)  # read-only defaults
_ZERO3.flags.writeable = False
_ZERO6.flags.writeable = False


def _target_arrays(p, R, v, w) -> tuple | None:
    """(p, R, v, w) as C-ordered float arrays of shapes (3,), (3, 3), (3,), (3,) (what the kernels
    index unchecked; already such arrays pass through without a copy), or None when they are not."""
    c = np.ascontiguousarray
    try:
        p, R, v, w = c(p, dtype=float), c(R, dtype=float), c(v, dtype=float), c(w, dtype=float)
    except (TypeError, ValueError):
        return None
    return (p, R, v, w) if p.shape == v.shape == w.shape == (3,) and R.shape == (3, 3) else None


class SlaveArm:
    """The slave arm and its follower: joint state q (rad), qd (rad/s), tau (N*m), the tool frame E.

    ``step(p_t, R_t, v_t, w_t)`` runs one tick of ``dt_s`` and returns a status from ``STATUSES``.
    ``fixture_constraints``: any :class:`teleop.dynamics.constraints.Constraint` objects, a user's
    own included, in the patient frame (the arm's world).
    """

    def __init__(self, cfg, fixture_constraints=(), dt_s: float = 1e-3):
        if not np.isfinite(dt_s) or dt_s <= 0:
            raise ConfigError(f"slave.dt_s: expected a positive period, got {dt_s}")
        if cfg.k_task_1ps * dt_s >= 1.0 or cfg.k_fixture_1ps * dt_s >= 1.0:
            raise ConfigError(f"slave.k_task_1ps: gains times dt must stay below 1 (dt = {dt_s} s)")
        self.cfg, self.dt = cfg, float(dt_s)
        am = build_model(cfg)
        self.model, self.frame_E, self.limits = am.model, am.frame_E, am.limits
        self.data = self.model.createData()
        self._tau_data = self.model.createData()  # the torques' own, read on demand (see ``tau``)
        self.nv = self.model.nv
        self.q_post = am.q0.copy()
        self.qp = FollowerQP(self.nv, fixture_constraints, cfg)
        self.fixture_constraints = self.qp.constraints
        self._alpha = dt_s / (cfg.servo_lag_s + dt_s)
        self.status = "ok"
        self.slack = np.zeros(self.qp.m)
        self._y = None  # the last solve's row multipliers (None: no forces), see fixture_forces
        self._set_state(am.q0.copy())

    # -- state ------------------------------------------------------------------------------
    def _set_state(self, q):
        self.q = np.asarray(q, dtype=float).copy()
        self.qd = np.zeros(self.nv)
        self.qd_cmd = np.zeros(self.nv)
        self.qdd = np.zeros(self.nv)
        self._kinematics()
        self._torques_at(None)

    def _kinematics(self):
        """J (6, nv) and the pose matrix T_WE (4, 4) of the tool frame, new arrays."""
        self.J = pin.computeFrameJacobian(self.model, self.data, self.q, self.frame_E, pin.LOCAL_WORLD_ALIGNED)
        self.T_WE = pin.updateFramePlacement(self.model, self.data, self.frame_E).homogeneous  # a copy

    def _torques_at(self, F_tip_W) -> None:
        """Keep the state (and the contact wrench F_tip_W, or None) the joint torques are of; they
        are computed when read (:attr:`tau`): nothing in the tick needs them."""
        F = None if F_tip_W is None else np.array(F_tip_W, dtype=float)
        self._tau_of, self._tau = (self.q, self.qd, self.qdd, self.J, F), None

    @property
    def fixture_forces(self) -> np.ndarray:
        """The fixture rows' forces (N or N*m) of the last tick: the QP's row multipliers times
        -``impedance_Ns_per_m`` (zeros when the QP did not solve). Computed when read."""
        if self._y is None:
            return np.zeros(self.qp.m)
        return self._y * -self.cfg.impedance_Ns_per_m

    @property
    def tau(self) -> np.ndarray:
        """The joint torques (N*m) of the last tick: inverse dynamics (pin.rnea) at its state, less
        J^T F_tip_W for the contact wrench the motors resist. Computed on first read."""
        if self._tau is None:
            q, qd, qdd, J, F = self._tau_of
            tau = pin.rnea(self.model, self._tau_data, q, qd, qdd).copy()
            self._tau = tau if F is None else tau - J.T @ F
        return self._tau

    @property
    def p(self) -> np.ndarray:
        """Origin of the tool frame E (3,), m: a view of T_WE."""
        return self.T_WE[:3, 3]

    @property
    def R(self) -> np.ndarray:
        """R_WE (3, 3): a view of T_WE."""
        return self.T_WE[:3, :3]

    def tool_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(p (3,) m, R_WE (3, 3)) of the tool frame E."""
        return self.p.copy(), self.R.copy()

    def tool_twist(self) -> tuple[np.ndarray, np.ndarray]:
        """(v m/s, w rad/s) of the tool frame E, LOCAL_WORLD_ALIGNED."""
        nu = self.J @ self.qd
        return nu[:3], nu[3:]

    def fixture_residual(self) -> np.ndarray:
        """Holonomic fixture residuals at the current tool pose (m or rad)."""
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
        cfg, qp = self.cfg, self.qp
        target = _target_arrays(p_target, R_target, _ZERO3 if v_target is None else v_target,
                                _ZERO3 if w_target is None else w_target)
        if target is None:
            e, (lb, ub) = None, self.limits.compute_velocity_bounds(self.q, self.qd_cmd, self.dt)
        else:
            e, lb, ub = qp.build_within(self.limits, self.q, self.qd_cmd, self.dt, self.J, self.T_WE, *target,
                                        self.q_post)
        if e is None:  # a target that is not finite never reaches the solver: stop within the bounds
            qd, status = qp.compute_fallback(self.J, _ZERO6, lb, ub, True, self.qd_cmd), "invalid_target"
            self.slack, self._y = np.zeros(qp.m), None
        else:
            qd, s, y, ok = qp.solve()
            if ok:
                self.slack = s
                self._y = y
                tol = cfg.relaxed_tol_mps  # on max |s|; |s|_2 <= tol rules it out with one product
                if np.vdot(s, s) > tol * tol and max(np.abs(s).tolist()) > tol:
                    status = "fixtures_relaxed"
                elif qp.position_error_m > cfg.tracking_alarm_m:
                    status = "tracking_error"
                elif qp.bound_margin <= 1e-9:  # a joint on a bound, rad/s
                    status = "saturated"
                else:
                    status = "ok"
            else:
                qd = qp.compute_fallback(self.J, e, lb, ub, cfg.fallback == "hold", self.qd_cmd)
                self.slack, self._y = np.zeros(qp.m), None
                status = "infeasible_fallback"
        self._advance(qd, F_tip_W)
        self.status = status
        return status

    def hold(self, F_tip_W=None) -> str:
        """The safe state for one tick: zero joint velocity commanded (through the servo lag), no
        QP solved, so the joints stop where they are. Returns "hold"."""
        self._advance(np.zeros(self.nv), F_tip_W)
        self.status = "hold"
        return self.status

    def _advance(self, qd_cmd, F_tip_W) -> None:
        """Command the joint velocity qd_cmd (rad/s) through the servo lag for one tick; update
        the state and the kinematics (the joint torques of ``F_tip_W``, N and N*m, when read)."""
        self.qd_cmd = qd_cmd
        # build_model admits only nq == nv, i.e. revolute and prismatic joints: pin.integrate is a sum
        state = np.empty((3, self.nv))  # the new q, qd, qdd: views of one array
        advance_joints(self.q, self.qd, np.asarray(qd_cmd, dtype=float), self._alpha, self.cfg.servo_lag_s > 0,
                       self.dt, state)
        self.q, self.qd, self.qdd = state[0], state[1], state[2]
        self._kinematics()
        self._torques_at(F_tip_W)
