"""The keyboard operator (fed through a pipe) and real-time pacing."""

import os
import time

import numpy as np

from teleop.runtime import run_scene
from teleop.scenario.keyboard import KeyboardOperator
from teleop.scenario.schema import FixtureSpec, load_scene


def test_keys_push_twist_clutch_and_stop():
    r, w = os.pipe()
    op = KeyboardOperator(FixtureSpec("free"), fd=r, force_N=2.0, torque_Nm=0.02, hold_s=0.25)
    os.write(w, b"wq")
    F = op.wrench(0.0, np.zeros(3), np.eye(3))
    np.testing.assert_allclose(F, [2.0, 0, 0, 0, 0, 0.02])
    assert np.all(op.wrench(0.3, np.zeros(3), np.eye(3)) == 0)  # released after hold_s
    os.write(w, b" ")
    op.wrench(0.4, np.zeros(3), np.eye(3))
    assert op.clutch_engaged is False
    os.write(w, b"x")
    op.wrench(0.5, np.zeros(3), np.eye(3))
    assert op.stop is True
    os.close(w)
    os.close(r)


def test_keyboard_drives_a_scene_and_stops_it():
    r, w = os.pipe()
    scene = load_scene("scalpel_fixture").with_overrides(duration_s=5.0)
    op = KeyboardOperator(FixtureSpec("scalpel", tip_m=(0, 0, 0.1)), fd=r, force_N=0.5)
    os.write(w, b"w" * 3 + b"x")  # push forward, then stop at once
    s = run_scene(scene, operator=op).summary
    # x is a clean stop: the run is ok (both sides did what was asked) and says who stopped it
    assert s["status"] == "ok" and s["stopped_by_operator"] and s["master_status"] == "stopped_by_operator"
    assert s["steps"] == 1 and not s["nan"]
    os.close(w)
    os.close(r)


def test_clutch_out_lets_go_of_the_ideal_tool():
    r, w = os.pipe()
    op = KeyboardOperator(FixtureSpec("scalpel", tip_m=(0, 0, 0.1)), fd=r, force_N=0.5, hold_s=10.0)
    os.write(w, b"w ")  # push, and clutch out
    s = run_scene(load_scene("scalpel_fixture").with_overrides(duration_s=0.5), operator=op)
    assert np.abs(s.log["q_r"][-1, :2] - s.log["q_r"][0, :2]).max() < 1e-9  # never moved
    os.close(w)
    os.close(r)


def test_realtime_paces_to_the_wall_clock():
    scene = load_scene("paper_rolling_disk").with_overrides(duration_s=0.3)
    t0 = time.perf_counter()
    s = run_scene(scene, realtime=True).summary
    wall = time.perf_counter() - t0
    assert wall >= 0.3 and s["status"] == "ok"
    assert "late_ticks" in s and s["late_ticks"] < s["steps"]
