"""The cobot's compiled kernels against independent references: Pinocchio (kinematics, Jacobian,
spatial inertia, exp/log), finite differences, an ODE solver for the servo model, the textbook DLS
formula, and steps worked out by hand; and the joint observer on quantized, late readings."""

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from teleop.control.admittance import Phi
from teleop.control.kernels import pid_step
from teleop.dynamics.kernels.so3 import exp3, log3
from teleop.master.cobot.frame_kernels import DRIVER_STATE
from teleop.master.cobot.kernels import (
    HOST_CONSTS,
    HOST_STATE,
    advance_prediction,
    correct_kernel,
    distal_wrench_H,
    dls_command,
    gantry_zxz_pose_jacobian,
    hand_wrench_W,
    handle_command,
    host_command,
    host_feedback,
    host_sense,
    predict_kernel,
    servo_advance,
)
from teleop.master.cobot.model import GRAVITY_W, CobotModel
from teleop.master.cobot.observer import HISTORY, JointObserver

MODEL = CobotModel()
HANDLE = (MODEL.handle_mass_kg, MODEL.handle_com_H, MODEL.handle_J_H, GRAVITY_W)
vec3 = st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3).map(np.array)
seeds = st.integers(0, 2**32 - 1)


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


def _pin_distal_wrench_H(R, v_o, w, a_o, alpha):
    """Newton-Euler with Pinocchio's spatial inertia in the handle frame: the cell carries gravity
    minus I a - v x* I v, with the spatial acceleration from the classical one (a = a_o - w x v_o)."""
    I = pin.Inertia(MODEL.handle_mass_kg, MODEL.handle_com_H, MODEL.handle_J_H)
    v = pin.Motion(R.T @ v_o, R.T @ w)
    a = pin.Motion(R.T @ (a_o - np.cross(w, v_o)), R.T @ alpha)
    inertial = I * a + v.cross(I * v)
    gravity = I * pin.Motion(-R.T @ GRAVITY_W, np.zeros(3))  # weight = the inertia under -g
    return -(gravity + inertial).vector


@settings(max_examples=100, deadline=None)
@given(vec3, vec3, vec3, vec3, vec3)
def test_distal_wrench_matches_pinocchio_newton_euler(rv, v_o, w, a_o, alpha):
    """Any origin velocity v_o: the classical origin acceleration makes the kernel independent of it."""
    R = pin.exp3(rv)
    np.testing.assert_allclose(distal_wrench_H(R, w, a_o, alpha, *HANDLE), _pin_distal_wrench_H(R, v_o, w, a_o, alpha),
                               atol=1e-10)


@settings(max_examples=100, deadline=None)
@given(vec3, vec3, vec3, vec3, st.floats(0.1, 50.0), st.floats(0.1, 5.0))
def test_hand_wrench_removes_tare_and_handle_and_saturates(rv, w, a, alpha, fmax, tmax):
    """A load cell that reads bias + distal handle + the hand (in H) gives back the hand in the
    world, each half scaled down to its norm limit."""
    rng = np.random.default_rng(0)
    R, bias, F_hand_H = pin.exp3(rv), rng.normal(size=6), rng.normal(size=6) * 20
    S = bias + _pin_distal_wrench_H(R, np.zeros(3), w, a, alpha) + F_hand_H
    out = hand_wrench_W(S, bias, R, np.concatenate([a, alpha]), w, *HANDLE, fmax, tmax)
    f, t = F_hand_H[:3], F_hand_H[3:]
    f = f * min(1.0, fmax / np.linalg.norm(f))
    t = t * min(1.0, tmax / np.linalg.norm(t))
    np.testing.assert_allclose(out, np.concatenate([R @ f, R @ t]), atol=1e-9)


