"""A live one-line status of a running session, rewritten in place on a terminal (tqdm) about five
times a second; silent in a pipe.

    t 12.3 s  0.98x  late 3 | tool 12.0 -4.1 95.0 mm  0 0 -3 deg | hand 0.11 N 0.000 N*m | slave ok | wall

Fields: simulated time (s), real-time factor (simulated s per wall s since the first tick), late
ticks (``--realtime``), the reference tool's position (mm) and ZYX Euler angles (deg), the hand's
force (N) and torque (N*m), the slave's status (``-`` without a slave), then what is on: the
clutch out, a limit acting (``wall``, ``speed``, ``spin``: :mod:`teleop.app.limits`), a master
fault. Log messages (the ``--realtime`` warnings) print above it while it shows
(:func:`logging_above`).
"""

from __future__ import annotations

import logging
import sys
import time
from contextlib import contextmanager

import numpy as np
from scipy.spatial.transform import Rotation

from teleop.tick.loop import Hook

#: wall-clock seconds between two redraws
PERIOD_S = 0.2
#: ticks between two looks at the wall clock (the hook costs nothing on the other ticks)
EVERY_TICKS = 20


def status_text(t_s: float, rtf: float, late: int | None, p, R, hand_W, slave: str | None,
                flags=()) -> str:
    """The status line's text from a tick's numbers (see the module docstring for the fields)."""
    ypr = Rotation.from_matrix(np.asarray(R, float)).as_euler("ZYX", degrees=True)
    pos = " ".join(f"{1e3 * x:.1f}" for x in p)
    ang = " ".join(f"{a:.0f}" for a in ypr)
    F, T = np.linalg.norm(hand_W[:3]), np.linalg.norm(hand_W[3:])
    parts = [f"t {t_s:.1f} s  {rtf:.2f}x" + (f"  late {late}" if late is not None else ""),
             f"tool {pos} mm  {ang} deg", f"hand {F:.2f} N {T:.3f} N*m", f"slave {slave or '-'}"]
    if flags:
        parts.append(" ".join(flags))
    return " | ".join(parts)


class StatusLine(Hook):
    """The status line as a loop hook. Shown only when ``enabled`` and ``stream`` (stderr) is a
    terminal; :meth:`watch` gives it the session (for the late ticks); :meth:`close` clears it."""

    def __init__(self, enabled: bool = True, stream=None):
        stream = stream or sys.stderr
        self.bar = None
        if enabled and getattr(stream, "isatty", lambda: False)():
            from tqdm import tqdm

            self.bar = tqdm(total=None, bar_format="{desc}", file=stream, leave=False, dynamic_ncols=True,
                            mininterval=0.0)
        self.session = None
        self._start = None
        self._next = 0.0
        self.text = ""

    def watch(self, session) -> None:
        self.session = session

    def after_tick(self, i, t_s, loop) -> None:
        if self.bar is None or i % EVERY_TICKS:
            return
        now = time.perf_counter()
        if self._start is None:
            self._start = (now, t_s)
        if now < self._next:
            return
        self._next = now + PERIOD_S
        wall, sim = now - self._start[0], t_s - self._start[1]
        self.text = self.line(t_s + loop.dt, sim / wall if wall > 0 else 0.0, loop)
        self.bar.set_description_str(self.text, refresh=True)

    def line(self, t_s: float, rtf: float, loop) -> str:
        """The status text of ``loop`` at time ``t_s`` (s) running at ``rtf``."""
        s = self.session
        late = s.late_ticks if s is not None and s.realtime else None
        slave = loop.slave.state.status if loop.slave is not None else None
        op = loop.operator
        flags = list(getattr(op, "active", ()))
        if not op.clutch_engaged:
            flags.insert(0, "clutch out")
        if loop.status != "ok":
            flags.append(f"master {loop.status}")
        return status_text(t_s, rtf, late, *loop.tool.pose(), loop.hand_W, slave, flags)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


@contextmanager
def logging_above(line: StatusLine, logger: str = "teleop"):
    """While ``line`` shows, ``logger``'s messages print above it instead of through it."""
    if line.bar is None:
        yield
        return
    from tqdm.contrib.logging import logging_redirect_tqdm

    with logging_redirect_tqdm(loggers=[logging.getLogger(logger)]):
        yield
