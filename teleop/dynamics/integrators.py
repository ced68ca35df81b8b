"""Integrators of the constrained reference tool, selectable by name.

* ``parametric``   the paper's method (eqs. 10-11): integrate z on q = psi(z) (semi-implicit), then
                   project zd onto the nonholonomic rows in the kinetic-energy metric.
* ``energy``       a RATTLE-type split of the parametric step (the constraint impulse half at each
                   end), then the rates scaled so that the energy changes by the work done over
                   the step: keeps the energy of an undamped tool (:class:`EnergyConsistent`).
* ``explicit_euler`` plain explicit Euler on (q, qd): drifts off the manifold; for comparison.
* ``baumgarte``    semi-implicit Euler with Baumgarte stabilization of the constraint rows.
* ``projection``   semi-implicit Euler, then Newton projection of q on h = 0 and of qd on A qd = 0
                   (half the start's constraint impulse taken back first: RATTLE's split).
* ``rk4``          classic RK4 on (q, qd), then the same projections.
* ``lie_group``    semi-implicit Euler on SE(3): R <- exp(h w) R with Pinocchio's exp3, then
                   projection by retraction (the twist's as ``projection``'s). No Euler chart.

Every integrator advances a :class:`ToolState` in place and returns the :class:`Evaluation` (or
twist evaluation) at the start of the step, whose multipliers are the step's constraint forces.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from teleop.dynamics.body import Kinematics
from teleop.dynamics.kernels.motion import energy_scale, flat_advance, left_pinv, split_end, split_twist
from teleop.dynamics.kernels.steps import flat_parametric_step, flat_split_step
from teleop.dynamics.model import ConstrainedBody
from teleop.dynamics.multipliers import RANK_RTOL
from teleop.dynamics.rotations import EulerChart, chart_conditioning, euler_from_rotation, rechart
from teleop.util.errors import ConfigError

#: Newton projection: stop when the holonomic residual norm is below this (m or rad).
PROJECTION_TOL = 1e-13
PROJECTION_ITERS = 6


@dataclass
class ToolState:
    """Mutable state of the reference tool: chart, q (6,), qd (6,), time t (s), and z, zd for the
    parametric integrator (None otherwise)."""

    chart: EulerChart
    q: np.ndarray
    qd: np.ndarray
    t: float = 0.0
    z: np.ndarray | None = None
    zd: np.ndarray | None = None


class Integrator(ABC):
    name: str = "integrator"

    def reset(self, model: ConstrainedBody, state: ToolState, parametrization) -> None:  # noqa: B027 - optional hook
        """Prepare integrator-specific state (z for parametric, the pose for Lie group)."""

    @abstractmethod
    def step(self, model: ConstrainedBody, state: ToolState, h: float, operator_W):
        """Advance ``state`` by h seconds under the operator wrench (6,) held over the step."""


# -- projections ------------------------------------------------------------------------------------
def project_position(model: ConstrainedBody, state: ToolState) -> None:
    """Newton iterations on h(q) = 0: the M-weighted minimum-norm twist correction, mapped to q."""
    if not model.holonomic:
        return
    for _ in range(PROJECTION_ITERS):
        pt = model.pose_terms(state.chart, state.q)
        d, err = model.correction(pt.p, pt.R)
        if err < PROJECTION_TOL:
            return
        state.q = state.q - model.rates(pt, d)


def project_velocity(model: ConstrainedBody, state: ToolState) -> None:
    """qd <- the admissible rates closest to qd in kinetic energy (all constraint rows)."""
    if not model.m:
        return
    state.qd = model.project_rates(model.pose_terms(state.chart, state.q), state.qd)


# -- integrators ------------------------------------------------------------------------------------
class ExplicitEuler(Integrator):
    name = "explicit_euler"

    def step(self, model, state, h, operator_W):
        ev = model.evaluate(state.chart, state.q, state.qd, state.t, operator_W)
        state.q = state.q + h * state.qd
        state.qd = state.qd + h * ev.qdd
        return ev


class Baumgarte(Integrator):
    """Semi-implicit Euler with constraint stabilization at natural frequency ``omega`` (rad/s),
    critically damped: alpha = omega, beta = omega. Defaults to omega = 0.2 / h."""

    name = "baumgarte"

    def __init__(self, omega_rad_s: float | None = None):
        self.omega = omega_rad_s

    def step(self, model, state, h, operator_W):
        w = self.omega if self.omega is not None else 0.2 / h
        ev = model.evaluate(state.chart, state.q, state.qd, state.t, operator_W, stabilize=(w, w))
        state.qd = state.qd + h * ev.qdd
        state.q = state.q + h * state.qd
        return ev


class Projection(Integrator):
    """Semi-implicit Euler, the Newton projection of q, then the projection of the rates after half
    the start's constraint impulse is taken back out: the projection at the end supplies the
    other half, as in RATTLE. (Applying the whole impulse at the start and projecting gains kinetic
    energy at first order; on an undamped sphere slide that grows until the speed bound stops
    the tool, status "diverged".)"""

    name = "projection"

    def step(self, model, state, h, operator_W):
        ev = model.evaluate(state.chart, state.q, state.qd, state.t, operator_W)
        state.qd = state.qd + h * ev.qdd
        state.q = state.q + h * state.qd
        project_position(model, state)
        if model.m:
            half = model.rates(ev.pose, model.constraint_acceleration(ev.pose.R, ev.constraint_wrench_W))
            state.qd = state.qd - (0.5 * h) * half
        project_velocity(model, state)
        return ev


class RK4(Integrator):
    name = "rk4"

    def step(self, model, state, h, operator_W):
        q0, v0, t0, ch = state.q, state.qd, state.t, state.chart
        ev = model.evaluate(ch, q0, v0, t0, operator_W)
        k1q, k1v = v0, ev.qdd
        q2, v2 = q0 + 0.5 * h * k1q, v0 + 0.5 * h * k1v
        k2v = model.evaluate(ch, q2, v2, t0 + 0.5 * h, operator_W).qdd
        q3, v3 = q0 + 0.5 * h * v2, v0 + 0.5 * h * k2v
        k3v = model.evaluate(ch, q3, v3, t0 + 0.5 * h, operator_W).qdd
        q4, v4 = q0 + h * v3, v0 + h * k3v
        k4v = model.evaluate(ch, q4, v4, t0 + h, operator_W).qdd
        state.q = q0 + (h / 6.0) * (k1q + 2.0 * v2 + 2.0 * v3 + v4)
        state.qd = v0 + (h / 6.0) * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
        project_position(model, state)
        project_velocity(model, state)
        return ev


class Parametric(Integrator):
    """Eqs. 10-11: zdd = Psi^+ (qdd - zd^T psi_zz zd); semi-implicit Euler on z; q = psi(z); then zd
    is projected onto the nonholonomic rows in the kinetic-energy metric (the holonomic rows hold
    by construction). The pose work of that projection is reused by the next step's evaluation."""

    name = "parametric"

    def reset(self, model, state, parametrization):
        if parametrization is None:
            names = ", ".join(c.name for c in model.holonomic) or "none"
            raise ConfigError(
                f"integrator 'parametric' needs a parametrization of the holonomic constraints "
                f"({names}); this fixture has none. Choose 'projection', 'rk4' or 'lie_group'."
            )
        self.param = parametrization
        self._pinv = None
        self._last = None
        if parametrization.flat and not parametrization.constant_jacobian:
            raise ConfigError("a flat (affine) parametrization must declare constant_jacobian")
        if parametrization.constant_jacobian:
            self._P = parametrization.jacobian(state.chart, None)
            self._pinv = np.linalg.pinv(self._P)
        if parametrization.flat:  # psi(z) = psi(0) + P z
            self._q0 = parametrization.psi(state.chart, np.zeros(parametrization.dim))
        #: one kernel call per step (kernels.steps) where psi is affine and the model all compiled
        self._fused = bool(parametrization.flat and model.fused)
        self._nonholonomic = bool(model.nonholonomic)
        self._args = None  # (chart, the fused kernels' leading arguments for it)
        state.z, state.zd = parametrization.from_q(state.chart, state.q, state.qd)

    def _jac(self, chart, z):
        """(Psi, Psi^+) at z; the last one is kept, since each step asks for it twice."""
        if self._pinv is not None:
            return self._P, self._pinv
        key = z.tobytes()
        c = self._last
        if c is not None and c[0] is chart and c[1] == key:
            return c[2], c[3]
        P = self.param.jacobian(chart, z)
        Pinv = left_pinv(P)  # the pseudo-inverse of eq. 11
        self._last = (chart, key, P, Pinv)
        return P, Pinv

    def sync(self, state: ToolState) -> None:
        """q, qd from z, zd (after a step or a re-chart)."""
        P, _ = self._jac(state.chart, state.z)
        state.q = self.param.psi(state.chart, state.z)
        state.qd = P @ state.zd

    def step(self, model, state, h, operator_W):
        if self._fused:
            return self._fused_step(model, state, h, operator_W)
        param, chart = self.param, state.chart
        ev = model.evaluate(chart, state.q, state.qd, state.t, operator_W)
        if param.flat:
            return self._flat_step(model, state, h, ev)
        _, Pinv = self._jac(chart, state.z)
        zdd = Pinv @ (ev.qdd - param.curvature(chart, state.z, state.zd))
        state.zd = state.zd + h * zdd
        state.z = state.z + h * state.zd
        P, Pinv = self._jac(chart, state.z)
        state.q = param.psi(chart, state.z)
        state.qd = P @ state.zd
        if model.nonholonomic:
            qd = model.project_rates(model.pose_terms(chart, state.q), state.qd)
            state.zd = Pinv @ qd
            state.qd = P @ state.zd
        return ev


    def _flat_step(self, model, state, h, ev):
        """:meth:`step` after the evaluation, for an affine psi (no curvature term): the advance
        and the projection each in one kernel call."""
        P, Pinv = self._P, self._pinv
        state.z, state.zd, state.q, state.qd = flat_advance(state.z, state.zd, ev.qdd, P, Pinv, self._q0, h)
        if model.nonholonomic:
            pt = model.pose_terms(state.chart, state.q)
            state.zd, state.qd = model.project_parameter_rates(pt, state.qd, P, Pinv)
        return ev

    def _fused_args(self, model, chart) -> tuple:
        """The fused kernels' arguments up to the state: :meth:`ConstrainedBody.fused_args`, then
        P, P^+ and psi(0); kept for the chart last asked for."""
        a = self._args
        if a is None or a[0] is not chart:
            a = self._args = (chart, (*model.fused_args(chart), self._P, self._pinv, self._q0))
        return a[1]

    def _unpack(self, model, state, out, mats):
        """The state and the start's evaluation from a fused kernel's (out, mats), as views; out
        ends with the step's end checks and twist (9,) (:attr:`Evaluation.end`)."""
        k = self._P.shape[1]
        o = 12 + 2 * k
        state.q, state.qd, state.z, state.zd = out[0:6], out[6:12], out[12:12 + k], out[12 + k:o]
        model.keep_pose_terms(state.chart, state.q, mats)
        return model.evaluation(out, None, out[-9:], o)

    def _fused_step(self, model, state, h, operator_W):
        """The flat step (:meth:`step`, :meth:`_flat_step`) in one call of
        :func:`kernels.steps.flat_parametric_step`."""
        out, mats = flat_parametric_step(*self._fused_args(model, state.chart), state.q, state.qd, state.z,
                                         state.zd, model.operator_wrench(operator_W), h, self._nonholonomic)
        return self._unpack(model, state, out, mats)


