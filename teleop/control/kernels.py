"""Compiled kernels (numba) of the admittance controller's hot path.

Why compiled: one PID period is some twenty operations on 6-vectors and a rotation log; in numpy
each costs about a microsecond of call overhead whatever its size. Here the period is one call.

This is the one definition of the PID period; tests/unit/test_admittance.py checks it against
hand-computed steps and its closed-loop behaviour (run it uncompiled with ``NUMBA_DISABLE_JIT=1``).
The rotation log is :func:`teleop.dynamics.kernels.so3.log3`. Units as in
:mod:`teleop.control.admittance` (SI, world frame).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from teleop.dynamics.kernels.small import matmul, solve
from teleop.dynamics.kernels.so3 import log3


@njit(cache=True)
def pid_step(p_r, R_r, nu_r, accel_r, p_v, R_v, kp, ki, kd, integral_limit, max_accel, max_velocity,
             dt, integral, nu_cmd):
    """One period of eqs. 18-19: e = (p_r - p_v, log(R_r R_vᵀ)); the integral of e clamped to
    ±integral_limit; q̈ = accel_r + kp e + ki ∫e + kd (nu_r - nu_cmd) clamped to ±max_accel;
    ν = nu_cmd + q̈ dt clamped to ±max_velocity; the integral holds on a saturated axis; the
    acceleration returned is the one actually commanded, (ν - nu_cmd) / dt. Gains (6,) each.

    Returns (nu_c (6,), accel commanded (6,), error e (6,), integral (6,)), all new arrays.
    """
    e = np.empty(6)
    e[:3] = p_r - p_v
    e[3:] = log3(matmul(R_r, R_v.T))
    nu, accel_out, integral_out = np.empty(6), np.empty(6), np.empty(6)
    for i in range(6):
        integ = min(max(integral[i] + e[i] * dt, -integral_limit[i]), integral_limit[i])
        a = accel_r[i] + kp[i] * e[i] + ki[i] * integ + kd[i] * (nu_r[i] - nu_cmd[i])
        a_sat = min(max(a, -max_accel[i]), max_accel[i])
        v = nu_cmd[i] + a_sat * dt
        v_sat = min(max(v, -max_velocity[i]), max_velocity[i])
        integral_out[i] = integral[i] if (a_sat != a or v_sat != v) else integ
        nu[i] = v_sat
        accel_out[i] = a_sat + (v_sat - v) / dt
    return nu, accel_out, e, integral_out


@njit(cache=True)
def render_local_damping(mass, J_B, R, V, f, channel, D, dt):
    """The contact's damping rendered implicitly on the free tool (:mod:`teleop.tick.feedback`):
    V+ from (M + dt D) V+ = M V + dt (f + channel), M = blockdiag(mass I, R J_B R^T) (kg, kg*m^2),
    V (6,) the tool's twist (m/s, rad/s, world), f (6,) the hand's and the tool's own wrench,
    ``channel`` (6,) the channel's force F0 (N, N*m), D (6, 6). Returns (ok, channel - D V+);
    ok False when the system is singular (the wrench is then not meaningful)."""
    JW = matmul(matmul(R, J_B), R.T)
    A = np.empty((6, 6))
    rhs = np.empty(6)
    for i in range(6):
        for j in range(6):
            A[i, j] = dt * D[i, j]
    for i in range(3):
        A[i, i] += mass
        rhs[i] = mass * V[i] + dt * (f[i] + channel[i])
        s = 0.0
        for j in range(3):
            A[3 + i, 3 + j] += JW[i, j]
            s += JW[i, j] * V[3 + j]
        rhs[3 + i] = s + dt * (f[3 + i] + channel[3 + i])
    ok, V_next = solve(A, rhs)
    W = np.empty(6)
    for i in range(6):
        s = channel[i]
        for j in range(6):
            s -= D[i, j] * V_next[j]
        W[i] = s
    return ok, W


@njit(cache=True)
def damping_to_master(Rb, gc, D):
    """The contact damping D (6, 6; W_P = -D V_P) as the master feels it (:meth:`teleop.control.
    mapping.Registration.damping_to_master`): the symmetric part of D_M = (Rb^T D Rb) * gc, Rb
    (6, 6) blockdiag(R_PM, R_PM), gc (6, 6) the gains (force or torque scale over the motion
    scale) elementwise. A new array."""
    M = matmul(Rb.T, matmul(D, Rb))
    out = np.empty((6, 6))
    for i in range(6):
        for j in range(6):
            out[i, j] = 0.5 * (M[i, j] * gc[i, j] + M[j, i] * gc[j, i])
    return out


@njit(cache=True, inline="always")
def _to_patient(p_PM, R_PM, scale, x, out):
    """out (3,) = p_PM + R_PM x / scale: a master point x (m) in the patient frame (m)."""
    for i in range(3):
        out[i] = p_PM[i] + (R_PM[i, 0] * x[0] + R_PM[i, 1] * x[1] + R_PM[i, 2] * x[2]) / scale


@njit(cache=True)
def point_to_patient(p_PM, R_PM, scale, x):
    """A master point x (3,) m in the patient frame (:meth:`teleop.control.mapping.Registration.
    point_to_patient`), a new array."""
    out = np.empty(3)
    _to_patient(p_PM, R_PM, scale, x, out)
    return out


@njit(cache=True)
def target_to_patient(p_PM, R_PM, scale, p, R, v, w, out):
    """(p m, R, v m/s, w rad/s) of the master's tool (M) as the slave's target (P), into out (18,)
    = (p, R row-major, v, w) (:meth:`teleop.control.mapping.Registration.target`): the point
    through :func:`point_to_patient`'s map, R_PM R, R_PM v / scale and R_PM w."""
    _to_patient(p_PM, R_PM, scale, p, out[0:3])
    for i in range(3):
        for j in range(3):
            out[3 + 3 * i + j] = R_PM[i, 0] * R[0, j] + R_PM[i, 1] * R[1, j] + R_PM[i, 2] * R[2, j]
        out[12 + i] = (R_PM[i, 0] * v[0] + R_PM[i, 1] * v[1] + R_PM[i, 2] * v[2]) / scale
        out[15 + i] = R_PM[i, 0] * w[0] + R_PM[i, 1] * w[1] + R_PM[i, 2] * w[2]
