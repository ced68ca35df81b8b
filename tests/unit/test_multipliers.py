"""Eq. 8 by factorization: full rank, duplicated rows, nearly dependent rows."""

import numpy as np
import pytest

from teleop.dynamics import fixtures
from teleop.dynamics.constraints import PlaneHeight
from teleop.dynamics.model import ConstrainedBody
from teleop.dynamics.multipliers import solve_delassus
from teleop.dynamics.tool import ReferenceTool


def test_delassus_full_rank_matches_dense_solve():
    rng = np.random.default_rng(0)
    B = rng.normal(size=(4, 4))
    K = B @ B.T + 0.1 * np.eye(4)
    rhs = rng.normal(size=4)
    lam, rank = solve_delassus(K, rhs)
    assert rank == 4
    np.testing.assert_allclose(lam, np.linalg.solve(K, rhs), rtol=1e-12)


def test_delassus_rank_deficient_gives_minimum_norm_solution():
    rng = np.random.default_rng(1)
    B = rng.normal(size=(4, 2))
    K = B @ B.T  # rank 2
    rhs = K @ rng.normal(size=4)  # consistent
    lam, rank = solve_delassus(K, rhs)
    assert rank == 2
    np.testing.assert_allclose(lam, np.linalg.pinv(K) @ rhs, atol=1e-10)


@pytest.mark.parametrize("scale", [1.0, 1.0 + 1e-13])
def test_duplicated_constraint_row_still_solves(paper_body, scale):
    """A disk with its height row given twice (or nearly twice): same motion, force split in two."""
    fx = fixtures.rolling_disk(0.03)
    dup = PlaneHeight(normal=(0.0, 0.0, scale), height=0.03, name="height_again")
    base = ConstrainedBody(paper_body, fx.constraints)
    twice = ConstrainedBody(paper_body, (*fx.constraints, dup))
    chart = fx.parametrization.initial_chart()
    q = np.array([0.01, 0.02, 0.03, 0.3, np.pi / 2, 0.1])
    qd = np.array([-0.03 * 2.0 * np.cos(0.3), -0.03 * 2.0 * np.sin(0.3), 0, 0.5, 0, 2.0])
    F = np.array([0.5, -0.2, -3.0, 0.01, 0.02, 0.0])
    a = base.evaluate(chart, q, qd, 0.0, F)
    b = twice.evaluate(chart, q, qd, 0.0, F)
    assert a.rank == 4 and b.rank == 4  # 5 rows, rank 4
    np.testing.assert_allclose(b.qdd, a.qdd, atol=1e-9)
    np.testing.assert_allclose(b.constraint_wrench_W, a.constraint_wrench_W, atol=1e-9)
    assert b.lam[0] == pytest.approx(b.lam[-1], rel=1e-6)  # the shared normal force, split evenly


def test_duplicated_row_through_a_whole_run(paper_body):
    fx = fixtures.rolling_disk(0.03)
    tool = ReferenceTool(paper_body, fx.with_extra(PlaneHeight(height=0.03, name="dup")), integrator="parametric")
    tool.reset([0, 0, 0.03, 0, np.pi / 2, 0])
    for _ in range(2000):
        assert tool.step(1e-3, np.array([1.0, 0.3, -2.0, 0, 0, 0.01])) == "ok"
    assert tool.rank == 4
    assert np.all(np.isfinite(tool.q))
    assert abs(tool.residual()).max() < 1e-12
