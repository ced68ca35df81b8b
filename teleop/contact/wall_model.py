"""The slave's estimated surface rendered at the master as a wall of its own, its updates applied
passively: the master's half of model-mediated teleoperation (Mitra and Niemeyer,
"Model-mediated telemanipulation", SPIE 2008; the passive update after Xu, Schuwerk, Cizmeci and
Steinbach, "Energy prediction for teleoperation systems that combine the time domain passivity
approach with perceptual deadband-based haptic data reduction", IEEE T-Haptics 2016, and the energy
tank of Franken, Stramigioli, Misra, Secchi and Macchelli, "Bilateral telemanipulation with time
delays: a two-layer approach combining passivity and transparency", IEEE T-RO 2011).

The wall is a unilateral spring along a unit normal ``n`` (out of the surface):

    f = k max(h - n . x, 0) n,   E = k max(h - n . x, 0)^2 / 2,

``x`` the tool's tip (m), ``h`` the surface's offset along ``n`` (m), ``k`` (N/m). Between updates
it is a fixed conservative spring, passive wherever the tool goes. An update (a new estimate from
the slave, one round trip old) changes ``n``, ``k`` and the target offset ``h*``; applied as it
comes it could store energy at the tool's present tip that nobody put in (the tool found deep
inside a surface the slave has just found: the wall would throw it out). So the rendered ``h``
moves to ``h*`` only as far as an energy tank allows: the new wall's energy at the tip may exceed
the old one's by at most what the tank holds; a change that lowers the stored energy puts the
difference into the tank. The tank is also credited with what the master's local contact damping
dissipates (:meth:`credit`) and is capped (``tank_max_J``), so it can never hand back more than the
model took in. Sum of the stored energy and the tank: never raised by an update (tested).

What is left between ``h`` and ``h*`` is the wall's offset: how far the master's surface sits from
the slave's (at the master's scale), the model-mediated form of the guard's position drift. It
closes whenever that costs nothing: the moment the tool leaves the wall (then the stored energy
is zero at any ``h`` outside the tip), or as the tank fills. Units: m, N/m, N, J (master units).
"""

from __future__ import annotations

import math

import numpy as np


class PassiveWall:
    """``aim(n, h, k)`` a new estimate (None: the slave touches nothing); ``update(x_tip)`` each
    tick before the wall is rendered: the rendered wall moved toward the estimate passively;
    ``force(x_tip)`` its normal force (N, >= 0); ``n``, ``h``, ``k`` the wall rendered (``n``
    None: none); ``offset_m`` |h - h*|."""

    def __init__(self, tank_max_J: float = 1e-3) -> None:
        if not (math.isfinite(tank_max_J) and tank_max_J >= 0.0):
            raise ValueError(f"wall model: tank_max_J must be a finite number >= 0, got {tank_max_J!r}")
        self.tank_max_J = float(tank_max_J)
        self.reset()

    def reset(self) -> None:
        """No wall, an empty tank."""
        self.n: np.ndarray | None = None
        self.h = self.k = 0.0
        self.tank_J = 0.0
        self._aim: tuple[np.ndarray, float, float] | None = None
        self.offset_m = 0.0

    def aim(self, n: np.ndarray | None, h: float = 0.0, k: float = 0.0) -> None:
        """The newest estimate: unit normal ``n`` (3,), offset ``h`` (m), stiffness ``k`` (N/m);
        ``n`` None or ``k`` <= 0: no surface (the wall goes at the next :meth:`update`)."""
        self._aim = None if n is None or not k > 0.0 else (np.asarray(n, dtype=float), float(h), float(k))

    def energy(self, x_tip: np.ndarray) -> float:
        """The wall's stored energy (J) with the tip at ``x_tip``."""
        if self.n is None:
            return 0.0
        d = self.h - float(self.n @ x_tip)
        return 0.5 * self.k * d * d if d > 0.0 else 0.0

    def depth(self, x_tip: np.ndarray) -> float:
        """How far the tip is inside the rendered wall (m; 0 outside or with no wall)."""
        return 0.0 if self.n is None else max(self.h - float(self.n @ x_tip), 0.0)

    def force(self, x_tip: np.ndarray) -> float:
        """The wall's normal force on the tip at ``x_tip`` (N, >= 0)."""
        return self.k * self.depth(x_tip)

    def credit(self, energy_J: float) -> None:
        """Energy the master's local model dissipated (J, >= 0) into the tank, up to its cap."""
        if energy_J > 0.0:
            self.tank_J = min(self.tank_J + energy_J, self.tank_max_J)

    def update(self, x_tip: np.ndarray) -> None:
        """The rendered wall moved toward the newest estimate with the tip at ``x_tip`` (3,) m:
        as far as the stored energy plus the tank allows (see the module docstring)."""
        before = self.energy(x_tip)
        if self._aim is None:
            if self.n is not None:  # the surface is gone: what the wall held goes to the tank
                self.credit(before)
                self.n, self.h, self.k, self.offset_m = None, 0.0, 0.0, 0.0
            return
        n, h_aim, k = self._aim
        s = float(n @ x_tip)
        d_aim = h_aim - s
        after = 0.5 * k * d_aim * d_aim if d_aim > 0.0 else 0.0
        budget = before + self.tank_J
        if after <= budget:
            h = h_aim
            self.tank_J = min(budget - after, self.tank_max_J)
        else:  # only as deep as the budget: the rest waits for the tank or for the tip to leave
            h = s + math.sqrt(2.0 * budget / k)
            self.tank_J = 0.0
        self.n, self.h, self.k = n, h, k
        self.offset_m = abs(h_aim - h)
