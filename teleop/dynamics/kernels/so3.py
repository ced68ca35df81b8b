"""Compiled SO(3) maps (numba), shared by the master, the controller and the slave kernels.

``pinocchio.log3`` and ``pinocchio.exp3`` are the references (tests/unit/test_master_kernels.py).
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
