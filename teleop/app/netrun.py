"""Master and slave as two processes over Eclipse Zenoh, on the wall clock at the scene's rate.

    teleop slave SCENE --listen tcp/127.0.0.1:7447 [--json OUT]
    teleop master SCENE --connect tcp/127.0.0.1:7447 [--json OUT]
    teleop run SCENE --link zenoh [--out DIR] [--json OUT]   # both on a free loopback port, one summary

Each process builds its side with :mod:`teleop.app.assembly` and ticks it
(:meth:`MasterSide.tick`, :meth:`SlaveSide.tick`): the same objects, hooks, metrics and verdict
as the in-process run; only the link (:class:`~teleop.link.zenoh_link.ZenohLink`) and the clock
differ. The passivity guard of the scene's [link] table runs at both ends.

Start-up: each side first runs a twin of itself for a few ticks on a link to nowhere (the numba
kernels' first loads, not the first ticks). The master sends hello commands (``t_s = -1``, clutch
out) until a reply comes; the slave answers every hello. The master then ticks ``duration_s /
dt_s`` times on the wall clock; the slave ticks when the master's next command arrives (or one
period past the slot it was due in if none comes, :func:`_next_slot`; when behind, back to back), until it has
followed the master's last command (or, if the master is gone, for as long again plus
``GRACE_S``). The master feels the newest reply at the start of its tick, as in one process
(``reply_lag_ticks`` "0": in step with one process). Each side is pinned to a core of its own and
waits by spinning, its memory locked where allowed (:func:`claim_core`, :func:`locked_memory`;
``--no-pin``: neither, it sleeps instead). Before either side opens its link it loads every
compiled kernel it will call (:func:`warm_up`), so that none loads mid-run.

Heartbeat and safe states are the sides' own (:mod:`teleop.tick.heartbeat`), on the wall clock
here. A side that never hears its peer ends with status ``link_lost`` (exit 1), never a traceback.
"""

from __future__ import annotations

import ctypes
import math
import os
import socket
import sys
import time
from contextlib import contextmanager, nullcontext
from dataclasses import asdict, replace
from typing import Any

import numpy as np

from teleop.app.assembly import build_master, build_slave, exempt_metrics
from teleop.app.metrics import link_metrics
from teleop.app.session import (
    _YIELD,
    PACE_SPIN_S,
    RunResult,
    Session,
    SideRun,
    _fine_timer_slack,
    _pace,
    _stop_requests,
    tick_count,
    tick_stats,
)
from teleop.link import wire
from teleop.link.schedule import ScheduleTap, hello_command, hello_reply
from teleop.scenario.build import build_registration
from teleop.scenario.schema import Scene
from teleop.tick.messages import ContactFeedback, ToolCommand
from teleop.util.errors import TeleopError
from teleop.util.numba_cache import load_cached_kernels

GRACE_S = 2.0          # the slave's run beyond the scene's duration when the master is gone (s)
CONNECT_TIMEOUT_S = 120.0  # the first message must come within this (s): a loaded machine is slow
CONNECT_TRY_S = 5.0    # one connection attempt (s): a TLS port that answers but refuses ends it at once
WARMUP_TICKS = 5       # ticks a side's twin runs before the clock starts
NETWORK_LAG_S = 0.05   # the most a loopback or LAN round trip is looked for when aligning felt and true force
_Z3 = np.zeros(3)


POLL_S = 1e-4  # the slave's poll period while it waits for the master's next command, unpinned (s)


def claim_core(role: str) -> int | None:
    """Pin the calling thread, the loop's, to one core of those it may run on, the master to the
    first, the slave to the second, so the two halves never share one (no root needed). Called
    once the link is open: Zenoh's threads, started with the session, keep every core and run
    where one yields first, instead of preempting their own loop mid-tick (measured at 2 kHz,
    four runs each alternating: master on time 94.6-99.4 % against 89.2-98.1 % with them pinned
    beside it, the slave 85.8-99.2 % against 77.7-96.2 %). Returns the core, or None (nothing
    done) with fewer than two. A pinned half waits by spinning, not sleeping: a sleeping half's
    core goes to other jobs, whose caches it then ticks in (measured on this 2-core machine under
    load: each tick's CPU time doubled and the halves fell to 0.4-0.7 of real time; pinned and
    spinning, both held it)."""
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) < 2:
        return None
    core = cores[0 if role == "master" else 1]
    os.sched_setaffinity(0, {core})
    return core


