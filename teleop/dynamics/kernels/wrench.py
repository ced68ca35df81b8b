"""The compiled effects' wrench, written once (numba): the dampers and gravity that
:func:`teleop.dynamics.effects.effect_params` packs as fx = (c_lin N*s/m, c_ang N*m*s/rad,
gravity force (3,) N). The engine's evaluation (:func:`.motion.newton_euler`) and
:func:`teleop.dynamics.effects.total_wrench` (what the feedback path renders against) both add
them here. World frame, at the body origin: v m/s, w rad/s, wrenches (N, N*m)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def add_compiled_effects(F_in, fx, v, w, F):
    """F (6,) = F_in (6,) plus the compiled effects at the twist (v, w):
    (f - c_lin v + m g, tau - c_ang w)."""
    for i in range(3):
        F[i] = F_in[i] - fx[0] * v[i] + fx[2 + i]
        F[3 + i] = F_in[3 + i] - fx[1] * w[i]


@njit(cache=True)
def compiled_wrench(F_in, fx, v, w):
    """:func:`add_compiled_effects` into a new (6,) array."""
    F = np.empty(6)
    add_compiled_effects(F_in, fx, v, w, F)
    return F
