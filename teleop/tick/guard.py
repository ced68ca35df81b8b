"""The passivity guard (TDPA) at the two ends of the link, in the master's frame M.

:class:`MasterGuard` sits on the master side between the feedback path and the reference tool:
it observes the energy the channel puts out at the master port (the felt force times the tool's
velocity) and damps the felt force when the observer goes negative. The damped force is still the
force fed to the reference tool (eq. 4), so the tool's own fixture rows keep it on the fixture.
It stamps the master port's input energy into every outgoing command.

:class:`SlaveGuard` sits on the slave side between the link and the slave: it observes the energy
the channel puts out at the slave port (the contact wrench times the commanded velocity; with the
contact's damping rendered at the master, the model's offset F0 = W + D V instead, the force the
master's port counts too: the damper is passive where it is rendered, see
:mod:`teleop.tick.feedback`), corrects
the commanded velocity when the observer goes negative and adds the accumulated correction (the
position drift) to the commanded pose before the slave maps it; drift compensation pulls the offset
back with surplus energy only. The slave's fixture projection and QP rows act after the guard, so a
correction can never take the blade past the fixture. It stamps the slave port's input energy into
every reply, and adds the drift to the reply's wrench as a spring (``drift_stiffness`` times the
offset, mapped back to P): the master feels where the slave's target is, the hand works against
that spring, and the energy it puts in is what the slave's drift compensation then spends (the
slave port's books keep the contact wrench alone: the spring does no work on the environment).

Both ports work in M units: the slave maps its contact wrench with the registration's
``wrench_to_master`` (force_scale, torque_scale), so power at both ports is counted alike. See
:mod:`teleop.control.passivity` for the observers and controllers and their sources.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from teleop.control import passivity_kernels as kern
from teleop.control.mapping import Registration
from teleop.control.passivity import MasterPassivity, SlavePassivity, TdpaParams
from teleop.tick.messages import ContactFeedback, ToolCommand

_ZERO3 = np.zeros(3)  # the reply's normal off a wall: writable, as the estimate's normal is
# A command with nothing to follow passes these where a command passes its fields, which are
# read-only (teleop.tick.messages): a compiled kernel loads once per argument type signature, and a
# writable stand-in loaded guard_command again on the first tick without a command, mid-run
# (22 ms at 2 kHz, past the master's heartbeat).
_HOLD_V3, _HOLD_P3, _HOLD_R = np.zeros(3), np.zeros(3), np.eye(3)
for _a in (_HOLD_V3, _HOLD_P3, _HOLD_R):
    _a.flags.writeable = False
_UNUSED3, _UNUSED33 = np.zeros(3), np.zeros((3, 3))  # the pose outputs of a command with nothing to follow


def _vec3(x: ArrayLike) -> np.ndarray:
    """x as a float (3,) array for the kernels (broadcast as numpy would, or its error)."""
    a = np.asarray(x, dtype=float)
    return a if a.shape == (3,) else np.broadcast_to(a, (3,))


class MasterGuard:
    """The master port: ``feedback(wrench_M, twist_M, msg, t_s)`` -> the wrench to render."""

    def __init__(self, params: TdpaParams, log_capacity: int = 0) -> None:
        self.port = MasterPassivity(params, log_capacity)
        self.W_min_J = float("inf")  # the observer's lowest sum over the axes, seen at the ends of ticks (J)
        self.motion_scaled = 0  # ticks whose rendered motion the guard slowed to keep the port passive

    def observe(self) -> None:
        """At the end of the master side's tick: the observer's sum into the running minimum."""
        self.W_min_J = min(self.W_min_J, self.port.observer_sum())

    def summary(self) -> dict:
        """``dissipated_master_J`` (J, all axes) and ``W_master_min_J`` (J) so far."""
        return {"dissipated_master_J": self.port.dissipated_J,
                "W_master_min_J": self.W_min_J if self.W_min_J != float("inf") else 0.0,
                "motion_scaled_ticks": self.motion_scaled}

    @property
    def energy_J(self) -> np.ndarray:
        """(6,) J: the master port's input energy counted so far."""
        return self.port.energy_J

    @property
    def slows_motion(self) -> bool:
        """Whether this port scales the rendered motion (``[link] guard_slows_motion``)."""
        return self.port.params.enabled and self.port.params.slows_motion

    def motion_scale(self, twist_M: np.ndarray) -> float:
        """sigma in [0, 1]: the tool's twist after its step scaled by it keeps this port's
        observer >= 0 (:meth:`teleop.control.passivity.MasterPassivity.motion_scale`); counted in
        ``motion_scaled`` when below 1."""
        sigma = self.port.motion_scale(twist_M)
        if sigma < 1.0:
            self.motion_scaled += 1
        return sigma

    def energy_after(self, twist_M: np.ndarray) -> np.ndarray:
        """(6,) J: the input energy for the command sent this tick, with the work of the force
        rendered last counted at the tool's ``twist_M`` (6,) after its step."""
        return self.port.energy_after(twist_M)

    def drop_force(self) -> None:
        """The remote force is dropped (a lost link's safe state): nothing rendered any more."""
        self.port.f_channel = self.port.f_rendered = np.zeros(6)

    def feedback(self, wrench_M: np.ndarray, twist_M: np.ndarray, msg: ContactFeedback | None,
                 t_s: float) -> np.ndarray:
        """The felt wrench (6,: N, N*m, M) after damping, from the filtered feedback ``wrench_M``,
        the reference tool's ``twist_M`` (6,: m/s, rad/s) and the newest feedback ``msg`` (its
        ``energy_J``; None: hold the last)."""
        return self.port.step(wrench_M, twist_M, None if msg is None else msg.energy_J, t_s)


