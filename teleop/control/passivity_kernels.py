"""Compiled kernels (numba) of the passivity guard's tick (:mod:`teleop.control.passivity`,
:mod:`teleop.tick.guard`).

Why compiled: a port's tick is some thirty operations on 6-vectors, which in numpy cost about a
microsecond of call overhead apiece (110 us a tick for both ports at 2 kHz, a third of the tick).
Here a port's step is one call, and each guard method one or two.

This is the one definition of the guard's arithmetic; the module docstring of
:mod:`teleop.control.passivity` gives the formulas and their sources, the Python methods there
and in :mod:`teleop.tick.guard` only prepare the arguments. Units as there (J, W, N, N*m, m/s,
rad/s, s). tests/unit/test_passivity_kernels.py checks them against the numpy formulas they
replaced, bit for bit (run it uncompiled with ``NUMBA_DISABLE_JIT=1``).

The same floats as numpy: no fastmath, each expression evaluated in numpy's order, and
:func:`_max` / :func:`_min` are ``np.maximum`` / ``np.minimum`` (NaN propagates; of two equal
values, the second is taken, which decides the sign of a zero). The matrix products go through
``np.dot``, which is the BLAS call numpy's ``@`` makes (BLAS fuses multiply-adds: the loops of
:mod:`teleop.dynamics.kernels.small` would round differently).

A port's state is one (rows, 6) block, row ``E_IN`` the energy that entered the channel at the
port (J, cumulative), ``E_OUT`` what left it, ``E_DISS`` what the controller dissipated,
``E_REMOTE`` the other port's ``E_in`` as received, ``W`` the observer, ``ACTION`` the
controller's last action (alpha N*s/m at the master, dv m/s at the slave), then at the master
``F_CHANNEL`` and ``F_RENDERED`` (the channel's force last tick before and after the controller,
N), at the slave ``OFFSET`` (the drift, m, rad). A kernel never writes into a block it reads: it
fills a new one (``out``), so a row handed to a recorder stays as its tick left it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from teleop.dynamics.kernels.so3 import exp3

E_IN, E_OUT, E_DISS, E_REMOTE, W, ACTION = 0, 1, 2, 3, 4, 5
F_CHANNEL, F_RENDERED = 6, 7  # the master's block: 8 rows
OFFSET = 6  # the slave's block: 7 rows
MASTER_ROWS, SLAVE_ROWS = 8, 7

#: a port's settings as the kernels take them, one float array (:func:`port_settings`): the tick
#: (s), enabled (1.0 or 0.0), the master's v_floor, the slave's f_floor, dv_max, drift_gain,
#: drift_share, then the master's alpha_max (6)
P_DT, P_ENABLED, P_V_FLOOR, P_F_FLOOR, P_DV_MAX, P_DRIFT_GAIN, P_DRIFT_SHARE, P_ALPHA_MAX = 0, 1, 2, 3, 4, 5, 6, 7
#: the slave guard's reply settings (:func:`reply_settings`): drift_stiffness (6), drift_speed,
#: force_scale, torque_scale, scale
R_K, R_DRIFT_SPEED, R_FORCE_SCALE, R_TORQUE_SCALE, R_SCALE = 0, 6, 7, 8, 9


def port_settings(dt_s, enabled, v_floor, f_floor, dv_max, drift_gain, drift_share, alpha_max):
    """The settings array of a port (``P_*``), from :class:`~teleop.control.passivity.TdpaParams`'
    fields (``alpha_max`` one number or six)."""
    out = np.empty(P_ALPHA_MAX + 6)
    out[:P_ALPHA_MAX] = (dt_s, 1.0 if enabled else 0.0, v_floor, f_floor, dv_max, drift_gain, drift_share)
    out[P_ALPHA_MAX:] = np.broadcast_to(np.asarray(alpha_max, dtype=float), 6)
    return out


def reply_settings(drift_stiffness, drift_speed, force_scale, torque_scale, scale):
    """The settings array of the slave guard's reply (``R_*``)."""
    out = np.empty(R_SCALE + 1)
    out[R_K:R_K + 6] = drift_stiffness
    out[R_DRIFT_SPEED:] = (drift_speed, force_scale, torque_scale, scale)
    return out


