"""The ideal master: a device that renders the reference tool perfectly.

The operator's wrench reaches the reference tool unchanged (eq. 4 with φ the identity), and the
virtual tool *is* the reference tool: the ideal master only reads the tool, it never steps it.
"""

from __future__ import annotations

import math

import numpy as np

from teleop.master.base import Master


class IdealMaster(Master):
    """The master interface (:class:`teleop.master.base.Master`) for a perfect device."""

    def __init__(self, tool, dt_s: float):
        self.tool, self.dt_s = tool, float(dt_s)
        self.engaged = True
        self.status = "ok"
        self._zero = np.zeros(6)

    def start(self) -> None:
        """Nothing to bring up."""

    def close(self) -> None:
        """Nothing to release; safe to call twice."""

    def set_clutch(self, engaged: bool) -> None:
        """Clutch out: the hand lets go of the tool (its wrench no longer reaches it)."""
        self.engaged = bool(engaged)

    def hand_state(self):
        """(p (3,) m, R (3, 3), v (3,) m/s, w (3,) rad/s): the hand holds the tool itself."""
        return (*self.tool.pose(), *self.tool.twist())

    def sense(self, hand_wrench_W) -> np.ndarray:
        """The wrench (6,: N, N*m, world) that reaches the tool: the hand's, or zero when the clutch
        is out or the input is not 6 finite numbers."""
        if not self.engaged:
            return self._zero
        w = np.asarray(hand_wrench_W, dtype=float)
        if w.shape != (6,) or not math.isfinite(float(w @ w)):
            return self._zero
        return w

    def command(self, p_r, R_r, nu_r, a_r) -> str:
        """A perfect device follows the tool by itself: nothing to command."""
        return self.status

    def virtual_pose(self):
        return self.tool.pose()

    def virtual_twist(self):
        return self.tool.twist()

    def virtual_estimate(self):
        """(p, R, v, w) of the virtual tool for the slave: here the tool itself."""
        return (*self.tool.pose(), *self.tool.twist())
