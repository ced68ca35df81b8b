"""The tables of a scene file as frozen dataclasses: each field's type, unit and rules in one place.

The scene tree (``teleop.scenario.schema.Scene``) holds these and the runtime configs that are
nodes of it too (``CobotConfig`` with ``FaultSettings``, ``SlaveConfig``, ``TissueBlock`` with
``CuttingModel``). One validator (``teleop.util.typed``) checks them all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from teleop.control.mapping import Registration
from teleop.dynamics import fixtures
from teleop.dynamics.fixtures import Fixture
from teleop.dynamics.registry import FrameMap
from teleop.util.errors import FieldError
from teleop.util.typed import Checked, as_table, setting

FIXTURES = ("free", "rolling_disk", "sphere", "scalpel")
FRAMES = ("world", "tool", "task")
#: the fixture keys each fixture type reads (besides ``type``); any other key given is an error
FIXTURE_KEYS = {
    "free": ("euler_sequence",),
    "rolling_disk": ("radius_m", "plane_origin_m", "plane_normal"),
    "sphere": ("radius_m", "center_m"),
    "scalpel": ("plane_origin_m", "plane_normal", "depth_m", "tip_m", "knife_edge", "trocar_m"),
}

Vec3 = tuple[float, ...]


def _nonzero(v) -> str | None:
    return None if sum(x * x for x in v) > 1e-12 else "must be non-zero"


def _inertia(v) -> str | None:
    ok = len(v) in (3, 9) and all(x > 0 for x in v[:: 4 if len(v) == 9 else 1])
    return None if ok else f"give 3 positive principal inertias or a 3x3 matrix (9 numbers) (got {list(v)})"


def _band(b) -> str | None:
    return None if len(b) == 2 and 0 < b[0] < b[1] else f"expected [low, high] Hz with 0 < low < high (got {list(b)})"


@dataclass(frozen=True)
class ToolSpec(Checked):
    """The reference tool: mass (kg), inertia (kg*m^2: 3 principal or a 3x3 matrix row by row),
    initial generalized position and velocity (the fixture's chart: m, rad; m/s, rad/s)."""

    mass_kg: float = setting(gt=0.0, why="mass must be positive", doc="mass, kg")
    inertia_kgm2: tuple[float, ...] = setting(check=_inertia, doc="3 principal inertias or a 3x3 matrix, kg*m^2")
    q0: tuple[float, ...] = setting((0.0,) * 6, n=6, doc="initial generalized position (m, rad)")
    qd0: tuple[float, ...] = setting((0.0,) * 6, n=6, doc="initial generalized velocity (m/s, rad/s)")


@dataclass(frozen=True)
class FixtureSpec(Checked):
    """``type`` from FIXTURES; the geometry in SI units (m, unit normals). A scene file may set only
    the keys its type reads (FIXTURE_KEYS)."""

    type: Literal["free", "rolling_disk", "sphere", "scalpel"] = setting(doc="fixture type")
    radius_m: float = setting(0.03, gt=0.0, why="radius must be positive", doc="disk or sphere radius, m")
    center_m: Vec3 = setting((0.0, 0.0, 0.0), n=3, doc="sphere centre, m")
    plane_origin_m: Vec3 = setting((0.0, 0.0, 0.0), n=3, doc="a point of the plane, m")
    plane_normal: Vec3 = setting((0.0, 0.0, 1.0), n=3, check=_nonzero, doc="plane normal (normalized by the fixture)")
    depth_m: float = setting(0.005, ge=0.0, why="depth must be >= 0", doc="blade depth below the plane, m")
    tip_m: Vec3 = setting((0.0, 0.0, 0.0), n=3, doc="blade tip in the tool frame, m")
    knife_edge: bool = setting(True, doc="the blade cannot slip sideways")
    trocar_m: Vec3 | None = setting(None, n=3, doc="remote centre of motion (laparoscopic), m")
    euler_sequence: str = setting("ZYX", check=lambda s: None if len(s) == 3 and set(s) <= set("XYZ") else
                                  f"expected three axes such as 'ZYX' (got {s!r})", doc="Euler chart of a free tool")

    def mapped(self, frame: FrameMap) -> "FixtureSpec":
        """The same fixture with its geometry placed by ``frame`` (points mapped, normals rotated,
        lengths and the tool-frame tip scaled): the patient-frame spec as the master sees it."""
        mapped = dict(plane_origin_m=tuple(frame.point(self.plane_origin_m)),
                      plane_normal=tuple(frame.direction(self.plane_normal)),
                      center_m=tuple(frame.point(self.center_m)), radius_m=frame.length(self.radius_m),
                      depth_m=frame.length(self.depth_m), tip_m=tuple(frame.body_point(self.tip_m)))
        if self.trocar_m is not None:
            mapped["trocar_m"] = tuple(frame.point(self.trocar_m))
        return replace(self, **mapped)

    def build(self, frame: FrameMap | None = None) -> Fixture:
        """The fixture's constraints, placed by ``frame`` (None: where the spec says)."""
        spec = self if frame is None else self.mapped(frame)
        if spec.type == "rolling_disk":
            return fixtures.rolling_disk(spec.radius_m, spec.plane_origin_m, spec.plane_normal)
        if spec.type == "sphere":
            return fixtures.sphere(spec.center_m, spec.radius_m)
        if spec.type == "scalpel" and spec.trocar_m is not None:
            return fixtures.laparoscopic(spec.plane_origin_m, spec.plane_normal, spec.depth_m, spec.tip_m,
                                         spec.trocar_m, spec.knife_edge)
        if spec.type == "scalpel":
            return fixtures.scalpel(spec.plane_origin_m, spec.plane_normal, spec.depth_m, spec.tip_m, spec.knife_edge)
        return fixtures.free(spec.euler_sequence)


@dataclass(frozen=True)
class CustomFixture:
    """A [fixture] whose ``type`` names a user's fixture type (:mod:`teleop.dynamics.registry`):
    ``params`` the user's dataclass instance, validated from the rest of the table. Its
    ``build(frame)`` places the fixture; ``tip_m`` is the params' own when they have one (m)."""

    type: str
    params: object = field(compare=False)

    @property
    def tip_m(self) -> tuple:
        return tuple(getattr(self.params, "tip_m", (0.0, 0.0, 0.0)))

    def mapped(self, frame: FrameMap) -> "CustomFixture":
        return self  # a user's type places its own geometry, in build(frame)

    def build(self, frame: FrameMap | None = None) -> Fixture:
        fx = self.params.build(FrameMap.identity() if frame is None else frame)
        if not isinstance(fx, Fixture):
            raise FieldError("fixture", f"fixture type {self.type!r}: build(frame) returned "
                                        f"{type(fx).__name__}, expected a teleop Fixture")
        return fx

    @staticmethod
    def __json_schema__() -> dict:
        return {"type": "object", "properties": {"type": {"type": "string", "description":
                "a fixture type registered with teleop.dynamics.registry.register_fixture"}},
                "required": ["type"], "additionalProperties": True,
                "description": "a user's fixture type: its own keys, checked by its dataclass"}

    def __table__(self) -> dict:
        return {"type": self.type, **as_table(self.params)}


@dataclass(frozen=True)
class Phase(Checked):
    """A wrench (force N, torque N*m) in ``frame`` held from ``start_s`` to ``end_s`` with linear
    ramps of ``ramp_s`` at both ends."""

    start_s: float = setting(ge=0.0, why="must be >= 0", doc="s")
    end_s: float = setting(doc="s, after start_s")
    force_N: Vec3 = setting((0.0, 0.0, 0.0), n=3, doc="N")
    torque_Nm: Vec3 = setting((0.0, 0.0, 0.0), n=3, doc="N*m")
    frame: Literal["world", "tool", "task"] = setting("task", doc="axes of the wrench")
    ramp_s: float = setting(0.0, ge=0.0, why="must be in [0, (end_s - start_s)/2]", doc="s")

    def __post_init__(self):
        super().__post_init__()
        if not self.end_s > self.start_s:
            raise FieldError("end_s", f"must be after start_s (got {self.end_s!r})")
        if self.ramp_s > (self.end_s - self.start_s) / 2:
            raise FieldError("ramp_s", f"must be in [0, (end_s - start_s)/2] (got {self.ramp_s!r})")


@dataclass(frozen=True)
class HandSpec(Checked):
    """A virtual hand: a spring (N/m) and damper (N*s/m) pulling the handle along waypoints
    ((t s, x m, y m, z m), world), with tremor of RMS ``tremor_amplitude_m`` per axis in
    ``tremor_band_hz`` when the scene switches the "tremor" effect on."""

    waypoints: tuple[tuple[float, float, float, float], ...] = setting(doc="[t_s, x_m, y_m, z_m] each")
    stiffness_N_per_m: float = setting(200.0, gt=0.0, why="must be positive", doc="N/m")
    damping_Ns_per_m: float = setting(5.0, ge=0.0, why="must be >= 0", doc="N*s/m")
    angular_damping_Nms_per_rad: float = setting(0.0, ge=0.0, why="must be >= 0", doc="N*m*s/rad")
    tremor_amplitude_m: float = setting(0.0, ge=0.0, le=0.01, why="must be in [0, 0.01] m", doc="RMS per axis, m")
    tremor_band_hz: tuple[float, ...] = setting((8.0, 12.0), check=_band, doc="[low, high], Hz")

    def __post_init__(self):
        super().__post_init__()
        if len(self.waypoints) < 2:
            raise FieldError("waypoints", "give at least two waypoints")
        for i in range(1, len(self.waypoints)):
            if not self.waypoints[i][0] > self.waypoints[i - 1][0]:
                raise FieldError(f"waypoints[{i}]", "waypoint times must increase")


@dataclass(frozen=True)
class OperatorSpec(Checked):
    """Scripted wrench phases (repeating every ``repeat_s`` if given) and/or a virtual hand."""

    phases: tuple[Phase, ...] = setting((), doc="wrench phases")
    repeat_s: float | None = setting(None, gt=0.0, why="must be positive", doc="period of the script, s")
    hand: HandSpec | None = setting(None, doc="a virtual hand on the handle")


@dataclass(frozen=True)
class SpringSpec(Checked):
    """A spring from ``anchor_m`` (world, m) to the tool: k_N_per_m (N/m), k_Nm_per_rad (N*m/rad)."""

    anchor_m: Vec3 = setting(n=3, doc="m")
    k_N_per_m: float = setting(ge=0.0, why="must be >= 0", doc="N/m")
    k_Nm_per_rad: float = setting(0.0, ge=0.0, why="must be >= 0", doc="N*m/rad")


@dataclass(frozen=True)
class DampingSpec(Checked):
    """Viscous damping of the reference tool (effect "damping")."""

    linear_Ns_per_m: float = setting(0.0, ge=0.0, why="must be >= 0", doc="N*s/m")
    angular_Nms_per_rad: float = setting(0.0, ge=0.0, why="must be >= 0", doc="N*m*s/rad")


@dataclass(frozen=True)
class GravitySpec(Checked):
    """Gravity on the reference tool (effect "gravity")."""

    g_m_s2: Vec3 = setting(n=3, doc="m/s^2, world")


@dataclass(frozen=True)
class MappingSpec(Checked):
    """Master-to-patient registration X_PM (position m, roll-pitch-yaw rad), motion scale
    (master : slave), feedback gains, and the force feedback's low-pass cut-off (Hz, 0: off)."""

    position_m: Vec3 = setting((0.0, 0.0, 0.0), n=3, doc="p_PM, m")
    rpy_rad: Vec3 = setting((0.0, 0.0, 0.0), n=3, doc="R_PM as roll, pitch, yaw, rad")
    scale: float = setting(1.0, gt=0.0, doc="motion scale master : slave")
    force_scale: float = setting(1.0, gt=0.0, doc="force feedback gain")
    torque_scale: float | None = setting(None, gt=0.0, doc="torque feedback gain (default force_scale * scale)")
    feedback_cutoff_hz: float = setting(20.0, ge=0.0, doc="force feedback low-pass cut-off, Hz (0: off)")
    feedback_local_damping: bool = setting(True, doc="render the contact's damping at the master, implicitly and without "
                                           "the link's delay (teleop.tick.feedback); false: the wrench alone")

    def registration(self) -> Registration:
        return Registration(np.array(self.position_m), rpy_matrix(*self.rpy_rad), self.scale, self.force_scale,
                            self.torque_scale)


@dataclass(frozen=True)
class ViewerSpec(Checked):
    """What the Meshcat view draws beyond the scene's geometry."""

    tissue_size_m: tuple[float, ...] = setting((0.12, 0.08), n=2, gt=0.0, doc="drawn tissue block, m")
    tool_radius_m: float | None = setting(None, gt=0.0, why="must be positive",
                                          doc="drawn disk radius, m (default: the fixture's; a fifth of a sphere's)")


@dataclass(frozen=True)
class LinkSpec(Checked):
    """The master-slave link: a simulated channel in lockstep simulated time
    (:class:`teleop.link.channel.SimulatedChannel`) and the passivity guard
    (:mod:`teleop.control.passivity`). All defaults: the in-process lockstep link, at no cost."""

    round_trip_ms: float = setting(0.0, ge=0.0, le=10_000.0, doc="constant round-trip delay, ms (half each way)")
    jitter_ms: float = setting(0.0, ge=0.0, le=10_000.0, doc="mean of the exponential extra one-way delay, ms")
    loss: float = setting(0.0, ge=0.0, lt=1.0, doc="fraction of messages lost (good state), in [0, 1)")
    burst_enter: float = setting(0.0, ge=0.0, le=1.0, doc="Gilbert-Elliott good->bad probability per message (0: no bursts)")
    burst_exit: float = setting(0.5, gt=0.0, le=1.0, doc="bad->good probability per message (mean burst 1/burst_exit)")
    burst_loss: float = setting(1.0, ge=0.0, le=1.0, doc="loss probability in the bad state")
    bandwidth_kBps: float = setting(0.0, ge=0.0, doc="wire rate each way, kB/s (0: no limit)")
    passivity: Literal["auto", "off", "tdpa"] = setting(
        "auto", doc="passivity guard: auto (TDPA on a link with delay, jitter, loss or a bandwidth limit, and over "
                    "a network; off on the in-process link), off, or tdpa (time-domain passivity)")
    alpha_max: float = setting(0.5, gt=0.0, le=1.0,
                               doc="master damping cap as a fraction of what the tool's explicit step takes (mass/dt)")
    dv_max_m_s: float = setting(0.5, gt=0.0, doc="slave velocity correction cap, m/s (rad/s on rotation axes)")
    drift_gain: float = setting(2.0, ge=0.0, doc="position drift compensation rate, 1/s (0: off)")
    heartbeat_ms: float = setting(20.0, gt=0.0, le=10_000.0,
                                  doc="over Zenoh: a side that hears nothing for this long goes to its safe state, ms")

    @property
    def channel_named(self) -> bool:
        """True when the table names a channel effect (delay, jitter, loss, bursts, bandwidth)."""
        return (self.round_trip_ms > 0 or self.jitter_ms > 0 or self.loss > 0 or self.burst_enter > 0
                or self.bandwidth_kBps > 0)

    @property
    def simulated(self) -> bool:
        """True when the link does anything the in-process lockstep link does not."""
        return self.channel_named or self.passivity == "tdpa"

    def guarded(self, networked: bool = False) -> bool:
        """Whether the passivity guard runs: "tdpa" always, "off" never, "auto" on a channel that
        delays or loses messages and on a ``networked`` link (two processes over Zenoh), where even
        a tick of delay makes a stiff contact unstable (stiff_contact at a 1 ms round trip)."""
        return self.passivity == "tdpa" or (self.passivity == "auto" and (networked or self.channel_named))


def rpy_matrix(r: float, p: float, y: float) -> np.ndarray:
    """R = Rz(y) Ry(p) Rx(r) (Pinocchio's rpyToMatrix)."""
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])
