"""Eqs. 8 and 9: Lagrange multipliers and the constrained acceleration, by factorization.

    lambda = (A M^-1 A^T)^-1 (-Adot qd + A M^-1 (C qd - tau))          (8)
    qdd    = M^-1 (tau + A^T lambda - C qd)                              (9)

M is factored (Cholesky), never inverted. The Delassus matrix K = A M^-1 A^T is factored by
Cholesky when it is well conditioned; when rows are redundant or nearly dependent, a symmetric
eigendecomposition gives the minimum-norm multipliers and the numerical rank is reported.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dpotrf, dpotrs

from teleop.errors import DynamicsError

#: Relative eigenvalue floor below which a direction of K counts as dependent.
RANK_RTOL = 1e-10


@dataclass(frozen=True, eq=False)
class ConstrainedAcceleration:
    """Result of eqs. 8-9: qdd (n,), lam (m,), rank of K (int), and Minv_At for reuse (n, m)."""

    qdd: np.ndarray
    lam: np.ndarray
    rank: int


def cholesky(M: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of a symmetric positive definite matrix, or DynamicsError."""
    L, info = dpotrf(M, lower=1, clean=1, overwrite_a=0)
    if info != 0:
        raise DynamicsError(f"inertia matrix is not positive definite (LAPACK dpotrf info={info})")
    return L


def cho_solve(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    X, info = dpotrs(L, B, lower=1)
    if info != 0:  # pragma: no cover - dpotrs only fails on bad arguments
        raise DynamicsError(f"LAPACK dpotrs failed, info={info}")
    return X


def solve_delassus(K: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, int]:
    """Solve K lam = rhs for symmetric PSD K (m, m) through :class:`DelassusFactor`: Cholesky with
    a pivot-ratio check, else eigendecomposition with eigenvalues below RANK_RTOL * max dropped
    (minimum-norm, least-squares for inconsistent rows). Returns (lam, rank)."""
    if K.shape[0] == 0:
        return np.zeros(0), 0
    f = DelassusFactor(K)
    return f.solve(rhs), f.rank


class DelassusFactor:
    """A factored symmetric PSD matrix K (m, m): Cholesky when well conditioned, otherwise a
    truncated eigendecomposition (minimum-norm / least-squares solves). ``rank`` is numerical."""

    __slots__ = ("L", "V", "w", "rank")

    def __init__(self, K: np.ndarray):
        m = K.shape[0]
        self.L = self.V = self.w = None
        L, info = dpotrf(K, lower=1, clean=1, overwrite_a=0)
        if info == 0:
            d = L.diagonal().tolist()  # positive for a successful Cholesky; m is small
            if min(d) ** 2 > RANK_RTOL * max(d) ** 2:
                self.L, self.rank = L, m
                return
        self._eigen(K)

    @classmethod
    def from_cholesky(cls, K: np.ndarray, L: np.ndarray, ok: bool) -> "DelassusFactor":
        """The factor of K from a Cholesky factor L computed elsewhere (the compiled kernel);
        ``ok`` False (no usable factor) takes the eigendecomposition fallback."""
        self = cls.__new__(cls)
        self.V = self.w = None
        if ok:
            self.L, self.rank = L, K.shape[0]
        else:
            self.L = None
            self._eigen(K)
        return self

    def _eigen(self, K: np.ndarray) -> None:
        w, V = np.linalg.eigh(K)
        keep = w > RANK_RTOL * max(w[-1], 0.0)
        self.V, self.w, self.rank = V[:, keep], w[keep], int(keep.sum())

    def pseudo_inverse(self) -> np.ndarray:
        """K^+ (m, m) of the eigen fallback: V diag(1/w) V^T over the kept directions."""
        return (self.V / self.w) @ self.V.T

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        if self.L is not None:
            return dpotrs(self.L, rhs, lower=1)[0]
        if rhs.ndim == 1:
            return self.V @ ((self.V.T @ rhs) / self.w)
        return self.V @ ((self.V.T @ rhs) / self.w[:, None])


def compute_constrained_acceleration(
    M: np.ndarray, Cqd: np.ndarray, tau: np.ndarray, A: np.ndarray, Adot_qd: np.ndarray
) -> ConstrainedAcceleration:
    """Eqs. 8-9 for inertia M (n, n), C qd (n,), generalized force tau (n,), constraints A (m, n)."""
    L = cholesky(M)
    m = A.shape[0]
    rhs = np.empty((M.shape[0], m + 1))
    rhs[:, :m] = A.T
    rhs[:, m] = tau - Cqd
    X = cho_solve(L, rhs)
    Minv_At, qdd_free = X[:, :m], X[:, m]
    if m == 0:
        return ConstrainedAcceleration(qdd_free, np.zeros(0), 0)
    K = A @ Minv_At
    lam, rank = solve_delassus(K, -Adot_qd - A @ qdd_free)
    return ConstrainedAcceleration(qdd_free + Minv_At @ lam, lam, rank)
