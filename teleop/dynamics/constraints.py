"""Constraints on a rigid tool, defined once on its pose and twist.

Every constraint works on the pose ``(p, R)`` of a body frame B (``p``: origin in world, m;
``R = R_WB``) and on the twist ``nu = (v, w)``: the world velocity of B's origin (m/s) and the world
angular velocity (rad/s), Pinocchio's LOCAL_WORLD_ALIGNED convention. A constraint gives

* ``jacobian(p, R)``: G, shape (rows, 6), the rows of the Pfaffian form  G @ nu = 0;
* ``bias(p, R, v, w)``: d/dt(G) @ nu, shape (rows,), so that  d/dt(G nu) = G @ nudot + bias;
* ``residual(p, R)``: h, shape (rows,), for holonomic constraints (h = 0 on the manifold).

The rows of the built-in constraints are written once, in compiled code
(:mod:`teleop.dynamics.kernels.rows`); each class holds its parameters and names its kernel
(:attr:`Constraint.kernel`), and its methods call that code. A user's own constraint subclasses
:class:`Constraint` and fills the methods in Python; :func:`compiled_kind` says which path a
constraint takes (see its docstring for the protocol).

Rows are normalised so that the multiplier of each row is a force in N (rows acting on ``v``) or a
torque in N*m (rows acting on ``w`` only); ``units`` names them. The same objects constrain the
master's reference tool (mapped to Euler-angle coordinates by the engine) and the slave arm's tool
frame (mapped through the arm's frame Jacobian by the QP follower).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from teleop.dynamics.kernels import rows as K
from teleop.dynamics.rotations import cross
from teleop.util.errors import ConfigError


def _unit(v, name: str) -> np.ndarray:
    v = np.asarray(v, dtype=float).reshape(-1)
    n = float(np.linalg.norm(v)) if v.shape == (3,) else 0.0
    if not np.isfinite(n) or n < 1e-12:
        raise ConfigError(f"{name}: expected a finite non-zero 3-vector, got {v.tolist()}")
    return v / n


def _vec3(v, name: str) -> np.ndarray:
    v = np.asarray(v, dtype=float).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"{name}: expected a finite 3-vector, got {np.asarray(v).tolist()}")
    return v


def _positive(x: float, name: str) -> float:
    x = float(x)
    if not np.isfinite(x) or x <= 0.0:
        raise ConfigError(f"{name}: expected a finite positive number, got {x}")
    return x


def plane_tangents(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (t1, t2) with t1 x t2 = n, for a unit normal ``n``.

    For n = +z they are world x and y, so a horizontal plane gives the paper's rows (eqs. 14-15).
    """
    if n[2] > 1.0 - 1e-12:
        return np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = helper - (helper @ n) * n
    t1 /= np.linalg.norm(t1)
    return t1, cross(n, t1)


