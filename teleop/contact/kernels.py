"""Compiled kernels (numba) of the contact laws: the blade's in-plane axes, the cutting model, the
normal models, the contact law they make and its damping written out, one definition each
(:mod:`teleop.contact.cutting` and :mod:`teleop.contact.tissue` call them; a tick evaluates the
block's wrench and damping in one call each). Tested against hand-computed forces and central
differences of the laws (tests/unit/test_contact_tissue.py, tests/unit/test_contact_damping.py;
run uncompiled with ``NUMBA_DISABLE_JIT=1``). Units SI: m, m/s, rad/s, N, N*m."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def unit_in_plane(a, n):
    """The unit projection of a (3-tuple) onto the plane normal to the unit n (3-tuple), as a
    3-tuple; zero if a is along n."""
    an = a[0] * n[0] + a[1] * n[1] + a[2] * n[2]
    x, y, z = a[0] - an * n[0], a[1] - an * n[1], a[2] - an * n[2]
    norm = math.sqrt(x * x + y * y + z * z)
    if norm <= 1e-9:
        return 0.0, 0.0, 0.0
    return x / norm, y / norm, z / norm


@njit(cache=True)
def contact_damping_at_tip(depth, n, R, v_tip, f, b, lateral, twist, v_smooth, c_n):
    """-dW/d(v_tip, w) (6, 6) of the tissue's wrench at the tip, ``depth`` m deep under the
    outward unit normal n (3,), tool rotation R (3, 3), tip velocity v_tip (3,) m/s: along the
    cutting direction c the slope of the cut law, depth (b sign(v_c) tanh(u) + (f + b |v_c|)
    sech^2(u) / v_smooth), u = v_c / v_smooth (the stick: f depth / v_smooth at v_c = 0); along the
    side axis s ``lateral * depth``; along n the normal model's ``c_n`` (0 while its force is
    clamped); about n ``twist * depth``. Coefficients as :class:`teleop.contact.cutting.CuttingModel`.
    Zero outside the tissue."""
    D = np.zeros((6, 6))
    if depth <= 0.0:
        return D
    nn = (n[0], n[1], n[2])
    c = unit_in_plane((R[0, 0], R[1, 0], R[2, 0]), nn)
    s = unit_in_plane((R[0, 1], R[1, 1], R[2, 1]), nn)
    v_c = c[0] * v_tip[0] + c[1] * v_tip[1] + c[2] * v_tip[2]
    u = v_c / v_smooth
    ch = math.cosh(min(abs(u), 350.0))
    slope = depth * (b * math.copysign(1.0, v_c) * math.tanh(u) + (f + b * abs(v_c)) / (ch * ch) / v_smooth)
    lt, tw = lateral * depth, twist * depth
    for i in range(3):
        for j in range(3):
            D[i, j] = slope * c[i] * c[j] + lt * s[i] * s[j] + c_n * nn[i] * nn[j]
            D[3 + i, 3 + j] = tw * nn[i] * nn[j]
    return D


# -- the contact law: normal model plus cutting, at a tip d m deep under the unit normal n --------
#: ``law`` (LAW_SIZE,): model (1.0 Hunt-Crossley, 0.0 Kelvin-Voigt), stiffness, exponent,
#: alpha (s/m), Kelvin-Voigt damping (N*s/m), then the cutting model's f, b, lateral, twist,
#: v_smooth (:class:`teleop.contact.cutting.CuttingModel`); see :meth:`TissueBlock.law`
LAW_SIZE = 10
#: :func:`contact_law`'s output: wrench (0:6, N, N*m), F_cut (6:9), F_lat (9:12) N, the cutting
#: torque tau (12:15) N*m, the normal force F_n (15) N, the cut speed v_c (16) m/s
LAW_OUT = 17


@njit(cache=True, inline="always")
def _normal_force(d, d_dot, law):
    """(F_n N, clamped >= 0; its damping dF_n/d(d_dot) N*s/m, zero while clamped) of the normal
    model at depth d (m) and penetration rate d_dot (m/s): Hunt-Crossley k d^e (1 + 1.5 alpha
    d_dot), Kelvin-Voigt k d + c d_dot."""
    if law[0] != 0.0:
        kd = law[1] * d ** law[2]
        fn, c_n = kd * (1.0 + 1.5 * law[3] * d_dot), kd * 1.5 * law[3]
    else:
        fn, c_n = law[1] * d + law[4] * d_dot, law[4]
    return max(fn, 0.0), c_n if fn > 0.0 else 0.0


@njit(cache=True, inline="always")
def _cutting(depth, n, R, v_tip, w, f, b, lateral, twist, v_smooth, out, o):
    """The cutting model (:mod:`teleop.contact.cutting`) at a tip ``depth`` > 0 m deep: writes
    F_cut, F_lat (N) and tau (N*m) into out[o:o + 9]; returns v_c (m/s)."""
    nn = (n[0], n[1], n[2])
    c = unit_in_plane((R[0, 0], R[1, 0], R[2, 0]), nn)
    s = unit_in_plane((R[0, 1], R[1, 1], R[2, 1]), nn)
    v_c = v_tip[0] * c[0] + v_tip[1] * c[1] + v_tip[2] * c[2]
    v_s = v_tip[0] * s[0] + v_tip[1] * s[1] + v_tip[2] * s[2]
    k_cut = -(f + b * abs(v_c)) * depth * math.tanh(v_c / v_smooth)
    k_lat = -lateral * depth * v_s
    k_tw = -twist * depth * (w[0] * nn[0] + w[1] * nn[1] + w[2] * nn[2])
    for i in range(3):
        out[o + i] = k_cut * c[i]
        out[o + 3 + i] = k_lat * s[i]
        out[o + 6 + i] = k_tw * nn[i]
    return v_c


@njit(cache=True)
def cutting_forces(depth, n, R, v_tip, w, f, b, lateral, twist, v_smooth):
    """(out (9,): F_cut, F_lat (N), tau (N*m); v_c m/s) of the cutting model; zeros and 0.0 at
    ``depth`` <= 0 (outside the tissue)."""
    out = np.zeros(9)
    if depth <= 0.0:
        return out, 0.0
    return out, _cutting(depth, n, R, v_tip, w, f, b, lateral, twist, v_smooth, out, 0)


@njit(cache=True)
def contact_law(d, n, R, v_tip, w, law):
    """The contact of a tip ``d`` m deep under the outward unit normal n (3,) (tool rotation R,
    tip velocity v_tip m/s, rate w rad/s): out (LAW_OUT,) as laid out above, zeros for d <= 0.
    The wrench is F_n n + F_cut + F_lat and tau, at the tip, world axes."""
    out = np.zeros(LAW_OUT)
    if d <= 0.0:
        return out
    fn = _normal_force(d, -(n[0] * v_tip[0] + n[1] * v_tip[1] + n[2] * v_tip[2]), law)[0]
    out[16] = _cutting(d, n, R, v_tip, w, law[5], law[6], law[7], law[8], law[9], out, 6)
    for i in range(3):
        out[i] = fn * n[i] + out[6 + i] + out[9 + i]
        out[3 + i] = out[12 + i]
    out[15] = fn
    return out


@njit(cache=True)
def contact_damping(d, n, R, v_tip, law):
    """-dW/d(v_tip, w) (6, 6) of :func:`contact_law`: the normal model's damping along n plus the
    cutting model's (:func:`contact_damping_at_tip`); zeros for d <= 0."""
    if d <= 0.0:
        return np.zeros((6, 6))
    c_n = _normal_force(d, -(n[0] * v_tip[0] + n[1] * v_tip[1] + n[2] * v_tip[2]), law)[1]
    return contact_damping_at_tip(d, n, R, v_tip, law[5], law[6], law[7], law[8], law[9], c_n)


@njit(cache=True, inline="always")
def plane_depth(p_tip, geom):
    """Penetration (m) of the point p_tip (3,) below the plane of ``geom`` (7,): a point of it
    (0:3, m), its outward unit normal (3:6), clamped to [0, the thickness geom[6]]."""
    d = -(geom[3] * (p_tip[0] - geom[0]) + geom[4] * (p_tip[1] - geom[1]) + geom[5] * (p_tip[2] - geom[2]))
    return min(max(d, 0.0), geom[6])


@njit(cache=True)
def block_wrench(p_tip, R, v_tip, w, geom, law):
    """The wrench (6,: N, N*m, at the tip, world axes) of the block of ``geom`` (:func:`plane_depth`)
    and ``law`` on a tip at p_tip (m): :func:`contact_law`'s first six."""
    return contact_law(plane_depth(p_tip, geom), geom[3:6], R, v_tip, w, law)[:6]


@njit(cache=True)
def block_damping(p_tip, R, v_tip, geom, law):
    """:func:`contact_damping` (6, 6) of the block of ``geom`` and ``law`` at a tip at p_tip (m)."""
    return contact_damping(plane_depth(p_tip, geom), geom[3:6], R, v_tip, law)
