"""An in-process CAN wire for lockstep simulation: ``can.Bus(interface="teleop_lockstep")``.

Every bus opened on a channel receives, in send order, every frame the other buses on that
channel send. Nothing else happens on the way: no thread, no lock, no copy. That is what a
lockstep run needs, since the simulator (:class:`~teleop.can.simulator.CobotSimulator`) already
models the wire itself: frame times at the bitrate, arbitration by id, bus load, latency and
faults. python-can's own ``virtual`` interface does the same job through locked queues and a deep
copy of every frame, about four times the cost per frame; it stays selectable
(``[master] interface = "virtual"``) and the driver is tested on both.

Frames are passed by reference, as on any bus whose frames are immutable once sent: a sender must
not change a :class:`can.Message` after sending it (the driver and the simulator build a new one
for every frame). Registered under python-can's ``can.interface`` entry points (pyproject.toml).
"""

from __future__ import annotations

from collections import deque

import can
from can.bus import LOG as _LOG  # python-can's own receive log

#: open buses per channel name
_CHANNELS: dict[str, list[LockstepBus]] = {}


class LockstepBus(can.BusABC):
    """One node on an in-process channel. ``receive_own_messages``: also queue what this bus sends."""

    def __init__(self, channel: str = "teleop", receive_own_messages: bool = False, **kwargs):
        self.channel_id = str(channel)
        self.channel_info = f"teleop lockstep channel {self.channel_id!r}"
        self.receive_own_messages = bool(receive_own_messages)
        self._queue: deque[can.Message] = deque()
        self._peers = _CHANNELS.setdefault(self.channel_id, [])
        self._peers.append(self)
        self._open = True
        kwargs.pop("fd", None)  # CAN FD frames pass as they are; the flag is python-can's convention
        kwargs.pop("preserve_timestamps", None)  # timestamps always pass unchanged
        super().__init__(channel=self.channel_id, **kwargs)
        self._can_protocol = can.CanProtocol.CAN_FD  # carries CAN FD frames (and classic ones)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self._open:
            raise can.CanOperationError(f"{self.channel_info}: the bus is shut down")
        for peer in self._peers:
            if peer is not self or self.receive_own_messages:
                peer._queue.append(msg)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """:meth:`can.BusABC.recv`; a poll (``timeout=0``) without filters takes the queue's head
        directly, without the base class's timing loop (same frames, same receive log)."""
        if timeout != 0.0 or self._filters is not None:
            return super().recv(timeout)
        msg = self._queue.popleft() if self._queue else None
        if msg:
            _LOG.log(self.RECV_LOGGING_LEVEL, "Received: %s", msg)
            return msg
        return None

    def _recv_internal(self, timeout: float | None):
        # lockstep: a frame is either queued now or will only come after the caller advances time
        return (self._queue.popleft() if self._queue else None), False

    def shutdown(self) -> None:
        if self._open:
            self._open = False
            self._peers.remove(self)
            if not self._peers:
                _CHANNELS.pop(self.channel_id, None)
        super().shutdown()
