"""The two-process halves without a network: the heartbeat's timing on a fake clock, the master's
and the slave's safe states and their resumption, and the merged summary's status."""

import numpy as np
import pytest

from teleop.app.runtime import make_slave
from teleop.link import ContactFeedback
from teleop.master.ideal import IdealMaster
from teleop.scenario.build import build_fixture, build_registration, build_tool, master_fixture_spec
from teleop.scenario.operators import make_operator
from teleop.scenario.schema import load_scene
from teleop.tick.feedback import FeedbackPath
from teleop.tick.heartbeat import HeartbeatState
from teleop.tick.master_side import MasterSide
from teleop.tick.verdict import run_summary

DT = 1e-3


class FakeLink:
    """A link whose peer answers every tick while ``up``; the clock is the test's."""

    def __init__(self):
        self.now, self.up, self.last_receive_s = 0.0, True, None
        self.sent, self.inbox = [], None

    def clock(self, t_s=0.0):
        return self.now

    def last_heard_s(self, side=""):
        return self.last_receive_s

    def alive(self, now_s=None, timeout_s=0.02):
        return (self.last_receive_s is not None
                and (self.now if now_s is None else now_s) - self.last_receive_s <= timeout_s)

    def deliver(self, msg):
        if self.up:
            self.inbox, self.last_receive_s = msg, self.now

    def send_command(self, msg):
        self.sent.append(msg)

    def send_feedback(self, msg):
        self.sent.append(msg)

    def receive_feedback(self, t_s=0.0):
        m, self.inbox = self.inbox, None
        return m

    receive_command = receive_feedback


def test_heartbeat_trips_after_the_timeout_and_counts():
    hb = HeartbeatState(0.02)
    assert hb.update(5.0, None) is False  # nothing heard yet: the start-up, not a loss
    for k in range(21):  # 0..20 ms: alive
        assert hb.update(k * DT, 0.0) is False
    assert hb.update(0.0211, 0.0) is True and hb.events == 1 and hb.latency_s[0] == pytest.approx(0.0211)
    assert hb.update(0.03, 0.03) is False and hb.resumed == 1 and hb.ticks_lost == 1
    assert hb.update(0.031, 0.031, peer_lost=True) is True and hb.events == 2  # the slave says link_lost


def _master_half(link):
    scene = load_scene("straight_incision")
    rng = np.random.default_rng(0)
    tool = build_tool(scene)
    op = make_operator(scene.operator, master_fixture_spec(scene), scene.effects, rng)
    fb = FeedbackPath(build_registration(scene), 0.0, DT)
    return MasterSide(tool, IdealMaster(tool, DT), op, DT, fb, None, 0.02)


def test_master_safe_state_holds_the_tool_and_drops_the_force_then_resumes_without_a_jump():
    link = FakeLink()
    half = _master_half(link)
    tick = half.tick
    half.tick = lambda i: tick(i, i * DT, link)
    link.last_receive_s = 0.0
    for i in range(600):  # the hand starts pulling at 0.5 s
        link.now = i * DT
        link.deliver(ContactFeedback(i + 1, i * DT, [-1.0, 0, 0, 0, 0, 0], "ok"))
        half.tick(i)
    assert np.linalg.norm(half.tool.qd) > 0 and half.feedback_W[0] == pytest.approx(-1.0)
    link.up = False
    p_lost = None
    for i in range(600, 700):
        link.now = i * DT
        half.tick(i)
        if half.heart.lost and p_lost is None:
            p_lost, i_lost = half.tool.pose()[0], i
    assert i_lost - 600 <= 21  # detected within 20 ms (+ the tick that sees it)
    assert np.all(half.tool.qd == 0) and np.all(half.feedback_W == 0)
    np.testing.assert_array_equal(half.tool.pose()[0], p_lost)  # held where it stopped
    assert half.heart.speed_lost_max == 0.0
    link.up = True
    for i in range(700, 800):
        link.now = i * DT
        link.deliver(ContactFeedback(i + 1, i * DT, [-1.0, 0, 0, 0, 0, 0], "ok"))
        half.tick(i)
    s = half.heart.summary()
    assert s["resumed"] == 1 and s["step_after_resume_max_m"] <= 1e-4  # 0.1 mm a tick: no jump
    assert link.sent[-1].clutch and not any(m.clutch for m in link.sent[i_lost:i_lost + 50])


