"""Latency accounting of the link: every message carries its send time, and its receiver stamps
when it arrived and when its side's tick applied it; a reply carries back the stamps of the
command it answered. One :class:`LatencyLedger` per end of a link keeps them and
:func:`latency_summary` turns them into the summary's ``link.latency`` part, for every link alike
(the simulated channel in simulated time, Zenoh on the wall clock).

For one command and the reply that answered it, six times (s)::

    T1 master sends the command      (master's clock)   ---- command way ---->
    T2 slave receives it             (slave's clock)    slave waits for its tick
    T3 slave's tick applies it       (slave's clock)    the slave's tick
    T4 slave sends the reply         (slave's clock)    <--- feedback way ----
    T5 master receives the reply     (master's clock)   master waits for its tick
    T6 master's tick applies it      (master's clock)

``round_trip`` = T5 - T1 (the master's clock alone: good between two hosts too); the
command-to-applied-reply latency T6 - T1 is split into T2 - T1 (command way), T3 - T2 (slave
wait), T4 - T3 (slave tick), T5 - T4 (feedback way) and T6 - T5 (master wait); T6 - T5 is at most
a tick, so the split closes on the round trip within one tick. The cross-host parts (the two ways)
need one clock on both ends: on one host both processes read CLOCK_MONOTONIC (Python's
``time.monotonic`` and ``time.perf_counter`` on Linux); between two hosts only round_trip,
the slave's parts and the master's wait are meaningful. In a simulated channel every time is the
simulated time: T1 and T4 the messages' ``t_s``, T2 and T5 their arrival, T3 and T6 the time of
the receive call that took them.
"""

from __future__ import annotations

from array import array
from typing import Any, NamedTuple

import numpy as np


class Stamps(NamedTuple):
    """The times a frame carries (s, see the module docstring): its own send time ``sent_s`` (the
    sender's clock), and in a reply those of the command it answered: ``echo_sent_s`` (T1, as
    the master stamped it), ``echo_received_s`` (T2) and ``echo_applied_s`` (T3), all 0 when it
    answered none."""

    sent_s: float = 0.0
    echo_sent_s: float = 0.0
    echo_received_s: float = 0.0
    echo_applied_s: float = 0.0


NO_STAMPS = Stamps()
#: the split's parts, in order (the chain's consecutive differences)
PARTS = ("command_way", "slave_wait", "slave_tick", "feedback_way", "master_wait")


class LatencyLedger:
    """One end's stamps (``role`` "master" or "slave"). The link calls :meth:`sending` for every
    message it sends (the stamps to put on it), :meth:`received` for every fresh one that
    arrived, :meth:`applied` for what each receive call handed its side (None: nothing new). The
    master's end keeps one chain (T1..T6) per reply applied that answered a command; ``last``
    is the newest chain, ``taken`` (the slave's) the newest command's (seq, T1, T2, T3)."""

    def __init__(self, role: str) -> None:
        self.role = role
        self.chains = array("d")  # T1..T6 per reply applied (the master's end), flat
        self.last: tuple[float, ...] | None = None
        self.taken: tuple[int, float, float, float] | None = None
        self.last_sent_s = 0.0
        self._arrived: dict[int, tuple[Stamps, float]] = {}  # seq -> (its stamps, T2 or T5)
        self.first_seq = self.last_seq = -1
        self.received_count = 0
        self.late = 0  # receive calls that found nothing new, once messages flowed

    def sending(self, msg: Any, now_s: float) -> Stamps:
        """The stamps to put on ``msg``, sent now (``now_s``, this end's clock)."""
        self.last_sent_s = now_s
        k = self.taken
        if self.role == "slave" and k is not None and getattr(msg, "command_seq", -1) == k[0]:
            return Stamps(now_s, k[1], k[2], k[3])
        return Stamps(now_s)

    def received(self, msg: Any, stamps: Stamps, now_s: float) -> None:
        """A fresh message ``msg`` arrived at ``now_s`` with ``stamps``."""
        seq = msg.seq
        if msg.t_s < 0:  # a hello: no message of the run
            return
        self._arrived[seq] = (stamps, now_s)
        if len(self._arrived) > 256:  # never taken (superseded): forget the oldest
            for k in sorted(self._arrived)[:128]:
                del self._arrived[k]
        if self.first_seq < 0:
            self.first_seq = seq
        self.last_seq = max(self.last_seq, seq)
        self.received_count += 1

    def applied(self, msg: Any, now_s: float) -> None:
        """A receive call handed its side ``msg`` (None: nothing new) at ``now_s``."""
        if msg is None:
            self.late += self.first_seq >= 0
            return
        got = self._arrived.pop(msg.seq, None)
        if got is None:
            return
        stamps, arrived = got
        if self.role == "slave":
            self.taken = (msg.seq, stamps.sent_s, arrived, now_s)
        elif msg.command_seq >= 0 and stamps.echo_sent_s > 0.0:
            self.last = (stamps.echo_sent_s, stamps.echo_received_s, stamps.echo_applied_s, stamps.sent_s,
                         arrived, now_s)
            self.chains.extend(self.last)

    def loss(self) -> float:
        """The share of the peer's messages in the span received that never arrived."""
        span = self.last_seq - self.first_seq + 1
        return 0.0 if span <= 0 else max(0.0, 1.0 - self.received_count / span)

    def chain_array(self) -> np.ndarray:
        """The chains (n, 6: T1..T6, s)."""
        return np.frombuffer(self.chains, dtype=float).reshape(-1, 6) if len(self.chains) else np.zeros((0, 6))


def _ms(x: np.ndarray) -> dict:
    if not len(x):
        return {"p50": None, "p99": None, "max": None}
    return {"p50": float(np.median(x)) * 1e3, "p99": float(np.percentile(x, 99)) * 1e3, "max": float(x.max()) * 1e3}


def latency_summary(master: LatencyLedger | None, slave: LatencyLedger | None = None, clock: str = "") -> dict:
    """The ``link.latency`` part of a summary from the ends' ledgers (either may be None: a
    process has one end). Times in ms: ``round_trip_ms`` p50/p99/max (T5 - T1), ``jitter_ms`` the
    mean change of the round trip from one reply to the next, ``loss`` per way (the share of the
    messages in the span an end received that never arrived), ``late_ticks`` (the master's ticks
    with no new reply, once replies came), ``split_ms`` each part's p50/p99/max and the whole
    ``command_to_applied_reply`` (T6 - T1), ``split_closes_ms`` the sum of the parts' medians less
    the round trip's median (within one tick), ``replies`` the chains measured; ``clock`` what the
    times were read on."""
    out: dict = {"clock": clock}
    if master is not None:
        c = master.chain_array()
        rt = c[:, 4] - c[:, 0]
        parts = np.diff(c, axis=1)
        out["round_trip_ms"] = _ms(rt)
        out["jitter_ms"] = float(np.abs(np.diff(rt)).mean()) * 1e3 if len(rt) > 1 else None
        out["late_ticks"] = master.late
        out["split_ms"] = {**{p: _ms(parts[:, k]) for k, p in enumerate(PARTS)},
                           "command_to_applied_reply": _ms(c[:, 5] - c[:, 0])}
        out["split_closes_ms"] = (float(sum(np.median(parts[:, k]) for k in range(5)) - np.median(rt)) * 1e3
                                  if len(rt) else None)
        out["replies"] = len(c)
        out.setdefault("loss", {})["feedback"] = master.loss()
    if slave is not None:
        out.setdefault("loss", {})["command"] = slave.loss()
    return out