MCL_CURRENT, MCL_FUTURE = 1, 2  # mlockall's flags (Linux, <sys/mman.h>)


@contextmanager
def locked_memory(on: bool = True):
    """Within: every page of the process kept in memory (``mlockall``, current and future pages),
    as a real-time loop keeps its own; yields whether they are. A page the kernel pages out is read
    back when next touched, a major fault of milliseconds in the middle of a tick, and a library's
    page that both sides share stalls both at once (this machine's kernel runs DAMON's pageout
    scheme on cold pages; a slave saw one major fault in a 2 kHz run of three, none with its memory
    locked). Needs root, CAP_IPC_LOCK or a memlock limit above the process's size; without, or off
    Linux, nothing is locked and the run goes on. Costs 110-150 ms as it locks, and the side's
    resident memory grows to all it has mapped (some 0.9 GB here); unlocked on exit."""
    libc = None
    if on and sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
                libc = None
        except (OSError, AttributeError):
            libc = None
    try:
        yield libc is not None
    finally:
        if libc is not None:
            libc.munlockall()


def _await_command(link, timeout: float, poll_s: float = POLL_S) -> tuple[float | None, bool]:
    """Slave: wait until a command newer than the last one taken has come, or the wall clock
    (perf_counter, s) reaches ``timeout``, polling every ``poll_s`` (0: without sleeping). Returns
    when the command was seen (perf_counter, s; None at the timeout) and whether it was waiting
    already. The slave ticks when the master's command arrives, so its reply is back before the
    master's next tick (one process's timing); the timeout keeps it ticking (and its heartbeat
    checked) when no command comes."""
    waiting = True
    while link.peek() is None:
        waiting = False
        left = timeout - time.perf_counter()
        if left <= 0:
            return None, False
        if poll_s > 0:
            time.sleep(min(left, poll_s))
        elif _YIELD:
            os.sched_yield()
    return time.perf_counter(), waiting


def _next_slot(slot: float, dt_s: float, waiting: bool, seen: float | None) -> float:
    """Slave: when its next tick is due (perf_counter, s), after a tick due at ``slot``. The slave
    keeps the master's phase: a command that came while it waited (``seen``, not ``waiting``)
    sets the slot; one that was already waiting, or none by the timeout, leaves the slot a period
    on (the slave is behind, or the command is late or lost). Anchored on its own start alone (the
    moment it saw the first command), the slave counted the link's latency beyond that first
    one's as its own lateness and gave up on commands by a clock the master does not keep: at
    2 kHz over Zenoh, five runs, 106-3140 late ticks of 14000 and 35-519 ticks without a command
    (the slave idle between ticks); in the master's phase, 44-141 and 23-61."""
    return seen if seen is not None and not waiting else slot + dt_s


def _open_link(role: str, session: str, listen, connect, timeout_s: float, config_json5=None, *, keys,
               allow_plaintext_network: bool = False, stop=()):
    """The side's authenticated link, paired with its peer: a :class:`ZenohLink` opened (retried
    while the other side is not up yet) and paired (:meth:`ZenohLink.pair`). Raises
    :class:`~teleop.link.zenoh_link.PairingRefused` (the peer is paired with another: one line to
    say), :class:`~teleop.link.zenoh_link.ConnectRefused` (TLS refused) or LinkError past
    ``timeout_s``."""
    from teleop.link.zenoh_link import ConnectRefused, LinkError, ZenohLink

    other = "slave" if role == "master" else "master"
    print(f"{role}: waiting for the {other} {'on' if listen else 'at'} {listen or connect} (up to {timeout_s:g} s)",
          flush=True)
    end = time.monotonic() + timeout_s
    while True:
        try:
            link = ZenohLink(role, session=session, listen=listen, connect=connect, config_json5=config_json5,
                             keys=keys, allow_plaintext_network=allow_plaintext_network,
                             connect_timeout_s=CONNECT_TRY_S if connect else None)
            break
        except ConnectRefused:
            raise
        except LinkError:
            if time.monotonic() > end or stop:
                raise
            time.sleep(0.2)
    try:
        link.pair(max(1.0, end - time.monotonic()))
    except BaseException:
        link.close()
        raise
    print(f"{role}: paired with {link.peer}", flush=True)
    return link


