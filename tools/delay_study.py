"""The delay study: stability and transparency over walls, round trips to 2 s, lossy links and the guard.

What delay does to bilateral teleoperation, and what the passivity guard (TDPA) and the local
contact model buy back.

    python tools/delay_study.py [--out DIR] [--scenes stiff_contact straight_incision]
                                [--walls 1e3 1e4 3e4 1e5] [--delays 0 10 100 250 500 1000 2000]
                                [--losses 0 0.05 0.1] [--bursts 0 0.01] [--guards off tdpa model]
                                [--seconds S] [--reuse CSV ...] [--workers N | --scheduler ADDRESS]

Writes into a new ``runs/delay_study-DATE-TIME/`` unless ``--out`` names a folder (the published
study: ``--out docs/delay``). ``--seconds 2`` is the quick mode: every run cut to 2 s; it gives
the full study's verdicts where a 2 s run can tell, and says "cannot judge" where the start-up
outlasts the run (see ``stable`` and ``transparent`` below). Without ``--seconds`` a run lasts the
scene's ``duration_s``, lengthened where a long round trip needs it, so that every point is judged
(the steady window below, a full second after the start-up).

The axes (every combination runs):

* ``--walls``: the contact's stiffness, ``tissue.stiffness`` (N/m), on scenes whose tissue is a
  Kelvin-Voigt wall (``stiff_contact``); a scene with no tissue or another law (the cut's
  Hunt-Crossley tissue, whose stiffness is not in N/m) runs its own tissue once (``wall_N_m`` 0,
  "own" in the table);
* ``--delays``: the round trip, ``link.round_trip_ms`` (ms, half each way);
* ``--losses`` and ``--bursts``: ``link.loss``, the fraction of messages lost independently; every
  lossy point runs once per ``--bursts`` value, the Gilbert-Elliott ``link.burst_enter`` (good to
  bad per message; ``burst_exit`` 0.5: bursts of 2 messages on average, all lost). A lossless point
  stays a clean link. ``loss_mean`` is the stationary share lost, ``loss (1 - b) + b`` with
  ``b = burst_enter / (burst_enter + 0.5)``;
* ``--guards``: ``off`` (``link.passivity = "off"``, ``mapping.feedback_contact_plane = false``:
  the bare delayed channel), ``tdpa`` (the passivity guard alone: passivity "tdpa", no contact
  plane), ``model`` (the guard and the local contact model: passivity "tdpa" and the slave's
  estimated plane rendered at the master about the measured force),
  ``mediated`` (the guard passive by construction and model-mediated contact,
  ``link.guard_slows_motion`` and ``link.model_mediated``: the plane rendered as the master's own
  wall, updated passively, the slave pressing no harder; its drift columns add the wall's offset
  from the slave's surface; what a scene does by default on a delayed link); ``model_unguarded``
  (the plane without the guard) on request. The contact's damping is rendered
  locally in all four (the scene's ``feedback_local_damping``).

Each run gives a row:

* ``stable``: no NaN, no fault (master or slave tracking), contact force below 10x the
  reference run's peak (below) and no oscillation: the tool's 2-50 Hz motion in the last second
  below ``OSC_LIMIT_M`` (energy that keeps growing shows as both). ``cannot judge`` (None) when the
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
* ``F_tissue`` / ``F_tissue_max`` / ``F_felt``: RMS and peak contact force at the slave / RMS
  force felt at the master (N);
* the transparency, from the run's summary (``teleop.app.metrics.link_metrics``): ``felt_rms_N``
  and ``felt_peak_N``, the force felt at the master against the slave's contact force, time-aligned
  at the lag ``felt_lag_ms`` in [0, the round trip] that fits best; ``drift_mm`` /
  ``drift_end_mm``: the guard's largest / final position offset (mm at the slave; 0 unguarded);
* the steady state, over the last second once the hand holds still (its last waypoint) and
  ``SETTLE_ROUND_TRIPS`` round trips have passed, over at least ``OSC_MIN_WINDOW_S`` (nan: cannot
  judge): ``F_ss_N``, the mean contact force, and ``F_ss_err_pct``, its error against the
  reference run's (%); ``v_settled_mm_s``, the slave tip's largest speed (mm/s);
  ``F_peak_x``: the peak contact force over the reference run's;
* ``transparent``: what issue 23 asks of a delayed contact: stable, status ok, steady force within
  ``F_SS_TOL`` of the reference, final drift at most ``DRIFT_END_MAX_M``, no motion above
  ``V_SETTLED_MAX_M_S`` once settled, peak force within ``PEAK_MAX_X`` of the reference and, on a
  cut, the depth error at most ``DEPTH_MAX_M``; None when the run is too short to judge its steady
  state;
* ``diss_mJ``: energy the guard dissipated, both ports (mJ); ``tick_us``: CPU per tick, median
  (µs); ``duration_s``: the run's simulated length (s); ``wall_s``: its wall-clock time (s).

The reference of a scene and wall is its undelayed, lossless run, the ``model`` one where the
grid has it (at zero delay the guard is idle and the plane renders the true wall; ``off`` has no
plane, and a 100 kN/m wall without it faults undelayed), else the next of ``model_unguarded``,
``tdpa``, ``off``; a grid without an undelayed lossless point runs the ``model`` one for it.

``--reuse`` reads rows from earlier ``delay.csv`` files instead of running their points (a point
is its scene, wall, delay, loss, bursts and guard; the unguarded rows do not depend on the guard's
code), so a study split over processes (``--scenes``, ``--walls``, ``--guards``) is merged by one
last call that runs nothing; the relative columns and verdicts are recomputed over the merged
table. Writes ``delay.csv``, ``delay.md`` (the table), ``delay.png`` (stability against delay),
``transparency.png`` (felt force error, drift and steady force error against delay, one line per
wall and guard, one column per channel), ``envelope.png`` (each point's verdict on a grid) and
``passivity.png`` (observers, dissipation and drift of
``PASSIVITY_POINT``).
"""

