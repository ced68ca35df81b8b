"""The slave side of the bilateral tick: a command in, a contact wrench out. It owns everything
on the slave's end of the link: its half of the tick (:meth:`SlaveSide.tick`), its passivity guard
port, its heartbeat and its safe state (:meth:`SlaveSide.hold`). Every run composes it: the
in-process loop (:mod:`teleop.tick.loop`) and the slave process over Zenoh
(:mod:`teleop.app.netrun`) alike.

``follow(cmd)`` maps the master's :class:`~teleop.tick.messages.ToolCommand` into the patient frame
(the registration), moves the target onto the patient-frame fixture, runs the follower QP under the
same fixture rows, evaluates the tissue at the blade tip and answers with a
:class:`~teleop.tick.messages.ContactFeedback`: the contact wrench at the slave tool frame's origin,
in the patient frame, with the contact's local damping (:mod:`teleop.contact.damping`) and the
tool's twist it was taken at, for the master to render. No command (a late or lost message) holds
the last target; a command with the clutch out holds the arm where it is. A tick the arm ends with a
joint at a position limit (:meth:`teleop.slave.limits.JointLimits.at_limit`) it reached during the
run (a joint the start pose put on its stop is not reported while it stays there; once it leaves, it
is watched like the others) says ``joint_limit`` instead of what the follower reported, unless that
was worse (a solver fallback, an invalid target); when the stop made the follower relax its fixture
rows, the slave holds its joints from the next tick (the safe state, as on a lost link) until a
command comes with the clutch open.
While the heartbeat (:mod:`teleop.tick.heartbeat`) says the master is lost, no command is
followed: the joints are commanded to stop where they are (:meth:`teleop.slave.qp.SlaveArm.hold`,
no QP) and the reply says ``link_lost``; when commands come again it follows from where it held.
Plain arguments only: no scene, no runtime.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from time import perf_counter_ns
from typing import Any

import numpy as np

from teleop.contact.damping import contact_damping, moved_to_origin
from teleop.contact.estimate import NO_PLANE, PlaneEstimator
from teleop.control.mapping import Registration
from teleop.dynamics.rotations import cross
from teleop.slave.projection import project_onto_fixture
from teleop.slave.qp import SlaveArm
from teleop.tick.guard import SlaveGuard
from teleop.tick.heartbeat import HeartbeatState
from teleop.tick.messages import ContactFeedback, ToolCommand
from teleop.tick.plausible import CommandCheck, CommandLimits
from teleop.tick.ports import Hook, SlaveEnd

#: model-mediated: how long a surface the tip left still bounds its target (s)
WALL_MEMORY_S = 0.2
#: model-mediated: the largest tracking offset (m) the bound on the target makes up for
TRACK_LAG_MAX_M = 1e-3
#: model-mediated: the secant stiffness since the first touch is taken over at least this depth (m)
SECANT_DEPTH_MIN_M = 1e-6
_Z3 = np.zeros(3)
_Z3.flags.writeable = False
#: the heartbeat's timeout when none is given (s): ``[link] heartbeat_ms``'s default
HEARTBEAT_S = 0.02


#: the follower's statuses a joint at its position limit explains (it is reported instead)
_LIMIT_EXPLAINS = ("ok", "saturated", "tracking_error", "fixtures_relaxed")


class SlaveState:
    """What the slave did this tick (patient frame): target ``p_t``, ``R_t``; tool pose ``p``,
    ``R`` and twist ``v``, ``w``; blade ``tip`` (m); ``contact_P`` the tissue wrench at the tip
    (6,: N, N*m); ``status`` of the follower."""

    __slots__ = ("R", "R_t", "contact_P", "p", "p_t", "status", "ticks", "tip", "v", "w")

    def __init__(self) -> None:
        self.p_t = self.p = self.tip = np.zeros(3)
        self.R_t = self.R = np.eye(3)
        self.v = self.w = np.zeros(3)
        self.contact_P = np.zeros(6)
        self.status = "ok"
        self.ticks = 0


class SlaveSide:
    """``arm`` the follower, ``registration`` master -> patient, ``tissue`` (or None) with a
    ``wrench(tip, R, v_tip, w)`` method, ``tip_B`` the blade tip in the tool frame (m, slave
    scale); ``guard`` the passivity guard's slave port (None: unguarded); ``heartbeat_s`` the
    silence (s) after which the master is lost; ``hooks`` see this side around each tick;
    ``limits`` what a real master can ask (:class:`~teleop.tick.plausible.CommandLimits`): a
    command past them is refused and counted, and the arm holds (status ``implausible_command``)
    until a command comes with the clutch open."""

    def __init__(self, arm: SlaveArm, registration: Registration, tissue: Any = None,
                 tip_B: Sequence[float] = (0.0, 0.0, 0.0),
                 guard: SlaveGuard | None = None, heartbeat_s: float = HEARTBEAT_S,
                 hooks: Sequence[Hook] = (), limits: CommandLimits | None = None,
                 contact_plane: bool = True, wall: bool = False, probe_N: float = 0.5) -> None:
        self.arm, self.reg, self.tissue = arm, registration, tissue
        #: the contact plane estimated from the measured force and the tip's motion (None: not sent)
        #: model-mediated (the master renders the plane as its own wall): the plane anchored on the
        #: surface, and the tip pressed no harder than the master's wall, or ``probe_N`` (N, P) on a
        #: surface the master has not felt yet; the estimate sure after 2 um along the normal (a
        #: stiff surface is pressed no further than the probe force takes it)
        self.wall = bool(wall) and contact_plane and tissue is not None
        self.estimator = (PlaneEstimator(arm.dt, excursion_m=2e-6 if self.wall else 2e-5)
                          if contact_plane and tissue is not None else None)
        self._touched_s = -math.inf    # when the tip last touched the surface (s)
        self._surface: tuple[np.ndarray, float, float] | None = None  # located: normal, offset (m), k (N/m)
        self._plane_c: float | None = None  # the surface's offset located with the estimate's stiffness (m)
        self._still = False  # the target is the pose the arm held as the clutch went out
        self._wall_N = 0.0  # the master's wall force in the last command followed (N, M)
        if not (math.isfinite(probe_N) and probe_N >= 0.0):
            raise ValueError(f"slave side: probe_N must be a finite force >= 0 N, got {probe_N!r}")
        self.probe_N = float(probe_N)
        self.pressed_less = 0          # ticks whose target was moved out of the surface (model-mediated)
        self.tip_B = np.asarray(tip_B, dtype=float)
        self._tip_at_origin = not self.tip_B.any()
        self._written_damping = hasattr(tissue, "damping")  # the model writes its damping out
        self.guard, self.hooks = guard, list(hooks)
        self.heart = HeartbeatState(heartbeat_s)
        self.last_seq = 0              # the newest command taken (its seq)
        self.without_command = 0       # ticks with no new command
        self.skipped = 0               # commands never followed (a newer one came first)
        self.tick_ns = 0               # the last tick's CPU time, hooks excluded (ns)
        self.statuses: dict[str, int] = {}  # ticks per status
        self.check = CommandCheck(limits if limits is not None else CommandLimits(), arm.dt)
        self._refusing: str | None = None  # why the last command was refused: held until the clutch opens
        self._rows = arm.qp.rows  # the fixture's rows (RowStack), the same the master evaluates
        self.state = SlaveState()
        self._target: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._seq = 0
        self._stopped = False  # held at a joint limit that cost the fixture, until the clutch opens
        self._resting = np.zeros(arm.nv, dtype=bool)  # joints the start pose put on a stop (set by reset)

    def reset(self, p_M: np.ndarray, R_M: np.ndarray) -> str:
        """Place the arm at the mapped master pose (inverse kinematics); returns its status."""
        p, R, _, _ = self.reg.target(p_M, R_M, np.zeros(3), np.zeros(3))
        status = self.arm.reset((p, R))
        self._resting = self.arm.limits.at_limit(self.arm.q, self.arm.dt)
        self._stopped = self._still = False
        return status

    def stats(self) -> dict:
        """Counters for the run's summary: ``slave_qp_retries``, the ticks whose QP the exact
        active-set solver finished after the configured solver stopped short."""
        return {"slave_qp_retries": int(self.arm.qp.retries)}

    def tick(self, i: int, t_s: float, link: SlaveEnd) -> ContactFeedback:
        """The slave's half of tick ``i`` at time ``t_s`` (s): the newest command taken from
        ``link``, the heartbeat checked, the command followed through the guard (or the joints
        held while the master is lost) and the reply sent. Returns the reply."""
        for h in self.hooks:
            h.before_tick(i, t_s, self)
        t0 = perf_counter_ns()
        cmd = link.receive_command(t_s)
        if cmd is not None and cmd.t_s < 0:
            cmd = None  # a hello (the two-process handshake): nothing to follow
        why = (self.check.energy_reason(cmd) or self.check.wall_reason(cmd, float(self.reg.force_scale))
               if cmd is not None else None)
        if why is not None:  # not a real master's: neither the guard nor the follower sees it
            self._refusing, cmd = why, None
        lost = self.heart.update(link.clock(t_s), link.last_heard_s("slave"))
        if cmd is not None and not lost:
            self.skipped += max(0, cmd.seq - self.last_seq - 1)
            self.last_seq = cmd.seq
        self.without_command += cmd is None
        reply = self.hold(t_s) if lost else self._follow_guarded(cmd, t_s)
        link.send_feedback(reply)
        if self.guard is not None:
            self.guard.observe()
        self.tick_ns = perf_counter_ns() - t0
        st = self.state.status
        self.statuses[st] = self.statuses.get(st, 0) + 1
        self.heart.motion(self.state.p, math.hypot(*self.arm.qd.tolist()))
        for h in self.hooks:
            h.after_tick(i, t_s, self)
        return reply

    def _follow_guarded(self, cmd: ToolCommand | None, t_s: float) -> ContactFeedback:
        if self.guard is None:
            return self.follow(cmd, t_s)
        reply = self.follow(self.guard.command(cmd, t_s), t_s)
        return self.guard.reply(reply, self._wall_normal())

    def _wall_normal(self) -> np.ndarray | None:
        """The normal (3,) of the surface the tip is on, when the master renders it as a wall."""
        est = self.estimator
        return est.n if self.wall and est is not None and est.in_contact else None

    def _locate_surface(self, tip: np.ndarray, F: np.ndarray, t_s: float) -> None:
        """Model-mediated: the surface the tip is on, from this tick's measured force, while in
        contact: its normal n, the offset c = n . tip + f_n / k where the force is zero (exact at
        rest for a linear surface, whatever the estimate's own offset), and k the larger of the
        estimate's stiffness (once confident) and the secant since the first touch. Bounding the
        target with the larger stiffness corrects by at most the whole force error each tick (a
        smaller one overshoots: at half the true stiffness the bound's loop rings). Off the
        surface the remembered one, never above the tip (the tip is outside it). The plane sent
        to the master (:meth:`_surface_plane`) is located with the estimate's own stiffness."""
        est = self.estimator
        assert est is not None
        n = est.n
        s = float(n @ tip)
        if est.in_contact:
            fn = float(n @ F)
            k_sec = max(fn, 0.0) / max(est.first_touch_m - s, SECANT_DEPTH_MIN_M)
            k_est = est.k if est.confidence > 0.0 else 0.0
            k = max(k_est, k_sec)
            if not k > 0.0:
                self._surface = None
                return
            self._surface = (n, s + fn / k, k)
            self._plane_c = s + fn / k_est if k_est > 0.0 else None
            self._touched_s = t_s
        elif self._surface is not None:
            n, c, k = self._surface
            self._surface = (n, min(c, s), k)
            if self._plane_c is not None:
                self._plane_c = min(self._plane_c, s)

    def _surface_plane(self, t_s: float) -> np.ndarray:
        """The reply's plane, model-mediated: the estimate anchored on the located surface while
        in contact, and after the tip left it (never above the tip: see :meth:`_locate_surface`)
        for as long as the slave's own bound keeps it (:meth:`_forgotten`): a bounce off the
        surface does not take the master's wall away, which the hand would then push the master
        through, each bounce deeper (measured: behind a lost link's outages the wall's offset
        ratcheted to 3 mm and the slave pressed 18 N); NO_PLANE otherwise."""
        est = self.estimator
        if est is None or self._plane_c is None or not est.confidence > 0.0:
            return NO_PLANE
        remembered = not est.in_contact
        if remembered and (self._surface is None or self._forgotten(t_s)):
            return NO_PLANE
        return est.plane(self._plane_c * est.n, remembered)

    def _forgotten(self, t_s: float) -> bool:
        """Model-mediated: the surface the tip left is let go: WALL_MEMORY_S after the last touch,
        unless the master still presses its wall (the last command's ``wall_N`` > 0). Let go under a
        master pressing its wall, the bound dropped and the arm plunged to the master's pose, past
        the wall's offset (measured: 14.6 N on a 100 kN/m wall after an arm hovering 2 um off it
        for 0.2 s); kept, a surface that is gone is a wall the hand feels until it backs off."""
        return t_s - self._touched_s > WALL_MEMORY_S and not self._wall_N > 0.0

    def _pressed_no_harder(self, target: tuple, wall_N: float, t_s: float) -> tuple:
        """Model-mediated: the target (p, R, v, w) moved out along the surface's normal so that
        the estimated force at its tip is at most the master's wall's (``wall_N``, N in M), or
        the probe force on a surface the master has not felt; its velocity into the surface
        dropped. Unchanged while the estimate is not confident, and once the surface is let go
        (:meth:`_forgotten`; a bounce keeps the surface: the target would plunge)."""
        est = self.estimator
        if est is None or self._surface is None or self._forgotten(t_s):
            return target
        n, c, k = self._surface
        p, R, v, w = target
        tip = p if self._tip_at_origin else p + R @ self.tip_B
        allowed = max(wall_N / float(self.reg.force_scale), self.probe_N) / k
        # where the tip ends up for a target: the arm's last offset from its target along n (its
        # steady tracking error is of the order of a stiff surface's whole allowed depth)
        lag = 0.0
        if self._target is not None and self.state.ticks:
            p0, R0 = self._target[0], self._target[1]
            lag = float(n @ (self.state.tip - (p0 if self._tip_at_origin else p0 + R0 @ self.tip_B)))
            lag = min(max(lag, -TRACK_LAG_MAX_M), TRACK_LAG_MAX_M)
        excess = c - float(n @ tip) - lag - allowed
        if not excess > 0.0:
            return target
        self.pressed_less += 1
        vn = float(n @ v)
        return p + excess * n, R, (v - vn * n if vn < 0.0 else v), w

    def hold(self, t_s: float) -> ContactFeedback:
        """The safe state for one tick (the master is lost): no command followed, the joints
        commanded to stop where they are, the guard's port counting the tick with no command; the
        reply says ``link_lost`` (the rest as measured: wrench, damping, energy)."""
        if self.guard is not None:
            self.guard.command(None, t_s)
        reply = self.follow(None, t_s, hold=True)
        if self.guard is not None:
            reply = self.guard.reply(reply)
        self.state.status = "link_lost"
        return replace(reply, status="link_lost")

    def add_hooks(self, *hooks: Hook) -> None:
        """More hooks, after those given when the side was made."""
        self.hooks.extend(hooks)

    def summary(self) -> dict:
        """This side's part of a run's summary (:func:`teleop.tick.verdict.run_summary`)."""
        out = {"slave_statuses": dict(self.statuses), "heartbeat": self.heart.summary(),
               **({"pressed_less_ticks": self.pressed_less} if self.wall else {}),
               "last_command_seq": self.last_seq, "ticks_without_command": self.without_command,
               "commands_skipped": self.skipped, "commands_refused": dict(self.check.refused), **self.stats()}
        if self.guard is not None:
            out["passivity_slave"] = self.guard.summary()
        return out

    def project(self, p: np.ndarray, R: np.ndarray, v: np.ndarray,
                w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The target moved onto the patient-frame fixture
        (:func:`teleop.slave.projection.project_onto_fixture`)."""
        return project_onto_fixture(self._rows, p, R, v, w)

    def follow(self, cmd: ToolCommand | None, t_s: float, hold: bool = False) -> ContactFeedback:
        """One tick toward the newest command (see the module docstring); ``hold``: the safe
        state instead (the joints stop where they are, no command followed; a lost link)."""
        s = self.state
        if hold:
            p, R = self.arm.tool_pose()
            self._target = (p, R, np.zeros(3), np.zeros(3))
            self._still = False
        elif cmd is not None and cmd.clutch and self._refusing is None:
            self._still = False
            target = self.reg.target(cmd.p_m, cmd.R, cmd.v_m_s, cmd.w_rad_s)
            self._refusing = self.check.pose_reason(cmd, target[0], target[1])
            if self._refusing is None:
                if self.wall:
                    self._wall_N = cmd.wall_N
                    target = self._pressed_no_harder(target, cmd.wall_N, t_s)
                self._target = self.project(*target)
            else:  # no real master asks this: hold where the arm is
                p, R = self.arm.tool_pose()
                self._target = (p, R, np.zeros(3), np.zeros(3))
        elif cmd is not None or self._target is None:  # clutch out, or nothing yet: hold still
            # model-mediated: held where it was as the clutch went out, so that a stiff wall
            # pressing on the tool does not push it off tick by tick (it came back onto it at 11 N
            # after a held link); else where it is, read again
            if self._target is None or not (self._still and self.wall):
                p, R = self.arm.tool_pose()
                self._target = (p, R, np.zeros(3), np.zeros(3))
                self._still = True
        elif self._target[2].any() or self._target[3].any():  # a lost message: hold the last pose
            self._target = (self._target[0], self._target[1], np.zeros(3), np.zeros(3))
        p_t, R_t, v_t, w_t = self._target
        F = s.contact_P if s.ticks else None
        if cmd is not None and not cmd.clutch:
            self._stopped = False  # the operator let go: follow again
            self._refusing = None
            self.check.forget()
        if hold or self._stopped or self._refusing is not None:
            status = self.arm.hold(F)
            if not hold:
                status = "implausible_command" if self._refusing is not None else "joint_limit"
        else:
            status = self.arm.step(p_t, R_t, v_t, w_t, F)
            at = self.arm.limits.at_limit(self.arm.q, self.arm.dt)
            self._resting &= at  # a joint that leaves the stop it started on is watched from then on
            if status in _LIMIT_EXPLAINS and np.any(at & ~self._resting):
                # a joint at its stop: the task goes on with the other joints while they keep the
                # fixture; when it cost the fixture (rows relaxed), the joints hold from the next tick
                self._stopped = status == "fixtures_relaxed"
                status = "joint_limit"
        s.status = status
        p, R = self.arm.tool_pose()
        v, w = self.arm.tool_twist()
        if self._tip_at_origin:  # the shipped scalpels: the blade tip is the tool frame's origin
            d, tip, v_tip = _Z3, p, v
        else:
            d = R @ self.tip_B
            tip, v_tip = p + d, v + cross(w, d)
        contact = self.tissue.wrench(tip, R, v_tip, w) if self.tissue is not None else np.zeros(6)
        s.p_t, s.R_t, s.p, s.R, s.v, s.w, s.tip, s.contact_P = p_t, R_t, p, R, v, w, tip, contact
        s.ticks += 1
        at_origin = contact.copy()
        if not self._tip_at_origin:
            at_origin[3:] += cross(d, contact[:3])  # the tip's wrench moved to the tool frame origin
        twist = np.empty(6)
        twist[:3], twist[3:] = v, w
        damping = None
        if self.tissue is not None and contact.any():  # the contact's damping, for the master to render
            if self._written_damping:  # written out by the model
                damping = moved_to_origin(self.tissue.damping(tip, R, v_tip, w), d)
            else:
                damping = contact_damping(lambda V: self._wrench_at_origin(tip, R, d, V), twist)
        plane = None
        if self.estimator is not None:
            self.estimator.update(tip, v_tip, contact[:3])
            if self.wall:
                self._locate_surface(tip, contact[:3], t_s)
            # anchored where the master asked the tip to be: at rest there, the master feels what is measured
            plane = (self._surface_plane(t_s) if self.wall else
                     self.estimator.plane(p_t + (R_t @ self.tip_B if not self._tip_at_origin else _Z3)))
        self._seq += 1
        return ContactFeedback(self._seq, t_s, at_origin, s.status, -1 if cmd is None else cmd.seq,
                               damping_P=damping, twist_P=twist, plane_P=plane)

    def _wrench_at_origin(self, tip: np.ndarray, R: np.ndarray, d: np.ndarray, V: np.ndarray) -> np.ndarray:
        """The tissue's wrench (N, N*m, P) at the tool frame origin for the origin twist V (6,)."""
        v, w = V[:3], V[3:]
        W = self.tissue.wrench(tip, R, v + cross(w, d), w).copy()
        W[3:] += cross(d, W[:3])
        return W