def test_kinematics_match_pinocchio_and_finite_differences():
    rng = np.random.default_rng(5)
    for _ in range(20):
        x = rng.uniform(-2.0, 2.0, 6)
        p, R, J = gantry_zxz_pose_jacobian(x)
        p_ref, R_ref = MODEL.compute_handle_pose(x)
        np.testing.assert_allclose(p, p_ref, atol=1e-12)
        np.testing.assert_allclose(R, R_ref, atol=1e-12)
        np.testing.assert_allclose(J, MODEL.compute_jacobian(x), atol=1e-12)
        h = 1e-6
        for i in range(6):
            dx = np.zeros(6)
            dx[i] = h
            p1, R1, _ = gantry_zxz_pose_jacobian(x + dx)
            p0, R0, _ = gantry_zxz_pose_jacobian(x - dx)
            np.testing.assert_allclose((p1 - p0) / (2 * h), J[:3, i], atol=1e-8)
            np.testing.assert_allclose(pin.log3(R1 @ R0.T) / (2 * h), J[3:, i], atol=1e-8)


@settings(max_examples=30, deadline=None)
@given(seeds, st.floats(1e-4, 5e-3), st.floats(1e-4, 2e-3))
def test_servo_advance_matches_the_ode(seed, tau, h):
    """Below the acceleration limit: the first-order lag qdd = (u - qd) / tau integrated by an ODE
    solver; when a joint exceeds it, every joint's rate change is clipped to amax h and the
    positions follow the trapezoid."""
    rng = np.random.default_rng(seed)
    x0, qd0, u = rng.normal(size=6), rng.normal(size=6) * 0.1, rng.normal(size=6) * 0.1
    x, qd = servo_advance(x0, qd0, u, h, tau, np.full(6, 1e9))
    sol = solve_ivp(lambda t, y: np.concatenate([y[6:], (u - y[6:]) / tau]), (0.0, h), np.concatenate([x0, qd0]),
                    rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(x, sol.y[:6, -1], atol=1e-12)
    np.testing.assert_allclose(qd, sol.y[6:, -1], atol=1e-10)
    qd_lag = sol.y[6:, -1]
    amax = np.full(6, 0.5 * np.abs(qd_lag - qd0).max() / h)  # one joint over its limit: all ramp
    x, qd = servo_advance(x0, qd0, u, h, tau, amax)
    np.testing.assert_allclose(qd, qd0 + np.clip(qd_lag - qd0, -amax * h, amax * h), atol=1e-10)
    np.testing.assert_allclose(x, x0 + 0.5 * (qd0 + qd) * h, atol=1e-12)


def test_observer_prediction_matches_the_ode_over_a_period():
    """The command changes ``window`` s after SYNC: the prediction is the ODE under the old
    command, then the new one clipped to vmax, plus the rate bias over the period."""
    rng = np.random.default_rng(2)
    x0, qd0 = rng.normal(size=6), rng.normal(size=6) * 0.1
    u_old, bias = rng.normal(size=6) * 0.1, rng.normal(size=6) * 1e-3
    u_cmd, vmax, tau, dt, window = np.array([0.7, -0.1, 0.2, -0.9, 0.0, 0.3]), np.full(6, 0.5), 8e-4, 1e-3, 3e-4
    x, qd, u = predict_kernel(x0, qd0, u_old, u_cmd, bias, vmax, np.full(6, 1e9), dt, window, tau)
    y = np.concatenate([x0, qd0])
    for cmd, h in ((u_old, window), (np.clip(u_cmd, -vmax, vmax), dt - window)):
        y = solve_ivp(lambda t, y, cmd=cmd: np.concatenate([y[6:], (cmd - y[6:]) / tau]), (0.0, h), y, rtol=1e-12,
                      atol=1e-14).y[:, -1]
    np.testing.assert_allclose(x, y[:6] + bias * dt, atol=1e-12)
    np.testing.assert_allclose(qd, y[6:], atol=1e-10)
    np.testing.assert_allclose(u, np.clip(u_cmd, -vmax, vmax))


def test_observer_correction_by_hand():
    """Innovation r = y - history[j]: x += alpha r + (beta/dt) r lag dt; bias += (beta/dt) r; the
    estimates of SYNC j+1..k move by alpha r + m dt (beta/dt) r."""
    alpha, beta, dt = 0.3, 0.05, 1e-3
    history = np.zeros((HISTORY, 1))
    history[10, 0], history[11, 0], history[12, 0] = 1.0, 1.1, 1.2
    x, b = correct_kernel(history, np.array([1.2]), np.array([0.0]), np.array([1.5]), 10, 12, alpha, beta, dt)
    r = 0.5
    assert b[0] == pytest.approx(50.0 * r) and x[0] == pytest.approx(1.2 + 0.3 * r + 50.0 * r * 2e-3)
    assert history[11, 0] == pytest.approx(1.1 + 0.3 * r + 50.0 * r * 1e-3)
    assert history[12, 0] == pytest.approx(1.2 + 0.3 * r + 50.0 * r * 2e-3) and history[10, 0] == 1.0
    history = np.full((HISTORY, 1), 2.0)
    x, b = correct_kernel(history, np.array([2.0]), np.array([1.0]), np.array([2.1]), 255, 255, alpha, beta, dt)
    assert x[0] == pytest.approx(2.03) and b[0] == pytest.approx(1.0 + 5.0)


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


def _textbook_dls(J, twist, sigma0=0.05, lam0=0.02):
    smin = np.linalg.svd(J, compute_uv=False)[-1]
    lam2 = 0.0 if smin >= sigma0 else lam0 ** 2 * (1.0 - (smin / sigma0) ** 2)
    if lam2 == 0.0:
        return np.linalg.solve(J, twist)
    return J.T @ np.linalg.solve(J @ J.T + lam2 * np.eye(6), twist)


@settings(max_examples=60, deadline=None)
@given(seed=seeds, singular=st.booleans())
def test_dls_command_is_the_textbook_dls_then_the_workspace_limit(seed, singular):
    """Random Jacobians, some near-singular (damped: J^T (J J^T + lam^2 I)^-1), and joints beyond the
    workspace margins on random axes (a rate further out is zeroed, a rate back in kept)."""
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(6, 6))
    if singular:
        U, S, Vt = np.linalg.svd(J)
        S[-1] = rng.uniform(0.0, 0.05)
        J = (U * S) @ Vt
    twist, joints = rng.normal(size=6), rng.normal(size=6)
    hi, lo = np.full(6, 0.5), np.full(6, -0.5)
    ref = _textbook_dls(J, twist)
    ref[((joints > hi) & (ref > 0)) | ((joints < lo) & (ref < 0))] = 0.0
    np.testing.assert_allclose(dls_command(np.asfortranarray(J), twist, joints, hi, lo, 0.05, 0.02), ref,
                               rtol=1e-8, atol=1e-8 * (1.0 + np.abs(ref).max()))


