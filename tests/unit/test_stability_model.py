"""The linearized sampled-data model of the admittance loop (teleop.control.stability) against hand
cases: the continuous limit (the PID's error dynamics s^3 + kd s^2 + kp s + ki and the rendered
m s^2 + b s + k), the mass ratio boundary of the commanded-acceleration compensation, the
explicit damping step limit, and the loop's linearity."""

import math

import numpy as np
import pytest

from teleop.control.stability import LoopParams, _Loop, closed_loop_matrix, critical_mass, is_stable, spectral_radius
from teleop.util.errors import ConfigError


def test_continuous_limit_has_the_pid_and_the_tool_poles():
    """No handle mass, a fast period and servo, no window: the closed loop's poles are exp(s T) of
    the PID's error poles (e = x_r - x_h: e''' + kd e'' + kp e' + ki e = 0 on the integral) and of
    the rendered tool's m s^2 + b s + k, to the period's first order."""
    T = 1e-6
    p = LoopParams(mass=0.2, damping=3.0, stiffness=400.0, handle_mass=0.0, dt_s=T, servo_bandwidth_hz=1e5,
                   read_window_s=0.0)
    z = np.linalg.eigvals(closed_loop_matrix(p))
    s_expected = np.concatenate([np.roots([1.0, p.kd, p.kp, p.ki]), np.roots([p.mass, p.damping, p.stiffness])])
    z = z[np.abs(z) > 1e-12]  # the delay lines' poles at 0
    s_got = np.log(z.astype(complex)) / T
    for s in s_expected:
        assert np.min(np.abs(s_got - s)) <= 1e-2 * abs(s), s


def test_the_map_is_linear():
    p = LoopParams(mass=0.05, damping=1.0, latency_periods=2, compensation="commanded")
    A = closed_loop_matrix(p)
    rng = np.random.default_rng(0)
    x, y = rng.standard_normal(A.shape[0]), rng.standard_normal(A.shape[0])
    loop = _Loop(p)
    assert np.allclose(loop.step(2.0 * x - 3.0 * y), 2.0 * (A @ x) - 3.0 * (A @ y), rtol=1e-12, atol=1e-9)


def test_commanded_compensation_needs_a_heavy_enough_tool():
    """Compensating the handle's 0.15 kg by the previous period's commanded acceleration leaves a
    loop of gain ~ m_h / m: a 0.01 kg tool limit-cycles, 0.15 kg renders (the simulated device
    agrees: tools/stability_map.py)."""
    base = LoopParams(mass=1.0, compensation="commanded")
    assert not is_stable(LoopParams(**{**base.__dict__, "mass": 0.01}))
    assert is_stable(LoopParams(**{**base.__dict__, "mass": 0.15}))
    m = critical_mass(base)
    assert 0.02 < m < 0.08
    # no handle mass: nothing to compensate, the boundary disappears
    assert critical_mass(LoopParams(mass=1.0, handle_mass=0.0, compensation="commanded")) <= 1e-5


def test_servo_model_compensation_renders_a_third_of_the_handle():
    assert is_stable(LoopParams(mass=0.05))
    assert is_stable(LoopParams(mass=0.005))
    # with bus latency the model acceleration of the late reading's SYNC still matches
    assert is_stable(LoopParams(mass=0.05, latency_periods=2))
    assert not is_stable(LoopParams(mass=0.05, latency_periods=2, compensation="commanded"))


def test_explicit_damping_limit_by_hand():
    """With exact compensation what is left is the tool's semi-implicit Euler: b T / m < 2."""
    b = 20.0
    m = critical_mass(LoopParams(mass=1.0, damping=b))
    assert m == pytest.approx(b * 1e-3 / 2.0, rel=0.01)


def test_a_slow_period_is_unstable_at_the_default_gains():
    """The commanded velocity's own update ν <- ν (1 - kd T) + ... wants |1 - kd T| < 1, kd T < 2:
    at kd = 400 /s, 4 ms (1.6) is inside, 6 ms (2.4) outside."""
    assert spectral_radius(LoopParams(mass=1.0, dt_s=4e-3)) < 1.0
    assert spectral_radius(LoopParams(mass=1.0, dt_s=6e-3)) > 1.0


def test_bad_settings_name_the_field():
    with pytest.raises(ConfigError, match=r"LoopParams\.mass"):
        LoopParams(mass=0.0)
    with pytest.raises(ConfigError, match="compensation"):
        LoopParams(mass=1.0, compensation="magic")
    with pytest.raises(ConfigError, match="read_window_s"):
        LoopParams(mass=1.0, read_window_s=2e-3)
    assert math.isinf(critical_mass(LoopParams(mass=1.0, dt_s=6e-3)))


def test_an_undamped_spring_is_marginal_only_with_the_servo_model():
    """A rendered 2000 N/m spring with no damping: the servo model's compensation leaves its poles
    on the unit circle at its own frequency sqrt(k/m) (to the step's order); the commanded one
    feeds it energy (poles outside: 1.003 at 0.2 kg, an e-fold in 0.3 s)."""
    for m in (0.005, 0.05, 1.0):
        p = LoopParams(mass=m, stiffness=2000.0)
        z = np.linalg.eigvals(closed_loop_matrix(p))
        top = z[np.argmax(np.abs(z))]
        assert abs(abs(top) - 1.0) <= 1e-9
        assert abs(np.angle(top)) / 1e-3 == pytest.approx(math.sqrt(2000.0 / m), rel=0.05)
        assert is_stable(p)
    assert spectral_radius(LoopParams(mass=0.2, stiffness=2000.0, compensation="commanded")) > 1.002


def test_the_grip_rotation_explained():
    """The light scalpel's blade axis (2e-5 kg m^2, 0.02 N m s/rad) on the handle's z axis
    (3e-5 kg m^2, φ's world-frame rotation) renders with the commanded compensation; on its x axis
    (2.55e-4 kg m^2 about H: a body-fixed grip rotation) it does not. The servo model renders both."""
    blade = dict(mass=2e-5, damping=0.02)
    assert is_stable(LoopParams(**blade, handle_mass=3e-5, compensation="commanded"))
    assert spectral_radius(LoopParams(**blade, handle_mass=2.55e-4, compensation="commanded")) > 1.1
    assert is_stable(LoopParams(**blade, handle_mass=2.55e-4))
