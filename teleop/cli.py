"""The ``teleop`` command: ``run``, ``list``.

    teleop run [NAME_OR_PATH] [--master ideal|cobot] [--viewer|--headless] [--realtime]
               [--operator script|keyboard] [--duration S] [--seed N] [--integrator NAME] [--dt S]
               [--set KEY=VALUE ...] [--json PATH] [--out DIR]
    teleop list
    teleop schema [--out FILE]
    teleop replay RUN_DIR [--viewer [--hold]] [--out FILE [--force]] [--view perspective|side]
    teleop plot LOG [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import sys

from teleop import __version__
from teleop.errors import TeleopError
from teleop.netcli import add_run_flags, add_subcommands, cmd_run_zenoh

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
        lines.append(f"  {k:34s} {v:.4g}" if v is not None else f"  {k:34s} null")
    for k in ("can_bus_load_pct", "can_frames_lost", "watchdog_trips", "late_ticks"):
        if k in s:
            lines.append(f"  {k:34s} {s[k]}")
    return "\n".join(lines)


def cmd_run(args) -> int:
    if args.link == "zenoh":
        return cmd_run_zenoh(args)
    from teleop.runtime import run_scene
    from teleop.scenario.schema import load_scene

    scene = load_scene(args.scene or DEFAULT_SCENE).with_overrides(
        args.set, duration_s=args.duration, seed=args.seed, master=args.master, integrator=args.integrator,
        dt_s=args.dt,
    )
    show = sys.stderr.isatty() and scene.duration_s / scene.dt_s > 5000 and args.operator != "keyboard"
    view = None
    if args.viewer or args.out:
        from teleop.viz import make_view
        from teleop.viz_bridge import RunView, save_scene_copy, viz_scene_for

        view = make_view("meshcat", viz_scene_for(scene, view=args.view), record=bool(args.out))
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
            save_scene_copy(scene, args.out)  # what `teleop replay` needs: the scene and the frames
            rv.save_frames(args.out)
        if args.viewer and args.hold:
            view.hold(lambda url: print(f"viewer: {url} holds the last frame; Ctrl-C ends it", file=sys.stderr))
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
    """Show a recorded run again: live in Meshcat (--viewer), or as replay.html in the run folder
    (the run's own recording.html is never touched)."""
    from teleop.viz.replay import replay_command

    return replay_command(args.log, viewer=args.viewer, out=args.out, force=args.force, view=args.view,
                          hold=args.hold)


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
    run.add_argument("--view", choices=["perspective", "side"], default="perspective",
                     help="viewer camera: perspective from above, or side (level, orthographic)")
    run.add_argument("--hold", action="store_true", help="with --viewer: keep the page served after the run until Ctrl-C")
    run.add_argument("--json", help="write the run summary as JSON here")
    run.add_argument("--out", help="write metrics.json, log.npz and PNG plots into this folder")
    add_run_flags(run)
    run.set_defaults(func=cmd_run)
    add_subcommands(sub)
    ls = sub.add_parser("list", help="list the scenes")
    ls.set_defaults(func=cmd_list)
    rp = sub.add_parser("replay", help="show a run folder again (live in Meshcat, or into replay.html)")
    rp.add_argument("log", help="a log.npz or the --out folder of a run")
    rp.add_argument("--viewer", action="store_true", help="replay live in Meshcat instead of writing HTML")
    rp.add_argument("--out", help="HTML file to write (default: replay.html in the run folder)")
    rp.add_argument("--force", action="store_true", help="allow --out to overwrite an existing file")
    rp.add_argument("--view", choices=["perspective", "side"], default="perspective", help="viewer camera")
    rp.add_argument("--hold", action="store_true", help="with --viewer: keep the page served until Ctrl-C")
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
