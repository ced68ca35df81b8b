"""The workspace and speed limits on an operator's wrench (teleop.app.limits)."""

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from teleop.app.limits import LimitedOperator, Limits, Workspace, device_workspace, limits_for
from teleop.control.admittance import Phi
from teleop.master.cobot.model import CobotModel
from teleop.scenario.operators import Operator
from teleop.scenario.schema import load_scene


class Push(Operator):
    """A constant wrench."""

    def __init__(self, W):
        self.W = np.asarray(W, float)

    def wrench(self, t, p, R, v=None, w=None):
        return self.W.copy()


BOX = Workspace(np.zeros(3), np.eye(3), np.array([0.1, 0.2, 0.3]))
LIM = Limits(BOX, speed_m_s=0.1, angular_speed_rad_s=1.0, mass_kg=0.2, inertia_kgm2=np.diag([1e-3, 2e-3, 3e-3]),
             max_force_N=5.0, max_torque_Nm=0.5, zone_m=0.01, brake_s=0.02, wall_s=0.08, dt_s=0.001)


def test_the_device_workspace_is_the_travel_through_phi():
    """Oracle: the cobot's own model and phi put the handle, joints at their travel less the margin,
    on the box's faces (and its centre at the box's centre)."""
    scene = load_scene("scalpel_fixture")  # scale 1.5, offset, turned 90 degrees about x
    cfg = scene.cobot
    ws = device_workspace(cfg)
    model, m = CobotModel(), cfg.workspace_margin_m
    phi = Phi(cfg.scale, np.array(cfg.offset_m), pin.exp3(np.array(cfg.offset_rotvec_rad)))
    lo, hi = model.lower[:3] + m, model.upper[:3] - m
    for corner in ([lo[0], lo[1], lo[2]], [hi[0], lo[1], hi[2]], [hi[0], hi[1], hi[2]]):
        p_H, R_H = model.compute_handle_pose(np.array([*corner, 0.0, 1.0, 0.0]))
        p_V, _ = phi.compute_virtual_pose(p_H, R_H)
        assert abs(ws.margin(p_V)) < 1e-12
        assert np.all(np.sort(np.abs(ws.distances(p_V)))[:3] < 1e-12)  # a corner: on three faces
    p_H, R_H = model.compute_handle_pose(np.r_[(lo + hi) / 2, 0.0, 1.0, 0.0])
    np.testing.assert_allclose(phi.compute_virtual_pose(p_H, R_H)[0], ws.center, atol=1e-12)


def test_limits_of_a_scene_keep_the_tool_off_the_device_stops_and_take_in_its_start():
    scene = load_scene("scalpel_fixture")
    lim = limits_for(scene, np.array([0.0, 0.0, 0.095]), speed_m_s=0.1, angular_speed_rad_s=1.0)
    np.testing.assert_allclose(lim.workspace.half, device_workspace(scene.cobot).half - lim.zone_m)
    assert lim.speed_m_s == 0.1 and lim.mass_kg == 0.1 and lim.max_force_N == scene.cobot.max_force_N
    fast = limits_for(scene, np.zeros(3), speed_m_s=10.0, angular_speed_rad_s=100.0)
    assert fast.speed_m_s == pytest.approx(0.8 * 1.5 * 0.5) and fast.angular_speed_rad_s == pytest.approx(8.0)
    far = np.array([3.0, 0.0, 0.0])  # a tool that starts outside the device's reach (an ideal master)
    grown = limits_for(scene, far, 0.1, 1.0)
    assert grown.workspace.margin(far) == pytest.approx(2 * grown.zone_m)
    assert grown.workspace.margin(np.array([0.27, 0.0, 0.0])) > 0  # and still holds the device's box


def test_inside_and_slow_the_hand_is_untouched():
    W = np.array([1.0, -2.0, 0.5, 0.01, 0.02, -0.03])
    op = LimitedOperator(Push(W), LIM)
    np.testing.assert_array_equal(op.wrench(0.0, np.zeros(3), np.eye(3), np.full(3, 0.01), np.full(3, 0.1)), W)
    assert op.active == () and op.braked_ticks == 0


