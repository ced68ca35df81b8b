"""The admittance controller of §III: the virtual tool q_v = φ(x) tracks the reference tool q_r.

φ (:class:`Phi`) maps the handle pose X_MH to the virtual tool X_WV with a motion scale and a pose
offset: p_V = p_off + s R_off p_H, R_V = R_off R_H. In world twists φ's Jacobian is constant,
v_V = s R_off v_H, w_V = R_off w_H, so eq. 4 reads f_v = (R_off f / s, R_off τ) and the second-order
term of ẍ = (∂φ/∂x)^-1 (q̈ - ẋᵀ ∂²φ/∂x² ẋ) vanishes.

The feedback (eqs. 18-19) is done chart-free, in world coordinates: e = (p_r - p_v, log(R_r R_vᵀ)),
so a re-chart of the tool's Euler angles never shows up as a jump in the error.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from teleop.control.kernels import pid_step
from teleop.util.errors import ConfigError
from teleop.util.views import view


def _vec6(value, key: str, where: str, positive: bool = False) -> np.ndarray:
    v = np.asarray(value, dtype=float)
    if v.ndim == 0:
        v = np.full(6, float(v))
    if v.shape != (6,) or not np.all(np.isfinite(v)) or np.any(v < 0) or (positive and np.any(v <= 0)):
        raise ConfigError(f"{where}.{key}: expected a finite {'positive' if positive else 'non-negative'} "
                          f"scalar or 6-vector, got {value!r}")
    return v


@dataclass(frozen=True, eq=False)
class Phi:
    """Handle -> virtual tool: scale s (> 0), offset position (3,) m and rotation (3, 3)."""

    scale: float = 1.0
    offset_p: np.ndarray = field(default_factory=lambda: np.zeros(3))
    offset_R: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        s = float(self.scale)
        if not np.isfinite(s) or s <= 0:
            raise ConfigError(f"phi.scale: expected a finite positive motion scale, got {self.scale}")
        p = np.asarray(self.offset_p, dtype=float).reshape(3)
        R = np.asarray(self.offset_R, dtype=float).reshape(3, 3)
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ConfigError("phi.offset_R: expected a rotation matrix")
        object.__setattr__(self, "scale", s)
        object.__setattr__(self, "offset_p", p)
        object.__setattr__(self, "offset_R", R)
        # φ's constant 6x6 maps: twist to virtual, twist to handle, wrench to virtual, to handle
        Z = np.zeros((3, 3))
        maps = tuple(np.block([[a * Ra, Z], [Z, Rb]]) for a, Ra, Rb in (
            (s, R, R), (1.0 / s, R.T, R.T), (1.0 / s, R, R), (s, R.T, R.T)))
        object.__setattr__(self, "_maps", maps)

    def compute_virtual_pose(self, p_H, R_H):
        """q_v = φ(x): (p_V m, R_V)."""
        return self.offset_p + self.scale * (self.offset_R @ p_H), self.offset_R @ R_H

    def compute_handle_pose(self, p_V, R_V):
        """x = φ^-1(q_v): (p_H m, R_H)."""
        return self.offset_R.T @ (np.asarray(p_V) - self.offset_p) / self.scale, self.offset_R.T @ R_V

    def twist_to_virtual(self, nu_H) -> np.ndarray:
        """Twist (6,: m/s, rad/s, world) of the handle -> the virtual tool's."""
        return self._maps[0] @ nu_H

    @property
    def wrench_map_to_virtual(self) -> np.ndarray:
        """The constant 6x6 map of :meth:`wrench_to_virtual` (for compiled callers)."""
        return self._maps[2]

    @property
    def twist_map_to_handle(self) -> np.ndarray:
        """The constant 6x6 map of :meth:`twist_to_handle` (for compiled callers)."""
        return self._maps[1]

    def twist_to_handle(self, nu_V) -> np.ndarray:
        """Twist or twist rate (6,) of the virtual tool -> the handle's (m/s, rad/s [/s])."""
        return self._maps[1] @ nu_V

    def wrench_to_virtual(self, F_H) -> np.ndarray:
        """Eq. 4, f_v = (∂φ/∂x)ᵀ f: handle wrench (N, N*m, world at H) -> at the tool origin."""
        return self._maps[2] @ F_H

    def wrench_to_handle(self, F_V) -> np.ndarray:
        """Inverse of :meth:`wrench_to_virtual`: a wrench at the tool origin -> at the handle."""
        return self._maps[3] @ F_V

    def reindexed(self, p_H, R_H, p_V, R_V) -> Phi:
        """The same scale with the offset that maps the handle pose exactly onto (p_V, R_V)."""
        R_off = R_V @ np.asarray(R_H).T
        return Phi(self.scale, np.asarray(p_V) - self.scale * (R_off @ p_H), R_off)


