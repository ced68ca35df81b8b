"""``teleop replay RUN_DIR``: draw a run folder again from what it keeps (the scene it ran, the
frames its view drew), into a new ``replay.html`` or live in Meshcat. The run's own files are never
written; ``--out`` names another .html file. An existing page (an earlier replay's ``replay.html``,
the run's recording.html, any ``--out``) is replaced only with ``--force``; the run's data files
never are."""

from __future__ import annotations

import sys
from pathlib import Path

from teleop.util.errors import ConfigError


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
