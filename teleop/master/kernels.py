"""Compiled kernels (numba) of the host's period: load-cell compensation, DLS, kinematics,
prediction, and the two fused halves of a period (:func:`host_feedback`, :func:`host_command`).

The readable reference of the load-cell kernel is :func:`compute_hand_wrench_W` below (numpy, with
the device model's :meth:`~teleop.master.cobot.CobotModel.compute_distal_wrench_W`);
tests/unit/test_master_kernels.py checks the kernel against it. SI units: N, N*m, m/s^2, rad/s,
rad/s^2.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from teleop.control.kernels import pid_step as _pid_step
from teleop.dynamics.kernels.so3 import exp3
from teleop.master.observer import _predict as _observer_predict


def compute_hand_wrench_W(model, wrench_S, bias_S, R, accel_W, w_W, max_force_N, max_torque_Nm):
    """The hand's wrench (6,) at H, world: the load cell ``wrench_S`` (S = H frame) minus its tare
    ``bias_S``, minus the distal handle's weight and inertia at handle rotation R, angular velocity
    ``w_W`` (3,) and acceleration ``accel_W`` (6,: origin, angular), each half saturated."""
    meas = wrench_S - bias_S
    distal = model.compute_distal_wrench_W(R, w_W, accel_W[:3], accel_W[3:])
    F = np.concatenate([R @ meas[:3], R @ meas[3:]]) - distal
    for sl, lim in ((slice(0, 3), max_force_N), (slice(3, 6), max_torque_Nm)):
        n = float(np.linalg.norm(F[sl]))
        if n > lim:
            F[sl] *= lim / n
    return F


@njit(cache=True)
def _cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@njit(cache=True)
def hand_wrench_W(wrench_S, bias_S, R, accel_W, w_W, mass_kg, com_H, inertia_H, gravity_W,
                  max_force_N, max_torque_Nm):
    """:func:`compute_hand_wrench_W` in the handle frame, in one pass; com_H (3,) m and inertia_H
    (3, 3) kg*m^2 about the COM are the handle's, in H."""
    Rt = R.T
    w, a_o, alpha = Rt @ w_W, Rt @ accel_W[:3], Rt @ accel_W[3:]
    c = com_H
    a_c = a_o + _cross(alpha, c) + _cross(w, _cross(w, c))
    f = mass_kg * (Rt @ gravity_W - a_c)
    tau = _cross(c, f) - inertia_H @ alpha - _cross(w, inertia_H @ w)
    F_H = wrench_S - bias_S
    F_H[:3] -= f
    F_H[3:] -= tau
    for lo, lim in ((0, max_force_N), (3, max_torque_Nm)):
        n = np.sqrt(F_H[lo] ** 2 + F_H[lo + 1] ** 2 + F_H[lo + 2] ** 2)
        if n > lim:
            F_H[lo:lo + 3] *= lim / n
    out = np.empty(6)
    out[:3] = R @ F_H[:3]
    out[3:] = R @ F_H[3:]
    return out


@njit(cache=True)
def handle_command(J, to_handle, nu_V, a_V, tau, joints, ws_hi, ws_lo, sigma0, lam0):
    """The virtual command (twist nu_V (6,), acceleration a_V (6,)) mapped to the handle by the
    6x6 map ``to_handle`` (φ's), and the joint rates for nu_H + tau a_H by :func:`dls_command`
    (tau: servo lag, s). Returns nu_H, a_H, qd (6,) each."""
    nu_H = to_handle @ nu_V
    a_H = to_handle @ a_V
    return nu_H, a_H, dls_command(J, nu_H + tau * a_H, joints, ws_hi, ws_lo, sigma0, lam0)


@njit(cache=True)
def dls_command(J, twist, joints, ws_hi, ws_lo, sigma0, lam0):
    """Joint rates (6,) for a handle twist (6,): :func:`teleop.master.cobot_master.compute_dls`
    (damped least squares, no damping while the smallest singular value exceeds sigma0) followed by
    the workspace limit (a rate that drives a joint past ws_hi or ws_lo (6,) is zeroed), in one pass."""
    U, S, Vt = np.linalg.svd(J)
    smin = S[-1]
    lam2 = 0.0 if smin >= sigma0 else lam0 * lam0 * (1.0 - (smin / sigma0) ** 2)
    y = U.T @ twist
    for i in range(6):
        y[i] *= S[i] / (S[i] * S[i] + lam2)
    qd = Vt.T @ y
    for i in range(6):
        if (joints[i] > ws_hi[i] and qd[i] > 0.0) or (joints[i] < ws_lo[i] and qd[i] < 0.0):
            qd[i] = 0.0
    return qd


@njit(cache=True)
def gantry_zxz_pose_jacobian(joints):
    """Closed-form kinematics of a 3-axis gantry (x, y, z in m) carrying a Z-X-Z wrist (a, b, c in
    rad) whose axes meet at the handle origin: p (3,), R = Rz(a) Rx(b) Rz(c) (3, 3) and the
    Jacobian (6, 6) from joint rates to the handle twist (v, w), world axes at the handle."""
    a, b, c = joints[3], joints[4], joints[5]
    ca, sa, cb, sb, cc, sc = math.cos(a), math.sin(a), math.cos(b), math.sin(b), math.cos(c), math.sin(c)
    p = joints[:3].copy()
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = ca * cc - sa * cb * sc, -ca * sc - sa * cb * cc, sa * sb
    R[1, 0], R[1, 1], R[1, 2] = sa * cc + ca * cb * sc, -sa * sc + ca * cb * cc, -ca * sb
    R[2, 0], R[2, 1], R[2, 2] = sb * sc, sb * cc, cb
    J = np.zeros((6, 6))
    J[0, 0] = J[1, 1] = J[2, 2] = 1.0
    J[5, 3] = 1.0  # wrist a about world z
    J[3, 4], J[4, 4] = ca, sa  # wrist b about Rz(a) x
    J[3, 5], J[4, 5], J[5, 5] = sa * sb, -ca * sb, cb  # wrist c about Rz(a) Rx(b) z
    return p, R, J


