"""The two-process run's timing pieces: the pacing (sleep then spin, or spin all the way), the
slave's wait for the master's next command, pinning each side to a core of its own, and the link's
``last_receive_s`` never later than the frame's arrival."""

import json
import math
import os
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from teleop.app import netrun
from teleop.app.session import _pace
from teleop.link import ToolCommand


def test_pace_returns_at_the_deadline_sleeping_or_spinning():
    for spin_s in (5e-5, math.inf):
        deadline = time.perf_counter() + 2e-3
        assert _pace(deadline, spin_s) == 0
        # never before it; after it by scheduling only (a loaded CI core may be taken for ms; a
        # pacing bug that sleeps a period or more too long still shows)
        assert 0.0 <= time.perf_counter() - deadline < 0.25
    assert _pace(time.perf_counter() - 1e-3) == 1  # already late: counted, no wait


class _Mailbox:
    """A link whose next command shows up at a given wall-clock time."""

    def __init__(self, at_s):
        self.at_s = at_s

    def peek(self):
        return object() if time.perf_counter() >= self.at_s else None


@pytest.mark.parametrize("poll_s", [0.0, 1e-4])
def test_the_slave_ticks_when_the_command_comes_not_at_its_timeout(poll_s):
    t0 = time.perf_counter()
    seen, waiting = netrun._await_command(_Mailbox(t0 + 2e-3), t0 + 2.0, poll_s)
    waited = time.perf_counter() - t0
    assert 2e-3 <= waited < 0.5  # returned on the command, far before the 2 s timeout (slack: a loaded core)
    assert seen is not None and t0 + 2e-3 <= seen <= time.perf_counter()  # when it was seen
    assert not waiting  # it came while the slave waited
    seen, waiting = netrun._await_command(_Mailbox(t0), t0 + 2.0, poll_s)
    assert waiting and seen is not None  # already there: no wait


def test_the_slave_stops_waiting_at_its_timeout_when_no_command_comes():
    t0 = time.perf_counter()
    assert netrun._await_command(_Mailbox(math.inf), t0 + 3e-3, 1e-4) == (None, False)
    assert 3e-3 <= time.perf_counter() - t0 < 0.5  # slack: a loaded core


def test_the_slave_keeps_the_master_s_phase():
    """A command that came while the slave waited sets its next slot; one already waiting (the slave
    behind) or none by the timeout leaves the slot a period on, so a slow slave or a silent link
    still shows as late."""
    dt = 5e-4
    assert netrun._next_slot(1.0, dt, waiting=False, seen=1.0007) == 1.0007  # a command 0.7 ms on: no timeout next
    assert netrun._next_slot(1.0, dt, waiting=True, seen=1.002) == 1.0 + dt   # behind: measured from its own slot
    assert netrun._next_slot(1.0, dt, waiting=False, seen=None) == 1.0 + dt   # nothing came by the timeout


def _slave_on(arrivals: list[float], dt: float) -> tuple[int, int]:
    """The slave's loop on a simulated clock (its slots, timeouts and newest-command box; ticks
    taking no time), its first command seen at 0: (its ticks without a command plus the commands
    it skipped, its ticks started more than a period after their slot)."""
    arrivals_a = np.asarray(arrivals)
    slot = t = 0.0
    taken = misses = late = 0
    for _ in range(len(arrivals) - 1):
        timeout = slot + 2 * dt
        nxt = arrivals_a[taken] if taken < len(arrivals) else np.inf
        waiting = nxt <= t
        seen = t if waiting else (nxt if nxt < timeout else None)
        t = timeout if seen is None else seen
        arrived = int(np.searchsorted(arrivals_a, t, side="right"))
        misses += arrived - taken - 1 if arrived > taken else 1  # skipped, or a tick without one
        taken = max(taken, arrived)
        slot = netrun._next_slot(slot, dt, waiting, seen)
        late += t - slot > dt
    return misses, late


def test_a_slave_started_early_on_the_commands_takes_each_as_it_comes():
    """Commands every period, each 0.5 +- 0.2 ms after the slot the slave's start would give it
    (its first command seen early, the others later by the link's latency, a period at 2 kHz):
    in the master's phase the slave misses at most the first, then neither times out nor skips,
    and no tick counts as late; against slots anchored on its start, a quarter would have."""
    dt = 5e-4
    jitter = np.random.default_rng(7).uniform(-2e-4, 2e-4, 2000)
    arrivals = [k * dt + 5e-4 + j for k, j in enumerate(jitter, start=1)]
    misses, late = _slave_on(arrivals, dt)
    assert misses <= 1 and late == 0
    assert sum(a - k * dt > dt for k, a in enumerate(arrivals, start=1)) > len(arrivals) // 4


