"""metrics.EnergyDrift: the stretches with no external work, found from the applied wrench."""

from types import SimpleNamespace

import numpy as np
import pytest

from teleop.app.metrics import EnergyDrift


class FakeTool:
    """What the hook reads: model.dissipative, energy(), applied_W, status."""

    def __init__(self, dissipative=False, E=1.0):
        self.model = SimpleNamespace(dissipative=dissipative)
        self.E, self.applied_W, self.status = E, None, "ok"

    def energy(self):
        return self.E


def run(hook, tool, ticks):
    """ticks: (applied wrench or None, energy after the tick, status)."""
    loop = SimpleNamespace(tool=tool)
    for i, (W, E, st) in enumerate(ticks):
        hook.before_tick(i, 0.0, loop)
        tool.applied_W, tool.E, tool.status = W, E, st
        hook.after_tick(i, 0.0, loop)
    return hook.result()["energy_drift_rel_max"]


PUSH = np.array([1.0, 0, 0, 0, 0, 0])
ZERO = np.zeros(6)


def test_stretches_are_measured_from_their_own_start():
    tool = FakeTool(E=1.0)
    ticks = [
        (PUSH, 2.0, "ok"),          # work done: 1 -> 2, not a stretch
        (ZERO, 2.0 + 2e-3, "ok"),   # stretch A from 2.0: 1e-3
        (None, 2.0 - 4e-3, "ok"),   # still A (no wrench at all): 2e-3
        (PUSH, 10.0, "ok"),         # ends A
        (ZERO, 10.0 + 1e-2, "ok"),  # stretch B from 10: 1e-3
        (ZERO, 10.0 + 5e-3, "ok"),
    ]
    assert run(EnergyDrift(tool), tool, ticks) == pytest.approx(2e-3, rel=1e-9)


def test_the_first_tick_measures_from_the_initial_energy():
    tool = FakeTool(E=4.0)
    assert run(EnergyDrift(tool), tool, [(ZERO, 4.4, "ok")]) == pytest.approx(0.1)


def test_null_without_a_force_free_stretch():
    tool = FakeTool()
    assert run(EnergyDrift(tool), tool, [(PUSH, 1.0 + i, "ok") for i in range(5)]) is None


def test_null_for_a_damped_tool_whatever_the_wrench():
    tool = FakeTool(dissipative=True)
    assert run(EnergyDrift(tool), tool, [(ZERO, 1.0 / (i + 1), "ok") for i in range(5)]) is None


def test_a_failed_step_ends_the_stretch_and_is_not_measured():
    tool = FakeTool(E=1.0)
    ticks = [(ZERO, 1.0 + 1e-6, "ok"), (ZERO, 0.0, "singular"), (ZERO, 0.0, "ok")]
    assert run(EnergyDrift(tool), tool, ticks) == pytest.approx(1e-6)


def test_a_tool_at_rest_uses_the_energy_floor():
    tool = FakeTool(E=0.0)
    assert run(EnergyDrift(tool), tool, [(ZERO, 1e-18, "ok")]) == pytest.approx(1e-18 / EnergyDrift.E_FLOOR_J)
