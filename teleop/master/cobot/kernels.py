"""Compiled kernels (numba) of the cobot: the handle's distal wrench, the servo model, kinematics,
damped least squares, the pose prediction, and the host's period as two fused calls
(:func:`host_sense` in ``sense``, :func:`host_command` in ``command``) on one state record.

Each formula lives here once; the plant (:mod:`.plant`) and the host (:mod:`.host`) call the same
kernels. They are tested against independent references (Pinocchio's kinematics, Jacobian and
spatial inertia, finite differences, an ODE solver, the textbook DLS formula). Set
``NUMBA_DISABLE_JIT=1`` to run and debug them as plain Python. SI units: m, rad, N, N*m, s.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from teleop.control.kernels import pid_step
from teleop.dynamics.kernels.small import is_positive_definite, matmul, matvec, solve
from teleop.dynamics.kernels.so3 import exp3
from teleop.master.cobot.frame_kernels import end_cycle_counts


@njit(cache=True)
def _cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@njit(cache=True)
def distal_wrench_H(R, w_W, a_o_W, alpha_W, mass_kg, com_H, inertia_H, gravity_W):
    """The wrench (6,: N, N*m, at H, in the handle frame H) that the handle's weight and inertia put
    on the load cell, for handle rotation R (3, 3), angular velocity w_W (rad/s), origin
    acceleration a_o_W (m/s^2) and angular acceleration alpha_W (rad/s^2), all in the world frame;
    com_H (3,) m and inertia_H (3, 3) kg*m^2 about the COM are the handle's, in H."""
    Rt = R.T
    w, a_o, alpha = matvec(Rt, w_W), matvec(Rt, a_o_W), matvec(Rt, alpha_W)
    c = com_H
    a_c = a_o + _cross(alpha, c) + _cross(w, _cross(w, c))
    f = mass_kg * (matvec(Rt, gravity_W) - a_c)
    out = np.empty(6)
    out[:3] = f
    out[3:] = _cross(c, f) - matvec(inertia_H, alpha) - _cross(w, matvec(inertia_H, w))
    return out


@njit(cache=True)
def hand_wrench_W(wrench_S, bias_S, R, accel_W, w_W, mass_kg, com_H, inertia_H, gravity_W,
                  max_force_N, max_torque_Nm):
    """The hand's wrench (6,) at H, world: the load cell ``wrench_S`` (S = H frame) minus its tare
    ``bias_S``, minus :func:`distal_wrench_H` at the handle's commanded motion (w_W (3,), accel_W
    (6,: origin, angular)), force and torque each saturated to its norm limit."""
    F_H = wrench_S - bias_S - distal_wrench_H(R, w_W, accel_W[:3], accel_W[3:], mass_kg, com_H, inertia_H,
                                              gravity_W)
    for lo, lim in ((0, max_force_N), (3, max_torque_Nm)):
        n = math.sqrt(F_H[lo] ** 2 + F_H[lo + 1] ** 2 + F_H[lo + 2] ** 2)
        if n > lim:
            F_H[lo:lo + 3] *= lim / n
    out = np.empty(6)
    out[:3] = matvec(R, F_H[:3])
    out[3:] = matvec(R, F_H[3:])
    return out


@njit(cache=True)
def servo_advance(x, qd, u, h, tau, amax):
    """First-order velocity servos (lag tau s) under the command u (6,) for h s from joints x and
    rates qd (6,), exactly; when any joint's rate change would exceed amax h (amax (6,)), every
    joint ramps at its limit instead (trapezoidal position). Returns new (x, qd)."""
    n = x.shape[0]
    x, qd = x.copy(), qd.copy()
    if h <= 0.0:
        return x, qd
    e = math.exp(-h / tau)
    qd_new = np.empty(n)
    ramp = False
    for i in range(n):
        qd_new[i] = u[i] + (qd[i] - u[i]) * e
        ramp = ramp or abs(qd_new[i] - qd[i]) > amax[i] * h
    for i in range(n):
        if ramp:
            dv = amax[i] * h
            q1 = qd[i] + min(max(qd_new[i] - qd[i], -dv), dv)
            x[i] += 0.5 * (qd[i] + q1) * h
            qd[i] = q1
        else:
            x[i] += u[i] * h + (qd[i] - u[i]) * (tau * (1.0 - e))
            qd[i] = qd_new[i]
    return x, qd