class Constraint(ABC):
    """A block of Pfaffian rows on a rigid body's twist. Subclasses fill three pure methods.

    ``kernel``: the compiled row kernel (a ``KIND_*`` code of :mod:`teleop.dynamics.kernels.rows`)
    that computes this class's rows, or None (a user's constraint: its Python methods are called).
    A class that sets it also gives :meth:`kernel_params`. See :func:`compiled_kind`.
    """

    name: str = "constraint"
    holonomic: bool = True
    rows: int = 1
    units: tuple[str, ...] = ("N",)
    #: G does not depend on the pose and the bias is zero.
    constant: bool = False
    kernel: int | None = None

    @abstractmethod
    def jacobian(self, p: np.ndarray, R: np.ndarray) -> np.ndarray:
        """G (rows, 6) acting on the twist (v, w)."""

    @abstractmethod
    def bias(self, p: np.ndarray, R: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """d/dt(G) @ (v, w), shape (rows,), in m/s^2 or rad/s^2."""

    def residual(self, p: np.ndarray, R: np.ndarray) -> np.ndarray:
        """h (rows,) in m or rad; zero on the constraint manifold. Nonholonomic rows have none."""
        raise ConfigError(f"constraint {self.name!r} is nonholonomic: it has no residual h(q)")

    def kernel_params(self) -> np.ndarray:
        """The (NPAR,) float parameters the compiled kernel reads (classes that set ``kernel``)."""
        raise NotImplementedError(f"constraint {self.name!r} has no compiled kernel")


#: the names a compiled constraint class must not see overridden below it (see compiled_kind)
KERNEL_PROTOCOL = ("jacobian", "bias", "residual", "rows", "holonomic", "kernel", "kernel_params")


def compiled_kind(c: Constraint) -> int | None:
    """The compiled row kernel that computes ``c``'s rows, or None (its Python methods are used).

    The protocol: the class in ``type(c)``'s MRO that sets ``kernel`` (not None) owns the kernel;
    it is used only if no class below that owner redefines any name of :data:`KERNEL_PROTOCOL`.
    A subclass of a built-in that overrides, say, ``jacobian`` therefore takes the Python path for
    all its rows, never a kernel that would silently ignore the override.
    """
    mro = type(c).__mro__
    owner = next((i for i, k in enumerate(mro) if "kernel" in k.__dict__), None)
    if owner is None or mro[owner].__dict__["kernel"] is None:
        return None
    if any(name in k.__dict__ for k in mro[:owner] for name in KERNEL_PROTOCOL):
        return None
    return int(mro[owner].__dict__["kernel"])


def _f(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=float)


class _Compiled(Constraint):
    """The methods of a built-in constraint: its compiled rows (:func:`kernels.rows.one_constraint`)."""

    def kernel_params(self) -> np.ndarray:
        return self._par  # type: ignore[attr-defined]

    def _set_params(self, *parts) -> None:
        par = np.zeros(K.NPAR)
        flat = np.concatenate([np.atleast_1d(np.asarray(x, dtype=float)) for x in parts])
        par[: flat.size] = flat
        object.__setattr__(self, "_par", par)

    def _eval(self, p, R, v=None, w=None):
        z = np.zeros(3)
        return K.one_constraint(self.kernel, self._par, self.rows, _f(p), _f(R),  # type: ignore[attr-defined]
                                z if v is None else _f(v), z if w is None else _f(w))

    def jacobian(self, p, R):
        return self._eval(p, R)[0]

    def bias(self, p, R, v, w):
        return self._eval(p, R, v, w)[1]

    def residual(self, p, R):
        if not self.holonomic:
            return super().residual(p, R)
        return self._eval(p, R)[2]


@dataclass(frozen=True, eq=False)
class PlaneHeight(_Compiled):
    """Body origin at ``height`` (m) above a plane through ``origin`` with unit ``normal``.

    h = n . (p - o) - height (m); G = [n, 0]."""

    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    height: float = 0.0
    name: str = "plane_height"

    holonomic = True
    rows = 1
    units = ("N",)
    constant = True
    kernel = K.KIND_PLANE_HEIGHT

    def __post_init__(self):
        object.__setattr__(self, "origin", _vec3(self.origin, f"{self.name}.origin"))
        object.__setattr__(self, "normal", _unit(self.normal, f"{self.name}.normal"))
        if not np.isfinite(self.height):
            raise ConfigError(f"{self.name}.height: expected a finite number, got {self.height}")
        self._set_params(self.origin, self.normal, self.height)


@dataclass(frozen=True, eq=False)
class AxisInPlane(_Compiled):
    """Body axis ``axis_B`` (unit, body frame) stays perpendicular to ``normal``: a disk upright.

    h = n . (R a_B) (dimensionless, ~rad). Its multiplier is a torque (N*m) about (R a_B) x n.
    """

    axis_B: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    name: str = "axis_in_plane"

    holonomic = True
    rows = 1
    units = ("N*m",)
    kernel = K.KIND_AXIS_IN_PLANE

    def __post_init__(self):
        object.__setattr__(self, "axis_B", _unit(self.axis_B, f"{self.name}.axis"))
        object.__setattr__(self, "normal", _unit(self.normal, f"{self.name}.normal"))
        self._set_params(self.axis_B, self.normal)


@dataclass(frozen=True, eq=False)
class RollingWithoutSlip(_Compiled):
    """Nonholonomic: the contact point of an upright disk (radius m) does not slide on the plane.

    The contact point is ``p - radius * normal`` (valid while the disk is held upright), and its
    velocity along both plane tangents is zero: rows [t_i, -radius (n x t_i)], the paper's eqs. 14-15.
    """

    radius: float = 0.03
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    name: str = "rolling_without_slip"

    holonomic = False
    rows = 2
    units = ("N", "N")
    constant = True
    kernel = K.KIND_ROLLING

    def __post_init__(self):
        _positive(self.radius, f"{self.name}.radius")
        n = _unit(self.normal, f"{self.name}.normal")
        object.__setattr__(self, "normal", n)
        t1, t2 = plane_tangents(n)
        self._set_params(t1, t2, n, self.radius)


@dataclass(frozen=True, eq=False)
class SphereContact(_Compiled):
    """The body origin stays on a sphere (centre m, radius m), the body axis ``normal_B`` radial.

    h = p - c - radius * R n_B (3 rows, m). Its multipliers are the world force (N) the sphere
    applies, the paper's eqs. 21-24.
    """

    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    radius: float = 0.05
    normal_B: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    name: str = "sphere_contact"

    holonomic = True
    rows = 3
    units = ("N", "N", "N")
    kernel = K.KIND_SPHERE

    def __post_init__(self):
        object.__setattr__(self, "center", _vec3(self.center, f"{self.name}.center"))
        _positive(self.radius, f"{self.name}.radius")
        object.__setattr__(self, "normal_B", _unit(self.normal_B, f"{self.name}.normal"))
        self._set_params(self.center, self.radius, self.normal_B)


@dataclass(frozen=True, eq=False)
class PointDepth(_Compiled):
    """A body point ``point_B`` (m, body frame) held ``depth`` (m) below a plane (unit normal out).

    h = n . (p + R d - o) + depth. The scalpel's blade tip at a fixed cutting depth.
    """

    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    depth: float = 0.005
    point_B: np.ndarray = field(default_factory=lambda: np.zeros(3))
    name: str = "point_depth"

    holonomic = True
    rows = 1
    units = ("N",)
    kernel = K.KIND_POINT_DEPTH

    def __post_init__(self):
        object.__setattr__(self, "origin", _vec3(self.origin, f"{self.name}.origin"))
        object.__setattr__(self, "normal", _unit(self.normal, f"{self.name}.normal"))
        object.__setattr__(self, "point_B", _vec3(self.point_B, f"{self.name}.point"))
        if not np.isfinite(self.depth):
            raise ConfigError(f"{self.name}.depth: expected a finite number, got {self.depth}")
        self._set_params(self.origin, self.normal, self.depth, self.point_B)


@dataclass(frozen=True, eq=False)
class AxisAlong(_Compiled):
    """Body axis ``axis_B`` stays parallel to the world ``direction``: two rows (N*m).

    h_i = t_i . (R a_B) for the two tangents t_i of ``direction``. Keeps a blade normal to tissue.
    """

    axis_B: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    direction: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -1.0]))
    name: str = "axis_along"

    holonomic = True
    rows = 2
    units = ("N*m", "N*m")
    kernel = K.KIND_AXIS_ALONG

    def __post_init__(self):
        object.__setattr__(self, "axis_B", _unit(self.axis_B, f"{self.name}.axis"))
        d = _unit(self.direction, f"{self.name}.direction")
        object.__setattr__(self, "direction", d)
        self._set_params(self.axis_B, *plane_tangents(d))


