"""The master's rendering of the contact (teleop.tick.feedback): the delayed wrench plus the
contact's damping at the tool's own twist, solved implicitly. Checked against the backward Euler
step written out, the stale stick that must not throw the tool back, and bad models refused."""

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from teleop.control.mapping import Registration
from teleop.dynamics.effects import AngularDamper, LinearDamper
from teleop.tick.feedback import FeedbackPath
from teleop.tick.messages import ContactFeedback

DT = 1e-3


class _Body:
    def __init__(self, m, J):
        self.mass_kg, self.J = m, np.asarray(J, dtype=float)


class _Tool:
    """A free rigid body: pose, twist and inertia, as the reference tool shows them."""

    def __init__(self, m=0.1, J=(4e-4, 4e-4, 2e-5), R=None, V=None, effects=()):
        self.body = _Body(m, np.diag(J))
        self.R = np.eye(3) if R is None else np.asarray(R)
        self.V = np.zeros(6) if V is None else np.asarray(V, dtype=float)
        self.model, self.t = SimpleNamespace(effects=tuple(effects)), 0.0

    def pose(self):
        return np.zeros(3), self.R

    def twist(self):
        return self.V[:3].copy(), self.V[3:].copy()

    def mass_matrix(self):
        M = np.zeros((6, 6))
        M[:3, :3] = self.body.mass_kg * np.eye(3)
        M[3:, 3:] = self.R @ self.body.J @ self.R.T
        return M


def _path(D_P, V_P, W_P, reg=None):
    """(the path, the channel's force F0 it hands the guard and then the render)."""
    fb = FeedbackPath(reg or Registration([0, 0, 0], np.eye(3)), cutoff_hz=0.0, dt_s=DT)
    return fb, fb.update(ContactFeedback(1, 0.0, W_P, "ok", 0, damping_P=D_P, twist_P=V_P))


def test_one_axis_is_backward_euler():
    """Mass 0.1 kg, D = 667 N*s/m on x (the cut's stick seen at the master): the explicit step
    under the rendered force lands on the backward Euler velocity (m v + dt (f + W + D vs)) /
    (m + dt D)."""
    m, D, v, vs, W, f = 0.1, 667.0, 0.03, 0.01, -2.0, 1.5
    Dm = np.zeros((6, 6))
    Dm[0, 0] = D
    tool = _Tool(m, V=[v, 0, 0, 0, 0, 0])
    fb, F0 = _path(Dm, np.array([vs, 0, 0, 0, 0, 0]), np.array([W, 0, 0, 0, 0, 0]))
    F = fb.render(F0, tool, np.array([f, 0, 0, 0, 0, 0]), DT)
    v_next = v + DT / m * (f + F[0])
    assert v_next == pytest.approx((m * v + DT * (f + W + D * vs)) / (m + DT * D), rel=1e-12)
    np.testing.assert_array_equal(F[1:], 0.0)


def test_the_stale_stick_does_not_throw_the_tool_back():
    """The slave was sliding into the stick (its wrench -D vs) when the tool has already stopped:
    rendered raw, that force throws the tool back at D vs dt / m = 20 mm/s in one tick; rendered
    with the damping at the tool's own velocity it is cancelled."""
    D, vs = 2000.0, 1e-3
    Dm = np.zeros((6, 6))
    Dm[0, 0] = D
    tool = _Tool(0.1)  # at rest
    fb, F0 = _path(Dm, np.array([vs, 0, 0, 0, 0, 0]), np.array([-D * vs, 0, 0, 0, 0, 0]))
    assert fb.wrench_M[0] == pytest.approx(-2.0)  # what the tool would feel without the model
    F = fb.render(F0, tool, np.zeros(6), DT)
    assert abs(F[0]) < 1e-12


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_any_tool_any_damping_steps_as_backward_euler(data):
    """Random inertia, orientation, positive semidefinite D, twists and forces: M (V+ - V) =
    dt (f + W + D (Vs - V+)) holds for the V+ the explicit step reaches under the render."""
    fl = st.floats(-1.0, 1.0)
    m = data.draw(st.floats(0.01, 10.0))
    J = data.draw(st.lists(st.floats(1e-6, 1e-1), min_size=3, max_size=3))
    R = Rotation.from_rotvec(data.draw(st.lists(fl, min_size=3, max_size=3))).as_matrix()
    A = np.array(data.draw(st.lists(st.floats(-50.0, 50.0), min_size=36, max_size=36))).reshape(6, 6)
    D = A @ A.T  # positive semidefinite, up to ~1e4
    V, Vs, W, f = (np.array(data.draw(st.lists(fl, min_size=6, max_size=6))) for _ in range(4))
    tool = _Tool(m, J, R, V)
    fb, F0 = _path(D, Vs, W)
    F = fb.render(F0, tool, f, DT)
    M = tool.mass_matrix()
    V_next = V + DT * np.linalg.solve(M, f + F)
    resid = M @ (V_next - V) - DT * (f + W + D @ (Vs - V_next))
    assert np.abs(resid).max() <= 1e-9 * max(1.0, np.abs(D).max(), np.abs(M).max())