@njit(cache=True, inline="always")
def _max(a, b):
    """np.maximum(a, b) on two floats: NaN if either is; b when equal (max(-0.0, 0.0) is 0.0)."""
    return a if (a > b or a != a) else b


@njit(cache=True, inline="always")
def _min(a, b):
    """np.minimum(a, b) on two floats: NaN if either is; b when equal."""
    return a if (a < b or a != a) else b


@njit(cache=True, inline="always")
def _split(E_in, E_out, power, dt):
    """One axis of :func:`port_energy`: (E_in + (p)+ dt, E_out + (-p)+ dt)."""
    return E_in + _max(power, 0.0) * dt, E_out + _max(-power, 0.0) * dt


@njit(cache=True)
def port_energy(E_in, E_out, power, dt, E_in_out, E_out_out):
    """The cumulative (E_in, E_out) (n,) J after one tick of port power ``power`` (n,) W (positive
    into the channel) held for ``dt`` s, into ``E_in_out`` and ``E_out_out``."""
    for i in range(power.shape[0]):
        E_in_out[i], E_out_out[i] = _split(E_in[i], E_out[i], power[i], dt)


@njit(cache=True, inline="always")
def _account(E_in, E_out, f_channel, f_rendered, v, dt):
    """One axis of the master's accounting: the rendered force's work at the velocity after its
    step, out of the channel when positive; into it, the channel's own force's share only."""
    p_done = f_rendered * v
    return (E_in + _min(_max(-f_channel * v, 0.0), _max(-p_done, 0.0)) * dt,
            E_out + _max(p_done, 0.0) * dt)


@njit(cache=True)
def master_account(s, out, v_m, dt):
    """:meth:`~teleop.control.passivity.MasterPassivity.account`: the master block ``s`` with the
    work of the force rendered last counted at the master's velocity ``v_m`` (6,), into ``out``."""
    out[:, :] = s
    for i in range(6):
        out[E_IN, i], out[E_OUT, i] = _account(s[E_IN, i], s[E_OUT, i], s[F_CHANNEL, i], s[F_RENDERED, i],
                                               v_m[i], dt)


@njit(cache=True)
def master_step(s, out, f_m, v_m, E_remote, received, counted, prm):
    """:meth:`~teleop.control.passivity.MasterPassivity.step` on the master block ``s``, into
    ``out``, with the settings ``prm`` (``P_*``): ``E_remote`` (6,) J taken when ``received`` (the
    largest yet), the work of the force rendered last counted unless ``counted``, the observer
    ``W = E_remote - E_out`` and, when enabled, the damping
    ``alpha = min(-W / (dt v^2), max(alpha_max, f / v))`` (6,) where ``W < 0`` and
    ``|v| > v_floor``. The force to render is row ``F_RENDERED`` of ``out``."""
    dt, enabled, v_floor = prm[P_DT], prm[P_ENABLED] != 0.0, prm[P_V_FLOOR]
    for i in range(6):
        Er = _max(s[E_REMOTE, i], E_remote[i]) if received else s[E_REMOTE, i]
        f, v = f_m[i], v_m[i]
        E_in, E_out = s[E_IN, i], s[E_OUT, i]
        if not counted:
            E_in, E_out = _account(E_in, E_out, s[F_CHANNEL, i], s[F_RENDERED, i], v, dt)
        W_i = Er - E_out
        alpha = 0.0
        if enabled and W_i < 0.0 and abs(v) > v_floor:
            alpha = _min(-W_i / (dt * (v * v)), _max(prm[P_ALPHA_MAX + i], f / v))
        out[E_IN, i], out[E_OUT, i], out[E_REMOTE, i], out[W, i] = E_in, E_out, Er, W_i
        out[E_DISS, i] = s[E_DISS, i] + alpha * v * v * dt
        out[ACTION, i] = alpha
        out[F_CHANNEL, i] = f
        out[F_RENDERED, i] = f - alpha * v


