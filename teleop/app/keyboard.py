"""A person at the keyboard as the operator: pushes and twists the handle, clutches, stops.

Keys (motions along the fixture's task frame, turns about its axes; a capital letter goes
:data:`FAST` times faster):

    w / s   forward / back (x)             q / e   turn about z
    a / d   left / right (y)               i / k   turn about x
    r / f   up / down (z)                  j / l   turn about y
    arrows  as w / s / a / d               space   clutch (toggle)
    x, ESC  stop the session (a clean stop: status "ok" when both sides did what was asked)

The hand the keys stand for holds the handle: a held key pushes it until it moves at the key's
speed along that axis; a released key's axis is brought to rest for :data:`SETTLE_S`, then let go
(a proportional-integral push on the tool's velocity in the task frame, axis by axis; an axis no
key touched is left free, so a fixture that ties motions together, a rolling disk, still rolls).
The push is scaled to the tool and the device (:func:`key_scale`): the speed crosses the
workspace in :data:`KEY_CROSSING_S`; the push never exceeds :data:`KEY_FORCE_SHARE` of the
device's force (torque) range, and a tool that does not move gets all of it after
:data:`KEY_STUCK_S` (the integral gain), whatever resists (a fixture's added inertia, damping,
tissue); the proportional gain damps that critically on the tool's own mass (largest inertia),
within what an explicit step of the lightest axis takes. A key holds for ``hold_s`` after its
last press (keyboards auto-repeat, after a first pause of up to half a second). Input is read
without blocking from a file descriptor (the terminal in cbreak mode by default; a pipe in tests).

:func:`run_at_keyboard` runs a scene with it, in real time, under the workspace and speed limits
of :mod:`teleop.app.limits`, with a live status line (:mod:`teleop.app.statusline`), until the
person stops it.
"""

from __future__ import annotations

import logging
import math
import os
import select
import sys
from dataclasses import dataclass

import numpy as np

from teleop.app.limits import LimitedOperator, Limits, device_workspace, limits_for
from teleop.app.session import MAX_TICKS
from teleop.scenario.build import build_tool, master_fixture_spec
from teleop.scenario.operators import Operator, task_frame
from teleop.util.errors import ConfigError

log = logging.getLogger(__name__)

KEYMAP = {
    "w": (0, +1), "s": (0, -1), "a": (1, +1), "d": (1, -1), "r": (2, +1), "f": (2, -1),
    "i": (3, +1), "k": (3, -1), "j": (4, +1), "l": (4, -1), "q": (5, +1), "e": (5, -1),
}
#: the arrow keys' escape sequences' last character -> the key they stand for
ARROWS = {"A": "w", "B": "s", "C": "d", "D": "a"}
HELP = ("w/s a/d r/f: move x/y/z   i/k j/l q/e: turn about x/y/z   capitals: faster   space: clutch   "
        "x or ESC: stop")
#: a held key's speed crosses the workspace's narrowest width in this long, s
KEY_CROSSING_S = 20.0
#: a held key brings the tool's own mass from rest to the key's speed in about this long, s
KEY_REACH_S = 0.5
#: the angular speed of a held turn key, rad/s
KEY_SPIN_RAD_S = 0.5
#: the share of the device's force (torque) range the hand may push with
KEY_FORCE_SHARE = 0.1
#: a capital letter goes this many times faster
FAST = 2.0
#: the speed limits, as multiples of a key's speeds (a capital's speed, with room to settle)
SPEED_LIMIT_FACTOR = 2.5
#: a held key's axis that does not move gets the hand's whole push after this long, s
KEY_STUCK_S = 2.0
#: a key pushes this long after its last press (covers the keyboard's first auto-repeat pause), s
HOLD_S = 0.5
#: after a key is released its axis is brought to rest for this long, then let go, s
SETTLE_S = 1.0


