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


# -- small scalar helpers: 3-vectors as tuples (no array allocated, no slice assigned) -------------
@njit(cache=True, inline="always")
def _rv3(R, x0, x1, x2):
    """R @ (x0, x1, x2), a 3-tuple."""
    return (R[0, 0] * x0 + R[0, 1] * x1 + R[0, 2] * x2, R[1, 0] * x0 + R[1, 1] * x1 + R[1, 2] * x2,
            R[2, 0] * x0 + R[2, 1] * x1 + R[2, 2] * x2)


@njit(cache=True, inline="always")
def _rv(R, x0, x1, x2, out):
    """out = R @ (x0, x1, x2) (:func:`_rv3` into an array; the other kernels' form)."""
    out[0], out[1], out[2] = _rv3(R, x0, x1, x2)


@njit(cache=True, inline="always")
def _v3(x, o):
    """x[o:o + 3] as a 3-tuple."""
    return (x[o], x[o + 1], x[o + 2])


@njit(cache=True, inline="always")
def _cross3(a, b):
    """a x b, a 3-tuple."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@njit(cache=True, inline="always")
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, inline="always")
def _wwx(w, a):
    """w x (w x a): the centripetal term of a body vector a turning at w."""
    wa = _dot(w, a)
    ww = _dot(w, w)
    return (wa * w[0] - ww * a[0], wa * w[1] - ww * a[1], wa * w[2] - ww * a[2])


@njit(cache=True, inline="always")
def _set_row(G, r, x, y):
    """G[r] = (x, y), two 3-tuples."""
    for i in range(3):
        G[r, i] = x[i]
        G[r, 3 + i] = y[i]


@njit(cache=True, inline="always")
def _point_row(n, a, w, G, b, r):
    """Row r of a body point at offset a (world) moving along the fixed unit n: G = [n, a x n],
    b = n . w x (w x a)."""
    _set_row(G, r, n, _cross3(a, n))
    b[r] = _dot(n, _wwx(w, a))


@njit(cache=True, inline="always")
def _axis_row(n, a, w, G, b, h, r):
    """Row r of a body axis a (world) held perpendicular to the fixed unit n: h = n . a,
    G = [0, a x n], b = n . w x (w x a)."""
    _set_row(G, r, (0.0, 0.0, 0.0), _cross3(a, n))
    b[r] = _dot(n, _wwx(w, a))
    h[r] = _dot(n, a)


# -- the constraint rows --------------------------------------------------------------------------
@njit(cache=True, inline="always")
def constraint_rows(kind, par, p, R, v, w, G, b, h, r0):
    """Fill G[r0:r0+rows] (rows, 6), b and h [r0:r0+rows] for one constraint of ``kind``."""
    if kind == KIND_PLANE_HEIGHT:
        n = _v3(par, 3)
        _set_row(G, r0, n, (0.0, 0.0, 0.0))
        b[r0] = 0.0
        h[r0] = _dot(n, p) - _dot(n, _v3(par, 0)) - par[6]
    elif kind == KIND_AXIS_IN_PLANE:
        _axis_row(_v3(par, 3), _rv3(R, par[0], par[1], par[2]), w, G, b, h, r0)
    elif kind == KIND_ROLLING:  # contact point p - r n: rows [t_i, -r (n x t_i)] (eqs. 14-15)
        r = par[9]
        for k in range(2):
            tk = _v3(par, 3 * k)
            s = _cross3(_v3(par, 6), tk)
            _set_row(G, r0 + k, tk, (-r * s[0], -r * s[1], -r * s[2]))
            b[r0 + k] = 0.0
            h[r0 + k] = 0.0
    elif kind == KIND_SPHERE:  # h = p - c - r R n_B; d/dt(-r R n_B) = r [R n_B]x w
        r = par[3]
        a = _rv3(R, par[4], par[5], par[6])
        _set_row(G, r0, (1.0, 0.0, 0.0), (0.0, -r * a[2], r * a[1]))
        _set_row(G, r0 + 1, (0.0, 1.0, 0.0), (r * a[2], 0.0, -r * a[0]))
        _set_row(G, r0 + 2, (0.0, 0.0, 1.0), (-r * a[1], r * a[0], 0.0))
        s = _wwx(w, a)
        for i in range(3):
            b[r0 + i] = -r * s[i]  # r (w x a) x w = -r w x (w x a)
            h[r0 + i] = p[i] - par[i] - r * a[i]
    elif kind == KIND_POINT_DEPTH:  # h = n . (p + R d - o) + depth
        n = _v3(par, 3)
        a = _rv3(R, par[7], par[8], par[9])
        _point_row(n, a, w, G, b, r0)
        h[r0] = _dot(n, (p[0] + a[0] - par[0], p[1] + a[1] - par[1], p[2] + a[2] - par[2])) + par[6]
    elif kind == KIND_AXIS_ALONG:  # h_k = t_k . (R a_B)
        a = _rv3(R, par[0], par[1], par[2])
        for k in range(2):
            _axis_row(_v3(par, 3 + 3 * k), a, w, G, b, h, r0 + k)
    elif kind == KIND_KNIFE_EDGE:  # s . (v + w x R d) = 0, s = R side_B
        a = _rv3(R, par[0], par[1], par[2])
        s = _rv3(R, par[3], par[4], par[5])
        _set_row(G, r0, s, _cross3(a, s))
        wa = _cross3(w, a)
        bb = _dot(_cross3(w, s), (wa[0] + v[0], wa[1] + v[1], wa[2] + v[2]))
        b[r0] = bb + _dot(s, _wwx(w, a))
        h[r0] = 0.0
    elif kind == KIND_REMOTE_CENTER:
        # the shaft's material point at the trocar, r = c - p, moves at v + w x r (rdot = -v)
        a = _rv3(R, par[3], par[4], par[5])
        rr = (par[0] - p[0], par[1] - p[1], par[2] - p[2])
        off = (p[0] + a[0] - par[0], p[1] + a[1] - par[1], p[2] + a[2] - par[2])
        wr = _cross3(w, rr)
        vr = (wr[0] + v[0], wr[1] + v[1], wr[2] + v[2])
        wv = _cross3(w, v)
        for k in range(2):
            o = 6 + 3 * k
            a = _rv3(R, par[o], par[o + 1], par[o + 2])
            _set_row(G, r0 + k, a, _cross3(rr, a))
            b[r0 + k] = _dot(_cross3(w, a), vr) - _dot(a, wv)
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
