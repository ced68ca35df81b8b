"""What accuracy costs in time: sweep integrators, control periods and effect sets.

    python tools/accuracy_vs_time.py [--out docs/accuracy] [--seconds 2.0]

It also runs straight_incision over the master's integrator and period and the slave's QP solver
and tolerance (tracking and depth error). For every point it records the constraint drift (holonomic position residual, velocity residual
|G nu|), the energy error on a conservative scene, the trajectory error against a reference run
(RK4 at 0.1 ms), CPU microseconds per tick (median, p99) and the CPU load (us per tick over the
period: a shorter period costs more ticks a second) and, on the undamped scenes
(tests/data/undamped: pushed for 0.5 s, then left alone), the energy drift over the force-free
stretch (``metrics.energy_drift_rel_max``). It writes ``accuracy.csv``, ``accuracy.md``
and ``pareto.png`` (errors against CPU load, log-log), and marks the shipped default
(parametric at 1 ms). The effect sweep shows what each simulated effect costs.
"""

from __future__ import annotations

import argparse
import csv
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from teleop.dynamics.constraints import stack_jacobian, stack_residual
from teleop.dynamics.integrators import INTEGRATORS
from teleop.scenario.build import build_tool
from teleop.scenario.metrics import EnergyDrift
from teleop.scenario.operators import make_operator
from teleop.scenario.schema import load_scene

PERIODS_MS = (0.1, 0.25, 0.5, 1.0, 2.0)
UNDAMPED_DIR = Path(__file__).resolve().parents[1] / "tests" / "data" / "undamped"
UNDAMPED = ("undamped_sphere_slide", "undamped_rolling_disk", "undamped_scalpel_slide")
SCENES = ("paper_rolling_disk", "paper_disk_on_sphere") + UNDAMPED
DEFAULT = ("parametric", 1.0)
EFFECT_SETS = {
    "effect set: coriolis + damping": ("coriolis", "damping"),
    "effect set: damping only": ("damping",),
    "effect set: none": (),
}
#: loads within this fraction are a tie: repeated runs on this shared machine differ by that much
LOAD_TIE = 0.10


def _load(name: str):
    return load_scene(str(UNDAMPED_DIR / f"{name}.toml")) if name in UNDAMPED else load_scene(name)


def simulate(scene, seconds: float, record_dt: float = 0.01):
    """Run a scene's tool (ideal master) and measure drift, energy, and the sampled trajectory."""
    scene = scene.with_overrides(duration_s=seconds)
    tool = build_tool(scene)
    drift, loop = EnergyDrift(tool), SimpleNamespace(tool=tool)
    op = make_operator(scene.operator, scene.fixture, scene.effects, np.random.default_rng(scene.seed))
    n = int(round(seconds / scene.dt_s))
    every = max(1, int(round(record_dt / scene.dt_s)))
    ticks, traj = np.empty(n), []
    pos_res = vel_res = 0.0
    e0 = tool.energy()
    status = "ok"
    for i in range(n):
        p, R = tool.pose()
        v, w = tool.twist()
        F = op.wrench(i * scene.dt_s, p, R, v, w)
        drift.before_tick(i, i * scene.dt_s, loop)
        t0 = time.perf_counter_ns()
        st = tool.step(scene.dt_s, F)
        ticks[i] = (time.perf_counter_ns() - t0) * 1e-3
        drift.after_tick(i, i * scene.dt_s, loop)
        if st != "ok":
            status = st
            break
        p, R = tool.pose()
        v, w = tool.twist()
        cons = tool.model.constraints
        if cons:
            h = stack_residual(cons, p, R)
            pos_res = max(pos_res, float(np.abs(h).max()) if h.size else 0.0)
            vel_res = max(vel_res, float(np.abs(stack_jacobian(cons, p, R) @ np.concatenate([v, w])).max()))
        if (i + 1) % every == 0:
            traj.append(p.copy())
    return {
        "status": status,
        "pos_residual_max": pos_res,
        "vel_residual_max": vel_res,
        "energy_rel_err": abs(tool.energy() - e0) / max(e0, 1e-12),
        "energy_drift_rel_max": float("nan") if drift.worst is None else drift.worst,
        "traj": np.array(traj),
        "tick_median_us": float(np.median(ticks[: i + 1])),
        "tick_p99_us": float(np.percentile(ticks[: i + 1], 99)),
    }


def conservative(scene):
    """The same scene with no damping and no operator: a start velocity, energy must stay put."""
    from teleop.scenario.schema import OperatorSpec

    q0 = scene.tool.q0
    qd0 = (0.02, 0.0, 0.0, 0.5, 0.0, 1.0) if scene.fixture.type == "sphere" else (0.0, 0.0, 0.0, 0.8, 0.0, -1.0)
    return replace(scene, effects=("coriolis",), operator=OperatorSpec(), tool=replace(scene.tool, q0=q0, qd0=qd0))


