"""FixtureRowMetrics judges each row at the level where it is a constraint: a holonomic row by its
residual, a nonholonomic one by its rate; the holonomic rows' rate is reported apart (hand-computed)."""

import numpy as np

from teleop.app.metrics import FixtureRowMetrics
from teleop.dynamics.constraints import KnifeEdge, PointDepth


def _metrics():
    rows = (PointDepth(origin=np.zeros(3), normal=np.array([0.0, 0.0, 1.0]), depth=0.004),
            KnifeEdge(point_B=np.zeros(3), side_B=np.array([0.0, 1.0, 0.0])))
    return FixtureRowMetrics(None, 4, 0.1, rows)


def test_depth_is_judged_by_residual_and_side_slip_by_rate():
    m = _metrics()
    # tip 1 mm above its depth (residual 1e-3 m), sinking at 3 mm/s (the depth row's rate),
    # slipping sideways at 2 mm/s (the knife edge's rate): identity orientation
    m.update(np.array([0.0, 0.0, -0.003]), np.eye(3), np.array([0.0, 0.002, -0.003]), np.zeros(3),
             np.zeros(6), np.zeros(6))
    r = m.result()
    assert np.isclose(r["fixture_residual_max"], 1e-3)
    assert np.isclose(r["fixture_rate_max"], 2e-3)             # the knife edge only
    assert np.isclose(r["fixture_holonomic_rate_max"], 3e-3)   # the depth row's d/dt, reported


def test_a_fixture_without_velocity_rows_has_no_rate_to_judge():
    m = FixtureRowMetrics(None, 2, 0.1, (PointDepth(depth=0.004),))
    m.update(np.array([0.0, 0.0, -0.004]), np.eye(3), np.array([0.0, 0.0, 0.5]), np.zeros(3), np.zeros(6), np.zeros(6))
    r = m.result()
    assert r["fixture_rate_max"] == 0.0 and np.isclose(r["fixture_holonomic_rate_max"], 0.5)
    assert np.isclose(r["fixture_residual_max"], 0.0, atol=1e-15)
