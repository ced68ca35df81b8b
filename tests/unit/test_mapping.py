"""Registration, scaling, fixture mapping between patient and master frames, force feedback."""

import numpy as np
import pinocchio as pin
import pytest

from teleop.control.mapping import Registration
from teleop.dynamics import constraints as C
from teleop.scenario.tables import FixtureSpec, MappingSpec
from teleop.util.errors import ConfigError
from teleop.util.typed import validate

REG = Registration([0.5, -0.1, 0.2], pin.rpy.rpyToMatrix(0.1, -0.2, 0.7), scale=3.0, force_scale=0.5)

#: every built-in fixture type (all constraint kinds: plane height, axis in plane, rolling, sphere
#: contact, point depth, axis along, knife edge, remote centre), in the patient frame
SPECS = [
    FixtureSpec(type="rolling_disk", radius_m=0.01, plane_origin_m=(0.5, 0, 0.2), plane_normal=(0, 0.3, 1)),
    FixtureSpec(type="sphere", center_m=(0.5, 0, 0.2), radius_m=0.02),
    FixtureSpec(type="scalpel", plane_origin_m=(0.5, 0, 0.2), plane_normal=(0, 0.2, 1), depth_m=0.005,
                tip_m=(0, 0, 0.01)),
    FixtureSpec(type="scalpel", plane_origin_m=(0.5, 0, 0.2), depth_m=0.005, tip_m=(0, 0, 0.01),
                trocar_m=(0.5, 0, 0.25)),
]
#: constraints whose residual is a length (m): it scales with the registration
LENGTH_UNITS = {C.PlaneHeight: True, C.SphereContact: True, C.PointDepth: True, C.RemoteCenter: True}


def test_target_maps_pose_and_twist():
    p_r, R_r = np.array([0.03, 0.0, -0.06]), pin.exp3(np.array([0.2, 0.1, 0.0]))
    v_r, w_r = np.array([0.03, 0.0, 0.0]), np.array([0.0, 0.0, 0.3])
    p, R, v, w = REG.target(p_r, R_r, v_r, w_r)
    assert np.allclose(p, REG.X_PM_p + REG.X_PM_R @ p_r / 3) and np.allclose(R, REG.X_PM_R @ R_r)
    assert np.isclose(np.linalg.norm(v), 0.01) and np.allclose(w, REG.X_PM_R @ w_r)
    p_back, R_back = REG.pose_to_master(p, R)
    assert np.allclose(p_back, p_r) and np.allclose(R_back, R_r)


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: s.type + ("+trocar" if s.trocar_m else ""))
def test_the_master_fixture_is_the_patient_fixture_seen_from_the_master(spec):
    """The fixture built through the registration's one map (Registration.master_frame): at
    corresponding poses its residual equals the patient-frame one (lengths times scale; world
    vectors rotated), and its rows annihilate the master twists that correspond to admissible
    slave twists."""
    rng = np.random.default_rng(3)
    fx_P, fx_M = spec.build(), spec.build(REG.master_frame())
    for c, cm in zip(fx_P.constraints, fx_M.constraints):
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
                if isinstance(c, (C.AxisAlong, C.RemoteCenter)):  # tangent bases of their own: same plane
                    h_M, h_P = np.linalg.norm(h_M), np.linalg.norm(h_P)
                assert np.allclose(h_M, k * h_P, atol=1e-12)
            G_P = c.jacobian(p_P, R_P)
            null = np.linalg.svd(G_P)[2][G_P.shape[0]:]
            nu_P = null.T @ rng.normal(size=null.shape[0])
            v_M = REG.scale * REG.X_PM_R.T @ nu_P[:3]
            w_M = REG.X_PM_R.T @ nu_P[3:]
            assert np.allclose(cm.jacobian(p_M, R_M) @ np.concatenate([v_M, w_M]), 0.0, atol=1e-10)


def test_wrench_to_master_scales_and_rotates():
    F = np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
    out = REG.wrench_to_master(F)
    assert np.allclose(out[:3], 0.5 * REG.X_PM_R.T @ F[:3]) and np.allclose(out[3:], 1.5 * REG.X_PM_R.T @ F[3:])


def test_bad_settings_are_named():
    with pytest.raises(ConfigError, match=r"mapping\.scale"):
        Registration([0, 0, 0], np.eye(3), scale=0.0)
    with pytest.raises(ConfigError, match="X_PM_R"):
        Registration([0, 0, 0], 2 * np.eye(3))
    with pytest.raises(ConfigError, match=r"mapping\.bogus"):
        validate(MappingSpec, {"bogus": 1}, "", "mapping")
    r = validate(MappingSpec, {"position_m": [0.5, 0, 0.2], "rpy_rad": [0, 0, 0.5], "scale": 3}, "",
                 "mapping").registration()
    assert r.scale == 3.0 and np.isclose(r.torque_scale, 3.0)


def test_twist_and_damping_to_master_agree_with_target_and_wrench_to_master():
    """D_M from damping_to_master against the path a master twist takes: to P by ``target``,
    through -D_P, back by ``wrench_to_master`` (torque_scale the default, so D_M is symmetric)."""
    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6))
    D_P = A @ A.T
    D_M = REG.damping_to_master(D_P)
    for _ in range(5):
        V_M = rng.normal(size=6)
        _, _, v_P, w_P = REG.target(np.zeros(3), np.eye(3), V_M[:3], V_M[3:])
        V_P = np.concatenate((v_P, w_P))
        np.testing.assert_allclose(REG.twist_to_master(V_P), V_M, atol=1e-12)
        np.testing.assert_allclose(-D_M @ V_M, REG.wrench_to_master(-D_P @ V_P), atol=1e-9)
    assert np.linalg.eigvalsh(D_M).min() >= -1e-9