@njit(cache=True)
def servo_acceleration(u, qd, tau, amax):
    """The first-order servos' joint acceleration (6,) under the command u (6,) at rates qd (6,):
    (u - qd) / tau, each clipped to its limit amax (6,)."""
    out = np.empty(u.shape[0])
    for i in range(u.shape[0]):
        out[i] = min(max((u[i] - qd[i]) / tau, -amax[i]), amax[i])
    return out


@njit(cache=True)
def predict_kernel(x, qd, u_old, u_cmd, bias, vmax, amax, dt, window, tau):
    """The joint observer's prediction over one period (:meth:`.observer.JointObserver.predict`):
    the servo model (:func:`servo_advance`) under the old command u_old for ``window`` s, then
    under u_cmd clipped to vmax for dt - window s, plus the rate bias over dt. Returns new
    (x, qd_model, u_new)."""
    n = x.shape[0]
    u_new = np.empty(n)
    for i in range(n):
        u_new[i] = min(max(u_cmd[i], -vmax[i]), vmax[i])
    x, qd = servo_advance(x, qd, u_old, window, tau, amax)
    x, qd = servo_advance(x, qd, u_new, dt - window, tau, amax)
    for i in range(n):
        x[i] += bias[i] * dt
    return x, qd, u_new


@njit(cache=True)
def correct_kernel(history, x, bias, y, j, k, alpha, beta, dt):
    """The joint observer's correction (:meth:`.observer.JointObserver.correct`) by a reading y
    (n,) of SYNC j fused at SYNC k: history (H, n) in place; returns new (x, bias)."""
    H, n = history.shape
    lag = (k - j) % H
    jj = j % H
    x, bias = x.copy(), bias.copy()
    for i in range(n):
        r = y[i] - history[jj, i]
        dx, db = alpha * r, (beta / dt) * r
        for m in range(1, lag + 1):
            history[(j + m) % H, i] += dx + m * dt * db
        x[i] += dx + db * (lag * dt)
        bias[i] += db
    return x, bias


@njit(cache=True)
def _smallest_singular_value_above(J, sigma0):
    """Whether every singular value of J exceeds sigma0: JᵀJ - sigma0² I positive definite (its
    Cholesky factorization exists). A tenth of the SVD's cost or less (the 6x6 SVD in numba: about
    25 µs on this machine, 2026-11; the Cholesky in loops well under 1 µs)."""
    A = matmul(J.T, J)
    for i in range(A.shape[0]):
        A[i, i] -= sigma0 * sigma0
    return is_positive_definite(A)


@njit(cache=True)
def dls_command(J, twist, joints, ws_hi, ws_lo, sigma0, lam0):
    """Joint rates (6,) for a handle twist (6,) by damped least squares (no damping while the
    smallest singular value of J exceeds sigma0, then lam^2 = lam0^2 (1 - (s_min/sigma0)^2)), then
    the workspace limit: a rate that drives a joint past ws_hi or ws_lo (6,) is zeroed. Undamped,
    the rates solve J qd = twist (LU); the SVD is taken only near a singularity."""
    ok = _smallest_singular_value_above(J, sigma0)
    if ok:
        ok, qd = solve(J, twist)
    if not ok:
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
def handle_command(J, to_handle, nu_V, a_V, tau, joints, ws_hi, ws_lo, sigma0, lam0):
    """The virtual command (twist nu_V (6,), acceleration a_V (6,)) mapped to the handle by φ's
    6x6 ``to_handle``, and the joint rates for nu_H + tau a_H (tau: servo lag, s) by
    :func:`dls_command`. Returns nu_H, a_H, qd (6,) each."""
    nu_H = matvec(to_handle, nu_V)
    a_H = matvec(to_handle, a_V)
    return nu_H, a_H, dls_command(J, nu_H + tau * a_H, joints, ws_hi, ws_lo, sigma0, lam0)


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