@njit(cache=True)
def master_motion_scale(s, v_m, dt):
    """:meth:`~teleop.control.passivity.MasterPassivity.motion_scale`: the largest sigma in [0, 1]
    with the rendered force's work ``f v sigma dt`` within ``E_remote - E_out`` on every axis."""
    sigma = 1.0
    for i in range(6):
        p_done = s[F_RENDERED, i] * v_m[i] * dt
        room = s[E_REMOTE, i] - s[E_OUT, i]
        if p_done > 0.0 and p_done > room:
            q = (0.0 if 0.0 > room else room) / p_done  # Python's max(room, 0.0), then min(sigma, q)
            if q < sigma:
                sigma = q
    return sigma


@njit(cache=True)
def slave_step(s, out, v_des, f_s, E_remote, received, prm, v):
    """:meth:`~teleop.control.passivity.SlavePassivity.step` on the slave block ``s``, into ``out``
    and the velocity to follow ``v`` (6,), with the settings ``prm`` (``P_*``): ``E_remote`` taken
    when ``received``, the port energy of ``f_s v_des``, the observer
    ``W = E_remote - E_out + E_diss``; when enabled the correction ``dv = clip(-W / (dt f),
    +-dv_max)`` where ``W < 0`` and ``|f| > f_floor``, and with ``drift_gain`` > 0 the drift
    compensation ``-drift_gain * offset``, cut to ``drift_share`` of the surplus left."""
    dt, enabled, f_floor, dv_max = prm[P_DT], prm[P_ENABLED] != 0.0, prm[P_F_FLOOR], prm[P_DV_MAX]
    drift_gain, drift_share = prm[P_DRIFT_GAIN], prm[P_DRIFT_SHARE]
    ng = -drift_gain
    for i in range(6):
        Er = _max(s[E_REMOTE, i], E_remote[i]) if received else s[E_REMOTE, i]
        f, vd = f_s[i], v_des[i]
        E_in, E_out = _split(s[E_IN, i], s[E_OUT, i], f * vd, dt)
        W_i = Er - E_out + s[E_DISS, i]
        dv = 0.0
        diss = 0.0
        if enabled:
            if W_i < 0.0 and abs(f) > f_floor:
                dv = _min(_max(-W_i / (dt * f), -dv_max), dv_max)  # np.clip
            diss = f * dv * dt
            if drift_gain > 0.0:
                W_after = W_i + diss
                dc = ng * s[OFFSET, i]
                cost = _max(-f * dc * dt, 0.0)  # energy the correction would put out
                budget = _max(drift_share * W_after, 0.0)
                scale = budget / _max(cost, 1e-300) if cost > budget else 1.0
                dc = dc * scale if W_after >= 0.0 else 0.0  # free (cost 0) when no force acts
                dv = dv + dc
                diss = diss + f * dc * dt
        v[i] = vd + dv
        out[E_IN, i], out[E_OUT, i], out[E_REMOTE, i] = E_in, E_out, Er
        out[E_DISS, i] = s[E_DISS, i] + diss
        out[ACTION, i] = dv
        out[W, i] = W_i + diss
        out[OFFSET, i] = s[OFFSET, i] + dv * dt


@njit(cache=True)
def sum6(s, row):
    """The sum of row ``row`` of a block, left to right (numpy's for six numbers)."""
    t = s[row, 0]
    for i in range(1, 6):
        t += s[row, i]
    return t


