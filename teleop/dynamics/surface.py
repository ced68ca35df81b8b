"""A curved surface for fixtures and tissue: a B-spline height field placed in the world.

The surface is a quintic (or quartic) tensor-product B-spline height field ``f(u, v)`` (scipy's
:class:`scipy.interpolate.RectBivariateSpline`, interpolating a grid of heights), placed by a frame:

    S(u, v) = o + k Q (u, v, f(u, v))        (m)

with ``o`` (3,) the frame origin (m), ``Q`` (3, 3) a rotation whose third column is the outward
"up" of the height field, ``k`` > 0 a length scale (the master's copy of a patient-frame surface is
the same spline with ``k`` = the mapping's scale) and (u, v) the surface parameters in the grid's
own units (m of the patient frame). Everything a fixture or a tissue needs is computed here once:
S and its partial derivatives to third order, the unit normal n = (S_u x S_v)/|S_u x S_v| and its
first derivatives, a tangent frame, and the closest point (foot) of a world point by Newton's
method on (p - S) . S_i = 0.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.interpolate import RectBivariateSpline

from teleop.dynamics.rotations import cross
from teleop.errors import ConfigError

#: the partial derivative orders (du, dv) of f evaluated at once, to third order
_ORDERS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (3, 0), (2, 1), (1, 2), (0, 3))


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
            raise ConfigError(f"surface.degree: expected 4 or 5 (third derivatives need a degree above 3), got {degree}")
        if x.size <= degree or y.size <= degree:
            raise ConfigError(f"surface: a degree-{degree} spline needs more than {degree} grid points "
                              f"each way, got {x.size} x {y.size}")
        if np.any(np.diff(x) <= 0) or np.any(np.diff(y) <= 0):
            raise ConfigError("surface: x_m and y_m must be strictly increasing")
        self.x, self.y, self.heights, self.degree = x, y, H, int(degree)
        self.spline = RectBivariateSpline(x, y, H, kx=degree, ky=degree, s=0.0)
        self._cells_from_spline()
        self.o = np.asarray(origin, dtype=float)
        self.Q = np.eye(3) if Q is None else np.asarray(Q, dtype=float)
        self.k = float(scale)
        self.bounds = (x[0], x[-1], y[0], y[-1])

    def placed(self, origin, Q, scale: float) -> "HeightSurface":
        """The same spline placed by another frame (e.g. the master's)."""
        return HeightSurface(self.x, self.y, self.heights, origin, Q, scale, self.degree)

    def inside(self, u: float, v: float) -> bool:
        x0, x1, y0, y1 = self.bounds
        return x0 <= u <= x1 and y0 <= v <= y1

    def _cells_from_spline(self) -> None:
        """The spline's polynomial pieces: per knot cell (i, j) the coefficients C[i, j, p, q] of
        f = sum C s^p t^q, s = (u - u_i)/h_i, t = (v - v_j)/h_j in [0, 1]. Each piece is sampled by
        scipy's own evaluation at (k+1)^2 Chebyshev points and interpolated exactly (a polynomial of
        degree k each way), so every derivative order comes from one small product."""
        k = self.degree
        tx, ty = (np.unique(t) for t in self.spline.get_knots())  # the cells' edges
        self._ux, self._vy = tx, ty
        s = 0.5 - 0.5 * np.cos(np.pi * (np.arange(k + 1) + 0.5) / (k + 1))
        Vinv = np.linalg.inv(np.vander(s, k + 1, increasing=True))
        C = np.empty((tx.size - 1, ty.size - 1, k + 1, k + 1))
        for i in range(tx.size - 1):
            for j in range(ty.size - 1):
                vals = self.spline(tx[i] + s * (tx[i + 1] - tx[i]), ty[j] + s * (ty[j + 1] - ty[j]))
                C[i, j] = Vinv @ vals @ Vinv.T
        self._C = C
        p = np.arange(k + 1)
        # falling factorials p!/(p-a)! for a = 0..3
        self._fall = np.array([[math.perm(int(q), a) if q >= a else 0 for q in p] for a in range(4)], float)
        self._fall_list = self._fall.tolist()

    def _basis(self, x: float, knots: np.ndarray):
        """(cell index, (4, k+1) rows: d^a/dx^a of the powers s^p, a = 0..3)."""
        i = int(np.searchsorted(knots, x, side="right")) - 1
        i = min(max(i, 0), knots.size - 2)
        h = float(knots[i + 1] - knots[i])
        s = (float(x) - float(knots[i])) / h
        k = self.degree
        pw = [1.0] * (k + 1)
        for q in range(1, k + 1):
            pw[q] = pw[q - 1] * s
        fall = self._fall_list
        rows = []
        inv = 1.0
        for a in range(4):
            rows.append([fall[a][q] * pw[q - a] * inv if q >= a else 0.0 for q in range(k + 1)])
            inv /= h
        return i, np.array(rows)

    def _f(self, u: float, v: float, upto: int) -> list:
        """f and its partials in the order of _ORDERS, up to total order ``upto``."""
        i, Bu = self._basis(u, self._ux)
        j, Bv = self._basis(v, self._vy)
        F = Bu @ self._C[i, j] @ Bv.T  # F[a, b] = d^(a+b) f / du^a dv^b
        return [float(F[a, b]) for a, b in _ORDERS if a + b <= upto]

    def derivatives(self, u: float, v: float, upto: int = 3):
        """World (S (3,), S1 (2, 3), S2 (2, 2, 3), S3 (2, 2, 2, 3) or None), m per parameter unit^i.

        S1[i] = dS/dc_i, S2[i, j] = d2S/dc_i dc_j, ... with c = (u, v); S3 only for ``upto`` = 3.
        """
        f = self._f(u, v, max(upto, 2))
        kQ = self.k * self.Q
        e = kQ[:, 2]  # the height direction, scaled
        S = self.o + kQ @ np.array([u, v, f[0]])
        S1 = np.array([kQ[:, 0] + f[1] * e, kQ[:, 1] + f[2] * e])
        S2 = np.empty((2, 2, 3))
        S2[0, 0], S2[0, 1], S2[1, 1] = f[3] * e, f[4] * e, f[5] * e
        S2[1, 0] = S2[0, 1]
        S3 = None
        if upto >= 3:
            S3 = np.empty((2, 2, 2, 3))
            for i in range(2):
                for j in range(2):
                    for m in range(2):
                        S3[i, j, m] = f[6 + i + j + m] * e  # f_uuu, f_uuv, f_uvv, f_vvv by the count of v's
        return S, S1, S2, S3

    @staticmethod
    def normal_and_derivatives(S1, S2):
        """(n (3,), m_norm, N (2, 3)): the unit normal, |S_u x S_v| and dn/dc_i (rows)."""
        m = cross(S1[0], S1[1])
        mu = math.sqrt(float(m @ m))
        n = m / mu
        N = np.empty((2, 3))
        for i in range(2):
            mi = cross(S2[0, i], S1[1]) + cross(S1[0], S2[1, i])
            N[i] = (mi - n * float(n @ mi)) / mu
        return n, mu, N

    def frame(self, u: float, v: float):
        """(F (3, 3), S (3,)): columns (t1, t2, n), t1 = S_u/|S_u|, t2 = n x t1, at (u, v)."""
        S, S1, _, _ = self._first(u, v)
        m = cross(S1[0], S1[1])
        n = m / math.sqrt(float(m @ m))
        t1 = S1[0] / math.sqrt(float(S1[0] @ S1[0]))
        return np.column_stack([t1, cross(n, t1), n]), S

    def _first(self, u, v):
        f = self._f(u, v, 1)
        kQ = self.k * self.Q
        e = kQ[:, 2]
        S = self.o + kQ @ np.array([u, v, f[0]])
        return S, np.array([kQ[:, 0] + f[1] * e, kQ[:, 1] + f[2] * e]), None, None

    def frame_derivatives(self, u: float, v: float):
        """(F, S, S1, n, dF (2, 3, 3)): the frame of :meth:`frame`, S, S1, n and dF/dc_i."""
        S, S1, S2, _ = self.derivatives(u, v, upto=2)
        n, _, N = self.normal_and_derivatives(S1, S2)
        su = S1[0]
        lu = math.sqrt(float(su @ su))
        t1 = su / lu
        t2 = cross(n, t1)
        dF = np.empty((2, 3, 3))
        for i in range(2):
            t1i = (S2[0, i] - t1 * float(t1 @ S2[0, i])) / lu
            dF[i] = np.column_stack([t1i, cross(N[i], t1) + cross(n, t1i), N[i]])
        return np.column_stack([t1, t2, n]), S, S1, n, dF

    def closest(self, p, guess=None, tol: float = 1e-13, iters: int = 30):
        """The foot (u, v) of the world point p (3,): (p - S) . S_i = 0 by Newton from ``guess``
        (default: p's own (u, v) in the height field's frame). Returns (u, v, converged)."""
        p = np.asarray(p, dtype=float)
        if guess is None:
            loc = self.Q.T @ (p - self.o) / self.k
            c = np.array([loc[0], loc[1]])
        else:
            c = np.array(guess, dtype=float)
        for _ in range(iters):
            S, S1, S2, _ = self.derivatives(c[0], c[1], upto=2)
            r = p - S
            F = S1 @ r
            A = S1 @ S1.T - np.einsum("ijk,k->ij", S2, r)
            dc = np.linalg.solve(A, F)
            c = c + dc
            if abs(dc[0]) + abs(dc[1]) < tol * max(1.0, abs(c[0]) + abs(c[1])):
                return float(c[0]), float(c[1]), True
        return float(c[0]), float(c[1]), False

    def signed_distance(self, p, guess=None):
        """(s, n, (u, v)): n . (p - S(foot)) (m, > 0 above), the unit normal at the foot, the foot.
        Newton starts from ``guess`` and, if that fails, from p's own (u, v)."""
        u, v, ok = self.closest(p, guess)
        if not ok and guess is not None:
            u, v, ok = self.closest(p)
        S, S1, _, _ = self._first(u, v)
        m = cross(S1[0], S1[1])
        n = m / math.sqrt(float(m @ m))
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
