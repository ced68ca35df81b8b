"""The master interface the bilateral tick (:mod:`teleop.tick.loop`) talks to, and its life cycle.

A master stands between the operator's hand and the reference tool: it senses the hand's wrench
(for the cobot, over the bus and through the load cell and eq. 4) and commands the device to
follow the tool (eqs. 18-19). Poses are (p (3,) m, R (3, 3)), twists (v (3,) m/s, w (3,) rad/s),
wrenches (6,: N, N*m), all in the master's world frame.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np


class Master(ABC):
    """``with master:`` brings the device up (``start``) and always releases it (``close``).
    ``status`` is "ok" or the fault that stopped the master."""

    status: str = "ok"

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.close()

    @abstractmethod
    def start(self) -> None:
        """Bring the device up; idempotent."""

    @abstractmethod
    def close(self) -> None:
        """Release the device (its safe state); safe to call twice."""

    @abstractmethod
    def set_clutch(self, engaged: bool) -> None:
        """Clutch in (the hand drives the tool) or out (it lets go)."""

    @abstractmethod
    def hand_state(self):
        """(p, R, v, w) of what the hand holds (the handle)."""

    @abstractmethod
    def sense(self, hand_wrench_W) -> np.ndarray:
        """The wrench (6,) the hand puts on the reference tool this tick."""

    @abstractmethod
    def command(self, p_r, R_r, nu_r, a_r) -> str:
        """Make the device follow the reference tool's pose, twist nu_r (6,) and acceleration a_r
        (6,: m/s^2, rad/s^2); returns the master's status."""

    @abstractmethod
    def virtual_pose(self):
        """(p, R) of the virtual tool (the device's rendering of the reference tool)."""

    @abstractmethod
    def virtual_twist(self):
        """(v, w) of the virtual tool."""

    @abstractmethod
    def virtual_estimate(self):
        """(p, R, v, w) of the virtual tool as sent to the slave."""

    def joints(self):
        """The device's joint positions (rad or m), or None without a device."""
        return None

    def stats(self) -> dict:
        """Counters for the run's summary."""
        return {}
