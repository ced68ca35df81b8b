"""The curved-surface scalpel (teleop.dynamics.surface, surface_fixture): the spline's pieces
against scipy's own evaluation, the foot against scipy's minimizer on the analytic dome, the rows
against finite differences of the residual off the manifold, psi's Jacobian and curvature against
finite differences of psi, the master's copy through FrameMap, and the constrained dynamics
against the rk4 integrator (which never sees psi) and the work-energy balance."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pinocchio import skew
from scipy.linalg import expm
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from teleop.contact import SurfaceTissue, TissueBlock
from teleop.dynamics.body import RigidBody
from teleop.dynamics.registry import FIXTURE_TYPES, FrameMap
from teleop.dynamics.rotations import rate_map, rotation
from teleop.dynamics.surface import HeightSurface
from teleop.dynamics.surface_fixture import SurfaceScalpelSpec
from teleop.dynamics.tool import ReferenceTool
from teleop.util.errors import ConfigError

H, RB = 0.015, 0.08  # the dome: f = H (1 - r^2 / RB^2), m
X = np.round(np.arange(-0.06, 0.0601, 0.01), 3)
Y = np.round(np.arange(-0.04, 0.0401, 0.01), 3)


def dome(x, y):
    return H * (1.0 - (x**2 + y**2) / RB**2)


HEIGHTS = dome(*np.meshgrid(X, Y, indexing="ij"))


def spec(**kw):
    base = dict(x_m=tuple(X), y_m=tuple(Y), heights_m=tuple(map(tuple, HEIGHTS)), origin_m=(0.5, 0.0, 0.2),
                normal=(0.0, 0.0, 1.0), depth_m=0.005, tip_m=(0.0, 0.0, 0.1))
    base.update(kw)
    return SurfaceScalpelSpec(**base)


def tilted_spec():
    """A bumpy, tilted field (not a quadric) with the tip off the tool origin."""
    Xg, Yg = np.meshgrid(X, Y, indexing="ij")
    Hb = 0.01 * np.exp(-(Xg**2 + Yg**2) / (2 * 0.03**2)) + 0.002 * np.sin(60 * Xg) * np.cos(40 * Yg)
    return spec(heights_m=tuple(map(tuple, Hb)), normal=(0.2, -0.1, 1.0), tip_m=(0.01, -0.02, 0.08))


seeds = st.integers(0, 2**32 - 1)


def test_registered_as_a_fixture_type():
    assert FIXTURE_TYPES.get("surface_scalpel") is SurfaceScalpelSpec


ORDERS = [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (3, 0), (2, 1), (1, 2), (0, 3)]


def test_compiled_spline_matches_scipy_derivatives():
    """The compiled evaluation from scipy's knots and coefficients (Cox-de Boor) against scipy's
    own fitpack evaluation, every partial to third order."""
    s = spec().surface()
    rng = np.random.default_rng(0)
    for _ in range(50):
        u, v = rng.uniform(X[0], X[-1]), rng.uniform(Y[0], Y[-1])
        F = s.height_partials(u, v, 3)
        for a, b in ORDERS:
            ref = float(s.spline(u, v, dx=a, dy=b, grid=False))
            assert F[a, b] == pytest.approx(ref, rel=1e-10, abs=1e-13 * 100.0 ** (a + b))
    # the quintic interpolant reproduces the paraboloid dome
    assert abs(s.height_partials(0.013, -0.021, 0)[0, 0] - dome(0.013, -0.021)) < 1e-12


@settings(max_examples=40, deadline=None)
@given(seed=seeds, degree=st.sampled_from([4, 5]), nx=st.integers(6, 14), ny=st.integers(6, 11))
def test_compiled_spline_matches_scipy_on_random_grids(seed, degree, nx, ny):
    """Uneven grids and random heights, both degrees, at random points and on the knots and the
    grid's edges: the compiled partials equal scipy's to rounding."""
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.uniform(0.2, 1.0, nx)) * 0.01
    y = np.cumsum(rng.uniform(0.2, 1.0, ny)) * 0.01
    s = HeightSurface(x, y, rng.normal(size=(nx, ny)) * 0.01, degree=degree)
    tx, ty, _ = s.spline.tck
    pts = [(rng.uniform(x[0], x[-1]), rng.uniform(y[0], y[-1])) for _ in range(10)]
    pts += [(float(a), float(b)) for a, b in zip(np.unique(tx), np.resize(np.unique(ty), np.unique(tx).size))]
    for u, v in pts:
        F = s.height_partials(u, v, 3)
        for a, b in ORDERS:
            ref = float(s.spline(u, v, dx=a, dy=b, grid=False))
            scale = float(np.abs(s.spline(x, y, dx=a, dy=b)).max())  # the order's magnitude on the grid
            assert abs(F[a, b] - ref) <= 1e-9 * scale + 1e-300, (u, v, a, b, F[a, b], ref)


def test_foot_and_depth_against_scipy_minimizer_on_the_dome():
    s = spec().surface()
    rng = np.random.default_rng(1)
    for _ in range(20):
        x, y = rng.uniform(-0.04, 0.04), rng.uniform(-0.03, 0.03)
        p = np.array([0.5 + x, y, 0.2 + dome(x, y) + rng.uniform(-0.008, 0.008)])
        res = minimize(lambda c, p=p: np.sum((p - [0.5 + c[0], c[1], 0.2 + dome(*c)]) ** 2), [x, y],
                       method="Nelder-Mead", options={"xatol": 1e-12, "fatol": 1e-20, "maxiter": 4000})
        u, v, ok = s.closest(p)
        assert ok and abs(u - res.x[0]) < 1e-7 and abs(v - res.x[1]) < 1e-7
        sd, n, _ = s.signed_distance(p)
        below = p[2] < 0.2 + dome(x, y)
        assert abs(abs(sd) - np.sqrt(res.fun)) < 1e-9 and (sd < 0) == below
        g = np.array([2 * H * res.x[0] / RB**2, 2 * H * res.x[1] / RB**2, 1.0])  # analytic normal
        np.testing.assert_allclose(n, g / np.linalg.norm(g), atol=1e-9)


def _off_manifold(fx, rng):
    par, c = fx.parametrization, fx.constraints[0]
    chart = par.initial_chart()
    z = np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.02, 0.02), rng.uniform(-3, 3)])
    q = par.psi(chart, z)
    np.testing.assert_allclose(c.residual(q[:3], rotation(chart, q[3:])), 0.0, atol=1e-12)
    p = q[:3] + rng.normal(scale=1e-3, size=3)
    R = rotation(chart, q[3:]) @ expm(skew(rng.normal(scale=0.03, size=3)))
    return c, p, R, rng.normal(scale=0.1, size=3), rng.normal(scale=1.0, size=3)


@pytest.mark.parametrize("make", [spec, tilted_spec])
@given(seed=seeds)
@settings(max_examples=15, deadline=None)
def test_rows_against_finite_differences(make, seed):
    """G nu = dh/dt and bias = d/dt(G) nu, along the flow (p + v t, exp(w t) R), off the manifold."""
    rng = np.random.default_rng(seed)
    c, p, R, v, w = _off_manifold(make().build(FrameMap.identity()), rng)
    nu = np.concatenate([v, w])

    def pose(t):
        return p + v * t, expm(skew(w * t)) @ R

    e = 1e-6
    hdot = (c.residual(*pose(e)) - c.residual(*pose(-e))) / (2 * e)
    np.testing.assert_allclose(c.jacobian(p, R) @ nu, hdot, atol=1e-7 * (1 + np.abs(hdot).max()))
    e = 1e-5
    Gdot_nu = (c.jacobian(*pose(e)) @ nu - c.jacobian(*pose(-e)) @ nu) / (2 * e)
    np.testing.assert_allclose(c.bias(p, R, v, w), Gdot_nu, atol=1e-6 * (1 + np.abs(Gdot_nu).max()))


@pytest.mark.parametrize("make", [spec, tilted_spec])
@given(seed=seeds)
@settings(max_examples=15, deadline=None)
def test_psi_jacobian_curvature_and_inverse(make, seed):
    rng = np.random.default_rng(seed)
    fx = make().build(FrameMap.identity())
    par, c = fx.parametrization, fx.constraints[0]
    chart = par.initial_chart()
    z = np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.02, 0.02), rng.uniform(-3, 3)])
    zd = rng.normal(size=3) * [0.05, 0.05, 1.0]
    e = 1e-6
    fd = np.column_stack([(par.psi(chart, z + e * k) - par.psi(chart, z - e * k)) / (2 * e) for k in np.eye(3)])
    P = par.jacobian(chart, z)
    np.testing.assert_allclose(P, fd, atol=1e-7)
    e = 1e-4
    second = (par.psi(chart, z + e * zd) - 2 * par.psi(chart, z) + par.psi(chart, z - e * zd)) / e**2
    np.testing.assert_allclose(par.curvature(chart, z, zd), second, atol=1e-4 * (1 + np.abs(second).max()))
    q, qd = par.psi(chart, z), P @ zd
    z2, zd2 = par.from_q(chart, q, qd)
    np.testing.assert_allclose(z2, z, atol=1e-10)
    np.testing.assert_allclose(zd2, zd, atol=1e-9)
    # a velocity along psi keeps every row: G nu = 0 (the twist of qd in the chart)
    R, E, _ = rate_map(chart, q[3:], qd[3:])
    nu = np.concatenate([qd[:3], R @ E @ qd[3:]])
    np.testing.assert_allclose(c.jacobian(q[:3], R) @ nu, 0.0, atol=1e-10)


def test_master_copy_through_the_frame_map():
    """Points mapped, lengths scaled, directions rotated: the master's surface is the patient's."""
    R = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    frame = FrameMap(R, np.array([-0.5, 0.1, -0.2]), 3.0)
    s_p, s_m = spec().surface(), spec().surface(frame)
    fx = spec().build(frame)
    assert fx.constraints[0].depth == pytest.approx(0.015)
    np.testing.assert_allclose(fx.constraints[0].d, [0.0, 0.0, 0.3])
    rng = np.random.default_rng(3)
    for _ in range(10):
        u, v = rng.uniform(-0.05, 0.05), rng.uniform(-0.03, 0.03)
        S_p, S_m = s_p.derivatives(u, v, 1)[0], s_m.derivatives(u, v, 1)[0]
        np.testing.assert_allclose(S_m, frame.point(S_p), atol=1e-12)
        p = S_p + rng.normal(scale=0.004, size=3)
        assert s_m.signed_distance(frame.point(p))[0] == pytest.approx(3.0 * s_p.signed_distance(p)[0], abs=1e-12)


def test_bad_grids_and_too_deep_cuts_are_clear_errors():
    with pytest.raises(ConfigError, match="heights must be"):
        spec(heights_m=((0.0,) * 9,) * 5).build(FrameMap.identity())
    with pytest.raises(ConfigError, match="strictly increasing"):
        spec(x_m=tuple(X[::-1])).build(FrameMap.identity())
    with pytest.raises(ConfigError, match="too deep"):
        spec(depth_m=0.12).build(FrameMap.identity())
    with pytest.raises(ConfigError, match="degree"):
        HeightSurface(X, Y, HEIGHTS, degree=3)


def _run(integrator, h, seconds, push=0.1):
    """A 0.25 kg scalpel pushed along its cut over the dome, undamped: (tool, tip path at every
    millisecond, the operator's work J, the energy gained J)."""
    fx = spec(tip_m=(0.0, 0.0, 0.0)).build(FrameMap.identity())
    body = RigidBody(0.25, np.array([0.0004, 0.0004, 0.00002]))
    tool = ReferenceTool(body, fx, (), integrator=integrator)
    par = fx.parametrization
    tool.reset(par.psi(par.initial_chart(), np.array([-0.03, 0.005, 0.3])), np.zeros(6))
    work, E0, path = 0.0, tool.energy(), []
    every = round(1e-3 / h)
    for k in range(round(seconds / h)):
        _p, R = tool.pose()
        W = np.concatenate([push * R[:, 0], [0.0, 0.0, 0.0]])  # along the cut
        v, _ = tool.twist()
        assert tool.step(h, W) == "ok"
        work += 0.5 * h * (W[:3] @ (v + tool.twist()[0]))  # trapezoid: the operator's work
        if (k + 1) % every == 0:
            path.append(tool.pose()[0].copy())
    return tool, np.array(path), work, tool.energy() - E0


def test_parametric_dynamics_converge_to_rk4_and_keep_the_work_energy_balance():
    """The parametric step (psi, first order) converges to rk4 (rows only, no psi) as h halves,
    holds the rows to round-off, and the energy gained is the operator's work (the constraint
    forces, the knife edge's included, do none)."""
    ref, path_r, work_r, dE_r = _run("rk4", 1e-3, 0.3)
    p1, path_1, work_1, dE_1 = _run("parametric", 1e-3, 0.3)
    _p2, path_2, _, _ = _run("parametric", 5e-4, 0.3)
    assert np.linalg.norm(path_r[-1] - path_r[0]) > 0.003  # it moved over the dome
    assert np.abs(p1.residual()).max() < 1e-9 and np.abs(ref.residual()).max() < 1e-7
    e1, e2 = np.abs(path_1 - path_r).max(), np.abs(path_2 - path_r).max()
    assert e1 < 1e-4 and 1.8 < e1 / e2 < 2.2  # first order (measured 2.000), towards rk4's answer
    assert dE_r == pytest.approx(work_r, rel=1e-4)
    assert dE_1 == pytest.approx(work_1, rel=1e-2)


def test_surface_tissue_depth_and_normal():
    """The tissue's depth is the distance below the dome along the normal at the foot; on a flat
    field it is the planar block's."""
    block = TissueBlock()
    tissue = SurfaceTissue(block, spec().surface())
    p = np.array([0.5 + 0.02, -0.01, 0.2 + dome(0.02, -0.01) - 0.004])
    d, n = tissue.depth_and_normal(p)
    assert d == pytest.approx(-spec().surface().signed_distance(p)[0]) and 0.0039 < d < 0.0041
    assert n[0] > 0 and n[1] < 0  # the dome's flank faces out
    F = tissue.wrench(p, np.eye(3), np.zeros(3), np.zeros(3))
    np.testing.assert_allclose(F[:3] / np.linalg.norm(F[:3]), n, atol=1e-12)  # at rest: the normal push
    flat = SurfaceTissue(block, spec(heights_m=tuple(map(tuple, 0 * HEIGHTS))).surface())
    planar = TissueBlock(origin_m=np.array([0.5, 0.0, 0.2]))
    for z in (0.198, 0.1995, 0.201):
        q = np.array([0.51, 0.003, z])
        assert flat.compute_depth(q) == pytest.approx(planar.compute_depth(q), abs=1e-15)
