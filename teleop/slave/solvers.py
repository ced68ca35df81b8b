"""Persistent QP solvers for the slave follower, all on one fixed-size problem.

The problem, with x in R^n (joint velocities rad/s, then slack variables in row units):

    minimize  0.5 x' H x + g' x   subject to   A_eq x = b_eq   (m rows),   lb <= x <= ub.

Every wrapper is created once per arm with the problem sizes, keeps its workspace, and is fed new
values every tick through ``solve(H, g, A_eq, b_eq, lb, ub)``. It returns a :class:`QPResult`
whose equality duals ``y_eq`` follow one sign convention for all solvers (OSQP's):
``H x + g + A_eq' y_eq + (bound terms) = 0``. Infinite bounds are given as +-inf.

The OSQP wrapper builds its sparse structures once (fixed sparsity pattern with explicit zeros)
and afterwards updates only the values of P, q, A, l, u, warm-starting from the previous tick.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

from dataclasses import dataclass

import numpy as np
import qpsolvers
import scipy.sparse as sp

from teleop.errors import SolverError

BIG = 1e20  # stands in for infinity in solvers that want finite bounds


@dataclass(frozen=True)
class QPResult:
    """x (n,), y_eq (m,), ok (bool: solved to tolerance), status (solver's own word), iters."""

    x: np.ndarray
    y_eq: np.ndarray
    ok: bool
    status: str
    iters: int


class QPSolver(ABC):
    """Base: one fixed problem size (n variables, m equality rows). Subclasses fill ``solve``."""

    name = "base"

    def __init__(self, n: int, m: int, eps: float, max_iter: int):
        self.n, self.m, self.eps, self.max_iter = int(n), int(m), float(eps), int(max_iter)

    @abstractmethod
    def solve(self, H, g, A_eq, b_eq, lb, ub) -> QPResult:
        """min 1/2 x'Hx + g'x  s.t.  A_eq x = b_eq, lb <= x <= ub."""

    def _checked(self, x, y, ok, status, iters) -> QPResult:
        if x is None or not np.all(np.isfinite(x)):
            return QPResult(np.zeros(self.n), np.zeros(self.m), False, str(status), int(iters))
        y = np.zeros(self.m) if y is None or not np.all(np.isfinite(y)) else np.asarray(y, float)
        return QPResult(np.asarray(x, float).copy(), y.copy(), bool(ok), str(status), int(iters))


class OsqpSolver(QPSolver):
    """osqp 1.x ``OSQP`` object: set up once, then ``update(Px=, Ax=, q=, l=, u=)`` per tick."""

    name = "osqp"

    def __init__(self, n, m, eps=1e-7, max_iter=4000, polish=True):
        super().__init__(n, m, eps, max_iter)
        import osqp

        # P: full upper triangle (dense block); A: [A_eq; I_n], A_eq fully dense.
        iu = np.triu_indices(n)
        order = np.lexsort((iu[0], iu[1]))  # CSC: column-major
        self._P_r, self._P_c = iu[0][order], iu[1][order]
        P = sp.csc_matrix((np.ones(len(self._P_r)), (self._P_r, self._P_c)), shape=(n, n))
        ar, ac = np.meshgrid(np.arange(m), np.arange(n), indexing="ij")
        rows = np.concatenate([ar.ravel(), m + np.arange(n)])
        cols = np.concatenate([ac.ravel(), np.arange(n)])
        order = np.lexsort((rows, cols))
        self._A_r, self._A_c = rows[order], cols[order]
        self._A_full = np.zeros((m + n, n))
        self._A_full[m + np.arange(n), np.arange(n)] = 1.0
        A = sp.csc_matrix((np.ones(len(rows)), (self._A_r, self._A_c)), shape=(m + n, n))
        assert P.nnz == len(self._P_r) and A.nnz == len(self._A_r)
        self._l = np.empty(m + n)
        self._u = np.empty(m + n)
        self._prob = osqp.OSQP()
        self._prob.setup(
            P, np.zeros(n), A, -np.ones(m + n), np.ones(m + n),
            eps_abs=eps, eps_rel=eps, max_iter=max_iter, polishing=polish, verbose=False,
            warm_starting=True, adaptive_rho=True, check_termination=10,
        )
        self._polish = polish

    def solve(self, H, g, A_eq, b_eq, lb, ub):
        m = self.m
        self._A_full[:m] = A_eq
        self._l[:m] = b_eq
        self._u[:m] = b_eq
        self._l[m:] = np.maximum(lb, -BIG)
        self._u[m:] = np.minimum(ub, BIG)
        self._prob.update(
            q=g, l=self._l, u=self._u, Px=H[self._P_r, self._P_c], Ax=self._A_full[self._A_r, self._A_c]
        )
        res = self._prob.solve(raise_error=False)
        st = res.info.status
        ok = st in ("solved",) or (st == "solved inaccurate" and self._polish and res.info.status_polish == 1)
        return self._checked(res.x, None if res.y is None else res.y[:m], ok, st, res.info.iter)


class DaqpSolver(QPSolver):
    """DAQP (dense active set); warm-started from the previous active set."""

    name = "daqp"

    def __init__(self, n, m, eps=1e-7, max_iter=4000):
        super().__init__(n, m, eps, max_iter)
        import daqp

        self._daqp = daqp
        self._sense = np.zeros(n + m, dtype=np.int32)
        self._sense[n:] = 5
        self._bu = np.empty(n + m)
        self._bl = np.empty(n + m)

    def solve(self, H, g, A_eq, b_eq, lb, ub):
        n = self.n
        self._bu[:n] = np.minimum(ub, BIG)
        self._bl[:n] = np.maximum(lb, -BIG)
        self._bu[n:] = b_eq
        self._bl[n:] = b_eq
        x, _, flag, info = self._daqp.solve(
            np.ascontiguousarray(H), g, np.ascontiguousarray(A_eq), self._bu, self._bl, self._sense.copy(),
            primal_tol=self.eps, dual_tol=self.eps, iter_limit=self.max_iter,
        )
        lam = np.asarray(info.get("lam", np.zeros(n + self.m)))
        return self._checked(x, lam[n:], flag == 1, f"exitflag {flag}", info.get("iterations", 0))


class ProxqpSolver(QPSolver):
    """proxsuite's dense ProxQP with box constraints; init once, then update + warm start."""

    name = "proxqp"

    def __init__(self, n, m, eps=1e-7, max_iter=4000):
        super().__init__(n, m, eps, max_iter)
        from proxsuite import proxqp

        self._px = proxqp
        self._qp = proxqp.dense.QP(n, m, 0, True)
        self._qp.settings.eps_abs = eps
        self._qp.settings.eps_rel = 0.0
        self._qp.settings.max_iter = max_iter
        self._qp.settings.initial_guess = proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
        self._init = False

    def solve(self, H, g, A_eq, b_eq, lb, ub):
        l, u = np.maximum(lb, -BIG), np.minimum(ub, BIG)
        if not self._init:
            self._qp.init(H, g, A_eq, b_eq, None, None, None, l, u)
            self._init = True
        else:
            self._qp.update(H, g, A_eq, b_eq, None, None, None, l, u)
        self._qp.solve()
        r = self._qp.results
        ok = r.info.status == self._px.QPSolverOutput.PROXQP_SOLVED
        return self._checked(r.x, r.y, ok, str(r.info.status), r.info.iter)


class QuadprogSolver(QPSolver):
    """quadprog (dense Goldfarb-Idnani); stateless, so nothing to warm-start."""

    name = "quadprog"

    def __init__(self, n, m, eps=1e-7, max_iter=4000):
        super().__init__(n, m, eps, max_iter)
        import quadprog

        self._qp = quadprog

    def solve(self, H, g, A_eq, b_eq, lb, ub):
        fin_l, fin_u = np.isfinite(lb), np.isfinite(ub)
        I = np.eye(self.n)
        C = np.vstack([A_eq, I[fin_l], -I[fin_u]]).T
        b = np.concatenate([b_eq, lb[fin_l], -ub[fin_u]])
        try:
            x, _, _, it, lagr, _ = self._qp.solve_qp(H, -g, C, b, self.m)
        except ValueError as exc:  # "constraints are inconsistent" / "matrix G is not positive definite"
            return QPResult(np.zeros(self.n), np.zeros(self.m), False, str(exc), 0)
        return self._checked(x, -lagr[: self.m], True, "solved", it[0])


SOLVERS = {"osqp": OsqpSolver, "daqp": DaqpSolver, "proxqp": ProxqpSolver, "quadprog": QuadprogSolver}


def installed_solvers() -> tuple[str, ...]:
    """Names usable here: those this module wraps that qpsolvers finds installed."""
    return tuple(s for s in SOLVERS if s in qpsolvers.available_solvers)


def make_solver(name: str, n: int, m: int, eps: float = 1e-7, max_iter: int = 4000) -> QPSolver:
    """A persistent solver for n variables and m equality rows; unknown name -> SolverError."""
    if name not in installed_solvers():
        raise SolverError(
            f"slave.solver: unknown or uninstalled QP solver {name!r}; installed: "
            f"{list(installed_solvers())} (qpsolvers.available_solvers = {qpsolvers.available_solvers})"
        )
    return SOLVERS[name](n, m, eps=eps, max_iter=max_iter)
