"""Every shipped scene rendered by the CAN cobot, whole (issue 15): status ok, no NaN. The scenes
that need it fit the device with the paper's phi (eq. 4: scale, offset, rotation) in their [cobot]
table; nothing here changes a scene."""

import pytest

from teleop.runtime import run_scene
from teleop.scenario.schema import list_scenes, load_scene

pytestmark = pytest.mark.long  # the whole scenes, 5-20 s simulated each


#: open (issue 15): the master side limit-cycles at ~6 Hz on the cobot (the cut's stick, a tanh of
#: ~2000 N*s/m at the slave, fed back through the device's lag; without the cutting effect it does
#: not), so the virtual tool leaves its rows at 22 mm/s (fixture_rate_max, tolerance 10 mm/s). The
#: slave holds its fixture (residual 2e-6): its relaxed rows were fixed by the fixtures-first stage.
MASTER_OPEN = {"curved_surface_incision"}


def _cases():
    for name in list_scenes():
        marks = [pytest.mark.xfail(strict=True, reason="fixture_violated on the cobot: the cut's stick limit-cycles the master (open)")] \
            if name in MASTER_OPEN else []
        yield pytest.param(name, marks=marks, id=name)


@pytest.mark.parametrize("name", _cases())
def test_scene_runs_on_the_cobot(name):
    scene = load_scene(name).with_overrides(master="cobot")
    s = run_scene(scene).summary
    assert s["status"] == "ok" and s["nan"] is False, (name, s["status"])
    assert s["steps"] == round(scene.duration_s / scene.dt_s)  # ran to the end
