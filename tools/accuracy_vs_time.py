"""What accuracy costs in time: sweep integrators, control periods and effect sets.

    python tools/accuracy_vs_time.py [--out DIR] [--seconds 2.0] [--incision-seconds 2.0] [--quick]
                                     [--workers N | --scheduler ADDRESS] [--replot accuracy.csv]

Writes into a new ``runs/accuracy_vs_time-DATE-TIME/`` unless ``--out`` names a folder (the
published study: ``--out docs/accuracy``). ``--quick`` is a smoke run: one paper scene, two
periods, the default and shipped integrators, 0.5 s per point, no incision points.

It also runs straight_incision over the master's integrator and period and the slave's QP solver
and tolerance (tracking and depth error). For every point it records the constraint drift
(holonomic position residual, velocity residual |G nu|), the energy error on a conservative scene,
the trajectory error against a reference run (RK4 at 0.1 ms), CPU microseconds per tick (median,
p99) and the CPU load (us per tick over the period: a shorter period costs more ticks a second)
and, on the undamped scenes (tests/data/undamped: pushed for 0.5 s, then left alone), the energy
drift over the force-free stretch (``metrics.energy_drift_rel_max``). It writes ``accuracy.csv``, ``accuracy.md``
and ``pareto.png`` (errors against CPU load, log-log), and marks the default (``energy`` at 1 ms,
what a scene that names no integrator runs) and what the shipped scenes run (``parametric`` at
1 ms). The effect sweep shows what each simulated effect costs.

The points run in parallel through Dask (``teleop.app.sweep``: a local cluster of ``--workers``
processes, or the scheduler at ``--scheduler``), each a pure function of its parameters (the
scenes' own seeds), so the table does not depend on the number of workers; only the measured CPU
columns (µs per tick, load, and the front, which weighs the load) vary from run to run.
"""

from __future__ import annotations

import argparse
import csv
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from teleop.app.metrics import EnergyDrift
from teleop.app.outputs import out_help, study_folder
from teleop.app.sweep import add_sweep_args, check_sweep_args, run_sweep
from teleop.dynamics.constraints import stack_jacobian, stack_residual
from teleop.dynamics.integrators import INTEGRATORS
from teleop.scenario.build import build_tool
from teleop.scenario.operators import make_operator
from teleop.scenario.schema import load_scene

PERIODS_MS = (0.1, 0.25, 0.5, 1.0, 2.0)
UNDAMPED_DIR = Path(__file__).resolve().parents[1] / "tests" / "data" / "undamped"
UNDAMPED = ("undamped_sphere_slide", "undamped_rolling_disk", "undamped_scalpel_slide")
SCENES = ("paper_rolling_disk", "paper_disk_on_sphere", *UNDAMPED)
DEFAULT = ("energy", 1.0)  #: what a scene that names no integrator runs (ReferenceTool's default)
SHIPPED = ("parametric", 1.0)  #: what the shipped scenes name (they were tuned with it)
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
    n = round(seconds / scene.dt_s)
    every = max(1, round(record_dt / scene.dt_s))
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


def with_effects(scene, effects: tuple):
    """The scene with only ``effects`` on, and the tables of the effects turned off dropped (a
    scene that gives a [damping] table without the effect is refused)."""
    drop = {k: (() if k == "springs" else None) for k in ("damping", "gravity", "springs") if k not in effects}
    return replace(scene, effects=tuple(effects), **drop)


def conservative(scene):
    """The same scene with no damping and no operator: a start velocity, energy must stay put."""
    from teleop.scenario.schema import OperatorSpec

    q0 = scene.tool.q0
    qd0 = (0.02, 0.0, 0.0, 0.5, 0.0, 1.0) if scene.fixture.type == "sphere" else (0.0, 0.0, 0.0, 0.8, 0.0, -1.0)
    return replace(
        with_effects(scene, ("coriolis",)), operator=OperatorSpec(), tool=replace(scene.tool, q0=q0, qd0=qd0)
    )


def _traj_err(traj, ref) -> float:
    """RMS distance of a sampled trajectory from the reference's over their common samples, m."""
    k = min(len(traj), len(ref))
    return float(np.sqrt(((traj[:k] - ref[:k]) ** 2).sum(axis=1).mean())) if k else float("nan")


