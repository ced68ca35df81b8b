"""The command-line side of :mod:`teleop.app.netrun` (kept apart so that ``teleop --help`` loads
nothing heavy): the ``master`` and ``slave`` subcommands and ``run --link zenoh``."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def add_subcommands(sub) -> None:
    """Register ``teleop master`` and ``teleop slave`` on the CLI's subparsers."""
    for role, flag, default_help in (("slave", "--listen", "listen on this Zenoh endpoint (default tcp/127.0.0.1:7447)"),
                                     ("master", "--connect", "connect to the slave's endpoint (default tcp/127.0.0.1:7447)")):
        p = sub.add_parser(role, help=f"run the {role} side of a scene over Zenoh (wall clock, the scene's rate)")
        p.add_argument("scene", help="scene name (see 'teleop list') or path to a .toml file")
        p.add_argument(flag, dest="endpoint", default="tcp/127.0.0.1:7447", help=default_help)
        p.add_argument("--session", default="default", help="key expression name shared by the pair (default: default)")
        p.add_argument("--timeout", type=float, default=120.0, help="seconds to wait for the other side (default 120)")
        p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="set any scene key (as 'run')")
        p.add_argument("--zenoh-config", metavar="FILE.json",
                       help='extra Zenoh settings, a JSON object {"path/to/key": "json5 value"} (e.g. TLS)')
        p.add_argument("--no-pin", dest="pin", action="store_false",
                       help="do not pin this side to a core of its own (pinned, it spins instead of sleeping)")
        p.add_argument("--json", help="write this side's summary as JSON here")
        p.set_defaults(func=cmd_side, role=role)


def add_run_flags(run) -> None:
    """``teleop run --link sim|zenoh``."""
    run.add_argument("--link", choices=["sim", "zenoh"], default="sim",
                     help="sim: one process, the [link] table's channel in simulated time (default); "
                          "zenoh: master and slave as two processes on loopback, wall clock")


def cmd_side(args) -> int:
    from teleop.app.netrun import run_master, run_slave
    from teleop.scenario.schema import load_scene

    scene = load_scene(args.scene, sets=args.set)
    extra = _zenoh_config(args.zenoh_config) if args.zenoh_config else None
    if args.role == "slave":
        out = run_slave(scene, listen=args.endpoint, session=args.session, timeout_s=args.timeout, config_json5=extra,
                        pin=args.pin)
    else:
        out = run_master(scene, connect=args.endpoint, session=args.session, timeout_s=args.timeout, config_json5=extra,
                         pin=args.pin)
    out = {"scenario": scene.name, **out}
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    hb = out["heartbeat"]
    ck = out["clock"]
    print(f"{args.role}: {out['status']}  steps={out['steps']}  late={out['late_ticks']}  "
          f"real-time factor {ck['realtime_factor']:.2f} (behind at most {ck['behind_max_ms']:.0f} ms, load {ck['load_1min']:.1f})  "
          f"link lost {hb['lost_events']}x ({hb['lost_ticks']} ticks, detected within {hb['detect_latency_max_s'] * 1e3:.1f} ms)")
    return 0 if out["status"] == "ok" else 1


def _zenoh_config(path: str) -> dict:
    """The --zenoh-config file: a JSON object of Zenoh configuration keys to json5 values."""
    from teleop.util.errors import ConfigError

    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ConfigError(f"--zenoh-config {path}: cannot read a JSON object: {e}".splitlines()[0]) from None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise ConfigError(f'--zenoh-config {path}: expected {{"path/to/key": "json5 value", ...}} (strings)')
    return data


def cmd_run_zenoh(args) -> int:
    """``teleop run SCENE --link zenoh``: both sides on loopback, one summary."""
    from teleop.app.netrun import run_pair
    from teleop.scenario.schema import load_scene

    scene_arg = args.scene or "straight_incision"
    load_scene(scene_arg, sets=args.set)  # a bad scene fails here, before any process starts
    summary = run_pair(scene_arg, sets=args.set)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(summary, indent=2) + "\n")
    print(f"zenoh run: {summary['status']}  endpoint {summary['endpoint']}", file=sys.stderr)
    for k, v in summary["metrics"].items():
        print(f"  {k:34s} {v:.4g}")
    return 0 if summary["status"] == "ok" and not summary["nan"] else 1
