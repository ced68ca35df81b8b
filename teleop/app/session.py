"""A teleoperation session: the bilateral loop run for a duration, recorded and summarised.

    session = Session(tool, master, operator, dt_s=1e-3, duration_s=2.0)   # + slave, link, hooks
    result = session.run()            # RunResult: .summary (JSON-able dict), .log (arrays)

Simulated time by default: the loop advances ``dt_s`` a tick with no wall clock, so a run is a
pure function of its inputs and seed. ``realtime`` paces each tick to the wall clock from the end
of the first (which may compile kernels); late ticks are counted (``late_ticks``), never skipped.
The run ends at the duration, on the first master-side status that is not "ok", or when the
operator sets ``stop``.

The run's ``status`` covers both sides (:func:`run_status`): the master side's fault if one ended
the run; otherwise the worst slave status seen, when it is one of :data:`SLAVE_FAULTS`; otherwise
"ok". A run of zero ticks is "no_ticks".
"""

from __future__ import annotations

import ctypes
import json
import logging
import os
import signal
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from teleop.util.errors import ConfigError
from teleop.tick.loop import BilateralLoop, Hook

log = logging.getLogger(__name__)

#: the longest run, ticks: its log (about 0.5 kB a tick) stays under about 1 GB
MAX_TICKS = 2_000_000
#: ticks of log reserved at first and added each time it fills (the log grows, never preallocated)
LOG_CHUNK = 16_384
#: --realtime: warn when the loop falls this far behind the wall clock, s (then once a second)
LAG_WARN_S = 0.05


def tick_count(duration_s: float, dt_s: float, where: str = "duration_s") -> int:
    """The ticks of a run (duration / dt rounded); ConfigError naming ``where`` past MAX_TICKS."""
    n = round(duration_s / dt_s)
    if n > MAX_TICKS:
        raise ConfigError(f"{where}: {duration_s:g} s at dt {dt_s:g} s is {n:.3g} ticks; a run is at most "
                          f"{MAX_TICKS} ticks (teleop.app.session.MAX_TICKS)")
    return int(n)


class Columns(dict):
    """Named per-tick arrays that grow in chunks of LOG_CHUNK ticks: ``ensure(i)`` before writing
    tick i, ``trimmed(n)`` the first n ticks. ``shapes`` maps a name to (trailing shape, dtype)."""

    def __init__(self, shapes: dict, expected: int = LOG_CHUNK):
        cap = max(1, min(int(expected), LOG_CHUNK))
        super().__init__({k: np.zeros((cap, *shape), dtype=dt) for k, (shape, dt) in shapes.items()})
        self.capacity = cap

    def ensure(self, i: int) -> None:
        if i < self.capacity:
            return
        grown = 2 * self.capacity if self.capacity < 8 * LOG_CHUNK else self.capacity + 8 * LOG_CHUNK
        cap = max(i + 1, grown)
        for k, a in self.items():
            b = np.zeros((cap, *a.shape[1:]), dtype=a.dtype)
            b[: self.capacity] = a
            self[k] = b
        self.capacity = cap

    def trimmed(self, n: int) -> dict:
        return {k: v[:n] for k, v in self.items()}

#: slave statuses that keep a run from being "ok", mildest first: the run goes on (the slave holds
#: or degrades safely), but its status names the worst of them ("slave_<status>"). "saturated"
#: (a joint bound active, the target still met) is reported in the counts only; relaxed fixture rows
#: (DEGRADED: "fixtures_relaxed") fail the run only on more than RELAXED_SHARE_MAX of its ticks (the
#: fixture tolerances still hold the result); any other fault fails it on one tick.
SLAVE_FAULTS = ("hold", "link_lost", "tracking_error", "fixtures_relaxed", "joint_limit", "infeasible_fallback",
                "invalid_target")
