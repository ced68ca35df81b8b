"""The felt-versus-true force measure of a delayed run (teleop.app.metrics.felt_versus_true and
link_metrics): a felt force that is the true one delayed is found at that delay with no error;
a felt force off by a constant shows that constant; and a delayed scene's summary reports it."""

import numpy as np
import pytest

from teleop.app.metrics import felt_versus_true

DT = 1e-3


def test_a_delayed_copy_is_found_at_its_delay_with_no_error():
    t = np.arange(3000) * DT
    true = np.maximum(0.0, np.sin(2 * np.pi * 1.5 * t)) * 2.0
    felt = np.concatenate((np.zeros(37), true[:-37]))
    m = felt_versus_true(felt, true, DT, 0.1)
    assert m["felt_lag_s"] == pytest.approx(0.037) and m["felt_error_rms_N"] == pytest.approx(0.0, abs=1e-12)


def test_an_offset_shows_as_itself_and_nothing_in_contact_is_zero():
    true = np.full(500, 1.5)
    m = felt_versus_true(true + 0.25, true, DT, 0.02)
    assert m["felt_error_rms_N"] == pytest.approx(0.25) and m["felt_error_peak_N"] == pytest.approx(0.25)
    assert felt_versus_true(np.zeros(10), np.zeros(10), DT, 0.01) == {"felt_error_rms_N": 0.0,
                                                                      "felt_error_peak_N": 0.0, "felt_lag_s": 0.0}


def test_a_delayed_runs_summary_reports_the_felt_force_against_the_true_one_and_the_drift():
    from teleop.app.runtime import run_scene
    from teleop.scenario.schema import load_scene

    m = run_scene(load_scene("stiff_contact", sets=["link.round_trip_ms=20", "duration_s=1.5"])).summary["metrics"]
    assert {"felt_error_rms_N", "felt_error_peak_N", "felt_lag_s", "link_drift_max_m", "link_drift_final_m"} <= set(m)
    assert 0.0 <= m["felt_lag_s"] <= 0.021 and m["felt_error_peak_N"] >= m["felt_error_rms_N"] >= 0.0
