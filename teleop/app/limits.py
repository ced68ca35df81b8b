"""Limits on what a hand may do to the tool: a workspace box and a speed limit, enforced on the
operator's wrench (any :class:`~teleop.scenario.operators.Operator`; the keyboard's by default).

The **workspace** is the device's: the cobot's gantry travel (less its ``workspace_margin_m``)
carried through the scene's φ (``[cobot]`` scale, offset, rotation) into the tool's space, an
oriented box, less a wall zone (so the tool stops before the device's own end stops). The ideal
master renders the same device perfectly, so it gets the same box; a tool that starts outside it
(a scene placed elsewhere) gets the box grown to take it in.

Both limits act the same way, as a person's hand near a stop would:

* the hand's push *toward* a limit fades to nothing across a zone before it (a wall zone of
  ``zone_m`` before each face; the last fifth below the speed limit), and is gone at once while
  the tool comes on toward a face faster than the wall allows (the brake below then acts alone), and
* past a face or a speed limit all the same (a fixture can turn a push along a face into a slide
  through it, a push into a turn: a knife edge, a rolling disk), the hand's whole wrench fades out
  over :data:`PAST_LIMIT_SHARE` of the zone or the limit, and
* a brake, a damper of ``mass / brake_s`` (the tool's inertia over a fixed time, N*s/m; for the
  rotation ``R I R^T / brake_s``), acts on the velocity *past what is allowed*: toward a face at
  distance d the allowed speed is ``d / wall_s`` (negative outside: then the brake is a spring of
  ``mass / (brake_s * wall_s)`` pulling back in, critically damped for ``wall_s = 4 brake_s``),
  and along the motion it is the speed limit.

The brake is capped at the device's force (torque) range. Nothing is added while the tool is well
inside and slower than the limit, so a hand that stays inside feels nothing. And a push that would
carry the tool past a speed limit within one control period (a hand stiff against a light tool:
0.04 N*m on a blade's 2e-5 kg*m^2 is 2 rad/s in a millisecond) is cut to what reaches the limit in
that period: the fade above reads the speed once a period, so alone it would let such a push
through on every other tick (the property test found the blade turning at 3.2 rad/s against 1.9).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from teleop.master.cobot.model import CobotModel
from teleop.scenario.operators import Operator

log = logging.getLogger(__name__)

#: the brake's time constant in control periods (explicitly stable: dt / brake_s = 0.05), and at least, s
BRAKE_TICKS, BRAKE_MIN_S = 20, 0.02
#: the speed (as a share of the limit) above which the hand's push along the motion fades
SPEED_FADE_FROM = 0.8
#: past a face or a speed limit, the hand's whole wrench fades out over this share of the wall zone
#: or the limit
PAST_LIMIT_SHARE = 0.1


@dataclass(frozen=True)
class Workspace:
    """An oriented box in the tool's space: ``center`` (3,) m, ``axes`` (3, 3) unit columns, ``half``
    (3,) m half-widths along them."""

    center: np.ndarray
    axes: np.ndarray
    half: np.ndarray

    def distances(self, p) -> np.ndarray:
        """(6,) m from ``p`` to the faces +axis 0, 1, 2 then -axis 0, 1, 2; positive inside."""
        u = self.axes.T @ (np.asarray(p, float) - self.center)
        return np.concatenate([self.half - u, self.half + u])

    def normals(self) -> np.ndarray:
        """(6, 3) outward unit normals of the faces, in the order of :meth:`distances`."""
        return np.concatenate([self.axes.T, -self.axes.T])

    def margin(self, p) -> float:
        """The distance (m) from ``p`` to the nearest face: positive inside, negative outside."""
        return float(self.distances(p).min())

    def shrunk(self, by: float) -> Workspace:
        """The box ``by`` m inside this one on every face (never thinner than nothing)."""
        return Workspace(self.center, self.axes, np.maximum(self.half - by, 0.0))

    def grown_to(self, p, by: float) -> Workspace:
        """The smallest box with the same axes holding this one and the ball of radius ``by`` at p."""
        u = self.axes.T @ (np.asarray(p, float) - self.center)
        lo, hi = np.minimum(-self.half, u - by), np.maximum(self.half, u + by)
        return Workspace(self.center + self.axes @ ((lo + hi) / 2), self.axes, (hi - lo) / 2)


def device_workspace(cobot) -> Workspace:
    """The cobot's gantry travel, less its margin, through the config's φ into the tool's space."""
    model = CobotModel()
    m = cobot.workspace_margin_m
    lo, hi = model.lower[:3] + m, model.upper[:3] - m
    R = pin.exp3(np.asarray(cobot.offset_rotvec_rad, float))  # as the cobot's φ does
    s = cobot.scale
    return Workspace(np.asarray(cobot.offset_m, float) + s * (R @ ((lo + hi) / 2)), R, s * (hi - lo) / 2)


