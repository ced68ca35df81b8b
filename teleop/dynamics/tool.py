"""The reference tool: the paper's physics simulation (§II) behind one ``step()``.

``ReferenceTool`` owns a :class:`ConstrainedBody`, an integrator and the state. ``step`` never
raises: a singular or non-finite evaluation holds the last valid pose, zeroes the velocity (the safe
state for an admittance display) and reports a status other than ``"ok"``.
"""

from __future__ import annotations

import math

import numpy as np

from teleop.dynamics.body import Kinematics, RigidBody
from teleop.dynamics.fixtures import Fixture
from teleop.dynamics.integrators import (
    Integrator,
    Parametric,
    ToolState,
    make_integrator,
    project_position,
    project_velocity,
)
from teleop.dynamics.kernels.steps import end_checks
from teleop.dynamics.model import ConstrainedBody
from teleop.dynamics.rotations import EulerChart, chart_conditioning, rechart
from teleop.util.errors import ConfigError, TeleopError

#: Re-chart when the Euler chart's conditioning (|sin| or |cos| of the middle angle) drops below this.
RECHART_BELOW = 0.25

STATUS_OK = "ok"
STATUS_NAN = "nan"
STATUS_SINGULAR = "singular"
STATUS_DIVERGED = "diverged"


class ReferenceTool:
    """A rigid tool under a fixture's constraints and a scene's effects.

    ``integrator``: a name from :data:`teleop.dynamics.integrators.INTEGRATORS` or an instance.
    ``chart``: the Euler chart of the coordinates; defaults to the fixture parametrization's chart.
    ``max_speed_m_s``, ``max_rate_rad_s``: a step that ends faster than this has diverged (an
    unstable stiffness for the period); the tool then holds its last pose, status "diverged".
    """

    def __init__(
        self,
        body: RigidBody,
        fixture: Fixture,
        effects=(),
        integrator: str | Integrator = "energy",
        coriolis: bool = True,
        chart: EulerChart | None = None,
        max_speed_m_s: float = 100.0,
        max_rate_rad_s: float = 1e4,
    ):
        self.body = body
        self.fixture = fixture
        self.model = ConstrainedBody(body, fixture.constraints, effects, coriolis=coriolis)
        self.integrator = make_integrator(integrator) if isinstance(integrator, str) else integrator
        param = fixture.parametrization
        if chart is None:
            chart = fixture.initial_chart()
        self._rechartable = param is None or param.rechartable or not isinstance(
            self.integrator, Parametric
        )
        self.state = ToolState(chart, np.zeros(6), np.zeros(6))
        self.status = STATUS_OK
        #: the last ok step's evaluation, read by :attr:`lam`, :attr:`rank`, :attr:`wrench_W`,
        #: :attr:`acceleration_W`, :attr:`constraint_wrench_W` (views, on demand); None: the values
        #: held in ``_held`` (before any step, after a safe state)
        self._ev = None
        self._held = (np.zeros(self.model.m), self.model.m, np.zeros(6), np.zeros(6), np.zeros(6))
        self.recharts = 0
        #: the wrench (6,) the last step applied (operator and feedback; None: none), for energy audits
        self.applied_W = None
        if not (max_speed_m_s > 0 and max_rate_rad_s > 0):
            raise ConfigError("max_speed_m_s and max_rate_rad_s must be positive")
        self._max_v2, self._max_w2 = max_speed_m_s**2, max_rate_rad_s**2
        #: the fastest the tool may move (m/s, rad/s): a step past it has diverged (a real master's limit)
        self.max_speed_m_s, self.max_rate_rad_s = float(max_speed_m_s), float(max_rate_rad_s)
        #: (qd, q, chart, end) of the last fused step: ``end`` (9,) holds the world twist
        #: at that state in [3:9] (:attr:`~teleop.dynamics.model.Evaluation.end`); None: no such step
        self._end = None

    # -- set-up -------------------------------------------------------------------------------------
    def reset(self, q0=None, qd0=None, t0: float = 0.0) -> None:
        """Place the tool at q0 (6,) with rates qd0 (6,), projected onto the constraints."""
        q0 = np.zeros(6) if q0 is None else np.array(q0, dtype=float).reshape(-1)
        qd0 = np.zeros(6) if qd0 is None else np.array(qd0, dtype=float).reshape(-1)
        if q0.shape != (6,) or qd0.shape != (6,) or not (np.all(np.isfinite(q0)) and np.all(np.isfinite(qd0))):
            raise ConfigError("initial state: expected finite q0 and qd0 of 6 values each")
        self.state.q, self.state.qd, self.state.t = q0, qd0, float(t0)
        self.status = STATUS_OK
        project_position(self.model, self.state)
        project_velocity(self.model, self.state)
        self.integrator.reset(self.model, self.state, self.fixture.parametrization)
        if isinstance(self.integrator, Parametric):
            self.integrator.sync(self.state)

    # -- one step -----------------------------------------------------------------------------------
    def step(self, h: float, operator_W=None) -> str:
        """Advance by h s under the operator wrench (6,: N, N*m, world, at the body origin).

        Returns the status. Never raises: an input that is not 6 finite numbers is dropped (status
        "nan"); on a singular or non-finite step the tool holds its last valid pose with zero
        velocity (the safe state of an admittance display).
        """
        s = self.state
        saved = (s.chart, s.q, s.qd, s.t, s.z, s.zd)  # integrators replace arrays, never mutate them
        bad_input = False
        if operator_W is not None:  # 6 finite floats, or dropped: the kernels index it unchecked
            try:
                operator_W = np.asarray(operator_W, dtype=float)
                bad_input = operator_W.shape != (6,) or not math.isfinite(sum(operator_W.tolist()))
            except (TypeError, ValueError):
                bad_input = True
        if bad_input:
            operator_W = None  # a non-finite or misshapen input never reaches the math
        try:
            ev = self.integrator.step(self.model, s, h, operator_W)
            end = ev.end  # a fused step computed the checks in its kernel
            total, v2, w2 = end_checks(s.q, s.qd, ev.lam, ev.nudot) if end is None else end[:3].tolist()
            ok = math.isfinite(total)  # finite only if every term of the sum is
        except (TeleopError, FloatingPointError, np.linalg.LinAlgError, ValueError):
            ok, ev = False, None
        if not ok:
            self._safe_state(saved)
            return self.status
        # Euler rates bound the body rate only up to the chart's conditioning: check w itself
        if v2 > self._max_v2 or (w2 > self._max_w2 and float(np.dot(*(2 * [self.kinematics().w]))) > self._max_w2):
            self._safe_state(saved)
            self.status = STATUS_DIVERGED
            return self.status
        s.t += h
        self.applied_W = operator_W
        self._ev = ev
        self._end = None if end is None else (s.qd, s.q, s.chart, end)
        if self._rechartable:
            self._maybe_rechart()
        self.status = STATUS_NAN if bad_input else STATUS_OK
        return self.status

    def _safe_state(self, saved) -> None:
        s = self.state
        s.chart, s.q, s.qd, s.t, s.z, s.zd = saved
        s.qd = np.zeros(6)
        if not math.isfinite(float(s.q.sum())):  # pragma: no cover - saved states are finite
            s.q = np.zeros(6)
        if s.zd is not None:
            s.zd = np.zeros_like(s.zd)
        self.integrator.reset(self.model, s, self.fixture.parametrization)
        self.status = STATUS_SINGULAR
        rank, wrench = self.rank, self.wrench_W  # kept from the last ok step
        self._ev = None
        self._held = (np.zeros(self.model.m), rank, wrench, np.zeros(6), np.zeros(6))

    @property
    def lam(self) -> np.ndarray:
        """The multipliers (m,: N, N*m) of the last step (zeros after a safe state)."""
        ev = self._ev
        return self._held[0] if ev is None else ev.lam

    @property
    def rank(self) -> int:
        """The Delassus matrix's numerical rank at the last ok step."""
        ev = self._ev
        return self._held[1] if ev is None else ev.rank

    @property
    def wrench_W(self) -> np.ndarray:
        """The applied wrench (6,: N, N*m, world, at the body origin) of the last ok step."""
        ev = self._ev
        return self._held[2] if ev is None else ev.wrench_W

    @property
    def acceleration_W(self) -> np.ndarray:
        """(vdot m/s^2, wdot rad/s^2) (6,), world, of the last step (zeros after a safe state):
        eq. 19's feedforward."""
        ev = self._ev
        return self._held[3] if ev is None else ev.nudot

    @property
    def constraint_wrench_W(self) -> np.ndarray:
        """G^T lam (6,): the wrench (N, N*m, world, at the body origin) the constraints applied
        over the last step, the force the master renders."""
        ev = self._ev
        return self._held[4] if ev is None else ev.constraint_wrench_W

    def _maybe_rechart(self) -> None:
        s = self.state
        if chart_conditioning(s.chart, s.q[3:]) >= RECHART_BELOW:
            return
        s.chart, theta, thetad = rechart(s.chart, s.q[3:], s.qd[3:])
        s.q = np.concatenate([s.q[:3], theta])
        s.qd = np.concatenate([s.qd[:3], thetad])
        self.recharts += 1
        if isinstance(self.integrator, Parametric):
            self.integrator.reset(self.model, s, self.fixture.parametrization)
            self.integrator.sync(s)

    def hold(self) -> None:
        """Stop the tool where it is (zero velocity; the pose and time unchanged): a side's safe
        state. The next step starts from rest: the parametric integrator's own rates ``zd`` are
        zeroed too (the step integrates them, not ``qd``)."""
        self.state.qd = np.zeros(6)
        if self.state.zd is not None:
            self.state.zd = np.zeros_like(self.state.zd)

    def scale_velocity(self, sigma: float) -> None:
        """Scale the tool's velocity by ``sigma`` in [0, 1] (the pose and time unchanged): the
        passivity guard's action on the rendered motion (:meth:`teleop.tick.guard.MasterGuard.
        motion_scale`). The constraint rows are homogeneous in the velocity, so the scaled
        velocity satisfies them as the step's did; the kinetic energy only falls."""
        if not 0.0 <= sigma <= 1.0:
            raise ValueError(f"scale_velocity: sigma must be in [0, 1], got {sigma!r}")
        self.state.qd = self.state.qd * sigma
        if self.state.zd is not None:
            self.state.zd = self.state.zd * sigma

    # -- read-outs ----------------------------------------------------------------------------------
    @property
    def q(self) -> np.ndarray:
        return self.state.q

    @property
    def qd(self) -> np.ndarray:
        return self.state.qd

    @property
    def t(self) -> float:
        return self.state.t

    def kinematics(self) -> Kinematics:
        return Kinematics(self.state.chart, self.state.q, self.state.qd)

    def pose(self):
        """(p (3,) m, R_WB (3, 3)) of the body frame. Read from the pose cache the step filled."""
        pt = self.model.pose_terms(self.state.chart, self.state.q)
        return pt.p.copy(), pt.R

    def twist(self):
        """(v (3,) m/s, w (3,) rad/s), world frame: the fused step's (the same product), while its
        state stands (a re-chart, the safe state or a reset replace the arrays)."""
        s, e = self.state, self._end
        if e is not None and e[0] is s.qd and e[1] is s.q and e[2] is s.chart:
            return e[3][3:6].copy(), e[3][6:9].copy()
        pt = self.model.pose_terms(s.chart, s.q)
        return s.qd[:3].copy(), pt.E_W @ s.qd[3:]

    def residual(self) -> np.ndarray:
        """Holonomic residuals (m or rad) at the current pose."""
        p, R = self.pose()
        return self.model.rows.evaluate(p, R)[2][self.model.holonomic_mask]

    def energy(self) -> float:
        """Kinetic plus potential energy of the conservative effects (J)."""
        return self.model.energy(self.state.chart, self.state.q, self.state.qd)
