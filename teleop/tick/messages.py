"""The two messages master and slave exchange, and nothing else crosses between the sides.

Master -> slave, :class:`ToolCommand`: the virtual tool (the device's rendering of the reference
tool) as a pose and twist in the master's world frame M, the clutch, a sequence number and the
master's time. Slave -> master, :class:`ContactFeedback`: the contact wrench at the slave's tool
frame origin in the patient frame P, the contact's local damping and the twist it was taken at,
the slave's status, the sequence number of the command it answered, its own sequence number and
time.

Both carry ``energy_J`` (6,) J: the sender's cumulative energy that has entered the channel at
its port, per axis of the twist/wrench (the two-port time-domain passivity approach, see
:mod:`teleop.control.passivity`). It is zero when no passivity guard runs.

Both are frozen, slotted and checked when made: a message that exists is well formed (shapes,
finite numbers, a known status). A side that cannot make a well-formed message sends none.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from teleop.util.errors import TeleopError


class MessageError(TeleopError):
    """A malformed message: names the field and the reason."""


#: slave statuses a ContactFeedback may carry (the slave's own plus the link's safe states)
SLAVE_STATUSES = ("ok", "saturated", "tracking_error", "fixtures_relaxed", "infeasible_fallback",
                  "invalid_target", "hold", "link_lost", "joint_limit", "implausible_command")


_ZERO36, _ZERO6 = np.zeros(36), np.zeros(6)
_NO_ENERGY = np.zeros(6)  # the energy of a message without one (J): shared, read-only
_NO_ENERGY.flags.writeable = False


@njit(cache=True)
def _well_formed(x: np.ndarray, kind: int, r: int, e: int) -> bool:
    """True when the packed fields x (float64, 1-d) of a message pass every check of its
    ``__init__``: all finite; ``kind`` 1: x[r:r + 9] a row-major 3x3 with |det - 1| <= 1e-6
    (:func:`_det3`'s arithmetic); ``kind`` 2: x[r:r + 36] a 6x6 symmetric within 1e-9 of
    max(1, its largest entry); x[e:] (the energy, J) >= 0. One compiled pass over the message:
    the fast path of the checks, whose slow path names the field that fails."""
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    for i in range(e, x.shape[0]):
        if x[i] < 0.0:
            return False
    if kind == 1:
        a, b, c, d, f, g, h, k, m = x[r], x[r + 1], x[r + 2], x[r + 3], x[r + 4], x[r + 5], x[r + 6], x[r + 7], x[r + 8]
        return abs(a * (f * m - g * k) - b * (d * m - g * h) + c * (d * k - f * h) - 1.0) <= 1e-6
    asym, big = 0.0, 0.0
    for i in range(6):
        for j in range(6):
            big = max(big, abs(x[r + 6 * i + j]))
            asym = max(asym, abs(x[r + 6 * i + j] - x[r + 6 * j + i]))
    return not asym > 1e-9 * max(1.0, big)


_F64 = np.dtype(np.float64)


_NO_PLANE = np.zeros(8)
_NO_PLANE.flags.writeable = False


def _check_plane(plane: np.ndarray) -> None:
    """A contact plane (normal, anchor, stiffness, confidence) as :class:`ContactFeedback` takes it."""
    if abs(float(plane[:3] @ plane[:3]) - 1.0) > 1e-6:
        raise MessageError("ContactFeedback.plane_P: the normal is not a unit vector")
    if not plane[6] >= 0.0:
        raise MessageError(f"ContactFeedback.plane_P: stiffness {plane[6]!r} N/m is negative")
    if not 0.0 <= plane[7] <= 1.0:
        raise MessageError(f"ContactFeedback.plane_P: confidence {plane[7]!r} outside [0, 1]")


def _fast_flat(parts: tuple[ArrayLike, ...], energy: ArrayLike | None, n: int, kind: int,
               r: int) -> np.ndarray | None:
    """The parts (``n`` numbers) and ``energy`` (None: none; else 6 more) as one read-only float
    array, when they pass every check of the message (:func:`_well_formed`): the fields are then
    views into it, as :func:`_packed` and :func:`_energy` make them. None when they do not, or are
    not float arrays and lists of the right total size (the field-by-field checks then name what
    is wrong)."""
    try:
        flat = np.concatenate(parts if energy is None else (*parts, energy), axis=None)
    except (TypeError, ValueError):
        return None
    if flat.dtype is not _F64 or flat.size != (n if energy is None else n + 6) or not _well_formed(flat, kind, r, n):
        return None
    flat.flags.writeable = False
    return flat


def _packed(parts: tuple[ArrayLike, ...], sizes: tuple[int, ...], names: tuple[str, ...]) -> tuple[np.ndarray, ...]:
    """The parts as read-only float views into one array, after one finiteness check (a message
    is made every tick: one concatenation instead of a check per field)."""
    try:
        flat = np.concatenate([np.asarray(x, dtype=float).reshape(-1) for x in parts])
    except (TypeError, ValueError) as e:
        raise MessageError(f"{'/'.join(names)}: not numbers ({e})") from None
    if flat.size != sum(sizes):
        for x, n, name in zip(parts, sizes, names):
            if np.size(x) != n:
                raise MessageError(f"{name}: expected {n} numbers, got {np.size(x)}")
    with np.errstate(over="ignore"):  # huge finite numbers overflow the fast check: looked at below
        norm2 = float(flat @ flat)
    if not math.isfinite(norm2):
        bad = [name for x, name in zip(parts, names) if not np.all(np.isfinite(np.asarray(x, dtype=float)))]
        if bad:
            raise MessageError(f"{', '.join(bad)}: not finite")
    flat.flags.writeable = False
    out: list[np.ndarray] = []
    i = 0
    for n in sizes:
        out.append(flat[i:i + n])
        i += n
    return tuple(out)


def _det3(r: Sequence[float]) -> float:
    """det of a row-major 3x3 given as 9 floats."""
    a, b, c, d, e, f, g, h, k = r
    return a * (e * k - f * h) - b * (d * k - f * g) + c * (d * h - e * g)


def _seq(x: Any, name: str) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)) or not 0 <= int(x) < 2**63:
        raise MessageError(f"{name}: expected an integer in [0, 2^63), got {x!r}")
    return int(x)


def _energy(x: ArrayLike | None, name: str) -> np.ndarray:
    """(6,) cumulative port energy in J, non-negative; None gives zeros."""
    if x is None:
        a = np.zeros(6)
        a.flags.writeable = False
        return a
    (a,) = _packed((x,), (6,), (name,))
    if float(a.min()) < 0.0:
        raise MessageError(f"{name}: cumulative energy must be >= 0, got {a.min()!r}")
    return a


def _time(x: Any, name: str) -> float:
    t = float(x)
    if not math.isfinite(t):
        raise MessageError(f"{name}: not finite")
    return t


@dataclass(frozen=True, slots=True, init=False)
class ToolCommand:
    """Master -> slave: the virtual tool at master time ``t_s`` (s).

    ``p_m`` (3,) m and ``R`` (3, 3) the pose in M; ``v_m_s`` (3,) m/s and ``w_rad_s`` (3,) rad/s the
    twist in M; ``clutch`` True while the operator drives the slave; ``energy_J`` (6,) J the energy
    that has entered the channel at the master port so far, per axis (None: zeros); ``wall_N`` the
    normal force (N in M, >= 0) of the contact wall the master renders at this pose (model-mediated
    rendering, :mod:`teleop.contact.wall_model`; 0: none): the slave presses no harder.
    """

    seq: int
    t_s: float
    p_m: np.ndarray
    R: np.ndarray
    v_m_s: np.ndarray
    w_rad_s: np.ndarray
    clutch: bool
    energy_J: np.ndarray
    wall_N: float

    def __init__(self, seq: int, t_s: float, p_m: ArrayLike, R: ArrayLike, v_m_s: ArrayLike, w_rad_s: ArrayLike,
                 clutch: bool = True, energy_J: ArrayLike | None = None, wall_N: float = 0.0) -> None:
        """Checked as made (each field written once, with its checked value)."""
        object.__setattr__(self, "seq", _seq(seq, "ToolCommand.seq"))
        object.__setattr__(self, "t_s", _time(t_s, "ToolCommand.t_s"))
        parts = (p_m, R, v_m_s, w_rad_s)
        f = _fast_flat(parts, energy_J, 18, 1, 3)
        if f is not None:  # well formed (the usual case): checked in one pass
            p, R, v, w = f[0:3], f[3:12], f[12:15], f[15:18]
            energy = _NO_ENERGY if f.size == 18 else f[18:]
        else:  # the checks field by field, naming the first that fails
            p, R, v, w = _packed(parts, (3, 9, 3, 3),
                                 ("ToolCommand.p_m", "ToolCommand.R", "ToolCommand.v_m_s", "ToolCommand.w_rad_s"))
            if abs(_det3(R.tolist()) - 1.0) > 1e-6:
                raise MessageError("ToolCommand.R: not a rotation (det != 1)")
            energy = _energy(energy_J, "ToolCommand.energy_J")
        object.__setattr__(self, "p_m", p)
        object.__setattr__(self, "R", R.reshape(3, 3))
        object.__setattr__(self, "v_m_s", v)
        object.__setattr__(self, "w_rad_s", w)
        object.__setattr__(self, "clutch", bool(clutch))
        object.__setattr__(self, "energy_J", energy)
        fw = float(wall_N)
        if not (math.isfinite(fw) and fw >= 0.0):
            raise MessageError(f"ToolCommand.wall_N: expected a finite force >= 0 N, got {wall_N!r}")
        object.__setattr__(self, "wall_N", fw)


@dataclass(frozen=True, slots=True, init=False)
class ContactFeedback:
    """Slave -> master: the contact wrench ``wrench_P`` (6,: N, N*m) at the slave tool frame's
    origin, in the patient frame P, at slave time ``t_s`` (s), with the slave's ``status`` and the
    sequence number ``command_seq`` of the command it followed (-1 for none yet), and ``energy_J``
    (6,) J the energy that has entered the channel at the slave port so far (None: zeros).

    ``damping_P`` (6, 6) the contact's local damping D = -dW/dV at the tool's twist ``twist_P``
    (6,: m/s, rad/s), both in P at the tool frame's origin (:mod:`teleop.contact.damping`; None:
    zeros, no contact). D must be symmetric; the master renders it only when positive
    semidefinite.

    ``plane_P`` (8,) the contact as the slave estimates it (:mod:`teleop.contact.estimate`): the
    surface's unit normal (3), the anchor (3, m: the tip's position the model is measured at, less
    the guard's drift; model-mediated, a point on the surface), the stiffness along the normal
    (N/m, >= 0) and the estimate's confidence in [0, 1]; all zeros (None): no model, nothing
    rendered beyond the wrench and the damping."""

    seq: int
    t_s: float
    wrench_P: np.ndarray
    status: str
    command_seq: int
    energy_J: np.ndarray
    damping_P: np.ndarray
    twist_P: np.ndarray
    plane_P: np.ndarray

    def __init__(self, seq: int, t_s: float, wrench_P: ArrayLike, status: str, command_seq: int = -1,
                 energy_J: ArrayLike | None = None, damping_P: ArrayLike | None = None,
                 twist_P: ArrayLike | None = None, plane_P: ArrayLike | None = None) -> None:
        """Checked as made (each field written once, with its checked value)."""
        object.__setattr__(self, "seq", _seq(seq, "ContactFeedback.seq"))
        object.__setattr__(self, "t_s", _time(t_s, "ContactFeedback.t_s"))
        D = _ZERO36 if damping_P is None else damping_P
        V = _ZERO6 if twist_P is None else twist_P
        parts = (wrench_P, D, V, _NO_PLANE if plane_P is None else plane_P)
        f = _fast_flat(parts, energy_J, 56, 2, 6)
        if f is not None:  # well formed (the usual case): checked in one pass
            W, D, V, plane = f[0:6], f[6:42].reshape(6, 6), f[42:48], f[48:56]
            energy = _NO_ENERGY if f.size == 56 else f[56:]
        else:  # the checks field by field, naming the first that fails
            W, D, V, plane = _packed(parts, (6, 36, 6, 8),
                                     ("ContactFeedback.wrench_P", "ContactFeedback.damping_P",
                                      "ContactFeedback.twist_P", "ContactFeedback.plane_P"))
            D = D.reshape(6, 6)
            if float(np.abs(D - D.T).max()) > 1e-9 * max(1.0, float(np.abs(D).max())):
                raise MessageError("ContactFeedback.damping_P: not symmetric")
            energy = None
        if plane[6] != 0.0 or plane[7] != 0.0 or plane[:3].any():
            _check_plane(plane)
        object.__setattr__(self, "wrench_P", W)
        object.__setattr__(self, "damping_P", D)
        object.__setattr__(self, "twist_P", V)
        object.__setattr__(self, "plane_P", plane)
        if status not in SLAVE_STATUSES:
            raise MessageError(f"ContactFeedback.status: unknown status {status!r}")
        object.__setattr__(self, "status", status)
        c = command_seq
        if isinstance(c, bool) or not isinstance(c, (int, np.integer)) or not -1 <= int(c) < 2**63:
            raise MessageError(f"ContactFeedback.command_seq: expected an integer >= -1, got {c!r}")
        object.__setattr__(self, "command_seq", int(c))
        if energy is None:
            energy = _energy(energy_J, "ContactFeedback.energy_J")
        object.__setattr__(self, "energy_J", energy)

    @property
    def model_offset_P(self) -> np.ndarray:
        """F0 = W + D V (6,: N, N*m, P): the contact's local model's offset, the force that stays
        when its damping is rendered where it is felt (:mod:`teleop.tick.feedback`)."""
        return self.wrench_P + self.damping_P @ self.twist_P