def _linked(role: str, stop, session, listen, connect, timeout_s, config_json5, keys, allow_plaintext_network):
    """The side's paired link, or, when there is none to run on, the run of no ticks that says why:
    ``link_refused`` (the peer is paired with another, or TLS refused this side: one line printed),
    ``link_lost`` (no peer within ``timeout_s``), ``interrupted``."""
    from teleop.link.zenoh_link import ConnectRefused, LinkError, PairingRefused

    try:
        return _open_link(role, session, listen, connect, timeout_s, config_json5, keys=keys,
                          allow_plaintext_network=allow_plaintext_network, stop=stop)
    except (PairingRefused, ConnectRefused) as e:
        status, why = "link_refused", str(e).splitlines()[0]
    except LinkError as e:
        status, why = ("interrupted" if stop else "link_lost"), str(e).splitlines()[0]
    print(f"{role}: {why}", flush=True)
    runner = {"tick_us": tick_stats(np.zeros(0)), "late_ticks": 0, "link": {f"zenoh_{role}": {"not_linked": why}},
              "clock": {}}
    return SideRun(status, 0, 0.0, None, None, False, runner, {})


def _lateness(heart, slot: float) -> float:
    """How late a tick due at ``slot`` (perf_counter, s) starts on the wall clock (s), told to the
    side's heartbeat (a detection's latency is read against it)."""
    heart.tick_late_s = max(0.0, time.perf_counter() - slot)
    return heart.tick_late_s


class _Teller:
    """Says when a side loses its peer and when the peer is back (the first EVENTS_SAID events)."""

    EVENTS_SAID = 10

    def __init__(self, role: str, heart, dt_s: float) -> None:
        self.role, self.heart, self.dt = role, heart, dt_s
        self.other = "slave" if role == "master" else "master"
        self.lost, self.said, self.since = False, 0, 0.0

    def tick(self, i: int) -> None:
        h = self.heart
        if h.lost == self.lost:
            return
        self.lost = h.lost
        self.said += 1
        if self.said > self.EVENTS_SAID:
            return
        t = i * self.dt
        if h.lost:
            self.since = t
            print(f"{self.role}: lost the {self.other} at t = {t:.3f} s: nothing heard for "
                  f"{1e3 * h.latency_s[-1]:.0f} ms (heartbeat {1e3 * h.timeout_s:.0f} ms); holding", flush=True)
        else:
            print(f"{self.role}: the {self.other} is back at t = {t:.3f} s after {t - self.since:.3f} s; resuming",
                  flush=True)


def _hello(side, link, timeout_s: float, stop=()) -> bool:
    """Master: hello commands until the slave answers (True), or ``timeout_s`` passes or ``stop``
    is set (False)."""
    end = time.monotonic() + timeout_s
    s = side.state
    while link.last_receive_s is None:
        if time.monotonic() > end or stop:
            return False
        link.send_command(hello_command(s.p, s.R))
        time.sleep(0.005)
    return True


def _answer_hellos(link, timeout_s: float, stop=()) -> bool:
    """Slave: answer hello commands until the first real one is waiting (True; left for the first
    tick to take), or ``timeout_s`` passes or ``stop`` is set (False)."""
    end = time.monotonic() + timeout_s
    while True:
        cmd = link.peek()
        if cmd is not None and cmd.t_s >= 0:
            return True
        if time.monotonic() > end or stop:
            return False
        if cmd is not None:
            link.receive_command(0.0)  # a hello, taken
        if link.last_receive_s is not None:
            link.send_feedback(hello_reply())
        time.sleep(0.001)


