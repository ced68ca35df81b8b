"""A live one-line status of a running session, rewritten in place on a terminal (tqdm) about five
times a second; silent in a pipe.

    t 12.3 s  0.98x | tool 12.0 -4.1 95.0 mm  0 0 -3 deg | hand 9.80 N 0 N*m | slave ok | held by the fixture along z

Fields: simulated time (s), real-time factor (simulated s per wall s since the first tick), late
ticks (``--realtime``), the reference tool's position (mm) and ZYX Euler angles (deg), the hand's
force (N) and torque (N*m), the slave's status (``-`` without a slave), then why the hand's push
may not move the tool (:func:`reasons`): the clutch out, a limit acting (braked at the workspace's
edge, at the speed or turn-rate limit: :mod:`teleop.app.limits`), a key's axis held by the fixture
(the push along a direction the fixture's rows forbid, a blade pushed into its depth) or held by
something else (tissue, damping: pushing without moving), and a master fault. Log messages (the
``--realtime`` warnings) print above it while it shows (:func:`logging_above`).
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
#: the limits of :class:`teleop.app.limits.LimitedOperator` acting, in words
LIMIT_WORDS = {"wall": "wall: braked at the workspace edge", "speed": "speed: braked at the speed limit",
               "spin": "spin: braked at the turn-rate limit"}
#: a held key's axis is stuck when the tool moves along it below this share of the key's speed ...
STUCK_SPEED_SHARE = 0.2
#: ... while the hand's push along it has grown past this share of its cap
STUCK_PUSH_SHARE = 0.5
#: a stuck axis is the fixture's doing when its rows take at least this share of the push
FIXTURE_SHARE = 0.9
#: the task frame's axes, forces then torques
AXES = ("x", "y", "z", "turn x", "turn y", "turn z")


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
        parts.append(", ".join(flags))
    return " | ".join(parts)


def _fixture_share(tool, direction, torque: bool) -> float:
    """The share (0..1) of a unit push ``direction`` (a force, or a torque) that the tool's fixture
    rows take: the norm of its projection on the row space of G (p, R)."""
    from teleop.dynamics.constraints import stack_jacobian

    fixture = getattr(tool, "fixture", None)
    p, R = tool.pose()
    G = stack_jacobian(getattr(fixture, "constraints", ()), p, R)
    if G.shape[0] == 0:
        return 0.0
    g = np.concatenate([np.zeros(3), direction] if torque else [direction, np.zeros(3)])
    y, *_ = np.linalg.lstsq(G.T, g, rcond=None)  # the rows' part of g: G^T y closest to g
    return float(np.linalg.norm(G.T @ y))


def stuck_axes(op, tool) -> tuple[list[str], list[str]]:
    """The axes of the keys ``op`` holds (the keyboard's, or the one a LimitedOperator wraps) whose
    push has grown (past STUCK_PUSH_SHARE of its cap) while the tool does not move along them
    (below STUCK_SPEED_SHARE of the key's speed): (held by the fixture, held by anything else)."""
    from teleop.scenario.operators import task_frame

    hand = getattr(op, "inner", op)
    target, effort, caps = (getattr(hand, k, None) for k in ("target", "effort", "caps"))
    if target is None or effort is None or caps is None or not np.any(target):
        return [], []
    _, R = tool.pose()
    v, w = tool.twist()
    Rf = task_frame(hand.fixture, R)
    twist = np.concatenate([Rf.T @ v, Rf.T @ w])
    by_fixture, by_other = [], []
    for k in np.flatnonzero(target):
        pushing = abs(effort[k]) >= STUCK_PUSH_SHARE * caps[k] and np.sign(effort[k]) == np.sign(target[k])
        if not pushing or abs(twist[k]) >= STUCK_SPEED_SHARE * abs(target[k]):
            continue
        held = _fixture_share(tool, Rf[:, k % 3], torque=k >= 3) >= FIXTURE_SHARE
        (by_fixture if held else by_other).append(AXES[k])
    return by_fixture, by_other


def reasons(op, tool=None) -> list[str]:
    """Why the hand's push may not move the tool, in words, for the status line: the clutch out,
    the limits acting (LIMIT_WORDS), the keys' axes held by the fixture or by something else
    (:func:`stuck_axes`, when ``tool`` is given)."""
    out = []
    if not getattr(op, "clutch_engaged", True):
        out.append("clutch out (space)")
    out += [LIMIT_WORDS.get(a, a) for a in getattr(op, "active", ())]
    if tool is not None:
        fixture, other = stuck_axes(op, tool)
        if fixture:
            out.append(f"held by the fixture along {' '.join(fixture)}")
        if other:
            out.append(f"pushing {' '.join(other)} without moving (something resists)")
    return out


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
        slave_arm = getattr(loop, "slave", None)  # a master side alone (a two-process run) has none
        slave = slave_arm.state.status if slave_arm is not None else None
        flags = reasons(loop.operator, loop.tool)
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