class EnergyConsistent(Parametric):
    """A RATTLE-type split of the parametric step, then an energy-consistent correction.

    The step (where the fixture has a parametrization; otherwise the ``projection`` step):

    1. half kick: zd_h = zd_0 + h/2 zdd_0 (eq. 11 with every force at the start, constraints too);
    2. drift on the manifold: z_1 = z_0 + h zd_h, q_1 = psi(z_1) (holonomic rows exact);
    3. velocity: nu* = nu_0 + h M^-1 F_0 + h/2 M^-1 G_0^T lam_0 (world twists: the applied forces
       over the step, the start's constraint impulse over its first half), projected in the
       kinetic-energy metric onto every row at q_1: the second half of the constraint impulse, as
       in RATTLE (velocity rows exact). Splitting the constraint impulse between the
       two ends cancels the first-order energy gain of the parametric step's one-sided impulse.

    Then the rates are scaled by the s that makes the energy change over the step equal the work
    of the non-conservative forces by the trapezoid rule,

        E(q1, s qd1) - E(q0, qd0) = h/2 (P0 + P1(s)),   P = F . nu - c_lin v.v - c_ang w.w,

    F the operator wrench held over the step plus the non-conservative effects, E kinetic plus
    potential energy (gravity, springs). Scaling keeps every row. With no force and no damper the
    energy is then constant to rounding; under forces it follows their work to second order. A
    correction beyond :attr:`MAX_SCALE` (the kinetic energy too small to carry the defect, e.g.
    at rest or a spring's turning point) is not made: the step's own energy is kept and the
    balance starts again from it (counted in ``corrections_skipped``)."""

    name = "energy"
    #: the largest relative change of the rates the correction makes (dimensionless)
    MAX_SCALE = 0.05

    def reset(self, model, state, parametrization):
        self._base = None if parametrization is not None else Projection()
        if self._base is None:
            super().reset(model, state, parametrization)
        self.E = model.energy(state.chart, state.q, state.qd)
        self.corrections_skipped = 0

    def sync(self, state: ToolState) -> None:
        if self._base is None:
            super().sync(state)

    def _split_step(self, model, state, h, operator_W):
        """Steps 1-3 of the class docstring, then the correction's terms at both ends.
        Returns the start's evaluation and (a0, b0, K, a, b) of :func:`kernels.motion.energy_rates`;
        the non-conservative wrench is held at the start's over the step. (A fused model does the
        whole step, the correction included, in :func:`kernels.steps.flat_split_step`.)"""
        param, chart = self.param, state.chart
        ev = model.evaluate(chart, state.q, state.qd, state.t, operator_W)
        pt0, body = ev.pose, model.body
        F = model.working_wrench(pt0, state.qd, state.t, operator_W)
        _, Pinv = self._jac(chart, state.z)
        zd_h = state.zd + (0.5 * h) * (Pinv @ (ev.qdd - param.curvature(chart, state.z, state.zd)))
        nu, a0, b0 = split_twist(pt0.R, pt0.E_W, body.J_inv, model._inv_m, state.qd, ev.nudot,
                                 ev.constraint_wrench_W, F, model._fx, h)
        state.z = state.z + h * zd_h
        P, Pinv = self._jac(chart, state.z)
        state.q = param.psi(chart, state.z)
        pt = model.pose_terms(chart, state.q)
        G = model.rows.evaluate(pt.p, pt.R)[0]
        state.zd, state.qd, K, a, b = split_end(pt.R, pt.E_W, pt.E_inv, body.J, body.J_inv, body.mass_kg, G, nu,
                                                P, Pinv, F, model._fx, RANK_RTOL)
        return ev, (a0, b0, K, a, b)

    def step(self, model, state, h, operator_W):
        if self._base is None and self._fused:
            out, mats = flat_split_step(*self._fused_args(model, state.chart), state.q, state.qd, state.z,
                                        state.zd, model.operator_wrench(operator_W), h, self.E, self.MAX_SCALE)
            ev = self._unpack(model, state, out, mats)
            self.E, applied = out[-11:-9].tolist()
            if not applied:
                self.corrections_skipped += 1
            return ev
        if self._base is None:
            ev, (a0, b0, K, a, b) = self._split_step(model, state, h, operator_W)
        else:
            _, a0, b0 = model.energy_rates(model.pose_terms(state.chart, state.q), state.qd, state.t, operator_W)
            ev = self._base.step(model, state, h, operator_W)
            K, a, b = model.energy_rates(model.pose_terms(state.chart, state.q), state.qd, state.t + h, operator_W)
        pt = model.pose_terms(state.chart, state.q)
        V = model.potential_energy(pt.p, pt.R)
        s, self.E, applied = energy_scale(self.E, K, a, b, a0, b0, V, h, self.MAX_SCALE)
        if applied:
            state.qd = s * state.qd
            if self._base is None:
                state.zd = s * state.zd
        else:
            self.corrections_skipped += 1
        return ev


