"""Build a run from a scene and run it: the scene's tool, master, slave, link and operator handed
to a :class:`~teleop.session.Session`, with the scene's metrics as hooks.

Only what the scene names is built: no slave, tissue, tremor probe or device effect it does not
call for. The tick itself is :mod:`teleop.loop`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from teleop.contact import SurfaceTissue, TissueBlock
from teleop.contact.cutting import CuttingModel
from teleop.control.feedback import FeedbackPath
from teleop.dynamics.constraints import RemoteCenter
from teleop.errors import ConfigError, SceneError
from teleop.loop import Hook
from teleop.master import CobotMaster, IdealMaster
from teleop.scenario.build import build_fixture, build_registration, build_tool, master_fixture_spec
from teleop.scenario.metrics import MasterMetrics, SlaveMetrics, TremorProbe, make_metrics, tissue_surface
from teleop.scenario.operators import make_operator
from teleop.scenario.schema import FixtureSpec, Scene
from teleop.session import RunResult, Session
from teleop.slave import SlaveArm
from teleop.slave.side import SlaveSide

__all__ = ["run_scene", "make_master", "RunResult"]


def make_master(scene: Scene, tool, rng: np.random.Generator):
    """The scene's master: the ideal one, or the cobot with only the device effects it names."""
    if scene.master != "cobot":
        return IdealMaster(tool, scene.dt_s)
    cfg = scene.cobot
    if "can_faults" not in scene.effects:
        cfg = replace(cfg, faults=type(cfg.faults)())
    if "sensor_noise" not in scene.effects:
        cfg = replace(cfg, force_noise_N=0.0, torque_noise_Nm=0.0, force_bias_N=(0.0, 0.0, 0.0),
                      torque_bias_Nm=(0.0, 0.0, 0.0))
    if "servo_lag" not in scene.effects:
        cfg = replace(cfg, servo_bandwidth_hz=1e4)  # a 16 us lag: nothing at a 1 kHz tick
    p0, R0 = tool.pose()
    return CobotMaster(cfg, scene.dt_s, rng, p0, R0, tool.body.mass_kg)


def make_slave(scene: Scene, registration, constraints_P):
    """The slave side of a scene with a [slave] table (None without one): the arm under the
    patient-frame fixture ``constraints_P``, the tissue if the scene calls for it."""
    if scene.slave is None:
        return None
    try:
        arm = SlaveArm(scene.slave, constraints_P, scene.dt_s)
        tissue = None
        if "tissue" in scene.effects:
            tissue = scene.tissue or TissueBlock()
            if "cutting" not in scene.effects:  # normal contact only: no cutting resistance
                tissue = replace(tissue, cutting=CuttingModel(0.0, 0.0, 0.0, 0.0))
            surface = tissue_surface(scene.fixture)
            if surface is not None:  # the fixture's curved surface is the tissue's
                tissue = SurfaceTissue(tissue, surface)
    except ConfigError as e:
        key, _, reason = str(e).partition(": ")
        raise SceneError(scene.path, key, reason) from None
    return SlaveSide(arm, registration, tissue, scene.fixture.tip_m)


class _ViewHook(Hook):
    """Hands each tick to a view (which throttles itself)."""

    def __init__(self, view):
        self.view = view

    def after_tick(self, i, t_s, loop) -> None:
        self.view.publish_tick(t_s, loop)


def run_scene(scene: Scene, progress=None, realtime: bool = False, operator=None, view=None) -> RunResult:
    """Run a scene. ``operator`` replaces the scene's (e.g. a keyboard); ``view`` gets every tick
    and throttles itself; ``progress(i, n)`` is called every 1000 ticks."""
    rng = np.random.default_rng(scene.seed)
    tool = build_tool(scene)
    spec_M = master_fixture_spec(scene)
    if operator is None:
        operator = make_operator(scene.operator, spec_M, scene.effects, rng)
    n = int(round(scene.duration_s / scene.dt_s))
    master_metrics = MasterMetrics(make_metrics(spec_M, n, tool.body.mass_kg, tool.fixture.constraints))
    hooks: list = [master_metrics]
    reg = build_registration(scene)
    constraints_P = build_fixture(scene.fixture).constraints  # the fixture where the patient is
    slave = make_slave(scene, reg, constraints_P)
    feedback = tremor = slave_metrics = None
    if slave is not None:
        slave.reset(*tool.pose())
        feedback = FeedbackPath(reg, scene.mapping.feedback_cutoff_hz, scene.dt_s)
        rcm = [c for c in constraints_P if isinstance(c, RemoteCenter)]
        slave_metrics = SlaveMetrics(scene.fixture, n, slave.arm.nv, rcm, constraints_P)
        hooks.append(slave_metrics)
        if getattr(operator, "tremor_on", False) and isinstance(scene.fixture, FixtureSpec):
            tremor = TremorProbe(operator, n, reg.scale, reg.X_PM_R, scene.fixture.plane_normal)
            hooks.append(tremor)
    if view is not None:
        hooks.append(_ViewHook(view))
    master = make_master(scene, tool, rng)
    session = Session(tool, master, operator, scene.dt_s, scene.duration_s, slave=slave, feedback=feedback,
                      hooks=hooks, realtime=realtime, progress=progress)
    result = session.run()
    metrics = master_metrics.result()
    result.log.update(master_metrics.log())
    if slave_metrics is not None:
        metrics.update(slave_metrics.result())
        result.log.update(slave_metrics.log())
    if tremor is not None:
        metrics.update(tremor.result(scene.dt_s))
    s = result.summary
    result.summary = {"scenario": scene.name, **s, "integrator": scene.integrator, "master": scene.master,
                      "seed": scene.seed, "effects": list(scene.effects), "metrics": metrics}
    return result
