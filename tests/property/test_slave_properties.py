"""Properties of the slave's limits, mapping and contact over random inputs (hypothesis)."""

import numpy as np
import pinocchio as pin
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop.contact import TissueBlock
from teleop.control.mapping import Registration
from teleop.slave import JointLimits

LIM = JointLimits([-2.9, -1.7, -0.5], [2.9, 1.7, 0.5], [2.0, 2.5, 1.0], [15.0, 7.5, 20.0])
f = st.floats(-4.0, 4.0, allow_nan=False)
vec3 = st.tuples(f, f, f)


@settings(max_examples=200, deadline=None)
@given(q=vec3, qd=vec3, dt=st.floats(1e-4, 1e-2))
def test_velocity_bounds_are_consistent_and_within_limits(q, qd, dt):
    q, qd = np.array(q), np.array(qd)
    lb, ub = LIM.compute_velocity_bounds(q, qd, dt)
    assert np.all(np.isfinite(lb)) and np.all(np.isfinite(ub)) and np.all(lb <= ub)
    assert np.all(ub <= LIM.v_max + 1e-12) and np.all(lb >= -LIM.v_max - 1e-12)
    # any velocity in the box keeps an in-range joint in range after one tick
    inside = (q >= LIM.q_min) & (q <= LIM.q_max)
    for v in (lb, ub):
        q1 = q + v * dt
        assert np.all(q1[inside] <= LIM.q_max[inside] + 1e-12) and np.all(q1[inside] >= LIM.q_min[inside] - 1e-12)