def sweep(seconds: float):
    rows = []
    for name in SCENES:
        base = _load(name)
        ref = simulate(base.with_overrides(integrator="rk4", dt_s=1e-4), seconds)
        cons_scene = conservative(base) if name not in UNDAMPED else None  # these are their own test
        for integ in INTEGRATORS:
            for ms in PERIODS_MS:
                sc = base.with_overrides(integrator=integ, dt_s=ms * 1e-3)
                r = simulate(sc, seconds)
                e = (simulate(cons_scene.with_overrides(integrator=integ, dt_s=ms * 1e-3), seconds) if cons_scene
                     else {"energy_rel_err": float("nan")})
                k = min(len(r["traj"]), len(ref["traj"]))
                err = float(np.sqrt(((r["traj"][:k] - ref["traj"][:k]) ** 2).sum(axis=1).mean())) if k else float("nan")
                rows.append({
                    "scene": name, "integrator": integ, "period_ms": ms,
                    "effects": "all (coriolis, damping)" if name not in UNDAMPED else "undamped (coriolis)",
                    "solver": "", "eps": float("nan"),
                    "status": r["status"], "traj_err_m": err,
                    "pos_residual_max": r["pos_residual_max"], "vel_residual_max": r["vel_residual_max"],
                    "energy_rel_err": e["energy_rel_err"], "energy_drift_rel_max": r["energy_drift_rel_max"],
                    "tick_median_us": r["tick_median_us"], "tick_p99_us": r["tick_p99_us"],
                    "cpu_load_pct": 100.0 * r["tick_median_us"] / (ms * 1e3),
                    "default": (integ, ms) == DEFAULT,
                })
                print(f"{name:22s} {integ:15s} {ms:5.2f} ms  err {err:9.2e} m  drift {r['pos_residual_max']:9.2e}  "
                      f"E {e['energy_rel_err']:9.2e}  drift {r['energy_drift_rel_max']:9.2e}  {r['tick_median_us']:7.1f} us")
        for label, effects in (EFFECT_SETS.items() if name not in UNDAMPED else ()):
            sc = replace(base, effects=effects)
            r = simulate(sc.with_overrides(integrator=DEFAULT[0], dt_s=DEFAULT[1] * 1e-3), seconds)
            k = min(len(r["traj"]), len(ref["traj"]))
            err = float(np.sqrt(((r["traj"][:k] - ref["traj"][:k]) ** 2).sum(axis=1).mean()))
            rows.append({
                "scene": name, "integrator": DEFAULT[0], "period_ms": DEFAULT[1], "effects": label,
                "solver": "", "eps": float("nan"),
                "status": r["status"], "traj_err_m": err, "pos_residual_max": r["pos_residual_max"],
                "vel_residual_max": r["vel_residual_max"], "energy_rel_err": float("nan"),
                "tick_median_us": r["tick_median_us"], "tick_p99_us": r["tick_p99_us"],
                "cpu_load_pct": 100.0 * r["tick_median_us"] / (DEFAULT[1] * 1e3), "default": False,
            })
            print(f"{name:22s} effects={label:26s} err {err:9.2e} m  {r['tick_median_us']:7.1f} us")
    return rows


INCISION = "straight_incision"
SHIPPED_SOLVER = "osqp"  # what the incision scenes ship with: the library default (issue #4), in the base install
SOLVERS = (("osqp", 1e-3), ("osqp", 1e-5), ("osqp", 1e-7), ("proxqp", 1e-3), ("proxqp", 1e-7), ("daqp", None), ("quadprog", None))


def incision_point(integrator: str, period_ms: float, solver: str, eps, seconds: float, every_tick: bool = False) -> dict:
    """One straight_incision run: the master's integrator and period, the slave's solver and tolerance.
    ``every_tick``: the slave's QP solver runs every tick (``kkt_shortcut`` off), so that solvers
    are compared on what they do; by default it runs only on ticks where a joint bound binds."""
    from teleop.runtime import run_scene

    base = load_scene(INCISION)
    slave = replace(base.slave, solver=solver, kkt_shortcut=not every_tick)
    if eps is not None:
        slave = replace(slave, eps=eps)
    sc = replace(base, slave=slave).with_overrides(
        integrator=integrator, dt_s=period_ms * 1e-3, duration_s=seconds)
    r = run_scene(sc)
    m, t = r.summary["metrics"], r.summary["tick_us"]
    print(f"{INCISION:22s} {integrator:15s} {period_ms:5.2f} ms  {solver:8s} eps={eps} every_tick={every_tick}  track {m['tip_tracking_rms_m']:9.2e}  "
          f"depth {m['cut_depth_error_max_m']:9.2e}  {t['median']:7.1f} us  {r.summary['status']}")
    return {
        "scene": INCISION, "integrator": integrator, "period_ms": period_ms, "effects": "all (incision)",
        "solver": solver, "eps": eps if eps is not None else float("nan"), "every_tick": every_tick,
        "status": r.summary["status"],
        "traj_err_m": m["tip_tracking_rms_m"], "pos_residual_max": m["cut_depth_error_max_m"],
        "vel_residual_max": m["sideslip_max_m_per_s"], "energy_rel_err": float("nan"),
        "tick_median_us": t["median"], "tick_p99_us": t["p99"],
        "cpu_load_pct": 100.0 * t["median"] / (period_ms * 1e3),
        "default": (integrator, period_ms, solver, eps, every_tick) == (DEFAULT[0], DEFAULT[1], SHIPPED_SOLVER, None, False),
    }


