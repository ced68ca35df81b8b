"""The command-line side of :mod:`teleop.app.netrun` (kept apart so that ``teleop --help`` loads
nothing heavy): the ``master`` and ``slave`` subcommands and ``run --link zenoh``. Each takes the
flags ``teleop run`` takes (:func:`teleop.app.args.add_scene_flags`), and refuses with one line
those a side in its own process cannot honour."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from teleop.app.args import add_scene_flags
from teleop.util.errors import ConfigError

#: exit codes, as :mod:`teleop.app.cli`'s
EXIT_OK, EXIT_FAILED, EXIT_INTERRUPTED = 0, 1, 130
#: how long the pair may take beyond the scene's duration before the parent stops it (s)
PAIR_MARGIN_S = 240.0


def add_subcommands(sub) -> None:
    """Register ``teleop master`` and ``teleop slave`` on the CLI's subparsers."""
    for role, flag, default_help in (
            ("slave", "--listen", "listen on this Zenoh endpoint (default tcp/127.0.0.1:7447)"),
            ("master", "--connect", "connect to the slave's endpoint (default tcp/127.0.0.1:7447)")):
        p = sub.add_parser(role, help=f"run the {role} side of a scene over Zenoh (wall clock, the scene's rate)")
        add_scene_flags(p)
        p.add_argument(flag, dest="endpoint", default="tcp/127.0.0.1:7447", help=default_help)
        p.add_argument("--session", default="default", help="key expression name shared by the pair (default: default)")
        p.add_argument("--timeout", type=float, default=120.0, help="seconds to wait for the other side (default 120)")
        p.add_argument("--zenoh-config", metavar="FILE.json",
                       help='extra Zenoh settings, a JSON object {"path/to/key": "json5 value"} (e.g. TLS)')
        trust = p.add_mutually_exclusive_group()
        trust.add_argument("--keys", metavar="DIR", help="the keys folder 'teleop keys DIR' made (pairing key; "
                                                         "certificates for a tls/ endpoint)")
        trust.add_argument("--pairing-key", metavar="FILE", help="a pairing key file alone (loopback or tcp/)")
        p.add_argument("--allow-plaintext-network", action="store_true",
                       help="DANGEROUS: let a plain tcp/ endpoint off loopback through (frames are "
                            "authenticated but not encrypted: use a tls/ endpoint instead)")
        p.add_argument("--no-pin", dest="pin", action="store_false",
                       help="do not pin this side to a core of its own (pinned, it spins instead of sleeping "
                            "and locks its memory where allowed)")
        p.add_argument("--record", metavar="PATH", help="every tick of this side to an MCAP file (default with --out: "
                                                         f"OUT/{role}.mcap)")
        p.add_argument("--part", help=argparse_suppress())
        p.set_defaults(func=cmd_side, role=role, link="zenoh")


def argparse_suppress() -> str:
    import argparse

    return argparse.SUPPRESS  # --part DIR: where `run --link zenoh` collects the sides' runs (internal)


def add_keys_command(sub) -> None:
    """``teleop keys DIR``: a pairing key and, for two hosts, a local CA and both sides' certificates."""
    k = sub.add_parser("keys", help="make the keys a master and a slave pair with (a pairing key; a local CA and "
                                    "certificates for TLS between two hosts)")
    k.add_argument("folder", help="folder to write them in (created; files are made private)")
    k.add_argument("--host", action="append", default=[], metavar="ADDR",
                   help="an address or name the slave is reached at (repeat; default 127.0.0.1 and localhost)")
    k.add_argument("--no-tls", dest="tls", action="store_false", help="the pairing key only (loopback)")
    k.add_argument("--days", type=int, default=365, help="certificate validity (default 365)")
    k.add_argument("--force", action="store_true", help="replace existing key files")
    k.set_defaults(func=cmd_keys)


def cmd_keys(args) -> int:
    from teleop.link.keys import DEFAULT_HOSTS, make_keys

    written = make_keys(args.folder, tuple(args.host) or DEFAULT_HOSTS, tls=args.tls, days=args.days,
                        overwrite=args.force)
    for name, path in written.items():
        print(f"{name:12s} {path}")
    print(f"copy the folder to both hosts; each side reads its own files: "
          f"'teleop slave SCENE --keys {args.folder}' and 'teleop master SCENE --keys {args.folder}'")
    return 0


