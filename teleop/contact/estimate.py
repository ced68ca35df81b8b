"""The contact as the slave sees it, estimated online: a plane (normal, anchor point, stiffness) from
the slave's own contact force and tip motion, for the master to render where it is felt
(model-mediated teleoperation: Mitra and Niemeyer, "Model-mediated telemanipulation", 2008;
Passenberg, Peer and Buss, "A survey of environment-, operator-, and task-adapted controllers for
teleoperation systems", Mechatronics 2010; the estimator as in Achhammer et al., "Improvement of
model-mediated teleoperation using a new hybrid environment estimation technique", ICRA 2010).

The model is a unilateral spring along the normal ``n`` (unit, pointing out of the surface, the
direction the contact pushes the tip):

    f_n = k (c - s),  s = n . x_tip   (in contact, f_n > 0; nothing outside),

estimated by recursive least squares with exponential forgetting on the normal force against the
tip's position and velocity along ``n`` (regressors 1, s - s0, ds/dt: the damping term is fitted
so that it does not bias ``k``, and is not sent: the contact's damping travels as the model's
``D``, :mod:`teleop.contact.damping`). The normal is the direction of the low-passed contact force
(a frictionless plane's is exact; a cut's tangential drag tilts it, and the estimate's confidence
falls with the fit). The slave never uses its contact model here: only the force it measures and
where its tip is, as a real slave with a force sensor would.

The surface is remembered between touches (a bouncing contact keeps its model; a touch whose
force points more than 30 degrees away from the remembered normal starts a new one), but a model is
sent only while in contact. Confidence in [0, 1]: zero until the tip has moved ``excursion_m`` along the normal while in
contact (position alone cannot separate stiffness from where the surface is) and while the fitted
stiffness is not positive; then the fraction of the force's variance the fit explains over the
forgetting window. Units: m, m/s, N, N/m.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: the plane a reply carries when there is none: normal, anchor, stiffness, confidence all zero
NO_PLANE = np.zeros(8)
NO_PLANE.flags.writeable = False


#: the estimator's state, one float array: normal (3), theta (3), P (9, row-major), s0, s_lo, s_hi,
#: mean_f, var_f, var_e, k, confidence, in_contact (0/1)
_N, _TH, _P, _S0, _LO, _HI, _MF, _VF, _VE, _K, _C, _IN = 0, 3, 6, 15, 16, 17, 18, 19, 20, 21, 22, 23
_STATE = 24


@njit(cache=True)
def _reset(st):
    st[:] = 0.0
    for i in range(3):
        st[_P + 4 * i] = 1e4


@njit(cache=True)
def rls_plane_update(st, x, v, F, lam, f_contact, excursion, a_n, same_cos, rel_max, L, Vs):
    """One tick of :class:`PlaneEstimator` on its state ``st`` (in place; see the class)."""
    f = math.sqrt(F[0] * F[0] + F[1] * F[1] + F[2] * F[2])
    if not math.isfinite(f) or f < f_contact:
        st[_IN] = 0.0
        return
    u0, u1, u2 = F[0] / f, F[1] / f, F[2] / f
    known = st[_N] != 0.0 or st[_N + 1] != 0.0 or st[_N + 2] != 0.0
    if not known or u0 * st[_N] + u1 * st[_N + 1] + u2 * st[_N + 2] < same_cos:  # first touch, or another surface
        _reset(st)
        st[_N], st[_N + 1], st[_N + 2] = u0, u1, u2
        s = u0 * x[0] + u1 * x[1] + u2 * x[2]
        st[_S0] = st[_LO] = st[_HI] = s
        st[_MF] = f
    else:
        n0 = st[_N] + a_n * (u0 - st[_N])
        n1 = st[_N + 1] + a_n * (u1 - st[_N + 1])
        n2 = st[_N + 2] + a_n * (u2 - st[_N + 2])
        nn = max(math.sqrt(n0 * n0 + n1 * n1 + n2 * n2), 1e-12)
        st[_N], st[_N + 1], st[_N + 2] = n0 / nn, n1 / nn, n2 / nn
    st[_IN] = 1.0
    n0, n1, n2 = st[_N], st[_N + 1], st[_N + 2]
    s = n0 * x[0] + n1 * x[1] + n2 * x[2]
    fn = n0 * F[0] + n1 * F[1] + n2 * F[2]
    phi = (1.0, (s - st[_S0]) / L, (n0 * v[0] + n1 * v[1] + n2 * v[2]) / Vs)
    Pphi = [0.0, 0.0, 0.0]
    for i in range(3):
        Pphi[i] = st[_P + 3 * i] * phi[0] + st[_P + 3 * i + 1] * phi[1] + st[_P + 3 * i + 2] * phi[2]
    den = lam + phi[0] * Pphi[0] + phi[1] * Pphi[1] + phi[2] * Pphi[2]
    e = fn - (phi[0] * st[_TH] + phi[1] * st[_TH + 1] + phi[2] * st[_TH + 2])
    trace = 0.0
    for i in range(3):
        g = Pphi[i] / den
        st[_TH + i] += g * e
        for j in range(3):
            st[_P + 3 * i + j] -= g * Pphi[j]
        trace += st[_P + 4 * i]
    if trace < 1e6:  # no wind-up while nothing excites it
        for i in range(9):
            st[_P + i] /= lam
    st[_MF] = lam * st[_MF] + (1.0 - lam) * fn
    st[_VF] = lam * st[_VF] + (1.0 - lam) * (fn - st[_MF]) ** 2
    st[_VE] = lam * st[_VE] + (1.0 - lam) * e * e
    st[_LO], st[_HI] = min(st[_LO], s), max(st[_HI], s)
    k = -st[_TH + 1] / L
    st[_K] = k
    moved = min(1.0, (st[_HI] - st[_LO]) / excursion)
    fit = 1.0 - min(1.0, st[_VE] / st[_VF]) if st[_VF] > 0.0 else 0.0
    # the stiffness's standard error relative to it (RLS: cov(theta) ~ P var(e)); rel_max or more: none
    rel = math.sqrt(max(st[_P + 4], 0.0) * st[_VE]) / max(abs(st[_TH + 1]), 1e-300)
    sure = max(0.0, 1.0 - rel / rel_max)
    st[_C] = moved * fit * sure if k > 0.0 and math.isfinite(k) else 0.0


class PlaneEstimator:
    """``update(x_tip, v_tip, F_tip)`` once per tick (P frame: m, m/s, N); ``plane(anchor)`` the
    model as a reply carries it (8,): normal (3), anchor (3, m), stiffness (N/m), confidence. One
    compiled kernel per tick (:func:`rls_plane_update`) on one state array."""

    #: the stiffness's relative standard error at which the confidence reaches zero
    REL_STD_MAX = 0.1
    #: a touch whose force is within this cosine of the remembered normal is the same surface
    SAME_SURFACE_COS = math.cos(math.radians(30.0))
    #: regressor scales (m, m/s): a well-conditioned covariance
    L_M, V_M_S = 1e-3, 1e-2

    def __init__(self, dt_s: float, memory_s: float = 0.2, f_contact_N: float = 0.05,
                 excursion_m: float = 2e-5, normal_tau_s: float = 0.01) -> None:
        if not (dt_s > 0 and memory_s > 0 and f_contact_N > 0 and excursion_m > 0 and normal_tau_s >= 0):
            raise ValueError("PlaneEstimator: dt_s, memory_s, f_contact_N, excursion_m > 0, normal_tau_s >= 0")
        self._args = (math.exp(-dt_s / memory_s), f_contact_N, excursion_m,
                      1.0 - math.exp(-dt_s / normal_tau_s) if normal_tau_s > 0 else 1.0,
                      self.SAME_SURFACE_COS, self.REL_STD_MAX, self.L_M, self.V_M_S)
        self.state = np.zeros(_STATE)
        self.reset()

    def reset(self) -> None:
        """The estimate forgotten (a touch on another surface starts a new plane)."""
        _reset(self.state)

    def update(self, x_tip: np.ndarray, v_tip: np.ndarray, F_tip: np.ndarray) -> None:
        """One tick's measurement: the tip's position ``x_tip`` (3,) m and velocity ``v_tip`` (3,)
        m/s, and the contact force on it ``F_tip`` (3,) N."""
        rls_plane_update(self.state, x_tip, v_tip, F_tip, *self._args)

    @property
    def n(self) -> np.ndarray:
        """(3,) the estimated normal (unit; zeros before a first touch)."""
        return self.state[_N:_N + 3].copy()

    @property
    def k(self) -> float:
        """The estimated stiffness along the normal (N/m)."""
        return float(self.state[_K])

    @property
    def confidence(self) -> float:
        """The estimate's confidence in [0, 1]."""
        return float(self.state[_C])

    @property
    def in_contact(self) -> bool:
        return bool(self.state[_IN])

    @property
    def first_touch_m(self) -> float:
        """Where along the normal the tip first touched this surface (m)."""
        return float(self.state[_S0])

    def plane(self, anchor_tip: np.ndarray, remembered: bool = False) -> np.ndarray:
        """(8,): the normal (3), ``anchor_tip`` (3, m: where the tip is held to be, the model's
        force there being the measured one), the stiffness (N/m) and the confidence; NO_PLANE when
        not confident, or not in contact unless ``remembered`` (the last estimate, the tip having
        left the surface a moment ago)."""
        st = self.state
        if (st[_IN] == 0.0 and not remembered) or st[_C] <= 0.0:
            return NO_PLANE
        out = np.empty(8)
        out[:3], out[3:6], out[6], out[7] = st[_N:_N + 3], anchor_tip, st[_K], st[_C]
        return out
