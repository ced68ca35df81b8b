"""The constrained rigid tool as a dynamical system: one evaluation of eqs. 5-9.

Eq. 7 factors as M(q) = T^T M_nu T with T = blockdiag(I3, R E_B) and M_nu = blockdiag(m I3, R J R^T)
(see :mod:`teleop.dynamics.body`). With A = G T this gives A M^-1 A^T = G M_nu^-1 G^T, so eq. 8 is
solved through that factorization: the Delassus matrix is built from the block-diagonal M_nu, whose
inverse is exact (1/m and R J^-1 R^T), and never from the Euler-chart M(q), which becomes
ill-conditioned near gimbal lock. The multipliers are the same; the acceleration of eq. 9 is then
mapped to the chart, qdd = T^-1 (nudot - Tdot qd). :func:`evaluate_literal` keeps the textbook
chart-coordinate evaluation of eqs. 8-9 for reference and tests.

Everything that depends on the pose only (R, E_B, G, the inverse inertia, the factored Delassus
matrix) is cached in :class:`PoseTerms`, so a step that ends with a velocity projection hands its
pose work to the next evaluation.

The same arithmetic runs in two forms: compiled kernels (:mod:`teleop.dynamics.kernels`, the
default when every constraint has one) and the numpy reference below (``compiled=False``, and the
path for constraint classes without a kernel). The tests hold the two equal.
"""

from __future__ import annotations

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
from teleop.dynamics import kernels
from teleop.dynamics.constraints import stack_bias, stack_jacobian, stack_residual
from teleop.dynamics.effects import total_wrench
from teleop.dynamics.multipliers import (
    RANK_RTOL,
    ConstrainedAcceleration,
    DelassusFactor,
    compute_constrained_acceleration,
)
from teleop.dynamics.rotations import EulerChart, cross, rate_map_terms


# no wrench; the kernels only read it. Writable on purpose: a read-only array is another numba type,
# and passing one would compile the kernel a second time in mid-run
_ZERO6 = np.zeros(6)


def _wrench6(F) -> np.ndarray:
    """F as a float64 (6,) array (the kernels index it unchecked); ValueError for another shape."""
    if type(F) is not np.ndarray or F.dtype != np.float64 or not F.flags.c_contiguous:
        F = np.ascontiguousarray(F, dtype=float)
    if F.shape != (6,):
        raise ValueError(f"operator wrench: expected 6 values, got shape {F.shape}")
    return F


class PoseTerms:
    """Pose-only quantities at (chart, q): p, R, E_B, E_B^-1, the Edot pieces, G, I_W^-1,
    M_nu^-1 G^T and the factored Delassus matrix K = G M_nu^-1 G^T; for the kernels, S and mode
    (the Cholesky factor or the pseudo-inverse of K, see :data:`kernels.SOLVE_CHOLESKY`)."""

    __slots__ = ("key", "p", "R", "E_B", "E_inv", "dE", "G", "Iinv_W", "MinvGt", "_K", "S", "mode",
                 "rank", "_Kmat")

    @property
    def K(self) -> DelassusFactor | None:
        """The factored Delassus matrix (built on first use from the kernel's Cholesky factor)."""
        if self._K is None and self._Kmat is not None:
            self._K = DelassusFactor.from_cholesky(self._Kmat, self.S, True)
        return self._K

    @K.setter
    def K(self, value: DelassusFactor | None) -> None:
        self._K, self._Kmat = value, None
        self.rank = value.rank if value is not None else 0


class Evaluation:
    """One evaluation at (q, qd): qdd (6,) chart accel., nudot (6,) world (vdot, wdot), lam (m,),
    rank of the Delassus matrix, the applied external wrench (6,), G (m, 6) and the pose terms.
    (A slotted class, not a frozen dataclass: it is built every tick.)"""

    __slots__ = ("qdd", "nudot", "lam", "rank", "wrench_W", "G", "pose")

    def __init__(self, qdd, nudot, lam, rank, wrench_W, G, pose):
        self.qdd, self.nudot, self.lam, self.rank = qdd, nudot, lam, rank
        self.wrench_W, self.G, self.pose = wrench_W, G, pose


