"""One control tick and the loop: operator -> master -> reference tool -> metrics (-> slave later).

Simulated time by default: the loop advances ``dt_s`` per tick with no wall clock, so a run is a
pure function of its scene and seed. Every tick is timed (CPU ``perf_counter_ns``) for ``tick_us``.
The loop never raises mid-flight: a fault ends the run with a status and the tool in a safe state.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from teleop.scenario.build import build_tool, master_fixture_spec
from teleop.scenario.operators import make_operator
from teleop.scenario.metrics import make_metrics
from teleop.scenario.schema import Scene


@dataclass
class RunResult:
    """What a run produced: the JSON summary and the per-tick log arrays."""

    summary: dict
    log: dict = field(default_factory=dict)

    def write_json(self, path) -> None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(json.dumps(self.summary, indent=2, sort_keys=False) + "\n")

    def write_log(self, path) -> None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, **self.log, summary=json.dumps(self.summary))


class IdealMaster:
    """The operator's wrench goes straight to the reference tool; the virtual tool *is* the reference."""

    def __init__(self, tool, dt_s: float):
        self.tool, self.dt = tool, dt_s
        self.engaged = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        pass

    def set_clutch(self, engaged: bool) -> None:
        """Clutch out: the hand lets go of the tool (its wrench no longer reaches it)."""
        self.engaged = bool(engaged)

    def step(self, hand_wrench_W, contact_wrench_W=None) -> str:
        w = hand_wrench_W if self.engaged else np.zeros(6)
        w = w if contact_wrench_W is None else w + contact_wrench_W
        return self.tool.step(self.dt, w)

    def virtual_pose(self):
        return self.tool.pose()

    def virtual_twist(self):
        return self.tool.twist()

    def virtual_estimate(self):
        """The virtual tool for the slave (p, R, v, w): here the tool itself."""
        return (*self.tool.pose(), *self.tool.twist())

    hand_state = virtual_estimate  # what the operator's hand touches: the tool itself too

    def stats(self) -> dict:
        return {}


def _pace(deadline: float) -> int:
    """Wait for the wall-clock deadline (s, perf_counter): sleep, then spin the last 0.3 ms.
    Returns 1 when the tick is already late, else 0."""
    now = time.perf_counter()
    if now > deadline:
        return 1
    if deadline - now > 3e-4:
        time.sleep(deadline - now - 3e-4)
    while time.perf_counter() < deadline:
        pass
    return 0


def make_master(scene: Scene, tool, rng: np.random.Generator):
    if scene.master == "cobot":
        from teleop.master import CobotMaster

        cfg = scene.cobot
        # the device's effects follow the scene: what it does not name is not simulated
        if "can_faults" not in scene.effects:
            cfg = replace(cfg, faults=type(cfg.faults)())
        if "sensor_noise" not in scene.effects:
            cfg = replace(cfg, force_noise_N=0.0, torque_noise_Nm=0.0, force_bias_N=(0.0, 0.0, 0.0), torque_bias_Nm=(0.0, 0.0, 0.0))
        if "servo_lag" not in scene.effects:
            cfg = replace(cfg, servo_bandwidth_hz=1e4)  # a 16 us lag: nothing at a 1 kHz tick
        return CobotMaster(tool, cfg, scene.dt_s, rng)
    return IdealMaster(tool, scene.dt_s)


