"""Every shipped scene: a very short smoke run, and the same seed giving the same trajectory."""

import numpy as np
import pytest

from teleop.app.runtime import run_scene
from teleop.scenario.schema import list_scenes, load_scene

SCENES = list_scenes()


@pytest.mark.parametrize("name", SCENES)
def test_smoke(name):
    s = run_scene(load_scene(name).with_overrides(duration_s=0.05)).summary
    assert s["status"] == "ok" and s["nan"] is False and s["steps"] == 50


@pytest.mark.parametrize("name", SCENES)
def test_same_seed_same_trajectory(name):
    scene = load_scene(name).with_overrides(duration_s=0.1)
    a, b = run_scene(scene), run_scene(scene)
    for key in a.log:
        if not key.endswith("tick_us"):  # wall-clock time is the one thing allowed to differ
            np.testing.assert_array_equal(a.log[key], b.log[key], err_msg=f"{name}: {key}")


def test_default_run_is_the_surgical_cut():
    from teleop.app.args import DEFAULT_SCENE

    assert DEFAULT_SCENE == "straight_incision" and DEFAULT_SCENE in SCENES


def test_device_effects_follow_the_scene():
    """With 'sensor_noise' off the cobot has no noise: two seeds give the same run. With it on
    they differ. An effect a scene does not name is not simulated."""
    from dataclasses import replace

    base = load_scene("paper_rolling_disk").with_overrides(duration_s=0.2, master="cobot")
    quiet = replace(base, effects=tuple(e for e in base.effects if e != "sensor_noise"))
    a = run_scene(quiet.with_overrides(seed=1)).log["q_r"]
    b = run_scene(quiet.with_overrides(seed=2)).log["q_r"]
    np.testing.assert_array_equal(a, b)
    c = run_scene(base.with_overrides(seed=1)).log["q_r"]
    d = run_scene(base.with_overrides(seed=2)).log["q_r"]
    assert np.abs(c - d).max() > 0


def test_cobot_log_has_device_joints_and_can_statistics():
    r = run_scene(load_scene("can_faults_incision").with_overrides(duration_s=0.3))
    assert np.abs(r.log["master_q"]).max() > 0
    assert r.log["can_frames_lost"][-1] > 0 and np.all(np.diff(r.log["can_frames_lost"]) >= 0)
