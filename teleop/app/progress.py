"""What a run says while it runs: a one-line notice when the kernels compile, a progress bar with
its ETA and real-time factor (tqdm), both on stderr and only where a person is looking.

``kernels_cold()`` asks numba's own on-disk cache whether the engine's largest kernel has a valid
entry; a cold cache means the first tick compiles every kernel (about 30-60 s once).

:class:`CompileClock` times what numba spends compiling during the run's ticks (numba's own
``numba:compile`` events), so that the real-time factor a first run reports is the loop's, not the
compiler's. :func:`realtime_figures` is the one place a run's wall-clock figures are made:
``realtime_factor`` leaves the compile out and ``compile_s`` reports it apart; every run in one
process (the command line, :func:`teleop.app.runtime.run_scene`, ``Session.run`` of the Python
API) gets them from :meth:`teleop.app.session.Session.run_ticks`.
"""

from __future__ import annotations

import logging
import sys
import time
from contextlib import contextmanager

from teleop.tick.ports import Hook

log = logging.getLogger("teleop")

#: show the bar only for runs that last longer than this, wall-clock s (tqdm's delay)
BAR_DELAY_S = 2.0


def kernels_cold() -> bool:
    """True when numba's cache holds no valid compiled engine kernel (the first tick compiles)."""
    try:
        from teleop.dynamics.kernels import motion

        return not motion.evaluate._cache._cache_file._load_index()  # numba's cache index: {} when stale
    except Exception:  # a private numba API: unknown means "say nothing"
        return False


def notice_compile(stream=None) -> None:
    """The one-line notice before a cold first tick, where a person is looking: on a terminal (or
    with -v). In a pipe it stays out of the way, so a refused scene is still one line on stderr."""
    stream = stream or sys.stderr
    looking = getattr(stream, "isatty", lambda: False)() or log.isEnabledFor(logging.INFO)
    if looking and kernels_cold():
        log.warning("compiling kernels, once, about 30-60 s (cached for the next runs)")


def numba_cache_dir() -> str:
    """Where numba keeps the compiled kernels (for -vv): its cache folder, or beside the sources."""
    import os

    folder = os.environ.get("NUMBA_CACHE_DIR")
    if folder:
        return folder
    try:
        from teleop.dynamics.kernels import motion

        return str(motion.evaluate._cache._cache_path)  # numba's private API: the folder it caches in
    except Exception:  # unknown: say where numba's default puts it
        return "__pycache__ beside the kernels' sources"


def realtime_figures(steps: int, dt_s: float, wall_s: float, compile_s: float = 0.0) -> dict:
    """A run's wall-clock figures: ``wall_s`` (s) its ``steps`` ticks of ``dt_s`` (s) took,
    ``realtime_factor`` the simulated time over that wall time less ``compile_s`` (s numba spent
    compiling kernels in it, once per machine: the loop's own rate, 1 is real time), and
    ``compile_s`` when there was any. Times to the millisecond, the factor to 3 decimals."""
    out = {"wall_s": round(wall_s, 3)}
    loop_s = wall_s - compile_s if 0.0 < compile_s < wall_s else wall_s
    out["realtime_factor"] = round(steps * dt_s / loop_s, 3) if loop_s > 0 else 0.0
    if compile_s > 0.0:
        out["compile_s"] = round(compile_s, 3)
    return out


class CompileClock(Hook):
    """The wall time numba spends compiling during a run's ticks (see the module docstring). Use
    as a context manager around the run (it listens to numba's compile events while open) and as
    a loop hook of the run (it marks the first tick's start). ``seconds`` is the compile time
    since the first tick started (so far; whole after the run)."""

    def __init__(self):
        self.spans: list[tuple[float, float]] = []  # (start, end) of each outermost compile, perf_counter
        self.first_tick = None  # perf_counter at the start of tick 0
        self._depth, self._t0 = 0, 0.0
        self._installed = None

    def _started(self) -> None:
        if self._depth == 0:
            self._t0 = time.perf_counter()
        self._depth += 1

    def _ended(self) -> None:
        if self._depth > 0:
            self._depth -= 1
            if self._depth == 0:
                self.spans.append((self._t0, time.perf_counter()))

    def __enter__(self):
        try:
            from numba.core import event
        except ImportError:  # no numba events: nothing discounted
            return self
        clock = self

        class _Listener(event.Listener):
            def on_start(self, e):
                clock._started()

            def on_end(self, e):
                clock._ended()

        listener = _Listener()
        event.register("numba:compile", listener)
        self._installed = (event, listener)
        return self

    def __exit__(self, *exc) -> None:
        if self._installed is not None:
            event, listener = self._installed
            event.unregister("numba:compile", listener)
            self._installed = None

    def start(self, at: float | None = None) -> float:
        """Mark where the run's wall clock starts (perf_counter s; now by default) and return it:
        the compile time counted is the one after it."""
        self.first_tick = time.perf_counter() if at is None else at
        return self.first_tick

    def before_tick(self, i, t_s, side) -> None:
        if self.first_tick is None:
            self.start()

    def seconds_between(self, start: float, end: float = float("inf")) -> float:
        """Compile time (s) inside [start, end] (perf_counter)."""
        return sum(max(0.0, min(b, end) - max(a, start)) for a, b in self.spans)

    @property
    def seconds(self) -> float:
        return 0.0 if self.first_tick is None else self.seconds_between(self.first_tick)

    def discount(self, summary: dict) -> dict:
        """``summary`` with the compile time inside its run's wall time taken out of its
        ``realtime_factor`` and reported as ``compile_s`` (changed in place, returned); a run that
        compiled nothing is left as it is."""
        wall = summary.get("wall_s")
        if self.first_tick is None or not wall:
            return summary
        spent = self.seconds_between(self.first_tick, self.first_tick + wall)
        if spent <= 0.0:
            return summary
        figures = realtime_figures(summary["steps"], summary["dt_s"], wall, spent)
        summary["compile_s"] = figures["compile_s"]
        if spent < wall:
            summary["realtime_factor"] = figures["realtime_factor"]
        log.info("the kernels compiled for %.1f s during the run; the real-time factor leaves that out", spent)
        return summary


@contextmanager
def compile_clock():
    """A :class:`CompileClock` listening for the block."""
    clock = CompileClock()
    with clock:
        yield clock


class RunBar:
    """A progress bar in simulated seconds: ``update(i, n)`` from the session every 1000 ticks; the
    rate tqdm shows is simulated s per wall s, the real-time factor (less the time ``clock``, a
    :class:`CompileClock`, saw numba compile). Off when ``enabled`` is false or stderr is not a
    terminal; appears only after BAR_DELAY_S of wall time."""

    def __init__(self, duration_s: float, dt_s: float, enabled: bool = True, stream=None, clock=None):
        stream = stream or sys.stderr
        self.dt = dt_s
        self.clock = clock
        self.bar = None
        if enabled and getattr(stream, "isatty", lambda: False)():
            from tqdm import tqdm

            self.bar = tqdm(total=round(duration_s, 6), unit="sim s", unit_scale=False, delay=BAR_DELAY_S,
                            file=stream, leave=False, dynamic_ncols=True,
                            bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} s simulated "
                                       "[{elapsed}<{remaining}{postfix}]")

    def __call__(self, i: int, n: int) -> None:
        if self.bar is not None:
            self.bar.update(round(i * self.dt, 6) - self.bar.n)
            elapsed = self.bar.format_dict["elapsed"] - (self.clock.seconds if self.clock is not None else 0.0)
            if elapsed > 0:
                self.bar.set_postfix_str(f"{i * self.dt / elapsed:.2f}x real time", refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
