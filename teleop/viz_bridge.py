"""From a run to the Meshcat views: build the view's scene from a Scene, and turn loop ticks (or a
recorded log) into frames. The loop calls :meth:`RunView.publish_tick` every tick; frames are
built only at ``fps`` of simulated time, so the 1 kHz loop pays nothing in between.
"""

from __future__ import annotations

import numpy as np

from teleop.scenario.build import master_fixture_spec


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


def viz_scene_for(scene):
    """The VizScene of a run: master fixture geometry (in the master frame), tool shape, arm, tissue."""
    from dataclasses import asdict

    from teleop.viz import VizScene

    spec = master_fixture_spec(scene)
    params = {k: v for k, v in asdict(spec).items() if k not in ("type", "euler_sequence", "knife_edge", "trocar_m")}
    shape = {"rolling_disk": "disk", "sphere": "disk", "scalpel": "scalpel"}.get(spec.type, "box")
    tissue = None
    if scene.tissue is not None or scene.slave is not None:
        t = scene.tissue
        tissue = {
            "origin_m": list(t.origin_m if t is not None else scene.fixture.plane_origin_m),
            "normal": list(t.normal if t is not None else scene.fixture.plane_normal),
            "size_m": list(scene.viewer.tissue_size_m),
            "thickness_m": float(t.thickness_m if t is not None else 0.03),
        }
    return VizScene(
        fixture_type=spec.type, fixture_params=params, tool_shape=shape,
        slave_robot=slave_robot_for(scene), tissue=tissue,
    )


class RunView:
    """Adapter between the loop and a view: throttles by simulated time and builds VizFrames."""

    def __init__(self, view, fps: float = 30.0):
        self.view, self.period, self.next_t = view, 1.0 / fps, 0.0
        self.trace: list = []  # the slave's blade tip at each frame (m, patient frame)

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
        slave = loop.slave
        if slave is not None and slave.state.ticks:
            self.trace.append(slave.state.tip.copy())
            kw.update(
                slave_q=slave.arm.q.copy(), slave_tool_pose=slave.arm.tool_pose(),
                contact_wrench=slave.state.contact_P, cut_trace=np.array(self.trace),
            )
        self.view.publish(VizFrame(**kw))


def replay_log(log: dict, view, fps: float = 30.0, realtime: bool = False) -> int:
    """Publish a recorded run (a loaded log.npz) frame by frame, paced to the wall clock when
    ``realtime``; returns the number of frames."""
    import time

    from teleop.viz import VizFrame

    wall0 = time.perf_counter()
    t = log["t"]
    if t.size == 0:
        return 0
    step = max(1, int(round((1.0 / fps) / max(t[1] - t[0], 1e-9)))) if t.size > 1 else 1
    frames = 0
    for i in range(0, t.size, step):
        kw = dict(t=float(t[i]), reference_pose=(log["p_r"][i], log["R_r"][i]),
                  virtual_pose=(log["q_v_p"][i], log["R_v"][i]),
                  operator_wrench=log["operator_W"][i], constraint_wrench=log["constraint_W"][i])
        if "slave_q" in log:
            kw.update(slave_q=log["slave_q"][i], cut_trace=log["slave_tip"][: i + 1 : 20])
        if realtime:
            time.sleep(max(0.0, wall0 + float(t[i] - t[0]) - time.perf_counter()))
        view.publish(VizFrame(**kw))
        frames += 1
    return frames
