"""One side's trust rules for the frames it receives and sends, independent of the transport.

:class:`LinkAuth` pairs the side (:mod:`teleop.link.pairing`), tags every frame it sends with its
session's key and a counter, and takes a received frame only when all of these hold, in order
(else it counts the frame under the first reason that fails and drops it):

============== ==============================================================================
reason         the frame ...
============== ==============================================================================
malformed      is not a frame of this wire version, or not one this side receives
unpaired       carries a message while this side has no session yet
other_session  names a session that is not this side's (nor one the slave offered)
bad_mac        has a tag that does not verify under the session's (or the pairing) key
second_master  (slave) comes from a master other than the one it is paired with: told REFUSE
stale          has a counter below the last one taken (a replay, or out of order)
duplicate      has the counter of the last one taken (a replay)
far_future     has a counter more than ``window`` frames past the last one taken
invalid        is authentic and fresh but its values are not a valid message
============== ==============================================================================

A frame taken is *fresh*: authentic, of this session, and newer than every frame taken before;
only those are handed on (and so only those feed the heartbeat). Frames of the peer that never
arrived are counted as ``missed`` (the gaps in its counter).
"""

from __future__ import annotations

import math

from teleop.link import wire
from teleop.link.keys import LinkKeys
from teleop.link.latency import NO_STAMPS, Stamps
from teleop.link.pairing import MasterPairing, Session, SlavePairing
from teleop.tick.messages import ContactFeedback, MessageError, ToolCommand

REASONS = ("malformed", "unpaired", "other_session", "bad_mac", "second_master", "stale", "duplicate",
           "far_future", "invalid")
WINDOW = 10_000       # frames a counter may run ahead of the last one taken (10 s at 1 kHz)
HELLO_EVERY_S = 0.02  # the master's HELLO period until its first authentic feedback (s)


