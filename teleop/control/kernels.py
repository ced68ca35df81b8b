"""Compiled kernels (numba) of the admittance controller's hot path.

Why compiled: one PID period is some twenty operations on 6-vectors and a rotation log; in numpy
each costs about a microsecond of call overhead whatever its size. Here the period is one call.

The readable definitions stay in Python and are the reference: ``pinocchio.log3`` for
:func:`log3`, and ``AdmittanceController.step`` with ``compiled=False`` for :func:`pid_step`;
tests/unit/test_control_kernels.py checks each kernel against them. Units as in
:mod:`teleop.control.admittance` (SI, world frame).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: below this angle (rad) log3 uses the series of theta / (2 sin theta)
SMALL_ANGLE = 1e-4
#: above this cos(theta) magnitude near pi (cos < -NEAR_PI_COS) the axis comes from R's symmetric part
NEAR_PI_COS = 0.9


@njit(cache=True)
def log3(R):
    """Rotation vector (3,) rad of a rotation matrix R (3, 3), angle in [0, pi]."""
    s_vec = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) * 0.5  # sin(theta) axis
    s = math.sqrt(s_vec[0] ** 2 + s_vec[1] ** 2 + s_vec[2] ** 2)
    c = min(1.0, max(-1.0, 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)))
    theta = math.atan2(s, c)
    if theta < SMALL_ANGLE:
        return s_vec * (1.0 + theta * theta / 6.0)  # theta / sin(theta) to second order
    if c > -NEAR_PI_COS:
        return s_vec * (theta / s)
    # near pi: a a^T = ((R + R^T) / 2 - c I) / (1 - c); take the largest diagonal, sign from s_vec
    B = (0.5 * (R + R.T) - c * np.eye(3)) / (1.0 - c)
    i = np.argmax(np.diag(B))
    axis = B[i] / math.sqrt(B[i, i])
    if axis @ s_vec < 0.0:
        axis = -axis
    return axis * theta


@njit(cache=True)
def pid_step(p_r, R_r, nu_r, accel_r, p_v, R_v, kp, ki, kd, integral_limit, max_accel, max_velocity,
             dt, integral, nu_cmd):
    """One period of eqs. 18-19 (see ``AdmittanceController.step``).

    Returns (nu_c (6,), accel commanded (6,), error e (6,), integral (6,)), all new arrays.
    """
    e = np.empty(6)
    e[:3] = p_r - p_v
    e[3:] = log3(R_r @ R_v.T)
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
