"""The pairing handshake: one master bound to one slave, and the keys of their session.

Both sides hold the same pre-shared pairing key (:class:`~teleop.link.keys.LinkKeys`); the
handshake frames are tagged under a key derived from it for the link's name (HKDF-SHA256, info
``teleop-link v4 pairing | link``), so only a holder can make one::

    master -> slave  HELLO    nonce_m (32 random bytes), name_m
    slave -> master  WELCOME  nonce_m, nonce_s (32 random bytes), name_s, name_m, session id
    master -> slave  CONFIRM  (empty) in the session: tagged with the session's command key, so
                     it proves the master holds the key and saw nonce_s (fresh); the slave
                     takes the first offered session confirmed so (a command does it too)
    slave -> master  ACCEPT   (empty) in the session, under the feedback key: the master now
                     drives the slave (its first authentic feedback does it too)
    slave -> master  REFUSE   nonce_m, name_s, the name and session id of the master it follows
                     (to any other master that says HELLO, or confirms a session offered to it)

The master repeats HELLO, then CONFIRM, every 20 ms until it is accepted or refused; the slave
answers each. CONFIRM and ACCEPT carry counters like every session frame (the replay rules).

Session keys: HKDF-SHA256 of the pairing key with salt ``nonce_m || nonce_s`` and info
``teleop-link v4 session | link | name_m | name_s`` (each length-prefixed), 72 bytes: the
command MAC key (32), the feedback MAC key (32), the session id (8; never 0). Each direction has
its own key, so a frame cannot be reflected back to its sender; a replayed HELLO yields a
session nobody holds the keys of (nonce_s is new), a replayed WELCOME matches no live nonce_m.

This module packs and checks the handshake frames (:mod:`teleop.link.wire` types 16-20) and
keeps each side's state; :class:`teleop.link.auth.LinkAuth` calls it.
"""

from __future__ import annotations

import secrets
import struct
from dataclasses import dataclass, field

from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from teleop.link import wire
from teleop.link.keys import LinkKeys
from teleop.util.errors import plain

NONCE = 32
NAME = 64
PENDING = 4              # sessions a slave offers at once (WELCOMEs not yet answered)
REFUSE_EVERY_S = 0.05    # a slave tells one refused session at most this often (s)
_HELLO = struct.Struct(f"<{NONCE}s{NAME}s")
_REPLY = struct.Struct(f"<{NONCE}s{NONCE}s{NAME}s{NAME}sQ")
assert _HELLO.size == wire.PAIRING_SIZES[wire.TYPE_HELLO] and _REPLY.size == wire.PAIRING_SIZES[wire.TYPE_WELCOME]


def _lp(*parts: str) -> bytes:
    out = b""
    for p in parts:
        b = p.encode()
        out += struct.pack("<B", len(b)) + b
    return out


def _name(raw: bytes) -> str:
    return raw.rstrip(b"\0").decode("utf-8", "replace")


def _hkdf(secret: bytes, n: int, info: bytes, salt: bytes | None = None) -> bytes:
    return HKDF(algorithm=hashes.SHA256(), length=n, salt=salt, info=info).derive(secret)


def pairing_mac(secret: bytes, link: str) -> wire.Mac:
    """The MAC of the handshake frames of link ``link`` under pairing key ``secret``."""
    return wire.Mac(_hkdf(secret, 32, b"teleop-link v4 pairing" + _lp(link)))


@dataclass(frozen=True)
class Session:
    """One paired session: its id, the names of both sides, and a MAC per direction."""

    id: int
    master: str
    slave: str
    cmd: wire.Mac = field(repr=False)
    fb: wire.Mac = field(repr=False)

    def peer(self, role: str) -> str:
        """The other side's name, seen from ``role``."""
        return self.slave if role == "master" else self.master


def derive(secret: bytes, link: str, nonce_m: bytes, nonce_s: bytes, master: str, slave: str) -> Session:
    """The session of a handshake (see the module docstring)."""
    okm = _hkdf(secret, 72, b"teleop-link v4 session" + _lp(link, master, slave), salt=nonce_m + nonce_s)
    sid = int.from_bytes(okm[64:], "little") or 1
    return Session(sid, master, slave, wire.Mac(okm[:32]), wire.Mac(okm[32:64]))


def refusal_text(me: str, slave: str, driver: str, sid: int) -> str:
    """The one line a refused master reports."""
    return plain(f"master {me!r}: refused by slave {slave!r}: it is already paired with master "
                 f"{driver!r} (session {sid:016x}); stop that master first")