from __future__ import annotations

import argparse
import csv
import itertools
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

SCENES = ("stiff_contact", "straight_incision")
WALLS_N_M = (1e3, 1e4, 3e4, 1e5)
DELAYS_MS = (0, 10, 100, 250, 500, 1000, 2000)
LOSSES = (0.0, 0.05, 0.1)
BURSTS = (0.0, 0.01)
BURST_EXIT = 0.5  #: Gilbert-Elliott bad->good per message (the [link] default): bursts of 2 messages on average
#: the guard axis: name -> (link.passivity, mapping.feedback_contact_plane, link.model_mediated)
GUARDS = {"off": ("off", False, False), "tdpa": ("tdpa", False, False), "model": ("tdpa", True, False),
          "model_unguarded": ("off", True, False), "mediated": ("tdpa", True, True)}
DEFAULT_GUARDS = ("off", "tdpa", "model", "mediated")
REFERENCE_GUARDS = ("model", "model_unguarded", "tdpa", "off")  #: the reference run's guard, first present
OSC_LIMIT_M = 1e-3  # 2-50 Hz motion of the master's tool beyond this in the last second: oscillating
OSC_BAND_HZ = (2.0, 50.0)  #: the oscillation band, Hz
OSC_WINDOW_S = 1.0  #: the oscillation and the steady state are measured over the run's last this-many seconds ...
OSC_MIN_WINDOW_S = 0.5  #: ... after the start-up, and over at least this long, or not judged
#: the start-up: SETTLE_S plus this many round trips (the straight cut's hand starts at 0.5 s; its
#: transient is gone 1.0 s + 3 round trips in, at 0 to 1000 ms, measured in 0.25 s steps)
SETTLE_S, SETTLE_ROUND_TRIPS = 1.0, 3.0
#: transparent (issue 23's must-show): steady force within this fraction of the reference's, final
#: drift (m), settled speed (m/s), peak force over the reference's, cut depth error (m)
F_SS_TOL, DRIFT_END_MAX_M, V_SETTLED_MAX_M_S, PEAK_MAX_X, DEPTH_MAX_M = 0.10, 0.5e-3, 0.01, 2.0, 50e-6


def settle_s(delay_ms: float) -> float:
    """When the start-up of a run with this round trip (ms) is over, s of run time."""
    return SETTLE_S + SETTLE_ROUND_TRIPS * delay_ms * 1e-3


def hand_still_s(scene) -> float:
    """When the scene's virtual hand reaches its last waypoint and holds (s; 0 without a hand)."""
    hand = getattr(scene.operator, "hand", None)
    wps = getattr(hand, "waypoints", None) or ()
    t = 0.0
    for a, b in itertools.pairwise(wps):
        if tuple(a[1:]) != tuple(b[1:]):
            t = float(b[0])
    return t


def steady_s(delay_ms: float, hand_still: float) -> float:
    """When the steady state of a run with this round trip (ms) begins: the start-up over and
    SETTLE_ROUND_TRIPS round trips after the hand holds still (s of run time)."""
    return max(settle_s(delay_ms), hand_still + SETTLE_ROUND_TRIPS * delay_ms * 1e-3)


def loss_mean(loss: float, bursts: float) -> float:
    """The stationary share of messages lost: ``loss`` in the good state, all in the bad one."""
    b = bursts / (bursts + BURST_EXIT) if bursts > 0 else 0.0
    return loss * (1.0 - b) + b


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


def takes_wall(scene) -> bool:
    """The wall axis applies: the scene's tissue is a Kelvin-Voigt wall (stiffness in N/m)."""
    return scene.tissue is not None and "tissue" in scene.effects and scene.tissue.model == "kelvin_voigt"


