"""What the MCAP recorder (teleop.app.record) costs the tick, measured in one run with and without it.

    python tools/record_bench.py [--scene straight_incision] [--seconds 5] [--block 250] [--repeats 2]
                                 [--mode process|thread] [--spool] [--realtime SECONDS] [--paced]
                                 [--json OUT.json]

Two loops of the same scene and seed are built side by side, one with the recorder's side hooks
(``build_master(record=)``, ``build_slave(record=)`` on a ``RecordWriter``: what ``teleop run
--out`` records with), one without, and ticked in interleaved blocks of
``--block`` ticks on the simulated clock (as fast as they go), so both see the same machine,
the same caches and the same physics. Per tick, for each:

* ``tick_us``: the loop's own figure (``BilateralLoop.tick_ns``: both sides' CPU time, hooks
  excluded), what the runs report as ``tick_us``;
* ``wall_us``: the wall time of the whole ``loop.tick(i)``, hooks included: the recorder's copy
  into its ring is in here, and anything its writer process takes from the tick's core.

Printed: median and p99 of each, with and without, and the difference of the medians (the
recorder's cost to the median tick), for each of ``--repeats`` runs, the loop with the recorder
built first and second in turn (of two loops built alike, the first built ticks 1-2 us slower on
this machine: one order alone biases the figure), and the median of the runs' differences. Also
the writer process's CPU time per simulated second, and the record's size. ``--realtime S``: then
S seconds paced to the wall clock with and without (``run_scene(realtime=True)``, alternating,
``--repeats`` times each, at least twice) and their late ticks.

``--paced``: the same, each tick waiting for its period of the wall clock as a paced run does.
``--floor``: where the cost comes from, the same comparison with the recorder's hooks cut down
(:data:`FLOOR`, each against the loop without hooks, both build orders, the steps alternating):
``call`` the hooks made and called, doing nothing, ``full`` the recorder (the rows the sides'
captures hold, handed to the writer every 10 ms of the run). ``--probe``: the recorder's own
hooks timed inside the tick (median ns, ``perf_counter_ns`` around each hook: the timers' own
cost included).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def _stats(us) -> dict:
    a = np.asarray(us, dtype=float)
    return {"median": round(float(np.median(a)), 2), "p99": round(float(np.percentile(a, 99)), 2)}


def _cpu_s(pid: int) -> float:
    """A process's user + system CPU time (s), from /proc."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


def _loop(scene, record=None, hooks=None):
    """The scene's loop as runs build it (:mod:`teleop.app.assembly`), with the record's side
    hooks (``build_master(record=)``, ``build_slave(record=)``: what ``teleop run --out`` uses)
    when ``record`` is a writer; ``hooks``: (master class, slave class) to add in their place, last
    on each side as ``build_*`` adds them (``--floor``)."""
    from teleop.app.assembly import build_master, build_slave, make_link
    from teleop.app.session import tick_count
    from teleop.tick.loop import BilateralLoop

    n = tick_count(scene.duration_s, scene.dt_s)
    rng = np.random.default_rng(scene.seed)
    rec = record if hooks is None else None
    mb, sb = build_master(scene, n, rng, record=rec), build_slave(scene, n, record=rec)
    if hooks is not None and record is not None:
        mb.side.add_hooks(hooks[0](record, side=mb.side))
        if sb is not None:
            sb.side.add_hooks(hooks[1](record, side=sb.side))
    link = make_link(scene, rng) if sb is not None else None
    return BilateralLoop(mb.side, sb.side if sb is not None else None, link), n


def _floor_hooks(step: str) -> tuple:
    """The recorder's hooks cut down to ``step`` (see the module docstring); "full": the recorder's."""
    from teleop.app.record import MasterRecorderMcap, SlaveRecorderMcap

    if step == "full":
        return MasterRecorderMcap, SlaveRecorderMcap

    class Master(MasterRecorderMcap):  # made, its ring laid out, but called for nothing
        def before_tick(self, i, t_s, side):
            pass

        def after_tick(self, i, t_s, side):
            pass

    class Slave(SlaveRecorderMcap):
        def after_tick(self, i, t_s, side):
            pass

    return Master, Slave


