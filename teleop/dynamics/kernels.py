"""Compiled kernels (numba) of the engine's hot path: the pose terms, one evaluation of eqs. 8-9
and the kinetic-energy projection of the rates, each in one call.

Why compiled: an evaluation is some sixty operations on 3-vectors and 3x3 to 6x6 matrices. In
numpy each costs about a microsecond of call overhead whatever its size, which is what kept the
step at 30x one ``pinocchio.aba``. Here each call does the same arithmetic in one pass.

The readable definitions stay in Python and are the reference: :mod:`teleop.dynamics.rotations`
(``rate_map_terms``), the constraint classes' ``jacobian`` and ``bias``, and
``ConstrainedBody.evaluate(compiled=False)``. The tests check every kernel against them. A
constraint class without a kernel row function (a user's own, say) sends its model down the
Python path; nothing else changes.

Conventions are those of :mod:`teleop.dynamics.model`: twist nu = (v, w), world frame, at the
body origin; G (m, 6) acts on nu; M_nu^-1 = blockdiag(I3/m, R J^-1 R^T).

Constraint rows are described by a kind code and up to :data:`NPAR` floats (:func:`row_params`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from teleop.dynamics import constraints as C
from teleop.dynamics import effects as E

#: floats per constraint in the parameter table
NPAR = 12

KIND_AXIS_IN_PLANE = 1
KIND_SPHERE = 2
KIND_POINT_DEPTH = 3
KIND_AXIS_ALONG = 4
KIND_KNIFE_EDGE = 5
KIND_REMOTE_CENTER = 6

#: Delassus solve modes: no rows, Cholesky factor L, or a pseudo-inverse matrix (rank-deficient K)
SOLVE_NONE, SOLVE_CHOLESKY, SOLVE_PINV = 0, 1, 2


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


def effect_params(effects) -> tuple[np.ndarray, tuple]:
    """Split effects into the compiled ones, summed into fx = (c_lin N*s/m, c_ang N*m*s/rad,
    gravity force (3,) N), and the rest (a tuple, run in Python)."""
    fx, rest = np.zeros(5), []
    for e in effects:
        if type(e) is E.LinearDamper:
            fx[0] += e.c
        elif type(e) is E.AngularDamper:
            fx[1] += e.c
        elif type(e) is E.Gravity:
            fx[2:5] += e._f
        else:
            rest.append(e)
    return fx, tuple(rest)


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


# -- pose terms -----------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _rot_cols(M, k, c, s):
    """M <- M @ R_k(angle) (only two columns change)."""
    i, j = (k + 1) % 3, (k + 2) % 3
    for r in range(3):
        mi, mj = M[r, i], M[r, j]
        M[r, i] = c * mi + s * mj
        M[r, j] = c * mj - s * mi


@njit(cache=True, inline="always")
def _rot_vec_T(v, k, c, s, out):
    """out = R_k(angle)^T @ v."""
    i, j = (k + 1) % 3, (k + 2) % 3
    out[0], out[1], out[2] = v[0], v[1], v[2]
    out[i] = c * v[i] + s * v[j]
    out[j] = c * v[j] - s * v[i]


@njit(cache=True)
def rate_map_terms(R0, axes, theta):
    """Compiled twin of :func:`teleop.dynamics.rotations.rate_map_terms`.

    Returns R (3, 3), E_B (3, 3), E_B^-1 (3, 3) and dE (3, 3) whose rows are (a1, u, a2), with
    d/dt(E_B) thetadot = -(d1 d3) a1 - (d1 d2) u - (d2 d3) a2.
    """
    a, bx, c = axes[0], axes[1], axes[2]
    c1, s1 = math.cos(theta[0]), math.sin(theta[0])
    c2, s2 = math.cos(theta[1]), math.sin(theta[1])
    c3, s3 = math.cos(theta[2]), math.sin(theta[2])
    R = R0.copy()
    _rot_cols(R, a, c1, s1)
    _rot_cols(R, bx, c2, s2)
    _rot_cols(R, c, c3, s3)
    ea = np.zeros(3)
    ea[a] = 1.0
    eb = np.zeros(3)
    eb[bx] = 1.0
    ec = np.zeros(3)
    ec[c] = 1.0
    RbT_ea = np.empty(3)
    _rot_vec_T(ea, bx, c2, s2, RbT_ea)
    col1 = np.empty(3)
    _rot_vec_T(RbT_ea, c, c3, s3, col1)
    col2 = np.empty(3)
    _rot_vec_T(eb, c, c3, s3, col2)
    E = np.empty((3, 3))
    E[:, 0], E[:, 1], E[:, 2] = col1, col2, ec
    Einv = np.empty((3, 3))
    r = np.empty(3)
    _cross(col2, ec, r)
    Einv[0] = r
    _cross(ec, col1, r)
    Einv[1] = r
    _cross(col1, col2, r)
    Einv[2] = r
    det = _dot(col1, Einv[0])
    inv = 1.0 / det if det != 0.0 else math.inf
    for i in range(3):
        for j in range(3):
            Einv[i, j] *= inv
    dE = np.empty((3, 3))
    _cross(ec, col1, r)
    dE[0] = r
    _cross(eb, RbT_ea, r)
    u = np.empty(3)
    _rot_vec_T(r, c, c3, s3, u)
    dE[1] = u
    _cross(ec, col2, r)
    dE[2] = r
    return R, E, Einv, dE


@njit(cache=True)
def cholesky(K, rtol):
    """(L, ok): the lower Cholesky factor of K (m, m), and whether it exists with every pivot
    ratio min(d)^2 / max(d)^2 above ``rtol`` (otherwise the caller takes the eigen fallback)."""
    m = K.shape[0]
    L = np.zeros((m, m))
    for j in range(m):
        s = K[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:  # also catches NaN
            return L, False
        L[j, j] = math.sqrt(s)
        for i in range(j + 1, m):
            t = K[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / L[j, j]
    if m:
        dmin = dmax = L[0, 0]
        for j in range(1, m):
            dmin, dmax = min(dmin, L[j, j]), max(dmax, L[j, j])
        if not dmin * dmin > rtol * dmax * dmax:
            return L, False
    return L, True


@njit(cache=True)
def constraint_terms(R, p, J_inv, inv_m, G_template, kinds, offsets, params, rtol):
    """Pose-only dynamics terms at (p, R): I_W^-1 = R J^-1 R^T (3, 3), G (m, 6), M_nu^-1 G^T
    (6, m), the Delassus matrix K = G M_nu^-1 G^T (m, m), its Cholesky factor L and whether L is
    usable (see :func:`cholesky`)."""
    RJ = R @ J_inv
    Iinv = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            Iinv[i, j] = RJ[i, 0] * R[j, 0] + RJ[i, 1] * R[j, 1] + RJ[i, 2] * R[j, 2]
    m = G_template.shape[0]
    G = G_template.copy()
    b = np.empty(m)
    zero = np.zeros(3)
    stack_rows(G, b, kinds, offsets, params, p, R, zero, zero)
    MinvGt = np.empty((6, m))
    for r in range(m):
        for i in range(3):
            MinvGt[i, r] = G[r, i] * inv_m
            MinvGt[3 + i, r] = Iinv[i, 0] * G[r, 3] + Iinv[i, 1] * G[r, 4] + Iinv[i, 2] * G[r, 5]
    K = np.empty((m, m))
    for r in range(m):
        for c in range(r, m):
            s = 0.0
            for i in range(6):
                s += G[r, i] * MinvGt[i, c]
            K[r, c] = K[c, r] = s
    L, ok = cholesky(K, rtol)
    return Iinv, G, MinvGt, K, L, ok


@njit(cache=True)
def pose_terms(R0, axes, q, J_inv, inv_m, G_template, kinds, offsets, params, rtol):
    """Everything that depends on the pose q (6,) only, for a chart (R0, axes): R, E_B, E_B^-1,
    dE (see :func:`rate_map_terms`) followed by :func:`constraint_terms`."""
    R, E, Einv, dE = rate_map_terms(R0, axes, q[3:])
    Iinv, G, MinvGt, K, L, ok = constraint_terms(R, q[:3], J_inv, inv_m, G_template, kinds, offsets,
                                                 params, rtol)
    return R, E, Einv, dE, Iinv, G, MinvGt, K, L, ok


@njit(cache=True)
def _solve(S, mode, rhs):
    """lam with K lam = rhs: S is the Cholesky factor L (mode 1) or the pseudo-inverse (mode 2)."""
    m = rhs.shape[0]
    lam = np.zeros(m)
    if mode == SOLVE_CHOLESKY:
        y = np.empty(m)
        for i in range(m):
            s = rhs[i]
            for k in range(i):
                s -= S[i, k] * y[k]
            y[i] = s / S[i, i]
        for i in range(m - 1, -1, -1):
            s = y[i]
            for k in range(i + 1, m):
                s -= S[k, i] * lam[k]
            lam[i] = s / S[i, i]
    elif mode == SOLVE_PINV:
        for i in range(m):
            s = 0.0
            for k in range(m):
                s += S[i, k] * rhs[k]
            lam[i] = s
    return lam


@njit(cache=True, inline="always")
def _add_product(A, x, sign, out):
    """out += sign * A x, for A (n, m), x (m,), out (n,)."""
    for i in range(A.shape[0]):
        s = 0.0
        for r in range(A.shape[1]):
            s += A[i, r] * x[r]
        out[i] += sign * s


@njit(cache=True)
def newton_euler(R, Iinv, J, inv_m, coriolis, G, MinvGt, S, mode, kinds, offsets, params, p, v, w, F_in,
                 fx):
    """Eqs. 8-9 in twist form at pose (p, R), twist (v, w) (world), under the wrench F_in (6,)
    plus the compiled effects fx = (c_lin N*s/m, c_ang N*m*s/rad, gravity force (3,) N) (see
    :func:`effect_params`).

    Returns nudot (6,) = (vdot, wdot) world, lam (m,) and the total wrench F (6,).
    """
    F = np.empty(6)
    for i in range(3):
        F[i] = F_in[i] - fx[0] * v[i] + fx[2 + i]
        F[3 + i] = F_in[3 + i] - fx[1] * w[i]
    free = np.empty(6)
    for i in range(3):
        free[i] = F[i] * inv_m
    tq = np.empty(3)
    if coriolis:  # w x I_W w = R (w_B x J w_B)
        wB = np.empty(3)
        for i in range(3):
            wB[i] = R[0, i] * w[0] + R[1, i] * w[1] + R[2, i] * w[2]
        JwB = J @ wB
        g = np.empty(3)
        _cross(wB, JwB, g)
        _rv(R, g[0], g[1], g[2], tq)
        for i in range(3):
            tq[i] = F[3 + i] - tq[i]
    else:
        tq[:] = F[3:]
    _rv(Iinv, tq[0], tq[1], tq[2], free[3:])
    m = G.shape[0]
    nudot = free.copy()
    lam = np.zeros(m)
    if m:
        scratch = np.empty((m, 6))
        b = np.zeros(m)
        stack_rows(scratch, b, kinds, offsets, params, p, R, v, w)
        rhs = np.empty(m)
        for r in range(m):
            s = -b[r]
            for i in range(6):
                s -= G[r, i] * free[i]
            rhs[r] = s
        lam = _solve(S, mode, rhs)
        _add_product(MinvGt, lam, 1.0, nudot)
    return nudot, lam, F


@njit(cache=True)
def evaluate(R, E, Einv, dE, Iinv, J, inv_m, coriolis, G, MinvGt, S, mode,
             kinds, offsets, params, p, qd, F, fx):
    """Eqs. 8-9 at chart rates qd (6,) under the wrench F (6,) (operator plus the Python effects,
    world) and the compiled effects fx (see :func:`newton_euler`).

    Returns qdd (6,) chart accelerations, nudot (6,) = (vdot, wdot) world, lam (m,) and the total
    wrench (6,).
    """
    d1, d2, d3 = qd[3], qd[4], qd[5]
    w = np.empty(3)
    _rv(R, E[0, 0] * d1 + E[0, 1] * d2 + E[0, 2] * d3, E[1, 0] * d1 + E[1, 1] * d2 + E[1, 2] * d3,
        E[2, 0] * d1 + E[2, 1] * d2 + E[2, 2] * d3, w)
    nudot, lam, F = newton_euler(R, Iinv, J, inv_m, coriolis, G, MinvGt, S, mode, kinds, offsets,
                                 params, p, qd[:3], w, F, fx)
    k1, k2, k3 = d1 * d3, d1 * d2, d2 * d3
    qdd = np.empty(6)
    qdd[:3] = nudot[:3]
    x = np.empty(3)
    for i in range(3):  # R^T wdot - Edot thetadot
        x[i] = (R[0, i] * nudot[3] + R[1, i] * nudot[4] + R[2, i] * nudot[5]
                + k1 * dE[0, i] + k2 * dE[1, i] + k3 * dE[2, i])
    _rv(Einv, x[0], x[1], x[2], qdd[3:])
    return qdd, nudot, lam, F


@njit(cache=True)
def project_twist(G, MinvGt, S, mode, nu):
    """nu - M^-1 G^T K^+ G nu (6,): the admissible twist closest to nu in kinetic energy."""
    m = G.shape[0]
    out = nu.copy()
    if m == 0:
        return out
    Gnu = np.empty(m)
    for r in range(m):
        s = 0.0
        for i in range(6):
            s += G[r, i] * nu[i]
        Gnu[r] = s
    _add_product(MinvGt, _solve(S, mode, Gnu), -1.0, out)
    return out


@njit(cache=True)
def project_rates(R, E, Einv, G, MinvGt, S, mode, qd):
    """The admissible rates closest to qd (6,) in kinetic energy: T^-1 (nu - M^-1 G^T K^+ G nu)."""
    nu = np.empty(6)
    nu[:3] = qd[:3]
    d1, d2, d3 = qd[3], qd[4], qd[5]
    _rv(R, E[0, 0] * d1 + E[0, 1] * d2 + E[0, 2] * d3, E[1, 0] * d1 + E[1, 1] * d2 + E[1, 2] * d3,
        E[2, 0] * d1 + E[2, 1] * d2 + E[2, 2] * d3, nu[3:])
    nu = project_twist(G, MinvGt, S, mode, nu)
    out = np.empty(6)
    out[:3] = nu[:3]
    x = np.empty(3)
    for i in range(3):
        x[i] = R[0, i] * nu[3] + R[1, i] * nu[4] + R[2, i] * nu[5]
    _rv(Einv, x[0], x[1], x[2], out[3:])
    return out


@njit(cache=True)
def left_pinv(P):
    """(P^T P)^-1 P^T for a tall P (n, k) of full column rank: eq. 11's pseudo-inverse of Psi.

    Solved by Cholesky of the k x k normal matrix; a rank-deficient P (a chart pole) gives
    non-finite entries, which the caller treats as a singular step.
    """
    n, k = P.shape
    N = np.empty((k, k))
    for i in range(k):
        for j in range(i, k):
            s = 0.0
            for r in range(n):
                s += P[r, i] * P[r, j]
            N[i, j] = N[j, i] = s
    L, ok = cholesky(N, 0.0)
    out = np.empty((k, n))
    if not ok:
        out[:] = np.nan
        return out
    for c in range(n):
        out[:, c] = _solve(L, SOLVE_CHOLESKY, P[c].copy())
    return out


@njit(cache=True)
def flat_advance(z, zd, qdd, P, Pinv, q0, h):
    """Eqs. 10-11 for an affine parametrization q = q0 + P z (no curvature term): semi-implicit
    Euler zd += h P^+ qdd, z += h zd, then q and qd = P zd. Returns z, zd, q, qd (new arrays)."""
    n, k = P.shape
    zd2 = np.empty(k)
    z2 = np.empty(k)
    for i in range(k):
        s = 0.0
        for j in range(n):
            s += Pinv[i, j] * qdd[j]
        zd2[i] = zd[i] + h * s
        z2[i] = z[i] + h * zd2[i]
    q = np.empty(n)
    qd = np.empty(n)
    for j in range(n):
        a, b = q0[j], 0.0
        for i in range(k):
            a += P[j, i] * z2[i]
            b += P[j, i] * zd2[i]
        q[j], qd[j] = a, b
    return z2, zd2, q, qd


@njit(cache=True)
def project_parameter_rates(R, E, Einv, G, MinvGt, S, mode, qd, P, Pinv):
    """:func:`project_rates` in parameter space: zd = P^+ (projected qd), and qd = P zd again.
    Returns zd (k,), qd (6,)."""
    qp = project_rates(R, E, Einv, G, MinvGt, S, mode, qd)
    n, k = P.shape
    zd = np.zeros(k)
    _add_product(Pinv, qp, 1.0, zd)
    out = np.zeros(n)
    _add_product(P, zd, 1.0, out)
    return zd, out
