"""The stiffest renderable spring (teleop.control.stability): the tool's own sampled-data bound
K < 4 m / T^2 - 2 B / T against its one-period map by hand, against the linearized loop of the
cobot (servo-model compensation: the same boundary), and how it grows with the rate."""

import math

import numpy as np
import pytest

from teleop.control.stability import LoopParams, critical_stiffness, is_stable, sampled_data_stiffness
from teleop.util.errors import ConfigError


def _tool_radius(m: float, B: float, K: float, T: float) -> float:
    """The pole radius of semi-implicit Euler on m a = -B v - K x: v+ = v + T a, x+ = x + T v+."""
    A = np.array([[1.0 - T * T * K / m, T * (1.0 - T * B / m)], [-T * K / m, 1.0 - T * B / m]])
    return float(np.max(np.abs(np.linalg.eigvals(A))))


@pytest.mark.parametrize(("m", "B", "T"), [(0.05, 2.0, 1e-3), (0.05, 30.0, 5e-4), (0.25, 10.0, 1e-3),
                                           (0.02, 30.0, 1e-3)])
def test_the_bound_is_where_the_tools_step_turns_unstable(m, B, T):
    K = sampled_data_stiffness(m, B, T)
    assert K == pytest.approx(4 * m / T**2 - 2 * B / T)
    assert _tool_radius(m, B, 0.99 * K, T) < 1.0 < _tool_radius(m, B, 1.01 * K, T)
    assert K * T / 2 + B == pytest.approx(2 * m / T)  # Colgate's b > K T / 2 + |B| with b = 2 m / T


@pytest.mark.parametrize(("m", "B"), [(0.05, 2.0), (0.25, 30.0), (0.02, 10.0)])
@pytest.mark.parametrize("T", [1e-3, 5e-4])
def test_the_linearized_cobot_loop_has_the_same_boundary(m, B, T):
    """With the servo model's compensation the device follows the tool and feeds nothing back:
    the loop's stiffest stable spring is the tool's own bound (to the bisection's 1e-3)."""
    p = LoopParams(mass=m, damping=B, dt_s=T)
    K = critical_stiffness(p)
    assert K == pytest.approx(sampled_data_stiffness(m, B, T), rel=2e-3)
    assert is_stable(LoopParams(mass=m, damping=B, stiffness=0.98 * K, dt_s=T))
    assert not is_stable(LoopParams(mass=m, damping=B, stiffness=1.02 * K, dt_s=T))


def test_twice_the_rate_renders_four_times_the_stiffness_and_more_with_damping():
    for m in (0.02, 0.05, 0.25):
        assert sampled_data_stiffness(m, 0.0, 5e-4) == pytest.approx(4 * sampled_data_stiffness(m, 0.0, 1e-3))
        assert sampled_data_stiffness(m, 10.0, 5e-4) > 4 * sampled_data_stiffness(m, 10.0, 1e-3)
    # a damper past 2 m / T at 1 kHz leaves no spring there; at 2 kHz it is inside again
    assert sampled_data_stiffness(0.02, 40.0, 1e-3) == 0.0
    assert sampled_data_stiffness(0.02, 40.0, 5e-4) == pytest.approx(2 * (80.0 - 40.0) / 5e-4)


def test_bad_inputs_are_refused_and_the_ends_of_the_search_said():
    with pytest.raises(ConfigError, match="damping"):
        sampled_data_stiffness(0.05, -1.0, 1e-3)
    with pytest.raises(ConfigError, match="mass"):
        sampled_data_stiffness(0.0, 1.0, 1e-3)
    p = LoopParams(mass=0.05, damping=2.0)
    assert critical_stiffness(p, lo=1e9, hi=1e10) == 0.0  # the soft end is already unstable
    assert math.isinf(critical_stiffness(p, lo=1.0, hi=1e3))  # stable all the way up
    with pytest.raises(ConfigError, match="lo < hi"):
        critical_stiffness(p, lo=10.0, hi=1.0)