@settings(max_examples=60, deadline=None)
@given(r=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3), small=st.booleans())
def test_exp3_and_prediction_match_pinocchio(r, small):
    r = np.array(r) * (1e-6 if small else 1.0)
    np.testing.assert_allclose(exp3(r), pin.exp3(r), atol=1e-14)
    pred_p, pred_R = np.zeros((4, 3)), np.tile(np.eye(3), (4, 1, 1))
    pred_R[3] = pin.exp3(np.array([0.3, -0.2, 0.1]))
    nu = np.r_[0.1, -0.2, 0.3, r]
    advance_prediction(pred_p, pred_R, 3, nu, 1e-3)  # wraps to slot 0
    np.testing.assert_allclose(pred_p[0], pred_p[3] + nu[:3] * 1e-3, atol=1e-15)
    np.testing.assert_allclose(pred_R[0], pin.exp3(r * 1e-3) @ pred_R[3], atol=1e-14)


def test_handle_command_maps_through_phi_then_solves():
    rng = np.random.default_rng(7)
    phi = Phi(3.0, np.array([0.1, 0.0, 0.2]), pin.exp3(np.array([0.2, -0.1, 0.4])))
    J, nu_V, a_V = rng.normal(size=(6, 6)), rng.normal(size=6), rng.normal(size=6)
    inf = np.full(6, np.inf)
    nu_H, a_H, qd = handle_command(J, phi.twist_map_to_handle, nu_V, a_V, 0.004, np.zeros(6), inf, -inf, 0.05, 0.02)
    np.testing.assert_allclose(nu_H, phi.twist_to_handle(nu_V), atol=1e-14)
    np.testing.assert_allclose(a_H, phi.twist_to_handle(a_V), atol=1e-14)
    np.testing.assert_allclose(qd, _textbook_dls(J, nu_H + 0.004 * a_H), rtol=1e-8, atol=1e-10)


