"""Every shipped scene: a very short smoke run, and the same seed giving the same trajectory."""

import numpy as np
import pytest

from teleop.runtime import run_scene
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
        if key != "tick_us":  # wall-clock time is the one thing allowed to differ
            np.testing.assert_array_equal(a.log[key], b.log[key], err_msg=f"{name}: {key}")


def test_default_run_is_the_surgical_cut():
    from teleop.cli import DEFAULT_SCENE

    assert DEFAULT_SCENE == "straight_incision" and DEFAULT_SCENE in SCENES
