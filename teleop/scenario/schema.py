"""The scene format: one TOML file per scene, one typed tree of frozen dataclasses, one validator.

A scene declares its duration and control period, the effects it calls for (only those are built),
the tool and its fixture, the operator, the master (and the cobot's settings), the slave, the
mapping, the tissue, the viewer and the link, and the seed. Every table and key is checked on
every load whatever runs (``teleop.util.typed.validate``); errors name the file, the key and the
reason. See ``scenarios/*.toml`` and ``teleop schema`` for the format as a JSON Schema.
"""

from __future__ import annotations

import copy
import difflib
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import Literal

from teleop.contact.tissue import TissueBlock
from teleop.dynamics import surface_fixture  # noqa: F401 - registers the built-in 'surface_scalpel' type
from teleop.dynamics.integrators import INTEGRATORS
from teleop.dynamics.registry import FIXTURE_TYPES
from teleop.master.config import CobotConfig
from teleop.scenario.overrides import apply_settings, parse_setting
from teleop.scenario.plausibility import annotate_schema, cross_rules, pick_key, range_problems
from teleop.scenario.tables import (
    DT_S,
    FIXTURE_KEYS,
    FIXTURES,
    FRAMES,
    CustomFixture,
    DampingSpec,
    FixtureSpec,
    GravitySpec,
    HandSpec,
    LinkSpec,
    MappingSpec,
    OperatorSpec,
    Phase,
    SpringSpec,
    ToolSpec,
    ViewerSpec,
)
from teleop.slave.arm import SlaveConfig
from teleop.util.errors import ConfigError, FieldError, SceneError
from teleop.util.inputs import read_text
from teleop.util.resources import robot_dir, scenario_dir
from teleop.util.typed import Checked, as_table, json_schema, setting, validate

__all__ = [
    "EFFECTS", "FIXTURES", "FRAMES", "MASTERS", "DampingSpec", "FixtureSpec", "GravitySpec",
    "HandSpec", "LinkSpec", "MappingSpec", "OperatorSpec", "Phase", "Scene", "SpringSpec",
    "ToolSpec", "ViewerSpec", "find_scene", "list_scenes", "load_scene", "parse_scene",
    "scene_schema",
]

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
MASTERS = ("ideal", "cobot")
#: the largest scene file read, bytes
MAX_SCENE_BYTES = 1_000_000

SCENARIO_DIR = scenario_dir()


def _effects(effects) -> str | None:
    for e in effects:
        if e not in EFFECTS:
            return f"unknown effect {e!r}; known effects: {', '.join(EFFECTS)}"
    return "an effect is listed twice" if len(set(effects)) != len(effects) else None


