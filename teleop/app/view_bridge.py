"""From a run to the Meshcat views: build the view's scene from a Scene, turn loop ticks into
frames, keep what the view drew, and show a run folder again.

The loop calls :meth:`RunView.publish_tick` every tick; frames are built only at ``fps`` of
simulated time, so the 1 kHz loop pays nothing in between. A run written with ``--out`` keeps,
beside its log, the scene it ran (``scene.toml``, :func:`save_scene_copy`) and the frames its view
drew (``view_frames.npz``, :meth:`RunView.save_frames`), so :func:`replay_run` draws everything the
live view drew, for a run of any scene file.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import numpy as np
import tomli_w

from teleop.scenario.build import master_fixture_spec, master_frame
from teleop.scenario.schema import Scene, load_scene
from teleop.scenario.tables import CustomFixture
from teleop.util.errors import ConfigError
from teleop.util.inputs import plain
from teleop.util.typed import as_table

#: the files a run folder holds for the viewer
SCENE_COPY, FRAMES_FILE = "scene.toml", "view_frames.npz"


def _plain(x):
    """A table with numpy scalars made Python numbers and URDF paths made absolute (TOML-ready)."""
    if isinstance(x, dict):
        return {k: (str(Path(v).resolve()) if k == "urdf" and isinstance(v, str) else _plain(v)) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x


def save_scene_copy(scene: Scene, folder) -> Path:
    """Write the scene a run ran, resolved (overrides applied, defaults left out), as
    ``folder/scene.toml``; :func:`load_run_scene` reads it back. Returns the path."""
    out = Path(folder) / SCENE_COPY
    out.parent.mkdir(parents=True, exist_ok=True)
    text = tomli_w.dumps(_plain(as_table(scene)))
    out.write_text(f"# the scene this run ran (from {scene.path}, overrides applied)\n{text}", encoding="utf-8")
    return out


def load_run_scene(folder) -> Scene:
    """The scene a run folder's run ran: its ``scene.toml``; for a folder written before runs kept
    it, the shipped scene of the summary's name. ConfigError naming the folder when neither."""
    folder = Path(folder)
    copy = folder / SCENE_COPY
    if copy.is_file():
        return load_scene(str(copy))
    log = folder / "log.npz"
    if log.is_file():
        with np.load(log) as z:
            name = json.loads(str(z["summary"]))["scenario"]
        if not (isinstance(name, str) and re.fullmatch(r"[A-Za-z0-9_-]{1,100}", name)):
            raise ConfigError(f"{log}: summary.scenario: {plain(str(name))!r} is not a scene name "
                              "(the shipped scenes' names only)")
        try:
            return load_scene(name)
        except ConfigError:
            pass
    raise ConfigError(f"{folder}: no {SCENE_COPY} (the scene the run ran); re-run with 'teleop run --out'")


def slave_robot_for(scene):
    """The slave arm's visual model, reduced exactly like the follower's model (fingers locked),
    so the view's joint vector is the arm's ``q``. None when the scene has no slave or a URDF arm."""
    if scene.slave is None or not isinstance(scene.slave.arm, str):
        return None
    import example_robot_data as erd
    import pinocchio as pin

    from teleop.slave.arm import ARMS

    robot = erd.load(ARMS[scene.slave.arm][0])
    full = robot.model
    lock = [j for j in range(1, full.njoints) if "finger" in full.names[j]]
    if not lock:
        return robot

    class Reduced:  # the two attributes the view reads
        pass

    r = Reduced()
    r.model, geoms = pin.buildReducedModel(full, [robot.visual_model], lock, pin.neutral(full))
    r.visual_model = geoms[0]
    return r


