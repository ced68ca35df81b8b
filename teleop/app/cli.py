"""The ``teleop`` command: ``run``, ``list``, ``replay``, ``plot``, ``schema``.

    teleop run [NAME_OR_PATH] [--master ideal|cobot] [--viewer|--headless] [--host ADDR] [--realtime]
               [--operator script|keyboard] [--duration S] [--seed N] [--integrator NAME] [--dt S]
               [--set KEY=VALUE ...] [--allow-hardware] [--json PATH|-] [--out DIR] [-v|-q]
               [--view perspective|side] [--hold] [--link sim|zenoh] [--can-log PATH]
    teleop list
    teleop schema [--out FILE]
    teleop replay RUN_DIR [--viewer [--hold]] [--host ADDR] [--out FILE [--force]] [--view perspective|side]
    teleop replay RUN_DIR --check
    teleop slave NAME_OR_PATH --listen ENDPOINT / teleop master NAME_OR_PATH --connect ENDPOINT
    teleop plot LOG [--out DIR]

Bad input (a scene, an argument, a file) is one line on stderr naming the file, key or argument
and the reason, exit code 2, nothing run and nothing written. ``--out`` is written whole or not at
all (teleop.app.outputs); a Ctrl-C'd run leaves its summary with status "interrupted" (exit 130).
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
from contextlib import contextmanager
from pathlib import Path

from teleop import __version__
from teleop.app.args import add_scene_flags, scene_for, with_capture
from teleop.app.netcli import (
    add_keys_command,
    add_run_flags,
    add_subcommands,
    cmd_run_zenoh,
    record_from_log,
    refuse_over_zenoh,
)
from teleop.util.errors import ConfigError, TeleopError
from teleop.util.inputs import plain

#: exit codes: the run's status "ok"; any other status; bad input (nothing run, nothing written);
#: Ctrl-C (the summary, if a run had started, says "interrupted")
EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
#: stdout's reader went away before the output ended (a pipe into ``head``): 128 + SIGPIPE, no message
EXIT_READER_GONE = 141

log = logging.getLogger("teleop")


def _summary_text(s: dict) -> str:
    lines = [
        f"scene      {plain(s['scenario'])}   master={s['master']}  integrator={s['integrator']}  seed={s['seed']}",
        f"status     {s['status']}   steps={s['steps']}  dt={s['dt_s'] * 1e3:g} ms  "
        f"simulated={s['duration_s']:g} s  nan={s['nan']}",
        f"           {s.get('status_reason', '')}",
        f"tick       median {s['tick_us']['median']:.1f} us   p99 {s['tick_us']['p99']:.1f} us   "
        f"{s.get('realtime_factor', 0):.2f}x real time"
        + (f" (not counting {s['compile_s']:.1f} s compiling the kernels, once)" if s.get("compile_s") else ""),
    ]
    for k, v in s["metrics"].items():
        lines.append(f"  {k:34s} {v:.4g}" if v is not None else f"  {k:34s} null")
    op = s.get("operator") or {}
    if "speed_limit_m_s" in op:  # an operator held to limits (the keyboard)
        margin = op["workspace_margin_min_m"]
        lines.append(f"limits     closest to the workspace's edge {1e3 * margin:.1f} mm   top speed "
                     f"{1e3 * op['speed_max_m_s']:.0f} of {1e3 * op['speed_limit_m_s']:.0f} mm/s   braked on "
                     f"{op['braked_ticks']} ticks" if margin is not None else "limits     no tick")
    for k in ("can_bus_load_pct", "can_frames_lost", "watchdog_trips", "late_ticks"):
        if k in s:
            v = s[k]
            lines.append(f"  {k:34s} {v:.4g}" if isinstance(v, float) else f"  {k:34s} {v}")
    return "\n".join(lines)


def _write_run(result, view, rv, scene, folder) -> list[str]:
    """The run's files into the temporary folder, the summary last; returns their names. Beside the
    recording: the scene the run ran and the frames its view drew (what `teleop replay` needs)."""
    from teleop.app.plots import plot_log
    from teleop.app.view_bridge import save_scene_copy

    save_scene_copy(scene, folder.tmp)
    if view is not None:
        view.save_html(folder.path("recording.html"))
        rv.save_frames(folder.tmp)
    result.write_log(folder.path("log.npz"))
    plot_log(folder.path("log.npz"), folder.tmp)
    result.write_json(folder.path("metrics.json"))
    return sorted(p.name for p in folder.tmp.iterdir())


def cmd_run(args) -> int:
    from teleop.app.outputs import RunFolder, check_json_target, write_json
    from teleop.app.progress import RunBar, compile_clock, notice_compile
    from teleop.app.runtime import run_scene

    scene, capture = scene_for(args)
    _debug_scene(scene, args)
    if args.link == "zenoh":
        refuse_over_zenoh(args)
    if args.operator == "keyboard":
        from teleop.app.keyboard import require_terminal
        from teleop.app.session import MAX_TICKS

        require_terminal()
        if args.duration is None:  # open-ended: until x, Ctrl-C or MAX_TICKS
            scene = scene.with_overrides(duration_s=MAX_TICKS * scene.dt_s)
    json_path = check_json_target(args.json) if args.json else None
    folder = RunFolder(args.out) if args.out else None
    view = bar = None
    try:
        if capture is not None:
            scene = with_capture(scene, folder, capture)
        notice_compile()
        if (args.viewer or args.out) and args.link != "zenoh":  # over Zenoh: replay the run's folder
            from teleop.app.view_bridge import viz_scene_for
            from teleop.viz import make_view

            view = make_view("meshcat", viz_scene_for(scene, view=args.view), record=bool(args.out), host=args.host)
            if args.viewer:
                print(f"viewer: {view.url}  (bound to {args.host})", file=sys.stderr)
        from teleop.app.view_bridge import RunView

        rv = RunView(view) if view is not None else None
        record = _record_writer(args, scene, folder)
        try:
            with compile_clock() as clock:  # the kernels' compile time kept out of the real-time factor
                if args.link == "zenoh":  # two processes on loopback, wall clock; each records its side
                    result = cmd_run_zenoh(scene, quiet=args.quiet, record_dir=folder.tmp if folder else None)
                elif args.operator == "keyboard":  # real time, limited, until the person stops it
                    from teleop.app.keyboard import run_at_keyboard

                    result = run_at_keyboard(scene, view=rv, quiet=args.quiet, hooks=[clock], record=record)
                else:
                    bar = RunBar(scene.duration_s, scene.dt_s, enabled=not args.quiet, clock=clock)
                    result = run_scene(scene, progress=bar, realtime=args.realtime, view=rv, hooks=[clock],
                                       record=record)
                    bar.close()
        finally:
            if record is not None:
                record.close()  # the file whole before the folder is committed
        clock.discount(result.summary)
        if record is not None:
            result.summary["record"] = {k: v for k, v in record.stats().items() if k != "path"}
        with _deferred_interrupts() as late:  # the run is over: its files are written whole, then told
            written = _write_run(result, view, rv, scene, folder) if folder is not None else []
            if folder is not None and args.link == "zenoh":  # the recording drawn from the merged log
                record_from_log(result, scene, folder)
                written = sorted(p.name for p in folder.tmp.iterdir())
            if folder is not None:
                folder.commit()
                folder = None
            s = result.summary
            if json_path is not None:
                write_json(json_path, s)
        if late:
            print("teleop: Ctrl-C came after the run ended: its files were written first", file=sys.stderr)
        if args.viewer and args.hold:
            print(_summary_text(result.summary), file=sys.stderr)
            view.hold(lambda url: print(f"viewer: {url} holds the last frame; Ctrl-C ends it", file=sys.stderr))
    finally:
        if bar is not None:
            bar.close()
        if view is not None:
            view.close()  # the meshcat server never outlives the run, even on Ctrl-C
        if folder is not None:
            folder.abort()  # nothing half-written
    if args.json == "-":
        sys.stdout.write(json.dumps(s, indent=2) + "\n")
    text = sys.stderr if args.json == "-" else sys.stdout
    if not args.quiet:
        print(_summary_text(s), file=text)
        if written:
            print(f"files      {args.out}/  ({', '.join(written)})", file=text)
        if json_path is not None:
            print(f"summary    {json_path}", file=text)
        if not written and json_path is None and args.json != "-":
            print("files      none written (add --out DIR for the log, plots and a recording; --json FILE for "
                  "the summary)", file=text)
    if s["status"] == "interrupted":
        return EXIT_INTERRUPTED
    return EXIT_OK if s["status"] == "ok" else EXIT_FAILED


def _debug_scene(scene, args) -> None:
    """-vv: what the command line resolved to, and where the compiled kernels are kept."""
    if not log.isEnabledFor(logging.DEBUG):
        return
    from teleop.app.progress import kernels_cold, numba_cache_dir

    slave = "none" if scene.slave is None else f"{scene.slave.arm if isinstance(scene.slave.arm, str) else 'urdf'}"
    log.debug("scene %s from %s: %g s at dt %g s (%d ticks), master %s, slave %s, integrator %s, seed %d, "
              "effects %s", scene.name, scene.path, scene.duration_s, scene.dt_s,
              round(scene.duration_s / scene.dt_s), scene.master, slave, scene.integrator, scene.seed,
              ", ".join(scene.effects) or "none")
    if scene.overridden:
        log.debug("changed on the command line: %s", ", ".join(scene.overridden))
    log.debug("link: %s; operator: %s; pacing: %s", getattr(args, "link", "sim"), args.operator,
              "wall clock" if args.realtime or args.operator == "keyboard" else "simulated time")
    log.debug("numba kernels cached in %s (%s)", numba_cache_dir(),
              "cold: the first tick compiles them" if kernels_cold() else "warm")
    log.debug("writes: --out %s, --json %s", args.out or "none", args.json or "none")


def _record_writer(args, scene, folder):
    """With ``--out`` in one process: every tick to ``OUT/record.mcap`` (a writer process; paced to
    the wall clock, it never makes a tick wait), with what ``teleop replay --check`` needs to run it
    again (:mod:`teleop.app.record.runinfo`). None otherwise (over Zenoh each side records its own)."""
    if folder is None or args.link == "zenoh":
        return None
    from teleop.app.record.runinfo import open_run_record

    keyboard = args.operator == "keyboard"
    return open_run_record(folder.path("record.mcap"), scene, runner="one_process",
                           operator="keyboard" if keyboard else "script", realtime=bool(args.realtime or keyboard))


@contextmanager
def _deferred_interrupts():
    """Ctrl-C and SIGTERM wait while the block runs (a run's files being written and committed):
    the flag yielded says one came. Main thread only; elsewhere nothing changes."""
    came = []
    if threading.current_thread() is not threading.main_thread():
        yield came
        return
    previous = {sig: signal.signal(sig, lambda signum, frame: came.append(signum))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield came
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _run_log(arg: str):
    """(log path, arrays, summary) of ``replay``/``plot``'s LOG argument, every array checked."""
    from teleop.util.inputs import load_run_log

    log_path = Path(arg)
    if log_path.is_dir():
        log_path = log_path / "log.npz"
    if not log_path.exists():
        raise ConfigError(f"{arg}: no run log here (expected a log.npz written by 'teleop run --out')")
    arrays, summary = load_run_log(log_path)
    return log_path, arrays, summary


def cmd_replay(args) -> int:
    """Show a recorded run again: live in Meshcat (--viewer), or as replay.html in the run folder
    (the run's own recording.html is never touched). The log is checked whole first. ``--check``:
    run it again from its record and compare (:func:`teleop.app.replay.check_run`)."""
    from teleop.app.replay import check_command, replay_command

    if args.check:  # the run again from its record, compared bit for bit
        if args.viewer or args.out or args.hold:
            raise ConfigError("--check: runs the run again and compares it; it draws nothing (drop --viewer, "
                              "--out, --hold)")
        return check_command(args.log)
    if args.hold and not args.viewer:
        raise ConfigError("--hold: keeps the live viewer's page up after the replay; add --viewer")
    log_path, _, _ = _run_log(args.log)
    return replay_command(log_path.parent, viewer=args.viewer, out=args.out, force=args.force, view=args.view,
                          hold=args.hold, host=args.host)


def cmd_list(args) -> int:
    from teleop.scenario.schema import list_scenes, load_scene

    for name in list_scenes():
        scene = load_scene(name)
        print(f"{name:28s} {scene.description}")
    return 0


def cmd_plot(args) -> int:
    from teleop.app.plots import plot_log

    log_path, _, _ = _run_log(args.log)
    if args.out:
        from teleop.app.outputs import check_folder

        check_folder(Path(args.out), "--out", args.out)
    for p in plot_log(log_path, args.out or log_path.parent):
        print(p)
    return 0


def cmd_schema(args) -> int:
    """Print (or write to --out) the JSON Schema of scene files."""
    from teleop.scenario.schema import scene_schema

    text = json.dumps(scene_schema(), indent=2) + "\n"
    if args.out:
        from teleop.app.outputs import check_json_target

        target = check_json_target(args.out, "--out")
        target.write_text(text, encoding="utf-8")
        print(args.out)
    else:
        sys.stdout.write(text)
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="teleop", description="Constrained teleoperation of surgical-style robots",
                                 epilog="exit codes: 0 ok, 1 the run's status is not ok, 2 bad input (nothing run, "
                                        "nothing written), 130 interrupted (Ctrl-C)")
    ap.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    common = argparse.ArgumentParser(add_help=False)
    loud = common.add_mutually_exclusive_group()
    loud.add_argument("-v", "--verbose", action="count", default=0, help="more messages (-vv: debug)")
    loud.add_argument(
        "-q", "--quiet", action="store_true", help="errors only: no notices, no progress bar, no summary text"
    )
    sub = ap.add_subparsers(dest="command", required=True)
    _add = sub.add_parser
    sub.add_parser = lambda *a, **kw: _add(*a, parents=[common, *kw.pop("parents", [])], **kw)
    run = sub.add_parser("run", help="run a scene (default: the scripted surgical cut)")
    add_scene_flags(run, optional_scene=True)
    add_run_flags(run)
    run.set_defaults(func=cmd_run)
    add_subcommands(sub)
    add_keys_command(sub)
    ls = sub.add_parser("list", help="list the scenes")
    ls.set_defaults(func=cmd_list)
    rp = sub.add_parser("replay", help="show a recorded run again (Meshcat, or recording.html)")
    rp.add_argument("log", help="a log.npz or the --out folder of a run")
    rp.add_argument("--viewer", action="store_true", help="replay live in Meshcat instead of writing HTML")
    rp.add_argument("--host", default="127.0.0.1", help="address the viewer's web server binds (default 127.0.0.1)")
    rp.add_argument("--out", help="write the replay to this .html file (default: replay.html in the run folder)")
    rp.add_argument("--force", action="store_true",
                    help="replace the page if it exists (replay.html, or --out; never the run's data files)")
    rp.add_argument("--view", choices=["perspective", "side"], default="perspective", help="viewer camera")
    rp.add_argument("--hold", action="store_true", help="with --viewer: keep the page served until Ctrl-C")
    rp.add_argument("--check", action="store_true",
                    help="run the run again from its record and compare every recorded state bit for bit: one "
                         "line, exit 0 identical, 1 the first tick and field that differ")
    rp.set_defaults(func=cmd_replay)
    pl = sub.add_parser("plot", help="paper-style PNG figures of a run log")
    pl.add_argument("log", help="a log.npz or the --out folder of a run")
    pl.add_argument("--out", help="folder for the PNGs (default: next to the log)")
    pl.set_defaults(func=cmd_plot)
    sc = sub.add_parser("schema", help="the JSON Schema of the scene format (for editors)")
    sc.add_argument("--out", help="write it to this file instead of printing it")
    sc.set_defaults(func=cmd_schema)
    return ap


