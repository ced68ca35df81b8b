"""``teleop replay RUN_DIR``: draw a run folder again from what it keeps (the scene it ran, the
frames its view drew), into a new ``replay.html`` or live in Meshcat. The run's own files are never
written; ``--out`` names another .html file. An existing page (an earlier replay's ``replay.html``,
the run's recording.html, any ``--out``) is replaced only with ``--force``; the run's data files
never are.

``teleop replay RUN_DIR --check`` (:func:`check_run`): the run again from its record, every
recorded state compared bit for bit; one line, exit 0 identical, 1 the first tick and field that
differ, 2 no usable record."""

from __future__ import annotations

import json
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from teleop.util.errors import ConfigError

if TYPE_CHECKING:
    from teleop.app.record.compare import Difference


def replay_command(source, viewer: bool = False, out=None, force: bool = False, view: str = "perspective",
                   hold: bool = False, host: str = "127.0.0.1") -> int:
    """Replay the run folder (or its log.npz) ``source``; returns the exit code (0)."""
    from teleop.app.view_bridge import load_run_scene, replay_run, viz_scene_for
    from teleop.viz import make_view

    folder = Path(source)
    if folder.suffix == ".npz":
        folder = folder.parent
    if not (folder / "log.npz").is_file():
        raise ConfigError(f"{source}: no run here (expected the --out folder of 'teleop run', with its log.npz)")
    target = None
    if not viewer:
        target = Path(out) if out else folder / "replay.html"
        data = {(folder / n).resolve() for n in ("log.npz", "metrics.json", "scene.toml", "view_frames.npz")}
        if target.resolve() in data or target.suffix.lower() != ".html":
            raise ConfigError(f"--out {target}: expected a new .html file, not one of the run's data files")
        if target.resolve() == (folder / "recording.html").resolve() and not force:
            raise ConfigError(f"--out {target}: that is the run's own recording; pick another name (or --force)")
        if target.exists() and not force:  # an earlier replay's page, or any file: replaced only when asked
            what = f"--out {target}" if out else f"{target}"
            raise ConfigError(f"{what}: exists (an earlier replay?); add --force to replace it, or --out another .html")
    scene = load_run_scene(folder)
    with make_view("meshcat", viz_scene_for(scene, view=view), record=not viewer, host=host) as v:
        if viewer:
            print(f"viewer: {v.url}  (replaying {scene.name} in real time)", file=sys.stderr)
        frames = replay_run(folder, v, realtime=viewer)
        if target is not None:
            print(v.save_html(target, autoplay=False))
        elif hold:
            v.hold(lambda url: print(f"viewer: {url} holds the last frame; Ctrl-C ends it", file=sys.stderr))
    print(f"replayed {frames} frames of {scene.name}")
    return 0


# -- teleop replay RUN --check: the run again from its record, compared bit for bit ----------------

#: the topics a side's record holds of the run's state (the others: its time stamps, the keys typed)
_NOT_COMPARED = ("/operator/keys", "/master/link", "/slave/link", "/link/events")


@dataclass
class CheckResult:
    """What ``teleop replay RUN --check`` found: ``identical``, the ``difference`` (None when
    identical), the one ``line`` to print, ``ticks`` and ``messages`` compared."""

    identical: bool
    line: str
    ticks: int
    messages: int
    difference: Difference | None = None


def check_command(source) -> int:
    """``teleop replay RUN --check``: one line; 0 identical, 1 not (bad input raises ConfigError)."""
    result = check_run(source)
    print(result.line)
    return 0 if result.identical else 1


def check_run(source) -> CheckResult:
    """Run the run of ``source`` (a run folder, or one of its records) again from its record and
    compare every recorded state (:func:`teleop.app.record.compare.first_difference`): a run of one
    process as it ran (its scene, seed and overrides, its operator's keys), a two-process run in one
    process in lockstep from its delivery schedule (:mod:`teleop.link.schedule`). ConfigError (one
    line naming the file and the reason) when there is no record, or one cut short, or one of
    another record version."""
    folder = Path(source)
    if folder.suffix in (".mcap", ".npz") and not folder.is_dir():  # a file of the run folder
        folder = folder.parent
    one, master, slave = (folder / n for n in ("record.mcap", "master.mcap", "slave.mcap"))
    if one.is_file():
        return _check_one(folder, _load(one))
    if master.is_file() and slave.is_file():
        return _check_two(folder, _load(master), _load(slave))
    if master.is_file() or slave.is_file():
        have, lack = (master, slave) if master.is_file() else (slave, master)
        raise ConfigError(f"{lack}: missing: a two-process run is checked from both sides' records ({have.name} "
                          f"and {lack.name})")
    raise ConfigError(f"{source}: no record to check (expected record.mcap, or master.mcap and slave.mcap, written "
                      f"by 'teleop run --out')")


