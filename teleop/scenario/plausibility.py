"""Physical plausibility of a whole scene: the rules that tie keys together, and the ranges of the
runtime configs a scene holds (the tissue, the cobot, the slave), checked before anything runs.

Each table's own keys carry their ranges where they are declared (:mod:`teleop.scenario.tables`).
What is checked here:

* **Ranges of the nested runtime configs** (:data:`RANGES`): the [tissue] block (positions within
  +-10 m, thickness up to 1 m, stiffness up to 1e7, ...), the [cobot] and the [slave]. They are
  declared here, by key, because their classes belong to other layers; ``teleop schema`` shows
  them too (:func:`annotate_schema`).
* **Rules on two or more keys** (:func:`cross_rules`):

  - the tool's radius of gyration sqrt(J / m) is at most 1 m (``tool.inertia_kgm2`` vs
    ``tool.mass_kg``);
  - a scalpel's depth is less than the tissue's thickness (``fixture.depth_m`` vs
    ``tissue.thickness_m``), when the scene has a tissue;
  - a trocar lies outside the tissue, above the fixture's plane (``fixture.trocar_m``);
  - every band and cut-off the tick samples is below its Nyquist rate 1 / (2 dt_s): the hand's
    tremor band (effect "tremor"), the force feedback's low-pass (with a slave), the cobot's joint
    observer (master "cobot").

A rule on several keys names the key a ``--set`` override changed when it changed one of them
(:func:`pick_key`), else the first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from teleop.scenario.tables import MAX_GYRATION_M, MAX_POSITION_M, MAX_TOOL_POINT_M, principal_inertias


@dataclass(frozen=True)
class Range:
    """A plausible range of one key: ``lo`` .. ``hi`` in ``unit`` (``open_lo``: lo excluded)."""

    key: str
    lo: float
    hi: float
    unit: str
    open_lo: bool = False
    what: str = ""

    def text(self) -> str:
        return f"{'(' if self.open_lo else '['}{self.lo:g}, {self.hi:g}] {self.unit}".rstrip()

    def holds(self, x: float) -> bool:
        return (self.lo < x if self.open_lo else self.lo <= x) and x <= self.hi


P = MAX_POSITION_M
#: plausible ranges of the nested runtime configs, by dotted key (a list's every item)
RANGES = (
    Range("tissue.origin_m", -P, P, "m", what="each coordinate"),
    Range("tissue.thickness_m", 0.0, 1.0, "m", open_lo=True, what="a tissue block's thickness"),
    Range("tissue.stiffness", 0.0, 1e7, "N/m^exponent", open_lo=True, what="a tissue's stiffness"),
    Range("tissue.exponent", 1.0, 3.0, "", what="a Hunt-Crossley exponent"),
    Range("tissue.alpha_s_per_m", 0.0, 100.0, "s/m", what="a Hunt-Crossley damping"),
    Range("tissue.damping_Ns_per_m", 0.0, 1e4, "N*s/m", what="a tissue's damping"),
    Range("tissue.cutting.f_N_per_m", 0.0, 1e6, "N/m", what="a fracture resistance"),
    Range("tissue.cutting.b_Ns_per_m2", 0.0, 1e7, "N*s/m^2", what="a viscous cutting resistance"),
    Range("tissue.cutting.lateral_Ns_per_m2", 0.0, 1e8, "N*s/m^2", what="a sideways resistance"),
    Range("tissue.cutting.twist_Nms_per_m", 0.0, 1e4, "N*m*s/m", what="a twist resistance"),
    Range("tissue.cutting.v_smooth_mps", 0.0, 1.0, "m/s", open_lo=True, what="a smoothing speed"),
    Range("cobot.offset_m", -P, P, "m", what="each coordinate"),
    Range("cobot.max_velocity", 0.0, 100.0, "m/s, rad/s", open_lo=True, what="a joint velocity limit"),
    Range("cobot.max_acceleration", 0.0, 1e4, "m/s^2, rad/s^2", open_lo=True, what="a joint acceleration limit"),
    Range("cobot.free_damping", 0.0, 1e4, "N*s/m, N*m*s/rad", open_lo=True, what="a clutch-released damping"),
    Range("slave.base_xyz_m", -P, P, "m", what="each coordinate"),
    Range("slave.mount_xyz_m", -MAX_TOOL_POINT_M, MAX_TOOL_POINT_M, "m", what="each coordinate"),
    Range("slave.servo_lag_s", 0.0, 1.0, "s", what="a joint servo's time constant"),
    Range("slave.tracking_alarm_m", 0.0, 1.0, "m", open_lo=True, what="a tracking alarm"),
    Range("slave.impedance_Ns_per_m", 0.0, 1e6, "N*s/m", open_lo=True, what="an impedance"),
)


def _get(scene, key: str):
    node = scene
    for part in key.split("."):
        node = getattr(node, part, None)
        if node is None:
            return None
    return node


def range_problems(scene):
    """(key, reason) of the first value of a nested config outside its range (RANGES), or None."""
    for r in RANGES:
        value = _get(scene, r.key)
        if value is None:
            continue
        items = [float(x) for x in np.asarray(value, dtype=float).reshape(-1)]
        for x in items:
            if not r.holds(x):
                got = items if len(items) > 1 else x
                return r.key, f"{r.what} must be in {r.text()} (got {got!r})"
    return None


def nyquist_hz(dt_s: float) -> float:
    return 1.0 / (2.0 * dt_s)


def _tissue_thickness(scene) -> tuple[float, str] | None:
    """The thickness (m) of the tissue the scene cuts and where it comes from, or None without one
    (the runtime uses the [tissue] table, or a default block when effect "tissue" is on with a slave)."""
    if scene.tissue is not None:
        return scene.tissue.thickness_m, "tissue.thickness_m"
    if scene.slave is not None and "tissue" in scene.effects:
        from teleop.contact.tissue import TissueBlock

        return TissueBlock().thickness_m, "the default tissue's thickness_m"
    return None


def cross_rules(scene):
    """Yield (keys, reason) for each broken rule on several keys of ``scene`` (keys: the ones the
    rule reads, the one to name first)."""
    tool = scene.tool
    J = principal_inertias(tool.inertia_kgm2)
    if J is not None and tool.mass_kg > 0:
        radius = math.sqrt(J[2] / tool.mass_kg)
        if radius > MAX_GYRATION_M:
            yield (("tool.inertia_kgm2", "tool.mass_kg"),
                   f"a {tool.mass_kg:g} kg tool with a {J[2]:g} kg*m^2 moment has a radius of gyration of "
                   f"{radius:.3g} m; a hand-held tool's is at most {MAX_GYRATION_M:g} m "
                   f"(J <= m * {MAX_GYRATION_M:g}^2)")
    fixture = scene.fixture
    depth = getattr(fixture, "depth_m", None) if fixture.type == "scalpel" else (
        getattr(getattr(fixture, "params", None), "depth_m", None))
    thick = _tissue_thickness(scene)
    if depth is not None and thick is not None and not depth < thick[0]:
        yield (("fixture.depth_m", "tissue.thickness_m", "tissue", "effects", "slave"),
               f"a cut {depth * 1e3:g} mm deep does not fit in {thick[0] * 1e3:g} mm of tissue ({thick[1]}); "
               "the blade's depth must be less than the tissue's thickness")
    if fixture.type == "scalpel" and getattr(fixture, "trocar_m", None) is not None:
        n = np.asarray(fixture.plane_normal, dtype=float)
        height = (float(n @ (np.asarray(fixture.trocar_m) - np.asarray(fixture.plane_origin_m)))
                  / float(np.linalg.norm(n)))
        if not height > 0.0:
            yield (("fixture.trocar_m", "fixture.plane_origin_m", "fixture.plane_normal"),
                   f"the trocar is {-height * 1e3:g} mm inside the tissue (below the fixture's plane along "
                   "plane_normal); a trocar sits in the body wall, above the tissue")
    nyq = nyquist_hz(scene.dt_s)
    hand = scene.operator.hand
    if hand is not None and "tremor" in scene.effects and not hand.tremor_band_hz[1] < nyq:
        yield (("operator.hand.tremor_band_hz", "dt_s", "effects"),
               f"a tremor band up to {hand.tremor_band_hz[1]:g} Hz is not below the Nyquist rate {nyq:g} Hz of a "
               f"{scene.dt_s:g} s tick (1 / (2 dt_s)): the tick cannot sample it")
    cutoff = scene.mapping.feedback_cutoff_hz
    if scene.slave is not None and cutoff > 0 and not cutoff < nyq:
        yield (("mapping.feedback_cutoff_hz", "dt_s", "slave"),
               f"a {cutoff:g} Hz force feedback low-pass is not below the Nyquist rate {nyq:g} Hz of a "
               f"{scene.dt_s:g} s tick (1 / (2 dt_s)); use 0 for no filter")
    observer = scene.cobot.observer_bandwidth_hz
    if scene.master == "cobot" and not observer < nyq:
        yield (("cobot.observer_bandwidth_hz", "dt_s", "master"),
               f"a {observer:g} Hz joint observer is not below the Nyquist rate {nyq:g} Hz of a {scene.dt_s:g} s "
               "tick (1 / (2 dt_s))")


def _under(key: str, prefix: str) -> bool:
    return key == prefix or key.startswith(prefix + ".") or key.startswith(prefix + "[")


def pick_key(keys, overridden) -> str:
    """The key to name for a rule on ``keys``: the last of ``overridden`` (the keys ``--set``
    changed, in order) that is one of them, inside one (``fixture.trocar_m[2]``) or holds one
    (``tissue`` for ``tissue.thickness_m``: then the rule's own key); else the rule's first key."""
    for set_key in reversed(tuple(overridden)):
        for k in keys:
            if _under(set_key, k):
                return set_key
            if _under(k, set_key):
                return k
    return keys[0]


def annotate_schema(schema: dict) -> dict:
    """``schema`` (the scene's JSON Schema) with RANGES as minimum / maximum of their keys (of
    their items for a list) and in their descriptions."""
    for r in RANGES:
        node = schema
        for part in r.key.split("."):
            node = node.get("properties", {}).get(part) if isinstance(node, dict) else None
            if node is None:
                break
        if node is None:
            continue
        node["description"] = f"{node.get('description', r.what)}; plausible: {r.text()}"
        targets = [node] + [a for a in node.get("anyOf", [])]
        for t in targets:
            t = t.get("items", t) if t.get("type") == "array" else t
            if t.get("type") not in ("number", "integer"):
                continue
            t["exclusiveMinimum" if r.open_lo else "minimum"] = r.lo
            t.pop("minimum" if r.open_lo else "exclusiveMinimum", None)
            t["maximum"] = r.hi
            t.pop("exclusiveMaximum", None)
    return schema
