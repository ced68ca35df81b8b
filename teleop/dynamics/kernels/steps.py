"""Whole steps in one compiled call, for a model whose rows and effects are all compiled.

Each kernel here only chains the kernels of :mod:`.motion` and :mod:`.rows` in the order the
Python integrators chain them (:class:`teleop.dynamics.integrators.Parametric` and
:class:`~teleop.dynamics.integrators.EnergyConsistent` on an affine psi); it holds no formula of
its own. Why: a Python-to-numba call costs about 1-3 us of dispatch, and every array a kernel
returns costs a boxing (one ``_numba_unpickle`` of its type); on the paper's rolling disk the split
path made five calls returning sixteen arrays per step. Here a step is one call returning two
arrays, the packed output and the pose terms at its end. The parametric step also packs what the
tool checks after a step (:func:`end_checks`) and the world twist at its end, so that neither
needs another call or a numpy operation in Python.

Inputs shared by the kernels: the chart (R0 (3, 3), axes (3,) int64), the compiled rows (``table``
(k, 2) int64, ``params`` (k, NPAR), ``m`` rows in all, as in :func:`.rows.stack_rows`) and ``body``,
the packed constants of :func:`body_pack`. The pose terms come back as one (5, 3, 3) array:
R, E_B, E_B^-1, dE, E_W. Tested against the split path they replace
(tests/unit/test_fused_steps.py): the same trajectories to rounding.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from teleop.dynamics.kernels.motion import (
    energy_scale,
    evaluate,
    flat_advance,
    gravity_potential,
    project_parameter_rates,
    rate_map_into,
    split_end,
    split_twist,
)
from teleop.dynamics.kernels.rows import stack_rows


def body_pack(J, J_inv, mass: float, coriolis: bool, rtol: float, fx) -> np.ndarray:
    """The body's constants (27,) for the fused kernels: inertia J (3, 3) kg*m^2 and its
    inverse, mass kg, the gyroscopic switch, the Delassus rank tolerance and the compiled effects
    fx (5,) of :func:`teleop.dynamics.effects.effect_params`. Layout: J (0:9), J^-1 (9:18), 1/m (18),
    m (19), coriolis 0 or 1 (20), rtol (21), fx (22:27)."""
    return np.concatenate([np.ravel(J), np.ravel(J_inv), [1.0 / mass, mass, float(coriolis), rtol],
                           np.asarray(fx, dtype=float)])


@njit(cache=True)
def end_checks(q, qd, lam, nudot):
    """(total, v2 (m/s)^2, w2 (rad/s)^2) after a step to (q (6,), qd (6,)) whose evaluation gave
    lam (m,) and nudot (6,): total = sum q + v2 + w2 + sum lam + sum nudot, finite only if every
    term is (inf - inf is NaN); v2 = |qd[:3]|^2, w2 = |qd[3:]|^2 the squared chart rates. The sums
    run left to right, as Python's ``sum`` of floats (3.11) does."""
    v2 = qd[0] * qd[0] + qd[1] * qd[1] + qd[2] * qd[2]
    w2 = qd[3] * qd[3] + qd[4] * qd[4] + qd[5] * qd[5]
    sq = 0.0
    for x in q:
        sq += x
    sl = 0.0
    for x in lam:
        sl += x
    sn = 0.0
    for x in nudot:
        sn += x
    return sq + v2 + w2 + sl + sn, v2, w2


@njit(cache=True)
def _pose(R0, axes, q, mats):
    """The chart terms of :func:`.motion.rate_map_terms` at q (6,), into mats (5, 3, 3)."""
    rate_map_into(R0, axes, q[3:], mats)


@njit(cache=True)
def _rows(table, params, m, q, R, v, w):
    """G (m, 6), b (m,), h (m,) of the compiled stack at pose (q[:3], R), twist (v, w)."""
    G = np.zeros((m, 6))
    b = np.zeros(m)
    h = np.zeros(m)
    stack_rows(table, params, q[:3], R, v, w, G, b, h)
    return G, b, h


@njit(cache=True)
def _evaluate_at(R0, axes, table, params, m, body, q, qd, F, mats, out):
    """:meth:`teleop.dynamics.model.ConstrainedBody.evaluate` at (q, qd) under the wrench F (6,):
    the pose terms into mats (5, 3, 3), then out[0:24 + m] = (qdd, nudot, total wrench, G^T lam,
    lam) (see :func:`.motion.evaluate`). Returns the rank."""
    _pose(R0, axes, q, mats)
    R, E, EW = mats[0], mats[1], mats[4]
    v = qd[:3]
    w = np.empty(3)
    for i in range(3):
        w[i] = EW[i, 0] * qd[3] + EW[i, 1] * qd[4] + EW[i, 2] * qd[5]
    G, b, _ = _rows(table, params, m, q, R, v, w)
    J, J_inv = body[0:9].reshape((3, 3)), body[9:18].reshape((3, 3))
    qdd, nudot, lam, rank, Fw, Gtl = evaluate(R, E, mats[2], mats[3], J, J_inv, body[18], body[20] != 0.0,
                                              G, b, qd, F, body[22:27], body[21])
    out[0:6], out[6:12], out[12:18], out[18:24], out[24:24 + m] = qdd, nudot, Fw, Gtl, lam
    return rank


@njit(cache=True)
def evaluate_at(R0, axes, table, params, m, body, q, qd, F):
    """One evaluation of eqs. 8-9 at (q (6,), qd (6,)) under F (6,). Returns (out (25 + m,), mats
    (5, 3, 3)): out = (qdd, nudot, total wrench, G^T lam, lam, rank), mats the pose terms at q."""
    mats = np.empty((5, 3, 3))
    out = np.empty(25 + m)
    out[24 + m] = _evaluate_at(R0, axes, table, params, m, body, q, qd, F, mats, out)
    return out, mats


