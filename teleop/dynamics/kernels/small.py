"""Linear algebra on small dense matrices (3x3 to 6x6) written as loops, for the compiled kernels.

numba's ``@``, ``np.linalg.solve`` and ``np.linalg.cholesky`` call BLAS and LAPACK through
wrappers that check layouts, copy to Fortran order and allocate workspaces: about 0.5-1 us a call
at these sizes, several times the arithmetic (a 6x6 matrix-vector product is 36 multiply-adds).
The loops below take tens of nanoseconds. They are the textbook algorithms, tested against numpy
and LAPACK on random matrices (tests/property/test_small_linalg.py); LAPACK stays where the work
is larger or rare (the eigendecomposition near a singularity). Any layout (a transposed view
included) is accepted: the loops index, they do not assume contiguity.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def matmul(A, B):
    """A @ B (n, k) x (k, m), a new (n, m) array."""
    n, k = A.shape
    m = B.shape[1]
    C = np.empty((n, m))
    for i in range(n):
        for j in range(m):
            s = 0.0
            for l in range(k):
                s += A[i, l] * B[l, j]
            C[i, j] = s
    return C


@njit(cache=True, inline="always")
def matvec(A, x):
    """A @ x (n, k) x (k,), a new (n,) array."""
    n, k = A.shape
    y = np.empty(n)
    for i in range(n):
        s = 0.0
        for l in range(k):
            s += A[i, l] * x[l]
        y[i] = s
    return y


@njit(cache=True)
def cholesky(K, rtol):
    """(L, ok): the lower Cholesky factor of the symmetric K (m, m), and whether it exists with
    every pivot ratio min(d)^2 / max(d)^2 above ``rtol`` (rtol 0: K positive definite)."""
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
def is_positive_definite(A):
    """Whether the symmetric matrix A (n, n) is positive definite (its Cholesky factor exists)."""
    return cholesky(A, 0.0)[1]


@njit(cache=True)
def solve_into(A, b, x):
    """x (n,) <- the solution of A x = b (A (n, n), b (n,)) by Gaussian elimination with partial
    pivoting (LAPACK's getrf/getrs algorithm) on a copy of A. Returns False for a zero or
    non-finite pivot (x is then not meaningful)."""
    n = A.shape[0]
    M = A.copy()
    for i in range(n):
        x[i] = b[i]
    for k in range(n):
        piv, best = k, abs(M[k, k])
        for r in range(k + 1, n):
            if abs(M[r, k]) > best:
                piv, best = r, abs(M[r, k])
        if not best > 0.0 or not math.isfinite(best):
            return False
        if piv != k:
            for c in range(n):
                M[k, c], M[piv, c] = M[piv, c], M[k, c]
            x[k], x[piv] = x[piv], x[k]
        inv = 1.0 / M[k, k]
        for r in range(k + 1, n):
            f = M[r, k] * inv
            if f != 0.0:
                for c in range(k + 1, n):
                    M[r, c] -= f * M[k, c]
                x[r] -= f * x[k]
    for k in range(n - 1, -1, -1):
        s = x[k]
        for c in range(k + 1, n):
            s -= M[k, c] * x[c]
        x[k] = s / M[k, k]
    return True


@njit(cache=True)
def solve(A, b):
    """(ok, x): :func:`solve_into` into a new array."""
    x = np.empty(A.shape[0])
    return solve_into(A, b, x), x


#: :func:`lstsq_min_norm`: a pair of columns counts as orthogonal when |w_i . w_j| is below this
#: times |w_i| |w_j| (one-sided Jacobi's usual test, at the double precision's unit round-off)
JACOBI_TOL = 2.0 ** -52
JACOBI_SWEEPS = 60


@njit(cache=True)
def lstsq_min_norm(A, b, rcond):
    """x (n,): the minimum-norm least-squares solution of A x = b, A (m, n) small, b (m,), with the
    singular values s_i <= rcond * max(s) taken as zero (LAPACK gelsd's rule, so a rank-deficient
    A, e.g. a row given twice, is fine). By a one-sided Jacobi SVD (Hestenes): the columns of
    A^T are rotated pairwise until orthogonal, A^T V = W, so A = V W^T and
    x = sum_i W_i (V_i . b) / s_i^2 over the kept s_i = |W_i|. Units: x in b's over A's."""
    m, n = A.shape
    W = np.empty((n, m))
    for i in range(m):
        for j in range(n):
            W[j, i] = A[i, j]
    V = np.eye(m)
    for _ in range(JACOBI_SWEEPS):
        rotated = False
        for i in range(m - 1):
            for j in range(i + 1, m):
                a = c = g = 0.0
                for k in range(n):
                    a += W[k, i] * W[k, i]
                    c += W[k, j] * W[k, j]
                    g += W[k, i] * W[k, j]
                if not abs(g) > JACOBI_TOL * math.sqrt(a * c):
                    continue
                rotated = True
                zeta = (c - a) / (2.0 * g)
                t = math.copysign(1.0, zeta) / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
                cs = 1.0 / math.sqrt(1.0 + t * t)
                sn = cs * t
                for k in range(n):
                    wi, wj = W[k, i], W[k, j]
                    W[k, i], W[k, j] = cs * wi - sn * wj, sn * wi + cs * wj
                for k in range(m):
                    vi, vj = V[k, i], V[k, j]
                    V[k, i], V[k, j] = cs * vi - sn * vj, sn * vi + cs * vj
        if not rotated:
            break
    s2 = np.empty(m)
    top = 0.0
    for i in range(m):
        q = 0.0
        for k in range(n):
            q += W[k, i] * W[k, i]
        s2[i] = q
        top = max(top, q)
    x = np.zeros(n)
    floor = rcond * math.sqrt(top)
    for i in range(m):
        if math.sqrt(s2[i]) > floor:
            f = 0.0
            for k in range(m):
                f += V[k, i] * b[k]
            f /= s2[i]
            for k in range(n):
                x[k] += f * W[k, i]
    return x

