"""What a run says while it runs: a one-line notice when the kernels compile, a progress bar with
its ETA and real-time factor (tqdm), both on stderr and only where a person is looking.

``kernels_cold()`` asks numba's own on-disk cache whether the engine's largest kernel has a valid
entry; a cold cache means the first tick compiles every kernel (about 30-60 s once).
"""

from __future__ import annotations

import logging
import sys

log = logging.getLogger("teleop")

#: show the bar only for runs that last longer than this, wall-clock s (tqdm's delay)
BAR_DELAY_S = 2.0


def kernels_cold() -> bool:
    """True when numba's cache holds no valid compiled engine kernel (the first tick compiles)."""
    try:
        from teleop.dynamics.kernels import motion

        return not motion.evaluate._cache._cache_file._load_index()  # numba's cache index: {} when stale
    except Exception:  # noqa: BLE001 - a private numba API: unknown means "say nothing"
        return False


def notice_compile(stream=None) -> None:
    """The one-line notice before a cold first tick, where a person is looking: on a terminal (or
    with -v). In a pipe it stays out of the way, so a refused scene is still one line on stderr."""
    stream = stream or sys.stderr
    looking = getattr(stream, "isatty", lambda: False)() or log.isEnabledFor(logging.INFO)
    if looking and kernels_cold():
        log.warning("compiling kernels, once, about 30-60 s (cached for the next runs)")


class RunBar:
    """A progress bar in simulated seconds: ``update(i, n)`` from the session every 1000 ticks; the
    rate tqdm shows is simulated s per wall s, the real-time factor. Off when ``enabled`` is false
    or stderr is not a terminal; appears only after BAR_DELAY_S of wall time."""

    def __init__(self, duration_s: float, dt_s: float, enabled: bool = True, stream=None):
        stream = stream or sys.stderr
        self.dt = dt_s
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
            elapsed = self.bar.format_dict["elapsed"]
            if elapsed > 0:
                self.bar.set_postfix_str(f"{i * self.dt / elapsed:.2f}x real time", refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