@dataclass(frozen=True)
class KeyScale:
    """The hand behind the keys: the speeds of a held key (m/s, rad/s), the proportional gains on
    the velocity error (N*s/m, N*m*s/rad), the most it pushes (N, N*m) and the integral gains
    (N/m, N*m/rad)."""

    speed_m_s: float
    angular_speed_rad_s: float
    gain_Ns_per_m: float
    gain_Nms_per_rad: float
    force_N: float
    torque_Nm: float
    integral_N_per_m: float
    integral_Nm_per_rad: float


def hand_gains(m_min: float, m_max: float, speed: float, cap: float, dt_s: float) -> tuple[float, float]:
    """(proportional, integral) gains of one kind of axis (translation: masses in kg, m/s, N; turn:
    inertias in kg*m^2, rad/s, N*m): the integral gives the whole ``cap`` to a tool stuck for
    KEY_STUCK_S; the proportional gain damps it critically on the heaviest axis ``m_max`` (at least
    m_max / (KEY_REACH_S / 5)), and at most half what an explicit step of the lightest ``m_min``
    takes (m_min / dt), the integral then lowered to keep the damping critical."""
    k_i = cap / (speed * KEY_STUCK_S)
    k_p = min(max(m_max / (KEY_REACH_S / 5.0), 2.0 * math.sqrt(k_i * m_max)), 0.5 * m_min / dt_s)
    return k_p, min(k_i, k_p * k_p / (4.0 * m_max))


def key_scale(scene, workspace=None) -> KeyScale:
    """The hand for ``scene``'s tool and device (see the module docstring): speed = the workspace's
    narrowest width / KEY_CROSSING_S; caps = KEY_FORCE_SHARE of ``cobot.max_force_N`` /
    ``max_torque_Nm``; gains from :func:`hand_gains` on the tool's mass and principal inertias."""
    ws = workspace if workspace is not None else device_workspace(scene.cobot)
    inertia = np.asarray(scene.tool.inertia_kgm2, float)
    inertia = np.linalg.eigvalsh(inertia.reshape(3, 3) if inertia.size == 9 else np.diag(inertia))
    speed, m = 2.0 * float(ws.half.min()) / KEY_CROSSING_S, scene.tool.mass_kg
    force, torque = KEY_FORCE_SHARE * scene.cobot.max_force_N, KEY_FORCE_SHARE * scene.cobot.max_torque_Nm
    kp, ki = hand_gains(m, m, speed, force, scene.dt_s)
    kp_w, ki_w = hand_gains(float(inertia.min()), float(inertia.max()), KEY_SPIN_RAD_S, torque, scene.dt_s)
    return KeyScale(speed, KEY_SPIN_RAD_S, kp, kp_w, force, torque, ki, ki_w)


