"""The simulated channel: delay exact in ticks, loss rate, bursts, order, bandwidth, determinism."""

import dataclasses
import math

import numpy as np
import pytest

from teleop.link import ChannelSpec, ContactFeedback, LockstepLink, SimulatedChannel, ToolCommand
from teleop.link.wire import COMMAND_SIZE
from teleop.util.errors import ConfigError

DT = 1e-3


def cmd(k, t=None):
    return ToolCommand(seq=k, t_s=k * DT if t is None else t, p_m=[k * 1e-3, 0, 0], R=np.eye(3),
                       v_m_s=np.zeros(3), w_rad_s=np.zeros(3))


def fb(k):
    return ContactFeedback(seq=k, t_s=k * DT, wrench_P=[k, 0, 0, 0, 0, 0], status="ok", command_seq=k)


def run(link, n, way="command"):
    """Send one message a tick for n ticks (then 2 s of silence); the (tick, seq) received."""
    got = []
    for k in range(n + 2000):
        t = k * DT
        if k < n:
            (link.send_command if way == "command" else link.send_feedback)(cmd(k) if way == "command" else fb(k))
        m = (link.receive_command if way == "command" else link.receive_feedback)(t)
        if m is not None:
            got.append((k, m.seq))
    return got


def test_zero_delay_is_lockstep():
    a, b = SimulatedChannel(ChannelSpec(), np.random.default_rng(1)), LockstepLink()
    for way in ("command", "feedback"):
        assert run(a, 50, way) == run(b, 50, way) == [(k, k) for k in range(50)]


@pytest.mark.parametrize("rt_ms, share", [(0.0, 0.5), (10.0, 0.5), (200.0, 0.5), (1000.0, 0.5), (30.0, 0.7)])
def test_delay_is_exact_in_ticks(rt_ms, share):
    spec = ChannelSpec(round_trip_ms=rt_ms, cmd_share=share)
    ch = SimulatedChannel(spec, np.random.default_rng(2))
    for way, frac in (("command", share), ("feedback", 1 - share)):
        d = round(rt_ms * frac)
        assert run(ch, 100, way) == [(k + d, k) for k in range(100)]
    s = ch.stats()["command"]
    assert s["sent"] == s["delivered"] == 100 and s["lost"] == s["dropped_old"] == 0
    assert s["max_age_s"] == pytest.approx(rt_ms * share * 1e-3, abs=1e-9)


def test_iid_loss_rate_and_determinism():
    spec = ChannelSpec(round_trip_ms=20, loss=0.1)
    a = run(SimulatedChannel(spec, np.random.default_rng(3)), 20000)
    b = run(SimulatedChannel(spec, np.random.default_rng(3)), 20000)
    c = run(SimulatedChannel(spec, np.random.default_rng(4)), 20000)
    assert a == b and a != c
    rate = 1 - len(a) / 20000
    assert abs(rate - 0.1) < 4 * math.sqrt(0.1 * 0.9 / 20000)


def test_gilbert_elliott_bursts():
    # stationary loss = P(bad) = enter / (enter + exit) = 0.01 / 0.11; mean burst 1 / exit = 10 messages
    spec = ChannelSpec(burst_enter=0.01, burst_exit=0.1, burst_loss=1.0)
    ch = SimulatedChannel(spec, np.random.default_rng(5))
    got = {s for _, s in run(ch, 50000)}
    lost = np.array([k not in got for k in range(50000)])
    assert abs(lost.mean() - 0.01 / 0.11) < 0.02
    starts = np.flatnonzero(lost[1:] & ~lost[:-1])
    runs = lost.sum() / max(len(starts), 1)
    assert 7 < runs < 13  # i.i.d. loss at that rate would give runs of ~1.1
    assert ch.stats()["command"]["bursts"] > 0


def test_jitter_reorders_but_never_out_of_order():
    spec = ChannelSpec(round_trip_ms=20, jitter_ms=5.0)
    ch = SimulatedChannel(spec, np.random.default_rng(6))
    got = run(ch, 5000)
    seqs = [s for _, s in got]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    s = ch.stats()["command"]
    assert s["dropped_old"] > 100  # exponential jitter of mean 5 ms at 1 kHz reorders a lot
    assert s["sent"] == s["delivered"] + s["superseded"] + s["dropped_old"] + s["lost"] + s["in_flight"]
    for k, seq in got:  # never before the constant delay
        assert k >= seq + 10


def test_bandwidth_queues_messages():
    # a command (wire.COMMAND_SIZE bytes) each ms at two ticks of wire each: the queue grows
    size = COMMAND_SIZE
    spec = ChannelSpec(bandwidth_Bps=size / (2 * DT), queue_limit=10)
    ch = SimulatedChannel(spec, np.random.default_rng(7))
    got = run(ch, 100)
    assert got[0] == (2, 0)  # waits the wire: 2 ms
    s = ch.stats()["command"]
    assert s["dropped_queue"] > 0
    assert s["delivered"] + s["superseded"] + s["dropped_queue"] + s["dropped_old"] == 100
    # a fast enough wire: 0.5 ms per message, delivered the next tick, nothing queued
    ch = SimulatedChannel(ChannelSpec(bandwidth_Bps=size / (0.5 * DT)), np.random.default_rng(7))
    assert run(ch, 100) == [(k + 1, k) for k in range(100)]


def test_per_direction_settings():
    spec = ChannelSpec(loss=(0.0, 1.0))
    ch = SimulatedChannel(spec, np.random.default_rng(8))
    assert len(run(ch, 100, "command")) == 100 and run(ch, 100, "feedback") == []


@pytest.mark.parametrize("kw", [dict(round_trip_ms=-1), dict(loss=1.5), dict(jitter_ms=float("nan")),
                                dict(bandwidth_Bps=0), dict(loss=(0.1, 0.2, 0.3)), dict(queue_limit=0),
                                dict(burst_exit=0.0), dict(round_trip_ms=(1, 2)), dict(loss="x")])
def test_spec_is_validated(kw):
    with pytest.raises(ConfigError):
        ChannelSpec(**kw)


def test_spec_is_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        ChannelSpec().loss = 0.5
