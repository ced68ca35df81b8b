"""The [link] table in a run: the link it builds, the guard's two ends against hand-computed
energies and offsets, and the damping cap from the tool's mass."""

import numpy as np
import pytest

from teleop.app.runtime import make_guard, make_link
from teleop.control.mapping import Registration
from teleop.control.passivity import TdpaParams
from teleop.link import ContactFeedback, LockstepLink, SimulatedChannel, ToolCommand
from teleop.scenario.schema import load_scene
from teleop.tick.feedback import FeedbackPath
from teleop.tick.guard import MasterGuard, SlaveGuard, tdpa_params
from teleop.util.errors import SceneError

DT = 1e-3


def test_no_link_table_is_the_lockstep_link():
    scene = load_scene("straight_incision")
    assert not scene.link.simulated
    assert type(make_link(scene, np.random.default_rng(0))) is LockstepLink
    assert make_guard(scene, scene.mapping.registration(), 10) is None


def test_link_table_from_the_command_line_builds_the_channel():
    scene = load_scene("straight_incision", sets=["link.round_trip_ms=40", "link.loss=0.1",
                                                  "link.burst_enter=0.01", "link.bandwidth_kBps=100"])
    link = make_link(scene, np.random.default_rng(0))
    assert isinstance(link, SimulatedChannel)
    spec = link.spec
    assert spec.round_trip_ms == 40.0 and spec.loss == (0.1, 0.1) and spec.burst_enter == (0.01, 0.01)
    assert spec.bandwidth_Bps == (1e5, 1e5) and spec.delay_s(0) == pytest.approx(0.02)


@pytest.mark.parametrize("sets, networked, guarded", [
    ([], False, False),                                             # the in-process link: nothing to guard
    ([], True, True),                                               # over Zenoh: "auto" guards
    (["link.round_trip_ms=1"], False, True),                        # a delay named: guarded
    (["link.jitter_ms=0.5"], False, True), (["link.loss=0.01"], False, True),
    (["link.bandwidth_kBps=500"], False, True), (["link.burst_enter=0.01"], False, True),
    (["link.round_trip_ms=100", 'link.passivity="off"'], True, False),  # said off: off, even on a network
    (['link.passivity="tdpa"'], False, True),                       # said tdpa: on, even in one process
])
def test_auto_guards_a_link_that_delays_or_crosses_a_network(sets, networked, guarded):
    scene = load_scene("straight_incision", sets=sets)
    assert scene.link.guarded(networked) is guarded
    assert (make_guard(scene, scene.mapping.registration(), 10, networked=networked) is not None) is guarded


def test_the_default_is_auto_and_a_delayed_run_is_guarded():
    assert load_scene("straight_incision").link.passivity == "auto"
    from teleop.app.runtime import run_scene
    s = run_scene(load_scene("straight_incision", sets=["duration_s=0.2", "link.round_trip_ms=20"])).summary
    assert "passivity" in s and s["status"] == "ok"


@pytest.mark.parametrize("setting, key", [
    ("link.loss=1.0", "link.loss"), ("link.round_trip_ms=-1", "link.round_trip_ms"),
    ('link.passivity="on"', "link.passivity"), ("link.delay_ms=5", "link.delay_ms")])
def test_bad_link_settings_name_the_key(setting, key):
    with pytest.raises(SceneError, match=key.replace(".", r"\.")):
        load_scene("straight_incision", sets=[setting])


def test_damping_cap_follows_the_tool():
    scene = load_scene("straight_incision", sets=['link.passivity="tdpa"', "link.alpha_max=0.5"])
    p = tdpa_params(scene.link, 1e-3, 0.1, [0.0004, 0.0004, 0.00002], enabled=True)
    # 0.5 * m / dt on force axes, 0.5 * J_min / dt on torque axes (by hand)
    assert p.alpha_max == pytest.approx((50.0, 50.0, 50.0, 0.01, 0.01, 0.01))
    # the reflected drift spring: drift_gain (2/s by default) x the damping cap, N/m and N*m/rad
    assert scene.link.drift_gain == 2.0
    assert p.drift_stiffness == pytest.approx((100.0, 100.0, 100.0, 0.02, 0.02, 0.02))
    J = np.diag([3e-4, 2e-4, 5e-4])
    assert tdpa_params(scene.link, 1e-3, 1.0, J, True).alpha_max[3] == pytest.approx(0.5 * 2e-4 / 1e-3)