@dataclass(frozen=True, kw_only=True)
class Scene(Checked):
    """A whole scene. ``path`` is the file it came from; the ``damping_*`` and ``gravity_m_s2``
    fields are derived from the [damping] and [gravity] tables (zero / -9.81 z when absent).
    ``overridden``: the dotted keys the last ``--set`` / :meth:`with_overrides` changed, in order
    (a rule on two keys names the one changed).

    Built, a scene is physically plausible: every table's ranges hold, and the rules on several
    keys and the nested configs' ranges of :mod:`teleop.scenario.plausibility` (the tool's
    radius of gyration, a cut that fits its tissue, a trocar outside the tissue, bands and
    cut-offs below the Nyquist rate 1 / (2 dt_s))."""

    name: str = setting("", doc="scene name (default: the file's stem)")
    path: str = setting("<scene>", internal=True)
    description: str = setting("", doc="one line shown by 'teleop list'")
    overridden: tuple[str, ...] = field(default=(), compare=False, repr=False, metadata={"internal": True})
    duration_s: float = setting(gt=0.0, why="must be positive",
                                doc="simulated time, s, > 0 (at most 2e6 ticks: teleop.app.session.MAX_TICKS, "
                                    "checked when a run is built)")
    dt_s: float = setting(0.001, ge=DT_S[0], le=DT_S[1],
                          why=f"must be in (0, {DT_S[1]:g}] s and at least {DT_S[0]:g} s (a 100 kHz .. 10 Hz tick)",
                          doc=f"control period, s, in [{DT_S[0]:g}, {DT_S[1]:g}]")
    seed: int = setting(0, ge=0, why="must be non-negative", doc="seed of the run's random generator")
    integrator: str = setting("energy", choices=tuple(sorted(INTEGRATORS)),
                              why="unknown integrator; choose one of", doc="the reference tool's integrator")
    effects: tuple[str, ...] = setting((), check=_effects, choices=EFFECTS, doc="effects to build")
    tool: ToolSpec = setting(doc="the reference tool")
    fixture: FixtureSpec | CustomFixture = setting(doc="the virtual fixture (patient frame when the scene has a "
                                                       "slave); a registered type's name gives a CustomFixture")
    operator: OperatorSpec = setting(factory=OperatorSpec, doc="scripted wrenches and/or a virtual hand")
    damping: DampingSpec | None = setting(None, doc="needs effect 'damping'")
    gravity: GravitySpec | None = setting(None, doc="needs effect 'gravity'")
    springs: tuple[SpringSpec, ...] = setting((), doc="needs effect 'springs'")
    master: Literal["ideal", "cobot"] = setting("ideal",
                                                doc="ideal: wrench straight to the tool; cobot: the CAN device")
    cobot: CobotConfig = setting(factory=CobotConfig, doc="the cobot master (checked whichever master runs)")
    slave: SlaveConfig | None = setting(None, doc="the slave arm; none: the master alone")
    mapping: MappingSpec = setting(factory=MappingSpec, doc="master-to-patient registration and feedback")
    tissue: TissueBlock | None = setting(None, doc="the tissue block (effect 'tissue'; defaults when absent)")
    viewer: ViewerSpec = setting(factory=ViewerSpec, doc="what the viewer draws")
    link: LinkSpec = setting(factory=LinkSpec, doc="the master-slave link: delay, loss, passivity guard")
    damping_linear_Ns_per_m: float = field(init=False, default=0.0)
    damping_angular_Nms_per_rad: float = field(init=False, default=0.0)
    gravity_m_s2: tuple = field(init=False, default=(0.0, 0.0, -9.81))

    def __post_init__(self):
        super().__post_init__()
        s = object.__setattr__
        if not self.name:
            s(self, "name", Path(self.path).stem)
        if self.damping is not None:
            s(self, "damping_linear_Ns_per_m", self.damping.linear_Ns_per_m)
            s(self, "damping_angular_Nms_per_rad", self.damping.angular_Nms_per_rad)
        if self.gravity is not None:
            s(self, "gravity_m_s2", self.gravity.g_m_s2)
        problem = range_problems(self)
        if problem is not None:
            raise FieldError(*problem)
        broken = next(cross_rules(self), None)  # the first rule broken
        if broken is not None:
            keys, reason = broken
            raise FieldError(pick_key(keys, self.overridden), reason)

    def with_overrides(self, sets=(), **kw) -> Scene:
        """A copy with settings changed and validated again like the file: ``sets`` a list of
        "dotted.key=TOML value" strings, ``kw`` top-level keys (duration_s, seed, master,
        integrator, dt_s; None leaves a key as it is)."""
        pairs = [(k, v) for k, v in kw.items() if v is not None]
        if not pairs and not sets:
            return self
        return parse_scene(as_table(self), self.path, sets=sets, pairs=pairs)


def scene_schema() -> dict:
    """The JSON Schema of a scene file (for editors: taplo, VS Code's Even Better TOML)."""
    return annotate_schema(json_schema(Scene, "teleop scene"))


