"""Every shipped scene rendered by the CAN cobot, whole (issue 15): status ok, no NaN. The scenes
that need it fit the device with the paper's phi (eq. 4: scale, offset, rotation) in their [cobot]
table; nothing here changes a scene."""

from dataclasses import replace

import pytest

from teleop.app.runtime import run_scene
from teleop.scenario.schema import list_scenes, load_scene

pytestmark = pytest.mark.long  # the whole scenes, 5-20 s simulated each


@pytest.mark.parametrize("name", list_scenes())
def test_scene_runs_on_the_cobot(name):
    scene = load_scene(name).with_overrides(master="cobot")
    s = run_scene(scene).summary
    assert s["status"] == "ok" and s["nan"] is False, (name, s["status"])
    assert s["steps"] == round(scene.duration_s / scene.dt_s)  # ran to the end


@pytest.mark.parametrize("name", ["laparoscopic_incision", "curved_surface_incision"])
def test_the_cut_on_the_cobot_is_as_smooth_as_on_the_ideal_master(name):
    """The slave follows the admittance model's output (the reference tool), not the observer's
    estimate of the device: fed the estimate, the cut's stick closed a loop through the device's
    corrections and the tool limit-cycled along the cut (6-9 Hz, cut speed 0.32 m/s against 0.036
    on the ideal master). The oscillation lengthens the blade's path in the tissue (the dome's cut
    was 155 mm on the cobot against 50 mm on the ideal master): over the first 2.5 s (the hand pulls
    from 0.3 or 0.5 s on) the cut on the cobot is within 20 % of the ideal master's."""
    scene = replace(load_scene(name), duration_s=2.5)
    cut = {}
    for master in ("ideal", "cobot"):
        s = run_scene(scene.with_overrides(master=master)).summary
        cut[master] = s["metrics"]["cut_length_m"]
        assert s["slave_statuses"].get("fixtures_relaxed", 0) == 0, (master, s["slave_statuses"])
    assert cut["ideal"] > 0.01 and abs(cut["cobot"] - cut["ideal"]) <= 0.2 * cut["ideal"], cut