def test_master_guard_damps_the_deficit_and_stamps_energy():
    g = MasterGuard(TdpaParams(dt_s=DT, alpha_max=(1e6,) * 6))
    x = np.eye(6)[0]
    # the channel pushes the master along its motion, nothing from the slave: rendered (nothing
    # owed yet); the tool then moves at 0.1 m/s under it: f v = 0.2 W out for a tick
    assert g.feedback(2.0 * x, 0.1 * x, None, 0.0)[0] == 2.0
    out = g.feedback(2.0 * x, 0.1 * x, None, DT)
    W = -0.2 * DT  # observer before the controller
    alpha = -W / (DT * 0.1**2)
    assert g.port.W[0] == pytest.approx(W)
    assert out[0] == pytest.approx(2.0 - alpha * 0.1) and out[0] == pytest.approx(0.0, abs=1e-12)
    assert g.energy_J[0] == 0.0
    # now the channel's -1 N is rendered (damped: still in deficit) and the master pushes against
    # it at 0.5 m/s: the slave is credited with the channel's own 0.5 W, not the damping's share
    g.feedback(-1.0 * x, 0.5 * x, None, 2 * DT)
    assert g.energy_after(0.5 * x)[0] == pytest.approx(0.5 * DT)
    assert g.energy_J[0] == pytest.approx(0.5 * DT)


def test_slave_guard_corrects_velocity_and_offsets_the_pose():
    reg = Registration(np.zeros(3), np.eye(3), 1.0, 1.0)
    g = SlaveGuard(TdpaParams(dt_s=DT, dv_max=10.0), reg)
    fb = g.reply(ContactFeedback(1, 0.0, [-4.0, 0, 0, 0, 0, 0], "ok", 0))  # resisting force 4 N
    assert fb.energy_J[0] == 0.0 and g.f_M[0] == -4.0
    cmd = ToolCommand(1, 0.0, [0.1, 0, 0], np.eye(3), [0.05, 0, 0], np.zeros(3), True)
    out = g.command(cmd, DT)
    # the channel gives 4 * 0.05 = 0.2 W to the slave's environment with nothing from the master:
    # W = -0.2 dt; dv = -W / (dt f) = -0.05 (stops the slave); the offset -0.05 dt
    assert out.v_m_s[0] == pytest.approx(0.0, abs=1e-12)
    assert out.p_m[0] == pytest.approx(0.1 - 0.05 * DT)
    assert g.drift_M[0] == pytest.approx(-0.05 * DT)
    np.testing.assert_allclose(out.R, np.eye(3))
    assert g.command(None, 2 * DT) is None  # nothing to follow: the slave holds


@pytest.mark.parametrize("model_offset", [True, False])
def test_slave_guard_counts_the_force_the_master_renders_from(model_offset):
    """With the contact's damping rendered at the master, the channel brings F0 = W + D V (the
    damper is passive where it is rendered): the slave port counts F0, as the master port does;
    without it, the wrench W alone. By hand: W = -4 N, D = 1000 N*s/m, V = 3 mm/s: F0 = -1 N."""
    reg = Registration(np.zeros(3), np.eye(3), 1.0, 1.0)
    g = SlaveGuard(TdpaParams(dt_s=DT, dv_max=10.0), reg, model_offset=model_offset)
    D = np.zeros((6, 6))
    D[0, 0] = 1000.0
    fb = g.reply(ContactFeedback(1, 0.0, [-4.0, 0, 0, 0, 0, 0], "ok", 0, damping_P=D,
                                 twist_P=[0.003, 0, 0, 0, 0, 0]))
    assert g.f_M[0] == pytest.approx(-1.0 if model_offset else -4.0)
    np.testing.assert_array_equal(fb.wrench_P, [-4.0, 0, 0, 0, 0, 0])  # the reply still says what was measured
    fp = FeedbackPath(reg, cutoff_hz=0.0, dt_s=DT, local_damping=model_offset)
    assert fp.update(fb)[0] == pytest.approx(g.f_M[0])  # the master's port sees the same force


