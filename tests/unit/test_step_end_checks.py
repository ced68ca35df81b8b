"""What the tool checks after a step (kernels.steps.end_checks) and the twist a fused step
hands over, held against plain Python and numpy: the finiteness verdict and the squared speeds
must be the ones Python's float arithmetic gives, and tool.twist() the product numpy's ``@`` gives
at the tool's current state, whichever path computed it; a twist kept from a step never outlives
the state it was computed for."""

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from teleop.dynamics.kernels.motion import energy_scale
from teleop.dynamics.kernels.steps import end_checks
from teleop.scenario.build import build_tool
from teleop.scenario.operators import ScriptedWrench
from teleop.scenario.schema import load_scene

_any = st.floats(allow_nan=True, allow_infinity=True, width=64)
_big = st.one_of(_any, st.floats(min_value=1e150, max_value=1e308), st.floats(min_value=-1e308, max_value=-1e150))


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # NUMBA_DISABLE_JIT=1: numpy scalars warn on overflow
@settings(max_examples=300, deadline=None)
@given(q=st.lists(_big, min_size=6, max_size=6), qd=st.lists(_big, min_size=6, max_size=6),
       lam=st.lists(_big, min_size=0, max_size=5), nudot=st.lists(_big, min_size=6, max_size=6))
@example(q=[1e308] * 6, qd=[0.0] * 6, lam=[], nudot=[0.0] * 6)  # finite terms, an infinite sum
@example(q=[0.0] * 6, qd=[2e154, 0, 0, 0, 0, 0], lam=[1.0], nudot=[0.0] * 6)  # v2 overflows alone
def test_end_checks_are_python_float_arithmetic(q, qd, lam, nudot):
    total, v2, w2 = end_checks(np.array(q), np.array(qd), np.array(lam, dtype=float), np.array(nudot))
    x, y, z, a, b, c = qd
    py_v2, py_w2 = x * x + y * y + z * z, a * a + b * b + c * c
    py_total = sum(q) + py_v2 + py_w2 + sum(lam) + sum(nudot)
    assert math.isfinite(total) == math.isfinite(py_total)
    for got, want in ((v2, py_v2), (w2, py_w2), (total, py_total)):
        assert got == want or (math.isnan(got) and math.isnan(want))


def _numpy_twist(tool):
    """(v, w) at the tool's state from a fresh evaluation of the pose terms (a copy of q: another
    object, so the pose cache computes it again) and numpy's product."""
    s = tool.state
    pt = tool.model.pose_terms(s.chart, s.q.copy())
    return s.qd[:3].copy(), pt.E_W @ s.qd[3:]


@pytest.mark.parametrize("integrator", ["parametric", "energy", "projection"])
def test_twist_is_numpys_product_at_the_current_state(integrator):
    scene = load_scene("paper_rolling_disk").with_overrides(integrator=integrator)
    tool = build_tool(scene)
    op = ScriptedWrench(scene.operator, scene.fixture)
    fused_twists = 0
    for i in range(300):
        p, R = tool.pose()
        tool.step(scene.dt_s, op.wrench(i * scene.dt_s, p, R))
        fused_twists += tool._end is not None
        v, w = tool.twist()
        v_ref, w_ref = _numpy_twist(tool)
        assert np.array_equal(v, v_ref) and np.array_equal(w, w_ref)  # bit for bit
        # and it is the world rate R E_B thetadot of the chart (the pose terms' own definition)
        pt = tool.model.pose_terms(tool.state.chart, tool.q)
        np.testing.assert_allclose(w, pt.R @ (pt.E_B @ tool.qd[3:]), rtol=1e-12, atol=1e-15)
        v[0] = w[0] = 1e9  # the caller's copies: writing into them changes nothing of the tool's
        assert np.array_equal(tool.twist()[0], v_ref) and np.array_equal(tool.twist()[1], w_ref)
    assert fused_twists == (0 if integrator == "projection" else 300)  # the fused steps hand over their twist


def test_a_kept_twist_does_not_outlive_its_state():
    """After a fused step's twist is kept: a singular step (safe state), a reset and a re-chart
    replace the state, and twist() follows the new state."""
    scene = load_scene("paper_rolling_disk").with_overrides(integrator="parametric")
    tool = build_tool(scene)
    push = np.array([2.0, 0.5, 0.0, 0.0, 0.0, 0.01])
    for _ in range(50):
        assert tool.step(scene.dt_s, push) == "ok"
    assert tool._end is not None and np.abs(tool.twist()[0]).max() > 0
    assert tool.step(scene.dt_s, push * 1e9) == "diverged"  # the safe state: zero rates
    v, w = tool.twist()
    assert not v.any() and not w.any()
    assert tool.step(scene.dt_s, push) == "ok"
    moving = tool.twist()
    tool.reset(scene.tool.q0)
    assert not tool.twist()[0].any() and not np.array_equal(tool.twist()[0], moving[0])
    for _ in range(5):
        tool.step(scene.dt_s, push)
    tool.state.qd = tool.state.qd * 2.0  # anyone replacing the rates: the kept twist is not used
    v, w = tool.twist()
    v_ref, w_ref = _numpy_twist(tool)
    assert np.array_equal(v, v_ref) and np.array_equal(w, w_ref)


def test_energy_scale_by_hand():
    """The correction's root on hand-computed cases: no forces, an energy defect of 1 % on K = 1 J
    (s = sqrt(1.01), then E1 = s^2 K); a defect beyond the bound (not applied, E1 = K + V); and
    no kinetic energy to carry it (NaN, not applied)."""
    s, E1, applied = energy_scale(1.01, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e-3, 0.05)
    assert applied and s == pytest.approx(math.sqrt(1.01), rel=1e-15) and E1 == pytest.approx(1.01, rel=1e-15)
    s, E1, applied = energy_scale(1.5, 1.0, 0.0, 0.0, 0.0, 0.0, 0.25, 1e-3, 0.05)
    assert not applied and s == pytest.approx(math.sqrt(1.25)) and E1 == 1.25
    s, E1, applied = energy_scale(1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e-3, 0.05)
    assert not applied and math.isnan(s) and E1 == 0.0
    # a power a = 2 W held over h at rates s: s^2 K - (h a / 2) s - (E0 + h a0 / 2) = 0
    E0, K, a, h = 1.0, 1.0, 2.0, 1e-3
    s, E1, applied = energy_scale(E0, K, a, 0.0, a, 0.0, 0.0, h, 0.05)
    assert applied and s * s * K - 0.5 * h * a * s - (E0 + 0.5 * h * a) == pytest.approx(0.0, abs=1e-15)
    assert E1 == pytest.approx(E0 + 0.5 * h * (a + a * s), rel=1e-15)