def test_no_contact_renders_the_wrench_alone():
    tool = _Tool(V=[0.1, 0, 0, 0, 0, 0.3])
    fb, F0 = _path(None, None, np.array([1.0, 2, 3, 0, 0, 0]))
    np.testing.assert_array_equal(F0, fb.wrench_M)  # no model: the channel brings the wrench
    assert fb.render(F0, tool, np.ones(6), DT) is F0


def test_a_damping_that_feeds_energy_is_refused_and_counted():
    Dm = -np.eye(6)
    fb, F0 = _path(Dm, np.ones(6), np.array([1.0, 0, 0, 0, 0, 0]))
    assert fb.refused == 1 and not fb.damping_M.any()
    np.testing.assert_array_equal(F0, fb.wrench_M)
    assert fb.render(F0, _Tool(V=np.ones(6)), np.zeros(6), DT) is F0


def test_local_damping_off_is_the_wrench_alone():
    Dm = np.eye(6)
    fb = FeedbackPath(Registration([0, 0, 0], np.eye(3)), cutoff_hz=0.0, dt_s=DT, local_damping=False)
    w = fb.update(ContactFeedback(1, 0.0, np.ones(6), "ok", 0, damping_P=Dm, twist_P=np.ones(6)))
    np.testing.assert_array_equal(w, np.ones(6))
    assert fb.render(w, _Tool(V=np.ones(6)), np.zeros(6), DT) is w


def test_a_message_with_an_unsymmetric_damping_is_refused():
    from teleop.tick.messages import MessageError
    D = np.zeros((6, 6))
    D[0, 1] = 1.0
    with pytest.raises(MessageError, match="damping_P: not symmetric"):
        ContactFeedback(1, 0.0, np.zeros(6), "ok", 0, damping_P=D, twist_P=np.zeros(6))


def test_a_steady_turn_against_the_tools_own_damping_is_not_read_as_an_acceleration():
    """The curved cut's case: the hand's torque balances the tool's own angular damping (0.02) and
    the contact's (0.03) at a steady rate; the slave turns at the same rate. Nothing is added to
    the reported wrench (before the tool's own effects were counted, 0.0015 N*m was)."""
    c, D, w = 0.02, 0.03, 0.08
    Dm = np.zeros((6, 6))
    Dm[5, 5] = D
    V = np.array([0, 0, 0, 0, 0, w])
    tool = _Tool(0.25, V=V, effects=(LinearDamper(2.0), AngularDamper(c)))
    fb, F0 = _path(Dm, V, -D * V)
    F = fb.render(F0, tool, np.array([0, 0, 0, 0, 0, (c + D) * w]), DT)
    np.testing.assert_allclose(F, -D * V, atol=1e-15)


@pytest.mark.parametrize("big", [1e300, 1e200])
def test_a_damping_too_large_to_multiply_is_refused_and_nothing_goes_non_finite(big):
    """A hostile reply: finite numbers whose products overflow (D V_s = inf). Refused and counted,
    the wrench alone rendered, every number finite."""
    fb, F0 = _path(big * np.eye(6), np.full(6, 1e200), np.array([1.0, 0, 0, 0, 0, 0]))
    assert fb.refused == 1 and np.all(np.isfinite(F0)) and np.all(np.isfinite(fb.damping_M))
    F = fb.render(F0, _Tool(V=np.ones(6)), np.zeros(6), DT)
    assert np.all(np.isfinite(F))


def test_after_the_contact_the_filtered_damping_returns_to_zero():
    """Replies without contact after one with: the filtered D decays and then is exactly zero,
    so the render stops (the reported wrench alone), not a vanishing damper solved every tick."""
    Dm = 2000.0 * np.eye(6)
    fb = FeedbackPath(Registration([0, 0, 0], np.eye(3)), cutoff_hz=20.0, dt_s=DT)
    fb.update(ContactFeedback(1, 0.0, np.zeros(6), "ok", 0, damping_P=Dm, twist_P=np.zeros(6)))
    assert fb.damping_M.any()
    for k in range(2, 600):
        F0 = fb.update(ContactFeedback(k, k * DT, np.zeros(6), "ok", k - 1))
    assert not fb.damping_M.any()
    assert fb.render(F0, _Tool(V=np.ones(6)), np.zeros(6), DT) is F0


