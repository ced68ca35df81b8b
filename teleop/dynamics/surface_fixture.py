"""The scalpel on curved tissue (the paper's closing NURBS remark): the blade tip held ``depth``
below a B-spline surface (:class:`teleop.dynamics.surface.HeightSurface`), the blade along the
surface's inward normal, and a knife edge along the cut.

Rows (:class:`SurfaceDepth`, 3 holonomic rows on the tool's pose, plus the built-in
:class:`~teleop.dynamics.constraints.KnifeEdge`): with the tip p_t = p + R d, its foot c = (u, v)
on the surface ((p_t - S(c)) . S_i(c) = 0), n = n(c) and the blade's side axes b1 = R e_x,
b2 = R e_y,

    h0 = n . (p_t - S(c)) + depth   (m; the signed distance of the tip plus the depth)
    h1 = b1 . n,  h2 = b2 . n       (rad; zero when the blade axis R e_z is along -n)

Their time derivatives follow from the foot's rate c_dot = A^-1 S_c^T v_t, A = S_c^T S_c -
(p_t - S) . S_cc (the closest-point condition differentiated), so G needs S to second order and
the velocity-product term d/dt(G) nu (the same expression with nu_dot = 0) to third order. The
foot's Newton search and the three rows are one compiled call
(:func:`teleop.dynamics.kernels.surface.depth_rows`).

Parametrization (the paper's psi, eq. 10-11), z = (u, v, heading) in (m, m, rad): the tip at
S(u, v) - depth n(u, v), the tool's rotation R = F(u, v) Rx(pi) Rz(heading) with F = (t1, t2, n)
the surface frame (t1 along S_u), in a ZYX chart placed at Q Rx(pi) (blade down along the height
field's "up" Q e_z), so on a flat field theta = (heading, 0, 0) as for the planar scalpel.
Psi is analytic (the surface frame's derivatives); the curvature term zd^T psi_zz zd is the
directional derivative of that analytic Psi along zd by a central difference of step 1e-6 in z
(error ~1e-10 relative: the integrator's own step error is far larger).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from teleop.dynamics.constraints import Constraint, KnifeEdge
from teleop.dynamics.fixtures import Fixture
from teleop.dynamics.kernels import surface as SK
from teleop.dynamics.parametrizations import Parametrization, plane_frame
from teleop.dynamics.registry import FrameMap, register_fixture
from teleop.dynamics.rotations import (
    EulerChart,
    axis_rotation,
    cross,
    euler_from_rotation,
    inverse3,
    rate_map,
    rotation,
)
from teleop.dynamics.surface import HeightSurface
from teleop.util.errors import ConfigError
from teleop.util.typed import setting

_RX_PI = axis_rotation(0, math.pi)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class SurfaceDepth(Constraint):
    """Tip (body point ``tip_B``, m) ``depth`` m below ``surface`` along its normal, blade axis
    (body z) along the inward normal: 3 holonomic rows (N, N*m, N*m). See the module docstring."""

    holonomic = True
    rows = 3
    units = ("N", "N*m", "N*m")

    def __init__(self, surface: HeightSurface, depth: float, tip_B, name: str = "surface_depth"):
        self.surface, self.depth = surface, float(depth)
        self.d = np.ascontiguousarray(tip_B, dtype=float)
        self.name = name
        self._foot = np.zeros(3)  # (u, v, valid): the last foot, Newton's warm start
        self._G, self._b, self._h = np.zeros((3, 6)), np.zeros(3), np.zeros(3)
        self._key = None  # the pose (and twist) the arrays above belong to
        self._zero3 = np.zeros(3)

    def _rows(self, p, R, v=None, w=None):
        """(G, b, h) at the pose (and twist: b is zero without one), one compiled call
        (:func:`teleop.dynamics.kernels.surface.depth_rows`); the last pose's result is reused (the
        row stack asks for G, b and h in turn). Copies."""
        p, R = np.ascontiguousarray(p, dtype=float), np.ascontiguousarray(R, dtype=float)
        moving = v is not None
        v = self._zero3 if v is None else np.ascontiguousarray(v, dtype=float)
        w = self._zero3 if w is None else np.ascontiguousarray(w, dtype=float)
        pose = (p.tobytes(), R.tobytes())
        key = pose + ((v.tobytes(), w.tobytes()) if moving else ())
        if self._key is None or (self._key != key if moving else self._key[:2] != pose):
            SK.depth_rows(*self.surface.geometry(), self.d, self.depth, p, R, v, w, moving, self._foot,
                          self._G, self._b, self._h)
            self._key = key
        return self._G.copy(), self._b.copy(), self._h.copy()

    def foot(self, p, R):
        """(u, v) of the tip's foot on the surface, or None when Newton found none."""
        self._rows(p, R)
        return (float(self._foot[0]), float(self._foot[1])) if self._foot[2] else None

    def residual(self, p, R):
        return self._rows(p, R)[2]

    def jacobian(self, p, R):
        return self._rows(p, R)[0]

    def bias(self, p, R, v, w):
        return self._rows(p, R, v, w)[1]


