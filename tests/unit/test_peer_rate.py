"""Two processes at two rates are refused: each side reads its peer's period off the first message
numbered 2 or more (seq i + 1 stamped i dt) and ends "link_refused" with one line naming both."""

import numpy as np

from teleop.app.netrun import PeerRate
from teleop.tick.messages import ContactFeedback, ToolCommand

Z3 = np.zeros(3)


class Link:
    """Hands the test's message to a side; records what is sent."""

    def __init__(self):
        self.inbox, self.sent = None, []

    def receive_command(self, t_s):
        return self.inbox

    receive_feedback = receive_command

    def send_command(self, msg):
        self.sent.append(msg)

    send_feedback = send_command

    def clock(self, t_s):
        return 7.0

    def last_heard_s(self, side):
        return 6.5


def command(i, dt):
    return ToolCommand(i + 1, i * dt, Z3, np.eye(3), Z3, Z3, True)


def reply(i, dt):
    return ContactFeedback(i + 1, i * dt, np.zeros(6), "ok", i + 1)


def test_the_same_period_passes_and_every_call_goes_through():
    link = Link()
    port = PeerRate(link, "slave", 5e-4)
    for i in range(5):
        link.inbox = command(i, 5e-4)
        assert port.receive_command(i * 5e-4) is link.inbox
    assert port.checked and port.refused is None
    port.send_feedback("x")
    assert link.sent == ["x"] and port.clock(0.0) == 7.0 and port.last_heard_s("slave") == 6.5


def test_a_hello_and_the_first_tick_tell_nothing():
    link = Link()
    port = PeerRate(link, "master", 5e-4)
    for msg in (ContactFeedback(0, -1.0, np.zeros(6), "hold", -1), reply(0, 1e-3), None):
        link.inbox = msg
        port.receive_feedback(0.0)
    assert not port.checked and port.refused is None


def test_another_period_is_refused_on_either_side_naming_both():
    link = Link()
    slave = PeerRate(link, "slave", 1e-3)
    link.inbox = command(3, 5e-4)
    slave.receive_command(0.0)
    assert slave.refused.startswith("the master ticks every 0.5 ms, this slave every 1 ms")
    master = PeerRate(link, "master", 5e-4)
    link.inbox = reply(1, 1e-3)
    master.receive_feedback(0.0)
    assert master.refused.startswith("the slave ticks every 1 ms, this master every 0.5 ms")
