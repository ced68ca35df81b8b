"""Master and slave as two processes over Eclipse Zenoh, on the wall clock at the scene's rate.

    teleop slave SCENE --listen tcp/127.0.0.1:7447 [--json OUT]
    teleop master SCENE --connect tcp/127.0.0.1:7447 [--json OUT]
    teleop run SCENE --link zenoh [--json OUT]      # both on a free loopback port, one summary

Each process runs its half of :class:`teleop.tick.loop.BilateralLoop`'s tick (the same calls in the
same order) and the two halves meet only in :class:`~teleop.link.zenoh_link.ZenohLink`. The
passivity guard of the scene's [link] table runs at both ends, as in the simulated run.

Start-up: each side first runs a twin of its half for a few ticks on a link to nowhere (the
numba kernels' first loads, not the first ticks). The master sends hello commands (``t_s = -1``,
clutch out) until a reply comes; the slave answers every hello. The master then ticks
``duration_s / dt_s`` times on the wall clock; the slave ticks when the master's next command
arrives (or one period past its own nominal tick start if none comes; when behind, back to back),
until it has followed the master's last command (or, if the master is gone, for as long again plus
``GRACE_S``). The master feels the newest reply at the start of its tick: a reply back within the
period is felt at the same step as in one process (``reply_lag_ticks`` 0). Each side is pinned to
a core of its own and waits by spinning (:func:`claim_core`; ``--no-pin``: sleep instead).

Heartbeat and safe states: :mod:`teleop.tick.heartbeat`, the same as the in-process run's (a side
that has heard nothing for ``link.heartbeat_ms``, 20 ms by default, goes to its safe state at once;
the master also while the slave's replies say ``link_lost``), on the wall clock here. Each side
counts lost-link events, lost ticks and the detection latency (time from the last message heard to
the safe state, s) in its summary; a run with any lost tick is ``link_lost``, not "ok".
"""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from teleop.tick.feedback import FeedbackPath
from teleop.dynamics.constraints import RemoteCenter
from teleop.util.errors import TeleopError
from teleop.tick.heartbeat import HeartbeatState, follow_or_hold, hold_master
from teleop.tick.messages import ContactFeedback, MessageError, ToolCommand
from teleop.app.runtime import make_guard, make_master, make_slave
from teleop.scenario.build import build_fixture, build_registration, build_tool, master_fixture_spec
from teleop.app.metrics import MasterMetrics, SlaveMetrics, make_metrics
from teleop.scenario.operators import make_operator
from teleop.app.session import (_YIELD, PACE_SPIN_S, GuardRecorder, MasterRecorder, SlaveCounter, _fine_timer_slack, _pace,
                            run_status)

GRACE_S = 2.0          # the slave's run beyond the scene's duration when the master is gone (s)
CONNECT_TIMEOUT_S = 120.0  # the first message must come within this (s): a loaded machine is slow
_Z6 = np.zeros(6)
_Z3 = np.zeros(3)


