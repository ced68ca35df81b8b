"""ZenohLink's trust rules end to end on an in-process stand-in for Zenoh (no sockets, fast): a
flood through the ring counted and bounded per poll, replays never feed the heartbeat, a second
master's pair() raises with one line, the slave names who drives it."""

import time
from collections import deque
from types import SimpleNamespace

import numpy as np
import pytest

zenoh = pytest.importorskip("zenoh")

from teleop.link import wire
from teleop.link.keys import LinkKeys, random_secret
from teleop.link.zenoh_link import RING, PairingRefused, ZenohLink, process_name
from teleop.tick.messages import ContactFeedback, ToolCommand

KEY = random_secret()


class Bus:
    """Key expression -> the rings subscribed to it (each a Zenoh RingChannel's behaviour:
    the newest RING samples kept)."""

    def __init__(self):
        self.rings: dict[str, list] = {}
        self.log: dict[str, list] = {}

    def put(self, key, data):
        self.log.setdefault(key, []).append(bytes(data))
        for ring in self.rings.get(key, []):
            ring.append(SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda d=bytes(data): d)))


class Ring:
    def __init__(self, q):
        self.q = q

    def try_recv(self):
        return self.q.popleft() if self.q else None

    def undeclare(self):
        self.q.clear()


class Session:
    def __init__(self, bus):
        self.bus = bus

    def declare_publisher(self, key, **kw):
        return SimpleNamespace(put=lambda data: self.bus.put(key, data), undeclare=lambda: None)

    def declare_subscriber(self, key, handler):
        q = deque(maxlen=RING)
        self.bus.rings.setdefault(key, []).append(q)
        return Ring(q)

    def close(self):
        pass


@pytest.fixture
def bus(monkeypatch):
    b = Bus()
    monkeypatch.setattr(zenoh, "open", lambda config: Session(b))
    return b


def cmd(k):
    return ToolCommand(k, k * 1e-3, [0.01 * k, 0, 0], np.eye(3), np.zeros(3), np.zeros(3))


def fb(k):
    return ContactFeedback(k, k * 1e-3, np.zeros(6), "ok", k)


def pair_up(name="M"):
    slave = ZenohLink("slave", session="t", keys=LinkKeys(KEY, "S"))
    master = ZenohLink("master", session="t", keys=LinkKeys(KEY, name))
    for _ in range(50):
        if master.paired and slave.paired:
            break
        master.poll(), slave.poll()
        time.sleep(0.005)
    return master, slave


def test_pair_and_exchange(bus):
    master, slave = pair_up()
    me = process_name("")  # "@host:pid": each side pairs as name@host:pid
    assert master.pair(1.0) == "S" + me and slave.pair(1.0) == "M" + me and slave.peer == "M" + me
    master.send_command(cmd(1))
    slave.send_feedback(fb(1))
    assert slave.receive_command().seq == 1 and master.receive_feedback().seq == 1
    s = slave.stats()
    assert s["bad_frames"] == 0 and s["peer"] == "M" + me and s["session"] == f"{master.session_id:016x}"


def test_flood_of_garbage_is_counted_and_bounded_per_poll(bus):
    master, slave = pair_up()
    for i in range(10_000):
        bus.put("teleop/t/cmd", i.to_bytes(4, "little") * 70)
    polls = 0
    while slave.poll() >= 0 and polls < 10_000:
        polls += 1
        if not bus.rings["teleop/t/cmd"][0]:
            break
    s = slave.stats()
    # the ring held the newest RING: one poll took them all (at most RING a call), the rest the
    # ring dropped, which the poll saw as a full ring (one flood)
    assert polls == 1 and s["refused"]["malformed"] == RING and s["flood"] == 1
    assert slave.receive_command() is None
    for k in range(3 * RING):  # a flood while the real master sends: at most RING frames a poll
        bus.put("teleop/t/cmd", b"x" * 300)
        if k % 2 == 0:
            master.send_command(cmd(10 + k))
    assert slave.poll() <= RING and slave.stats()["flood"] == 2
    got = slave.receive_command()
    assert got is not None and got.seq == 10 + 3 * RING - 2  # the newest real one


def test_replayed_frames_never_feed_the_heartbeat(bus):
    master, slave = pair_up()
    for k in range(1, 20):
        master.send_command(cmd(k))
    assert slave.receive_command().seq == 19
    heard = slave.last_receive_s
    frames = list(bus.log["teleop/t/cmd"])
    master.close()  # the master is gone; an attacker replays what it recorded
    time.sleep(0.03)
    for f in frames:
        bus.put("teleop/t/cmd", f)
    assert slave.receive_command() is None and slave.last_receive_s == heard
    assert not slave.alive(timeout_s=0.02)
    r = slave.stats()["refused"]
    assert r["stale"] + r["duplicate"] == 19 + 1  # 19 commands + the CONFIRM; HELLOs are late copies


def test_a_second_master_is_refused_and_told(bus):
    master, slave = pair_up()
    other = ZenohLink("master", session="t", keys=LinkKeys(KEY, "intruder"))
    with pytest.raises(PairingRefused) as e:
        for _ in range(10):
            slave.poll()
            other.pair(0.02)
    assert "\n" not in str(e.value) and "'intruder@" in str(e.value) and "'M@" in str(e.value)
    assert slave.peer.startswith("M@") and slave.stats()["refused"]["second_master"] >= 1
    other.send_command(cmd(99))
    master.send_command(cmd(1))
    assert slave.receive_command().seq == 1 and other.stats()["unsent"] == 1


def test_an_unauthenticated_publisher_is_not_followed(bus):
    master, slave = pair_up()
    for k in range(1, 200):  # the project's own wire format, without the key
        bus.put("teleop/t/cmd", wire.encode(cmd(k + 1000), session=master.session_id, counter=k))
        bus.put("teleop/t/fb", wire.encode(fb(k + 1000), session=master.session_id, counter=k))
        if k % 20 == 0:
            assert slave.receive_command() is None and master.receive_feedback() is None
    assert slave.stats()["refused"]["bad_mac"] == master.stats()["refused"]["bad_mac"] == 199
    assert slave.last_receive_s is None and master.last_receive_s is None
