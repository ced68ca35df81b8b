"""The loop-written small linear algebra (teleop/dynamics/kernels/small.py) against numpy and
LAPACK on random matrices (hypothesis): products, the positive-definiteness test, the solve."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop.dynamics.kernels.small import is_positive_definite, matmul, matvec, solve

SIZES = st.integers(1, 7)


def _matrix(draw, n, m, scale=10.0):
    seed = draw(st.integers(0, 2**32 - 1))
    return np.random.default_rng(seed).uniform(-scale, scale, (n, m))


@settings(max_examples=200, deadline=None)
@given(st.data(), SIZES, SIZES, SIZES)
def test_products_match_numpy_on_any_layout(data, n, k, m):
    A, B, x = _matrix(data.draw, n, k), _matrix(data.draw, k, m), _matrix(data.draw, k, 1)[:, 0]
    np.testing.assert_allclose(matmul(A, B), A @ B, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(matvec(A, x), A @ x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(matmul(B.T, A.T), B.T @ A.T, rtol=1e-12, atol=1e-12)  # transposed views


@settings(max_examples=200, deadline=None)
@given(st.data(), st.integers(1, 7), st.floats(-2.0, 2.0))
def test_positive_definite_agrees_with_lapack_cholesky(data, n, shift):
    """A = MᵀM + shift·I: positive definite exactly when its smallest eigenvalue is positive;
    cases within rounding of zero are skipped (either answer is right there)."""
    M = _matrix(data.draw, n, n, 1.0)
    A = M.T @ M + shift * np.eye(n)
    lam_min = np.linalg.eigvalsh(A)[0]
    if abs(lam_min) < 1e-9 * max(1.0, np.abs(A).max()):
        return
    try:
        np.linalg.cholesky(A)
        lapack = True
    except np.linalg.LinAlgError:
        lapack = False
    assert is_positive_definite(A) == lapack == (lam_min > 0)


@settings(max_examples=200, deadline=None)
@given(st.data(), st.integers(1, 7))
def test_solve_matches_lapack_on_regular_matrices(data, n):
    A, b = _matrix(data.draw, n, n), _matrix(data.draw, n, 1)[:, 0]
    cond = np.linalg.cond(A)
    if cond > 1e8:
        return
    ok, x = solve(A, b)
    assert ok
    np.testing.assert_allclose(x, np.linalg.solve(A, b), rtol=1e-12 * cond, atol=1e-12 * cond)
    np.testing.assert_allclose(A @ x, b, atol=1e-10 * cond * max(1.0, np.abs(b).max()))


@pytest.mark.parametrize("A", [np.zeros((3, 3)), np.array([[1.0, 2.0], [2.0, 4.0]]), np.full((2, 2), np.nan)])
def test_solve_says_singular(A):
    assert not solve(A, np.ones(A.shape[0]))[0]
    assert not is_positive_definite(A)
