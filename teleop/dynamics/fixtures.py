"""Fixtures: named groups of constraints with the parametrization of their holonomic part.

A fixture is what a scene asks for ("disk rolling on a plane", "tangent to a sphere", "scalpel at a
depth"). The same constraint objects constrain the master's reference tool and the slave's tool.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teleop.dynamics import constraints as C
from teleop.dynamics import parametrizations as P
from teleop.dynamics.rotations import EulerChart, axis_rotation
from teleop.util.errors import ConfigError


@dataclass(frozen=True, eq=False)
class Fixture:
    """Constraints (tuple of Constraint) and, when known, a parametrization of their manifold."""

    name: str
    constraints: tuple
    parametrization: P.Parametrization | None
    #: the Euler chart the tool's coordinates use when there is no parametrization to say it
    chart: EulerChart | None = None

    def initial_chart(self) -> EulerChart:
        if self.parametrization is not None:
            return self.parametrization.initial_chart()
        return self.chart if self.chart is not None else EulerChart("ZYX")

    @property
    def rows(self) -> int:
        return sum(c.rows for c in self.constraints)

    @property
    def holonomic(self) -> tuple:
        return tuple(c for c in self.constraints if c.holonomic)

    @property
    def nonholonomic(self) -> tuple:
        return tuple(c for c in self.constraints if not c.holonomic)

    def with_extra(self, *extra) -> Fixture:
        """The same fixture with more rows (e.g. a duplicated row); keeps the parametrization."""
        return Fixture(self.name, self.constraints + tuple(extra), self.parametrization, self.chart)


def free(sequence: str = "ZYX") -> Fixture:
    """No constraint: a free rigid body."""
    return Fixture("free", (), P.Identity(sequence))


def rolling_disk(radius: float, plane_origin=(0.0, 0.0, 0.0), plane_normal=(0.0, 0.0, 1.0)) -> Fixture:
    """Example 1: an upright disk (axle = body z) rolling without slip on a plane (eqs. 12-17)."""
    if not np.isfinite(radius) or radius <= 0:
        raise ConfigError(f"fixture.radius_m: expected a positive radius, got {radius}")
    n = np.asarray(plane_normal, dtype=float)
    n = n / np.linalg.norm(n)
    cons = (
        C.PlaneHeight(origin=plane_origin, normal=n, height=radius, name="disk_height"),
        C.AxisInPlane(axis_B=(0.0, 0.0, 1.0), normal=n, name="disk_upright"),
        C.RollingWithoutSlip(radius=radius, normal=n, name="disk_rolling"),
    )
    return Fixture("rolling_disk", cons, P.UprightDisk(radius, plane_origin, n))


def sphere(center=(0.0, 0.0, 0.0), radius: float = 0.05) -> Fixture:
    """Example 2: body origin on a sphere with the body z axis along the sphere normal (eqs. 21-25)."""
    cons = (C.SphereContact(center=center, radius=radius, normal_B=(0.0, 0.0, 1.0), name="sphere"),)
    return Fixture("sphere", cons, P.SphereSurface(center, radius))


def scalpel(
    plane_origin=(0.0, 0.0, 0.0),
    plane_normal=(0.0, 0.0, 1.0),
    depth: float = 0.005,
    tip_B=(0.0, 0.0, 0.0),
    knife_edge: bool = True,
) -> Fixture:
    """The scalpel: blade tip (body point ``tip_B``, m) ``depth`` m below the tissue plane, blade axis
    (body z) along the inward normal, and (``knife_edge``) no sideways (body y) slip of the tip.
    """
    if not np.isfinite(depth) or depth < 0:
        raise ConfigError(f"fixture.depth_m: expected a non-negative depth, got {depth}")
    n = np.asarray(plane_normal, dtype=float)
    n = n / np.linalg.norm(n)
    cons = [
        C.PointDepth(origin=plane_origin, normal=n, depth=depth, point_B=tip_B, name="blade_depth"),
        C.AxisAlong(axis_B=(0.0, 0.0, 1.0), direction=-n, name="blade_normal"),
    ]
    if knife_edge:
        cons.append(C.KnifeEdge(point_B=tip_B, side_B=(0.0, 1.0, 0.0), name="knife_edge"))
    return Fixture("scalpel", tuple(cons), P.ScalpelPlane(plane_origin, n, depth, tip_B))


def laparoscopic(
    plane_origin=(0.0, 0.0, 0.0),
    plane_normal=(0.0, 0.0, 1.0),
    depth: float = 0.005,
    tip_B=(0.0, 0.0, 0.0),
    trocar=(0.0, 0.0, 0.075),
    knife_edge: bool = True,
) -> Fixture:
    """A laparoscopic scalpel: the blade tip ``depth`` m below the tissue plane, the shaft (the body
    z axis through the tip) through the trocar point (a remote centre of motion), and no sideways
    slip. The blade tilts with the shaft, so there is no blade-normal row; no parametrization is
    known, so use the 'projection', 'rk4' or 'lie_group' integrator."""
    if not np.isfinite(depth) or depth < 0:
        raise ConfigError(f"fixture.depth_m: expected a non-negative depth, got {depth}")
    n = np.asarray(plane_normal, dtype=float)
    n = n / np.linalg.norm(n)
    if float(n @ (np.asarray(trocar, dtype=float) - np.asarray(plane_origin, dtype=float))) <= 0:
        raise ConfigError("fixture.trocar_m: the trocar must lie above the tissue plane")
    cons = [
        C.PointDepth(origin=plane_origin, normal=n, depth=depth, point_B=tip_B, name="blade_depth"),
        C.RemoteCenter(center=trocar, point_B=tip_B, axis_B=(0.0, 0.0, 1.0), name="trocar"),
    ]
    if knife_edge:
        cons.append(C.KnifeEdge(point_B=tip_B, side_B=(0.0, 1.0, 0.0), name="knife_edge"))
    # blade down: the same chart as the scalpel's (ZYX at R_plane Rx(pi)), far from its singularity
    chart = EulerChart("ZYX", P.plane_frame(n) @ axis_rotation(0, np.pi))
    return Fixture("laparoscopic", tuple(cons), None, chart)
