"""The link's trust rules without a transport (teleop.link.auth, teleop.link.pairing): pairing,
forged, foreign, replayed, far-future and invalid frames refused and counted, a second master
refused with one line, only fresh authentic frames handed on."""

import numpy as np
import pytest

from teleop.link import wire
from teleop.link.auth import HELLO_EVERY_S, LinkAuth
from teleop.link.keys import LinkKeys, random_secret
from teleop.link.pairing import derive
from teleop.tick.messages import ContactFeedback, ToolCommand

KEY = random_secret()


def cmd(k, p=0.0):
    return ToolCommand(k, k * 1e-3, [p, 0, 0], np.eye(3), np.zeros(3), np.zeros(3))


def fb(k):
    return ContactFeedback(k, k * 1e-3, np.zeros(6), "ok", k)


class Net:
    """Frames between auth objects: every master hears every slave and the other way round."""

    def __init__(self):
        self.t = 0.0

    def step(self, masters, slaves, rounds=6):
        for _ in range(rounds):
            self.t += HELLO_EVERY_S
            for m in masters:
                f = m.handshake_due(self.t)
                for s in slaves:
                    if f is not None:
                        s.open(f, self.t)
            for s in slaves:
                for f in s.outbox:
                    for m in masters:
                        m.open(f, self.t)
                s.outbox.clear()


def paired(key=KEY, link="t", m_name="M", s_name="S"):
    m = LinkAuth("master", LinkKeys(key, m_name), link)
    s = LinkAuth("slave", LinkKeys(key, s_name), link)
    Net().step([m], [s])
    return m, s


def refused(a):
    return {k: v for k, v in a.refused.items() if v}


def test_pairing_binds_names_and_one_session():
    m, s = paired()
    assert m.confirmed and s.confirmed
    assert m.peer == "S" and s.peer == "M" and m.session.id == s.session.id
    assert refused(m) == refused(s) == {}
    got = s.open(m.seal(cmd(1)), 0.0)
    assert got.seq == 1 and m.open(s.seal(fb(1)), 0.0).seq == 1


def test_each_pairing_has_its_own_session_and_keys():
    (m1, _), (m2, s2) = paired(), paired()
    assert m1.session.id != m2.session.id
    assert s2.open(m1.seal(cmd(1)), 0.0) is None
    assert refused(s2) == {"other_session": 1}


def test_forged_frame_is_refused_and_counted():
    m, s = paired()
    forged = wire.encode(cmd(5, 0.5), wire.Mac(random_secret()), m.session.id, 1)
    assert s.open(forged, 0.0) is None and refused(s) == {"bad_mac": 1}
    # a frame of the right session tagged under the pairing key, or under the other direction's key
    sess = m.session
    for mac in (s.pairing.mac, sess.fb, wire.PLAIN):
        assert s.open(wire.encode(cmd(6), mac, sess.id, 2), 0.0) is None
    assert refused(s) == {"bad_mac": 4}
    assert s.open(m.seal(cmd(7)), 0.0).seq == 7  # the real master still gets through


def test_replays_are_stale_or_duplicate_and_not_handed_on():
    m, s = paired()
    frames = [m.seal(cmd(k)) for k in range(1, 6)]
    assert [s.open(f, 0.0).seq for f in frames] == [1, 2, 3, 4, 5]
    assert s.open(frames[-1], 0.0) is None and s.open(frames[0], 0.0) is None
    assert refused(s) == {"duplicate": 1, "stale": 1}


def test_far_future_counter_is_refused():
    m, s = paired()
    s.window = 100
    assert s.open(m.seal(cmd(1)), 0.0) is not None
    m._count += 100  # the next frame is 101 ahead of the last one taken
    assert s.open(m.seal(cmd(2)), 0.0) is None and refused(s) == {"far_future": 1}
    m._count -= 2  # exactly 100 ahead: the window's edge, taken; the 99 between counted missed
    assert s.open(m.seal(cmd(3)), 0.0).seq == 3 and s.missed == 99


