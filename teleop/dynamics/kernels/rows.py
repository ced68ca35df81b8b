"""The rows of every built-in constraint, written once, compiled (numba).

One function per constraint kind fills, for its rows starting at r0, the Jacobian G on the twist
(v, w) (world, at the body origin), the velocity-product term b = d/dt(G) (v, w) (m/s^2 or
rad/s^2; zero at zero twist, since every term is quadratic in it) and the residual h (m or rad;
zero on nonholonomic rows). The constraint classes of :mod:`teleop.dynamics.constraints` hold only
their parameters (:data:`NPAR` floats each, laid out as noted per kind) and call this code for
their ``jacobian``, ``bias`` and ``residual``; :class:`teleop.dynamics.rows.RowStack` calls
:func:`stack_rows` for a whole stack. Tested against central finite differences
(tests/unit/test_constraint_jacobians.py), not against a second copy.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: floats per constraint in the parameter table
NPAR = 12

KIND_PLANE_HEIGHT = 1  # origin o (0:3), normal n (3:6), height (6)
KIND_AXIS_IN_PLANE = 2  # axis_B a (0:3), normal n (3:6)
KIND_ROLLING = 3  # tangents t1 (0:3), t2 (3:6), normal n (6:9), radius (9)
KIND_SPHERE = 4  # centre c (0:3), radius (3), normal_B (4:7)
KIND_POINT_DEPTH = 5  # origin o (0:3), normal n (3:6), depth (6), point_B d (7:10)
KIND_AXIS_ALONG = 6  # axis_B a (0:3), tangents t1 (3:6), t2 (6:9)
KIND_KNIFE_EDGE = 7  # point_B d (0:3), side_B s (3:6)
KIND_REMOTE_CENTER = 8  # centre c (0:3), point_B d (3:6), body normals n1 (6:9), n2 (9:12)


# -- small scalar helpers -------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _rv(R, x0, x1, x2, out):
    """out = R @ (x0, x1, x2)."""
    for i in range(3):
        out[i] = R[i, 0] * x0 + R[i, 1] * x1 + R[i, 2] * x2


@njit(cache=True, inline="always")
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@njit(cache=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, inline="always")
def _wwx(w, a, out):
    """out = w x (w x a): the centripetal term of a body vector a turning at w."""
    wa = _dot(w, a)
    ww = _dot(w, w)
    for i in range(3):
        out[i] = wa * w[i] - ww * a[i]


@njit(cache=True, inline="always")
def _point_row(n, a, w, G, b, r):
    """Row r of a body point at offset a (world) moving along the fixed unit n: G = [n, a x n],
    b = n . w x (w x a)."""
    t = np.empty(3)
    G[r, 0:3] = n
    _cross(a, n, t)
    G[r, 3:6] = t
    _wwx(w, a, t)
    b[r] = _dot(n, t)


@njit(cache=True, inline="always")
def _axis_row(n, a, w, G, b, h, r):
    """Row r of a body axis a (world) held perpendicular to the fixed unit n: h = n . a,
    G = [0, a x n], b = n . w x (w x a)."""
    _point_row(n, a, w, G, b, r)
    G[r, 0:3] = 0.0
    h[r] = _dot(n, a)


# -- the constraint rows --------------------------------------------------------------------------
@njit(cache=True)
def constraint_rows(kind, par, p, R, v, w, G, b, h, r0):
    """Fill G[r0:r0+rows] (rows, 6), b and h [r0:r0+rows] for one constraint of ``kind``."""
    a = np.empty(3)
    s = np.empty(3)
    t = np.empty(3)
    if kind == KIND_PLANE_HEIGHT:
        G[r0, :] = 0.0
        G[r0, 0:3] = par[3:6]
        b[r0] = 0.0
        h[r0] = _dot(par[3:6], p) - _dot(par[3:6], par[0:3]) - par[6]
    elif kind == KIND_AXIS_IN_PLANE:
        _rv(R, par[0], par[1], par[2], a)
        _axis_row(par[3:6], a, w, G, b, h, r0)
    elif kind == KIND_ROLLING:  # contact point p - r n: rows [t_i, -r (n x t_i)] (eqs. 14-15)
        r = par[9]
        for k in range(2):
            tk = par[3 * k : 3 * k + 3]
            G[r0 + k, 0:3] = tk
            _cross(par[6:9], tk, s)
            for i in range(3):
                G[r0 + k, 3 + i] = -r * s[i]
            b[r0 + k] = 0.0
            h[r0 + k] = 0.0
    elif kind == KIND_SPHERE:  # h = p - c - r R n_B; d/dt(-r R n_B) = r [R n_B]x w
        r = par[3]
        _rv(R, par[4], par[5], par[6], a)
        G[r0 : r0 + 3, :] = 0.0
        G[r0, 0] = G[r0 + 1, 1] = G[r0 + 2, 2] = 1.0
        G[r0, 4], G[r0, 5] = -r * a[2], r * a[1]
        G[r0 + 1, 3], G[r0 + 1, 5] = r * a[2], -r * a[0]
        G[r0 + 2, 3], G[r0 + 2, 4] = -r * a[1], r * a[0]
        _wwx(w, a, s)
        for i in range(3):
            b[r0 + i] = -r * s[i]  # r (w x a) x w = -r w x (w x a)
            h[r0 + i] = p[i] - par[i] - r * a[i]
    elif kind == KIND_POINT_DEPTH:  # h = n . (p + R d - o) + depth
        n = par[3:6]
        _rv(R, par[7], par[8], par[9], a)
        _point_row(n, a, w, G, b, r0)
        for i in range(3):
            s[i] = p[i] + a[i] - par[i]
        h[r0] = _dot(n, s) + par[6]
    elif kind == KIND_AXIS_ALONG:  # h_k = t_k . (R a_B)
        _rv(R, par[0], par[1], par[2], a)
        for k in range(2):
            _axis_row(par[3 + 3 * k : 6 + 3 * k], a, w, G, b, h, r0 + k)
    elif kind == KIND_KNIFE_EDGE:  # s . (v + w x R d) = 0, s = R side_B
        _rv(R, par[0], par[1], par[2], a)
        _rv(R, par[3], par[4], par[5], s)
        G[r0, 0:3] = s
        _cross(a, s, t)
        G[r0, 3:6] = t
        vp = np.empty(3)
        _cross(w, a, vp)
        for i in range(3):
            vp[i] += v[i]
        _cross(w, s, t)
        bb = _dot(t, vp)
        _wwx(w, a, t)
        b[r0] = bb + _dot(s, t)
        h[r0] = 0.0
    elif kind == KIND_REMOTE_CENTER:
        # the shaft's material point at the trocar, r = c - p, moves at v + w x r (rdot = -v)
        rr = np.empty(3)
        off = np.empty(3)
        _rv(R, par[3], par[4], par[5], a)
        for i in range(3):
            rr[i] = par[i] - p[i]
            off[i] = p[i] + a[i] - par[i]
        vr = np.empty(3)
        _cross(w, rr, vr)
        for i in range(3):
            vr[i] += v[i]
        wv = np.empty(3)
        _cross(w, v, wv)
        for k in range(2):
            o = 6 + 3 * k
            _rv(R, par[o], par[o + 1], par[o + 2], a)
            G[r0 + k, 0:3] = a
            _cross(rr, a, t)
            G[r0 + k, 3:6] = t
            _cross(w, a, t)
            b[r0 + k] = _dot(t, vr) - _dot(a, wv)
            h[r0 + k] = _dot(a, off)  # offset of the shaft from the trocar along normal k


@njit(cache=True)
def stack_rows(table, params, p, R, v, w, G, b, h):
    """Rows of every compiled constraint of a stack: ``table`` (k, 2) int64 holds (kind, first
    row) and ``params`` (k, NPAR) the parameters; the other rows of G, b, h are left as given."""
    for k in range(table.shape[0]):
        constraint_rows(table[k, 0], params[k], p, R, v, w, G, b, h, table[k, 1])


@njit(cache=True)
def one_constraint(kind, par, rows, p, R, v, w):
    """(G (rows, 6), b (rows,), h (rows,)) of one constraint: what the classes' methods return."""
    G = np.zeros((rows, 6))
    b = np.zeros(rows)
    h = np.zeros(rows)
    constraint_rows(kind, par, p, R, v, w, G, b, h, 0)
    return G, b, h