def side_keys(args, role: str):
    """The side's key material from ``--keys DIR`` or ``--pairing-key FILE``; ConfigError when
    neither is given (the link never runs unauthenticated)."""
    from teleop.link.keys import LinkKeys, load_keys, load_pairing_key

    if args.keys:
        return load_keys(args.keys, role)
    if args.pairing_key:
        return LinkKeys(load_pairing_key(args.pairing_key), role)
    raise ConfigError(f"teleop {role}: no keys: the link is always authenticated; make them once with "
                      f"'teleop keys DIR' and pass --keys DIR to both sides")


def add_run_flags(run) -> None:
    """``teleop run --link sim|zenoh``."""
    run.add_argument("--link", choices=["sim", "zenoh"], default="sim",
                     help="sim: one process, the [link] table's channel in simulated time (default); "
                          "zenoh: master and slave as two processes on loopback, wall clock")


def refuse_over_zenoh(args) -> None:
    """The flags a side in its own process cannot honour: a one-line ConfigError."""
    if getattr(args, "viewer", False):
        raise ConfigError("--viewer: not over --link zenoh (each side runs in its own process); add --out DIR "
                          "and watch the run with 'teleop replay DIR --viewer'")
    if getattr(args, "operator", "script") == "keyboard":
        raise ConfigError("--operator keyboard: not over --link zenoh yet; run it in one process "
                          "('teleop run SCENE --operator keyboard')")


def cmd_side(args) -> int:
    """``teleop master`` / ``teleop slave``: one side in this process, its own summary. Ctrl-C or
    SIGTERM from the start ends the side between steps with status "interrupted", written."""
    from teleop.app.session import _stop_requests

    with _stop_requests() as stop:
        return _side(args, stop)


def _side(args, stop) -> int:
    from teleop.app.args import scene_for
    from teleop.app.netrun import run_master, run_slave, save_side, side_result
    from teleop.app.outputs import RunFolder, check_json_target

    refuse_over_zenoh(args)
    scene, capture = scene_for(args)
    extra = _zenoh_config(args.zenoh_config) if args.zenoh_config else None
    json_path = check_json_target(args.json) if args.json else None
    folder = RunFolder(args.out) if args.out else None
    try:
        if capture is not None:
            from teleop.app.args import with_capture

            scene = with_capture(scene, folder, capture)
        if args.role == "slave" and scene.slave is None:
            raise ConfigError(f"{scene.path}: slave: the scene has no [slave] table: nothing to run on this side")
        trust = dict(keys=side_keys(args, args.role), allow_plaintext_network=args.allow_plaintext_network,
                     record=args.record or (folder.path(f"{args.role}.mcap") if folder is not None else None))
        run = (run_slave(scene, listen=args.endpoint, session=args.session, timeout_s=args.timeout, config_json5=extra,
                         pin=args.pin, stop=stop, **trust) if args.role == "slave" else
               run_master(scene, connect=args.endpoint, session=args.session, timeout_s=args.timeout,
                          config_json5=extra, pin=args.pin, stop=stop, **trust))
        if args.part:
            save_side(*run, args.part)
        result = side_result(scene, *run)
        if folder is not None:
            _write_folder(result, scene, folder)
            folder.commit()
            folder = None
    finally:
        if folder is not None:
            folder.abort()
    return _report(result.summary, args, json_path, f"{args.role}: ")