def _load(path: Path):
    """A record read whole (bytes), with its replay metadata and scene; ConfigError if unusable."""
    from teleop.app.record.reader import scan_record
    from teleop.app.record.runinfo import RECORD_VERSION, REPLAY_KEY, SCENE_ATTACHMENT

    raw = scan_record(path)
    if not raw.complete:
        if not raw.messages and not raw.metadata:
            raise ConfigError(f"{path}: not an MCAP record ({raw.error or 'empty'})")
        raise ConfigError(f"{path}: truncated ({raw.error or 'no footer'}): its writer did not finish the file, "
                          f"so the run is not all there")
    info = raw.metadata.get(REPLAY_KEY)
    if info is None:
        raise ConfigError(f"{path}: no replay data in it (written before record version {RECORD_VERSION}, which "
                          f"keeps the scene, seed and inputs)")
    if info.get("record_version") != str(RECORD_VERSION):
        raise ConfigError(f"{path}: record version {info.get('record_version')!r}; this teleop "
                          f"({_version()}) checks version {RECORD_VERSION}")
    text = raw.attachments.get(SCENE_ATTACHMENT)
    if text is None:
        raise ConfigError(f"{path}: no {SCENE_ATTACHMENT} attached (the scene it ran)")
    return raw, info, _scene(path, text.decode("utf-8"))


def _version() -> str:
    from teleop import __version__

    return __version__


def _scene(path: Path, text: str):
    """The scene a record carries, as it ran (a CAN capture file is not written again)."""
    import tomllib

    from teleop.scenario.schema import parse_scene

    table = tomllib.loads(text)
    table.get("cobot", {}).pop("capture_path", None)
    return parse_scene(table, f"{path}:{'scene.toml'}")


def _steps(raw, prefix: str) -> int:
    return len(raw.messages.get(f"{prefix}/state", []))


def _keys(raw) -> dict[float, list[str]]:
    """The keyboard's reads by simulated time (s), in the order they came."""
    out: dict[float, list[str]] = {}
    for _, _, data in raw.messages.get("/operator/keys", []):
        m = json.loads(data)
        out.setdefault(float(m["t_s"]), []).append(str(m["text"]))
    return out


def _check_one(folder: Path, loaded) -> CheckResult:
    """A run of one process: its scene run again for its recorded ticks, on the simulated clock."""
    from teleop.app.record import RecordWriter
    from teleop.app.runtime import run_scene

    raw, info, scene = loaded
    steps = _steps(raw, "/master")
    scene = scene.with_overrides(duration_s=steps * scene.dt_s)
    operator = None
    if info.get("operator") == "keyboard":
        from teleop.app.keyboard import scripted_keyboard

        operator = scripted_keyboard(scene, _keys(raw))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "replay.mcap"
        with RecordWriter(path) as writer:
            run_scene(scene, operator=operator, record=writer)
        replayed = _scan(path)
    topics = [t for t in raw.messages if t not in _NOT_COMPARED]
    return _verdict(folder, scene, raw, replayed, topics, steps, "one process")


def _check_two(folder: Path, master, slave) -> CheckResult:
    """A two-process run: both sides in this process, each message delivered at the tick its
    record says it was (:class:`teleop.link.schedule.ScheduleLink`)."""
    from teleop.app.record import RecordWriter
    from teleop.app.record.reader import RawRecord

    (raw_m, _, scene), (raw_s, _, _) = master, slave
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "replay.mcap"
        with RecordWriter(path) as writer:
            run_schedule(scene, raw_m, raw_s, writer)
        replayed = _scan(path)
    merged = RawRecord({**raw_m.messages, **raw_s.messages}, {**raw_m.schemas, **raw_s.schemas},
                       {**raw_m.encodings, **raw_s.encodings}, {}, {}, True)
    topics = [t for t in merged.messages if t not in _NOT_COMPARED]
    return _verdict(folder, scene, merged, replayed, topics, _steps(raw_m, "/master"), "two processes, in lockstep")


