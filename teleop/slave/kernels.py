"""Compiled kernels (numba) of the slave tick: joint velocity bounds, the follower's linear system
and its unbounded solve.

Why compiled: the follower's tick is some thirty numpy operations on arrays of 6 to 13 entries,
each costing about a microsecond of call overhead whatever its size; here it is three calls.

Each is written once, here; set ``NUMBA_DISABLE_JIT=1`` to step through them in Python. The tests
hold them against independent oracles, not against a second copy: the bounds against hand-computed
cases (tests/property/test_slave_properties.py), the system and its solve against the QP's own
definition, daqp and quadprog, and the KKT conditions (tests/unit/test_slave_kernels.py).
Units as in :mod:`teleop.slave.follower`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from teleop.dynamics.kernels.rows import stack_rows
from teleop.dynamics.kernels.small import solve_into
from teleop.dynamics.kernels.so3 import log3


@njit(cache=True)
def velocity_bounds(q, qd_prev, dt, q_min, q_max, margin, v_max, a_max, lb, ub):
    """Write into lb, ub (nv,) the joint velocity bounds (rad/s) for the next tick of dt s.

    Per joint: the velocity limit, no crossing of [q_min + margin, q_max - margin] within the tick,
    room to stop at a_max (sqrt(2 a room)), and the acceleration box qd_prev +- a dt; the position
    caps always contain 0. When the boxes do not meet, both bounds collapse onto the point of the
    position/velocity box nearest qd_prev. A q that is not finite leaves only the velocity limit.
    """
    for i in range(q.shape[0]):
        v, a = v_max[i], a_max[i]
        cap_up, cap_dn = v, v  # caps on qd and on -qd
        if math.isfinite(q[i]):
            up = q_max[i] - margin - q[i]  # rad left above (negative beyond the limit)
            dn = q[i] - q_min[i] - margin
            cap_up = max(min(v, up / dt, math.sqrt(2.0 * a * max(up, 0.0))), 0.0)
            cap_dn = max(min(v, dn / dt, math.sqrt(2.0 * a * max(dn, 0.0))), 0.0)
        lo = max(-cap_dn, qd_prev[i] - a * dt)
        hi = min(cap_up, qd_prev[i] + a * dt)
        if lo > hi:
            lo = hi = min(max(qd_prev[i], -cap_dn), cap_up)
        lb[i], ub[i] = lo, hi


@njit(cache=True)
def at_position_limit(q, q_min, q_max, v_max, margin, dt):
    """Per joint (bool, nv): within one tick at its velocity limit (v_max dt, rad) plus ``margin``
    (rad) of q_min or q_max, or past it (:meth:`teleop.slave.limits.JointLimits.at_limit`)."""
    out = np.empty(q.shape[0], dtype=np.bool_)
    for i in range(q.shape[0]):
        room = v_max[i] * dt + margin
        out[i] = q[i] - q_min[i] < room or q_max[i] - q[i] < room
    return out


@njit(cache=True)
def advance_joints(q, qd, qd_cmd, alpha, lag, dt, out):
    """One tick of dt s of the joint servo after commanding qd_cmd (rad/s), into out (3, nv): the
    new q, qd and qdd (rad, rad/s, rad/s^2): qd+ = qd + alpha (qd_cmd - qd) with a servo lag
    (``lag``), else qd_cmd; qdd = (qd+ - qd) / dt; q+ = q + qd+ dt (revolute and prismatic joints:
    a sum)."""
    for i in range(q.shape[0]):
        out[1, i] = qd[i] + alpha * (qd_cmd[i] - qd[i]) if lag else qd_cmd[i]
        out[2, i] = (out[1, i] - qd[i]) / dt
        out[0, i] = q[i] + out[1, i] * dt


@njit(cache=True)
def build_system_on_rows(table, params, G, b, h, q, J, T, p_t, R_t, v_t, w_t, q_post, k_fix, W, k_task,
                         w_post_k, lam0, lm_p, lm_o, K, rhs, e):
    """:func:`build_system` with the fixture rows evaluated here, at the tool's pose T (4, 4), by
    :func:`teleop.dynamics.kernels.rows.stack_rows` (``table``, ``params``) into the stack's
    workspaces G, b, h: the follower's build in one call when every row is compiled."""
    p, R = np.empty(3), np.empty((3, 3))
    for i in range(3):
        p[i] = T[i, 3]
        for j in range(3):
            R[i, j] = T[i, j]
    zero = np.zeros(3)
    stack_rows(table, params, p, R, zero, zero, G, b, h)
    return build_system(q, J, T, p_t, R_t, v_t, w_t, q_post, G, h, k_fix, W, k_task, w_post_k, lam0, lm_p, lm_o,
                        K, rhs, e)


