"""One assembly for every run: each side of the teleoperator built from a scene, with the hooks
that record it, so that one process (:func:`teleop.app.runtime.run_scene`), two processes
(:mod:`teleop.app.netrun`), the keyboard, the benches and the studies all run the same two
objects. Only what the scene names is built: no slave, tissue, tremor probe or device effect it
does not call for.

    master = build_master(scene, n, rng)            # MasterSide + its recorder and metrics
    slave = build_slave(scene, n)                   # SlaveSide + its metrics (None: no [slave])
    loop = BilateralLoop(master.side, slave.side, make_link(scene, rng))
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from teleop.app.metrics import EnergyDrift, MasterMetrics, SlaveMetrics, make_metrics, tissue_surface
from teleop.app.recorders import MasterRecorder, SlaveRecorder
from teleop.contact import SurfaceTissue, TissueBlock
from teleop.contact.cutting import CuttingModel
from teleop.dynamics.constraints import RemoteCenter
from teleop.link import ChannelSpec, LockstepLink, SimulatedChannel
from teleop.master import CobotMaster, IdealMaster
from teleop.scenario.build import build_fixture, build_registration, build_tool, master_fixture_spec
from teleop.scenario.operators import make_operator
from teleop.scenario.schema import FixtureSpec, Scene
from teleop.slave import SlaveArm
from teleop.tick.feedback import FeedbackPath
from teleop.tick.guard import MasterGuard, SlaveGuard, tdpa_params
from teleop.tick.master_side import MasterSide
from teleop.tick.plausible import CommandLimits
from teleop.tick.slave_side import SlaveSide
from teleop.util.errors import ConfigError, SceneError


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


def make_slave(scene: Scene, registration, constraints_P, guard: SlaveGuard | None = None, tool=None,
               scale: float = 1.0) -> SlaveSide | None:
    """The slave side of a scene with a [slave] table (None without one): the arm under the
    patient-frame fixture ``constraints_P``, the tissue if the scene calls for it, the guard's
    slave port ``guard`` and the scene's heartbeat. Its commands are held to the arm's reach and,
    given the master's reference ``tool``, to the tool's own speed limits (a real master's
    fastest, at the slave's ``scale``)."""
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
    return SlaveSide(arm, registration, tissue, scene.fixture.tip_m, guard=guard,
                     heartbeat_s=scene.link.heartbeat_ms * 1e-3, limits=command_limits(arm, tool, scale),
                     contact_plane=scene.mapping.feedback_contact_plane and scene.mapping.feedback_local_damping,
                     wall=model_mediated(scene), probe_N=scene.link.probe_force_N)


def model_mediated(scene: Scene) -> bool:
    """Whether the contact is rendered model-mediated (``[link] model_mediated``): a plane wall
    stands for a surface pressed on, so not where the tissue cuts (a cut's drag is no surface:
    its local model is the contact's damping, :mod:`teleop.tick.feedback`)."""
    return bool(scene.link.model_mediated) and "cutting" not in scene.effects


def command_limits(arm: SlaveArm, tool=None, scale: float = 1.0) -> CommandLimits:
    """What a real master can ask of ``arm``: its reach, and the reference ``tool``'s speed limits
    (a master never sends the tool faster: its step would have diverged) at the slave's ``scale``."""
    center, reach = arm_reach(arm)
    if tool is None:
        return CommandLimits(center, reach)
    return CommandLimits(center, reach, tool.max_speed_m_s / scale, tool.max_rate_rad_s)


def arm_reach(arm: SlaveArm) -> tuple[tuple[float, float, float], float]:
    """The sphere no target of the arm's tool can leave: its first joint's origin (m, in the arm's
    world, the patient frame) and the sum of the link offsets along the chain to the tool frame
    (m), an upper bound on the reach, 5 % over."""
    m = arm.model
    frame = m.frames[arm.frame_E]
    chain, j = [], frame.parentJoint
    while j > 0:
        chain.append(j)
        j = m.parents[j]
    chain.reverse()
    center = m.jointPlacements[chain[0]].translation
    reach = sum(float(np.linalg.norm(m.jointPlacements[k].translation)) for k in chain[1:])
    reach += float(np.linalg.norm(frame.placement.translation))
    return (float(center[0]), float(center[1]), float(center[2])), 1.05 * reach


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


@dataclass
class MasterBuild:
    """The master side of a scene and what records it: ``side``, its ``recorder`` (the capture:
    one row a tick, which the log, the metrics and a record read), ``metrics`` (the scene's
    fixture metrics), ``energy`` (the energy drift on conservative scenes); ``registration``
    master -> patient."""

    side: MasterSide
    recorder: MasterRecorder
    metrics: MasterMetrics
    energy: EnergyDrift
    registration: object

    def result(self) -> dict:
        """The master's metrics (the names of the scene's fixture, the energy drift)."""
        return {**self.metrics.result(), **self.energy.result()}

    def log(self, steps: int) -> dict:
        return {**self.recorder.log(steps), **{k: v[:steps] for k, v in self.metrics.log().items()}}


@dataclass
class SlaveBuild:
    """The slave side of a scene and what records it: ``side``, ``recorder`` (its capture),
    ``metrics``."""

    side: SlaveSide
    metrics: SlaveMetrics
    recorder: SlaveRecorder
    extra: list = field(default_factory=list)

    def result(self) -> dict:
        return self.metrics.result()

    def log(self, steps: int) -> dict:
        out = {k: v[:steps] for k, v in self.metrics.log().items()}
        out.update(self.recorder.log(steps))
        return out


def build_master(scene: Scene, n: int, rng: np.random.Generator, operator=None, networked: bool = False,
                 record=None) -> MasterBuild:
    """The master side of ``scene`` for a run of ``n`` ticks: its tool, master (ideal or cobot),
    operator (the scene's, or ``operator``), feedback path (with a [slave]), the guard's master port
    when the link is guarded (``networked``: the link crosses a network) and the scene's heartbeat,
    with its recorder and metrics as hooks, and, given a ``record`` (a
    :class:`~teleop.app.record.RecordWriter`), every tick on record. Draws from ``rng`` in a fixed
    order (operator, master)."""
    tool = build_tool(scene)
    spec_M = master_fixture_spec(scene)
    if operator is None:
        operator = make_operator(scene.operator, spec_M, scene.effects, rng)
    reg = build_registration(scene)
    feedback = None
    if scene.slave is not None:
        feedback = FeedbackPath(reg, scene.mapping.feedback_cutoff_hz, scene.dt_s, scene.mapping.feedback_local_damping,
                                tip_B=getattr(spec_M, "tip_m", (0.0, 0.0, 0.0)),
                                contact_plane=scene.mapping.feedback_contact_plane, wall=model_mediated(scene))
    guard = make_guard(scene, reg, n, networked)
    master = make_master(scene, tool, rng)
    energy = EnergyDrift(tool)
    side = MasterSide(tool, master, operator, scene.dt_s, feedback, guard[0] if guard else None,
                      scene.link.heartbeat_ms * 1e-3)
    recorder = MasterRecorder(side, n)
    metrics = MasterMetrics(make_metrics(spec_M, n, tool.body.mass_kg, tool.fixture.constraints), recorder)
    side.add_hooks(recorder, energy)
    if record is not None:
        from teleop.app.record import MasterRecorderMcap

        side.add_hooks(MasterRecorderMcap(record, side=side))
    return MasterBuild(side, recorder, metrics, energy, reg)


def build_slave(scene: Scene, n: int, networked: bool = False, record=None) -> SlaveBuild | None:
    """The slave side of ``scene`` (None without a [slave] table), placed where the scene's tool
    starts, with the guard's slave port when the link is guarded, and its metrics as hooks."""
    if scene.slave is None:
        return None
    reg = build_registration(scene)
    constraints_P = build_fixture(scene.fixture).constraints  # the fixture where the patient is
    guard = make_guard(scene, reg, n, networked)
    tool = build_tool(scene)
    side = make_slave(scene, reg, constraints_P, guard[1] if guard else None, tool, reg.scale)
    side.reset(*tool.pose())
    rcm = [c for c in constraints_P if isinstance(c, RemoteCenter)]
    recorder = SlaveRecorder(side, n)
    metrics = SlaveMetrics(scene.fixture, recorder, rcm, constraints_P)
    side.add_hooks(recorder)
    if record is not None:
        from teleop.app.record import SlaveRecorderMcap

        side.add_hooks(SlaveRecorderMcap(record, side=side))
    return SlaveBuild(side, metrics, recorder)


def exempt_metrics(scene: Scene) -> tuple[str, ...]:
    """The fixture metrics the scene's fixture does not hold (a trocar lets the blade tilt, a
    fixture without a knife edge lets it slip sideways): not judged by the verdict."""
    builtin = isinstance(scene.fixture, FixtureSpec)
    return (("blade_tilt_max_rad",) if builtin and scene.fixture.trocar_m is not None else ()) \
        + (("sideslip_max_m_per_s",) if builtin and not scene.fixture.knife_edge else ())