def _scan(path: Path):
    from teleop.app.record.reader import scan_record

    raw = scan_record(path)
    if not raw.complete:
        raise RuntimeError(f"replay: the replay's own record {path} is incomplete: {raw.error}")
    return raw


def _verdict(folder: Path, scene, raw, replayed, topics: list[str], steps: int, how: str) -> CheckResult:
    from teleop.app.record.compare import count_messages, first_difference

    d = first_difference(raw, replayed, topics, scene.dt_s)
    n = count_messages(raw, topics)
    if d is None:
        return CheckResult(True, f"replay {folder}: identical: {steps} ticks of {scene.name} ({how}), {n} messages "
                                 f"on {len(topics)} channels, bit for bit", steps, n)
    return CheckResult(False, f"replay {folder}: differs at {d.text()}", steps, n, d)


def _schedule(raw, prefix: str) -> np.ndarray:
    """A side's delivery schedule from its record's ``<prefix>/link``: (ticks, 4) seq, hello,
    clock_s, heard_s (NaN: never heard); ConfigError when the record has none."""
    items = raw.messages.get(f"{prefix}/link")
    if items is None:
        raise ConfigError(f"{prefix[1:]}.mcap: no {prefix}/link channel (the delivery schedule a two-process check "
                          f"follows)")
    rows = np.empty((len(items), 4))
    for k, (_, _, data) in enumerate(items):
        m = json.loads(data)
        heard = m["heard_s"]
        rows[k] = (m["seq"], bool(m["hello"]), m["clock_s"], np.nan if heard is None else heard)
    return rows


def run_schedule(scene, raw_master, raw_slave, writer) -> tuple[int, int]:
    """Both sides of a two-process run in this process, built as the two processes built them
    (:mod:`teleop.app.assembly`, networked), their ticks interleaved in lockstep on a
    :class:`~teleop.link.schedule.ScheduleLink` that hands each tick the message its record says
    it was handed (a side's tick runs once its peer has sent that message), both recorded into
    ``writer``. Returns the ticks run (master, slave)."""
    from teleop.app.assembly import build_master, build_slave
    from teleop.link.schedule import ScheduleError, ScheduleLink

    sched_m, sched_s = _schedule(raw_master, "/master"), _schedule(raw_slave, "/slave")
    n_m, n_s = min(len(sched_m), _steps(raw_master, "/master")), min(len(sched_s), _steps(raw_slave, "/slave"))
    mb = build_master(scene, max(n_m, 1), np.random.default_rng(scene.seed), networked=True, record=writer)
    sb = build_slave(scene, max(n_s, 1), networked=True, record=writer)
    link = ScheduleLink(sched_m, sched_s)
    m_end, s_end, dt = link.master_end, link.slave_end, scene.dt_s
    with mb.side.master:
        try:
            _interleave(mb.side, sb.side, m_end, s_end, n_m, n_s, dt)
        except ScheduleError as e:
            raise ConfigError(str(e)) from None
    return n_m, n_s


def _interleave(master, slave, m_end, s_end, n_m: int, n_s: int, dt: float) -> None:
    """The two sides' ticks in an order the schedule allows (the master's first when both may)."""
    i = j = 0
    while i < n_m or j < n_s:
        if i < n_m and m_end.needs(i) <= j:  # reply k is sent by the slave's tick k - 1
            m_end.at(i)
            master.tick(i, i * dt, m_end)
            i += 1
        elif j < n_s and s_end.needs(j) <= i:  # command k is sent by the master's tick k - 1
            s_end.at(j)
            slave.tick(j, j * dt, s_end)
            j += 1
        else:
            raise ConfigError(f"schedule: the master's tick {i} waits for reply {m_end.needs(i)} and the slave's "
                              f"tick {j} for command {s_end.needs(j)}: no run sends them so")