class MasterHalf:
    """The master's half of the tick (the slave's newest reply felt, operator, sense, tool step,
    command, send), with the safe state on a lost link. Attributes as :class:`BilateralLoop` for
    the hooks.

    The reply is felt at the start of the tick, before the step: the reply to the command sent at
    the end of the tick before, when the slave answered within the period, is then felt at the same
    step as in one process (where it is felt at the end of the tick before); ``reply_lag`` counts
    the ticks by how many ticks older the newest reply was (0: in step with one process; "none":
    no new reply)."""

    def __init__(self, tool, master, operator, dt_s, link, feedback, guard, hooks, heartbeat_s):
        self.tool, self.master, self.operator, self.dt = tool, master, operator, dt_s
        self.link, self.feedback, self.master_guard, self.hooks = link, feedback, guard, hooks
        self.slave = self.slave_guard = None
        self.heart = HeartbeatState(heartbeat_s)
        self.peer_lost = False  # the newest reply says the slave hears nothing
        self.hand_W, self.feedback_W, self.felt_W = np.zeros(6), np.zeros(6), np.zeros(6)
        self.tick_ns, self.status, self.command_errors = 0, "ok", 0
        self.slave_status: dict[str, int] = {}
        self.reply_lag: dict = {}  # ticks whose newest reply answered the command of k ticks before the last

    def tick(self, i: int) -> str:
        t, master, tool = i * self.dt, self.master, self.tool
        for h in self.hooks:
            h.before_tick(i, t, self)
        t0 = time.perf_counter_ns()
        msg = self.link.receive_feedback(t)  # the reply to the last command, if it is back
        if msg is not None and msg.t_s >= 0:
            self.slave_status[msg.status] = self.slave_status.get(msg.status, 0) + 1
            self.peer_lost = msg.status == "link_lost"
        lag = "none" if msg is None or msg.command_seq < 0 else min(i - msg.command_seq, 5)
        self.reply_lag[lag] = self.reply_lag.get(lag, 0) + 1
        lost = self.heart.update(self.link.clock(), self.link.last_receive_s, self.peer_lost)
        if not lost and i > 0:  # felt before the step, as one process feels it at the end of the tick before
            self.feedback_W = self.feedback.update(msg)
            if self.master_guard is not None:
                self.feedback_W = self.master_guard.feedback(self.feedback_W, np.concatenate(tool.twist()), msg,
                                                             t - self.dt)
        self.hand_W = self.operator.wrench(t, *master.hand_state())
        master.set_clutch(self.operator.clutch_engaged)
        f_v = master.sense(self.hand_W)
        p_r, R_r = tool.pose()
        if lost:                                   # safe state: the tool holds, no remote force
            st, st_m = "ok", hold_master(tool, master, self.feedback, p_r, R_r, self.master_guard)
            self.feedback_W = self.felt_W = np.zeros(6)
        else:
            v_r, w_r = tool.twist()
            self.felt_W = self.feedback.render(self.feedback_W, tool, f_v, self.dt, (p_r, R_r, v_r, w_r))
            st = tool.step(self.dt, f_v + self.felt_W)
            st_m = master.command(p_r, R_r, np.concatenate((v_r, w_r)), tool.acceleration_W)
        mg = self.master_guard
        energy = None if mg is None else mg.energy_J if lost else mg.energy_after(np.concatenate(tool.twist()))
        try:  # sent even when lost: the heartbeat the slave listens for
            self.link.send_command(ToolCommand(i + 1, t, *master.virtual_estimate(),
                                               self.operator.clutch_engaged and not lost, energy))
        except MessageError:
            self.command_errors += 1
        self.tick_ns = time.perf_counter_ns() - t0
        self.heart.motion(tool.pose()[0], float(np.linalg.norm(tool.qd)))
        for h in self.hooks:
            h.after_tick(i, t, self)
        self.status = st if st != "ok" else st_m
        return self.status


class SlaveHalf:
    """The slave's half of the tick (receive, guard, follow, reply), with the safe state."""

    def __init__(self, slave, link, guard, hooks, heartbeat_s, dt_s):
        self.slave, self.link, self.slave_guard, self.hooks = slave, link, guard, hooks
        self.master_guard = None
        self.heart = HeartbeatState(heartbeat_s)
        self.dt, self.tick_ns, self.last_seq = dt_s, 0, 0
        self.without_command = self.skipped = 0  # ticks with no new command; commands never followed
        self.pending = None  # the first command, taken while answering hellos

    def tick(self, i: int) -> None:
        t = i * self.dt
        t0 = time.perf_counter_ns()
        lost = self.heart.update(self.link.clock(), self.link.last_receive_s)
        cmd = self.link.receive_command(t)
        if cmd is None and self.pending is not None:
            cmd = self.pending
        self.pending = None
        if cmd is not None and cmd.t_s < 0:
            cmd = None  # a hello
        if cmd is not None and not lost:
            self.skipped += max(0, cmd.seq - self.last_seq - 1)
            self.last_seq = cmd.seq
        self.without_command += cmd is None
        reply = follow_or_hold(self.slave, self.slave_guard, cmd, t, lost)  # lost: hold, say link_lost
        self.link.send_feedback(reply)
        self.tick_ns = time.perf_counter_ns() - t0
        self.heart.motion(self.slave.state.p, float(np.linalg.norm(self.slave.arm.qd)))
        for h in self.hooks:
            h.after_tick(i, t, self)