def test_no_push_carries_the_tool_past_a_speed_limit_within_one_period():
    """A stiff hand on a light blade: 0.04 N*m on 2e-5 kg*m^2 turns it 2 rad/s in one millisecond
    (the limit 1 rad/s), 50 N on 0.2 kg moves it 0.25 m/s (the limit 0.1): each is cut to what
    reaches the limit in the period, along the push, by the tool's own dynamics (oracle: the
    explicit step v + dt M^-1 F)."""
    lim = replace(LIM, inertia_kgm2=np.diag([2e-5] * 3))
    op = LimitedOperator(Push([50.0, 0, 0, 0, 0, 0.04]), lim)
    v0, w0 = np.array([0.0, 0.02, 0.0]), np.array([0.0, 0.0, 0.1])
    W = op.wrench(0.0, np.zeros(3), np.eye(3), v0, w0)
    v1 = v0 + lim.dt_s * W[:3] / lim.mass_kg
    w1 = w0 + lim.dt_s * np.linalg.solve(lim.inertia_kgm2, W[3:])
    assert np.linalg.norm(v1) == pytest.approx(lim.speed_m_s, rel=1e-12)
    assert np.linalg.norm(w1) == pytest.approx(lim.angular_speed_rad_s, rel=1e-12)
    assert W[0] > 0 and W[5] > 0 and W[1] == W[2] == W[3] == W[4] == 0  # cut, not turned


def test_at_a_face_the_push_out_is_gone_and_the_push_in_kept():
    op = LimitedOperator(Push([3.0, 1.0, 0, 0, 0, 0]), LIM)
    F = op.wrench(0.0, np.array([0.1, 0.0, 0.0]), np.eye(3), np.zeros(3), np.zeros(3))  # on the +x face
    np.testing.assert_allclose(F[:3], [0.0, 1.0, 0.0])
    half = op.wrench(0.0, np.array([0.095, 0.0, 0.0]), np.eye(3), np.zeros(3), np.zeros(3))  # mid-zone
    np.testing.assert_allclose(half[:3], [1.5, 1.0, 0.0])
    op = LimitedOperator(Push([-3.0, 0, 0, 0, 0, 0]), LIM)
    np.testing.assert_allclose(op.wrench(0.0, np.array([0.1, 0, 0]), np.eye(3), np.zeros(3), np.zeros(3))[:3],
                               [-3.0, 0, 0])


def test_outside_a_spring_and_damper_pull_back_in():
    op = LimitedOperator(Push(np.zeros(6)), LIM)
    c = LIM.mass_kg / LIM.brake_s
    F = op.wrench(0.0, np.array([0.0, 0.0, -0.31]), np.eye(3), np.zeros(3), np.zeros(3))  # 10 mm past -z
    np.testing.assert_allclose(F[:3], [0, 0, c * 0.01 / LIM.wall_s])
    F = op.wrench(0.0, np.array([0.0, 0.0, -0.3]), np.eye(3), np.array([0, 0, -0.05]), np.zeros(3))  # on it, going out
    np.testing.assert_allclose(F[:3], [0, 0, c * 0.05])
    assert op.active == ("wall",) and op.margin_min_m == pytest.approx(-0.01)
    F = op.wrench(0.0, np.array([0.0, 0.0, -5.0]), np.eye(3), np.zeros(3), np.zeros(3))  # far out: capped
    np.testing.assert_allclose(F[:3], [0, 0, LIM.max_force_N])


def test_over_the_speed_limits_brakes_oppose_the_motion():
    op = LimitedOperator(Push([2.0, 0, 0, 0, 0, 0.1]), LIM)
    v, w = np.array([0.15, 0.0, 0.0]), np.array([0.0, 0.0, 1.5])
    F = op.wrench(0.0, np.zeros(3), np.eye(3), v, w)
    c = LIM.mass_kg / LIM.brake_s
    np.testing.assert_allclose(F[:3], [-c * 0.05, 0, 0])  # the push along the motion gone, the brake on
    np.testing.assert_allclose(F[3:], [0, 0, -3e-3 * 0.5 / LIM.brake_s])  # R I R^T, about z
    assert set(op.active) == {"speed", "spin"}
    s = op.stats()
    assert s["speed_max_m_s"] == pytest.approx(0.15) and s["angular_speed_max_rad_s"] == pytest.approx(1.5)


def test_a_non_finite_hand_is_no_push_and_flags_are_forwarded():
    inner = Push([np.nan] * 6)
    inner.stop, inner.clutch_engaged = True, False
    op = LimitedOperator(inner, LIM)
    assert np.all(op.wrench(0.0, np.zeros(3), np.eye(3)) == 0)
    assert op.stop is True and op.clutch_engaged is False and op.tremor_on is False
