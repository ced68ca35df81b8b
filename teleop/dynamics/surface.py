"""A curved surface for fixtures and tissue: a B-spline height field placed in the world.

The surface is a quintic (or quartic) tensor-product B-spline height field ``f(u, v)`` (scipy's
:class:`scipy.interpolate.RectBivariateSpline`, interpolating a grid of heights), placed by a frame:

    S(u, v) = o + k Q (u, v, f(u, v))        (m)

with ``o`` (3,) the frame origin (m), ``Q`` (3, 3) a rotation whose third column is the outward
"up" of the height field, ``k`` > 0 a length scale (the master's copy of a patient-frame surface is
the same spline with ``k`` = the mapping's scale) and (u, v) the surface parameters in the grid's
own units (m of the patient frame). Everything a fixture or a tissue needs is computed once, in
compiled code from scipy's knots and coefficients (:mod:`teleop.dynamics.kernels.surface`): S and
its partial derivatives to third order, the unit normal n = (S_u x S_v)/|S_u x S_v| and its first
derivatives, a tangent frame, and the closest point (foot) of a world point by Newton's method on
(p - S) . S_i = 0.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import RectBivariateSpline

from teleop.dynamics.kernels import surface as SK
from teleop.util.errors import ConfigError


class HeightSurface:
    """A spline height field ``heights[i][j] = f(x[i], y[j])`` (m) placed by (origin, Q, scale).

    ``degree``: the spline's degree in each direction (4 or 5): the rows' velocity-product terms use
    third derivatives, which scipy's fitpack evaluates only below the degree.
    """

    def __init__(self, x, y, heights, origin=(0.0, 0.0, 0.0), Q=None, scale: float = 1.0, degree: int = 5):
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        H = np.asarray(heights, dtype=float)
        if x.ndim != 1 or y.ndim != 1 or H.shape != (x.size, y.size):
            raise ConfigError(f"surface: heights must be a {x.size} x {y.size} grid over x_m and y_m, "
                              f"got shape {H.shape}")
        if not (np.all(np.isfinite(H)) and np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            raise ConfigError("surface: grid and heights must be finite")
        if degree not in (4, 5):
            raise ConfigError("surface.degree: expected 4 or 5 (third derivatives need a degree above 3), "
                              f"got {degree}")
        if x.size <= degree or y.size <= degree:
            raise ConfigError(f"surface: a degree-{degree} spline needs more than {degree} grid points "
                              f"each way, got {x.size} x {y.size}")
        if np.any(np.diff(x) <= 0) or np.any(np.diff(y) <= 0):
            raise ConfigError("surface: x_m and y_m must be strictly increasing")
        self.x, self.y, self.heights, self.degree = x, y, H, int(degree)
        self.spline = RectBivariateSpline(x, y, H, kx=degree, ky=degree, s=0.0)
        self.o = np.ascontiguousarray(origin, dtype=float)
        self.Q = np.eye(3) if Q is None else np.ascontiguousarray(Q, dtype=float)
        self.k = float(scale)
        tx, ty, c = self.spline.tck
        self._geo = (self.o, np.ascontiguousarray(self.k * self.Q), np.ascontiguousarray(tx, dtype=float),
                     np.ascontiguousarray(ty, dtype=float),
                     np.ascontiguousarray(np.reshape(c, (tx.size - degree - 1, ty.size - degree - 1)), dtype=float),
                     int(degree))
        self.bounds = (x[0], x[-1], y[0], y[-1])

    def placed(self, origin, Q, scale: float) -> HeightSurface:
        """The same spline placed by another frame (e.g. the master's)."""
        return HeightSurface(self.x, self.y, self.heights, origin, Q, scale, self.degree)

    def inside(self, u: float, v: float) -> bool:
        x0, x1, y0, y1 = self.bounds
        return x0 <= u <= x1 and y0 <= v <= y1

    def geometry(self) -> tuple:
        """(o (3,), kQ (3, 3), tx, ty, c (nx, ny), k): the placed spline as the compiled kernels
        (:mod:`teleop.dynamics.kernels.surface`) read it, from scipy's own knots and coefficients."""
        return self._geo

    def height_partials(self, u: float, v: float, upto: int = 3) -> np.ndarray:
        """F (4, 4): F[a, b] = d^(a+b) f / du^a dv^b at (u, v) for a + b <= upto (m per m^(a+b))."""
        _o, _kQ, tx, ty, c, k = self._geo
        return SK.height_partials(tx, ty, c, k, float(u), float(v), int(upto), np.empty((4, 4)))

    def derivatives(self, u: float, v: float, upto: int = 3):
        """World (S (3,), S1 (2, 3), S2 (2, 2, 3), S3 (2, 2, 2, 3) or None), m per parameter unit^i.

        S1[i] = dS/dc_i, S2[i, j] = d2S/dc_i dc_j, ... with c = (u, v); S3 only for ``upto`` = 3.
        """
        S, S1, S2, S3 = np.empty(3), np.empty((2, 3)), np.empty((2, 2, 3)), np.empty((2, 2, 2, 3))
        SK.surface_derivatives(*self._geo, float(u), float(v), int(upto), S, S1, S2, S3)
        return S, S1, S2, (S3 if upto >= 3 else None)

    @staticmethod
    def normal_and_derivatives(S1, S2):
        """(n (3,), m_norm, N (2, 3)): the unit normal, |S_u x S_v| and dn/dc_i (rows)."""
        S1, S2 = np.ascontiguousarray(S1, dtype=float), np.ascontiguousarray(S2, dtype=float)
        n, N = np.empty(3), np.empty((2, 3))
        mu = SK.unit_normal(S1, n)
        SK.normal_derivatives(S1, S2, n, mu, N)
        return n, mu, N

    def frame(self, u: float, v: float):
        """(F (3, 3), S (3,)): columns (t1, t2, n), t1 = S_u/|S_u|, t2 = n x t1, at (u, v)."""
        F, S, _, _, _ = self.frame_derivatives(u, v)
        return F, S

    def frame_derivatives(self, u: float, v: float):
        """(F, S, S1, n, dF (2, 3, 3)): the frame of :meth:`frame`, S, S1, n and dF/dc_i."""
        F, S, S1, n, dF = np.empty((3, 3)), np.empty(3), np.empty((2, 3)), np.empty(3), np.empty((2, 3, 3))
        SK.surface_frame(*self._geo, float(u), float(v), F, S, S1, n, dF)
        return F, S, S1, n, dF

    def own_uv(self, p) -> tuple[float, float]:
        """p's own (u, v) in the height field's frame (Newton's default start)."""
        loc = self.Q.T @ (np.asarray(p, dtype=float) - self.o) / self.k
        return float(loc[0]), float(loc[1])

    def closest(self, p, guess=None, tol: float = 1e-13, iters: int = 30):
        """The foot (u, v) of the world point p (3,): (p - S) . S_i = 0 by Newton from ``guess``
        (default: p's own (u, v) in the height field's frame), compiled
        (:func:`teleop.dynamics.kernels.surface.closest_foot`). Returns (u, v, converged)."""
        p = np.ascontiguousarray(p, dtype=float)
        u0, v0 = self.own_uv(p) if guess is None else (float(guess[0]), float(guess[1]))
        out = np.empty(2)
        ok = SK.closest_foot(*self._geo, p, u0, v0, float(tol), int(iters), out)
        return float(out[0]), float(out[1]), bool(ok)

    def signed_distance(self, p, guess=None):
        """(s, n, (u, v)): n . (p - S(foot)) (m, > 0 above), the unit normal at the foot, the foot.
        Newton starts from ``guess`` and, if that fails, from p's own (u, v)."""
        u, v, ok = self.closest(p, guess)
        if not ok and guess is not None:
            u, v, ok = self.closest(p)
        _, S, _, n, _ = self.frame_derivatives(u, v)
        return float(n @ (np.asarray(p, dtype=float) - S)), n, (u, v)

    def max_curvature(self, samples: int = 21) -> float:
        """Largest principal curvature magnitude (1/m, world) over a grid of samples."""
        kmax = 0.0
        for u in np.linspace(self.bounds[0], self.bounds[1], samples):
            for v in np.linspace(self.bounds[2], self.bounds[3], samples):
                _, S1, S2, _ = self.derivatives(u, v, upto=2)
                n, _, _ = self.normal_and_derivatives(S1, S2)
                g = S1 @ S1.T
                L = np.einsum("ijk,k->ij", S2, n)
                kmax = max(kmax, float(np.abs(np.linalg.eigvals(np.linalg.solve(g, L))).max()))
        return kmax
