"""Eq. 7 for Euler-angle rates and the Coriolis vector consistent with M(q)."""

import numpy as np
import pinocchio as pin
import pytest

from teleop.dynamics.body import (
    Kinematics,
    RigidBody,
    compute_coriolis,
    compute_mass_matrix,
    kinetic_energy,
)
from teleop.dynamics.rotations import EulerChart, rate_map, rechart, rotation
from teleop.util.errors import ConfigError

SEQS = ["ZXZ", "ZYX", "XYZ", "YXY"]


@pytest.mark.parametrize("seq", SEQS)
def test_mass_matrix_gives_the_twist_kinetic_energy(seq, lopsided_body):
    rng = np.random.default_rng(0)
    chart = EulerChart(seq, pin.exp3(rng.normal(size=3)))
    for _ in range(10):
        q = np.concatenate([rng.normal(size=3), rng.uniform(-1, 1, 3) + [0, 0.7, 0]])
        qd = rng.normal(size=6)
        k = Kinematics(chart, q, qd)
        M = compute_mass_matrix(lopsided_body, k)
        I_W = k.R @ lopsided_body.J @ k.R.T
        # the paper's rotational block R J R^T, done right for rates: E_W^T (R J R^T) E_W
        np.testing.assert_allclose(M[3:, 3:], k.E_W.T @ I_W @ k.E_W, atol=1e-14)
        e_twist = 0.5 * lopsided_body.mass_kg * k.v @ k.v + 0.5 * k.w @ I_W @ k.w
        assert 0.5 * qd @ M @ qd == pytest.approx(e_twist, rel=1e-12)
        assert kinetic_energy(lopsided_body, k) == pytest.approx(e_twist, rel=1e-12)


@pytest.mark.parametrize("seq", SEQS)
def test_rate_map_matches_finite_differences_of_rotation(seq):
    rng = np.random.default_rng(1)
    chart = EulerChart(seq, pin.exp3(rng.normal(size=3)))
    th, thd = rng.uniform(-1, 1, 3) + [0, 0.7, 0], rng.normal(size=3)
    eps = 1e-6
    R, E, Edq = rate_map(chart, th, thd)
    dR = (rotation(chart, th + eps * thd) - rotation(chart, th - eps * thd)) / (2 * eps)
    w_B = pin.unSkew(R.T @ dR)
    np.testing.assert_allclose(E @ thd, w_B, atol=1e-8)
    Ep = rate_map(chart, th + eps * thd, thd)[1]
    Em = rate_map(chart, th - eps * thd, thd)[1]
    np.testing.assert_allclose(Edq, (Ep - Em) @ thd / (2 * eps), atol=1e-7)


@pytest.mark.parametrize("seq", SEQS)
def test_coriolis_is_consistent_with_mass_matrix(seq, lopsided_body):
    """C(q,qd) qd = Mdot qd - 1/2 d/dq (qd^T M qd), both sides by finite differences of M(q)."""
    rng = np.random.default_rng(2)
    chart = EulerChart(seq)
    eps = 1e-6
    for _ in range(10):
        q = np.concatenate([rng.normal(size=3), rng.uniform(-1, 1, 3) + [0, 0.7, 0]])
        qd = rng.normal(size=6)

        def M_at(qq, qd=qd):
            return compute_mass_matrix(lopsided_body, Kinematics(chart, qq, qd))

        Mdot = (M_at(q + eps * qd) - M_at(q - eps * qd)) / (2 * eps)
        grad = np.empty(6)
        for i in range(6):
            dq = np.zeros(6)
            dq[i] = eps
            grad[i] = (qd @ M_at(q + dq) @ qd - qd @ M_at(q - dq) @ qd) / (2 * eps)
        expected = Mdot @ qd - 0.5 * grad
        got = compute_coriolis(lopsided_body, Kinematics(chart, q, qd))
        np.testing.assert_allclose(got, expected, atol=1e-6 * (1 + np.abs(expected).max()))


def test_rechart_preserves_rotation_and_body_rate():
    rng = np.random.default_rng(3)
    chart = EulerChart("ZXZ")
    th, thd = np.array([0.4, 0.05, -1.0]), rng.normal(size=3)
    new, th2, thd2 = rechart(chart, th, thd)
    R1, E1, _ = rate_map(chart, th, thd)
    R2, E2, _ = rate_map(new, th2, thd2)
    np.testing.assert_allclose(R1, R2, atol=1e-12)
    np.testing.assert_allclose(E1 @ thd, E2 @ thd2, atol=1e-12)
    assert abs(np.sin(th2[1])) == pytest.approx(1.0)


@pytest.mark.parametrize(
    "mass, inertia, msg",
    [
        (0.0, [1, 1, 1], "mass_kg"),
        (float("nan"), [1, 1, 1], "mass_kg"),
        (1.0, [1, -1, 1], "positive definite"),
        (1.0, [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]], "symmetric"),
        (1.0, [1, 1], "inertia_kgm2"),
    ],
)
def test_bad_body_is_a_clear_error(mass, inertia, msg):
    with pytest.raises(ConfigError, match=msg):
        RigidBody(mass, inertia)


def test_bad_euler_sequence_is_a_clear_error():
    with pytest.raises(ConfigError, match="euler sequence"):
        EulerChart("ZZX")