class KeyboardOperator(Operator):
    """Wrench from key presses through the hand of ``scale`` (:class:`KeyScale`); ``hold_s`` how
    long a press holds its key (simulated s). ``target`` is the task-frame twist the hand is after
    (6,: m/s, rad/s). ``tap(t_s, text)``, when set, is told every read of the terminal (the
    record keeps the keys, :class:`~teleop.app.record.runinfo.KeyTap`); ``script`` (simulated time
    s -> the texts read then, in order), when set, stands in for the terminal: a replay types
    what the record says was typed, at the tick it was read."""

    def __init__(self, fixture, scale: KeyScale, fd: int | None = None, hold_s: float = HOLD_S):
        self.fixture, self.scale, self.fd, self.hold = fixture, scale, fd, hold_s
        self.speeds = np.array([scale.speed_m_s] * 3 + [scale.angular_speed_rad_s] * 3)
        self.gains = np.array([scale.gain_Ns_per_m] * 3 + [scale.gain_Nms_per_rad] * 3)
        self.integral = np.array([scale.integral_N_per_m] * 3 + [scale.integral_Nm_per_rad] * 3)
        self.caps = np.array([scale.force_N] * 3 + [scale.torque_Nm] * 3)
        self.last_press = np.full(6, -np.inf)
        self.sign = np.zeros(6)
        self.effort = np.zeros(6)  # the integral part of the push (task frame, N and N*m)
        self.target = np.zeros(6)
        self.clutch_engaged = True
        self.stop = False
        self._t = None
        self._tty = None
        self._pending = ""  # an escape sequence cut by the end of a read
        self.tap = None
        self.script: dict[float, list[str]] | None = None

    def __enter__(self):
        """Read the terminal on stdin in cbreak mode (keys one by one, no echo; Ctrl-C still a
        signal) when no ``fd`` was given."""
        if self.fd is None:
            import termios  # POSIX only: imported where a terminal is used
            import tty

            fd = require_terminal()
            self._tty = termios.tcgetattr(fd)
            self.fd = fd
            tty.setcbreak(fd)
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        """Give the terminal back as it was; safe to call twice."""
        if self._tty is not None:
            import termios  # POSIX only

            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._tty)
            self._tty = None

    def poll(self, t: float) -> None:
        """Read every pending key (never blocks); with a ``script``, its texts of time ``t``."""
        if self.script is not None:
            for text in self.script.get(t, ()):
                self.feed(text, t)
            return
        while self.fd is not None and select.select([self.fd], [], [], 0.0)[0]:
            data = os.read(self.fd, 64)
            if not data:
                return
            text = data.decode(errors="ignore")
            if self.tap is not None:
                self.tap(t, text)
            self.feed(text, t)

    def feed(self, text: str, t: float) -> None:
        """Act on typed characters: keys, arrows (ESC [ A ...), a lone ESC (stop)."""
        text, self._pending = self._pending + text, ""
        i = 0
        while i < len(text):
            ch = text[i]
            if ch == "\x1b" and i + 1 < len(text) and text[i + 1] in "[O":
                j = i + 2
                while j < len(text) and not (text[j].isalpha() or text[j] == "~"):
                    j += 1
                if j == len(text):  # the rest of the sequence comes with the next read
                    self._pending = text[i:]
                    return
                if text[j] in ARROWS:
                    self.press(ARROWS[text[j]], t)
                i = j + 1
                continue
            self.press(ch, t)
            i += 1

    def press(self, ch: str, t: float) -> None:
        if ch.lower() in KEYMAP:
            axis, sign = KEYMAP[ch.lower()]
            self.last_press[axis], self.sign[axis] = t, sign * (FAST if ch.isupper() else 1.0)
        elif ch == " ":
            self.clutch_engaged = not self.clutch_engaged
        elif ch in ("x", "X", "\x1b"):
            self.stop = True

    def wrench(self, t: float, p, R, v=None, w=None) -> np.ndarray:
        """The hand's wrench (6,: N, N*m, world): a proportional-integral push toward the held keys'
        twist in the task frame, each axis capped; zero with the clutch out."""
        self.poll(t)
        dt = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        if not self.clutch_engaged:
            self.effort[:] = 0.0
            return np.zeros(6)
        Rf = task_frame(self.fixture, R)
        v = np.zeros(3) if v is None else np.asarray(v, float)
        w = np.zeros(3) if w is None else np.asarray(w, float)
        twist = np.concatenate([Rf.T @ v, Rf.T @ w])
        since = t - self.last_press
        self.target = np.where(since <= self.hold, self.sign, 0.0) * self.speeds
        engaged = since <= self.hold + SETTLE_S  # a released key's axis is stopped, then let go
        err = np.where(engaged & np.isfinite(twist), self.target - twist, 0.0)
        grown = np.clip(self.effort + dt * self.integral * err, -self.caps, self.caps)
        self.effort = np.where(engaged, grown, 0.0)
        local = np.clip(self.gains * err + self.effort, -self.caps, self.caps)
        return np.concatenate([Rf @ local[:3], Rf @ local[3:]])


def require_terminal() -> int:
    """The file descriptor of stdin when it is a terminal; ConfigError otherwise."""
    try:
        fd = sys.stdin.fileno()
        if os.isatty(fd):
            return fd
    except (OSError, ValueError):  # no file behind stdin (closed, or replaced)
        pass
    raise ConfigError("--operator keyboard: standard input is not a terminal (the keys are read from it; "
                      "run teleop in a terminal)")


