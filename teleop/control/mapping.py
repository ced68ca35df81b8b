"""Master-to-slave mapping: registration X_PM, motion scaling, constraints and force feedback.

Frames: M the master workspace, P the patient frame (the slave's world W). The registration X_PM
(p_PM m, R_PM) places M in P. Motion is scaled down by ``scale`` (master : slave, e.g. 3.0 for 3:1):
a master point x_M maps to

    x_P = p_PM + R_PM x_M / scale,

so a master twist (v, w) maps to (R_PM v / scale, R_PM w): rotations are not scaled. The reference
tool's body frame maps onto the slave's tool frame E, so body points scale by 1/scale as well.

``master_frame`` is the one map of patient-frame geometry into M (points through the inverse map,
directions rotated by R_PM', lengths and body points times ``scale``): a fixture type builds the
master's fixture through it and the slave's through the identity, so one definition serves both.
``wrench_to_master`` scales the slave's contact wrench back to the master: forces by ``force_scale``
and torques by ``torque_scale`` (default force_scale * scale, since lever arms at the master are
``scale`` times longer).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teleop.control.kernels import damping_to_master, point_to_patient, target_to_patient
from teleop.dynamics.registry import FrameMap
from teleop.util.errors import ConfigError


def _rotation(R, name: str) -> np.ndarray:
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ConfigError(f"{name}: expected a finite 3x3 rotation, got shape {R.shape}")
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise ConfigError(f"{name}: not a rotation (R'R != I or det < 0)")
    return R


@dataclass(frozen=True, eq=False)
class Registration:
    """X_PM = (X_PM_p m, X_PM_R), ``scale`` master:slave (> 0), feedback gains (dimensionless,
    torque_scale in (N*m at M)/(N*m at P))."""

    X_PM_p: np.ndarray
    X_PM_R: np.ndarray
    scale: float = 1.0
    force_scale: float = 1.0
    torque_scale: float | None = None

    def __post_init__(self):
        p = np.asarray(self.X_PM_p, dtype=float).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ConfigError(f"mapping.X_PM_p: expected a finite 3-vector, got {self.X_PM_p!r}")
        object.__setattr__(self, "X_PM_p", p)
        object.__setattr__(self, "X_PM_R", _rotation(self.X_PM_R, "mapping.X_PM_R"))
        for key in ("scale", "force_scale"):
            x = getattr(self, key)
            if not isinstance(x, (int, float)) or not np.isfinite(x) or x <= 0:
                raise ConfigError(f"mapping.{key}: expected a finite positive number, got {x!r}")
        if self.torque_scale is None:
            object.__setattr__(self, "torque_scale", float(self.force_scale * self.scale))
        elif not np.isfinite(self.torque_scale) or self.torque_scale <= 0:
            raise ConfigError(f"mapping.torque_scale: expected a finite positive number, got {self.torque_scale!r}")
        Rb = np.zeros((6, 6))
        Rb[:3, :3] = Rb[3:, 3:] = self.X_PM_R
        g = np.array([self.force_scale] * 3 + [self.torque_scale] * 3)
        c = np.array([1.0 / self.scale] * 3 + [1.0] * 3)
        object.__setattr__(self, "_damping_map", (Rb, g[:, None] * c[None, :]))  # damping_to_master's factors
        object.__setattr__(self, "_wrench_map", g[:, None] * Rb.T)  # wrench_to_master's: W_M = B W_P

    # -- poses and twists -------------------------------------------------------------------
    def point_to_patient(self, x_M) -> np.ndarray:
        """A master point x_M (3,) m in the patient frame (m): p_PM + R_PM x_M / scale (compiled,
        :func:`teleop.control.kernels.point_to_patient`, the map ``target`` uses)."""
        return point_to_patient(self.X_PM_p, self.X_PM_R, float(self.scale), np.asarray(x_M, dtype=float))

    def point_to_master(self, x_P) -> np.ndarray:
        return self.scale * (self.X_PM_R.T @ (np.asarray(x_P, dtype=float) - self.X_PM_p))

    def target(self, p_r, R_r, v_r, w_r):
        """Reference tool pose/twist in M (p_r m, R_r, v_r m/s, w_r rad/s) -> slave tool target
        (p m, R, v m/s, w rad/s) in P, new arrays: one compiled call
        (:func:`teleop.control.kernels.target_to_patient`)."""
        f, out = float, np.empty(18)
        target_to_patient(self.X_PM_p, self.X_PM_R, f(self.scale), np.asarray(p_r, f), np.asarray(R_r, f),
                          np.asarray(v_r, f), np.asarray(w_r, f), out)
        return out[0:3], out[3:12].reshape(3, 3), out[12:15], out[15:18]

    def master_frame(self) -> FrameMap:
        """Where patient-frame geometry lands in the master workspace: the one map that fixture
        types (:mod:`teleop.dynamics.registry`) use to build the master's fixture."""
        Rt = self.X_PM_R.T
        return FrameMap(Rt, -Rt @ self.X_PM_p, self.scale)

    def pose_to_master(self, p, R_P):
        """Slave tool pose in P -> reference tool pose in M (the inverse of ``target``'s pose)."""
        return self.point_to_master(p), self.X_PM_R.T @ np.asarray(R_P, float)

    def wrench_to_master(self, F_P) -> np.ndarray:
        """Slave contact wrench (6,: N, N*m; P axes) -> wrench to render at the master (M axes):
        forces times ``force_scale``, torques times ``torque_scale``, both rotated by R_PM^T (one
        product with the 6 x 6 map made at construction)."""
        return self._wrench_map @ np.asarray(F_P, dtype=float)

    def twist_to_master(self, V_P) -> np.ndarray:
        """Slave tool twist (6,: m/s, rad/s; P axes) -> master twist (M axes): the inverse of
        ``target``'s twist (translations times ``scale``, rotations unscaled)."""
        V_P = np.asarray(V_P, dtype=float)
        Rt = self.X_PM_R.T
        return np.concatenate((self.scale * (Rt @ V_P[:3]), Rt @ V_P[3:]))

    def damping_to_master(self, D_P) -> np.ndarray:
        """A contact damping D (6, 6; W_P = -D V_P) -> the damping the master feels, D_M = B D T
        with W_M = B W_P (``wrench_to_master``) and V_P = T V_M (``target``); its symmetric part
        (D_M is symmetric when ``torque_scale`` is ``force_scale * scale``, the default)."""
        Rb, gc = self._damping_map
        return damping_to_master(Rb, gc, np.asarray(D_P, dtype=float))  # one compiled call
