"""Compiled kernels (numba) of the plausibility rules (:mod:`teleop.tick.plausible`).

Why compiled: each rule is a handful of products on 3- and 6-vectors, which in numpy cost about a
microsecond of call overhead apiece; checked on every message at each end, they were 35-40 us of
the tick. Here each check is one call returning a code (0: plausible; else the index of its reason
in the caller's table). This is the one definition of each rule; tests/unit/test_plausibility.py
checks them against messages built to break each one.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from teleop.dynamics.kernels.small import is_positive_definite

#: energy may run backwards by round-off only (J)
ENERGY_TOL_J = 1e-9
#: |R^T R - I| beyond this is not a rotation (the message check only looks at the determinant)
ORTHO_TOL = 1e-6


@njit(cache=True)
def energy_code(E, E0, has_last, dt_s, power_W):
    """0 when the port energy ``E`` (6,) J may follow ``E0`` (6,) after ``dt_s`` s (``has_last``
    False: no reference yet); 1 not finite or negative, 2 ran backwards, 3 grew faster than
    ``power_W`` on an axis."""
    for i in range(6):
        if not math.isfinite(E[i]) or E[i] < -ENERGY_TOL_J:
            return 1
    if not has_last:
        return 0
    limit = power_W * max(dt_s, 0.0) + ENERGY_TOL_J
    for i in range(6):
        grow = E[i] - E0[i]
        if grow < -ENERGY_TOL_J:
            return 2
        if grow > limit:
            return 3
    return 0


@njit(cache=True)
def reply_code(W, D, force_N, torque_Nm, damping_max):
    """0 when a reply's wrench ``W`` (6,: N, N*m) and damping ``D`` (6, 6) are within what a slave
    produces; 1 the force or torque too large (or not finite), 2 the damping too large."""
    f = math.sqrt(W[0] * W[0] + W[1] * W[1] + W[2] * W[2])
    m = math.sqrt(W[3] * W[3] + W[4] * W[4] + W[5] * W[5])
    if not (f <= force_N and m <= torque_Nm):
        return 1
    for i in range(6):
        for j in range(6):
            if not abs(D[i, j]) <= damping_max:
                return 2
    return 0


@njit(cache=True)
def pose_code(Rc, p, center, reach_m, has_last, p0, R0, R, dt_s, speed_m_s, rate_rad_s):
    """0 when a command may be followed: its rotation ``Rc`` (3, 3) orthonormal, its target ``p``
    (3,) m within ``reach_m`` of ``center``, and (``has_last``) the target moved from ``p0``,
    ``R0`` to ``p``, ``R`` no faster than ``speed_m_s`` and ``rate_rad_s`` over ``dt_s``;
    1 not a rotation, 2 out of reach, 3 a jump too far, 4 a turn too fast."""
    for i in range(3):
        for j in range(3):
            g = Rc[0, i] * Rc[0, j] + Rc[1, i] * Rc[1, j] + Rc[2, i] * Rc[2, j] - (1.0 if i == j else 0.0)
            if not abs(g) <= ORTHO_TOL:
                return 1
    d = math.sqrt((p[0] - center[0]) ** 2 + (p[1] - center[1]) ** 2 + (p[2] - center[2]) ** 2)
    if not d <= reach_m:
        return 2
    if not has_last:
        return 0
    step = math.sqrt((p[0] - p0[0]) ** 2 + (p[1] - p0[1]) ** 2 + (p[2] - p0[2]) ** 2)
    if step > speed_m_s * dt_s:
        return 3
    tr = 0.0  # trace(R0^T R): the cosine of the turn is (tr - 1) / 2
    for i in range(3):
        for j in range(3):
            tr += R0[i, j] * R[i, j]
    turn = rate_rad_s * dt_s
    if turn < math.pi and 0.5 * (tr - 1.0) < math.cos(turn):
        return 4
    return 0


def _read_only(ndim: int) -> types.Array:
    return types.Array(types.float64, ndim, "C", readonly=True)


# Typed once for read-only inputs, which writable arrays convert to: the filter's state and target
# are each a writable result or a shared read-only zero by turns, and a kernel typed per call loads
# anew for each mix it meets (5-25 ms, mid-run: tests/integration/test_warm_up.py).
@njit([types.float64[::1](_read_only(1), _read_only(1), types.float64),
       types.float64[:, ::1](_read_only(2), _read_only(2), types.float64)], cache=True)
def lowpass(y, target, alpha):
    """One step of the first-order low-pass y + alpha (target - y), elementwise, for (n,) and
    (n, m) C-contiguous float arrays: a new array, the arithmetic of numpy's
    ``y + alpha * (target - y)``."""
    out = np.empty_like(y)
    yf, tf, of = y.ravel(), target.ravel(), out.ravel()
    for i in range(yf.size):
        of[i] = yf[i] + alpha * (tf[i] - yf[i])
    return out


@njit(cache=True)
def damper_ok(D, offset):
    """Whether a contact model may be rendered: its damping ``D`` (6, 6) and offset ``offset``
    (6,) finite (the offset's squares too), and D positive semidefinite, tested as D + 1e-9
    max(1, max|D|) I positive definite (its Cholesky factor exists)."""
    scale, sq = 1.0, 0.0
    for i in range(6):
        sq += offset[i] * offset[i]
        for j in range(6):
            a = abs(D[i, j])
            if not math.isfinite(a):
                return False
            scale = max(scale, a)
    if not math.isfinite(sq):
        return False
    A = D.copy()
    for i in range(6):
        A[i, i] += 1e-9 * scale
    return is_positive_definite(A)
