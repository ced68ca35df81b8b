"""A person at the keyboard as the operator: pushes and twists the handle, clutches, stops.

Keys (forces in the fixture's task frame, torques about its axes):

    w / s   push forward / back (x)        q / e   twist about z
    a / d   push left / right (y)          i / k   twist about x
    r / f   push up / down (z)             j / l   twist about y
    space   clutch (toggle)                x, ESC  stop the run

A key holds its push for ``hold_s`` after the last press (keyboards auto-repeat), so holding a key
gives a steady push. Input is read without blocking from a file descriptor (the terminal in raw
mode by default; a pipe in tests).
"""

from __future__ import annotations

import os
import select

import numpy as np

from teleop.scenario.operators import Operator, task_frame

KEYMAP = {
    "w": (0, +1), "s": (0, -1), "a": (1, +1), "d": (1, -1), "r": (2, +1), "f": (2, -1),
    "i": (3, +1), "k": (3, -1), "j": (4, +1), "l": (4, -1), "q": (5, +1), "e": (5, -1),
}
HELP = "w/s a/d r/f: push x/y/z   i/k j/l q/e: twist x/y/z   space: clutch   x: stop"


class KeyboardOperator(Operator):
    """Wrench from key presses. ``force_N`` and ``torque_Nm`` are the push per key."""

    def __init__(self, fixture, fd: int | None = None, force_N: float = 2.0, torque_Nm: float = 0.02, hold_s: float = 0.25):
        self.fixture = fixture
        self.fd = fd
        self.force, self.torque, self.hold = force_N, torque_Nm, hold_s
        self.last_press = np.full(6, -np.inf)
        self.sign = np.zeros(6)
        self.clutch_engaged = True
        self.stop = False
        self._tty = None

    def __enter__(self):
        if self.fd is None:
            import sys
            import termios
            import tty

            self.fd = sys.stdin.fileno()
            self._tty = termios.tcgetattr(self.fd)
            tty.setcbreak(self.fd)
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        if self._tty is not None:
            import termios

            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._tty)
            self._tty = None

    def poll(self, t: float) -> None:
        """Read every pending key (never blocks)."""
        while self.fd is not None and select.select([self.fd], [], [], 0.0)[0]:
            data = os.read(self.fd, 64)
            if not data:
                return
            for ch in data.decode(errors="ignore"):
                self.press(ch, t)

    def press(self, ch: str, t: float) -> None:
        if ch in KEYMAP:
            axis, sign = KEYMAP[ch]
            self.last_press[axis], self.sign[axis] = t, sign
        elif ch == " ":
            self.clutch_engaged = not self.clutch_engaged
        elif ch in ("x", "\x1b"):
            self.stop = True

    def wrench(self, t: float, p, R, v=None, w=None) -> np.ndarray:
        self.poll(t)
        active = (t - self.last_press) <= self.hold
        local = np.where(active, self.sign, 0.0) * np.array([self.force] * 3 + [self.torque] * 3)
        Rf = task_frame(self.fixture, R)
        return np.concatenate([Rf @ local[:3], Rf @ local[3:]])
