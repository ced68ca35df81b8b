"""Fault-injection campaign on the cobot master: each single fault at a random (seeded) time in the
shipped blade scenes, and what the system did about it.

    python tools/fault_campaign.py [--scenes NAME ...] [--trials N] [--seed S] [--json PATH]

Faults (one per run, injected after the tick whose time first reaches the drawn instant):

* ``sensor_nan``: one load-cell axis reads NaN (the device's firmware checks its samples);
* ``sensor_stuck``: the load cell's converter stops delivering samples;
* ``encoder_jump``: one joint's encoder count jumps by 1-10 mm (gantry) or 0.05-0.5 rad (wrist);
* ``lost_frames``: every frame on the bus is lost from then on;
* ``corrupted_frames``: every frame arrives with one payload bit flipped;
* ``silent_device``: the device stops sending;
* ``slave_joint_limit``: one slave joint's limits close around its position (a joint at its stop);
* ``slave_solver_failure``: the slave's QP solver fails on every tick from then on;
* ``link_loss``: the master-slave link is cut (:meth:`teleop.link.channel.SimulatedChannel.cut`):
  every message of one way (commands or feedback, drawn) or of both is lost from then on. These
  runs use the scene's link as the simulated channel of its ``[link]`` table (at the defaults a
  zero-delay channel, which reproduces the lockstep run exactly).

The injection hooks are the device simulator's :meth:`CobotSimulator.inject_sensor_fault` and its
``faults`` settings, and the channel's ``cut``; the slave faults are applied from here, on the
run's objects, without a hook in ``teleop.slave``: the arm's ``limits`` are replaced, and its QP's
``solve`` is wrapped to report failure.

Per run: detected (the status that names the fault: the master's latched fault; the slave's
``joint_limit`` or ``infeasible_fallback``, see ``SLAVE_DETECTS``; a side's heartbeat losing the
link, :mod:`teleop.tick.heartbeat`), the time from injection to detection, the time to the safe
state, and whether anything unsafe happened from the injection until the safe state (or the end
of the run): the slave's blade tip deeper than the fixture's depth by more than ``DEPTH_TOL_M``, or
a tissue contact force above ``FORCE_LIMIT_N``. The depth is measured against the fixture's own
tissue: a plane scalpel's plane, or the surface of a fixture type that has one
(:func:`teleop.app.metrics.tissue_surface`: ``surface_scalpel``'s B-spline, along its normal at the
tip's foot); a fixture with neither gets no depth column ("-", said under the table) and is judged
on the contact force alone. Times count from the last tick before the fault
acts (a fault detected on the next tick took 1 ms). Safe state: for a master-side fault, the
device at rest (every joint rate below ``SAFE_RATE``) with the slave holding still (tip speed below
``SAFE_TIP_M_S``), the link running at zero velocity for up to ``POST_CYCLES`` periods after the
fault; for a slave fault, the tick the slave's own fallback (QP failure) or bound (joint limit)
takes over, which is the tick it is detected: the master goes on (the run's status names the
slave's fault at the end, and the blade is watched to the end of the run, as the cut goes on);
for a link loss, issue 12's safe states: the master's tool at zero velocity and its remote force
zero, with the slave holding still (its joints held, or its tool held under a clutch-out command);
``t_device_rest_s`` adds when the device's gantry, following the held tool, fell below 1 mm/s.

The device's own log lines (rejected CAN frames, the fault it latched: the injected faults'
expected traces) stay out of the table: they are counted under it, and ``-v`` prints them.
"""

from __future__ import annotations

import argparse
import collections
import json
import logging
import math
import re
import sys
from dataclasses import replace

import numpy as np

from teleop.app.metrics import tissue_surface
from teleop.app.runtime import run_scene
from teleop.scenario.schema import list_scenes, load_scene
from teleop.util.crc32 import crc32
from teleop.util.errors import ConfigError

FAULTS = ("sensor_nan", "sensor_stuck", "encoder_jump", "lost_frames", "corrupted_frames", "silent_device",
          "slave_joint_limit", "slave_solver_failure", "link_loss")