def _probe_hooks() -> tuple:
    """The recorder's hooks, each call timed (:data:`PROBE_NS`, ns per tick, the master's and the
    slave's after_tick and the master's before_tick summed)."""
    from teleop.app.record import MasterRecorderMcap, SlaveRecorderMcap

    pc = time.perf_counter_ns
    before, after, slave_after = (MasterRecorderMcap.before_tick, MasterRecorderMcap.after_tick,
                                  SlaveRecorderMcap.after_tick)

    class Master(MasterRecorderMcap):
        def before_tick(self, i, t_s, side):
            t0 = pc()
            before(self, i, t_s, side)
            PROBE_NS[i] += pc() - t0

        def after_tick(self, i, t_s, side):
            t0 = pc()
            after(self, i, t_s, side)
            PROBE_NS[i] += pc() - t0

    class Slave(SlaveRecorderMcap):
        def after_tick(self, i, t_s, side):
            t0 = pc()
            slave_after(self, i, t_s, side)
            PROBE_NS[i] += pc() - t0

    return Master, Slave


#: the steps of ``--floor``
FLOOR = ("call", "full")
#: ``--probe``: the hooks' time per tick (ns)
PROBE_NS = np.zeros(0)


def interleaved(scene_name: str, seconds: float, block: int, folder: Path, with_first: bool = True,
                hooks: tuple | None = None, paced: bool = False, **opts) -> dict:
    """The scene's loop with the record's side hooks and without, ticked in interleaved blocks
    of ``block`` ticks; the figures of each (see the module docstring). ``with_first``: the loop
    with the recorder is built first (else second): of two loops built alike, the one built
    first ticks some 1-2 us slower here, so a figure from one order alone is biased; run both.
    ``hooks``: (master class, slave class) in place of the recorder's (``--floor``, ``--probe``).
    ``paced``: each tick then waits for the next period of the wall clock as a paced run does
    (:func:`teleop.app.session._pace`), the writer made for a paced run (``realtime=True``): the
    tick starts with cold caches after each wait, and what the recorder's copy takes from them
    shows there."""
    from teleop.app.record import RecordWriter
    from teleop.app.session import _pace
    from teleop.scenario.schema import load_scene

    scene = load_scene(scene_name, sets=[f"duration_s={seconds}"])
    load0 = os.getloadavg()
    if paced:
        opts = {**opts, "realtime": True, "spool": opts.get("spool") or None}
    writer = RecordWriter(folder / "record.mcap", metadata={"scene": scene.name, "bench": "record_bench"}, **opts)
    # the rings laid out before the clock starts
    if with_first:
        loops = {"with": _loop(scene, writer, hooks), "without": _loop(scene)}
    else:
        loops = {"without": _loop(scene), "with": _loop(scene, writer, hooks)}
    n = loops["with"][1]
    tick = {k: np.zeros(n) for k in loops}
    wall = {k: np.zeros(n) for k in loops}
    pid = writer.pid
    cpu0 = _cpu_s(pid) if pid != os.getpid() else float("nan")
    late, deadline = 0, time.perf_counter()
    with loops["with"][0].master, loops["without"][0].master:
        for a in range(0, n, block):
            order = ("with", "without") if (a // block) % 2 == 0 else ("without", "with")
            for k in order:
                loop = loops[k][0]
                for i in range(a, min(n, a + block)):
                    t0 = time.perf_counter_ns()
                    loop.tick(i)
                    wall[k][i] = (time.perf_counter_ns() - t0) * 1e-3
                    tick[k][i] = loop.tick_ns * 1e-3
                    if paced:
                        deadline = max(deadline + scene.dt_s, time.perf_counter())
                        late += _pace(deadline)
    time.sleep(0.1)  # the writer's last poll
    cpu = _cpu_s(pid) - cpu0
    writer.close()
    skip = min(n - 1, 10)  # the first ticks load the kernels
    out = {"scene": scene.name, "ticks": n, "block": block, "writer": opts, "with_first": with_first,
           "paced": paced, "late_ticks": late,
           "load": [round((a + b) / 2, 2) for a, b in zip(load0, os.getloadavg())]}
    for k in loops:
        out[k] = {"tick_us": _stats(tick[k][skip:]), "wall_us": _stats(wall[k][skip:])}
    out["added_median_us"] = {m: round(out["with"][m]["median"] - out["without"][m]["median"], 2)
                              for m in ("tick_us", "wall_us")}
    out["added_p99_us"] = {m: round(out["with"][m]["p99"] - out["without"][m]["p99"], 2)
                           for m in ("tick_us", "wall_us")}
    out["writer_cpu_s_per_sim_s"] = round(cpu / (n * scene.dt_s), 4)
    out["record_bytes"] = (folder / "record.mcap").stat().st_size
    out["record"] = {k: v for k, v in writer.stats().items() if k != "path"}
    return out


def realtime(scene_name: str, seconds: float, folder: Path, repeats: int = 2, **opts) -> dict:
    """``repeats`` runs of ``seconds`` paced to the wall clock with the recorder and as many
    without, alternating, each pair in turn with the recorder first and second."""
    from teleop.app.record import RecordWriter
    from teleop.app.runtime import run_scene
    from teleop.scenario.schema import load_scene

    scene = load_scene(scene_name, sets=[f"duration_s={seconds}"])
    out: dict = {"seconds": seconds, "with": [], "without": []}
    for rep in range(max(1, repeats)):
        for k in (("with", "without") if rep % 2 == 0 else ("without", "with")):
            if k == "with":
                with RecordWriter(folder / f"rt{rep}.mcap", realtime=True, **opts) as w:
                    s = run_scene(scene, realtime=True, record=w).summary
            else:
                s = run_scene(scene, realtime=True).summary
            out[k].append({"late_ticks": s["late_ticks"], "tick_us": s["tick_us"],
                           "realtime_factor": s["realtime_factor"]})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="straight_incision")
    ap.add_argument("--seconds", type=float, default=5.0, help="simulated seconds (default 5)")
    ap.add_argument("--block", type=int, default=250, help="ticks per interleaved block (default 250)")
    ap.add_argument("--realtime", type=float, default=0.0, metavar="S",
                    help="also S seconds paced to the wall clock, with and without, --repeats times each (at least 2)")
    ap.add_argument("--mode", choices=["process", "thread"], default="process", help="the writer's (default process)")
    ap.add_argument("--spool", action="store_true", help="the writer spools, and writes the MCAP file after the run")
    ap.add_argument("--repeats", type=int, default=2,
                    help="interleaved runs, the loop with the recorder built first and second in turn (default 2)")
    ap.add_argument("--floor", action="store_true",
                    help="the recorder's hooks cut down step by step (call, read, join, full; see above)")
    ap.add_argument("--probe", action="store_true", help="the recorder's hooks timed inside the tick")
    ap.add_argument("--paced", action="store_true",
                    help="each tick waits for its period of the wall clock, as a paced run (--realtime) does "
                         "(the writer a paced run's)")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args(argv)
    if args.floor or args.probe:
        return _diagnose(args)
    with tempfile.TemporaryDirectory() as tmp:
        kw = {"mode": args.mode, "spool": args.spool}
        runs = [interleaved(args.scene, args.seconds, args.block, Path(tmp) / str(k), with_first=k % 2 == 0,
                            paced=args.paced, **kw) for k in range(max(1, args.repeats))]
        res: dict = {"interleaved": runs}
        if args.realtime > 0:
            res["realtime"] = realtime(args.scene, args.realtime, Path(tmp), max(2, args.repeats), **kw)
    for r in runs:
        print(f"{r['scene']}: {r['ticks']} ticks, interleaved blocks of {r['block']}, writer {r['writer']}, the loop "
              f"with it built {'first' if r['with_first'] else 'second'}, load average {r['load'][0]:.1f}"
              + (f", paced ({r['late_ticks']} late ticks)" if r["paced"] else ""))
        print(f"{'':10s} {'tick_us median':>15s} {'p99':>8s} {'wall_us median':>15s} {'p99':>8s}")
        for k in ("without", "with"):
            print(f"{k:10s} {r[k]['tick_us']['median']:15.2f} {r[k]['tick_us']['p99']:8.2f} "
                  f"{r[k]['wall_us']['median']:15.2f} {r[k]['wall_us']['p99']:8.2f}")
        print(f"{'added':10s} {r['added_median_us']['tick_us']:15.2f} {r['added_p99_us']['tick_us']:8.2f} "
              f"{r['added_median_us']['wall_us']:15.2f} {r['added_p99_us']['wall_us']:8.2f}")
        print(f"writer process: {100 * r['writer_cpu_s_per_sim_s']:.1f} % of a core per simulated second; "
              f"record {r['record_bytes'] / 1e6:.2f} MB, {r['record'].get('messages')} messages, "
              f"{r['record'].get('ticks_dropped')} ticks dropped")
    if len(runs) > 1:
        added = [r["added_median_us"]["wall_us"] for r in runs]
        res["added_median_us"] = round(float(np.median(added)), 2)
        print(f"added to the median tick's wall time, median of {len(runs)} runs: {res['added_median_us']:+.2f} us")
    if "realtime" in res:
        rt = res["realtime"]
        for k in ("without", "with"):
            print(f"realtime {rt['seconds']:g} s {k:8s}: late ticks {[x['late_ticks'] for x in rt[k]]}, "
                  f"tick p99 {[x['tick_us']['p99'] for x in rt[k]]} us")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2))
    return 0


