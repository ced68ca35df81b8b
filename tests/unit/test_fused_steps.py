"""The fused steps (teleop.dynamics.kernels.steps) against the split path they replace: the same
kernels called one by one from Python, the path a model with a user's Python row or effect takes.
The split path is itself held against Pinocchio, finite differences and energy elsewhere
(test_kernels, tests/oracle); here the fusion must not change the physics."""

import numpy as np
import pytest

from teleop.dynamics.body import RigidBody
from teleop.dynamics.constraints import PlaneHeight
from teleop.dynamics.effects import Spring
from teleop.dynamics.model import ConstrainedBody
from teleop.scenario.build import build_tool
from teleop.scenario.operators import ScriptedWrench
from teleop.scenario.schema import list_scenes, load_scene
from tests.user_rows import SineRow

FLAT = ["paper_rolling_disk", "tests/data/undamped/undamped_rolling_disk.toml"]


def _run(scene, fused: bool, steps: int = 400):
    tool = build_tool(scene)
    if not fused:  # the split path: as for a model with a Python row
        tool.model.fused = False
        tool.reset(scene.tool.q0, scene.tool.qd0)
    assert tool.integrator._fused is fused
    op = ScriptedWrench(scene.operator, scene.fixture)
    rec = []
    for i in range(steps):
        assert tool.step(scene.dt_s, op.wrench(i * scene.dt_s, *tool.pose())) == "ok"
        rec.append(np.concatenate([tool.q, tool.qd, tool.lam, tool.wrench_W, tool.acceleration_W,
                                   tool.constraint_wrench_W, [tool.rank, tool.energy()]]))
    return np.array(rec), tool


@pytest.mark.parametrize("integrator", ["parametric", "energy"])
@pytest.mark.parametrize("name", FLAT)
def test_fused_step_follows_the_split_path(name, integrator):
    scene = load_scene(name).with_overrides(integrator=integrator, seed=3)
    fused, tf = _run(scene, True)
    split, ts = _run(scene, False)
    assert np.abs(fused[:, :6]).max() > 1e-3  # the tool moved
    np.testing.assert_allclose(fused, split, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(tf.pose()[1], ts.pose()[1], atol=1e-13)
    if integrator == "energy":
        assert tf.integrator.E == pytest.approx(ts.integrator.E, rel=1e-12)


@pytest.mark.parametrize("name", list_scenes())
def test_fused_evaluation_is_the_split_one(name):
    """model.evaluate in one kernel call against the kernel-by-kernel evaluation, on every scene
    (every fixture), at a moving state with an operator wrench."""
    tool = build_tool(load_scene(name))
    model = tool.model
    if not model.fused:  # a scene with a Python row or effect (the dome's surface rows): split only
        assert model.rows.python_rows or model._py_effects
        return
    rng = np.random.default_rng(7)
    q, qd = tool.q.copy(), rng.normal(scale=0.2, size=6)
    F = rng.normal(size=6)
    fused = model.evaluate(tool.state.chart, q, qd, 0.0, F)
    model.fused = False
    model._cache = None
    split = model.evaluate(tool.state.chart, q, qd, 0.0, F)
    for key in ("qdd", "nudot", "lam", "wrench_W", "constraint_wrench_W"):
        np.testing.assert_allclose(getattr(fused, key), getattr(split, key), rtol=1e-11, atol=1e-11, err_msg=key)
    assert fused.rank == split.rank
    for key in ("R", "E_B", "E_inv", "dE", "E_W"):
        np.testing.assert_allclose(getattr(fused.pose, key), getattr(split.pose, key), atol=1e-14, err_msg=key)


def test_a_python_row_or_effect_takes_the_split_path():
    body = RigidBody(0.2, [1e-3, 1e-3, 1e-3])
    plane = PlaneHeight(np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.0)
    assert ConstrainedBody(body, (plane,)).fused
    assert not ConstrainedBody(body, (plane, SineRow(0.0))).fused
    assert not ConstrainedBody(body, (plane,), (Spring(np.zeros(3), 10.0),)).fused