#: the slave statuses that detect a slave fault (a status the fault-free cuts also report, such as
#: "saturated" or a few ticks of "fixtures_relaxed", does not)
SLAVE_DETECTS = {"slave_joint_limit": ("joint_limit",), "slave_solver_failure": ("infeasible_fallback",)}
LINK_WAYS = (("command", "feedback"), ("command",), ("feedback",))  #: a link loss cuts one of these
DEPTH_TOL_M = 50e-6  #: the blade past the fixture's depth by more than this is unsafe, m
FORCE_LIMIT_N = 20.0  #: a tissue contact force above this is unsafe, N
SAFE_RATE = np.array([1e-3] * 3 + [1e-2] * 3)  #: device at rest: joint rates below, m/s x3, rad/s x3
SAFE_TIP_M_S = 1e-3  #: slave holding still: blade tip speed below, m/s
POST_CYCLES = 200  #: hold periods run after a master-side fault to watch the safe state
SAFE_WITHIN_S = 0.05  #: the stated target: detection and safe state within this time of the injection, s
#: a link loss is detected within the heartbeat (20 ms of silence, ``[link] heartbeat_ms``) plus a
#: tick to the first lost message and a tick for the master to read the slave's "link_lost", s
DETECT_WITHIN_S = {"link_loss": 0.022}
WINDOW_S = 0.4  #: a run lasts this long past the injection (a master fault ends it sooner), s


def blade_scenes() -> list[str]:
    """Shipped scenes with a slave holding a blade under a depth fixture."""
    out = []
    for name in list_scenes():
        s = load_scene(name)
        if s.slave is not None and s.fixture.type == "scalpel":
            out.append(name)
    return out


