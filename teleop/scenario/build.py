"""Turn a validated :class:`Scene` into engine objects: body, fixture, effects, tool, operator.

Only the effects a scene names are constructed; an effect it does not name costs nothing.
"""

from __future__ import annotations

import numpy as np

from teleop.dynamics import fixtures
from teleop.dynamics.body import RigidBody
from teleop.dynamics.effects import AngularDamper, Gravity, LinearDamper, Spring
from teleop.dynamics.fixtures import Fixture
from teleop.dynamics.rotations import cross
from teleop.dynamics.tool import ReferenceTool
from teleop.errors import ConfigError, SceneError
from teleop.scenario.schema import FixtureSpec, OperatorSpec, Scene


def build_body(scene: Scene) -> RigidBody:
    inertia = np.array(scene.tool.inertia_kgm2)
    try:
        return RigidBody(scene.tool.mass_kg, inertia.reshape(3, 3) if inertia.size == 9 else inertia)
    except ConfigError as e:
        raise SceneError(scene.path, "tool", str(e)) from None


def build_fixture(spec: FixtureSpec) -> Fixture:
    if spec.type == "rolling_disk":
        return fixtures.rolling_disk(spec.radius_m, spec.plane_origin_m, spec.plane_normal)
    if spec.type == "sphere":
        return fixtures.sphere(spec.center_m, spec.radius_m)
    if spec.type == "scalpel":
        return fixtures.scalpel(spec.plane_origin_m, spec.plane_normal, spec.depth_m, spec.tip_m, spec.knife_edge)
    return fixtures.free(spec.euler_sequence)


def build_effects(scene: Scene, body: RigidBody) -> list:
    effects = []
    if "damping" in scene.effects:
        if scene.damping_linear_Ns_per_m:
            effects.append(LinearDamper(scene.damping_linear_Ns_per_m))
        if scene.damping_angular_Nms_per_rad:
            effects.append(AngularDamper(scene.damping_angular_Nms_per_rad))
    if "gravity" in scene.effects:
        effects.append(Gravity(body.mass_kg, np.array(scene.gravity_m_s2)))
    if "springs" in scene.effects:
        effects += [Spring(np.array(s.anchor_m), s.k_N_per_m, np.eye(3), s.k_Nm_per_rad) for s in scene.springs]
    return effects


def build_tool(scene: Scene) -> ReferenceTool:
    """The reference tool of a scene, reset to its initial state (projected onto the fixture)."""
    body = build_body(scene)
    try:
        tool = ReferenceTool(
            body, build_fixture(scene.fixture), build_effects(scene, body),
            integrator=scene.integrator, coriolis="coriolis" in scene.effects,
        )
        tool.reset(scene.tool.q0, scene.tool.qd0)
    except ConfigError as e:
        raise SceneError(scene.path, "fixture", str(e)) from None
    return tool


def task_frame(spec: FixtureSpec, R: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) whose columns are the fixture's natural directions for the operator.

    rolling disk: (forward, lateral, plane normal); otherwise the tool's body axes.
    """
    if spec.type != "rolling_disk":
        return R
    n = np.asarray(spec.plane_normal, dtype=float)
    n = n / np.linalg.norm(n)
    forward = cross(n, R[:, 2])
    norm = np.linalg.norm(forward)
    if norm < 1e-9:
        return R
    forward /= norm
    return np.column_stack([forward, cross(n, forward), n])


class ScriptedWrench:
    """The scripted operator: phases of constant wrench with linear ramps, optionally repeating."""

    def __init__(self, spec: OperatorSpec, fixture: FixtureSpec):
        self.spec = spec
        self.fixture = fixture

    def wrench(self, t: float, p: np.ndarray, R: np.ndarray) -> np.ndarray:
        """World wrench (6,: N, N*m) at the tool origin at time t s for the tool pose (p, R)."""
        spec = self.spec
        if spec.repeat_s:
            t = t % spec.repeat_s
        out = np.zeros(6)
        for ph in spec.phases:
            if not ph.start_s <= t < ph.end_s:
                continue
            gain = 1.0
            if ph.ramp_s > 0:
                gain = min(1.0, (t - ph.start_s) / ph.ramp_s, (ph.end_s - t) / ph.ramp_s)
            if ph.frame == "world":
                Rf = np.eye(3)
            elif ph.frame == "tool":
                Rf = R
            else:
                Rf = task_frame(self.fixture, R)
            out[:3] += gain * (Rf @ np.array(ph.force_N))
            out[3:] += gain * (Rf @ np.array(ph.torque_Nm))
        return out
