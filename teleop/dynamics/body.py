"""A rigid body in generalized coordinates q = (p, theta): 3 positions (m) and 3 Euler angles (rad).

The twist nu = (v, w) (world velocity of the body origin, world angular velocity) is linear in the
coordinate rates:  nu = T(q) qd,  T = blockdiag(I3, R E_B),  where E_B maps Euler rates to the
body angular velocity (see :mod:`teleop.dynamics.rotations`). Hence eq. 7 done right:

    M(q) = T^T blockdiag(m I3, R J R^T) T = blockdiag(m I3, E_B^T J E_B),

and the Coriolis/centrifugal vector consistent with that M(q) (the projected Newton-Euler equations):

    C(q, qd) qd = [0;  E_B^T (J Edot_B thetadot + w_B x J w_B)].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teleop.dynamics.rotations import EulerChart, cross, rate_map
from teleop.util.errors import ConfigError


@dataclass(frozen=True, eq=False)
class RigidBody:
    """Mass (kg) and body-frame rotational inertia about the body origin (kg*m^2, 3x3 or 3 diag)."""

    mass_kg: float
    inertia_kgm2: np.ndarray

    def __post_init__(self):
        m = float(self.mass_kg)
        if not np.isfinite(m) or m <= 0:
            raise ConfigError(f"body.mass_kg: expected a finite positive mass, got {self.mass_kg}")
        J = np.asarray(self.inertia_kgm2, dtype=float)
        if J.shape == (3,):
            J = np.diag(J)
        if J.shape != (3, 3) or not np.all(np.isfinite(J)):
            raise ConfigError("body.inertia_kgm2: expected 3 principal values or a 3x3 matrix")
        if not np.allclose(J, J.T, rtol=1e-9, atol=1e-15):
            raise ConfigError("body.inertia_kgm2: the inertia matrix must be symmetric")
        if np.linalg.eigvalsh(J).min() <= 0:
            raise ConfigError("body.inertia_kgm2: the inertia matrix must be positive definite")
        object.__setattr__(self, "mass_kg", m)
        object.__setattr__(self, "inertia_kgm2", J)
        object.__setattr__(self, "_J_inv", np.linalg.inv(J))

    @property
    def J(self) -> np.ndarray:
        return self.inertia_kgm2

    @property
    def J_inv(self) -> np.ndarray:
        return self._J_inv  # type: ignore[attr-defined]


class Kinematics:
    """Everything one evaluation needs from (chart, q, qd), computed once.

    p (3,) m, R (3, 3), E_B (3, 3), Edq (3,) = d/dt(E_B) thetadot, v (3,) m/s, w (3,) rad/s world,
    w_B (3,) rad/s body, E_W = R E_B (3, 3).
    """

    __slots__ = ("E_B", "E_W", "Edq", "R", "p", "v", "w", "w_B")

    def __init__(self, chart: EulerChart, q: np.ndarray, qd: np.ndarray):
        R, E_B, Edq = rate_map(chart, q[3:], qd[3:])
        self.p = q[:3]
        self.R = R
        self.E_B = E_B
        self.Edq = Edq
        self.v = qd[:3]
        self.w_B = E_B @ qd[3:]
        self.w = R @ self.w_B
        self.E_W = R @ E_B


def compute_mass_matrix(body: RigidBody, kin: Kinematics) -> np.ndarray:
    """M(q) (6, 6), eq. 7 for Euler-angle rates: blockdiag(m I3, E_B^T J E_B)."""
    M = np.zeros((6, 6))
    M[0, 0] = M[1, 1] = M[2, 2] = body.mass_kg
    M[3:, 3:] = kin.E_B.T @ body.J @ kin.E_B
    return M


def compute_coriolis(body: RigidBody, kin: Kinematics, gyroscopic: bool = True) -> np.ndarray:
    """C(q, qd) qd (6,), in N and N*m per generalized coordinate.

    ``gyroscopic=False`` drops the w_B x J w_B torque (the scene effect "coriolis" switched off);
    the chart term E_B^T J Edot_B thetadot stays, since it is kinematics, not an effect.
    """
    out = np.zeros(6)
    tq = body.J @ kin.Edq
    if gyroscopic:
        tq = tq + cross(kin.w_B, body.J @ kin.w_B)
    out[3:] = kin.E_B.T @ tq
    return out


def generalized_force(kin: Kinematics, wrench_W: np.ndarray) -> np.ndarray:
    """T^T F: a world wrench (f N, tau N*m) at the body origin as a generalized force (6,)."""
    out = np.empty(6)
    out[:3] = wrench_W[:3]
    out[3:] = kin.E_W.T @ wrench_W[3:]
    return out


def constraint_matrix(G: np.ndarray, kin: Kinematics) -> np.ndarray:
    """A(q) = G T (m, 6): twist rows mapped to generalized coordinates."""
    A = np.empty((G.shape[0], 6))
    A[:, :3] = G[:, :3]
    A[:, 3:] = G[:, 3:] @ kin.E_W
    return A


def constraint_bias(G: np.ndarray, bias: np.ndarray, kin: Kinematics) -> np.ndarray:
    """Adot(q, qd) qd (m,) = d/dt(G) nu + G_w R (Edot_B thetadot)."""
    return bias + G[:, 3:] @ (kin.R @ kin.Edq)


def kinetic_energy(body: RigidBody, kin: Kinematics) -> float:
    """1/2 m |v|^2 + 1/2 w_B^T J w_B (J)."""
    return 0.5 * body.mass_kg * float(kin.v @ kin.v) + 0.5 * float(kin.w_B @ body.J @ kin.w_B)
