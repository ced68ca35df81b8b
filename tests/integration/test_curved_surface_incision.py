"""The cut across a dome-shaped organ (scene curved_surface_incision, fixture type
surface_scalpel): issue 4's bounds against the curved surface at the slave with the ideal master,
and the same scene rendered by the CAN cobot."""

import numpy as np
import pytest

from teleop.app.runtime import run_scene
from teleop.scenario.schema import load_scene

pytestmark = pytest.mark.long  # the whole 7 s scene each (the cobot's CAN simulation too)


def test_cut_over_the_dome_ideal_master():
    r = run_scene(load_scene("curved_surface_incision"))
    s, m = r.summary, r.summary["metrics"]
    assert s["status"] == "ok" and not s["nan"] and set(s["slave_statuses"]) == {"ok"}
    assert m["tip_tracking_rms_m"] <= 1e-4
    assert m["cut_depth_error_max_m"] <= 5e-5  # along the dome's normal at the tip's foot
    assert m["cut_direction_error_max_rad"] <= 1e-3
    assert m["fixture_residual_max"] <= 1e-6  # the master's rows on the virtual tool
    assert m["cut_length_m"] > 0.02 and m["contact_force_max_N"] > 1.0
    tip = r.log["slave_tip"]
    assert tip[0, 0] < 0.47 and tip[-1, 0] > 0.51  # from the flank over the apex (x = 0.5)
    assert np.ptp(tip[:, 2]) > 0.002  # and up the dome: 12.1 mm -> 15 mm of surface height
    assert np.all(r.log["slave_depth_err_m"] > 0)  # in the tissue all along


def test_cut_over_the_dome_on_the_cobot():
    """The cobot renders the whole cut (its status ok, it tracks the reference tool) and the slave,
    following the admittance model's output, meets issue 4's bounds as on the ideal master, its
    fixture rows never relaxed."""
    r = run_scene(load_scene("curved_surface_incision").with_overrides(master="cobot"))
    s, m = r.summary, r.summary["metrics"]
    assert s["master_status"] == "ok" and not s["nan"] and s["steps"] == 7000
    assert s["tracking_error_max_m"] < 1e-3
    assert "fixtures_relaxed" not in s["slave_statuses"]
    assert m["tip_tracking_rms_m"] <= 1e-4
    assert m["cut_depth_error_max_m"] <= 5e-5
    assert m["cut_direction_error_max_rad"] <= 1e-3
    assert m["slave_fixture_residual_max"] <= 1e-6
    assert 0.04 < m["cut_length_m"] < 0.06  # the ideal master's 49.6 mm: no limit cycle along it


def test_cut_over_the_dome_on_the_cobot_status_ok():
    """Its rows judged each at its own level: the blade-normal rows by their residual (rad), the
    knife edge by its rate; the normal rows' rate is the wrist encoders' noise, reported apart."""
    s = run_scene(load_scene("curved_surface_incision").with_overrides(master="cobot")).summary
    assert s["status"] == "ok" and not s["nan"], s["status_reason"]
    m = s["metrics"]
    assert m["fixture_residual_max"] <= 1e-3 and m["fixture_rate_max"] <= 1e-2
