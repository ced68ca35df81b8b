"""A target pose and twist moved onto a fixture: the slave follows the closest admissible target.

The virtual tool carries the master device's tracking error (tens of um, mrad). Rather than chase
it with its own fixture rows, the slave follows the target projected onto the fixture, evaluated
on the same rows as the master's (:class:`teleop.dynamics.rows.RowStack`):

1. Newton steps on the holonomic rows: the minimum-norm twist d (6,) (m, rad) with G_h d = -h
   (least squares, rank-revealing, so redundant rows are fine), applied as p <- p + d_v and
   R <- exp(d_w) R (a retraction on SO(3), world frame, as the rows' twists are);
2. the twist (v, w) minus its least-squares component along every row's G (holonomic and
   nonholonomic): the admissible twist closest to it, G (v, w) = 0.

Units: p m, R = R_WE (3, 3), v m/s, w rad/s, all in the fixture's frame (the patient frame).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from teleop.dynamics.kernels.rows import stack_rows
from teleop.dynamics.kernels.small import lstsq_min_norm
from teleop.dynamics.kernels.so3 import exp3

_EPS = np.finfo(np.float64).eps  # singular values below eps * max(rows, 6) * s_max count as zero


@njit(cache=True)
def _newton_step(G, h, mask, tol, p, R) -> bool:
    """One Newton step on the rows where ``mask``; p (3,), R (3, 3) updated in place. False (no
    step) when max |h| on those rows is below tol (m or rad) or G, h are not finite."""
    k = 0
    worst = 0.0
    for r in range(mask.shape[0]):
        if mask[r]:
            k += 1
            worst = max(worst, abs(h[r]))
    if not worst >= tol:  # converged, or NaN
        return False
    Gh, hh = np.empty((k, 6)), np.empty(k)
    j = 0
    for r in range(mask.shape[0]):
        if mask[r]:
            hh[j] = -h[r]
            for c in range(6):
                Gh[j, c] = G[r, c]
            j += 1
    if not np.all(np.isfinite(Gh)):
        return False
    d = lstsq_min_norm(Gh, hh, _EPS * max(k, 6))
    E = exp3(d[3:])
    R[:, :] = E @ R
    for i in range(3):
        p[i] += d[i]
    return True


@njit(cache=True)
def _project_twist(G, nu):
    """nu (6,) minus its least-squares component along the rows G (m, 6), in place."""
    if not (np.all(np.isfinite(G)) and np.all(np.isfinite(nu))):
        return
    Gnu = np.zeros(G.shape[0])
    for r in range(G.shape[0]):
        for c in range(6):
            Gnu[r] += G[r, c] * nu[c]
    nu -= lstsq_min_norm(G, Gnu, _EPS * max(G.shape[0], 6))


@njit(cache=True)
def _project_compiled(table, params, mask, G, b, h, p0, R0, v0, w0, iterations, tol, out):
    """:func:`project_onto_fixture` on a stack of compiled rows only (:func:`stack_rows` into the
    stack's workspaces G, b, h), one call: the target copied into out (18,) = (p, R row-major, v,
    w) and moved there."""
    p, R, nu = out[0:3], out[3:12].reshape((3, 3)), out[12:18]
    s = 0.0
    for i in range(3):
        p[i], nu[i], nu[3 + i] = p0[i], v0[i], w0[i]
        for j in range(3):
            R[i, j] = R0[i, j]
            s += R[i, j] * R[i, j]
        s += p[i] * p[i]
    zero = np.zeros(3)
    if mask.any() and math.isfinite(s):
        for _ in range(iterations):
            stack_rows(table, params, p, R, zero, zero, G, b, h)
            if not _newton_step(G, h, mask, tol, p, R):
                break
    stack_rows(table, params, p, R, zero, zero, G, b, h)
    _project_twist(G, nu)


def project_onto_fixture(rows, p, R, v, w, iterations: int = 3, tol: float = 1e-12):
    """(p, R, v, w) moved onto the fixture of ``rows`` (a :class:`teleop.dynamics.rows.RowStack`):
    up to ``iterations`` Newton steps until max |h| < ``tol`` (m or rad) on the holonomic rows, then
    the twist onto the null space of all rows G. New arrays; a target that is not finite comes back
    unchanged (the arm refuses it). Units: p m, R, v m/s, w rad/s (the fixture's frame)."""
    if rows.m and not rows.python_rows:  # every row compiled: the whole projection in one call
        c, out = np.ascontiguousarray, np.empty(18)
        _project_compiled(rows.table, rows.params, rows.holonomic_mask, *rows.workspaces, c(p, dtype=float),
                          c(R, dtype=float), c(v, dtype=float), c(w, dtype=float), iterations, tol, out)
        return out[0:3], out[3:12].reshape(3, 3), out[12:15], out[15:18]
    p = np.array(p, dtype=float)
    R = np.array(R, dtype=float)
    nu = np.empty(6)
    nu[:3], nu[3:] = v, w
    if rows.m == 0:
        return p, R, nu[:3], nu[3:]
    mask = rows.holonomic_mask
    if mask.any() and math.isfinite(np.vdot(p, p) + np.vdot(R, R)):
        for _ in range(iterations):
            G, _, h = rows.evaluate(p, R)
            if not _newton_step(G, h, mask, tol, p, R):
                break
    G = rows.evaluate(p, R)[0]
    _project_twist(np.ascontiguousarray(G), nu)
    return p, R, nu[:3], nu[3:]
