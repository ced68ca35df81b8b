"""Persistent QP solvers for the slave follower, all on one fixed-size problem.

The problem, with x in R^n (joint velocities rad/s, then slack variables in row units):

    minimize  0.5 x' H x + g' x   subject to   A_eq x = b_eq   (m rows),   lb <= x <= ub.

Every wrapper is created once per arm with the problem sizes, keeps its workspace, and is fed new
values every tick through ``solve(H, g, A_eq, b_eq, lb, ub)``. It returns a :class:`QPResult`
whose equality duals ``y_eq`` follow one sign convention for all solvers (OSQP's):
``H x + g + A_eq' y_eq + (bound terms) = 0``. Infinite bounds are given as +-inf.

osqp and daqp are base dependencies and imported here (daqp finishes exactly what OSQP leaves at its
iteration cap); proxsuite and quadprog are optional (the test extras) and imported by their wrappers
on demand. The OSQP wrapper builds its sparse structures once (fixed sparsity pattern with explicit
zeros) and afterwards updates only the values of P, q, A, l, u, warm-starting from the previous
tick; the DAQP wrapper keeps one model and its active set from tick to tick. The follower calls a
solver only on ticks where a joint bound binds (see ``teleop.slave.follower``), unless its
``kkt_shortcut`` is off.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import daqp
import numpy as np
import qpsolvers
import scipy.sparse as sp
from osqp import ext_builtin as osqp_ext

from teleop.util.errors import SolverError

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
        """The result, with copies of x and y; not ok when x is missing or not finite (entries
        from 1e154 on count as not finite: the sum of squares overflows)."""
        if x is None or not math.isfinite(np.vdot(x, x)):
            return QPResult(np.zeros(self.n), np.zeros(self.m), False, str(status), int(iters))
        y = np.zeros(self.m) if y is None or not math.isfinite(np.vdot(y, y)) else np.array(y, dtype=float)
        return QPResult(np.array(x, dtype=float), y, bool(ok), str(status), int(iters))


class OsqpSolver(QPSolver):
    """OSQP 1.x: one solver set up with a fixed sparsity pattern, then only values are updated.

    P is the full upper triangle and A = [A_eq; I_n], both with explicit zeros, so that new values
    never change the structure; the solve warm-starts from the previous one. The solver object of
    osqp's extension module is used directly: ``osqp.OSQP.update``/``solve`` add about 20 us of
    Python bookkeeping per tick (argument checks, a result namespace), more than the solve itself.
    """

    name = "osqp"

    def __init__(self, n, m, eps=1e-7, max_iter=4000, polish=True):
        super().__init__(n, m, eps, max_iter)
        ext = osqp_ext

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
        settings = ext.OSQPSettings()
        ext.osqp_set_default_settings(settings)
        for key, value in dict(eps_abs=eps, eps_rel=eps, max_iter=max_iter, polishing=polish, verbose=False,
                               warm_starting=True, adaptive_rho=True, check_termination=10).items():
            setattr(settings, key, value)
        self._solver = ext.OSQPSolver(
            ext.CSC(P), np.zeros(n), ext.CSC(A), -np.ones(m + n), np.ones(m + n), m + n, n, settings)
        self._polish = polish

    def solve(self, H, g, A_eq, b_eq, lb, ub):
        m, solver = self.m, self._solver
        self._A_full[:m] = A_eq
        self._l[:m] = b_eq
        self._u[:m] = b_eq
        np.maximum(lb, -BIG, out=self._l[m:])
        np.minimum(ub, BIG, out=self._u[m:])
        solver.update_data_vec(q=np.ascontiguousarray(g, dtype=float), l=self._l, u=self._u)
        solver.update_data_mat(
            P_x=H[self._P_r, self._P_c], P_i=None, A_x=self._A_full[self._A_r, self._A_c], A_i=None)
        solver.solve()
        info, sol = solver.info, solver.solution
        st = info.status
        ok = st == "solved" or (st == "solved inaccurate" and self._polish and info.status_polish == 1)
        return self._checked(sol.x, sol.y[:m], ok, st, info.iter)


class DaqpSolver(QPSolver):
    """DAQP (dense active set): a ``daqp.Model`` set up once, then updated in place, so that each
    solve starts from the previous active set; after a failure the next solve sets up afresh.
    The problem's arrays are copied into buffers owned here, which the model may keep using."""

    name = "daqp"

    def __init__(self, n, m, eps=1e-7, max_iter=4000):
        super().__init__(n, m, eps, max_iter)
        self._daqp = daqp
        self._sense = np.zeros(n + m, dtype=np.int32)
        self._sense[n:] = 5  # equality rows
        self._H, self._g, self._A = np.zeros((n, n)), np.zeros(n), np.zeros((m, n))
        self._bu = np.empty(n + m)
        self._bl = np.empty(n + m)
        self._model = None

    def solve(self, H, g, A_eq, b_eq, lb, ub):
        n = self.n
        self._H[:] = H
        self._g[:] = g
        self._A[:] = A_eq
        np.minimum(ub, BIG, out=self._bu[:n])
        np.maximum(lb, -BIG, out=self._bl[:n])
        self._bu[n:] = b_eq
        self._bl[n:] = b_eq
        settings = {"primal_tol": self.eps, "dual_tol": self.eps, "iter_limit": self.max_iter}
        if not hasattr(self._daqp, "Model"):  # an older daqp: stateless, no warm start
            x, _, flag, info = self._daqp.solve(
                self._H, self._g, self._A, self._bu, self._bl, self._sense.copy(), **settings)
        else:
            if self._model is None:
                self._model = self._daqp.Model()
                self._model.settings = settings
                flag = self._model.setup(self._H, self._g, self._A, self._bu, self._bl, self._sense.copy())[0]
                if flag < 0:
                    self._model = None
                    return QPResult(np.zeros(n), np.zeros(self.m), False, f"setup exitflag {flag}", 0)
            else:
                mats = {"A": self._A} if self.m else {}  # daqp's update indexes A's first row
                self._model.update(H=self._H, f=self._g, bupper=self._bu, blower=self._bl, **mats)
            x, _, flag, info = self._model.solve()
            if flag != 1:
                self._model = None
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
PACKAGES = {"osqp": "osqp", "daqp": "daqp", "proxqp": "proxsuite", "quadprog": "quadprog"}  # pip names


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