def _rotations(rng, n):
    return [pin.exp3(rng.normal(size=3)) for _ in range(n)]


@settings(max_examples=60, deadline=None)
@given(seeds, st.booleans(), st.floats(0.2, 5.0))
def test_host_feedback_against_pinocchio_and_phi(seed, late, scale):
    """The measured pose from Pinocchio's kinematics, carried forward by the predicted motion
    (p + p_k - p_j, R_k R_j^T R), the hand's wrench (load cell minus bias minus the Newton-Euler
    handle), φ's pose and eq. 4 from :class:`Phi`."""
    rng = np.random.default_rng(seed)
    joints = rng.uniform(-1.0, 1.0, 6)
    k = int(rng.integers(HISTORY))
    j = (k - int(rng.integers(1, 5))) % HISTORY if late else k
    pred_p = rng.normal(size=(HISTORY, 3)) * 0.1
    pred_R = np.array(_rotations(rng, 1) * HISTORY)
    pred_R[j], pred_R[k] = _rotations(rng, 2)
    bias_S, accel, nu = rng.normal(size=6), rng.normal(size=6) * 5, rng.normal(size=6)
    phi = Phi(scale, rng.normal(size=3) * 0.1, _rotations(rng, 1)[0])
    p_m, R_m = MODEL.compute_handle_pose(joints)
    F_hand_H = rng.normal(size=6)  # small: no saturation at 100 N / 5 N*m
    wrench_S = bias_S + _pin_distal_wrench_H(R_m, np.zeros(3), nu[3:], accel[:3], accel[3:]) + F_hand_H
    p_est, R_est, F, f_v, p_v, R_v = host_feedback(
        p_m, R_m, k, j, pred_p, pred_R, wrench_S, bias_S, accel, nu, *HANDLE, 100.0, 5.0, phi.wrench_map_to_virtual,
        phi.offset_p, phi.scale, phi.offset_R)
    p_ref, R_ref = (p_m, R_m) if j == k else (p_m + pred_p[k] - pred_p[j], pred_R[k] @ pred_R[j].T @ R_m)
    F_ref = np.concatenate([R_m @ F_hand_H[:3], R_m @ F_hand_H[3:]])
    pv_ref, Rv_ref = phi.compute_virtual_pose(p_ref, R_ref)
    for got, ref in ((p_est, p_ref), (R_est, R_ref), (F, F_ref), (f_v, phi.wrench_to_virtual(F_ref)),
                     (p_v, pv_ref), (R_v, Rv_ref)):
        np.testing.assert_allclose(got, ref, atol=1e-9)


