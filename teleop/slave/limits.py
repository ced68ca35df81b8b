"""Joint limits of the slave arm, turned into bounds on the joint velocity of one tick.

One class holds the limits (positions rad, velocities rad/s, accelerations rad/s^2); its pure
``compute_velocity_bounds`` turns them into a box  lb <= qd <= ub  for the next tick of length dt:

* position: the joint must stop before its limit under the acceleration limit,
  |qd| <= sqrt(2 a d) with d the distance left (rad), and must not cross it within the tick,
  |qd| <= d / dt;
* velocity: |qd| <= v_max;
* acceleration: |qd - qd_prev| <= a_max dt.

Position and velocity bounds always contain 0 (a joint already beyond its limit is only allowed to
come back). When the acceleration box does not meet them (e.g. after an external jump), the bound
collapses onto the point of the position/velocity box nearest to ``qd_prev``: the limits of
position and velocity win over the acceleration limit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teleop.slave.kernels import at_position_limit, velocity_bounds
from teleop.util.errors import ConfigError


@dataclass(frozen=True, eq=False)
class JointLimits:
    """q_min, q_max (rad), v_max (rad/s), a_max (rad/s^2), each shape (nv,); margin_rad >= 0 is
    kept free inside both position limits."""

    q_min: np.ndarray
    q_max: np.ndarray
    v_max: np.ndarray
    a_max: np.ndarray
    margin_rad: float = 0.0

    def __post_init__(self):
        arrs = {}
        for key in ("q_min", "q_max", "v_max", "a_max"):
            a = np.asarray(getattr(self, key), dtype=float).reshape(-1)
            if np.any(np.isnan(a)):
                raise ConfigError(f"slave.limits.{key}: NaN in {a.tolist()}")
            arrs[key] = a
            object.__setattr__(self, key, a)
        n = arrs["q_min"].shape[0]
        if any(a.shape != (n,) for a in arrs.values()):
            raise ConfigError(f"slave.limits: shapes differ: { {k: a.shape for k, a in arrs.items()} }")
        if np.any(arrs["q_min"] + 2 * self.margin_rad >= arrs["q_max"]):
            raise ConfigError("slave.limits.q_min: must be below q_max (with the margin on both sides)")
        for key in ("v_max", "a_max"):
            if np.any(arrs[key] <= 0.0) or not np.all(np.isfinite(arrs[key])):
                raise ConfigError(f"slave.limits.{key}: expected finite positive values, got {arrs[key].tolist()}")
        if not np.isfinite(self.margin_rad) or self.margin_rad < 0:
            raise ConfigError(f"slave.limits.margin_rad: expected >= 0, got {self.margin_rad}")
        #: (4, nv): q_min, q_max (rad), v_max (rad/s), a_max (rad/s^2), as the kernels take them
        object.__setattr__(self, "packed", np.array([arrs["q_min"], arrs["q_max"], arrs["v_max"], arrs["a_max"]]))

    @property
    def nv(self) -> int:
        return self.q_min.shape[0]

    def compute_velocity_bounds(self, q: np.ndarray, qd_prev: np.ndarray, dt: float):
        """(lb, ub) in rad/s for the joint velocity held over the next tick of ``dt`` s (new arrays;
        one compiled call, :func:`teleop.slave.kernels.velocity_bounds`)."""
        lb, ub = np.empty(self.q_min.shape[0]), np.empty(self.q_min.shape[0])
        velocity_bounds(np.asarray(q, dtype=float), np.asarray(qd_prev, dtype=float), float(dt), self.q_min,
                        self.q_max, float(self.margin_rad), self.v_max, self.a_max, lb, ub)
        return lb, ub

    def at_limit(self, q: np.ndarray, dt: float) -> np.ndarray:
        """Per joint (bool, nv): at a position limit, i.e. within one tick at its velocity limit
        (v_max dt, rad) of q_min + margin or q_max - margin, or past it. There the tick's
        no-crossing cap (room / dt in :func:`teleop.slave.kernels.velocity_bounds`) is tighter than
        the velocity limit: the stop, not the joint's speed, decides how far it may move. One
        compiled call (:func:`teleop.slave.kernels.at_position_limit`)."""
        return at_position_limit(np.asarray(q, dtype=float), self.q_min, self.q_max, self.v_max,
                                 float(self.margin_rad), float(dt))

    def clip_position(self, q: np.ndarray) -> np.ndarray:
        """q clipped into [q_min, q_max] (rad)."""
        return np.clip(q, self.q_min, self.q_max)