@dataclass(frozen=True, eq=False)
class AdmittanceGains:
    """PID gains on the world error (6-vectors, or scalars for all six axes).

    kp 1/s^2, ki 1/s^3, kd 1/s; integral_limit (m*s, rad*s); max_accel (m/s^2, rad/s^2) and
    max_velocity (m/s, rad/s) of the virtual tool command.
    """

    kp: np.ndarray = 40000.0
    ki: np.ndarray = 400000.0
    kd: np.ndarray = 400.0
    integral_limit: np.ndarray = 2e-6
    max_accel: np.ndarray = (30.0, 30.0, 30.0, 600.0, 600.0, 600.0)
    max_velocity: np.ndarray = (0.5, 0.5, 0.5, 10.0, 10.0, 10.0)

    def __post_init__(self):
        for key in ("kp", "ki", "kd", "integral_limit"):
            object.__setattr__(self, key, _vec6(getattr(self, key), key, "gains"))
        for key in ("max_accel", "max_velocity"):
            object.__setattr__(self, key, _vec6(getattr(self, key), key, "gains", positive=True))

    def check_stable(self, dt_s: float, where: str = "gains") -> None:
        """Continuous stability (kd kp > ki) and a discrete step limit (kd dt < 1)."""
        if np.any(self.kd * dt_s >= 1.0):
            raise ConfigError(f"{where}.kd: kd*dt must be < 1 for the integrated command, got {self.kd * dt_s}")
        if np.any(self.kd * self.kp <= self.ki):
            raise ConfigError(f"{where}.ki: the PID is unstable unless kd*kp > ki")


class AdmittanceController:
    """Eqs. 18-19 with a velocity-commanded device: the commanded virtual twist ν_c integrates
    q̈_v = q̈_r + Kp e + Ki ∫e + Kd (ν_r - ν_c), so ν_c carries the reference velocity forward.

    Anti-windup: the integral is clamped and is not advanced on an axis whose acceleration or
    velocity command saturates (conditional integration). The period is one compiled kernel,
    :func:`teleop.control.kernels.pid_step`; this object holds its state.
    """

    def __init__(self, gains: AdmittanceGains, dt_s: float, state=None):
        """state (4, 6): where to keep ν_c, q̈_v, e and ∫e (rows, written in place: the cobot's
        host passes a view of its state record, which its compiled period updates); None: own."""
        gains.check_stable(dt_s)
        self.gains, self.dt = gains, float(dt_s)
        self.state = np.zeros((4, 6)) if state is None else state
        self.reset()

    # the state's rows, read as views and assigned in place
    nu_cmd = view("state", 0, "commanded virtual twist ν_c (6,: m/s, rad/s, world)")
    accel_cmd = view("state", 1, "commanded acceleration q̈_v (6,: m/s^2, rad/s^2)")
    error = view("state", 2, "the last error e (6,: m, rad)")
    integral = view("state", 3, "the integral of e (6,: m*s, rad*s)")

    def reset(self, nu0=None) -> None:
        self.integral = 0.0
        self.nu_cmd = 0.0 if nu0 is None else np.asarray(nu0, dtype=float)
        self.accel_cmd = 0.0

    def step(self, p_r, R_r, nu_r, accel_r, p_v, R_v):
        """One period: reference pose/twist at the measurement time, reference acceleration over
        the period (6,), virtual pose -> (ν_c (6,) m/s rad/s, q̈_v (6,) m/s^2 rad/s^2), world
        (copies: the state itself changes with the next period)."""
        g = self.gains
        self.nu_cmd, self.accel_cmd, self.error, self.integral = pid_step(
            np.asarray(p_r, float), np.asarray(R_r, float), np.asarray(nu_r, float), np.asarray(accel_r, float),
            np.asarray(p_v, float), np.asarray(R_v, float), g.kp, g.ki, g.kd, g.integral_limit, g.max_accel,
            g.max_velocity, self.dt, self.integral, self.nu_cmd)
        return self.nu_cmd.copy(), self.accel_cmd.copy()
