"""Build a run from a scene and run it: the scene's tool, master, slave, link and operator handed
to a :class:`~teleop.app.session.Session`, with the scene's metrics as hooks.

Only what the scene names is built: no slave, tissue, tremor probe or device effect it does not
call for. The tick itself is :mod:`teleop.tick.loop`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from teleop.contact import SurfaceTissue, TissueBlock
from teleop.contact.cutting import CuttingModel
from teleop.tick.feedback import FeedbackPath
from teleop.dynamics.constraints import RemoteCenter
from teleop.util.errors import ConfigError, SceneError
from teleop.link import ChannelSpec, LockstepLink, SimulatedChannel
from teleop.tick.guard import MasterGuard, SlaveGuard, tdpa_params
from teleop.tick.loop import Hook
from teleop.master import CobotMaster, IdealMaster
from teleop.scenario.build import build_fixture, build_registration, build_tool, master_fixture_spec
from teleop.app.metrics import EnergyDrift, MasterMetrics, SlaveMetrics, TremorProbe, make_metrics, tissue_surface
from teleop.scenario.operators import make_operator
from teleop.scenario.schema import FixtureSpec, Scene
from teleop.app.session import RunResult, Session, tick_count, verdict
from teleop.slave import SlaveArm
from teleop.tick.slave_side import SlaveSide

__all__ = ["run_scene", "make_master", "make_link", "make_guard", "RunResult"]


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
    return CobotMaster(cfg, scene.dt_s, rng, p0, R0, tool.body.mass_kg, reference=tool)


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


def channel_spec(scene: Scene) -> ChannelSpec:
    """The scene's [link] table as a ChannelSpec (the same both ways)."""
    ln = scene.link
    return ChannelSpec(round_trip_ms=ln.round_trip_ms, jitter_ms=ln.jitter_ms, loss=ln.loss,
                       burst_enter=ln.burst_enter, burst_exit=ln.burst_exit, burst_loss=ln.burst_loss,
                       bandwidth_Bps=ln.bandwidth_kBps * 1e3 if ln.bandwidth_kBps > 0 else float("inf"))


def make_link(scene: Scene, rng: np.random.Generator, simulated: bool | None = None):
    """The scene's link: the simulated channel of its [link] table in lockstep simulated time, or
    the in-process lockstep link when the table asks for nothing (``simulated`` forces either).
    The channel's draws come from children spawned from ``rng``: the run's own stream is not
    advanced, so a zero-delay channel reproduces the lockstep run."""
    if not (scene.link.simulated if simulated is None else simulated):
        return LockstepLink()
    return SimulatedChannel(channel_spec(scene), rng)


def make_guard(scene: Scene, registration, n_ticks: int, networked: bool = False):
    """(MasterGuard, SlaveGuard) when the scene's link is guarded (:meth:`LinkSpec.guarded`: its
    ``passivity``, and for "auto" whether the link delays or is ``networked``); None otherwise."""
    if not scene.link.guarded(networked) or scene.slave is None:
        return None
    t = scene.tool
    params = tdpa_params(scene.link, scene.dt_s, t.mass_kg, _inertia(t.inertia_kgm2), enabled=True)
    return MasterGuard(params), SlaveGuard(params, registration,
                                           model_offset=scene.mapping.feedback_local_damping)


def _inertia(v) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    return a.reshape(3, 3) if a.size == 9 else a


class _ViewHook(Hook):
    """Hands each tick to a view (which throttles itself)."""

    def __init__(self, view):
        self.view = view

    def after_tick(self, i, t_s, loop) -> None:
        self.view.publish_tick(t_s, loop)