def point_sets(name: str, delay_ms: float, loss: float, guard: str, seconds: float | None, wall: float,
               bursts: float) -> list[str]:
    """The ``--set`` assignments of a point (without the duration a full study adds)."""
    passivity, plane, mediated = GUARDS[guard]
    sets = [f"link.round_trip_ms={delay_ms}", f"link.loss={loss}", f'link.passivity="{passivity}"',
            f"mapping.feedback_contact_plane={'true' if plane else 'false'}"]
    flag = "true" if mediated else "false"  # said either way: the defaults are the mediated guard's
    sets += [f"link.model_mediated={flag}", f"link.guard_slows_motion={flag}"]
    if bursts > 0:
        sets += [f"link.burst_enter={bursts}", f"link.burst_exit={BURST_EXIT}"]
    if wall > 0:
        sets.append(f"tissue.stiffness={wall}")
    if seconds:
        sets.append(f"duration_s={seconds}")
    return sets


def run_point(name: str, delay_ms: float, loss: float, guard: str, seconds: float | None, wall: float = 0.0,
              bursts: float = 0.0) -> tuple[dict, dict]:
    """One run: ``guard`` a name of GUARDS, ``wall`` N/m (0: the scene's own tissue), ``bursts``
    the burst_enter probability. ``seconds`` None: the scene's duration, lengthened to judge the
    steady state (see the module docstring)."""
    scene = load_scene(name, sets=point_sets(name, delay_ms, loss, guard, seconds, wall, bursts))
    still = hand_still_s(scene)
    if not seconds:
        need = steady_s(delay_ms, still) + OSC_WINDOW_S
        if need > scene.duration_s + 1e-9:
            scene = load_scene(name, sets=[*point_sets(name, delay_ms, loss, guard, None, wall, bursts),
                                           f"duration_s={math.ceil(need * 10 - 1e-6) / 10}"])
    n = round(scene.duration_s / scene.dt_s)
    felt = FeltForce(n)
    t0 = time.perf_counter()
    r = run_scene(scene, hooks=[felt])
    elapsed = time.perf_counter() - t0
    s, log, m = r.summary, r.log, r.summary["metrics"]
    k, dt = s["steps"], scene.dt_s
    window = round(OSC_WINDOW_S / dt)
    start = max(k - window, math.ceil(settle_s(delay_ms) / dt - 1e-9))
    judged = k - start >= round(OSC_MIN_WINDOW_S / dt)
    osc = oscillation(log["p_r"][start:k], dt) if judged else math.nan
    reg = scene.mapping.registration()
    tip = np.asarray(scene.fixture.tip_m if scene.fixture.type == "scalpel" else (0.0, 0.0, 0.0))
    master_tip_P = np.array([reg.point_to_patient(p) for p in log["p_r"][:k]]) + \
        np.einsum("ij,njk,k->ni", reg.X_PM_R, log["R_r"][:k], tip)
    slave_tip = log["slave_tip"][:k]
    track = float(np.sqrt(np.mean(np.sum((slave_tip - master_tip_P) ** 2, axis=1)))) if k else 0.0
    contact = log["slave_contact_N"][:k]
    # the steady state: the last second once the hand holds still and the round trips have passed
    s0 = max(k - window, math.ceil(steady_s(delay_ms, still) / dt - 1e-9))
    steady = k - s0 >= round(OSC_MIN_WINDOW_S / dt) and k == n  # a run cut short by a fault has none
    F_ss = float(np.mean(contact[s0:k])) if steady else math.nan
    v_settled = float(np.max(np.linalg.norm(np.diff(slave_tip[s0 - 1:k], axis=0), axis=1)) / dt) if steady \
        else math.nan
    p = s.get("passivity", {})
    row = {
        "scene": name, "wall_N_m": float(wall), "delay_ms": delay_ms, "loss": loss, "burst_enter": bursts,
        "loss_mean": loss_mean(loss, bursts), "guard": guard,
        "status": s["status"], "nan": s["nan"], "osc_mm": osc * 1e3, "track_mm": track * 1e3,
        "follow_um": m.get("tip_tracking_rms_m", 0.0) * 1e6,
        "depth_um": m.get("cut_depth_error_max_m", 0.0) * 1e6 if scene.fixture.type == "scalpel" else float("nan"),
        "F_tissue": float(np.sqrt(np.mean(contact ** 2))) if k else 0.0,
        "F_tissue_max": float(contact.max(initial=0.0)),
        "F_felt": float(np.sqrt(np.mean(felt.F[:k] ** 2))) if k else 0.0,
        "felt_rms_N": m.get("felt_error_rms_N", math.nan), "felt_peak_N": m.get("felt_error_peak_N", math.nan),
        "felt_lag_ms": m.get("felt_lag_s", math.nan) * 1e3,
        "F_ss_N": F_ss, "v_settled_mm_s": v_settled * 1e3,
        "diss_mJ": (p.get("dissipated_master_J", 0.0) + p.get("dissipated_slave_J", 0.0)) * 1e3,
        # master-slave offset: the guard's drift, plus (model-mediated) the master's wall from the slave's surface
        "drift_mm": (m.get("link_drift_max_m", 0.0) + m.get("link_wall_offset_max_m", 0.0)) * 1e3,
        "drift_end_mm": (m.get("link_drift_final_m", 0.0) + m.get("link_wall_offset_final_m", 0.0)) * 1e3,
        "tick_us": s["tick_us"]["median"], "duration_s": scene.duration_s, "wall_s": elapsed,
    }
    return row, (log if GUARDS[guard][0] == "tdpa" else {})


