"""Time-domain passivity guard (TDPA) on the delayed channel, per axis of the 6-D twist/wrench.

After Ryu, Kwon, Hannaford, "Stable teleoperation with time-domain passivity control", IEEE T-RA
20(2), 2004, and the two-port TDPA of Artigas, Ryu, Preusche, Hirzinger ("Time domain passivity
control for position-position teleoperation architectures", Presence 19(5), 2010; "Network
representation and passivity of delayed teleoperation systems", IROS 2011; and "Position drift
compensation in time domain passivity based teleoperation", IROS 2010).

The channel is a two-port between the master port (velocity ``v_m`` in, force ``f_m`` out: the
force the channel puts on the master) and the slave port (velocity ``v_s`` out to the slave, force
``f_s`` in: the force the slave's environment puts on the slave, which is what is sent back).
Power into the channel, per axis and per tick (W, with m/s and N, or rad/s and N*m)::

    master port: p_m = -f_m * v_m        slave port: p_s = f_s * v_s

Each side splits its port power into the energy that entered the channel there, ``E_in``, and the
energy that left it there, ``E_out`` (both non-decreasing, J), and sends ``E_in`` with every
message (``energy_J``) as a cumulative sum, so a lost message loses nothing: the next one carries
the whole sum. Without delay ``p_m + p_s = 0`` (a lossless wire); with delay the channel may
create energy. Two passivity observers split that, one per direction of flow::

    master (right to left): W_m(n) = E_in_s(n - D_sm) - E_out_m(n)
    slave  (left to right): W_s(n) = E_in_m(n - D_ms) - E_out_s(n) + E_diss_s(n - 1)

``E_in`` of the other side is the largest received (held when a message is late or lost, which
is conservative: it only ever grows, and a stale value is never taken for a newer one). At the
master ``E_out`` is the work the rendered force (after the controller) did on the tool, counted
after the step it acted in (see :class:`MasterPassivity`), so it needs no ``E_diss`` term. A
negative observer means the channel has put out more than it was given; the controller at that
port dissipates it:

* master, impedance-type port: adaptive damping, ``f = f_m - alpha * v_m`` with
  ``alpha = -W / (dt v_m^2)``, capped at ``max(alpha_max, f_m / v_m)`` (N*s/m: removing a force
  that pushes along the motion is always allowed, reversing it only up to ``alpha_max``), not
  computed below ``v_floor``.
* slave, admittance-type port: a velocity correction, ``v_s = v_des + dv`` with
  ``dv = -W / (dt f_s)``, capped at ``dv_max`` (m/s), not computed below ``f_floor``.

The slave's correction accumulates into a position offset ``offset`` (the drift): the slave's
position target is the master's delayed position plus ``offset``. Drift compensation (Artigas
et al. 2010) spends only surplus energy: when ``W_s > 0``, a correction ``-drift_gain * offset``
is added, cut so that its energy cost does not exceed ``drift_share * W_s`` (so it is free, and
taken in full, while no force acts on the slave); ``E_diss`` counts it
negatively (energy given back), so the observer stays non-negative.

Surplus alone is rarely there: the drift is the energy the slave's environment took before the
master felt it (the first second of a cut at 1 s round trip), and in steady contact nothing
moves, so nothing is paid. The drift is therefore also reflected to the master as a spring
(``drift_stiffness`` times ``offset``, added to the force sent back, :class:`SlaveGuard`), the
position-error coupling of the position-position architectures (Artigas et al., Presence 2010): the hand
feels where the slave's target is and works against the spring, that work is master ``E_in``
like any other, and it arrives at the slave as the surplus the compensation spends. Both
observers still count port energy only (the slave port counts the contact force, which the spring
is not), so passivity holds as before: the spring is paid for by whoever pushes against it.

A port with ``enabled=False`` observes and logs but never acts ("off").

The arithmetic above is compiled (:mod:`teleop.control.passivity_kernels`, one call a port's
tick, the same floats as numpy); a port's state is one array, a new one every tick.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import overload

import numpy as np
from numpy.typing import ArrayLike

from teleop.control import passivity_kernels as kern
from teleop.control.passivity_kernels import port_energy
from teleop.util.errors import ConfigError


def compute_port_energy(E_in: np.ndarray, E_out: np.ndarray, power_W: np.ndarray, dt_s: float):
    """Pure: the cumulative (E_in, E_out) (6,) J after one tick of port power ``power_W`` (6,) W
    (positive into the channel) held for ``dt_s`` s."""
    E_in, E_out, power = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (E_in, E_out, power_W)))
    E_in_out, E_out_out = np.empty(power.shape), np.empty(power.shape)
    port_energy(E_in.ravel(), E_out.ravel(), power.ravel(), float(dt_s), E_in_out.reshape(-1), E_out_out.reshape(-1))
    return E_in_out, E_out_out


@dataclass(frozen=True)
class TdpaParams:
    """Settings of one port, validated when made.

    dt_s: tick (s), > 0.
    enabled: act (True) or only observe (False, ``passivity = "off"``).
    alpha_max: master damping cap (N*s/m on force axes, N*m*s/rad on torque axes), > 0: one number
        or six (per axis); SAI caps it at 0.9 of what the device can render.
    v_floor: master velocities below this (m/s or rad/s) get no damping (alpha would blow up).
    f_floor: slave forces below this (N or N*m) get no velocity correction.
    dv_max: slave velocity correction cap (m/s or rad/s), > 0.
    drift_gain: drift compensation rate (1/s), >= 0 (0: off, the default here; scenes use 2).
    drift_share: fraction of the slave observer's surplus that compensation may spend, [0, 1].
    drift_stiffness: the spring (N/m on force axes, N*m/rad on torque axes) that reflects the
        drift to the master, one number or six, >= 0 (0: none, the default here; scenes use
        drift_gain x alpha_max). On the 1-DOF stiff-wall test at 200 ms round trip it takes the
        final drift from 19.5 to 6.2 mm with 1000 N/m.
    drift_speed: the commanded speed (m/s, rad/s; |twist| per axis low-passed over
        ``drift_speed_tau_s`` s) from which the spring is felt in full; slower, in proportion, so
        a held contact is not pushed back by it (at rest nobody pays for a catch-up: the spring
        would only lift the hand; on stiff_contact it took the contact force from 0.16 to 0.03 N).
        0.01 m/s and 0.2 s: the step-gated version (full spring while moving away from the
        target) chattered on the cut at 50 ms, 0.6 mm of 2-50 Hz motion; this one 0.33 mm.
    slows_motion: the master port also scales the tool's velocity after each step so that its
        observer never goes below zero (:meth:`MasterPassivity.motion_scale`; off by default).
    """

    dt_s: float
    enabled: bool = True
    alpha_max: float | tuple = 500.0
    v_floor: float = 1e-4
    f_floor: float = 1e-3
    dv_max: float = 0.5
    drift_gain: float = 0.0
    drift_share: float = 0.5
    drift_stiffness: float | tuple = 0.0
    drift_speed: float = 0.01
    drift_speed_tau_s: float = 0.2
    slows_motion: bool = False

    def __post_init__(self):
        a = self.alpha_max
        if isinstance(a, (tuple, list, np.ndarray)):
            if len(a) != 6 or not all(isinstance(x, (int, float, np.floating)) and math.isfinite(x) and x > 0
                                      for x in a):
                raise ConfigError(f"TdpaParams.alpha_max: expected one or six finite numbers > 0, got {a!r}")
            object.__setattr__(self, "alpha_max", tuple(float(x) for x in a))
        for name, lo in (("dt_s", 0.0), ("alpha_max", 0.0), ("v_floor", 0.0), ("f_floor", 0.0), ("dv_max", 0.0),
                         ("drift_speed", 0.0), ("drift_speed_tau_s", 0.0)):
            if name == "alpha_max" and isinstance(self.alpha_max, tuple):
                continue
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= lo:
                raise ConfigError(f"TdpaParams.{name}: expected a finite number > {lo}, got {v!r}")
        k = self.drift_stiffness
        ks = k if isinstance(k, (tuple, list, np.ndarray)) else (k,)
        if len(ks) not in (1, 6) or not all(not isinstance(x, bool) and isinstance(x, (int, float, np.floating))
                                            and math.isfinite(x) and x >= 0 for x in ks):
            raise ConfigError(f"TdpaParams.drift_stiffness: expected one or six finite numbers >= 0, got {k!r}")
        object.__setattr__(self, "drift_stiffness", tuple(float(x) for x in ks) * (6 // len(ks)))
        g = self.drift_gain
        if isinstance(g, bool) or not isinstance(g, (int, float)) or not math.isfinite(g) or g < 0:
            raise ConfigError(f"TdpaParams.drift_gain: expected a finite number >= 0, got {g!r}")
        s = self.drift_share
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not 0.0 <= s <= 1.0:
            raise ConfigError(f"TdpaParams.drift_share: expected a number in [0, 1], got {s!r}")
        object.__setattr__(self, "enabled", bool(self.enabled))


class PortLog:
    """Per-tick record of one port, preallocated for ``capacity`` ticks: time ``t_s`` (n,) s, and
    (n, 6) arrays of the observer ``W_J``, ``E_in_J``, ``E_out_J``, ``E_diss_J`` (J, cumulative),
    ``E_remote_J`` (the other side's E_in as received) and ``action`` (alpha in N*s/m at the
    master, dv in m/s at the slave)."""

    FIELDS = ("W_J", "E_in_J", "E_out_J", "E_diss_J", "E_remote_J", "action")

    def __init__(self, capacity: int):
        self.n = 0
        self.t_s = np.zeros(capacity)
        for f in self.FIELDS:
            setattr(self, f, np.zeros((capacity, 6)))

    def record(self, t_s: float, port: _Port) -> None:
        if self.n >= len(self.t_s):
            return
        k = self.n
        self.t_s[k] = t_s
        self.W_J[k], self.E_in_J[k], self.E_out_J[k] = port.W, port.E_in, port.E_out
        self.E_diss_J[k], self.E_remote_J[k], self.action[k] = port.E_diss, port.E_remote, port.action
        self.n += 1

    def arrays(self) -> dict:
        """The filled part: {"t_s": (n,), field: (n, 6), ...}."""
        return {"t_s": self.t_s[: self.n], **{f: getattr(self, f)[: self.n] for f in self.FIELDS}}


class _Row:
    """One row of a port's state block (:attr:`_Port.block`) as an attribute: read, a (6,) view;
    set, a new block with the row replaced (a block is never written once made)."""

    def __init__(self, row: int):
        self.row = row

    @overload
    def __get__(self, port: None, owner: type) -> _Row: ...
    @overload
    def __get__(self, port: _Port, owner: type) -> np.ndarray: ...

    def __get__(self, port: _Port | None, owner: type) -> np.ndarray | _Row:
        return self if port is None else port.block[self.row]

    def __set__(self, port: _Port, value: ArrayLike) -> None:
        block = port.block.copy()
        block[self.row] = value
        port.block = block


def _vec6(x: ArrayLike) -> np.ndarray:
    """x as a float (6,) array for the kernels (a copy only when it is not one; broadcast as numpy
    would, or its error)."""
    a = np.asarray(x, dtype=float)
    return a if a.shape == (6,) else np.broadcast_to(a, (6,))


_NOTHING = np.zeros(6)  # the kernels' E_remote when nothing was received (not read)
_NOTHING.flags.writeable = False


class _Port:
    """State shared by both ports: cumulative energies (6,) J and the observer, rows of one block
    (:attr:`block`), and the settings as the kernels take them."""

    ROWS = 6
    E_in = _Row(kern.E_IN)
    E_out = _Row(kern.E_OUT)
    E_diss = _Row(kern.E_DISS)
    E_remote = _Row(kern.E_REMOTE)
    W = _Row(kern.W)
    action = _Row(kern.ACTION)

    def __init__(self, params: TdpaParams, log_capacity: int = 0):
        self.params = params
        #: (ROWS, 6) the port's state (rows as in :mod:`teleop.control.passivity_kernels`): a new
        #: array every tick, never written once made (a recorder may hold a tick's rows)
        self.block = np.zeros((self.ROWS, 6))
        self.log = PortLog(log_capacity) if log_capacity else None

    @property
    def params(self) -> TdpaParams:
        """The port's settings (:class:`TdpaParams`)."""
        return self._params

    @params.setter
    def params(self, p: TdpaParams) -> None:
        self._params, self._dt = p, float(p.dt_s)
        #: the settings as the kernels take them (:func:`teleop.control.passivity_kernels.port_settings`)
        self.settings = kern.port_settings(p.dt_s, p.enabled, p.v_floor, p.f_floor, p.dv_max, p.drift_gain,
                                           p.drift_share, p.alpha_max)

    def commit(self, block: np.ndarray, t_s: float) -> None:
        """``block`` (a new array, filled by a kernel) is the port's state from now; the tick at
        ``t_s`` (s) logged."""
        self.block = block
        if self.log is not None:
            self.log.record(t_s, self)

    @staticmethod
    def incoming(E_remote: ArrayLike | None) -> tuple[bool, np.ndarray]:
        """(whether the other side's ``E_in`` came, it as (6,) J): the kernels keep the largest."""
        return (False, _NOTHING) if E_remote is None else (True, _vec6(E_remote))

    @property
    def energy_J(self) -> np.ndarray:
        """(6,) J: what to put in the outgoing message's ``energy_J``."""
        return self.block[kern.E_IN].copy()

    @property
    def dissipated_J(self) -> float:
        """Total energy dissipated by this port's controller so far (J, all axes)."""
        return float(self.block[kern.E_DISS].sum())

    def observer_sum(self) -> float:
        """The observer summed over the axes (J)."""
        return kern.sum6(self.block, kern.W)