def incision_sweep(seconds: float) -> list:
    """The master integrator at 1 ms, the default integrator over the periods, and every slave QP
    solver and tolerance at the defaults, each run on every tick: tracking error (RMS) and depth
    error against CPU load."""
    rows = [incision_point(i, DEFAULT[1], SHIPPED_SOLVER, None, seconds) for i in INTEGRATORS]
    rows += [incision_point(DEFAULT[0], ms, SHIPPED_SOLVER, None, seconds) for ms in PERIODS_MS if ms != DEFAULT[1]]
    rows += [incision_point(DEFAULT[0], DEFAULT[1], sv, eps, seconds, every_tick=True) for sv, eps in SOLVERS]
    assert any(r["default"] for r in rows), "the shipped configuration must be among the points"
    return rows


def _dominates(b, a, tie: float) -> bool:
    """b dominates a: no worse anywhere, better somewhere. Coordinate 0 is the measured cost,
    where values within ``tie`` (relative) are equal; the errors compare exactly."""
    cost_better = b[0] < a[0] * (1.0 - tie)
    cost_no_worse = b[0] <= a[0] * (1.0 + tie)
    errs_no_worse = all(y <= x for x, y in zip(a[1:], b[1:]))
    errs_better = any(y < x for x, y in zip(a[1:], b[1:]))
    return cost_no_worse and errs_no_worse and (cost_better or errs_better)


def pareto_front(points, tie: float = 0.0):
    """Indices of points no other point dominates; every coordinate is minimised."""
    return [i for i, a in enumerate(points) if not any(_dominates(b, a, tie) for j, b in enumerate(points) if j != i)]


def read_csv(path: Path) -> list:
    """Rows of an accuracy.csv with their numbers back as numbers."""
    out = []
    for r in csv.DictReader(open(path)):
        for k, v in r.items():
            if k in ("period_ms", "eps", "traj_err_m", "pos_residual_max", "vel_residual_max", "energy_rel_err",
                     "energy_drift_rel_max",
                     "tick_median_us", "tick_p99_us", "cpu_load_pct"):
                r[k] = float(v) if v != "" else float("nan")
        r["default"] = r["default"] == "True"
        r["every_tick"] = r.get("every_tick") == "True"
        r.pop("front", None)
        out.append(r)
    return out


