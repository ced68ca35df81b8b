"""The cut over Zenoh, run after run, against the same cut in one process (issue 22: the sides keep
their real-time figures once every frame is authenticated).

Runs ``teleop run SCENE --link zenoh`` ``--runs`` times in a row (two processes on loopback, each
side pinned, a one-run pairing key, HMAC on every frame) and the same scene once in one process,
each through the command line a user types, and prints per run: status, tip tracking (RMS, max),
cut length, each side's tick median and p99 (us), late ticks and each side's ticks on time (%),
real-time factor, the load average and the round trip
p50/p99 (ms); then the Zenoh runs' worst tracking over one process's. Writes runs.json and
table.md into a new ``runs/zenoh_runs-DATE-TIME/`` unless ``--out`` names a folder.

    python tools/zenoh_runs.py [--runs 10] [--scene straight_incision] [--duration 7] [--dt 0.0005]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from teleop.app.outputs import out_help, study_folder


def teleop_run(scene: str, duration: float, out: Path, zenoh: bool, dt: float | None = None) -> dict:
    """One run through the command line (``dt``: ``--dt``, the control period in s); its summary
    (the --json file)."""
    cmd = [sys.executable, "-m", "teleop", "run", scene, "--duration", str(duration), "--json", str(out)]
    if dt is not None:
        cmd += ["--dt", str(dt)]
    if zenoh:
        cmd += ["--link", "zenoh"]
    subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=600, check=False)
    return json.loads(out.read_text()) if out.is_file() else {"status": "no summary"}


def row(label: str, s: dict) -> dict:
    """The figures of one run's summary that this tool prints."""
    m = s.get("metrics", {})
    link = next(iter(s.get("link", {}).values()), {}) if s.get("link") else {}
    rt = link.get("latency", {}).get("round_trip_ms", {}) if isinstance(link, dict) else {}
    st = s.get("slave_tick_us") or {}
    return {"run": label, "status": s.get("status"), "tip_rms_um": 1e6 * m.get("tip_tracking_rms_m", float("nan")),
            "tip_max_um": 1e6 * m.get("tip_tracking_max_m", float("nan")),
            "cut_mm": 1e3 * m.get("cut_length_m", float("nan")),
            "master_us": s.get("tick_us", {}).get("median"), "master_p99_us": s.get("tick_us", {}).get("p99"),
            "slave_us": st.get("median"), "slave_p99_us": st.get("p99"),
            "late": (s.get("late_ticks") or 0) + (s.get("slave_late_ticks") or 0),
            "master_on_time_pct": _on_time(s.get("late_ticks"), s.get("steps")),
            "slave_on_time_pct": _on_time(s.get("slave_late_ticks"), s.get("steps")),
            "load": (s.get("clock") or {}).get("master", {}).get("load_1min"),
            "rtf": s.get("realtime_factor"), "rt_p50_ms": rt.get("p50"), "rt_p99_ms": rt.get("p99")}


def _on_time(late, steps) -> float | None:
    """Ticks on time (%) of ``steps`` with ``late`` late; None without both."""
    return None if late is None or not steps else round(100.0 * (1.0 - late / steps), 3)


def table(rows: list[dict]) -> str:
    keys = list(rows[0])
    out = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        out.append("| " + " | ".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in r.values()) + " |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10, help="Zenoh runs in a row (default 10)")
    ap.add_argument("--scene", default="straight_incision", help="the scene (default straight_incision)")
    ap.add_argument("--duration", type=float, default=7.0, help="simulated seconds per run (default 7)")
    ap.add_argument("--dt", type=float, help="the control period, s (default: the scene's; 0.0005 is 2 kHz)")
    ap.add_argument("--out", metavar="DIR", help=out_help("zenoh_runs", "runs.json and table.md"))
    a = ap.parse_args(argv)
    if a.runs < 1 or a.duration <= 0 or (a.dt is not None and not a.dt > 0):
        ap.error("--runs: at least 1; --duration and --dt: above 0")
    out = study_folder("zenoh_runs", a.out)
    one = row("one process", teleop_run(a.scene, a.duration, out / "one.json", zenoh=False, dt=a.dt))
    print(table([one]), flush=True)
    rows = [one]
    for k in range(a.runs):
        rows.append(row(f"zenoh {k + 1}", teleop_run(a.scene, a.duration, out / f"zenoh{k + 1}.json", zenoh=True,
                                                      dt=a.dt)))
        print(table(rows[-1:]).splitlines()[-1], flush=True)
    zen = rows[1:]
    ok = sum(r["status"] == "ok" for r in zen)
    worst = max(r["tip_rms_um"] for r in zen) / one["tip_rms_um"] if one["tip_rms_um"] else float("nan")
    verdict = (f"{ok}/{len(zen)} Zenoh runs ok; worst tip tracking RMS {worst:.2f}x one process's "
               f"({one['tip_rms_um']:.2f} um)")
    (out / "runs.json").write_text(json.dumps({"scene": a.scene, "duration_s": a.duration, "dt_s": a.dt, "rows": rows,
                                               "verdict": verdict}, indent=1))
    (out / "table.md").write_text(table(rows) + "\n\n" + verdict + "\n")
    print(verdict)
    print(f"wrote {out}/runs.json, table.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