class _Bench:
    """A link that goes nowhere, for a side's warm-up twin: sends nothing; to a slave it hands a
    command holding ``pose`` (master frame) with the clutch engaged, to a master (``contact``) a
    reply in light contact, with a damping and a plane, two ticks in three (nothing the third), so
    that the feedback path's kernels and those of a tick without news load before the clock starts
    too (the first real reply loaded them in the master's first ticks: 25 ms late, and the slave's
    20 ms heartbeat tripped)."""

    def __init__(self, pose=None, contact: bool = False):
        self.pose, self.k, self.contact, self.t = pose, 0, contact, None

    def clock(self, t_s: float) -> float:
        self.t = t_s
        return t_s

    def last_heard_s(self, side: str) -> float | None:
        return self.t if self.contact else None

    def send_command(self, msg) -> None:
        pass

    send_feedback = send_command

    def _silent(self) -> bool:
        """Every third tick nothing comes: a side's tick without news loads its kernels too."""
        self.k += 1
        return self.k % 3 == 0

    def receive_feedback(self, t_s: float) -> ContactFeedback | None:
        if not self.contact or self._silent():
            return None
        D = np.diag([5.0, 5.0, 5.0, 0.0, 0.0, 0.0])
        return _delivered(ContactFeedback(self.k, t_s, [0.0, 0.0, 0.01, 0.0, 0.0, 0.0], "ok", self.k, np.zeros(6),
                                          D, np.zeros(6), [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1e3, 0.5]))

    def receive_command(self, t_s: float) -> ToolCommand | None:
        if self._silent():
            return None
        return _delivered(ToolCommand(self.k, t_s, *self.pose, _Z3, _Z3, True))


def _delivered(msg):
    """``msg`` as the link hands it over, through the wire's encoding and back: the twin's kernels
    then meet the argument types the run's messages bring (a compiled kernel loads once per type
    signature; tests/integration/test_warm_up.py)."""
    return wire.decode(wire.encode(msg))


def warm_up(scene: Scene, role: str, cached: bool = True) -> None:
    """Run a twin of the ``role`` side for a few ticks on a link to nowhere, so that the first
    calls (numba kernels loaded from the cache, 60-170 ms each here) happen before the clock
    starts and not in the first ticks, where they tripped the 20 ms heartbeat; then (``cached``)
    load every other signature the cache holds for the kernels now imported, such as those the
    twin never reaches (a kernel called only in contact; 160 signatures in 0.8 s here)."""
    if role == "master":
        side = build_master(scene, WARMUP_TICKS, np.random.default_rng(scene.seed), networked=True).side
        with side.master:
            bench = _Bench(contact=scene.slave is not None)
            for i in range(WARMUP_TICKS):
                side.tick(i, i * scene.dt_s, bench)
    else:
        sb = build_slave(scene, WARMUP_TICKS, networked=True)
        bench = _Bench(_start_pose(scene))
        for i in range(WARMUP_TICKS):
            sb.side.tick(i, i * scene.dt_s, bench)
    if cached:
        load_cached_kernels()


def _start_pose(scene: Scene):
    from teleop.scenario.build import build_tool

    return build_tool(scene).pose()


@contextmanager
def _recording(path, scene: Scene, role: str):
    """This side's MCAP writer at ``path`` (None: no record), paced for the wall clock (its file
    written after the run, off the tick's core), closed however the run ends."""
    if path is None:
        yield None
        return
    from teleop.app.record.runinfo import open_run_record

    writer = open_run_record(path, scene, runner="two_process", realtime=True, side=role)
    try:
        yield writer
    finally:
        writer.close()


