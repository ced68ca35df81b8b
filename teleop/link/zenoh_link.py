"""The link over Eclipse Zenoh: master and slave as two processes (or two hosts).

One side listens (by default the slave, on ``tcp/127.0.0.1:7447``, loopback only), the other
connects; multicast scouting is off, so a session talks only to the endpoint it is given. Frames
are the :mod:`teleop.link.wire` bytes, put on two key expressions::

    teleop/<session>/cmd   master -> slave (ToolCommand)
    teleop/<session>/fb    slave -> master (ContactFeedback)

published with congestion control DROP, priority REAL_TIME and express (no batching): a late
message is worth less than the next one, so nothing queues behind it. The subscriber hands the
frames to a ring of the newest ``RING`` (a Zenoh ``RingChannel``, in Rust); the control loop's own
thread drains it (:meth:`ZenohLink.poll`, called by ``receive_*``, ``last_receive_s`` and
``stats``), decodes each frame and puts it in a :class:`Mailbox`. No Python code runs on Zenoh's
threads: a Python callback there would wake a Python thread for every frame and make it and the
control loop take turns at the GIL (measured: ticks of 5-6 ms, the interpreter's switch interval;
see the README, "Two processes over Zenoh"). ``receive_*`` never blocks
and returns the newest in-order message (or None). A frame that fails to decode is counted
(``bad_frames``) and dropped. ``last_receive_s`` feeds the heartbeat (``alive(now_s,
timeout_s=0.02)``): the clock's time of the poll *before* the one that found the last valid frame
(even one not newer), a time the frame certainly arrived after, so the silence the heartbeat sees
is never shorter than the real one.

Two hosts, TLS with mutual authentication (zenoh 1.x configuration keys; certificates from your
own CA). On the slave host, listening on its address::

    link = ZenohLink("slave", listen="tls/10.0.0.2:7447", config_json5={
        "transport/link/tls/root_ca_certificate": '"/etc/teleop/ca.pem"',
        "transport/link/tls/listen_certificate": '"/etc/teleop/slave.pem"',
        "transport/link/tls/listen_private_key": '"/etc/teleop/slave.key"',
        "transport/link/tls/enable_mtls": "true",
    })

and on the master host::

    link = ZenohLink("master", connect="tls/10.0.0.2:7447", config_json5={
        "transport/link/tls/root_ca_certificate": '"/etc/teleop/ca.pem"',
        "transport/link/tls/connect_certificate": '"/etc/teleop/master.pem"',
        "transport/link/tls/connect_private_key": '"/etc/teleop/master.key"',
        "transport/link/tls/enable_mtls": "true",
        "transport/link/tls/verify_name_on_connect": "true",
    })

The slave certificate's subject alternative name must carry the address or name connected to.
Keep the TCP endpoint off anything but loopback; open only the TLS port between the hosts.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable

from teleop.util.errors import ConfigError, TeleopError
from teleop.link import wire
from teleop.link.base import Link, Mailbox
from teleop.tick.messages import ContactFeedback, MessageError, ToolCommand

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
RING = 64  # frames kept between two polls (the newest; 64 ms at 1 kHz)
ROLES = ("master", "slave")


class LinkError(TeleopError):
    """The link cannot be opened or is used from the wrong side."""


def make_config(listen: str | None = None, connect: str | None = None, config_json5: dict | None = None):
    """A zenoh.Config: peer mode, multicast scouting off, the given endpoints, then any extra
    ``{"path/to/key": "json5 value"}`` entries (e.g. TLS)."""
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("listen/endpoints", json.dumps([listen] if listen else []))
    c.insert_json5("connect/endpoints", json.dumps([connect] if connect else []))
    for key, value in (config_json5 or {}).items():
        try:
            c.insert_json5(key, value)
        except Exception as e:  # zenoh raises ZError
            raise ConfigError(f"ZenohLink config: {key}: {e}") from e
    return c


class ZenohLink(Link):
    """One side of the link over Zenoh.

    role: "master" (sends commands, receives feedback) or "slave" (the other way).
    session: the key expressions' middle part, so several pairs can share a network.
    listen / connect: Zenoh endpoints; with neither given the slave listens on
        DEFAULT_ENDPOINT and the master connects to it.
    config_json5: extra configuration entries (see the module docstring for TLS).
    clock: a monotonic clock in s (``time.monotonic``), for ``last_receive_s``.
    """

    def __init__(self, role: str, session: str = "default", listen: str | None = None,
                 connect: str | None = None, config_json5: dict | None = None,
                 clock: Callable[[], float] = time.monotonic):
        import zenoh

        if role not in ROLES:
            raise ConfigError(f"ZenohLink.role: expected one of {ROLES}, got {role!r}")
        if not session or any(ch in session for ch in "/*$?#"):
            raise ConfigError(f"ZenohLink.session: a plain non-empty name, got {session!r}")
        if listen is None and connect is None:
            listen, connect = (DEFAULT_ENDPOINT, None) if role == "slave" else (None, DEFAULT_ENDPOINT)
        self.role, self.session_name, self._now = role, session, clock
        self.listen, self.connect = listen, connect
        self._box = Mailbox()
        self._heard_s: float | None = None  # see last_receive_s
        self._polled_s = clock()  # the clock's time of the last poll
        self.received = self.bad_frames = self.sent = 0
        self._closed = False
        try:
            self._session = zenoh.open(make_config(listen, connect, config_json5))
        except Exception as e:
            raise LinkError(f"ZenohLink({role}): cannot open a session (listen={listen}, "
                            f"connect={connect}): {e}") from e
        out_key, in_key = (("cmd", "fb") if role == "master" else ("fb", "cmd"))
        self._pub = self._session.declare_publisher(
            f"teleop/{session}/{out_key}", congestion_control=zenoh.CongestionControl.DROP,
            priority=zenoh.Priority.REAL_TIME, express=True)
        self._in_type = ContactFeedback if role == "master" else ToolCommand
        self._sub = self._session.declare_subscriber(f"teleop/{session}/{in_key}", zenoh.handlers.RingChannel(RING))

    def poll(self) -> int:
        """Drain the frames Zenoh has received since the last poll into the mailbox (on the
        caller's thread); returns how many were valid. Frames found now arrived after the last
        poll, so ``last_receive_s`` becomes that poll's time."""
        before, self._polled_s = self._polled_s, self.clock()
        if self._closed:
            return 0
        valid = 0
        while True:
            try:
                sample = self._sub.try_recv()
            except Exception:  # the subscriber is gone (session closed): nothing more to take
                return valid
            if sample is None:
                return valid
            try:
                msg = wire.decode(sample.payload.to_bytes())
                if not isinstance(msg, self._in_type):
                    raise MessageError(f"wire: a {type(msg).__name__} on the {self._in_type.__name__} key")
            except MessageError:
                self.bad_frames += 1
                continue
            valid += 1
            self.received += 1
            self._heard_s = before
            self._box.put(msg)

    @property
    def last_receive_s(self) -> float | None:
        """The clock's time (s) the last valid frame had certainly arrived after (the poll before
        the one that found it; polled now); None before the first frame."""
        self.poll()
        return self._heard_s

    def _send(self, msg, role: str) -> None:
        if self.role != role:
            raise LinkError(f"ZenohLink: the {self.role} side cannot send a {type(msg).__name__}")
        if self._closed:
            return
        try:
            self._pub.put(wire.encode(msg))
            self.sent += 1
        except Exception:  # a lost peer never raises into the loop
            pass

    def _take(self, role: str):
        if self.role != role:
            raise LinkError(f"ZenohLink: the {self.role} side receives no such message")
        self.poll()
        return self._box.take()

    def peek(self):
        """The newest in-order message received and not yet taken (None if none), left in place."""
        self.poll()
        return self._box.pending

    def send_command(self, msg: ToolCommand) -> None:
        self._send(msg, "master")

    def receive_command(self, t_s: float = 0.0) -> ToolCommand | None:
        """The newest in-order command received so far (``t_s`` unused: wall clock)."""
        return self._take("slave")

    def send_feedback(self, msg: ContactFeedback) -> None:
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
        """True if a frame came within ``timeout_s`` (s) before ``now_s`` (the clock's time,
        default now); False before the first frame."""
        last = self.last_receive_s
        if last is None:
            return False
        return (self.clock() if now_s is None else now_s) - last <= timeout_s

    def stats(self) -> dict:
        self.poll()
        return {"sent": self.sent, "received": self.received, "delivered": self._box.delivered,
                "dropped_old": self._box.dropped_old, "bad_frames": self.bad_frames}

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
