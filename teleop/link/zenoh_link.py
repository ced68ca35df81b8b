"""The link over Eclipse Zenoh: master and slave as two processes (or two hosts).

One side listens (by default the slave, on ``tcp/127.0.0.1:7447``, loopback only), the other
connects; multicast scouting and gossip are off, so a session talks only to the endpoint it is
given. Frames are the :mod:`teleop.link.wire` bytes, put on two key expressions::

    teleop/<session>/cmd   master -> slave (ToolCommand; HELLO, CONFIRM)
    teleop/<session>/fb    slave -> master (ContactFeedback; WELCOME, ACCEPT, REFUSE)

published with congestion control DROP, priority REAL_TIME and express (no batching): a late
message is worth less than the next one, so nothing queues behind it.

**Trust.** Every frame is authenticated (:mod:`teleop.link.auth`): the two sides pair
(:mod:`teleop.link.pairing`, a handshake under the pre-shared pairing key of
:mod:`teleop.link.keys`, run by :meth:`ZenohLink.poll` on its own, or waited for with
:meth:`ZenohLink.pair`), and a side takes only fresh frames of its session whose HMAC-SHA256
verifies; everything else is counted by reason in ``stats()["refused"]`` and dropped. A second
master is refused and told so (:attr:`ZenohLink.refusal`, :class:`PairingRefused`). Off loopback
the transport is TLS with mutual authentication (:mod:`teleop.link.endpoints`; plain ``tcp/``
off loopback is refused unless ``allow_plaintext_network=True``).

**Polling.** The subscriber hands the frames to a ring of the newest ``RING`` (a Zenoh
``RingChannel``, in Rust); the control loop's own thread drains it (:meth:`ZenohLink.poll`,
called by ``receive_*``, ``peek``, ``last_receive_s`` and ``stats``), at most ``RING`` frames a
call, checks each and puts the messages in a :class:`Mailbox`. No Python code runs on Zenoh's
threads: a Python callback there would wake a Python thread for every frame and make it and the
control loop take turns at the GIL (measured: ticks of 5-6 ms, see the README, "Two processes
over Zenoh"). A poll that finds the ring full counts one ``flood`` (the ring then kept only the
newest ``RING`` frames: those it dropped are not seen, so not counted by reason; the peer's own
lost frames show in ``missed``). ``receive_*`` never blocks and returns the newest in-order
message (or None). ``last_receive_s`` feeds the heartbeat (``alive(now_s, timeout_s=0.02)``):
the clock's time of the poll *before* the one that found the last fresh authentic frame (even
one not newer), a time the frame certainly arrived after, so the silence the heartbeat sees is
never shorter than the real one; a replayed, forged or foreign frame never moves it.

Two hosts (keys from :func:`teleop.link.keys.make_keys` with the slave's address among the
hosts, copied to both)::

    keys = load_keys("keys", "slave")
    link = ZenohLink("slave", listen="tls/10.0.0.2:7447", keys=keys)     # on 10.0.0.2
    keys = load_keys("keys", "master")
    link = ZenohLink("master", connect="tls/10.0.0.2:7447", keys=keys, connect_timeout_s=5)

A peer whose certificate is not from the same CA never gets a Zenoh session: with
``connect_timeout_s`` the connecting side's constructor raises :class:`ConnectRefused`; the
listening side sees nothing.
"""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import time
from collections.abc import Callable

from teleop.link import wire
from teleop.link.auth import WINDOW, LinkAuth
from teleop.link.base import Link, Mailbox
from teleop.link.endpoints import acl_settings, check_endpoint, split_endpoint, tls_settings
from teleop.link.keys import LinkKeys
from teleop.link.latency import LatencyLedger, latency_summary
from teleop.tick.messages import ContactFeedback, ToolCommand
from teleop.util.errors import ConfigError, TeleopError

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
RING = 64  # frames kept between two polls, and the most one poll takes (64 ms at 1 kHz)
ROLES = ("master", "slave")
_ENDPOINT_KEYS = ("listen/endpoints", "connect/endpoints", "listen", "connect")


class LinkError(TeleopError):
    """The link cannot be opened or is used from the wrong side."""


class ConnectRefused(LinkError):
    """The peer's port answers but Zenoh could not open a session over TLS: the certificates
    do not match (another CA, a name not in the certificate, none)."""


class PairingRefused(LinkError):
    """The slave refused this master: it is paired with another (the message says which)."""


