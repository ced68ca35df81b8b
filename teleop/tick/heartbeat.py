"""The link's heartbeat: one side's view of whether its peer is still there. Each side owns one
(:class:`~teleop.tick.master_side.MasterSide`, :class:`~teleop.tick.slave_side.SlaveSide`), in
every run: one process over a simulated channel (simulated time), or two over Zenoh (wall clock).

Every tick each side sends a message, so silence means a lost link. A side that has heard nothing
for more than ``timeout_s`` (``[link] heartbeat_ms``, 20 ms by default) is **lost**; the master is
lost as well while the newest reply says ``link_lost`` (the slave hears nothing of it: the command
way is down while replies still come). A side that has never heard the other is not lost: that is
the start-up (the two-process run's handshake, a delayed channel's first message in flight).

The safe states are the sides' own methods (:meth:`MasterSide.hold`, :meth:`SlaveSide.hold`);
nothing here touches another object's state. When messages come again each side resumes from
where it held.
"""

from __future__ import annotations

import math

import numpy as np

#: silence within this of the timeout does not count (s): simulated ticks are float sums
SILENCE_EPS_S = 1e-9
RESUME_WINDOW = 100  # ticks after a resume in which the position steps are watched


class HeartbeatState:
    """One side's view of the link: lost or not, with counts for the summary. ``timeout_s``: the
    silence (s) after which the side is lost."""

    def __init__(self, timeout_s: float):
        self.timeout_s = float(timeout_s)
        self.lost = False
        self.events = self.ticks_lost = self.resumed = 0
        self.latency_s: list[float] = []  # last message heard -> safe state, per event (s)
        self.detected_at_s: list[float] = []  # the clock's time of each detection (s)
        self.late_at_detect_s: list[float] = []  # how late the detecting tick itself ran (s)
        self.tick_late_s = 0.0  # set by a wall-clock run loop before each tick: its lateness (s)
        self.speed_lost_max = self.speed_lost_last = 0.0  # the side's speed while lost (m/s or rad/s)
        self.jump_after_resume_m = self.step_max_m = 0.0  # position step per tick (m)
        self._prev: list[float] | None = None  # the last position (m), as floats
        self._since_resume = 10**9

    def silent(self, now_s: float, last_heard_s: float | None) -> bool:
        """True when the last message was heard more than ``timeout_s`` before ``now_s`` (s);
        False before the first message."""
        return last_heard_s is not None and now_s - last_heard_s > self.timeout_s + SILENCE_EPS_S

    def update(self, now_s: float, last_heard_s: float | None, peer_lost: bool = False) -> bool:
        """Check the heartbeat at ``now_s`` (s, the clock of ``last_heard_s``, the time the last
        message arrived, None before the first); ``peer_lost``: the newest reply says the other
        side is lost. True while the link is lost."""
        lost = peer_lost or self.silent(now_s, last_heard_s)
        if lost and not self.lost:
            self.lost, self.events = True, self.events + 1
            self.latency_s.append(now_s - last_heard_s if last_heard_s is not None else float("inf"))
            self.detected_at_s.append(now_s)
            self.late_at_detect_s.append(self.tick_late_s)
        elif not lost and self.lost:
            self.lost, self.resumed = False, self.resumed + 1
        self.ticks_lost += self.lost
        return self.lost

    def motion(self, p: np.ndarray, speed: float) -> None:
        """After the tick: the side's position ``p`` (3,) m and speed, for the safe-state and
        no-jump figures (the largest step within ``RESUME_WINDOW`` ticks of a resume)."""
        if self.lost:
            self.speed_lost_max, self.speed_lost_last = max(self.speed_lost_max, speed), speed
            self._since_resume = -1
        now = np.asarray(p, dtype=float).tolist()
        if self._prev is not None:
            step = math.dist(now, self._prev)
            if step > self.step_max_m:
                self.step_max_m = step
            if 0 <= self._since_resume < RESUME_WINDOW and step > self.jump_after_resume_m:
                self.jump_after_resume_m = step
        self._since_resume += 1
        self._prev = now

    def summary(self) -> dict:
        return {"lost_events": self.events, "lost_ticks": self.ticks_lost, "resumed": self.resumed,
                "detect_latency_max_s": max(self.latency_s, default=0.0), "lost_at_end": self.lost,
                "detect_latency_s": self.latency_s[:20], "detect_tick_late_s": self.late_at_detect_s[:20],
                "heartbeat_s": self.timeout_s, "speed_while_lost_max": self.speed_lost_max,
                "speed_while_lost_last": self.speed_lost_last, "step_max_m": self.step_max_m,
                "step_after_resume_max_m": self.jump_after_resume_m}