@njit(cache=True, inline="always")
def _start(R0, axes, table, params, m, body, q, qd, F, k, tail):
    """A fused step's output and its start: out (12 + 2k + 25 + m + tail,), the pose terms mats,
    the start's evaluation written into out (``ev``, as :func:`evaluate_at`), and the offsets of
    the evaluation (o) and of the tail (e)."""
    o = 12 + 2 * k
    e = o + 25 + m
    out = np.empty(e + tail)
    mats = np.empty((5, 3, 3))
    ev = out[o:e]
    ev[24 + m] = _evaluate_at(R0, axes, table, params, m, body, q, qd, F, mats, ev)
    return out, mats, ev, o, e


@njit(cache=True, inline="always")
def _finish(out, mats, ev, m, k, o, at, q1, qd1, z1, zd1):
    """A fused step's end state into out, then from ``at`` its :func:`end_checks` (3,) and world
    twist (v, E_W thetadot) (6,) (numpy's dot: the BLAS product numpy's ``@`` gives)."""
    out[0:6], out[6:12], out[12:12 + k], out[12 + k:o] = q1, qd1, z1, zd1
    out[at], out[at + 1], out[at + 2] = end_checks(q1, qd1, ev[24:24 + m], ev[6:12])
    out[at + 3:at + 6] = qd1[:3]
    out[at + 6:at + 9] = np.dot(mats[4], qd1[3:])


@njit(cache=True)
def flat_parametric_step(R0, axes, table, params, m, body, P, Pinv, q0, q, qd, z, zd, F, h, project):
    """The parametric step on psi(z) = q0 + P z (P (6, k), Pinv its pseudo-inverse): evaluation
    at the start, :func:`.motion.flat_advance`, and (``project``: the stack has nonholonomic rows)
    :func:`.motion.project_parameter_rates` at the end pose.

    Returns (out, mats): out = (q, qd, z, zd, then the start's evaluation as in
    :func:`evaluate_at`, then the end's :func:`end_checks` (3,) and world twist nu = (v, E_W thetadot)
    (6,)), length 12 + 2k + 25 + m + 9; mats the pose terms at the end. (E_W thetadot is numpy's
    dot, the BLAS product numpy's ``@`` gives.)"""
    k = P.shape[1]
    out, mats, ev, o, e = _start(R0, axes, table, params, m, body, q, qd, F, k, 9)
    z1, zd1, q1, qd1 = flat_advance(z, zd, ev[0:6], P, Pinv, q0, h)
    _pose(R0, axes, q1, mats)
    if project:
        zero = np.zeros(3)
        G, _, _ = _rows(table, params, m, q1, mats[0], zero, zero)
        J_inv = body[9:18].reshape((3, 3))
        zd1, qd1 = project_parameter_rates(mats[0], mats[1], mats[2], J_inv, body[18], G, qd1, P, Pinv, body[21])
    _finish(out, mats, ev, m, k, o, e, q1, qd1, z1, zd1)
    return out, mats


@njit(cache=True)
def flat_split_step(R0, axes, table, params, m, body, P, Pinv, q0, q, qd, z, zd, F, h, E0, max_scale):
    """The ``energy`` integrator's step on psi(z) = q0 + P z: the evaluation at the start, the half
    kick zd_h = zd + h/2 P^+ qdd, :func:`.motion.split_twist`, the drift z1 = z + h zd_h,
    q1 = q0 + P z1 (:func:`.motion.flat_advance` with no acceleration), :func:`.motion.split_end` on
    every row at q1, then the correction :func:`.motion.energy_scale` from the energy E0 (J)
    before the step (the potential energy that of the compiled gravity, :func:`.motion.gravity_potential`;
    a fused model has no other) and its rates scaled when it applies. F (6,) is the working wrench
    (the operator's).

    Returns (out, mats): out = (q1, qd1, z1, zd1, the start's evaluation as in :func:`evaluate_at`,
    E1, applied (1.0 or 0.0), then the end's :func:`end_checks` (3,) and world twist (6,) as in
    :func:`flat_parametric_step`), length 12 + 2k + 25 + m + 11; mats the pose terms at the end."""
    n, k = P.shape
    out, mats, ev, o, e = _start(R0, axes, table, params, m, body, q, qd, F, k, 11)
    J, J_inv = body[0:9].reshape((3, 3)), body[9:18].reshape((3, 3))
    fx = body[22:27]
    nu, a0, b0 = split_twist(mats[0], mats[4], J_inv, body[18], qd, ev[6:12], ev[18:24], F, fx, h)
    zd_h = zd.copy()
    for i in range(k):
        s = 0.0
        for j in range(n):
            s += Pinv[i, j] * ev[j]
        zd_h[i] += 0.5 * h * s
    z1, _, q1, _ = flat_advance(z, zd_h, np.zeros(n), P, Pinv, q0, h)
    _pose(R0, axes, q1, mats)
    zero = np.zeros(3)
    G, _, _ = _rows(table, params, m, q1, mats[0], zero, zero)
    zd1, qd1, K, a, b = split_end(mats[0], mats[4], mats[2], J, J_inv, body[19], G, nu, P, Pinv, F, fx, body[21])
    sc, E1, applied = energy_scale(E0, K, a, b, a0, b0, gravity_potential(fx, q1), h, max_scale)
    if applied:
        for i in range(n):
            qd1[i] = sc * qd1[i]
        for i in range(k):
            zd1[i] = sc * zd1[i]
    out[e], out[e + 1] = E1, 1.0 if applied else 0.0
    _finish(out, mats, ev, m, k, o, e + 2, q1, qd1, z1, zd1)
    return out, mats