def _on_record(link, side, writer, role: str):
    """The link the side ticks on: with a record, a :class:`~teleop.link.schedule.ScheduleTap` in
    front of it whose notes (what each tick was handed, the clock and heartbeat it read, the
    messages' stamps) go on ``/<role>/link``, so that ``teleop replay --check`` can deliver the
    same messages at the same ticks; without, the link itself."""
    if writer is None:
        return link
    from teleop.app.record import LinkRecorderMcap

    tap = ScheduleTap(link, role)
    side.add_hooks(LinkRecorderMcap(writer, tap, f"/{role}"))
    return tap


class PeerRate:
    """Stands between a side and its link (``link``: the side's port, a
    :class:`~teleop.link.zenoh_link.ZenohLink` or the record's tap in front of it), passing every
    call through, and checks once that the peer ticks at this side's period ``dt_s`` (s): each side
    numbers what it sends by its tick, message ``seq`` = i + 1 stamped ``t_s`` = i dt (a command
    by the master's tick, a reply by the slave's), so the first message of the run numbered 2 or
    more tells the peer's period, t_s / (seq - 1). Two sides given different periods (``teleop
    master --dt 0.0005`` against a slave at the scene's 1 ms) would each run their own number of
    ticks on their own clock: the slave followed the master's half-way command as its last and
    said "ok" while the master lost it. ``refused`` is None until a different period is found, then
    the one line that says so; the runner ends the side "link_refused" on it."""

    REL_TOL = 1e-9  # the periods agree to round-off: the stamp is i * dt computed the same way

    def __init__(self, link: Any, role: str, dt_s: float) -> None:
        self.link, self.role, self.dt = link, role, float(dt_s)
        self.checked = False
        self.refused: str | None = None

    def _check(self, msg: ToolCommand | ContactFeedback | None) -> None:
        if msg is None or msg.t_s < 0 or msg.seq < 2:  # a hello, or the first tick's (stamped 0 at any rate)
            return
        self.checked = True
        peer_dt = msg.t_s / (msg.seq - 1)
        if not math.isclose(peer_dt, self.dt, rel_tol=self.REL_TOL):
            other = "slave" if self.role == "master" else "master"
            self.refused = (f"the {other} ticks every {1e3 * peer_dt:g} ms, this {self.role} every "
                            f"{1e3 * self.dt:g} ms:"
                            f" give both sides the same period (the scene's dt_s, or the same --dt)")

    def receive_feedback(self, t_s: float) -> ContactFeedback | None:
        msg = self.link.receive_feedback(t_s)
        if not self.checked:
            self._check(msg)
        return msg

    def receive_command(self, t_s: float) -> ToolCommand | None:
        msg = self.link.receive_command(t_s)
        if not self.checked:
            self._check(msg)
        return msg

    def send_command(self, msg: ToolCommand) -> None:
        self.link.send_command(msg)

    def send_feedback(self, msg: ContactFeedback) -> None:
        self.link.send_feedback(msg)

    def clock(self, t_s: float) -> float:
        return self.link.clock(t_s)

    def last_heard_s(self, side: str) -> float | None:
        return self.link.last_heard_s(side)


def _refused(role: str, rate: PeerRate, runner: dict) -> None:
    """Say a side's refusal of its peer's period (one line) and put it in its summary."""
    print(f"{role}: {rate.refused}", flush=True)
    runner["status_reason"] = rate.refused


def _own_stop(stop):
    """The caller's stop flag (set by its own Ctrl-C handler), or one of this side's own."""
    return nullcontext(stop) if stop is not None else _stop_requests()


def run_master(scene: Scene, connect: str | None, listen: str | None = None, session: str = "default",
               timeout_s: float = CONNECT_TIMEOUT_S, config_json5: dict | None = None, pin: bool = True,
               stop=None, *, keys, allow_plaintext_network: bool = False, record=None) -> tuple[SideRun, dict]:
    """The master process: its side ticked on the wall clock over Zenoh. Returns its run and its
    metrics. ``config_json5``: extra Zenoh settings (TLS, see :mod:`teleop.link.zenoh_link`);
    ``pin``: :func:`claim_core`. Ctrl-C or SIGTERM at any point (warm-up, connection, ticks) ends
    it with status "interrupted" and what it ran."""
    with _own_stop(stop) as stop, _recording(record, scene, "master") as writer:
        return _run_master(scene, connect, listen, session, timeout_s, config_json5, pin, stop, keys,
                           allow_plaintext_network, writer)


