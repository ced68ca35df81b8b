"""What the tick talks to, as protocols: the operator's hand, the link's two ends, and hooks.

The tick owns its two sides (:mod:`teleop.tick.master_side`, :mod:`teleop.tick.slave_side`) and
the messages between them (:mod:`teleop.tick.messages`); a transport (:mod:`teleop.link`) is
anything with the methods below, so the tick imports none. Times are seconds; ``clock(t_s)`` is
the clock the link's ``last_heard_s`` is read in (the simulated time ``t_s`` itself for an
in-process link, a wall clock for a network link).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

import numpy as np

if TYPE_CHECKING:
    from teleop.tick.messages import ContactFeedback, ToolCommand


class ToolState(NamedTuple):
    """The reference tool as a tick reads it, once: pose ``p`` (3,) m and ``R`` (3, 3) in M, and
    the twist ``V`` (6,: m/s, rad/s; linear first) in M. ``v`` and ``w`` are views of ``V``."""

    p: np.ndarray
    R: np.ndarray
    V: np.ndarray

    @property
    def v(self) -> np.ndarray:
        return self.V[:3]

    @property
    def w(self) -> np.ndarray:
        return self.V[3:]


class Operator(Protocol):
    """The hand: the wrench (6,: N, N*m, M) it puts on what it holds, given its state."""

    clutch_engaged: bool

    def wrench(self, t_s: float, p: np.ndarray, R: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray: ...


class MasterEnd(Protocol):
    """The master's end of a link."""

    def send_command(self, msg: ToolCommand) -> None: ...

    def receive_feedback(self, t_s: float) -> ContactFeedback | None: ...

    def last_heard_s(self, side: str) -> float | None: ...

    def clock(self, t_s: float) -> float: ...


class SlaveEnd(Protocol):
    """The slave's end of a link."""

    def receive_command(self, t_s: float) -> ToolCommand | None: ...

    def send_feedback(self, msg: ContactFeedback) -> None: ...

    def last_heard_s(self, side: str) -> float | None: ...

    def clock(self, t_s: float) -> float: ...


class Hook:
    """Called around every tick with the object it is attached to: a master-side hook with the
    :class:`~teleop.tick.master_side.MasterSide`, a slave-side hook with the
    :class:`~teleop.tick.slave_side.SlaveSide`, a loop hook with the in-process
    :class:`~teleop.tick.loop.BilateralLoop` (which shows both). A hook reads; it never changes
    the physics."""

    def before_tick(self, i: int, t_s: float, side: Any) -> None:
        """Before the tick (the state it starts from)."""

    def after_tick(self, i: int, t_s: float, side: Any) -> None:
        """After the tick (the state it ends in)."""
