"""Compiled SO(3) maps (numba), shared by the master, the controller, the slave kernels and the
Euler charts of the engine.

``pinocchio.log3`` and ``pinocchio.exp3`` are the references of :func:`log3` and :func:`exp3`
(tests/unit/test_master_kernels.py), scipy's ``Rotation.as_euler`` that of :func:`euler_angles`
(tests/unit/test_rotations.py).
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
def exp3(r):
    """Rotation matrix (3, 3) of a rotation vector r (3,) rad (Rodrigues; series near 0)."""
    t2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
    t = math.sqrt(t2)
    if t < 1e-4:
        a, b = 1.0 - t2 / 6.0, 0.5 - t2 / 24.0
    else:
        a, b = math.sin(t) / t, (1.0 - math.cos(t)) / t2
    x, y, z = r[0], r[1], r[2]
    return np.array([[1.0 - b * (y * y + z * z), -a * z + b * x * y, a * y + b * x * z],
                     [a * z + b * x * y, 1.0 - b * (x * x + z * z), -a * x + b * y * z],
                     [-a * y + b * x * z, a * x + b * y * z, 1.0 - b * (x * x + y * y)]])


@njit(cache=True)
def euler_angles(R0, axes, R_WB):
    """Euler angles (3,) rad of R_WB (3, 3) in the chart (R0 (3, 3), axes (3,) int64) with
    R_WB = R0 R_a(t1) R_b(t2) R_c(t3); see :func:`teleop.dynamics.rotations.euler_from_rotation`.

    Why not scipy's ``Rotation.from_matrix(R).as_euler(seq)``, the oracle of the tests: about
    25 us per call on an idle core (140 us measured on the loaded CI machine), against some
    30 us for a whole engine step, which asks for it once (``lie_group``) or twice (a surface
    fixture's psi and Jacobian); this is about 1 us from Python.

    Closed form (scipy's conventions: t1, t3 in (-pi, pi], t2 in [-pi/2, pi/2] for Tait-Bryan and
    [0, pi] for proper sequences), t2 from atan2 so it stays accurate near the chart centre. With d
    the remaining axis, s = +1 when (a, b, c) (Tait-Bryan) or (a, b, d) (proper) is a cyclic
    order of (x, y, z), else -1:

    * Tait-Bryan: sin t2 = s R_ac; t1 = atan2(-s R_bc, R_cc); t3 = atan2(-s R_ab, R_aa).
    * proper:     cos t2 = R_aa;   t1 = atan2(R_ba, -s R_da); t3 = atan2(R_ab, s R_ad).
    """
    R = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            R[i, j] = R0[0, i] * R_WB[0, j] + R0[1, i] * R_WB[1, j] + R0[2, i] * R_WB[2, j]
    a, b, c = axes[0], axes[1], axes[2]
    s = 1.0 if (b - a) % 3 == 1 else -1.0
    out = np.empty(3)
    if a != c:
        out[0] = math.atan2(-s * R[b, c], R[c, c])
        out[1] = math.atan2(s * R[a, c], math.hypot(R[b, c], R[c, c]))
        out[2] = math.atan2(-s * R[a, b], R[a, a])
        return out
    d = 3 - a - b
    out[0] = math.atan2(R[b, a], -s * R[d, a])
    out[1] = math.atan2(math.hypot(R[a, b], R[a, d]), R[a, a])
    out[2] = math.atan2(R[a, b], s * R[a, d])
    return out