def _run_master(scene, connect, listen, session, timeout_s, config_json5, pin, stop, keys,
                allow_plaintext_network, writer=None) -> tuple[SideRun, dict]:
    n = tick_count(scene.duration_s, scene.dt_s)
    warm_up(scene, "master")
    mb = build_master(scene, n, np.random.default_rng(scene.seed), networked=True, record=writer)
    side, dt = mb.side, scene.dt_s
    link = _linked("master", stop, session, listen, connect, timeout_s, config_json5, keys, allow_plaintext_network)
    if isinstance(link, SideRun):
        return replace(link, dt_s=dt, master=side.summary()), {}
    core = claim_core("master") if pin else None  # after the session's threads started (claim_core)
    spin_s = math.inf if core is not None else PACE_SPIN_S
    status, late, steps, behind = "ok", 0, 0, 0.0
    ticks = np.zeros(n)
    wall0 = time.perf_counter()
    port = PeerRate(_on_record(link, side, writer, "master"), "master", dt)
    with link, side.master, locked_memory(core is not None) as locked:
        status = side.master.status
        if status == "ok" and not _hello(side, link, timeout_s, stop):
            status = "interrupted" if stop else "link_lost"
            print(f"master: no answer from the slave within {timeout_s:g} s (is 'teleop slave' running on "
                  f"{link.connect}?)" if status == "link_lost" else "master: interrupted", flush=True)
        elif status == "ok":
            print("master: running", flush=True)
        wall0 = time.perf_counter()
        say = _Teller("master", side.heart, dt)
        for i in range(n if status == "ok" else 0):
            if stop:
                status = "interrupted"
                break
            behind = max(behind, _lateness(side.heart, wall0 + i * dt))
            status = side.tick(i, i * dt, port)
            say.tick(i)
            ticks[i], steps = side.tick_ns * 1e-3, i + 1
            if port.refused is not None:
                status = "link_refused"
            if status != "ok":
                break
            late += _pace(wall0 + (i + 1) * dt, spin_s)
        ck = _clock(wall0, steps, dt, behind, core, locked)
        runner = {"tick_us": tick_stats(ticks[:steps]), "late_ticks": late, "link": {"zenoh_master": link.stats()},
                  "clock": {"master": ck}, "wall_s": round(ck["wall_s"], 3),
                  "realtime_factor": round(ck["realtime_factor"], 3)}
        runner.update({k: v for k, v in side.master.stats().items() if k != "master_status"})
        if port.refused is not None:
            _refused("master", port, runner)
    log = mb.log(steps)
    log["tick_us"] = ticks[:steps]
    return SideRun(status, steps, dt, side.summary(), None, mb.recorder.nan, runner, log), mb.result()


def run_slave(scene: Scene, listen: str | None, connect: str | None = None, session: str = "default",
              timeout_s: float = CONNECT_TIMEOUT_S, config_json5: dict | None = None, pin: bool = True,
              stop=None, *, keys, allow_plaintext_network: bool = False, record=None) -> tuple[SideRun, dict]:
    """The slave process: its side ticked as the master's commands come. Returns its run and its
    metrics; ``pin``: :func:`claim_core`. Ctrl-C or SIGTERM at any point ends it with status
    "interrupted" and what it ran."""
    if scene.slave is None:
        raise TeleopError(f"{scene.path}: slave: the scene has no [slave] table: nothing to run on this side")
    with _own_stop(stop) as stop, _recording(record, scene, "slave") as writer:
        return _run_slave(scene, listen, connect, session, timeout_s, config_json5, pin, stop, keys,
                          allow_plaintext_network, writer)