def find_scene(name_or_path: str) -> Path:
    """A scene file by path, or by plain name (letters, digits, '_', '-') in ``scenarios/``."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.is_file():
            raise SceneError("", str(p), "no such scene file" if not p.exists() else "not a regular file")
        return p
    if not re.fullmatch(r"[A-Za-z0-9_-]{1,100}", name_or_path):
        raise SceneError("", repr(name_or_path),
                         "a scene name is letters, digits, '_' and '-' (or give a .toml path)")
    candidate = SCENARIO_DIR / f"{name_or_path}.toml"
    if not candidate.is_file():
        known = list_scenes()
        close = difflib.get_close_matches(name_or_path, known, n=1, cutoff=0.6)
        hint = (f"did you mean {close[0]!r}? ('teleop list' shows the known scenes)" if close
                else f"known scenes: {', '.join(known) or 'none'}")
        raise SceneError("", name_or_path, f"no such scene; {hint}")
    return candidate


def list_scenes() -> list[str]:
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))


def load_scene(name_or_path: str, sets=()) -> Scene:
    """Load and validate a scene (then ``sets``, "key=value" overrides). Any problem is a
    SceneError naming the file, the key and the reason. The file itself stays in its lane
    (:func:`check_lane`); ``sets`` come from the command line and may name any path."""
    path = find_scene(name_or_path)
    try:
        data = tomllib.loads(read_text(path, MAX_SCENE_BYTES, "scene file"))
    except tomllib.TOMLDecodeError as e:
        raise SceneError(str(path), "<syntax>", f"not valid TOML: {e}") from None
    except RecursionError:
        raise SceneError(str(path), "<syntax>", "tables or lists nested too deeply") from None
    except ConfigError as e:
        raise SceneError(str(path), "<file>", getattr(e, "reason", str(e))) from None
    check_lane(data, str(path))
    return parse_scene(data, str(path), sets=sets)


#: keys of a scene file that name a file to read: each must be inside the robot folder
URDF_KEYS = (("slave", "arm", "urdf"), ("slave", "tool", "urdf"))


def check_lane(data: dict, path: str) -> None:
    """A scene *file* reaches nothing outside its run: its URDF paths resolve inside the project's
    robot folder (relative paths are relative to it; they are rewritten to absolute paths),
    ``slave.arm.package_dirs`` too, and ``cobot.capture_path`` is a relative path without '..'
    (written inside the run's folder). Hardware interfaces are checked on the whole run
    (:func:`hardware_interface`)."""
    robots = robot_dir().resolve()

    def inside(key: str, value) -> str:
        if not isinstance(value, str):
            return value  # the validator names the type
        p = (robots / value).resolve()
        if not p.is_relative_to(robots):
            raise SceneError(path, key, f"a scene file reads files only inside the robot folder {robots} "
                                        f"(got {value!r}); give other paths on the command line (--set {key}=PATH)")
        return str(p)

    for keys in URDF_KEYS:
        node = data
        for k in keys[:-1]:
            node = node.get(k) if isinstance(node, dict) else None
        if isinstance(node, dict) and keys[-1] in node:
            node[keys[-1]] = inside(".".join(keys), node[keys[-1]])
    arm = data.get("slave", {}).get("arm") if isinstance(data.get("slave"), dict) else None
    if isinstance(arm, dict) and isinstance(arm.get("package_dirs"), list):
        arm["package_dirs"] = [inside(f"slave.arm.package_dirs[{i}]", d) for i, d in enumerate(arm["package_dirs"])]
    cobot = data.get("cobot")
    cap = cobot.get("capture_path") if isinstance(cobot, dict) else None
    if isinstance(cap, str):
        p = PurePath(cap)
        if p.is_absolute() or ".." in p.parts or not p.parts:
            raise SceneError(path, "cobot.capture_path", "a scene file writes only inside its run's folder: give a "
                                                         f"relative path without '..' (got {cap!r})")


def hardware_interface(scene: Scene) -> str | None:
    """The CAN interface the scene's cobot would open when it is real hardware (not one of the
    simulated ones), else None. The command line must allow it (``--allow-hardware``)."""
    from teleop.master.cobot.host import SIMULATED_INTERFACES

    return None if scene.cobot.interface in SIMULATED_INTERFACES else scene.cobot.interface


def _optional_tables(cls, prefix: str = "") -> set[str]:
    """The dotted keys of the tables of ``cls`` (a settings dataclass) whose absence turns a part
    off (their default is None: [slave], [tissue], [damping], [gravity], [operator.hand], ...),
    through the tables that are always there."""
    import dataclasses
    import typing

    from teleop.util.typed import _is_table, _options

    out: set[str] = set()
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if not f.init or f.metadata.get("internal") or not _is_table(hints.get(f.name)):
            continue
        key = prefix + f.name
        if f.default is None:
            out.add(key)
        for option in _options(hints[f.name]):
            if dataclasses.is_dataclass(option):
                out |= _optional_tables(option, key + ".")
    return out


#: tables a ``--set`` of one of their keys may not create (:func:`_optional_tables` of a Scene)
OPTIONAL_TABLES = frozenset(_optional_tables(Scene))


def parse_scene(data: dict, path: str = "<scene>", sets=(), pairs=()) -> Scene:
    """Validate a scene table (a parsed TOML file), after applying overrides: ``sets`` as
    "dotted.key=TOML value" strings, ``pairs`` as (dotted key, value). A key of a table the scene
    does not have and whose absence turns a part off (OPTIONAL_TABLES: a ``slave.solver`` on a
    scene without a slave) is refused rather than adding the part."""
    if sets or pairs:
        data = apply_settings(copy.deepcopy(data), path, sets, pairs, optional=OPTIONAL_TABLES)
    overridden = tuple(parse_setting(s, path)[0] for s in sets or ()) + tuple(k for k, _ in pairs or ())
    given = {"path": path, "overridden": overridden}
    custom = _custom_fixture(data, path)
    if custom is not None:
        given["fixture"] = custom
        data = {k: v for k, v in data.items() if k != "fixture"}
    scene = validate(Scene, data, path, given=given)
    _check_tables(scene, data, path)
    return scene


def _custom_fixture(data: dict, path: str) -> CustomFixture | None:
    """The [fixture] table as a user's fixture type when its ``type`` is not built in (None when it
    is): the type looked up in the registry, the other keys checked by its dataclass."""
    table = data.get("fixture") if isinstance(data, dict) else None
    if not isinstance(table, dict) or not isinstance(table.get("type"), str) or table["type"] in FIXTURES:
        return None
    name = table["type"]
    cls = FIXTURE_TYPES.get(name)
    if cls is None:
        known = list(FIXTURES) + FIXTURE_TYPES.names()
        close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
        hint = f"did you mean {close[0]!r}?" if close else f"known types: {', '.join(known)}"
        raise SceneError(path, "fixture.type", f"unknown fixture type {name!r}; {hint} (a type of your own: "
                                               "teleop.dynamics.registry.register_fixture)")
    params = validate(cls, {k: v for k, v in table.items() if k != "type"}, path, "fixture")
    return CustomFixture(name, params)


def _check_tables(scene: Scene, data: dict, path: str) -> None:
    """Rules on which tables and keys a file gives: an effect's table without the effect, a
    fixture key its type does not read."""
    if "damping" in scene.effects and scene.damping is None:
        raise SceneError(path, "damping", "effect 'damping' is on but the [damping] table is missing")
    for table, given in (("damping", scene.damping is not None), ("gravity", scene.gravity is not None),
                         ("springs", bool(scene.springs))):
        if given and table not in scene.effects:
            what = "springs are given" if table == "springs" else f"a [{table}] table is given"
            raise SceneError(path, table, f"{what} but effect {table!r} is not on")
    if isinstance(scene.fixture, CustomFixture):
        return  # its own dataclass checked every key
    reads = FIXTURE_KEYS[scene.fixture.type]
    for key in data["fixture"]:
        if key != "type" and key not in reads:
            raise SceneError(path, f"fixture.{key}", f"not read by a {scene.fixture.type!r} fixture; "
                                                     f"it reads {', '.join(reads)}")
