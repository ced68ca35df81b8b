"""The stable rendering range of the cobot's admittance loop, from a linearized sampled-data model.

One axis of the loop of :mod:`teleop.master.cobot.host` (a translation, or a rotation with inertia
in place of mass), in the handle's space (a tool of mass m rendered with φ's scale s weighs s² m
at the handle). Per period T, at SYNC t_k:

* the device samples the handle position x_h(t_k) and the load cell F_c = F_hand - m_h a_h(t_k)
  (the handle mass m_h sits behind the cell; a_h(t_k) = (u_{k-1} - v_h(t_k)) / τ is the servo's
  acceleration at that instant); the host sees both ``latency_periods`` periods late;
* the host removes the handle's inertia with an acceleration estimate â: ``"commanded"``, the
  acceleration it commanded in the previous period (the host before issue 15); ``"servo_model"``,
  the servo model's acceleration at the sampled SYNC, (u - v̂) / τ̂, v̂ being the model's rate
  run on the commands sent (the host's observer prediction);
* the reference tool m a_r = F_c + m_h â - b v_r - k x_r is stepped by semi-implicit Euler (the
  parametric integrator of an unconstrained body);
* eqs. 18-19: e = x_r - x̂_h (the late reading carried forward by the commanded motion since),
  q̈ = a_r + kp e + ki ∫e + kd (v_r - ν_c), ν_c += T q̈; the command u = ν_c + τ̂ q̈ (the servo lag's
  feedforward) goes out ``read_window_s`` after SYNC;
* the servo is a first-order velocity lag τ = 1 / (2π f_servo), exact between commands (zero-order
  hold on u, split at the command instant: scipy.signal.cont2discrete over the window and over
  the rest of the period).

Assumptions (where the simulated device differs, see README "The stable rendering range"): the
loop is linear: no velocity, acceleration or integral-clamp saturation, no encoder quantization,
no load-cell noise, no joint observer (its 20 Hz correction is slow beside the loop's modes), a
rigid device with the hand exerting an exogenous force (zero for stability), one axis alone (the
handle's COM offset couples force and torque on the real handle; DLS, the wrist's Coriolis
acceleration and φ's rotation are dropped). Units SI: kg, N*s/m, N/m (or kg*m^2, N*m*s/rad,
N*m/rad), s, Hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import cont2discrete

from teleop.util.errors import ConfigError

COMPENSATIONS = ("commanded", "servo_model")


@dataclass(frozen=True)
class LoopParams:
    """One axis of the admittance loop (see the module docstring); SI units."""

    mass: float  #: rendered mass at the handle, kg (or inertia, kg*m^2)
    damping: float = 0.0  #: rendered damping, N*s/m (N*m*s/rad)
    stiffness: float = 0.0  #: rendered stiffness, N/m (N*m/rad)
    handle_mass: float = 0.15  #: handle behind the load cell, kg (kg*m^2 about the axis)
    dt_s: float = 1e-3  #: control period, s
    servo_bandwidth_hz: float = 200.0  #: the device's velocity servo, Hz
    model_bandwidth_hz: float | None = None  #: the host's servo model, Hz (None: the true one)
    read_window_s: float = 3e-4  #: the command goes out this long after SYNC, s
    latency_periods: int = 0  #: feedback (encoders and load cell) this many periods late
    kp: float = 40000.0  #: 1/s^2
    ki: float = 400000.0  #: 1/s^3
    kd: float = 400.0  #: 1/s
    compensation: str = "servo_model"  #: "commanded" or "servo_model" (see the module docstring)

    def __post_init__(self):
        for key in ("mass", "dt_s", "servo_bandwidth_hz"):
            if not getattr(self, key) > 0:
                raise ConfigError(f"LoopParams.{key}: expected > 0, got {getattr(self, key)}")
        if not 0.0 <= self.read_window_s < self.dt_s:
            raise ConfigError(f"LoopParams.read_window_s: expected in [0, dt_s), got {self.read_window_s}")
        if self.compensation not in COMPENSATIONS:
            raise ConfigError(f"LoopParams.compensation: expected one of {COMPENSATIONS}, got {self.compensation!r}")
        if int(self.latency_periods) != self.latency_periods or self.latency_periods < 0:
            raise ConfigError(f"LoopParams.latency_periods: expected a whole number >= 0, got {self.latency_periods}")


def _servo_maps(tau: float, h: float):
    """(Φ (2, 2), Γ (2,)) of the servo x' = v, v' = (u - v) / τ over h s under a held u."""
    A = np.array([[0.0, 1.0], [0.0, -1.0 / tau]])
    B = np.array([[0.0], [1.0 / tau]])
    Ad, Bd, *_ = cont2discrete((A, B, np.eye(2), np.zeros((2, 1))), h, method="zoh")
    return Ad, Bd[:, 0]


class _Loop:
    """The closed loop's one-period map on a flat state vector (linear by construction)."""

    def __init__(self, p: LoopParams):
        self.p = p
        self.tau = 1.0 / (2.0 * math.pi * p.servo_bandwidth_hz)
        fm = p.model_bandwidth_hz or p.servo_bandwidth_hz
        self.tau_m = 1.0 / (2.0 * math.pi * fm)
        w, T = p.read_window_s, p.dt_s
        self.plant = (_servo_maps(self.tau, w), _servo_maps(self.tau, T - w))
        self.model = (_servo_maps(self.tau_m, w), _servo_maps(self.tau_m, T - w))
        n = p.latency_periods
        # state: plant x_h v_h | model v̂ | tool x_r v_r | PID ν_c ∫e | u in force | a commanded last
        # | delay lines (n each): readings x, F, model accel, commanded motion since
        self.names = ["x_h", "v_h", "v_m", "x_r", "v_r", "nu", "integ", "u", "a_cmd"]
        for line in ("dx", "dF", "da", "dmove"):
            self.names += [f"{line}{i}" for i in range(n)]
        self.idx = {k: i for i, k in enumerate(self.names)}

    def step(self, s: np.ndarray) -> np.ndarray:
        p, ix, n, T = self.p, self.idx, self.p.latency_periods, self.p.dt_s
        g = {k: s[i] for k, i in ix.items()}
        # sampled at SYNC k: the handle and the load cell (F_hand = 0), the model's acceleration
        a_h = (g["u"] - g["v_h"]) / self.tau
        y_x, y_F, y_a = g["x_h"], -p.handle_mass * a_h, (g["u"] - g["v_m"]) / self.tau_m
        move = 0.0  # the commanded motion since the reading's SYNC
        if n:  # the host sees the readings of SYNC k - n
            lines = {k: [g[f"{k}{i}"] for i in range(n)] for k in ("dx", "dF", "da", "dmove")}
            y_x, y_F, y_a = lines["dx"][-1], lines["dF"][-1], lines["da"][-1]
            move = sum(lines["dmove"])
        a_hat = y_a if p.compensation == "servo_model" else g["a_cmd"]
        F_est = y_F + p.handle_mass * a_hat
        a_r = (F_est - p.damping * g["v_r"] - p.stiffness * g["x_r"]) / p.mass
        e = g["x_r"] - (y_x + move)
        integ = g["integ"] + e * T
        q_dd = a_r + p.kp * e + p.ki * integ + p.kd * (g["v_r"] - g["nu"])
        nu = g["nu"] + T * q_dd
        u_new = nu + self.tau_m * q_dd
        v_r = g["v_r"] + T * a_r
        x_r = g["x_r"] + T * v_r
        out = np.zeros_like(s)
        xh, vm = np.array([g["x_h"], g["v_h"]]), np.array([0.0, g["v_m"]])
        for (Phi, Gam), (Phm, Gm), u in zip(self.plant, self.model, (g["u"], u_new)):
            xh = Phi @ xh + Gam * u
            vm = Phm @ vm + Gm * u
        vals = {"x_h": xh[0], "v_h": xh[1], "v_m": vm[1], "x_r": x_r, "v_r": v_r, "nu": nu, "integ": integ,
                "u": u_new, "a_cmd": q_dd}
        if n:
            for k, y in (("dx", g["x_h"]), ("dF", -p.handle_mass * a_h), ("da", (g["u"] - g["v_m"]) / self.tau_m),
                         ("dmove", nu * T)):
                shifted = [y, *lines[k][:-1]]
                vals.update({f"{k}{i}": shifted[i] for i in range(n)})
        for k, v in vals.items():
            out[ix[k]] = v
        return out