def run_point(point: dict) -> dict:
    """One point of the study, a pure function of ``point`` (kind "ref", "run", "effects" or
    "incision"; see ``sweep_points``), so that it runs anywhere: the trajectory errors against the
    reference are taken afterwards, in ``assemble``."""
    kind, seconds = point["kind"], point["seconds"]
    if kind == "incision":
        return incision_point(point["integrator"], point["period_ms"], point["solver"], point["eps"], seconds,
                              every_tick=point["every_tick"])
    base = _load(point["scene"])
    if kind == "ref":
        return simulate(base.with_overrides(integrator="rk4", dt_s=1e-4), seconds)
    sc = base if kind == "run" else with_effects(base, EFFECT_SETS[point["effects"]])
    dt = point["period_ms"] * 1e-3
    r = simulate(sc.with_overrides(integrator=point["integrator"], dt_s=dt), seconds)
    if kind == "run" and point["scene"] not in UNDAMPED:  # the undamped scenes are their own test
        r["energy_rel_err"] = simulate(conservative(base).with_overrides(integrator=point["integrator"], dt_s=dt),
                                       seconds)["energy_rel_err"]
    else:
        r["energy_rel_err"] = float("nan")
    return r


def sweep_points(seconds: float, incision_seconds: float, scenes=None, integrators=None, periods=None,
                 solvers=None) -> list[dict]:
    """Every point of the study, in table order: per scene its RK4 reference at 0.1 ms, every
    integrator at every period, the effect sets at the default; then straight_incision (see
    ``incision_points``). ``incision_seconds`` 0 leaves the incision out."""
    scenes = SCENES if scenes is None else tuple(scenes)
    integrators = tuple(INTEGRATORS) if integrators is None else tuple(integrators)
    periods = PERIODS_MS if periods is None else tuple(periods)
    pts = []
    for name in scenes:
        pts.append({"kind": "ref", "scene": name, "seconds": seconds})
        pts += [{"kind": "run", "scene": name, "integrator": i, "period_ms": ms, "seconds": seconds}
                for i in integrators for ms in periods]
        pts += [{"kind": "effects", "scene": name, "integrator": DEFAULT[0], "period_ms": DEFAULT[1],
                 "effects": label, "seconds": seconds} for label in (EFFECT_SETS if name not in UNDAMPED else ())]
    if incision_seconds:
        pts += incision_points(incision_seconds, integrators, periods, SOLVERS if solvers is None else solvers)
    return pts


def assemble(points: list[dict], results: list[dict]) -> list[dict]:
    """The table's rows from the points and their results (same order): trajectory errors against
    each scene's reference, CPU load, the default and shipped marks."""
    refs = {p["scene"]: r["traj"] for p, r in zip(points, results) if p["kind"] == "ref"}
    rows = []
    for p, r in zip(points, results):
        if p["kind"] in ("ref", "incision"):
            if p["kind"] == "incision":
                rows.append(r)
            continue
        name, integ, ms = p["scene"], p["integrator"], p["period_ms"]
        if p["kind"] == "run":
            effects = "all (coriolis, damping)" if name not in UNDAMPED else "undamped (coriolis)"
        else:
            effects = p["effects"]
        run = p["kind"] == "run"
        rows.append({
            "scene": name, "integrator": integ, "period_ms": ms, "effects": effects,
            "solver": "", "eps": float("nan"),
            "status": r["status"], "traj_err_m": _traj_err(r["traj"], refs[name]),
            "pos_residual_max": r["pos_residual_max"], "vel_residual_max": r["vel_residual_max"],
            "energy_rel_err": r["energy_rel_err"],
            "energy_drift_rel_max": r["energy_drift_rel_max"] if run else float("nan"),
            "tick_median_us": r["tick_median_us"], "tick_p99_us": r["tick_p99_us"],
            "cpu_load_pct": 100.0 * r["tick_median_us"] / (ms * 1e3),
            "default": run and (integ, ms) == DEFAULT, "shipped": run and (integ, ms) == SHIPPED,
        })
    return rows


def print_rows(rows: list[dict]) -> None:
    """One line a row, as the study used to print while it ran."""
    for r in rows:
        qp = f" {r['solver']:8s} eps={r['eps']:.0e}" if r["solver"] else ""
        print(f"{r['scene']:22s} {r['integrator']:15s} {r['period_ms']:5.2f} ms {r['effects']:30s}{qp} "
              f"err {r['traj_err_m']:9.2e} m  drift {r['pos_residual_max']:9.2e}  E {r['energy_rel_err']:9.2e}  "
              f"{r['tick_median_us']:7.1f} us  {r['status']}")


INCISION = "straight_incision"
SHIPPED_SOLVER = "osqp"  # what the incision scenes ship with: the library default (issue #4), in the base install
SOLVERS = (
    ("osqp", 1e-3),
    ("osqp", 1e-5),
    ("osqp", 1e-7),
    ("proxqp", 1e-3),
    ("proxqp", 1e-7),
    ("daqp", None),
    ("quadprog", None),
)