class MasterPairing:
    """The master's side: says HELLO (fresh nonce) until a WELCOME for its nonce comes; takes the
    newest such WELCOME until an ACCEPT or the first authentic feedback (``confirmed``) fixes the
    session; a REFUSE for its nonce before that ends it (``refusal``)."""

    def __init__(self, keys: LinkKeys, link: str):
        self.keys, self.link = keys, link
        self.mac = pairing_mac(keys.secret, link)
        self.nonce = secrets.token_bytes(NONCE)
        self.session: Session | None = None
        self.confirmed = False
        self.refusal: str | None = None

    def hello(self) -> bytes:
        """A HELLO frame."""
        return wire.seal(wire.TYPE_HELLO, 0, 0, 0, _HELLO.pack(self.nonce, self.keys.name.encode()), self.mac)

    def on_reply(self, head: wire.Header, data: bytes) -> str | None:
        """A WELCOME or REFUSE whose tag verified; returns a refusal reason to count, or None."""
        nonce_m, nonce_s, slave, master, sid = _REPLY.unpack(wire.payload(data))
        if nonce_m != self.nonce:
            return "other_session"  # another master's
        if self.confirmed or self.refusal is not None:
            return None  # a late copy: nothing changes now
        slave = _name(slave)
        if head.kind == wire.TYPE_REFUSE:
            self.session = None
            self.refusal = refusal_text(self.keys.name, slave, _name(master), sid)
            return None
        s = derive(self.keys.secret, self.link, self.nonce, nonce_s, self.keys.name, slave)
        if s.id != sid:
            return "malformed"
        self.session = s
        return None


@dataclass
class _Offer:
    session: Session
    nonce_m: bytes
    welcome: bytes
    refused_s: float = float("-inf")


class SlavePairing:
    """The slave's side: answers each HELLO with a WELCOME (the same one for the same nonce,
    at most :data:`PENDING` offers kept, the oldest forgotten); the first offered session whose
    CONFIRM or command verifies is taken (``session``); after that every other master is refused."""

    def __init__(self, keys: LinkKeys, link: str):
        self.keys, self.link = keys, link
        self.mac = pairing_mac(keys.secret, link)
        self.session: Session | None = None
        self._offers: dict[int, _Offer] = {}  # by session id, oldest first
        self._by_nonce: dict[bytes, int] = {}

    def on_hello(self, data: bytes, now_s: float) -> tuple[bytes | None, str | None]:
        """A HELLO whose tag verified: (the frame to answer with or None, a reason to count)."""
        nonce_m, name = _HELLO.unpack(wire.payload(data))
        if self.session is not None:
            if self._by_nonce.get(nonce_m) == self.session.id:
                return None, None  # the master we follow, a late copy
            return self._refuse(nonce_m), "second_master"
        sid = self._by_nonce.get(nonce_m)
        if sid is not None:
            return self._offers[sid].welcome, None
        nonce_s = secrets.token_bytes(NONCE)
        s = derive(self.keys.secret, self.link, nonce_m, nonce_s, _name(name), self.keys.name)
        body = _REPLY.pack(nonce_m, nonce_s, self.keys.name.encode(), name, s.id)
        offer = _Offer(s, nonce_m, wire.seal(wire.TYPE_WELCOME, 0, 0, 0, body, self.mac))
        while len(self._offers) >= PENDING:
            old = self._offers.pop(next(iter(self._offers)))
            self._by_nonce.pop(old.nonce_m, None)
        self._offers[s.id] = offer
        self._by_nonce[nonce_m] = s.id
        return offer.welcome, None

    def offered(self, sid: int) -> Session | None:
        """The session offered under id ``sid`` (taken or not), or None."""
        o = self._offers.get(sid)
        return None if o is None else o.session

    def take(self, sid: int) -> Session:
        """Take the offered session ``sid`` (its command verified)."""
        self.session = self._offers[sid].session
        return self.session

    def refuse_session(self, sid: int, now_s: float) -> bytes | None:
        """A REFUSE for the master of offered session ``sid`` (not the one taken), at most every
        :data:`REFUSE_EVERY_S`; None when told recently."""
        o = self._offers[sid]
        if now_s - o.refused_s < REFUSE_EVERY_S:
            return None
        o.refused_s = now_s
        return self._refuse(o.nonce_m)

    def _refuse(self, nonce_m: bytes) -> bytes:
        s = self.session
        assert s is not None, "a slave refuses only once paired"
        body = _REPLY.pack(nonce_m, bytes(NONCE), self.keys.name.encode(), s.master.encode(), s.id)
        return wire.seal(wire.TYPE_REFUSE, 0, 0, 0, body, self.mac)