def closed_loop_matrix(p: LoopParams) -> np.ndarray:
    """A (N, N): the closed loop's state one period on, s_{k+1} = A s_k (hand force zero), built
    column by column from the period's map (linear by construction)."""
    loop = _Loop(p)
    n = len(loop.names)
    return np.column_stack([loop.step(col) for col in np.eye(n)])


def rigid_modes(p: LoopParams) -> int:
    """How many poles sit at z = 1 by construction: the tool's free translation (no stiffness)
    and, with no damping either, its free drift."""
    return 0 if p.stiffness > 0 else (1 if p.damping > 0 else 2)


def spectral_radius(p: LoopParams) -> float:
    """The largest pole modulus of the closed loop, the free tool's poles at z = 1
    (:func:`rigid_modes`) set aside: < 1 is stable."""
    z = np.linalg.eigvals(closed_loop_matrix(p))
    order = np.argsort(np.abs(z - 1.0))
    rest = z[order[rigid_modes(p):]]
    return float(np.max(np.abs(rest)))


#: a pole this close outside the unit circle counts as on it: an undamped rendered spring is exactly
#: marginal under the semi-implicit Euler step (|z| = 1 to round-off); 1e-7 grows e-fold in 1e7 periods
MARGINAL = 1e-7


def is_stable(p: LoopParams, margin: float = 0.0) -> bool:
    """Whether every pole but the free tool's lies inside the circle of radius 1 - margin (with
    margin 0: on or inside, to :data:`MARGINAL`)."""
    return spectral_radius(p) < (1.0 - margin if margin > 0 else 1.0 + MARGINAL)