def test_slave_guard_reflects_the_drift_to_the_master():
    """The reply carries the contact wrench plus the drift spring, mapped back to P so that the
    master, after ``wrench_to_master``, feels exactly K * offset more once the commanded speed is
    past ``drift_speed`` (in proportion below it, nothing at rest); the slave port's own books
    keep the contact wrench alone (the spring does no work on the slave's environment)."""
    Rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # M is P turned 90 deg about z
    reg = Registration(np.zeros(3), Rz, 1.0, 0.5, 0.25)
    K = (100.0, 200.0, 300.0, 1.0, 2.0, 3.0)
    g = SlaveGuard(TdpaParams(dt_s=DT, drift_stiffness=K), reg)
    contact = np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
    fb = g.reply(ContactFeedback(1, 0.0, contact, "ok", 0))
    np.testing.assert_array_equal(fb.wrench_P, contact)  # no drift yet: the contact as measured
    g.port.offset = np.array([1e-3, -2e-3, 0.0, 0.0, 0.0, 0.01])
    fb = g.reply(ContactFeedback(2, DT, contact, "ok", 1))
    np.testing.assert_array_equal(fb.wrench_P, contact)  # a drift, but nothing moves: nothing felt
    g.speed = np.full(6, 0.5 * g.port.params.drift_speed)
    fb = g.reply(ContactFeedback(2, DT, contact, "ok", 1))  # half the gate's speed: half the spring
    np.testing.assert_allclose(reg.wrench_to_master(fb.wrench_P), [1.05, -0.7, 1.5, 0.05, -0.025, 0.09], atol=1e-12)
    g.speed = np.full(6, 2.0 * g.port.params.drift_speed)
    fb = g.reply(ContactFeedback(2, DT, contact, "ok", 1))
    # by hand: R^T f = (2, -1, 3) x 0.5 + K * offset (0.1, -0.4, 0); R^T tau = (0.2, -0.1, 0.3) x 0.25 + (0, 0, 0.03)
    np.testing.assert_allclose(reg.wrench_to_master(fb.wrench_P), [1.1, -0.9, 1.5, 0.05, -0.025, 0.105], atol=1e-12)
    np.testing.assert_allclose(g.f_M, [1.0, -0.5, 1.5, 0.05, -0.025, 0.075], atol=1e-12)
    assert fb.energy_J is not None and fb.seq == 2 and fb.status == "ok"


def test_slave_guard_speed_follows_the_commanded_twist():
    """The gate's speed: |twist| through a first-order low-pass of time constant tau (by hand:
    after one tick dt / (tau + dt) of the step)."""
    reg = Registration(np.zeros(3), np.eye(3), 1.0, 1.0)
    g = SlaveGuard(TdpaParams(dt_s=DT, drift_speed_tau_s=0.2), reg)
    cmd = ToolCommand(1, 0.0, [0.1, 0, 0], np.eye(3), [-0.05, 0, 0], [0, 0, 0.3], True)
    g.command(cmd, DT)
    a = DT / (0.2 + DT)
    np.testing.assert_allclose(g.speed, a * np.array([0.05, 0, 0, 0, 0, 0.3]), rtol=1e-12)
    g.command(None, 2 * DT)  # nothing commanded: the speed decays toward zero
    np.testing.assert_allclose(g.speed, (1 - a) * a * np.array([0.05, 0, 0, 0, 0, 0.3]), rtol=1e-12)


def test_zero_delay_channel_is_the_lockstep_link():
    """The same run through the channel model at zero delay and through the lockstep link."""
    from teleop.app.runtime import run_scene

    base = load_scene("straight_incision", sets=["duration_s=0.6"])
    # builds the channel (1e-13 s per message); the guard off, as "auto" would put it on a named channel
    via = base.with_overrides(["link.bandwidth_kBps=1e12", 'link.passivity="off"'])
    a, b = run_scene(base), run_scene(via)
    assert "link" in b.summary and "link" not in a.summary
    assert a.summary["metrics"] == b.summary["metrics"]
    np.testing.assert_array_equal(a.log["slave_tip"], b.log["slave_tip"])
