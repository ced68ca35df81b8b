"""Master tick benchmark: driver decode + engine step + controller + encode, per 1 kHz cycle,
WITHOUT the device simulation (its frames are pre-recorded from a lockstep run and replayed).
A tick is the master side of the bilateral period, as every run ticks it (``MasterSide.tick``:
the hand, ``sense``, the reference tool's step, ``command``).

    python tools/master_bench.py [--steps N]

The per-phase split (µs per cycle, medians) times the driver's ``read`` (drain + decode +
checks: ``decode``), the reference tool's ``step`` (``engine``) and the driver's sends (SYNC, the
heartbeat when due, the command: encode, seal and send, ``encode_send``); ``controller`` is the
rest of the cycle (pose, Jacobian,
load-cell compensation, PID, DLS, prediction). The phase timers add about 0.1 µs each.

The machine may be shared and noisy, so the ticks are timed in blocks interleaved with the
yardstick of tools/bench.py (one ``pinocchio.aba`` of the Panda, ``pin_aba_us``) and the tick is also
given as a multiple of it (``tick_over_aba``). The replay plays the recording forwards then
backwards, so the joints never jump: the driver's encoder-jump check stays on (a jump would latch
``encoder_fault`` and time the cheap fault path; the status printed must be "ok").
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import uuid
from collections import defaultdict
from pathlib import Path

import can
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

PHASES = ("decode", "engine", "controller", "encode_send")


def _side(m, tool):
    """The master side every run ticks (teleop.tick.master_side), driven with a set wrench."""
    from teleop.tick.master_side import MasterSide, SetWrench

    return MasterSide(tool, m, SetWrench(), m.dt_s)


def _tick(side, hand) -> str:
    """hand -> sense -> tool step -> command: one MasterSide.tick."""
    side.operator.W = hand
    return side.tick(0, side.tool.t)


def _disk_tool():
    from teleop.dynamics import fixtures
    from teleop.dynamics.body import RigidBody
    from teleop.dynamics.effects import AngularDamper, LinearDamper
    from teleop.dynamics.tool import ReferenceTool

    tool = ReferenceTool(RigidBody(0.25, [0.0025] * 3), fixtures.rolling_disk(0.03),
                         [LinearDamper(1.0), AngularDamper(0.1)], integrator="parametric")
    tool.reset([0, 0, 0.03, 0, np.pi / 2, 0])
    return tool


def _record_feedback(n: int):
    """Device frames (joints, wrench) of a lockstep run, one pair per cycle."""
    from teleop.master import CobotConfig, CobotMaster

    tool = _disk_tool()
    m = CobotMaster(CobotConfig.from_dict({}, "bench"), 1e-3, np.random.default_rng(0), *tool.pose(), tool.body.mass_kg)
    frames = []
    side = _side(m, tool)
    with m:
        for i in range(n):
            _tick(side, np.array([3.0 * np.cos(i * 1e-3), 0.5, 0, 0, 0, 0.02]))
            frames.append((m.driver.joints_rad_m.copy(), m.driver.wrench_S.copy()))
    return m, frames


class PhaseClock:
    """Accumulates the time (ns) spent in wrapped callables, per phase, within one cycle."""

    def __init__(self):
        self.ns = defaultdict(int)

    def wrap(self, fn, phase: str):
        def timed(*args, **kw):
            t0 = time.perf_counter_ns()
            try:
                return fn(*args, **kw)
            finally:
                self.ns[phase] += time.perf_counter_ns() - t0
        return timed

    def take(self) -> dict:
        out, self.ns = dict(self.ns), defaultdict(int)
        return out


def _stats(samples_us) -> dict:
    return {"median": round(float(np.median(samples_us)), 1), "p99": round(float(np.percentile(samples_us, 99)), 1)}


def _replay_index(i: int, n: int) -> int:
    """Frame i of a replay of n frames played forwards, backwards, forwards...: no jump anywhere."""
    i %= 2 * n - 2
    return i if i < n else 2 * n - 2 - i


def _in_range(db, name: str, values) -> list:
    """``values`` clipped to the DBC ranges of ``name``'s first signals (what the device sends)."""
    sigs = db.codecs[name].signals
    return [min(max(v, s.minimum), s.maximum) for v, s in zip(values, sigs)]


