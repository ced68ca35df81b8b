"""The cobot's stable rendering range, mapped by lockstep simulation beside the analytic boundary.

Each point renders a free tool (mass, inertia, damping, stiffness) on the simulated CAN cobot with
given device settings (control period, servo bandwidth, bus latency, handle mass, PID gains,
inertia compensation), kicks it with a scripted force (or torque) pulse, no hand on the handle,
and runs 0.5 s in lockstep. Criterion, stated: a point is UNSTABLE when the run ends in a fault
(the tracking fault at 20 mm / 0.35 rad, NaN, any non-ok status), when the tracking error
|q_r - q_v| over the last 0.2 s has an RMS above 0.5 mm (10 mrad on a rotation: a limit cycle; a
stable loop keeps it near 10 µm under the load cell's noise), or when that RMS grew more than 5x
from its value over 0.05-0.15 s while above 50 µm (1 mrad): an oscillation that grows. (The tool's
own energy is no criterion here: under the load cell's 0.02 N of noise a free 10 g tool random-walks
by as much as the kick gave it, stable or not.) Every point is seeded from (seed, point
index), so the results do not depend on the number of workers.

    python tools/stability_map.py [--workers N | --scheduler ADDRESS] [--out DIR]
                                  [--quick] [--from-json docs/stability/map.json]

Writes map.json (every point), table.md and zwidth.png into a new ``runs/stability_map-DATE-TIME/``,
or into ``--out`` (the published map: ``--out docs/stability``). Points run through Dask
(teleop.app.sweep: a local cluster of N single-threaded processes by default, or the scheduler at
ADDRESS).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import matplotlib
import numpy as np

from teleop.app.outputs import out_help, study_folder
from teleop.app.sweep import add_sweep_args, check_sweep_args, run_sweep
from teleop.control.stability import LoopParams, critical_mass
from teleop.dynamics import fixtures
from teleop.dynamics.body import RigidBody
from teleop.dynamics.effects import AngularDamper, LinearDamper, Spring
from teleop.dynamics.tool import ReferenceTool
from teleop.master import CobotConfig, CobotMaster
from teleop.tick.master_side import MasterSide, SetWrench

PULSE_S, DURATION_S, TAIL_S = 0.02, 0.5, 0.2
KICK_M_PER_S, KICK_RAD_PER_S = 0.05, 0.5
RMS_LIMIT = {"linear": 5e-4, "angular": 1e-2}  # m, rad
GROWTH, GROWTH_FLOOR = 5.0, {"linear": 5e-5, "angular": 1e-3}  # x, m, rad
EARLY_S = (0.05, 0.15)
HANDLE_INERTIA_X = 0.00012 + 0.15 * 0.03 ** 2  #: the shipped handle about H's x axis, kg*m^2

#: the device's settings a point may change, with their defaults (CobotConfig's)
DEVICE = {"dt_s": 1e-3, "servo_bandwidth_hz": 200.0, "latency_ms": 0.0, "handle_scale": 1.0, "gain_scale": 1.0,
          "inertia_compensation": "servo_model"}


def run_point(point: dict) -> dict:
    """One lockstep run (see the module docstring). ``point``: axis ("linear" or "angular"),
    mass (kg, or kg*m^2 for "angular"), damping, stiffness, seed, and any of DEVICE's keys.
    Returns the point with: stable, status, rms_tail, growth (the tail's RMS over the early one)."""
    d = {**DEVICE, **point}
    angular = d["axis"] == "angular"
    g = d["gain_scale"]
    cfg = CobotConfig.from_dict({
        "offset_rotvec_rad": [math.pi / 2, 0.0, 0.0],  # the wrist mid-range
        "servo_bandwidth_hz": d["servo_bandwidth_hz"], "kp": 40000.0 * g * g, "ki": 400000.0 * g ** 3,
        "kd": 400.0 * g, "inertia_compensation": d["inertia_compensation"],
        "faults": {"latency_ms": d["latency_ms"]}}, "cobot")
    m_lin, J = (0.25, d["mass"]) if angular else (d["mass"], 0.0025)
    effects = [LinearDamper(0.0 if angular else d["damping"]), AngularDamper(d["damping"] if angular else 0.0)]
    if d["stiffness"] > 0:
        effects.append(Spring(np.zeros(3), 0.0 if angular else d["stiffness"],
                              k_Nm_per_rad=d["stiffness"] if angular else 0.0))
    tool = ReferenceTool(RigidBody(m_lin, [J] * 3), fixtures.free(), effects, integrator="parametric")
    tool.reset(np.zeros(6))
    dt = d["dt_s"]
    rng = np.random.default_rng([int(d["seed"]), int(d["index"])])
    master = CobotMaster(cfg, dt, rng, *tool.pose(), tool.body.mass_kg)
    _scale_handle(master, d["handle_scale"])
    kick = np.zeros(6)
    kick[3 if angular else 0] = (KICK_RAD_PER_S if angular else KICK_M_PER_S) * d["mass"] / PULSE_S
    n, n_tail = round(DURATION_S / dt), round(TAIL_S / dt)
    err, status = np.zeros(n), "ok"
    side = MasterSide(tool, master, SetWrench(), dt)  # the master side every run ticks
    with master:
        for i in range(n):
            side.operator.W = kick if i * dt < PULSE_S else np.zeros(6)
            status = side.tick(i, i * dt)
            e = master.ctrl.error
            err[i] = np.linalg.norm(e[3:] if angular else e[:3])
            if status != "ok" or not np.isfinite(tool.q).all():
                status = status if status != "ok" else "nan"
                break
    if status != "ok":
        return {**point, "stable": False, "status": status, "rms_tail": math.inf, "growth": math.inf}
    rms = float(np.sqrt(np.mean(err[n - n_tail:] ** 2)))
    early = err[round(EARLY_S[0] / dt):round(EARLY_S[1] / dt)]
    growth = rms / max(float(np.sqrt(np.mean(early ** 2))), 1e-12)
    axis = d["axis"]
    stable = rms <= RMS_LIMIT[axis] and not (growth > GROWTH and rms > GROWTH_FLOOR[axis])
    return {**point, "stable": bool(stable), "status": status, "rms_tail": rms, "growth": growth}


def _scale_handle(master, s: float) -> None:
    """The handle behind the load cell s times as heavy (mass and inertia), on the plant and the
    host's model alike (they share the CobotModel)."""
    if s != 1.0:
        m = master.model
        m.handle_mass_kg, m.handle_J_H = m.handle_mass_kg * s, m.handle_J_H * s


def analytic_params(point: dict) -> LoopParams:
    """The linear model's settings for a map point (LoopParams: one axis at the handle)."""
    d = {**DEVICE, **point}
    g = d["gain_scale"]
    angular = d["axis"] == "angular"
    handle = (HANDLE_INERTIA_X if angular else 0.15) * d["handle_scale"]
    return LoopParams(mass=d["mass"], damping=d["damping"], stiffness=d["stiffness"], handle_mass=handle,
                      dt_s=d["dt_s"], servo_bandwidth_hz=d["servo_bandwidth_hz"],
                      latency_periods=math.ceil(d["latency_ms"] * 1e-3 / d["dt_s"] - 1e-9),
                      kp=40000.0 * g * g, ki=400000.0 * g ** 3, kd=400.0 * g,
                      compensation=d["inertia_compensation"])


# -- the sweeps -------------------------------------------------------------------------------------

MASSES = (0.005, 0.01, 0.02, 0.03, 0.05, 0.08, 0.12, 0.2)
INERTIAS = (1e-5, 2e-5, 4e-5, 8e-5, 1.6e-4, 3.2e-4, 6.4e-4)
DAMPINGS = (0.0, 0.5, 2.0, 8.0)
ROWS = (  # (label, device overrides) of the table: the critical mass against each device setting
    ("default (1 ms, 200 Hz, no latency)", {}),
    ("period 0.5 ms", {"dt_s": 5e-4}),
    ("period 2 ms", {"dt_s": 2e-3}),
    ("servo 100 Hz", {"servo_bandwidth_hz": 100.0}),
    ("servo 400 Hz", {"servo_bandwidth_hz": 400.0}),
    ("bus latency 1 ms", {"latency_ms": 1.0}),
    ("bus latency 2 ms", {"latency_ms": 2.0}),
    ("handle x2 (0.30 kg)", {"handle_scale": 2.0}),
    ("gains x0.5 (PID bandwidth)", {"gain_scale": 0.5}),
)


def sweep_points(quick: bool = False, seed: int = 0) -> list[dict]:
    """Every point of the map: the Z-width sweep (mass x damping, both compensations), the
    device-settings table (mass ladder per row and compensation), the rotational ladder."""
    masses = (*MASSES[::2], MASSES[-1]) if quick else MASSES
    pts = []
    for comp in ("commanded", "servo_model"):
        for b in (DAMPINGS[:2] if quick else DAMPINGS):
            for m in masses:
                pts.append({"sweep": "zwidth", "axis": "linear", "mass": m, "damping": b, "stiffness": 0.0,
                            "inertia_compensation": comp})
        for m in masses:
            pts.append({"sweep": "spring", "axis": "linear", "mass": m, "damping": 0.0, "stiffness": 2000.0,
                        "inertia_compensation": comp})
        for label, dev in (ROWS[:2] if quick else ROWS)[1:]:
            for m in masses:
                pts.append({"sweep": "table", "row": label, "axis": "linear", "mass": m, "damping": 0.0,
                            "stiffness": 0.0, "inertia_compensation": comp, **dev})
        for J in (INERTIAS[::2] if quick else INERTIAS):
            pts.append({"sweep": "angular", "axis": "angular", "mass": J, "damping": 0.0, "stiffness": 0.0,
                        "inertia_compensation": comp})
    for i, p in enumerate(pts):
        p.update(index=i, seed=seed)
    return pts


def run_points(points: list[dict], workers: int = 2, scheduler: str | None = None) -> list[dict]:
    """Every point through Dask (teleop.app.sweep) with a tqdm progress bar; results in the points' order."""
    return run_sweep(run_point, points, workers, scheduler, desc="stability map")


def lightest_stable(results: list[dict]) -> float:
    """The lightest mass of a ladder above which every point is stable (inf: none)."""
    ok = sorted((r["mass"], r["stable"]) for r in results)
    best = math.inf
    for m, stable in reversed(ok):
        if not stable:
            break
        best = m
    return best


def write_outputs(results: list[dict], out: Path) -> None:
    """map.json, table.md and zwidth.png (see the README section "The stable rendering range")."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "map.json").write_text(json.dumps(results, indent=1))
    lines = ["| device | compensation | lightest stable, simulated (kg) | analytic (kg) |", "|---|---|---|---|"]
    rows = [("default (1 ms, 200 Hz, no latency)", "zwidth", {"damping": 0.0})] + \
           [(label, "table", {}) for label, _ in ROWS[1:]] + [("spring 2000 N/m", "spring", {}),
                                                              ("rotation (kg m^2, handle 2.55e-4)", "angular", {})]
    for label, sweep, extra in rows:
        for comp in ("commanded", "servo_model"):
            sel = [r for r in results if r["sweep"] == sweep and r["inertia_compensation"] == comp
                   and r.get("row", label) == label and all(r[k] == v for k, v in extra.items())]
            if not sel:
                continue
            sim = lightest_stable(sel)
            params = analytic_params(sel[0])
            ana = critical_mass(params)
            floor = ana <= 1.0001e-3 * params.handle_mass  # the bisection's floor: no limit found
            lines.append(f"| {label} | {comp} | {sim:.3g} | {'none above ' if floor else ''}{ana:.3g} |")
    (out / "table.md").write_text("\n".join(lines) + "\n")
    plot_stability_map([r for r in results if r["sweep"] == "zwidth"], analytic_params, out / "zwidth.png")


def plot_stability_map(results: list[dict], params_of, path: Path) -> None:
    """Z-width style: rendered mass (log) against rendered damping, one panel per compensation;
    simulated points stable (o) / unstable (x), the analytic lightest stable mass as a line."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after the backend is chosen

    comps = ("commanded", "servo_model")
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), sharey=True)
    for ax, comp in zip(axes, comps):
        sel = [r for r in results if r["inertia_compensation"] == comp]
        for stable, marker, color, label in ((True, "o", "tab:green", "stable (sim)"),
                                             (False, "x", "tab:red", "unstable (sim)")):
            pts = [(r["damping"], r["mass"]) for r in sel if r["stable"] == stable]
            if pts:
                ax.scatter(*zip(*pts), marker=marker, c=color, label=label, zorder=3)
        b = np.linspace(0.0, max(r["damping"] for r in sel), 41)
        ref = sel[0]
        ax.plot(b, [critical_mass(params_of({**ref, "damping": x})) for x in b], "k-",
                label="analytic boundary (lightest stable)")
        ax.axhline(0.15, color="grey", ls=":", label="handle behind the load cell, 0.15 kg")
        ax.set_yscale("log")
        ax.set_ylim(2e-3, 0.4)  # the mass ladder's span (the analytic floor below it means: no limit)
        ax.set_xlabel("rendered damping, N s/m")
        ax.set_title(f"inertia compensation: {comp}")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("rendered mass at the handle, kg")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8)
    fig.suptitle("Cobot rendering range, 1 kHz, 200 Hz servo, no hand on the handle")
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sweep_args(ap)
    ap.add_argument("--out", metavar="DIR", help=out_help("stability_map", "map.json, table.md and zwidth.png"))
    ap.add_argument("--quick", action="store_true",
                    help=f"a coarse map for a smoke run: every other mass (kg) and inertia (kg*m^2) of the ladders, "
                         f"dampings {DAMPINGS[0]:g} and {DAMPINGS[1]:g} N*s/m, the default device and {ROWS[1][0]}; "
                         f"each point still runs {DURATION_S:g} s")
    ap.add_argument("--seed", type=int, default=0, help="seed of the load cell's noise, per point (default 0)")
    ap.add_argument("--from-json", default=None, metavar="MAP_JSON",
                    help="redraw the table and plot from a map.json, no runs")
    a = ap.parse_args(argv)
    check_sweep_args(ap, a)
    if a.from_json and not Path(a.from_json).is_file():
        ap.error(f"--from-json: no such file {a.from_json}")
    out = study_folder("stability_map", a.out)
    if a.from_json:
        results = json.loads(Path(a.from_json).read_text())
    else:
        results = run_points(sweep_points(a.quick, a.seed), a.workers, a.scheduler)
    write_outputs(results, out)
    print((out / "table.md").read_text())
    print(f"wrote {out}/map.json, table.md, zwidth.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
