"""A run's status covers the slave: a slave that cannot follow is not an "ok" run."""

import numpy as np

from teleop.app.runtime import run_scene
from teleop.scenario.operators import Operator
from teleop.scenario.schema import load_scene


class _Shove(Operator):
    """100 N along the cut and 100 N into the tissue: far beyond what the arm can follow."""

    def wrench(self, t, p, R, v=None, w=None):
        return np.array([100.0, 0.0, -100.0, 0.0, 0.0, 0.0])


def test_a_slave_that_relaxes_its_fixtures_fails_the_run():
    scene = load_scene("straight_incision").with_overrides(duration_s=0.5)
    r = run_scene(scene, operator=_Shove())
    counts = r.summary["slave_statuses"]
    assert r.summary["master_status"] == "ok"
    bad = {k: v for k, v in counts.items() if k not in ("ok", "saturated")}
    assert bad, counts
    assert r.summary["status"].startswith("slave_"), r.summary["status"]


def test_the_shipped_cut_is_ok_on_both_sides():
    r = run_scene(load_scene("straight_incision").with_overrides(duration_s=0.5))
    assert r.summary["status"] == "ok" and set(r.summary["slave_statuses"]) <= {"ok", "saturated"}


def test_a_run_of_zero_ticks_is_not_ok():
    r = run_scene(load_scene("paper_rolling_disk").with_overrides(duration_s=1e-6))
    assert r.summary["steps"] == 0 and r.summary["status"] == "no_ticks"