POLL_S = 1e-4  # the slave's poll period while it waits for the master's next command, unpinned (s)


def claim_core(role: str) -> int | None:
    """Pin this process to one core of those it may run on, the master to the first, the slave to
    the second, so the two halves never share one (the threads started afterwards, Zenoh's,
    inherit it; no root needed). Returns the core, or None (nothing done) with fewer than two.
    A pinned half waits by spinning, not sleeping: a sleeping half's core goes to other jobs,
    whose caches it then ticks in (measured on this 2-core machine under load: each tick's CPU
    time doubled and the halves fell to 0.4-0.7 of real time; pinned and spinning, both held it)."""
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) < 2:
        return None
    core = cores[0 if role == "master" else 1]
    os.sched_setaffinity(0, {core})
    return core


def _await_command(link, timeout: float, poll_s: float = POLL_S) -> None:
    """Slave: wait until a command newer than the last one taken has come, or the wall clock
    (perf_counter, s) reaches ``timeout``, polling every ``poll_s`` (0: without sleeping). The
    slave ticks when the master's command arrives, so its reply is back before the master's next
    tick (one process's timing); the timeout, one period after the tick's nominal start, keeps it
    ticking (and its heartbeat checked) when no command comes; a slave behind its clock does not
    wait (it replays the ticks it owes, as before)."""
    while link.peek() is None:
        left = timeout - time.perf_counter()
        if left <= 0:
            return
        if poll_s > 0:
            time.sleep(min(left, poll_s))
        elif _YIELD:
            os.sched_yield()


def _open_link(role: str, session: str, listen, connect, timeout_s: float, config_json5=None):
    from teleop.link.zenoh_link import LinkError, ZenohLink

    end = time.monotonic() + timeout_s
    while True:
        try:
            return ZenohLink(role, session=session, listen=listen, connect=connect, config_json5=config_json5)
        except LinkError:
            if time.monotonic() > end:
                raise
            time.sleep(0.2)


def _hello(master, link, timeout_s: float) -> None:
    """Master: hello commands until the slave answers."""
    end = time.monotonic() + timeout_s
    p, R, _, _ = master.virtual_estimate()
    while link.last_receive_s is None:
        if time.monotonic() > end:
            raise TeleopError(f"master: no answer from the slave within {timeout_s:g} s "
                              f"(is 'teleop slave' running on {link.connect}?)")
        link.send_command(ToolCommand(0, -1.0, p, R, _Z3, _Z3, False))
        time.sleep(0.005)


class _Bench:
    """A link that goes nowhere, for a half's warm-up twin: sends nothing, hears nothing, and to
    a slave hands a command holding ``pose`` (master frame) with the clutch engaged."""

    def __init__(self, pose=None):
        self.pose, self.last_receive_s, self.k = pose, None, 0

    def clock(self) -> float:
        return time.monotonic()

    def send_command(self, msg) -> None:
        pass

    send_feedback = send_command

    def receive_feedback(self, t_s: float = 0.0):
        return None

    def receive_command(self, t_s: float = 0.0):
        self.k += 1
        return ToolCommand(self.k, t_s, *self.pose, _Z3, _Z3, True)


WARMUP_TICKS = 5  # ticks a half's twin runs before the clock starts


