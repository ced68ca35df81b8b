"""The master clutch: while released the handle moves without moving the tool; on re-engage φ is
re-indexed so that φ(x) equals the tool's pose exactly, so nothing jumps (position or rotation)."""

from __future__ import annotations

from teleop.control.admittance import Phi


class Clutch:
    """Holds the current φ. ``engaged`` is False between :meth:`release` and :meth:`engage`."""

    def __init__(self, phi: Phi):
        self.phi = phi
        self.engaged = True
        self.reindex_count = 0

    def release(self) -> None:
        self.engaged = False

    def engage(self, p_H, R_H, p_tool, R_tool) -> Phi:
        """Re-engage with the handle at (p_H m, R_H) and the tool at (p_tool m, R_tool)."""
        if not self.engaged:
            self.phi = self.phi.reindexed(p_H, R_H, p_tool, R_tool)
            self.reindex_count += 1
        self.engaged = True
        return self.phi