# -- the host's period: two calls --------------------------------------------------------------------

#: the host's state between periods, one record (a numpy structured array of shape (1,)): the kernels
#: below read and write it in place, the host, its controller and its observer hold views of its
#: fields. ctrl rows: commanded virtual twist ν_c, commanded acceleration, error e, integral of e;
#: obs rows: joints x, servo-model rates, command in force, rate bias (6 each, see .observer);
#: nu_H, a_H: the handle's commanded twist and acceleration; F_hand: the hand's wrench (world, at H);
#: f_v: its image by φ (eq. 4); p_est/R_est: the handle pose estimated for this SYNC, p_v/R_v: φ of
#: it; p_m/R_m/J: the measured pose and Jacobian; qd: the joint rates commanded; err_max: the maxima
#: of the tracking error |e[:3]| m, |e[3:]| rad while engaged; per SYNC counter:
#: obs_hist (the observer's estimates), pred_p/pred_R (the pose the commands predict),
#: accel_model (the servo model's handle acceleration).
HISTORY = 256  # the SYNC counter's range
HOST_STATE = np.dtype([
    ("ctrl", "f8", (4, 6)), ("obs", "f8", (4, 6)), ("nu_H", "f8", 6), ("a_H", "f8", 6), ("F_hand", "f8", 6),
    ("f_v", "f8", 6), ("p_est", "f8", 3), ("R_est", "f8", (3, 3)), ("p_v", "f8", 3), ("R_v", "f8", (3, 3)),
    ("p_m", "f8", 3), ("R_m", "f8", (3, 3)), ("J", "f8", (6, 6)), ("qd", "f8", 6), ("err_max", "f8", 2),
    ("obs_hist", "f8", (HISTORY, 6)), ("pred_p", "f8", (HISTORY, 3)), ("pred_R", "f8", (HISTORY, 3, 3)),
    ("accel_model", "f8", (HISTORY, 6))])
#: the constants the host's kernels read, one record (rebuilt when φ, the gains or the observer's
#: limits are replaced): gains rows kp, ki, kd, integral_limit, max_accel, max_velocity; obs_lim rows
#: velocity, acceleration limits; ws rows workspace upper, lower; the handle's mass, COM and inertia
#: (H frame), gravity (world), the wrench saturation; φ's maps and offset; tau: servo lag (s), dt:
#: host period, dt_ctrl: controller period, obs_dt/obs_window/obs_tau/alpha/beta: the observer's;
#: sigma0/lam0: DLS; servo_model: 1 for the servo-model inertia compensation, 0 for the commanded;
#: vmax (6,): the device's velocity limits; free_damping (6,): the clutched-out admittance.
HOST_CONSTS = np.dtype([
    ("gains", "f8", (6, 6)), ("obs_lim", "f8", (2, 6)), ("ws", "f8", (2, 6)), ("mass", "f8"), ("com", "f8", 3),
    ("inertia", "f8", (3, 3)), ("gravity", "f8", 3), ("max_force", "f8"), ("max_torque", "f8"),
    ("wrench_map", "f8", (6, 6)), ("to_handle", "f8", (6, 6)), ("off_p", "f8", 3), ("scale", "f8"),
    ("off_R", "f8", (3, 3)), ("tau", "f8"), ("dt", "f8"), ("dt_ctrl", "f8"), ("obs_dt", "f8"),
    ("obs_window", "f8"), ("obs_tau", "f8"), ("alpha", "f8"), ("beta", "f8"), ("sigma0", "f8"),
    ("lam0", "f8"), ("servo_model", "i8"), ("vmax", "f8", 6), ("free_damping", "f8", 6)])


