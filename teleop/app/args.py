"""The flags every command that runs a scene takes (``run``, ``master``, ``slave``), and the scene
they make: one parser, one resolution, so a flag means the same on every runner."""

from __future__ import annotations

import argparse
import json

from teleop.util.errors import ConfigError, SceneError

DEFAULT_SCENE = "straight_incision"
#: command-line flags of the scene's top-level keys, for error messages
FLAGS = {
    "duration_s": "--duration",
    "dt_s": "--dt",
    "seed": "--seed",
    "integrator": "--integrator",
    "master": "--master",
}


def add_scene_flags(p: argparse.ArgumentParser, optional_scene: bool = False) -> None:
    """The scene and the flags that change it or how it runs, on ``p``."""
    p.add_argument("scene", nargs="?" if optional_scene else None,
                   help="scene name (see 'teleop list') or path to a .toml file")
    p.add_argument(
        "--master", choices=["ideal", "cobot"], help="ideal: wrench straight to the tool; cobot: the CAN device"
    )
    view = p.add_mutually_exclusive_group()
    view.add_argument("--headless", action="store_true", default=True, help="no viewer (default)")
    view.add_argument("--viewer", action="store_true", help="show both sides live in Meshcat (prints the URL)")
    p.add_argument("--host", default="127.0.0.1",
                     help="address the viewer's web server binds (default 127.0.0.1: this machine only)")
    p.add_argument("--realtime", action="store_true", help="pace ticks to the wall clock (default: simulated time; "
                                                               "always with --operator keyboard)")
    p.add_argument("--operator", choices=["script", "keyboard"], default="script",
                     help="the scene's scripted operator (default) or you at the keyboard (in real time, until you "
                          "press x)")
    p.add_argument("--duration", type=float, help="simulated seconds (overrides the scene; a keyboard session "
                                                    "runs until stopped unless given)")
    p.add_argument("--seed", type=int, help="random seed (overrides the scene)")
    p.add_argument("--integrator", help="integrator name (overrides the scene)")
    p.add_argument("--dt", type=float, help="control period in s (overrides the scene)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                     help="set any scene key, VALUE as TOML (e.g. --set slave.solver=daqp --set tool.mass_kg=0.3)")
    p.add_argument("--allow-hardware", action="store_true",
                     help="let the scene open a hardware CAN interface (cobot.interface other than a simulated one)")
    p.add_argument("--can-log", metavar="PATH",
                     help="cobot master: write the CAN traffic here (.log candump, .asc, .blf, .csv by suffix)")
    p.add_argument("--json", help="write the run summary as JSON here ('-': to stdout, the text summary to stderr)")
    p.add_argument("--out", help="write metrics.json, log.npz, recording.html and PNG plots into this folder "
                                   "(whole or not at all)")
    p.add_argument("--view", choices=["perspective", "side"], default="perspective",
                     help="viewer camera: perspective from above, or side (level, orthographic)")
    p.add_argument("--hold", action="store_true", help="with --viewer: keep the page served after the run until Ctrl-C")


def scene_for(args):
    """The scene of a ``run``, its overrides applied and checked: (scene, capture path from the
    scene file or None)."""
    from teleop.app.session import tick_count
    from teleop.scenario.schema import hardware_interface, load_scene

    if getattr(args, "hold", False) and not getattr(args, "viewer", False):
        raise ConfigError("--hold: keeps the live viewer's page up after the run; add --viewer (a run's "
                          "--out DIR keeps recording.html to open later)")
    base = load_scene(args.scene or DEFAULT_SCENE)
    given = dict(duration_s=args.duration, seed=args.seed, master=args.master, integrator=args.integrator,
                 dt_s=args.dt)
    sets = list(args.set)
    if args.can_log:  # the cobot's capture_path, as a TOML string (json.dumps quotes and escapes it)
        if (args.master or base.master) != "cobot":
            raise ConfigError("--can-log: only the cobot master has a CAN bus (add --master cobot)")
        sets.append(f"cobot.capture_path={json.dumps(str(args.can_log))}")
    try:
        scene = base.with_overrides(sets, **given)
    except SceneError as e:
        if e.key in FLAGS and given.get(e.key) is not None:
            raise ConfigError(f"{FLAGS[e.key]} {given[e.key]}: {e.reason}") from None
        raise
    check_slave_gains(scene, given)
    where = (
        "--duration" if args.duration is not None else "--dt" if args.dt is not None else f"{scene.path}: duration_s"
    )
    try:
        n = tick_count(scene.duration_s, scene.dt_s, where)
    except ConfigError as e:
        raise ConfigError(str(e)) from None
    if n == 0:
        raise ConfigError(f"{where}: {scene.duration_s:g} s is shorter than one tick of dt {scene.dt_s:g} s: "
                          "a run of zero ticks")
    hw = hardware_interface(scene)
    if hw is not None and not args.allow_hardware:
        raise ConfigError(f"{scene.path}: cobot.interface: {hw!r} is a hardware CAN interface; "
                          "add --allow-hardware to open it")
    cap = scene.cobot.capture_path
    from_file = cap is not None and cap == base.cobot.capture_path
    if from_file and not args.out and not getattr(args, "part", None):  # a pair's child: the parent placed it
        raise ConfigError(f"{scene.path}: cobot.capture_path: a scene's capture is written inside its run's "
                          "folder; add --out DIR")
    return scene, (cap if from_file else None)


def check_slave_gains(scene, given: dict | None = None) -> None:
    """The slave's follower corrects its error within one tick: its task and fixture gains (1/s)
    times dt stay below 1 (:class:`teleop.slave.arm.SlaveArm` refuses otherwise, once built). Said
    before anything runs, naming what changed it: the flag (``--dt``), a ``--set`` key, or the file's
    key; ``given`` the flags' values by scene key (FLAGS)."""
    from teleop.scenario.plausibility import pick_key

    slave = scene.slave
    if slave is None:
        return
    for gain, what in (("k_task_1ps", "task"), ("k_fixture_1ps", "fixture")):
        k = float(getattr(slave, gain))
        if k * scene.dt_s < 1.0:
            continue
        why = (f"the slave's {what} gain {k:g} /s (slave.{gain}) times dt must stay below 1 (the follower corrects "
               f"within one tick): it needs dt < {1.0 / k:.3g} s")
        key = pick_key(("dt_s", f"slave.{gain}", "slave"), scene.overridden)
        flag = FLAGS.get(key)
        if flag is not None and (given or {}).get(key) is not None:
            raise ConfigError(f"{flag} {given[key]:g}: {why}, or a lower slave.{gain}")
        if key in scene.overridden:
            raise ConfigError(f"--set {key}: {why} (dt is {scene.dt_s:g} s)")
        raise ConfigError(f"{scene.path}: dt_s: {why} (got {scene.dt_s:g} s), or a lower slave.{gain}")


def with_capture(scene, folder, cap: str):
    """The scene with its file's capture path placed inside the run's (temporary) folder."""
    from teleop.scenario.schema import parse_scene
    from teleop.util.typed import as_table

    target = folder.path(cap)
    target.parent.mkdir(parents=True, exist_ok=True)
    return parse_scene(as_table(scene), scene.path, pairs=[("cobot.capture_path", str(target))])