def verdict(row: dict, ref_force_max: float) -> bool | None:
    """Stable: no NaN, no fault, no force blow-up, no oscillation; None: none of the first three,
    and the run too short to judge the oscillation (osc_mm nan; see the module docstring)."""
    fault = row["status"] not in ("ok",) and row["status"] != "slave_saturated"
    if row["nan"] or fault or not row["F_tissue_max"] <= 10.0 * max(ref_force_max, 0.1):
        return False
    if math.isnan(row["osc_mm"]):
        return None
    return row["osc_mm"] * 1e-3 < OSC_LIMIT_M


def transparent(row: dict) -> bool | None:
    """Issue 23's must-show on one row (the relative columns filled, see :func:`relate`): stable,
    status ok, steady force within F_SS_TOL, final drift, settled speed, peak force and depth within
    their limits. None when the run is too short for its steady state (F_ss_N nan) or its
    stability, and has neither failed nor faulted: the end-of-run measures of a cut-short run are
    not the full run's (a quick run's start is the full run's start, tick for tick, so a fault or a
    depth error there is one in the full run too)."""
    if row["stable"] is False or row["status"] != "ok":
        return False
    if not math.isnan(row["depth_um"]) and row["depth_um"] > DEPTH_MAX_M * 1e6:
        return False
    if row["stable"] is None or any(math.isnan(row[c]) for c in ("F_ss_N", "F_ss_err_pct", "F_peak_x")):
        return None  # (a relative column is nan when the reference has no steady state or no contact)
    return bool(abs(row["F_ss_err_pct"]) <= 100.0 * F_SS_TOL and row["drift_end_mm"] <= DRIFT_END_MAX_M * 1e3
                and row["v_settled_mm_s"] <= V_SETTLED_MAX_M_S * 1e3 and row["F_peak_x"] <= PEAK_MAX_X)


def reference_key(key: tuple, keys) -> tuple:
    """The key of the reference row of ``key``'s scene and wall among ``keys``: undelayed, lossless,
    the first guard of REFERENCE_GUARDS there is; the ``model`` one when there is none."""
    scene, wall = key[0], key[1]
    for guard in REFERENCE_GUARDS:
        k = (scene, wall, 0.0, 0.0, 0.0, guard)
        if k in keys:
            return k
    return scene, wall, 0.0, 0.0, 0.0, "model"


def _ratio(a: float, b: float) -> float:
    return a / b if b > 0 and math.isfinite(a) and math.isfinite(b) else math.nan


def relate(rows: dict) -> None:
    """Fill each row's columns against its reference (F_ss_err_pct, F_peak_x) and its verdicts
    (stable, transparent), in place; ``rows``: {key: row}."""
    for key, row in rows.items():
        ref = rows[reference_key(key, rows)]
        row["F_ss_err_pct"] = 100.0 * (_ratio(row["F_ss_N"], ref["F_ss_N"]) - 1.0)
        row["F_peak_x"] = _ratio(row["F_tissue_max"], ref["F_tissue_max"])
        row["stable"] = verdict(row, ref["F_tissue_max"])
        row["transparent"] = transparent(row)


COLUMNS = ("scene", "wall_N_m", "delay_ms", "loss", "burst_enter", "guard", "stable", "transparent", "status",
           "osc_mm", "track_mm", "depth_um", "F_tissue", "F_felt", "felt_rms_N", "felt_peak_N", "felt_lag_ms",
           "F_ss_N", "F_ss_err_pct", "F_peak_x", "v_settled_mm_s", "drift_mm", "drift_end_mm", "diss_mJ",
           "tick_us")


def _fmt(v, column: str = "") -> str:
    if v is None:  # a verdict the run cannot give
        return "cannot judge"
    if column == "wall_N_m" and v == 0:
        return "own"
    if isinstance(v, float):
        return "-" if math.isnan(v) else f"{v:.3g}"
    return str(v)


def write_table(rows: list[dict], out: Path) -> None:
    with open(out / "delay.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)), restval="")
        w.writeheader()
        w.writerows(rows)
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r[c], c) for c in COLUMNS) + " |")
    (out / "delay.md").write_text("\n".join(lines) + "\n")


def _line_label(scene: str, wall: float) -> str:
    return f"{scene} {wall / 1e3:g} kN/m" if wall > 0 else f"{scene} (own tissue)"


def _colours(rows: list[dict]) -> dict:
    """A colour per (scene, wall): the walls of a scene darker as they stiffen, each scene its map."""
    import matplotlib

    maps = ("viridis", "Oranges", "Greys", "Blues")
    out = {}
    for i, scene in enumerate(dict.fromkeys(r["scene"] for r in rows)):
        walls = sorted({r["wall_N_m"] for r in rows if r["scene"] == scene})
        cmap = matplotlib.colormaps[maps[i % len(maps)]]
        for j, wall in enumerate(walls):
            if i == 0:  # viridis: light to dark as the wall stiffens
                out[(scene, wall)] = cmap(0.85 - 0.75 * j / max(len(walls) - 1, 1))
            else:  # a sequential map: mid to dark
                out[(scene, wall)] = cmap(0.6 + 0.3 * j / max(len(walls) - 1, 1))
    return out


