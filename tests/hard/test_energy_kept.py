"""Issue 15's 'energy kept': three undamped scenes (tests/data/undamped), pushed for 0.5 s then left
alone, on the 'energy' integrator at 1 kHz. Over the force-free stretch the relative energy drift
must stay <= 1e-6 in 60 s (scaled to the run's length for the short default test) and the
constraints must hold to 1e-9, as measured by the scene metrics (geometry of the pose, not the
integrator's rows) and by ``metrics.energy_drift_rel_max``.
"""

from pathlib import Path

import numpy as np
import pytest

from teleop.app.runtime import run_scene
from teleop.scenario.schema import load_scene

SCENES = Path(__file__).resolve().parents[1] / "data" / "undamped"
NAMES = ("undamped_sphere_slide", "undamped_rolling_disk", "undamped_scalpel_slide")
#: issue 15: relative drift over 60 s, constraints
DRIFT_60S, CONSTRAINT = 1e-6, 1e-9
#: the metrics that measure a constraint (m, rad or m/s); the rolling error is a percentage of V
CONSTRAINT_KEYS = ("sphere_deviation_max_m", "normal_angle_error_max_rad", "height_error_max_m",
                   "upright_error_max_rad", "depth_error_max_m", "blade_tilt_max_rad", "sideslip_max_m_per_s")


def run_undamped(name: str, seconds: float, integrator: str = "energy") -> dict:
    scene = load_scene(str(SCENES / f"{name}.toml")).with_overrides(duration_s=seconds, integrator=integrator)
    return run_scene(scene).summary


def check(summary: dict, seconds: float) -> None:
    assert summary["status"] == "ok" and not summary["nan"]
    m = summary["metrics"]
    drift = m["energy_drift_rel_max"]
    assert drift is not None  # the scene has a force-free stretch, from 0.5 s on
    assert drift <= DRIFT_60S * seconds / 60.0
    for k in CONSTRAINT_KEYS:
        if k in m:
            assert m[k] <= CONSTRAINT, k
    if "rolling_error_max_pct" in m:  # no slip: rolling error in % of the speed
        assert m["rolling_error_max_pct"] <= 1e-6


@pytest.mark.parametrize("name", NAMES)
def test_energy_kept_5s(name):
    check(run_undamped(name, 5.0), 5.0)


@pytest.mark.long
@pytest.mark.parametrize("name", NAMES)
def test_energy_kept_60s(name):
    check(run_undamped(name, 60.0), 60.0)


def test_the_parametric_step_gains_energy_where_energy_does_not():
    """The finding, kept honest: on the knife edge the parametric step gains far more than the
    bound in 5 s (a first-order gain from its one-sided constraint impulse)."""
    drift = run_undamped("undamped_scalpel_slide", 5.0, "parametric")["metrics"]["energy_drift_rel_max"]
    assert drift > 1e-2


def test_a_damped_scene_has_no_force_free_stretch():
    s = run_scene(load_scene("paper_rolling_disk").with_overrides(duration_s=0.2)).summary
    assert "energy_drift_rel_max" in s["metrics"] and s["metrics"]["energy_drift_rel_max"] is None
    assert np.isfinite(s["metrics"]["height_error_max_m"])