def _run_slave(scene, listen, connect, session, timeout_s, config_json5, pin, stop, keys,
               allow_plaintext_network, writer=None) -> tuple[SideRun, dict]:
    n = tick_count(scene.duration_s, scene.dt_s)
    cap = n + round(GRACE_S / scene.dt_s) + 1
    warm_up(scene, "slave")
    sb = build_slave(scene, cap, networked=True, record=writer)
    side, dt = sb.side, scene.dt_s
    link = _linked("slave", stop, session, listen, connect, timeout_s, config_json5, keys, allow_plaintext_network)
    if isinstance(link, SideRun):
        return replace(link, dt_s=dt, slave={**side.summary(), "followed_last_command": False}), {}
    core = claim_core("slave") if pin else None  # after the session's threads started (claim_core)
    poll_s = 0.0 if core is not None else POLL_S
    status, late, steps, behind = "ok", 0, 0, 0.0
    ticks = np.zeros(cap)
    wall0 = time.perf_counter()
    port = PeerRate(_on_record(link, side, writer, "slave"), "slave", dt)
    with link, locked_memory(core is not None) as locked:
        if not _answer_hellos(link, timeout_s, stop):
            status = "interrupted" if stop else "link_lost"
            print(f"slave: no command from a master within {timeout_s:g} s" if status == "link_lost"
                  else "slave: interrupted", flush=True)
        else:
            print("slave: running", flush=True)
        _fine_timer_slack()
        wall0 = slot = time.perf_counter()
        say = _Teller("slave", side.heart, dt)
        for i in range(cap if status == "ok" else 0):
            if stop:
                status = "interrupted"
                break
            lateness = _lateness(side.heart, slot)
            behind = max(behind, lateness)
            late += lateness > dt  # a period past its slot: a tick owed, or one the timeout ran
            side.tick(i, i * dt, port)
            say.tick(i)
            ticks[i], steps = side.tick_ns * 1e-3, i + 1
            if port.refused is not None and i >= 1:  # two replies sent: the master can tell this period too
                status = "link_refused"
                break
            if side.last_seq >= n:
                break
            seen, waiting = _await_command(link, slot + 2 * dt, poll_s)
            slot = _next_slot(slot, dt, waiting, seen)
        runner = {"tick_us": tick_stats(ticks[:steps]), "late_ticks": late, "link": {"zenoh_slave": link.stats()},
                  "clock": {"slave": _clock(wall0, steps, dt, behind, core, locked)}}
        if port.refused is not None:
            _refused("slave", port, runner)
    part = side.summary()
    part["followed_last_command"] = side.last_seq >= n
    log = sb.log(steps)
    return SideRun(status, steps, dt, None, part, False, runner, log), sb.result()


def side_result(scene: Scene, run: SideRun, metrics: dict) -> RunResult:
    """One process's own summary (the shape of every run's: :meth:`Session.result`)."""
    return scene_summary(scene, Session.result(run, metrics, exempt_metrics(scene)))


def scene_summary(scene: Scene, result: RunResult) -> RunResult:
    """The scene's names around a summary, as :func:`teleop.app.runtime.run_scene` gives them."""
    result.summary = {"scenario": scene.name, **result.summary, "integrator": scene.integrator,
                      "master": scene.master, "seed": scene.seed, "effects": list(scene.effects)}
    return result


