"""Cutting resistance on a scalpel blade in tissue.

Along the cutting direction c (the tool's +x projected on the tissue plane) the tissue resists the
blade's advance with a force that grows with depth and speed,

    F_cut = -(f_N_per_m + b_Ns_per_m2 |v_c|) * depth * tanh(v_c / v_smooth) * c,

a fracture term per metre of depth (N/m) plus a viscous term (N s/m^2). Sideways (along the side
axis s, the tool's +y) the blade meets a viscous lateral resistance growing with depth,
F_lat = -lateral_Ns_per_m2 * depth * v_s * s, and twisting the blade about the tissue normal meets
-twist_Nms_per_m * depth * w_n (N*m). tanh smooths the stick at v_c = 0 (v_smooth m/s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teleop.errors import ConfigError


@dataclass(frozen=True)
class CuttingModel:
    """Resistance coefficients (SI): see the module docstring."""

    f_N_per_m: float = 400.0
    b_Ns_per_m2: float = 4000.0
    lateral_Ns_per_m2: float = 20000.0
    twist_Nms_per_m: float = 2.0
    v_smooth_mps: float = 1e-3

    def __post_init__(self):
        for key in ("f_N_per_m", "b_Ns_per_m2", "lateral_Ns_per_m2", "twist_Nms_per_m"):
            x = getattr(self, key)
            if not np.isfinite(x) or x < 0:
                raise ConfigError(f"cutting.{key}: expected a finite value >= 0, got {x}")
        if not np.isfinite(self.v_smooth_mps) or self.v_smooth_mps <= 0:
            raise ConfigError(f"cutting.v_smooth_mps: expected > 0, got {self.v_smooth_mps}")

    def compute_forces(self, depth, n, R, v_tip, w):
        """(F_cut (3,) N, F_lat (3,) N, tau (3,) N*m, v_c m/s) for the tip ``depth`` m under a
        plane with outward normal n, tool rotation R, tip velocity v_tip (m/s), angular w (rad/s)."""
        if depth <= 0.0:
            z = np.zeros(3)
            return z, z.copy(), z.copy(), 0.0
        c = R[:, 0] - (R[:, 0] @ n) * n
        nc = np.linalg.norm(c)
        c = c / nc if nc > 1e-9 else c * 0.0
        s = R[:, 1] - (R[:, 1] @ n) * n
        ns = np.linalg.norm(s)
        s = s / ns if ns > 1e-9 else s * 0.0
        v_c = float(v_tip @ c)
        v_s = float(v_tip @ s)
        F_cut = -(self.f_N_per_m + self.b_Ns_per_m2 * abs(v_c)) * depth * np.tanh(v_c / self.v_smooth_mps) * c
        F_lat = -self.lateral_Ns_per_m2 * depth * v_s * s
        tau = -self.twist_Nms_per_m * depth * float(w @ n) * n
        return F_cut, F_lat, tau, v_c
