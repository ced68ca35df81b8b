"""What the MCAP recorder (teleop.app.record) costs the tick, measured in one run with and without it.

    python tools/record_bench.py [--scene straight_incision] [--seconds 5] [--block 250] [--repeats 2]
                                 [--mode process|thread] [--spool] [--realtime SECONDS] [--json OUT.json]

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
twice each) and their late ticks.
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


def _loop(scene, record=None):
    """The scene's loop as runs build it (:mod:`teleop.app.assembly`), with the record's side
    hooks (``build_master(record=)``, ``build_slave(record=)``: what ``teleop run --out`` uses)
    when ``record`` is a writer."""
    from teleop.app.assembly import build_master, build_slave, make_link
    from teleop.app.session import tick_count
    from teleop.tick.loop import BilateralLoop

    n = tick_count(scene.duration_s, scene.dt_s)
    rng = np.random.default_rng(scene.seed)
    mb, sb = build_master(scene, n, rng, record=record), build_slave(scene, n, record=record)
    link = make_link(scene, rng) if sb is not None else None
    return BilateralLoop(mb.side, sb.side if sb is not None else None, link), n


def interleaved(scene_name: str, seconds: float, block: int, folder: Path, with_first: bool = True,
                **opts) -> dict:
    """The scene's loop with the record's side hooks and without, ticked in interleaved blocks
    of ``block`` ticks; the figures of each (see the module docstring). ``with_first``: the loop
    with the recorder is built first (else second): of two loops built alike, the one built
    first ticks some 1-2 us slower here, so a figure from one order alone is biased; run both."""
    from teleop.app.record import RecordWriter
    from teleop.scenario.schema import load_scene

    scene = load_scene(scene_name, sets=[f"duration_s={seconds}"])
    load0 = os.getloadavg()
    writer = RecordWriter(folder / "record.mcap", metadata={"scene": scene.name, "bench": "record_bench"}, **opts)
    # the rings laid out before the clock starts
    if with_first:
        loops = {"with": _loop(scene, writer), "without": _loop(scene)}
    else:
        loops = {"without": _loop(scene), "with": _loop(scene, writer)}
    n = loops["with"][1]
    tick = {k: np.zeros(n) for k in loops}
    wall = {k: np.zeros(n) for k in loops}
    pid = writer.pid
    cpu0 = _cpu_s(pid) if pid != os.getpid() else float("nan")
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
    time.sleep(0.1)  # the writer's last poll
    cpu = _cpu_s(pid) - cpu0
    writer.close()
    skip = min(n - 1, 10)  # the first ticks load the kernels
    out = {"scene": scene.name, "ticks": n, "block": block, "writer": opts, "with_first": with_first,
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


def realtime(scene_name: str, seconds: float, folder: Path, **opts) -> dict:
    from teleop.app.record import RecordWriter
    from teleop.app.runtime import run_scene
    from teleop.scenario.schema import load_scene

    scene = load_scene(scene_name, sets=[f"duration_s={seconds}"])
    out: dict = {"seconds": seconds, "with": [], "without": []}
    for rep in range(2):
        for k in ("with", "without"):
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
                    help="also S seconds paced to the wall clock, with and without, twice each")
    ap.add_argument("--mode", choices=["process", "thread"], default="process", help="the writer's (default process)")
    ap.add_argument("--spool", action="store_true", help="the writer spools, and writes the MCAP file after the run")
    ap.add_argument("--repeats", type=int, default=2,
                    help="interleaved runs, the loop with the recorder built first and second in turn (default 2)")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        kw = {"mode": args.mode, "spool": args.spool}
        runs = [interleaved(args.scene, args.seconds, args.block, Path(tmp) / str(k), with_first=k % 2 == 0, **kw)
                for k in range(max(1, args.repeats))]
        res: dict = {"interleaved": runs}
        if args.realtime > 0:
            res["realtime"] = realtime(args.scene, args.realtime, Path(tmp), **kw)
    for r in runs:
        print(f"{r['scene']}: {r['ticks']} ticks, interleaved blocks of {r['block']}, writer {r['writer']}, the loop "
              f"with it built {'first' if r['with_first'] else 'second'}, load average {r['load'][0]:.1f}")
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


if __name__ == "__main__":
    sys.exit(main())
