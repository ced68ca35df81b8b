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

from teleop.app.progress import CompileClock, realtime_figures
from teleop.app.recorders import Columns, MasterRecorder
from teleop.link import LockstepLink
from teleop.tick.loop import BilateralLoop
from teleop.tick.master_side import HEARTBEAT_S, MasterSide
from teleop.tick.verdict import run_summary
from teleop.util.errors import ConfigError

log = logging.getLogger(__name__)

#: the longest run, ticks: the sides' captured rows (1.1 kB a tick on the cut: 81 and 62 numbers)
#: stay under about 2.3 GB
MAX_TICKS = 2_000_000
#: --realtime: warn when the loop falls this far behind the wall clock, s (then once a second)
LAG_WARN_S = 0.05


def tick_count(duration_s: float, dt_s: float, where: str = "duration_s") -> int:
    """The ticks of a run (duration / dt rounded); ConfigError naming ``where`` past MAX_TICKS."""
    n = round(duration_s / dt_s)
    if n > MAX_TICKS:
        raise ConfigError(f"{where}: {duration_s:g} s at dt {dt_s:g} s is {n:.3g} ticks; a run is at most "
                          f"{MAX_TICKS} ticks (teleop.app.session.MAX_TICKS)")
    return int(n)


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


@dataclass
class SideRun:
    """What a runner hands on of one run: the master side's ``status`` (or the slave's, for a
    slave process alone), ``steps`` ticked, the sides' parts (:meth:`MasterSide.summary`,
    :meth:`SlaveSide.summary`; None where a side did not run here), the ``runner``'s own figures
    (clock, CPU times, link counters) and the per-tick ``log`` columns."""

    status: str
    steps: int
    dt_s: float
    master: dict | None
    slave: dict | None
    nan: bool
    runner: dict
    log: dict


def tick_stats(ticks_us: np.ndarray) -> dict:
    """Median and p99 of per-tick CPU times (us)."""
    n = len(ticks_us)
    return {"median": float(np.median(ticks_us)) if n else 0.0, "p99": float(np.percentile(ticks_us, 99)) if n else 0.0}


class Session:
    """Run a :class:`~teleop.tick.loop.BilateralLoop` for ``duration_s`` on the simulated clock, or
    paced to the wall clock (``realtime``); see the module docstring. ``progress(i, n)`` is called
    every 1000 ticks.

    ``Session(tool, master, operator, dt_s, duration_s, slave=..., feedback=..., hooks=...)``
    composes the sides itself (a :class:`~teleop.tick.master_side.MasterSide` over ``tool``,
    ``master`` and ``operator``; ``slave`` a :class:`~teleop.tick.slave_side.SlaveSide`; ``link``
    by default the lockstep link) and records the master side; :meth:`of` runs a loop composed
    elsewhere (:func:`teleop.app.assembly.build_loop`)."""

    def __init__(self, tool, master, operator, dt_s: float, duration_s: float, slave=None, link=None,
                 feedback=None, hooks=(), realtime: bool = False, progress=None, heartbeat_s: float = HEARTBEAT_S):
        if not (dt_s > 0 and duration_s >= 0 and np.isfinite(dt_s) and np.isfinite(duration_s)):
            raise ConfigError(f"dt_s must be > 0 and duration_s >= 0, both finite, got {dt_s!r}, {duration_s!r}")
        n = tick_count(duration_s, dt_s)
        side = MasterSide(tool, master, operator, dt_s, feedback, heartbeat_s=heartbeat_s)
        recorder = MasterRecorder(side, n)
        side.add_hooks(recorder)
        if slave is not None and link is None:
            link = LockstepLink()
        self._setup(BilateralLoop(side, slave, link, hooks), n, recorder, realtime, progress)

    @classmethod
    def of(cls, loop: BilateralLoop, duration_s: float, recorder: MasterRecorder, realtime: bool = False,
           progress=None) -> Session:
        """A session over a composed ``loop`` whose master side ``recorder`` records."""
        self = cls.__new__(cls)
        self._setup(loop, tick_count(duration_s, loop.dt), recorder, realtime, progress)
        return self

    def _setup(self, loop: BilateralLoop, n: int, recorder: MasterRecorder, realtime: bool, progress) -> None:
        self.loop, self.n, self.recorder = loop, n, recorder
        self.realtime, self.progress = realtime, progress
        self.ticks = Columns({"tick_us": ((), float)}, n)
        self.late_ticks = 0  # --realtime: ticks that ended past their wall-clock deadline (so far)
        self.steps = 0

    def run(self) -> RunResult:
        """Run to the end and summarise (:meth:`result`, with no scene metrics)."""
        return self.result(self.run_ticks())

    def run_ticks(self) -> SideRun:
        """Run to the end (see the module docstring). Ctrl-C ends the run between ticks with status
        "interrupted": what was recorded up to then is kept. The runner's ``realtime_factor``
        leaves out what numba spent compiling kernels during the run, reported apart as
        ``compile_s`` (:func:`teleop.app.progress.realtime_figures`, for every runner in one
        process)."""
        with CompileClock() as clock:
            return self._run_ticks(clock, clock.start())

    def _run_ticks(self, clock: CompileClock, wall0: float) -> SideRun:
        loop, status = self.loop, "ok"
        pace0 = wall0
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
                        self.ticks.ensure(i)
                        self.ticks["tick_us"][i] = loop.tick_ns * 1e-3
                        self.steps = i + 1
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
        wall = time.perf_counter() - wall0
        steps = min(self.steps, self.recorder.n)
        runner = {"tick_us": tick_stats(self.ticks["tick_us"][:steps]),
                  **realtime_figures(steps, loop.dt, wall, clock.seconds_between(wall0, wall0 + wall))}
        if self.realtime:
            runner["late_ticks"] = self.late_ticks
        link_stats = loop.link.stats() if loop.link is not None else {}
        if link_stats:
            runner["link"] = link_stats
        runner.update({k: v for k, v in stats.items() if k != "master_status"})
        ss = loop.slave_side
        logs = {**self.recorder.log(steps), **self.ticks.trimmed(steps)}
        return SideRun(status, steps, loop.dt, loop.master_side.summary(), ss.summary() if ss is not None else None,
                       self.recorder.nan, runner, logs)

    @staticmethod
    def result(run: SideRun, metrics: dict | None = None, exempt=()) -> RunResult:
        """The run's summary (:func:`teleop.tick.verdict.run_summary`, the runner's figures beside)
        and its log."""
        summary = run_summary(run.status, run.steps, run.dt_s, run.master, run.slave, metrics or {}, run.nan, exempt,
                              run.runner.get("link"))
        if run.status == "stopped_by_operator":
            summary["stopped_by_operator"] = True
        if run.status == "interrupted":
            summary["interrupted"] = True  # a partial run: what was recorded up to Ctrl-C
        summary.update(run.runner)
        return RunResult(summary, run.log)
