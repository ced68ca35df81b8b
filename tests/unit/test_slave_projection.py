"""The target's projection onto a fixture (teleop.slave.projection) against hand cases, scipy's
closest point under the constraints and scipy's null space."""

import numpy as np
import pinocchio as pin
import pytest
from scipy.linalg import null_space
from scipy.optimize import minimize

from teleop.dynamics import constraints as C
from teleop.dynamics import fixtures
from teleop.dynamics.rows import RowStack
from teleop.slave.projection import project_onto_fixture
from tests.user_rows import SineRow

PLANE_O = np.array([0.5, 0.0, 0.2])
R_CUT = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
FIXTURES = {
    "scalpel": fixtures.scalpel(plane_origin=PLANE_O, plane_normal=(0.1, 0.2, 1.0), depth=0.005,
                                tip_B=(0.01, 0.0, 0.02)).constraints,
    "laparoscopic": fixtures.laparoscopic(plane_origin=PLANE_O, trocar=PLANE_O + [0, 0, 0.075]).constraints,
    "sphere": fixtures.sphere(PLANE_O, 0.05).constraints,
}


def _on(cons, rng):
    """A pose on the holonomic rows of ``cons``, near the blade-down pose over PLANE_O."""
    p, R = PLANE_O + [0.0, 0.0, -0.005], R_CUT
    rows = RowStack(cons)
    for _ in range(30):
        p, R, _, _ = project_onto_fixture(rows, p + rng.normal(size=3) * 1e-3, R, np.zeros(3), np.zeros(3))
    return p, R


def _closest(cons, p, R):
    """scipy's closest pose to (p, R) on the holonomic rows: min |d|^2 over d = (dp, dtheta),
    pose (p + dp, exp(dtheta) R), subject to h = 0 (SLSQP)."""
    hol = [c for c in cons if c.holonomic]
    s = 1e-3  # d = s x: x of order one

    def h(x):
        return C.stack_residual(hol, p + s * x[:3], pin.exp3(s * x[3:]) @ R) / s

    def dh(x):  # world twist of exp(s x_w) R per unit x_w: the left Jacobian of SO(3), Jexp3(-s x_w)
        B = np.eye(6)
        B[3:, 3:] = pin.Jexp3(-s * x[3:])
        return C.stack_jacobian(hol, p + s * x[:3], pin.exp3(s * x[3:]) @ R) @ B

    # SLSQP reaches the optimum within ~30 iterations but rarely reports success at this ftol
    r = minimize(lambda x: x @ x, np.zeros(6), jac=lambda x: 2 * x, constraints={"type": "eq", "fun": h, "jac": dh},
                 method="SLSQP", options={"ftol": 1e-15, "maxiter": 200})
    assert np.abs(h(r.x)).max() < 1e-7, r  # 1e-10 m or rad
    return p + s * r.x[:3], pin.exp3(s * r.x[3:]) @ R


def test_a_plane_by_hand():
    """Onto a plane through the origin of the body (PointDepth with the point at the origin): one
    step, to p - h n exactly, R unchanged; the twist loses its normal component, w is free."""
    n = np.array([0.0, 0.6, 0.8])
    rows = RowStack((C.PointDepth(origin=PLANE_O, normal=n, depth=0.005),))
    p = PLANE_O + [0.01, 0.02, 0.03]
    R = pin.exp3(np.array([0.3, -0.2, 0.1]))
    v, w = np.array([0.1, 0.2, 0.3]), np.array([1.0, 2.0, 3.0])
    h = n @ (p - PLANE_O) + 0.005
    p1, R1, v1, w1 = project_onto_fixture(rows, p, R, v, w)
    assert np.allclose(p1, p - h * n, atol=1e-15, rtol=0) and np.array_equal(R1, R)
    assert np.allclose(v1, v - (n @ v) * n, atol=1e-15, rtol=0) and np.allclose(w1, w, atol=1e-15, rtol=0)