@dataclass(frozen=True)
class Limits:
    """What the hand may do: ``workspace`` (the tool origin stays in it), ``speed_m_s`` and
    ``angular_speed_rad_s`` (the most it drives the tool at), the tool's ``mass_kg`` and inertia
    ``inertia_kgm2`` (3, 3, body) for the brake, ``max_force_N`` / ``max_torque_Nm`` (the brake's
    cap: the device's range), ``zone_m`` (the wall zone), ``brake_s`` and ``wall_s`` (s), and the
    control period ``dt_s`` (s)."""

    workspace: Workspace
    speed_m_s: float
    angular_speed_rad_s: float
    mass_kg: float
    inertia_kgm2: np.ndarray
    max_force_N: float
    max_torque_Nm: float
    zone_m: float
    brake_s: float
    wall_s: float
    dt_s: float


def limits_for(scene, p0, speed_m_s: float, angular_speed_rad_s: float) -> Limits:
    """The limits of a scene whose tool starts at ``p0`` (3,) m: the device's workspace (grown to
    take in p0 when it starts outside), the given speed limits capped at 80 % of the device's, the
    brake from the tool's mass and inertia and the control period, capped by the device's range."""
    cobot, tool = scene.cobot, scene.tool
    brake = max(BRAKE_TICKS * scene.dt_s, BRAKE_MIN_S)
    vmax = np.asarray(cobot.max_velocity, float)
    speed = min(speed_m_s, 0.8 * cobot.scale * float(vmax[:3].min()))
    spin = min(angular_speed_rad_s, 0.8 * float(vmax[3:].min()))
    zone = speed * 4.0 * brake  # the distance the brake needs to stop the tool from the speed limit
    ws = device_workspace(cobot).shrunk(zone)  # the tool stops before the device's own stops
    if ws.margin(p0) < zone:
        log.info("limits: the tool starts %.3g m from the device's workspace; the box is grown to take it in",
                 -ws.margin(p0))
        ws = ws.grown_to(p0, 2.0 * zone)
    inertia = np.asarray(tool.inertia_kgm2, float)
    inertia = inertia.reshape(3, 3) if inertia.size == 9 else np.diag(inertia)
    return Limits(ws, speed, spin, tool.mass_kg, inertia, cobot.max_force_N, cobot.max_torque_Nm, zone, brake,
                  4.0 * brake, scene.dt_s)


def _fade(F: np.ndarray, n: np.ndarray, keep: float, M: np.ndarray | None = None) -> np.ndarray:
    """F with what it does to the velocity along unit n (when it speeds it up) scaled by ``keep`` in
    [0, 1]. ``M`` (3, 3) the inertia it acts on (None: isotropic): the rate along n is
    n . M^-1 F, and the part taken away is along M n (the least change in the inertia's metric)."""
    if M is None:
        along = float(F @ n)
        return F - (1.0 - keep) * along * n if along > 0.0 else F
    along = float(n @ np.linalg.solve(M, F))
    return F - (1.0 - keep) * along * (M @ n) if along > 0.0 else F


def _within_one_period(x: np.ndarray, a: np.ndarray, limit: float) -> float:
    """The largest share s in [0, 1] of a velocity change ``a`` (3,) that keeps |x + s a| at most
    ``limit`` from a velocity ``x`` (3,), or at most |x| when x is already past the limit (the
    brake slows it; a push may not make it faster, not even one across the motion: in one explicit
    step it adds |a|^2 to |x|^2, and the property test found a tool held against a face turned at
    a right angle from 30.0 to 31.1 mm/s in one tick)."""
    aa = float(a @ a)
    x2 = float(x @ x)
    limit2 = max(limit * limit, x2)
    if aa == 0.0 or float((x + a) @ (x + a)) <= limit2:
        return 1.0
    limit = math.sqrt(limit2)
    xa = float(x @ a)
    return max(0.0, (-xa + math.sqrt(max(0.0, xa * xa - aa * (x2 - limit * limit)))) / aa)


def _capped(F: np.ndarray, cap: float) -> np.ndarray:
    norm = float(np.linalg.norm(F))
    return F * (cap / norm) if norm > cap else F