DEGRADED = ("fixtures_relaxed",)
#: the share of ticks the slave may spend with its fixtures relaxed (DEGRADED) in an "ok" run
RELAXED_SHARE_MAX = 0.01
#: the slave tool's largest distance from its target in an "ok" run, m
SLAVE_TARGET_MAX_M = 0.005
#: each fixture metric's tolerance in an "ok" run (the master side's virtual tool, as the encoders
#: see it, and the slave's blade): m, rad, m/s. A metric absent from a run is not checked.
FIXTURE_TOLERANCES = {
    "depth_error_max_m": 1e-3, "blade_tilt_max_rad": 0.1, "sideslip_max_m_per_s": 0.01,
    "height_error_max_m": 1e-3, "upright_error_max_rad": 0.1,
    "sphere_deviation_max_m": 1e-3, "normal_angle_error_max_rad": 0.1,
    "fixture_residual_max": 1e-3, "fixture_rate_max": 0.01,  # a user's type: holonomic rows by residual, the others by rate
}
SLAVE_FIXTURE_TOLERANCES = {"cut_depth_error_max_m": 1e-3, "rcm_error_max_m": 2e-3, "slave_fixture_residual_max": 1e-3}


def verdict(master_status: str, steps: int, slave_counts: dict | None = None, metrics: dict | None = None,
            nan: bool = False, exempt=(), master_link_lost: int = 0) -> tuple[str, str]:
    """The run's one-word status and a one-line reason, first match wins: "interrupted" (Ctrl-C),
    "no_ticks", the master side's fault, "nan", "slave_<status>" (the worst slave fault, see
    SLAVE_FAULTS), "fixture_violated" (the master side past FIXTURE_TOLERANCES),
    "slave_fixture_violated" (SLAVE_FIXTURE_TOLERANCES), "slave_off_target" (the slave's tool
    farther than SLAVE_TARGET_MAX_M from its target), else "ok". ``exempt``: metric names the
    scene's fixture does not hold (a trocar's fixture lets the blade tilt). ``master_link_lost``:
    the ticks the master spent in its lost-link safe state (:mod:`teleop.tick.heartbeat`): the run
    is "link_lost" unless the slave did worse than ``link_lost``."""
    counts, metrics = slave_counts or {}, metrics or {}
    if master_status == "interrupted":
        return "interrupted", f"stopped by Ctrl-C or SIGTERM after {steps} ticks: a partial run"
    if steps == 0:
        return "no_ticks", "the run ended before its first tick"
    if master_status not in ("ok", "stopped_by_operator"):
        return master_status, f"the master side stopped the run: {master_status}"
    if nan:
        return "nan", "the tool's state became NaN"
    total = max(1, sum(counts.values()))
    worst = [s for s in SLAVE_FAULTS if counts.get(s, 0) and (
        s not in DEGRADED or counts[s] / total > RELAXED_SHARE_MAX)]
    if master_link_lost and (not worst or SLAVE_FAULTS.index(worst[-1]) <= SLAVE_FAULTS.index("link_lost")):
        return "link_lost", f"the master lost the link to the slave on {master_link_lost} ticks (held in its safe state)"
    if worst:
        s = worst[-1]
        return f"slave_{s}", f"the slave was {s!r} on {counts[s]} of {total} ticks"
    for status, tols in (("fixture_violated", FIXTURE_TOLERANCES), ("slave_fixture_violated", SLAVE_FIXTURE_TOLERANCES)):
        for key, tol in tols.items():
            if key not in exempt and metrics.get(key, 0.0) > tol:
                return status, f"{key} = {metrics[key]:.3g}, past its tolerance {tol:g}"
    far = metrics.get("tip_tracking_max_m", 0.0)
    if far > SLAVE_TARGET_MAX_M:
        return "slave_off_target", f"the slave's tool was {far:.3g} m from its target (bound {SLAVE_TARGET_MAX_M:g} m)"
    return "ok", "both sides did what was asked"


def run_status(master_status: str, steps: int, slave_counts: dict | None, metrics: dict | None = None,
               nan: bool = False, master_link_lost: int = 0) -> str:
    """The run's one-word verdict (:func:`verdict`)."""
    return verdict(master_status, steps, slave_counts, metrics, nan, master_link_lost=master_link_lost)[0]


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


