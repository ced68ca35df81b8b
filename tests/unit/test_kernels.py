"""The compiled kernels against the numpy reference they replace (the same arithmetic, so to
round-off), over hypothesis-drawn charts, states and constraint stacks, including duplicated rows
(the eigen fallback) and a user constraint class without a kernel (the Python path)."""

from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop.dynamics import fixtures, kernels
from teleop.dynamics.body import RigidBody
from teleop.dynamics.constraints import Constraint, stack_bias, stack_jacobian
from teleop.dynamics.effects import AngularDamper, Gravity, LinearDamper, Spring
from teleop.dynamics.model import ConstrainedBody
from teleop.dynamics.rotations import EulerChart, rate_map_terms

STACKS = {
    "free": lambda: fixtures.free().constraints,
    "rolling_disk": lambda: fixtures.rolling_disk(0.03, (0, 0, 0.1), (0.2, 0.1, 1.0)).constraints,
    "sphere": lambda: fixtures.sphere((0.1, 0, 0), 0.1).constraints,
    "scalpel": lambda: fixtures.scalpel(tip_B=(0.01, 0.0, 0.05)).constraints,
    "laparoscopic": lambda: fixtures.laparoscopic(tip_B=(0.0, 0.0, 0.02)).constraints,
    "duplicated_row": lambda: fixtures.scalpel().constraints + fixtures.scalpel().constraints[:1],
}
SEQUENCES = ("ZYX", "ZXZ", "XYZ", "YZY")
seeds = st.integers(0, 2**32 - 1)


def _rel(a, b):
    return np.abs(a - b).max() / (1.0 + np.abs(b).max()) if a.size else 0.0


@given(seed=seeds, seq=st.sampled_from(SEQUENCES))
@settings(max_examples=50, deadline=None)
def test_rate_map_terms_matches_the_python_reference(seed, seq):
    rng = np.random.default_rng(seed)
    chart = EulerChart(seq, EulerChart(seq).R0 if seed % 2 else _random_rotation(rng))
    theta = rng.uniform(-3, 3, 3)
    ref = rate_map_terms(chart, theta)
    got = kernels.rate_map_terms(chart.R0, chart.axes_array, theta)
    for a, b in zip(got[:3], ref[:3]):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())
    np.testing.assert_allclose(got[3], np.array(ref[3]), atol=1e-12)


def _random_rotation(rng):
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return Q * np.sign(np.linalg.det(Q))


