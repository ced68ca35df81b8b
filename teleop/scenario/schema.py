"""The scene format: one TOML file per scene, loaded into frozen dataclasses and validated.

A scene declares its duration and control period, the effects it calls for (only those are built),
the tool and its fixture, the operator, the master, and the seed. See ``scenarios/*.toml``.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

from teleop.dynamics.integrators import INTEGRATORS
from teleop.errors import SceneError
from teleop.resources import scenario_dir
from teleop.scenario.reader import Table

#: Effects a scene may call for. The runtime assembles only the ones a scene names.
EFFECTS = (
    "coriolis",
    "damping",
    "gravity",
    "springs",
    "tissue",
    "cutting",
    "sensor_noise",
    "servo_lag",
    "can_faults",
    "tremor",
)
FIXTURES = ("free", "rolling_disk", "sphere", "scalpel")
FRAMES = ("world", "tool", "task")
MASTERS = ("ideal", "cobot")

SCENARIO_DIR = scenario_dir()


def _pos(x) -> bool:
    return x > 0


@dataclass(frozen=True)
class ToolSpec:
    mass_kg: float
    inertia_kgm2: tuple
    q0: tuple
    qd0: tuple


@dataclass(frozen=True)
class FixtureSpec:
    """``type`` from FIXTURES; the geometry in SI units (m, unit normals)."""

    type: str
    radius_m: float = 0.03
    center_m: tuple = (0.0, 0.0, 0.0)
    plane_origin_m: tuple = (0.0, 0.0, 0.0)
    plane_normal: tuple = (0.0, 0.0, 1.0)
    depth_m: float = 0.005
    tip_m: tuple = (0.0, 0.0, 0.0)
    knife_edge: bool = True
    trocar_m: tuple | None = None
    euler_sequence: str = "ZYX"


@dataclass(frozen=True)
class Phase:
    """A wrench (force N, torque N*m) in ``frame`` held from ``start_s`` to ``end_s`` with linear
    ramps of ``ramp_s`` at both ends."""

    start_s: float
    end_s: float
    force_N: tuple = (0.0, 0.0, 0.0)
    torque_Nm: tuple = (0.0, 0.0, 0.0)
    frame: str = "task"
    ramp_s: float = 0.0


@dataclass(frozen=True)
class HandSpec:
    """A virtual hand: a spring (N/m) and damper (N*s/m) pulling the handle along waypoints
    ((t s, x m, y m, z m), world), with tremor of RMS ``tremor_amplitude_m`` per axis in
    ``tremor_band_hz`` when the scene switches the "tremor" effect on."""

    waypoints: tuple
    stiffness_N_per_m: float = 200.0
    damping_Ns_per_m: float = 5.0
    angular_damping_Nms_per_rad: float = 0.0
    tremor_amplitude_m: float = 0.0
    tremor_band_hz: tuple = (8.0, 12.0)


@dataclass(frozen=True)
class OperatorSpec:
    """Scripted wrench phases (repeating every ``repeat_s`` if given) and/or a virtual hand."""

    phases: tuple = ()
    repeat_s: float | None = None
    hand: HandSpec | None = None


@dataclass(frozen=True)
class SpringSpec:
    anchor_m: tuple
    k_N_per_m: float
    k_Nm_per_rad: float = 0.0


@dataclass(frozen=True)
class Scene:
    name: str
    path: str
    description: str
    duration_s: float
    dt_s: float
    seed: int
    integrator: str
    effects: tuple
    tool: ToolSpec
    fixture: FixtureSpec
    operator: OperatorSpec
    damping_linear_Ns_per_m: float = 0.0
    damping_angular_Nms_per_rad: float = 0.0
    gravity_m_s2: tuple = (0.0, 0.0, -9.81)
    springs: tuple = ()
    master: str = "ideal"
    master_config: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)

    def with_overrides(self, **kw) -> "Scene":
        """A copy with command-line overrides (duration_s, seed, master, integrator, dt_s)."""
        kw = {k: v for k, v in kw.items() if v is not None}
        if "integrator" in kw and kw["integrator"] not in INTEGRATORS:
            raise SceneError(self.path, "integrator", f"unknown integrator; choose one of {sorted(INTEGRATORS)}")
        if "master" in kw and kw["master"] not in MASTERS:
            raise SceneError(self.path, "master", f"unknown master; choose one of {MASTERS}")
        for k in ("duration_s", "dt_s"):
            if k in kw and not kw[k] > 0:
                raise SceneError(self.path, k, "must be positive")
        return replace(self, **kw)


def find_scene(name_or_path: str) -> Path:
    """A scene file by path, or by name in ``scenarios/``."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.exists():
            raise SceneError(str(p), "<file>", "no such scene file")
        return p
    candidate = SCENARIO_DIR / f"{name_or_path}.toml"
    if not candidate.exists():
        known = ", ".join(list_scenes()) or "none"
        raise SceneError(name_or_path, "<name>", f"no such scene; known scenes: {known}")
    return candidate