@settings(max_examples=100, deadline=None)
@given(p=vec3, rpy=vec3, scale=st.floats(0.2, 10.0), x=vec3)
def test_mapping_round_trip(p, rpy, scale, x):
    reg = Registration(np.array(p), pin.rpy.rpyToMatrix(*rpy), scale)
    x = np.array(x)
    assert np.allclose(reg.point_to_master(reg.point_to_patient(x)), x, atol=1e-9)
    R = pin.rpy.rpyToMatrix(*x)
    pp, RR = reg.pose_to_master(*reg.target(x, R, np.zeros(3), np.zeros(3))[:2])
    assert np.allclose(pp, x, atol=1e-9) and np.allclose(RR, R, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(depth=st.floats(-0.01, 0.05), v=vec3, w=vec3)
def test_tissue_wrench_is_finite_and_never_pulls_in(depth, v, w):
    t = TissueBlock(origin_m=np.zeros(3))
    R = np.diag([1.0, -1.0, -1.0])
    rep = t.compute_contact(np.array([0.0, 0.0, -depth]), R, np.array(v), np.array(w))
    assert np.all(np.isfinite(rep.wrench)) and rep.normal_N >= 0.0
    assert rep.in_contact == (depth > 0)
    # cutting and lateral forces dissipate: they never push along the tip's motion
    assert rep.wrench[:2] @ np.array(v)[:2] <= 1e-12


# Hand-computed bounds of one joint: q_min = -1, q_max = 1 rad, v_max = 2 rad/s, a_max = 10 rad/s^2,
# dt = 0.01 s, margin 0 unless given. Columns: q, qd_prev, margin, (lb, ub).
HAND = [
    # mid-range at rest: the acceleration box +-a dt = +-0.1 is the tightest
    (0.0, 0.0, 0.0, (-0.1, 0.1)),
    # mid-range at full speed: the velocity limit above, the acceleration box below
    (0.0, 2.0, 0.0, (1.9, 2.0)),
    # 0.05 rad below q_max, moving up at 1 rad/s: room to stop sqrt(2 a 0.05) = 1, crossing 0.05 / dt = 5
    (0.95, 1.0, 0.0, (0.9, 1.0)),
    # 0.002 rad below q_max at rest: sqrt(2 a 0.002) = 0.2, crossing 0.002 / dt = 0.2, box 0.1
    (0.998, 0.0, 0.0, (-0.1, 0.1)),
    # 0.0005 rad below q_max: crossing 0.0005 / dt = 0.05 caps it (sqrt(2 a d) = 0.1)
    (0.9995, 0.0, 0.0, (-0.1, 0.05)),
    # on q_max: may not go up (0), may come back at the acceleration box
    (1.0, 0.0, 0.0, (-0.1, 0.0)),
    # beyond q_max by 0.1: caps on the way up collapse to 0
    (1.1, 0.0, 0.0, (-0.1, 0.0)),
    # the margin moves the limit: 0.2 rad kept free, q 0.3 below q_max leaves 0.1: sqrt(2) = 1.414...,
    # 10, box qd_prev 1.5 +- 0.1: ub = min(1.4142, 1.6) = 1.41421356
    (0.7, 1.5, 0.2, (1.4, np.sqrt(2.0))),
    # moving up fast toward q_max: caps 0.3 / dt = 30, sqrt(2 a 0.3) = 2.449 -> v 2; box around -3
    # misses the box [-2, 2] (qd_prev beyond v_max): both collapse onto qd_prev's nearest point, -2
    (0.7, -3.0, 0.0, (-2.0, -2.0)),
    # near q_min moving down at 1.5: room below 0.05: sqrt(1) = 1 < 1.4 = qd_prev - a dt: the boxes miss,
    # collapse onto -1 (nearest to -1.5 in [-1, 2])
    (-0.95, -1.5, 0.0, (-1.0, -1.0)),
    # q not finite: only the velocity limit and the acceleration box
    (np.nan, 0.5, 0.0, (0.4, 0.6)),
    (np.inf, -1.95, 0.0, (-2.0, -1.85)),
]


def test_velocity_bounds_by_hand():
    """The bounds of one joint in the cases worked out by hand above (1e-12 rad/s)."""
    for q, qd, margin, (lo, hi) in HAND:
        lim = JointLimits([-1.0], [1.0], [2.0], [10.0], margin)
        lb, ub = lim.compute_velocity_bounds(np.array([q]), np.array([qd]), 0.01)
        assert np.allclose([lb[0], ub[0]], [lo, hi], rtol=0, atol=1e-12), (q, qd, margin, lb, ub, (lo, hi))


@settings(max_examples=300, deadline=None)
@given(q=vec3, qd=vec3, near=st.floats(0.0, 1.0), dt=st.sampled_from([1e-4, 1e-3, 1e-2]),
       bad=st.sampled_from([None, np.nan, np.inf, -np.inf]))
def test_velocity_bounds_keep_their_promises(q, qd, near, dt, bad):
    """Near and far from the limits, at rest or moving, and with q not finite, the box keeps the
    promises of teleop.slave.limits (its values are checked by hand above): every qd in it keeps
    the joint from crossing its limits within the tick and leaves room to stop at a_max; it lies
    in the acceleration box, or has collapsed onto one point."""
    q, qd = np.array(q) * near, np.array(qd)
    if bad is not None:
        q[1] = bad
    lb, ub = LIM.compute_velocity_bounds(q, qd, dt)
    a, v = LIM.a_max, LIM.v_max
    assert np.all(lb <= ub) and np.all(ub <= v + 1e-12) and np.all(lb >= -v - 1e-12)
    fin = np.isfinite(q)
    up, dn = LIM.q_max - q, q - LIM.q_min
    for i in np.flatnonzero(fin):
        if up[i] >= 0:
            assert ub[i] <= up[i] / dt + 1e-12 and max(ub[i], 0.0) ** 2 <= 2 * a[i] * up[i] + 1e-12
        else:
            assert ub[i] <= 1e-15  # beyond the limit: only back
        if dn[i] >= 0:
            assert -lb[i] <= dn[i] / dt + 1e-12 and max(-lb[i], 0.0) ** 2 <= 2 * a[i] * dn[i] + 1e-12
        else:
            assert lb[i] >= -1e-15
    meets = (lb >= qd - a * dt - 1e-12) & (ub <= qd + a * dt + 1e-12)
    collapsed = lb == ub
    assert np.all(meets | collapsed)