class MasterPassivity(_Port):
    """The master port: observer W_m and adaptive damping (impedance-type port).

    The force rendered at tick n acts on the tool through its step at tick n + 1, so the port's
    energy is counted when that step is done: the work of the force last rendered against the
    velocity it produced, ``f_out(n-1) v(n) dt`` (a stiff wall's force arriving at a tool at rest
    does its work in the step after it arrives; paired with the velocity before, it would go
    unseen). ``E_out`` counts what the channel (after the controller) put into the master;
    ``E_in`` credits the slave only with what entered through the channel's own force, not the
    work the hand did against the controller's damping: ``min((-f(n-1) v)+, (-f_out(n-1) v)+)``.
    The observer ``W = E_in_slave - E_out`` then holds the controller's past action (no separate
    ``E_diss`` term: what the damping took is missing from ``E_out``). A negative observer is
    dissipated on the force about to be rendered, ``alpha = -W / (dt v^2)``, capped at
    ``alpha_max`` (a damper the tool's explicit step can take) except that a force pushing along
    the motion may always be removed down to zero (``alpha <= f / v`` there): the cap alone let a
    stiff wall's force, arriving late, throw the tool (1.8 mm shake at 1 s round trip with loss,
    a blow-up at 10 ms). Each method is one compiled call (:mod:`teleop.control.passivity_kernels`)."""

    ROWS = kern.MASTER_ROWS
    f_channel = _Row(kern.F_CHANNEL)  # the channel's force last tick, before the controller
    f_rendered = _Row(kern.F_RENDERED)  # the force rendered last tick, after it

    def __init__(self, params: TdpaParams, log_capacity: int = 0):
        super().__init__(params, log_capacity)
        self._counted = False  # the rendered force's work already counted (by energy_after)

    def account(self, v_m) -> None:
        """Count the work the force rendered last did on the master, now that it has moved it at
        ``v_m`` (6,) m/s, rad/s; once per tick (:meth:`step` calls it if nobody did)."""
        if self._counted:
            return
        out = np.empty((kern.MASTER_ROWS, 6))
        kern.master_account(self.block, out, _vec6(v_m), self._dt)
        self.block, self._counted = out, True

    def motion_scale(self, v_m) -> float:
        """The largest sigma in [0, 1] such that the force rendered last, working against the
        master's velocity ``sigma * v_m`` (6,) after its step, keeps the observer ``E_remote -
        E_out`` at or above zero on every axis: scale the step's velocity by it before
        :meth:`account` and the port is passive by construction, whatever the force and however
        still the hand is (the damping alone acts only on a tool already moving, a tick late)."""
        if not (self._params.enabled and self._params.slows_motion) or self._counted:
            return 1.0
        return kern.master_motion_scale(self.block, _vec6(v_m), self._dt)

    def energy_after(self, v_m) -> np.ndarray:
        """(6,) J: ``E_in`` with the work of the force rendered last counted at the master's
        velocity ``v_m`` after its step: what to stamp in the command sent that tick, so the
        slave hears of the energy in the same tick it enters (no tick of lag at zero delay)."""
        self.account(v_m)
        return self.block[kern.E_IN].copy()

    def step(self, f_m: np.ndarray, v_m: np.ndarray, E_remote=None, t_s: float = 0.0) -> np.ndarray:
        """The force (6,) N, N*m to render on the master, from the channel's force ``f_m`` (6,) on
        the master, the master's velocity ``v_m`` (6,) m/s, rad/s (after the step under the force
        rendered last tick), and the slave's ``E_in`` ``E_remote`` (6,) J from the newest feedback
        (None: hold the last)."""
        received, E_r = self.incoming(E_remote)
        out = np.empty((kern.MASTER_ROWS, 6))
        kern.master_step(self.block, out, _vec6(f_m), _vec6(v_m), E_r, received, self._counted, self.settings)
        self._counted = False
        self.commit(out, t_s)
        return out[kern.F_RENDERED]


class SlavePassivity(_Port):
    """The slave port: observer W_s, velocity correction (admittance-type port), drift offset.
    Its step is one compiled call (:func:`teleop.control.passivity_kernels.slave_step`)."""

    ROWS = kern.SLAVE_ROWS
    offset = _Row(kern.OFFSET)

    def step(self, v_des: np.ndarray, f_s: np.ndarray, E_remote=None, t_s: float = 0.0) -> np.ndarray:
        """The velocity (6,) m/s, rad/s the slave should follow, from the channel's velocity
        ``v_des`` (the master's, delayed), the force ``f_s`` (6,) N, N*m the environment puts on the
        slave (the force sent back), and the master's ``E_in`` ``E_remote`` (None: hold the last).
        ``offset`` (6,) m, rad accumulates the correction: add it to the delayed master position."""
        received, E_r = self.incoming(E_remote)
        out, v = np.empty((kern.SLAVE_ROWS, 6)), np.empty(6)
        kern.slave_step(self.block, out, _vec6(v_des), _vec6(f_s), E_r, received, self.settings, v)
        self.commit(out, t_s)
        return v
