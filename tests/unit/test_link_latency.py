"""The link's latency accounting (teleop.link.latency) on the simulated channel, in simulated
time: a fixed one-way delay d gives a round trip of 2d within one tick, the split of the
command-to-applied-reply latency closes on it within one tick, loss and late ticks count what
the channel lost; the wire carries the stamps (version 5) and refuses non-finite ones."""

import struct

import numpy as np
import pytest

from teleop.link import ChannelSpec, SimulatedChannel, wire
from teleop.link.latency import LatencyLedger, Stamps, latency_summary
from teleop.tick.messages import ContactFeedback, MessageError, ToolCommand

DT = 1e-3


def _cmd(seq: int, t: float) -> ToolCommand:
    return ToolCommand(seq, t, [0.1, 0.2, 0.3], np.eye(3), [0, 0, 0], [0, 0, 0])


def _lockstep(ch: SimulatedChannel, n: int) -> None:
    """Both sides of one process, as BilateralLoop ticks them: the master feels what came in the
    last period, sends; the slave takes the newest command and replies."""
    k = 0
    for i in range(n):
        t = i * DT
        if i > 0:
            ch.receive_feedback(t - DT)
        ch.send_command(_cmd(i + 1, t))
        c = ch.receive_command(t)
        k += 1
        ch.send_feedback(ContactFeedback(k, t, np.zeros(6), "ok", -1 if c is None else c.seq))


@pytest.mark.parametrize("round_trip_ms", [0.0, 4.0, 20.0, 37.0])
def test_a_fixed_delay_gives_twice_it_as_round_trip_and_the_split_closes(round_trip_ms):
    ch = SimulatedChannel(ChannelSpec(round_trip_ms=round_trip_ms), np.random.default_rng(1))
    _lockstep(ch, 1000)
    lat = ch.stats()["latency"]
    assert lat["clock"] == "simulated time"
    rt = lat["round_trip_ms"]
    tick_ms = DT * 1e3
    assert round_trip_ms - 1e-6 <= rt["p50"] <= round_trip_ms + tick_ms + 1e-6
    assert round_trip_ms - 1e-6 <= rt["max"] <= round_trip_ms + tick_ms + 1e-6
    split = lat["split_ms"]
    d = round_trip_ms / 2
    assert split["command_way"]["p50"] == pytest.approx(d) and split["feedback_way"]["p50"] == pytest.approx(d)
    assert split["slave_tick"]["max"] == pytest.approx(0.0)  # the reply leaves in the tick that applied it
    for part in ("slave_wait", "master_wait"):
        assert -1e-9 <= split[part]["p50"] <= tick_ms and split[part]["max"] <= tick_ms + 1e-9
    assert abs(lat["split_closes_ms"]) <= tick_ms + 1e-9
    whole = split["command_to_applied_reply"]["p50"]
    assert rt["p50"] - 1e-9 <= whole <= rt["p50"] + tick_ms + 1e-9
    assert lat["loss"] == {"feedback": 0.0, "command": 0.0} and lat["late_ticks"] == 0
    assert lat["jitter_ms"] == pytest.approx(0.0, abs=1e-9)
    assert lat["replies"] >= 1000 - round_trip_ms / tick_ms - 3  # all but those still in flight at the end


def test_loss_and_jitter_are_counted():
    ch = SimulatedChannel(ChannelSpec(round_trip_ms=10.0, jitter_ms=1.0, loss=0.1), np.random.default_rng(7))
    _lockstep(ch, 4000)
    s = ch.stats()
    lat = s["latency"]
    for way, key in (("command", "command"), ("feedback", "feedback")):
        expected = s[way]["lost"] / s[way]["sent"]
        assert lat["loss"][key] == pytest.approx(expected, abs=0.01)
    assert 0.05 < lat["loss"]["feedback"] < 0.15
    assert lat["late_ticks"] > 0.05 * 4000  # a lost or late reply: a tick with nothing new
    assert lat["jitter_ms"] > 0.1
    assert lat["round_trip_ms"]["p50"] >= 10.0 and lat["round_trip_ms"]["p99"] > lat["round_trip_ms"]["p50"]


def test_a_scene_over_a_delayed_link_reports_its_latency():
    from teleop.app.runtime import run_scene
    from teleop.scenario.schema import load_scene

    scene = load_scene("straight_incision", sets=["duration_s=0.3", "link.round_trip_ms=20"])
    lat = run_scene(scene).summary["link"]["latency"]
    assert 20.0 - 1e-6 <= lat["round_trip_ms"]["p50"] <= 21.0 + 1e-6
    assert abs(lat["split_closes_ms"]) <= 1.0 + 1e-9


def test_the_wire_carries_the_stamps_and_refuses_non_finite_ones():
    fb = ContactFeedback(4, 0.5, np.arange(6.0), "ok", 3)
    st = Stamps(12.5, 11.0, 11.25, 11.5)
    frame = wire.encode(fb, stamps=st)
    assert wire.stamps(frame) == st and wire.decode(frame).command_seq == 3
    assert len(frame) == wire.FEEDBACK_SIZE and wire.parse(frame).seq == 4
    cmd = wire.encode(_cmd(9, 0.25), stamps=Stamps(3.0))
    assert wire.stamps(cmd) == Stamps(3.0)
    echo = len(frame) - wire.TAG_SIZE - 8
    bad = frame[:echo] + struct.pack("<d", float("nan")) + frame[echo + 8:]
    bad = bad[:-wire.TAG_SIZE] + wire.PLAIN.tag(bad[:-wire.TAG_SIZE])
    with pytest.raises(MessageError, match="non-finite"):
        wire.decode(bad)


def test_a_ledger_pair_follows_one_command_and_its_reply():
    m, s = LatencyLedger("master"), LatencyLedger("slave")
    cmd = _cmd(1, 0.0)
    st = m.sending(cmd, 10.0)
    s.received(cmd, st, 10.002)
    s.applied(cmd, 10.003)
    fb = ContactFeedback(1, 0.0, np.zeros(6), "ok", 1)
    back = s.sending(fb, 10.004)
    assert back == Stamps(10.004, 10.0, 10.002, 10.003)
    m.received(fb, back, 10.007)
    m.applied(fb, 10.0075)
    assert m.last == (10.0, 10.002, 10.003, 10.004, 10.007, 10.0075)
    lat = latency_summary(m, s)
    assert lat["round_trip_ms"]["p50"] == pytest.approx(7.0)
    assert lat["split_ms"]["command_to_applied_reply"]["p50"] == pytest.approx(7.5)
