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

Two sweeps (``--sweep``):

* **mass**: the lightest tool rendered stably (a mass ladder) against each device setting, and the
  Z-width map (mass x damping), beside :func:`teleop.control.stability.critical_mass`;
* **stiffness**: the stiffest spring rendered stably on a tool of a few masses and dampings, at
  1 kHz and at 2 kHz (the default device, servo-model compensation), beside the sampled-data bound
  K < 4 m / T^2 - 2 B / T (:func:`teleop.control.stability.sampled_data_stiffness`) and the
  linearized loop's own boundary (:func:`~teleop.control.stability.critical_stiffness`). Each
  (mass, damping, period) is one task: a ladder of springs x4 from 1 kN/m until one is unstable,
  then bisection in log stiffness between the last stable and the first unstable spring until
  they are within ``--stiffness-tol``; the verdicts (2 kHz above 1 kHz, simulated within 10 % of
  the bound, the rise from 1 to 2 kHz as the bound predicts) are read off those brackets, and say
  "cannot judge" when a bracket straddles the line.

    python tools/stability_map.py [--workers N | --scheduler ADDRESS] [--out DIR]
                                  [--sweep all|mass|stiffness] [--quick] [--stiffness-tol R]
                                  [--from-json docs/stability/map.json]

Writes map.json (every point), table.md (the tables and the verdicts), zwidth.png and
stiffness.png into a new ``runs/stability_map-DATE-TIME/``, or into ``--out`` (the published map:
``--out docs/stability``). Points run through Dask (teleop.app.sweep: a local cluster of N
single-threaded processes by default, or the scheduler at ADDRESS).
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
from teleop.control.stability import LoopParams, critical_mass, critical_stiffness, sampled_data_stiffness
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
    mass (kg, or kg*m^2 for "angular"), damping (N*s/m, N*m*s/rad), stiffness (N/m, N*m/rad), seed,
    index (and trial: a stiffness task's runs), and any of DEVICE's keys.
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
    rng = np.random.default_rng([int(d["seed"]), int(d["index"]), *([int(d["trial"])] if "trial" in d else [])])
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


#: the stiffness sweep: rendered masses (kg), dampings (N*s/m), periods (s: 1 and 2 kHz); every one
#: renders with the default device (servo-model compensation, 200 Hz servo, no latency)
STIFF_MASSES = (0.02, 0.05, 0.25)
STIFF_DAMPINGS = (2.0, 10.0, 30.0)
STIFF_PERIODS = (1e-3, 5e-4)
K_FIRST, K_LADDER, K_CEILING = 1e3, 4.0, 1e9  # N/m, x, N/m: the ladder's first rung, its step, its top
K_TOL, K_TOL_QUICK = 0.01, 0.04  # the bisection's bracket, relative: last stable to first unstable
AGREE = 0.10  # the verdicts' tolerance: simulated against the bound, relative
STIFF_INDEX0 = 10000  # the stiffness tasks' indices (seeds) start here, whichever sweeps run
SWEEPS = ("all", "mass", "stiffness")


def sweep_points(quick: bool = False, seed: int = 0, sweep: str = "all", k_tol: float | None = None) -> list[dict]:
    """Every point of the map: ``sweep`` "mass" the Z-width sweep (mass x damping, both
    compensations), the device-settings table (mass ladder per row and compensation), the
    rotational ladder; "stiffness" one task per (mass, damping, period) of the stiffness sweep
    (:func:`run_stiffness`; ``k_tol`` its bracket, default K_TOL, K_TOL_QUICK with ``quick``);
    "all" both. Indices (seeds) do not depend on which sweeps run."""
    if sweep not in SWEEPS:
        raise ValueError(f"sweep: expected one of {SWEEPS}, got {sweep!r}")
    pts = _mass_points(quick) if sweep in ("all", "mass") else []
    for i, p in enumerate(pts):
        p.update(index=i, seed=seed)
    if sweep in ("all", "stiffness"):
        tol = k_tol if k_tol is not None else K_TOL_QUICK if quick else K_TOL
        masses, dampings = ((STIFF_MASSES[1], STIFF_MASSES[2]), (STIFF_DAMPINGS[0], STIFF_DAMPINGS[2])) if quick else \
            (STIFF_MASSES, STIFF_DAMPINGS)
        k = 0
        for m in STIFF_MASSES:
            for b in STIFF_DAMPINGS:
                for dt in STIFF_PERIODS:
                    if m in masses and b in dampings:
                        pts.append({"sweep": "stiffness", "axis": "linear", "mass": m, "damping": b, "dt_s": dt,
                                    "inertia_compensation": "servo_model", "k_tol": tol,
                                    "index": STIFF_INDEX0 + k, "seed": seed})
                    k += 1
    return pts


def _mass_points(quick: bool) -> list[dict]:
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
    return pts


def run_stiffness(task: dict) -> dict:
    """The stiffest spring the simulated cobot renders stably on ``task``'s tool (mass kg, damping
    N*s/m, dt_s s, any of DEVICE's keys): springs K_FIRST x K_LADDER^j N/m until one is unstable
    (or K_CEILING), then bisection in log stiffness until the last stable and the first unstable
    are within ``task["k_tol"]`` (relative). Each run is :func:`run_point`, seeded (seed, index,
    trial). Returns the task with ``k_stable`` (N/m; 0: not even K_FIRST), ``k_unstable`` (N/m;
    inf: none up to K_CEILING) and ``trials`` (stiffness N/m, stable, status, rms_tail m, growth)."""
    trials: list[dict] = []

    def stable(k: float) -> bool:
        r = run_point({**task, "stiffness": k, "trial": len(trials)})
        trials.append({key: r[key] for key in ("stiffness", "stable", "status", "rms_tail", "growth")})
        return r["stable"]

    lo, hi = 0.0, K_FIRST
    while stable(hi):
        lo, hi = hi, hi * K_LADDER
        if hi > K_CEILING:
            return {**task, "k_stable": lo, "k_unstable": math.inf, "trials": trials}
    while lo > 0 and hi / lo > 1.0 + task["k_tol"]:
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    return {**task, "k_stable": lo, "k_unstable": hi, "trials": trials}


def run_task(point: dict) -> dict:
    """A point of the map: a stiffness task (:func:`run_stiffness`) or one run (:func:`run_point`)."""
    return run_stiffness(point) if point["sweep"] == "stiffness" else run_point(point)


def run_points(points: list[dict], workers: int = 2, scheduler: str | None = None) -> list[dict]:
    """Every point through Dask (teleop.app.sweep) with a tqdm progress bar; results in the points' order."""
    return run_sweep(run_task, points, workers, scheduler, desc="stability map")


def lightest_stable(results: list[dict]) -> float:
    """The lightest mass of a ladder above which every point is stable (inf: none)."""
    ok = sorted((r["mass"], r["stable"]) for r in results)
    best = math.inf
    for m, stable in reversed(ok):
        if not stable:
            break
        best = m
    return best


def write_outputs(results: list[dict], out: Path) -> list[str]:
    """map.json, table.md, zwidth.png and stiffness.png (those of the sweeps ``results`` hold; see
    docs/stability/index.md). Returns the names of the files written."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "map.json").write_text(json.dumps(results, indent=1))
    written, parts = ["map.json", "table.md"], []
    if any(r["sweep"] != "stiffness" for r in results):
        parts.append("\n".join(mass_table(results)))
        plot_stability_map([r for r in results if r["sweep"] == "zwidth"], analytic_params, out / "zwidth.png")
        written.append("zwidth.png")
    rows = stiffness_rows(results)
    if rows:
        parts.append("\n".join(stiffness_table(rows)))
        plot_stiffness(rows, out / "stiffness.png")
        written.append("stiffness.png")
    (out / "table.md").write_text("\n\n".join(parts) + "\n")
    return written


def mass_table(results: list[dict]) -> list[str]:
    """The mass sweep's table (markdown lines): the lightest stable mass, simulated and analytic,
    per device setting and compensation."""
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
    return lines


# -- the stiffness sweep's reading ------------------------------------------------------------------

def stiffness_rows(results: list[dict]) -> list[dict]:
    """One row per stiffness task: mass (kg), damping (N*s/m), dt_s (s), ``bound`` the
    sampled-data bound and ``loop`` the linearized loop's boundary (N/m), ``lo`` the stiffest
    stable and ``hi`` the first unstable spring simulated (N/m)."""
    rows = []
    for r in results:
        if r["sweep"] != "stiffness":
            continue
        rows.append({"mass": r["mass"], "damping": r["damping"], "dt_s": r["dt_s"],
                     "bound": sampled_data_stiffness(r["mass"], r["damping"], r["dt_s"]),
                     "loop": critical_stiffness(analytic_params({**r, "stiffness": 0.0})),
                     "lo": float(r["k_stable"]), "hi": float(r["k_unstable"])})
    return sorted(rows, key=lambda x: (x["mass"], x["damping"], -x["dt_s"]))


def judge(lo: float, hi: float, target: float, tol: float = AGREE) -> str:
    """Whether a boundary known to lie in [lo, hi] is within ``target`` x (1 +- tol): "yes" (the
    whole bracket is), "no" (none of it is), else "cannot judge"."""
    if target * (1 - tol) <= lo and hi <= target * (1 + tol):
        return "yes"
    if hi < target * (1 - tol) or lo > target * (1 + tol):
        return "no"
    return "cannot judge"


def _overall(verdicts: list[str]) -> str:
    return "no" if "no" in verdicts else "cannot judge" if "cannot judge" in verdicts or not verdicts else "yes"


def rate_pairs(rows: list[dict]) -> list[tuple[dict, dict]]:
    """(1 kHz row, 2 kHz row) of each (mass, damping) that has both."""
    by = {(r["mass"], r["damping"], r["dt_s"]): r for r in rows}
    slow, fast = STIFF_PERIODS
    return [(by[(m, b, slow)], by[(m, b, fast)]) for (m, b, dt) in sorted(by) if dt == slow and (m, b, fast) in by]


def stiffness_verdicts(rows: list[dict]) -> list[tuple[str, str, str]]:
    """The stiffness sweep's three claims, each (claim, "yes" / "no" / "cannot judge", detail),
    read off the brackets (:func:`judge`): the 2 kHz boundary above the 1 kHz one; the simulated
    boundary within AGREE of the sampled-data bound at every point; its rise from 1 to 2 kHz within
    AGREE of the bound's."""
    pairs = rate_pairs(rows)
    above = ["yes" if f["lo"] > s["hi"] else "no" if f["hi"] <= s["lo"] else "cannot judge" for s, f in pairs]
    near = [judge(r["lo"], r["hi"], r["bound"]) for r in rows]
    rise = [judge(f["lo"] / s["hi"], f["hi"] / s["lo"] if s["lo"] > 0 else math.inf, f["bound"] / s["bound"])
            for s, f in pairs]
    ratios = [r["lo"] / r["bound"] for r in rows if r["bound"] > 0]
    span = f"stiffest stable / bound {min(ratios):.3f}-{max(ratios):.3f}" if ratios else "no bound"
    pct = round(100 * AGREE)
    return [(f"the 2 kHz boundary above the 1 kHz one, at every mass and damping ({len(pairs)})", _overall(above),
             "first unstable at 1 kHz below the stiffest stable at 2 kHz"),
            (f"simulated within {pct} % of the sampled-data bound at every point ({len(rows)})", _overall(near), span),
            (f"the rise from 1 to 2 kHz as the bound predicts, within {pct} % ({len(pairs)})", _overall(rise),
             "the simulated ratio's bracket against the bound's ratio")]


def stiffness_table(rows: list[dict]) -> list[str]:
    """The stiffness sweep's tables and verdicts (markdown lines)."""
    lines = ["| mass (kg) | damping (N s/m) | rate | bound 4m/T² − 2B/T (N/m) | linearized loop (N/m) | "
             "simulated: stiffest stable (N/m) | first unstable (N/m) | stable / bound |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ratio = r["lo"] / r["bound"] if r["bound"] > 0 else math.nan
        lines.append(f"| {r['mass']:g} | {r['damping']:g} | {1e-3 / r['dt_s']:g} kHz | {r['bound']:.4g} | "
                     f"{r['loop']:.4g} | {r['lo']:.4g} | {r['hi']:.4g} | {ratio:.3f} |")
    pairs = rate_pairs(rows)
    if pairs:
        lines += ["", "| mass (kg) | damping (N s/m) | bound, 2 kHz / 1 kHz | "
                      "simulated (stiffest stable), 2 kHz / 1 kHz |", "|---|---|---|---|"]
        for s, f in pairs:
            sim = f["lo"] / s["lo"] if s["lo"] > 0 else math.inf
            lines.append(f"| {s['mass']:g} | {s['damping']:g} | {f['bound'] / s['bound']:.3f} | {sim:.3f} |")
    lines += ["", "Verdicts (from the brackets: \"cannot judge\" when one straddles the line):", ""]
    lines += [f"* {claim}: **{v}** ({detail})" for claim, v, detail in stiffness_verdicts(rows)]
    return lines


def plot_stiffness(rows: list[dict], path: Path) -> None:
    """Left: the stiffest stable spring (log) against the rendered damping, one colour per mass,
    the sampled-data bound as lines (dashed 1 kHz, solid 2 kHz) and the simulated bracket (stiffest
    stable to first unstable) as markers with bars. Right: the stiffest stable over the bound, with
    the verdicts' +-10 % band."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after the backend is chosen

    fig, (ax, rx) = plt.subplots(1, 2, figsize=(11, 4.8), gridspec_kw={"width_ratios": (1.6, 1)})
    colours = dict(zip(STIFF_MASSES, ("tab:blue", "tab:orange", "tab:green")))
    b = np.linspace(0.0, max(STIFF_DAMPINGS) * 1.05, 61)
    for m in sorted({r["mass"] for r in rows}):
        c = colours.get(m, "k")
        for dt, ls, marker in zip(STIFF_PERIODS, ("--", "-"), ("o", "s")):
            sel = [r for r in rows if r["mass"] == m and r["dt_s"] == dt]
            if not sel:
                continue
            rate = f"{1e-3 / dt:g} kHz"
            ax.plot(b, [sampled_data_stiffness(m, x, dt) for x in b], ls, color=c, lw=1.2,
                    label=f"{m:g} kg, {rate}: bound 4m/T² − 2B/T")
            lo, hi = np.array([r["lo"] for r in sel]), np.array([r["hi"] for r in sel])
            face = "white" if dt == STIFF_PERIODS[0] else c
            ax.errorbar([r["damping"] for r in sel], lo, yerr=[np.zeros_like(lo), np.minimum(hi, 1e12) - lo],
                        fmt=marker, color=c, mfc=face, capsize=3, label=f"{m:g} kg, {rate}: simulated")
            rx.plot([r["damping"] for r in sel], [r["lo"] / r["bound"] for r in sel], marker, color=c, mfc=face,
                    ls="none")
    ax.set_yscale("log")
    ax.set_xlabel("rendered damping B, N s/m")
    ax.set_ylabel("stiffest stable spring K, N/m")
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title("the stiffest stable spring: bound (lines), simulated (markers)", fontsize=9)
    rx.axhspan(1 - AGREE, 1 + AGREE, color="grey", alpha=0.15, label=f"bound ± {100 * AGREE:g} %")
    rx.axhline(1.0, color="k", lw=0.8)
    rx.set_ylim(1 - 2 * AGREE, 1 + 2 * AGREE)
    rx.set_xlabel("rendered damping B, N s/m")
    rx.set_ylabel("simulated stiffest stable / bound")
    rx.grid(True, alpha=0.3)
    rx.legend(fontsize=8, loc="upper right")
    rx.set_title("open: 1 kHz, filled: 2 kHz", fontsize=9)
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=7)
    fig.suptitle("Cobot: the stiffest stable spring at 1 and 2 kHz (servo-model compensation, 200 Hz servo, "
                 "no hand on the handle)", fontsize=10)
    fig.tight_layout(rect=(0, 0.13, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


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
    ap.add_argument("--out", metavar="DIR",
                    help=out_help("stability_map", "map.json, table.md, zwidth.png and stiffness.png"))
    ap.add_argument("--sweep", choices=SWEEPS, default="all",
                    help="mass: the lightest stable tool per device setting and the Z-width map; stiffness: the "
                         f"stiffest stable spring at {', '.join(f'{1e-3 / t:g}' for t in STIFF_PERIODS)} kHz; "
                         "all: both (default)")
    ap.add_argument("--quick", action="store_true",
                    help=f"a coarse map for a smoke run: every other mass (kg) and inertia (kg*m^2) of the ladders, "
                         f"dampings {DAMPINGS[0]:g} and {DAMPINGS[1]:g} N*s/m, the default device and {ROWS[1][0]}; "
                         f"the stiffness sweep on {STIFF_MASSES[1]:g} and {STIFF_MASSES[2]:g} kg, "
                         f"{STIFF_DAMPINGS[0]:g} and {STIFF_DAMPINGS[2]:g} N*s/m, bisected to "
                         f"{100 * K_TOL_QUICK:g} %%; each point still runs {DURATION_S:g} s. Its verdicts are the full "
                         "map's on those points, or 'cannot judge'")
    ap.add_argument("--stiffness-tol", type=float, default=None, metavar="R",
                    help=f"the stiffness sweep's bisection stops when the first unstable spring is within "
                         f"(1 + R) x the last stable one (a ratio; default {K_TOL:g}, {K_TOL_QUICK:g} with --quick)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the load cell's noise, per point (default 0)")
    ap.add_argument("--from-json", default=None, metavar="MAP_JSON",
                    help="redraw the tables, verdicts and plots from a map.json, no runs")
    a = ap.parse_args(argv)
    check_sweep_args(ap, a)
    if a.from_json and not Path(a.from_json).is_file():
        ap.error(f"--from-json: no such file {a.from_json}")
    if a.stiffness_tol is not None and not 0.0 < a.stiffness_tol < 1.0:
        ap.error(f"--stiffness-tol: expected a ratio in (0, 1), got {a.stiffness_tol:g}")
    out = study_folder("stability_map", a.out)
    if a.from_json:
        results = json.loads(Path(a.from_json).read_text())
    else:
        results = run_points(sweep_points(a.quick, a.seed, a.sweep, a.stiffness_tol), a.workers, a.scheduler)
    written = write_outputs(results, out)
    print((out / "table.md").read_text())
    print(f"wrote {', '.join(str(out / f) for f in written)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
