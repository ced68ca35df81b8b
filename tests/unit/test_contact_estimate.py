"""The contact plane the slave estimates from its own force and tip motion
(teleop.contact.estimate): recovered from a plane it never reads, confident only once the tip has
moved along the normal, remembered across a bouncing contact, forgotten on another surface; and,
in a running scene, the tissue's declared stiffness (which the estimator never sees) recovered."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop.contact.estimate import NO_PLANE, PlaneEstimator

DT = 1e-3


def _press(est, k, n, c, b=5.0, ticks=3000, noise=0.005, seed=0):
    """The tip pushed into the plane n . x = c (stiffness k N/m, damping b N*s/m) and rocked."""
    rng = np.random.default_rng(seed)
    n = np.asarray(n, float) / np.linalg.norm(n)
    t1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    for i in range(ticks):
        t = i * DT
        depth = 1e-3 * min(t, 1.0) + 2e-4 * np.sin(2 * np.pi * 2 * t) + 3e-4  # m, always in contact
        ddepth = 1e-3 * (t < 1.0) + 2e-4 * 2 * np.pi * 2 * np.cos(2 * np.pi * 2 * t)
        x = (c - depth) * n + 0.01 * t1
        v = -ddepth * n
        f = max(0.0, k * depth + b * ddepth)
        est.update(x, v, f * n + rng.normal(0.0, noise, 3))
    return est


@settings(max_examples=25, deadline=None)
@given(k=st.floats(1e3, 1e5), c=st.floats(-0.05, 0.05),
       n=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(0.2, 1)))
def test_a_plane_it_never_reads_is_recovered(k, c, n):
    est = _press(PlaneEstimator(DT), k, n, c)
    n = np.asarray(n) / np.linalg.norm(n)
    assert est.k == pytest.approx(k, rel=0.02)
    assert float(est.n @ n) > 0.9999
    assert est.confidence > 0.8
    plane = est.plane(np.array([1.0, 2.0, 3.0]))
    assert np.allclose(plane[3:6], [1, 2, 3]) and plane[6] == est.k and plane[7] == est.confidence


def test_no_confidence_before_the_tip_has_moved_along_the_normal():
    est = PlaneEstimator(DT)
    for _ in range(500):  # pressed at one depth: force alone cannot tell stiffness from where the surface is
        est.update(np.array([0.0, 0.0, -1e-4]), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    assert est.in_contact and est.confidence == 0.0
    assert np.array_equal(est.plane(np.zeros(3)), NO_PLANE)


def test_a_bouncing_contact_keeps_its_model_and_another_surface_starts_a_new_one():
    est = _press(PlaneEstimator(DT), 2e4, (0, 0, 1), 0.0)
    k, conf = est.k, est.confidence
    est.update(np.array([0.0, 0.0, 0.01]), np.zeros(3), np.zeros(3))  # lifted off
    assert not est.in_contact and np.array_equal(est.plane(np.zeros(3)), NO_PLANE)  # nothing sent off contact
    est.update(np.array([0.0, 0.0, -1e-4]), np.zeros(3), np.array([0.0, 0.0, 2.0]))  # back on the same surface
    assert est.k == pytest.approx(k, rel=0.05) and est.confidence > 0.5 * conf
    est.update(np.array([0.0, 0.0, 0.0]), np.zeros(3), np.array([2.0, 0.0, 0.0]))  # a wall at 90 degrees
    assert est.confidence == 0.0 and np.allclose(est.n, [1, 0, 0])


def test_nothing_but_numbers_is_taken():
    est = PlaneEstimator(DT)
    est.update(np.zeros(3), np.zeros(3), np.array([np.nan, 0.0, 1.0]))
    assert not est.in_contact and est.confidence == 0.0
    with pytest.raises(ValueError):
        PlaneEstimator(0.0)


@pytest.mark.parametrize("stiffness", [1e4, 1e5])
def test_the_slave_recovers_the_scenes_tissue_stiffness(stiffness):
    """The oracle is the scene's own [tissue] stiffness, which the estimator never reads: it
    sees only the force the slave measures and where its tip is."""
    from teleop.app.runtime import run_scene
    from teleop.scenario.schema import load_scene
    from teleop.tick.ports import Hook

    class Last(Hook):
        k = conf = 0.0

        def after_tick(self, i, t_s, loop):
            e = loop.slave_side.estimator
            Last.k, Last.conf = e.k, e.confidence

    scene = load_scene("stiff_contact", sets=[f"tissue.stiffness={stiffness}", "duration_s=2.0"])
    r = run_scene(scene, hooks=[Last()])
    assert r.summary["status"] == "ok"
    assert Last.k == pytest.approx(stiffness, rel=0.05) and Last.conf > 0.5


def test_without_the_plane_a_100_kN_per_m_wall_is_not_rendered_and_with_it_it_is():
    """The scene key turns the mechanism off on both sides: the same wall, one process, no delay."""
    from teleop.app.runtime import run_scene
    from teleop.scenario.schema import load_scene

    sets = ["tissue.stiffness=100000.0", "duration_s=2.0"]
    off = run_scene(load_scene("stiff_contact", sets=[*sets, "mapping.feedback_contact_plane=false"])).summary
    on = run_scene(load_scene("stiff_contact", sets=sets)).summary
    assert off["status"] == "implausible_feedback"  # the wall's force, one tick late, throws the tool
    assert on["status"] == "ok" and on["metrics"]["contact_force_max_N"] < 5.0