class SurfaceScalpel(Parametrization):
    """psi(u, v, heading) of the module docstring; ``surface`` placed where the tool is."""

    dim = 3

    def __init__(self, surface: HeightSurface, depth: float, tip_B):
        self.surface, self.depth = surface, float(depth)
        self.d = np.asarray(tip_B, dtype=float)
        self._chart = EulerChart("ZYX", surface.Q @ _RX_PI)
        self._ez = np.array([0.0, 0.0, 1.0])

    def initial_chart(self):
        return self._chart

    def _pose(self, chart, z):
        u, v, yaw = float(z[0]), float(z[1]), float(z[2])
        F, S = self.surface.frame(u, v)
        R = F @ _RX_PI @ axis_rotation(2, yaw)
        theta = euler_from_rotation(chart, R)
        theta[0] = yaw + _wrap(theta[0] - yaw)
        return R, S - self.depth * F[:, 2] - R @ self.d, theta

    def psi(self, chart, z):
        _R, p, theta = self._pose(chart, z)
        return np.concatenate([p, theta])

    def jacobian(self, chart, z):
        u, v, yaw = float(z[0]), float(z[1]), float(z[2])
        F, _S, S1, _n, dF = self.surface.frame_derivatives(u, v)
        R = F @ _RX_PI @ axis_rotation(2, yaw)
        theta = euler_from_rotation(chart, R)
        _, E, _ = rate_map(chart, theta, np.zeros(3))
        Einv_RT = inverse3(E) @ R.T  # world angular velocity -> Euler rates
        Rd = R @ self.d
        P = np.empty((6, 3))
        for k in range(2):
            W = dF[k] @ F.T  # skew: dR/dc_k R^T
            om = 0.5 * np.array([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]])
            P[:3, k] = S1[k] - self.depth * dF[k][:, 2] - cross(om, Rd)
            P[3:, k] = Einv_RT @ om
        om = R[:, 2]
        P[:3, 2] = -cross(om, Rd)
        P[3:, 2] = Einv_RT @ om
        return P

    def curvature(self, chart, z, zd):
        z = np.asarray(z, dtype=float)
        zd = np.asarray(zd, dtype=float)
        speed = float(np.abs(zd).max())
        if speed == 0.0:
            return np.zeros(6)
        h = 1e-6 / speed
        Jp, Jm = self.jacobian(chart, z + h * zd), self.jacobian(chart, z - h * zd)
        return (Jp - Jm) @ zd / (2.0 * h)

    def from_q(self, chart, q, qd):
        R = rotation(chart, q[3:])
        tip = q[:3] + R @ self.d
        u, v, ok = self.surface.closest(tip)
        if not ok:
            raise ConfigError("surface fixture: the tool's tip has no foot on the surface")
        F, _ = self.surface.frame(u, v)
        M = (F @ _RX_PI).T @ R
        yaw = float(q[3]) + _wrap(math.atan2(M[1, 0], M[0, 0]) - float(q[3]))
        z = np.array([u, v, yaw])
        zd = np.linalg.lstsq(self.jacobian(chart, z), np.asarray(qd, dtype=float), rcond=None)[0]
        return z, zd