class Injector:
    """Injects one fault at ``t_inject`` (s of run time) and watches the run; handed to
    ``run_scene`` as its view (it only needs ``publish_tick``, called after every tick)."""

    def __init__(self, fault: str, t_inject: float, rng: np.random.Generator, fixture):
        self.fault, self.t_inject, self.rng = fault, t_inject, rng
        self.depth_m, self.normal, self.origin, self._foot = None, None, None, None
        self.surface = tissue_surface(fixture)  # a fixture's own curved tissue, or None
        if self.surface is not None:
            self.depth_m = float(fixture.params.depth_m)
        elif getattr(fixture, "type", None) == "scalpel":  # a plane scalpel: the plane and its depth
            self.normal = np.asarray(fixture.plane_normal, float) / np.linalg.norm(fixture.plane_normal)
            self.origin = np.asarray(fixture.plane_origin_m, float)
            self.depth_m = float(fixture.depth_m)
        self.injected_at = self.detected_at = self.safe_at = None
        self.status_before = None  # the slave's status on the tick of the injection
        self.depth_excess_m = 0.0  # worst blade depth past the fixture's, from injection to safe state
        self.force_max_N = 0.0
        self.detail = ""
        self.ways = ""  # a link loss: the way(s) cut
        self.device_rest_at = None  # a link loss: the device's gantry below SAFE_RATE (s of run time)
        self._tip_prev = None

    # -- the view interface run_scene calls ---------------------------------------------------------
    def publish_tick(self, t_s: float, loop) -> None:
        if self.injected_at is None and t_s + 1e-12 >= self.t_inject:
            self.status_before = loop.slave.state.status
            self._inject(loop, t_s)
            self.injected_at = t_s
            self._tip_prev = loop.slave.state.tip.copy()
            return
        if self.injected_at is None:
            return
        speed = self._watch(loop) if self.safe_at is None or self.fault.startswith("slave_") else None
        if self.detected_at is None:
            if loop.master.status != "ok":  # any master-side fault ends the run: hold, watch the rest
                self.detected_at, self.detail = t_s, loop.master.status
                self._hold_after_fault(loop, t_s)
            elif loop.slave.state.status in SLAVE_DETECTS.get(self.fault, ()):
                # a slave fault: its fallback / bound acts in this very tick
                self.detected_at = self.safe_at = t_s
                self.detail = f"slave {loop.slave.state.status}"
            elif self.fault == "link_loss" and (loop.master_side.heart.lost or loop.slave_side.heart.lost):
                sides = [n for n, h in (("master", loop.master_side.heart), ("slave", loop.slave_side.heart)) if h.lost]
                self.detected_at, self.detail = t_s, f"heartbeat {' and '.join(sides)} ({self.ways} cut)"
        if self.fault == "link_loss" and self.detected_at is not None:
            if self.safe_at is None:  # issue 12's safe states: the tool held, no remote force; the slave still
                held = loop.master_side.heart.lost and not np.any(loop.tool.qd) and not np.any(loop.feedback_W)
                if held and speed < SAFE_TIP_M_S:
                    self.safe_at = t_s
            m = loop.master
            if (
                self.device_rest_at is None
                and m.joints() is not None
                and np.all(np.abs(m.sim.plant.qd[:3]) < SAFE_RATE[:3])
            ):
                self.device_rest_at = t_s  # the device's gantry has stopped following the held tool

    def close(self) -> None:
        pass

    # -- faults -------------------------------------------------------------------------------------
    def _inject(self, loop, t_s: float) -> None:
        m, rng, f = loop.master, self.rng, self.fault
        sim = m.sim
        if f in ("sensor_nan", "sensor_stuck"):
            sim.inject_sensor_fault(f, sim.t, axis=int(rng.integers(0, 6)))
        elif f == "encoder_jump":
            axis = int(rng.integers(0, 6))
            size = rng.uniform(1e-3, 1e-2) if axis < 3 else rng.uniform(0.05, 0.5)
            sim.inject_sensor_fault(f, sim.t, axis=axis, size=size * rng.choice([-1.0, 1.0]))
        elif f == "lost_frames":
            sim.faults = replace(sim.faults, loss_pct=100.0)
        elif f == "corrupted_frames":
            sim.faults = replace(sim.faults, corrupt_pct=100.0)
        elif f == "silent_device":
            sim.faults = replace(sim.faults, silent_after_s=sim.t)
        elif f == "slave_joint_limit":
            arm = loop.slave.arm
            lim, j = arm.limits, int(rng.integers(0, arm.limits.nv))
            q_min, q_max = lim.q_min.copy(), lim.q_max.copy()
            q_min[j] = max(q_min[j], arm.q[j] - lim.margin_rad - 1e-4)
            q_max[j] = min(q_max[j], arm.q[j] + lim.margin_rad + 1e-4)
            arm.limits = replace(lim, q_min=q_min, q_max=q_max)
        elif f == "link_loss":
            ways = LINK_WAYS[int(rng.integers(0, len(LINK_WAYS)))]
            loop.link.cut(t_s + 0.5 * loop.dt, ways)  # from the next tick's messages on
            self.ways = "+".join(ways)
        elif f == "slave_solver_failure":
            qp = loop.slave.arm.qp
            solve = qp.solve

            def failing_solve():
                qd, s, y, _ = solve()
                return qd, s, y, False

            qp.solve = failing_solve
        else:
            raise ValueError(f"fault {f!r}: expected one of {FAULTS}")

    # -- watching -----------------------------------------------------------------------------------
    def _watch(self, loop) -> float:
        """Record the blade's depth and contact force; returns the tip speed (m/s)."""
        s = loop.slave.state
        if self.surface is not None:
            sd, _, self._foot = self.surface.signed_distance(s.tip, self._foot)
            depth = -float(sd)
        elif self.normal is not None:
            depth = -float(self.normal @ (s.tip - self.origin))
        if self.depth_m is not None:
            self.depth_excess_m = max(self.depth_excess_m, depth - self.depth_m)
        self.force_max_N = max(self.force_max_N, float(np.linalg.norm(s.contact_P[:3])))
        speed = float(np.linalg.norm(s.tip - self._tip_prev)) / loop.dt
        self._tip_prev = s.tip.copy()
        return speed

    def _hold_after_fault(self, loop, t_s: float) -> None:
        """The master latched a fault: run the link at zero velocity (the master's hold) and the
        slave on lost commands (it holds its last pose) until both are at rest."""
        m, slave, dt = loop.master, loop.slave_side, loop.dt
        zero = np.zeros(6)
        i0 = round(t_s / dt)
        for k in range(1, POST_CYCLES + 1):
            m.sense(zero)  # the device runs on; the master side has stopped: no command comes
            slave.tick(i0 + k, t_s + k * dt, loop.link)
            speed = self._watch(loop)
            rate = np.abs(m.sim.plant.qd)
            if np.all(rate < SAFE_RATE) and speed < SAFE_TIP_M_S:
                self.safe_at = t_s + k * dt
                return