GUARD_STYLE = {"off": ":", "tdpa": "--", "model": "-", "model_unguarded": "-.", "mediated": (0, (5, 1, 1, 1))}


def _channels(rows: list[dict]) -> list[tuple]:
    return sorted({(r["loss"], r["burst_enter"]) for r in rows})


def _channel_label(ch: tuple) -> str:
    loss, bursts = ch
    if bursts > 0:
        return f"loss {loss:g} + bursts {bursts:g} (mean {loss_mean(loss, bursts):.3g})"
    return f"loss {loss:g}" if loss > 0 else "no loss"


def plot(rows: list[dict], out: Path) -> None:
    """delay.png: stability against delay, one line per scene, wall and guard on the lossless
    link, the band the lossy and bursty links span around it; red circles: unstable somewhere."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = (("osc_mm", "oscillation 2-50 Hz [mm]"), ("track_mm", "master-slave tracking RMS [mm]"),
              ("F_tissue", "contact force RMS [N]"), ("drift_mm", "guard drift max [mm]"))
    colours = _colours(rows)
    fig, axes = plt.subplots(2, 2, figsize=(12, 8))
    for ax, (key, label) in zip(axes.flat, panels):
        for (scene, wall), colour in colours.items():
            for guard, ls in GUARD_STYLE.items():
                pts = [r for r in rows if r["scene"] == scene and r["wall_N_m"] == wall and r["guard"] == guard]
                if not pts or (key == "drift_mm" and GUARDS[guard][0] == "off"):  # no guard, no drift
                    continue
                delays = sorted({r["delay_ms"] for r in pts})
                x, lo, mid, hi, bad = [], [], [], [], []
                for d in delays:
                    at = [r for r in pts if r["delay_ms"] == d]
                    v = [max(r[key], 1e-4) for r in at if math.isfinite(r[key])]
                    if not v:  # an osc_mm not judged (nan) is not drawn
                        continue
                    clean = [max(r[key], 1e-4) for r in at if r["loss"] == 0 and math.isfinite(r[key])]
                    x.append(max(d, 1.0))
                    lo.append(min(v))
                    hi.append(max(v))
                    mid.append(clean[0] if clean else float(np.median(v)))
                    if any(r["stable"] is False for r in at):
                        bad.append((x[-1], mid[-1]))
                if not x:
                    continue
                ax.plot(x, mid, linestyle=ls, color=colour, lw=1.2, marker="o", ms=3,
                        label=f"{_line_label(scene, wall)}, {guard}")
                ax.fill_between(x, lo, hi, color=colour, alpha=0.12, lw=0)
                if bad:
                    ax.scatter(*zip(*bad), s=60, facecolors="none", edgecolors="r", zorder=5)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("round-trip delay [ms] (0 drawn at 1)")
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3, which="both")
    handles, labels = next(((h, lab) for h, lab in (ax.get_legend_handles_labels() for ax in axes.flat) if h),
                           ([], []))
    if handles:
        fig.legend(handles, labels, loc="center right", fontsize=7)
    fig.suptitle("delay study: a line per scene, wall and guard (dotted off, dashed tdpa, solid model, dash-dot-dot "
                 "mediated) on the "
                 "lossless link;\nshaded: the span over the lossy and bursty links; red circles: unstable on one of "
                 "them; below 1e-4 drawn at 1e-4", fontsize=9)
    fig.tight_layout(rect=(0, 0, 0.8 if handles else 1, 0.96))
    fig.savefig(out / "delay.png", dpi=110)
    plt.close(fig)


def plot_transparency(rows: list[dict], out: Path) -> None:
    """transparency.png: the felt force's error against the slave's, the guard's final drift and the
    steady force's error against round trip; a line per scene, wall and guard, a column per channel
    (loss, bursts); red circles: unstable; the dashed grey lines: issue 23's limits."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    channels = _channels(rows)
    panels = (("felt_rms_N", "felt vs true force, RMS [N]", None, 1e-3),
              ("drift_end_mm", "guard drift at the end [mm]", DRIFT_END_MAX_M * 1e3, 1e-3),
              ("F_ss_err_pct", "|steady force error| vs undelayed [%]", 100.0 * F_SS_TOL, 1e-2))
    colours = _colours(rows)
    fig, axes = plt.subplots(len(panels), len(channels), figsize=(3.6 * len(channels) + 1.0, 10.0), squeeze=False,
                             sharex=True, sharey="row")
    drawn = [[] for _ in panels]  # each row's values, for its limits
    for col, ch in enumerate(channels):
        for rix, (key, label, limit, floor) in enumerate(panels):
            ax = axes[rix][col]
            ax.set_xscale("log")
            ax.set_yscale("log")
            for (scene, wall), colour in colours.items():
                for guard, ls in GUARD_STYLE.items():
                    if key == "drift_end_mm" and GUARDS[guard][0] == "off":
                        continue  # no guard, no drift
                    pts = sorted((r for r in rows if r["scene"] == scene and r["wall_N_m"] == wall and
                                  r["guard"] == guard and (r["loss"], r["burst_enter"]) == ch
                                  and math.isfinite(r[key])), key=lambda r: r["delay_ms"])
                    if not pts:
                        continue
                    x = [max(r["delay_ms"], 1.0) for r in pts]
                    y = [max(abs(r[key]), floor) for r in pts]
                    drawn[rix] += y
                    ax.plot(x, y, linestyle=ls, color=colour, lw=1.2, marker="o", ms=3,
                            label=f"{_line_label(scene, wall)}, {guard}")
                    bad = [(xx, yy) for xx, yy, r in zip(x, y, pts) if r["stable"] is False]
                    if bad:
                        ax.scatter(*zip(*bad), s=50, facecolors="none", edgecolors="r", zorder=5)
            if limit is not None:
                ax.axhline(limit, color="0.4", ls="--", lw=0.8)
                drawn[rix].append(limit)
            ax.grid(alpha=0.3, which="both")
            if rix == 0:
                ax.set_title(_channel_label(ch), fontsize=8)
            if col == 0:
                ax.set_ylabel(label, fontsize=8)
            if rix == len(panels) - 1:
                ax.set_xlabel("round trip [ms] (0 at 1)", fontsize=8)
    for rix, (_key, _label, _limit, floor) in enumerate(panels):  # shared along the row
        lo, hi = min(drawn[rix], default=floor), max(drawn[rix], default=floor)
        axes[rix][0].set_ylim(lo / 2.0, hi * 2.0)
    seen = {}
    for ax in axes.flat:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            seen.setdefault(lab, h)
    if seen:  # a column per scene and wall, a row per guard
        ncol = max(len({lab.rsplit(", ", 1)[0] for lab in seen}), 1)
        fig.legend(list(seen.values()), list(seen.keys()), loc="lower center", ncol=ncol, fontsize=7)
    fig.suptitle("transparency: a line per scene, wall and guard (dotted off, dashed tdpa, solid model: tdpa and the "
                 "contact plane, dash-dot-dot mediated: the plane as the master's own wall), a column per "
                 "channel (loss, bursts);\nred circles: unstable; grey dashed: issue "
                 f"23's limits (final drift {DRIFT_END_MAX_M * 1e3:g} mm, steady force {100 * F_SS_TOL:g} %); "
                 "values below a row's floor drawn on it; the steady force only where the run settles long enough "
                 "to judge", fontsize=9)
    fig.tight_layout(rect=(0, 0.08 if seen else 0, 1, 0.95))
    fig.savefig(out / "transparency.png", dpi=100)
    plt.close(fig)


