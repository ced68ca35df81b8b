"""Parametrizations q = psi(z) (eqs. 10-11): on the manifold, Psi and the curvature term against
finite differences of psi, and from_q inverting psi. Random charts and parameters."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from teleop.dynamics import fixtures
from teleop.dynamics.constraints import stack_residual
from teleop.dynamics.rotations import rotation

FIXTURES = {
    "rolling_disk": lambda: fixtures.rolling_disk(0.03, (0.1, -0.2, 0.05), (0.3, 0.2, 1.0)),
    "sphere": lambda: fixtures.sphere((0.1, 0.0, -0.3), 0.12),
    "scalpel": lambda: fixtures.scalpel((0.2, 0.1, 0.0), (0.1, -0.2, 1.0), 0.004, (0.01, -0.02, 0.03)),
    "free": lambda: fixtures.free("XYZ"),
}

seeds = st.integers(0, 2**32 - 1)


def _setup(name, seed):
    fx = FIXTURES[name]()
    par = fx.parametrization
    rng = np.random.default_rng(seed)
    chart = par.initial_chart()
    if par.rechartable:  # any placement of the chart must work
        chart = chart.with_R0(Rotation.from_rotvec(rng.normal(size=3)).as_matrix())
    z = rng.normal(scale=0.3, size=par.dim)
    if name == "sphere":
        z[1] = rng.uniform(0.5, 2.6)  # away from the chart's poles
    zd = rng.normal(size=par.dim)
    return fx, par, chart, z, zd


@pytest.mark.parametrize("name", sorted(FIXTURES))
@given(seed=seeds)
@settings(max_examples=25, deadline=None)
def test_psi_lies_on_the_manifold(name, seed):
    fx, par, chart, z, _ = _setup(name, seed)
    q = par.psi(chart, z)
    h = stack_residual(fx.constraints, q[:3], rotation(chart, q[3:]))
    assert np.all(np.abs(h) < 1e-12)


@pytest.mark.parametrize("name", sorted(FIXTURES))
@given(seed=seeds)
@settings(max_examples=25, deadline=None)
def test_jacobian_and_curvature_match_finite_differences(name, seed):
    _, par, chart, z, zd = _setup(name, seed)
    eps = 1e-5
    P = par.jacobian(chart, z)
    fd = np.column_stack([(par.psi(chart, z + eps * e) - par.psi(chart, z - eps * e)) / (2 * eps)
                          for e in np.eye(par.dim)])
    np.testing.assert_allclose(P, fd, atol=1e-8)
    # zd^T psi_zz zd is the second derivative of psi along the line z + s zd
    e2 = 1e-4
    fd2 = (par.psi(chart, z + e2 * zd) - 2 * par.psi(chart, z) + par.psi(chart, z - e2 * zd)) / e2**2
    np.testing.assert_allclose(par.curvature(chart, z, zd), fd2, atol=1e-5)


@pytest.mark.parametrize("name", sorted(FIXTURES))
@given(seed=seeds)
@settings(max_examples=25, deadline=None)
def test_from_q_inverts_psi(name, seed):
    _, par, chart, z, zd = _setup(name, seed)
    q, qd = par.psi(chart, z), par.jacobian(chart, z) @ zd
    z2, zd2 = par.from_q(chart, q, qd)
    np.testing.assert_allclose(par.psi(chart, z2), q, atol=1e-12)
    np.testing.assert_allclose(zd2, zd, atol=1e-9)
