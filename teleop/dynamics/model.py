"""The constrained rigid tool as a dynamical system: one evaluation of eqs. 5-9.

:class:`ConstrainedBody` owns the body, the constraint stack and the effect list, and evaluates the
constrained acceleration either in Euler-chart coordinates (the paper's formulation) or in twist
space (used by the Lie-group integrator; identical physics, no chart).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teleop.dynamics.body import (
    Kinematics,
    RigidBody,
    compute_coriolis,
    compute_mass_matrix,
    constraint_bias,
    constraint_matrix,
    generalized_force,
)
from teleop.dynamics.constraints import stack_bias, stack_jacobian, stack_residual
from teleop.dynamics.effects import total_wrench
from teleop.dynamics.multipliers import (
    compute_constrained_acceleration,
    solve_delassus,
)
from teleop.dynamics.rotations import EulerChart, cross


@dataclass(frozen=True, eq=False)
class Evaluation:
    """One evaluation at (q, qd): acceleration qdd (6,), multipliers lam (m,), rank of A M^-1 A^T,
    the applied external wrench wrench_W (6,), and the kinematics, M (6, 6), A (m, 6), G (m, 6)."""

    kin: Kinematics
    M: np.ndarray
    A: np.ndarray
    G: np.ndarray
    qdd: np.ndarray
    lam: np.ndarray
    rank: int
    wrench_W: np.ndarray


@dataclass(frozen=True, eq=False)
class TwistEvaluation:
    """Twist-space evaluation: nudot = (vdot, wdot) (6,), lam (m,), rank, wrench_W (6,), G (m, 6)."""

    G: np.ndarray
    nudot: np.ndarray
    lam: np.ndarray
    rank: int
    wrench_W: np.ndarray


class ConstrainedBody:
    """Body + constraints + effects. ``coriolis=False`` drops C(q, qd) qd (a scene-level effect)."""

    def __init__(self, body: RigidBody, constraints=(), effects=(), coriolis: bool = True):
        self.body = body
        self.constraints = tuple(constraints)
        self.effects = tuple(effects)
        self.coriolis = bool(coriolis)
        self.m = sum(c.rows for c in self.constraints)
        mask = []
        for c in self.constraints:
            mask += [c.holonomic] * c.rows
        self.holonomic_mask = np.array(mask, dtype=bool)
        self.holonomic = tuple(c for c in self.constraints if c.holonomic)
        self.nonholonomic = tuple(c for c in self.constraints if not c.holonomic)
        self._zeros6 = np.zeros(6)

    # -- Euler-chart coordinates (the paper's eqs. 5-9) -------------------------------------------
    def evaluate(self, chart: EulerChart, q, qd, t: float, operator_W=None, stabilize=None) -> Evaluation:
        """Eqs. 8-9 at (q, qd). ``stabilize=(alpha, beta)`` adds Baumgarte terms 2a A qd + b^2 h."""
        kin = Kinematics(chart, q, qd)
        M = compute_mass_matrix(self.body, kin)
        Cqd = compute_coriolis(self.body, kin) if self.coriolis else self._zeros6
        F = total_wrench(self.effects, kin.p, kin.R, kin.v, kin.w, t, operator_W)
        tau = generalized_force(kin, F)
        G = stack_jacobian(self.constraints, kin.p, kin.R)
        A = constraint_matrix(G, kin)
        Adq = constraint_bias(G, stack_bias(self.constraints, kin.p, kin.R, kin.v, kin.w), kin)
        if stabilize is not None and self.m:
            alpha, beta = stabilize
            Adq = Adq + 2.0 * alpha * (A @ qd)
            h = np.zeros(self.m)
            h[self.holonomic_mask] = stack_residual(self.constraints, kin.p, kin.R)
            Adq = Adq + beta * beta * h
        res = compute_constrained_acceleration(M, Cqd, tau, A, Adq)
        return Evaluation(kin, M, A, G, res.qdd, res.lam, res.rank, F)

    # -- twist space (Lie group), also the Newton-Euler oracle --------------------------------------
    def evaluate_twist(self, p, R, v, w, t: float, operator_W=None) -> TwistEvaluation:
        """Newton-Euler with constraints: m vdot = f + lam_f, I_W wdot + w x I_W w = tau + lam_tau."""
        body = self.body
        F = total_wrench(self.effects, p, R, v, w, t, operator_W)
        I_W = R @ body.J @ R.T
        Iinv_W = R @ body.J_inv @ R.T
        rhs = np.empty(6)
        rhs[:3] = F[:3] / body.mass_kg
        tq = F[3:] - (cross(w, I_W @ w) if self.coriolis else 0.0)
        rhs[3:] = Iinv_W @ tq
        if not self.m:
            return TwistEvaluation(np.zeros((0, 6)), rhs, np.zeros(0), 0, F)
        G = stack_jacobian(self.constraints, p, R)
        b = stack_bias(self.constraints, p, R, v, w)
        MinvGt = np.empty((6, self.m))
        MinvGt[:3] = G[:, :3].T / body.mass_kg
        MinvGt[3:] = Iinv_W @ G[:, 3:].T
        lam, rank = solve_delassus(G @ MinvGt, -b - G @ rhs)
        return TwistEvaluation(G, rhs + MinvGt @ lam, lam, rank, F)

    def twist_mass_inverse(self, R) -> np.ndarray:
        """blockdiag(I3/m, R J^-1 R^T) (6, 6)."""
        Minv = np.zeros((6, 6))
        Minv[0, 0] = Minv[1, 1] = Minv[2, 2] = 1.0 / self.body.mass_kg
        Minv[3:, 3:] = R @ self.body.J_inv @ R.T
        return Minv
