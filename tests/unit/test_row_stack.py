"""RowStack, the row interface of both sides: one compiled call for the built-in rows, the Python
methods of any other constraint into the same arrays, and an explicit dispatch protocol."""

import numpy as np
import pinocchio as pin
import pytest

from teleop.dynamics import constraints as C
from teleop.dynamics.rows import RowStack
from teleop.util.errors import ConfigError


class TiltedPoint(C.Constraint):
    """A user's constraint in Python only: the body point d_B stays on the plane n . x = c."""

    name, holonomic, rows, units = "tilted_point", True, 1, ("N",)

    def __init__(self, n=(0.2, -0.1, 1.0), c=0.04, d_B=(0.01, 0.02, -0.03)):
        self.n = np.asarray(n, float) / np.linalg.norm(n)
        self.c, self.d_B = c, np.asarray(d_B, float)

    def residual(self, p, R):
        return np.array([self.n @ (p + R @ self.d_B) - self.c])

    def jacobian(self, p, R):
        return np.concatenate([self.n, np.cross(R @ self.d_B, self.n)])[None, :]

    def bias(self, p, R, v, w):
        return np.array([self.n @ np.cross(w, np.cross(w, R @ self.d_B))])


class LoudAxis(C.AxisInPlane):
    """A built-in's subclass that overrides one protocol method: it must take the Python path."""

    def jacobian(self, p, R):
        return 2.0 * super().jacobian(p, R)


STACK = [
    C.PlaneHeight(origin=(0.1, 0, 0.2), normal=(0.2, 0.1, 1.0), height=0.03),
    TiltedPoint(),
    C.RollingWithoutSlip(radius=0.03),
    C.SphereContact(center=(0.01, 0.02, -0.03), radius=0.05),
    C.KnifeEdge(point_B=(0.0, 0.01, 0.12)),
    C.AxisAlong(axis_B=(0, 0, 1), direction=(0.1, 0, -1)),
    C.RemoteCenter(center=(0.02, 0.01, 0.3), point_B=(0, 0, 0.1)),
    C.PointDepth(normal=(0, 0.2, 1), point_B=(0.01, -0.02, 0.15)),
    C.AxisInPlane(axis_B=(0, 1, 0)),
]


def _flow(p, R, v, w, t):
    return p + v * t, pin.exp3(w * t) @ R


def test_layout_and_dispatch():
    rs = RowStack(STACK)
    assert rs.m == sum(c.rows for c in STACK) == 14
    assert rs.compiled_mask.tolist() == [c is not STACK[1] for c in STACK]
    assert rs.holonomic_mask.tolist() == [c.holonomic for c in STACK for _ in range(c.rows)]
    assert C.compiled_kind(LoudAxis()) is None and C.compiled_kind(C.AxisInPlane()) is not None
    assert C.compiled_kind(TiltedPoint()) is None


def test_rows_are_derivatives_of_the_residuals_and_of_themselves():
    """G (nu) = d/dt h and b = d/dt(G) nu, by central differences along a constant twist, for the
    whole mixed stack; h and b vanish where they must."""
    rs = RowStack(STACK)
    rng = np.random.default_rng(5)
    eps = 1e-6
    for _ in range(6):
        p, R = rng.normal(size=3) * 0.1, pin.exp3(rng.normal(size=3))
        v, w = rng.normal(size=3), rng.normal(size=3)
        nu = np.concatenate([v, w])
        G, b, h = (x.copy() for x in rs.evaluate(p, R, v, w))
        Gp, _, hp = (x.copy() for x in rs.evaluate(*_flow(p, R, v, w, eps)))
        Gm, _, hm = (x.copy() for x in rs.evaluate(*_flow(p, R, v, w, -eps)))
        hol = rs.holonomic_mask
        np.testing.assert_allclose((G @ nu)[hol], ((hp - hm) / (2 * eps))[hol], atol=1e-8)
        np.testing.assert_allclose(b, (Gp - Gm) @ nu / (2 * eps), atol=1e-7)
        assert np.all(h[~hol] == 0.0)
        G0, b0, _ = rs.evaluate(p, R)
        np.testing.assert_array_equal(G0, G)
        assert np.all(b0 == 0.0)


def test_stack_equals_each_constraints_own_methods():
    rs = RowStack(STACK)
    rng = np.random.default_rng(6)
    p, R = rng.normal(size=3), pin.exp3(rng.normal(size=3))
    v, w = rng.normal(size=3), rng.normal(size=3)
    G, b, h = rs.evaluate(p, R, v, w)
    np.testing.assert_allclose(G, C.stack_jacobian(STACK, p, R), atol=1e-15)
    np.testing.assert_allclose(b, C.stack_bias(STACK, p, R, v, w), atol=1e-15)
    np.testing.assert_allclose(h[rs.holonomic_mask], C.stack_residual(STACK, p, R), atol=1e-15)


def test_an_overriding_subclass_is_not_silently_compiled():
    p, R = np.zeros(3), pin.exp3(np.array([0.3, -0.2, 0.5]))
    G_loud = RowStack([LoudAxis(axis_B=(0, 1, 0))]).evaluate(p, R)[0]
    G_base = RowStack([C.AxisInPlane(axis_B=(0, 1, 0))]).evaluate(p, R)[0]
    np.testing.assert_allclose(G_loud, 2.0 * G_base)


def test_workspaces_are_reused_and_empty_stack_works():
    rs = RowStack(STACK)
    a = rs.evaluate(np.zeros(3), np.eye(3))
    b = rs.evaluate(np.ones(3), np.eye(3))
    assert all(x is y for x, y in zip(a, b))
    G, bb, h = RowStack(()).evaluate(np.zeros(3), np.eye(3), np.zeros(3), np.zeros(3))
    assert G.shape == (0, 6) and bb.shape == (0,) and h.shape == (0,)


def test_nonholonomic_builtin_has_no_residual():
    with pytest.raises(ConfigError, match="nonholonomic"):
        C.KnifeEdge().residual(np.zeros(3), np.eye(3))
