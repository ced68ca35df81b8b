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


def _reference_bounds(lim, q, qd_prev, dt):
    """compute_velocity_bounds written out joint by joint (the formulas of teleop.slave.limits)."""
    lb, ub = np.empty(lim.nv), np.empty(lim.nv)
    for i in range(lim.nv):
        up, dn = lim.q_max[i] - lim.margin_rad - q[i], q[i] - lim.q_min[i] - lim.margin_rad
        a, v = lim.a_max[i], lim.v_max[i]
        hi = min(v, up / dt, np.sqrt(2 * a * max(up, 0.0)))
        lo = -min(v, dn / dt, np.sqrt(2 * a * max(dn, 0.0)))
        hi = max(hi, 0.0) if np.isfinite(hi) else v
        lo = min(lo, 0.0) if np.isfinite(lo) else -v
        lb[i], ub[i] = max(lo, qd_prev[i] - a * dt), min(hi, qd_prev[i] + a * dt)
        if lb[i] > ub[i]:
            lb[i] = ub[i] = min(max(qd_prev[i], lo), hi)
    return lb, ub


@settings(max_examples=300, deadline=None)
@given(q=vec3, qd=vec3, near=st.floats(0.0, 1.0), dt=st.sampled_from([1e-4, 1e-3, 1e-2]),
       bad=st.sampled_from([None, np.nan, np.inf, -np.inf]))
def test_velocity_bounds_match_the_joint_by_joint_formulas(q, qd, near, dt, bad):
    """Near and far from the limits (the fast path), at rest or moving, and with q not finite."""
    q = np.array(q) * near
    if bad is not None:
        q[1] = bad
    lb, ub = LIM.compute_velocity_bounds(q, np.array(qd), dt)
    rlb, rub = _reference_bounds(LIM, q, np.array(qd), dt)
    assert np.allclose(lb, rlb, rtol=1e-12, atol=1e-12) and np.allclose(ub, rub, rtol=1e-12, atol=1e-12)
