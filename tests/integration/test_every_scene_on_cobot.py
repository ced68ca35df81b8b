"""Every shipped scene rendered by the CAN cobot, whole (issue 15): status ok, no NaN. The scenes
that need it fit the device with the paper's phi (eq. 4: scale, offset, rotation) in their [cobot]
table; nothing here changes a scene."""

import pytest

from teleop.runtime import run_scene
from teleop.scenario.schema import list_scenes, load_scene

pytestmark = pytest.mark.long  # the whole scenes, 5-20 s simulated each


#: open (issue 15): the master renders these whole, but the slave, fed the cobot's virtual tool,
#: sits on its joint-velocity box and relaxes its fixture rows (34 ticks) with mm of tracking error
SLAVE_OPEN = {"laparoscopic_incision", "curved_surface_incision"}
#: scenes whose master side stops on the cobot (open): the delay study's 10 kN/m wall, rendered 1:1
#: with unfiltered feedback, ends on the device's tracking_error
MASTER_OPEN = {"stiff_contact"}


def _cases():
    for name in list_scenes():
        marks = [pytest.mark.xfail(strict=True, reason="slave_fixtures_relaxed on the cobot (open)")] \
            if name in SLAVE_OPEN else \
            [pytest.mark.xfail(strict=True, reason="tracking_error on the cobot: a 10 kN/m wall at 1:1 (open)")] \
            if name in MASTER_OPEN else []
        yield pytest.param(name, marks=marks, id=name)


@pytest.mark.parametrize("name", _cases())
def test_scene_runs_on_the_cobot(name):
    scene = load_scene(name).with_overrides(master="cobot")
    s = run_scene(scene).summary
    assert s["status"] == "ok" and s["nan"] is False, (name, s["status"])
    assert s["steps"] == round(scene.duration_s / scene.dt_s)  # ran to the end