def test_authentic_but_invalid_values_are_refused():
    m, s = paired()
    sess = m.session
    kind, body = wire.pack_message(cmd(1))
    bad = bytearray(body)
    bad[0:8] = np.float64(np.inf).tobytes()
    frame = wire.seal(kind, sess.id, m._count + 1, 1, bytes(bad), sess.cmd)
    assert s.open(frame, 0.0) is None and refused(s) == {"invalid": 1}


def test_frames_before_pairing_and_wrong_direction():
    m = LinkAuth("master", LinkKeys(KEY, "M"), "t")
    s = LinkAuth("slave", LinkKeys(KEY, "S"), "t")
    assert m.seal(cmd(1)) is None and m.unsent == 1
    sess = derive(KEY, "t", bytes(32), bytes(32), "M", "S")
    assert s.open(wire.encode(cmd(1), sess.cmd, sess.id, 1), 0.0) is None
    assert m.open(wire.encode(fb(1), sess.fb, sess.id, 1), 0.0) is None
    assert refused(s) == refused(m) == {"unpaired": 1}
    m, s = paired()
    s_frame = s.seal(fb(1))
    assert s.open(s_frame, 0.0) is None and refused(s) == {"malformed": 1}  # reflected back
    assert s.open(b"garbage", 0.0) is None and refused(s) == {"malformed": 2}


def test_handshake_needs_the_pairing_key_and_the_link_name():
    for key, link in ((random_secret(), "t"), (KEY, "other")):
        m = LinkAuth("master", LinkKeys(key, "M"), link)
        s = LinkAuth("slave", LinkKeys(KEY, "S"), "t")
        Net().step([m], [s])
        assert not m.confirmed and s.peer is None
        assert set(refused(s)) == {"bad_mac"} and s.refused["bad_mac"] >= 3


def test_a_replayed_hello_does_not_block_the_real_master():
    old = LinkAuth("master", LinkKeys(KEY, "M"), "t")
    hello = old.handshake_due(0.0)
    s = LinkAuth("slave", LinkKeys(KEY, "S"), "t")
    for _ in range(10):
        s.open(hello, 0.0)  # replayed: offers a session nobody confirms
    m = LinkAuth("master", LinkKeys(KEY, "M"), "t")
    Net().step([m], [s])
    assert m.confirmed and s.peer == "M" and s.session.id == m.session.id


def test_second_master_is_refused_and_told_in_one_line():
    m1, s = paired(m_name="first")
    m2 = LinkAuth("master", LinkKeys(KEY, "second"), "t")
    Net().step([m1, m2], [s])
    assert m1.confirmed and s.peer == "first"
    assert not m2.confirmed and m2.session is None
    assert m2.refusal is not None and "\n" not in m2.refusal
    assert "'second'" in m2.refusal and "'first'" in m2.refusal and "'S'" in m2.refusal
    assert s.refused["second_master"] >= 1
    assert m2.handshake_due(1e9) is None  # refused: says nothing more


def test_two_masters_at_once_one_wins_the_other_is_refused():
    m1 = LinkAuth("master", LinkKeys(KEY, "a"), "t")
    m2 = LinkAuth("master", LinkKeys(KEY, "b"), "t")
    s = LinkAuth("slave", LinkKeys(KEY, "S"), "t")
    Net().step([m1, m2], [s], rounds=10)
    winner, loser = (m1, m2) if s.peer == "a" else (m2, m1)
    assert winner.confirmed and loser.refusal is not None and not loser.confirmed
    assert s.open(loser.seal(cmd(1)) or b"", 0.0) is None  # nothing of the loser is taken


def test_window_must_be_positive():
    with pytest.raises(ValueError):
        LinkAuth("slave", LinkKeys(KEY, "S"), "t", window=0)