def write_outputs(rows, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "accuracy.csv", "w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)), restval="")
        wr.writeheader()
        wr.writerows(rows)
    lines = ["| scene | integrator | period ms | effects | QP solver (eps) | traj / tracking err m | drift / depth err m | |Gν| | energy err | energy drift | µs median | µs p99 | CPU load % | front |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    main = [r for r in rows if not r["effects"].startswith("effect set")]
    for name in SCENES + (INCISION,):
        sub = [r for r in main if r["scene"] == name]
        # objectives: CPU load (us per tick / period: a shorter period costs more ticks a second),
        # trajectory (or tracking) error, and the constraint drift in position and in velocity
        # (what a haptic user feels as sinking into a surface or a slipping knife edge)
        front = set(pareto_front([
            (r["cpu_load_pct"], max(r["traj_err_m"], 1e-16), max(r["pos_residual_max"], 1e-16), max(r["vel_residual_max"], 1e-16))
            for r in sub
        ], tie=LOAD_TIE))
        for i, r in enumerate(sub):
            r["front"] = i in front
    for r in rows:
        mark = "**default**" if r["default"] else ""
        qp = r["solver"] if r["eps"] != r["eps"] else f"{r['solver']} ({r['eps']:.0e})"  # eps NaN: none
        qp += ", every tick" if r.get("every_tick") else ""
        lines.append(
            f"| {r['scene']} | {r['integrator']} {mark} | {r['period_ms']:g} | {r['effects']} | "
            f"{qp} | {r['traj_err_m']:.2e} | "
            f"{r['pos_residual_max']:.1e} | {r['vel_residual_max']:.1e} | {r['energy_rel_err']:.1e} | "
            f"{r.get('energy_drift_rel_max', float('nan')):.1e} | "
            f"{r['tick_median_us']:.1f} | {r['tick_p99_us']:.1f} | {r['cpu_load_pct']:.1f} | {'yes' if r.get('front') else ''} |"
        )
    (out / "accuracy.md").write_text("\n".join(lines) + "\n")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import matplotlib.ticker  # noqa: F401 (matplotlib.ticker below)

    fig, axes = plt.subplots(3, len(SCENES) + 1, figsize=(26, 12.5))
    markers = dict(zip(INTEGRATORS, "osD^v*p"))
    rows_spec = (("traj_err_m", "trajectory error vs RK4 @ 0.1 ms [m]"), ("pos_residual_max", "constraint drift max |h| [m]"),
                 ("energy_drift_rel_max", "energy drift, force-free stretch (relative)"))
    for col, name in enumerate(SCENES):
        for row, (key, label) in enumerate(rows_spec):
            ax = axes[row][col]
            if key == "energy_drift_rel_max" and name not in UNDAMPED:
                ax.set_axis_off()  # damped: no force-free stretch
                continue
            for integ in INTEGRATORS:
                sub = [r for r in main if r["scene"] == name and r["integrator"] == integ]
                ax.plot([r["cpu_load_pct"] for r in sub], [max(r[key], 1e-17) for r in sub],
                        marker=markers[integ], lw=0.8, label=integ)
            d = [r for r in main if r["scene"] == name and r["default"]][0]
            ax.plot(d["cpu_load_pct"], max(d[key], 1e-17), "o", ms=16, mfc="none", mec="red", label="default")
            ax.axvline(100.0, color="k", lw=0.6, ls="--")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("CPU load, % of real time (µs per tick / period)")
            ax.set_ylabel(label, fontsize=8)
            ax.set_title(f"{name} (periods 0.1-2 ms; floor 1e-17 = exact)", fontsize=9)
            ax.grid(alpha=0.3, which="both")
    inc = [r for r in rows if r["scene"] == INCISION]
    groups: dict = {}  # one legend entry per kind of point (no labels on the points: they overlap)
    for r in inc:
        if r["every_tick"]:
            key = f"{r['solver']} QP every tick" + ("" if r["eps"] != r["eps"] else f" (eps {r['eps']:.0e})")
        elif r["period_ms"] != DEFAULT[1]:
            key = f"{r['integrator']}, period {r['period_ms']:g} ms"
        else:
            key = f"{r['integrator']}, {DEFAULT[1]:g} ms"
        groups.setdefault(key, []).append(r)
    colors = plt.get_cmap("tab20").colors
    for row, (key, label) in enumerate((("traj_err_m", "slave tip tracking RMS [m]"), ("pos_residual_max", "slave cut depth error max [m]"))):
        ax = axes[row][len(SCENES)]
        for k, (name, sub) in enumerate(groups.items()):
            every = sub[0]["every_tick"]
            marker = "s" if every else ("x" if "period" in name else markers.get(sub[0]["integrator"], "o"))
            ax.plot([r["cpu_load_pct"] for r in sub], [max(r[key], 1e-17) for r in sub], marker, ms=6,
                    color=colors[k % len(colors)], label=name, mew=1.5)
        d = [r for r in inc if r["default"]]
        if d:
            ax.plot(d[0]["cpu_load_pct"], max(d[0][key], 1e-17), "o", ms=16, mfc="none", mec="red", label="default")
        ax.axvline(100.0, color="k", lw=0.6, ls="--")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        ax.xaxis.set_minor_locator(matplotlib.ticker.LogLocator(base=10.0, subs=(2.0, 5.0)))
        ax.xaxis.set_minor_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        ax.set_xlabel("CPU load, % of real time (whole tick / period)")
        ax.set_ylabel(label, fontsize=8)
        ax.set_title(f"{INCISION}: integrators, periods, QP solvers", fontsize=9)
        ax.grid(alpha=0.3, which="both")
    axes[0][len(SCENES)].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    axes[2][len(SCENES)].set_axis_off()
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "pareto.png", dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="docs/accuracy")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per paper-scene point")
    ap.add_argument("--replot", help="redraw the table and plot from an accuracy.csv, no runs")
    ap.add_argument("--incision-seconds", type=float, default=2.0, help="simulated seconds per straight_incision point")
    args = ap.parse_args(argv)
    if args.replot:
        rows = read_csv(Path(args.replot))
    else:
        rows = sweep(args.seconds) + incision_sweep(args.incision_seconds)
    write_outputs(rows, Path(args.out))
    print(f"wrote {args.out}/accuracy.csv, accuracy.md, pareto.png ({len(rows)} points)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
