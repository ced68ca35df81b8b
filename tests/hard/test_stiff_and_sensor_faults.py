"""Hard cases at the largest control period and with bad sensor data. Each states its bound."""

import numpy as np
import pytest

from teleop.dynamics import fixtures
from teleop.dynamics.body import RigidBody
from teleop.dynamics.effects import Spring
from teleop.dynamics.tool import ReferenceTool
from teleop.util.errors import ConfigError
from tests.cobot_tick import make_cobot, tick

H = 2e-3  # the largest period of the study
MASS = 0.25


def _spring_tool(omega_h: float, integrator: str) -> ReferenceTool:
    k = MASS * (omega_h / H) ** 2  # natural frequency omega with omega*h = omega_h
    tool = ReferenceTool(RigidBody(MASS, [0.0025] * 3), fixtures.free("ZYX"), [Spring(np.zeros(3), k)], integrator)
    tool.reset([0.01, 0, 0, 0, 0, 0])
    return tool


@pytest.mark.parametrize("integrator", ["parametric", "lie_group", "rk4"])
def test_stiff_spring_inside_the_stability_limit(integrator):
    """omega*h = 1.9 (symplectic Euler's limit is 2): all ok, amplitude <= 4x the 10 mm start."""
    tool = _spring_tool(1.9, integrator)
    for _ in range(3000):
        assert tool.step(H) == "ok"
        assert np.linalg.norm(tool.pose()[0]) <= 0.04


@pytest.mark.parametrize("integrator", ["parametric", "lie_group", "baumgarte", "projection"])
def test_stiff_spring_beyond_the_limit_is_caught_early(integrator):
    """omega*h = 2.5: the explicit schemes diverge. Bound: reported 'diverged' within 100 steps,
    the pose never leaves 0.1 m, no NaN; the tool holds still instead of flying off."""
    tool = _spring_tool(2.5, integrator)
    statuses = [tool.step(H) for _ in range(300)]
    assert "diverged" in statuses[:100]
    assert np.all(np.isfinite(tool.q)) and np.linalg.norm(tool.pose()[0]) <= 0.1


def _cobot(gains: dict, dt: float):
    from teleop.master import CobotConfig
    from teleop.scenario.build import build_tool
    from teleop.scenario.schema import load_scene

    tool = build_tool(load_scene("paper_rolling_disk").with_overrides(dt_s=dt))
    return tool, make_cobot(tool, CobotConfig.from_dict(gains, "cobot"), dt, np.random.default_rng(0))


def test_large_pid_gains_at_the_largest_period():
    """kp 1.5e5 /s^2, ki 1.5e6, kd 450 /s at 2 ms (kd*dt = 0.9): ok, upright disk within 50 um."""
    tool, master = _cobot({"kp": 1.5e5, "ki": 1.5e6, "kd": 450.0}, H)
    with master:
        for _ in range(1000):
            assert tick(master, tool, np.array([2.0, 0.3, 0, 0, 0, 0.02])) == "ok"
            assert abs(master.virtual_pose()[0][2] - 0.03) <= 50e-6
    assert np.all(np.isfinite(tool.q))


def test_pid_gains_the_period_cannot_integrate_are_refused():
    """kd*dt >= 1 cannot be integrated stably: a clear error naming the key, not a run that explodes."""
    with pytest.raises(ConfigError, match="kd"):
        _cobot({"kd": 4000.0}, H)


def test_non_finite_sensor_values_never_reach_the_math():
    """NaN/Inf at the hand-load-cell end for some cycles: no NaN in the tool, a status each cycle,
    and the chain carries on when the data is finite again."""
    tool, master = _cobot({}, 1e-3)
    with master:
        statuses = []
        for i in range(300):
            w = (np.full(6, np.nan) if 50 <= i < 60 else np.array([np.inf, 0, 0, 0, 0, 0]) if 100 <= i < 103
                 else np.array([1.0, 0, 0, 0, 0, 0]))
            statuses.append(tick(master, tool, w))
            assert np.all(np.isfinite(tool.q)) and np.all(np.isfinite(master.virtual_pose()[0]))
        assert all(isinstance(s, str) for s in statuses) and statuses[-1] == "ok"
        assert master.virtual_pose()[0][0] > 0.001  # it moved on the finite pushes
