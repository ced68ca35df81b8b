"""Every constraint Jacobian and velocity-product term against central finite differences."""

import numpy as np
import pinocchio as pin
import pytest

from teleop.dynamics import constraints as C
from teleop.dynamics.body import Kinematics, constraint_bias, constraint_matrix
from teleop.dynamics.rotations import EulerChart

CONSTRAINTS = [
    C.PlaneHeight(origin=(0.1, 0, 0.2), normal=(0.2, 0.1, 1.0), height=0.03),
    C.AxisInPlane(axis_B=(0, 0, 1), normal=(0, 0.3, 1)),
    C.RollingWithoutSlip(radius=0.03, normal=(0, 0, 1)),
    C.RollingWithoutSlip(radius=0.05, normal=(0.3, 0, 1)),
    C.SphereContact(center=(0.01, 0.02, -0.03), radius=0.05, normal_B=(0, 0, 1)),
    C.PointDepth(origin=(0, 0, 0.1), normal=(0, 0.2, 1), depth=0.005, point_B=(0.01, -0.02, 0.15)),
    C.AxisAlong(axis_B=(0, 0, 1), direction=(0.1, 0, -1)),
    C.KnifeEdge(point_B=(0.0, 0.01, 0.12), side_B=(0, 1, 0)),
    C.RemoteCenter(center=(0.02, 0.01, 0.3), point_B=(0, 0, 0.1), axis_B=(0, 0, 1)),
]
IDS = [f"{c.name}{i}" for i, c in enumerate(CONSTRAINTS)]
HOLONOMIC = [c for c in CONSTRAINTS if c.holonomic]


def _pose(rng):
    p = rng.normal(size=3) * 0.1
    R = pin.exp3(rng.normal(size=3))
    return p, R


def _flow(p, R, v, w, t):
    """Constant world-aligned twist: p + v t, exp(w t) R."""
    return p + v * t, pin.exp3(w * t) @ R


@pytest.mark.parametrize("c", HOLONOMIC, ids=[c.name for c in HOLONOMIC])
def test_jacobian_is_derivative_of_residual(c):
    rng = np.random.default_rng(1)
    for _ in range(5):
        p, R = _pose(rng)
        nu = rng.normal(size=6)
        eps = 1e-6
        hp = c.residual(*_flow(p, R, nu[:3], nu[3:], eps))
        hm = c.residual(*_flow(p, R, nu[:3], nu[3:], -eps))
        np.testing.assert_allclose(c.jacobian(p, R) @ nu, (hp - hm) / (2 * eps), atol=1e-8)


@pytest.mark.parametrize("c", CONSTRAINTS, ids=IDS)
def test_bias_is_derivative_of_jacobian(c):
    rng = np.random.default_rng(2)
    for _ in range(5):
        p, R = _pose(rng)
        v, w = rng.normal(size=3), rng.normal(size=3)
        nu = np.concatenate([v, w])
        eps = 1e-6
        Gp = c.jacobian(*_flow(p, R, v, w, eps))
        Gm = c.jacobian(*_flow(p, R, v, w, -eps))
        np.testing.assert_allclose(c.bias(p, R, v, w), (Gp - Gm) @ nu / (2 * eps), atol=1e-7)


@pytest.mark.parametrize("seq", ["ZXZ", "ZYX", "XZY"])
@pytest.mark.parametrize("c", CONSTRAINTS, ids=IDS)
def test_chart_coordinates_A_and_Adot_qd(seq, c):
    """A(q) = dh/dq for holonomic rows, and Adot qd = d/dt(A(q)) qd along q + t qd."""
    rng = np.random.default_rng(3)
    chart = EulerChart(seq, pin.exp3(rng.normal(size=3)))
    for _ in range(4):
        q = np.concatenate([rng.normal(size=3) * 0.1, rng.uniform(-1.0, 1.0, 3) + [0, 0.6, 0]])
        qd = rng.normal(size=6)
        eps = 1e-6

        def A_at(qq, qd=qd):
            k = Kinematics(chart, qq, qd)
            return constraint_matrix(c.jacobian(k.p, k.R), k)

        k = Kinematics(chart, q, qd)
        G = c.jacobian(k.p, k.R)
        Adq = constraint_bias(G, c.bias(k.p, k.R, k.v, k.w), k)
        np.testing.assert_allclose(Adq, (A_at(q + eps * qd) - A_at(q - eps * qd)) @ qd / (2 * eps), atol=1e-6)
        if c.holonomic:
            for i in range(6):
                dq = np.zeros(6)
                dq[i] = eps
                kp, km = Kinematics(chart, q + dq, qd), Kinematics(chart, q - dq, qd)
                fd = (c.residual(kp.p, kp.R) - c.residual(km.p, km.R)) / (2 * eps)
                np.testing.assert_allclose(A_at(q)[:, i], fd, atol=1e-8)
