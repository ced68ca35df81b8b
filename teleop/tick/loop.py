"""The in-process composition: the two sides of :mod:`teleop.tick` meeting on one link, one tick
after the other, in one process.

    loop = BilateralLoop(master_side, slave_side, LockstepLink())
    status = loop.tick(i)

A tick is the master's half (:meth:`MasterSide.tick`: feel the newest reply, step the tool, command
the device, send the tool) and then the slave's (:meth:`SlaveSide.tick`: take the newest command,
follow it, reply). The two share nothing but the link's two messages, so a link that delays, drops
or crosses a network changes nothing here, and the two-process run composes the same two objects
(:mod:`teleop.app.netrun`). Loop hooks see both sides (``loop.master_side``, ``loop.slave_side``)
and, for brevity, the master side's read-outs (``loop.tool``, ``loop.hand_W``, ...).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

from teleop.tick.master_side import MasterSide
from teleop.tick.ports import Hook, MasterEnd, SlaveEnd
from teleop.tick.slave_side import SlaveSide
from teleop.util.errors import ConfigError

#: what a loop hook reads of the master side through the loop
MASTER_READOUTS = frozenset(("dt", "tool", "master", "operator", "feedback", "hand_W", "felt_W", "feedback_W",
                             "status"))


class Link(MasterEnd, SlaveEnd, Protocol):
    """Both ends of a link, as the in-process loop holds it."""


class BilateralLoop:
    """``master_side`` and (optionally) ``slave_side`` on ``link`` (both ends of one
    :class:`teleop.link.base.Link`; required with a slave); ``hooks`` see the loop around each
    tick."""

    def __init__(self, master_side: MasterSide, slave_side: SlaveSide | None = None, link: Link | None = None,
                 hooks: Sequence[Hook] = ()):
        if slave_side is not None and link is None:
            raise ConfigError("BilateralLoop: a slave side needs a link, e.g. teleop.link.LockstepLink()")
        if slave_side is not None and master_side.feedback is None:
            raise ConfigError("BilateralLoop: a slave needs a feedback path on the master side, e.g. "
                              "MasterSide(..., feedback=FeedbackPath(registration, cutoff_hz=20.0, dt_s=dt_s))")
        self.master_side, self.slave_side, self.link, self.hooks = master_side, slave_side, link, tuple(hooks)
        self.tick_ns = 0  # the last tick's CPU time, both sides, hooks excluded (ns)

    def tick(self, i: int) -> str:
        """One period; returns the master side's status ("ok" or what stopped it)."""
        ms, ss = self.master_side, self.slave_side
        t = i * ms.dt
        for h in self.hooks:
            h.before_tick(i, t, self)
        status = ms.tick(i, t, self.link if ss is not None else None)
        if ss is not None and self.link is not None:
            ss.tick(i, t, self.link)
        self.tick_ns = ms.tick_ns + (ss.tick_ns if ss is not None else 0)
        for h in self.hooks:
            h.after_tick(i, t, self)
        return status

    def __getattr__(self, name: str) -> Any:
        """The master side's read-outs, for loop hooks (``loop.tool``, ``loop.hand_W``, ...)."""
        if name in MASTER_READOUTS:
            return getattr(self.master_side, name)
        raise AttributeError(f"BilateralLoop has no attribute {name!r}")

    @property
    def slave(self) -> SlaveSide | None:
        """The slave side (None without one)."""
        return self.slave_side
