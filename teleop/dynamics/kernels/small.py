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
def is_positive_definite(A):
    """Whether the symmetric matrix A (n, n) is positive definite: its Cholesky factorization
    (lower triangle, in a scratch copy) meets no non-positive pivot."""
    n = A.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        d = A[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:  # NaN too
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    return True


@njit(cache=True)
def solve(A, b):
    """x with A x = b (A (n, n), b (n,)) by Gaussian elimination with partial pivoting (LAPACK's
    getrf/getrs algorithm). Returns (ok, x); ok is False for an exactly singular or non-finite
    pivot (x is then not meaningful)."""
    n = A.shape[0]
    M = np.empty((n, n))
    x = np.empty(n)
    for i in range(n):
        x[i] = b[i]
        for j in range(n):
            M[i, j] = A[i, j]
    for c in range(n):
        p, big = c, abs(M[c, c])
        for r in range(c + 1, n):
            if abs(M[r, c]) > big:
                p, big = r, abs(M[r, c])
        if not big > 0.0 or not math.isfinite(big):
            return False, x
        if p != c:
            for j in range(n):
                M[c, j], M[p, j] = M[p, j], M[c, j]
            x[c], x[p] = x[p], x[c]
        for r in range(c + 1, n):
            f = M[r, c] / M[c, c]
            if f != 0.0:
                for j in range(c + 1, n):
                    M[r, j] -= f * M[c, j]
                x[r] -= f * x[c]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for j in range(i + 1, n):
            s -= M[i, j] * x[j]
        x[i] = s / M[i, i]
    return True, x
