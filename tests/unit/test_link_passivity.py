"""TDPA: the observers against hand-computed energy sums, the controllers dissipating exactly the
observer's deficit, and a 1-DOF delayed teleoperation against a 10 kN/m wall, unstable at 200 ms
round trip without the guard and stable with it."""

import numpy as np
import pytest

from teleop.control.passivity import MasterPassivity, SlavePassivity, TdpaParams, compute_port_energy
from teleop.link import ChannelSpec, ContactFeedback, SimulatedChannel, ToolCommand
from teleop.util.errors import ConfigError

DT = 1e-3
E6 = np.eye(6)[0]


def test_compute_port_energy_splits_signs():
    E_in, E_out = compute_port_energy(np.zeros(6), np.ones(6), np.array([2.0, -3.0, 0, 0, 0, 0]), 0.5)
    np.testing.assert_allclose(E_in, [1.0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(E_out, [1.0, 2.5, 1, 1, 1, 1])


def test_master_observer_against_hand_sum():
    # f on the master and v of the master, axis 0. The force rendered at one tick does its work
    # with the velocity of the next: power into the channel p(k) = -f(k-1) v(k)
    f = [-2.0, -2.0, 1.0, 3.0, -1.0]
    v = [0.5, 1.0, 1.0, 2.0, -1.0]
    E_remote = [0.0, 1e-3, 1e-3, 2e-3, 2e-3]
    port = MasterPassivity(TdpaParams(dt_s=DT, enabled=False), log_capacity=10)
    for k in range(5):
        out = port.step(f[k] * E6, v[k] * E6, E_remote[k] * E6, t_s=k * DT)
        assert out[0] == f[k]
    # by hand: f(k-1) v(k) = -2, -2, 2, -3 -> E_in = (2 + 2 + 3) dt, E_out = 2 dt
    assert port.E_in[0] == pytest.approx(7e-3) and port.E_out[0] == pytest.approx(2e-3)
    log = port.log.arrays()  # W = E_remote - E_out after each tick
    np.testing.assert_allclose(log["W_J"][:, 0], [0, 1e-3, 1e-3, 0, 0], atol=1e-15)
    np.testing.assert_allclose(log["t_s"], np.arange(5) * DT)
    assert np.all(port.E_in[1:] == 0) and port.dissipated_J == 0


def test_energy_for_the_command_counts_the_step_just_done():
    port = MasterPassivity(TdpaParams(dt_s=DT, enabled=False))
    port.step(-3.0 * E6, np.zeros(6))  # -3 N rendered
    assert port.energy_after(2.0 * E6)[0] == pytest.approx(6e-3)  # the tool moved at 2 m/s against it
    port.step(np.zeros(6), 2.0 * E6)  # the same tick: counted once
    assert port.E_in[0] == pytest.approx(6e-3)


def test_master_controller_dissipates_exactly_the_deficit():
    port = MasterPassivity(TdpaParams(dt_s=DT, alpha_max=1e9))
    port.step(-1.0 * E6, 1.0 * E6, 5e-3 * E6)  # 5 mJ announced by the slave
    assert port.step(4.0 * E6, 2.0 * E6)[0] == 4.0  # -1 N against 2 m/s: 2 mJ in; no deficit
    assert port.E_in[0] == pytest.approx(2e-3)
    out = port.step(4.0 * E6, 2.0 * E6)  # the 4 N gave 8 mJ: W = 5 - 8 = -3 mJ
    alpha = 3e-3 / (DT * 4.0)
    assert port.W[0] == pytest.approx(-3e-3)
    assert out[0] == pytest.approx(4.0 - alpha * 2.0)
    assert port.dissipated_J == pytest.approx(3e-3)
    # below the velocity floor nothing is done, and the deficit is kept for later
    out = port.step(4.0 * E6, 1e-6 * E6)
    assert out[0] == 4.0 and port.W[0] < 0


def test_a_force_arriving_at_rest_is_seen_in_the_step_it_acts():
    """A stiff wall's force reaching a tool at rest: no velocity yet (below the floor), so it is
    rendered whole; its work shows in the next tick's observer, which then damps, capped."""
    port = MasterPassivity(TdpaParams(dt_s=DT, alpha_max=10.0))
    out = port.step(100.0 * E6, np.zeros(6))
    assert out[0] == 100.0 and port.W[0] == 0.0
    out = port.step(np.zeros(6), 1.0 * E6)  # the 100 N did 0.1 J on the tool in its step
    assert port.E_out[0] == pytest.approx(0.1) and port.W[0] == pytest.approx(-0.1)
    assert out[0] == pytest.approx(-10.0)  # alpha wants 100 N*s/m: reversing the force is capped


def test_master_may_always_remove_a_force_along_the_motion():
    port = MasterPassivity(TdpaParams(dt_s=DT, alpha_max=10.0))
    assert port.step(100.0 * E6, 1.0 * E6)[0] == 100.0  # nothing owed yet
    out = port.step(100.0 * E6, 1.0 * E6)  # it gave 0.1 J: alpha = f / v = 100 > the cap, allowed
    assert port.W[0] == pytest.approx(-0.1) and out[0] == pytest.approx(0.0, abs=1e-12)
    port.step(100.0 * E6, 1.0 * E6)
    assert port.W[0] == pytest.approx(-0.1)  # nothing more went out


def test_slave_observer_and_velocity_correction():
    port = SlavePassivity(TdpaParams(dt_s=DT, dv_max=1e9), log_capacity=4)
    # slave pushes into the wall (v > 0, f < 0): p = f v = -5 W, 5 mJ out; 2 mJ announced
    v = port.step(1.0 * E6, -5.0 * E6, 2e-3 * E6)
    dv = -(2e-3 - 5e-3) / (DT * -5.0)
    assert v[0] == pytest.approx(1.0 + dv) and dv < 0  # backs off
    assert port.dissipated_J == pytest.approx(3e-3) and port.W[0] == pytest.approx(0.0, abs=1e-15)
    assert port.offset[0] == pytest.approx(dv * DT)
    assert port.E_in[0] == 0 and port.E_out[0] == pytest.approx(5e-3)
    # the wall pushes the slave back: energy enters at the slave port
    port.step(-1.0 * E6, -5.0 * E6)
    assert port.E_in[0] == pytest.approx(5e-3)


def test_a_lost_packet_loses_no_energy():
    """Energy messages are cumulative: whatever is lost, the next message that arrives carries
    the whole sum. The slave port counts a known power each tick and sends E_in through a channel
    that loses half the messages; the master's received energy never runs ahead of what was
    sent, and after the last delivered message it is the hand-computed sum."""
    dt, n = DT, 400
    ch = SimulatedChannel(ChannelSpec(round_trip_ms=20.0, loss=0.5), np.random.default_rng(3))
    sp = SlavePassivity(TdpaParams(dt_s=dt, enabled=False))
    mp = MasterPassivity(TdpaParams(dt_s=dt, enabled=False))
    power = [(k % 7) * 0.5 for k in range(n)]  # W the environment gives back at tick k
    sent = []
    for k in range(n):
        t = k * dt
        sp.step(-1.0 * E6, -power[k] * E6)  # commanded away at 1 m/s, the wall pushing with p N
        sent.append(sp.energy_J[0])
        ch.send_feedback(ContactFeedback(k, t, np.zeros(6), "ok", k, sp.energy_J))
        fb = ch.receive_feedback(t)
        mp.step(np.zeros(6), np.zeros(6), None if fb is None else fb.energy_J, t)
        assert mp.E_remote[0] <= sent[-1] + 1e-15
        if fb is not None:
            assert mp.E_remote[0] == sent[fb.seq]  # the newest arrived value, not a sum of what came
    last = None
    for k in range(n, n + 40):  # flush: the last messages arrive (10 ms one way), a few more sent
        t = k * dt
        ch.send_feedback(ContactFeedback(k, t, np.zeros(6), "ok", k, sp.energy_J))
        fb = ch.receive_feedback(t)
        if fb is not None:
            mp.step(np.zeros(6), np.zeros(6), fb.energy_J, t)
            last = fb
    assert ch.stats()["feedback"]["lost"] > 150  # half of them lost
    assert last is not None
    hand = sum(power) * dt  # 0 + 0.5 + ... + 3 W repeating, each for one tick
    assert hand == pytest.approx(sum((k % 7) * 0.5 for k in range(n)) * 1e-3)
    assert mp.E_remote[0] == pytest.approx(hand, rel=1e-12)


def test_received_energy_is_held_and_never_decreases():
    port = MasterPassivity(TdpaParams(dt_s=DT, enabled=False))
    port.step(np.zeros(6), np.zeros(6), 3.0 * E6)
    port.step(np.zeros(6), np.zeros(6), None)
    port.step(np.zeros(6), np.zeros(6), 1.0 * E6)
    assert port.E_remote[0] == 3.0


@pytest.mark.parametrize("kw", [{"dt_s": 0}, {"dt_s": DT, "alpha_max": -1}, {"dt_s": DT, "drift_gain": -1},
                                {"dt_s": DT, "drift_share": 2}, {"dt_s": float("nan")},
                                {"dt_s": DT, "drift_stiffness": -1.0}, {"dt_s": DT, "drift_stiffness": (1.0, 2.0)},
                                {"dt_s": DT, "drift_stiffness": float("inf")}, {"dt_s": DT, "drift_speed": 0.0},
                                {"dt_s": DT, "drift_speed_tau_s": -1.0}])
def test_params_are_validated(kw):
    with pytest.raises(ConfigError):
        TdpaParams(**kw)


def two_masses(rt_ms, guard, T=6.0, loss=0.0, seed=0, drift_gain=0.0, drift_k=0.0):
    """1-DOF: a hand (spring-damper to a target ramping to 30 mm) pushes a 0.5 kg master; the
    slave (0.5 kg, PD 2000 N/m, 40 N*s/m) follows the delayed master position, a 10 kN/m wall at
    10 mm; the wall force goes back and is rendered on the master, plus ``drift_k`` (N/m) times
    the slave's offset (the drift reflected as :class:`SlaveGuard` does, without its speed gate:
    the spring alone). Rows: t, x_m, x_s, f on
    the master, wall force, slave offset, the force the slave port counted, the velocity it
    commanded (s, m, m, N, N, m, N, m/s)."""
    ch = SimulatedChannel(ChannelSpec(round_trip_ms=rt_ms, loss=loss), np.random.default_rng(seed))
    n = round(T / DT)
    prm = TdpaParams(dt_s=DT, enabled=guard, drift_gain=drift_gain, drift_stiffness=drift_k)
    mp, sp = MasterPassivity(prm, n), SlavePassivity(prm, n)
    m_m, b_m, m_s, K_h, B_h, Kp, Kd, k_w, x_w = 0.5, 0.5, 0.5, 300.0, 2.0, 2000.0, 40.0, 1e4, 0.01
    xm = vm = xs = vs = x_cmd = v_cmd = f_fb = 0.0
    out = np.zeros((n, 8))
    for k in range(n):
        t = k * DT
        fb = ch.receive_feedback(t)
        if fb is not None:
            f_fb = fb.wrench_P[0]
        f = mp.step(f_fb * E6, vm * E6, None if fb is None else fb.energy_J, t)[0]
        Fh = K_h * (0.03 * min(t, 1.0) - xm) - B_h * vm
        vm += DT * (Fh + f - b_m * vm) / m_m
        xm += DT * vm
        E_m = mp.energy_after(vm * E6)  # with the work the force just did
        ch.send_command(ToolCommand(k, t, [xm, 0, 0], np.eye(3), [vm, 0, 0], np.zeros(3), energy_J=E_m))
        cm = ch.receive_command(t)
        if cm is not None:
            x_cmd, v_cmd = cm.p_m[0], cm.v_m_s[0]
        Fe = f_port = -k_w * (xs - x_w) if xs > x_w else 0.0  # the force the slave port counts
        v = sp.step(v_cmd * E6, Fe * E6, None if cm is None else cm.energy_J, t)[0]
        vs += DT * (Kp * (x_cmd + sp.offset[0] - xs) + Kd * (v - vs) + Fe) / m_s
        xs += DT * vs
        Fe = -k_w * (xs - x_w) if xs > x_w else 0.0
        reflected = Fe + drift_k * sp.offset[0]
        ch.send_feedback(ContactFeedback(k, t, [reflected, 0, 0, 0, 0, 0], "ok", command_seq=k, energy_J=sp.energy_J))
        out[k] = (t, xm, xs, f, Fe, sp.offset[0], f_port, v)
        if not abs(xm) < 10.0:  # diverged
            return out[: k + 1], mp, sp
    return out, mp, sp


def swing(x, a, b):
    """Peak-to-peak of x over ticks [a, b) (m)."""
    return float(np.ptp(x[a:b]))


def test_zero_delay_guard_does_nothing():
    a, mp, sp = two_masses(0.0, True, T=3.0)
    b, _, _ = two_masses(0.0, False, T=3.0)
    np.testing.assert_array_equal(a, b)
    assert mp.dissipated_J == 0.0 and sp.dissipated_J == 0.0
    assert a[-1, 4] < -1.0  # pressing on the wall, and the master feels it
    assert a[-1, 3] == pytest.approx(a[-1, 4], rel=1e-2)


def test_unguarded_200ms_is_unstable():
    out, mp, _ = two_masses(200.0, False, T=4.0)
    xm = out[:, 1]
    assert not np.all(np.abs(xm) < 0.1) or swing(xm, 3000, 4000) > 10 * swing(xm, 1000, 2000)
    assert mp.log.W_J[: mp.log.n, 0].min() < -1.0  # the channel generated joules


@pytest.mark.parametrize("rt_ms, loss", [(200.0, 0.0), (200.0, 0.05), (1000.0, 0.05)])
def test_guarded_is_stable(rt_ms, loss):
    out, mp, sp = two_masses(rt_ms, True, loss=loss)
    xm, xs = out[:, 1], out[:, 2]
    assert np.all(np.isfinite(out)) and len(out) == 6000
    assert np.abs(xm).max() < 0.05 and np.abs(xs).max() < 0.05
    assert np.abs(out[:, 4]).max() < 50.0  # wall force bounded (N)
    assert swing(xm, 4500, 6000) <= 1.2 * swing(xm, 3000, 4500) + 1e-4  # not growing
    assert mp.dissipated_J + sp.dissipated_J > 0
    # the observers stay (nearly) non-negative: what is left is the floor and cap
    assert mp.log.W_J[: mp.log.n, 0].min() > -0.01 and sp.log.W_J[: sp.log.n, 0].min() > -0.01
    # the drift the guard causes: measured (the slave stops short of the master)
    drift = out[-1, 5]
    assert -0.05 < drift < 0.0


def test_drift_compensation_spends_only_surplus_and_stays_stable():
    plain, _, _ = two_masses(200.0, True)
    comp, _, sp = two_masses(200.0, True, drift_gain=2.0)
    assert np.all(np.isfinite(comp)) and np.abs(comp[:, 1]).max() < 0.05
    assert abs(comp[-1, 5]) < abs(plain[-1, 5])  # less drift
    assert sp.log.W_J[: sp.log.n, 0].min() > -0.01


def test_reflected_drift_is_compensated_and_the_slave_port_stays_passive():
    """The drift reflected to the master as a spring (drift_k times the offset, in the feedback)
    makes the hand pay for the catch-up: the hand works against the spring, that energy reaches the
    slave's observer and the drift compensation spends it. At 200 ms round trip the final drift
    is 19.5 mm without the spring and 6.2 mm with 1000 N/m; the bound is 8 mm (0.4x the
    unreflected run's). The slave port's net output, summed here from the force and velocity it
    used (not from its own books), never exceeds the master's energy it had received: what is
    left below zero is the floor (f_floor, 1 mN) and the cap, nanojoules."""
    plain, _, _ = two_masses(200.0, True, drift_gain=2.0)
    comp, _, sp = two_masses(200.0, True, drift_gain=2.0, drift_k=1000.0)
    assert len(comp) == 6000 and np.all(np.isfinite(comp))
    assert abs(plain[-1, 5]) > 0.015  # the drift the reflection is measured against
    assert abs(comp[-1, 5]) < 0.008 and abs(comp[-1, 5]) < 0.4 * abs(plain[-1, 5])
    xm = comp[:, 1]
    assert np.abs(xm).max() < 0.05 and np.abs(comp[:, 4]).max() < 50.0
    assert swing(xm, 4500, 6000) <= 1.2 * swing(xm, 3000, 4500) + 1e-4  # not growing
    net_out = np.cumsum(-comp[:, 6] * comp[:, 7]) * DT  # J the slave port put into the slave side
    received = sp.log.E_remote_J[: sp.log.n, 0]  # the master's E_in as the slave had it each tick
    assert np.all(net_out <= received + 1e-8)
    assert sp.log.W_J[: sp.log.n, 0].min() > -1e-8  # the slave's observer after its controller


def test_reflected_drift_changes_nothing_at_zero_delay():
    """At zero delay the guard never acts, the offset stays zero and so does the reflected spring:
    the run is the unguarded one bit for bit."""
    a, _, sp = two_masses(0.0, True, T=3.0, drift_gain=2.0, drift_k=1000.0)
    b, _, _ = two_masses(0.0, False, T=3.0)
    np.testing.assert_array_equal(a, b)
    assert not np.any(sp.offset)
