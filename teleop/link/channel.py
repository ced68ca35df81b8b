"""A simulated network channel between master and slave, in lockstep simulated time.

Each direction (command master -> slave, feedback slave -> master) is modelled per message, in
the order messages are sent, with the sender's timestamp ``msg.t_s`` as the send time:

1. **Loss**, Gilbert–Elliott: a two-state chain (good, bad) stepped once per message. In the good
   state a message is lost with probability ``loss`` (i.i.d. loss when bursts are off); in the bad
   state with ``burst_loss``. good -> bad with probability ``burst_enter`` per message, bad -> good
   with ``burst_exit`` (mean burst length 1/burst_exit messages). ``burst_enter = 0`` turns bursts
   off.
2. **Bandwidth**: the message occupies the wire for ``size / bandwidth_Bps`` s, ``size`` from the
   wire codec (:func:`teleop.link.wire.encoded_size`); it waits until the wire is free (FIFO), so a
   sender above the bandwidth builds a queue; beyond ``queue_limit`` waiting messages it is dropped.
3. **Delay**: it arrives ``delay + jitter`` after it left the wire, the constant one-way delay
   ``delay = round_trip_ms / 2`` (or ``cmd_share`` of it on the command way), the jitter drawn
   **exponential with mean ``jitter_ms``** (one-sided: never earlier than the constant delay,
   a long tail like real networks). Two messages whose jitter differs by more than their send
   interval arrive out of order: that is the reordering.

``receive_*(t_s)`` hands every message arrived by ``t_s`` to a :class:`Mailbox` in arrival order,
which keeps only newer sequence numbers, and returns the newest in-order one (or None). With the
default spec (zero delay, no jitter, loss or bandwidth limit) a message sent at t is received at
t: exactly :class:`LockstepLink`.

**A cut** (:meth:`SimulatedChannel.cut`, the fault campaign's link loss): from an instant on,
every message of the chosen way(s) is lost, those already in flight included (counted ``cut``).
The heartbeat (:mod:`teleop.tick.heartbeat`) reads :meth:`SimulatedChannel.last_heard_s`, the
arrival time of the last message each side received.

All draws come from the Generator given (three per message per direction, always, so a run is
deterministic and a change of loss does not shift the jitter stream).
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from teleop.link.base import Link, Mailbox
from teleop.link.latency import LatencyLedger, latency_summary
from teleop.link.wire import encoded_size
from teleop.tick.messages import ContactFeedback, ToolCommand
from teleop.util.errors import ConfigError

#: arrival times within this of the receive time count as arrived (s): ticks are float sums
_EPS_S = 1e-9


def _pair(x, name: str, lo: float, hi: float) -> tuple[float, float]:
    """A number or a (command, feedback) pair -> a validated pair."""
    v = tuple(x) if isinstance(x, (tuple, list)) else (x, x)
    if len(v) != 2:
        raise ConfigError(f"ChannelSpec.{name}: expected a number or a (command, feedback) pair, got {x!r}")
    out = []
    for a in v:
        if (isinstance(a, bool) or not isinstance(a, (int, float)) or math.isnan(a) or not lo <= a <= hi
                or (math.isinf(a) and hi != math.inf)):
            raise ConfigError(f"ChannelSpec.{name}: expected a number in [{lo}, {hi}], got {a!r}")
        out.append(float(a))
    return out[0], out[1]


@dataclass(frozen=True)
class ChannelSpec:
    """The channel, validated when made. Every field but ``round_trip_ms`` and ``cmd_share`` takes
    a number (both ways) or a pair ``(command way, feedback way)``.

    round_trip_ms: constant round-trip delay (ms), >= 0; split ``cmd_share`` on the command way.
    jitter_ms: mean of the exponential extra one-way delay (ms), >= 0.
    loss: probability a message is lost in the good state, [0, 1].
    burst_enter: Gilbert–Elliott good -> bad probability per message, [0, 1] (0: no bursts).
    burst_exit: bad -> good probability per message, (0, 1].
    burst_loss: loss probability in the bad state, [0, 1].
    bandwidth_Bps: wire rate (bytes/s), > 0; ``math.inf`` for no limit.
    queue_limit: messages that may wait for the wire, >= 1; beyond, a message is dropped.
    """

    round_trip_ms: float = 0.0
    jitter_ms: float | tuple = 0.0
    loss: float | tuple = 0.0
    burst_enter: float | tuple = 0.0
    burst_exit: float | tuple = 0.5
    burst_loss: float | tuple = 1.0
    bandwidth_Bps: float | tuple = math.inf
    queue_limit: int = 1000
    cmd_share: float = 0.5

    def __post_init__(self):
        rt = _pair(self.round_trip_ms, "round_trip_ms", 0.0, 1e7)[0]
        if isinstance(self.round_trip_ms, (tuple, list)):
            raise ConfigError("ChannelSpec.round_trip_ms: one number (split it with cmd_share)")
        object.__setattr__(self, "round_trip_ms", rt)
        object.__setattr__(self, "cmd_share", _pair(self.cmd_share, "cmd_share", 0.0, 1.0)[0])
        for name, lo, hi in (("jitter_ms", 0.0, 1e7), ("loss", 0.0, 1.0), ("burst_enter", 0.0, 1.0),
                             ("burst_exit", 1e-12, 1.0), ("burst_loss", 0.0, 1.0),
                             ("bandwidth_Bps", 1e-12, math.inf)):
            object.__setattr__(self, name, _pair(getattr(self, name), name, lo, hi))
        q = self.queue_limit
        if isinstance(q, bool) or not isinstance(q, int) or q < 1:
            raise ConfigError(f"ChannelSpec.queue_limit: expected an integer >= 1, got {q!r}")

    def delay_s(self, way: int) -> float:
        """Constant one-way delay (s) of way 0 (command) or 1 (feedback)."""
        share = self.cmd_share if way == 0 else 1.0 - self.cmd_share
        return self.round_trip_ms * 1e-3 * share


class _Way:
    """One direction: the loss chain, the wire, the messages in flight and the mailbox."""

    def __init__(self, spec: ChannelSpec, way: int, rng: np.random.Generator, sender: LatencyLedger,
                 receiver: LatencyLedger):
        self.sender, self.receiver = sender, receiver  # the ends' time stamps (simulated time)
        self.delay_s = spec.delay_s(way)
        self.jitter_s = spec.jitter_ms[way] * 1e-3
        self.loss, self.enter, self.exit = spec.loss[way], spec.burst_enter[way], spec.burst_exit[way]
        self.burst_loss, self.bw = spec.burst_loss[way], spec.bandwidth_Bps[way]
        self.queue_limit = spec.queue_limit
        self.rng = rng
        self.bad = False
        self.wire_free_s = -math.inf
        self.leaving: deque[float] = deque()  # times the queued messages leave the wire (FIFO)
        self.flight: list = []  # heap of (arrival_s, order, msg)
        self.order = 0
        self.box = Mailbox()
        self.sent = self.lost = self.dropped_queue = self.bursts = self.superseded = 0
        self.max_age_s = 0.0
        self.age_sum_s = 0.0
        self.cut_s = math.inf  # from this send / arrival time (s) on, every message is lost ...
        self.restore_s = math.inf  # ... until this one (s)
        self.cut = 0
        self.last_arrival_s = None  # arrival time (s) of the last message received

    def send(self, msg) -> None:
        self.sent += 1
        stamps = self.sender.sending(msg, msg.t_s)
        u_loss, u_state, u_jit = self.rng.random(3)
        lost = u_loss < (self.burst_loss if self.bad else self.loss)
        if self.bad:
            self.bad = not u_state < self.exit
        elif u_state < self.enter:
            self.bad = True
            self.bursts += 1
        if lost:
            self.lost += 1
            return
        t = msg.t_s
        if self._down(t):
            self.cut += 1
            return
        if math.isfinite(self.bw):
            while self.leaving and self.leaving[0] <= t:
                self.leaving.popleft()
            if len(self.leaving) >= self.queue_limit:
                self.dropped_queue += 1
                return
            t = max(t, self.wire_free_s) + encoded_size(msg) / self.bw
            self.wire_free_s = t
            self.leaving.append(t)
        jitter = -self.jitter_s * math.log1p(-u_jit) if self.jitter_s > 0.0 else 0.0
        heapq.heappush(self.flight, (t + self.delay_s + jitter, self.order, msg, stamps))
        self.order += 1

    def _down(self, t_s: float) -> bool:
        """The way is cut at time ``t_s`` (s)."""
        return self.cut_s - _EPS_S <= t_s < self.restore_s - _EPS_S

    def receive(self, t_s: float):
        box = self.box
        while self.flight and self.flight[0][0] <= t_s + _EPS_S:
            arrival, _, msg, stamps = heapq.heappop(self.flight)
            if self._down(arrival):  # in flight when the link was cut
                self.cut += 1
                continue
            self.last_arrival_s = arrival
            self.receiver.received(msg, stamps, arrival)
            if box.pending is not None and msg.seq > box.pending.seq:
                self.superseded += 1
            box.put(msg)
        msg = self.box.take()
        self.receiver.applied(msg, t_s)
        if msg is not None:
            age = t_s - msg.t_s
            self.max_age_s = max(self.max_age_s, age)
            self.age_sum_s += age
        return msg

    def stats(self) -> dict:
        d = self.box.delivered
        return {"sent": self.sent, "delivered": d, "lost": self.lost, "dropped_queue": self.dropped_queue,
                "dropped_old": self.box.dropped_old, "superseded": self.superseded, "in_flight": len(self.flight),
                "bursts": self.bursts, "cut": self.cut,
                "max_age_s": self.max_age_s, "mean_age_s": self.age_sum_s / d if d else 0.0}


class SimulatedChannel(Link):
    """A :class:`Link` through the channel ``spec``, deterministic under ``rng`` (one Generator per
    run; the two directions draw from two children spawned from it)."""

    def __init__(self, spec: ChannelSpec | None = None, rng: np.random.Generator | None = None):
        self.spec = spec if spec is not None else ChannelSpec()
        if rng is None:
            rng = np.random.default_rng(0)
        r_cmd, r_fb = rng.spawn(2)
        self.ledgers = {"master": LatencyLedger("master"), "slave": LatencyLedger("slave")}
        self._cmd = _Way(self.spec, 0, r_cmd, self.ledgers["master"], self.ledgers["slave"])
        self._fb = _Way(self.spec, 1, r_fb, self.ledgers["slave"], self.ledgers["master"])

    def send_command(self, msg: ToolCommand) -> None:
        self._cmd.send(msg)

    def receive_command(self, t_s: float) -> ToolCommand | None:
        return self._cmd.receive(t_s)

    def send_feedback(self, msg: ContactFeedback) -> None:
        self._fb.send(msg)

    def receive_feedback(self, t_s: float) -> ContactFeedback | None:
        return self._fb.receive(t_s)

    def last_heard_s(self, side: str) -> float | None:
        """Arrival time (s) of the last command the slave received (``side="slave"``) or of the
        last feedback the master received (``"master"``); None before the first."""
        return (self._cmd if side == "slave" else self._fb).last_arrival_s

    def cut(self, t_s: float, ways=("command", "feedback")) -> None:
        """Lose every message of ``ways`` ("command", "feedback" or both) sent or arriving at or
        after ``t_s`` (s) from now on: the link is gone (the fault campaign's link loss)."""
        for way in ways:
            if way not in ("command", "feedback"):
                raise ValueError(f"SimulatedChannel.cut: way {way!r}: expected 'command' or 'feedback'")
            w = self._cmd if way == "command" else self._fb
            w.cut_s, w.restore_s = float(t_s), math.inf

    def restore(self, t_s: float, ways=("command", "feedback")) -> None:
        """Messages of ``ways`` sent and arriving at or after ``t_s`` (s) get through again (those
        of the cut before it stay lost)."""
        for way in ways:
            if way not in ("command", "feedback"):
                raise ValueError(f"SimulatedChannel.restore: way {way!r}: expected 'command' or 'feedback'")
            (self._cmd if way == "command" else self._fb).restore_s = float(t_s)

    def stats(self) -> dict:
        """``{"command": {...}, "feedback": {...}}``: sent, delivered, lost (loss and bursts), cut
        (lost to :meth:`cut`), dropped_queue (bandwidth queue full), dropped_old (reordered or
        stale), superseded (arrived in the same receive as a newer one), in_flight, bursts (times
        the bad state was entered), max_age_s and mean_age_s (receive time - send time of the
        delivered messages, s); and ``"latency"``: the messages' times in simulated time
        (:func:`teleop.link.latency.latency_summary`: round trip, jitter, loss, late ticks, the split)."""
        return {"command": self._cmd.stats(), "feedback": self._fb.stats(),
                "latency": latency_summary(self.ledgers["master"], self.ledgers["slave"], clock="simulated time")}
