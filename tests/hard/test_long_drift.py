"""10^6 steps (1000 s at 1 kHz) on the sphere: the parametric integrator must not drift.

Marked ``long``; CI runs it anyway (the marker lets a developer skip it locally with -m 'not long').
"""

import numpy as np
import pytest

from teleop.dynamics import fixtures
from teleop.dynamics.body import RigidBody
from teleop.dynamics.effects import AngularDamper, LinearDamper
from teleop.dynamics.tool import ReferenceTool


@pytest.mark.long
def test_million_steps_on_the_sphere_stay_on_it():
    """Bound: |deviation| <= 1e-9 m and |body z - normal| <= 1e-9 rad over 10^6 steps, no NaN,
    speed bounded by the push over the damping."""
    tool = ReferenceTool(RigidBody(0.25, [0.0025] * 3), fixtures.sphere((0, 0, 0), 0.05),
                         [LinearDamper(1.0), AngularDamper(0.1)], "parametric")
    tool.reset([0, -0.05, 0, 0, np.pi / 2, 0])
    worst = 0.0
    for i in range(1_000_000):
        p, R = tool.pose()
        # a wandering tangential push with a slow spin: visits the whole sphere, poles included
        F = R @ np.array([2.0 * np.cos(1e-4 * i), 2.0 * np.sin(3e-4 * i), -5.0])
        assert tool.step(1e-3, np.concatenate([F, [0, 0, 0.002]])) == "ok"
        if i % 1000 == 0:
            worst = max(worst, abs(np.linalg.norm(p) - 0.05), np.linalg.norm(np.cross(R[:, 2], p / np.linalg.norm(p))))
            assert np.all(np.isfinite(tool.q))
    assert worst <= 1e-9
    v, _ = tool.twist()
    assert np.linalg.norm(v) < 2.5  # 2.8 N of push against >= 1 N s/m of damping
    assert tool.recharts > 0
