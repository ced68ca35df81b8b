"""The row stack both sides evaluate: G, the velocity-product term b and the residual h of a
tuple of constraints, at a pose (and twist), into workspaces allocated once.

Built-in constraints (those :func:`teleop.dynamics.constraints.compiled_kind` names a kernel for)
are evaluated by one compiled call for the whole stack (:func:`teleop.dynamics.kernels.rows.stack_rows`);
any other :class:`~teleop.dynamics.constraints.Constraint` by its own Python methods into the same
arrays. The master's reference tool and the slave's follower both read their rows here.

Conventions: pose (p (3,) m, R = R_WB (3, 3)), twist (v (3,) m/s, w (3,) rad/s) world, at the body
origin; G (m, 6) acts on (v, w); b (m,) = d/dt(G) (v, w) in m/s^2 or rad/s^2; h (m,) in m or rad.
"""

from __future__ import annotations

import numpy as np

from teleop.dynamics.constraints import compiled_kind
from teleop.dynamics.kernels.rows import NPAR, stack_rows


class RowStack:
    """The rows of ``constraints`` (a sequence of Constraint), in order.

    ``m``: total rows; ``holonomic_mask`` (m,) bool; ``constraints``: the tuple;
    ``compiled_mask`` (len(constraints),) bool: which constraints run in the compiled kernel.
    """

    def __init__(self, constraints):
        self.constraints = tuple(constraints)
        self.m = int(sum(c.rows for c in self.constraints))
        mask, table, params, python = [], [], [], []
        r = 0
        for c in self.constraints:
            kind = compiled_kind(c)
            if kind is None:
                python.append((r, r + c.rows, c))
            else:
                table.append((kind, r))
                params.append(np.asarray(c.kernel_params(), dtype=float).reshape(NPAR))
            mask += [bool(c.holonomic)] * c.rows
            r += c.rows
        self.holonomic_mask = np.array(mask, dtype=bool)
        self.compiled_mask = np.array([compiled_kind(c) is not None for c in self.constraints], dtype=bool)
        #: (k, 2) int64 (kind, first row) and (k, NPAR) parameters of the compiled constraints
        self.table = np.array(table, dtype=np.int64).reshape(len(table), 2)
        self.params = np.array(params, dtype=float).reshape(len(params), NPAR)
        #: (first row, end row, constraint) of the constraints evaluated by their Python methods
        self.python_rows = tuple(python)
        self._G = np.zeros((self.m, 6))
        self._b = np.zeros(self.m)
        self._h = np.zeros(self.m)
        self._zero3 = np.zeros(3)

    @property
    def workspaces(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(G (m, 6), b (m,), h (m,)): the arrays :meth:`evaluate` fills and returns, for a kernel
        that evaluates the compiled rows itself (:func:`teleop.dynamics.kernels.rows.stack_rows`)."""
        return self._G, self._b, self._h

    def evaluate(self, p, R, v=None, w=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(G (m, 6), b (m,), h (m,)) at pose (p, R) and twist (v, w): b is zero when v, w are
        None, h is zero on nonholonomic rows. The arrays are this stack's workspaces, valid until
        the next call (copy them to keep them)."""
        G, b, h = self._G, self._b, self._h
        moving = v is not None
        if not moving:
            v = w = self._zero3
        if self.table.shape[0]:
            stack_rows(self.table, self.params, p, R, v, w, G, b, h)
        for i, j, c in self.python_rows:
            G[i:j] = c.jacobian(p, R)
            b[i:j] = c.bias(p, R, v, w) if moving else 0.0
            h[i:j] = c.residual(p, R) if c.holonomic else 0.0
        return G, b, h
