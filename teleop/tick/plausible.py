"""Plausibility at each end of the link: a side acts only on what its peer could physically send.

Authentication (:mod:`teleop.link`) says who sent a message; these checks say whether a real peer
could have sent it. The slave (:class:`CommandCheck`) refuses a target outside the arm's reach, a
rotation that is not one, a jump faster than a hand moves the tool in the time the master's clock
says passed, and an energy count that is not finite, runs backwards or grows faster than the
master port could put energy in. The master (:class:`ReplyCheck`) refuses a contact wrench or
damping beyond what the slave's arm and contact could produce, and the same energy rules. A refused
message is counted by reason and never reaches the guard, the follower or the tool; what the side
does then is its own safe state (:meth:`SlaveSide.follow`, :meth:`MasterSide.tick`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from teleop.tick.kernels import energy_code, pose_code, reply_code
from teleop.tick.messages import ContactFeedback, ToolCommand


@dataclass(frozen=True)
class CommandLimits:
    """What a real master can ask of this slave (slave units, patient frame): targets within
    ``reach_m`` of ``center_m`` (the arm's first joint), moving at most ``speed_m_s`` and turning at
    most ``rate_rad_s`` between commands (by the master's clock), a port energy growing at
    most ``power_W`` per axis, and a contact wall rendered at most ``wall_force_N`` (at the
    slave's scale: what a real slave could ever have reported, :class:`ReplyLimits`)."""

    center_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    reach_m: float = math.inf
    speed_m_s: float = 2.0
    rate_rad_s: float = 30.0
    power_W: float = 1e3
    wall_force_N: float = 200.0


@dataclass(frozen=True)
class ReplyLimits:
    """What a real slave can send back (slave units, at its tool origin, as the reply carries
    them): a wrench of at most ``force_N`` and ``torque_Nm``, a contact damping of at most
    ``damping`` per entry (N*s/m or N*m*s/rad), and a port energy (master units, as counted)
    growing at most ``power_W`` per axis."""

    force_N: float = 200.0
    torque_Nm: float = 20.0
    damping: float = 1e6
    power_W: float = 1e3


ENERGY_REASONS = (None, "energy_not_finite_or_negative", "energy_ran_backwards", "energy_too_fast")
POSE_REASONS = (None, "not_a_rotation", "out_of_reach", "jump_too_far", "turn_too_fast")
REPLY_REASONS = (None, "wrench_too_large", "damping_too_large")
_Z3, _I3, _Z6 = np.zeros(3), np.eye(3), np.zeros(6)


def _energy_reason(E: np.ndarray, last: np.ndarray | None, dt_s: float, power_W: float) -> str | None:
    """Why the port energy ``E`` (6,) J cannot follow ``last`` after ``dt_s`` s, or None."""
    return ENERGY_REASONS[energy_code(E, _Z6 if last is None else last, last is not None, dt_s, power_W)]


class CommandCheck:
    """The slave's check of each command (see the module docstring); ``dt_s`` the period (s), the
    least time between two commands. :meth:`energy_reason` for every command (the guard counts
    them all), :meth:`pose_reason` for those the slave would follow."""

    def __init__(self, limits: CommandLimits, dt_s: float) -> None:
        self.limits, self.dt = limits, float(dt_s)
        self.center = np.asarray(limits.center_m, dtype=float)
        self.refused: dict[str, int] = {}
        self._pose: tuple[float, np.ndarray, np.ndarray] | None = None  # t, p, R of the last followed
        self._energy: tuple[float, np.ndarray] | None = None  # t, energy of the last accepted

    def _refuse(self, why: str | None) -> str | None:
        if why is not None:
            self.refused[why] = self.refused.get(why, 0) + 1
        return why

    def energy_reason(self, cmd: ToolCommand) -> str | None:
        """Why the command's time or energy is implausible, or None (it becomes the reference)."""
        if self._energy is None:
            why = _energy_reason(cmd.energy_J, None, 0.0, self.limits.power_W)
        elif cmd.t_s < self._energy[0]:
            why = "time_ran_backwards"
        else:
            t0, E0 = self._energy
            why = _energy_reason(cmd.energy_J, E0, max(cmd.t_s - t0, self.dt), self.limits.power_W)
        if why is None:
            self._energy = (cmd.t_s, cmd.energy_J)
        return self._refuse(why)

    def wall_reason(self, cmd: ToolCommand, force_scale: float) -> str | None:
        """Why the command's wall force (``wall_N``, master units; ``force_scale`` master:slave)
        is implausible, or None: beyond what a real slave could have reported."""
        return self._refuse("wall_force_too_large" if cmd.wall_N / force_scale > self.limits.wall_force_N else None)

    def pose_reason(self, cmd: ToolCommand, p_P: np.ndarray, R_P: np.ndarray) -> str | None:
        """Why the command's target (``p_P`` m, ``R_P`` in the patient frame) is implausible, or
        None (it becomes the reference for the next)."""
        lim, last = self.limits, self._pose
        t0, p0, R0 = last if last is not None else (cmd.t_s, _Z3, _I3)
        why = POSE_REASONS[pose_code(cmd.R, p_P, self.center, lim.reach_m, last is not None, p0, R0, R_P,
                                     max(cmd.t_s - t0, self.dt), lim.speed_m_s, lim.rate_rad_s)]
        if why is None:
            self._pose = (cmd.t_s, p_P, R_P)
        return self._refuse(why)

    def forget(self) -> None:
        """The operator let go (clutch out): the next target is checked against the reach only."""
        self._pose = None


class ReplyCheck:
    """The master's check of each reply before it is felt (see the module docstring)."""

    def __init__(self, limits: ReplyLimits, dt_s: float) -> None:
        self.limits, self.dt = limits, float(dt_s)
        self.refused: dict[str, int] = {}
        self._last: tuple[float, np.ndarray] | None = None  # t, energy

    def reason(self, msg: ContactFeedback) -> str | None:
        """Why the reply is implausible, or None (it becomes the reference for the next)."""
        lim = self.limits
        why = REPLY_REASONS[reply_code(msg.wrench_P, msg.damping_P, lim.force_N, lim.torque_Nm, lim.damping)]
        if why is None:
            t0, E0 = self._last if self._last is not None else (msg.t_s, None)
            if msg.t_s < t0:
                why = "time_ran_backwards"
            else:
                why = _energy_reason(msg.energy_J, E0, max(msg.t_s - t0, self.dt), lim.power_W)
        if why is not None:
            self.refused[why] = self.refused.get(why, 0) + 1
            return why
        self._last = (msg.t_s, msg.energy_J)
        return None