def measure(n_steps: int = 5000, yard=None) -> dict:
    """{"master_tick_us": {"median", "p99"}, "phases_us": {phase: {"median", "p99"}},
    "pin_aba_us", "tick_over_aba"}: one host cycle (decode 2 frames, engine step, PID, Jacobian +
    DLS, encode and send SYNC and the command) on a virtual bus with no simulator, in blocks
    interleaved with ``yard`` (a tools/bench.py Yardstick; None: a new one)."""
    from bench import Yardstick

    from teleop.master import CobotConfig, CobotMaster
    from teleop.master.cobot.database import FrameDatabase

    yard = yard or Yardstick()
    n_aba = len(yard.samples)
    ref, frames = _record_feedback(min(n_steps, 2000))
    db = FrameDatabase()
    # the replayed frames do not follow this host's commands (open loop), so the reference tool
    # drifts away from them: the tracking fault would latch and leave only the cheap fault path
    open_loop = {"tracking_fault_m": 100.0, "tracking_fault_rad": 100.0}
    tool = _disk_tool()
    m = CobotMaster(CobotConfig.from_dict(open_loop, "bench"), 1e-3, np.random.default_rng(0), *tool.pose(),
                    tool.body.mass_kg)
    m.sim.close()
    m.sim = None  # the host alone: the feedback comes from the replay bus below
    m.bias_S, m.driver.joints_rad_m = ref.bias_S, frames[0][0].copy()
    m.driver.start(m.joints0)
    m.pred_p[:], m.pred_R[:] = m.p_H_est, m.R_H_est
    ch = f"bench-{uuid.uuid4().hex}"
    m.driver.bus.shutdown()
    m.driver.bus = can.Bus(interface=m.cfg.interface, channel=ch, fd=True, preserve_timestamps=True)
    replay = can.Bus(interface=m.cfg.interface, channel=ch, fd=True, preserve_timestamps=True)
    clock = PhaseClock()
    m.driver.read = clock.wrap(m.driver.read, "decode")
    m.driver.send_sync = clock.wrap(m.driver.send_sync, "encode_send")
    m.driver.send_heartbeat = clock.wrap(m.driver.send_heartbeat, "encode_send")
    m.driver.send_command = clock.wrap(m.driver.send_command, "encode_send")
    tool.step = clock.wrap(tool.step, "engine")
    side = _side(m, tool)
    samples = np.empty(n_steps)
    phases = {p: np.empty(n_steps) for p in PHASES}
    wrench_in = np.array([1.0, 0.2, 0, 0, 0, 0.01])
    payloads = []  # the device's two frames per recorded cycle, but for the counter (and the CRC over its count)
    for joints, wrench in frames:
        wrapped = np.r_[joints[:3], (joints[3:] + np.pi) % (2 * np.pi) - np.pi]  # the wire's angles
        payloads.append((("DEV_JOINTS", [*_in_range(db, "DEV_JOINTS", wrapped.tolist()), 2]),
                         ("DEV_WRENCH", _in_range(db, "DEV_WRENCH", wrench.tolist()))))
    for i in range(n_steps):
        if i % 500 == 0:
            yard.block(100)
        count = m.driver._sync  # the SYNC this tick sends: the device's answer carries its low byte, its CRC the count
        for name, values in payloads[_replay_index(i, len(payloads))]:
            fid, data, fd = db.encode_ordered(name, (*values, count % 256), count)
            replay.send(can.Message(arbitration_id=fid, data=data, is_fd=fd, is_extended_id=False))
        clock.take()
        t0 = time.perf_counter_ns()
        _tick(side, wrench_in)  # SYNC + read/decode + engine + controller + command encode/send
        total = time.perf_counter_ns() - t0
        split = clock.take()
        samples[i] = total * 1e-3
        for p in ("decode", "engine", "encode_send"):
            phases[p][i] = split.get(p, 0) * 1e-3
        phases["controller"][i] = samples[i] - sum(phases[p][i] for p in ("decode", "engine", "encode_send"))
        while replay.recv(timeout=0.0) is not None:  # drain the host's frames (not timed)
            pass
        m.driver.last_device_hb_s = m.t
    replay.shutdown()
    m.close()
    aba = _stats(np.asarray(yard.samples[n_aba:]) * 1e-3)
    tick = _stats(samples)
    return {"master_tick_us": tick, "pin_aba_us": aba, "tick_over_aba": round(tick["median"] / aba["median"], 1),
            "interface": m.cfg.interface, "phases_us": {p: _stats(phases[p]) for p in PHASES},
            "status": m.status, "steps": n_steps, "can_rejected_by_reason": m.driver.stats()["can_rejected_by_reason"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=5000)
    print(json.dumps(measure(ap.parse_args().steps), indent=2))


if __name__ == "__main__":
    main()
