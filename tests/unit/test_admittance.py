"""φ, eq. 4, the chart-free error, the PID with anti-windup, and the clutch."""

import numpy as np
import pinocchio as pin
import pytest

from teleop.control import AdmittanceController, AdmittanceGains, Clutch, Phi
from teleop.util.errors import ConfigError

RNG = np.random.default_rng(7)


def rand_phi():
    return Phi(2.5, RNG.normal(size=3), pin.exp3(RNG.normal(size=3)))


def test_phi_round_trip_and_power_consistency():
    phi = rand_phi()
    p, R = RNG.normal(size=3), pin.exp3(RNG.normal(size=3))
    pv, Rv = phi.compute_virtual_pose(p, R)
    p2, R2 = phi.compute_handle_pose(pv, Rv)
    assert np.allclose(p2, p) and np.allclose(R2, R)
    nu_H, F_H = RNG.normal(size=6), RNG.normal(size=6)
    # eq. 4: f_v = (dφ/dx)^T f keeps the power f . x_dot
    assert phi.wrench_to_virtual(F_H) @ phi.twist_to_virtual(nu_H) == pytest.approx(F_H @ nu_H)
    assert np.allclose(phi.twist_to_handle(phi.twist_to_virtual(nu_H)), nu_H)
    assert np.allclose(phi.wrench_to_handle(phi.wrench_to_virtual(F_H)), F_H)
    # the twist map is φ's derivative
    h = 1e-7
    pv1, Rv1 = phi.compute_virtual_pose(p + h * nu_H[:3], pin.exp3(h * nu_H[3:]) @ R)
    nu_V = phi.twist_to_virtual(nu_H)
    assert np.allclose((pv1 - pv) / h, nu_V[:3], atol=1e-6)
    assert np.allclose(pin.log3(Rv1 @ Rv.T) / h, nu_V[3:], atol=1e-6)


def test_phi_validation():
    with pytest.raises(ConfigError, match=r"phi\.scale"):
        Phi(0.0)
    with pytest.raises(ConfigError, match=r"phi\.offset_R"):
        Phi(1.0, np.zeros(3), np.diag([1, 1, -1.0]))


def test_error_is_chart_free_world_rotation_vector():
    R_v = pin.exp3(np.array([0.3, -0.2, 1.0]))
    dr = np.array([1e-3, -2e-3, 5e-4])
    ctrl = AdmittanceController(AdmittanceGains(), 1e-3)
    ctrl.step(np.ones(3), pin.exp3(dr) @ R_v, np.zeros(6), np.zeros(6), np.zeros(3), R_v)
    assert np.allclose(ctrl.error, np.concatenate([np.ones(3), dr]), atol=1e-15)


