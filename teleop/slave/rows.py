"""Fixture rows on the slave's tool frame, evaluated for all constraints with two matrix products.

Every constraint of ``teleop.dynamics.constraints`` has rows G(p, R) (rows, 6) and, when holonomic,
a residual h(p, R) (rows,) that are polynomials of degree <= 2 in the entries of the pose matrix

    T = [[R, p], [0, 1]]   (4, 4; p in m),

for R on SO(3): they are built from R a_B, world vectors, p and cross and dot products of those,
and (R a) x (R b) = R (a x b), (R a) . (R b) = a . b. Each is therefore  u' C_k t  with
u = T[:, 3] = (p, 1), t = T.ravel() and a constant C_k (4, 16) per row entry k.
:class:`FixtureRows` identifies C from the constraints' own ``jacobian``/``residual`` at random
poses (least squares: the constraint classes stay the only definition of the rows), checks it at
other random poses, and per tick needs only two products instead of a Python call per constraint.
A constraint that is not of this form (the check fails) is evaluated by its own methods.

Why not the engine's row kernels (:mod:`teleop.dynamics.kernels.rows`): those cover the built-in
kinds only and give G and the velocity product, not h. The fit covers any constraint whose rows are
of this form, a user's own included, and gives G and h from one product.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

_FIT_POSES, _CHECK_POSES = 128, 16
_TOL = 1e-9  # fit error allowed at the check poses, relative to the rows' size (1 + |G|, |h|)


def _pose_matrix(p, R) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def _random_poses(rng, k: int, scale_m: float):
    """k poses: rotations spread over SO(3), positions in a cube of half-width ``scale_m``."""
    return [(rng.uniform(-scale_m, scale_m, 3), pin.exp3(rng.normal(size=3) * 2.0)) for _ in range(k)]


def _rows(c, p, R) -> np.ndarray:
    """(rows, 7): G and h (0 for nonholonomic rows) of one constraint."""
    out = np.zeros((c.rows, 7))
    out[:, :6] = c.jacobian(p, R)
    if c.holonomic:
        out[:, 6] = c.residual(p, R)
    return out


def _fit(c, scale_m: float, seed: int):
    """C (rows * 7 * 4, 16) with rows(p, R).ravel() = (C t).reshape(-1, 4) @ u, or None when
    the rows are not of that form."""
    rng = np.random.default_rng(seed)
    fit, check = _random_poses(rng, _FIT_POSES, scale_m), _random_poses(rng, _CHECK_POSES, scale_m)

    def features(p, R):
        T = _pose_matrix(p, R)
        return np.outer(T[:, 3], T.ravel()).ravel()

    try:  # a constraint that cannot be evaluated at any pose is left to its own methods
        Y = np.array([_rows(c, p, R).ravel() for p, R in fit])
    except (ArithmeticError, ValueError):
        return None
    if not np.all(np.isfinite(Y)):
        return None
    # features repeat (p appears in u and in t): lstsq takes the minimum-norm coefficients
    C = np.linalg.lstsq(np.array([features(p, R) for p, R in fit]), Y, rcond=None)[0].T
    for p, R in check:
        try:
            rows = _rows(c, p, R).ravel()
        except (ArithmeticError, ValueError):
            return None
        if not np.all(np.abs(C @ features(p, R) - rows) <= _TOL * (1.0 + np.abs(rows).max())):
            return None
    return C.reshape(-1, 16)


class FixtureRows:
    """The stacked rows of a tuple of constraints, G (m, 6), and their scaled residuals
    ``h_scale`` h (m,), holonomic residuals in m or rad and 0 on nonholonomic rows.

    ``scale_m`` is the size of the region (m) where the identification samples positions; any
    size gives the same rows, one near the work space keeps the fit's rounding small.
    """

    def __init__(self, constraints, h_scale: float = 1.0, scale_m: float = 2.0, seed: int = 0):
        self.constraints = tuple(constraints)
        self.m = sum(c.rows for c in self.constraints)
        self.h_scale = float(h_scale)
        C = np.zeros((self.m, 7, 4, 16))  # directly evaluated constraints keep zero rows here
        self._direct = []  # (constraint, first row) of those evaluated by their own methods
        i = 0
        for k, c in enumerate(self.constraints):
            Ck = _fit(c, scale_m, seed + k)
            if Ck is None:
                self._direct.append((c, i))
            else:
                C[i : i + c.rows] = Ck.reshape(c.rows, 7, 4, 16)
            i += c.rows
        C[:, 6] *= self.h_scale
        # ordered so that the product is (G.ravel(), h_scale h)
        self._C = np.concatenate([C[:, :6].reshape(-1, 16), C[:, 6].reshape(-1, 16)])
        self._Ct = np.empty(self.m * 7 * 4)
        self._Ct4 = self._Ct.reshape(self.m * 7, 4)

    @property
    def coefficients(self) -> np.ndarray:
        """C (28 m, 16): the fitted rows, ``h_scale`` folded in, as
        :func:`teleop.slave.kernels.fixture_rows` reads them (zero rows for ``direct`` ones)."""
        return self._C

    def coefficients_of(self, rows, h_scale: float = 1.0) -> np.ndarray:
        """The coefficients (28 k, 16) of the k rows ``rows`` (indices into the m rows), with
        ``h_scale`` in place of this object's: the same fit, no new identification."""
        rows, m = np.asarray(rows, dtype=int), self.m
        G = self._C[: 24 * m].reshape(m, 24, 16)[rows].reshape(-1, 16)
        h = self._C[24 * m :].reshape(m, 4, 16)[rows].reshape(-1, 16) * (h_scale / self.h_scale)
        return np.concatenate([G, h])

    @property
    def direct(self) -> tuple:
        """The constraints evaluated by their own methods each tick (not of the fitted form)."""
        return tuple(c for c, _ in self._direct)

    def evaluate(self, p: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(G (m, 6), h_scale h (m,)) at the pose p (m), R = R_WB, as new arrays."""
        out = np.empty(7 * self.m)
        self.evaluate_into(_pose_matrix(p, R), out)
        return out[: 6 * self.m].reshape(self.m, 6), out[6 * self.m :]

    def evaluate_into(self, T: np.ndarray, out: np.ndarray) -> None:
        """Write (G.ravel(), h_scale h), shape (7 m,), into the contiguous ``out`` at the pose
        matrix T (4, 4)."""
        np.dot(self._C, T.reshape(16), out=self._Ct)
        np.dot(self._Ct4, T[:, 3], out=out)
        m = self.m
        for c, i in self._direct:
            rows = _rows(c, T[:3, 3], T[:3, :3])
            out[6 * i : 6 * (i + c.rows)] = rows[:, :6].ravel()
            out[6 * m + i : 6 * m + i + c.rows] = self.h_scale * rows[:, 6]