def test_a_sphere_point_by_hand():
    """Onto the paper's sphere (the body origin on it, body z radial; position and rotation coupled)
    from 0.2 mm off: on it to 1e-12, at scipy's closest pose (1e-8 m, 1e-6 rad)."""
    cons = fixtures.sphere(PLANE_O, 0.05).constraints
    rows = RowStack(cons)
    R = pin.exp3(np.array([0.2, -0.1, 0.4]))
    p = PLANE_O + 0.05 * R[:, 2] + np.array([1e-4, -2e-4, 5e-5])
    p1, R1, _, _ = project_onto_fixture(rows, p, R, np.zeros(3), np.zeros(3))
    assert np.abs(cons[0].residual(p1, R1)).max() < 1e-12
    pc, Rc = _closest(cons, p, R)
    assert np.abs(p1 - pc).max() < 1e-8 and np.abs(pin.log3(R1 @ Rc.T)).max() < 1e-6


@pytest.mark.parametrize("name", sorted(FIXTURES))
@pytest.mark.parametrize("seed", range(5))
def test_onto_the_fixture_and_its_closest_pose(name, seed):
    """Targets off the fixture by tracking errors (0.1 mm, 2 mrad): the result lies on the holonomic
    rows (1e-12), is scipy's closest pose up to the Newton steps' second-order difference, and its
    twist is the orthogonal projection onto the null space of all rows (scipy.linalg.null_space)."""
    cons = FIXTURES[name]
    rng = np.random.default_rng(seed)
    p0, R0 = _on(cons, rng)
    p = p0 + rng.normal(size=3) * 1e-4
    R = pin.exp3(rng.normal(size=3) * 2e-3) @ R0
    v, w = rng.normal(size=3) * 0.01, rng.normal(size=3) * 0.1
    p1, R1, v1, w1 = project_onto_fixture(RowStack(cons), p, R, v, w)
    assert np.abs(C.stack_residual(cons, p1, R1)).max() < 1e-12
    pc, Rc = _closest(cons, p, R)
    off = np.linalg.norm(p - pc) + np.linalg.norm(pin.log3(R @ Rc.T))
    assert np.linalg.norm(p1 - pc) + np.linalg.norm(pin.log3(R1 @ Rc.T)) < 10.0 * off**2 + 1e-10
    N = null_space(C.stack_jacobian(cons, p1, R1))
    nu = np.concatenate([v, w])
    assert np.allclose(np.concatenate([v1, w1]), N @ (N.T @ nu), atol=1e-12, rtol=0)


def test_a_users_own_row_by_hand():
    """Onto a user's row x = x0 (Newton on sin, 3 steps from 1 mm: within 1e-12 of x0); y, z and R
    untouched, and the twist loses its x component."""
    rows = RowStack((SineRow(0.3),))
    p, R = np.array([0.301, 0.1, 0.2]), pin.exp3(np.array([0.1, 0.2, 0.3]))
    p1, R1, v1, w1 = project_onto_fixture(rows, p, R, np.array([1.0, 2.0, 3.0]), np.array([4.0, 5.0, 6.0]))
    assert abs(p1[0] - 0.3) < 1e-12 and np.array_equal(p1[1:], p[1:]) and np.array_equal(R1, R)
    assert np.allclose(v1, [0.0, 2.0, 3.0], atol=1e-15) and np.allclose(w1, [4.0, 5.0, 6.0], atol=1e-15)


def test_redundant_rows_and_no_rows():
    """The same plane twice (a rank-deficient G): the minimum-norm step is still p - h n; no rows:
    the target comes back as it was (copies)."""
    plane = C.PointDepth(origin=PLANE_O, normal=(0, 0, 1), depth=0.0)
    p, R, v, w = PLANE_O + [0.0, 0.0, 0.01], R_CUT, np.array([0.0, 0.0, 1.0]), np.zeros(3)
    p1, R1, v1, _ = project_onto_fixture(RowStack((plane, plane)), p, R, v, w)
    assert np.allclose(p1, PLANE_O, atol=1e-15) and np.array_equal(R1, R) and np.allclose(v1, 0.0, atol=1e-15)
    out = project_onto_fixture(RowStack(()), p, R, v, w)
    for a, b in zip(out, (p, R, v, w)):
        assert np.array_equal(a, b) and a is not b


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_target_that_is_not_finite_passes_unchanged(bad):
    """No exception and no Newton step; the arm refuses such a target itself ("invalid_target")."""
    cons = FIXTURES["scalpel"]
    p = PLANE_O + [0.0, 0.0, -0.004]
    p[0] = bad
    p1, R1, _v1, _w1 = project_onto_fixture(RowStack(cons), p, R_CUT, np.zeros(3), np.zeros(3))
    assert np.array_equal(R1, R_CUT) and not np.isfinite(p1[0])
