"""What delay does to bilateral teleoperation, and what the passivity guard (TDPA) buys back.

    python tools/delay_study.py [--out DIR] [--delays 0 10 50 100 200 500 1000]
                                [--losses 0 0.05] [--scenes straight_incision stiff_contact]
                                [--guards off tdpa] [--seconds S] [--reuse CSV ...]
                                [--workers N | --scheduler ADDRESS]

Writes into a new ``runs/delay_study-DATE-TIME/`` unless ``--out`` names a folder (the published
study: ``--out docs/delay``). ``--seconds 2`` is the quick mode: every run cut to 2 s; it gives
the full study's verdicts where a 2 s run can tell (no delay up to 100 ms round trip), and says
"cannot judge" where the start-up outlasts the run (see ``stable`` below).

For each scene, round-trip delay (ms), message loss and guard (off / tdpa) it runs the scene in
simulated time through the [link] channel (``--set link.*``, the same path as the command line)
and records:

* ``stable``: no NaN, no fault (master or slave tracking), contact force below 10x the
  undelayed run's peak and no oscillation: the tool's 2-50 Hz motion in the last second below
  ``OSC_LIMIT_M`` (energy that keeps growing shows as both). ``cannot judge`` (None) when the
  run has none of the first three and is too short to judge the oscillation: the start-up (the
  hand's start and the first feedback coming back: ``SETTLE_S`` plus ``SETTLE_ROUND_TRIPS``
  round trips, measured on both scenes) leaves less than ``OSC_MIN_WINDOW_S`` of it;
* ``osc_mm``: that 2-50 Hz RMS of the reference tool's position over the last second after the
  start-up (mm; nan: cannot judge), the window's straight-line trend taken out first
  (:func:`oscillation`): the hand drags the tool at a steady 30 mm/s through most of a cut, and a
  ramp seen through an FFT window is a sawtooth whose harmonics fill the band (a 2 s run, whose
  last second is mid-cut, read 5.3 mm at zero delay against 0.3 mm for the full run, whose last
  second is at rest: the quick mode said "unstable" where the full study said "stable");
* ``track_mm``: RMS distance of the slave's tip from the master's tip mapped to the patient
  frame, at the same instant (delay, drift and all; mm);
* ``follow_um``: RMS distance of the slave from its own (delayed, corrected) target (µm);
* ``depth_um``: the cut depth error, max while in tissue (µm; scalpel scenes);
* ``F_tissue`` / ``F_felt``: RMS contact force at the slave / RMS force felt at the master (N);
* ``diss_mJ``: energy the guard dissipated, both ports (mJ); ``drift_mm`` / ``drift_end_mm``: the
  slave's largest / final position offset from the guard (mm at the slave);
* ``tick_us``: CPU per tick, median (µs).

``--reuse`` reads rows from earlier ``delay.csv`` files instead of running their points (a point
is its scene, delay, loss and guard; the unguarded rows do not depend on the guard's code), so a
study split over processes (``--scenes``, ``--guards``) is merged by one last call that runs
nothing. Writes ``delay.csv``, ``delay.md`` (the table), ``delay.png`` (the panels against delay) and
``passivity.png`` (observers, dissipation and drift of the stiff scene at 200 ms, guarded).
"""

from __future__ import annotations

import argparse
import csv
import math
import time
from pathlib import Path

import numpy as np

from teleop.app.metrics import band_rms
from teleop.app.outputs import out_help, study_folder
from teleop.app.plots import plot_passivity
from teleop.app.runtime import run_scene
from teleop.app.sweep import add_sweep_args, check_sweep_args, run_sweep
from teleop.scenario.schema import load_scene
from teleop.tick.loop import Hook

DELAYS_MS = (0, 10, 50, 100, 200, 500, 1000)
LOSSES = (0.0, 0.05)
SCENES = ("straight_incision", "stiff_contact")
OSC_LIMIT_M = 1e-3  # 2-50 Hz motion of the master's tool beyond this in the last second: oscillating
OSC_BAND_HZ = (2.0, 50.0)  #: the oscillation band, Hz
OSC_WINDOW_S = 1.0  #: the oscillation is measured over the run's last this-many seconds ...
OSC_MIN_WINDOW_S = 0.5  #: ... after the start-up, and over at least this long, or not judged
#: the start-up: SETTLE_S plus this many round trips (the straight cut's hand starts at 0.5 s; its
#: transient is gone 1.0 s + 3 round trips in, at 0 to 1000 ms, measured in 0.25 s steps)
SETTLE_S, SETTLE_ROUND_TRIPS = 1.0, 3.0


