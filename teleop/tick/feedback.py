"""The force-feedback path on the master side: the slave's contact wrench, mapped into the master
frame by the registration, low-passed, and its damping rendered here, without delay.

The cutting force is steep in velocity (about 2000 N*s/m below 1 mm/s at the slave); fed to a light
reference tool integrated explicitly, one tick late or more, it makes a limit cycle: the stale
stick keeps pushing after the tool has stopped, so the tool is thrown back. A first-order low-pass
at ``cutoff_hz`` (20 Hz by default; 0: off) kept the one-tick loop of one process still, but one
tick more (a 1 ms round trip, a late reply over a network) already tipped the cut into a 9 Hz
stick-slip cycle, guard or no guard.

So the slave also sends the contact's local damping D (:mod:`teleop.contact.damping`) and the
twist V_s it was taken at, and the master renders the contact as that local model, in the manner
of model-mediated teleoperation (Mitra and Niemeyer 2008; Passenberg, Peer and Buss 2010):

    W = W_s + D (V_s - V+) = F0 - D V+,   F0 = W_s + D V_s,

the delayed wrench corrected by the damping for the difference between the slave's twist then and
the tool's twist V+ at the end of this step, solved implicitly (backward Euler on the free tool,
mass matrix M: (M + dt D) V+ = M V + dt (F + F0), F the hand's wrench plus the tool's own effects
at its present state, as the step applies them: leaving out the tool's own damping made a steady
turn read as an acceleration, and the curved cut turned 0.20 rad instead of 0.32). The steep part
of the contact is then felt at the tool's own present velocity, and an implicit damper cannot throw
the tool back however steep it is; in steady sliding V+ = V_s and W = W_s.

What crosses the link is then the model's offset F0 (a force) and a damper; the damper is passive
wherever it is rendered, so the passivity guard (:mod:`teleop.tick.guard`) observes and damps F0 at
both ports, and :meth:`FeedbackPath.update` returns F0 for it. F0 and D go through the same
low-pass (F0 filtered as the slave counted it: filtering W_s, D and V_s apart and multiplying made
the two ports disagree at the stick, and the guard drifted 0.5 mm at a 1 ms round trip). A reply
without contact carries D = 0 (nothing rendered beyond W_s, and the filtered D, once it has
decayed, is zero again); a D that is not positive semidefinite is not rendered (counted in
``refused``). A tick with no new message holds the last model.

The contact's stiffness is the same mechanism one order down. The slave estimates the surface it
touches from its own force and tip motion (:mod:`teleop.contact.estimate`: a plane, its normal n,
stiffness k and the estimate's confidence) and sends it with an anchor a: where its tip was, less
the guard's drift, i.e. where the master's tip was when it asked for that pose. The master renders

    W = F0 + k' n max(n . (a - x_tip), -n . F0 / k'),   k' = confidence x k (in M units),

the reported force corrected by the wall's stiffness for how far the master's tip has moved into
(or out of) the surface since: a unilateral spring, so the master leaves the surface freely and
the normal force never pulls it in. At rest the slave catches up, a = x_tip and W = F0: what the
operator feels in steady state is what the slave measures, whatever the estimate; the estimate
only shapes how quickly the wall is felt, which is now at the master's own rate, not a round trip
later. The spring's part at the present pose is part of the channel's force the guard observes
(:meth:`update`); its change over the step is rendered implicitly with the damping
((D + dt K) in place of D, K = k' n n^T at the tip, moved to the origin), so a stiff estimate
cannot make the light tool's step unstable (backward Euler on a spring dissipates).

Model-mediated (``wall``, ``[link] model_mediated``): the slave anchors its plane on the surface
it locates from its measured force (where the force is zero) rather than where its tip is held,
and the master
renders the plane as a wall of its own (:class:`~teleop.contact.wall_model.PassiveWall`): a fixed
spring in the master's frame, its updates applied passively through an energy tank fed by the
contact damping rendered here. While a wall is held, the channel's force along its normal is not
rendered (the wall stands for it) and the guard observes the rest only; the wall, like the damper,
is a local passive element, rendered whole and stepped implicitly ((D + dt K) as above). Each
command carries the wall's normal force (:meth:`wall_force`): the slave presses no harder.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from teleop.contact.damping import moved_to_origin
from teleop.contact.wall_model import PassiveWall
from teleop.control.kernels import render_local_damping
from teleop.control.mapping import Registration
from teleop.dynamics.effects import total_wrench
from teleop.tick.kernels import damper_ok, lowpass
from teleop.tick.messages import ContactFeedback
from teleop.tick.ports import ToolState

_ZERO66 = np.zeros((6, 6))
_ZERO66.flags.writeable = False
_D_FLOOR = 1e-9  # N*s/m: a filtered damping below this after the contact ended is zero
_ZERO6 = np.zeros(6)
_ZERO6.flags.writeable = False


def _at_origin(f: np.ndarray, d: np.ndarray) -> np.ndarray:
    """A force ``f`` (3,) N at the tip, ``d`` (3,) m from the tool's origin: its wrench (6,) there."""
    out = np.empty(6)
    out[:3] = f
    out[3:] = np.cross(d, f)
    return out


