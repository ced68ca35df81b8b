"""Parametric descriptions q = psi(z) of constraint manifolds (the paper's §II-D, eqs. 10-11).

A parametrization gives, in an Euler chart, psi(z) -> q (6,), its Jacobian Psi = dpsi/dz (6, k),
the curvature term zd^T (d2psi/dz2) zd (6,), and the inverse map (q, qd) -> (z, zd). The chart is
part of the state: parametrizations marked ``rechartable`` accept any chart placement R0, so the
engine can move the chart away from a singularity (the pole of eq. 25) without leaving the manifold.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import numpy as np

from teleop.dynamics.constraints import plane_tangents
from teleop.dynamics.rotations import EulerChart, axis_rotation, cross
from teleop.util.errors import ConfigError


class Parametrization(ABC):
    """q = psi(z) for one family of holonomic constraints."""

    dim: int = 6
    rechartable: bool = False
    #: True when Psi does not depend on z (then ``jacobian`` may be called with z=None).
    constant_jacobian: bool = False
    #: True when psi is affine in z, so the curvature term is identically zero.
    flat: bool = False

    @abstractmethod
    def initial_chart(self) -> EulerChart:
        """The chart this parametrization is written in."""

    @abstractmethod
    def psi(self, chart: EulerChart, z: np.ndarray) -> np.ndarray:
        """q (6,) for parameters z (dim,)."""

    @abstractmethod
    def jacobian(self, chart: EulerChart, z: np.ndarray) -> np.ndarray:
        """Psi = dpsi/dz, shape (6, dim)."""

    @abstractmethod
    def curvature(self, chart: EulerChart, z: np.ndarray, zd: np.ndarray) -> np.ndarray:
        """zd^T (d2psi/dz2) zd, shape (6,)."""

    @abstractmethod
    def from_q(self, chart: EulerChart, q: np.ndarray, qd: np.ndarray):
        """(z, zd) of a configuration on the manifold and a velocity tangent to it."""


class Identity(Parametrization):
    """No holonomic constraint: z = q in any chart."""

    dim = 6
    rechartable = True
    constant_jacobian = True
    flat = True

    def __init__(self, sequence: str = "ZYX"):
        self._chart = EulerChart(sequence)

    def initial_chart(self):
        return self._chart

    def psi(self, chart, z):
        return np.array(z, dtype=float)

    def jacobian(self, chart, z):
        return np.eye(6)

    def curvature(self, chart, z, zd):
        return np.zeros(6)

    def from_q(self, chart, q, qd):
        return np.array(q, dtype=float), np.array(qd, dtype=float)


def plane_frame(normal: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) whose columns are (t1, t2, n) for the plane tangents of the unit normal n."""
    t1, t2 = plane_tangents(normal)
    return np.column_stack([t1, t2, normal])


class UprightDisk(Parametrization):
    """Example 1 (eq. 17): a disk of radius r upright on a plane. z = (x, y, heading, spin).

    Chart ZXZ placed on the plane: theta = (heading, tilt = pi/2, spin). The paper orders the
    angles (heading q4, spin q5, tilt q6); here the chart order is (heading, tilt, spin).
    """

    dim = 4
    constant_jacobian = True
    flat = True

    def __init__(self, radius: float, origin: np.ndarray, normal: np.ndarray):
        self.r = float(radius)
        self.o = np.asarray(origin, dtype=float)
        self.R_plane = plane_frame(np.asarray(normal, dtype=float))
        P = np.zeros((6, 4))
        P[:3, 0] = self.R_plane[:, 0]
        P[:3, 1] = self.R_plane[:, 1]
        P[3, 2] = 1.0
        P[5, 3] = 1.0
        self._P = P
        # psi is affine: q = q0 + P z, with the axle height r above the origin and the tilt pi/2
        self._q0 = np.zeros(6)
        self._q0[:3] = self.o + self.r * self.R_plane[:, 2]
        self._q0[4] = math.pi / 2

    def initial_chart(self):
        return EulerChart("ZXZ", self.R_plane)

    def psi(self, chart, z):
        return self._q0 + self._P @ z

    def jacobian(self, chart, z):
        return self._P

    def curvature(self, chart, z, zd):
        return np.zeros(6)

    def from_q(self, chart, q, qd):
        d = q[:3] - self.o
        z = np.array([d @ self.R_plane[:, 0], d @ self.R_plane[:, 1], q[3], q[5]])
        zd = np.array([qd[:3] @ self.R_plane[:, 0], qd[:3] @ self.R_plane[:, 1], qd[3], qd[5]])
        return z, zd


