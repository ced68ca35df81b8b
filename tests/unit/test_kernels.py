"""The compiled kernels against independent oracles (no second copy of themselves): the chart terms
against the axis-product rate map, eqs. 8-9 against their chart-coordinate textbook form
(``evaluate_literal``), the projections against a null-space least-squares solve, whole runs
against the textbook form step by step; over hypothesis-drawn charts, states and stacks,
duplicated rows (the eigen fallback) and a user's constraint class (the Python rows) included."""

from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import null_space

from teleop.dynamics import fixtures
from teleop.dynamics.body import RigidBody
from teleop.dynamics.constraints import Constraint
from teleop.dynamics.effects import AngularDamper, Gravity, LinearDamper, Spring
from teleop.dynamics.kernels import motion
from teleop.dynamics.model import ConstrainedBody, evaluate_literal
from teleop.dynamics.rotations import EulerChart, rate_map
from teleop.dynamics.tool import ReferenceTool
from teleop.scenario.build import build_tool
from teleop.scenario.operators import ScriptedWrench
from teleop.scenario.schema import load_scene


@dataclass(frozen=True, eq=False)
class _UserPlane(Constraint):
    """A constraint class the kernels do not know: z of the body origin fixed (a user's own)."""

    name: str = "user_plane"

    def jacobian(self, p, R):
        return np.array([[0.0, 0.0, 1.0, 0.0, 0.0, 0.0]])

    def bias(self, p, R, v, w):
        return np.zeros(1)

    def residual(self, p, R):
        return np.array([p[2]])


STACKS = {
    "free": lambda: fixtures.free().constraints,
    "rolling_disk": lambda: fixtures.rolling_disk(0.03, (0, 0, 0.1), (0.2, 0.1, 1.0)).constraints,
    "sphere": lambda: fixtures.sphere((0.1, 0, 0), 0.1).constraints,
    "scalpel": lambda: fixtures.scalpel(tip_B=(0.01, 0.0, 0.05)).constraints,
    "laparoscopic": lambda: fixtures.laparoscopic(tip_B=(0.0, 0.0, 0.02)).constraints,
    "duplicated_row": lambda: fixtures.scalpel().constraints + fixtures.scalpel().constraints[:1],
    "user_and_knife": lambda: (_UserPlane(), *fixtures.scalpel().constraints[2:]),
}
SEQUENCES = ("ZYX", "ZXZ", "XYZ", "YZY")
seeds = st.integers(0, 2**32 - 1)


def _rel(a, b):
    return np.abs(a - b).max() / (1.0 + np.abs(b).max()) if a.size else 0.0


def _random_rotation(rng):
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return Q * np.sign(np.linalg.det(Q))


@given(seed=seeds, seq=st.sampled_from(SEQUENCES))
@settings(max_examples=50, deadline=None)
def test_chart_terms_match_the_axis_product_rate_map(seed, seq):
    rng = np.random.default_rng(seed)
    chart = EulerChart(seq, EulerChart(seq).R0 if seed % 2 else _random_rotation(rng))
    theta, thd = rng.uniform(-3, 3, 3), rng.normal(size=3)
    theta[1] = chart.center[1] + rng.uniform(-1.0, 1.0)
    R_ref, E_ref, Edq_ref = rate_map(chart, theta, thd)
    R, E, E_inv, dE, E_W = motion.rate_map_terms(chart.R0, chart.axes_array, theta)
    np.testing.assert_allclose(R, R_ref, atol=1e-12)
    np.testing.assert_allclose(E, E_ref, atol=1e-12)
    np.testing.assert_allclose(E_inv @ E, np.eye(3), atol=1e-9)
    np.testing.assert_allclose(E_W, R @ E, atol=1e-12)
    d1, d2, d3 = thd
    np.testing.assert_allclose(-(d1 * d3) * dE[0] - (d1 * d2) * dE[1] - (d2 * d3) * dE[2], Edq_ref, atol=1e-10)


def _model(stack, coriolis):
    body = RigidBody(0.25, [0.0025, 0.003, 0.004])
    # compiled effects (dampers, gravity) and one that stays in Python (a spring)
    effects = (LinearDamper(1.0), AngularDamper(0.1), Gravity(0.25),
               Spring(np.array([0.1, 0.0, 0.2]), 50.0, k_Nm_per_rad=0.5))
    return ConstrainedBody(body, STACKS[stack](), effects, coriolis=coriolis)


def _ke_projection(M, G, nu):
    """argmin (x - nu)^T M (x - nu) s.t. G x = 0, through a null-space basis N of G (scipy)."""
    N = null_space(G) if G.shape[0] else np.eye(6)
    return N @ np.linalg.solve(N.T @ M @ N, N.T @ M @ nu)