def _master_half(scene, link, n: int):
    """The master's half and its hooks, built from the scene (the run's, or a warm-up twin's);
    returns (half, recorder, metrics, guard_log or None)."""
    rng = np.random.default_rng(scene.seed)
    tool = build_tool(scene)
    spec_M = master_fixture_spec(scene)
    operator = make_operator(scene.operator, spec_M, scene.effects, rng)
    reg = build_registration(scene)
    feedback = FeedbackPath(reg, scene.mapping.feedback_cutoff_hz, scene.dt_s,
                            scene.mapping.feedback_local_damping)
    guard = make_guard(scene, reg, n, networked=True)
    metrics = MasterMetrics(make_metrics(spec_M, n, tool.body.mass_kg))
    recorder = MasterRecorder(tool, n)
    glog = _GuardLog(n, 0) if guard else None
    hooks = [recorder, metrics] + ([glog] if glog else [])
    master = make_master(scene, tool, rng)
    half = MasterHalf(tool, master, operator, scene.dt_s, link, feedback, guard[0] if guard else None, hooks,
                      scene.link.heartbeat_ms * 1e-3)
    return half, recorder, metrics, glog


def warm_up_master(scene) -> None:
    """Run a twin of the master's half for a few ticks on a link to nowhere, so that the first
    calls (numba kernels loaded from the cache, 60-170 ms each here) happen before the clock
    starts and not in the first ticks, where they tripped the 20 ms heartbeat."""
    half = _master_half(scene, _Bench(), WARMUP_TICKS)[0]
    with half.master:
        for i in range(WARMUP_TICKS):
            half.tick(i)


def run_master(scene, connect: str | None, listen: str | None = None, session: str = "default",
               timeout_s: float = CONNECT_TIMEOUT_S, config_json5: dict | None = None, pin: bool = True) -> dict:
    """The master process: returns its summary (also the master's metrics). ``config_json5``:
    extra Zenoh settings (TLS, see :mod:`teleop.link.zenoh_link`); ``pin``: :func:`claim_core`."""
    n = int(round(scene.duration_s / scene.dt_s))
    core = claim_core("master") if pin else None
    spin_s = math.inf if core is not None else PACE_SPIN_S
    warm_up_master(scene)
    link = _open_link("master", session, listen, connect, timeout_s, config_json5)
    half, recorder, metrics, glog = _master_half(scene, link, n)
    master = half.master
    status, late = "ok", 0
    with link, master:
        _hello(master, link, timeout_s)
        print("master: running", flush=True)
        wall0, behind = time.perf_counter(), 0.0
        for i in range(n):
            half.heart.tick_late_s = max(0.0, time.perf_counter() - (wall0 + i * scene.dt_s))
            behind = max(behind, half.heart.tick_late_s)
            status = half.tick(i)
            if status != "ok":
                break
            late += _pace(wall0 + (i + 1) * scene.dt_s, spin_s)
        clock = _clock(wall0, recorder.n, scene.dt_s, behind, core)
        link_stats = link.stats()
    ticks = recorder.log["tick_us"][: recorder.n]
    heart = half.heart.summary()
    out = {"side": "master", "status": status if status != "ok" else ("link_lost" if heart["lost_ticks"] else "ok"),
           "steps": recorder.n, "late_ticks": late, "clock": clock, "nan": bool(recorder.nan),
           "tick_us": {"median": float(np.median(ticks)) if len(ticks) else 0.0,
                       "p99": float(np.percentile(ticks, 99)) if len(ticks) else 0.0},
           "heartbeat": heart, "zenoh": link_stats, "slave_statuses_heard": half.slave_status,
           "reply_lag_ticks": {str(k): v for k, v in sorted(half.reply_lag.items(), key=str)},
           "command_errors": half.command_errors, "feedback_damping_refused": half.feedback.refused,
           "metrics": metrics.result()}
    if glog:
        out["passivity_master"] = glog.summary()
    return out


