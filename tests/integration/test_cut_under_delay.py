"""The cut under a tick or more of feedback delay, unguarded: the contact's damping rendered at the
master (teleop.tick.feedback) keeps it as in one process; the wrench alone falls into the
stick-slip limit cycle that a late reply over a network used to start."""

import numpy as np
import pytest

from teleop.app.runtime import run_scene
from teleop.scenario.schema import load_scene

SETS = ["duration_s=2.5", 'link.passivity="off"']


def _cut(*sets):
    r = run_scene(load_scene("straight_incision", sets=SETS + list(sets)))
    return r.summary["status"], r.summary["metrics"]


@pytest.fixture(scope="module")
def one_process():
    return _cut()[1]


@pytest.mark.parametrize("link", [["link.round_trip_ms=1"], ["link.jitter_ms=1"], ["link.round_trip_ms=50"]],
                         ids=["1ms", "jitter1ms", "50ms"])
def test_the_cut_under_delay_is_the_cut_in_one_process(one_process, link):
    status, m = _cut(*link)
    assert status == "ok"
    assert m["tip_tracking_rms_m"] <= 2.0 * one_process["tip_tracking_rms_m"]
    assert m["cut_length_m"] == pytest.approx(one_process["cut_length_m"], rel=0.05)
    assert m["cut_speed_max_m_per_s"] <= 2.0 * one_process["cut_speed_max_m_per_s"]


def test_without_the_local_damping_one_tick_more_is_a_limit_cycle(one_process):
    _, m = _cut("link.round_trip_ms=1", "mapping.feedback_local_damping=false")
    assert m["cut_speed_max_m_per_s"] > 5.0 * one_process["cut_speed_max_m_per_s"]
    assert m["cut_length_m"] > 2.0 * one_process["cut_length_m"]


def test_a_slave_that_sends_a_damping_feeding_energy_is_not_rendered(monkeypatch):
    """A contact model (or a slave) whose damping is not positive semidefinite: the master renders
    the wrench alone for those replies, counts them, and the run goes on without NaN."""
    from teleop.contact.tissue import TissueBlock

    monkeypatch.setattr(TissueBlock, "damping", lambda self, *a: -1000.0 * np.eye(6))
    r = run_scene(load_scene("straight_incision", sets=SETS))
    s = r.summary
    assert s["feedback_damping_refused"] > 1000 and not s["nan"] and s["status"] == "ok"


def test_a_tissue_model_without_a_written_out_damping_is_differentiated(monkeypatch):
    """A user's contact model with only ``wrench`` (no ``damping``): the slave takes the damping
    by central differences, and the cut under 1 ms runs as with the written-out law."""
    from teleop.contact.tissue import TissueBlock

    sets = ["link.round_trip_ms=1"]
    written = _cut(*sets)[1]
    monkeypatch.delattr(TissueBlock, "damping")
    status, m = _cut(*sets)
    assert status == "ok"
    assert m["tip_tracking_rms_m"] == pytest.approx(written["tip_tracking_rms_m"], rel=1e-3)
    assert m["cut_length_m"] == pytest.approx(written["cut_length_m"], rel=1e-3)