def viz_scene_for(scene, view: str = "perspective", follow: bool = True):
    """The VizScene of a run: the fixture as each side builds it (the master's in the master
    frame, the slave's in the patient frame; drawn from their constraints), the map between the
    two (the tissue is drawn on both sides), the tool shape the fixture implies, the arm, the
    tissue, the cobot device when it is the master; ``view`` one of teleop.viz.frames.VIEW_KINDS."""
    from dataclasses import asdict

    from teleop.viz import VizScene
    from teleop.viz.environment import tool_shape_for

    spec = master_fixture_spec(scene)
    custom = isinstance(spec, CustomFixture)
    params = {} if custom else {k: v for k, v in asdict(spec).items()
                                if k not in ("type", "euler_sequence", "knife_edge")}
    frame = master_frame(scene)
    master_fixture = scene.fixture.build(frame)
    slave_fixture = scene.fixture.build(None) if scene.slave is not None else None
    tissue = None
    if scene.tissue is not None or (scene.slave is not None and not custom):
        t = scene.tissue
        tissue = {
            "origin_m": list(t.origin_m if t is not None else scene.fixture.plane_origin_m),
            "normal": list(t.normal if t is not None else scene.fixture.plane_normal),
            "size_m": list(scene.viewer.tissue_size_m),
            "thickness_m": float(t.thickness_m if t is not None else 0.03),
        }
    radius = getattr(scene.viewer, "tool_radius_m", None)
    if radius is None and spec.type == "sphere":  # a small disk on a big sphere (Faulring et al. Ex. 2)
        radius = 0.2 * spec.radius_m
    return VizScene(
        fixture_type=spec.type, fixture_params=params,
        tool_shape=tool_shape_for(master_fixture.constraints, scene.slave is not None),
        slave_robot=slave_robot_for(scene), tissue=tissue, tool_radius_m=radius,
        master_robot=master_robot_for(scene), view=view, follow=follow,
        fixture_object=spec.params if custom else None, fixture_frame=frame if scene.slave is not None else None,
        master_fixture=master_fixture, slave_fixture=slave_fixture,
    )


def master_robot_for(scene):
    """The cobot's model and visual model from its URDF (Pinocchio), when the scene runs the cobot
    master; None for the ideal master."""
    if scene.master != "cobot":
        return None
    import pinocchio as pin

    from teleop.master.cobot.model import DEFAULT_URDF

    class Device:  # the two attributes the view reads
        pass

    d = Device()
    d.model, _, d.visual_model = pin.buildModelsFromUrdf(str(DEFAULT_URDF))
    return d


class RunView:
    """Adapter between the loop and a view: throttles by simulated time, builds VizFrames and keeps
    them (``save_frames``), so a replay draws what the live view drew."""

    def __init__(self, view, fps: float = 30.0):
        self.view, self.period, self.next_t = view, 1.0 / fps, 0.0
        self.trace: list = []  # the slave's blade tip at each frame (m, patient frame)
        self.frames: list = []  # the kwargs of every VizFrame published

    def publish_tick(self, t: float, loop) -> None:
        """A frame of the loop's state at simulated time t (s), at most ``fps`` a second."""
        if t + 1e-12 < self.next_t:
            return
        self.next_t = t + self.period
        from teleop.viz import VizFrame

        tool = loop.tool
        kw = dict(
            t=t, reference_pose=tool.pose(), virtual_pose=loop.master.virtual_pose(),
            operator_wrench=np.asarray(loop.hand_W, dtype=float), constraint_wrench=tool.constraint_wrench_W,
        )
        joints = loop.master.joints()
        if joints is not None:
            kw["master_q"] = np.asarray(joints, dtype=float).copy()
        slave = loop.slave
        if slave is not None and slave.state.ticks:
            self.trace.append(slave.state.tip.copy())
            kw.update(
                slave_q=slave.arm.q.copy(), slave_tool_pose=slave.arm.tool_pose(),
                contact_wrench=np.asarray(slave.state.contact_P, dtype=float).copy(), cut_trace=np.array(self.trace),
            )
        frame = VizFrame(**kw)
        self.frames.append({"t": frame.t, **{k: getattr(frame, k) for k in _FIELDS},
                            "cut_tip": self.trace[-1] if "cut_trace" in kw else None})
        self.view.publish(frame)

    def save_frames(self, folder) -> Path:
        """Write the published frames as ``folder/view_frames.npz`` (arrays per field, NaN where
        a frame lacked the field; the cut trace as each frame's newest tip)."""
        n = len(self.frames)
        cols: dict = {"t": np.array([f["t"] for f in self.frames], dtype=float)}
        for name in (*_FIELDS, "cut_tip"):
            vals = [_flat(f[name]) for f in self.frames]
            size = next((v.size for v in vals if v is not None), None)
            if size is None:
                continue
            a = np.full((n, size), np.nan)
            for i, v in enumerate(vals):
                if v is not None:
                    a[i] = v
            cols[name] = a
        out = Path(folder) / FRAMES_FILE
        out.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(out, **cols)
        return out


