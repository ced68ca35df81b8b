"""The master's fused period (``CobotMaster(compiled=True)``: two kernels) against its reference,
the same period piece by piece (``compiled=False``): kernel by kernel over random inputs, and
whole lockstep runs (late and lost frames, a contact wrench, clutch cycles) step by step."""

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop.control.admittance import AdmittanceController, AdmittanceGains, Phi
from teleop.dynamics import fixtures
from teleop.dynamics.body import RigidBody
from teleop.dynamics.effects import AngularDamper, LinearDamper
from teleop.dynamics.tool import ReferenceTool
from teleop.master import CobotConfig, CobotMaster
from teleop.master.cobot import GRAVITY_W, CobotModel
from teleop.master.cobot_master import compute_dls, compute_workspace_limit
from teleop.master.kernels import (advance_prediction, compute_hand_wrench_W, handle_command, host_command,
                                   host_feedback)
from teleop.master.observer import HISTORY, JointObserver

MODEL = CobotModel()
TOL = dict(rtol=1e-12, atol=1e-12)
seeds = st.integers(0, 2**32 - 1)


def _rotations(rng, n):
    return [pin.exp3(rng.normal(size=3)) for _ in range(n)]


@settings(max_examples=100, deadline=None)
@given(seeds, st.booleans(), st.floats(0.2, 5.0))
def test_host_feedback_matches_the_pieces(seed, late, scale):
    rng = np.random.default_rng(seed)
    joints = rng.uniform(-1.0, 1.0, 6)
    k = int(rng.integers(HISTORY))
    j = (k - int(rng.integers(1, 5))) % HISTORY if late else k
    pred_p = rng.normal(size=(HISTORY, 3)) * 0.1
    pred_R = np.array(_rotations(rng, 1) * HISTORY)
    pred_R[j], pred_R[k] = _rotations(rng, 2)
    wrench_S, bias_S = rng.normal(size=6) * 20, rng.normal(size=6)
    accel, nu = rng.normal(size=6) * 5, rng.normal(size=6)
    phi = Phi(scale, rng.normal(size=3) * 0.1, _rotations(rng, 1)[0])
    fmax, tmax = rng.uniform(0.5, 50.0), rng.uniform(0.05, 5.0)

    J, p_est, R_est, f_v, p_v, R_v = host_feedback(
        joints, k, j, pred_p, pred_R, wrench_S, bias_S, accel, nu, MODEL.handle_mass_kg, MODEL.handle_com_H,
        MODEL.handle_J_H, GRAVITY_W, fmax, tmax, phi.wrench_map_to_virtual, phi.offset_p, phi.scale, phi.offset_R)

    p_m, R_m, J_ref = MODEL._pin_pose_and_jacobian(joints)  # Pinocchio, not the closed form
    if j == k:
        p_ref, R_ref = p_m, R_m
    else:
        p_ref, R_ref = p_m + pred_p[k] - pred_p[j], pred_R[k] @ pred_R[j].T @ R_m
    F = compute_hand_wrench_W(MODEL, wrench_S, bias_S, R_m, accel, nu[3:], fmax, tmax)
    pv_ref, Rv_ref = phi.compute_virtual_pose(p_ref, R_ref)
    for got, ref in ((J, J_ref), (p_est, p_ref), (R_est, R_ref), (f_v, phi.wrench_to_virtual(F)), (p_v, pv_ref),
                     (R_v, Rv_ref)):
        assert np.allclose(got, ref, **TOL)