def _host_records(rng, servo_model=1):
    """A state record (HOST_STATE) and a constants record (HOST_CONSTS) filled with random values."""
    hs, hc = np.zeros(1, HOST_STATE), np.zeros(1, HOST_CONSTS)
    r, c = hs[0], hc[0]
    for name in HOST_STATE.names:
        r[name] = rng.normal(size=HOST_STATE[name].shape) * 1e-2
    r["pred_R"] = np.array(_rotations(rng, HISTORY))
    r["R_v"], r["R_m"] = _rotations(rng, 2)
    r["obs"][0] += 0.3
    c["gains"] = np.array([[4e4] * 6, [4e5] * 6, [400.0] * 6, [2e-6] * 6, [30.0] * 3 + [600.0] * 3,
                           [0.5] * 3 + [10.0] * 3])
    c["obs_lim"] = np.array([[0.5] * 3 + [10.0] * 3, [20.0] * 3 + [400.0] * 3])
    c["ws"] = np.array([MODEL.upper - 0.01, MODEL.lower + 0.01])
    c["mass"], c["com"], c["inertia"], c["gravity"] = HANDLE
    c["max_force"], c["max_torque"] = 100.0, 5.0
    phi = Phi(2.0, rng.normal(size=3) * 0.1, pin.exp3(rng.normal(size=3)))
    c["wrench_map"], c["to_handle"] = phi.wrench_map_to_virtual, phi.twist_map_to_handle
    c["off_p"], c["scale"], c["off_R"] = phi.offset_p, phi.scale, phi.offset_R
    c["tau"], c["dt"], c["dt_ctrl"], c["obs_dt"], c["obs_window"], c["obs_tau"] = 1e-3, 1e-3, 1e-3, 1e-3, 2e-4, 1e-3
    c["alpha"], c["beta"], c["sigma0"], c["lam0"], c["servo_model"] = 0.2, 0.01, 0.05, 0.02, servo_model
    c["vmax"], c["free_damping"] = c["obs_lim"][0], [20.0] * 3 + [1.0] * 3
    return hs, hc


@pytest.mark.parametrize("engaged", [True, False])
def test_host_command_is_pid_then_handle_command_then_predictions(engaged):
    """The fused command half on the state record is the composition of its tested pieces, in
    order; clutched out, the handle's twist is the hand's wrench over free_damping, clipped."""
    rng = np.random.default_rng(4)
    hs, hc = _host_records(rng)
    ref = {name: hs[0][name].copy() for name in HOST_STATE.names}
    c = hc[0]
    p_r, R_r = ref["p_v"] + rng.normal(size=3) * 1e-3, pin.exp3(rng.normal(size=3) * 1e-2) @ ref["R_v"]
    nu_r, a_r = rng.normal(size=6) * 0.1, rng.normal(size=6)
    joints = rng.uniform(-0.3, 0.3, 6)
    joints[4] = 1.2
    _, _, J = MODEL.compute_pose_and_jacobian(joints)
    hs[0]["J"] = J
    k = 255
    e_p, e_r = host_command(hs, hc, p_r, R_r, nu_r, a_r, joints, k, engaged)
    g, ctrl, obs = c["gains"], ref["ctrl"], ref["obs"]
    if engaged:
        nu_V, a_V, e, integ = pid_step(p_r, R_r, nu_r, a_r, ref["p_v"], ref["R_v"], *g, c["dt_ctrl"], ctrl[3], ctrl[0])
        nu_H, a_H, qd = handle_command(J, c["to_handle"], nu_V, a_V, c["tau"], joints, c["ws"][0], c["ws"][1],
                                       0.05, 0.02)
        for got, want in zip(hs[0]["ctrl"], (nu_V, a_V, e, integ)):
            np.testing.assert_array_equal(got, want)
        assert (e_p, e_r) == (np.linalg.norm(e[:3]), np.linalg.norm(e[3:]))
    else:
        nu_H = np.clip(ref["F_hand"] / c["free_damping"], -c["vmax"], c["vmax"])
        a_H = (nu_H - ref["nu_H"]) / c["dt"]
        qd = dls_command(J, nu_H + c["tau"] * a_H, joints, c["ws"][0], c["ws"][1], 0.05, 0.02)
        np.testing.assert_array_equal(hs[0]["ctrl"], ctrl)  # the PID's state untouched
        assert (e_p, e_r) == (0.0, 0.0)
    x, qdm, u = predict_kernel(obs[0], obs[1], obs[2], qd, obs[3], c["obs_lim"][0], c["obs_lim"][1], 1e-3, 2e-4, 1e-3)
    pred_p, pred_R = ref["pred_p"], ref["pred_R"]
    advance_prediction(pred_p, pred_R, k, nu_H, 1e-3)
    r = hs[0]
    for got, want in ((r["nu_H"], nu_H), (r["a_H"], a_H), (r["qd"], qd), (r["obs"][:3], (x, qdm, u)),
                      (r["obs"][3], obs[3]), (r["obs_hist"][0], x), (r["pred_p"], pred_p), (r["pred_R"], pred_R),
                      (r["accel_model"][0], J @ np.clip((u - qdm) / 1e-3, -c["obs_lim"][1], c["obs_lim"][1]))):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(r["obs_hist"][1:], ref["obs_hist"][1:])


