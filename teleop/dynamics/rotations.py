"""Euler-angle charts of SO(3): rotation, the rate map E and its time derivative.

A chart is an intrinsic Euler sequence ``"abc"`` (e.g. ``"ZXZ"``, ``"ZYX"``) placed in the world by a
fixed rotation ``R0``:  ``R_WB = R0 @ R_a(t1) @ R_b(t2) @ R_c(t3)``.

With ``w_B`` the body angular velocity (rad/s, body frame) and ``td`` the Euler-angle rates (rad/s),

    w_B = E_B(t) @ td,      E_B = [R_c^T R_b^T e_a,  R_c^T e_b,  e_c].

``E_B`` does not depend on ``R0``, so re-placing the chart (re-charting) changes the angles but not
the physics. Proper Euler sequences (a == c) are singular where sin(t2) = 0, Tait-Bryan sequences
where cos(t2) = 0; :func:`chart_conditioning` measures the distance to that singularity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from teleop.dynamics.kernels.so3 import euler_angles
from teleop.util.errors import ConfigError

_AXES = {"X": 0, "Y": 1, "Z": 2}
_E = np.eye(3)


def axis_rotation(axis: int, angle: float) -> np.ndarray:
    """Rotation matrix (3, 3) about coordinate axis 0, 1 or 2 by ``angle`` rad."""
    c, s = math.cos(angle), math.sin(angle)
    if axis == 0:
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    if axis == 1:
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (any units; a new (3,) array), without numpy.cross's dispatch
    overhead: on Python floats (an array's ``tolist``, the cheapest read of three numbers)."""
    a0, a1, a2 = a.tolist() if type(a) is np.ndarray else a
    b0, b1, b2 = b.tolist() if type(b) is np.ndarray else b
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def inverse3(E: np.ndarray) -> np.ndarray:
    """Inverse of a 3x3 matrix by cross products (rows of the adjugate over the determinant)."""
    c0, c1, c2 = E[:, 0], E[:, 1], E[:, 2]
    r0, r1, r2 = cross(c1, c2), cross(c2, c0), cross(c0, c1)
    det = float(c0 @ r0)
    out = np.empty((3, 3))
    out[0], out[1], out[2] = r0, r1, r2
    return out / det


@dataclass(frozen=True, eq=False)
class EulerChart:
    """An intrinsic Euler sequence placed in the world by ``R0`` (3x3 rotation, world <- chart).

    ``sequence``: three letters from X, Y, Z with no two neighbours equal, e.g. "ZXZ" or "ZYX".
    """

    sequence: str = "ZYX"
    R0: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        seq = self.sequence.upper() if isinstance(self.sequence, str) else ""
        if len(seq) != 3 or any(c not in _AXES for c in seq) or seq[0] == seq[1] or seq[1] == seq[2]:
            raise ConfigError(
                f"euler sequence {self.sequence!r}: expected three axes from X, Y, Z with no two "
                "neighbours equal, e.g. 'ZXZ' or 'ZYX'"
            )
        R0 = np.array(self.R0, dtype=float)
        if R0.shape != (3, 3) or not np.allclose(R0 @ R0.T, np.eye(3), atol=1e-9):
            raise ConfigError("euler chart R0: expected a 3x3 rotation matrix")
        object.__setattr__(self, "sequence", seq)
        object.__setattr__(self, "R0", R0)
        object.__setattr__(self, "_R0_list", tuple(float(x) for x in R0.reshape(-1)))
        object.__setattr__(self, "_axes", tuple(_AXES[c] for c in seq))
        object.__setattr__(self, "axes_array", np.array(self._axes, dtype=np.int64))

    @property
    def axes(self) -> tuple[int, int, int]:
        return self._axes  # type: ignore[attr-defined]

    @property
    def proper(self) -> bool:
        """True for proper Euler sequences (first and last axis equal)."""
        return self.sequence[0] == self.sequence[2]

    @property
    def center(self) -> np.ndarray:
        """Angles (rad) farthest from the chart's singularity: where re-charting lands."""
        return np.array([0.0, math.pi / 2, 0.0]) if self.proper else np.zeros(3)

    def with_R0(self, R0: np.ndarray) -> EulerChart:
        return EulerChart(self.sequence, R0)


