"""A teleoperation session: the bilateral loop run for a duration, recorded and summarised.

    session = Session(tool, master, operator, dt_s=1e-3, duration_s=2.0)   # + slave, link, hooks
    result = session.run()            # RunResult: .summary (JSON-able dict), .log (arrays)

Simulated time by default: the loop advances ``dt_s`` a tick with no wall clock, so a run is a
pure function of its inputs and seed. ``realtime`` paces each tick to the wall clock (late ticks
are counted, never skipped). The run ends at the duration, on the first master-side status that is
not "ok", or when the operator sets ``stop``.

The run's ``status`` covers both sides (:func:`run_status`): the master side's fault if one ended
the run; otherwise the worst slave status seen, when it is one of :data:`SLAVE_FAULTS`; otherwise
"ok". A run of zero ticks is "no_ticks".
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from teleop.loop import BilateralLoop, Hook

#: slave statuses that keep a run from being "ok", mildest first: the run goes on (the slave holds
#: or degrades safely), but its status names the worst of them ("slave_<status>"). "saturated"
#: (a joint bound active, the target still met) is reported in the counts only.
SLAVE_FAULTS = ("hold", "link_lost", "tracking_error", "fixtures_relaxed", "infeasible_fallback",
                "invalid_target")


def run_status(master_status: str, steps: int, slave_counts: dict | None) -> str:
    """The run's one-word verdict (see the module docstring)."""
    if steps == 0:
        return "no_ticks"
    if master_status != "ok":
        return master_status
    worst = [s for s in SLAVE_FAULTS if (slave_counts or {}).get(s, 0)]
    return f"slave_{worst[-1]}" if worst else "ok"


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
        m = tool.model.m
        self.log = {
            "t": np.zeros(n), "q_r": np.zeros((n, 6)), "q_v_p": np.zeros((n, 3)),
            "p_r": np.zeros((n, 3)), "R_r": np.zeros((n, 3, 3)), "R_v": np.zeros((n, 3, 3)),
            "lam": np.zeros((n, m)), "operator_W": np.zeros((n, 6)), "master_q": np.zeros((n, 6)),
            "can_frames_lost": np.zeros(n, dtype=np.int64), "constraint_W": np.zeros((n, 6)), "tick_us": np.zeros(n),
        }
        self.n = 0
        self.nan = False
        self._pv = self._Rv = None

    def before_tick(self, i, t_s, loop) -> None:
        self._pv, self._Rv = loop.master.virtual_pose()  # what the encoders measure as it starts

    def after_tick(self, i, t_s, loop) -> None:
        tool, log = loop.tool, self.log
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
        self.log = {k: np.zeros((n, 6)) for k in ("tdpa_W_master_J", "tdpa_W_slave_J", "tdpa_diss_master_J",
                                                  "tdpa_diss_slave_J", "tdpa_alpha", "tdpa_drift_M")}
        self.n = 0

    def after_tick(self, i, t_s, loop) -> None:
        m, s, log = loop.master_guard.port, loop.slave_guard.port, self.log
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


class Session:
    """Compose and run: see the module docstring. ``hooks`` run after the built-in recorders;
    ``progress(i, n)`` is called every 1000 ticks."""

    def __init__(self, tool, master, operator, dt_s: float, duration_s: float, slave=None, link=None,
                 feedback=None, hooks=(), realtime: bool = False, progress=None, guard=None):
        if not (dt_s > 0 and duration_s >= 0):
            raise ValueError(f"dt_s must be > 0 and duration_s >= 0, got {dt_s!r}, {duration_s!r}")
        self.n = int(round(duration_s / dt_s))
        self.recorder = MasterRecorder(tool, self.n)
        self.slave_counter = SlaveCounter() if slave is not None else None
        own = [self.recorder] + ([self.slave_counter] if slave is not None else [])
        self.guard_recorder = GuardRecorder(self.n) if guard is not None and slave is not None else None
        if self.guard_recorder is not None:
            own.append(self.guard_recorder)
        self.loop = BilateralLoop(tool, master, operator, dt_s, slave=slave, link=link, feedback=feedback,
                                  hooks=own + list(hooks), guard=guard)
        self.realtime, self.progress = realtime, progress

    def run(self) -> RunResult:
        loop, status, late = self.loop, "ok", 0
        wall0 = time.perf_counter()
        with loop.master as master:
            status = master.status
            for i in range(self.n if status == "ok" else 0):
                status = loop.tick(i)
                if status != "ok":
                    break
                if getattr(loop.operator, "stop", False):
                    status = "stopped_by_operator"
                    break
                if self.progress is not None and i % 1000 == 0:
                    self.progress(i, self.n)
                if self.realtime:
                    late += _pace(wall0 + (i + 1) * loop.dt)
            stats = master.stats()
            link_stats = loop.link.stats()
            if link_stats:
                stats["link"] = link_stats
        return self._result(status, late, stats)

    def _result(self, status: str, late: int, stats: dict) -> RunResult:
        steps, rec = self.recorder.n, self.recorder
        log = {k: v[:steps] for k, v in rec.log.items()}
        if self.guard_recorder is not None:
            log.update({k: v[:steps] for k, v in self.guard_recorder.log.items()})
        ticks = log["tick_us"]
        counts = self.slave_counter.counts if self.slave_counter is not None else None
        summary = {
            "status": run_status(status if status != "stopped_by_operator" else "ok", steps, counts),
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
        if counts is not None:
            summary["slave_statuses"] = dict(counts)
            summary["command_errors"] = self.loop.command_errors
            summary.update(self.loop.slave.stats())
        if self.realtime:
            summary["late_ticks"] = late
        if self.guard_recorder is not None:
            summary["passivity"] = self.guard_recorder.summary()
        summary.update({k: v for k, v in stats.items() if k != "master_status"})
        return RunResult(summary, log)
