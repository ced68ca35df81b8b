"""Turn a validated :class:`Scene` into engine objects: body, fixture, effects, tool, operator.

Only the effects a scene names are constructed; an effect it does not name costs nothing.
"""

from __future__ import annotations

import numpy as np

from teleop.dynamics.body import RigidBody
from teleop.dynamics.effects import AngularDamper, Gravity, LinearDamper, Spring
from teleop.dynamics.fixtures import Fixture
from teleop.dynamics.registry import FrameMap
from teleop.dynamics.tool import ReferenceTool
from teleop.scenario.schema import Scene
from teleop.util.errors import ConfigError, DynamicsError, SceneError


def build_body(scene: Scene) -> RigidBody:
    inertia = np.array(scene.tool.inertia_kgm2)
    try:
        return RigidBody(scene.tool.mass_kg, inertia.reshape(3, 3) if inertia.size == 9 else inertia)
    except ConfigError as e:
        raise SceneError(scene.path, "tool", str(e)) from None


def build_fixture(spec, frame=None) -> Fixture:
    """The fixture of a [fixture] table (a FixtureSpec or a user's CustomFixture), placed by
    ``frame`` (a :class:`teleop.dynamics.registry.FrameMap`; None: the patient frame as written)."""
    return spec.build(frame)


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


def build_registration(scene: Scene):
    """The master-to-patient mapping of a teleoperation scene (the scene's [mapping])."""
    try:
        return scene.mapping.registration()
    except ConfigError as e:
        raise SceneError(scene.path, "mapping", str(e)) from None


def master_frame(scene: Scene):
    """Where the scene's patient-frame geometry lands at the master (identity without a slave)."""
    return build_registration(scene).master_frame() if scene.slave is not None else FrameMap.identity()


def master_fixture_spec(scene: Scene):
    """The fixture as the master's reference tool sees it: with a slave, the scene's [fixture] is
    written in the patient frame (where the tissue is) and placed in the master workspace by the
    registration's one map (:meth:`teleop.control.mapping.Registration.master_frame`)."""
    return scene.fixture.mapped(master_frame(scene))


def build_tool(scene: Scene) -> ReferenceTool:
    """The reference tool of a scene, reset to its initial state (projected onto the fixture)."""
    body = build_body(scene)
    try:
        tool = ReferenceTool(
            body, build_fixture(scene.fixture, master_frame(scene)), build_effects(scene, body),
            integrator=scene.integrator, coriolis="coriolis" in scene.effects,
        )
    except ConfigError as e:
        raise SceneError(scene.path, "fixture", str(e)) from None
    try:
        with np.errstate(all="raise"):
            tool.reset(scene.tool.q0, scene.tool.qd0)
        ok = np.all(np.isfinite(tool.q)) and np.all(np.isfinite(tool.qd))
    except ConfigError as e:
        raise SceneError(scene.path, "tool.q0", str(e)) from None
    except (np.linalg.LinAlgError, DynamicsError, FloatingPointError, ZeroDivisionError):
        ok = False
    if not ok:
        raise SceneError(scene.path, "tool.q0",
                         f"the {scene.fixture.type!r} fixture cannot be met from q0 = {list(scene.tool.q0)} "
                         "(a singular point of its chart); choose another q0")
    return tool