@pytest.mark.parametrize("fresh, late, servo_model", [(True, False, 1), (True, True, 0), (False, True, 1)])
def test_host_sense_is_correction_then_kinematics_then_feedback(fresh, late, servo_model):
    """The fused feedback half on the state record: the observer's correction by a fresh reading,
    the feedback aged a cycle, the closed-form kinematics, :func:`host_feedback` with the servo
    model's or the commanded handle acceleration; without ``feedback`` (a latched fault) or with
    stale feedback only the correction and the ageing."""
    rng = np.random.default_rng(9)
    for feedback, since in ((True, 0), (False, 0), (True, 2)):
        hs, hc = _host_records(rng, servo_model)
        ref = {name: hs[0][name].copy() for name in HOST_STATE.names}
        c = hc[0]
        joints = rng.uniform(-0.3, 0.3, 6)
        k, wc = 7, 6
        j = 5 if late else k
        wrench_S, bias_S = rng.normal(size=6), rng.normal(size=6) * 0.1
        ds = np.zeros(1, DRIVER_STATE)
        d = ds[0]
        d["joints"], d["wrench"], d["jc"], d["wc"], d["fresh_j"], d["fresh_w"] = joints, wrench_S, j, wc, fresh, 1
        d["since_j"] = 0 if fresh else since  # an arriving reading resets it (rx_period_frame)
        stale = host_sense(hs, hc, ds, k, bias_S, 3, feedback, True)
        assert stale == (not fresh and since == 2)  # 3 cycles without fresh joints
        assert d["fresh_j"] == d["fresh_w"] == 0 and d["since_j"] == (0 if fresh else since + 1)
        r = hs[0]
        x, b = ref["obs"][0], ref["obs"][3]
        if fresh:
            x, b = correct_kernel(ref["obs_hist"], x, b, joints, j, k, c["alpha"], c["beta"], c["obs_dt"])
        np.testing.assert_array_equal(r["obs"][0], x)
        np.testing.assert_array_equal(r["obs"][3], b)
        np.testing.assert_array_equal(r["obs_hist"], ref["obs_hist"])
        if not feedback or stale:
            np.testing.assert_array_equal(r["f_v"], ref["f_v"])
            continue
        p_m, R_m, J = gantry_zxz_pose_jacobian(joints)
        accel = ref["accel_model"][wc] if servo_model else ref["a_H"]
        want = host_feedback(p_m, R_m, k, j, ref["pred_p"], ref["pred_R"], wrench_S, bias_S, accel, ref["nu_H"],
                             *HANDLE, 100.0, 5.0, c["wrench_map"], c["off_p"], c["scale"], c["off_R"])
        for name, w in zip(("p_est", "R_est", "F_hand", "f_v", "p_v", "R_v"), want):
            np.testing.assert_array_equal(r[name], w)
        np.testing.assert_array_equal(r["J"], J)