def make_config(listen: str | None = None, connect: str | None = None, config_json5: dict | None = None,
                keys: LinkKeys | None = None, allow_plaintext_network: bool = False,
                connect_timeout_s: float | None = None, role: str | None = None, session: str = "default"):
    """A zenoh.Config: peer mode, multicast scouting and gossip off, the given endpoints (checked,
    :func:`teleop.link.endpoints.check_endpoint`), mutual TLS for ``tls/`` ones from ``keys`` and,
    for a side (``role``, ``session``), Zenoh's access control to its peer's certificate on a
    ``tls/`` link (:func:`teleop.link.endpoints.acl_settings`), then any extra
    ``{"path/to/key": "json5 value"}`` entries (neither endpoints nor, for a side, access control).
    ``connect_timeout_s`` (s): open fails when ``connect`` is not reached within it (None: open
    at once and keep trying in the background)."""
    import zenoh

    for ep in (listen, connect):
        if ep is not None:
            check_endpoint(ep, allow_plaintext_network)
    for key in config_json5 or {}:
        if key.strip("/") in _ENDPOINT_KEYS:
            raise ConfigError(f"ZenohLink config: {key}: pass the endpoints as listen=/connect= (they are checked)")
        if key.strip("/").startswith("access_control") and role is not None:
            raise ConfigError(f"ZenohLink config: {key}: the link sets its own access control")
    c = zenoh.Config()
    settings = {"mode": '"peer"', "scouting/multicast/enabled": "false", "scouting/gossip/enabled": "false",
                "listen/endpoints": json.dumps([listen] if listen else []),
                "connect/endpoints": json.dumps([connect] if connect else []),
                **tls_settings(keys, listen, connect),
                **(acl_settings(role, session, listen, connect) if role is not None else {})}
    if connect and connect_timeout_s is not None:
        settings.update({"connect/exit_on_failure": "true", "connect/timeout_ms": str(int(connect_timeout_s * 1e3))})
    for key, value in {**settings, **(config_json5 or {})}.items():
        try:
            c.insert_json5(key, value)
        except Exception as e:  # zenoh raises ZError
            raise ConfigError(f"ZenohLink config: {key}: {e}") from e
    return c


def process_name(name: str) -> str:
    """``name@host:pid``, at most 64 bytes: the name this process pairs under, so a refusal or
    :attr:`ZenohLink.peer` tells two processes with the same key or certificate apart."""
    tail = f":{os.getpid()}"
    host = socket.gethostname().encode()[: max(0, 63 - len(name.encode()) - len(tail))].decode("utf-8", "ignore")
    return f"{name}@{host}{tail}"[:64] if len(name.encode()) < 48 else name


def _port_answers(endpoint: str) -> bool:
    """True when a TCP connection to the endpoint's host and port succeeds (within 1 s)."""
    try:
        _, host, port = split_endpoint(endpoint)
        with socket.create_connection((host, int(port)), timeout=1.0):
            return True
    except (OSError, ValueError, ConfigError):
        return False


