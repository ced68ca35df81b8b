"""Compiled constraint rows: G (m, 6) and the velocity-product term of every built-in
pose-dependent constraint, from a kind code and up to :data:`NPAR` floats (:func:`row_params`).

The constraint classes of :mod:`teleop.dynamics.constraints` are the reference (``jacobian``,
``bias``); tests/unit/test_kernels.py holds these rows equal to them.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from teleop.dynamics import constraints as C

#: floats per constraint in the parameter table
NPAR = 12

KIND_AXIS_IN_PLANE = 1
KIND_SPHERE = 2
KIND_POINT_DEPTH = 3
KIND_AXIS_ALONG = 4
KIND_KNIFE_EDGE = 5
KIND_REMOTE_CENTER = 6


def row_params(c) -> tuple[int, np.ndarray] | None:
    """(kind, params (NPAR,)) of a pose-dependent built-in constraint, or None (no kernel)."""
    par = np.zeros(NPAR)
    if type(c) is C.AxisInPlane:
        par[0:3], par[3:6] = c.axis_B, c.normal
        return KIND_AXIS_IN_PLANE, par
    if type(c) is C.SphereContact:
        par[0:3], par[3], par[4:7] = c.center, c.radius, c.normal_B
        return KIND_SPHERE, par
    if type(c) is C.PointDepth:
        par[0:3], par[3:6], par[6], par[7:10] = c.origin, c.normal, c.depth, c.point_B
        return KIND_POINT_DEPTH, par
    if type(c) is C.AxisAlong:
        par[0:3], par[3:6], par[6:9] = c.axis_B, c._T[0], c._T[1]
        return KIND_AXIS_ALONG, par
    if type(c) is C.KnifeEdge:
        par[0:3], par[3:6] = c.point_B, c.side_B
        return KIND_KNIFE_EDGE, par
    if type(c) is C.RemoteCenter:
        par[0:3], par[3:6], par[6:9], par[9:12] = c.center, c.point_B, c._N_B[0], c._N_B[1]
        return KIND_REMOTE_CENTER, par
    return None


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


# -- the constraint rows --------------------------------------------------------------------------
@njit(cache=True)
def _rows(kind, par, p, R, v, w, G, b, r0):
    """Fill G[r0:r0+rows] and b[r0:r0+rows] for one constraint (see the classes in constraints.py)."""
    a = np.empty(3)
    s = np.empty(3)
    t = np.empty(3)
    if kind == KIND_AXIS_IN_PLANE:
        _rv(R, par[0], par[1], par[2], a)
        n = par[3:6]
        _cross(a, n, t)
        G[r0, 3:6] = t
        _wwx(w, a, s)
        b[r0] = _dot(n, s)
    elif kind == KIND_SPHERE:
        r = par[3]
        _rv(R, par[4], par[5], par[6], a)
        G[r0, 0] = G[r0 + 1, 1] = G[r0 + 2, 2] = 1.0
        G[r0, 4], G[r0, 5] = -r * a[2], r * a[1]
        G[r0 + 1, 3], G[r0 + 1, 5] = r * a[2], -r * a[0]
        G[r0 + 2, 3], G[r0 + 2, 4] = -r * a[1], r * a[0]
        _wwx(w, a, s)
        for i in range(3):
            b[r0 + i] = -r * s[i]  # r (w x a) x w = -r w x (w x a)
    elif kind == KIND_POINT_DEPTH:
        n = par[3:6]
        _rv(R, par[7], par[8], par[9], a)
        G[r0, 0:3] = n
        _cross(a, n, t)
        G[r0, 3:6] = t
        _wwx(w, a, s)
        b[r0] = _dot(n, s)
    elif kind == KIND_AXIS_ALONG:
        _rv(R, par[0], par[1], par[2], a)
        _wwx(w, a, s)
        for k in range(2):
            Tk = par[3 + 3 * k : 6 + 3 * k]
            _cross(a, Tk, t)
            G[r0 + k, 3:6] = t
            b[r0 + k] = _dot(Tk, s)
    elif kind == KIND_KNIFE_EDGE:
        _rv(R, par[0], par[1], par[2], a)  # d = R point_B
        _rv(R, par[3], par[4], par[5], s)  # s = R side_B
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
    elif kind == KIND_REMOTE_CENTER:
        rr = np.empty(3)
        for i in range(3):
            rr[i] = par[i] - p[i]
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


@njit(cache=True)
def stack_rows(G, b, kinds, offsets, params, p, R, v, w):
    """Rows of every pose-dependent constraint into G (m, 6) and b (m,); the others stay as given."""
    for k in range(kinds.shape[0]):
        _rows(kinds[k], params[k], p, R, v, w, G, b, offsets[k])
