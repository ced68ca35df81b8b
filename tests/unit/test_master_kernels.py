"""The compiled kernels of the master's hot path against their numpy/Pinocchio references, and
the joint observer on quantized, late readings."""

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop.control.admittance import AdmittanceController, AdmittanceGains
from teleop.dynamics.kernels.so3 import log3
from teleop.master.cobot import GRAVITY_W, CobotModel
from teleop.master.kernels import compute_hand_wrench_W, hand_wrench_W
from teleop.master.observer import JointObserver

MODEL = CobotModel()
vec3 = st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3).map(np.array)


@settings(max_examples=200, deadline=None)
@given(vec3, st.floats(0.0, np.pi - 1e-6))
def test_log3_matches_pinocchio(axis, angle):
    n = np.linalg.norm(axis)
    rv = axis / n * angle if n > 1e-3 else np.array([0.0, 0.0, angle])
    R = pin.exp3(rv)
    assert np.allclose(log3(R), pin.log3(R), atol=1e-9)


def test_log3_at_pi_is_a_valid_logarithm():
    R = pin.exp3(np.array([0.0, np.pi, 0.0]))
    assert np.allclose(pin.exp3(log3(R)), R, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(vec3, vec3, vec3, vec3, st.floats(0.1, 50.0), st.floats(0.1, 5.0))
def test_hand_wrench_kernel_matches_reference(rv, w, a, alpha, fmax, tmax):
    rng = np.random.default_rng(0)
    R, S, bias = pin.exp3(rv), rng.normal(size=6) * 20, rng.normal(size=6)
    acc = np.concatenate([a, alpha])
    ref = compute_hand_wrench_W(MODEL, S, bias, R, acc, w, fmax, tmax)
    out = hand_wrench_W(S, bias, R, acc, w, MODEL.handle_mass_kg, MODEL.handle_com_H, MODEL.handle_J_H,
                        GRAVITY_W, fmax, tmax)
    assert np.allclose(out, ref, atol=1e-10)


@pytest.mark.parametrize("gains", [{}, {"max_accel": 0.5, "max_velocity": 0.01}])  # free, saturating
def test_pid_kernel_matches_reference(gains):
    rng = np.random.default_rng(1)
    g = AdmittanceGains(**gains)
    fast, ref = AdmittanceController(g, 1e-3), AdmittanceController(g, 1e-3, compiled=False)
    for _ in range(200):
        p_r, p_v = rng.normal(size=3) * 1e-3, rng.normal(size=3) * 1e-3
        R_r, R_v = pin.exp3(rng.normal(size=3) * 1e-2), pin.exp3(rng.normal(size=3) * 1e-2)
        nu_r, acc_r = rng.normal(size=6) * 0.1, rng.normal(size=6)
        for c in (fast, ref):
            c.step(p_r, R_r, nu_r, acc_r, p_v, R_v)
        for k in ("nu_cmd", "accel_cmd", "error", "integral"):
            assert np.allclose(getattr(fast, k), getattr(ref, k), rtol=1e-12, atol=1e-15), k


def quantize(x, q):
    return np.round(x / q) * q


@pytest.mark.parametrize("latency", [0, 3])
def test_observer_rates_from_quantized_late_readings(latency):
    """A ramp at 20 mm/s and 0.6 rad/s read through 25 um / 0.5 mrad counts, `latency` periods
    late, while the commands miss a constant 2 mm/s: the rate estimate settles on the truth well
    inside one count per period (25 mm/s), the bias absorbing the model error."""
    dt, q = 1e-3, np.array([25e-6] * 3 + [5e-4] * 3)
    v_cmd = np.array([0.02, 0.0, -0.01, 0.6, 0.0, -0.3])
    v_true = v_cmd + np.array([0.002, 0, 0, 0.01, 0, 0])
    obs = JointObserver(np.zeros(6), dt, 1e-9, 0.0, np.full(6, 10.0), np.full(6, 1e6), bandwidth_hz=20.0)
    truth = []
    for k in range(600):
        truth.append(v_true * k * dt)
        if k >= latency:
            obs.correct(quantize(truth[k - latency], q), (k - latency) % 256, k % 256)
        obs.predict(k % 256, v_cmd)
    assert np.allclose(obs.rates, v_true, atol=np.r_[[1e-3] * 3, [2e-2] * 3])


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), window=st.floats(0.0, 5e-4), tau=st.floats(1e-4, 5e-3),
       amax=st.floats(0.5, 50.0))
