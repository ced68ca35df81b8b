"""The run's metrics are analysis: they never move its physics, and they are what they were when
computed in the tick.

The fixture metrics evaluated the tool's and the arm's own constraint rows, whose curved surface
keeps its foot point as a warm start, so on ``curved_surface_incision`` the run's joints differed
in the last bits with and without them. The metrics now derive their series at the end from the
sides' captured rows (teleop.app.recorders), with constraint rows of their own."""

import numpy as np
import pytest

from teleop.app import assembly
from teleop.app.runtime import run_scene
from teleop.scenario.schema import load_scene
from teleop.tick.ports import Hook


class _NoMetrics(Hook):
    """Stands in for the metrics: reads nothing, reports nothing."""

    def __init__(self, *args, **kwargs):
        pass

    def log(self) -> dict:
        return {}

    def result(self) -> dict:
        return {}


def _physics(log: dict) -> dict:
    return {k: log[k] for k in ("q_r", "p_r", "R_r", "lam", "felt_W", "constraint_W")}


@pytest.mark.parametrize("scene", ["curved_surface_incision", "laparoscopic_incision"])
def test_the_metrics_never_move_the_physics(scene, monkeypatch):
    sc = load_scene(scene, sets=["duration_s=1.0"])
    with_metrics = run_scene(sc)
    assert with_metrics.summary["metrics"]["tip_tracking_rms_m"] > 0.0  # the metrics were there
    monkeypatch.setattr(assembly, "MasterMetrics", _NoMetrics)
    monkeypatch.setattr(assembly, "SlaveMetrics", _NoMetrics)
    without = run_scene(sc)
    a, b = _physics(with_metrics.log), _physics(without.log)
    for k in a:
        assert np.array_equal(a[k], b[k]), f"{k} differs with the metrics on"


def test_the_metrics_cover_every_tick_and_asking_again_changes_nothing():
    """The run asks for the metrics' result and then their log: each tick fed once (a metric set
    fed twice would hold 2n rows)."""
    run = run_scene(load_scene("curved_surface_incision", sets=["duration_s=0.5"]))
    n = run.summary["steps"]
    assert len(run.log["slave_track_m"]) == n and len(run.log["m_fixture_residual"]) == n
    assert np.all(run.log["slave_track_m"] > 0.0)  # derived for every tick, none left at zero