#: VizFrame fields kept by RunView.save_frames, poses flattened as p (3) + R (9)
_FIELDS = ("reference_pose", "virtual_pose", "slave_tool_pose", "operator_wrench", "constraint_wrench",
           "contact_wrench", "master_q", "slave_q")


def _flat(v):
    if v is None:
        return None
    if isinstance(v, tuple):
        return np.concatenate([np.ravel(v[0]), np.ravel(v[1])])
    return np.ravel(v)


def _frames_from_file(path: Path):
    """VizFrame kwargs from a view_frames.npz."""
    with np.load(path) as z:
        cols = {k: z[k] for k in z.files}
    trace: list = []
    for i, t in enumerate(cols["t"]):
        kw = {"t": float(t)}
        for name in _FIELDS:
            if name in cols and not np.isnan(cols[name][i]).any():
                v = cols[name][i]
                kw[name] = (v[:3], v[3:].reshape(3, 3)) if name.endswith("_pose") else v
        if "cut_tip" in cols and not np.isnan(cols["cut_tip"][i]).any():
            trace.append(cols["cut_tip"][i])
            kw["cut_trace"] = np.array(trace)
        yield kw


def _frames_from_log(log: dict, fps: float):
    """VizFrame kwargs from a run's log.npz (runs written before view_frames.npz: no slave tool
    pose or contact vector in the log, so the slave tool is placed by the arm's kinematics)."""
    t = log["t"]
    step = max(1, round((1.0 / fps) / max(t[1] - t[0], 1e-9))) if t.size > 1 else 1
    device = "master_q" in log and np.any(log["master_q"])
    for i in range(0, t.size, step):
        kw = dict(t=float(t[i]), reference_pose=(log["p_r"][i], log["R_r"][i]),
                  virtual_pose=(log["q_v_p"][i], log["R_v"][i]),
                  operator_wrench=log["operator_W"][i], constraint_wrench=log["constraint_W"][i])
        if device:
            kw["master_q"] = log["master_q"][i]
        if "slave_q" in log and i < len(log["slave_q"]):
            kw.update(slave_q=log["slave_q"][i], cut_trace=log["slave_tip"][: i + 1 : 20])
        yield kw


def replay_run(folder, view, fps: float = 30.0, realtime: bool = False) -> int:
    """Publish a run folder's frames to ``view`` (its view_frames.npz, else its log.npz), paced to
    the wall clock when ``realtime``; returns the number of frames."""
    from teleop.viz import VizFrame

    folder = Path(folder)
    if (folder / FRAMES_FILE).is_file():
        frames = _frames_from_file(folder / FRAMES_FILE)
    else:
        with np.load(folder / "log.npz") as z:
            log = {k: z[k] for k in z.files if k != "summary"}
        frames = _frames_from_log(log, fps)
    wall0, t0, count = time.perf_counter(), None, 0
    for kw in frames:
        t0 = kw["t"] if t0 is None else t0
        if realtime:
            time.sleep(max(0.0, wall0 + kw["t"] - t0 - time.perf_counter()))
        view.publish(VizFrame(**kw))
        count += 1
    return count