class SlaveGuard:
    """The slave port: ``command(cmd, t_s)`` before the slave follows, ``reply(fb)`` after."""

    def __init__(self, params: TdpaParams, registration: Registration, log_capacity: int = 0,
                 model_offset: bool = True) -> None:
        self.port = SlavePassivity(params, log_capacity)
        self.reg = registration
        self.model_offset = bool(model_offset)  # count F0 = W + D V (the master renders D locally)
        self.f_M = np.zeros(6)  # the newest contact wrench, in M (N, N*m)
        self.speed = np.zeros(6)  # |commanded twist| low-passed (drift_speed_tau_s), m/s and rad/s in M
        self.W_min_J = float("inf")  # the observer's lowest sum over the axes, at the ends of ticks (J)
        self.drift_max_m = self.drift_final_m = 0.0  # |position offset| (m in M)
        self._speed_for: TdpaParams | None = None  # the settings _speed_k was made from
        self._speed_k = 0.0
        self._reply_for: tuple[TdpaParams | None, Registration | None] = (None, None)  # _reply_prm's
        self._reply_prm = np.zeros(0)

    def observe(self) -> None:
        """At the end of the slave side's tick: the observer's minimum and the drift."""
        self.W_min_J, self.drift_final_m, self.drift_max_m = kern.slave_observe(self.port.block, self.W_min_J,
                                                                              self.drift_max_m)

    def summary(self) -> dict:
        """``dissipated_slave_J``, ``W_slave_min_J`` (J) and the drift ``drift_max_M_m``,
        ``drift_final_M_m`` (m in M) so far."""
        return {"dissipated_slave_J": self.port.dissipated_J,
                "W_slave_min_J": self.W_min_J if self.W_min_J != float("inf") else 0.0,
                "drift_max_M_m": self.drift_max_m, "drift_final_M_m": self.drift_final_m}

    @property
    def drift_M(self) -> np.ndarray:
        """(6,) the offset added to the master's pose (m, rad in M)."""
        return self.port.offset

    def command(self, cmd: ToolCommand | None, t_s: float) -> ToolCommand | None:
        """The command the slave follows: ``cmd`` with its twist corrected and its pose offset by
        the drift (None stays None: the slave holds, the observer still counts the tick)."""
        live = cmd if cmd is not None and cmd.clutch else None
        port = self.port
        received, E_remote = port.incoming(None if cmd is None else cmd.energy_J)
        out, v, speed = np.empty((kern.SLAVE_ROWS, 6)), np.empty(6), np.empty(6)
        if live is None:
            kern.guard_command(port.block, out, False, _HOLD_V3, _HOLD_V3, self.f_M, E_remote, received,
                               port.settings, self.speed, self._speed_gain(), _HOLD_P3, _HOLD_R, v, speed, _UNUSED3,
                               _UNUSED33)
            port.commit(out, t_s)
            self.speed = speed
            return cmd
        p, R = np.empty(3), np.empty((3, 3))
        kern.guard_command(port.block, out, True, live.v_m_s, live.w_rad_s, self.f_M, E_remote, received,
                           port.settings, self.speed, self._speed_gain(), live.p_m, live.R, v, speed, p, R)
        port.commit(out, t_s)
        self.speed = speed
        return ToolCommand(live.seq, live.t_s, p, R, v[:3], v[3:], live.clutch, live.energy_J, live.wall_N)

    def _speed_gain(self) -> float:
        """dt / (drift_speed_tau_s + dt): the commanded speed's low-pass, per tick."""
        p = self.port.params
        if p is not self._speed_for:
            self._speed_for, self._speed_k = p, p.dt_s / (p.drift_speed_tau_s + p.dt_s)
        return self._speed_k

    def _reply_settings(self) -> np.ndarray:
        """The reply's settings (:func:`teleop.control.passivity_kernels.reply_settings`), made
        again when the port's settings or the registration are others."""
        p, reg = self.port.params, self.reg
        if self._reply_for[0] is not p or self._reply_for[1] is not reg:
            self._reply_for = (p, reg)
            self._reply_prm = kern.reply_settings(p.drift_stiffness, p.drift_speed, reg.force_scale,
                                                  reg.torque_scale or 1.0, reg.scale)
        return self._reply_prm

    def reply(self, fb: ContactFeedback, wall_normal_P: np.ndarray | None = None) -> ContactFeedback:
        """``fb`` with the slave port's input energy and the drift spring added to its wrench
        (nothing added while the offset is zero); remembers the contact wrench for the next tick.
        ``wall_normal_P`` (3,): the normal of a surface the master renders as its own wall
        (model-mediated): the force along it is not the channel's and is left out of the port's
        books, as the master leaves it out of its own."""
        f_M = self.reg.wrench_to_master(fb.model_offset_P if self.model_offset else fb.wrench_P)
        wall = wall_normal_P is not None
        out = np.empty(14)  # the wrench (6) and the plane (8) to send
        kern.guard_reply(self.port.block, self.speed, self._reply_settings(), self.reg.X_PM_R, fb.wrench_P, fb.plane_P,
                         f_M, _vec3(wall_normal_P) if wall_normal_P is not None else _ZERO3, wall, out)
        self.f_M = f_M
        return ContactFeedback(fb.seq, fb.t_s, out[:6], fb.status, fb.command_seq, self.port.energy_J,
                               fb.damping_P, fb.twist_P, out[6:])


def tdpa_params(link: Any, dt_s: float, mass_kg: float, inertia_kgm2: Any, enabled: bool) -> TdpaParams:
    """TdpaParams from a scene's [link] table: the master damping cap ``link.alpha_max`` times what
    the tool's explicit step takes (mass/dt on force axes, the smallest principal inertia/dt on
    torque axes), so the damping can never destabilise the tool itself; the reflected drift
    spring ``drift_gain`` times that cap (1/s x N*s/m = N/m; N*m/rad on torque axes): the spring
    pulls the master back at about the drift rate against the largest damping it may feel."""
    J = np.asarray(inertia_kgm2, dtype=float)
    j_min = float(np.min(np.linalg.eigvalsh(J))) if J.ndim == 2 else float(np.min(J))
    cap = (mass_kg / dt_s,) * 3 + (j_min / dt_s,) * 3
    return TdpaParams(dt_s=dt_s, enabled=enabled, alpha_max=tuple(link.alpha_max * c for c in cap),
                      dv_max=link.dv_max_m_s, drift_gain=link.drift_gain,
                      drift_stiffness=tuple(link.drift_gain * link.alpha_max * c for c in cap),
                      slows_motion=bool(getattr(link, "guard_slows_motion", False)))
