"""What the viewer draws: the scene (``VizScene``, fixed for a run) and one snapshot (``VizFrame``).

Both are frozen dataclasses validated when created; a bad field raises ``ConfigError`` naming the
field and the reason. SI units throughout (m, N, N*m, s, rad), world frame W, poses as ``(p, R)``
with p (3,) m and R (3, 3) a rotation matrix.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from teleop.util.errors import ConfigError

#: the built-in fixture types (the scene schema's FIXTURES), built from ``fixture_params`` when no
#: built fixture is given; a user's own type is drawn from its constraints or by its ``draw(frame)``
#: method (see :mod:`teleop.viz.environment`)
FIXTURE_TYPES = ("free", "rolling_disk", "sphere", "scalpel")
#: camera views: a perspective from slightly above, or level and orthographic (a vertical blade
#: looks vertical)
VIEW_KINDS = ("perspective", "side")
#: tool shapes: an upright disk (axle = body z), a scalpel (blade along body z), a plain box
TOOL_SHAPES = ("disk", "scalpel", "box")
FIXTURE_KEYS = ("radius_m", "center_m", "plane_origin_m", "plane_normal", "depth_m", "tip_m",
                "knife_edge", "trocar_m", "euler_sequence", "type")
TISSUE_KEYS = ("origin_m", "normal", "size_m", "thickness_m")


def _vector(where: str, x, n: int | None = None) -> np.ndarray:
    try:
        a = np.array(x, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected numbers, got {x!r}") from None
    if a.ndim != 1 or (n is not None and a.shape != (n,)):
        raise ConfigError(f"{where}: expected a vector of {n or 'some'} numbers, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ConfigError(f"{where}: contains NaN or inf")
    a.setflags(write=False)
    return a


def _pose(where: str, pose) -> tuple:
    try:
        p, R = pose
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected a pose (p (3,), R (3, 3)), got {type(pose).__name__}") from None
    p = _vector(f"{where}.p", p, 3)
    try:
        R = np.array(R, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}.R: expected a 3x3 matrix") from None
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ConfigError(f"{where}.R: expected a finite 3x3 rotation matrix, got shape {R.shape}")
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0:
        raise ConfigError(f"{where}.R: not a rotation matrix (R^T R != I or det < 0)")
    R.setflags(write=False)
    return p, R


@dataclass(frozen=True, eq=False)
class VizFrame:
    """One snapshot at simulated time ``t`` (s). Every field but ``t`` is optional.

    Poses are ``(p (3,) m, R (3, 3))`` in W; wrenches are (6,) = (force N, torque N*m) in W;
    ``master_q`` / ``slave_q`` are joint vectors of the scene's models (rad or m); ``cut_trace``
    is (n, 3) m, the cut so far, drawn as a line strip on the slave side.
    """

    t: float
    reference_pose: tuple | None = None
    virtual_pose: tuple | None = None
    operator_wrench: np.ndarray | None = None
    constraint_wrench: np.ndarray | None = None
    master_q: np.ndarray | None = None
    slave_q: np.ndarray | None = None
    slave_tool_pose: tuple | None = None
    contact_wrench: np.ndarray | None = None
    cut_trace: np.ndarray | None = None

    def __post_init__(self):
        t = self.t
        if isinstance(t, bool) or not isinstance(t, (int, float, np.floating, np.integer)) or not np.isfinite(t):
            raise ConfigError(f"VizFrame.t: expected a finite time in s, got {t!r}")
        object.__setattr__(self, "t", float(t))
        for name in ("reference_pose", "virtual_pose", "slave_tool_pose"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, _pose(f"VizFrame.{name}", v))
        for name in ("operator_wrench", "constraint_wrench", "contact_wrench"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, _vector(f"VizFrame.{name}", v, 6))
        for name in ("master_q", "slave_q"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, _vector(f"VizFrame.{name}", v))
        if self.cut_trace is not None:
            c = np.array(self.cut_trace, dtype=float)
            if c.size == 0:
                c = c.reshape(0, 3)
            if c.ndim != 2 or c.shape[1] != 3 or not np.all(np.isfinite(c)):
                raise ConfigError(f"VizFrame.cut_trace: expected finite (n, 3) points in m, got shape {c.shape}")
            c.setflags(write=False)
            object.__setattr__(self, "cut_trace", c)


def _positive(where: str, x) -> float:
    try:
        x = float(x)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: expected a number, got {x!r}") from None
    if not np.isfinite(x) or x <= 0:
        raise ConfigError(f"{where}: expected a positive number, got {x}")
    return x


@dataclass(frozen=True, eq=False)
class VizScene:
    """What stays fixed during a run.

    fixture_type: one of FIXTURE_TYPES; fixture_params: FixtureSpec fields (radius_m, center_m,
    plane_origin_m, plane_normal, depth_m, tip_m; SI). tool_shape: one of TOOL_SHAPES.
    master_model: optional pinocchio Model of the haptic device (drawn as rails and joint markers).
    slave_robot: optional object with ``.model`` and ``.visual_model`` (e.g. a RobotWrapper) whose
    forward kinematics give poses in W. tissue: optional {"origin_m", "normal", "size_m" [lx, ly],
    "thickness_m"} (m). slave_offset_m: where the slave side is drawn beside the master side (layout m;
    each side spans about 1).
    force_scale_m_per_N: arrow length per newton (layout m/N, the same on both sides); master_zoom: how
    much the (small) master side is magnified, None to choose from the fixture's size;
    master_robot: optional object with ``.model`` and ``.visual_model`` of the haptic device (e.g.
    the cobot's URDF through ``pin.buildModelsFromUrdf``): drawn from its visuals, posed from
    ``master_q``; replaces the stick drawing of ``master_model``. tool_radius_m: the drawn disk's
    radius (m; None: the fixture's radius_m). follow: each side's aim follows its tool. view: one
    of VIEW_KINDS. fixture_object: a user's fixture (an instance of a type named by
    ``fixture_type``, registered with ``teleop.dynamics.registry.register_fixture``), for its
    ``draw(frame)`` or its ``build(frame)``. fixture_frame: the FrameMap from the patient frame (the
    slave side's, where the tissue is) into the master workspace: the tissue is drawn through it
    on the master side, and a user's fixture placed by it. master_fixture / slave_fixture: the
    fixture as built for each side (``teleop.dynamics.fixtures.Fixture``: the master's in the
    master workspace, the slave's in the patient frame), drawn from its constraints (see
    :mod:`teleop.viz.environment`); None: the master's is built from ``fixture_type`` and
    ``fixture_params`` (or ``fixture_object``), the slave side draws none but its tissue.
    """

    fixture_type: str
    fixture_params: dict = field(default_factory=dict)
    tool_shape: str = "box"
    master_model: object = None
    slave_robot: object = None
    slave_tool_frame: str | None = None
    tissue: dict | None = None
    slave_offset_m: tuple = (1.15, 0.0, 0.0)
    force_scale_m_per_N: float = 0.03
    master_zoom: float | None = None
    master_robot: object = None
    tool_radius_m: float | None = None
    follow: bool = True
    view: str = "perspective"
    fixture_object: object = None
    fixture_frame: object = None
    master_fixture: object = None
    slave_fixture: object = None

    def __post_init__(self):
        if self.fixture_type not in FIXTURE_TYPES and self.fixture_object is None:
            raise ConfigError(f"VizScene.fixture_type: unknown {self.fixture_type!r}; choose one of {FIXTURE_TYPES}"
                              " or give the user fixture as fixture_object")
        if self.view not in VIEW_KINDS:
            raise ConfigError(f"VizScene.view: unknown {self.view!r}; choose one of {VIEW_KINDS}")
        if self.tool_radius_m is not None:
            object.__setattr__(self, "tool_radius_m", _positive("VizScene.tool_radius_m", self.tool_radius_m))
        if self.master_robot is not None:
            for attr in ("model", "visual_model"):
                if not hasattr(self.master_robot, attr):
                    raise ConfigError(f"VizScene.master_robot: has no .{attr} (give a RobotWrapper-like object)")
        if self.tool_shape not in TOOL_SHAPES:
            raise ConfigError(f"VizScene.tool_shape: unknown {self.tool_shape!r}; choose one of {TOOL_SHAPES}")
        if not isinstance(self.fixture_params, dict):
            raise ConfigError("VizScene.fixture_params: expected a dict of FixtureSpec fields")
        params = {k: v for k, v in self.fixture_params.items() if v is not None}
        for k in params:
            if k not in FIXTURE_KEYS and self.fixture_object is None:
                raise ConfigError(f"VizScene.fixture_params: unknown key {k!r}; known: {FIXTURE_KEYS}")
        for k in ("center_m", "plane_origin_m", "tip_m"):
            if k in params:
                params[k] = tuple(_vector(f"VizScene.fixture_params.{k}", params[k], 3))
        if "plane_normal" in params:
            n = _vector("VizScene.fixture_params.plane_normal", params["plane_normal"], 3)
            if np.linalg.norm(n) < 1e-9:
                raise ConfigError("VizScene.fixture_params.plane_normal: must be non-zero")
            params["plane_normal"] = tuple(n / np.linalg.norm(n))
        if "radius_m" in params:
            params["radius_m"] = _positive("VizScene.fixture_params.radius_m", params["radius_m"])
        if "depth_m" in params:
            d = float(params["depth_m"])
            if not np.isfinite(d) or d < 0:
                raise ConfigError(f"VizScene.fixture_params.depth_m: expected a depth >= 0 m, got {d}")
            params["depth_m"] = d
        object.__setattr__(self, "fixture_params", params)
        if self.tissue is not None:
            object.__setattr__(self, "tissue", _tissue(self.tissue))
        object.__setattr__(self, "slave_offset_m", tuple(_vector("VizScene.slave_offset_m", self.slave_offset_m, 3)))
        object.__setattr__(self, "force_scale_m_per_N",
                           _positive("VizScene.force_scale_m_per_N", self.force_scale_m_per_N))
        if self.master_zoom is not None:
            object.__setattr__(self, "master_zoom", _positive("VizScene.master_zoom", self.master_zoom))
        if self.slave_robot is not None:
            for attr in ("model", "visual_model"):
                if not hasattr(self.slave_robot, attr):
                    raise ConfigError(f"VizScene.slave_robot: has no .{attr} (give a RobotWrapper-like object)")
            if self.slave_tool_frame is not None and not self.slave_robot.model.existFrame(self.slave_tool_frame):
                raise ConfigError(f"VizScene.slave_tool_frame: {self.slave_tool_frame!r} is not a frame of the "
                                  "slave model")
        for name in ("master_fixture", "slave_fixture"):
            fx = getattr(self, name)
            if fx is not None and not hasattr(fx, "constraints"):
                raise ConfigError(f"VizScene.{name}: expected a built fixture (teleop.dynamics.fixtures.Fixture), "
                                  f"got {type(fx).__name__}")
        if self.master_model is not None and not hasattr(self.master_model, "njoints"):
            raise ConfigError("VizScene.master_model: expected a pinocchio Model")

    def param(self, key: str, default):
        """A fixture parameter, or ``default`` (the FixtureSpec default) when not given."""
        return self.fixture_params.get(key, default)


def _tissue(d) -> dict:
    if not isinstance(d, dict):
        raise ConfigError("VizScene.tissue: expected a dict {origin_m, normal, size_m, thickness_m}")
    for k in d:
        if k not in TISSUE_KEYS:
            raise ConfigError(f"VizScene.tissue: unknown key {k!r}; known: {TISSUE_KEYS}")
    n = _vector("VizScene.tissue.normal", d.get("normal", (0.0, 0.0, 1.0)), 3)
    if np.linalg.norm(n) < 1e-9:
        raise ConfigError("VizScene.tissue.normal: must be non-zero")
    size = _vector("VizScene.tissue.size_m", d.get("size_m", (0.1, 0.1)), 2)
    if np.any(size <= 0):
        raise ConfigError(f"VizScene.tissue.size_m: expected two positive lengths, got {size.tolist()}")
    return {
        "origin_m": tuple(_vector("VizScene.tissue.origin_m", d.get("origin_m", (0.0, 0.0, 0.0)), 3)),
        "normal": tuple(n / np.linalg.norm(n)),
        "size_m": tuple(size),
        "thickness_m": _positive("VizScene.tissue.thickness_m", d.get("thickness_m", 0.02)),
    }