def _slave_half(scene, link, cap: int):
    """The slave's half and its hooks, built from the scene (the run's, or a warm-up twin's);
    returns (half, metrics, counter, guard_log or None, the tool's start pose)."""
    tool = build_tool(scene)  # only for the initial pose, as in the simulated run
    reg = build_registration(scene)
    constraints_P = build_fixture(scene.fixture).constraints
    slave = make_slave(scene, reg, constraints_P)
    slave.reset(*tool.pose())
    guard = make_guard(scene, reg, cap, networked=True)
    rcm = [c for c in constraints_P if isinstance(c, RemoteCenter)]
    metrics, counter = SlaveMetrics(scene.fixture, cap, slave.arm.nv, rcm), SlaveCounter()
    glog = _GuardLog(cap, 1) if guard else None
    hooks = [metrics, counter] + ([glog] if glog else [])
    half = SlaveHalf(slave, link, guard[1] if guard else None, hooks, scene.link.heartbeat_ms * 1e-3, scene.dt_s)
    return half, metrics, counter, glog, tool.pose()


def warm_up_slave(scene) -> None:
    """Run a twin of the slave's half for a few ticks, following a command that holds the start
    pose (see :func:`warm_up_master`; here the fixture projection's kernels, 165 ms)."""
    bench = _Bench()
    half, _, _, _, pose = _slave_half(scene, bench, WARMUP_TICKS)
    bench.pose = pose
    for i in range(WARMUP_TICKS):
        half.tick(i)


def run_slave(scene, listen: str | None, connect: str | None = None, session: str = "default",
              timeout_s: float = CONNECT_TIMEOUT_S, config_json5: dict | None = None, pin: bool = True) -> dict:
    """The slave process: returns its summary (the slave's metrics); ``pin``: :func:`claim_core`."""
    if scene.slave is None:
        raise TeleopError(f"{scene.path}: slave: the scene has no [slave] table: nothing to run on this side")
    core = claim_core("slave") if pin else None
    poll_s = 0.0 if core is not None else POLL_S
    n = int(round(scene.duration_s / scene.dt_s))
    cap = n + int(round(GRACE_S / scene.dt_s)) + 1
    warm_up_slave(scene)
    link = _open_link("slave", session, listen, connect, timeout_s, config_json5)
    half, metrics, counter, glog, _ = _slave_half(scene, link, cap)
    late = steps = 0
    tick_ns = []
    with link:
        end = time.monotonic() + timeout_s
        while half.pending is None:  # answer hellos until the first real command
            if time.monotonic() > end:
                raise TeleopError(f"slave: no command from a master within {timeout_s:g} s")
            cmd = link.receive_command(0.0)
            if cmd is not None and cmd.t_s >= 0:
                half.pending = cmd
                print("slave: running", flush=True)
                break
            if link.last_receive_s is not None:
                link.send_feedback(ContactFeedback(0, -1.0, _Z6, "hold", -1))
            time.sleep(0.001)
        _fine_timer_slack()
        wall0, behind = time.perf_counter(), 0.0
        for i in range(cap):
            half.heart.tick_late_s = max(0.0, time.perf_counter() - (wall0 + i * scene.dt_s))
            behind = max(behind, half.heart.tick_late_s)
            late += half.heart.tick_late_s > scene.dt_s  # past its timeout: a tick owed, run back to back
            half.tick(i)
            tick_ns.append(half.tick_ns)
            steps = i + 1
            if half.last_seq >= n:
                break
            _await_command(link, wall0 + (i + 2) * scene.dt_s, poll_s)
        clock = _clock(wall0, steps, scene.dt_s, behind, core)
        link_stats = link.stats()
    heart = half.heart.summary()
    counts = counter.counts
    status = run_status("ok", steps, counts)
    if heart["lost_ticks"] and status in ("ok", "slave_link_lost", "slave_hold"):
        status = "link_lost"  # this side's own word for it (the lost ticks were counted as such)
    out = {"side": "slave", "status": status, "steps": steps, "late_ticks": late, "clock": clock,
           "followed_last_command": half.last_seq >= n, "slave_statuses": counts, "heartbeat": heart,
           "ticks_without_command": half.without_command, "commands_skipped": half.skipped,
           "zenoh": link_stats, "tick_us": {"median": float(np.median(tick_ns)) * 1e-3 if tick_ns else 0.0,
                                           "p99": float(np.percentile(tick_ns, 99)) * 1e-3 if tick_ns else 0.0},
           "metrics": metrics.result()}
    if glog:
        out["passivity_slave"] = glog.summary()
    return out