class ZenohLink(Link):
    """One side of the link over Zenoh.

    role: "master" (sends commands, receives feedback) or "slave" (the other way).
    session: the key expressions' middle part, so several pairs can share a network (bound into
        every key: a frame of another link name never verifies).
    listen / connect: Zenoh endpoints; with neither given the slave listens on
        DEFAULT_ENDPOINT and the master connects to it.
    config_json5: extra configuration entries (not the endpoints).
    clock: a monotonic clock in s (``time.monotonic``), for ``last_receive_s``.
    keys: this side's key material (:class:`~teleop.link.keys.LinkKeys`, e.g. from
        :func:`~teleop.link.keys.load_keys`), or the 32-byte pairing key itself (the side's name
        is then its role). Required: the link never runs unauthenticated. The side pairs as
        ``name@host:pid`` (:func:`process_name`).
    window: how far (frames) a peer's counter may jump ahead (:mod:`teleop.link.auth`).
    allow_plaintext_network: let a plain ``tcp/``/``udp/`` endpoint off loopback through.
    connect_timeout_s: with ``connect``, fail (LinkError; ConnectRefused when the port answers
        but TLS fails) if no session is up within it (s); None: keep trying in the background.
    """

    def __init__(self, role: str, session: str = "default", listen: str | None = None,
                 connect: str | None = None, config_json5: dict | None = None,
                 clock: Callable[[], float] = time.monotonic, *, keys: LinkKeys | bytes,
                 window: int = WINDOW, allow_plaintext_network: bool = False,
                 connect_timeout_s: float | None = None):
        import zenoh

        if role not in ROLES:
            raise ConfigError(f"ZenohLink.role: expected one of {ROLES}, got {role!r}")
        if not session or any(ch in session for ch in "/*$?#"):
            raise ConfigError(f"ZenohLink.session: a plain non-empty name, got {session!r}")
        keys = LinkKeys(keys, role) if isinstance(keys, bytes) else keys
        if not isinstance(keys, LinkKeys):
            raise ConfigError(f"ZenohLink.keys: LinkKeys or a 32-byte pairing key, got {type(keys).__name__}")
        keys = dataclasses.replace(keys, name=process_name(keys.name))
        if listen is None and connect is None:
            listen, connect = (DEFAULT_ENDPOINT, None) if role == "slave" else (None, DEFAULT_ENDPOINT)
        self.role, self.session_name, self._now = role, session, clock
        self.listen, self.connect = listen, connect
        self._auth = LinkAuth(role, keys, session, window)
        self._box = Mailbox()
        self.ledger = LatencyLedger(role)  # the messages' time stamps, on ``clock`` (teleop.link.latency)
        self._heard_s: float | None = None  # see last_receive_s
        self._polled_s = clock()  # the clock's time of the last poll
        self.received = self.sent = self.flood = 0
        self._closed = False
        config = make_config(listen, connect, config_json5, keys, allow_plaintext_network, connect_timeout_s,
                             role=role, session=session)
        try:
            self._session = zenoh.open(config)
        except Exception as e:
            if connect and split_endpoint(connect)[0] == "tls" and _port_answers(connect):
                raise ConnectRefused(f"ZenohLink({role}): {connect} answers but refused the TLS session "
                                     f"(a certificate from another CA, or a name not in it?)") from e
            raise LinkError(f"ZenohLink({role}): cannot open a session (listen={listen}, "
                            f"connect={connect}): {e}") from e
        out_key, in_key = (("cmd", "fb") if role == "master" else ("fb", "cmd"))
        self._pub = self._session.declare_publisher(
            f"teleop/{session}/{out_key}", congestion_control=zenoh.CongestionControl.DROP,
            priority=zenoh.Priority.REAL_TIME, express=True)
        self._sub = self._session.declare_subscriber(f"teleop/{session}/{in_key}", zenoh.handlers.RingChannel(RING))
        self._put(self._auth.handshake_due(self._polled_s))

    # -- pairing -------------------------------------------------------------------------------
    @property
    def peer(self) -> str | None:
        """The name of the side this one is paired with (the slave: the master that drives it),
        or None before pairing."""
        return self._auth.peer

    @property
    def session_id(self) -> int | None:
        """The paired session's id (u64), or None."""
        s = self._auth.session
        return None if s is None else s.id

    @property
    def paired(self) -> bool:
        """True once paired for good (master: accepted by the slave; slave: a master taken)."""
        return self._auth.confirmed

    @property
    def refusal(self) -> str | None:
        """(master) The slave's refusal as one line, once it refused this master; else None."""
        return self._auth.refusal

    def pair(self, timeout_s: float = 10.0, poll_s: float = 1e-3) -> str:
        """Wait (polling every ``poll_s`` s) until paired; returns the peer's name. Raises
        PairingRefused (a second master; the message is one line) or LinkError (no peer within
        ``timeout_s`` s)."""
        end = time.monotonic() + timeout_s
        while True:
            self.poll()
            if self.refusal is not None:
                raise PairingRefused(self.refusal)
            if self.paired:
                return str(self.peer)
            if time.monotonic() > end:
                raise LinkError(f"ZenohLink({self.role}): no {'slave' if self.role == 'master' else 'master'} "
                                f"paired within {timeout_s:g} s (listen={self.listen}, connect={self.connect})")
            time.sleep(poll_s)

    # -- receiving -----------------------------------------------------------------------------
    def poll(self) -> int:
        """Check the frames Zenoh has received since the last poll (at most RING, on the
        caller's thread), send the handshake frames due; returns how many messages were fresh
        and authentic. Frames found now arrived after the last poll, so ``last_receive_s``
        becomes that poll's time."""
        before, self._polled_s = self._polled_s, self.clock()
        if self._closed:
            return 0
        valid = 0
        for _ in range(RING):
            try:
                sample = self._sub.try_recv()
            except Exception:  # the subscriber is gone (session closed): nothing more to take
                break
            if sample is None:
                break
            frame = sample.payload.to_bytes()
            msg = self._auth.open(frame, self._polled_s)
            if msg is not None:
                valid += 1
                self._heard_s = before
                self._box.put(msg)
                # stamped now, not at the poll's start: a frame put while this poll drains the ring
                # would otherwise read as received before it was sent
                self.ledger.received(msg, wire.stamps(frame), self.clock())
        else:
            self.flood += 1
        self.received += valid
        self._put(self._auth.handshake_due(self._polled_s))
        out = self._auth.outbox
        while out:
            self._put(out.pop(0))
        return valid

    @property
    def last_receive_s(self) -> float | None:
        """The clock's time (s) the last fresh authentic frame had certainly arrived after (the
        poll before the one that found it; polled now); None before the first frame."""
        self.poll()
        return self._heard_s

    def _put(self, frame: bytes | None) -> bool:
        if frame is None or self._closed:
            return False
        try:
            self._pub.put(frame)
            return True
        except Exception:  # a lost peer never raises into the loop
            return False

    def _send(self, msg, role: str) -> None:
        if self.role != role:
            raise LinkError(f"ZenohLink: the {self.role} side cannot send a {type(msg).__name__}")
        if self._closed:
            return
        if self._auth.session is None:
            self.poll()  # the handshake moves on (a sender that never receives pairs too)
        if self._put(self._auth.seal(msg, self.ledger.sending(msg, self.clock()))):
            self.sent += 1

    def _take(self, role: str):
        if self.role != role:
            raise LinkError(f"ZenohLink: the {self.role} side receives no such message")
        self.poll()
        msg = self._box.take()
        self.ledger.applied(msg, self.clock())  # after the poll that may just have received it
        return msg

    def peek(self):
        """The newest in-order message received and not yet taken (None if none), left in place."""
        self.poll()
        return self._box.pending

    def send_command(self, msg: ToolCommand) -> None:
        """Master: send ``msg`` (dropped, counted ``unsent``, before pairing)."""
        self._send(msg, "master")

    def receive_command(self, t_s: float = 0.0) -> ToolCommand | None:
        """The newest in-order command received so far (``t_s`` unused: wall clock)."""
        return self._take("slave")

    def send_feedback(self, msg: ContactFeedback) -> None:
        """Slave: send ``msg`` (dropped, counted ``unsent``, before pairing)."""
        self._send(msg, "slave")

    def receive_feedback(self, t_s: float = 0.0) -> ContactFeedback | None:
        """The newest in-order feedback received so far (``t_s`` unused: wall clock)."""
        return self._take("master")

    def clock(self, t_s: float = 0.0) -> float:
        """The wall clock (s) ``last_heard_s`` is read in; ``t_s`` (the tick's time) is not used."""
        return self._now()

    def last_heard_s(self, side: str = "") -> float | None:
        """For a side's heartbeat: :attr:`last_receive_s` (this link has one side)."""
        return self.last_receive_s

    def alive(self, now_s: float | None = None, timeout_s: float = 0.02) -> bool:
        """True if a fresh authentic frame came within ``timeout_s`` (s) before ``now_s`` (the
        clock's time, default now); False before the first frame."""
        last = self.last_receive_s
        if last is None:
            return False
        return (self.clock() if now_s is None else now_s) - last <= timeout_s

    def stats(self) -> dict:
        """Counters (frames unless said): ``sent``; ``received`` fresh authentic messages;
        ``delivered`` / ``dropped_old`` by the mailbox; ``refused`` by reason
        (:mod:`teleop.link.auth`) and ``bad_frames`` their sum; ``missed`` the peer's frames
        that never arrived; ``unsent`` messages not sent before pairing; ``flood`` polls that
        found the ring full; ``peer`` and ``session`` (hex) once paired; ``latency`` the messages'
        times (:func:`teleop.link.latency.latency_summary`: round trip, jitter, loss, the split)."""
        self.poll()
        c = self._auth.counts()
        sid = self.session_id
        return {"sent": self.sent, "received": self.received, "delivered": self._box.delivered,
                "dropped_old": self._box.dropped_old, "bad_frames": sum(c["refused"].values()), **c,
                "flood": self.flood, "peer": self.peer, "session": None if sid is None else f"{sid:016x}",
                "latency": latency_summary(*((self.ledger, None) if self.role == "master" else (None, self.ledger)),
                                           clock="time.monotonic (CLOCK_MONOTONIC: one clock per host)")}

    def close(self) -> None:
        """Undeclare and close the session; safe to call twice."""
        if self._closed:
            return
        self._closed = True
        for obj in (self._sub, self._pub):
            try:
                obj.undeclare()
            except Exception:
                pass
        try:
            self._session.close()
        except Exception:
            pass
