"""A link's delivery schedule: what each side's tick was handed, tick by tick, noted during a run
(:class:`ScheduleTap`) and played back (:class:`ScheduleLink`), so that a two-process run is run
again in one process, in lockstep, bit for bit (``teleop replay RUN --check``); each message
played back goes through the wire format as it did between the processes.

A side's tick asks its link four things (:class:`~teleop.tick.ports.MasterEnd`,
:class:`~teleop.tick.ports.SlaveEnd`): the newest message (None, a hello of the start-up, or one
by its sequence number), the clock and the time it last heard its peer (its heartbeat's inputs),
and it sends one message. A schedule row per tick holds the answers: ``seq`` (-1: none), ``hello``
(1: the start-up's hello), ``clock_s`` and ``heard_s`` (NaN: never heard), with the link's time
stamps beside them (``sent_s``; the reply's or command's chain, :mod:`teleop.link.latency`),
which a replay does not need. Played back, each message is handed over at the tick the row says,
the one the peer's tick sent with that sequence number, and the clock and heartbeat read what
they read then: everything a side did follows.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from teleop.link import wire
from teleop.tick.messages import ContactFeedback, ToolCommand

#: a schedule row's columns (floats; NaN where nothing was)
COLUMNS = ("seq", "hello", "clock_s", "heard_s", "sent_s", "chain_1", "chain_2", "chain_3", "chain_4", "chain_5",
           "chain_6")
_NAN6 = (math.nan,) * 6
_Z3 = np.zeros(3)


def through_wire(msg: Any) -> Any:
    """``msg`` as its receiver gets it from a network link: encoded and decoded
    (:mod:`teleop.link.wire`; a reply's damping, say, comes back exactly symmetric)."""
    return wire.decode(wire.encode(msg))


def hello_command(p: Any, R: Any) -> ToolCommand:
    """The master's hello before its first tick (the tool's pose, clutch out, ``t_s`` -1: no
    command of the run; the slave follows none)."""
    return ToolCommand(0, -1.0, p, R, _Z3, _Z3, False)


def hello_reply() -> ContactFeedback:
    """The slave's answer to a hello (``t_s`` -1, no force, status hold)."""
    return ContactFeedback(0, -1.0, np.zeros(6), "hold", -1)


class ScheduleTap:
    """Stands between a side and its ``link`` (``role`` "master" or "slave"), passing every call
    through and noting, for the tick in progress (:meth:`begin` starts one), what the link
    answered: the row's values as attributes (``seq``, ``hello``, ``clock_s``, ``heard_s``,
    ``sent_s``, ``chain``) and :meth:`row`. The link's stamps come from its ``ledger``
    (:class:`~teleop.link.latency.LatencyLedger`), when it has one."""

    def __init__(self, link: Any, role: str) -> None:
        self.link, self.role = link, role
        self.ledger = getattr(link, "ledger", None)
        self.begin()

    def begin(self) -> None:
        """A new tick: nothing noted yet."""
        self.seq, self.hello = -1, 0
        self.clock_s = self.heard_s = self.sent_s = math.nan
        self.chain: tuple[float, ...] = _NAN6

    def row(self) -> tuple[float, ...]:
        """The tick's row (:data:`COLUMNS`)."""
        return (float(self.seq), float(self.hello), self.clock_s, self.heard_s, self.sent_s, *self.chain)

    def _took(self, msg: Any) -> None:
        if msg is not None:
            self.seq, self.hello = msg.seq, int(msg.t_s < 0)

    def receive_feedback(self, t_s: float) -> ContactFeedback | None:
        before = None if self.ledger is None else self.ledger.last
        msg = self.link.receive_feedback(t_s)
        self._took(msg)
        if self.ledger is not None and msg is not None and self.ledger.last is not before:
            self.chain = self.ledger.last
        return msg

    def receive_command(self, t_s: float) -> ToolCommand | None:
        msg = self.link.receive_command(t_s)
        self._took(msg)
        taken = None if self.ledger is None else self.ledger.taken
        if msg is not None and taken is not None and taken[0] == msg.seq:
            self.chain = (taken[1], taken[2], taken[3], math.nan, math.nan, math.nan)
        return msg

    def send_command(self, msg: ToolCommand) -> None:
        self.link.send_command(msg)
        self._sent()

    def send_feedback(self, msg: ContactFeedback) -> None:
        self.link.send_feedback(msg)
        self._sent()

    def _sent(self) -> None:
        if self.ledger is not None:
            self.sent_s = self.ledger.last_sent_s

    def clock(self, t_s: float) -> float:
        self.clock_s = self.link.clock(t_s)
        return self.clock_s

    def last_heard_s(self, side: str) -> float | None:
        heard = self.link.last_heard_s(side)
        self.heard_s = math.nan if heard is None else float(heard)
        return heard


class ScheduleError(ValueError):
    """A schedule that no run could have made (a message asked for before it was sent)."""


class ScheduleLink:
    """Both ends of a link that delivers by the recorded ``master`` and ``slave`` schedules
    (arrays (ticks, >= 4): seq, hello, clock_s, heard_s per tick, as :class:`ScheduleTap` noted
    them). ``master_end`` and ``slave_end`` are what each side's tick is given; the driver says
    which tick each is at (:meth:`ScheduleEnd.at`) and runs a side's tick only once the message
    it is to be handed was sent (:meth:`ScheduleEnd.needs`)."""

    def __init__(self, master: np.ndarray, slave: np.ndarray) -> None:
        self.commands: dict[int, ToolCommand] = {}
        self.replies: dict[int, ContactFeedback] = {}
        self.master_end = ScheduleEnd(self, "master", np.asarray(master, dtype=float))
        self.slave_end = ScheduleEnd(self, "slave", np.asarray(slave, dtype=float))


class ScheduleEnd:
    """One side's end of a :class:`ScheduleLink`."""

    def __init__(self, link: ScheduleLink, role: str, rows: np.ndarray) -> None:
        self.link, self.role, self.rows, self.i = link, role, rows, 0
        self._hello = through_wire(hello_reply() if role == "master" else hello_command(_Z3, np.eye(3)))

    def at(self, i: int) -> None:
        """The side's next tick is ``i``."""
        self.i = i

    def needs(self, i: int) -> int:
        """The sequence number of the message tick ``i`` is handed (0: none, or a hello): its peer
        sends it in the tick of that index less one."""
        seq, hello = self.rows[i, 0], self.rows[i, 1]
        return 0 if seq < 0 or hello else int(seq)

    def _take(self, store: dict) -> Any:
        seq, hello = self.rows[self.i, 0], self.rows[self.i, 1]
        if seq < 0:
            return None
        if hello:
            return self._hello
        msg = store.get(int(seq))
        if msg is None:
            raise ScheduleError(f"schedule: the {self.role}'s tick {self.i} is handed message {int(seq)}, never sent")
        return msg

    def receive_feedback(self, t_s: float) -> ContactFeedback | None:
        return self._take(self.link.replies)

    def receive_command(self, t_s: float) -> ToolCommand | None:
        return self._take(self.link.commands)

    def send_command(self, msg: ToolCommand) -> None:
        self.link.commands[msg.seq] = through_wire(msg)

    def send_feedback(self, msg: ContactFeedback) -> None:
        self.link.replies[msg.seq] = through_wire(msg)

    def clock(self, t_s: float) -> float:
        return float(self.rows[self.i, 2])

    def last_heard_s(self, side: str) -> float | None:
        heard = float(self.rows[self.i, 3])
        return None if math.isnan(heard) else heard