def settle_s(delay_ms: float) -> float:
    """When the start-up of a run with this round trip (ms) is over, s of run time."""
    return SETTLE_S + SETTLE_ROUND_TRIPS * delay_ms * 1e-3


def oscillation(p: np.ndarray, dt_s: float) -> float:
    """RMS (m) of the positions ``p`` (n, 3) in OSC_BAND_HZ, after each axis's least-squares straight
    line is taken out (a steady drag is no oscillation; see the module docstring)."""
    p = np.asarray(p, dtype=float)
    if len(p) < 8:
        return 0.0
    t = np.arange(len(p), dtype=float)
    A = np.column_stack([t, np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(A, p, rcond=None)
    return band_rms(p - A @ coef, dt_s, *OSC_BAND_HZ)


class FeltForce(Hook):
    """The force felt at the master each tick (after the guard), N."""

    def __init__(self, n: int):
        self.F = np.zeros(n)

    def after_tick(self, i, t_s, loop) -> None:
        self.F[i] = float(np.linalg.norm(loop.felt_W[:3]))


def run_point(name: str, delay_ms: float, loss: float, guard: bool, seconds: float | None) -> tuple[dict, dict]:
    sets = [f"link.round_trip_ms={delay_ms}", f"link.loss={loss}",
            f'link.passivity="{"tdpa" if guard else "off"}"']
    if seconds:
        sets.append(f"duration_s={seconds}")
    scene = load_scene(name, sets=sets)
    n = round(scene.duration_s / scene.dt_s)
    felt = FeltForce(n)
    t0 = time.perf_counter()
    r = run_scene(scene, hooks=[felt])
    wall = time.perf_counter() - t0
    s, log, m = r.summary, r.log, r.summary["metrics"]
    k = s["steps"]
    start = max(k - round(OSC_WINDOW_S / scene.dt_s), math.ceil(settle_s(delay_ms) / scene.dt_s - 1e-9))
    judged = k - start >= round(OSC_MIN_WINDOW_S / scene.dt_s)
    osc = oscillation(log["p_r"][start:k], scene.dt_s) if judged else math.nan
    reg = scene.mapping.registration()
    tip = np.asarray(scene.fixture.tip_m if scene.fixture.type == "scalpel" else (0.0, 0.0, 0.0))
    master_tip_P = np.array([reg.point_to_patient(p) for p in log["p_r"][:k]]) + \
        np.einsum("ij,njk,k->ni", reg.X_PM_R, log["R_r"][:k], tip)
    slave_tip = log["slave_tip"][:k]
    track = float(np.sqrt(np.mean(np.sum((slave_tip - master_tip_P) ** 2, axis=1)))) if k else 0.0
    contact = log["slave_contact_N"][:k]
    p = s.get("passivity", {})
    row = {
        "scene": name, "delay_ms": delay_ms, "loss": loss, "guard": "tdpa" if guard else "off",
        "status": s["status"], "nan": s["nan"], "osc_mm": osc * 1e3, "track_mm": track * 1e3,
        "follow_um": m.get("tip_tracking_rms_m", 0.0) * 1e6,
        "depth_um": m.get("cut_depth_error_max_m", 0.0) * 1e6 if scene.fixture.type == "scalpel" else float("nan"),
        "F_tissue": float(np.sqrt(np.mean(contact ** 2))) if k else 0.0,
        "F_tissue_max": float(contact.max(initial=0.0)),
        "F_felt": float(np.sqrt(np.mean(felt.F[:k] ** 2))) if k else 0.0,
        "diss_mJ": (p.get("dissipated_master_J", 0.0) + p.get("dissipated_slave_J", 0.0)) * 1e3,
        "drift_mm": m.get("link_drift_max_m", 0.0) * 1e3, "drift_end_mm": m.get("link_drift_final_m", 0.0) * 1e3,
        "tick_us": s["tick_us"]["median"], "wall_s": wall,
    }
    return row, (log if guard else {})


def verdict(row: dict, ref_force_max: float) -> bool | None:
    """Stable: no NaN, no fault, no force blow-up, no oscillation; None: none of the first three,
    and the run too short to judge the oscillation (osc_mm nan; see the module docstring)."""
    fault = row["status"] not in ("ok",) and row["status"] != "slave_saturated"
    if row["nan"] or fault or not row["F_tissue_max"] <= 10.0 * max(ref_force_max, 0.1):
        return False
    if math.isnan(row["osc_mm"]):
        return None
    return row["osc_mm"] * 1e-3 < OSC_LIMIT_M


COLUMNS = ("scene", "delay_ms", "loss", "guard", "stable", "status", "osc_mm", "track_mm", "follow_um",
           "depth_um", "F_tissue", "F_felt", "diss_mJ", "drift_mm", "drift_end_mm", "tick_us")


def _fmt(v) -> str:
    if v is None:  # a verdict the run cannot give
        return "cannot judge"
    if isinstance(v, float):
        return "-" if math.isnan(v) else f"{v:.3g}"
    return str(v)


def write_table(rows: list[dict], out: Path) -> None:
    with open(out / "delay.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r[c]) for c in COLUMNS) + " |")
    (out / "delay.md").write_text("\n".join(lines) + "\n")


def plot(rows: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = (("osc_mm", "oscillation 2-50 Hz [mm]"), ("track_mm", "master-slave tracking RMS [mm]"),
              ("F_tissue", "contact force RMS [N]"), ("drift_mm", "guard drift [mm]"))
    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    for ax, (key, label) in zip(axes.flat, panels):
        for scene in sorted({r["scene"] for r in rows}):
            for guard, ls in (("off", "--"), ("tdpa", "-")):
                for loss, mk in ((0.0, "o"), (0.05, "x")):
                    pts = [r for r in rows if r["scene"] == scene and r["guard"] == guard and r["loss"] == loss
                           and math.isfinite(r[key])]  # an osc_mm not judged (nan) is not drawn
                    if not pts:
                        continue
                    x = [max(r["delay_ms"], 1.0) for r in pts]
                    ax.plot(x, [max(r[key], 1e-6) for r in pts], ls, marker=mk, ms=4, lw=1,
                            label=f"{scene} {guard} loss {loss:g}")
                    bad = [(xx, max(r[key], 1e-6)) for xx, r in zip(x, pts) if r["stable"] is False]
                    if bad:
                        ax.scatter(*zip(*bad), s=60, facecolors="none", edgecolors="r")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("round-trip delay [ms] (0 drawn at 1)")
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3, which="both")
    drawn = next((ax for ax in axes.flat if ax.get_legend_handles_labels()[0]), None)
    if drawn is not None:  # the first panel that has points (osc_mm has none when no run could be judged)
        drawn.legend(fontsize=6)
    fig.suptitle("delay study: dashed unguarded, solid TDPA; red circles: unstable", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "delay.png", dpi=110)
    plt.close(fig)


PASSIVITY_POINT = ("stiff_contact", 200.0, 0.0, True)  #: (scene, delay ms, loss, guard) of passivity.png


def sweep_point(point: tuple) -> tuple[dict, dict]:
    """run_point on (scene, delay_ms, loss, guard, seconds), a pure function of the point (the
    scene's own seed); the log comes back only for the point that passivity.png draws."""
    row, log = run_point(*point)
    return row, (log if point[:4] == PASSIVITY_POINT else {})


def row_key(point: tuple) -> tuple:
    """(scene, delay_ms, loss, guard name) of a point: the key of its row in a delay.csv."""
    return point[0], point[1], point[2], "tdpa" if point[3] else "off"


def read_rows(paths) -> dict:
    """{(scene, delay_ms, loss, guard): row} from earlier ``delay.csv`` files (later files win)."""
    rows = {}
    for path in paths:
        with open(path, newline="") as f:
            for r in csv.DictReader(f):
                row = {}
                for k, v in r.items():
                    if k in ("scene", "guard", "status"):
                        row[k] = v
                    elif k in ("nan", "stable"):
                        row[k] = None if v in ("None", "") else v == "True"
                    else:
                        row[k] = float(v) if v not in ("", None) else float("nan")
                row.setdefault("drift_end_mm", float("nan"))
                rows[(row["scene"], row["delay_ms"], row["loss"], row["guard"])] = row
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", metavar="DIR", help=out_help("delay_study", "delay.csv, delay.md, delay.png and "
                                                                        "passivity.png"))
    ap.add_argument("--delays", type=float, nargs="+", default=DELAYS_MS, metavar="MS",
                    help=f"round-trip delays, ms (default: {' '.join(map(str, DELAYS_MS))})")
    ap.add_argument("--losses", type=float, nargs="+", default=LOSSES, metavar="FRACTION",
                    help=f"the share of messages the link loses, a fraction in [0, 1) (default: "
                         f"{' '.join(map(str, LOSSES))})")
    ap.add_argument("--scenes", nargs="+", default=SCENES, metavar="NAME",
                    help=f"scene names or .toml paths (default: {' '.join(SCENES)})")
    ap.add_argument("--seconds", type=float, metavar="S",
                    help=f"simulated seconds of every run, s (default: each scene's duration_s; 2: the quick "
                         f"mode). The oscillation is judged over the last {OSC_WINDOW_S:g} s after the start-up "
                         f"({SETTLE_S:g} s + {SETTLE_ROUND_TRIPS:g} round trips), over at least "
                         f"{OSC_MIN_WINDOW_S:g} s: a shorter run says 'cannot judge'")
    ap.add_argument("--guards", nargs="+", choices=("off", "tdpa"), default=("off", "tdpa"),
                    help="the passivity guard: off, tdpa (the time-domain passivity approach), or both (default)")
    ap.add_argument("--reuse", nargs="+", default=(), metavar="CSV",
                    help="take the rows of these earlier delay.csv files instead of running their points")
    add_sweep_args(ap)
    args = ap.parse_args(argv)
    check_sweep_args(ap, args)
    if args.seconds is not None and not args.seconds > 0:
        ap.error(f"--seconds: expected a positive duration, s, got {args.seconds:g}")
    if min(args.delays) < 0:
        ap.error(f"--delays: expected delays >= 0 ms, got {args.delays}")
    if not all(0 <= x < 1 for x in args.losses):
        ap.error(f"--losses: expected fractions in [0, 1), got {args.losses}")
    for name in args.scenes:
        try:
            load_scene(name)
        except ValueError as e:  # a SceneError: one line
            ap.error(f"--scenes: {e}")
    out = study_folder("delay_study", args.out)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for path in args.reuse:
        if not Path(path).is_file():
            ap.error(f"--reuse: {path}: no such file")
    old = read_rows(args.reuse)
    points = [(name, float(delay), float(loss), guard, args.seconds) for name in args.scenes
              for delay in args.delays for loss in args.losses for guard in (False, True)
              if ("tdpa" if guard else "off") in args.guards]
    todo = [p for p in points if row_key(p) not in old]
    ran = dict(zip(map(row_key, todo), run_sweep(sweep_point, todo, args.workers, args.scheduler, desc="delay study")))
    results = [ran[row_key(p)] if row_key(p) in ran else (dict(old[row_key(p)]), {}) for p in points]
    rows, ref_force = [], {}
    for point, (row, log) in zip(points, results):
        # each scene's first point (the first delay and loss, unguarded) is its reference force
        row["stable"] = verdict(row, ref_force.setdefault(point[0], row["F_tissue_max"]))
        rows.append(row)
        print(" ".join(f"{c}={_fmt(row[c])}" for c in COLUMNS), flush=True)
        if point[:4] == PASSIVITY_POINT and log:  # a reused row has no log
            plot_passivity(plt, log, "stiff_contact, 200 ms round trip, TDPA", out / "passivity.png")
    write_table(rows, out)
    plot(rows, out)
    unjudged = [(p, r) for p, r in zip(points, rows) if r["stable"] is None]
    if unjudged:
        need = max(settle_s(p[1]) + OSC_WINDOW_S for p, _ in unjudged)
        print(f"cannot judge {len(unjudged)} of {len(rows)} points: their runs end before the start-up "
              f"({SETTLE_S:g} s + {SETTLE_ROUND_TRIPS:g} round trips) leaves {OSC_MIN_WINDOW_S:g} s to judge the "
              f"oscillation; --seconds {need:g} judges them all")
    print(out / "delay.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
