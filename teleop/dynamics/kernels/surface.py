"""Compiled kernels of the curved-surface fixture and tissue (:mod:`teleop.dynamics.surface`).

The height field f(u, v) is a tensor-product B-spline given by scipy's own representation
(``RectBivariateSpline.tck``: full knot vectors tx, ty, coefficients c (nx, ny), degree k each
way), evaluated here from its knots and coefficients: the B-spline basis and its derivatives by
Cox-de Boor's recurrence (Piegl & Tiller, The NURBS Book, algorithm A2.3), so f and its partials to
third order cost (k+1)^2 products per order. Placed by a frame, S(u, v) = o + kQ (u, v, f(u, v))
(m), with kQ = k Q the scaled rotation (its third column the scaled "up").

Kernels (argument ``geo`` is the tuple (o (3,), kQ (3, 3), tx, ty, c (nx, ny), k)):

* :func:`height_partials`: F[a, b] = d^(a+b) f / du^a dv^b, a + b <= 3;
* :func:`surface_derivatives`: S (3,), S1 (2, 3), S2 (2, 2, 3), S3 (2, 2, 2, 3);
* :func:`closest_foot`: the foot (u, v) of a point, Newton on (p - S) . S_i = 0;
* :func:`surface_frame`: the tangent frame (t1, t2, n) and its derivatives along u, v;
* :func:`depth_rows`: the three rows of :class:`teleop.dynamics.surface_fixture.SurfaceDepth`
  (G, the velocity-product term b, the residual h; their formulas in that module's docstring).

Units: u, v in the grid's units (m of the patient frame), S in m, derivatives in m per unit^i.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def find_span(t, k, x):
    """The knot span i (k <= i < n, n = len(t) - k - 1) with t[i] <= x < t[i+1]; x outside the
    domain takes the end span (the end polynomial, extrapolated)."""
    n = t.shape[0] - k - 1
    if x >= t[n]:
        return n - 1
    if x <= t[k]:
        return k
    lo, hi = k, n
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if x < t[mid]:
            hi = mid
        else:
            lo = mid
    return lo


@njit(cache=True)
def basis_derivatives(t, k, span, x, nd, ders):
    """ders[a, j] (nd+1, k+1): the a-th derivative of the basis function N_{span-k+j, k} at x
    (The NURBS Book A2.3); orders above k are zero."""
    ndu = np.empty((k + 1, k + 1))
    left = np.empty(k + 1)
    right = np.empty(k + 1)
    ndu[0, 0] = 1.0
    for j in range(1, k + 1):
        left[j] = x - t[span + 1 - j]
        right[j] = t[span + j] - x
        saved = 0.0
        for r in range(j):
            ndu[j, r] = right[r + 1] + left[j - r]
            temp = ndu[r, j - 1] / ndu[j, r]
            ndu[r, j] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        ndu[j, j] = saved
    for a in range(nd + 1):
        for j in range(k + 1):
            ders[a, j] = 0.0
    for j in range(k + 1):
        ders[0, j] = ndu[j, k]
    a = np.empty((2, k + 1))
    top = min(nd, k)
    for r in range(k + 1):
        s1, s2 = 0, 1
        a[0, 0] = 1.0
        for kk in range(1, top + 1):
            d = 0.0
            rk, pk = r - kk, k - kk
            if r >= kk:
                a[s2, 0] = a[s1, 0] / ndu[pk + 1, rk]
                d = a[s2, 0] * ndu[rk, pk]
            j1 = 1 if rk >= -1 else -rk
            j2 = kk - 1 if r - 1 <= pk else k - r
            for j in range(j1, j2 + 1):
                a[s2, j] = (a[s1, j] - a[s1, j - 1]) / ndu[pk + 1, rk + j]
                d += a[s2, j] * ndu[rk + j, pk]
            if r <= pk:
                a[s2, kk] = -a[s1, kk - 1] / ndu[pk + 1, r]
                d += a[s2, kk] * ndu[r, pk]
            ders[kk, r] = d
            s1, s2 = s2, s1
    fac = float(k)
    for kk in range(1, top + 1):
        for j in range(k + 1):
            ders[kk, j] *= fac
        fac *= k - kk
    return ders


@njit(cache=True)
def height_partials(tx, ty, c, k, u, v, upto, F):
    """F[a, b] (4, 4) = d^(a+b) f / du^a dv^b at (u, v) for a + b <= upto (<= 3); others 0."""
    iu = find_span(tx, k, u)
    jv = find_span(ty, k, v)
    Bu = basis_derivatives(tx, k, iu, u, upto, np.empty((upto + 1, k + 1)))
    Bv = basis_derivatives(ty, k, jv, v, upto, np.empty((upto + 1, k + 1)))
    for a in range(4):
        for b in range(4):
            F[a, b] = 0.0
    for a in range(upto + 1):
        for b in range(upto + 1 - a):
            acc = 0.0
            for i in range(k + 1):
                row = 0.0
                for j in range(k + 1):
                    row += c[iu - k + i, jv - k + j] * Bv[b, j]
                acc += Bu[a, i] * row
            F[a, b] = acc
    return F


@njit(cache=True)
def surface_derivatives(o, kQ, tx, ty, c, k, u, v, upto, S, S1, S2, S3):
    """World S (3,), S1 (2, 3), S2 (2, 2, 3) and, for upto = 3, S3 (2, 2, 2, 3) at (u, v)."""
    F = height_partials(tx, ty, c, k, u, v, max(upto, 2), np.empty((4, 4)))
    for x in range(3):
        e = kQ[x, 2]
        S[x] = o[x] + kQ[x, 0] * u + kQ[x, 1] * v + e * F[0, 0]
        S1[0, x] = kQ[x, 0] + F[1, 0] * e
        S1[1, x] = kQ[x, 1] + F[0, 1] * e
        S2[0, 0, x] = F[2, 0] * e
        S2[0, 1, x] = F[1, 1] * e
        S2[1, 0, x] = F[1, 1] * e
        S2[1, 1, x] = F[0, 2] * e
        if upto >= 3:
            for i in range(2):
                for j in range(2):
                    for m in range(2):
                        nv_ = i + j + m  # derivatives along v among the three
                        S3[i, j, m, x] = F[3 - nv_, nv_] * e


@njit(cache=True)
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


@njit(cache=True)
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def closest_foot(o, kQ, tx, ty, c, k, p, u0, v0, tol, iters, out):
    """The foot (u, v) of the world point p (3,): Newton on (p - S) . S_i = 0 from (u0, v0).
    out (2,) gets (u, v); returns whether it converged (step below tol relative)."""
    S, S1 = np.empty(3), np.empty((2, 3))
    S2, S3 = np.empty((2, 2, 3)), np.empty((2, 2, 2, 3))
    u, v = u0, v0
    r = np.empty(3)
    for _ in range(iters):
        surface_derivatives(o, kQ, tx, ty, c, k, u, v, 2, S, S1, S2, S3)
        for x in range(3):
            r[x] = p[x] - S[x]
        f0, f1 = _dot(S1[0], r), _dot(S1[1], r)
        a00 = _dot(S1[0], S1[0]) - _dot(S2[0, 0], r)
        a01 = _dot(S1[0], S1[1]) - _dot(S2[0, 1], r)
        a11 = _dot(S1[1], S1[1]) - _dot(S2[1, 1], r)
        det = a00 * a11 - a01 * a01
        if not (abs(det) > 0.0 and math.isfinite(det)):
            break
        du = (a11 * f0 - a01 * f1) / det
        dv = (a00 * f1 - a01 * f0) / det
        u += du
        v += dv
        if not (math.isfinite(u) and math.isfinite(v)):
            break
        if abs(du) + abs(dv) < tol * max(1.0, abs(u) + abs(v)):
            out[0], out[1] = u, v
            return True
    out[0], out[1] = u, v
    return False


@njit(cache=True)
def unit_normal(S1, n):
    """n = (S_u x S_v) / |S_u x S_v| into n (3,); returns |S_u x S_v|."""
    _cross(S1[0], S1[1], n)
    mu = math.sqrt(_dot(n, n))
    for x in range(3):
        n[x] /= mu
    return mu


@njit(cache=True)
def normal_derivatives(S1, S2, n, mu, N):
    """N (2, 3): dn/dc_i of the unit normal n with |S_u x S_v| = mu."""
    a, b = np.empty(3), np.empty(3)
    for i in range(2):
        _cross(S2[0, i], S1[1], a)
        _cross(S1[0], S2[1, i], b)
        nm = 0.0
        for x in range(3):
            a[x] += b[x]
        nm = _dot(n, a)
        for x in range(3):
            N[i, x] = (a[x] - n[x] * nm) / mu


@njit(cache=True)
def surface_frame(o, kQ, tx, ty, c, k, u, v, F, S, S1, n, dF):
    """The frame F (3, 3) = columns (t1, t2, n), t1 = S_u/|S_u|, t2 = n x t1, and S, S1, n at
    (u, v); dF (2, 3, 3) = dF/dc_i."""
    S2, S3 = np.empty((2, 2, 3)), np.empty((2, 2, 2, 3))
    surface_derivatives(o, kQ, tx, ty, c, k, u, v, 2, S, S1, S2, S3)
    mu = unit_normal(S1, n)
    N = np.empty((2, 3))
    normal_derivatives(S1, S2, n, mu, N)
    lu = math.sqrt(_dot(S1[0], S1[0]))
    t1, t2 = np.empty(3), np.empty(3)
    for x in range(3):
        t1[x] = S1[0, x] / lu
    _cross(n, t1, t2)
    for x in range(3):
        F[x, 0], F[x, 1], F[x, 2] = t1[x], t2[x], n[x]
    t1i, a, b = np.empty(3), np.empty(3), np.empty(3)
    for i in range(2):
        d = _dot(t1, S2[0, i])
        for x in range(3):
            t1i[x] = (S2[0, i, x] - t1[x] * d) / lu
        _cross(N[i], t1, a)
        _cross(n, t1i, b)
        for x in range(3):
            dF[i, x, 0] = t1i[x]
            dF[i, x, 1] = a[x] + b[x]
            dF[i, x, 2] = N[i, x]


@njit(cache=True)
def _solve2(A, y, out):
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    out[0] = (A[1, 1] * y[0] - A[0, 1] * y[1]) / det
    out[1] = (A[0, 0] * y[1] - A[1, 0] * y[0]) / det
    return out


@njit(cache=True)
def depth_rows(o, kQ, tx, ty, c, k, d, depth, p, R, v, w, moving, foot, G, b, h):
    """The three rows of SurfaceDepth at the pose (p, R) and twist (v, w): G (3, 6), b (3,)
    (zero unless ``moving``), h (3,). ``foot`` (3,) = (u, v, valid): Newton's warm start, updated
    (valid 0: start from the point's own (u, v)). Returns False when a value is not finite."""
    Rd, tip = np.empty(3), np.empty(3)
    for x in range(3):
        Rd[x] = R[x, 0] * d[0] + R[x, 1] * d[1] + R[x, 2] * d[2]
        tip[x] = p[x] + Rd[x]
    uv = np.empty(2)
    ok = False
    if foot[2] != 0.0:
        ok = closest_foot(o, kQ, tx, ty, c, k, tip, foot[0], foot[1], 1e-13, 30, uv)
    if not ok:  # the point's own (u, v) in the height field's frame
        s2 = _dot(kQ[:, 0], kQ[:, 0])
        u0 = ((tip[0] - o[0]) * kQ[0, 0] + (tip[1] - o[1]) * kQ[1, 0] + (tip[2] - o[2]) * kQ[2, 0]) / s2
        v0 = ((tip[0] - o[0]) * kQ[0, 1] + (tip[1] - o[1]) * kQ[1, 1] + (tip[2] - o[2]) * kQ[2, 1]) / s2
        ok = closest_foot(o, kQ, tx, ty, c, k, tip, u0, v0, 1e-13, 30, uv)
    # not converged: the rows at Newton's last iterate (as close as it got), no warm start next time
    foot[0], foot[1], foot[2] = uv[0], uv[1], 1.0 if ok else 0.0
    S, S1 = np.empty(3), np.empty((2, 3))
    S2, S3 = np.empty((2, 2, 3)), np.empty((2, 2, 2, 3))
    surface_derivatives(o, kQ, tx, ty, c, k, uv[0], uv[1], 3, S, S1, S2, S3)
    n = np.empty(3)
    mu = unit_normal(S1, n)
    N = np.empty((2, 3))
    normal_derivatives(S1, S2, n, mu, N)
    r = np.empty(3)
    for x in range(3):
        r[x] = tip[x] - S[x]
    A = np.empty((2, 2))
    for i in range(2):
        for j in range(2):
            A[i, j] = _dot(S1[i], S1[j]) - _dot(S2[i, j], r)
    # M = N^T A^-1 S1 (3, 3): n_dot = M v_tip
    Ainv_S1 = np.empty((2, 3))
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    for x in range(3):
        Ainv_S1[0, x] = (A[1, 1] * S1[0, x] - A[0, 1] * S1[1, x]) / det
        Ainv_S1[1, x] = (A[0, 0] * S1[1, x] - A[1, 0] * S1[0, x]) / det
    M = np.empty((3, 3))
    for x in range(3):
        for y in range(3):
            M[x, y] = N[0, x] * Ainv_S1[0, y] + N[1, x] * Ainv_S1[1, y]
    tmp = np.empty(3)
    h[0] = _dot(n, r) + depth
    _cross(Rd, n, tmp)
    for x in range(3):
        G[0, x], G[0, 3 + x] = n[x], tmp[x]
    bvec, mb, t2 = np.empty(3), np.empty(3), np.empty(3)
    for i in (1, 2):
        for x in range(3):
            bvec[x] = R[x, i - 1]
        h[i] = _dot(bvec, n)
        for y in range(3):
            mb[y] = M[0, y] * bvec[0] + M[1, y] * bvec[1] + M[2, y] * bvec[2]
        _cross(bvec, n, tmp)
        _cross(Rd, mb, t2)
        for x in range(3):
            G[i, x], G[i, 3 + x] = mb[x], tmp[x] + t2[x]
    ok = True
    for i in range(3):
        ok = ok and math.isfinite(h[i])
        for x in range(6):
            ok = ok and math.isfinite(G[i, x])
    if not moving:
        b[0] = b[1] = b[2] = 0.0
        return ok
    # the velocity-product term: the rows' rates differentiated once more at nu_dot = 0
    v_t, a_t = np.empty(3), np.empty(3)
    _cross(w, Rd, tmp)
    for x in range(3):
        v_t[x] = v[x] + tmp[x]
    _cross(w, Rd, tmp)
    _cross(w, tmp, a_t)
    y2, cd = np.empty(2), np.empty(2)
    y2[0], y2[1] = _dot(S1[0], v_t), _dot(S1[1], v_t)
    _solve2(A, y2, cd)
    S1d = np.zeros((2, 3))
    S2d = np.zeros((2, 2, 3))
    for i in range(2):
        for x in range(3):
            S1d[i, x] = S2[i, 0, x] * cd[0] + S2[i, 1, x] * cd[1]
            for j in range(2):
                S2d[i, j, x] = S3[i, j, 0, x] * cd[0] + S3[i, j, 1, x] * cd[1]
    rd = np.empty(3)
    for x in range(3):
        rd[x] = v_t[x] - S1[0, x] * cd[0] - S1[1, x] * cd[1]
    Ad = np.empty((2, 2))
    for i in range(2):
        for j in range(2):
            Ad[i, j] = _dot(S1d[i], S1[j]) + _dot(S1[i], S1d[j]) - _dot(S2[i, j], rd) - _dot(S2d[i, j], r)
    for i in range(2):
        y2[i] = _dot(S1d[i], v_t) + _dot(S1[i], a_t) - Ad[i, 0] * cd[0] - Ad[i, 1] * cd[1]
    cdd = np.empty(2)
    _solve2(A, y2, cdd)
    S1dd = np.empty((2, 3))
    for i in range(2):
        for x in range(3):
            acc = S2[i, 0, x] * cdd[0] + S2[i, 1, x] * cdd[1]
            for kk in range(2):
                for ll in range(2):
                    acc += S3[i, kk, ll, x] * cd[kk] * cd[ll]
            S1dd[i, x] = acc
    md, mdd = np.empty(3), np.empty(3)
    a1, a2, a3 = np.empty(3), np.empty(3), np.empty(3)
    _cross(S1d[0], S1[1], a1)
    _cross(S1[0], S1d[1], a2)
    for x in range(3):
        md[x] = a1[x] + a2[x]
    _cross(S1dd[0], S1[1], a1)
    _cross(S1d[0], S1d[1], a2)
    _cross(S1[0], S1dd[1], a3)
    for x in range(3):
        mdd[x] = a1[x] + 2.0 * a2[x] + a3[x]
    mud = _dot(n, md)
    nd, ndd = np.empty(3), np.empty(3)
    for x in range(3):
        nd[x] = (md[x] - n[x] * mud) / mu
    mudd = _dot(nd, md) + _dot(n, mdd)
    for x in range(3):
        ndd[x] = (mdd[x] - 2.0 * nd[x] * mud - n[x] * mudd) / mu
    b[0] = _dot(nd, v_t) + _dot(n, a_t)
    bd, wbd = np.empty(3), np.empty(3)
    for i in (1, 2):
        for x in range(3):
            bvec[x] = R[x, i - 1]
        _cross(w, bvec, bd)
        _cross(w, bd, wbd)
        b[i] = _dot(wbd, n) + 2.0 * _dot(bd, nd) + _dot(bvec, ndd)
    for i in range(3):
        ok = ok and math.isfinite(b[i])
    return ok
