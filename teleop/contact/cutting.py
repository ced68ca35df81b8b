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

from teleop.contact.kernels import cutting_forces
from teleop.util.typed import Checked, setting


@dataclass(frozen=True)
class CuttingModel(Checked):
    """Resistance coefficients (SI): see the module docstring."""

    f_N_per_m: float = setting(400.0, ge=0.0, doc="fracture resistance per metre of depth, N/m")
    b_Ns_per_m2: float = setting(4000.0, ge=0.0, doc="viscous cutting resistance, N*s/m^2")
    lateral_Ns_per_m2: float = setting(20000.0, ge=0.0, doc="sideways resistance, N*s/m^2")
    twist_Nms_per_m: float = setting(2.0, ge=0.0, doc="twist resistance, N*m*s/m")
    v_smooth_mps: float = setting(1e-3, gt=0.0, doc="tanh smoothing speed of the stick, m/s")

    def compute_forces(self, depth, n, R, v_tip, w):
        """(F_cut (3,) N, F_lat (3,) N, tau (3,) N*m, v_c m/s) for the tip ``depth`` m under a
        plane with outward normal n, tool rotation R, tip velocity v_tip (m/s), angular w (rad/s):
        the law of the module docstring, compiled once (:func:`teleop.contact.kernels.cutting_forces`,
        which the tissue's contact law calls too)."""
        out, v_c = cutting_forces(float(depth), np.asarray(n, dtype=float), np.asarray(R, dtype=float),
                                  np.asarray(v_tip, dtype=float), np.asarray(w, dtype=float), self.f_N_per_m,
                                  self.b_Ns_per_m2, self.lateral_Ns_per_m2, self.twist_Nms_per_m, self.v_smooth_mps)
        return out[0:3], out[3:6], out[6:9], v_c

    def law_params(self) -> tuple[float, float, float, float, float]:
        """(f N/m, b N*s/m^2, lateral N*s/m^2, twist N*m*s/m, v_smooth m/s): the coefficients as
        the compiled laws take them (:data:`teleop.contact.kernels.LAW_SIZE`)."""
        return (self.f_N_per_m, self.b_Ns_per_m2, self.lateral_Ns_per_m2, self.twist_Nms_per_m, self.v_smooth_mps)