def test_slave_safe_state_holds_the_joints_and_reports_link_lost():
    scene = load_scene("straight_incision")
    reg = build_registration(scene)
    slave = make_slave(scene, reg, build_fixture(scene.fixture).constraints)
    tool = build_tool(scene)
    slave.reset(*tool.pose())
    link = FakeLink()
    half = slave
    tick = half.tick
    half.tick = lambda i: tick(i, i * DT, link)
    from teleop.link import ToolCommand

    p, R = tool.pose()
    link.last_receive_s = 0.0
    for i in range(100):  # a command moving at 30 mm/s
        link.now = i * DT
        link.deliver(ToolCommand(i + 1, i * DT, p + [0.03 * i * DT, 0, 0], R, [0.03, 0, 0], np.zeros(3)))
        half.tick(i)
    link.up = False
    for i in range(100, 400):
        link.now = i * DT
        half.tick(i)
    assert half.heart.lost and link.sent[-1].status == "link_lost"
    assert half.heart.speed_lost_last < 1e-6  # joints at rest
    assert slave.state.status == "link_lost"


def test_merged_status_is_ok_only_when_both_sides_are():
    hb = {"lost_ticks": 0}
    m = {"heartbeat": hb, "slave_statuses_heard": {"ok": 10}}
    s = {"heartbeat": hb, "slave_statuses": {"ok": 10}, "followed_last_command": True, "last_command_seq": 10}
    metrics = {"a": 1.0, "b": 2.0}

    def status(master_status="ok", m=m, s=s):
        return run_summary(master_status, 10, DT, m, s, metrics, False)["status"]

    assert status() == "ok"
    assert status(s={**s, "slave_statuses": {"ok": 5, "link_lost": 5}}) == "link_lost"
    assert status(s={**s, "heartbeat": {"lost_ticks": 3}}) == "link_lost"
    assert status(m={**m, "heartbeat": {"lost_ticks": 3}}) == "link_lost"
    assert status(s={**s, "followed_last_command": False}) == "link_lost"
    assert run_summary("ok", 10, DT, m, s, metrics, False)["metrics"] == metrics
    assert status(m=None) == "ok" and status(s=None) == "ok"  # a side alone judges by what it has


def test_cli_bad_input_is_one_line_and_exit_2(capsys):
    from teleop.app.cli import main

    assert main(["slave", "paper_rolling_disk", "--listen", "tcp/127.0.0.1:1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no [slave] table" in err[0]
    assert main(["run", "straight_incision", "--link", "zenoh", "--set", "link.loss=2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "link.loss" in err[0]


def test_zenoh_config_file_is_checked(tmp_path, capsys):
    from teleop.app.cli import main

    bad = tmp_path / "tls.json"
    bad.write_text('["not", "an object"]')
    assert main(["master", "straight_incision", "--zenoh-config", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--zenoh-config" in err[0]
    assert main(["master", "straight_incision", "--zenoh-config", str(tmp_path / "none.json")]) == 2


def test_frames_only_an_attacker_sends_make_the_run_say_so():
    hb = {"lost_ticks": 0}
    m, s = {"heartbeat": hb}, {"heartbeat": hb, "slave_statuses": {"ok": 10}}
    clean = {"zenoh_master": {"refused": {"stale": 1, "bad_mac": 0}}, "zenoh_slave": {"refused": {}}}
    # a stale frame may be the network's
    assert run_summary("ok", 10, DT, m, s, {}, False, link=clean)["status"] == "ok"
    forged = {"zenoh_master": {"refused": {"bad_mac": 3}}, "zenoh_slave": {"refused": {"other_session": 2}}}
    out = run_summary("ok", 10, DT, m, s, {}, False, link=forged)
    assert (out["status"] == "link_attacked" and "bad_mac 3" in out["status_reason"]
            and "other_session 2" in out["status_reason"])
    assert run_summary("tracking_error", 10, DT, m, s, {}, False, link=forged)["status"] == "tracking_error"
