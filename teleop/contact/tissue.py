"""A tissue block: a half-space slab under a plane, with a normal contact model and cutting.

The block's surface passes through ``origin_m`` with outward unit ``normal``; the block is
``thickness_m`` thick. A tip below the surface is ``depth`` = -n.(p - o) deep (m, clamped to the
thickness). The normal force pushes the blade out along +n:

* Hunt-Crossley:  F_n = k d^e (1 + 1.5 alpha d_dot),  clamped >= 0 (no sticking);
* Kelvin-Voigt:   F_n = k d + c d_dot,               clamped >= 0;

with d_dot = -n.v (m/s). Cutting and lateral resistance come from :class:`CuttingModel`. The world
wrench acts at the tip: (force N, torque N*m), Pinocchio's LOCAL_WORLD_ALIGNED order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from teleop.contact.cutting import CuttingModel
from teleop.errors import ConfigError, check_table


@dataclass(frozen=True, eq=False)
class ContactReport:
    """One evaluation: wrench (6,) at the tip in world axes, depth (m), force parts (N)."""

    wrench: np.ndarray
    depth_m: float
    in_contact: bool
    normal_N: float
    cutting_N: float
    lateral_N: float
    cut_speed_mps: float


@dataclass(frozen=True, eq=False)
class TissueBlock:
    """Tissue slab: geometry (m), normal model ("hunt_crossley" | "kelvin_voigt"), cutting model.

    stiffness: N/m^exponent (Hunt-Crossley) or N/m (Kelvin-Voigt); alpha_s_per_m: Hunt-Crossley
    damping (s/m); damping_Ns_per_m: Kelvin-Voigt damping.
    """

    origin_m: np.ndarray = field(default_factory=lambda: np.array([0.5, 0.0, 0.2]))
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    thickness_m: float = 0.03
    model: str = "hunt_crossley"
    stiffness: float = 1.0e4
    exponent: float = 1.5
    alpha_s_per_m: float = 2.0
    damping_Ns_per_m: float = 20.0
    cutting: CuttingModel = field(default_factory=CuttingModel)

    def __post_init__(self):
        o = np.asarray(self.origin_m, dtype=float).reshape(-1)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise ConfigError(f"tissue.origin_m: expected a finite 3-vector, got {self.origin_m!r}")
        n = np.asarray(self.normal, dtype=float).reshape(-1)
        nn = float(np.linalg.norm(n)) if n.shape == (3,) else 0.0
        if not np.isfinite(nn) or nn < 1e-12:
            raise ConfigError(f"tissue.normal: expected a non-zero 3-vector, got {self.normal!r}")
        object.__setattr__(self, "origin_m", o)
        object.__setattr__(self, "normal", n / nn)
        if self.model not in ("hunt_crossley", "kelvin_voigt"):
            raise ConfigError(f"tissue.model: expected 'hunt_crossley' or 'kelvin_voigt', got {self.model!r}")
        for key in ("thickness_m", "stiffness", "exponent"):
            x = getattr(self, key)
            if not isinstance(x, (int, float)) or not np.isfinite(x) or x <= 0:
                raise ConfigError(f"tissue.{key}: expected a finite positive number, got {x!r}")
        for key in ("alpha_s_per_m", "damping_Ns_per_m"):
            x = getattr(self, key)
            if not isinstance(x, (int, float)) or not np.isfinite(x) or x < 0:
                raise ConfigError(f"tissue.{key}: expected a finite number >= 0, got {x!r}")

    @classmethod
    def from_dict(cls, d: dict, where: str = "tissue") -> "TissueBlock":
        """Build from a table; cutting coefficients sit in a sub-table ``cutting``."""
        check_table(d, where, {f.name for f in fields(cls)})
        kw = {}
        for key, val in d.items():
            if key == "cutting":
                check_table(val, f"{where}.cutting", {f.name for f in fields(CuttingModel)})
                try:
                    val = CuttingModel(**{k: float(v) for k, v in val.items()})
                except (ConfigError, TypeError, ValueError) as exc:
                    raise ConfigError(f"{where}.{exc}") from None
            elif key in ("origin_m", "normal", "model"):
                pass
            else:
                try:
                    val = float(val)
                except (TypeError, ValueError):
                    raise ConfigError(f"{where}.{key}: expected a number, got {val!r}") from None
            kw[key] = val
        try:
            return cls(**kw)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None

    def compute_depth(self, p_tip) -> float:
        """Penetration (m) of the point below the surface, clamped to [0, thickness]."""
        d = -float(self.normal @ (np.asarray(p_tip, float) - self.origin_m))
        return min(max(d, 0.0), self.thickness_m)

    def compute_contact(self, p_tip, R_tool, v_tip, w) -> ContactReport:
        """The contact at the blade tip (pure): see the module docstring."""
        n = self.normal
        v_tip = np.asarray(v_tip, dtype=float)
        w = np.asarray(w, dtype=float)
        d = self.compute_depth(p_tip)
        if d <= 0.0:
            return ContactReport(np.zeros(6), 0.0, False, 0.0, 0.0, 0.0, 0.0)
        d_dot = -float(n @ v_tip)
        if self.model == "hunt_crossley":
            fn = self.stiffness * d**self.exponent * (1.0 + 1.5 * self.alpha_s_per_m * d_dot)
        else:
            fn = self.stiffness * d + self.damping_Ns_per_m * d_dot
        fn = max(fn, 0.0)
        F_cut, F_lat, tau, v_c = self.cutting.compute_forces(d, n, np.asarray(R_tool, float), v_tip, w)
        F = np.empty(6)
        F[:3] = fn * n + F_cut + F_lat
        F[3:] = tau
        return ContactReport(F, d, True, fn, math.hypot(*F_cut.tolist()), math.hypot(*F_lat.tolist()), v_c)

    def wrench(self, p_tip, R_tool, v_tip, w) -> np.ndarray:
        """World wrench (6,) on the tool at the tip: (N, N*m)."""
        return self.compute_contact(p_tip, R_tool, v_tip, w).wrench