class MasterRecorder(Hook):
    """The master side's per-tick log: reference and virtual tool, multipliers, wrenches, the
    device's joints, the tick's CPU time."""

    def __init__(self, tool, n: int):
        m, f = tool.model.m, float
        self.log = Columns({
            "t": ((), f), "q_r": ((6,), f), "q_v_p": ((3,), f), "p_r": ((3,), f), "R_r": ((3, 3), f),
            "R_v": ((3, 3), f), "lam": ((m,), f), "operator_W": ((6,), f), "master_q": ((6,), f),
            "can_frames_lost": ((), np.int64), "constraint_W": ((6,), f), "tick_us": ((), f),
        }, n)
        self.n = 0
        self.nan = False
        self._pv = self._Rv = None

    def before_tick(self, i, t_s, loop) -> None:
        self._pv, self._Rv = loop.master.virtual_pose()  # what the encoders measure as it starts

    def after_tick(self, i, t_s, loop) -> None:
        tool, log = loop.tool, self.log
        log.ensure(i)
        self.nan = self.nan or not (np.all(np.isfinite(tool.q)) and np.all(np.isfinite(self._pv)))
        log["t"][i] = tool.t
        log["q_r"][i] = tool.q
        log["q_v_p"][i] = self._pv
        log["R_v"][i] = self._Rv
        log["p_r"][i], log["R_r"][i] = tool.pose()
        log["lam"][i] = tool.lam
        log["operator_W"][i] = loop.hand_W
        log["constraint_W"][i] = tool.constraint_wrench_W
        joints = loop.master.joints()
        if joints is not None:  # a device: its encoders and the bus's running loss count
            log["master_q"][i] = joints
            log["can_frames_lost"][i] = loop.master.stats().get("can_frames_lost", 0)
        log["tick_us"][i] = loop.tick_ns * 1e-3
        self.n = i + 1


class GuardRecorder(Hook):
    """The passivity guard's per-tick log: both observers ``tdpa_W_master_J``/``tdpa_W_slave_J``,
    the dissipated energies ``tdpa_diss_master_J``/``tdpa_diss_slave_J`` (n, 6) J cumulative, the
    master's damping ``tdpa_alpha`` (n, 6) and the slave's pose offset ``tdpa_drift_M`` (n, 6: m,
    rad in M)."""

    def __init__(self, n: int):
        self.log = Columns({k: ((6,), float) for k in ("tdpa_W_master_J", "tdpa_W_slave_J", "tdpa_diss_master_J",
                                                       "tdpa_diss_slave_J", "tdpa_alpha", "tdpa_drift_M")}, n)
        self.n = 0

    def after_tick(self, i, t_s, loop) -> None:
        m, s, log = loop.master_guard.port, loop.slave_guard.port, self.log
        log.ensure(i)
        log["tdpa_W_master_J"][i], log["tdpa_W_slave_J"][i] = m.W, s.W
        log["tdpa_diss_master_J"][i], log["tdpa_diss_slave_J"][i] = m.E_diss, s.E_diss
        log["tdpa_alpha"][i], log["tdpa_drift_M"][i] = m.action, s.offset
        self.n = i + 1

    def summary(self) -> dict:
        """Totals: energies dissipated (J), the observers' lowest sums (J), the drift (m in M)."""
        n, log = self.n, self.log
        if n == 0:
            return {}
        drift = np.linalg.norm(log["tdpa_drift_M"][:n, :3], axis=1)
        return {"dissipated_master_J": float(log["tdpa_diss_master_J"][n - 1].sum()),
                "dissipated_slave_J": float(log["tdpa_diss_slave_J"][n - 1].sum()),
                "W_master_min_J": float(log["tdpa_W_master_J"][:n].sum(axis=1).min()),
                "W_slave_min_J": float(log["tdpa_W_slave_J"][:n].sum(axis=1).min()),
                "drift_max_M_m": float(drift.max()), "drift_final_M_m": float(drift[-1])}


class SlaveCounter(Hook):
    """How many ticks the slave spent in each status."""

    def __init__(self):
        self.counts: dict[str, int] = {}

    def after_tick(self, i, t_s, loop) -> None:
        st = loop.slave.state.status
        self.counts[st] = self.counts.get(st, 0) + 1


