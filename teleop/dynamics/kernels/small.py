"""Linear algebra on small dense matrices (3x3 to 6x6) written as loops, for the compiled kernels.

numba's ``@``, ``np.linalg.solve`` and ``np.linalg.cholesky`` call BLAS and LAPACK through
wrappers that check layouts, copy to Fortran order and allocate workspaces: about 0.5-1 us a call
at these sizes, several times the arithmetic (a 6x6 matrix-vector product is 36 multiply-adds).
The loops below take tens of nanoseconds. They are the textbook algorithms, tested against numpy
and LAPACK on random matrices (tests/property/test_small_linalg.py); LAPACK stays where the work
is larger or rare (the SVD near a singularity). Any layout (a transposed view included) is
accepted: the loops index, they do not assume contiguity.
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