@njit(cache=True)
def slave_observe(s, W_min, drift_max):
    """(W_min, drift_final, drift_max) at the end of the slave's tick: the observer's sum into its
    running minimum, |offset[:3]| (m) into its maximum (Python's min and max: NaN never taken)."""
    W_sum = sum6(s, W)
    o = np.empty(3)
    o[:] = s[OFFSET, :3]
    drift = math.sqrt(np.dot(o, o))  # np.linalg.norm
    return (W_sum if W_sum < W_min else W_min), drift, (drift if drift > drift_max else drift_max)


@njit(cache=True)
def guard_command(s, out, live, v_m, w_m, f_s, E_remote, received, prm, speed, k, p, R, v, speed_out, p_out, R_out):
    """The slave guard's command: the port's step (:func:`slave_step`, into ``out`` and ``v``)
    with the commanded twist ``(v_m, w_m)`` when ``live`` (else zero); the commanded speed
    low-passed, ``speed + k (|twist| - speed)`` into ``speed_out`` (6,); when ``live``, the pose
    ``(p, R)`` offset by the drift after the step (row ``OFFSET`` of ``out``): ``p + offset[:3]``
    into ``p_out`` (3,) m and ``exp3(offset[3:]) R`` into ``R_out`` (3, 3)."""
    v_des = np.zeros(6)
    if live:
        v_des[:3] = v_m
        v_des[3:] = w_m
    slave_step(s, out, v_des, f_s, E_remote, received, prm, v)
    for i in range(6):
        speed_out[i] = speed[i] + k * (abs(v_des[i]) - speed[i])
    if live:
        for i in range(3):
            p_out[i] = p[i] + out[OFFSET, i]
        R_out[:, :] = np.dot(exp3(out[OFFSET, 3:]), R)


@njit(cache=True)
def guard_reply(s, speed, prm, R, wrench, plane, f_M, normal, wall, out):
    """The slave guard's reply, with its settings ``prm`` (``R_*``). With ``wall``: the force
    along ``R^T normal`` taken out of ``f_M`` (6,, M), in place. Into ``out[:6]`` (P) the contact
    ``wrench`` plus, while the drift (row ``OFFSET`` of ``s``, M) is not zero, the spring
    ``K offset min(speed / drift_speed, 1)`` mapped to P (``R f / force_scale``,
    ``R tau / torque_scale``); into ``out[6:14]`` the ``plane``, its anchor less
    ``R offset[:3] / scale`` when the drift moves it and the plane is confident."""
    if wall:
        nP = np.empty(3)
        nP[:] = normal
        n = np.dot(R.T, nP)
        f3 = np.empty(3)
        f3[:] = f_M[:3]
        fn = np.dot(n, f3)
        for i in range(3):
            f_M[i] = f_M[i] - fn * n[i]
    out[:6] = wrench
    out[6:14] = plane
    moved = False
    for i in range(6):
        if s[OFFSET, i] != 0.0:  # np.any (NaN is not zero)
            moved = True
    if moved:  # the drift reflected to the master: a spring pulling it toward the slave's target
        pf, pt = np.empty(3), np.empty(3)
        ds = prm[R_DRIFT_SPEED]
        for i in range(3):
            pf[i] = prm[R_K + i] * s[OFFSET, i] * _min(speed[i] / ds, 1.0)
            pt[i] = prm[R_K + 3 + i] * s[OFFSET, 3 + i] * _min(speed[3 + i] / ds, 1.0)
        F, T = np.dot(R, pf), np.dot(R, pt)
        for i in range(3):
            out[i] = wrench[i] + F[i] / prm[R_FORCE_SCALE]
            out[3 + i] = wrench[3 + i] + T[i] / prm[R_TORQUE_SCALE]
    if plane[7] > 0.0 and (s[OFFSET, 0] != 0.0 or s[OFFSET, 1] != 0.0 or s[OFFSET, 2] != 0.0):
        # the anchor where the master's tip was: less the drift
        o = np.empty(3)
        o[:] = s[OFFSET, :3]
        a = np.dot(R, o)
        for i in range(3):
            out[9 + i] = plane[3 + i] - a[i] / prm[R_SCALE]