class LieGroup(Integrator):
    """Semi-implicit Euler on SE(3) in twist space, then projection by retraction. The chart state
    (q, qd) is written back after every step for reporting only."""

    name = "lie_group"

    def reset(self, model, state, parametrization):
        self._exp3 = pin.exp3
        kin = Kinematics(state.chart, state.q, state.qd)
        self.p, self.R = kin.p.copy(), kin.R.copy()
        self.v, self.w = kin.v.copy(), kin.w.copy()

    def step(self, model, state, h, operator_W):
        ev = model.evaluate_twist(self.p, self.R, self.v, self.w, state.t, operator_W)
        half = model.constraint_acceleration(self.R, ev.constraint_wrench_W) if model.m else None
        self.v = self.v + h * ev.nudot[:3]
        self.w = self.w + h * ev.nudot[3:]
        self.p = self.p + h * self.v
        self.R = self._exp3(h * self.w) @ self.R
        self._project(model, half, h)
        self._write_chart(model, state)
        return ev

    def _project(self, model, half, h):
        """Pose onto h = 0 by retraction; the twist, less half the start's constraint impulse
        (``half`` (6,): its acceleration; the end's projection gives the other half, as in
        RATTLE), onto every row."""
        for _ in range(PROJECTION_ITERS if model.holonomic else 0):
            d, err = model.correction(self.p, self.R, holonomic_only=True)
            if err < PROJECTION_TOL:
                break
            self.p = self.p - d[:3]
            self.R = self._exp3(-d[3:]) @ self.R
        if model.m:
            nu = model.project_twist_at(self.p, self.R, np.concatenate([self.v, self.w]) - (0.5 * h) * half)
            self.v, self.w = nu[:3], nu[3:]

    def _write_chart(self, model, state):
        theta = euler_from_rotation(state.chart, self.R)
        if chart_conditioning(state.chart, theta) < 0.25:
            state.chart, theta, _ = rechart(state.chart, theta, np.zeros(3))
        state.q = np.concatenate([self.p, theta])
        pt = model.pose_terms(state.chart, state.q)
        state.qd = np.concatenate([self.v, pt.E_inv @ (self.R.T @ self.w)])


INTEGRATORS = {
    cls.name: cls for cls in (Parametric, EnergyConsistent, ExplicitEuler, Baumgarte, Projection, RK4, LieGroup)
}


def make_integrator(name: str) -> Integrator:
    """An integrator by name; an unknown name is an error listing the known ones."""
    try:
        return INTEGRATORS[name]()
    except KeyError:
        raise ConfigError(
            f"integrator {name!r} is unknown; choose one of: {', '.join(sorted(INTEGRATORS))}"
        ) from None