def cmd_run_zenoh(scene, quiet: bool = False, record_dir=None):
    """``teleop run SCENE --link zenoh``: the slave and the master as two child processes on a
    free loopback port, each running ``scene`` (written resolved for them); their two runs merged
    into one (:func:`teleop.app.netrun.merge`). A side whose process dies is judged by the other
    (a lost peer: status ``link_lost``); Ctrl-C stops both between ticks and keeps what they ran."""
    from teleop.app.netrun import free_endpoint, load_side, merge
    from teleop.app.view_bridge import save_scene_copy
    from teleop.link.keys import one_run_keys

    ep = free_endpoint()
    key_file, _, _ = one_run_keys()  # a key for this run's two children only, in a private folder
    with tempfile.TemporaryDirectory() as tmp:
        path = save_scene_copy(scene, tmp)
        py = [sys.executable, "-m", "teleop"]
        common = ["--part", tmp, "-q", "--pairing-key", str(key_file)]  # the parent prints the one summary
        rec = {r: (["--record", str(Path(record_dir) / f"{r}.mcap")] if record_dir else [])
               for r in ("slave", "master")}
        slave = subprocess.Popen(py + ["slave", str(path), "--listen", ep] + common + rec["slave"])
        master = subprocess.Popen(py + ["master", str(path), "--connect", ep] + common + rec["master"])
        codes = _wait_pair(master, slave, scene.duration_s + PAIR_MARGIN_S)
        sides = {k: load_side(tmp, k) for k in codes}
        why = ", ".join(f"{k} process exit {c}" for k, c in codes.items()
                        if c not in (0, 1) or (c != 0 and sides[k] is None))
        interrupted = any(c in (130, -signal.SIGINT) for c in codes.values())
        result = merge(scene, sides["master"], sides["slave"], why, interrupted)
    shutil.rmtree(key_file.parent, ignore_errors=True)
    result.summary["endpoint"] = ep
    return result


def _wait_pair(master, slave, timeout_s: float) -> dict:
    """Wait for both children. Ctrl-C or SIGTERM here does not end the parent: it is passed on to
    the children that still run (as SIGINT), which end their runs between ticks and write what
    they ran, and the parent merges and writes the result as usual (a Ctrl-C after both had
    finished loses nothing). A child past ``timeout_s`` is stopped the same way, then killed."""
    import time

    from teleop.app.session import _stop_requests

    procs = {"master": master, "slave": slave}
    end, forwarded = time.monotonic() + timeout_s, False
    with _stop_requests() as stop:
        while any(p.poll() is None for p in procs.values()):
            if (stop or time.monotonic() > end) and not forwarded:
                for p in procs.values():
                    if p.poll() is None:
                        p.send_signal(signal.SIGINT)
                forwarded, end = True, time.monotonic() + 30.0
            elif forwarded and time.monotonic() > end:
                for p in procs.values():
                    if p.poll() is None:
                        p.kill()
            time.sleep(0.02)
    return {k: p.returncode for k, p in procs.items()}


def _write_folder(result, scene, folder) -> None:
    from teleop.app.cli import _write_run

    _write_run(result, None, None, scene, folder)
    record_from_log(result, scene, folder)


def record_from_log(result, scene, folder) -> None:
    """A run folder's ``recording.html`` drawn from its log, as an in-process run's view draws it
    live (over Zenoh the two sides' views are in two processes, so it is made afterwards)."""
    from teleop.app.view_bridge import replay_run, viz_scene_for
    from teleop.viz import make_view

    if "p_r" in result.log:  # a side's run (a slave alone has no master pose to draw)
        with make_view("meshcat", viz_scene_for(scene), record=True) as v:
            replay_run(folder.tmp, v)
            v.save_html(folder.path("recording.html"), autoplay=False)


def _report(summary: dict, args, json_path, prefix: str) -> int:
    from teleop.app.cli import _summary_text
    from teleop.app.outputs import write_json

    if json_path is not None:
        write_json(json_path, summary)
    elif args.json == "-":
        sys.stdout.write(json.dumps(summary, indent=2) + "\n")
    if not args.quiet:
        print(_summary_text(summary), file=sys.stderr if args.json == "-" else sys.stdout)
    st = summary["status"]
    return EXIT_INTERRUPTED if st == "interrupted" else EXIT_OK if st == "ok" else EXIT_FAILED


def _zenoh_config(path: str) -> dict:
    """The --zenoh-config file: a JSON object of Zenoh configuration keys to json5 values."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ConfigError(f"--zenoh-config {path}: cannot read a JSON object: {e}".splitlines()[0]) from None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise ConfigError(f'--zenoh-config {path}: expected {{"path/to/key": "json5 value", ...}} (strings)')
    return data