def test_observer_kernels_match_the_numpy_reference(seed, window, tau, amax):
    """Random commands (some past vmax, some steps past the acceleration limit: the ramp branch)
    and readings up to 4 periods late, the same sequence through both forms."""
    rng = np.random.default_rng(seed)
    args = (rng.normal(size=6), 1e-3, tau, window, np.full(6, 0.5), np.full(6, amax))
    fast, ref = JointObserver(*args), JointObserver(*args, compiled=False)
    for k in range(60):
        y = rng.normal(size=6) * 1e-3
        lag = int(rng.integers(0, 5))
        for obs in (fast, ref):
            obs.correct(y, (k - lag) % 256, k % 256)
        u = rng.normal(size=6) * (2.0 if k % 7 == 0 else 0.1)
        for obs in (fast, ref):
            obs.predict(k % 256, u)
        np.testing.assert_allclose(fast.x, ref.x, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(fast.rates, ref.rates, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(fast.history, ref.history, rtol=1e-12, atol=1e-15)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), singular=st.booleans())
def test_dls_command_matches_the_numpy_reference(seed, singular):
    """Random Jacobians, some made near-singular (the damped branch), and joints beyond the
    workspace margins on random axes."""
    from teleop.master.cobot_master import compute_dls, compute_workspace_limit
    from teleop.master.kernels import dls_command

    rng = np.random.default_rng(seed)
    J = rng.normal(size=(6, 6))
    if singular:
        U, S, Vt = np.linalg.svd(J)
        S[-1] = rng.uniform(0.0, 0.05)
        J = (U * S) @ Vt
    twist, joints = rng.normal(size=6), rng.normal(size=6)
    hi, lo = np.full(6, 0.5), np.full(6, -0.5)
    ref = compute_workspace_limit(joints, compute_dls(J, twist), hi, lo)
    np.testing.assert_allclose(dls_command(np.asfortranarray(J), twist, joints, hi, lo, 0.05, 0.02), ref,
                               rtol=1e-9, atol=1e-9 * (1.0 + np.abs(ref).max()))


@settings(max_examples=60, deadline=None)
@given(r=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3), small=st.booleans())
def test_exp3_and_prediction_match_pinocchio(r, small):
    from teleop.dynamics.kernels.so3 import exp3
    from teleop.master.kernels import advance_prediction

    r = np.array(r) * (1e-6 if small else 1.0)
    np.testing.assert_allclose(exp3(r), pin.exp3(r), atol=1e-14)
    pred_p, pred_R = np.zeros((4, 3)), np.tile(np.eye(3), (4, 1, 1))
    pred_R[3] = pin.exp3(np.array([0.3, -0.2, 0.1]))
    nu = np.r_[0.1, -0.2, 0.3, r]
    advance_prediction(pred_p, pred_R, 3, nu, 1e-3)  # wraps to slot 0
    np.testing.assert_allclose(pred_p[0], pred_p[3] + nu[:3] * 1e-3, atol=1e-15)
    np.testing.assert_allclose(pred_R[0], pin.exp3(r * 1e-3) @ pred_R[3], atol=1e-14)


def test_handle_command_maps_through_phi_then_solves():
    from teleop.control.admittance import Phi
    from teleop.master.cobot_master import compute_dls
    from teleop.master.kernels import handle_command

    rng = np.random.default_rng(7)
    phi = Phi(3.0, np.array([0.1, 0.0, 0.2]), pin.exp3(np.array([0.2, -0.1, 0.4])))
    J, nu_V, a_V = rng.normal(size=(6, 6)), rng.normal(size=6), rng.normal(size=6)
    inf = np.full(6, np.inf)
    nu_H, a_H, qd = handle_command(J, phi.twist_map_to_handle, nu_V, a_V, 0.004, np.zeros(6), inf, -inf, 0.05, 0.02)
    np.testing.assert_allclose(nu_H, phi.twist_to_handle(nu_V), atol=1e-14)
    np.testing.assert_allclose(a_H, phi.twist_to_handle(a_V), atol=1e-14)
    np.testing.assert_allclose(qd, compute_dls(J, nu_H + 0.004 * a_H), rtol=1e-10, atol=1e-12)
