"""Compiled kernels (numba) of the engine's motion, each written once: the chart terms, one
evaluation of eqs. 8-9 (chart and twist form), the kinetic-energy projection of twists and rates,
and the flat (affine psi) parametric step.

Every kernel takes the constraint rows as inputs: G (m, 6) on the twist nu = (v, w) (world, at the
body origin) and the velocity-product term b (m,) = d/dt(G) nu, both from
:class:`teleop.dynamics.rows.RowStack`, so a user's Python constraint goes through the same solve.
M_nu^-1 = blockdiag(I3/m, R J^-1 R^T); the Delassus matrix K = G M_nu^-1 G^T is factored by
Cholesky, or, when rows are redundant (a pivot ratio below ``rtol``), by a truncated symmetric
eigendecomposition (minimum-norm multipliers; the numerical rank is returned).

Why compiled: an evaluation is some sixty operations on 3-vectors and 3x3 to 6x6 matrices; numpy
costs about a microsecond of call overhead per operation whatever its size. ``NUMBA_DISABLE_JIT=1``
runs this code as Python. Tested against Pinocchio's constrained dynamics, the chart-coordinate
form of eqs. 8-9 (:func:`teleop.dynamics.model.evaluate_literal`), finite differences and energy.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from teleop.dynamics.kernels.rows import _cross3, _dot, _rv, _rv3
from teleop.dynamics.kernels.small import cholesky
from teleop.dynamics.kernels.wrench import add_compiled_effects


@njit(cache=True, inline="always")
def _chart_rates(R, Einv, nu, out):
    """out (6,) <- the chart rates of the world twist nu (6,): v, and E_B^-1 R^T w."""
    out[:3] = nu[:3]
    x0 = R[0, 0] * nu[3] + R[1, 0] * nu[4] + R[2, 0] * nu[5]
    x1 = R[0, 1] * nu[3] + R[1, 1] * nu[4] + R[2, 1] * nu[5]
    x2 = R[0, 2] * nu[3] + R[1, 2] * nu[4] + R[2, 2] * nu[5]
    _rv(Einv, x0, x1, x2, out[3:])


# -- chart terms -------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _rot_cols(M, k, c, s):
    """M <- M @ R_k(angle) (only two columns change)."""
    i, j = (k + 1) % 3, (k + 2) % 3
    for r in range(3):
        mi, mj = M[r, i], M[r, j]
        M[r, i] = c * mi + s * mj
        M[r, j] = c * mj - s * mi


@njit(cache=True, inline="always")
def _rot_vec_T(v, k, c, s):
    """R_k(angle)^T @ v, a 3-tuple (v a 3-tuple): only the entries (k + 1) % 3 and (k + 2) % 3
    change."""
    i, j = (k + 1) % 3, (k + 2) % 3
    x, y = c * v[i] + s * v[j], c * v[j] - s * v[i]
    if k == 0:
        return (v[0], x, y)
    if k == 1:
        return (y, v[1], x)
    return (x, y, v[2])


@njit(cache=True, inline="always")
def _unit(k):
    """The k-th coordinate axis, a 3-tuple."""
    return (1.0 if k == 0 else 0.0, 1.0 if k == 1 else 0.0, 1.0 if k == 2 else 0.0)


@njit(cache=True)
def rate_map_into(R0, axes, theta, mats):
    """:func:`rate_map_terms` into mats (5, 3, 3) = (R, E_B, E_B^-1, dE, E_W)."""
    a, bx, c = axes[0], axes[1], axes[2]
    c1, s1 = math.cos(theta[0]), math.sin(theta[0])
    c2, s2 = math.cos(theta[1]), math.sin(theta[1])
    c3, s3 = math.cos(theta[2]), math.sin(theta[2])
    R, E, Einv, dE, EW = mats[0], mats[1], mats[2], mats[3], mats[4]
    for i in range(3):
        for j in range(3):
            R[i, j] = R0[i, j]
    _rot_cols(R, a, c1, s1)
    _rot_cols(R, bx, c2, s2)
    _rot_cols(R, c, c3, s3)
    eb, ec = _unit(bx), _unit(c)
    RbT_ea = _rot_vec_T(_unit(a), bx, c2, s2)
    col1 = _rot_vec_T(RbT_ea, c, c3, s3)
    col2 = _rot_vec_T(eb, c, c3, s3)
    r0, r1, r2 = _cross3(col2, ec), _cross3(ec, col1), _cross3(col1, col2)
    det = _dot(col1, r0)
    inv = 1.0 / det if det != 0.0 else math.inf
    u = _rot_vec_T(_cross3(eb, RbT_ea), c, c3, s3)
    d2 = _cross3(ec, col2)
    for i in range(3):
        E[i, 0], E[i, 1], E[i, 2] = col1[i], col2[i], ec[i]
        Einv[0, i], Einv[1, i], Einv[2, i] = r0[i] * inv, r1[i] * inv, r2[i] * inv
        dE[0, i], dE[1, i], dE[2, i] = r1[i], u[i], d2[i]
    for i in range(3):
        for j in range(3):
            EW[i, j] = R[i, 0] * E[0, j] + R[i, 1] * E[1, j] + R[i, 2] * E[2, j]


@njit(cache=True)
def rate_map_terms(R0, axes, theta):
    """Pose-only chart terms at Euler angles theta (3,) rad of the chart (R0 (3, 3), axes (3,)).

    Returns one (5, 3, 3) array of R = R_WB, E_B (body rate = E_B thetadot), E_B^-1, dE whose
    rows are (a1, u, a2), with d/dt(E_B) thetadot = -(d1 d3) a1 - (d1 d2) u - (d2 d3) a2 for
    rates (d1, d2, d3), and E_W = R E_B (world rate = E_W thetadot). Tested against
    :func:`teleop.dynamics.rotations.rate_map` (axis products).
    """
    mats = np.empty((5, 3, 3))
    rate_map_into(R0, axes, theta, mats)
    return mats


@njit(cache=True)
def _solve(S, mode, rhs):
    """lam with L L^T lam = rhs for a lower Cholesky factor L = S (``mode`` is 1)."""
    m = rhs.shape[0]
    lam = np.zeros(m)
    if mode == 1:  # forward substitution into lam (y), then backward in place
        for i in range(m):
            s = rhs[i]
            for k in range(i):
                s -= S[i, k] * lam[k]
            lam[i] = s / S[i, i]
        for i in range(m - 1, -1, -1):
            s = lam[i]
            for k in range(i + 1, m):
                s -= S[k, i] * lam[k]
            lam[i] = s / S[i, i]
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
        out[:, c] = _solve(L, 1, P[c].copy())
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




# -- eqs. 8-9 and the projections, from rows (G, b) ----------------------------------------------
@njit(cache=True)
def delassus_solve(K, rhs, rtol):
    """(lam (m,), rank): K lam = rhs for a symmetric PSD K (m, m). Cholesky when every pivot ratio
    min(d)^2 / max(d)^2 exceeds ``rtol``; else the eigendecomposition with eigenvalues below
    rtol * max dropped (minimum-norm, least squares for inconsistent rows)."""
    m = K.shape[0]
    if m == 0:
        return np.zeros(0), 0
    L, ok = cholesky(K, rtol)
    if ok:
        return _solve(L, 1, rhs), m
    w, V = np.linalg.eigh(K)
    floor = rtol * max(w[m - 1], 0.0)
    lam = np.zeros(m)
    rank = 0
    for k in range(m):
        if w[k] > floor:
            rank += 1
            c = 0.0
            for i in range(m):
                c += V[i, k] * rhs[i]
            c /= w[k]
            for i in range(m):
                lam[i] += c * V[i, k]
    return lam, rank


@njit(cache=True)
def _inverse_inertia(R, J_inv):
    """I_W^-1 = R J^-1 R^T (3, 3)."""
    Iinv = np.empty((3, 3))
    for i in range(3):
        RJ = (R[i, 0] * J_inv[0, 0] + R[i, 1] * J_inv[1, 0] + R[i, 2] * J_inv[2, 0],
              R[i, 0] * J_inv[0, 1] + R[i, 1] * J_inv[1, 1] + R[i, 2] * J_inv[2, 1],
              R[i, 0] * J_inv[0, 2] + R[i, 1] * J_inv[1, 2] + R[i, 2] * J_inv[2, 2])  # row i of R J^-1
        for j in range(3):
            Iinv[i, j] = RJ[0] * R[j, 0] + RJ[1] * R[j, 1] + RJ[2] * R[j, 2]
    return Iinv


@njit(cache=True)
def solve_rows(R, J_inv, inv_m, G, rhs, rtol):
    """(d (6,), lam (m,), rank): lam = K^+ rhs and d = M_nu^-1 G^T lam, the twist of least kinetic
    energy with G d = rhs (when consistent), at the attitude R."""
    Iinv = _inverse_inertia(R, J_inv)
    m = G.shape[0]
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
    lam, rank = delassus_solve(K, rhs, rtol)
    d = np.zeros(6)
    _add_product(MinvGt, lam, 1.0, d)
    return d, lam, rank


@njit(cache=True)
def newton_euler(R, J, J_inv, inv_m, coriolis, G, b, v, w, F_in, fx, rtol):
    """Eqs. 8-9 in twist form at attitude R, twist (v, w) (world), rows G (m, 6), b (m,), under the
    wrench F_in (6,) plus the compiled effects fx = (c_lin N*s/m, c_ang N*m*s/rad, gravity force
    (3,) N) (see :func:`effect_params`).

    Returns nudot (6,) = (vdot, wdot) world, lam (m,) in N and N*m, the rank of K, the total
    applied wrench F (6,) and the constraint wrench G^T lam (6,).
    """
    F = np.empty(6)
    add_compiled_effects(F_in, fx, v, w, F)
    free = np.empty(6)
    for i in range(3):
        free[i] = F[i] * inv_m
    tq = (F[3], F[4], F[5])
    if coriolis:  # w x I_W w = R (w_B x J w_B)
        wB = (R[0, 0] * w[0] + R[1, 0] * w[1] + R[2, 0] * w[2], R[0, 1] * w[0] + R[1, 1] * w[1] + R[2, 1] * w[2],
              R[0, 2] * w[0] + R[1, 2] * w[1] + R[2, 2] * w[2])
        g = _cross3(wB, _rv3(J, wB[0], wB[1], wB[2]))
        Rg = _rv3(R, g[0], g[1], g[2])
        tq = (F[3] - Rg[0], F[4] - Rg[1], F[5] - Rg[2])
    Iinv = _inverse_inertia(R, J_inv)
    _rv(Iinv, tq[0], tq[1], tq[2], free[3:])
    m = G.shape[0]
    rhs = np.empty(m)
    for r in range(m):
        s = -b[r]
        for i in range(6):
            s -= G[r, i] * free[i]
        rhs[r] = s
    d, lam, rank = solve_rows(R, J_inv, inv_m, G, rhs, rtol)
    Gtl = np.zeros(6)
    for r in range(m):
        for i in range(6):
            Gtl[i] += G[r, i] * lam[r]
    for i in range(6):
        free[i] += d[i]
    return free, lam, rank, F, Gtl


@njit(cache=True)
def evaluate(R, E, Einv, dE, J, J_inv, inv_m, coriolis, G, b, qd, F, fx, rtol):
    """Eqs. 8-9 at chart rates qd (6,) (chart terms from :func:`rate_map_terms`), rows G, b and
    the wrench F (6,) (operator plus the Python effects, world); see :func:`newton_euler`.

    Returns qdd (6,) chart accelerations, nudot (6,), lam (m,), rank, total wrench (6,) and the
    constraint wrench G^T lam (6,).
    """
    d1, d2, d3 = qd[3], qd[4], qd[5]
    w = np.empty(3)
    _rv(R, E[0, 0] * d1 + E[0, 1] * d2 + E[0, 2] * d3, E[1, 0] * d1 + E[1, 1] * d2 + E[1, 2] * d3,
        E[2, 0] * d1 + E[2, 1] * d2 + E[2, 2] * d3, w)
    nudot, lam, rank, F, Gtl = newton_euler(R, J, J_inv, inv_m, coriolis, G, b, qd[:3], w, F, fx, rtol)
    k1, k2, k3 = d1 * d3, d1 * d2, d2 * d3
    qdd = np.empty(6)
    qdd[:3] = nudot[:3]
    x = np.empty(3)
    for i in range(3):  # R^T wdot - Edot thetadot
        x[i] = (R[0, i] * nudot[3] + R[1, i] * nudot[4] + R[2, i] * nudot[5]
                + k1 * dE[0, i] + k2 * dE[1, i] + k3 * dE[2, i])
    _rv(Einv, x[0], x[1], x[2], qdd[3:])
    return qdd, nudot, lam, rank, F, Gtl


@njit(cache=True)
def project_twist(R, J_inv, inv_m, G, nu, rtol):
    """nu - M_nu^-1 G^T K^+ G nu (6,): the admissible twist closest to nu in kinetic energy."""
    m = G.shape[0]
    Gnu = np.empty(m)
    for r in range(m):
        s = 0.0
        for i in range(6):
            s += G[r, i] * nu[i]
        Gnu[r] = s
    d, _, _ = solve_rows(R, J_inv, inv_m, G, Gnu, rtol)
    return nu - d


@njit(cache=True)
def project_rates(R, E, Einv, J_inv, inv_m, G, qd, rtol):
    """The admissible chart rates closest to qd (6,) in kinetic energy: T^-1 (projected T qd)."""
    nu = np.empty(6)
    nu[:3] = qd[:3]
    d1, d2, d3 = qd[3], qd[4], qd[5]
    _rv(R, E[0, 0] * d1 + E[0, 1] * d2 + E[0, 2] * d3, E[1, 0] * d1 + E[1, 1] * d2 + E[1, 2] * d3,
        E[2, 0] * d1 + E[2, 1] * d2 + E[2, 2] * d3, nu[3:])
    nu = project_twist(R, J_inv, inv_m, G, nu, rtol)
    out = np.empty(6)
    _chart_rates(R, Einv, nu, out)
    return out


@njit(cache=True)
def project_parameter_rates(R, E, Einv, J_inv, inv_m, G, qd, P, Pinv, rtol):
    """:func:`project_rates` in parameter space: zd = P^+ (projected qd), and qd = P zd again.
    Returns zd (k,), qd (6,)."""
    qp = project_rates(R, E, Einv, J_inv, inv_m, G, qd, rtol)
    n, k = P.shape
    zd = np.zeros(k)
    _add_product(Pinv, qp, 1.0, zd)
    out = np.zeros(n)
    _add_product(P, zd, 1.0, out)
    return zd, out


# -- energy ----------------------------------------------------------------------------------------
@njit(cache=True)
def energy_rates(R, E_W, J, mass, qd, F, fx):
    """(K J, a W, b W) at chart rates qd (6,) (chart terms R, E_W = R E_B): the kinetic energy
    K = 1/2 m v.v + 1/2 w_B.J w_B, the power a = F . nu of the wrench F (6,) (world, at the body
    origin), and the dampers' dissipation b = c_lin v.v + c_ang w.w (fx as in :func:`newton_euler`;
    gravity is conservative and is not in a or b). The power of the forces at rates s qd is
    a s - b s^2."""
    v0, v1, v2 = qd[0], qd[1], qd[2]
    d1, d2, d3 = qd[3], qd[4], qd[5]
    w = np.empty(3)
    for i in range(3):
        w[i] = E_W[i, 0] * d1 + E_W[i, 1] * d2 + E_W[i, 2] * d3
    wB = np.empty(3)
    for i in range(3):
        wB[i] = R[0, i] * w[0] + R[1, i] * w[1] + R[2, i] * w[2]
    vv = v0 * v0 + v1 * v1 + v2 * v2
    ww = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    rot = 0.0
    for i in range(3):
        rot += wB[i] * (J[i, 0] * wB[0] + J[i, 1] * wB[1] + J[i, 2] * wB[2])
    K = 0.5 * mass * vv + 0.5 * rot
    a = F[0] * v0 + F[1] * v1 + F[2] * v2 + F[3] * w[0] + F[4] * w[1] + F[5] * w[2]
    return K, a, fx[0] * vv + fx[1] * ww


@njit(cache=True)
def gravity_potential(fx, p):
    """-g . p (J): the potential energy of the compiled gravity (fx[2:5], the weight, N; fx as in
    :func:`newton_euler`) at the body origin p (3,) m."""
    return -(fx[2] * p[0] + fx[3] * p[1] + fx[4] * p[2])


@njit(cache=True)
def energy_scale(E0, K, a, b, a0, b0, V, h, max_scale):
    """The energy-consistent correction of :class:`teleop.dynamics.integrators.EnergyConsistent`:
    the scale s of the end rates that solves s^2 (K + h b / 2) - (h a / 2) s - (E0 + h P0 / 2 - V) = 0
    (the root near 1), i.e. E(q1, s qd1) - E0 = h/2 (P0 + P1(s)) with P = a - b (:func:`energy_rates`
    at the start, a0 and b0, and at the end, a and b; K the end's kinetic energy, V its potential
    energy, E0 the energy before the step, J). Returns (s, E1, applied): applied when |s - 1| <=
    max_scale (then the rates are scaled and E1 = s^2 K + V), otherwise (NaN included) the step's
    own energy E1 = K + V is kept."""
    A, B, C = K + 0.5 * h * b, 0.5 * h * a, E0 + 0.5 * h * (a0 - b0) - V
    disc = B * B + 4.0 * A * C
    s = (B + math.sqrt(disc)) / (2.0 * A) if A > 0.0 and disc >= 0.0 else math.nan
    if abs(s - 1.0) <= max_scale:  # False for NaN
        return s, C + V + 0.5 * h * (a * s - b * s * s), True  # = E0 + h/2 (P0 + P1(s)) = s^2 K + V
    return s, K + V, False


@njit(cache=True)
def constraint_acceleration(R, J_inv, inv_m, g):
    """M_nu^-1 g (6,): the twist acceleration (world) a wrench g (6,: N, N*m, world, at the body
    origin) gives the body at attitude R; for g = G^T lam, the constraints' share of nudot."""
    out = np.empty(6)
    for i in range(3):
        out[i] = inv_m * g[i]
    Iinv = _inverse_inertia(R, J_inv)
    _rv(Iinv, g[3], g[4], g[5], out[3:])
    return out