@njit(cache=True)
def host_feedback(p_m, R_m, k, j, pred_p, pred_R, wrench_S, bias_S, accel_H_cmd, nu_H_cmd, mass_kg, com_H,
                  inertia_H, gravity_W, max_force_N, max_torque_Nm, wrench_map, off_p, scale, off_R):
    """The feedback half of a period: the measured handle pose (p_m (3,) m, R_m) of SYNC j carried
    forward to SYNC k by the predicted poses (pred_p (N, 3), pred_R (N, 3, 3)), the hand's wrench
    (:func:`hand_wrench_W` at the measured rotation) and its image by φ's ``wrench_map`` (6, 6)
    (eq. 4), and φ of the estimated pose (offset off_p (3,) m, off_R, scale).

    Returns p_H_est (3,), R_H_est (3, 3), F_hand_W (6,), f_v (6,), p_v (3,), R_v (3, 3)."""
    if j == k:
        p_est, R_est = p_m, R_m
    else:
        p_est = p_m + pred_p[k] - pred_p[j]
        R_est = matmul(matmul(pred_R[k], pred_R[j].T), R_m)
    F = hand_wrench_W(wrench_S, bias_S, R_m, accel_H_cmd, nu_H_cmd[3:], mass_kg, com_H, inertia_H, gravity_W,
                      max_force_N, max_torque_Nm)
    return p_est, R_est, F, matvec(wrench_map, F), off_p + scale * matvec(off_R, p_est), matmul(off_R, R_est)


@njit(cache=True)
def host_sense(hs, hc, ds, k, bias_S, stale_cycles, feedback, closed_form):
    """The host's ``sense`` on its state record ``hs`` (:data:`HOST_STATE`, in place) with the
    constants ``hc`` (:data:`HOST_CONSTS`) and the driver's receive record ``ds``
    (:data:`.frame_kernels.DRIVER_STATE`) after this period's read: a fresh joint reading (taken at
    SYNC ``ds.jc``) corrects the observer (:func:`correct_kernel`) for SYNC k; the feedback ages by
    the cycle (:func:`.frame_kernels.end_cycle_counts`); then, with ``feedback`` (no fault latched)
    and the feedback not ``stale_cycles`` old, the handle's pose and Jacobian
    (:func:`gantry_zxz_pose_jacobian` when ``closed_form``, else the caller's, already in ``p_m``,
    ``R_m``, ``J``) and :func:`host_feedback` on the load cell reading (of SYNC ``ds.wc``), its tare
    ``bias_S`` (6,) removed, with the handle acceleration of the servo model at that SYNC or the
    commanded one (``servo_model``). Returns whether the feedback is stale (the watchdog trips)."""
    r, c, d = hs[0], hc[0], ds[0]
    obs, joints, j = r["obs"], d["joints"], d["jc"]
    if d["fresh_j"] != 0:
        x, b = correct_kernel(r["obs_hist"], obs[0].copy(), obs[3].copy(), joints, j, k, c["alpha"], c["beta"],
                              c["obs_dt"])
        obs[0, :] = x
        obs[3, :] = b
    stale = end_cycle_counts(ds, stale_cycles)
    if not feedback or stale:
        return stale
    if closed_form:
        p, R, J = gantry_zxz_pose_jacobian(joints)
        r["p_m"][:] = p
        r["R_m"][:, :] = R
        r["J"][:, :] = J
    accel = r["accel_model"][d["wc"] % HISTORY].copy() if c["servo_model"] else r["a_H"].copy()
    p_est, R_est, F, f_v, p_v, R_v = host_feedback(
        r["p_m"].copy(), r["R_m"].copy(), k, j, r["pred_p"], r["pred_R"], d["wrench"], bias_S, accel, r["nu_H"],
        c["mass"], c["com"], c["inertia"], c["gravity"], c["max_force"], c["max_torque"], c["wrench_map"], c["off_p"],
        c["scale"], c["off_R"])
    r["p_est"][:] = p_est
    r["R_est"][:, :] = R_est
    r["F_hand"][:] = F
    r["f_v"][:] = f_v
    r["p_v"][:] = p_v
    r["R_v"][:, :] = R_v
    return stale


