"""The keyboard operator (fed through a pipe or by hand), its scaling to the tool and the device,
the status line, and real-time pacing."""

import io
import os
import time

import numpy as np
import pytest

from teleop.app.keyboard import (
    FAST,
    KEY_CROSSING_S,
    KEY_FORCE_SHARE,
    KEY_STUCK_S,
    KeyboardOperator,
    KeyScale,
    describe,
    key_scale,
    keyboard_operator,
)
from teleop.app.runtime import run_scene
from teleop.app.session import MAX_TICKS
from teleop.app.statusline import StatusLine, status_text
from teleop.scenario.schema import FixtureSpec, load_scene

SCALE = KeyScale(speed_m_s=0.05, angular_speed_rad_s=0.5, gain_Ns_per_m=1.0, gain_Nms_per_rad=0.004,
                 force_N=10.0, torque_Nm=0.5, integral_N_per_m=2.0, integral_Nm_per_rad=0.01)


@pytest.fixture
def pipe():
    r, w = os.pipe()
    yield r, w
    os.close(w)
    os.close(r)


def test_a_held_key_pushes_toward_its_speed_and_a_released_one_stops(pipe):
    r, w = pipe
    op = KeyboardOperator(FixtureSpec("free"), SCALE, fd=r)
    os.write(w, b"wq")
    F = op.wrench(0.0, np.zeros(3), np.eye(3), np.zeros(3), np.zeros(3))
    # at rest: the proportional push, gain times the key's speed, along x and about z
    np.testing.assert_allclose(F, [1.0 * 0.05, 0, 0, 0, 0, 0.004 * 0.5])
    F = op.wrench(0.001, np.zeros(3), np.eye(3), np.array([0.05, 0, 0]), np.zeros(3))
    assert F[0] == pytest.approx(0.0)  # at the key's speed it pushes no more (the integral: 0 over 1 ms)
    for i in range(2, 1002):  # held still for a second: the integral adds 2 N/m x 0.05 m/s a second
        F = op.wrench(i * 1e-3, np.zeros(3), np.eye(3), np.zeros(3), np.zeros(3))
        op.press("w", i * 1e-3)
    assert F[0] == pytest.approx(0.05 + 2.0 * 0.05 * 1.0, rel=1e-2)
    # released (past hold_s): the hand brakes the axis it moved
    F = op.wrench(1.6, np.zeros(3), np.eye(3), np.array([0.05, 0, 0]), np.zeros(3))
    assert F[0] < 0
    # then lets go: an axis no key holds is free
    assert np.all(op.wrench(4.0, np.zeros(3), np.eye(3), np.array([0.05, 0, 0]), np.zeros(3)) == 0)


def test_keys_capitals_arrows_clutch_and_stop(pipe):
    r, w = pipe
    op = KeyboardOperator(FixtureSpec("free"), SCALE, fd=r)
    os.write(w, b"D")
    op.wrench(0.0, np.zeros(3), np.eye(3))
    np.testing.assert_allclose(op.target, [0, -FAST * 0.05, 0, 0, 0, 0])  # a capital goes FAST times faster
    os.write(w, b"\x1b[A")  # the up arrow is w, not a stop
    op.wrench(0.1, np.zeros(3), np.eye(3))
    assert op.target[0] == 0.05 and not op.stop
    op.feed("\x1b[", 0.2)  # an arrow cut between two reads
    op.feed("B", 0.2)
    assert op.target[0] == 0.05 and op.sign[0] == -1 and not op.stop
    os.write(w, b" ")
    assert np.all(op.wrench(0.3, np.zeros(3), np.eye(3)) == 0) and op.clutch_engaged is False
    os.write(w, b"\x1b")  # a lone ESC stops
    op.wrench(0.4, np.zeros(3), np.eye(3))
    assert op.stop is True
    op2 = KeyboardOperator(FixtureSpec("free"), SCALE)
    op2.feed("x", 0.0)
    assert op2.stop is True