def _grid_check(v) -> str | None:
    rows = {len(r) for r in v}
    return None if len(rows) == 1 else "every row of heights_m must have the same length"


@register_fixture("surface_scalpel")
@dataclass(frozen=True)
class SurfaceScalpelSpec:
    """A scalpel cutting at ``depth_m`` below a curved tissue surface: a spline height field
    ``heights_m[i][j]`` (m) over the grid ``x_m[i]``, ``y_m[j]`` (m) of the frame at ``origin_m``
    whose "up" is ``normal`` (its x axis: the plane tangent of ``normal`` that the planar scalpel
    uses). The blade tip is the tool point ``tip_m``; ``knife_edge``: no sideways slip."""

    x_m: tuple[float, ...] = setting(doc="grid x coordinates (strictly increasing), m")
    y_m: tuple[float, ...] = setting(doc="grid y coordinates (strictly increasing), m")
    heights_m: tuple[tuple[float, ...], ...] = setting(check=_grid_check, doc="heights over the grid, m")
    origin_m: tuple[float, float, float] = setting((0.0, 0.0, 0.0), doc="origin of the height field's frame, m")
    normal: tuple[float, float, float] = setting((0.0, 0.0, 1.0), doc="the height field's up direction")
    depth_m: float = setting(0.005, ge=0.0, doc="cutting depth below the surface along its normal, m")
    tip_m: tuple[float, float, float] = setting((0.0, 0.0, 0.0), doc="blade tip in the tool frame, m")
    knife_edge: bool = setting(True, doc="no sideways slip of the blade tip")
    degree: int = setting(5, ge=4, le=5, doc="spline degree each way (third derivatives need 4 or 5)")

    def surface(self, frame: FrameMap | None = None) -> HeightSurface:
        """The tissue surface placed by ``frame`` (None: the patient frame)."""
        frame = FrameMap.identity() if frame is None else frame
        nrm = np.asarray(self.normal, dtype=float)
        if not np.all(np.isfinite(nrm)) or np.linalg.norm(nrm) < 1e-12:
            raise ConfigError(f"fixture.normal: expected a non-zero 3-vector, got {list(self.normal)}")
        Q = plane_frame(nrm / np.linalg.norm(nrm))
        Qm = np.column_stack([frame.direction(Q[:, i]) for i in range(3)])
        return HeightSurface(self.x_m, self.y_m, self.heights_m, frame.point(self.origin_m), Qm,
                             frame.length(1.0), self.degree)

    def build(self, frame: FrameMap) -> Fixture:
        surf = self.surface(frame)
        depth, tip = frame.length(self.depth_m), frame.body_point(self.tip_m)
        kmax = surf.max_curvature()
        if depth * kmax >= 0.5:
            raise ConfigError(f"fixture.depth_m: {self.depth_m} m is too deep for the surface's curvature "
                              f"(radius {1.0 / kmax:.4g} m in this frame): keep depth below half the radius")
        cons = [SurfaceDepth(surf, depth, tip, name="blade_on_surface")]
        if self.knife_edge:
            cons.append(KnifeEdge(point_B=tip, side_B=(0.0, 1.0, 0.0), name="knife_edge"))
        return Fixture("surface_scalpel", tuple(cons), SurfaceScalpel(surf, depth, tip))

    def tissue_surface(self) -> HeightSurface:
        """The patient-frame surface (the slave's tissue and its metrics read it)."""
        return self.surface(None)
