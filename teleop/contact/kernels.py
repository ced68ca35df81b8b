"""Compiled kernels (numba) of the contact laws' hot path: the blade's in-plane axes and the
contact's damping written out (one definition each; :mod:`teleop.contact.cutting` and
:mod:`teleop.contact.tissue` call them). Tested against central differences of the laws
(tests/unit/test_contact_damping.py; run uncompiled with ``NUMBA_DISABLE_JIT=1``)."""

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
