"""The link between the master and slave sides: what a transport must do.

A link carries :class:`~teleop.tick.messages.ToolCommand` master -> slave and
:class:`~teleop.tick.messages.ContactFeedback` slave -> master. ``receive_*`` returns the newest
message that has arrived by time ``t_s`` and is newer (by sequence number) than the last one it
returned, or None: a late, lost or reordered message is never applied out of order, and the
receiving side holds what it had. Sending never blocks and never raises on a lost peer.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

from teleop.tick.messages import ContactFeedback, ToolCommand
from teleop.tick.ports import MasterEnd, SlaveEnd


class Link(ABC, MasterEnd, SlaveEnd):
    """Base of every transport. Context manager; ``close`` is safe to call twice."""

    @abstractmethod
    def send_command(self, msg: ToolCommand) -> None:
        """Master side: hand a command to the link."""

    @abstractmethod
    def receive_command(self, t_s: float) -> ToolCommand | None:
        """Slave side: the newest in-order command arrived by ``t_s`` (s), or None."""

    @abstractmethod
    def send_feedback(self, msg: ContactFeedback) -> None:
        """Slave side: hand a feedback message to the link."""

    @abstractmethod
    def receive_feedback(self, t_s: float) -> ContactFeedback | None:
        """Master side: the newest in-order feedback arrived by ``t_s`` (s), or None."""

    def stats(self) -> dict:
        """Counters for the run's summary (messages sent, delivered, dropped, ...)."""
        return {}

    def last_heard_s(self, side: str) -> float | None:
        """For the heartbeat (:mod:`teleop.tick.heartbeat`): the time (s, the receive calls'
        clock) the last message reached ``side`` ("master": a feedback, "slave": a command), even
        one not newer; None before the first, or on a link that cannot lose one (the lockstep
        link, whose heartbeat never trips)."""
        return None

    def clock(self, t_s: float) -> float:
        """The time (s) ``last_heard_s`` is read in, at the tick's time ``t_s``: the simulated
        time itself here; a network link answers with its wall clock."""
        return t_s

    def close(self) -> None:
        """Release what the link holds."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class Mailbox:
    """The newest in-order message of one direction: keeps the highest sequence number delivered,
    and refuses anything not newer (a reordered or duplicated message is counted and dropped)."""

    __slots__ = ("delivered", "dropped_old", "last_seq", "pending")

    def __init__(self):
        self.pending = None
        self.last_seq = -1
        self.delivered = 0
        self.dropped_old = 0

    def put(self, msg) -> None:
        if msg.seq <= self.last_seq or (self.pending is not None and msg.seq <= self.pending.seq):
            self.dropped_old += 1
            return
        self.pending = msg

    def take(self):
        msg, self.pending = self.pending, None
        if msg is not None:
            self.last_seq = msg.seq
            self.delivered += 1
        return msg


class LockstepLink(Link):
    """In-process, same tick: a message sent is received at once (the default, deterministic)."""

    def __init__(self):
        self._cmd, self._fb = Mailbox(), Mailbox()

    def send_command(self, msg: ToolCommand) -> None:
        self._cmd.put(msg)

    def receive_command(self, t_s: float) -> ToolCommand | None:
        return self._cmd.take()

    def send_feedback(self, msg: ContactFeedback) -> None:
        self._fb.put(msg)

    def receive_feedback(self, t_s: float) -> ContactFeedback | None:
        return self._fb.take()
