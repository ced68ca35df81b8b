"""The contact's local damping (teleop.contact.damping) against the cutting and tissue laws'
derivatives written out by hand, and the cut-off of energy-feeding directions."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from teleop.contact import CuttingModel, TissueBlock
from teleop.contact.damping import contact_damping, moved_to_origin, psd_part

R_CUT = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # blade along +x, edge down
O = np.array([0.5, 0.0, 0.2])


def _hand_damping(t: TissueBlock, depth: float, v_c: float) -> np.ndarray:
    """-dW/dV of the laws in teleop.contact (tip at the tool origin, blade along x, normal z)."""
    c = t.cutting
    u = v_c / c.v_smooth_mps
    d_cut = (c.b_Ns_per_m2 * math.copysign(1.0, v_c) * depth * math.tanh(u)
             + (c.f_N_per_m + c.b_Ns_per_m2 * abs(v_c)) * depth / math.cosh(u) ** 2 / c.v_smooth_mps)
    D = np.zeros((6, 6))
    D[0, 0] = d_cut
    D[1, 1] = c.lateral_Ns_per_m2 * depth
    D[2, 2] = t.stiffness * depth**t.exponent * 1.5 * t.alpha_s_per_m  # Hunt-Crossley, d_dot = -v_z
    D[5, 5] = c.twist_Nms_per_m * depth
    return D


@pytest.mark.parametrize("v_c", [0.0, 2e-4, -5e-4, 0.01, -0.03])
def test_damping_is_the_laws_derivative(v_c):
    t, depth = TissueBlock(origin_m=O), 0.005
    tip = O - [0, 0, depth]
    D = contact_damping(lambda V: t.wrench(tip, R_CUT, V[:3], V[3:]), np.array([v_c, 0, 0, 0, 0, 0]))
    ref = _hand_damping(t, depth, v_c)
    np.testing.assert_allclose(D, ref, rtol=1e-5, atol=1e-6 * np.abs(ref).max())
    if v_c == 0.0:  # the stick: f depth / v_smooth (the difference's own error is ~ (step / v_smooth)^2)
        assert D[0, 0] == pytest.approx(2000.0, rel=1e-4)


def test_no_contact_no_damping_and_a_spring_has_none():
    t = TissueBlock(origin_m=O, model="kelvin_voigt", damping_Ns_per_m=0.0,
                    cutting=CuttingModel(0.0, 0.0, 0.0, 0.0))
    above, below = O + [0, 0, 0.001], O - [0, 0, 0.002]
    for tip in (above, below):
        D = contact_damping(lambda V, tip=tip: t.wrench(tip, R_CUT, V[:3], V[3:]), np.zeros(6))
        assert np.abs(D).max() < 1e-6  # a pure spring's force does not depend on velocity


def test_a_moment_arm_moves_the_damping_to_the_origin():
    """Tip 2 cm below the origin: the damping at the origin is X^T D_tip X (the rigid transfer)."""
    t, depth = TissueBlock(origin_m=O), 0.004
    d = np.array([0.0, 0.0, -0.02])
    tip = O - [0, 0, depth]
    V0 = np.array([0.004, 0.0, 0.0, 0.0, 0.0, 0.0])

    def at_origin(V):
        v, w = V[:3], V[3:]
        W = t.wrench(tip, R_CUT, v + np.cross(w, d), w).copy()
        W[3:] += np.cross(d, W[:3])
        return W

    D = contact_damping(at_origin, V0)
    Dt = contact_damping(lambda V: t.wrench(tip, R_CUT, V[:3], V[3:]), V0)
    X = np.eye(6)  # tip twist = X V: v_tip = v - d x w
    X[:3, 3:] = -np.array([[0, -d[2], d[1]], [d[2], 0, -d[0]], [-d[1], d[0], 0]])
    np.testing.assert_allclose(D, X.T @ Dt @ X, rtol=1e-5, atol=1e-6)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=36, max_size=36))
def test_psd_part_keeps_the_dissipating_directions_only(a):
    A = np.array(a).reshape(6, 6)
    S = 0.5 * (A + A.T)
    P = psd_part(S)
    e, V = np.linalg.eigh(S)
    assert np.linalg.eigvalsh(P).min() >= -1e-9 * max(1.0, np.abs(S).max())
    for k in range(6):  # each eigen-direction keeps its positive value, loses its negative one
        assert V[:, k] @ P @ V[:, k] == pytest.approx(max(e[k], 0.0), abs=1e-8 * max(1.0, np.abs(S).max()))


@settings(max_examples=150, deadline=None)
@given(st.data())
def test_the_written_out_damping_is_the_differences_of_the_law(data):
    """Any pose, tip velocity, depth, both normal models, a tip off the origin: the shipped models'
    ``damping`` moved to the origin equals the central differences of their ``wrench``."""
    fl = st.floats(-1.0, 1.0)
    model = data.draw(st.sampled_from(["hunt_crossley", "kelvin_voigt"]))
    t = TissueBlock(origin_m=O, model=model, normal=np.array([0.1, -0.2, 1.0]))
    R = Rotation.from_rotvec(np.array(data.draw(st.lists(fl, min_size=3, max_size=3))) * 3).as_matrix()
    d = np.array(data.draw(st.lists(st.floats(-0.03, 0.03), min_size=3, max_size=3)))
    tip = O - t.normal * data.draw(st.floats(0.0005, 0.02))
    V = np.array(data.draw(st.lists(st.floats(-0.05, 0.05), min_size=6, max_size=6)))

    def at_origin(V):
        v, w = V[:3], V[3:]
        W = t.wrench(tip, R, v + np.cross(w, d), w).copy()
        W[3:] += np.cross(d, W[:3])
        return W

    v, w = V[:3], V[3:]
    D = moved_to_origin(t.damping(tip, R, v + np.cross(w, d), w), d)
    ref = contact_damping(at_origin, V)
    np.testing.assert_allclose(D, ref, rtol=1e-4, atol=1e-4 * max(1.0, np.abs(ref).max()))