def test_pid_steps_computed_by_hand():
    """Two periods with every term worked out by hand (gains kp 100, ki 500, kd 10, dt 0.01),
    then saturating ones: the integral holds, the acceleration is the one actually commanded."""
    g = AdmittanceGains(kp=100.0, ki=500.0, kd=10.0, integral_limit=1.0, max_accel=50.0, max_velocity=1.0)
    ctrl = AdmittanceController(g, 0.01)
    R = np.eye(3)
    th = 0.02  # rotation error about z: log(Rz(th)) = (0, 0, th)
    Rz = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0], [0.0, 0.0, 1.0]])
    nu_r, a_r = np.array([0.1, 0, 0, 0, 0, 0]), np.array([0.5, 0, 0, 0, 0, 0])
    # period 1, axis x: e = 0.01; integral 1e-4; a = 0.5 + 1 + 0.05 + 10 * 0.1 = 2.55; nu = 0.0255
    # axis rz: e = 0.02; integral 2e-4; a = 2 + 0.1 = 2.1; nu = 0.021
    nu, a = ctrl.step(np.array([0.01, 0, 0]), Rz, nu_r, a_r, np.zeros(3), R)
    np.testing.assert_allclose(a, [2.55, 0, 0, 0, 0, 2.1], atol=1e-12)
    np.testing.assert_allclose(nu, [0.0255, 0, 0, 0, 0, 0.021], atol=1e-14)
    np.testing.assert_allclose(ctrl.integral, [1e-4, 0, 0, 0, 0, 2e-4], atol=1e-16)
    # period 2, axis x: integral 2e-4; a = 0.5 + 1 + 0.1 + 10 * (0.1 - 0.0255) = 2.345;
    # nu = 0.0255 + 0.02345 = 0.04895
    nu, a = ctrl.step(np.array([0.01, 0, 0]), Rz, nu_r, a_r, np.zeros(3), R)
    assert a[0] == pytest.approx(2.345, abs=1e-12) and nu[0] == pytest.approx(0.04895, abs=1e-14)
    assert ctrl.integral[0] == pytest.approx(2e-4, abs=1e-16)
    # period 3, a 1 m error: a = 0.5 + 100 + 500 * 0.0102 + 10 * (0.1 - 0.04895) = 106.1105
    # saturates at 50; nu = 0.04895 + 0.5 = 0.54895; the integral stays at 2e-4
    nu, a = ctrl.step(np.array([1.0, 0, 0]), R, nu_r, a_r, np.zeros(3), R)
    assert a[0] == pytest.approx(50.0, abs=1e-12) and nu[0] == pytest.approx(0.54895, abs=1e-14)
    assert ctrl.integral[0] == pytest.approx(2e-4, abs=1e-16)
    # period 4: nu would be 1.04895, clamped to 1: the commanded acceleration is (1 - 0.54895) / dt
    nu, a = ctrl.step(np.array([1.0, 0, 0]), R, nu_r, a_r, np.zeros(3), R)
    assert nu[0] == pytest.approx(1.0) and a[0] == pytest.approx(45.105, abs=1e-9)
    assert ctrl.integral[0] == pytest.approx(2e-4, abs=1e-16)


def test_pid_tracks_a_step_and_feeds_forward():
    dt = 1e-3
    ctrl = AdmittanceController(AdmittanceGains(), dt)
    p_v, R = np.zeros(3), np.eye(3)
    p_r = np.array([1e-4, 0, 0])
    for _ in range(200):
        nu, _ = ctrl.step(p_r, R, np.zeros(6), np.zeros(6), p_v, R)
        p_v = p_v + nu[:3] * dt
    assert abs(p_v[0] - 1e-4) < 2e-6
    ctrl.reset()
    nu, a = ctrl.step(np.zeros(3), R, np.zeros(6), np.array([1.0, 0, 0, 0, 0, 0]), np.zeros(3), R)
    assert a[0] == pytest.approx(1.0) and nu[0] == pytest.approx(dt)


def test_anti_windup_under_saturation():
    g = AdmittanceGains(max_velocity=0.01)
    ctrl = AdmittanceController(g, 1e-3)
    for _ in range(500):  # a huge error saturates the velocity: the integral must not wind up
        nu, _ = ctrl.step(np.array([1.0, 0, 0]), np.eye(3), np.zeros(6), np.zeros(6), np.zeros(3), np.eye(3))
    assert nu[0] == pytest.approx(0.01)
    assert abs(ctrl.integral[0]) <= g.integral_limit[0]


def test_unstable_gains_rejected():
    with pytest.raises(ConfigError, match="kd"):
        AdmittanceController(AdmittanceGains(kd=2000.0), 1e-3)
    with pytest.raises(ConfigError, match="ki"):
        AdmittanceController(AdmittanceGains(kp=1.0, ki=1e6), 1e-3)


def test_clutch_reindexes_without_jump():
    clutch = Clutch(rand_phi())
    clutch.release()
    p_H, R_H = RNG.normal(size=3), pin.exp3(RNG.normal(size=3))
    p_t, R_t = RNG.normal(size=3), pin.exp3(RNG.normal(size=3))
    phi = clutch.engage(p_H, R_H, p_t, R_t)
    pv, Rv = phi.compute_virtual_pose(p_H, R_H)
    assert np.allclose(pv, p_t) and np.allclose(Rv, R_t) and phi.scale == 2.5
    assert clutch.engage(p_H, R_H, p_t + 1, R_t) is phi  # engaged already: no re-index