@pytest.mark.parametrize("stack", sorted(STACKS))
@given(seed=seeds, seq=st.sampled_from(SEQUENCES))
@settings(max_examples=30, deadline=None)
def test_constraint_rows_match_the_classes(stack, seed, seq):
    cons = STACKS[stack]()
    model = ConstrainedBody(RigidBody(0.3, [1e-3, 2e-3, 3e-3]), cons)
    assert model.compiled
    rng = np.random.default_rng(seed)
    p, R, v, w = rng.normal(size=3), _random_rotation(rng), rng.normal(size=3), rng.normal(size=3)
    G, b = model._G_template.copy(), np.zeros(model.m)
    kernels.stack_rows(G, b, model._kinds, model._offsets, model._params, p, R, v, w)
    np.testing.assert_allclose(G, stack_jacobian(cons, p, R), atol=1e-13)
    np.testing.assert_allclose(b, stack_bias(cons, p, R, v, w), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("stack", sorted(STACKS))
@given(seed=seeds, seq=st.sampled_from(SEQUENCES), coriolis=st.booleans())
@settings(max_examples=30, deadline=None)
def test_evaluation_and_projection_match_the_numpy_path(stack, seed, seq, coriolis):
    cons = STACKS[stack]()
    body = RigidBody(0.25, [0.0025, 0.003, 0.004])
    # compiled effects (dampers, gravity) and one that stays in Python (a spring)
    effects = (LinearDamper(1.0), AngularDamper(0.1), Gravity(0.25),
               Spring(np.array([0.1, 0.0, 0.2]), 50.0, k_Nm_per_rad=0.5))
    fast = ConstrainedBody(body, cons, effects, coriolis=coriolis)
    ref = ConstrainedBody(body, cons, effects, coriolis=coriolis, compiled=False)
    rng = np.random.default_rng(seed)
    chart = EulerChart(seq, _random_rotation(rng))
    q, qd, F = rng.normal(size=6), rng.normal(size=6), rng.normal(size=6)
    q[4] = chart.center[1] + rng.uniform(-1.0, 1.0)  # keep off the chart singularity
    a, b = fast.evaluate(chart, q, qd, 0.5, F), ref.evaluate(chart, q, qd, 0.5, F)
    assert a.rank == b.rank
    for x, y in ((a.qdd, b.qdd), (a.nudot, b.nudot), (a.lam, b.lam), (a.G, b.G), (a.wrench_W, b.wrench_W)):
        assert _rel(x, y) < 1e-9
    pa = fast.project_rates(fast.pose_terms(chart, q), qd)
    pb = ref.project_rates(ref.pose_terms(chart, q), qd)
    assert _rel(pa, pb) < 1e-9


@dataclass(frozen=True, eq=False)
class _UserPlane(Constraint):
    """A constraint class the kernels do not know: z of the body origin fixed (a user's own)."""

    name: str = "user_plane"

    def jacobian(self, p, R):
        return np.array([[0.0, 0.0, 1.0, 0.0, 0.0, 0.0]]) * (1.0 + 0.0 * p[0])

    def bias(self, p, R, v, w):
        return np.zeros(1)

    def residual(self, p, R):
        return np.array([p[2]])


def test_a_constraint_without_a_kernel_takes_the_python_path():
    model = ConstrainedBody(RigidBody(1.0, [1.0, 1.0, 1.0]), (_UserPlane(),))
    assert not model.compiled
    ev = model.evaluate(EulerChart(), np.zeros(6), np.zeros(6), 0.0, np.array([0, 0, -9.81, 0, 0, 0]))
    np.testing.assert_allclose(ev.nudot, 0.0, atol=1e-15)
    np.testing.assert_allclose(ev.lam, [9.81])


@given(seed=seeds, k=st.integers(1, 6))
@settings(max_examples=50, deadline=None)
def test_left_pinv_is_the_pseudo_inverse(seed, k):
    P = np.random.default_rng(seed).normal(size=(6, k))
    np.testing.assert_allclose(kernels.left_pinv(P), np.linalg.pinv(P), atol=1e-9)


def test_left_pinv_of_a_rank_deficient_matrix_is_not_finite():
    P = np.zeros((6, 3))
    P[0, 0] = P[1, 1] = 1.0
    assert not np.all(np.isfinite(kernels.left_pinv(P)))



@pytest.mark.parametrize("stack", sorted(STACKS))
@given(seed=seeds, coriolis=st.booleans())
@settings(max_examples=30, deadline=None)
def test_twist_form_matches_the_numpy_path(stack, seed, coriolis):
    """The Lie-group integrator's evaluation and projection (no chart)."""
    cons = STACKS[stack]()
    body = RigidBody(0.25, [0.0025, 0.003, 0.004])
    fast = ConstrainedBody(body, cons, (LinearDamper(1.0),), coriolis=coriolis)
    ref = ConstrainedBody(body, cons, (LinearDamper(1.0),), coriolis=coriolis, compiled=False)
    rng = np.random.default_rng(seed)
    p, R, v, w, F = rng.normal(size=3), _random_rotation(rng), rng.normal(size=3), rng.normal(size=3), rng.normal(size=6)
    a, b = fast.evaluate_twist(p, R, v, w, 0.0, F), ref.evaluate_twist(p, R, v, w, 0.0, F)
    assert a.rank == b.rank
    for x, y in ((a.nudot, b.nudot), (a.lam, b.lam), (a.G, b.G)):
        assert _rel(x, y) < 1e-9
    nu = rng.normal(size=6)
    assert _rel(fast.project_twist_at(p, R, nu), ref.project_twist_at(p, R, nu)) < 1e-9


@pytest.mark.parametrize("scene", ["paper_rolling_disk", "paper_disk_on_sphere", "scalpel_fixture"])
@pytest.mark.parametrize("integrator", ["parametric", "projection", "lie_group"])
def test_trajectories_match_the_numpy_path(scene, integrator):
    """Whole runs (2000 steps of each paper scene's scripted operator): the compiled tool and the
    numpy reference stay together, re-charts and the fused flat-parametric step included."""
    from dataclasses import replace

    from teleop.dynamics.tool import ReferenceTool
    from teleop.scenario.build import build_tool
    from teleop.scenario.operators import ScriptedWrench
    from teleop.scenario.schema import load_scene

    sc = load_scene(scene).with_overrides(integrator=integrator)
    fast = build_tool(sc)
    assert fast.model.compiled
    ref = ReferenceTool(fast.body, fast.fixture, fast.model.effects, integrator, fast.model.coriolis,
                        compiled=False)
    ref.reset(fast.q.copy(), fast.qd.copy())
    op = ScriptedWrench(sc.operator, sc.fixture)
    for i in range(2000):
        for tool in (fast, ref):
            p, R = tool.pose()
            tool.step(sc.dt_s, op.wrench(i * sc.dt_s, p, R))
    (pf, Rf), (pr, Rr) = fast.pose(), ref.pose()
    np.testing.assert_allclose(pf, pr, atol=1e-9)
    np.testing.assert_allclose(Rf, Rr, atol=1e-9)
    np.testing.assert_allclose(fast.lam, ref.lam, rtol=1e-6, atol=1e-9)
    assert fast.status == ref.status == "ok"