class _StopFlag:
    """Set by SIGINT or SIGTERM during a run; the loop reads it between ticks."""

    def __init__(self):
        self.set = False

    def __bool__(self) -> bool:
        return self.set


@contextmanager
def _stop_requests():
    """Ctrl-C and SIGTERM set a flag the loop reads between ticks, instead of raising inside a
    compiled kernel (numba turns a KeyboardInterrupt there into a SystemError). Main thread only;
    elsewhere the signals keep their handlers. A second Ctrl-C while a tick hangs raises as usual."""
    flag = _StopFlag()
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def request(signum, frame):
        if flag.set:
            raise KeyboardInterrupt
        flag.set = True

    previous = {sig: signal.signal(sig, request) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield flag
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


#: pacing: the last stretch before a deadline spun rather than slept (s). With the loop thread's
#: timer slack at 1 us a sleep overshoots by ~20 us (p99 ~55 us) on this machine, against ~70 us
#: (p99 ~100 us) at Linux's default 50 us slack; spinning less leaves the cores to the link's
#: threads and the other side's process (two spinning processes on two cores starve them).
PACE_SPIN_S = 5e-5
_slack_threads: set[int] = set()
_YIELD = hasattr(os, "sched_yield") and os.environ.get("TELEOP_NO_YIELD") is None


def _fine_timer_slack() -> None:
    """Ask Linux for 1 us timer slack on the calling thread (prctl PR_SET_TIMERSLACK, no root
    needed), so that ``time.sleep`` wakes close to when asked; nothing elsewhere."""
    _slack_threads.add(threading.get_ident())
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None).prctl(29, 1000, 0, 0, 0)  # 29: PR_SET_TIMERSLACK, in ns
        except (OSError, AttributeError):
            pass


def _pace(deadline: float, spin_s: float = PACE_SPIN_S) -> int:
    """Wait for the wall-clock deadline (s, perf_counter): sleep, then spin the last ``spin_s``
    (s; ``math.inf``: spin all the way, for a process that owns its core). Returns 1 when the
    tick is already late, else 0."""
    if threading.get_ident() not in _slack_threads:
        _fine_timer_slack()
    now = time.perf_counter()
    if now > deadline:
        return 1
    if deadline - now > spin_s:
        time.sleep(deadline - now - spin_s)
    while time.perf_counter() < deadline:
        if _YIELD:
            os.sched_yield()  # a thread of this process's link woken on this core runs at once
    return 0