@pytest.mark.parametrize("stack", sorted(STACKS))
@given(seed=seeds, seq=st.sampled_from(SEQUENCES), coriolis=st.booleans())
@settings(max_examples=30, deadline=None)
def test_evaluation_matches_the_textbook_form_and_projection_the_null_space(stack, seed, seq, coriolis):
    model = _model(stack, coriolis)
    rng = np.random.default_rng(seed)
    chart = EulerChart(seq, _random_rotation(rng))
    q, qd, F = rng.normal(size=6), rng.normal(size=6), rng.normal(size=6)
    q[4] = chart.center[1] + rng.uniform(-1.0, 1.0)  # keep off the chart singularity
    ev = model.evaluate(chart, q, qd, 0.5, F)
    lit = evaluate_literal(model, chart, q, qd, 0.5, F)
    assert ev.rank == lit.rank
    assert _rel(ev.qdd, lit.qdd) < 1e-8
    if ev.rank == model.m:
        assert _rel(ev.lam, lit.lam) < 1e-8
    pt = model.pose_terms(chart, q)
    G = model.rows.evaluate(pt.p, pt.R)[0].copy()
    np.testing.assert_allclose(ev.constraint_wrench_W, G.T @ ev.lam, atol=1e-12)
    # the projected rates: the admissible twist closest in kinetic energy
    Minv = np.zeros((6, 6))
    Minv[:3, :3] = np.eye(3) / model.body.mass_kg
    Minv[3:, 3:] = pt.R @ model.body.J_inv @ pt.R.T
    nu_ref = _ke_projection(np.linalg.inv(Minv), G, model.twist(pt, qd))
    assert _rel(model.twist(pt, model.project_rates(pt, qd)), nu_ref) < 1e-8
    # the twist form (Lie group) is the same physics
    v, w = qd[:3], pt.E_W @ qd[3:]
    tw = model.evaluate_twist(pt.p, pt.R, v, w, 0.5, F)
    assert _rel(tw.nudot, ev.nudot) < 1e-8
    nu = rng.normal(size=6)
    assert _rel(model.project_twist_at(pt.p, pt.R, nu), _ke_projection(np.linalg.inv(Minv), G, nu)) < 1e-8


def test_a_constraint_without_a_kernel_takes_the_python_path():
    model = ConstrainedBody(RigidBody(1.0, [1.0, 1.0, 1.0]), (_UserPlane(),))
    assert not model.rows.compiled_mask.any()
    ev = model.evaluate(EulerChart(), np.zeros(6), np.zeros(6), 0.0, np.array([0, 0, -9.81, 0, 0, 0]))
    np.testing.assert_allclose(ev.nudot, 0.0, atol=1e-15)
    np.testing.assert_allclose(ev.lam, [9.81])


@given(seed=seeds, k=st.integers(1, 6))
@settings(max_examples=50, deadline=None)
def test_left_pinv_is_the_pseudo_inverse(seed, k):
    P = np.random.default_rng(seed).normal(size=(6, k))
    np.testing.assert_allclose(motion.left_pinv(P), np.linalg.pinv(P), atol=1e-9)


def test_left_pinv_of_a_rank_deficient_matrix_is_not_finite():
    P = np.zeros((6, 3))
    P[0, 0] = P[1, 1] = 1.0
    assert not np.all(np.isfinite(motion.left_pinv(P)))


@pytest.mark.parametrize("scene", ["paper_rolling_disk", "paper_disk_on_sphere", "scalpel_fixture"])
@pytest.mark.parametrize("integrator", ["parametric", "projection", "lie_group"])
def test_runs_agree_with_the_textbook_form_step_by_step(scene, integrator):
    """Whole runs (2000 steps of each paper scene's scripted operator, re-charts and the flat
    parametric step included): every 50th step's multipliers equal eqs. 8-9 as printed at the
    step's starting state, and the holonomic rows hold."""
    sc = load_scene(scene).with_overrides(integrator=integrator)
    tool = build_tool(sc)
    assert isinstance(tool, ReferenceTool)
    op = ScriptedWrench(sc.operator, sc.fixture)
    for i in range(2000):
        p, R = tool.pose()
        F = op.wrench(i * sc.dt_s, p, R)
        lit = evaluate_literal(tool.model, tool.state.chart, tool.q, tool.qd, tool.t, F) if i % 50 == 0 else None
        assert tool.step(sc.dt_s, F) == "ok"
        if lit is not None:
            assert np.abs(tool.lam - lit.lam).max() <= 1e-6 * (1.0 + np.abs(lit.lam).max())
    assert np.abs(tool.residual()).max() < 1e-9