def test_the_hand_is_scaled_to_the_tool_and_the_device():
    scene = load_scene("scalpel_fixture")
    k = key_scale(scene)
    # the gantry's 0.8 m travel less 5 mm a side, times the scene's phi scale 1.5, crossed in 20 s
    assert k.speed_m_s == pytest.approx((0.8 - 2 * 0.005) * 1.5 / KEY_CROSSING_S)
    assert k.force_N == pytest.approx(KEY_FORCE_SHARE * 100.0) and k.torque_Nm == pytest.approx(KEY_FORCE_SHARE * 5.0)
    # stuck, the whole 10 N after KEY_STUCK_S; critically damped on the 0.1 kg tool
    assert k.integral_N_per_m == pytest.approx(10.0 / (k.speed_m_s * KEY_STUCK_S))
    assert k.gain_Ns_per_m == pytest.approx(2 * np.sqrt(k.integral_N_per_m * 0.1))
    # the turn: the lightest axis (2e-5 kg*m^2) takes at most 0.5 * 2e-5 / 1 ms; the integral is
    # lowered to keep the heaviest (4e-4) critically damped
    assert k.gain_Nms_per_rad == pytest.approx(0.5 * 2e-5 / 1e-3)
    assert k.integral_Nm_per_rad == pytest.approx(0.01 ** 2 / (4 * 4e-4))
    heavy = key_scale(scene.with_overrides(["tool.mass_kg=2.0", "cobot.max_force_N=20.0", "cobot.scale=1.0"]))
    assert heavy.force_N == pytest.approx(2.0) and heavy.speed_m_s == pytest.approx(k.speed_m_s / 1.5)
    assert heavy.integral_N_per_m == pytest.approx(2.0 / (heavy.speed_m_s * KEY_STUCK_S))
    assert heavy.gain_Ns_per_m == pytest.approx(2.0 / 0.1)  # the floor: its own mass to speed in 0.1 s


def test_keyboard_drives_a_scene_and_x_is_a_clean_stop(pipe):
    r, w = pipe
    scene = load_scene("scalpel_fixture").with_overrides(duration_s=5.0)
    op, _ = keyboard_operator(scene, fd=r)
    os.write(w, b"w" * 3 + b"x")  # push forward, then stop at once
    s = run_scene(scene, operator=op).summary
    # x is a clean stop: the run is ok (both sides did what was asked) and says who stopped it
    assert s["status"] == "ok" and s["stopped_by_operator"] and s["master_status"] == "stopped_by_operator"
    assert s["steps"] == 1 and not s["nan"]
    assert s["operator"]["speed_limit_m_s"] == op.limits.speed_m_s and s["operator"]["braked_ticks"] == 0


def test_clutch_out_lets_go_of_the_ideal_tool(pipe):
    r, w = pipe
    scene = load_scene("scalpel_fixture").with_overrides(duration_s=0.5)
    op, _ = keyboard_operator(scene, fd=r)
    os.write(w, b"w ")  # push, and clutch out
    s = run_scene(scene, operator=op)
    assert np.abs(s.log["q_r"][-1, :2] - s.log["q_r"][0, :2]).max() < 1e-9  # never moved


def test_describe_says_how_the_session_ends():
    scene = load_scene("scalpel_fixture")
    op, k = keyboard_operator(scene)
    text = describe(k, op.limits, scene.dt_s, MAX_TICKS * scene.dt_s)
    assert "until you press x" in text and "Ctrl-C" in text and f"{MAX_TICKS * scene.dt_s:g} s" in text
    assert "runs 5 s" in describe(k, op.limits, scene.dt_s, 5.0)


def test_status_text_fields():
    line = status_text(12.34, 0.98, 3, [0.012, -0.0041, 0.095], np.eye(3), np.array([0.3, 0.4, 0, 0, 0, 0.002]),
                       "ok", ["wall"])
    assert line.startswith("t 12.3 s  0.98x  late 3 | tool 12.0 -4.1 95.0 mm  0 0 0 deg | hand 0.50 N 0.002 N*m")
    assert line.endswith("| slave ok | wall")
    assert "late" not in status_text(1.0, 1.0, None, np.zeros(3), np.eye(3), np.zeros(6), None)


def test_status_line_is_quiet_in_a_pipe():
    line = StatusLine(stream=io.StringIO())
    assert line.bar is None
    line.after_tick(0, 0.0, None)  # a no-op off a terminal
    line.close()


def test_realtime_paces_to_the_wall_clock():
    scene = load_scene("paper_rolling_disk").with_overrides(duration_s=0.3)
    t0 = time.perf_counter()
    s = run_scene(scene, realtime=True).summary
    wall = time.perf_counter() - t0
    assert wall >= 0.3 and s["status"] == "ok"
    assert "late_ticks" in s and 0 <= s["late_ticks"] < s["steps"]