def _diagnose(args) -> int:
    """``--floor`` and ``--probe`` (see the module docstring)."""
    global PROBE_NS
    kw = {"mode": args.mode, "spool": args.spool}
    out: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        if args.floor:
            steps = {st: _floor_hooks(st) for st in FLOOR}
            runs: dict = {st: [] for st in FLOOR}
            for rd in range(max(1, args.repeats)):
                for k in (0, 1):  # the loop with the hooks built first, then second
                    for st in (FLOOR if (rd + k) % 2 == 0 else FLOOR[::-1]):
                        r = interleaved(args.scene, args.seconds, args.block, Path(tmp) / f"{st}{rd}{k}",
                                        with_first=k == 0, hooks=steps[st], **kw)
                        runs[st].append({"wall_us": r["added_median_us"]["wall_us"],
                                         "tick_us": r["added_median_us"]["tick_us"], "load": r["load"][0]})
            out["floor"] = runs
            print(f"{args.scene}: added to the median tick (us), each step against the loop without hooks, "
                  f"{2 * max(1, args.repeats)} runs each, both build orders")
            for st in FLOOR:
                w = [x["wall_us"] for x in runs[st]]
                t = [x["tick_us"] for x in runs[st]]
                print(f"{st:5s} wall {float(np.median(w)):+6.2f} (runs {', '.join(f'{x:.1f}' for x in w)}); tick's own "
                      f"{float(np.median(t)):+6.2f}; load {min(x['load'] for x in runs[st]):.1f}-"
                      f"{max(x['load'] for x in runs[st]):.1f}")
        if args.probe:
            out["probe"] = []
            for k in range(max(1, args.repeats)):
                PROBE_NS = np.zeros(100_000)
                r = interleaved(args.scene, args.seconds, args.block, Path(tmp) / f"probe{k}", with_first=k % 2 == 0,
                                hooks=_probe_hooks(), **kw)
                ns = PROBE_NS[10:r["ticks"]]
                out["probe"].append({"hooks_ns_median": float(np.median(ns)), "load": r["load"][0],
                                     "wall_us": r["added_median_us"]["wall_us"]})
                print(f"probe: the recorder's hooks {np.median(ns):.0f} ns a tick (median; p10 "
                      f"{np.percentile(ns, 10):.0f}), added to the median tick with the timers "
                      f"{r['added_median_us']['wall_us']:+.2f} us, load {r['load'][0]:.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
