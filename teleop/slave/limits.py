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

from teleop.errors import ConfigError

_SIDES = np.array([[-1.0], [1.0]])  # room above: (q_max - margin) - q; below: q - (q_min + margin)


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
        # for compute_velocity_bounds, stacked (2, nv): row 0 the upper side, row 1 the lower one
        # (negated), so that both sides take the same formulas
        edge = np.array([arrs["q_max"] - self.margin_rad, -(arrs["q_min"] + self.margin_rad)])
        object.__setattr__(self, "_edge", edge)
        object.__setattr__(self, "_two_a", np.array([2.0 * arrs["a_max"]] * 2))
        object.__setattr__(self, "_v2", np.array([arrs["v_max"]] * 2))
        object.__setattr__(self, "_neg_v", -arrs["v_max"])
        object.__setattr__(self, "_by_dt", {})  # dt -> _for_dt(dt)

    @property
    def nv(self) -> int:
        return self.q_min.shape[0]

    def _for_dt(self, dt: float):
        """(a_max dt (nv,) rad/s, q_lo, q_hi (nv,) rad): with q_lo < q < q_hi, each joint is at least
        v_max dt and v_max^2 / (2 a_max) inside its limits, so only the velocity limit binds."""
        if dt not in self._by_dt:
            if len(self._by_dt) > 16:
                self._by_dt.clear()
            far = np.maximum(self._v2 * dt, self._v2**2 / self._two_a) * (1.0 + 1e-12)
            self._by_dt[dt] = (self.a_max * dt, -(self._edge[1] - far[1]), self._edge[0] - far[0])
        return self._by_dt[dt]

    def compute_velocity_bounds(self, q: np.ndarray, qd_prev: np.ndarray, dt: float):
        """(lb, ub) in rad/s for the joint velocity held over the next tick of ``dt`` s."""
        a_dt, q_lo, q_hi = self._by_dt[dt] if dt in self._by_dt else self._for_dt(dt)
        if np.count_nonzero((q <= q_lo) | (q >= q_hi)):  # near a limit: stop in time, do not cross it
            room = self._edge + _SIDES * q  # rad left above, below (negative beyond the limit)
            cap = np.minimum(room / dt, np.sqrt(self._two_a * np.maximum(room, 0.0)))
            np.minimum(cap, self._v2, out=cap)
            # caps on (qd, -qd), containing 0; when q is not finite only the velocity limit is known
            cap = np.where(np.isfinite(cap), np.maximum(cap, 0.0), self._v2)
            ub_pv, lb_pv = cap[0], -cap[1]
        else:
            ub_pv, lb_pv = self.v_max, self._neg_v
        lb = np.maximum(lb_pv, qd_prev - a_dt)  # with the acceleration box
        ub = np.minimum(ub_pv, qd_prev + a_dt)
        if np.count_nonzero(lb > ub):  # empty: collapse onto the p/v box's point nearest qd_prev
            empty = lb > ub
            nearest = np.clip(qd_prev, lb_pv, ub_pv)
            lb = np.where(empty, nearest, lb)
            ub = np.where(empty, nearest, ub)
        return lb, ub

    def clip_position(self, q: np.ndarray) -> np.ndarray:
        """q clipped into [q_min, q_max] (rad)."""
        return np.clip(q, self.q_min, self.q_max)
