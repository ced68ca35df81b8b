"""The tables of a scene file as frozen dataclasses: each field's type, unit and rules in one place.

The scene tree (``teleop.scenario.schema.Scene``) holds these and the runtime configs that are
nodes of it too (``CobotConfig`` with ``FaultSettings``, ``SlaveConfig``, ``TissueBlock`` with
``CuttingModel``). One validator (``teleop.util.typed``) checks them all.

Every number with a physical meaning has a plausible range, one a real surgical teleoperator can
meet (the constants below; each field's doc states its range and unit, and ``teleop schema``
shows them as minimum / maximum). A value outside it is refused when the table is built, before
anything runs, so an impossible scene (a 1e300 kg tool, a start pose 1e300 m away) never runs.
Rules that tie two keys together (a fixture's depth vs the tissue's thickness, a band vs the
Nyquist rate of the tick) are checked on the whole scene (:mod:`teleop.scenario.plausibility`).
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

# -- plausible ranges (SI units) ------------------------------------------------------------------
#: every position (a point, an origin, an anchor, a waypoint) within this of the origin, per
#: coordinate, m
MAX_POSITION_M = 10.0
#: a point given in the tool's own frame (a blade tip, a tool mount), per coordinate, m
MAX_TOOL_POINT_M = 1.0
#: a hand-held tool's mass, kg (1 g .. 10 kg)
MASS_KG = (1e-3, 10.0)
#: a principal moment of inertia, kg*m^2
INERTIA_KGM2 = (1e-9, 1.0)
#: the tool's radius of gyration sqrt(J / m) about any principal axis, m: a body inside a ball of
#: radius R about its centre of mass has every J <= m R^2
MAX_GYRATION_M = 1.0
#: the control period, s (100 kHz .. 10 Hz)
DT_S = (1e-5, 0.1)
#: a time in a script (a phase, a waypoint, a repeat period), s (11.6 days)
MAX_TIME_S = 1e6
#: an initial generalized coordinate: m (position), rad (Euler angle)
MAX_Q0 = 10.0
#: an initial generalized velocity: m/s, rad/s (a hand moves a tool at < 2 m/s, turns it at
#: < 10 rad/s)
MAX_QD0 = 10.0
#: how fast a virtual hand's path may move between two waypoints, m/s
MAX_HAND_SPEED_M_S = 5.0
#: a scripted push per component, N, and torque, N*m
MAX_FORCE_N = 1000.0
MAX_TORQUE_NM = 100.0
#: a linear stiffness, N/m, and an angular one, N*m/rad
MAX_STIFFNESS_N_PER_M = 1e7
MAX_STIFFNESS_NM_PER_RAD = 1e4
#: a human hand's grip stiffness on the handle, N/m (measured: 1e2 .. 1e4)
MAX_HAND_STIFFNESS_N_PER_M = 1e5
#: a linear damping, N*s/m, and an angular one, N*m*s/rad
MAX_DAMPING_NS_PER_M = 1e4
MAX_DAMPING_NMS_PER_RAD = 1e3
#: gravity per component, m/s^2 (10 g)
MAX_GRAVITY_M_S2 = 100.0
#: a disk's or sphere's radius, m (0.1 mm .. 1 m)
RADIUS_M = (1e-4, 1.0)
#: a blade's depth below its plane, m
MAX_DEPTH_M = 0.1
#: physiological tremor lies in 3..30 Hz; no hand moves above this, Hz
MAX_TREMOR_HZ = 100.0
#: a low-pass cut-off, Hz: the Nyquist rate of the shortest tick (1 / (2 * DT_S[0]))
MAX_CUTOFF_HZ = 1.0 / (2.0 * DT_S[0])
#: a master : slave motion scale and a feedback gain
SCALE = (0.01, 100.0)
MAX_FEEDBACK_GAIN = 100.0
#: an angle given as roll / pitch / yaw, rad (one turn)
MAX_ANGLE_RAD = 2.0 * math.pi


def _nonzero(v) -> str | None:
    size = math.hypot(*v)  # no overflow: a 1e200 component is a direction, not inf
    return None if 1e-6 < size < math.inf else f"must be non-zero and finite as a direction (got {list(v)})"


def principal_inertias(v) -> tuple[float, ...] | None:
    """The principal moments (kg*m^2, ascending) of 3 principal values or a 3x3 matrix given
    row by row; None when ``v`` is neither or a matrix is not symmetric."""
    if len(v) == 3:
        return tuple(sorted(float(x) for x in v))
    if len(v) != 9:
        return None
    M = np.array(v, dtype=float).reshape(3, 3)
    if not np.allclose(M, M.T, rtol=0.0, atol=1e-9 * float(np.abs(M).max())):
        return None
    return tuple(float(x) for x in np.linalg.eigvalsh((M + M.T) / 2.0))


def inertia_problem(v) -> str | None:
    """Why ``v`` (3 principal inertias or a 3x3 matrix, kg*m^2) is no rigid body's inertia, or
    None: each principal moment positive and in INERTIA_KGM2, and the triangle inequality
    J1 + J2 >= J3 for every permutation (J3 = the largest; the equality is a flat lamina)."""
    if len(v) not in (3, 9):
        return f"give 3 positive principal inertias or a 3x3 matrix (9 numbers) (got {list(v)})"
    J = principal_inertias(v)
    if J is None:
        return f"a 3x3 inertia matrix must be symmetric (got {list(v)})"
    if not J[0] > 0:
        what = "3 positive principal inertias" if len(v) == 3 else "a positive definite 3x3 matrix"
        return f"give {what}: no mass has a zero or negative moment of inertia (got {list(v)})"
    lo, hi = INERTIA_KGM2
    for j in J:
        if not lo <= j <= hi:
            return (f"principal inertia {j:g} kg*m^2 is outside [{lo:g}, {hi:g}] kg*m^2, the range of a "
                    f"hand-held tool (got {list(v)})")
    if J[2] > (J[0] + J[1]) * (1.0 + 1e-9):
        return (f"principal inertias {J[0]:g}, {J[1]:g}, {J[2]:g} kg*m^2 break the triangle inequality: "
                f"{J[2]:g} > {J[0]:g} + {J[1]:g}, and no rigid body has them (J1 + J2 >= J3 for every order)")
    return None


def _position(what: str, limit: float = MAX_POSITION_M) -> dict:
    """The rules of a point: each coordinate within +-limit m."""
    return dict(ge=-limit, le=limit, why=f"each coordinate must be within +-{limit:g} m",
                doc=f"{what}, m, each coordinate within +-{limit:g}")


def _damping(limit: float, unit: str) -> dict:
    return dict(ge=0.0, le=limit, why=f"must be >= 0 and at most {limit:g} {unit}", doc=f"{unit}, in [0, {limit:g}]")


def _band(b) -> str | None:
    return None if len(b) == 2 and 0 < b[0] < b[1] else f"expected [low, high] Hz with 0 < low < high (got {list(b)})"


@dataclass(frozen=True)
class ToolSpec(Checked):
    """The reference tool: mass (kg), inertia (kg*m^2: 3 principal or a 3x3 matrix row by row),
    initial generalized position and velocity (the fixture's chart: m, rad; m/s, rad/s).

    Plausible: mass 1 g .. 10 kg; principal inertias 1e-9 .. 1 kg*m^2 obeying the triangle
    inequality (J1 + J2 >= J3); a radius of gyration sqrt(J / m) of at most 1 m (checked with the
    mass on the whole scene); q0 within +-10 m / rad, qd0 within +-10 m/s / rad/s."""

    mass_kg: float = setting(ge=MASS_KG[0], le=MASS_KG[1],
                             why=f"mass must be positive and in [{MASS_KG[0]:g}, {MASS_KG[1]:g}] kg (a hand-held tool)",
                             doc=f"mass, kg, in [{MASS_KG[0]:g}, {MASS_KG[1]:g}]")
    inertia_kgm2: tuple[float, ...] = setting(
        le=INERTIA_KGM2[1], check=inertia_problem,
        why=f"an inertia must be at most {INERTIA_KGM2[1]:g} kg*m^2 (principal inertias in "
            f"[{INERTIA_KGM2[0]:g}, {INERTIA_KGM2[1]:g}] kg*m^2)",
        doc=f"3 principal inertias or a 3x3 matrix, kg*m^2: principal values in [{INERTIA_KGM2[0]:g}, "
            f"{INERTIA_KGM2[1]:g}] with J1 + J2 >= J3")
    q0: tuple[float, ...] = setting((0.0,) * 6, n=6, ge=-MAX_Q0, le=MAX_Q0,
                                    why=f"must be within +-{MAX_Q0:g} (m for a position, rad for an angle)",
                                    doc=f"initial generalized position (m, rad), each within +-{MAX_Q0:g}")
    qd0: tuple[float, ...] = setting((0.0,) * 6, n=6, ge=-MAX_QD0, le=MAX_QD0,
                                     why=f"must be within +-{MAX_QD0:g} (m/s for a speed, rad/s for a rate)",
                                     doc=f"initial generalized velocity (m/s, rad/s), each within +-{MAX_QD0:g}")


@dataclass(frozen=True)
class FixtureSpec(Checked):
    """``type`` from FIXTURES; the geometry in SI units (m, unit normals). A scene file may set only
    the keys its type reads (FIXTURE_KEYS)."""

    type: Literal["free", "rolling_disk", "sphere", "scalpel"] = setting(doc="fixture type")
    radius_m: float = setting(0.03, ge=RADIUS_M[0], le=RADIUS_M[1],
                              why=f"radius must be positive and in [{RADIUS_M[0]:g}, {RADIUS_M[1]:g}] m",
                              doc=f"disk or sphere radius, m, in [{RADIUS_M[0]:g}, {RADIUS_M[1]:g}]")
    center_m: Vec3 = setting((0.0, 0.0, 0.0), n=3, **_position("sphere centre"))
    plane_origin_m: Vec3 = setting((0.0, 0.0, 0.0), n=3, **_position("a point of the plane"))
    plane_normal: Vec3 = setting((0.0, 0.0, 1.0), n=3, check=_nonzero, doc="plane normal (normalized by the fixture)")
    depth_m: float = setting(0.005, ge=0.0, le=MAX_DEPTH_M, why=f"depth must be >= 0 and at most {MAX_DEPTH_M:g} m",
                             doc=f"blade depth below the plane, m, in [0, {MAX_DEPTH_M:g}] (and less than the "
                                 "tissue's thickness)")
    tip_m: Vec3 = setting((0.0, 0.0, 0.0), n=3, **_position("blade tip in the tool frame", MAX_TOOL_POINT_M))
    knife_edge: bool = setting(True, doc="the blade cannot slip sideways")
    trocar_m: Vec3 | None = setting(None, n=3, **_position("remote centre of motion (laparoscopic), outside the "
                                                           "tissue"))
    euler_sequence: str = setting("ZYX", check=lambda s: None if len(s) == 3 and set(s) <= set("XYZ") else
                                  f"expected three axes such as 'ZYX' (got {s!r})", doc="Euler chart of a free tool")

    def mapped(self, frame: FrameMap) -> FixtureSpec:
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

    def mapped(self, frame: FrameMap) -> CustomFixture:
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
    ramps of ``ramp_s`` at both ends. A hand pushes at most 1000 N and twists at most 100 N*m per
    component."""

    start_s: float = setting(ge=0.0, le=MAX_TIME_S, why=f"must be >= 0 and at most {MAX_TIME_S:g} s",
                             doc=f"s, in [0, {MAX_TIME_S:g}]")
    end_s: float = setting(le=MAX_TIME_S, why=f"must be at most {MAX_TIME_S:g} s", doc="s, after start_s")
    force_N: Vec3 = setting((0.0, 0.0, 0.0), n=3, ge=-MAX_FORCE_N, le=MAX_FORCE_N,
                            why=f"a hand pushes at most {MAX_FORCE_N:g} N: each component within +-{MAX_FORCE_N:g} N",
                            doc=f"N, each within +-{MAX_FORCE_N:g}")
    torque_Nm: Vec3 = setting((0.0, 0.0, 0.0), n=3, ge=-MAX_TORQUE_NM, le=MAX_TORQUE_NM,
                              why=f"a hand twists at most {MAX_TORQUE_NM:g} N*m: each component within "
                                  f"+-{MAX_TORQUE_NM:g} N*m", doc=f"N*m, each within +-{MAX_TORQUE_NM:g}")
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
    ``tremor_band_hz`` when the scene switches the "tremor" effect on.

    Plausible: waypoint times in [0, 1e6] s, points within +-10 m, the path no faster than 5 m/s;
    a grip of at most 1e5 N/m; the tremor band below 100 Hz and below the tick's Nyquist rate
    1 / (2 dt_s) (checked on the whole scene)."""

    waypoints: tuple[tuple[float, float, float, float], ...] = setting(
        doc=f"[t_s, x_m, y_m, z_m] each: t in [0, {MAX_TIME_S:g}] s increasing, x y z within +-{MAX_POSITION_M:g} m, "
            f"at most {MAX_HAND_SPEED_M_S:g} m/s between waypoints")
    stiffness_N_per_m: float = setting(200.0, gt=0.0, le=MAX_HAND_STIFFNESS_N_PER_M,
                                       why=f"must be positive and at most {MAX_HAND_STIFFNESS_N_PER_M:g} N/m "
                                           "(a hand's grip)",
                                       doc=f"N/m, in (0, {MAX_HAND_STIFFNESS_N_PER_M:g}]")
    damping_Ns_per_m: float = setting(5.0, **_damping(MAX_DAMPING_NS_PER_M, "N*s/m"))
    angular_damping_Nms_per_rad: float = setting(0.0, **_damping(MAX_DAMPING_NMS_PER_RAD, "N*m*s/rad"))
    tremor_amplitude_m: float = setting(0.0, ge=0.0, le=0.01, why="must be in [0, 0.01] m", doc="RMS per axis, m")
    tremor_band_hz: tuple[float, ...] = setting((8.0, 12.0), le=MAX_TREMOR_HZ, check=_band,
                                                why=f"a hand's tremor lies below {MAX_TREMOR_HZ:g} Hz",
                                                doc=f"[low, high], Hz, 0 < low < high <= {MAX_TREMOR_HZ:g} and "
                                                    "high below the Nyquist rate 1 / (2 dt_s)")

    def __post_init__(self):
        super().__post_init__()
        if len(self.waypoints) < 2:
            raise FieldError("waypoints", "give at least two waypoints")
        for i, (t, *p) in enumerate(self.waypoints):
            if not 0.0 <= t <= MAX_TIME_S:
                raise FieldError(f"waypoints[{i}]", f"a waypoint's time must be in [0, {MAX_TIME_S:g}] s (got {t!r})")
            if not all(abs(x) <= MAX_POSITION_M for x in p):
                raise FieldError(f"waypoints[{i}]", f"a waypoint must be within +-{MAX_POSITION_M:g} m of the "
                                                    f"origin per coordinate (got {p})")
        for i in range(1, len(self.waypoints)):
            (t0, *p0), (t1, *p1) = self.waypoints[i - 1], self.waypoints[i]
            if not t1 > t0:
                raise FieldError(f"waypoints[{i}]", "waypoint times must increase")
            speed = math.dist(p0, p1) / (t1 - t0)
            if speed > MAX_HAND_SPEED_M_S:
                raise FieldError(f"waypoints[{i}]", f"the hand would move at {speed:.3g} m/s from waypoint {i - 1}; "
                                                    f"a hand moves a tool at most {MAX_HAND_SPEED_M_S:g} m/s")


@dataclass(frozen=True)
class OperatorSpec(Checked):
    """Scripted wrench phases (repeating every ``repeat_s`` if given) and/or a virtual hand."""

    phases: tuple[Phase, ...] = setting((), doc="wrench phases")
    repeat_s: float | None = setting(None, gt=0.0, le=MAX_TIME_S, why=f"must be positive and at most {MAX_TIME_S:g} s",
                                     doc=f"period of the script, s, in (0, {MAX_TIME_S:g}]")
    hand: HandSpec | None = setting(None, doc="a virtual hand on the handle")


@dataclass(frozen=True)
class SpringSpec(Checked):
    """A spring from ``anchor_m`` (world, m) to the tool: k_N_per_m (N/m, at most 1e7),
    k_Nm_per_rad (N*m/rad, at most 1e4)."""

    anchor_m: Vec3 = setting(n=3, **_position("anchor"))
    k_N_per_m: float = setting(ge=0.0, le=MAX_STIFFNESS_N_PER_M, why=f"must be in [0, {MAX_STIFFNESS_N_PER_M:g}] N/m",
                               doc=f"N/m, in [0, {MAX_STIFFNESS_N_PER_M:g}]")
    k_Nm_per_rad: float = setting(0.0, ge=0.0, le=MAX_STIFFNESS_NM_PER_RAD,
                                  why=f"must be in [0, {MAX_STIFFNESS_NM_PER_RAD:g}] N*m/rad",
                                  doc=f"N*m/rad, in [0, {MAX_STIFFNESS_NM_PER_RAD:g}]")


@dataclass(frozen=True)
class DampingSpec(Checked):
    """Viscous damping of the reference tool (effect "damping")."""

    linear_Ns_per_m: float = setting(0.0, **_damping(MAX_DAMPING_NS_PER_M, "N*s/m"))
    angular_Nms_per_rad: float = setting(0.0, **_damping(MAX_DAMPING_NMS_PER_RAD, "N*m*s/rad"))


@dataclass(frozen=True)
class GravitySpec(Checked):
    """Gravity on the reference tool (effect "gravity")."""

    g_m_s2: Vec3 = setting(n=3, ge=-MAX_GRAVITY_M_S2, le=MAX_GRAVITY_M_S2,
                           why=f"each component must be within +-{MAX_GRAVITY_M_S2:g} m/s^2 (10 g)",
                           doc=f"m/s^2, world, each within +-{MAX_GRAVITY_M_S2:g}")


@dataclass(frozen=True)
class MappingSpec(Checked):
    """Master-to-patient registration X_PM (position m, roll-pitch-yaw rad), motion scale
    (master : slave), feedback gains, and the force feedback's low-pass cut-off (Hz, 0: off)."""

    position_m: Vec3 = setting((0.0, 0.0, 0.0), n=3, **_position("p_PM"))
    rpy_rad: Vec3 = setting((0.0, 0.0, 0.0), n=3, ge=-MAX_ANGLE_RAD, le=MAX_ANGLE_RAD,
                            why=f"each angle must be within one turn, +-{MAX_ANGLE_RAD:.4g} rad",
                            doc=f"R_PM as roll, pitch, yaw, rad, each within +-{MAX_ANGLE_RAD:.4g}")
    scale: float = setting(1.0, ge=SCALE[0], le=SCALE[1],
                           why=f"expected a value > 0: a motion scale in [{SCALE[0]:g}, {SCALE[1]:g}]",
                           doc=f"motion scale master : slave, in [{SCALE[0]:g}, {SCALE[1]:g}]")
    force_scale: float = setting(1.0, gt=0.0, le=MAX_FEEDBACK_GAIN,
                                 doc=f"force feedback gain, in (0, {MAX_FEEDBACK_GAIN:g}]")
    torque_scale: float | None = setting(None, gt=0.0, le=MAX_FEEDBACK_GAIN * SCALE[1],
                                         doc="torque feedback gain (default force_scale * scale), in "
                                             f"(0, {MAX_FEEDBACK_GAIN * SCALE[1]:g}]")
    feedback_cutoff_hz: float = setting(20.0, ge=0.0, le=MAX_CUTOFF_HZ,
                                        doc=f"force feedback low-pass cut-off, Hz (0: off); below the Nyquist rate "
                                            f"1 / (2 dt_s) with a slave, at most {MAX_CUTOFF_HZ:g}")
    feedback_local_damping: bool = setting(True, doc="render the contact's damping at the master, implicitly and "
                                                     "without the link's delay (teleop.tick.feedback); false: the "
                                                     "wrench alone")
    feedback_contact_plane: bool = setting(True, doc="the slave estimates the surface it touches (a plane's normal "
                                                     "and stiffness, teleop.contact.estimate) and the master renders "
                                                     "its stiffness where it is felt; false: not estimated, not "
                                                     "rendered (needs feedback_local_damping)")

    def registration(self) -> Registration:
        return Registration(np.array(self.position_m), rpy_matrix(*self.rpy_rad), self.scale, self.force_scale,
                            self.torque_scale)


@dataclass(frozen=True)
class ViewerSpec(Checked):
    """What the Meshcat view draws beyond the scene's geometry."""

    tissue_size_m: tuple[float, ...] = setting((0.12, 0.08), n=2, gt=0.0, le=MAX_POSITION_M,
                                               doc=f"drawn tissue block, m, each in (0, {MAX_POSITION_M:g}]")
    tool_radius_m: float | None = setting(None, gt=0.0, le=RADIUS_M[1],
                                          why=f"must be positive and at most {RADIUS_M[1]:g} m",
                                          doc="drawn disk radius, m (default: the fixture's; a fifth of a sphere's), "
                                              f"in (0, {RADIUS_M[1]:g}]")


@dataclass(frozen=True)
class LinkSpec(Checked):
    """The master-slave link: a simulated channel in lockstep simulated time
    (:class:`teleop.link.channel.SimulatedChannel`) and the passivity guard
    (:mod:`teleop.control.passivity`). All defaults: the in-process lockstep link, at no cost."""

    round_trip_ms: float = setting(0.0, ge=0.0, le=10_000.0, doc="constant round-trip delay, ms (half each way)")
    jitter_ms: float = setting(0.0, ge=0.0, le=10_000.0, doc="mean of the exponential extra one-way delay, ms")
    loss: float = setting(0.0, ge=0.0, lt=1.0, doc="fraction of messages lost (good state), in [0, 1)")
    burst_enter: float = setting(0.0, ge=0.0, le=1.0,
                                 doc="Gilbert-Elliott good->bad probability per message (0: no bursts)")
    burst_exit: float = setting(0.5, gt=0.0, le=1.0, doc="bad->good probability per message (mean burst 1/burst_exit)")
    burst_loss: float = setting(1.0, ge=0.0, le=1.0, doc="loss probability in the bad state")
    bandwidth_kBps: float = setting(0.0, ge=0.0, doc="wire rate each way, kB/s (0: no limit)")
    passivity: Literal["auto", "off", "tdpa"] = setting(
        "auto", doc="passivity guard: auto (TDPA on a link with delay, jitter, loss or a bandwidth limit, and over "
                    "a network; off on the in-process link), off, or tdpa (time-domain passivity)")
    alpha_max: float = setting(0.5, gt=0.0, le=1.0,
                               doc="master damping cap as a fraction of what the tool's explicit step takes (mass/dt)")
    dv_max_m_s: float = setting(0.5, gt=0.0, le=MAX_QD0,
                                doc=f"slave velocity correction cap, m/s (rad/s on rotation axes), in (0, {MAX_QD0:g}]")
    drift_gain: float = setting(2.0, ge=0.0, le=1e3, doc="position drift compensation rate, 1/s (0: off), at most 1e3")
    guard_slows_motion: bool = setting(True, doc="the guard's master port also slows the rendered motion so that "
                                                 "its observed energy never goes below zero (passive by "
                                                 "construction; see docs/design/link.md)")
    model_mediated: bool = setting(True, doc="the master renders the slave's estimated contact plane as a wall of "
                                              "its own, updated passively, and the slave presses no harder than "
                                              "that wall (needs mapping.feedback_contact_plane; not where the "
                                              "tissue cuts, whose drag is rendered by its damping; see "
                                              "docs/design/link.md)")
    probe_force_N: float = setting(0.5, ge=0.0, le=1e3,
                                   doc="model-mediated: the force the slave may press on a surface the master has "
                                       "not felt yet, N at the slave, in [0, 1000]")
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