class Session:
    """Compose and run: see the module docstring. ``hooks`` run after the built-in recorders;
    ``progress(i, n)`` is called every 1000 ticks."""

    def __init__(self, tool, master, operator, dt_s: float, duration_s: float, slave=None, link=None,
                 feedback=None, hooks=(), realtime: bool = False, progress=None, guard=None,
                 heartbeat_s: float | None = None):
        if not (dt_s > 0 and duration_s >= 0 and np.isfinite(dt_s) and np.isfinite(duration_s)):
            raise ConfigError(f"dt_s must be > 0 and duration_s >= 0, both finite, got {dt_s!r}, {duration_s!r}")
        self.n = tick_count(duration_s, dt_s)
        self.recorder = MasterRecorder(tool, self.n)
        self.slave_counter = SlaveCounter() if slave is not None else None
        own = [self.recorder] + ([self.slave_counter] if slave is not None else [])
        self.guard_recorder = GuardRecorder(self.n) if guard is not None and slave is not None else None
        if self.guard_recorder is not None:
            own.append(self.guard_recorder)
        self.loop = BilateralLoop(tool, master, operator, dt_s, slave=slave, link=link, feedback=feedback,
                                  hooks=own + list(hooks), guard=guard, heartbeat_s=heartbeat_s)
        self.realtime, self.progress = realtime, progress
        self.late_ticks = 0  # --realtime: ticks that ended past their wall-clock deadline (so far)

    def run(self) -> RunResult:
        """Run to the end (see the module docstring). Ctrl-C ends the run between ticks with status
        "interrupted": the result holds what was recorded up to then."""
        loop, status = self.loop, "ok"
        wall0 = pace0 = time.perf_counter()
        warned = -1.0
        with loop.master as master:
            status = master.status
            log.info("running %d ticks of %g s (master %s)", self.n, loop.dt, status)
            with _stop_requests() as stop:
                try:
                    for i in range(self.n if status == "ok" else 0):
                        if stop:
                            status = "interrupted"
                            break
                        status = loop.tick(i)
                        if status != "ok":
                            break
                        if getattr(loop.operator, "stop", False):
                            status = "stopped_by_operator"
                            break
                        if self.progress is not None and i % 1000 == 0:
                            self.progress(i, self.n)
                        if self.realtime and i == 0:  # the first tick may compile or warm caches:
                            pace0 = time.perf_counter() - loop.dt  # the wall clock starts after it
                        elif self.realtime:
                            deadline = pace0 + (i + 1) * loop.dt
                            self.late_ticks += _pace(deadline)
                            lag = time.perf_counter() - deadline
                            if lag > LAG_WARN_S and time.perf_counter() - warned > 1.0:
                                warned = time.perf_counter()
                                rtf = i * loop.dt / (warned - pace0 - loop.dt)
                                log.warning("--realtime: %.0f ms behind the wall clock at t = %.2f s (running at "
                                            "%.2fx real time; %d late ticks)", 1e3 * lag, (i + 1) * loop.dt, rtf,
                                            self.late_ticks)
                except KeyboardInterrupt:  # a Ctrl-C outside the main thread's handler
                    status = "interrupted"
            stats = master.stats()
            link_stats = loop.link.stats()
            if link_stats:
                stats["link"] = link_stats
        self.wall_s = time.perf_counter() - wall0
        return self._result(status, self.late_ticks, stats)

    def _result(self, status: str, late: int, stats: dict) -> RunResult:
        steps, rec = self.recorder.n, self.recorder
        log = rec.log.trimmed(steps)
        if self.guard_recorder is not None:
            log.update({k: v[:steps] for k, v in self.guard_recorder.log.items()})
        ticks = log["tick_us"]
        counts = self.slave_counter.counts if self.slave_counter is not None else None
        hearts = (self.loop.master_heart, self.loop.slave_heart)
        lost_m = hearts[0].ticks_lost if hearts[0] is not None else 0
        summary = {
            "status": run_status(status, steps, counts, nan=rec.nan, master_link_lost=lost_m),
            "master_status": status,
            "steps": steps,
            "dt_s": self.loop.dt,
            "duration_s": steps * self.loop.dt,
            "nan": bool(rec.nan),
            "tick_us": {
                "median": float(np.median(ticks)) if steps else 0.0,
                "p99": float(np.percentile(ticks, 99)) if steps else 0.0,
            },
            "engine": {"rank_min": int(self.loop.tool.rank), "recharts": self.loop.tool.recharts},
        }
        if status == "stopped_by_operator":
            summary["stopped_by_operator"] = True
        if status == "interrupted":
            summary["interrupted"] = True  # a partial run: what was recorded up to Ctrl-C
        summary["wall_s"] = round(self.wall_s, 3)
        summary["realtime_factor"] = round(steps * self.loop.dt / self.wall_s, 3) if self.wall_s > 0 else 0.0
        if counts is not None:
            summary["slave_statuses"] = dict(counts)
            summary["command_errors"] = self.loop.command_errors
            summary["feedback_damping_refused"] = getattr(self.loop.feedback, "refused", 0)  # not PSD: not rendered
            summary.update(self.loop.slave.stats())
        if self.realtime:
            summary["late_ticks"] = late
        if self.guard_recorder is not None:
            summary["passivity"] = self.guard_recorder.summary()
        if "link" in stats and hearts[0] is not None:  # a link that can lose messages: its heartbeat
            summary["heartbeat"] = {"master": hearts[0].summary(), "slave": hearts[1].summary()}
        summary.update({k: v for k, v in stats.items() if k != "master_status"})
        return RunResult(summary, log)
