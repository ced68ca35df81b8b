"""Eqs. 8 and 9: Lagrange multipliers and the constrained acceleration, by factorization.

    lambda = (A M^-1 A^T)^-1 (-Adot qd + A M^-1 (C qd - tau))          (8)
    qdd    = M^-1 (tau + A^T lambda - C qd)                              (9)

M is factored (Cholesky), never inverted. The Delassus matrix K = A M^-1 A^T is factored by
Cholesky when it is well conditioned; when rows are redundant or nearly dependent, a symmetric
eigendecomposition gives the minimum-norm multipliers and the numerical rank is reported (the
engine's compiled solve, :func:`teleop.dynamics.kernels.motion.delassus_solve`).

This module is the chart-coordinate form that :func:`teleop.dynamics.model.evaluate_literal` uses
as a reference for tests; the engine itself solves eq. 8 in the kernels of
:mod:`teleop.dynamics.kernels.motion`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dpotrf, dpotrs

from teleop.dynamics.kernels.motion import delassus_solve
from teleop.util.errors import DynamicsError

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
    """Solve K lam = rhs for symmetric PSD K (m, m) with the engine's compiled solve
    (:func:`teleop.dynamics.kernels.motion.delassus_solve`): Cholesky with a pivot-ratio check, else
    eigendecomposition with eigenvalues below RANK_RTOL * max dropped (minimum-norm, least-squares
    for inconsistent rows). Returns (lam, rank)."""
    return delassus_solve(np.ascontiguousarray(K, dtype=float), np.ascontiguousarray(rhs, dtype=float), RANK_RTOL)


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