@njit(cache=True)
def bounded_system(table, params, G, b, h, lim, margin_rad, q, qd_prev, dt, J, T, p_t, R_t, v_t, w_t, q_post, c,
                   K, rhs, e, bounds, z, shortcut):
    """The follower's tick up to its solver in one call, on compiled rows: :func:`velocity_bounds`
    into bounds (2, nv) (lb, ub rad/s; ``lim`` (4, nv) = q_min, q_max rad, v_max rad/s, a_max
    rad/s^2, ``margin_rad``), :func:`build_system_on_rows` (``c`` (12,) its constants k_fix, W (6),
    k_task, w_post_k, lam0, lm_p, lm_o) and, with ``shortcut``, :func:`solve_unbounded` into z.
    Returns (|p_t - p|^2 m^2 or -1 for a target not finite, the unbounded solution's margin to
    the bounds rad/s: NaN when singular or not solved)."""
    velocity_bounds(q, qd_prev, dt, lim[0], lim[1], margin_rad, lim[2], lim[3], bounds[0], bounds[1])
    ep2 = build_system_on_rows(table, params, G, b, h, q, J, T, p_t, R_t, v_t, w_t, q_post, c[0], c[1:7], c[7],
                               c[8], c[9], c[10], c[11], K, rhs, e)
    margin = np.nan
    if ep2 >= 0.0 and shortcut:
        margin = solve_unbounded(K, rhs, q.shape[0], bounds[0], bounds[1], z)
    return ep2, margin


@njit(cache=True)
def build_system(q, J, T, p_t, R_t, v_t, w_t, q_post, G, h, k_fix, W, k_task, w_post_k, lam0, lm_p, lm_o, K, rhs, e):
    """Fill the follower's linear system (see :mod:`teleop.slave.follower`) in place.

    K (m + nv, m + nv): writes the blocks Aq = G J, Aq' and Hq (the block -I/rho is left as it is);
    rhs (m + nv,): (b, -gq); e (6,): the pose error (m, rad). G (m, 6), h (m,): the fixture rows and
    residuals (m or rad, 0 on nonholonomic rows) at T, so b = -k_fix h. Returns |p_t - p|^2 (m^2),
    or -1 when the target (p_t, R_t, v_t, w_t) is not finite, leaving K and rhs unusable.
    """
    nv = q.shape[0]
    m = K.shape[0] - nv
    for i in range(3):
        e[i] = p_t[i] - T[i, 3]
    Rerr = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            Rerr[i, j] = R_t[i, 0] * T[j, 0] + R_t[i, 1] * T[j, 1] + R_t[i, 2] * T[j, 2]
    e[3:] = log3(Rerr)
    check = 0.0
    for i in range(3):
        check += e[i] * e[i] + e[i + 3] * e[i + 3] + v_t[i] * v_t[i] + w_t[i] * w_t[i]
        for j in range(3):
            check += R_t[i, j] * R_t[i, j]
    if not math.isfinite(check):
        return -1.0
    ep2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
    eR2 = e[3] * e[3] + e[4] * e[4] + e[5] * e[5]
    for r in range(m):
        rhs[r] = -k_fix * h[r]
        for i in range(nv):
            s = 0.0
            for c in range(6):
                s += G[r, c] * J[c, i]
            K[r, m + i] = s
            K[m + i, r] = s
    # Hq = J' W J + lam I, with lam = lam0 + LM damping on the pose error
    lam = lam0 + lm_p * ep2 + lm_o * eR2
    for i in range(nv):
        for j in range(i, nv):
            s = 0.0
            for c in range(6):
                s += W[c] * J[c, i] * J[c, j]
            K[m + i, m + j] = s
            K[m + j, m + i] = s
        K[m + i, m + i] += lam
    # -gq = w_post k_post (q_post - q) + J' W (k e + (v_t, w_t))
    wnu = np.empty(6)
    for c in range(3):
        wnu[c] = W[c] * (k_task * e[c] + v_t[c])
        wnu[c + 3] = W[c + 3] * (k_task * e[c + 3] + w_t[c])
    for i in range(nv):
        s = w_post_k * (q_post[i] - q[i])
        for c in range(6):
            s += J[c, i] * wnu[c]
        rhs[m + i] = s
    return ep2


@njit(cache=True)
def solve_unbounded(K, rhs, nv, lb, ub, z):
    """Solve K z = rhs (LU with partial pivoting on a copy of K) into z; return the least distance
    (rad/s) of qd = z[-nv:] to its bounds lb, ub (nv,): >= 0 when qd is within them, negative when
    a bound binds, NaN when K is singular or z is not finite."""
    n = K.shape[0]
    if not solve_into(K, rhs, z):
        return np.nan
    check = 0.0
    for i in range(n):
        check += z[i] * z[i]
    if not math.isfinite(check):
        return np.nan
    margin = np.inf
    m = n - nv
    for i in range(nv):
        margin = min(margin, z[m + i] - lb[i], ub[i] - z[m + i])
    return margin
