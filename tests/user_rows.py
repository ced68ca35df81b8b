"""A user's own constraint for tests: a Python-only row (no compiled kernel), not polynomial in
the pose, so it exercises the path a user's constraint takes through the RowStack."""

import numpy as np

from teleop.dynamics import constraints as C


class SineRow(C.Constraint):
    """h = sin(5 (p_x - x0)) / 5 (m), zero at p_x = x0."""

    rows, holonomic = 1, True

    def __init__(self, x0: float):
        self.x0 = x0

    def jacobian(self, p, R):
        return np.array([[np.cos(5.0 * (p[0] - self.x0)), 0, 0, 0, 0, 0]])

    def residual(self, p, R):
        return np.array([np.sin(5.0 * (p[0] - self.x0)) / 5.0])

    def bias(self, p, R, v, w):
        return np.array([-5.0 * np.sin(5.0 * (p[0] - self.x0)) * v[0] ** 2])
