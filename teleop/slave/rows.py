"""Interim stand-in for :class:`teleop.dynamics.rows.RowStack` (the engine's one evaluation of the
constraint rows), evaluated by the constraints' own methods; replaced by the engine's on merge."""

from __future__ import annotations

import numpy as np


class RowStack:
    """G (m, 6), b (m,) and h (m,) of a tuple of constraints, written into arrays owned here."""

    def __init__(self, constraints):
        self.constraints = tuple(constraints)
        self.m = sum(c.rows for c in self.constraints)
        self.holonomic_mask = np.concatenate(
            [np.full(c.rows, c.holonomic) for c in self.constraints]) if self.constraints else np.zeros(0, bool)
        self._G, self._b, self._h = np.zeros((self.m, 6)), np.zeros(self.m), np.zeros(self.m)

    def evaluate(self, p, R, v=None, w=None):
        i = 0
        for c in self.constraints:
            self._G[i : i + c.rows] = c.jacobian(p, R)
            if c.holonomic:
                self._h[i : i + c.rows] = c.residual(p, R)
            if v is not None:
                self._b[i : i + c.rows] = c.bias(p, R, v, w)
            i += c.rows
        return self._G, self._b, self._h