def run_one(scene_name: str, fault: str, t_inject: float, seed: int, window_s: float = WINDOW_S, sets=()) -> dict:
    """One run of ``scene_name`` on the cobot (with the scene settings ``sets``, "key=value"),
    ``fault`` injected at ``t_inject`` (s), watched for ``window_s`` (s) after it; returns its row
    (see the module docstring)."""
    scene = load_scene(scene_name).with_overrides(list(sets), master="cobot", duration_s=t_inject + window_s)
    inj = Injector(fault, t_inject, np.random.default_rng(seed), scene.fixture)
    result = run_scene(scene, view=inj, simulated_link=True if fault == "link_loss" else None)
    t0 = inj.injected_at
    if t0 is None:  # the run ended before the instant: nothing was injected
        return {"scene": scene_name, "fault": fault, "injected": False, "t_inject_s": None,
                "status": result.summary["status"], "detected": False, "detected_as": "", "unsafe": False}
    row = {"injected": True,
        "scene": scene_name, "fault": fault, "t_inject_s": t0, "status": result.summary["status"],
        "detected": inj.detected_at is not None, "detected_as": inj.detail, "ways_cut": inj.ways,
        "slave_status_before": inj.status_before,
        "t_detect_s": None if inj.detected_at is None else inj.detected_at - t0,
        "t_safe_s": None if inj.safe_at is None else inj.safe_at - t0,
        "t_device_rest_s": None if inj.device_rest_at is None else inj.device_rest_at - t0,
        "depth_excess_um": 1e6 * inj.depth_excess_m if inj.depth_m is not None else math.nan,
        "force_max_N": inj.force_max_N,
    }
    row["unsafe"] = bool(row["depth_excess_um"] > 1e6 * DEPTH_TOL_M or row["force_max_N"] > FORCE_LIMIT_N)  # nan: False
    return row


def run_campaign(
    scenes, trials: int, seed: int, t_range=(0.6, 2.0), progress=None, faults=FAULTS, sets=()
) -> list[dict]:
    """Every fault of ``faults`` in every scene, ``trials`` times; the draws depend on neither
    ``faults`` nor the other scenes (a subset reruns the same instants)."""
    rows = []
    for name in scenes:  # each scene's own stream: a subset of scenes reruns the same instants
        rng = np.random.default_rng([seed, crc32(name.encode())])
        hi = min(t_range[1], load_scene(name).duration_s - WINDOW_S)
        for fault in FAULTS:
            for _ in range(trials):
                t, run_seed = float(rng.uniform(t_range[0], hi)), int(rng.integers(0, 2**31))
                if fault not in faults:
                    continue
                rows.append(run_one(name, fault, t, run_seed, sets=sets))
                if progress is not None:
                    progress(rows[-1])
    return rows


