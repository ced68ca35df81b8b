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
from dataclasses import dataclass
from typing import Literal

import numpy as np

from teleop.contact.cutting import CuttingModel
from teleop.contact.kernels import block_damping, block_wrench, contact_damping, contact_law, plane_depth
from teleop.util.typed import Checked, setting, validate


def _nonzero(v) -> str | None:
    return None if float(np.linalg.norm(v)) > 1e-12 else "expected a non-zero 3-vector"


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
class TissueBlock(Checked):
    """Tissue slab: geometry (m), normal model ("hunt_crossley" | "kelvin_voigt"), cutting model.

    stiffness: N/m^exponent (Hunt-Crossley) or N/m (Kelvin-Voigt); alpha_s_per_m: Hunt-Crossley
    damping (s/m); damping_Ns_per_m: Kelvin-Voigt damping.
    """

    origin_m: np.ndarray = setting(factory=lambda: np.array([0.5, 0.0, 0.2]), n=3, doc="a point of the surface, m")
    normal: np.ndarray = setting(factory=lambda: np.array([0.0, 0.0, 1.0]), n=3, check=_nonzero,
                                 doc="outward normal of the surface (normalized)")
    thickness_m: float = setting(0.03, gt=0.0, doc="thickness of the block, m")
    model: Literal["hunt_crossley", "kelvin_voigt"] = setting("hunt_crossley", doc="normal contact model")
    stiffness: float = setting(1.0e4, gt=0.0, doc="N/m^exponent (Hunt-Crossley) or N/m (Kelvin-Voigt)")
    exponent: float = setting(1.5, gt=0.0, doc="Hunt-Crossley exponent")
    alpha_s_per_m: float = setting(2.0, ge=0.0, doc="Hunt-Crossley damping, s/m")
    damping_Ns_per_m: float = setting(20.0, ge=0.0, doc="Kelvin-Voigt damping, N*s/m")
    cutting: CuttingModel = setting(factory=CuttingModel, doc="cutting resistance")

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "normal", self.normal / np.linalg.norm(self.normal))
        # what the compiled laws take (teleop.contact.kernels), made once
        object.__setattr__(self, "_geom", np.array([*self.origin_m, *self.normal, self.thickness_m], dtype=float))
        object.__setattr__(self, "_law", self.law())

    def law(self) -> np.ndarray:
        """The contact law's coefficients as the compiled laws take them, (LAW_SIZE,)
        (:data:`teleop.contact.kernels.LAW_SIZE`): model, stiffness, exponent, alpha s/m,
        damping N*s/m, then the cutting model's (:meth:`CuttingModel.law_params`)."""
        return np.array([1.0 if self.model == "hunt_crossley" else 0.0, self.stiffness, self.exponent,
                         self.alpha_s_per_m, self.damping_Ns_per_m, *self.cutting.law_params()], dtype=float)

    @classmethod
    def from_dict(cls, d: dict, where: str = "tissue") -> TissueBlock:
        """Build from a plain table through the one validator (errors name ``where.key``)."""
        return validate(cls, d, "", where)

    def compute_depth(self, p_tip) -> float:
        """Penetration (m) of the point below the surface, clamped to [0, thickness]."""
        return plane_depth(np.asarray(p_tip, dtype=float), self._geom)

    def compute_contact(self, p_tip, R_tool, v_tip, w) -> ContactReport:
        """The contact at the blade tip (pure): see the module docstring."""
        return self.contact_law(self.compute_depth(p_tip), self.normal, R_tool, v_tip, w)

    def contact_law(self, d: float, n, R_tool, v_tip, w) -> ContactReport:
        """The contact of a tip ``d`` m deep under a surface of outward unit normal ``n`` (3,):
        the normal model and the cutting model of the module docstring (any surface's tissue uses
        this one law, :func:`teleop.contact.kernels.contact_law`)."""
        if d <= 0.0:
            return ContactReport(np.zeros(6), 0.0, False, 0.0, 0.0, 0.0, 0.0)
        out = contact_law(float(d), np.asarray(n, dtype=float), np.asarray(R_tool, dtype=float),
                          np.asarray(v_tip, dtype=float), np.asarray(w, dtype=float), self._law)
        return ContactReport(out[:6], d, True, float(out[15]), math.hypot(*out[6:9].tolist()),
                             math.hypot(*out[9:12].tolist()), float(out[16]))

    def wrench(self, p_tip, R_tool, v_tip, w) -> np.ndarray:
        """World wrench (6,) on the tool at the tip: (N, N*m). One compiled call
        (:func:`teleop.contact.kernels.block_wrench`, the law of :meth:`contact_law`)."""
        return block_wrench(np.asarray(p_tip, dtype=float), np.asarray(R_tool, dtype=float),
                            np.asarray(v_tip, dtype=float), np.asarray(w, dtype=float), self._geom, self._law)

    def damping(self, p_tip, R_tool, v_tip, w) -> np.ndarray:
        """-dW/d(v_tip, w) (6, 6) of :meth:`wrench` at the tip (:mod:`teleop.contact.damping`);
        one compiled call (:func:`teleop.contact.kernels.block_damping`)."""
        return block_damping(np.asarray(p_tip, dtype=float), np.asarray(R_tool, dtype=float),
                             np.asarray(v_tip, dtype=float), self._geom, self._law)

    def damping_law(self, d: float, n, R_tool, v_tip, w) -> np.ndarray:
        """-dW/d(v_tip, w) (6, 6) of :meth:`contact_law`, written out: the normal model's damping
        along n (Hunt-Crossley k d^e 1.5 alpha, Kelvin-Voigt c; none while the force is clamped at
        zero) plus the cutting model's (:func:`teleop.contact.kernels.contact_damping`)."""
        return contact_damping(float(d), np.asarray(n, dtype=float), np.asarray(R_tool, dtype=float),
                               np.asarray(v_tip, dtype=float), self._law)


class SurfaceTissue:
    """Tissue under a curved surface (:class:`teleop.dynamics.surface.HeightSurface`, patient
    frame): the tip's depth is its distance below the surface along the normal at its foot (the
    closest surface point), and ``block``'s contact and cutting law acts along that normal. The
    block's material settings are used; its plane (origin, normal) is not."""

    def __init__(self, block: TissueBlock, surface):
        self.block, self.surface = block, surface
        self._foot = None  # Newton's warm start

    def depth_and_normal(self, p_tip) -> tuple[float, np.ndarray]:
        """(penetration m, clamped to [0, thickness], outward unit normal at the foot)."""
        s, n, foot = self.surface.signed_distance(p_tip, self._foot)
        self._foot = foot
        return min(max(-s, 0.0), self.block.thickness_m), n

    def compute_depth(self, p_tip) -> float:
        return self.depth_and_normal(p_tip)[0]

    def compute_contact(self, p_tip, R_tool, v_tip, w) -> ContactReport:
        d, n = self.depth_and_normal(p_tip)
        return self.block.contact_law(d, n, R_tool, v_tip, w)

    def wrench(self, p_tip, R_tool, v_tip, w) -> np.ndarray:
        return self.compute_contact(p_tip, R_tool, v_tip, w).wrench

    def damping(self, p_tip, R_tool, v_tip, w) -> np.ndarray:
        d, n = self.depth_and_normal(p_tip)
        return self.block.damping_law(d, n, R_tool, v_tip, w)
