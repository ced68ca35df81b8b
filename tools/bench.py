"""Benchmarks: microseconds per step, median and p99, against a yardstick timed in the same run.

    python tools/bench.py [--json OUT.json] [--steps N] [--fuzz N] [--engine-only]
                          [--workers N | --scheduler ADDRESS]   (where the fuzzed scenes run)
                          [--record-seconds S] [--record-repeats N] [--record-only]

The machine is shared and noisy, so every figure is taken in interleaved blocks with the
yardstick, one ``pinocchio.aba`` of example-robot-data's Panda (``pin_aba_us``); compare ratios.

What the runs log (a cobot's latched fault when a scene without its heavy effects runs off its
device's tracking, ...) is held out of the table and printed after it, each line with the run it
came from; a scene run whose status is not ok says so on its table line (its tick_us covers the
ticks up to the fault).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

from teleop.app.sweep import add_sweep_args, check_sweep_args, run_sweep

sys.path.insert(0, str(Path(__file__).resolve().parent))


class HeldLog(logging.Handler):
    """teleop's log lines during the benchmark, held (with the run they came from: ``phase``) and
    printed after the table by :meth:`report`, instead of mid-table on stderr."""

    def __init__(self):
        super().__init__(logging.INFO)
        self.phase = ""
        self.lines: list[tuple[str, str, str]] = []  # (phase, logger, message)

    def emit(self, record: logging.LogRecord) -> None:
        if record.levelno >= logging.WARNING:
            self.lines.append((self.phase, record.name, record.getMessage()))

    def __enter__(self):
        root = logging.getLogger("teleop")
        self._saved = (root.handlers[:], root.propagate, root.level)
        root.handlers[:], root.propagate = [self], False
        root.setLevel(logging.WARNING)
        return self

    def __exit__(self, *exc) -> None:
        root = logging.getLogger("teleop")
        root.handlers[:], root.propagate, level = self._saved
        root.setLevel(level)

    def report(self) -> None:
        if not self.lines:
            return
        print("\nwhat the runs logged (held out of the table above):")
        for phase, name, text in self.lines:
            why = ""
            if "fault latched" in text:
                why = ("  -> the cobot's host latched this fault and the run ended there, in its safe state; "
                       "the figures of that run cover the ticks up to it")
            print(f"  {phase or 'bench'}: {name}: {text}{why}")


HELD = HeldLog()


def _stats(samples_ns) -> dict:
    a = np.asarray(samples_ns, dtype=float) * 1e-3
    return {"median": round(float(np.median(a)), 2), "p99": round(float(np.percentile(a, 99)), 2)}


class Yardstick:
    """pinocchio.aba on the Panda at random states."""

    def __init__(self, seed: int = 0):
        import example_robot_data
        import pinocchio as pin

        self.pin = pin
        robot = example_robot_data.load("panda")
        self.model, self.data = robot.model, robot.model.createData()
        rng = np.random.default_rng(seed)
        self.states = [
            (pin.randomConfiguration(self.model), rng.normal(size=self.model.nv), rng.normal(size=self.model.nv))
            for _ in range(64)
        ]
        self.samples: list[int] = []

    def block(self, n: int) -> None:
        aba, m, d = self.pin.aba, self.model, self.data
        for i in range(n):
            q, v, tau = self.states[i % 64]
            t0 = time.perf_counter_ns()
            aba(m, d, q, v, tau)
            self.samples.append(time.perf_counter_ns() - t0)


def bench_integrators(steps: int, yard: Yardstick) -> dict:
    """Every integrator on Example 1 (the rolling disk with its parallel-parking operator)."""
    from teleop.dynamics.integrators import INTEGRATORS
    from teleop.scenario.build import build_tool
    from teleop.scenario.operators import ScriptedWrench
    from teleop.scenario.schema import load_scene

    scene = load_scene("paper_rolling_disk")
    out = {}
    for name in INTEGRATORS:
        sc = scene.with_overrides(integrator=name)
        tool = build_tool(sc)
        op = ScriptedWrench(sc.operator, sc.fixture)
        samples, block = [], 500
        for start in range(0, steps, block):
            yard.block(block // 5)
            for i in range(start, min(start + block, steps)):
                # the pose read-out counts: for integrators without a projection it is where the
                # step's pose terms get computed (they are cached and reused by the step)
                t0 = time.perf_counter_ns()
                p, R = tool.pose()
                t1 = time.perf_counter_ns()
                w = op.wrench(i * sc.dt_s, p, R)
                t2 = time.perf_counter_ns()
                tool.step(sc.dt_s, w)
                samples.append(time.perf_counter_ns() - t2 + t1 - t0)
        out[name] = _stats(samples)
    return out


UNDAMPED = Path(__file__).resolve().parents[1] / "tests" / "data" / "undamped"


def bench_energy(steps: int) -> dict:
    """The 'energy' integrator against the parametric step on the three undamped scenes (issue
    15's target: at most 2x), interleaved in blocks of 500 steps so that both see the same load.
    Each scene runs its scripted push, then force-free motion."""
    from teleop.scenario.build import build_tool
    from teleop.scenario.operators import ScriptedWrench
    from teleop.scenario.schema import load_scene

    out = {}
    for path in sorted(UNDAMPED.glob("*.toml")):
        scene = load_scene(str(path))
        runs = {}
        for name in ("parametric", "energy"):
            sc = scene.with_overrides(integrator=name)
            runs[name] = (build_tool(sc), ScriptedWrench(sc.operator, sc.fixture), [])
        dt, block = scene.dt_s, 500
        for start in range(0, steps, block):
            for tool, op, samples in runs.values():
                for i in range(start, min(start + block, steps)):
                    w = op.wrench(i * dt, *tool.pose())
                    t0 = time.perf_counter_ns()
                    tool.step(dt, w)
                    samples.append(time.perf_counter_ns() - t0)
        res = {name: _stats(r[2]) for name, r in runs.items()}
        res["ratio_median"] = round(res["energy"]["median"] / res["parametric"]["median"], 2)
        res["ratio_p99"] = round(res["energy"]["p99"] / res["parametric"]["p99"], 2)
        out[path.stem] = res
    return out


def scene_ticks(seconds: float, statuses: dict | None = None) -> dict:
    """tick_us of every scene (ideal master unless the scene names the cobot), and of the incision
    scenes with their heavy effects switched off: what simulating only what a scene calls for buys.
    ``statuses`` (for the printout) gets each run's status."""
    from dataclasses import replace

    from teleop.app.runtime import run_scene
    from teleop.scenario.schema import list_scenes, load_scene

    out = {}
    statuses = {} if statuses is None else statuses

    def tick_us(label, scene):
        HELD.phase = f"tick_us {label}"
        s = run_scene(scene).summary
        statuses[label] = s["status"]
        return s["tick_us"]

    for name in list_scenes():
        scene = load_scene(name).with_overrides(duration_s=seconds)
        out[name] = tick_us(name, scene)
        light = tuple(e for e in scene.effects if e not in ("tissue", "cutting", "can_faults", "tremor"))
        if light != scene.effects:
            label = f"{name} (without {', '.join(sorted(set(scene.effects) - set(light)))})"
            out[label] = tick_us(label, replace(scene, effects=light))
    HELD.phase = ""
    return out


def bench_record(seconds: float, repeats: int = 3) -> dict:
    """The straight cut's tick with the MCAP recorder's side hooks and without, ``repeats`` times
    (each in one run, interleaved blocks: :func:`record_bench.interleaved`; the loop with the
    recorder built first and second in turn, as the order biases one run's figure by 1-2 us);
    prints each run's medians and their difference, then the median of the differences over the
    runs (issue 24's target: at most 5 us) with the machine's load average."""
    import os
    import tempfile

    import record_bench

    runs = []
    for k in range(max(1, repeats)):
        with tempfile.TemporaryDirectory() as tmp:
            r = record_bench.interleaved("straight_incision", seconds, 250, Path(tmp), with_first=k % 2 == 0)
        runs.append(r)
        w, wo = r["with"]["wall_us"], r["without"]["wall_us"]
        order = "first" if r["with_first"] else "second"
        print(f"{'tick wall_us, straight cut':34s} median {wo['median']:8.2f} without the recorder, {w['median']:8.2f} "
              f"with it: {r['added_median_us']['wall_us']:+.2f} us (run {k + 1}, its loop built {order}; "
              f"p99 {wo['p99']:.1f} / {w['p99']:.1f}; load {r['load'][0]:.1f})")
    added = [r["added_median_us"]["wall_us"] for r in runs]
    out = {"runs": runs, "added_median_us": round(float(np.median(added)), 2), "added_us_each": added,
           "load_avg_1min": round(float(np.median([r["load"][0] for r in runs])), 2)}
    print(f"{'recorder, straight cut':34s} adds {out['added_median_us']:+.2f} us to the median tick (median of "
          f"{len(runs)} runs: {', '.join(f'{a:+.2f}' for a in added)}; target <= 5; load {os.getloadavg()[0]:.1f})")
    return out


def fuzz_point(seed: int) -> dict:
    """One random valid scene, drawn from its own seed, run to its end: the seed, status and nan."""
    import logging
    import warnings

    from teleop.app.runtime import run_scene
    from teleop.scenario.random_scene import random_scene
    from teleop.scenario.schema import parse_scene

    logging.getLogger("teleop").setLevel(logging.ERROR)  # a random scene's faults are tallied, not logged
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # overflow on purpose in diverging scenes
        s = run_scene(parse_scene(random_scene(np.random.default_rng(seed)), f"<fuzz {seed}>")).summary
    return {"seed": seed, "status": s["status"], "nan": bool(s["nan"])}


def fuzz_scenes(n: int, workers: int = 2, scheduler: str | None = None) -> dict:
    """Run n random valid scenes (seeds 0..n-1) in parallel through Dask (teleop.app.sweep); count
    statuses. Every one must finish with nan false. The tally does not depend on the workers."""
    import collections

    runs = run_sweep(fuzz_point, range(n), workers, scheduler, desc="fuzzed scenes")
    counts = collections.Counter(r["status"] for r in runs)
    nan_seeds = [r["seed"] for r in runs if r["nan"]]
    return {"scenes": n, "passed": n - len(nan_seeds), "statuses": dict(sorted(counts.items())),
            "nan_seeds": nan_seeds}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", metavar="PATH", help="write the figures here (times in us; default: printed only)")
    ap.add_argument("--steps", type=int, default=20_000, help="steps per integrator (default 20000)")
    ap.add_argument("--fuzz", type=int, default=500, help="random valid scenes to run (default 500)")
    add_sweep_args(ap)  # the fuzzed scenes run through Dask
    ap.add_argument("--engine-only", action="store_true", help="only the integrators and the yardstick")
    ap.add_argument("--scene-seconds", type=float, default=2.0,
                    help="simulated seconds per scene for tick_us, s (default 2)")
    ap.add_argument("--link-frames", type=int, default=3000,
                    help="frames for the link round trip, Zenoh against raw UDP, two processes at 1 kHz (0: skip)")
    ap.add_argument("--record-seconds", type=float, default=4.0,
                    help="simulated seconds of the straight cut with and without the MCAP recorder, interleaved "
                         "(tools/record_bench.py), s (default 4; 0: skip)")
    ap.add_argument("--record-repeats", type=int, default=4,
                    help="runs of the recorder's comparison, its loop built first and second in turn; the median "
                         "of their differences is the figure (default 4)")
    ap.add_argument("--record-only", action="store_true", help="only the recorder's comparison")
    args = ap.parse_args(argv)
    check_sweep_args(ap, args)
    if args.fuzz < 0:
        ap.error(f"--fuzz: expected a count >= 0, got {args.fuzz}")
    with HELD:
        code = _bench(args)
    HELD.report()
    return code


def _bench(args) -> int:
    if args.record_only:
        result = {"record": bench_record(args.record_seconds or 4.0, args.record_repeats)}
        if args.json:
            Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
        return 0

    yard = Yardstick()
    yard.block(2000)  # warm-up
    yard.samples.clear()
    integrators = bench_integrators(args.steps, yard)
    aba = _stats(yard.samples)
    result = {
        "pin_aba_us": aba,
        "integrator_step_us": integrators,
        "reference_step_us": integrators["parametric"],
        "reference_over_aba": round(integrators["parametric"]["median"] / aba["median"], 1),
    }
    print(f"{'pin_aba_us (Panda, yardstick)':34s} median {aba['median']:8.2f}  p99 {aba['p99']:8.2f}")
    for name, s in integrators.items():
        ratio = s["median"] / aba["median"]
        print(f"step_us {name:26s} median {s['median']:8.2f}  p99 {s['p99']:8.2f}   ({ratio:5.1f}x aba)")
    print(f"reference_step_us / pin_aba_us = {result['reference_over_aba']} (target <= 10, issue 11)")
    result["energy_vs_parametric_us"] = bench_energy(args.steps // 2)
    for name, r in result["energy_vs_parametric_us"].items():
        print(f"{name:26s} parametric median {r['parametric']['median']:7.2f} p99 {r['parametric']['p99']:7.2f}  "
              f"energy median {r['energy']['median']:7.2f} p99 {r['energy']['p99']:7.2f}  "
              f"ratio {r['ratio_median']:.2f} / {r['ratio_p99']:.2f} (target median <= 2)")
    if not args.engine_only:
        import master_bench
        import slave_bench

        yard.samples.clear()
        yard.block(3000)
        HELD.phase = "master_bench"
        result["master"] = master_bench.measure(args.steps // 4)
        HELD.phase = "slave_bench"
        result["slave"] = slave_bench.measure(args.steps // 8)
        HELD.phase = ""
        yard.block(3000)
        result["pin_aba_us_late"] = _stats(yard.samples)
        m, sl = result["master"]["master_tick_us"], result["slave"]
        print(f"{'master_tick_us':34s} median {m['median']:8.2f}  p99 {m['p99']:8.2f}   (target median <= 100)")
        if result["master"]["status"] != "ok":  # a fault path is cheaper: the figure would not count
            print(f"WARNING: the master benchmark ended in status {result['master']['status']!r}")
        for key in ("slave_step_us", "pink_step_us"):
            print(f"{key:34s} median {sl[key]['median']:8.2f}  p99 {sl[key]['p99']:8.2f}")
        print(
            f"slave_step_us / pink_step_us = {sl['slave_step_us']['median'] / sl['pink_step_us']['median']:.2f} "
            "(target <= 0.33)"
        )
        statuses: dict = {}
        result["scene_tick_us"] = scene_ticks(args.scene_seconds, statuses)
        for name, t in result["scene_tick_us"].items():
            ended = "" if statuses.get(name, "ok") == "ok" else f"   (ended {statuses[name]}: see below)"
            print(f"tick_us {name:60s} median {t['median']:8.1f}  p99 {t['p99']:8.1f}{ended}")
    if args.record_seconds > 0 and not args.engine_only:
        result["record"] = bench_record(args.record_seconds, args.record_repeats)
    if args.link_frames > 0 and not args.engine_only:
        import link_bench

        result["link_round_trip"] = lk = link_bench.measure(args.link_frames)
        for name, f in lk.items():
            print(f"link round trip {name:6s} p50 {f.get('p50_ms', float('nan')):6.3f} ms  "
                  f"p99 {f.get('p99_ms', float('nan')):6.3f} ms  max {f.get('max_ms', float('nan')):6.3f} ms  "
                  f"lost {f['lost']} of {f['frames']} (loopback, two processes, 1 kHz)")
    if args.fuzz:
        fz = fuzz_scenes(args.fuzz, args.workers, args.scheduler)
        result["fuzz"] = fz
        print(f"fuzzed scenes: {fz['passed']} of {fz['scenes']} finished with nan false; statuses {fz['statuses']}")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