def _normal_stiffness(n: np.ndarray, k: float, d: np.ndarray) -> np.ndarray:
    """(6, 6) at the tool's origin: a spring of ``k`` N/m along unit ``n`` at the tip ``d`` m away."""
    K_tip = np.zeros((6, 6))
    K_tip[:3, :3] = k * np.outer(n, n)
    return moved_to_origin(K_tip, d)


class FeedbackPath:
    """``update(msg)`` -> the wrench (6,: N, N*m, master world, at the reference tool's origin)
    the slave reported; ``render(wrench, tool, f_other, dt)`` -> the wrench the tool steps under.
    ``local_damping`` False renders the reported wrench alone."""

    def __init__(self, registration: Registration, cutoff_hz: float, dt_s: float, local_damping: bool = True,
                 tip_B: Any = (0.0, 0.0, 0.0), contact_plane: bool = True, wall: bool = False):
        if not (math.isfinite(cutoff_hz) and cutoff_hz >= 0):
            raise ValueError(f"feedback cutoff: expected a number >= 0 Hz, got {cutoff_hz!r}")
        self.reg = registration
        self.alpha = 1.0 - math.exp(-2.0 * math.pi * cutoff_hz * dt_s) if cutoff_hz > 0 else 1.0
        self.dt = dt_s
        self.local_damping = bool(local_damping)
        self.contact_plane = bool(contact_plane) and self.local_damping
        self.tip_B = np.asarray(tip_B, dtype=float)  # the tool's tip in its body frame (m, M units)
        self.wall = PassiveWall() if wall and self.contact_plane else None  # model-mediated: the plane as a wall
        self.wall_offset_max_m = 0.0        # the wall's largest offset from the slave's surface (m, M)
        self.refused = 0                    # replies whose damping was not positive semidefinite
        self.reset()

    def reset(self) -> None:
        """Empty the filter and the model (the master's safe state on a lost link): the force
        comes back from zero. Every field of the path's state is set here and only here."""
        self.wrench_M = np.zeros(6)         # the reported wrench W_s, filtered (N, N*m)
        self.offset_M = np.zeros(6)         # the model's offset F0 = W_s + D V_s, filtered (N, N*m)
        self.damping_M = _ZERO66            # D, filtered (N*s/m, N*m*s/rad: master units)
        self._target = np.zeros(6)
        self._offset = np.zeros(6)
        self._D = _ZERO66
        self._plane: tuple[np.ndarray, np.ndarray, float] | None = None  # n (3,), a (3,) m, k' N/m, in M
        self.spring_K: np.ndarray | None = None  # the spring's stiffness at the origin while it acts (6, 6)
        self.wall_W = _ZERO6                # the wall's wrench at the origin (N, N*m, M; model-mediated)
        if self.wall is not None:
            self.wall.reset()

    def update(self, msg: ContactFeedback | None, state: ToolState | None = None) -> np.ndarray:
        """The newest reply (None: hold the last) filtered in; returns the force the channel
        brings to the master, F0 = W_s + D V_s (the model's offset; W_s alone without the local
        damping), plus the contact plane's spring at the tool's ``state`` (the tool as the tick
        read it; None: no spring): what the passivity guard observes and damps before
        :meth:`render`. F0 is filtered as it is (not from a filtered W_s, D and V_s), so the
        master's port counts the force the slave's port counted."""
        if msg is not None:
            self._target = self.reg.wrench_to_master(msg.wrench_P)
            self._offset, self._D = self._target, _ZERO66
            if self.local_damping and np.any(msg.damping_P):
                self._take_model(msg)
            if self.contact_plane:
                self._take_plane(msg.plane_P)
        a = self.alpha
        self.wrench_M = lowpass(self.wrench_M, self._target, a)
        if not self.local_damping:
            return self.wrench_M
        self.offset_M = lowpass(self.offset_M, self._offset, a)
        if self._D is _ZERO66 and (self.damping_M is _ZERO66 or float(np.abs(self.damping_M).max()) <= _D_FLOOR):
            self.damping_M = _ZERO66  # decayed after the contact ended: nothing left to render
        else:
            self.damping_M = lowpass(self.damping_M, self._D, a)
        self.spring_K = None
        if self.wall is not None:
            return self._wall_step(state)
        if self._plane is None or state is None:
            return self.offset_M
        return self.offset_M + self._spring(state)

    def _tip(self, state: ToolState) -> tuple[np.ndarray, np.ndarray]:
        """The tool's tip (3,) m and its offset from the origin d = R tip_B (3,) m, in M."""
        d = state[1] @ self.tip_B
        return state[0] + d, d

    def _wall_step(self, state: ToolState | None) -> np.ndarray:
        """Model-mediated: the wall moved passively toward the newest plane at the tool's state,
        its wrench and stiffness kept for :meth:`render`; returns the channel's force less its
        part along the wall's normal (what the guard observes)."""
        wall, out = self.wall, self.offset_M
        assert wall is not None
        self.wall_W = _ZERO6
        if state is None:
            return out
        D = self.damping_M
        if D is not _ZERO66:  # the contact damping rendered last tick: energy dissipated, the tank's
            V = state[2]
            wall.credit(self.dt * float(V @ D @ V))
        x, d = self._tip(state)
        wall.update(x)
        self.wall_offset_max_m = max(self.wall_offset_max_m, wall.offset_m)
        n = wall.n
        if n is None:
            return out
        out = out - _at_origin(float(n @ out[:3]) * n, d)  # the wall stands for the normal force
        depth = wall.depth(x)
        if depth > 0.0:
            self.wall_W = _at_origin(wall.k * depth * n, d)
            self.spring_K = _normal_stiffness(n, wall.k, d)
        return out

    def wall_summary(self) -> dict:
        """Model-mediated: the wall's offset from the slave's surface, largest and at the end
        (m, M: the master's surface less the slave's), and the tank (J)."""
        w = self.wall
        return {} if w is None else {"offset_max_M_m": self.wall_offset_max_m, "offset_final_M_m": w.offset_m,
                                     "tank_J": w.tank_J}

    def wall_force(self, state: ToolState) -> float:
        """The wall's normal force (N, >= 0, M) with the tool at ``state``: what the next command
        carries (0 without a wall)."""
        return 0.0 if self.wall is None else self.wall.force(self._tip(state)[0])

    def _take_plane(self, plane_P: np.ndarray) -> None:
        """The slave's contact plane (normal, anchor, stiffness, confidence in P) in M, or None."""
        k = float(plane_P[6] * plane_P[7])
        if not k > 0.0:
            self._plane = None
            if self.wall is not None:
                self.wall.aim(None)
            return
        reg = self.reg
        n = reg.X_PM_R.T @ plane_P[:3]
        self._plane = (n, reg.point_to_master(plane_P[3:6]), k * float(reg.force_scale) / float(reg.scale))
        if self.wall is not None:
            n, a, k_M = self._plane
            self.wall.aim(n, float(n @ a), k_M)

    def _spring(self, state: ToolState) -> np.ndarray:
        """The plane's unilateral spring (6,: N, N*m at the origin, M) at the tool's ``state``;
        sets ``spring_K`` while the spring acts (the normal force is not clipped at zero)."""
        n, a, k = self._plane  # type: ignore[misc]  # only called with a plane
        p, R, _ = state
        d = R @ self.tip_B
        into = float(n @ (a - p - d))          # m: how far the tip is past the anchor, into the surface
        f0n = float(n @ self.offset_M[:3])     # N: the reported force along the normal
        fn = k * into
        if fn <= -f0n:                         # the model's normal force would pull: none at all
            return _at_origin(-f0n * n, d)
        self.spring_K = _normal_stiffness(n, k, d)
        return _at_origin(fn * n, d)

    def _take_model(self, msg: ContactFeedback) -> None:
        with np.errstate(over="ignore", invalid="ignore"):  # a hostile size is refused just below
            D = self.reg.damping_to_master(msg.damping_P)
            offset = self.reg.wrench_to_master(msg.model_offset_P)
        if not damper_ok(D, offset):
            self.refused += 1  # not a damper, or so large its products overflow: the wrench alone
            return
        self._D, self._offset = D, offset

    def render(self, channel_M: np.ndarray, tool: Any, f_other_W: np.ndarray, dt_s: float,
               state: ToolState | None = None, gain: float = 1.0) -> np.ndarray:
        """The wrench (6,: N, N*m, M) the ``tool`` steps under from the slave: the channel's force
        ``channel_M`` (:meth:`update`'s, after the guard) minus the contact's damping at the tool's
        twist after this step, D V+, solved implicitly (see the module docstring); ``gain`` in
        [0, 1] scales the channel's force alone (the master's ramp after a lost link: the damper is
        passive and is rendered whole, so a tool let go after a hold meets the contact's
        resistance at once); ``f_other_W`` (6,) the hand's
        wrench (the tool's own effects are added here); ``state`` the tool as the tick read it (None:
        read here).
        Returns ``gain * channel_M`` when there is no damping to render."""
        D = self.damping_M
        if self.spring_K is not None:  # the spring's change over the step, implicitly (see the module docstring)
            D = D + self.dt * self.spring_K
        if self.wall is not None and self.wall.n is not None:  # a local passive element: rendered whole
            channel_M = (channel_M if gain == 1.0 else gain * channel_M) + self.wall_W
            gain = 1.0
        if not self.local_damping or D is _ZERO66 or not D.any():
            return channel_M if gain == 1.0 else gain * channel_M
        if state is None:
            p, R = tool.pose()
            V = np.concatenate(tool.twist())
        else:
            p, R, V = state
        f = total_wrench(tool.model.effects, p, R, V[:3], V[3:], tool.t, f_other_W)  # the step's own forces too
        body = tool.body
        if gain != 1.0:
            channel_M = gain * channel_M
        ok, W = render_local_damping(body.mass_kg, body.J, R, V, f, channel_M, D, dt_s)
        return W if ok else gain * self.wrench_M  # singular: the reported wrench alone