def run_scene(scene: Scene, progress=None, realtime: bool = False, operator=None, view=None, hooks=(),
              status_line=None, simulated_link: bool | None = None) -> RunResult:
    """Run a scene. ``operator`` replaces the scene's (e.g. a keyboard; one with ``stats()`` adds
    them to the summary as "operator"); ``view`` gets every tick and throttles itself;
    ``progress(i, n)`` is called every 1000 ticks; ``hooks`` more :class:`~teleop.tick.loop.Hook` s,
    after the scene's own; ``status_line`` a :class:`~teleop.app.statusline.StatusLine` (it watches the
    session); ``simulated_link`` forces the link (:func:`make_link`: True, the simulated channel of
    the scene's [link] table even when it asks for nothing, as the fault campaign's link loss
    needs). The scene's ``heartbeat_ms`` watches a link that can lose messages
    (:mod:`teleop.tick.heartbeat`)."""
    n = tick_count(scene.duration_s, scene.dt_s)  # refuses a run past MAX_TICKS before building anything
    rng = np.random.default_rng(scene.seed)
    tool = build_tool(scene)
    spec_M = master_fixture_spec(scene)
    if operator is None:
        operator = make_operator(scene.operator, spec_M, scene.effects, rng)
    master_metrics = MasterMetrics(make_metrics(spec_M, n, tool.body.mass_kg, tool.fixture.constraints))
    energy_drift = EnergyDrift(tool)
    extra_hooks, hooks = hooks, [master_metrics, energy_drift]
    reg = build_registration(scene)
    constraints_P = build_fixture(scene.fixture).constraints  # the fixture where the patient is
    slave = make_slave(scene, reg, constraints_P)
    feedback = tremor = slave_metrics = None
    if slave is not None:
        slave.reset(*tool.pose())
        feedback = FeedbackPath(reg, scene.mapping.feedback_cutoff_hz, scene.dt_s,
                            scene.mapping.feedback_local_damping)
        rcm = [c for c in constraints_P if isinstance(c, RemoteCenter)]
        slave_metrics = SlaveMetrics(scene.fixture, n, slave.arm.nv, rcm, constraints_P)
        hooks.append(slave_metrics)
        if getattr(operator, "tremor_on", False) and isinstance(scene.fixture, FixtureSpec):
            tremor = TremorProbe(operator, n, reg.scale, reg.X_PM_R, scene.fixture.plane_normal)
            hooks.append(tremor)
    if view is not None:
        hooks.append(_ViewHook(view))
    hooks += list(extra_hooks) + ([status_line] if status_line is not None else [])
    master = make_master(scene, tool, rng)
    link = make_link(scene, rng, simulated_link) if slave is not None else None
    guard = make_guard(scene, reg, n)
    session = Session(tool, master, operator, scene.dt_s, scene.duration_s, slave=slave, feedback=feedback,
                      hooks=hooks, realtime=realtime, progress=progress, link=link, guard=guard,
                      heartbeat_s=scene.link.heartbeat_ms * 1e-3)
    if status_line is not None:
        status_line.watch(session)
    result = session.run()
    metrics = {**master_metrics.result(), **energy_drift.result()}
    if guard is not None and "passivity" in result.summary:  # the drift at the slave's scale (m)
        metrics["link_drift_max_m"] = result.summary["passivity"]["drift_max_M_m"] / reg.scale
        metrics["link_drift_final_m"] = result.summary["passivity"]["drift_final_M_m"] / reg.scale
    result.log.update(master_metrics.log())
    if slave_metrics is not None:
        metrics.update(slave_metrics.result())
        result.log.update(slave_metrics.log())
    if tremor is not None:
        metrics.update(tremor.result(scene.dt_s))
    s = result.summary
    # Ctrl-C may land between two hooks: every series keeps the ticks all of them recorded
    steps = min([s["steps"]] + [len(v) for v in result.log.values()])
    s["steps"] = steps
    result.log = {k: v[:steps] for k, v in result.log.items()}
    builtin = isinstance(scene.fixture, FixtureSpec)
    exempt = (("blade_tilt_max_rad",) if builtin and scene.fixture.trocar_m is not None else ()) \
        + (("sideslip_max_m_per_s",) if builtin and not scene.fixture.knife_edge else ())  # what the fixture frees
    lost_m = s.get("heartbeat", {}).get("master", {}).get("lost_ticks", 0)
    s["status"], s["status_reason"] = verdict(s["master_status"], steps, s.get("slave_statuses"), metrics, s["nan"],
                                              exempt, lost_m)
    result.summary = {"scenario": scene.name, **s, "integrator": scene.integrator, "master": scene.master,
                      "seed": scene.seed, "effects": list(scene.effects), "metrics": metrics}
    if callable(getattr(operator, "stats", None)):
        result.summary["operator"] = operator.stats()
    return result