@njit(cache=True)
def advance_prediction(pred_p, pred_R, k, nu, dt):
    """In place: the handle pose the commands predict at SYNC k+1 (mod len) from the one at SYNC
    k and the commanded handle twist nu (6,) held for dt s: p += v dt, R <- exp(w dt) R."""
    n = (k + 1) % pred_p.shape[0]
    E = exp3(nu[3:] * dt)
    for i in range(3):
        pred_p[n, i] = pred_p[k, i] + nu[i] * dt
        for j in range(3):
            pred_R[n, i, j] = E[i, 0] * pred_R[k, 0, j] + E[i, 1] * pred_R[k, 1, j] + E[i, 2] * pred_R[k, 2, j]


# -- the host period fused: two calls instead of seven ---------------------------------------------
# The per-piece path of CobotMaster (``compiled=False``: observer, kinematics, load-cell kernel, φ in
# numpy, PID, DLS, prediction, one call each) is the reference of these two; they run the same
# arithmetic in the same order (tests/unit/test_master_fused.py holds them equal).

@njit(cache=True)
def host_feedback(joints, k, j, pred_p, pred_R, wrench_S, bias_S, accel_H_cmd, nu_H_cmd, mass_kg, com_H,
                  inertia_H, gravity_W, max_force_N, max_torque_Nm, wrench_map, off_p, scale, off_R):
    """The feedback half of a period (gantry + Z-X-Z closed form): the handle pose and Jacobian from
    ``joints``, the measurement of SYNC j carried forward to SYNC k by the predicted poses, the
    hand's wrench (:func:`hand_wrench_W` at the measured rotation) mapped to the virtual tool by
    φ's ``wrench_map`` (6, 6), and φ of the estimated pose (offset off_p, off_R, scale).

    Returns J (6, 6), p_H_est (3,), R_H_est (3, 3), f_v (6,), p_v (3,), R_v (3, 3)."""
    p_m, R_m, J = gantry_zxz_pose_jacobian(joints)
    if j == k:
        p_est, R_est = p_m, R_m
    else:
        p_est = p_m + pred_p[k] - pred_p[j]
        R_est = pred_R[k] @ pred_R[j].T @ R_m
    F = hand_wrench_W(wrench_S, bias_S, R_m, accel_H_cmd, nu_H_cmd[3:], mass_kg, com_H, inertia_H, gravity_W,
                      max_force_N, max_torque_Nm)
    f_v = wrench_map @ F
    p_v = off_p + scale * (off_R @ p_est)
    R_v = off_R @ R_est
    return J, p_est, R_est, f_v, p_v, R_v


@njit(cache=True)
def host_command(p_r, R_r, v_r, w_r, accel_r, p_v, R_v, gains, dt_ctrl, integral, nu_cmd, to_handle, tau, J,
                 joints, ws, sigma0, lam0, k, pred_p, pred_R, dt, obs_x, obs_qd, obs_u, obs_bias, obs_lim,
                 obs_dt, obs_window, obs_tau, history):
    """The command half of a period: the PID (``teleop.control.kernels.pid_step`` with the gains
    (6, 6): kp, ki, kd, integral_limit, max_accel, max_velocity by row), :func:`handle_command`
    (ws (2, 6): workspace upper, lower), the observer's prediction for SYNC k+1 (obs_lim (2, 6):
    velocity, acceleration limits; ``history`` row k+1 in place) and :func:`advance_prediction`
    (pred_p, pred_R in place; the handle twist held for dt s). dt_ctrl, obs_dt: the controller's
    and the observer's periods (s).

    Returns (nu_V, a_V, e, integral, nu_H, a_H, qd, obs_x, obs_qd, obs_u) (6,) each, and the
    position and rotation error norms |e[:3]|, |e[3:]|."""
    nu_r = np.empty(6)
    nu_r[:3] = v_r
    nu_r[3:] = w_r
    nu_V, a_V, e, integ = _pid_step(p_r, R_r, nu_r, accel_r, p_v, R_v, gains[0], gains[1], gains[2], gains[3],
                                    gains[4], gains[5], dt_ctrl, integral, nu_cmd)
    e_p = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    e_r = math.sqrt(e[3] * e[3] + e[4] * e[4] + e[5] * e[5])
    nu_H, a_H, qd = handle_command(J, to_handle, nu_V, a_V, tau, joints, ws[0], ws[1], sigma0, lam0)
    x, qdm, u = _observer_predict(obs_x, obs_qd, obs_u, qd, obs_bias, obs_lim[0], obs_lim[1], obs_dt,
                                  obs_window, obs_tau)
    history[(k + 1) % history.shape[0]] = x
    advance_prediction(pred_p, pred_R, k, nu_H, dt)
    return nu_V, a_V, e, integ, nu_H, a_H, qd, x, qdm, u, e_p, e_r
