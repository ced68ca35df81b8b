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

from teleop.control.mapping import Registration
from teleop.control.passivity import MasterPassivity, SlavePassivity, TdpaParams
from teleop.dynamics.kernels.so3 import exp3
from teleop.tick.messages import ContactFeedback, ToolCommand

_ZERO6 = np.zeros(6)


class MasterGuard:
    """The master port: ``feedback(wrench_M, twist_M, msg, t_s)`` -> the wrench to render."""

    def __init__(self, params: TdpaParams, log_capacity: int = 0) -> None:
        self.port = MasterPassivity(params, log_capacity)
        self.W_min_J = float("inf")  # the observer's lowest sum over the axes, seen at the ends of ticks (J)
        self.motion_scaled = 0  # ticks whose rendered motion the guard slowed to keep the port passive

    def observe(self) -> None:
        """At the end of the master side's tick: the observer's sum into the running minimum."""
        self.W_min_J = min(self.W_min_J, float(self.port.W.sum()))

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

    def observe(self) -> None:
        """At the end of the slave side's tick: the observer's minimum and the drift."""
        self.W_min_J = min(self.W_min_J, float(self.port.W.sum()))
        self.drift_final_m = float(np.linalg.norm(self.port.offset[:3]))
        self.drift_max_m = max(self.drift_max_m, self.drift_final_m)

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
        v_des = np.concatenate((live.v_m_s, live.w_rad_s)) if live is not None else _ZERO6
        v = self.port.step(v_des, self.f_M, None if cmd is None else cmd.energy_J, t_s)
        p = self.port.params
        self.speed = self.speed + p.dt_s / (p.drift_speed_tau_s + p.dt_s) * (np.abs(v_des) - self.speed)
        if live is None:
            return cmd
        cmd = live
        off = self.port.offset
        return ToolCommand(cmd.seq, cmd.t_s, cmd.p_m + off[:3], exp3(off[3:]) @ cmd.R, v[:3], v[3:],
                           cmd.clutch, cmd.energy_J, cmd.wall_N)

    def reply(self, fb: ContactFeedback, wall_normal_P: np.ndarray | None = None) -> ContactFeedback:
        """``fb`` with the slave port's input energy and the drift spring added to its wrench
        (nothing added while the offset is zero); remembers the contact wrench for the next tick.
        ``wall_normal_P`` (3,): the normal of a surface the master renders as its own wall
        (model-mediated): the force along it is not the channel's and is left out of the port's
        books, as the master leaves it out of its own."""
        wrench_P = fb.wrench_P
        f_M = self.reg.wrench_to_master(fb.model_offset_P if self.model_offset else wrench_P)
        if wall_normal_P is not None:
            n = self.reg.X_PM_R.T @ wall_normal_P
            f_M = f_M.copy()
            f_M[:3] -= float(n @ f_M[:3]) * n
        self.f_M = f_M
        off = self.port.offset
        if np.any(off):  # the drift reflected to the master: a spring pulling it toward the slave's target
            p = self.port.params
            pull_M = np.asarray(p.drift_stiffness) * off * np.minimum(self.speed / p.drift_speed, 1.0)
            R, fs, ts = self.reg.X_PM_R, float(self.reg.force_scale), float(self.reg.torque_scale or 1.0)
            wrench_P = wrench_P + np.concatenate((R @ pull_M[:3] / fs, R @ pull_M[3:] / ts))
        plane = fb.plane_P
        if off[:3].any() and plane[7] > 0.0:  # the anchor where the master's tip was: less the drift
            plane = plane.copy()
            plane[3:6] -= self.reg.X_PM_R @ off[:3] / float(self.reg.scale)
        return ContactFeedback(fb.seq, fb.t_s, wrench_P, fb.status, fb.command_seq, self.port.energy_J,
                               fb.damping_P, fb.twist_P, plane)


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
