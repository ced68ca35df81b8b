"""The slave arm: its configuration, its Pinocchio model with the tool frame E, and its state.

``SlaveConfig`` is a frozen dataclass, a node of the scene tree (its ``[slave]`` table).
``build_model`` loads the arm (example-robot-data's Panda or UR5, or any URDF), appends the tool
URDF at the flange with ``pin.appendModel`` (the tool's mass joins the last link), and adds the
frame ``E`` at the tool tip. ``SlaveArm`` owns a ``pin.Data``, the follower QP and the joint state;
``step()`` advances one tick.

Frames: W is the world (the patient frame P of the mapping), S the arm base (``base_xyz_m``,
``base_rpy_rad`` give X_WS), E the tool frame at the blade tip (+z blade axis into tissue, +x the
cutting direction, +y the side axis).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Literal

import example_robot_data as erd
import numpy as np
import pinocchio as pin

from teleop.slave.limits import JointLimits
from teleop.slave.solvers import PACKAGES, installed_solvers
from teleop.util.errors import ConfigError
from teleop.util.inputs import plain, read_text
from teleop.util.resources import robot_file
from teleop.util.typed import Checked, setting, validate

SCALPEL_URDF = robot_file("scalpel/scalpel.urdf")

#: arm name -> (example-robot-data name, flange frame, default q0 rad, acceleration limits rad/s^2)
ARMS = {
    # Panda: q0 is Franka's "ready" pose; a_max from Franka's datasheet (15, 7.5, 10, 12.5, 15, 20, 20)
    "panda": ("panda", "panda_hand_tcp", (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785),
              (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)),
    # UR5: tool pointing down in front of the base; a_max a conservative 10 rad/s^2 per joint
    "ur5": ("ur5", "tool0", (0.0, -1.571, 1.571, -1.571, -1.571, 0.0), (10.0,) * 6),
}
TOOLS = {"scalpel": (SCALPEL_URDF, "scalpel_tip")}


def _file(p: str) -> str | None:
    return None if Path(p).is_file() else f"no such file {p!r}"


def _arm_name(arm) -> str | None:
    if isinstance(arm, str) and arm not in ARMS:
        return f"unknown arm {arm!r}; expected one of {sorted(ARMS)} or a table"
    return None


def _tool_name(tool) -> str | None:
    if isinstance(tool, str) and tool not in TOOLS:
        return f"unknown tool {tool!r}; expected one of {sorted(TOOLS)} or a table"
    return None


def _solver(name: str) -> str | None:
    if name in installed_solvers():
        return None
    known = (f"QP solver {name!r} is supported but not installed (pip install {PACKAGES[name]})"
             if name in PACKAGES else f"unknown QP solver {name!r}")
    return f"{known}; installed: {list(installed_solvers())}"


class _Pairs:
    """Iterates as (key, value) pairs of its set fields, so ``dict(spec)`` reads it as a mapping."""

    def __iter__(self):
        return iter((f.name, getattr(self, f.name)) for f in fields(self) if getattr(self, f.name) is not None)


@dataclass(frozen=True)
class UrdfArm(_Pairs, Checked):
    """An arm from a URDF: ``flange`` the frame the tool is mounted on; q0 (rad) and a_max (rad/s^2)
    default to the neutral pose and 10 rad/s^2."""

    urdf: str = setting(check=_file, doc="URDF file of the arm")
    flange: str = setting(doc="frame the tool is mounted on")
    q0: tuple[float, ...] | None = setting(None, doc="initial joint angles, rad")
    a_max: tuple[float, ...] | None = setting(None, gt=0.0, doc="joint acceleration limits, rad/s^2")
    package_dirs: tuple[str, ...] | None = setting(None, doc="folders the URDF's package:// paths resolve in")


@dataclass(frozen=True)
class UrdfTool(_Pairs, Checked):
    """A tool from a URDF: ``tip`` the frame at the blade tip."""

    urdf: str = setting(check=_file, doc="URDF file of the tool")
    tip: str = setting(doc="frame at the tool tip")


@dataclass(frozen=True)
class SlaveConfig(Checked):
    """Settings of the slave arm and its follower (SI units; gains in 1/s).

    arm: "panda" | "ur5" | {urdf, flange, q0, a_max}. tool: "scalpel" | {urdf, tip}. Weights are
    per (m/s)^2 (position), per (rad/s)^2 (orientation) and per (rad/s)^2 (posture, damping);
    ``impedance_Ns_per_m`` turns the QP's row multipliers into forces (N) for ``fixture_forces``.
    ``kkt_shortcut``: solve the QP without its joint bounds first (one linear solve, exact when no
    bound binds) and run ``solver`` only when that solution leaves the bounds.
    """

    arm: str | UrdfArm = setting("panda", check=_arm_name, doc="arm name or a URDF arm")
    tool: str | UrdfTool = setting("scalpel", check=_tool_name, doc="tool name or a URDF tool")
    mount_xyz_m: tuple[float, ...] = setting((0.0, 0.0, 0.0), n=3, doc="tool mount on the flange, m")
    mount_rpy_rad: tuple[float, ...] = setting((0.0, 0.0, 0.0), n=3, doc="tool mount on the flange, rad")
    base_xyz_m: tuple[float, ...] = setting((0.0, 0.0, 0.0), n=3, doc="arm base in the world (X_WS), m")
    base_rpy_rad: tuple[float, ...] = setting((0.0, 0.0, 0.0), n=3, doc="arm base in the world (X_WS), rad")
    q0: tuple[float, ...] | None = setting(None, doc="initial joint angles, rad (default: the arm's)")
    solver: str = setting("osqp", check=_solver, doc="QP solver (qpsolvers name)")
    eps: float = setting(1e-7, gt=0.0, doc="solver tolerance")
    max_iter: int = setting(4000, ge=1, doc="solver iteration limit")
    weight_position: float = setting(1.0, gt=0.0)
    weight_orientation: float = setting(0.1, gt=0.0)
    weight_posture: float = setting(1e-4, ge=0.0)
    damping: float = setting(1e-8, ge=0.0)
    lm_damping: float = setting(1e-2, ge=0.0)
    slack_weight: float = setting(1e6, gt=0.0)
    k_task_1ps: float = setting(300.0, gt=0.0, doc="task gain, 1/s")
    k_fixture_1ps: float = setting(300.0, gt=0.0, doc="fixture gain, 1/s")
    k_posture_1ps: float = setting(1.0, ge=0.0, doc="posture gain, 1/s")
    velocity_scale: float = setting(1.0, gt=0.0, doc="scale on the model's velocity limits")
    acceleration_scale: float = setting(1.0, gt=0.0, doc="scale on the acceleration limits")
    position_margin_rad: float = setting(0.0, ge=0.0, doc="margin inside the joint limits, rad")
    servo_lag_s: float = setting(0.0, ge=0.0, doc="joint servo time constant, s")
    impedance_Ns_per_m: float = setting(200.0, gt=0.0, doc="row multipliers to forces, N*s/m")
    relaxed_tol_mps: float = setting(1e-6, gt=0.0, doc="slack above which fixtures count as relaxed, m/s")
    tracking_alarm_m: float = setting(0.01, gt=0.0, doc="tip tracking error that raises the alarm, m")
    fallback: Literal["dls", "hold"] = setting("hold", doc="what the follower does when the QP fails: hold (stop "
                                                           "the joints, the blade stays) or dls (toward the target, "
                                                           "no fixture rows)")
    kkt_shortcut: bool = setting(True, doc="try the bound-free KKT solve first")

    @classmethod
    def from_dict(cls, d: dict, where: str = "slave") -> SlaveConfig:
        """Build from a plain table through the one validator (errors name ``where.key``)."""
        return validate(cls, d, "", where)


@dataclass(frozen=True, eq=False)
class ArmModel:
    """A Pinocchio model with the tool appended; ``frame_E`` the tool-tip frame id; limits."""

    model: pin.Model
    frame_E: int
    q0: np.ndarray
    limits: JointLimits


def _rpy_se3(xyz, rpy) -> pin.SE3:
    return pin.SE3(pin.rpy.rpyToMatrix(*rpy), np.asarray(xyz, dtype=float))


def _urdf_model(path, key: str) -> pin.Model:
    """Pinocchio's model of a URDF file, read as a regular file of bounded size (teleop.util.inputs);
    a file that is not a URDF is a ConfigError naming ``key``."""
    try:
        xml = read_text(path, what="URDF")
    except ConfigError as e:
        raise ConfigError(f"{key}: {getattr(e, 'reason', e)}") from None
    try:
        return pin.buildModelFromXML(xml)
    except (ValueError, RuntimeError) as e:
        raise ConfigError(f"{key}: {plain(path)} is not a valid URDF ({plain(str(e).splitlines()[0])[:120]})") from None


def build_model(cfg: SlaveConfig, where: str = "slave") -> ArmModel:
    """Load arm + tool, append the tool at the flange, add frame "E"; validate q0 and limits."""
    if isinstance(cfg.arm, str):
        erd_name, flange, q0, a_max = ARMS[cfg.arm]
        full = erd.load(erd_name).model
    else:
        spec = dict(cfg.arm)
        full = _urdf_model(spec["urdf"], f"{where}.arm.urdf")
        flange = spec["flange"]
        q0 = spec.get("q0", tuple(pin.neutral(full)))
        a_max = spec.get("a_max", (10.0,) * full.nv)
    # lock grippers' fingers: the scalpel is held in the hand
    lock = [j for j in range(1, full.njoints) if "finger" in full.names[j]]
    model = pin.buildReducedModel(full, lock, pin.neutral(full)) if lock else full
    if not model.existFrame(flange):
        raise ConfigError(f"{where}.arm: flange frame {flange!r} not in the model")
    tool_urdf, tip = TOOLS[cfg.tool] if isinstance(cfg.tool, str) else (dict(cfg.tool)["urdf"], dict(cfg.tool)["tip"])
    tool = _urdf_model(tool_urdf, f"{where}.tool.urdf")
    if not tool.existFrame(tip):
        raise ConfigError(f"{where}.tool: tip frame {tip!r} not in {tool_urdf}")
    model = pin.appendModel(model, tool, model.getFrameId(flange), _rpy_se3(cfg.mount_xyz_m, cfg.mount_rpy_rad))
    model.jointPlacements[1] = _rpy_se3(cfg.base_xyz_m, cfg.base_rpy_rad) * model.jointPlacements[1]
    ft = model.frames[model.getFrameId(tip)]
    model.addFrame(pin.Frame("E", ft.parentJoint, ft.parentFrame, ft.placement, pin.FrameType.OP_FRAME))
    if model.nq != model.nv:
        raise ConfigError(f"{where}.arm: only arms with nq == nv (no continuous joints) are supported")
    q0 = np.asarray(cfg.q0 if cfg.q0 is not None else q0, dtype=float)
    if q0.shape != (model.nq,):
        raise ConfigError(f"{where}.q0: expected {model.nq} joint angles, got {q0.shape[0]}")
    lim = JointLimits(
        model.lowerPositionLimit, model.upperPositionLimit,
        cfg.velocity_scale * model.velocityLimit, cfg.acceleration_scale * np.asarray(a_max, dtype=float),
        cfg.position_margin_rad,
    )
    if np.any(q0 < lim.q_min) or np.any(q0 > lim.q_max):
        raise ConfigError(f"{where}.q0: {q0.tolist()} is outside the joint limits")
    return ArmModel(model, model.getFrameId("E"), q0, lim)