def list_scenes() -> list[str]:
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))


def load_scene(name_or_path: str) -> Scene:
    """Load and validate a scene. Any problem is a SceneError naming the file, key and reason."""
    path = find_scene(name_or_path)
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise SceneError(str(path), "<syntax>", f"not valid TOML: {e}") from None
    return parse_scene(data, str(path))


def parse_scene(data: dict, path: str = "<scene>") -> Scene:
    root = Table(path, "", data)
    name = root.take("name", "str", Path(path).stem)
    description = root.take("description", "str", "")
    duration = root.take("duration_s", "float", check=_pos, why="must be positive")
    dt = root.take("dt_s", "float", 0.001, check=lambda x: 0 < x <= 0.1, why="must be in (0, 0.1] s")
    seed = root.take("seed", "int", 0, check=lambda x: x >= 0, why="must be non-negative")
    integrator = root.take(
        "integrator", "str", "parametric", check=lambda x: x in INTEGRATORS,
        why=f"unknown integrator; choose one of {sorted(INTEGRATORS)}",
    )
    effects = tuple(root.take("effects", "list", []))
    for e in effects:
        if e not in EFFECTS:
            raise root.error("effects", f"unknown effect {e!r}; known effects: {', '.join(EFFECTS)}")
    if len(set(effects)) != len(effects):
        raise root.error("effects", "an effect is listed twice")
    master = root.take("master", "str", "ideal", check=lambda x: x in MASTERS, why=f"choose one of {MASTERS}")

    tool = _tool(root.sub("tool"))
    fixture = _fixture(root.sub("fixture"))
    operator = _operator(root.sub("operator", None))
    scene = dict(
        name=name, path=path, description=description, duration_s=duration, dt_s=dt, seed=seed,
        integrator=integrator, effects=effects, tool=tool, fixture=fixture, operator=operator,
        master=master,
    )
    damping = root.sub("damping", None)
    if "damping" in effects:
        if damping is None:
            raise root.error("damping", "effect 'damping' is on but the [damping] table is missing")
        scene["damping_linear_Ns_per_m"] = damping.take("linear_Ns_per_m", "float", 0.0, lambda x: x >= 0, "must be >= 0")
        scene["damping_angular_Nms_per_rad"] = damping.take("angular_Nms_per_rad", "float", 0.0, lambda x: x >= 0, "must be >= 0")
        damping.done()
    elif damping is not None:
        raise root.error("damping", "a [damping] table is given but effect 'damping' is not on")
    gravity = root.sub("gravity", None)
    if gravity is not None:
        scene["gravity_m_s2"] = gravity.take("g_m_s2", "vec3")
        gravity.done()
    springs = root.take("springs", "list", [])
    if springs and "springs" not in effects:
        raise root.error("springs", "springs are given but effect 'springs' is not on")
    scene["springs"] = tuple(_spring(Table(path, f"springs[{i}]", s)) for i, s in enumerate(springs))
    scene["master_config"] = root.take("cobot", "table", {})
    extra = {}
    for k in ("slave", "tissue", "mapping", "viewer"):
        if root.has(k):
            extra[k] = root.take(k, "table")
    scene["extra"] = extra
    root.done()
    return Scene(**scene)


def _tool(t: Table) -> ToolSpec:
    mass = t.take("mass_kg", "float", check=_pos, why="mass must be positive")
    inertia = t.take("inertia_kgm2", "floats", check=lambda v: len(v) in (3, 9) and all(x > 0 for x in v[:: 4 if len(v) == 9 else 1]),
                     why="give 3 positive principal inertias or a 3x3 matrix (9 numbers)")
    q0 = t.take("q0", "vec6", (0.0,) * 6)
    qd0 = t.take("qd0", "vec6", (0.0,) * 6)
    t.done()
    return ToolSpec(mass, inertia, q0, qd0)