@settings(max_examples=100, deadline=None)
@given(seeds, st.booleans(), st.sampled_from([0.0, 2e-4]))
def test_host_command_matches_the_pieces(seed, saturating, window):
    rng = np.random.default_rng(seed)
    dt, tau = 1e-3, 1e-3
    g = AdmittanceGains(max_accel=0.5, max_velocity=0.01) if saturating else AdmittanceGains()
    ref_ctrl = AdmittanceController(g, dt, compiled=False)
    ref_ctrl.integral, ref_ctrl.nu_cmd = rng.normal(size=6) * 1e-6, rng.normal(size=6) * 0.05
    vmax, amax = np.array([0.5] * 3 + [10.0] * 3), np.array([20.0] * 3 + [400.0] * 3)
    ref_obs = JointObserver(rng.uniform(-0.3, 0.3, 6), dt, tau, window, vmax, amax, compiled=False)
    ref_obs.qd_model, ref_obs.u, ref_obs.bias = rng.normal(size=6) * 0.1, rng.normal(size=6) * 0.1, rng.normal(size=6) * 1e-3
    p_r, p_v = rng.normal(size=3) * 1e-3, rng.normal(size=3) * 1e-3
    R_r, R_v = pin.exp3(rng.normal(size=3) * 1e-2), pin.exp3(rng.normal(size=3) * 1e-2)
    v_r, w_r, acc_r = rng.normal(size=3) * 0.1, rng.normal(size=3) * 0.1, rng.normal(size=6)
    joints = rng.uniform(-0.45, 0.45, 6)
    joints[4] = rng.uniform(0.0, np.pi)  # near and far from the wrist singularity
    _, _, J = MODEL.compute_pose_and_jacobian(joints)
    ws_hi, ws_lo = MODEL.upper - 0.01, MODEL.lower + 0.01
    to_handle = Phi(rng.uniform(0.2, 5.0), np.zeros(3), pin.exp3(rng.normal(size=3))).twist_map_to_handle
    k = int(rng.integers(HISTORY))
    pred_p, pred_R = rng.normal(size=(HISTORY, 3)), np.array(_rotations(rng, 1) * HISTORY)
    history = np.tile(ref_obs.x, (HISTORY, 1))
    obs_state = (ref_obs.x.copy(), ref_obs.qd_model.copy(), ref_obs.u.copy(), ref_obs.bias.copy())
    integral0, nu0 = ref_ctrl.integral.copy(), ref_ctrl.nu_cmd.copy()
    pp, pR = pred_p.copy(), pred_R.copy()

    out = host_command(p_r, R_r, v_r, w_r, acc_r, p_v, R_v,
                       np.array([g.kp, g.ki, g.kd, g.integral_limit, g.max_accel, g.max_velocity]), dt, integral0,
                       nu0, to_handle, tau, J, joints, np.array([ws_hi, ws_lo]), 0.05, 0.02, k, pp, pR, dt,
                       *obs_state, np.array([vmax, amax]), dt, window, tau, history)
    nu_V, a_V, e, integ, nu_H, a_H, qd, x, qdm, u, e_p, e_r = out

    ref_nu_V, ref_a_V = ref_ctrl.step(p_r, R_r, np.concatenate([v_r, w_r]), acc_r, p_v, R_v)
    ref_nu_H, ref_a_H, ref_qd = handle_command(J, to_handle, ref_nu_V, ref_a_V, tau, joints, ws_hi, ws_lo, 0.05, 0.02)
    qd_np = compute_workspace_limit(joints, compute_dls(J, to_handle @ ref_nu_V + tau * (to_handle @ ref_a_V)),
                                    ws_hi, ws_lo)
    ref_obs.predict(k, ref_qd)
    advance_prediction(pred_p, pred_R, k, ref_nu_H, dt)
    pairs = ((nu_V, ref_nu_V), (a_V, ref_a_V), (e, ref_ctrl.error), (integ, ref_ctrl.integral), (nu_H, ref_nu_H),
             (a_H, ref_a_H), (qd, ref_qd), (qd, qd_np), (x, ref_obs.x), (qdm, ref_obs.qd_model), (u, ref_obs.u),
             (history[(k + 1) % HISTORY], ref_obs.x), (pp, pred_p), (pR, pred_R),
             ((e_p, e_r), (np.linalg.norm(ref_ctrl.error[:3]), np.linalg.norm(ref_ctrl.error[3:]))))
    for i, (got, ref) in enumerate(pairs):
        assert np.allclose(got, ref, rtol=1e-12, atol=1e-11), i


def _tool():
    tool = ReferenceTool(RigidBody(0.25, [0.0025] * 3), fixtures.rolling_disk(0.03),
                         [LinearDamper(1.0), AngularDamper(0.1)], integrator="parametric")
    tool.reset([0, 0, 0.03, 0, np.pi / 2, 0])
    return tool


def _state(m: CobotMaster) -> dict:
    return {"joints": m.driver.joints_rad_m, "p_H_est": m.p_H_est, "R_H_est": m.R_H_est, "nu_H": m.nu_H_cmd,
            "a_H": m.accel_H_cmd, "nu_c": m.ctrl.nu_cmd, "a_c": m.ctrl.accel_cmd, "e": m.ctrl.error,
            "integral": m.ctrl.integral, "x": m.observer.x, "qd_model": m.observer.qd_model, "u": m.observer.u,
            "bias": m.observer.bias, "history": m.observer.history, "pred_p": m.pred_p, "pred_R": m.pred_R,
            "err_max": np.array(m.err_max), "q_tool": m.tool.q}


@pytest.mark.parametrize("faults", [{}, {"latency_ms": 1.5, "jitter_ms": 1.0, "loss_pct": 3.0}])
def test_fused_master_runs_the_reference_trajectory(faults):
    """Two masters on the same seed, fused and piece by piece: the same state every period (late,
    jittered and lost frames exercise the carried-forward estimate; a clutch cycle and a contact
    wrench the other branches)."""
    cfg = CobotConfig.from_dict({"faults": faults, "stale_cycles": 50} if faults else {}, "test")
    masters = [CobotMaster(_tool(), cfg, 1e-3, np.random.default_rng(7), compiled=c) for c in (True, False)]
    for m in masters:
        m.start()
    try:
        for i in range(600):
            hand = np.array([3.0 * np.cos(i * 1e-2), 0.5, -1.0, 0.02, 0.0, 0.02 * np.sin(i * 1e-2)])
            contact = np.array([0.0, 0.3, 0.0, 0.0, 0.01, 0.0]) if 200 <= i < 260 else None
            for m in masters:
                if i == 300:
                    m.set_clutch(False)
                if i == 350:
                    m.set_clutch(True)
                assert m.step(hand, contact) == masters[0].status
            a, b = (_state(m) for m in masters)
            for key in a:
                assert np.allclose(a[key], b[key], rtol=1e-12, atol=1e-12), (i, key)
        assert masters[0].status == "ok"
    finally:
        for m in masters:
            m.close()