def merge(scene: Scene, master: tuple[SideRun, dict] | None, slave: tuple[SideRun, dict] | None,
          why: str = "", interrupted: bool = False) -> RunResult:
    """The two processes' runs as one run (the in-process run's summary shape and verdict);
    a side that left no run (its process died) is judged by the other (``why`` says what
    happened to it)."""
    m, s = (master or (None, {}))[0], (slave or (None, {}))[0]
    if m is None and s is None:  # both died before their first tick: a run of none, said so
        status = "interrupted" if interrupted else "link_lost"
        result = side_result(scene, SideRun(status, 0, scene.dt_s, None, None, False, {}, {}), {})
        result.summary["status_reason"] = f"neither side left a run ({why or 'no reason given'})"
        result.summary["processes"] = why
        return result
    steps = m.steps if m is not None else s.steps
    status = m.status if m is not None else "interrupted" if interrupted else "link_lost"
    if m is not None and s is not None and s.status == "interrupted":
        status = "interrupted"
    runner: dict = {"link": {}, "clock": {}}
    for side in (m, s):
        if side is not None:
            runner["link"].update(side.runner["link"])
            runner["clock"].update(side.runner["clock"])
    if m is not None:
        runner.update({k: v for k, v in m.runner.items() if k not in ("link", "clock")})
    if s is not None:
        runner["slave_tick_us"] = s.runner["tick_us"]
        runner["slave_late_ticks"] = s.runner["late_ticks"]
    log = {}
    if m is not None and s is not None:
        k = min(m.steps, s.steps)
        log = {**{n: v[:k] for n, v in m.log.items()}, **{n: v[:k] for n, v in s.log.items()}}
        log["tick_us"] = log["tick_us"] + log["slave_tick_us"]  # the log: the ticks both sides ran
    run = SideRun(status, steps, scene.dt_s, m.master if m is not None else None, s.slave if s is not None else None,
                  m.nan if m is not None else False, runner, log)
    metrics = {**(master or (None, {}))[1], **(slave or (None, {}))[1]}
    if log:  # as in one process; the felt force aligned within the scene's delay plus a network's 50 ms
        metrics.update(link_metrics(run.master, run.slave, log, build_registration(scene), scene.dt_s,
                                    scene.link.round_trip_ms * 1e-3 + NETWORK_LAG_S))
    result = side_result(scene, run, metrics)
    if why:
        result.summary["processes"] = why
        if m is None:
            result.summary["status_reason"] = f"the master process left no summary ({why})"
    return result


def save_side(run: SideRun, metrics: dict, folder) -> None:
    """A side's run into ``folder`` (``<side>.json`` and ``<side>.npz``), for :func:`load_side`."""
    import json
    from pathlib import Path

    role = "master" if run.master is not None else "slave"
    d = {k: v for k, v in asdict(run).items() if k != "log"}
    (Path(folder) / f"{role}.json").write_text(json.dumps({"run": d, "metrics": metrics}, default=float))
    np.savez(Path(folder) / f"{role}.npz", **run.log)


def load_side(folder, role: str) -> tuple[SideRun, dict] | None:
    """A side's run saved by :func:`save_side`, or None when its process left none."""
    import json
    from pathlib import Path

    js, npz = Path(folder) / f"{role}.json", Path(folder) / f"{role}.npz"
    if not (js.exists() and npz.exists()):
        return None
    d = json.loads(js.read_text())
    with np.load(npz) as z:
        log = {k: z[k] for k in z.files}
    return SideRun(**d["run"], log=log), d["metrics"]


def _clock(wall0: float, steps: int, dt_s: float, behind_s: float, core: int | None = None,
           locked: bool = False) -> dict:
    """How the wall clock kept up: ``wall_s`` the tick loop took (s), ``realtime_factor`` the
    simulated time over it (1: real time), ``behind_max_ms`` the furthest a tick started behind
    its deadline (ms; once behind, the ticks run back to back until caught up, so late_ticks
    counts every one of those), ``load_1min`` the machine's load average at the end (the other
    jobs' share of the cores: on 2 cores, a load of 4 leaves each process about half a core),
    ``core`` the core the side was pinned to (None: not pinned), ``memory_locked`` whether its
    pages were kept in memory (:func:`locked_memory`)."""
    wall = time.perf_counter() - wall0
    return {"wall_s": wall, "realtime_factor": steps * dt_s / wall if wall > 0 else 0.0,
            "behind_max_ms": behind_s * 1e3, "load_1min": os.getloadavg()[0], "core": core,
            "memory_locked": locked}


def free_endpoint() -> str:
    """A free TCP port on loopback, as a Zenoh endpoint."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