def summarize(rows) -> list[dict]:
    """Per fault: injected, detected, median / max time to detection and to the safe state (ms),
    unsafe runs, worst depth excess (um), worst contact force (N)."""
    out = []
    for fault in FAULTS:
        r = [x for x in rows if x["fault"] == fault and x.get("injected", True)]
        if not r:
            continue
        det = [x["t_detect_s"] for x in r if x["t_detect_s"] is not None]
        safe = [x["t_safe_s"] for x in r if x["t_safe_s"] is not None]
        out.append({
            "fault": fault, "injected": len(r), "detected": len(det), "reached_safe": len(safe),
            "detect_ms_median": 1e3 * float(np.median(det)) if det else math.nan,
            "detect_ms_max": 1e3 * max(det) if det else math.nan,
            "safe_ms_median": 1e3 * float(np.median(safe)) if safe else math.nan,
            "safe_ms_max": 1e3 * max(safe) if safe else math.nan,
            "unsafe": sum(x["unsafe"] for x in r),
            "depth_excess_um_max": max((x["depth_excess_um"] for x in r if not math.isnan(x["depth_excess_um"])),
                                       default=math.nan),
            "force_max_N": max(x["force_max_N"] for x in r),
            "detected_as": sorted({x["detected_as"] for x in r}),
        })
        rest = [x["t_device_rest_s"] for x in r if x.get("t_device_rest_s") is not None]
        if rest:
            out[-1]["device_rest_ms_median"] = 1e3 * float(np.median(rest))
            out[-1]["device_rest_ms_max"] = 1e3 * max(rest)
    return out


def table(summary) -> str:
    head = ("| fault | injected | detected | safe | detection ms (median / max) | safe state ms (median / max) "
            "| unsafe | blade past depth, max µm | contact force max N | detected as |")
    lines = [head, "|" + "---|" * 10]
    for s in summary:
        lines.append(f"| {s['fault']} | {s['injected']} | {s['detected']} | {s['reached_safe']} | "
                     f"{s['detect_ms_median']:.0f} / {s['detect_ms_max']:.0f} | "
                     f"{s['safe_ms_median']:.0f} / {s['safe_ms_max']:.0f} | {s['unsafe']} | "
                     f"{_um(s['depth_excess_um_max'])} | {s['force_max_N']:.1f} | {', '.join(s['detected_as'])} |")
    return "\n".join(lines)


def _um(x: float) -> str:
    return "-" if math.isnan(x) else f"{x:.1f}"


