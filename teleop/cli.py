"""The ``teleop`` command: ``run``, ``list``.

    teleop run [NAME_OR_PATH] [--master ideal|cobot] [--viewer|--headless] [--realtime]
               [--operator script|keyboard] [--duration S] [--seed N] [--integrator NAME] [--dt S]
               [--set KEY=VALUE ...] [--json PATH] [--out DIR]
    teleop list
    teleop schema [--out FILE]
    teleop replay LOG [--viewer]
    teleop plot LOG [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import sys

from teleop import __version__
from teleop.errors import TeleopError

DEFAULT_SCENE = "straight_incision"


def _progress(i: int, n: int) -> None:
    width = 30
    done = int(width * i / max(n, 1))
    sys.stderr.write(f"\r[{'#' * done}{'.' * (width - done)}] {100 * i // max(n, 1):3d}%")
    sys.stderr.flush()


def _summary_text(s: dict) -> str:
    lines = [
        f"scene      {s['scenario']}   master={s['master']}  integrator={s['integrator']}  seed={s['seed']}",
        f"status     {s['status']}   steps={s['steps']}  dt={s['dt_s'] * 1e3:g} ms  simulated={s['duration_s']:g} s  nan={s['nan']}",
        f"tick       median {s['tick_us']['median']:.1f} us   p99 {s['tick_us']['p99']:.1f} us",
    ]
    for k, v in s["metrics"].items():
        lines.append(f"  {k:34s} {v:.4g}")
    for k in ("can_bus_load_pct", "can_frames_lost", "watchdog_trips", "late_ticks"):
        if k in s:
            lines.append(f"  {k:34s} {s[k]}")
    return "\n".join(lines)


def cmd_run(args) -> int:
    from teleop.runtime import run_scene
    from teleop.scenario.schema import load_scene

    sets = list(args.set)
    if args.can_log:  # the cobot's capture_path, as a TOML string (json.dumps quotes and escapes it)
        if (args.master or load_scene(args.scene or DEFAULT_SCENE).master) != "cobot":
            from teleop.errors import ConfigError

            raise ConfigError("--can-log: only the cobot master has a CAN bus (add --master cobot)")
        sets.append(f"cobot.capture_path={json.dumps(str(args.can_log))}")
    scene = load_scene(args.scene or DEFAULT_SCENE).with_overrides(
        sets, duration_s=args.duration, seed=args.seed, master=args.master, integrator=args.integrator,
        dt_s=args.dt,
    )
    show = sys.stderr.isatty() and scene.duration_s / scene.dt_s > 5000 and args.operator != "keyboard"
    view = None
    if args.viewer or args.out:
        from teleop.viz import make_view
        from teleop.viz_bridge import RunView, viz_scene_for

        view = make_view("meshcat", viz_scene_for(scene), record=bool(args.out))
        if args.viewer:
            print(f"viewer: {view.url}", file=sys.stderr)
    try:
        rv = RunView(view) if view is not None else None
        if args.operator == "keyboard":
            from teleop.scenario.build import master_fixture_spec
            from teleop.scenario.keyboard import HELP, KeyboardOperator

            print(HELP, file=sys.stderr)
            with KeyboardOperator(master_fixture_spec(scene)) as keys:
                result = run_scene(scene, realtime=args.realtime, operator=keys, view=rv)
        else:
            result = run_scene(scene, progress=_progress if show else None, realtime=args.realtime, view=rv)
        if args.out:
            from pathlib import Path

            view.save_html(Path(args.out) / "recording.html")
    finally:
        if view is not None:
            view.close()  # the meshcat server never outlives the run, even on Ctrl-C
    if show:
        sys.stderr.write("\r" + " " * 40 + "\r")
    if args.json:
        result.write_json(args.json)
    if args.out:
        from pathlib import Path

        out = Path(args.out)
        result.write_json(out / "metrics.json")
        result.write_log(out / "log.npz")
        from teleop.plots import plot_log

        plot_log(out / "log.npz", out)
    print(_summary_text(result.summary))
    return 0 if result.summary["status"] == "ok" and not result.summary["nan"] else 1


def cmd_replay(args) -> int:
    """Show a recorded run again: live in Meshcat (--viewer), or as recording.html beside the log."""
    from pathlib import Path

    import numpy as np

    from teleop.errors import ConfigError
    from teleop.scenario.schema import load_scene
    from teleop.viz import make_view
    from teleop.viz_bridge import replay_log, viz_scene_for

    log_path = Path(args.log)
    if log_path.is_dir():
        log_path = log_path / "log.npz"
    if not log_path.exists():
        raise ConfigError(f"{args.log}: no run log here (expected a log.npz written by 'teleop run --out')")
    log = dict(np.load(log_path))
    summary = json.loads(str(log.pop("summary")))
    scene = load_scene(summary["scenario"])
    with make_view("meshcat", viz_scene_for(scene), record=not args.viewer) as view:
        if args.viewer:
            print(f"viewer: {view.url}  (replaying {summary['scenario']} in real time)", file=sys.stderr)
        frames = replay_log(log, view, realtime=args.viewer)
        if not args.viewer:
            out = view.save_html(log_path.parent / "recording.html")
            print(out)
    print(f"replayed {frames} frames of {summary['scenario']}")
    return 0


def cmd_list(args) -> int:
    from teleop.scenario.schema import list_scenes, load_scene

    for name in list_scenes():
        scene = load_scene(name)
        print(f"{name:28s} {scene.description}")
    return 0


def cmd_plot(args) -> int:
    from pathlib import Path

    from teleop.errors import ConfigError
    from teleop.plots import plot_log

    log = Path(args.log)
    if log.is_dir():
        log = log / "log.npz"
    if not log.exists():
        raise ConfigError(f"{args.log}: no run log here (expected a log.npz written by 'teleop run --out')")
    for p in plot_log(log, args.out or log.parent):
        print(p)
    return 0


def cmd_schema(args) -> int:
    """Print (or write to --out) the JSON Schema of scene files."""
    from teleop.scenario.schema import scene_schema

    text = json.dumps(scene_schema(), indent=2) + "\n"
    if args.out:
        with open(args.out, "w", encoding="utf-8") as f:
            f.write(text)
        print(args.out)
    else:
        sys.stdout.write(text)
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="teleop", description="Constrained teleoperation of surgical-style robots")
    ap.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a scene (default: the scripted surgical cut)")
    run.add_argument("scene", nargs="?", help="scene name (see 'teleop list') or path to a .toml file")
    run.add_argument("--master", choices=["ideal", "cobot"], help="ideal: wrench straight to the tool; cobot: the CAN device")
    view = run.add_mutually_exclusive_group()
    view.add_argument("--headless", action="store_true", default=True, help="no viewer (default)")
    view.add_argument("--viewer", action="store_true", help="show both sides live in Meshcat (prints the URL)")
    run.add_argument("--realtime", action="store_true", help="pace ticks to the wall clock (default: simulated time)")
    run.add_argument("--operator", choices=["script", "keyboard"], default="script",
                     help="the scene's scripted operator (default) or you at the keyboard")
    run.add_argument("--duration", type=float, help="simulated seconds (overrides the scene)")
    run.add_argument("--seed", type=int, help="random seed (overrides the scene)")
    run.add_argument("--integrator", help="integrator name (overrides the scene)")
    run.add_argument("--dt", type=float, help="control period in s (overrides the scene)")
    run.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                     help="set any scene key, VALUE as TOML (e.g. --set slave.solver=daqp --set tool.mass_kg=0.3)")
    run.add_argument("--can-log", metavar="PATH",
                     help="cobot master: write the CAN traffic here (.log candump, .asc, .blf, .csv by suffix)")
    run.add_argument("--json", help="write the run summary as JSON here")
    run.add_argument("--out", help="write metrics.json, log.npz and PNG plots into this folder")
    run.set_defaults(func=cmd_run)
    ls = sub.add_parser("list", help="list the scenes")
    ls.set_defaults(func=cmd_list)
    rp = sub.add_parser("replay", help="show a recorded run again (Meshcat, or recording.html)")
    rp.add_argument("log", help="a log.npz or the --out folder of a run")
    rp.add_argument("--viewer", action="store_true", help="replay live in Meshcat instead of writing HTML")
    rp.set_defaults(func=cmd_replay)
    pl = sub.add_parser("plot", help="paper-style PNG figures of a run log")
    pl.add_argument("log", help="a log.npz or the --out folder of a run")
    pl.add_argument("--out", help="folder for the PNGs (default: next to the log)")
    pl.set_defaults(func=cmd_plot)
    sc = sub.add_parser("schema", help="the JSON Schema of the scene format (for editors)")
    sc.add_argument("--out", help="write it to this file instead of printing it")
    sc.set_defaults(func=cmd_schema)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except TeleopError as e:
        print(f"teleop: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
