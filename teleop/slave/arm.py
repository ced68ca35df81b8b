"""The slave arm: its configuration, its Pinocchio model with the tool frame E, and its state.

``SlaveConfig`` is a frozen dataclass read from a plain dict (a scene's ``[slave]`` table).
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

import example_robot_data as erd
import numpy as np
import pinocchio as pin

from teleop.errors import ConfigError, check_table
from teleop.slave.limits import JointLimits
from teleop.slave.solvers import PACKAGES, installed_solvers

ROBOTS_DIR = Path(__file__).resolve().parents[2] / "robots"
SCALPEL_URDF = ROBOTS_DIR / "scalpel" / "scalpel.urdf"

#: arm name -> (example-robot-data name, flange frame, default q0 rad, acceleration limits rad/s^2)
ARMS = {
    # Panda: q0 is Franka's "ready" pose; a_max from Franka's datasheet (15, 7.5, 10, 12.5, 15, 20, 20)
    "panda": ("panda", "panda_hand_tcp", (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785),
              (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)),
    # UR5: tool pointing down in front of the base; a_max a conservative 10 rad/s^2 per joint
    "ur5": ("ur5", "tool0", (0.0, -1.571, 1.571, -1.571, -1.571, 0.0), (10.0,) * 6),
}
TOOLS = {"scalpel": (SCALPEL_URDF, "scalpel_tip")}


def _num(where, key, x, lo=None, hi=None, strict=False) -> float:
    try:
        x = float(x)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}.{key}: expected a number, got {x!r}") from None
    bad = not np.isfinite(x) or (lo is not None and (x <= lo if strict else x < lo)) or (hi is not None and x > hi)
    if bad:
        raise ConfigError(f"{where}.{key}: {x} is out of range (min {lo}{' exclusive' if strict else ''}, max {hi})")
    return x


def _vec(where, key, x, n=None) -> tuple:
    try:
        a = np.asarray(x, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}.{key}: expected a list of numbers, got {x!r}") from None
    if (n is not None and a.shape != (n,)) or not np.all(np.isfinite(a)):
        raise ConfigError(f"{where}.{key}: expected {n or 'some'} finite numbers, got {x!r}")
    return tuple(float(v) for v in a)


@dataclass(frozen=True)
class SlaveConfig:
    """Settings of the slave arm and its follower (SI units; gains in 1/s).

    arm: "panda" | "ur5" | {"urdf": path, "flange": frame, "q0": [...], "a_max": [...]}.
    tool: "scalpel" | {"urdf": path, "tip": frame}. Weights are per (m/s)^2 (position),
    per (rad/s)^2 (orientation) and per (rad/s)^2 (posture, damping); ``impedance_Ns_per_m``
    turns the QP's row multipliers into forces (N) for ``fixture_forces``. ``kkt_shortcut``: solve
    the QP without its joint bounds first (one linear solve, exact when no bound binds) and run
    ``solver`` only when that solution leaves the bounds.
    """

    arm: object = "panda"
    tool: object = "scalpel"
    mount_xyz_m: tuple = (0.0, 0.0, 0.0)
    mount_rpy_rad: tuple = (0.0, 0.0, 0.0)
    base_xyz_m: tuple = (0.0, 0.0, 0.0)
    base_rpy_rad: tuple = (0.0, 0.0, 0.0)
    q0: tuple | None = None
    solver: str = "osqp"
    eps: float = 1e-7
    max_iter: int = 4000
    weight_position: float = 1.0
    weight_orientation: float = 0.1
    weight_posture: float = 1e-4
    damping: float = 1e-8
    lm_damping: float = 1e-2
    slack_weight: float = 1e6
    k_task_1ps: float = 300.0
    k_fixture_1ps: float = 300.0
    k_posture_1ps: float = 1.0
    velocity_scale: float = 1.0
    acceleration_scale: float = 1.0
    position_margin_rad: float = 0.0
    servo_lag_s: float = 0.0
    impedance_Ns_per_m: float = 200.0
    relaxed_tol_mps: float = 1e-6
    tracking_alarm_m: float = 0.01
    fallback: str = "dls"
    kkt_shortcut: bool = True

    @classmethod
    def from_dict(cls, d: dict, where: str = "slave") -> "SlaveConfig":
        check_table(d, where, {f.name for f in fields(cls)})
        kw = {}
        arm = d.get("arm", "panda")
        if isinstance(arm, str):
            if arm not in ARMS:
                raise ConfigError(f"{where}.arm: unknown arm {arm!r}; expected one of {sorted(ARMS)} or a table")
        elif isinstance(arm, dict):
            check_table(arm, f"{where}.arm", ("urdf", "flange", "q0", "a_max", "package_dirs"))
            if "urdf" not in arm or "flange" not in arm:
                raise ConfigError(f"{where}.arm: a URDF arm needs both 'urdf' and 'flange'")
            if not Path(arm["urdf"]).is_file():
                raise ConfigError(f"{where}.arm.urdf: no such file {arm['urdf']!r}")
            arm = tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in arm.items()))
        else:
            raise ConfigError(f"{where}.arm: expected a name or a table, got {arm!r}")
        kw["arm"] = arm
        tool = d.get("tool", "scalpel")
        if isinstance(tool, str):
            if tool not in TOOLS:
                raise ConfigError(f"{where}.tool: unknown tool {tool!r}; expected one of {sorted(TOOLS)} or a table")
        elif isinstance(tool, dict):
            if set(tool) != {"urdf", "tip"}:
                raise ConfigError(f"{where}.tool: a URDF tool needs exactly 'urdf' and 'tip'")
            if not Path(tool["urdf"]).is_file():
                raise ConfigError(f"{where}.tool.urdf: no such file {tool['urdf']!r}")
            tool = (("tip", tool["tip"]), ("urdf", tool["urdf"]))
        else:
            raise ConfigError(f"{where}.tool: expected a name or a table, got {tool!r}")
        kw["tool"] = tool
        for key in ("mount_xyz_m", "mount_rpy_rad", "base_xyz_m", "base_rpy_rad"):
            if key in d:
                kw[key] = _vec(where, key, d[key], 3)
        if d.get("q0") is not None:
            kw["q0"] = _vec(where, "q0", d["q0"])
        solver = d.get("solver", "osqp")
        if solver not in installed_solvers():
            known = (f"QP solver {solver!r} is supported but not installed (pip install {PACKAGES[solver]})"
                     if solver in PACKAGES else f"unknown QP solver {solver!r}")
            raise ConfigError(f"{where}.solver: {known}; installed: {list(installed_solvers())}")
        kw["solver"] = solver
        fallback = d.get("fallback", "dls")
        if fallback not in ("dls", "hold"):
            raise ConfigError(f"{where}.fallback: expected 'dls' or 'hold', got {fallback!r}")
        kw["fallback"] = fallback
        if "kkt_shortcut" in d:
            if not isinstance(d["kkt_shortcut"], bool):
                raise ConfigError(f"{where}.kkt_shortcut: expected true or false, got {d['kkt_shortcut']!r}")
            kw["kkt_shortcut"] = d["kkt_shortcut"]
        pos = ("eps", "weight_position", "weight_orientation", "slack_weight", "k_task_1ps",
               "k_fixture_1ps", "velocity_scale", "acceleration_scale", "impedance_Ns_per_m",
               "relaxed_tol_mps", "tracking_alarm_m")
        nonneg = ("weight_posture", "damping", "lm_damping", "k_posture_1ps", "position_margin_rad", "servo_lag_s")
        for key in pos:
            if key in d:
                kw[key] = _num(where, key, d[key], lo=0.0, strict=True)
        for key in nonneg:
            if key in d:
                kw[key] = _num(where, key, d[key], lo=0.0)
        if "max_iter" in d:
            kw["max_iter"] = int(_num(where, "max_iter", d["max_iter"], lo=1))
        return cls(**kw)


@dataclass(frozen=True, eq=False)
class ArmModel:
    """A Pinocchio model with the tool appended; ``frame_E`` the tool-tip frame id; limits."""

    model: pin.Model
    frame_E: int
    q0: np.ndarray
    limits: JointLimits


def _rpy_se3(xyz, rpy) -> pin.SE3:
    return pin.SE3(pin.rpy.rpyToMatrix(*rpy), np.asarray(xyz, dtype=float))


def build_model(cfg: SlaveConfig, where: str = "slave") -> ArmModel:
    """Load arm + tool, append the tool at the flange, add frame "E"; validate q0 and limits."""
    if isinstance(cfg.arm, str):
        erd_name, flange, q0, a_max = ARMS[cfg.arm]
        full = erd.load(erd_name).model
    else:
        spec = dict(cfg.arm)
        full = pin.buildModelFromUrdf(str(spec["urdf"]))
        flange = spec["flange"]
        q0 = spec.get("q0", tuple(pin.neutral(full)))
        a_max = spec.get("a_max", (10.0,) * full.nv)
    # lock grippers' fingers: the scalpel is held in the hand
    lock = [j for j in range(1, full.njoints) if "finger" in full.names[j]]
    model = pin.buildReducedModel(full, lock, pin.neutral(full)) if lock else full
    if not model.existFrame(flange):
        raise ConfigError(f"{where}.arm: flange frame {flange!r} not in the model")
    tool_urdf, tip = TOOLS[cfg.tool] if isinstance(cfg.tool, str) else (dict(cfg.tool)["urdf"], dict(cfg.tool)["tip"])
    tool = pin.buildModelFromUrdf(str(tool_urdf))
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
