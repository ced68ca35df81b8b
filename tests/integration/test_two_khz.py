"""A scene at 2 kHz (dt_s = 0.5 ms) in one process: the ideal master's cut and the CAN cobot's cut
(CAN FD frames twice as often, a watchdog and a tare counted in cycles) run their ticks, status ok,
and the cut tracks at least as well as at 1 kHz (the slave's target is one tick, half as long, behind)."""

import pytest

from teleop.app.runtime import run_scene
from teleop.scenario.schema import load_scene


@pytest.mark.parametrize(("scene", "seconds"), [("straight_incision", 1.5), ("can_faults_incision", 1.2)])
def test_a_cut_runs_at_2_khz_in_one_process(scene, seconds):
    fast = run_scene(load_scene(scene, sets=["dt_s=0.0005", f"duration_s={seconds}"])).summary
    assert fast["status"] == "ok", fast["status_reason"]
    assert fast["dt_s"] == 0.0005 and fast["steps"] == round(seconds / 0.0005)
    assert fast["metrics"]["cut_depth_error_max_m"] <= 50e-6
    slow = run_scene(load_scene(scene, sets=[f"duration_s={seconds}"])).summary
    assert fast["metrics"]["tip_tracking_rms_m"] <= slow["metrics"]["tip_tracking_rms_m"]
