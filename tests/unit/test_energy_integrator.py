"""The 'energy' integrator (EnergyConsistent): energy kept with no work done, changed by the work
done otherwise, constraints held, against closed forms."""

import math

import numpy as np
import pytest

from teleop.dynamics import fixtures
from teleop.dynamics.effects import Gravity, LinearDamper, Spring
from teleop.dynamics.tool import ReferenceTool


def drift(tool, steps, h=1e-3):
    """Largest |E - E0| / |E0| over the steps, and the largest holonomic residual."""
    E0, worst, res = tool.energy(), 0.0, 0.0
    for _ in range(steps):
        assert tool.step(h) == "ok"
        worst = max(worst, abs(tool.energy() - E0) / abs(E0))
        r = tool.residual()
        res = max(res, float(np.abs(r).max()) if r.size else 0.0)
    return worst, res


def test_a_held_force_on_a_free_body_from_rest_does_exactly_its_work(lopsided_body):
    """Work of a constant force = F . displacement; the trapezoid balance is exact for it."""
    tool = ReferenceTool(lopsided_body, fixtures.free(), integrator="energy")
    tool.reset([0.1, 0, 0, 0.1, 0.2, 0.3])
    F = np.array([1.0, -2.0, 0.5, 0.0, 0.0, 0.0])
    p0 = tool.pose()[0].copy()
    for _ in range(1000):
        assert tool.step(1e-3, F) == "ok"
    assert tool.energy() == pytest.approx(float(F[:3] @ (tool.pose()[0] - p0)), rel=1e-12)


@pytest.mark.parametrize("integrator, tol", [("energy", 1e-5), ("parametric", 1e-2)])
def test_a_damped_slide_loses_the_closed_form_energy(lopsided_body, integrator, tol):
    """E(t) = E0 exp(-2 c t / m) for a mass sliding against a linear damper (no rotation)."""
    tool = ReferenceTool(lopsided_body, fixtures.free(), [LinearDamper(0.8)], integrator=integrator)
    tool.reset(np.zeros(6), [1.0, 0.5, 0.0, 0.0, 0.0, 0.0])
    E0 = tool.energy()
    for _ in range(1000):
        tool.step(1e-3)
    assert tool.energy() == pytest.approx(E0 * math.exp(-2 * 0.8 * 1.0 / lopsided_body.mass_kg), rel=tol)


def test_a_swinging_body_on_a_sphere_under_gravity_keeps_its_energy(lopsided_body):
    """Kinetic and potential energy traded over 10 s, through re-charts: drift <= 1e-9."""
    tool = ReferenceTool(lopsided_body, fixtures.sphere((0, 0, 0), 0.1), [Gravity(lopsided_body.mass_kg)],
                         integrator="energy")
    tool.reset([0, -0.1, 0, 0, np.pi / 2, 0], [0.3, 0, 0, 3.0, 0, 1.0])
    worst, res = drift(tool, 10_000)
    assert worst <= 1e-9 and res <= 1e-9
    assert tool.recharts > 0


def test_a_disk_rolling_against_a_spring_keeps_its_energy(lopsided_body):
    """A Python conservative effect (the spring's potential), nonholonomic rolling rows."""
    tool = ReferenceTool(lopsided_body, fixtures.rolling_disk(0.03), [Spring(np.array([0.05, 0, 0.03]), 20.0)],
                         integrator="energy")
    tool.reset([0, 0, 0.03, 0, np.pi / 2, 0], [0, 0, 0, 0, 0, 3.0])
    worst, res = drift(tool, 10_000)
    assert worst <= 1e-9 and res <= 1e-9


def test_without_a_parametrization_it_corrects_the_projection_step(lopsided_body):
    """The laparoscopic fixture (trocar, depth, knife edge) has no psi: the projection step."""
    tool = ReferenceTool(lopsided_body, fixtures.laparoscopic(), integrator="energy")
    tool.reset([0, 0, 0.005, 0, 0, 0], [0.05, 0.0, 0, 0.0, 0.0, 0.5])
    worst, res = drift(tool, 5000)
    assert worst <= 1e-9 and res <= 1e-9


def test_a_tool_at_rest_stays_at_rest(lopsided_body):
    tool = ReferenceTool(lopsided_body, fixtures.scalpel(), integrator="energy")
    tool.reset([0, 0, 0.005, 0, 0, 0])
    q0 = tool.q.copy()
    for _ in range(1000):
        assert tool.step(1e-3) == "ok"
    assert np.array_equal(tool.q, q0) and not np.any(tool.qd)
