"""The local damping of a contact: how steeply its wrench falls as the tool moves faster.

The slave sends it with every contact wrench so that the master can render that part of the
contact where it is felt, without the link's delay (see :mod:`teleop.tick.feedback`). It is
the linearization of the contact model at the tool's present twist,

    D = -sym(dW/dV),   W the wrench at the tool frame's origin, V = (v, w) its twist,

written out by the shipped tissue models (``damping`` at the tip, moved to the origin by
:func:`moved_to_origin`), or by central differences of the model itself for any other model with
a ``wrench`` method (a user's), with the part that would feed energy (negative eigenvalues) cut
off: the master renders a damper, never a source. The differences are the tests' oracle for the
written-out laws. Units: N*s/m on force/velocity, N*m*s/rad on torque/rate, N*s and N*m*s/m
across.
"""

from __future__ import annotations

import numpy as np

#: the central-difference step, m/s and rad/s, relative to max(1, |V|)
STEP = 1e-6


def contact_damping(wrench_at, V: np.ndarray) -> np.ndarray:
    """D (6, 6), symmetric positive semidefinite, of the wrench ``wrench_at(V)`` (6,) at the
    twist ``V`` (6,). Twelve evaluations of the model."""
    V = np.asarray(V, dtype=float)
    h = STEP * max(1.0, float(np.abs(V).max()))
    J = np.empty((6, 6))
    for j in range(6):
        dV = np.zeros(6)
        dV[j] = h
        J[:, j] = (wrench_at(V + dV) - wrench_at(V - dV)) / (2.0 * h)
    return psd_part(-0.5 * (J + J.T))


def psd_part(D: np.ndarray) -> np.ndarray:
    """The symmetric D with its negative eigenvalues set to zero (a damper keeps its dissipating
    directions only)."""
    e, V = np.linalg.eigh(D)
    if e[0] >= 0.0:
        return D
    return (V * np.maximum(e, 0.0)) @ V.T


def moved_to_origin(D_tip: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The damping D_tip (6, 6) of a wrench acting at the tip, seen at the tool origin, the tip
    at ``d`` (3,) m from it: X^T D_tip X, X the tip twist of the origin's (v - d x w, w)."""
    d = np.asarray(d, dtype=float)
    if not d.any():  # the tip at the origin
        return D_tip
    X = np.eye(6)
    X[:3, 3:] = np.array([[0.0, d[2], -d[1]], [-d[2], 0.0, d[0]], [d[1], -d[0], 0.0]])
    return X.T @ D_tip @ X
