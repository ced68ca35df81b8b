"""What a run's record holds beyond its ticks, so that ``teleop replay RUN --check`` can run it
again from the record alone (:mod:`teleop.app.replay`):

* the MCAP metadata record ``teleop.replay``: ``record_version`` (:data:`RECORD_VERSION`, bumped
  whenever a replay of an older record could not be bit for bit), ``runner`` ("one_process" or
  "two_process"), ``side`` (a two-process record: "master" or "slave"), ``operator`` ("script" or
  "keyboard"), ``realtime`` (paced to the wall clock: the physics is the same), ``teleop`` (the
  version that wrote it), ``dt_s`` and ``seed``;
* the attachment ``scene.toml``: the scene as run, resolved (every override applied, the seed in
  it), the text :func:`teleop.app.view_bridge.save_scene_copy` writes beside the run;
* ``/operator/keys`` (a keyboard session): what the person typed, by the tick that read it;
* ``/master/link``, ``/slave/link`` (a two-process run): the delivery schedule, tick by tick
  (:mod:`teleop.link.schedule`), with the link's time stamps.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from teleop.app.record.writer import RecordWriter

#: the version of what a record holds for a replay (the metadata, the attachments, the channels)
RECORD_VERSION = 1
#: the metadata record's name, and the scene's attachment
REPLAY_KEY, SCENE_ATTACHMENT = "teleop.replay", "scene.toml"


def scene_text(scene) -> str:
    """The resolved scene as TOML, exactly what a run folder keeps as ``scene.toml``."""
    from teleop.app.view_bridge import save_scene_copy

    with tempfile.TemporaryDirectory() as tmp:
        return save_scene_copy(scene, tmp).read_text(encoding="utf-8")


def open_run_record(path: str | Path, scene, *, runner: str, operator: str = "script", realtime: bool = False,
                    side: str | None = None) -> RecordWriter:
    """A :class:`RecordWriter` at ``path`` for a run of ``scene`` (its writer process started),
    holding from the start what a replay needs (see the module docstring). ``realtime``: the run is
    paced to the wall clock (the writer never makes a tick wait, and spools)."""
    from teleop import __version__

    meta = {"scene": scene.name, "seed": scene.seed, "master": scene.master}
    if side is not None:
        meta["side"] = side
    writer = RecordWriter(path, realtime=realtime, metadata=meta)
    info = {"record_version": RECORD_VERSION, "runner": runner, "operator": operator, "realtime": bool(realtime),
            "teleop": __version__, "dt_s": repr(float(scene.dt_s)), "seed": scene.seed}
    if side is not None:
        info["side"] = side
    writer.metadata_record(REPLAY_KEY, info)
    writer.attach(SCENE_ATTACHMENT, scene_text(scene), "application/toml")
    return writer


class KeyTap:
    """Hands what the keyboard read at each tick to the record (``/operator/keys``): the
    :class:`~teleop.app.keyboard.KeyboardOperator` calls it with the tick's time ``t_s`` (s) and
    the text; a read is rare (a key press), so each is one message down the writer's pipe."""

    def __init__(self, writer: RecordWriter, dt_s: float) -> None:
        self.writer, self.dt = writer, float(dt_s)

    def __call__(self, t_s: float, text: str) -> None:
        from teleop.app.record.schemas import OPERATOR_KEYS

        tick = round(t_s / self.dt)
        self.writer.message("/operator/keys", OPERATOR_KEYS, t_s, {"tick": tick, "t_s": t_s, "text": text}, tick)
