"""The model-mediated wall (teleop.contact.wall_model): its updates never raise the energy it
stores plus its tank, whatever the estimates and wherever the tool is; the offset closes the
moment that is free."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop.contact.wall_model import PassiveWall

_finite = st.floats(-5e-3, 5e-3, allow_nan=False)
_unit = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(lambda v: math.hypot(*v) > 0.1)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(_unit, _finite, st.floats(1.0, 1e6), st.tuples(_finite, _finite, _finite),
                          st.floats(0.0, 1e-4), st.booleans()), min_size=1, max_size=40))
def test_an_update_never_raises_stored_energy_plus_tank(steps):
    wall = PassiveWall(tank_max_J=1e-3)
    for n, h, k, x, credit, gone in steps:
        x = np.array(x)
        n = np.array(n) / np.linalg.norm(n)
        wall.credit(credit)
        before = wall.energy(x) + wall.tank_J
        wall.aim(None if gone else n, h, k)
        wall.update(x)
        assert wall.energy(x) + wall.tank_J <= before + 1e-12 * max(1.0, before)
        assert wall.force(x) >= 0.0 and wall.tank_J <= 1e-3


def test_a_tool_found_deep_inside_gets_a_wall_at_its_tip_not_a_throw():
    wall = PassiveWall()
    n = np.array([0.0, 0.0, 1.0])
    x = np.array([0.0, 0.0, -3e-3])            # 3 mm below the surface the slave just found
    wall.aim(n, 0.0, 1e4)
    wall.update(x)
    assert wall.energy(x) == 0.0 and wall.force(x) == 0.0
    assert math.isclose(wall.offset_m, 3e-3)
    x_out = np.array([0.0, 0.0, 1e-4])         # the tool leaves: the wall goes where the slave says at once
    wall.update(x_out)
    assert wall.h == 0.0 and wall.offset_m == 0.0


def test_the_tank_moves_the_wall_as_far_as_it_pays():
    wall = PassiveWall(tank_max_J=1.0)
    n = np.array([0.0, 0.0, 1.0])
    x = np.array([0.0, 0.0, -1e-3])
    wall.aim(n, 0.0, 1e4)
    wall.update(x)
    wall.credit(0.5 * 1e4 * (0.4e-3) ** 2)     # what a 0.4 mm deep wall stores
    wall.update(x)
    assert math.isclose(wall.depth(x), 0.4e-3, rel_tol=1e-9)
    assert math.isclose(wall.offset_m, 0.6e-3, rel_tol=1e-9) and wall.tank_J == 0.0


def test_bad_tank_size_is_refused():
    for bad in (-1.0, float("nan"), float("inf")):
        try:
            PassiveWall(tank_max_J=bad)
        except ValueError as e:
            assert "tank_max_J" in str(e)
        else:
            raise AssertionError(bad)