class ConstrainedBody:
    """Body + constraints + effects. ``coriolis=False`` drops the gyroscopic torque w x I_W w.

    ``compiled``: use the compiled kernels when every pose-dependent constraint has one (see
    :func:`kernels.row_params`); ``False`` forces the numpy reference path. ``self.compiled`` says
    which path runs.
    """

    def __init__(self, body: RigidBody, constraints=(), effects=(), coriolis: bool = True,
                 compiled: bool = True):
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
        self._cache: PoseTerms | None = None
        self._inv_m = 1.0 / body.mass_kg
        # rows of constant constraints are filled once; only the others are evaluated per pose
        self._G_template = np.zeros((self.m, 6))
        self._varying = []
        i = 0
        for c in self.constraints:
            if c.constant:
                self._G_template[i : i + c.rows] = c.jacobian(np.zeros(3), np.eye(3))
            else:
                self._varying.append((i, i + c.rows, c))
            i += c.rows
        # dampers and gravity run inside the kernels; any other effect runs in Python first
        self._fx, self._py_effects = kernels.effect_params(self.effects)
        rows = [(i, kernels.row_params(c)) for i, _, c in self._varying]
        self.compiled = bool(compiled) and all(r is not None for _, r in rows)
        if self.compiled:
            self._kinds = np.array([r[0] for _, r in rows], dtype=np.int64)
            self._offsets = np.array([i for i, _ in rows], dtype=np.int64)
            self._params = np.array([r[1] for _, r in rows]).reshape(len(rows), kernels.NPAR)

    # -- pose-only terms --------------------------------------------------------------------------
    def pose_terms(self, chart: EulerChart, q: np.ndarray) -> PoseTerms:
        qb = q.tobytes()
        c = self._cache
        if c is not None and c.key[0] is chart and c.key[1] == qb:  # the chart object itself, not its id
            return c
        pt = PoseTerms()
        pt.key = (chart, qb)
        if self.compiled:
            self._compiled_pose_terms(pt, chart, q)
            self._cache = pt
            return pt
        pt.R, pt.E_B, pt.E_inv, pt.dE = rate_map_terms(chart, q[3:])
        pt.p = q[:3]
        R = pt.R
        pt.Iinv_W = R @ self.body.J_inv @ R.T
        if self.m:
            G = self._G_template.copy()
            for i, j, c in self._varying:
                G[i:j] = c.jacobian(pt.p, R)
            MinvGt = np.empty((6, self.m))
            MinvGt[:3] = G[:, :3].T * self._inv_m
            MinvGt[3:] = pt.Iinv_W @ G[:, 3:].T
            pt.G, pt.MinvGt = G, MinvGt
            pt.K = DelassusFactor(G @ MinvGt)
        else:
            pt.G, pt.MinvGt, pt.K = np.zeros((0, 6)), np.zeros((6, 0)), None
        self._cache = pt
        return pt

    def _compiled_pose_terms(self, pt: PoseTerms, chart: EulerChart, q: np.ndarray) -> None:
        pt.p = q[:3]
        (pt.R, pt.E_B, pt.E_inv, pt.dE, pt.Iinv_W, pt.G, pt.MinvGt, K, L, ok) = kernels.pose_terms(
            chart.R0, chart.axes_array, q, self.body.J_inv, self._inv_m, self._G_template,
            self._kinds, self._offsets, self._params, RANK_RTOL)
        if self.m and ok:  # the common case: the DelassusFactor object is only built if asked for
            pt._K, pt._Kmat, pt.S, pt.mode, pt.rank = None, K, L, kernels.SOLVE_CHOLESKY, self.m
        else:
            pt.K, pt.S, pt.mode = self._factor(K, L, ok)

    def _factor(self, K, L, ok):
        """(DelassusFactor or None, S, mode) for the kernels from the kernel's Cholesky attempt."""
        if not self.m:
            return None, L, kernels.SOLVE_NONE
        f = DelassusFactor.from_cholesky(K, L, ok)
        if ok:
            return f, L, kernels.SOLVE_CHOLESKY
        return f, f.pseudo_inverse(), kernels.SOLVE_PINV

    def twist(self, pt: PoseTerms, qd: np.ndarray) -> np.ndarray:
        """nu = T qd = (v, R E_B thetadot) (6,)."""
        nu = np.empty(6)
        nu[:3] = qd[:3]
        nu[3:] = pt.R @ (pt.E_B @ qd[3:])
        return nu

    def rates(self, pt: PoseTerms, nu: np.ndarray) -> np.ndarray:
        """qd = T^-1 nu (6,)."""
        qd = np.empty(6)
        qd[:3] = nu[:3]
        qd[3:] = pt.E_inv @ (pt.R.T @ nu[3:])
        return qd

    # -- eqs. 8-9 ------------------------------------------------------------------------------------
    def evaluate(self, chart: EulerChart, q, qd, t: float, operator_W=None, stabilize=None) -> Evaluation:
        """Eqs. 8-9 at (q, qd). ``stabilize=(alpha, beta)`` adds Baumgarte terms 2a G nu + b^2 h."""
        pt = self.pose_terms(chart, q)
        if self.compiled and stabilize is None:
            F = _ZERO6 if operator_W is None else _wrench6(operator_W)
            if self._py_effects:  # otherwise F goes to the kernel as it is, uncopied
                F = total_wrench(self._py_effects, pt.p, pt.R, qd[:3], pt.R @ (pt.E_B @ qd[3:]), t, F)
            qdd, nudot, lam, F = kernels.evaluate(
                pt.R, pt.E_B, pt.E_inv, pt.dE, pt.Iinv_W, self.body.J, self._inv_m, self.coriolis,
                pt.G, pt.MinvGt, pt.S, pt.mode, self._kinds, self._offsets, self._params, pt.p, qd,
                F, self._fx)
            return Evaluation(qdd, nudot, lam, pt.rank, F, pt.G, pt)
        thd = qd[3:]
        d1, d2, d3 = float(thd[0]), float(thd[1]), float(thd[2])
        a1, u, a2 = pt.dE
        k1, k2, k3 = d1 * d3, d1 * d2, d2 * d3
        Edq = np.array([
            -k1 * a1[0] - k2 * u[0] - k3 * a2[0],
            -k1 * a1[1] - k2 * u[1] - k3 * a2[1],
            -k1 * a1[2] - k2 * u[2] - k3 * a2[2],
        ])
        v = qd[:3]
        w_B = pt.E_B @ thd
        w = pt.R @ w_B
        F = np.zeros(6) if operator_W is None else np.array(operator_W, dtype=float)
        for e in self.effects:
            e.add_wrench(pt.p, pt.R, v, w, t, F)
        free = np.empty(6)
        free[:3] = F[:3] * self._inv_m
        # gyroscopic torque w x I_W w = R (w_B x J w_B)
        tq = F[3:] - pt.R @ cross(w_B, self.body.J @ w_B) if self.coriolis else F[3:]
        free[3:] = pt.Iinv_W @ tq
        if self.m:
            b = np.zeros(self.m)
            for i, j, c in self._varying:
                b[i:j] = c.bias(pt.p, pt.R, v, w)
            if stabilize is not None:
                alpha, beta = stabilize
                nu = np.concatenate([v, w])
                h = np.zeros(self.m)
                h[self.holonomic_mask] = stack_residual(self.constraints, pt.p, pt.R)
                b = b + 2.0 * alpha * (pt.G @ nu) + beta * beta * h
            lam = pt.K.solve(-b - pt.G @ free)
            nudot = free + pt.MinvGt @ lam
            rank = pt.K.rank
        else:
            lam, nudot, rank = np.zeros(0), free, 0
        qdd = np.empty(6)
        qdd[:3] = nudot[:3]
        qdd[3:] = pt.E_inv @ (pt.R.T @ nudot[3:] - Edq)
        return Evaluation(qdd, nudot, lam, rank, F, pt.G, pt)

    def project_rates(self, pt: PoseTerms, qd: np.ndarray) -> np.ndarray:
        """The admissible rates closest to qd (6,) in kinetic energy, at the pose of ``pt``."""
        if not self.m:
            return qd
        if self.compiled:
            return kernels.project_rates(pt.R, pt.E_B, pt.E_inv, pt.G, pt.MinvGt, pt.S, pt.mode, qd)
        return self.rates(pt, self.project_twist(pt, self.twist(pt, qd)))

    def project_twist(self, pt: PoseTerms, nu: np.ndarray) -> np.ndarray:
        """The admissible twist closest to nu in kinetic energy: nu - M^-1 G^T K^+ G nu."""
        if not self.m:
            return nu
        return nu - pt.MinvGt @ pt.K.solve(pt.G @ nu)

    # -- Lie group: no chart ----------------------------------------------------------------------
    def evaluate_twist(self, p, R, v, w, t: float, operator_W=None) -> Evaluation:
        """Newton-Euler with constraints at pose (p, R), twist (v, w): no Euler chart involved."""
        body = self.body
        if self.compiled:
            F = total_wrench(self._py_effects, p, R, v, w, t, operator_W)
            Iinv, G, MinvGt, K, L, ok = self._twist_terms(p, R)
            Kf, S, mode = self._factor(K, L, ok)
            nudot, lam, F = kernels.newton_euler(R, Iinv, body.J, self._inv_m, self.coriolis, G, MinvGt, S,
                                                 mode, self._kinds, self._offsets, self._params, p, v, w, F,
                                                 self._fx)
            return Evaluation(nudot, nudot, lam, Kf.rank if self.m else 0, F, G, None)
        F = total_wrench(self.effects, p, R, v, w, t, operator_W)
        I_W = R @ body.J @ R.T
        Iinv_W = R @ body.J_inv @ R.T
        free = np.empty(6)
        free[:3] = F[:3] * self._inv_m
        free[3:] = Iinv_W @ (F[3:] - cross(w, I_W @ w) if self.coriolis else F[3:])
        if not self.m:
            return Evaluation(free, free, np.zeros(0), 0, F, np.zeros((0, 6)), None)
        G = stack_jacobian(self.constraints, p, R)
        b = stack_bias(self.constraints, p, R, v, w)
        MinvGt = np.empty((6, self.m))
        MinvGt[:3] = G[:, :3].T * self._inv_m
        MinvGt[3:] = Iinv_W @ G[:, 3:].T
        K = DelassusFactor(G @ MinvGt)
        lam = K.solve(-b - G @ free)
        nudot = free + MinvGt @ lam
        return Evaluation(nudot, nudot, lam, K.rank, F, G, None)

    def _twist_terms(self, p, R):
        return kernels.constraint_terms(R, p, self.body.J_inv, self._inv_m, self._G_template,
                                        self._kinds, self._offsets, self._params, RANK_RTOL)

    def project_twist_at(self, p, R, nu: np.ndarray) -> np.ndarray:
        """The admissible twist closest to nu (6,) in kinetic energy at pose (p, R)."""
        if not self.m:
            return nu
        if self.compiled:
            _, G, MinvGt, K, L, ok = self._twist_terms(p, R)
            _, S, mode = self._factor(K, L, ok)
            return kernels.project_twist(G, MinvGt, S, mode, nu)
        G = stack_jacobian(self.constraints, p, R)
        MinvGt = self.twist_mass_inverse(R) @ G.T
        return nu - MinvGt @ DelassusFactor(G @ MinvGt).solve(G @ nu)

    def twist_mass_inverse(self, R) -> np.ndarray:
        """blockdiag(I3/m, R J^-1 R^T) (6, 6)."""
        Minv = np.zeros((6, 6))
        Minv[0, 0] = Minv[1, 1] = Minv[2, 2] = self._inv_m
        Minv[3:, 3:] = R @ self.body.J_inv @ R.T
        return Minv


def evaluate_literal(model: ConstrainedBody, chart: EulerChart, q, qd, t: float, operator_W=None) -> ConstrainedAcceleration:
    """Eqs. 8-9 exactly as printed, in chart coordinates: M(q), C(q,qd)qd, A(q), Adot qd.

    The reference the fast path is tested against; also what a reader of the paper expects to see.
    """
    kin = Kinematics(chart, q, qd)
    M = compute_mass_matrix(model.body, kin)
    Cqd = compute_coriolis(model.body, kin, gyroscopic=model.coriolis)
    F = total_wrench(model.effects, kin.p, kin.R, kin.v, kin.w, t, operator_W)
    tau = generalized_force(kin, F)
    G = stack_jacobian(model.constraints, kin.p, kin.R)
    A = constraint_matrix(G, kin)
    Adq = constraint_bias(G, stack_bias(model.constraints, kin.p, kin.R, kin.v, kin.w), kin)
    return compute_constrained_acceleration(M, Cqd, tau, A, Adq)