def incision_point(
    integrator: str, period_ms: float, solver: str, eps, seconds: float, every_tick: bool = False
) -> dict:
    """One straight_incision run: the master's integrator and period, the slave's solver and tolerance.
    ``every_tick``: the slave's QP solver runs every tick (``kkt_shortcut`` off), so that solvers
    are compared on what they do; by default it runs only on ticks where a joint bound binds."""
    from teleop.app.runtime import run_scene

    base = load_scene(INCISION)
    slave = replace(base.slave, solver=solver, kkt_shortcut=not every_tick)
    if eps is not None:
        slave = replace(slave, eps=eps)
    sc = replace(base, slave=slave).with_overrides(
        integrator=integrator, dt_s=period_ms * 1e-3, duration_s=seconds)
    r = run_scene(sc)
    m, t = r.summary["metrics"], r.summary["tick_us"]
    config = (integrator, period_ms, solver, eps, every_tick)
    return {
        "scene": INCISION, "integrator": integrator, "period_ms": period_ms, "effects": "all (incision)",
        "solver": solver, "eps": eps if eps is not None else float("nan"), "every_tick": every_tick,
        "status": r.summary["status"],
        "traj_err_m": m["tip_tracking_rms_m"], "pos_residual_max": m["cut_depth_error_max_m"],
        "vel_residual_max": m["sideslip_max_m_per_s"], "energy_rel_err": float("nan"),
        "tick_median_us": t["median"], "tick_p99_us": t["p99"],
        "cpu_load_pct": 100.0 * t["median"] / (period_ms * 1e3),
        "default": config == (*DEFAULT, SHIPPED_SOLVER, None, False),
        "shipped": config == (*SHIPPED, SHIPPED_SOLVER, None, False),
    }


def incision_points(seconds: float, integrators=None, periods=None, solvers=SOLVERS) -> list[dict]:
    """The master integrator at 1 ms, the default integrator over the periods, and every slave QP
    solver and tolerance at the defaults, each run on every tick: tracking error (RMS) and depth
    error against CPU load."""
    integrators = tuple(INTEGRATORS) if integrators is None else tuple(integrators)
    periods = PERIODS_MS if periods is None else tuple(periods)

    def pt(i, ms, sv, eps, every):
        return {"kind": "incision", "integrator": i, "period_ms": ms, "solver": sv, "eps": eps,
                "every_tick": every, "seconds": seconds}

    pts = [pt(i, DEFAULT[1], SHIPPED_SOLVER, None, False) for i in integrators]
    pts += [pt(DEFAULT[0], ms, SHIPPED_SOLVER, None, False) for ms in periods if ms != DEFAULT[1]]
    pts += [pt(DEFAULT[0], DEFAULT[1], sv, eps, True) for sv, eps in solvers]
    return pts


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
        r["shipped"] = r.get("shipped") == "True"
        r["every_tick"] = r.get("every_tick") == "True"
        r.pop("front", None)
        out.append(r)
    return out


def _mark(r: dict) -> str:
    return "**default**" if r.get("default") else ("*shipped*" if r.get("shipped") else "")