def keyboard_operator(scene, fd: int | None = None) -> tuple[LimitedOperator, KeyScale]:
    """The keyboard for ``scene``: the hand of :func:`key_scale`, held to the scene's limits
    (speed limits SPEED_LIMIT_FACTOR times a key's speeds). Returns (operator, scale); the
    operator's ``inner`` is the :class:`KeyboardOperator` (enter it to read the terminal)."""
    p0, _ = build_tool(scene).pose()
    scale = key_scale(scene)
    limits: Limits = limits_for(scene, p0, SPEED_LIMIT_FACTOR * scale.speed_m_s,
                                SPEED_LIMIT_FACTOR * scale.angular_speed_rad_s)
    return LimitedOperator(KeyboardOperator(master_fixture_spec(scene), scale, fd=fd), limits), scale


def scripted_keyboard(scene, script: dict[float, list[str]]) -> LimitedOperator:
    """The keyboard of ``scene`` (:func:`keyboard_operator`) typing ``script`` (simulated time s ->
    the texts read at that tick) instead of reading a terminal: a recorded session again."""
    op, _ = keyboard_operator(scene)
    op.inner.script = script
    return op


def describe(scale: KeyScale, limits: Limits, dt_s: float, duration_s: float) -> str:
    """Two lines for the person at the keyboard: the keys' speeds, the limits, how it ends."""
    size = " x ".join(f"{2e3 * h:.0f}" for h in limits.workspace.half)
    longest = MAX_TICKS * dt_s
    end = (f"runs until you press x (at most {longest:g} s: teleop.app.session.MAX_TICKS ticks)"
           if duration_s >= longest else f"runs {duration_s:g} s or until you press x")
    return (f"keyboard: a key moves the tool {1e3 * scale.speed_m_s:.0f} mm/s or turns it "
            f"{scale.angular_speed_rad_s:g} rad/s (pushing up to {scale.force_N:.3g} N, {scale.torque_Nm:.3g} N*m); "
            f"limits {1e3 * limits.speed_m_s:.0f} mm/s, {limits.angular_speed_rad_s:g} rad/s, workspace {size} mm\n"
            f"keyboard: the session {end}; Ctrl-C ends it too (status 'interrupted')")


def run_at_keyboard(scene, view=None, quiet: bool = False, fd: int | None = None, stream=None, hooks=(), record=None):
    """Run ``scene`` with the person at the keyboard (stdin, or ``fd``), in real time, until they
    press x or ESC (or Ctrl-C, or the scene's duration). Prints the keys and the limits, shows the
    status line on a terminal; ``hooks`` more loop hooks; ``record`` a
    :class:`~teleop.app.record.RecordWriter` that gets every tick and every key read. Returns the
    RunResult (its summary has "operator": the limits met)."""
    from teleop.app.runtime import run_scene
    from teleop.app.statusline import StatusLine, logging_above

    stream = stream or sys.stderr
    op, scale = keyboard_operator(scene, fd)
    if not quiet:
        print(HELP, file=stream)
        print(describe(scale, op.limits, scene.dt_s, scene.duration_s), file=stream)
    line = StatusLine(enabled=not quiet, stream=stream)
    if record is not None:  # every read of the terminal on record, for `teleop replay --check`
        from teleop.app.record.runinfo import KeyTap

        op.inner.tap = KeyTap(record, scene.dt_s)
    try:
        with op.inner, logging_above(line):
            result = run_scene(scene, realtime=True, operator=op, view=view, hooks=hooks, status_line=line,
                               record=record)
    finally:
        line.close()
    s = result.summary
    if s["master_status"] == "ok" and s["steps"] >= MAX_TICKS:
        log.warning("keyboard: the session reached its longest run, %d ticks (%g s, teleop.app.session.MAX_TICKS), "
                    "and stopped", MAX_TICKS, MAX_TICKS * scene.dt_s)
    return result