@njit(cache=True)
def split_twist(R, E_W, J_inv, inv_m, qd, nudot, g, F, fx, h):
    """The velocity of the RATTLE-type split step, before the end's projection:
    nu* = nu_0 + h nudot_0 - h/2 M^-1 G^T lam_0 (6,) (the applied forces over the whole step, the
    start's constraint impulse over its first half), with nu_0 = (qd[:3], E_W qd[3:]) and the
    constraint wrench g = G^T lam (6,). Also the start's power terms (a0, b0) of
    :func:`energy_rates`. Returns nu*, a0, b0."""
    _, a0, b0 = energy_rates(R, E_W, np.eye(3), 1.0, qd, F, fx)
    c = constraint_acceleration(R, J_inv, inv_m, g)
    nu = np.empty(6)
    for i in range(3):
        nu[i] = qd[i]
        nu[3 + i] = E_W[i, 0] * qd[3] + E_W[i, 1] * qd[4] + E_W[i, 2] * qd[5]
    for i in range(6):
        nu[i] += h * nudot[i] - 0.5 * h * c[i]
    return nu, a0, b0


@njit(cache=True)
def split_end(R, E_W, Einv, J, J_inv, mass, G, nu, P, Pinv, F, fx, rtol):
    """The end of the split step at the new pose: nu (6,) projected onto the rows G in the
    kinetic-energy metric (the second half of the constraint impulse), mapped to parameter rates
    zd = P^+ T^-1 nu and chart rates qd = P zd; with :func:`energy_rates` at qd.
    Returns zd (k,), qd (6,), K, a, b."""
    nup = project_twist(R, J_inv, 1.0 / mass, G, nu, rtol)
    qf = np.empty(6)
    _chart_rates(R, Einv, nup, qf)
    n, k = P.shape
    zd = np.zeros(k)
    _add_product(Pinv, qf, 1.0, zd)
    qd = np.zeros(n)
    _add_product(P, zd, 1.0, qd)
    K, a, b = energy_rates(R, E_W, J, mass, qd, F, fx)
    return zd, qd, K, a, b