class LimitedOperator(Operator):
    """``inner``'s wrench held to ``limits`` (see the module docstring). Forwards ``clutch_engaged``,
    ``stop`` and ``tremor_on``; ``stats()`` sums up what the limits met, ``active`` names the
    limits acting this tick (for a status line)."""

    def __init__(self, inner: Operator, limits: Limits):
        self.inner, self.limits = inner, limits
        self.active: tuple[str, ...] = ()
        self.margin_min_m = math.inf
        self.speed_max_m_s = self.spin_max_rad_s = 0.0
        self.braked_ticks = 0

    clutch_engaged = property(lambda self: self.inner.clutch_engaged)
    stop = property(lambda self: self.inner.stop)
    tremor_on = property(lambda self: self.inner.tremor_on)

    def wrench(self, t: float, p, R, v=None, w=None) -> np.ndarray:
        """The inner operator's wrench (6,: N, N*m, world) with the limits applied; zeros where it is
        not finite."""
        W = np.asarray(self.inner.wrench(t, p, R, v, w), dtype=float).reshape(6)
        if not np.all(np.isfinite(W)):
            W = np.zeros(6)
        lim = self.limits
        p = np.asarray(p, float)
        v = np.zeros(3) if v is None else np.asarray(v, float)
        w = np.zeros(3) if w is None else np.asarray(w, float)
        F, T = W[:3].copy(), W[3:].copy()
        c = lim.mass_kg / lim.brake_s
        brake_F, brake_T = np.zeros(3), np.zeros(3)
        active = []
        d = lim.workspace.distances(p)
        for n, dk in zip(lim.workspace.normals(), d):
            if dk >= lim.zone_m:
                continue
            excess = float(v @ n) - dk / lim.wall_s
            # the push toward the face fades across the zone, and is gone while the tool comes on
            # faster than the wall allows: then the brake alone acts, a critically damped stop that
            # does not cross the face (a hand's integral push of newtons would outrun it)
            F = _fade(F, n, 0.0 if excess > 0.0 else max(0.0, dk / lim.zone_m))
            if excess > 0.0:
                # and no push along the motion either: a fixture turns a push across the face into
                # a slide toward it (a knife edge), which the push along n alone does not show
                vv = float(np.linalg.norm(v))
                if vv > 0.0:
                    F = _fade(F, v / vv, 0.0)
                brake_F -= c * excess * n
                active.append("wall")
        speed = float(np.linalg.norm(v))
        if speed > SPEED_FADE_FROM * lim.speed_m_s:
            u = v / speed
            F = _fade(F, u, max(0.0, (lim.speed_m_s - speed) / ((1 - SPEED_FADE_FROM) * lim.speed_m_s)))
            if speed > lim.speed_m_s:
                brake_F -= c * (speed - lim.speed_m_s) * u
                active.append("speed")
        spin = float(np.linalg.norm(w))
        if spin > SPEED_FADE_FROM * lim.angular_speed_rad_s:
            u, I_W = w / spin, R @ lim.inertia_kgm2 @ R.T  # the inertia is not isotropic: faded in its metric
            keep = max(0.0, (lim.angular_speed_rad_s - spin) / ((1 - SPEED_FADE_FROM) * lim.angular_speed_rad_s))
            T = _fade(T, u, keep, I_W)
            if spin > lim.angular_speed_rad_s:
                brake_T = -_capped(I_W @ (u * (spin - lim.angular_speed_rad_s)) / lim.brake_s, lim.max_torque_Nm)
                active.append("spin")
        # past a face or a speed limit all the same (a fixture turned the hand's push into a slide or
        # a turn: a knife edge, a rolling disk): the hand is let go of over PAST_LIMIT_SHARE
        past = max(-float(d.min()) / lim.zone_m, speed / lim.speed_m_s - 1.0, spin / lim.angular_speed_rad_s - 1.0)
        if past > 0.0:
            keep = max(0.0, 1.0 - past / PAST_LIMIT_SHARE)
            F, T = keep * F, keep * T
        # no push carries the tool past a speed limit within one period (the fades read the speed
        # once a period)
        F = F * _within_one_period(v, F * (lim.dt_s / lim.mass_kg), lim.speed_m_s)
        I_W = R @ lim.inertia_kgm2 @ R.T
        T = T * _within_one_period(w, lim.dt_s * np.linalg.solve(I_W, T), lim.angular_speed_rad_s)
        F = F + _capped(brake_F, lim.max_force_N)
        T = T + brake_T
        self.active = tuple(dict.fromkeys(active))
        self.braked_ticks += bool(active)
        self.margin_min_m = min(self.margin_min_m, float(d.min()))
        self.speed_max_m_s = max(self.speed_max_m_s, speed)
        self.spin_max_rad_s = max(self.spin_max_rad_s, spin)
        return np.concatenate([F, T])

    def stats(self) -> dict:
        """What the limits met over the run: the closest the tool came to a face (m, negative
        past it), its top speeds against the limits, the ticks a brake acted."""
        lim = self.limits
        return {"workspace_margin_min_m": self.margin_min_m if math.isfinite(self.margin_min_m) else None,
                "speed_max_m_s": self.speed_max_m_s, "speed_limit_m_s": lim.speed_m_s,
                "angular_speed_max_rad_s": self.spin_max_rad_s, "angular_speed_limit_rad_s": lim.angular_speed_rad_s,
                "braked_ticks": self.braked_ticks}