class _Lines(logging.Formatter):
    """``teleop: message``; a debug message says so (``teleop: debug: message``)."""

    def format(self, record) -> str:
        text = super().format(record)
        return f"teleop: debug: {text}" if record.levelno <= logging.DEBUG else f"teleop: {text}"


def configure_logging(verbose: int, quiet: bool) -> None:
    """teleop's messages on stderr, one line each: warnings by default, -v info, -vv debug (the
    scene resolved, the kernels' cache, what is written, the CAN frames the cobot's host refused),
    -q errors only."""
    level = logging.ERROR if quiet else logging.DEBUG if verbose > 1 else logging.INFO if verbose else logging.WARNING
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_Lines("%(message)s"))
    root = logging.getLogger("teleop")
    root.handlers[:] = [handler]
    root.setLevel(level)
    root.propagate = False


def _error(message) -> int:
    """One line on stderr, control characters escaped; the bad-input exit code."""
    print(f"teleop: error: {plain(str(message).splitlines()[0] if str(message) else message)}", file=sys.stderr)
    return EXIT_BAD_INPUT


def _reader_gone() -> int:
    """stdout's reader closed the pipe (``teleop list | head -1``): nothing more to say, no
    traceback; stdout is pointed at /dev/null so that the interpreter's last flush is quiet too.
    Exit 141, as a process ended by SIGPIPE shows in a shell (128 + 13)."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):  # stdout without a file descriptor (a test's capture)
        pass
    return EXIT_READER_GONE


def _caused_by_interrupt(e: BaseException) -> bool:
    """True when a KeyboardInterrupt is in ``e``'s chain of causes."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def _terminate(signum, frame):
    raise KeyboardInterrupt  # SIGTERM ends a run as Ctrl-C does: its summary says "interrupted"


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args.verbose, args.quiet)
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _terminate) if main_thread else None
    try:
        code = args.func(args)
        sys.stdout.flush()  # a reader gone away is told here, not at the interpreter's exit
        return code
    except BrokenPipeError:
        return _reader_gone()
    except TeleopError as e:
        return _error(e)
    except OSError as e:  # a file the command was pointed at: its name and the system's reason
        return _error(f"{e.filename or ''}: {e.strerror or e}" if e.filename else f"{type(e).__name__}: {e}")
    except MemoryError:
        return _error("out of memory: the run or file is too large for this machine")
    except KeyboardInterrupt:
        print("teleop: interrupted (nothing written)", file=sys.stderr)
        return EXIT_INTERRUPTED
    except SystemError as e:  # numba wraps a Ctrl-C that lands inside a compiled call
        if not _caused_by_interrupt(e):
            raise
        print("teleop: interrupted (nothing written)", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