@njit(cache=True)
def host_command(hs, hc, p_r, R_r, nu_r, accel_r, joints, k, engaged):
    """The host's ``command`` on its state record ``hs`` (:data:`HOST_STATE`, in place) with the
    constants ``hc`` (:data:`HOST_CONSTS`), for the reference tool's pose (p_r (3,) m, R_r), twist
    nu_r (6,) and acceleration accel_r (6,) and the joints (6,) read at SYNC k.

    ``engaged``: the PID (:func:`teleop.control.kernels.pid_step`, eqs. 18-19) on the virtual pose
    φ(estimate), then :func:`handle_command` (φ to the handle, DLS, workspace limit). Clutched
    out: the handle follows the hand's wrench through the admittance ``free_damping`` (clipped to
    ``vmax``), its acceleration the change over dt, the joint rates for nu_H + tau a_H by
    :func:`dls_command`. Then, either way: the observer's prediction for SYNC k+1
    (:func:`predict_kernel`, its estimate kept for SYNC k+1), :func:`advance_prediction` and the
    servo model's handle acceleration at SYNC k+1 (J times :func:`servo_acceleration`). The
    commanded joint rates land in ``qd``. Returns the error norms |e[:3]| m, |e[3:]| rad (0, 0
    clutched out), their maxima kept in ``err_max``."""
    r, c = hs[0], hc[0]
    ctrl, obs, g = r["ctrl"], r["obs"], c["gains"]
    e_p = e_r = 0.0
    if engaged:
        nu_V, a_V, e, integ = pid_step(p_r, R_r, nu_r, accel_r, r["p_v"], r["R_v"], g[0], g[1], g[2], g[3], g[4], g[5],
                                       c["dt_ctrl"], ctrl[3], ctrl[0])
        ctrl[0, :] = nu_V
        ctrl[1, :] = a_V
        ctrl[2, :] = e
        ctrl[3, :] = integ
        e_p = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
        e_r = math.sqrt(e[3] * e[3] + e[4] * e[4] + e[5] * e[5])
        err_max = r["err_max"]
        err_max[0] = max(err_max[0], e_p)
        err_max[1] = max(err_max[1], e_r)
        nu_H, a_H, qd = handle_command(r["J"], c["to_handle"], nu_V, a_V, c["tau"], joints, c["ws"][0], c["ws"][1],
                                       c["sigma0"],
                                       c["lam0"])
    else:
        nu_H, a_H = np.empty(6), np.empty(6)
        for i in range(6):
            nu_H[i] = min(max(r["F_hand"][i] / c["free_damping"][i], -c["vmax"][i]), c["vmax"][i])
            a_H[i] = (nu_H[i] - r["nu_H"][i]) / c["dt"]
        qd = dls_command(r["J"], nu_H + c["tau"] * a_H, joints, c["ws"][0], c["ws"][1], c["sigma0"], c["lam0"])
    x, qdm, u = predict_kernel(obs[0].copy(), obs[1].copy(), obs[2].copy(), qd, obs[3], c["obs_lim"][0],
                               c["obs_lim"][1], c["obs_dt"], c["obs_window"], c["obs_tau"])
    obs[0, :] = x
    obs[1, :] = qdm
    obs[2, :] = u
    r["obs_hist"][(k + 1) % HISTORY, :] = x
    advance_prediction(r["pred_p"], r["pred_R"], k, nu_H, c["dt"])
    r["nu_H"][:] = nu_H
    r["a_H"][:] = a_H
    r["qd"][:] = qd
    r["accel_model"][(k + 1) % HISTORY, :] = matvec(r["J"], servo_acceleration(u, qdm, c["tau"], c["obs_lim"][1]))
    return e_p, e_r
