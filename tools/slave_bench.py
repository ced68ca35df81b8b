"""Time one slave tick against pink on the straight-incision task, in the same run.

slave_step: kinematics + QP build + solve + integrate (``SlaveArm.step``) with the scalpel fixture,
default settings (OSQP, ``kkt_shortcut``: the QP solver runs only on ticks where a joint bound
binds; ``solver_ticks`` counts them, so the solver barely shows here).
``slave_step_{osqp,daqp}_every_tick`` turn the shortcut off, so that the solver runs every tick.
pink_step:  the same target (FrameTask on E + PostureTask, pink's default configuration and
velocity limits) solved with ``pink.solve_ik`` and its fastest installed solver, then integrated.
Pink gets no fixture rows, so it solves a smaller problem than the slave.

    python tools/slave_bench.py [n_steps]
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import pinocchio as pin
import qpsolvers

from teleop.dynamics import fixtures
from teleop.slave import SlaveArm, SlaveConfig

PLANE_O = np.array([0.5, 0.0, 0.2])
R_CUT = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
DT = 1e-3


def _target(k):
    s = min(0.01 * k * DT, 0.05)
    return PLANE_O + np.array([-0.05 + s, -0.02, -0.005]), np.array([0.01, 0.0, 0.0])


def _stats(ts) -> dict:
    a = np.asarray(ts) * 1e6
    return {"median": float(np.median(a)), "p99": float(np.percentile(a, 99))}


def _time_slave(solver, n_steps, kkt_shortcut=True):
    """(tick times s, the arm, number of ticks that ran the QP solver)."""
    fx = fixtures.scalpel(plane_origin=PLANE_O, depth=0.005)
    cfg = SlaveConfig.from_dict({"solver": solver, "kkt_shortcut": kkt_shortcut}, "slave")
    arm = SlaveArm(cfg, fx.constraints, DT)
    arm.reset((_target(0)[0], R_CUT))
    ts, w0, solver_ticks = [], np.zeros(3), 0
    for k in range(1, n_steps + 1):
        p, v = _target(k)
        t0 = time.perf_counter()
        arm.step(p, R_CUT, v, w0)
        ts.append(time.perf_counter() - t0)
        solver_ticks += arm.qp.used_solver
    return ts, arm, solver_ticks


def _time_pink(arm, n_steps):
    import pink  # a test extra: loaded on demand
    from pink.tasks import FrameTask, PostureTask

    arm.reset((_target(0)[0], R_CUT))
    conf = pink.Configuration(arm.model, arm.model.createData(), arm.q.copy())
    ft = FrameTask("E", position_cost=1.0, orientation_cost=0.1, lm_damping=1e-2)
    post = PostureTask(cost=1e-4)
    post.set_target(arm.q_post)
    solver = next(s for s in ("daqp", "quadprog", "proxqp", "osqp") if s in qpsolvers.available_solvers)
    ts = []
    for k in range(1, n_steps + 1):
        p, _ = _target(k)
        t0 = time.perf_counter()
        ft.set_target(pin.SE3(R_CUT, p))
        v = pink.solve_ik(conf, [ft, post], DT, solver=solver)
        conf.update(conf.integrate(v, DT))
        ts.append(time.perf_counter() - t0)
    return ts, solver


def measure(n_steps: int = 3000) -> dict:
    """{"slave_step_us": {median, p99}, "pink_step_us": {median, p99}, ...} in microseconds."""
    slave_ts, arm, solver_ticks = _time_slave("osqp", n_steps)
    pink_ts, pink_solver = _time_pink(arm, n_steps)
    out = {
        "slave_step_us": _stats(slave_ts),
        "pink_step_us": _stats(pink_ts),
        "slave_step_osqp_every_tick_us": _stats(_time_slave("osqp", n_steps, False)[0]),
        "slave_step_daqp_every_tick_us": _stats(_time_slave("daqp", n_steps, False)[0]),
        "solver_ticks": f"{solver_ticks} of {n_steps}",
        "pink_solver": pink_solver,
    }
    out["ratio_median"] = out["slave_step_us"]["median"] / out["pink_step_us"]["median"]
    return out


if __name__ == "__main__":
    print(json.dumps(measure(int(sys.argv[1]) if len(sys.argv) > 1 else 3000), indent=2))