class SphereSurface(Parametrization):
    """Example 2 (eq. 25): body origin on a sphere, body z axis radial. z = (t1, t2, t3) = theta.

    Chart ZXZ: the radial unit vector is R0 n(t1, t2), n = Rz(t1) Rx(t2) e_z, and t3 spins about it.
    psi loses rank at the chart's poles (sin t2 = 0); the engine re-charts before it gets there.
    Scalar arithmetic throughout (called twice per step).
    """

    dim = 3
    rechartable = True

    def __init__(self, center: np.ndarray, radius: float):
        self.c = np.asarray(center, dtype=float)
        self.r = float(radius)
        self._c = tuple(self.c.tolist())

    def initial_chart(self):
        return EulerChart("ZXZ")

    @staticmethod
    def _n(a, b):
        """n and its partial derivatives n_a, n_b, n_aa, n_ab, n_bb, each a 3-tuple."""
        sa, ca, sb, cb = math.sin(a), math.cos(a), math.sin(b), math.cos(b)
        return ((sa * sb, -ca * sb, cb), (ca * sb, sa * sb, 0.0), (sa * cb, -ca * cb, -sb),
                (-sa * sb, ca * sb, 0.0), (ca * cb, sa * cb, 0.0), (-sa * sb, ca * sb, -cb))

    def _check(self, chart):
        if chart.sequence != "ZXZ":
            raise ConfigError(f"sphere parametrization needs a ZXZ chart, got {chart.sequence}")

    @staticmethod
    def _R0(chart, x, k: float) -> tuple:
        """k * R0 @ x for a 3-tuple x."""
        m = chart._R0_list
        return (k * (m[0] * x[0] + m[1] * x[1] + m[2] * x[2]),
                k * (m[3] * x[0] + m[4] * x[1] + m[5] * x[2]),
                k * (m[6] * x[0] + m[7] * x[1] + m[8] * x[2]))

    def psi(self, chart, z):
        a, b, t3 = z.tolist()
        x = self._R0(chart, self._n(a, b)[0], self.r)
        c = self._c
        return np.array([c[0] + x[0], c[1] + x[1], c[2] + x[2], a, b, t3])

    def jacobian(self, chart, z):
        _, na, nb, *_ = self._n(float(z[0]), float(z[1]))
        xa, xb = self._R0(chart, na, self.r), self._R0(chart, nb, self.r)
        return np.array([[xa[0], xb[0], 0.0], [xa[1], xb[1], 0.0], [xa[2], xb[2], 0.0],
                         [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])

    def curvature(self, chart, z, zd):
        _, _, _, naa, nab, nbb = self._n(float(z[0]), float(z[1]))
        a, b = float(zd[0]), float(zd[1])
        k1, k2, k3 = a * a, 2.0 * a * b, b * b
        x = self._R0(chart, [k1 * naa[i] + k2 * nab[i] + k3 * nbb[i] for i in range(3)], self.r)
        return np.array([x[0], x[1], x[2], 0.0, 0.0, 0.0])

    def from_q(self, chart, q, qd):
        return np.array(q[3:], dtype=float), np.array(qd[3:], dtype=float)


class ScalpelPlane(Parametrization):
    """The scalpel fixture: blade tip (body point d) at a depth below a plane, blade axis (body z)
    along the inward normal. z = (tip u, tip v, yaw) (m, m, rad), chart ZYX placed at
    R0 = R_plane Rx(pi) so that theta = (yaw, 0, 0) points the blade into the tissue.

    With R(yaw) = R0 Rz(yaw): psi = (o + u t1 + v t2 - depth n - R d, yaw, 0, 0); only the R d
    term depends on yaw, so Psi's third column is -R (e_z x d) and the curvature -R e_z x (e_z x d)
    yawdot^2. Written with the two yaw-dependent columns of R, as the step calls it twice.
    """

    dim = 3

    def __init__(self, origin, normal, depth: float, tip_B):
        self.o = np.asarray(origin, dtype=float)
        self.R_plane = plane_frame(np.asarray(normal, dtype=float))
        self.depth = float(depth)
        self.d = np.asarray(tip_B, dtype=float)
        self.R0 = self.R_plane @ axis_rotation(0, math.pi)
        self._ez = np.array([0.0, 0.0, 1.0])
        self._base = self.o - self.depth * self.R_plane[:, 2] - self.d[2] * self.R0[:, 2]
        # in the plane of R0's first two columns, R d = c (d0 X + d1 Y) + s (d0 Y - d1 X)
        X, Y = self.R0[:, 0], self.R0[:, 1]
        d0, d1 = self.d[0], self.d[1]
        self._Rd_c, self._Rd_s = d0 * X + d1 * Y, d0 * Y - d1 * X
        #: a tip on the blade axis (d0 = d1 = 0, the shipped scalpels): R d does not turn with the
        #: yaw, so psi is affine and its Jacobian constant (the integrator's one-call flat step)
        self.flat = self.constant_jacobian = not (d0 or d1)

    def initial_chart(self):
        return EulerChart("ZYX", self.R0)

    def _rot(self, yaw):
        return self.R0 @ axis_rotation(2, yaw)

    def _planar_Rd(self, yaw):
        """(R d minus its yaw-independent part, its yaw derivative) (3,), (3,)."""
        c, s = math.cos(yaw), math.sin(yaw)
        return c * self._Rd_c + s * self._Rd_s, c * self._Rd_s - s * self._Rd_c

    def psi(self, chart, z):
        u, v, yaw = z.tolist()
        Rd, _ = self._planar_Rd(yaw)
        q = np.zeros(6)
        q[:3] = self._base + u * self.R_plane[:, 0] + v * self.R_plane[:, 1] - Rd
        q[3] = yaw
        return q

    def jacobian(self, chart, z):
        _, dRd = self._planar_Rd(0.0 if z is None else float(z[2]))  # None: a flat psi's constant P
        P = np.zeros((6, 3))
        P[:3, 0] = self.R_plane[:, 0]
        P[:3, 1] = self.R_plane[:, 1]
        P[:3, 2] = -dRd
        P[3, 2] = 1.0
        return P

    def curvature(self, chart, z, zd):
        Rd, _ = self._planar_Rd(float(z[2]))
        out = np.zeros(6)
        out[:3] = Rd * float(zd[2]) ** 2  # -(d2/dyaw2 of R d) = +(planar R d)
        return out

    def from_q(self, chart, q, qd):
        R = self._rot(q[3])
        tip = q[:3] + R @ self.d
        w = R @ (self._ez * qd[3])
        v_tip = qd[:3] + cross(w, R @ self.d)
        t1, t2 = self.R_plane[:, 0], self.R_plane[:, 1]
        z = np.array([t1 @ (tip - self.o), t2 @ (tip - self.o), q[3]])
        zd = np.array([t1 @ v_tip, t2 @ v_tip, qd[3]])
        return z, zd