def _fixture(t: Table) -> FixtureSpec:
    ftype = t.take("type", "str", check=lambda x: x in FIXTURES, why=f"choose one of {FIXTURES}")
    kw: dict = {"type": ftype}
    if ftype in ("rolling_disk", "sphere"):
        kw["radius_m"] = t.take("radius_m", "float", check=_pos, why="radius must be positive")
    if ftype == "sphere":
        kw["center_m"] = t.take("center_m", "vec3", (0.0, 0.0, 0.0))
    if ftype in ("rolling_disk", "scalpel"):
        kw["plane_origin_m"] = t.take("plane_origin_m", "vec3", (0.0, 0.0, 0.0))
        kw["plane_normal"] = t.take("plane_normal", "vec3", (0.0, 0.0, 1.0), lambda v: sum(x * x for x in v) > 1e-12, "must be non-zero")
    if ftype == "scalpel":
        kw["depth_m"] = t.take("depth_m", "float", 0.005, lambda x: x >= 0, "depth must be >= 0")
        kw["tip_m"] = t.take("tip_m", "vec3", (0.0, 0.0, 0.0))
        kw["knife_edge"] = t.take("knife_edge", "bool", True)
        kw["trocar_m"] = t.take("trocar_m", "vec3", None)
    if ftype == "free":
        kw["euler_sequence"] = t.take("euler_sequence", "str", "ZYX")
    t.done()
    return FixtureSpec(**kw)


def _operator(t: Table | None) -> OperatorSpec:
    if t is None:
        return OperatorSpec()
    repeat = t.take("repeat_s", "float", None, check=_pos, why="must be positive")
    phases = []
    for i, ph in enumerate(t.take("phases", "list", [])):
        p = Table(t.path, f"{t.where}.phases[{i}]", ph)
        start = p.take("start_s", "float", check=lambda x: x >= 0, why="must be >= 0")
        end = p.take("end_s", "float", check=lambda x: x > start, why="must be after start_s")
        phases.append(Phase(
            start, end,
            p.take("force_N", "vec3", (0.0, 0.0, 0.0)),
            p.take("torque_Nm", "vec3", (0.0, 0.0, 0.0)),
            p.take("frame", "str", "task", lambda x: x in FRAMES, f"choose one of {FRAMES}"),
            p.take("ramp_s", "float", 0.0, lambda x: 0 <= x <= (end - start) / 2, "must be in [0, (end_s - start_s)/2]"),
        ))
        p.done()
    hand = _hand(t.sub("hand", None))
    t.done()
    return OperatorSpec(tuple(phases), repeat, hand)


def _hand(t: Table | None) -> HandSpec | None:
    if t is None:
        return None
    raw = t.take("waypoints", "list")
    pts = []
    for i, wp in enumerate(raw):
        if not (isinstance(wp, list) and len(wp) == 4 and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in wp)):
            raise t.error(f"waypoints[{i}]", "expected [t_s, x_m, y_m, z_m]")
        if pts and not wp[0] > pts[-1][0]:
            raise t.error(f"waypoints[{i}]", "waypoint times must increase")
        pts.append(tuple(float(x) for x in wp))
    if len(pts) < 2:
        raise t.error("waypoints", "give at least two waypoints")
    band = t.take("tremor_band_hz", "floats", (8.0, 12.0), lambda b: len(b) == 2 and 0 < b[0] < b[1], "expected [low, high] Hz with 0 < low < high")
    h = HandSpec(
        tuple(pts),
        t.take("stiffness_N_per_m", "float", 200.0, _pos, "must be positive"),
        t.take("damping_Ns_per_m", "float", 5.0, lambda x: x >= 0, "must be >= 0"),
        t.take("angular_damping_Nms_per_rad", "float", 0.0, lambda x: x >= 0, "must be >= 0"),
        t.take("tremor_amplitude_m", "float", 0.0, lambda x: 0 <= x <= 0.01, "must be in [0, 0.01] m"),
        band,
    )
    t.done()
    return h


def _spring(t: Table) -> SpringSpec:
    s = SpringSpec(
        t.take("anchor_m", "vec3"),
        t.take("k_N_per_m", "float", check=lambda x: x >= 0, why="must be >= 0"),
        t.take("k_Nm_per_rad", "float", 0.0, lambda x: x >= 0, "must be >= 0"),
    )
    t.done()
    return s