def _clock(wall0: float, steps: int, dt_s: float, behind_s: float, core: int | None = None) -> dict:
    """How the wall clock kept up: ``wall_s`` the tick loop took (s), ``realtime_factor`` the
    simulated time over it (1: real time), ``behind_max_ms`` the furthest a tick started behind
    its deadline (ms; once behind, the ticks run back to back until caught up, so late_ticks
    counts every one of those), ``load_1min`` the machine's load average at the end (the other
    jobs' share of the cores: on 2 cores, a load of 4 leaves each process about half a core),
    ``core`` the core the side was pinned to (None: not pinned)."""
    wall = time.perf_counter() - wall0
    return {"wall_s": wall, "realtime_factor": steps * dt_s / wall if wall > 0 else 0.0,
            "behind_max_ms": behind_s * 1e3, "load_1min": os.getloadavg()[0], "core": core}


class _GuardLog:
    """One port's totals in a two-process run (the port's own log)."""

    def __init__(self, n: int, side: int):
        self.side, self.rec = side, GuardRecorder(n)

    def before_tick(self, i, t_s, loop) -> None:
        pass

    def after_tick(self, i, t_s, loop) -> None:
        g = loop.master_guard if self.side == 0 else loop.slave_guard
        key = "master" if self.side == 0 else "slave"
        log = self.rec.log
        log[f"tdpa_W_{key}_J"][i], log[f"tdpa_diss_{key}_J"][i] = g.port.W, g.port.E_diss
        if self.side == 1:
            log["tdpa_drift_M"][i] = g.port.offset
        else:
            log["tdpa_alpha"][i] = g.port.action
        self.rec.n = i + 1

    def summary(self) -> dict:
        key = "master" if self.side == 0 else "slave"
        s = self.rec.summary()
        return {k: v for k, v in s.items() if key in k or (self.side == 1 and k.startswith("drift"))}


def free_endpoint() -> str:
    """A free TCP port on loopback, as a Zenoh endpoint."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def run_pair(scene_arg: str, sets=(), timeout_s: float = CONNECT_TIMEOUT_S + 60.0) -> dict:
    """``teleop run --link zenoh``: the slave and the master as two child processes on a free
    loopback port; their two summaries merged into one."""
    ep = free_endpoint()
    extra = [a for s in sets for a in ("--set", s)]
    with tempfile.TemporaryDirectory() as tmp:
        js, jm = Path(tmp) / "slave.json", Path(tmp) / "master.json"
        py = [sys.executable, "-m", "teleop"]
        env = dict(os.environ)
        slave = subprocess.Popen(py + ["slave", scene_arg, "--listen", ep, "--json", str(js)] + extra, env=env)
        master = subprocess.Popen(py + ["master", scene_arg, "--connect", ep, "--json", str(jm)] + extra, env=env)
        try:
            rc_m = master.wait(timeout=timeout_s)
            rc_s = slave.wait(timeout=timeout_s)
        finally:
            for p in (master, slave):
                if p.poll() is None:
                    p.kill()
                    p.wait()
        sides = {}
        for name, path, rc in (("master", jm, rc_m), ("slave", js, rc_s)):
            if not path.exists():
                raise TeleopError(f"teleop run --link zenoh: the {name} process wrote no summary (exit {rc})")
            sides[name] = json.loads(path.read_text())
    return merge_summaries(sides["master"], sides["slave"], ep)


def merge_summaries(m: dict, s: dict, endpoint: str) -> dict:
    """One run summary from the two sides' (status "ok" only when both are)."""
    status = m["status"] if m["status"] != "ok" else (s["status"] if s["status"] != "ok" else "ok")
    if status == "ok" and not s.get("followed_last_command", False):
        status = "link_lost"
    return {"status": status, "link": "zenoh", "endpoint": endpoint, "nan": m["nan"],
            "metrics": {**m["metrics"], **s["metrics"]}, "master": m, "slave": s}