def test_the_model_offset_is_one_formula_for_both_ports():
    """F0 = W + D V, as the slave guard and the feedback path both read it from the message."""
    D = np.diag([1000.0, 2.0, 3.0, 0.1, 0.2, 0.3])
    V = np.array([0.003, 0.1, -0.2, 1.0, 0.0, -1.0])
    W = np.array([-4.0, 1.0, 2.0, 0.0, 0.5, 0.0])
    msg = ContactFeedback(1, 0.0, W, "ok", 0, damping_P=D, twist_P=V)
    np.testing.assert_allclose(msg.model_offset_P, [-1.0, 1.2, 1.4, 0.1, 0.5, -0.3], atol=1e-12)


def _plane_path(k=1e4, conf=1.0, W_z=2.0, anchor_z=0.0):
    """A path that took a reply pressing on the plane z = anchor_z - W_z / k (normal +z)."""
    fb = FeedbackPath(Registration([0, 0, 0], np.eye(3)), cutoff_hz=0.0, dt_s=DT)
    fb.update(ContactFeedback(1, 0.0, [0, 0, W_z, 0, 0, 0], "ok", 0,
                              plane_P=[0, 0, 1, 0, 0, anchor_z, k, conf]))
    return fb


def _state(z, vz=0.0):
    from teleop.tick.ports import ToolState

    return ToolState(np.array([0.0, 0.0, z]), np.eye(3), np.array([0.0, 0.0, vz, 0.0, 0.0, 0.0]))


def test_the_plane_renders_the_measured_force_at_the_anchor_and_the_wall_around_it():
    """At the anchor the master feels what the slave measured; 0.1 mm deeper, 1 N more (10 kN/m);
    above the plane, no normal force at all (the spring never pulls the tool in)."""
    fb = _plane_path(k=1e4, W_z=2.0)
    msg = None
    assert fb.update(msg, _state(0.0))[2] == pytest.approx(2.0)
    assert fb.update(msg, _state(-1e-4))[2] == pytest.approx(3.0)
    assert fb.update(msg, _state(1e-4))[2] == pytest.approx(1.0)
    assert fb.update(msg, _state(3e-4))[2] == pytest.approx(0.0) and fb.spring_K is None  # 0.1 mm off the surface
    assert fb.update(msg, _state(0.0), )[2] == pytest.approx(2.0) and fb.spring_K[2, 2] == pytest.approx(1e4)
    half = _plane_path(k=1e4, conf=0.5, W_z=2.0)
    assert half.update(None, _state(-1e-4))[2] == pytest.approx(2.5)  # the confidence scales the stiffness


def test_the_plane_is_rendered_implicitly_a_stiff_wall_does_not_throw_a_light_tool():
    """A 1e6 N/m wall on a 0.1 kg tool at 1 kHz (k dt^2 / m = 10: an explicit spring diverges):
    the tool dropped on it at 0.1 m/s bounces off no faster than it came (backward Euler on the
    spring dissipates), never deeper than the tick it arrives in (100 um) and the wall (32 um) allow."""
    from teleop.tick.ports import ToolState

    fb = _plane_path(k=1e6, W_z=0.0, anchor_z=0.0)
    tool = _Tool(V=[0, 0, -0.1, 0, 0, 0])
    z, speeds, z_min = 0.0, [], 0.0
    for _ in range(300):
        st_ = ToolState(np.array([0.0, 0.0, z]), np.eye(3), tool.V.copy())
        W = fb.render(fb.update(None, st_), tool, np.zeros(6), DT, st_)
        tool.V = tool.V + DT * W / 0.1 * np.array([1, 1, 1, 0, 0, 0])
        z += DT * tool.V[2]
        speeds.append(abs(tool.V[2]))
        z_min = min(z_min, z)
    assert max(speeds) <= 0.1 + 1e-12 and tool.V[2] > 0.0 and z_min > -1e-4 - 0.1 * DT  # one tick at 0.1 m/s in


@pytest.mark.parametrize("plane, why", [([0, 0, 2, 0, 0, 0, 1e4, 1], "unit"), ([0, 0, 1, 0, 0, 0, -1, 1], "negative"),
                                        ([0, 0, 1, 0, 0, 0, 1e4, 1.5], "confidence"),
                                        ([0, 0, 1, 0, 0, np.nan, 1e4, 1], "not finite")])
def test_a_plane_no_estimator_sends_is_refused(plane, why):
    from teleop.tick.messages import MessageError

    with pytest.raises(MessageError, match=why):
        ContactFeedback(1, 0.0, np.zeros(6), "ok", 0, plane_P=plane)


def test_the_plane_crosses_the_wire_whole():
    from teleop.link import wire

    msg = ContactFeedback(3, 0.5, [0, 0, 2, 0, 0, 0], "ok", 2, plane_P=[0, 0.6, 0.8, 0.1, 0.2, 0.3, 12345.0, 0.7])
    back = wire.decode(wire.encode(msg))
    assert np.array_equal(back.plane_P, msg.plane_P)