#: the envelope map's cells: (code, colour, what)
ENVELOPE_CODES = ((0, "#1a9850", "transparent (issue 23's limits)"), (1, "#a6d96a", "ok and stable"),
                  (2, "#fdae61", "status ok, unstable"), (3, "#d73027", "fault status"),
                  (4, "#e0e0e0", "cannot judge"))
FAULT_ABBREV = {"slave_joint_limit": "jl", "implausible_feedback": "if", "slave_off_target": "ot",
                "slave_tracking_error": "te", "slave_saturated": "sat"}


def envelope_code(row: dict) -> int:
    """The envelope map's cell of a row (ENVELOPE_CODES)."""
    if row["status"] != "ok" and row["status"] != "slave_saturated":
        return 3
    if row["stable"] is False:
        return 2
    if row["stable"] is None:
        return 4
    return 0 if row["transparent"] else (1 if row["transparent"] is False else 4)


def plot_envelope(rows: list[dict], out: Path) -> None:
    """envelope.png: each point's verdict, a row per scene, wall and guard, a column per round
    trip, a panel per channel (loss, bursts); a fault's cell names it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    channels = _channels(rows)
    groups = list(dict.fromkeys((r["scene"], r["wall_N_m"], r["guard"]) for r in rows))
    delays = sorted({r["delay_ms"] for r in rows})
    at = {(r["scene"], r["wall_N_m"], r["guard"], r["delay_ms"], r["loss"], r["burst_enter"]): r for r in rows}
    cmap = ListedColormap([c for _, c, _ in ENVELOPE_CODES])
    fig, axes = plt.subplots(1, len(channels), figsize=(2.4 * len(channels) + 2.6, 0.28 * len(groups) + 2.0),
                             squeeze=False, sharey=True)
    for ax, ch in zip(axes[0], channels):
        grid = np.full((len(groups), len(delays)), 4.0)
        for i, g in enumerate(groups):
            for j, d in enumerate(delays):
                r = at.get((*g, d, *ch))
                if r is None:
                    grid[i, j] = np.nan
                    continue
                grid[i, j] = envelope_code(r)
                if grid[i, j] == 3:
                    ax.text(j, i, FAULT_ABBREV.get(r["status"], r["status"][:3]), ha="center", va="center",
                            fontsize=6, color="white")
        ax.imshow(np.ma.masked_invalid(grid), cmap=cmap, vmin=-0.5, vmax=len(ENVELOPE_CODES) - 0.5, aspect="auto")
        ax.set_xticks(range(len(delays)), [f"{d:g}" for d in delays], fontsize=7, rotation=90)
        ax.set_xlabel("round trip [ms]", fontsize=8)
        ax.set_title(_channel_label(ch), fontsize=7)
        ax.set_xticks(np.arange(-0.5, len(delays)), minor=True)
        ax.set_yticks(np.arange(-0.5, len(groups)), minor=True)
        ax.grid(which="minor", color="white", lw=0.8)
        ax.tick_params(which="minor", length=0)
    axes[0][0].set_yticks(range(len(groups)),
                          [f"{_line_label(sc, w)}, {g}" for sc, w, g in groups], fontsize=7)
    fig.legend(handles=[Patch(color=c, label=what) for _, c, what in ENVELOPE_CODES], loc="lower center",
               ncol=len(ENVELOPE_CODES), fontsize=7)
    fig.suptitle("the envelope: each run's verdict (jl slave_joint_limit, if implausible_feedback, ot "
                 "slave_off_target)", fontsize=9)
    fig.tight_layout(rect=(0, 0.05, 1, 0.96))
    fig.savefig(out / "envelope.png", dpi=100)
    plt.close(fig)


#: (scene, delay ms, loss, guard, wall N/m, bursts) of passivity.png
PASSIVITY_POINT = ("stiff_contact", 250.0, 0.0, "model", 1e4, 0.0)


def _is_passivity_point(point: tuple) -> bool:
    return point[:4] == PASSIVITY_POINT[:4] and point[5:] == PASSIVITY_POINT[4:]


def sweep_point(point: tuple) -> tuple[dict, dict]:
    """run_point on (scene, delay_ms, loss, guard, seconds, wall, bursts), a pure function of the
    point (the scene's own seed); the log comes back only for the point that passivity.png draws."""
    row, log = run_point(*point)
    return row, (log if _is_passivity_point(point) else {})


def row_key(point: tuple) -> tuple:
    """(scene, wall, delay_ms, loss, bursts, guard) of a point: the key of its row in a delay.csv."""
    name, delay, loss, guard, _seconds, wall, bursts = point
    return name, wall, delay, loss, bursts, guard


def _key(row: dict) -> tuple:
    return row["scene"], row["wall_N_m"], row["delay_ms"], row["loss"], row["burst_enter"], row["guard"]


TEXT = ("scene", "guard", "status")
VERDICTS = ("nan", "stable", "transparent")


def read_rows(paths) -> dict:
    """{(scene, wall, delay_ms, loss, bursts, guard): row} from earlier ``delay.csv`` files (later
    files win). A file without the wall and burst columns (an older study) is refused: ValueError."""
    rows = {}
    for path in paths:
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            missing = {"wall_N_m", "burst_enter", "guard", "F_ss_N"} - set(reader.fieldnames or ())
            if missing:
                raise ValueError(f"{path}: no {', '.join(sorted(missing))} column (a delay.csv of an older "
                                 f"study: run its points again)")
            for r in reader:
                row = {}
                for k, v in r.items():
                    if k in TEXT:
                        row[k] = v
                    elif k in VERDICTS:
                        row[k] = None if v in ("None", "") else v == "True"
                    else:
                        row[k] = float(v) if v not in ("", None) else float("nan")
                rows[_key(row)] = row
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", metavar="DIR", help=out_help("delay_study", "delay.csv, delay.md, delay.png, "
                                                                        "transparency.png, envelope.png and "
                                                                        "passivity.png"))
    ap.add_argument("--scenes", nargs="+", default=SCENES, metavar="NAME",
                    help=f"scene names or .toml paths (default: {' '.join(SCENES)})")
    ap.add_argument("--walls", type=float, nargs="+", default=WALLS_N_M, metavar="N_PER_M",
                    help=f"contact stiffnesses, N/m, set as tissue.stiffness on a scene whose tissue is a "
                         f"Kelvin-Voigt wall (stiff_contact); other scenes run their own tissue once "
                         f"(default: {' '.join(f'{w:g}' for w in WALLS_N_M)})")
    ap.add_argument("--delays", type=float, nargs="+", default=DELAYS_MS, metavar="MS",
                    help=f"round-trip delays, ms (default: {' '.join(map(str, DELAYS_MS))})")
    ap.add_argument("--losses", type=float, nargs="+", default=LOSSES, metavar="FRACTION",
                    help=f"the share of messages the link loses independently, a fraction in [0, 1) (default: "
                         f"{' '.join(map(str, LOSSES))})")
    ap.add_argument("--bursts", type=float, nargs="+", default=BURSTS, metavar="FRACTION",
                    help=f"loss bursts on every lossy point: the Gilbert-Elliott good->bad probability per "
                         f"message (link.burst_enter), a fraction in [0, 1), with burst_exit {BURST_EXIT:g} (bursts "
                         f"of {1 / BURST_EXIT:g} messages on average, all lost); each value a point of its own, 0 "
                         f"none; a lossless point stays clean (default: {' '.join(map(str, BURSTS))})")
    ap.add_argument("--guards", nargs="+", choices=tuple(GUARDS), default=DEFAULT_GUARDS,
                    help="off: no guard, no contact plane; tdpa: the passivity guard (time-domain passivity) "
                         "alone; model: the guard and the contact plane estimated at the slave, rendered at the "
                         "master; mediated (what a scene does by default on a delayed link): the guard "
                         "slowing the motion and model-mediated contact (link.guard_slows_motion, "
                         "link.model_mediated); model_unguarded: the plane without the guard "
                         f"(default: {' '.join(DEFAULT_GUARDS)})")
    ap.add_argument("--seconds", type=float, metavar="S",
                    help=f"simulated seconds of every run, s (default: each scene's duration_s, lengthened to a "
                         f"full steady second after the start-up; 2: the quick mode). The oscillation is judged "
                         f"over the last {OSC_WINDOW_S:g} s after the start-up ({SETTLE_S:g} s + "
                         f"{SETTLE_ROUND_TRIPS:g} round trips), the steady state once the hand holds still and "
                         f"{SETTLE_ROUND_TRIPS:g} round trips more, each over at least {OSC_MIN_WINDOW_S:g} s: a "
                         f"shorter run says 'cannot judge'")
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
    if not all(0 <= x < 1 for x in args.bursts):
        ap.error(f"--bursts: expected fractions in [0, 1), got {args.bursts}")
    if not all(w > 0 for w in args.walls):
        ap.error(f"--walls: expected stiffnesses > 0 N/m, got {args.walls}")
    walls = {}
    for name in args.scenes:
        try:
            scene = load_scene(name)
        except ValueError as e:  # a SceneError: one line
            ap.error(f"--scenes: {e}")
        walls[name] = [float(w) for w in dict.fromkeys(args.walls)] if takes_wall(scene) else [0.0]
    for path in args.reuse:
        if not Path(path).is_file():
            ap.error(f"--reuse: {path}: no such file")
    try:
        old = read_rows(args.reuse)
    except ValueError as e:
        ap.error(f"--reuse: {e}")
    out = study_folder("delay_study", args.out)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    channels = [(float(loss), float(b)) for loss in dict.fromkeys(args.losses)
                for b in (dict.fromkeys(args.bursts) if loss > 0 else (0.0,))]
    channels = list(dict.fromkeys(channels))
    points = [(name, float(delay), loss, guard, args.seconds, wall, bursts) for name in args.scenes
              for wall in walls[name] for delay in dict.fromkeys(args.delays) for loss, bursts in channels
              for guard in args.guards]
    keys = {row_key(p) for p in points}
    for name in args.scenes:  # each scene and wall's reference, run when the grid lacks an undelayed lossless point
        for wall in walls[name]:
            ref = reference_key((name, wall), keys)
            if ref not in keys:
                points.insert(0, (name, 0.0, 0.0, "model", args.seconds, wall, 0.0))
                keys.add(ref)
    todo = [p for p in points if row_key(p) not in old]
    ran = dict(zip(map(row_key, todo), run_sweep(sweep_point, todo, args.workers, args.scheduler, desc="delay study")))
    rows, logs = {}, {}
    for p in points:
        row, log = ran[row_key(p)] if row_key(p) in ran else (dict(old[row_key(p)]), {})
        rows[row_key(p)], logs[row_key(p)] = row, log
    relate(rows)
    for p in points:
        row = rows[row_key(p)]
        print(" ".join(f"{c}={_fmt(row[c], c)}" for c in COLUMNS), flush=True)
        if _is_passivity_point(p) and logs[row_key(p)]:  # a reused row has no log
            plot_passivity(plt, logs[row_key(p)], f"stiff_contact, {PASSIVITY_POINT[4] / 1e3:g} kN/m, "
                           f"{PASSIVITY_POINT[1]:g} ms round trip, TDPA and the contact plane", out / "passivity.png")
    table = [rows[row_key(p)] for p in points]
    write_table(table, out)
    plot(table, out)
    plot_transparency(table, out)
    plot_envelope(table, out)
    unjudged = [(p, r) for p, r in zip(points, table) if r["stable"] is None or r["transparent"] is None]
    if unjudged:
        need = max(steady_s(p[1], hand_still_s(load_scene(p[0]))) + OSC_WINDOW_S for p, _ in unjudged)
        print(f"cannot judge {len(unjudged)} of {len(table)} points: their runs end before the start-up "
              f"({SETTLE_S:g} s + {SETTLE_ROUND_TRIPS:g} round trips, and as many after the hand holds still) "
              f"leaves {OSC_MIN_WINDOW_S:g} s to judge; --seconds {need:g} judges them all")
    print(out / "delay.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
