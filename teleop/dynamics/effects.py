"""External forces on the reference tool, one class per effect (the paper's tau = f_v - tau_d - tau_s - g).

Each effect adds a world wrench (force N, torque N*m, at the body origin) into a 6-vector. A scene
lists the effects it calls for; an effect it does not list is never constructed, so it costs nothing.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import pinocchio as pin

from teleop.dynamics.kernels.wrench import compiled_wrench
from teleop.util.errors import ConfigError


def _nonneg(x: float, name: str) -> float:
    x = float(x)
    if not np.isfinite(x) or x < 0:
        raise ConfigError(f"{name}: expected a finite non-negative number, got {x}")
    return x


class Effect(ABC):
    """One external force term. ``add_wrench`` accumulates into ``out`` (6,) = (f_W, tau_W)."""

    name: str = "effect"
    #: True when the wrench is minus the gradient of :meth:`potential_energy` (it does no net work
    #: beyond the change of that energy); False: its power counts as work done on the tool.
    conservative: bool = False

    @abstractmethod
    def add_wrench(self, p, R, v, w, t: float, out: np.ndarray) -> None:
        """Add this effect's wrench at pose (p m, R), twist (v m/s, w rad/s), time t s."""

    def potential_energy(self, p, R) -> float:
        """Potential energy (J) for conservative effects; 0 for dissipative ones."""
        return 0.0


@dataclass(frozen=True, eq=False)
class Gravity(Effect):
    """Uniform gravity g (m/s^2, world) on mass (kg)."""

    mass_kg: float
    g: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    name: str = "gravity"
    conservative = True

    def __post_init__(self):
        object.__setattr__(self, "g", np.asarray(self.g, dtype=float).reshape(3))
        object.__setattr__(self, "_f", self.mass_kg * self.g)

    def add_wrench(self, p, R, v, w, t, out):
        out[:3] += self._f

    def potential_energy(self, p, R):
        return -float(self._f @ p)


@dataclass(frozen=True, eq=False)
class LinearDamper(Effect):
    """Translational damping: f = -c v, c in N*s/m."""

    c: float
    name: str = "linear_damping"

    def __post_init__(self):
        _nonneg(self.c, "effects.damping.linear_Ns_per_m")

    def add_wrench(self, p, R, v, w, t, out):
        out[:3] -= self.c * v


@dataclass(frozen=True, eq=False)
class AngularDamper(Effect):
    """Rotational damping: tau = -c w, c in N*m*s/rad."""

    c: float
    name: str = "angular_damping"

    def __post_init__(self):
        _nonneg(self.c, "effects.damping.angular_Nms_per_rad")

    def add_wrench(self, p, R, v, w, t, out):
        out[3:] -= self.c * w


def rotation_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector (rad, 3) of a rotation matrix, robust near 0 and pi."""
    return np.asarray(pin.log3(R))


@dataclass(frozen=True, eq=False)
class Spring(Effect):
    """Virtual spring to an anchor pose: f = -k (p - p0) (k N/m), tau = -k_rot log(R R0^T) (N*m/rad)."""

    anchor_p: np.ndarray
    k_N_per_m: float
    anchor_R: np.ndarray = field(default_factory=lambda: np.eye(3))
    k_Nm_per_rad: float = 0.0
    name: str = "spring"
    conservative = True

    def __post_init__(self):
        object.__setattr__(self, "anchor_p", np.asarray(self.anchor_p, dtype=float).reshape(3))
        object.__setattr__(self, "anchor_R", np.asarray(self.anchor_R, dtype=float).reshape(3, 3))
        _nonneg(self.k_N_per_m, "effects.spring.k_N_per_m")
        _nonneg(self.k_Nm_per_rad, "effects.spring.k_Nm_per_rad")

    def add_wrench(self, p, R, v, w, t, out):
        out[:3] -= self.k_N_per_m * (p - self.anchor_p)
        if self.k_Nm_per_rad:
            out[3:] -= self.k_Nm_per_rad * rotation_log(R @ self.anchor_R.T)

    def potential_energy(self, p, R):
        d = p - self.anchor_p
        e = 0.5 * self.k_N_per_m * float(d @ d)
        if self.k_Nm_per_rad:
            r = rotation_log(R @ self.anchor_R.T)
            e += 0.5 * self.k_Nm_per_rad * float(r @ r)
        return e


def total_wrench(effects, p, R, v, w, t: float, operator_W=None) -> np.ndarray:
    """Sum of the operator wrench (6,) and every effect's wrench, world frame at the body origin
    (N, N*m; pose p m, R, twist v m/s, w rad/s, time t s). Effects the kernels apply (dampers,
    gravity) alone: one compiled call (:func:`teleop.dynamics.kernels.wrench.compiled_wrench`,
    the engine's own sum)."""
    try:
        fx, rest = _split(tuple(effects))
    except TypeError:  # an effect that cannot be hashed: each its own way
        fx, rest = None, effects
    F = np.zeros(6) if operator_W is None else np.asarray(operator_W, dtype=float)
    if not rest and F.shape == (6,):
        return compiled_wrench(F, fx, np.asarray(v, dtype=float), np.asarray(w, dtype=float))
    out = np.zeros(6) if operator_W is None else np.array(operator_W, dtype=float)
    for e in effects:
        e.add_wrench(p, R, v, w, t, out)
    return out


@lru_cache(maxsize=64)
def _split(effects: tuple) -> tuple[np.ndarray, tuple]:
    """:func:`effect_params` of a tuple of effects, kept (effects are immutable)."""
    return effect_params(effects)


def effect_params(effects) -> tuple[np.ndarray, tuple]:
    """Split effects into the ones the compiled kernels apply, summed into fx = (c_lin N*s/m, c_ang N*m*s/rad,
    gravity force (3,) N), and the rest (a tuple, run in Python)."""
    fx, rest = np.zeros(5), []
    for e in effects:
        if type(e) is LinearDamper:
            fx[0] += e.c
        elif type(e) is AngularDamper:
            fx[1] += e.c
        elif type(e) is Gravity:
            fx[2:5] += e._f
        else:
            rest.append(e)
    return fx, tuple(rest)