def run_scene(scene: Scene, progress=None, realtime: bool = False, operator=None, view=None) -> RunResult:
    """Run a scene. Simulated time by default; ``realtime`` paces each tick to the wall clock
    (late ticks are counted, never skipped). ``operator`` replaces the scene's (e.g. a keyboard);
    ``view`` gets a frame per tick and throttles itself. ``progress(i, n)`` is called now and then."""
    rng = np.random.default_rng(scene.seed)
    tool = build_tool(scene)
    if operator is None:
        operator = make_operator(scene.operator, master_fixture_spec(scene), scene.effects, rng)
    n = int(round(scene.duration_s / scene.dt_s))
    metrics = make_metrics(master_fixture_spec(scene), n, tool.body.mass_kg)
    log = {
        "t": np.zeros(n), "q_r": np.zeros((n, 6)), "q_v_p": np.zeros((n, 3)),
        "p_r": np.zeros((n, 3)), "R_r": np.zeros((n, 3, 3)), "R_v": np.zeros((n, 3, 3)),
        "lam": np.zeros((n, tool.model.m)), "operator_W": np.zeros((n, 6)),
        "master_q": np.zeros((n, 6)), "can_frames_lost": np.zeros(n, dtype=np.int64),
        "constraint_W": np.zeros((n, 6)), "tick_us": np.zeros(n),
    }
    slave = None
    if scene.slave is not None:
        from teleop.slave.side import SlaveSide

        slave = SlaveSide(scene, n)
        slave.reset(*tool.pose())
    tremor = None
    if slave is not None and getattr(operator, "tremor_on", False):
        from teleop.scenario.metrics import TremorProbe

        tremor = TremorProbe(operator, n, slave.reg.scale, slave.reg.X_PM_R, scene.fixture.plane_normal)
    contact = None
    status, steps, nan, late = "ok", 0, False, 0
    wall0 = time.perf_counter()
    with make_master(scene, tool, rng) as master:
        for i in range(n):
            t0 = time.perf_counter_ns()
            p_v, R_v = master.virtual_pose()  # what the encoders measure: the metrics
            v_v, w_v = master.virtual_twist()
            # the hand acts on the handle itself, not on the host's estimate of it
            wrench = operator.wrench(i * scene.dt_s, *master.hand_state())
            if hasattr(operator, "clutch_engaged"):  # the operator reads the clutch pedal too
                master.set_clutch(operator.clutch_engaged)
            st = master.step(wrench, contact)
            if slave is not None:
                contact = slave.step(*master.virtual_estimate())
                if tremor is not None:
                    tremor.update(i * scene.dt_s, R_v, slave.log["tip"][i])
            t1 = time.perf_counter_ns()
            nan = nan or not (np.all(np.isfinite(tool.q)) and np.all(np.isfinite(p_v)))
            # the tick's state, the wrench applied over it and the constraint force it produced
            constraint_W = tool.constraint_wrench_W  # G^T lam (N, N*m): computed on each read
            metrics.update(p_v, R_v, v_v, w_v, wrench, constraint_W)
            log["t"][i] = tool.t
            log["q_r"][i] = tool.q
            log["q_v_p"][i] = p_v
            log["R_v"][i] = R_v
            driver = getattr(master, "driver", None)
            if driver is not None:  # the cobot: its encoders and the bus's running loss count
                log["master_q"][i] = driver.joints_rad_m
                log["can_frames_lost"][i] = master.stats().get("can_frames_lost", 0)
            log["p_r"][i], log["R_r"][i] = tool.pose()
            log["lam"][i] = tool.lam
            log["operator_W"][i] = wrench
            log["constraint_W"][i] = constraint_W
            log["tick_us"][i] = (t1 - t0) * 1e-3
            steps = i + 1
            if view is not None:
                view.publish_tick(i * scene.dt_s, tool, master, wrench, slave)
            if getattr(operator, "stop", False):
                status = "stopped_by_operator"
                break
            if st != "ok":
                status = st
                break
            if progress is not None and i % 1000 == 0:
                progress(i, n)
            if realtime:
                late += _pace(wall0 + (i + 1) * scene.dt_s)
        stats = master.stats()
    log = {k: v[:steps] for k, v in log.items()}
    log.update({f"m_{k}": v for k, v in metrics.trimmed().items()})
    results = metrics.result()
    if slave is not None:
        log.update(slave.trimmed_log())
        results.update(slave.result())
    if tremor is not None:
        results.update(tremor.result(scene.dt_s))
    ticks = log["tick_us"]
    summary = {
        "scenario": scene.name,
        "status": status,
        "steps": steps,
        "dt_s": scene.dt_s,
        "duration_s": steps * scene.dt_s,
        "nan": bool(nan),
        "tick_us": {
            "median": float(np.median(ticks)) if steps else 0.0,
            "p99": float(np.percentile(ticks, 99)) if steps else 0.0,
        },
        "integrator": scene.integrator,
        "master": scene.master,
        "seed": scene.seed,
        "effects": list(scene.effects),
        "metrics": results,
        "engine": {"rank_min": int(tool.rank), "recharts": tool.recharts},
    }
    if slave is not None:
        summary["slave_statuses"] = slave.statuses
    if realtime:
        summary["late_ticks"] = late
    summary.update(stats)
    return RunResult(summary, log)