def test_claim_core_pins_master_and_slave_to_different_cores(monkeypatch):
    pinned = {}
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3, 1, 5})
    monkeypatch.setattr(os, "sched_setaffinity", lambda pid, cores: pinned.setdefault("cores", set(cores)))
    assert netrun.claim_core("master") == 1 and pinned["cores"] == {1}
    pinned.clear()
    assert netrun.claim_core("slave") == 3 and pinned["cores"] == {3}
    pinned.clear()
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    assert netrun.claim_core("slave") is None and not pinned  # one core: nothing to share out


PIN_CHILD = """
import json, os, threading
from teleop.app.netrun import claim_core
ready, done = threading.Event(), threading.Event()
def session_thread():  # stands for Zenoh's threads, started with the session before the pin
    ready.set()
    done.wait(10)
t = threading.Thread(target=session_thread)
t.start()
ready.wait(10)
before = sorted(os.sched_getaffinity(0))
core = claim_core("slave")
print(json.dumps([before, core, sorted(os.sched_getaffinity(0)), sorted(os.sched_getaffinity(t.native_id))]))
done.set()
"""


def test_claim_core_pins_the_loop_s_thread_only():
    """The link's threads, started before the pin, keep every core the process had; the loop's
    thread alone is pinned (a real process: the affinity is the kernel's)."""
    out = subprocess.run([sys.executable, "-c", PIN_CHILD], capture_output=True, text=True, timeout=60, check=True)
    before, core, loop, other = json.loads(out.stdout)
    if len(before) < 2:
        assert core is None and loop == other == before
        return
    assert loop == [core] and other == before


def test_last_receive_s_is_never_later_than_the_frame_s_arrival():
    pytest.importorskip("zenoh")
    from teleop.link.zenoh_link import ZenohLink

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        ep = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    cmd = ToolCommand(1, 0.0, np.zeros(3), np.eye(3), np.zeros(3), np.zeros(3))
    from teleop.link.keys import random_secret

    key = random_secret()
    with ZenohLink("slave", session="lr", listen=ep, keys=key) as slave, \
            ZenohLink("master", session="lr", connect=ep, keys=key) as master:
        end = time.monotonic() + 20.0
        while slave.last_receive_s is None and time.monotonic() < end:  # until the route is up
            master.send_command(cmd)
            time.sleep(0.01)
        assert slave.last_receive_s is not None
        t_empty = time.monotonic()
        slave.receive_command()  # a poll that finds nothing new
        time.sleep(0.05)
        master.send_command(ToolCommand(2, 0.0, np.zeros(3), np.eye(3), np.zeros(3), np.zeros(3)))
        end = time.monotonic() + 20.0
        while slave.peek() is None and time.monotonic() < end:
            time.sleep(0.001)
        t_found = time.monotonic()
        # the time of the poll before the one that found it: no earlier than the last empty poll,
        # no later than the frame's arrival (so before it was found)
        assert t_empty <= slave.last_receive_s <= t_found
        assert slave.receive_command().seq == 2


LOCK = """
import os
from teleop.app.netrun import locked_memory

def vmlck_kb():
    return int(next(l for l in open("/proc/self/status") if l.startswith("VmLck:")).split()[1])

with locked_memory(False) as off:
    assert off is False and vmlck_kb() == 0
with locked_memory() as on:
    inside = vmlck_kb()
after = vmlck_kb()
print(on, inside, after, os.geteuid())
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="mlockall and /proc/self/status are Linux's")
def test_locked_memory_keeps_every_page_in_while_it_holds_and_lets_go_after():
    out = subprocess.run([sys.executable, "-c", LOCK], capture_output=True, text=True, timeout=120, check=True)
    on, inside, after, euid = out.stdout.split()
    if euid == "0":  # root may lock it all (CI runs as root)
        assert on == "True" and int(inside) > 100_000 and int(after) == 0  # the process's whole map, then nothing
    else:  # a user under a small memlock limit: nothing locked, nothing failed
        assert on in ("True", "False") and int(after) == 0