def write_outputs(rows, out: Path) -> None:
    """accuracy.csv (every row), accuracy.md (the table, with the Pareto front) and pareto.png."""
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "accuracy.csv", "w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)), restval="")
        wr.writeheader()
        wr.writerows(rows)
    lines = [
        "| scene | integrator | period ms | effects | QP solver (eps) | traj / tracking err m | drift / depth err m "
        "| |Gν| | energy err | energy drift | µs median | µs p99 | CPU load % | front |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    main = [r for r in rows if not r["effects"].startswith("effect set")]
    for name in dict.fromkeys(r["scene"] for r in rows):
        sub = [r for r in main if r["scene"] == name]
        # objectives: CPU load (us per tick / period: a shorter period costs more ticks a second),
        # trajectory (or tracking) error, and the constraint drift in position and in velocity
        # (what a haptic user feels as sinking into a surface or a slipping knife edge)
        front = set(
            pareto_front(
                [
                    (
                        r["cpu_load_pct"],
                        max(r["traj_err_m"], 1e-16),
                        max(r["pos_residual_max"], 1e-16),
                        max(r["vel_residual_max"], 1e-16),
                    )
                    for r in sub
                ],
                tie=LOAD_TIE,
            )
        )
        for i, r in enumerate(sub):
            r["front"] = i in front
    for r in rows:
        qp = r["solver"] if r["eps"] != r["eps"] else f"{r['solver']} ({r['eps']:.0e})"  # eps NaN: none
        qp += ", every tick" if r.get("every_tick") else ""
        lines.append(
            f"| {r['scene']} | {r['integrator']} {_mark(r)} | {r['period_ms']:g} | {r['effects']} | "
            f"{qp} | {r['traj_err_m']:.2e} | "
            f"{r['pos_residual_max']:.1e} | {r['vel_residual_max']:.1e} | {r['energy_rel_err']:.1e} | "
            f"{r.get('energy_drift_rel_max', float('nan')):.1e} | "
            f"{r['tick_median_us']:.1f} | {r['tick_p99_us']:.1f} | {r['cpu_load_pct']:.1f} | "
            f"{'yes' if r.get('front') else ''} |"
        )
    (out / "accuracy.md").write_text("\n".join(lines) + "\n")
    plot_pareto(rows, out / "pareto.png")


FLOOR = 1e-17  #: errors below this are drawn at it (exact to round-off)


def _highlight(ax, rows, key) -> list:
    """Rings around the default (red) and the shipped scenes' setting (black) among ``rows``."""
    handles = []
    for flag, color, label in (("default", "red", "default: energy, 1 ms"),
                               ("shipped", "black", "shipped scenes: parametric, 1 ms")):
        d = [r for r in rows if r.get(flag)]
        if d:
            handles += ax.plot(d[0]["cpu_load_pct"], max(d[0][key], FLOOR), "o", ms=15, mfc="none", mec=color,
                               mew=1.4, label=label)
    return handles


def _log_axes(ax, xlabel: str, ylabel: str, title: str) -> None:
    import matplotlib.ticker as mticker

    ax.axvline(100.0, color="k", lw=0.6, ls="--")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_major_locator(mticker.LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(mticker.FormatStrFormatter("%g"))
    ax.xaxis.set_minor_formatter(mticker.NullFormatter())  # labelled minor ticks ran into each other
    ax.set_xlabel(xlabel, fontsize=8)
    ax.set_ylabel(ylabel, fontsize=8)
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3, which="both")


def plot_pareto(rows, path: Path) -> None:
    """Errors against CPU load, log-log: a column per scene (trajectory error, constraint drift,
    energy drift over the force-free stretch of the undamped scenes), one line per integrator
    over the periods; the incision's column (tracking and depth error) one marker per kind of
    point; the legends outside the panels, so that no label covers a point."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    main = [r for r in rows if not r["effects"].startswith("effect set")]
    scenes = [s for s in dict.fromkeys(r["scene"] for r in main) if s != INCISION]
    inc = [r for r in rows if r["scene"] == INCISION]
    integrators = list(dict.fromkeys(r["integrator"] for r in main if r["scene"] != INCISION))
    ncol = len(scenes) + (1 if inc else 0)
    fig, axes = plt.subplots(3, ncol, figsize=(4.3 * ncol + 2.6, 12.5), squeeze=False)
    markers = dict(zip(INTEGRATORS, "osD^v*pXh"))
    colors = dict(zip(INTEGRATORS, plt.get_cmap("tab10").colors))
    rows_spec = (
        ("traj_err_m", "trajectory error vs RK4 @ 0.1 ms [m]"),
        ("pos_residual_max", "constraint drift max |h| [m]"),
        ("energy_drift_rel_max", "energy drift, force-free stretch (relative)"),
    )
    legend = {}
    for col, name in enumerate(scenes):
        for row, (key, label) in enumerate(rows_spec):
            ax = axes[row][col]
            if key == "energy_drift_rel_max" and name not in UNDAMPED:
                ax.set_axis_off()  # damped: no force-free stretch
                continue
            for integ in integrators:
                sub = [r for r in main if r["scene"] == name and r["integrator"] == integ]
                h, = ax.plot([r["cpu_load_pct"] for r in sub], [max(r[key], FLOOR) for r in sub],
                             marker=markers[integ], color=colors[integ], lw=0.8, ms=5, label=integ)
                legend.setdefault(integ, h)
            for h in _highlight(ax, [r for r in main if r["scene"] == name], key):
                legend.setdefault(h.get_label(), h)
            _log_axes(ax, "CPU load, % of real time (µs per tick / period)", label,
                      f"{name}\n(periods 0.1-2 ms; {FLOOR:g} = exact)")
    fig.legend(list(legend.values()), list(legend.keys()), loc="lower center", ncol=len(legend), fontsize=9,
               title="integrator (points along a line: periods 2, 1, 0.5, 0.25, 0.1 ms from left to right)",
               title_fontsize=9)
    if inc:
        _plot_incision(axes, ncol - 1, inc, markers, plt)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _plot_incision(axes, col, inc, markers, plt) -> None:
    """The incision's column: one legend entry per kind of point (labels on the points overlap)."""
    groups: dict = {}
    for r in inc:
        if r["every_tick"]:
            key = f"{r['solver']} QP every tick" + ("" if r["eps"] != r["eps"] else f" (eps {r['eps']:.0e})")
        elif r["period_ms"] != DEFAULT[1]:
            key = f"{r['integrator']}, period {r['period_ms']:g} ms"
        else:
            key = f"{r['integrator']}, {DEFAULT[1]:g} ms"
        groups.setdefault(key, []).append(r)
    colors = plt.get_cmap("tab20").colors
    for row, (key, label) in enumerate((("traj_err_m", "slave tip tracking RMS [m]"),
                                        ("pos_residual_max", "slave cut depth error max [m]"))):
        ax = axes[row][col]
        for k, (name, sub) in enumerate(groups.items()):
            every = sub[0]["every_tick"]
            marker = "P" if every else ("x" if "period" in name else markers.get(sub[0]["integrator"], "o"))
            ax.plot([r["cpu_load_pct"] for r in sub], [max(r[key], FLOOR) for r in sub], marker, ms=6,
                    color=colors[k % len(colors)], label=name, mew=1.5)
        _highlight(ax, inc, key)
        _log_axes(ax, "CPU load, % of real time (whole tick / period)", label,
                  f"{INCISION}:\nmaster integrators, periods, slave QP solvers")
    handles, labels = axes[0][col].get_legend_handles_labels()
    axes[2][col].set_axis_off()
    axes[2][col].legend(handles, labels, fontsize=8, loc="upper left", ncol=1, frameon=False,
                        title=f"{INCISION} points", title_fontsize=9)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", metavar="DIR", help=out_help("accuracy_vs_time", "accuracy.csv, accuracy.md and "
                                                                             "pareto.png"))
    ap.add_argument("--seconds", type=float, default=2.0, metavar="S",
                    help="simulated seconds per paper-scene point, s (default 2)")
    ap.add_argument("--incision-seconds", type=float, default=2.0, metavar="S",
                    help="simulated seconds per straight_incision point, s (default 2; 0: no incision points)")
    ap.add_argument("--scenes", nargs="+", choices=SCENES, metavar="NAME",
                    help=f"a subset of the scenes (default: all: {', '.join(SCENES)})")
    ap.add_argument("--integrators", nargs="+", choices=tuple(INTEGRATORS), metavar="NAME",
                    help=f"a subset of the integrators (default: all: {', '.join(INTEGRATORS)})")
    ap.add_argument("--periods", nargs="+", type=float, metavar="MS",
                    help=f"control periods, ms (default: {' '.join(f'{x:g}' for x in PERIODS_MS)})")
    ap.add_argument("--quick", action="store_true",
                    help="a smoke run: paper_rolling_disk, periods 1 and 2 ms, the default and shipped integrators, "
                         "0.5 s per point, no incision points (the options above narrow it further)")
    ap.add_argument("--replot", metavar="CSV", help="redraw the table and plot from an accuracy.csv, no runs")
    add_sweep_args(ap)
    args = ap.parse_args(argv)
    check_sweep_args(ap, args)
    if args.quick:
        args.scenes = args.scenes or ["paper_rolling_disk"]
        args.integrators = args.integrators or sorted({DEFAULT[0], SHIPPED[0]})
        args.periods = args.periods or [1.0, 2.0]
        args.seconds, args.incision_seconds = min(args.seconds, 0.5), 0.0
    if args.seconds <= 0 or args.incision_seconds < 0:
        ap.error("--seconds must be > 0 and --incision-seconds >= 0")
    if args.periods and min(args.periods) <= 0:
        ap.error(f"--periods: expected periods > 0 ms, got {args.periods}")
    if args.replot and not Path(args.replot).is_file():
        ap.error(f"--replot: no such file {args.replot}")
    out = study_folder("accuracy_vs_time", args.out)
    if args.replot:
        rows = read_csv(Path(args.replot))
    else:
        points = sweep_points(args.seconds, args.incision_seconds, args.scenes, args.integrators, args.periods)
        results = run_sweep(run_point, points, args.workers, args.scheduler, desc="accuracy study")
        rows = assemble(points, results)
        print_rows(rows)
    write_outputs(rows, out)
    print(f"wrote {out}/accuracy.csv, accuracy.md, pareto.png ({len(rows)} points)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