def chart_conditioning(chart: EulerChart, theta: np.ndarray) -> float:
    """Distance to the chart singularity in [0, 1]: |sin t2| (proper) or |cos t2| (Tait-Bryan)."""
    return abs(math.sin(theta[1])) if chart.proper else abs(math.cos(theta[1]))


def rotation(chart: EulerChart, theta: np.ndarray) -> np.ndarray:
    """World rotation R_WB (3, 3) of the Euler angles ``theta`` (rad) in ``chart``."""
    a, b, c = chart.axes
    return chart.R0 @ axis_rotation(a, theta[0]) @ axis_rotation(b, theta[1]) @ axis_rotation(c, theta[2])


def rate_map(chart: EulerChart, theta: np.ndarray, theta_dot: np.ndarray):
    """Body-frame rate map and its derivative.

    Returns ``(R_WB, E_B, Edot_B @ theta_dot)``: the rotation (3, 3), the map E_B (3, 3) from Euler
    rates to body angular velocity, and the velocity product d/dt(E_B) @ theta_dot (3,) in rad/s^2.
    """
    a, b, c = chart.axes
    Ra, Rb, Rc = axis_rotation(a, theta[0]), axis_rotation(b, theta[1]), axis_rotation(c, theta[2])
    R = chart.R0 @ Ra @ Rb @ Rc
    RcT = Rc.T
    ea, eb, ec = _E[a], _E[b], _E[c]
    RbT_ea = Rb.T @ ea
    col1 = RcT @ RbT_ea
    col2 = RcT[:, b]
    E = np.empty((3, 3))
    E[:, 0] = col1
    E[:, 1] = col2
    E[:, 2] = ec
    d1, d2, d3 = theta_dot[0], theta_dot[1], theta_dot[2]
    # d/dt R_c^T = -[e_c]x d3 R_c^T ;  d/dt R_b^T = -[e_b]x d2 R_b^T
    dcol1 = -d3 * cross(ec, col1) - d2 * (RcT @ cross(eb, RbT_ea))
    dcol2 = -d3 * cross(ec, col2)
    return R, E, d1 * dcol1 + d2 * dcol2


def euler_from_rotation(chart: EulerChart, R_WB: np.ndarray) -> np.ndarray:
    """Euler angles (3,) rad of ``R_WB`` (3, 3) in ``chart``, in scipy's conventions (t1, t3 in
    (-pi, pi]; t2 in [-pi/2, pi/2] for Tait-Bryan, [0, pi] for proper sequences). Only well defined
    away from the chart's singularity. The compiled :func:`teleop.dynamics.kernels.so3.euler_angles`
    (scipy's ``as_euler`` costs about a step's budget; see there)."""
    R = R_WB if R_WB.dtype == np.float64 and R_WB.flags.c_contiguous else np.ascontiguousarray(R_WB, dtype=float)
    return euler_angles(chart.R0, chart.axes_array, R)


def rechart(chart: EulerChart, theta: np.ndarray, theta_dot: np.ndarray):
    """Move the chart so the current orientation sits at the chart centre.

    Returns ``(new_chart, new_theta, new_theta_dot)`` describing the same rotation and the same
    body angular velocity. Used when :func:`chart_conditioning` gets small (near gimbal lock).
    """
    R, E, _ = rate_map(chart, theta, theta_dot)
    w_B = E @ theta_dot
    center = chart.center
    a, b, c = chart.axes
    R_center = axis_rotation(a, center[0]) @ axis_rotation(b, center[1]) @ axis_rotation(c, center[2])
    new = chart.with_R0(R @ R_center.T)
    _, E_new, _ = rate_map(new, center, np.zeros(3))
    return new, center.copy(), np.linalg.solve(E_new, w_B)