class DeviceLog(logging.Handler):
    """The device's log lines during the campaign (``teleop.master``: rejected CAN frames, the
    faults it latched; the injected faults' own traces), held out of the table: counted by kind,
    and printed at once with ``verbose``. Anything else teleop logs prints as usual."""

    DEVICE = "teleop.master"

    def __init__(self, verbose: bool = False):
        super().__init__(logging.DEBUG)
        self.verbose = verbose
        self.counts: collections.Counter = collections.Counter()

    def emit(self, record: logging.LogRecord) -> None:
        device = record.name.startswith(self.DEVICE)
        if device:
            text = record.getMessage()
            self.counts[re.sub(r"\s*0x[0-9A-Fa-f]+", "", text.split(":")[0])] += 1  # the kind, not the frame id
        if self.verbose or not device:
            print(f"{'debug: ' if device else ''}{record.name}: {record.getMessage()}", file=sys.stderr, flush=True)

    def __enter__(self):
        root = logging.getLogger("teleop")
        self._saved = (root.handlers[:], root.propagate, root.level)
        root.handlers[:], root.propagate = [self], False
        root.setLevel(logging.DEBUG if self.verbose else logging.WARNING)
        return self

    def __exit__(self, *exc) -> None:
        root = logging.getLogger("teleop")
        root.handlers[:], root.propagate, level = self._saved
        root.setLevel(level)

    def note(self) -> str:
        """One line under the table: what the device logged (empty when nothing)."""
        if not self.counts:
            return ""
        kinds = "; ".join(f"{k} x{n}" for k, n in self.counts.most_common())
        return (f"the device logged {sum(self.counts.values())} line(s) during the runs, the injected faults' "
                f"expected traces ({kinds}); " + ("printed above" if self.verbose else "-v prints them"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="*", metavar="NAME",
                    help="scene names, any fixture (default: every shipped scene with a slave and a plane scalpel: "
                         f"{', '.join(blade_scenes())})")
    ap.add_argument("--trials", type=int, default=1, help="injections per fault and scene (default 1)")
    ap.add_argument("--faults", nargs="*", choices=FAULTS, default=list(FAULTS), metavar="FAULT",
                    help=f"a subset of the faults, drawn at the same instants (default all: {', '.join(FAULTS)})")
    ap.add_argument("--seed", type=int, default=0, help="seed of the injection instants and sizes (default 0)")
    ap.add_argument("--t-min", type=float, default=0.6, help="earliest injection, s of run time (default 0.6)")
    ap.add_argument("--t-max", type=float, default=2.0, help="latest injection, s (default 2.0; the cuts run to 5.5)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scene setting for every run, as teleop run's --set (e.g. slave.fallback=\"hold\")")
    ap.add_argument("--json", metavar="PATH", help="write every run's row and the summary here (times in s, depth "
                                                   "in um, force in N; default: nothing written)")
    ap.add_argument("-v", "--verbose", action="store_true",
                    help="print the device's log lines (rejected CAN frames, latched faults) as they come")
    args = ap.parse_args(argv)
    if args.trials < 1:
        ap.error(f"--trials: expected at least 1, got {args.trials}")
    if not 0 <= args.t_min <= args.t_max:
        ap.error(f"--t-min/--t-max: expected 0 <= t-min <= t-max s, got {args.t_min}, {args.t_max}")
    for name in args.scenes or ():
        try:
            load_scene(name)
        except ConfigError as e:
            ap.error(f"--scenes: {e}")
    scenes = args.scenes or blade_scenes()
    with DeviceLog(args.verbose) as device:
        return _campaign(args, scenes, device)


def _campaign(args, scenes, device) -> int:

    def show(row):
        if not row["injected"]:
            print(f"{row['scene']:24s} {row['fault']:22s} not injected: the run ended first ({row['status']})",
                  file=sys.stderr, flush=True)
            return
        print(f"{row['scene']:24s} {row['fault']:22s} t={row['t_inject_s']:.3f} s  -> {row['detected_as'] or '-':22s}"
              f" detect {row['t_detect_s']}  safe {row['t_safe_s']}  depth+ {_um(row['depth_excess_um'])} um"
              f"  F {row['force_max_N']:.1f} N", file=sys.stderr, flush=True)

    rows = run_campaign(scenes, args.trials, args.seed, (args.t_min, args.t_max), progress=show, faults=args.faults,
                        sets=args.set)
    summary = summarize(rows)
    print(f"scenes: {', '.join(scenes)}; {args.trials} trial(s) per fault and scene, injected in "
          f"[{args.t_min}, {args.t_max}] s; seed {args.seed}" + (f"; settings {args.set}" if args.set else ""))
    print(table(summary))
    skipped = sorted({(r["scene"], r["status"]) for r in rows if not r["injected"]})
    for name, status in skipped:
        print(f"not injected in {name}: its cobot run ends before the injection window ({status})")
    no_depth = sorted({r["scene"] for r in rows if r["injected"] and math.isnan(r["depth_excess_um"])})
    if no_depth:
        print(f"no blade depth measured in {', '.join(no_depth)}: the fixture has neither a plane nor a tissue "
              "surface (teleop.app.metrics.tissue_surface); judged on the contact force alone")
    if device.note():
        print(device.note())
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"rows": rows, "summary": summary}, f, indent=1)
    for s in summary:
        if "device_rest_ms_max" in s:
            print(f"{s['fault']}: the device's gantry below 1 mm/s after {s['device_rest_ms_median']:.0f} ms "
                  f"(median), {s['device_rest_ms_max']:.0f} ms (max)")
    ok = all(s["detected"] == s["injected"] and s["reached_safe"] == s["injected"] and s["unsafe"] == 0
             and s["detect_ms_max"] <= 1e3 * DETECT_WITHIN_S.get(s["fault"], SAFE_WITHIN_S)
             and s["safe_ms_max"] <= 1e3 * SAFE_WITHIN_S for s in summary)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
