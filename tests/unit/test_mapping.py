"""Registration, scaling, constraint mapping between patient and master frames, force feedback."""

import numpy as np
import pinocchio as pin
import pytest

from teleop.control.mapping import Registration
from teleop.dynamics import constraints as C
from teleop.errors import ConfigError

REG = Registration([0.5, -0.1, 0.2], pin.rpy.rpyToMatrix(0.1, -0.2, 0.7), scale=3.0, force_scale=0.5)

ALL = [
    C.PlaneHeight(origin=(0.5, 0, 0.2), normal=(0, 0.3, 1), height=0.01),
    C.AxisInPlane(axis_B=(0, 0, 1), normal=(0, 0, 1)),
    C.RollingWithoutSlip(radius=0.01, normal=(0, 0, 1)),
    C.SphereContact(center=(0.5, 0, 0.2), radius=0.02),
    C.PointDepth(origin=(0.5, 0, 0.2), normal=(0, 0, 1), depth=0.005, point_B=(0, 0, 0.01)),
    C.AxisAlong(axis_B=(0, 0, 1), direction=(0, 0, -1)),
    C.KnifeEdge(point_B=(0, 0, 0.01), side_B=(0, 1, 0)),
    C.RemoteCenter(center=(0.5, 0, 0.25), point_B=(0, 0, 0.01), axis_B=(0, 0, 1)),
]
LENGTH_UNITS = {C.PlaneHeight: True, C.SphereContact: True, C.PointDepth: True, C.RemoteCenter: True}


def test_target_maps_pose_and_twist():
    p_r, R_r = np.array([0.03, 0.0, -0.06]), pin.exp3(np.array([0.2, 0.1, 0.0]))
    v_r, w_r = np.array([0.03, 0.0, 0.0]), np.array([0.0, 0.0, 0.3])
    p, R, v, w = REG.target(p_r, R_r, v_r, w_r)
    assert np.allclose(p, REG.X_PM_p + REG.X_PM_R @ p_r / 3) and np.allclose(R, REG.X_PM_R @ R_r)
    assert np.isclose(np.linalg.norm(v), 0.01) and np.allclose(w, REG.X_PM_R @ w_r)
    p_back, R_back = REG.pose_to_master(p, R)
    assert np.allclose(p_back, p_r) and np.allclose(R_back, R_r)


@pytest.mark.parametrize("c", ALL, ids=lambda c: type(c).__name__)
def test_constraint_to_master_is_the_same_constraint_seen_from_the_master(c):
    """At corresponding poses the mapped residual equals the original (lengths times scale), and the
    mapped rows annihilate the master twists that correspond to admissible slave twists."""
    rng = np.random.default_rng(3)
    cm = REG.constraint_to_master(c)
    assert type(cm) is type(c)
    for _ in range(5):
        p_M, R_M = rng.normal(scale=0.05, size=3), pin.exp3(rng.normal(size=3))
        p_P, R_P, _, _ = REG.target(p_M, R_M, np.zeros(3), np.zeros(3))
        if c.holonomic:
            k = REG.scale if type(c) in LENGTH_UNITS else 1.0
            h_P = c.residual(p_P, R_P)
            if isinstance(c, C.SphereContact):  # its residual is a world vector: rotate it too
                h_P = REG.X_PM_R.T @ h_P
            h_M = cm.residual(p_M, R_M)
            if isinstance(c, C.AxisAlong):  # tangents of a rotated direction: same plane, own basis
                h_M, h_P = np.linalg.norm(h_M), np.linalg.norm(h_P)
            assert np.allclose(h_M, k * h_P, atol=1e-12)
        # twists in the null space of the slave rows map to twists in the null space of master rows
        G_P = c.jacobian(p_P, R_P)
        null = np.linalg.svd(G_P)[2][G_P.shape[0]:]
        nu_P = null.T @ rng.normal(size=null.shape[0])
        v_M = REG.scale * REG.X_PM_R.T @ nu_P[:3]
        w_M = REG.X_PM_R.T @ nu_P[3:]
        assert np.allclose(cm.jacobian(p_M, R_M) @ np.concatenate([v_M, w_M]), 0.0, atol=1e-10)
    back = REG.constraint_to_patient(cm)
    p, R = rng.normal(size=3), pin.exp3(rng.normal(size=3))
    assert np.allclose(back.jacobian(p, R), c.jacobian(p, R))


def test_wrench_to_master_scales_and_rotates():
    F = np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
    out = REG.wrench_to_master(F)
    assert np.allclose(out[:3], 0.5 * REG.X_PM_R.T @ F[:3]) and np.allclose(out[3:], 1.5 * REG.X_PM_R.T @ F[3:])


def test_unknown_constraint_and_bad_settings_are_named():
    class Odd(C.Constraint):
        def jacobian(self, p, R):
            return np.zeros((1, 6))

        def bias(self, p, R, v, w):
            return np.zeros(1)

    with pytest.raises(ConfigError, match="Odd"):
        REG.constraint_to_master(Odd())
    with pytest.raises(ConfigError, match="mapping.scale"):
        Registration([0, 0, 0], np.eye(3), scale=0.0)
    with pytest.raises(ConfigError, match="X_PM_R"):
        Registration([0, 0, 0], 2 * np.eye(3))
    with pytest.raises(ConfigError, match="mapping.bogus"):
        Registration.from_dict({"bogus": 1})
    r = Registration.from_dict({"position_m": [0.5, 0, 0.2], "rpy_rad": [0, 0, 0.5], "scale": 3})
    assert r.scale == 3.0 and np.isclose(r.torque_scale, 3.0)
