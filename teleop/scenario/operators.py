"""Scripted operators: what the person's hand does to the handle.

* :class:`ScriptedWrench` - phases of constant wrench with linear ramps, optionally repeating.
* :class:`VirtualHand` - a hand that pulls the handle along a scripted path through a
  spring-damper, with optional physiological tremor (8-12 Hz) from the run's seeded generator.

Both return a world wrench (6,: N, N*m) at the tool origin for the virtual tool's pose and twist.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from bisect import bisect_right

import numpy as np

from teleop.dynamics.rotations import cross
from teleop.scenario.schema import FixtureSpec, HandSpec, OperatorSpec


def task_frame(spec: FixtureSpec, R: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) whose columns are the fixture's natural directions for the operator.

    rolling disk: (forward, lateral, plane normal); otherwise the tool's body axes.
    """
    if spec.type != "rolling_disk":
        return R
    n = np.asarray(spec.plane_normal, dtype=float)
    n = n / np.linalg.norm(n)
    forward = cross(n, R[:, 2])
    norm = np.linalg.norm(forward)
    if norm < 1e-9:
        return R
    forward /= norm
    return np.column_stack([forward, cross(n, forward), n])


class Operator(ABC):
    """Who pushes the handle. ``wrench(t, p, R, v, w)`` -> (6,: N, N*m, world) from the time (s)
    and the state of what the hand holds; ``clutch_engaged`` False lets go of the tool; ``stop``
    True ends the run; ``tremor_on`` says a tremor is part of the hand's motion."""

    clutch_engaged = True
    stop = False
    tremor_on = False

    @abstractmethod
    def wrench(self, t: float, p: np.ndarray, R: np.ndarray, v=None, w=None) -> np.ndarray:
        """The hand's wrench at time t (s) on what it holds at (p, R) moving at (v, w)."""


class ScriptedWrench(Operator):
    """Phases of constant wrench with linear ramps, optionally repeating every ``repeat_s``."""

    def __init__(self, spec: OperatorSpec, fixture: FixtureSpec):
        self.spec = spec
        self.fixture = fixture

    def wrench(self, t: float, p: np.ndarray, R: np.ndarray, v=None, w=None) -> np.ndarray:
        """World wrench (6,: N, N*m) at the tool origin at time t s for the tool pose (p, R)."""
        spec = self.spec
        if spec.repeat_s:
            t = t % spec.repeat_s
        out = np.zeros(6)
        for ph in spec.phases:
            if not ph.start_s <= t < ph.end_s:
                continue
            gain = 1.0
            if ph.ramp_s > 0:
                gain = min(1.0, (t - ph.start_s) / ph.ramp_s, (ph.end_s - t) / ph.ramp_s)
            if ph.frame == "world":
                Rf = np.eye(3)
            elif ph.frame == "tool":
                Rf = R
            else:
                Rf = task_frame(self.fixture, R)
            out[:3] += gain * (Rf @ np.array(ph.force_N))
            out[3:] += gain * (Rf @ np.array(ph.torque_Nm))
        return out


class VirtualHand(Operator):
    """A hand holding the handle and pulling it toward a scripted path with a spring-damper.

    The path is piecewise linear in time through ``waypoints`` (t s, x, y, z m, world). Tremor, when
    switched on, adds to the hand's target a sum of sinusoids in the 8-12 Hz band with random
    directions and phases drawn once from the run's generator (amplitude in m, RMS per axis).
    """

    def __init__(self, spec: HandSpec, base: ScriptedWrench | None, rng: np.random.Generator, tremor: bool):
        self.spec = spec
        self.base = base
        wp = np.array(spec.waypoints, dtype=float)
        self.times, self.points = wp[:, 0], wp[:, 1:4]
        self._times = self.times.tolist()  # for bisect: a Python search per tick, not a numpy call
        self.tremor_on = tremor and spec.tremor_amplitude_m > 0
        n = 5  # components spread over the physiological band
        self.freqs = rng.uniform(spec.tremor_band_hz[0], spec.tremor_band_hz[1], n)
        self.phases = rng.uniform(0.0, 2.0 * math.pi, (n, 3))
        # per-component amplitude so that the per-axis RMS of the sum equals the setting
        self.amp = spec.tremor_amplitude_m * math.sqrt(2.0 / n)

    def path(self, t: float) -> np.ndarray:
        """The intended hand position (3,) at time t, without tremor (m)."""
        ts = self.times
        if t <= ts[0]:
            return self.points[0].copy()
        if t >= ts[-1]:
            return self.points[-1].copy()
        i = bisect_right(self._times, t) - 1
        a = (t - ts[i]) / (ts[i + 1] - ts[i])
        return (1.0 - a) * self.points[i] + a * self.points[i + 1]

    def path_velocity(self, t: float) -> np.ndarray:
        ts = self.times
        if t <= ts[0] or t >= ts[-1]:
            return np.zeros(3)
        i = bisect_right(self._times, t) - 1
        return (self.points[i + 1] - self.points[i]) / (ts[i + 1] - ts[i])

    def tremor(self, t: float) -> np.ndarray:
        """Tremor displacement (3,) m at time t (zero when off)."""
        if not self.tremor_on:
            return np.zeros(3)
        arg = 2.0 * math.pi * self.freqs[:, None] * t + self.phases
        return self.amp * np.sin(arg).sum(axis=0)

    def target(self, t: float) -> np.ndarray:
        return self.path(t) + self.tremor(t)

    def wrench(self, t: float, p: np.ndarray, R: np.ndarray, v=None, w=None) -> np.ndarray:
        s = self.spec
        v = np.zeros(3) if v is None else v
        out = np.zeros(6)
        out[:3] = s.stiffness_N_per_m * (self.target(t) - p) + s.damping_Ns_per_m * (self.path_velocity(t) - v)
        if w is not None and s.angular_damping_Nms_per_rad:
            out[3:] = -s.angular_damping_Nms_per_rad * w
        if self.base is not None:
            out += self.base.wrench(t, p, R)
        return out


def make_operator(spec: OperatorSpec, fixture: FixtureSpec, effects, rng: np.random.Generator):
    """The scene's operator: a virtual hand (with its wrench phases added) or scripted wrenches."""
    base = ScriptedWrench(spec, fixture) if spec.phases else None
    if spec.hand is not None:
        return VirtualHand(spec.hand, base, rng, tremor="tremor" in effects)
    return base if base is not None else ScriptedWrench(spec, fixture)
