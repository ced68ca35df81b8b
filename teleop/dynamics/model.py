"""The constrained rigid tool as a dynamical system: one evaluation of eqs. 5-9.

Eq. 7 factors as M(q) = T^T M_nu T with T = blockdiag(I3, R E_B) and M_nu = blockdiag(m I3, R J R^T)
(see :mod:`teleop.dynamics.body`). With A = G T this gives A M^-1 A^T = G M_nu^-1 G^T, so eq. 8 is
solved through that factorization: the Delassus matrix is built from the block-diagonal M_nu, whose
inverse is exact (1/m and R J^-1 R^T), and never from the Euler-chart M(q), which becomes
ill-conditioned near gimbal lock. The multipliers are the same; the acceleration of eq. 9 is then
mapped to the chart, qdd = T^-1 (nudot - Tdot qd).

One path: the rows G, b, h come from a :class:`~teleop.dynamics.rows.RowStack` (built-in rows
compiled, a user's constraint through its Python methods), and every solve is a compiled kernel of
:mod:`teleop.dynamics.kernels.motion` that takes those rows as inputs. :func:`evaluate_literal` is
the textbook chart-coordinate form of eqs. 8-9, kept only as an independent reference for tests.
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
from teleop.dynamics.constraints import stack_bias, stack_jacobian
from teleop.dynamics.effects import effect_params, total_wrench
from teleop.dynamics.kernels import motion as K
from teleop.dynamics.kernels import steps as S
from teleop.dynamics.multipliers import RANK_RTOL, ConstrainedAcceleration, compute_constrained_acceleration
from teleop.dynamics.rotations import EulerChart
from teleop.dynamics.rows import RowStack


def _wrench6(F) -> np.ndarray:
    """F as a writable float64 (6,) array (the kernels index it unchecked); ValueError otherwise.
    (A read-only array is another numba type and would compile the kernel a second time.)"""
    if type(F) is not np.ndarray or F.dtype != np.float64 or not F.flags.c_contiguous or not F.flags.writeable:
        F = np.array(F, dtype=float)
    if F.shape != (6,):
        raise ValueError(f"operator wrench: expected 6 values, got shape {F.shape}")
    return F


class PoseTerms:
    """Chart terms at (chart, q): p (3,) m, R (3, 3), E_B, E_B^-1, dE (see
    :func:`kernels.motion.rate_map_terms`) and E_W = R E_B (3, 3).

    ``terms`` holds (R, E_B, E_B^-1, dE, E_W) as the kernel gave them, a tuple or a (5, 3, 3) array
    (a fused step's); the rate maps are read from it on demand (unpacking a 3-d array into five
    views costs about 1.5 us, more than a fused step reads of them). ``chart`` and ``q`` are the
    objects they were computed for (the cache's key)."""

    __slots__ = ("R", "chart", "p", "q", "terms")

    def __init__(self, chart, q, terms):
        self.chart, self.q, self.p, self.terms, self.R = chart, q, q[:3], terms, terms[0]

    @property
    def E_B(self) -> np.ndarray:
        return self.terms[1]

    @property
    def E_inv(self) -> np.ndarray:
        return self.terms[2]

    @property
    def dE(self) -> np.ndarray:
        return self.terms[3]

    @property
    def E_W(self) -> np.ndarray:
        return self.terms[4]


class Evaluation:
    """One evaluation at (q, qd): qdd (6,) chart accel., nudot (6,) world (vdot, wdot), lam (m,)
    (N, N*m), rank of the Delassus matrix, the applied wrench (6,), the constraint wrench
    G^T lam (6,) (N, N*m, world, at the body origin) and the pose terms (None in twist form).

    ``end``: None, or (a fused step's) the checks and twist at the end of the step
    that started with this evaluation, (9,): :func:`kernels.steps.end_checks`'s (total, v2, w2),
    then the world twist nu (6,: m/s, rad/s)."""

    __slots__ = ("constraint_wrench_W", "end", "lam", "nudot", "pose", "qdd", "rank", "wrench_W")

    def __init__(self, qdd, nudot, lam, rank, wrench_W, constraint_wrench_W, pose, end=None):
        self.qdd, self.nudot, self.lam, self.rank = qdd, nudot, lam, rank
        self.wrench_W, self.constraint_wrench_W, self.pose, self.end = wrench_W, constraint_wrench_W, pose, end


class PackedEvaluation(Evaluation):
    """An :class:`Evaluation` packed by a fused kernel, out[o:o + 25 + m] = (qdd, nudot, total
    wrench, G^T lam, lam, rank) (see :func:`kernels.steps.evaluate_at`), read on demand as views
    into out (a slice costs about 0.2 us; a step reads some of them, a tick not all)."""

    __slots__ = ("_m", "_o", "_out")

    def __init__(self, out, o, m, pose, end=None):
        self._out, self._o, self._m, self.pose, self.end = out, o, m, pose, end

    @property
    def qdd(self):
        return self._out[self._o:self._o + 6]

    @property
    def nudot(self):
        return self._out[self._o + 6:self._o + 12]

    @property
    def wrench_W(self):
        return self._out[self._o + 12:self._o + 18]

    @property
    def constraint_wrench_W(self):
        return self._out[self._o + 18:self._o + 24]

    @property
    def lam(self):
        return self._out[self._o + 24:self._o + 24 + self._m]

    @property
    def rank(self):
        return int(self._out[self._o + 24 + self._m])


class ConstrainedBody:
    """Body + constraints + effects. ``coriolis=False`` drops the gyroscopic torque w x I_W w.

    ``rows`` is the :class:`RowStack` of the constraints; dampers and gravity are applied inside
    the kernels, any other effect in Python before them.
    """

    def __init__(self, body: RigidBody, constraints=(), effects=(), coriolis: bool = True):
        self.body = body
        self.rows = RowStack(constraints)
        self.constraints = self.rows.constraints
        self.effects = tuple(effects)
        self.coriolis = bool(coriolis)
        self.m = self.rows.m
        self.holonomic_mask = self.rows.holonomic_mask
        self.holonomic = tuple(c for c in self.constraints if c.holonomic)
        self.nonholonomic = tuple(c for c in self.constraints if not c.holonomic)
        self._hol_rows = RowStack(self.holonomic)
        self._cache: PoseTerms | None = None
        self._inv_m = 1.0 / body.mass_kg
        self._fx, self._py_effects = effect_params(self.effects)
        self._zero6 = np.zeros(6)
        self._conservative_py = tuple(e for e in self._py_effects if e.conservative)
        self._working_py = tuple(e for e in self._py_effects if not e.conservative)
        #: True when an effect takes energy out or puts it in (a damper, a non-conservative effect)
        self.dissipative = bool(self._fx[0] or self._fx[1] or self._working_py)
        #: True when every row and effect is compiled: a step can then be one fused kernel call
        #: (:mod:`teleop.dynamics.kernels.steps`); False takes the split path, kernel by kernel
        self.fused = not self.rows.python_rows and not self._py_effects
        self._body_pack = S.body_pack(body.J, body.J_inv, body.mass_kg, self.coriolis, RANK_RTOL, self._fx)

    # -- pose-only terms --------------------------------------------------------------------------
    def pose_terms(self, chart: EulerChart, q: np.ndarray) -> PoseTerms:
        """The chart terms at q (6,), cached for the last pose asked for.

        The key is the chart object and the q array object themselves (not their ids, not q's
        values): the engine replaces its state arrays and never writes into them, so the same
        object holds the same pose. (An equal q in another array is computed again, to the same
        values.) Do not write into an array after asking for its pose terms."""
        c = self._cache
        if c is not None and c.q is q and c.chart is chart:
            return c
        pt = self._cache = PoseTerms(chart, q, K.rate_map_terms(chart.R0, chart.axes_array, q[3:]))
        return pt

    def keep_pose_terms(self, chart: EulerChart, q: np.ndarray, mats: np.ndarray) -> PoseTerms:
        """Cache the pose terms mats (5, 3, 3) (R, E_B, E_B^-1, dE, E_W) a fused kernel computed at q."""
        pt = self._cache = PoseTerms(chart, q, mats)
        return pt

    def fused_args(self, chart: EulerChart) -> tuple:
        """The leading arguments of every kernel of :mod:`teleop.dynamics.kernels.steps` (a
        fused model only): the chart, the compiled rows and the body's constants."""
        rows = self.rows
        return chart.R0, chart.axes_array, rows.table, rows.params, self.m, self._body_pack

    def twist(self, pt: PoseTerms, qd: np.ndarray) -> np.ndarray:
        """nu = T qd = (v, R E_B thetadot) (6,)."""
        nu = np.empty(6)
        nu[:3] = qd[:3]
        nu[3:] = pt.E_W @ qd[3:]
        return nu

    def rates(self, pt: PoseTerms, nu: np.ndarray) -> np.ndarray:
        """qd = T^-1 nu (6,)."""
        qd = np.empty(6)
        qd[:3] = nu[:3]
        qd[3:] = pt.E_inv @ (pt.R.T @ nu[3:])
        return qd

    def operator_wrench(self, operator_W) -> np.ndarray:
        """The operator wrench as the kernels take it: a float64 (6,) array, zeros for None."""
        return self._zero6 if operator_W is None else _wrench6(operator_W)

    def _wrench(self, p, R, v, w, t, operator_W) -> np.ndarray:
        F = self.operator_wrench(operator_W)
        if self._py_effects:  # otherwise F goes to the kernel as it is, uncopied
            F = total_wrench(self._py_effects, p, R, v, w, t, F)
        return F

    # -- eqs. 8-9 ------------------------------------------------------------------------------------
    def evaluate(self, chart: EulerChart, q, qd, t: float, operator_W=None, stabilize=None) -> Evaluation:
        """Eqs. 8-9 at (q, qd). ``stabilize=(alpha, beta)`` adds Baumgarte terms 2a G nu + b^2 h."""
        if self.fused and stabilize is None:
            return self._evaluate_fused(chart, q, qd, operator_W)
        pt = self.pose_terms(chart, q)
        v, w = qd[:3], pt.E_W @ qd[3:]
        G, b, h = self.rows.evaluate(pt.p, pt.R, v, w)
        if stabilize is not None:
            alpha, beta = stabilize
            b = b + 2.0 * alpha * (G[:, :3] @ v + G[:, 3:] @ w) + beta * beta * h
        F = self._wrench(pt.p, pt.R, v, w, t, operator_W)
        qdd, nudot, lam, rank, F, Gtl = K.evaluate(
            pt.R, pt.E_B, pt.E_inv, pt.dE, self.body.J, self.body.J_inv, self._inv_m, self.coriolis,
            G, b, qd, F, self._fx, RANK_RTOL)
        return Evaluation(qdd, nudot, lam, rank, F, Gtl, pt)

    def _evaluate_fused(self, chart, q, qd, operator_W) -> Evaluation:
        """:meth:`evaluate` in one kernel call (:func:`kernels.steps.evaluate_at`)."""
        F = self.operator_wrench(operator_W)
        out, mats = S.evaluate_at(*self.fused_args(chart), q, qd, F)
        return self.evaluation(out, self.keep_pose_terms(chart, q, mats))

    def evaluation(self, out: np.ndarray, pose: PoseTerms | None, end=None, o: int = 0) -> Evaluation:
        """The :class:`Evaluation` packed by a fused kernel in out[o:o + 25 + m] (see
        :func:`kernels.steps.evaluate_at`), views into it (:class:`PackedEvaluation`); ``end`` its
        :attr:`Evaluation.end`."""
        return PackedEvaluation(out, o, self.m, pose, end)

    def project_rates(self, pt: PoseTerms, qd: np.ndarray) -> np.ndarray:
        """The admissible rates closest to qd (6,) in kinetic energy, at the pose of ``pt``."""
        if not self.m:
            return qd
        G = self.rows.evaluate(pt.p, pt.R)[0]
        return K.project_rates(pt.R, pt.E_B, pt.E_inv, self.body.J_inv, self._inv_m, G, qd, RANK_RTOL)

    def project_parameter_rates(self, pt: PoseTerms, qd, P, Pinv):
        """(zd, qd): :meth:`project_rates` through a parametrization's Jacobian P (6, k), P^+."""
        G = self.rows.evaluate(pt.p, pt.R)[0]
        return K.project_parameter_rates(pt.R, pt.E_B, pt.E_inv, self.body.J_inv, self._inv_m, G, qd,
                                         P, Pinv, RANK_RTOL)

    def correction(self, p, R, holonomic_only: bool = False) -> tuple[np.ndarray, float]:
        """(d (6,), max |h|): the twist of least kinetic energy with G d = h at pose (p, R) (a
        Newton step of the position projection is the pose moved by -d), and the largest
        holonomic residual (m or rad). ``holonomic_only`` leaves the nonholonomic rows out of G."""
        rows = self._hol_rows if holonomic_only else self.rows
        G, _, h = rows.evaluate(p, R)
        d, _, _ = K.solve_rows(R, self.body.J_inv, self._inv_m, G, h, RANK_RTOL)
        return d, float(np.abs(h).max()) if h.size else 0.0

    def constraint_acceleration(self, R, constraint_wrench_W) -> np.ndarray:
        """M_nu^-1 G^T lam (6,): the twist acceleration (world) the constraint wrench G^T lam
        (6,: N, N*m) gives the body at attitude R."""
        return K.constraint_acceleration(R, self.body.J_inv, self._inv_m, constraint_wrench_W)

    # -- energy -------------------------------------------------------------------------------------
    def potential_energy(self, p, R) -> float:
        """Potential energy (J) of the conservative effects (gravity, springs) at pose (p, R)."""
        V = K.gravity_potential(self._fx, p)
        for e in self._conservative_py:
            V += e.potential_energy(p, R)
        return V

    def working_wrench(self, pt: PoseTerms, qd, t: float, operator_W=None) -> np.ndarray:
        """The operator wrench plus the non-conservative Python effects' (6,) at (pose, rates):
        the forces whose power is work done on the tool (besides the compiled dampers)."""
        F = self.operator_wrench(operator_W)
        if self._working_py:
            F = total_wrench(self._working_py, pt.p, pt.R, qd[:3], pt.E_W @ qd[3:], t, F)
        return F

    def energy_rates(self, pt: PoseTerms, qd, t: float, operator_W=None) -> tuple[float, float, float]:
        """(K J, a W, b W) at chart rates qd (see :func:`kernels.motion.energy_rates`): the kinetic
        energy, the power of the operator wrench plus the non-conservative Python effects, and the
        dampers' dissipation. The power of all non-conservative forces is a - b."""
        F = self.working_wrench(pt, qd, t, operator_W)
        return K.energy_rates(pt.R, pt.E_W, self.body.J, self.body.mass_kg, qd, F, self._fx)

    def energy(self, chart: EulerChart, q, qd) -> float:
        """Kinetic plus potential energy (J) at (q, qd)."""
        pt = self.pose_terms(chart, q)
        return self.energy_rates(pt, qd, 0.0)[0] + self.potential_energy(pt.p, pt.R)

    # -- Lie group: no chart ----------------------------------------------------------------------
    def evaluate_twist(self, p, R, v, w, t: float, operator_W=None) -> Evaluation:
        """Newton-Euler with constraints at pose (p, R), twist (v, w): no Euler chart involved."""
        G, b, _ = self.rows.evaluate(p, R, v, w)
        F = self._wrench(p, R, v, w, t, operator_W)
        nudot, lam, rank, F, Gtl = K.newton_euler(R, self.body.J, self.body.J_inv, self._inv_m, self.coriolis,
                                                  G, b, v, w, F, self._fx, RANK_RTOL)
        return Evaluation(nudot, nudot, lam, rank, F, Gtl, None)

    def project_twist_at(self, p, R, nu: np.ndarray) -> np.ndarray:
        """The admissible twist closest to nu (6,) in kinetic energy at pose (p, R)."""
        if not self.m:
            return nu
        G = self.rows.evaluate(p, R)[0]
        return K.project_twist(R, self.body.J_inv, self._inv_m, G, nu, RANK_RTOL)


def evaluate_literal(model: ConstrainedBody, chart: EulerChart, q, qd, t: float,
                     operator_W=None) -> ConstrainedAcceleration:
    """Eqs. 8-9 exactly as printed, in chart coordinates: M(q), C(q,qd)qd, A(q), Adot qd.

    Not a production path: an independent formulation (chart-coordinate inertia, Coriolis vector
    and constraint matrix, scipy's Cholesky of M) that the tests hold the engine against; also
    what a reader of the paper expects to see.
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
