"""The energy integrator and the energy function against oracles we did not write: Pinocchio's
kinetic and potential energy, and scipy's DOP853 on the same equations of motion."""

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from teleop.dynamics.body import RigidBody
from teleop.dynamics.effects import Gravity
from teleop.dynamics.model import ConstrainedBody
from teleop.dynamics.rotations import EulerChart
from teleop.scenario.build import build_tool
from teleop.scenario.operators import make_operator
from teleop.scenario.schema import load_scene
from tests.pin_oracle import free_flyer_model

finite = st.floats(-3.0, 3.0, allow_nan=False)
UNDAMPED = Path(__file__).resolve().parents[1] / "data" / "undamped"


@settings(max_examples=50, deadline=None)
@given(st.lists(finite, min_size=12, max_size=12), st.sampled_from(["ZYX", "ZXZ", "XYZ"]))
def test_energy_matches_pinocchio(x, seq):
    """Kinetic energy (free flyer, body-frame velocity) and gravity's potential energy."""
    J = np.array([[0.004, 0.0003, -0.0002], [0.0003, 0.0025, 0.0001], [-0.0002, 0.0001, 0.0011]])
    lopsided_body = RigidBody(0.4, J)
    model = ConstrainedBody(lopsided_body, (), [Gravity(lopsided_body.mass_kg)])
    chart = EulerChart(seq)
    q, qd = np.array(x[:6]), np.array(x[6:])
    pt = model.pose_terms(chart, q)
    v, w = qd[:3], pt.E_W @ qd[3:]
    pm = free_flyer_model(lopsided_body.mass_kg, lopsided_body.J)
    pm.gravity = pin.Motion(np.array([0, 0, -9.81, 0, 0, 0]))
    data = pm.createData()
    qp = np.concatenate([pt.p, pin.Quaternion(pt.R).coeffs()])
    vp = np.concatenate([pt.R.T @ v, pt.R.T @ w])
    K = pin.computeKineticEnergy(pm, data, qp, vp)
    V = pin.computePotentialEnergy(pm, data, qp)
    assert model.energy(chart, q, qd) == pytest.approx(K + V, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("name, tol_m", [("undamped_sphere_slide", 1e-6), ("undamped_scalpel_slide", 1e-5),
                                         ("undamped_rolling_disk", 1e-6)])
def test_the_force_free_motion_follows_scipy(name, tol_m):
    """From the state at the end of the push, 2 s of force-free motion at 1 kHz against DOP853
    (rtol 1e-11) on the same eqs. 8-9: the position error stays within tol_m (the step's
    second-order error; measured 7e-8, 9e-7, 9e-8 m, the parametric step 2e-5, 9e-3, 2e-4 m),
    and the energy integrator's energy stays at the start's."""
    scene = load_scene(str(UNDAMPED / f"{name}.toml")).with_overrides(integrator="energy")
    tool = build_tool(scene)
    op = make_operator(scene.operator, scene.fixture, scene.effects, np.random.default_rng(0))
    for i in range(500):  # the push
        p, R = tool.pose()
        assert tool.step(scene.dt_s, op.wrench(i * scene.dt_s, p, R)) == "ok"
    model, chart = tool.model, tool.state.chart
    y0 = np.concatenate([tool.q, tool.qd])
    E0 = tool.energy()

    def rhs(t, y):
        return np.concatenate([y[6:], model.evaluate(chart, y[:6], y[6:], t).qdd])

    T = 2.0
    ref = solve_ivp(rhs, (0.0, T), y0, method="DOP853", rtol=1e-11, atol=1e-12)
    assert ref.success
    for _ in range(round(T / scene.dt_s)):
        assert tool.step(scene.dt_s) == "ok"
    assert tool.state.chart is chart  # no re-chart: the two runs share coordinates
    p_ref = ref.y[:3, -1]
    assert np.linalg.norm(tool.pose()[0] - p_ref) <= tol_m
    assert abs(tool.energy() - E0) <= 1e-12 * E0
    assert abs(model.energy(chart, ref.y[:6, -1], ref.y[6:, -1]) - E0) <= 1e-7 * E0  # the oracle's own energy