@dataclass(frozen=True, eq=False)
class KnifeEdge(_Compiled):
    """Nonholonomic: a body point ``point_B`` has no velocity along the body axis ``side_B``.

    The scalpel's blade cannot slip sideways: s . (v + w x R d) = 0 with s = R side_B (N).
    """

    point_B: np.ndarray = field(default_factory=lambda: np.zeros(3))
    side_B: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))
    name: str = "knife_edge"

    holonomic = False
    rows = 1
    units = ("N",)
    kernel = K.KIND_KNIFE_EDGE

    def __post_init__(self):
        object.__setattr__(self, "point_B", _vec3(self.point_B, f"{self.name}.point"))
        object.__setattr__(self, "side_B", _unit(self.side_B, f"{self.name}.side"))
        self._set_params(self.point_B, self.side_B)


@dataclass(frozen=True, eq=False)
class RemoteCenter(_Compiled):
    """A trocar (remote centre of motion): the tool shaft, the line through the body point
    ``point_B`` along body axis ``axis_B``, passes through the world point ``center`` (m).

    Two rows (N): the shaft's velocity at the trocar, perpendicular to the shaft, is zero. The
    residual is the trocar's offset from the shaft line along the two shaft normals.
    """

    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    point_B: np.ndarray = field(default_factory=lambda: np.zeros(3))
    axis_B: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    name: str = "remote_center"

    holonomic = True
    rows = 2
    units = ("N", "N")
    kernel = K.KIND_REMOTE_CENTER

    def __post_init__(self):
        object.__setattr__(self, "center", _vec3(self.center, f"{self.name}.center"))
        object.__setattr__(self, "point_B", _vec3(self.point_B, f"{self.name}.point"))
        object.__setattr__(self, "axis_B", _unit(self.axis_B, f"{self.name}.axis"))
        a = self.axis_B
        helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        n1 = helper - (helper @ a) * a
        n1 /= np.linalg.norm(n1)
        self._set_params(self.center, self.point_B, n1, cross(a, n1))


def stack_jacobian(constraints, p, R) -> np.ndarray:
    """Stack the rows of every constraint into G, shape (sum rows, 6)."""
    if not constraints:
        return np.zeros((0, 6))
    return np.vstack([c.jacobian(p, R) for c in constraints])


def stack_bias(constraints, p, R, v, w) -> np.ndarray:
    if not constraints:
        return np.zeros(0)
    return np.concatenate([c.bias(p, R, v, w) for c in constraints])


def stack_residual(constraints, p, R) -> np.ndarray:
    """Residuals of the holonomic constraints only, stacked (m or rad)."""
    hol = [c.residual(p, R) for c in constraints if c.holonomic]
    return np.concatenate(hol) if hol else np.zeros(0)