class LinkAuth:
    """The trust rules of one side (``role`` "master" or "slave") of link ``link`` (its name,
    bound into every key) holding ``keys``; ``window``: see ``far_future`` above.

    ``open(frame, now_s)`` returns the message of a fresh authentic frame or None (counted);
    ``seal(msg)`` the frame to send or None (no session yet; counted ``unsent``); handshake
    frames to send go to ``outbox`` (the transport sends and clears it); the master's HELLO and
    CONFIRM repeats come from ``handshake_due(now_s)``."""

    def __init__(self, role: str, keys: LinkKeys, link: str, window: int = WINDOW):
        if window < 1:
            raise ValueError("LinkAuth.window: at least 1 frame")
        self.role, self.window = role, int(window)
        self.pairing: MasterPairing | SlavePairing = (MasterPairing(keys, link) if role == "master"
                                                      else SlavePairing(keys, link))
        self.refused = dict.fromkeys(REASONS, 0)
        self.missed = self.unsent = 0
        self.outbox: list[bytes] = []
        self._in = ((wire.TYPE_FEEDBACK, wire.TYPE_ACCEPT) if role == "master"
                    else (wire.TYPE_COMMAND, wire.TYPE_CONFIRM))
        self._sid = 0         # the session the counters below belong to
        self._last = 0        # the peer's counter in the last frame taken
        self._count = 0       # this side's counter in the last frame sent
        self._hello_s = -math.inf

    # -- what the side knows -------------------------------------------------------------------
    @property
    def session(self) -> Session | None:
        """The session this side sends in (the master's: once welcomed; the slave's: once a
        master's command verified), or None."""
        return self.pairing.session

    @property
    def peer(self) -> str | None:
        """The name of the side this one is paired with, or None."""
        s = self.pairing.session
        return None if s is None else s.peer(self.role)

    @property
    def refusal(self) -> str | None:
        """(master) the slave's refusal as one line, once it refused this master; else None."""
        return self.pairing.refusal if isinstance(self.pairing, MasterPairing) else None

    # -- sending -------------------------------------------------------------------------------
    @property
    def confirmed(self) -> bool:
        """True once paired for good: the master accepted (ACCEPT or a feedback came), the slave
        with a session taken."""
        p = self.pairing
        return p.confirmed if isinstance(p, MasterPairing) else p.session is not None

    def seal(self, msg: ToolCommand | ContactFeedback, stamps: Stamps = NO_STAMPS) -> bytes | None:
        """The frame of ``msg`` in this side's session (next counter), carrying ``stamps`` (its send
        time, :mod:`teleop.link.latency`), or None without one."""
        s = self.pairing.session
        if s is None:
            self.unsent += 1
            return None
        self._follow(s)
        self._count += 1
        return wire.encode(msg, s.cmd if self.role == "master" else s.fb, s.id, self._count, stamps)

    def _seal_empty(self, kind: int, s: Session) -> bytes:
        self._follow(s)
        self._count += 1
        return wire.seal(kind, s.id, self._count, 0, b"", s.cmd if self.role == "master" else s.fb)

    def handshake_due(self, now_s: float) -> bytes | None:
        """(master) The handshake frame to send now: a HELLO (no session yet) or a CONFIRM (one
        offered), every HELLO_EVERY_S s until accepted or refused; else None."""
        p = self.pairing
        if not isinstance(p, MasterPairing) or p.confirmed or p.refusal is not None:
            return None
        if now_s - self._hello_s < HELLO_EVERY_S:
            return None
        self._hello_s = now_s
        return p.hello() if p.session is None else self._seal_empty(wire.TYPE_CONFIRM, p.session)

    # -- receiving -----------------------------------------------------------------------------
    def open(self, data: bytes, now_s: float) -> ToolCommand | ContactFeedback | None:
        """The message of ``data`` if it is a fresh authentic frame of this side's session;
        None otherwise (counted by reason; a handshake frame is handled and gives None)."""
        out = self._open(data, now_s)
        if isinstance(out, str):
            self.refused[out] += 1
            return None
        return out

    def _open(self, data: bytes, now_s: float) -> ToolCommand | ContactFeedback | str | None:
        """The message, None (a handshake frame handled), or the reason the frame is refused."""
        try:
            head = wire.parse(data)
        except MessageError:
            return "malformed"
        p = self.pairing
        if head.kind in self._in:
            s = self._session_of(head, data, now_s)
            return s if isinstance(s, str) else self._take(head, data, s)
        if head.session != 0 or not ((head.kind == wire.TYPE_HELLO and isinstance(p, SlavePairing)) or (head.kind in (
                wire.TYPE_WELCOME, wire.TYPE_REFUSE) and isinstance(p, MasterPairing))):
            return "malformed"  # not a frame this side receives
        if not wire.verified(data, p.mac):
            return "bad_mac"
        if isinstance(p, MasterPairing):
            return p.on_reply(head, data)
        reply, reason = p.on_hello(data, now_s)
        if reply is not None:
            self.outbox.append(reply)
        return reason

    def _follow(self, s: Session) -> None:
        if s.id != self._sid:  # a new session (the master took a newer WELCOME): counters anew
            self._sid, self._last, self._count = s.id, 0, 0

    def _session_of(self, head: wire.Header, data: bytes, now_s: float) -> Session | str:
        """The session a session frame verifies in, or the reason it is refused."""
        p = self.pairing
        s = p.session
        if s is not None and head.session == s.id:
            if not wire.verified(data, s.cmd if self.role == "slave" else s.fb):
                return "bad_mac"
            self._follow(s)
            return s
        offer = p.offered(head.session) if isinstance(p, SlavePairing) else None
        if offer is None or not isinstance(p, SlavePairing):
            return "unpaired" if s is None else "other_session"
        if not wire.verified(data, offer.cmd):
            return "bad_mac"
        if s is not None:  # another master that was offered a session too: told so
            frame = p.refuse_session(head.session, now_s)
            if frame is not None:
                self.outbox.append(frame)
            return "second_master"
        s = p.take(head.session)
        self._follow(s)
        return s

    def _take(self, head: wire.Header, data: bytes, s: Session) -> ToolCommand | ContactFeedback | str | None:
        """The message of an authentic frame if fresh; None for CONFIRM/ACCEPT; else the reason."""
        c, last = head.counter, self._last
        if c <= last:
            return "duplicate" if c == last else "stale"
        if c - last > self.window:
            return "far_future"
        self.missed += c - last - 1
        self._last = c
        if isinstance(self.pairing, MasterPairing):
            self.pairing.confirmed = True
        if head.kind == wire.TYPE_CONFIRM:
            self.outbox.append(self._seal_empty(wire.TYPE_ACCEPT, s))
        if head.kind in (wire.TYPE_CONFIRM, wire.TYPE_ACCEPT):
            return None
        try:
            return wire.unpack_message(head, data)
        except MessageError:
            return "invalid"

    def counts(self) -> dict:
        """The refusals by reason, ``missed`` and ``unsent`` (frames)."""
        return {"refused": dict(self.refused), "missed": self.missed, "unsent": self.unsent}