def critical_mass(p: LoopParams, lo: float | None = None, hi: float | None = None,
                  rel_tol: float = 1e-3) -> float:
    """The lightest stable rendered mass (kg, or kg*m^2) with p's other settings, by bisection in
    log mass on [lo, hi] (default 1e-3 and 100 handle masses, or 1e-6 and 0.1 with no handle;
    stability taken as monotone in mass there): lo if lo is stable, inf if hi is not."""
    ref = p.handle_mass if p.handle_mass > 0 else 1e-3
    lo = 1e-3 * ref if lo is None else lo
    hi = 100.0 * ref if hi is None else hi
    if is_stable(replace(p, mass=lo)):
        return lo
    if not is_stable(replace(p, mass=hi)):
        return math.inf
    while hi / lo > 1.0 + rel_tol:
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if is_stable(replace(p, mass=mid)) else (mid, hi)
    return hi


def sampled_data_stiffness(mass: float, damping: float, dt_s: float) -> float:
    """The stiffest spring the reference tool's own step renders stably, N/m (N*m/rad on a
    rotation): ``mass`` kg (kg*m^2), ``damping`` N*s/m (N*m*s/rad) >= 0, period ``dt_s`` s.

    The tool's step is semi-implicit Euler on m a = -B v - K x with the spring and the damper
    read at the period's start (held over it): v+ = v + T a, x+ = x + T v+. Its one-period map
    has determinant 1 - BT/m and trace 2 - KT^2/m - BT/m, so by Jury's test it is stable when
    0 < BT/m < 2 and

        K T / 2 + B < 2 m / T,   i.e.   K < 4 m / T^2 - 2 B / T,

    Colgate and Schenkel's sampled-data bound b > K T / 2 + |B| for a virtual wall on an impedance
    display (b the device's own damping), with b played here by 2 m / T: the rendered mass seen
    through one period. An admittance display renders the spring on the tool it simulates, so the
    tool's mass and the period, not the device's friction, bound the wall: halving T makes the
    stiffest wall 4x as stiff without damping (2 m / T doubles and so does 2 / T). Undamped (B = 0)
    a spring below the bound is marginal (poles on the unit circle), above it unstable. Returns 0
    when B >= 2 m / T (the damper alone is past its explicit limit: no spring renders).

    With the servo model's inertia compensation the linearized loop of the cobot has this bound
    and no other (:func:`critical_stiffness` finds it to its tolerance): the device follows the
    tool and the load cell feels no residual of the handle's inertia to feed back."""
    if not (mass > 0 and dt_s > 0):
        raise ConfigError(f"sampled_data_stiffness: expected mass > 0 and dt_s > 0, got {mass}, {dt_s}")
    if not damping >= 0:
        raise ConfigError(f"sampled_data_stiffness: expected damping >= 0 N*s/m, got {damping} "
                          "(a negative damper is unstable at any stiffness)")
    return max(0.0, 4.0 * mass / dt_s ** 2 - 2.0 * damping / dt_s)


def critical_stiffness(p: LoopParams, lo: float | None = None, hi: float | None = None,
                       rel_tol: float = 1e-3) -> float:
    """The stiffest stable rendered spring (N/m, or N*m/rad) with p's other settings, p.stiffness
    ignored: every stiffness of a log grid (x2 steps) from ``lo`` up to it is stable too (the
    stable band that starts at the soft end; with the commanded compensation the loop has stable
    bands higher up that this does not count). The grid's last stable point and first unstable
    one are then bisected in log stiffness to ``rel_tol``. Defaults: ``lo`` 1e-6 and ``hi`` 1e3
    times the tool's own bound (:func:`sampled_data_stiffness`; 4 m / T^2 when that is 0).
    Returns 0.0 when ``lo`` is unstable, inf when the whole grid to ``hi`` is stable."""
    ref = sampled_data_stiffness(p.mass, max(0.0, p.damping), p.dt_s) or 4.0 * p.mass / p.dt_s ** 2
    lo = 1e-6 * ref if lo is None else lo
    hi = 1e3 * ref if hi is None else hi
    if not 0 < lo < hi:
        raise ConfigError(f"critical_stiffness: expected 0 < lo < hi N/m, got {lo}, {hi}")
    if not is_stable(replace(p, stiffness=lo)):
        return 0.0
    k = lo
    while True:
        nxt = min(2.0 * k, hi)
        if not is_stable(replace(p, stiffness=nxt)):
            break
        if nxt >= hi:
            return math.inf
        k = nxt
    lo, hi = k, nxt
    while hi / lo > 1.0 + rel_tol:
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if is_stable(replace(p, stiffness=mid)) else (lo, mid)
    return lo
