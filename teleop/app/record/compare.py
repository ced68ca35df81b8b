"""Two records of one run compared bit for bit: the first tick and field where they differ.

Every message of every channel is compared as stored: a ROS 2 (CDR) message byte for byte, a JSON
message value for value (a number by its 64 bits, so -0.0 is not 0.0), except the fields that are
the recording host's clock or CPU time and no state of the run (:data:`NOT_STATE`). The first
difference is the one of the earliest tick (a message's tick is its sequence number; a CAN
frame's, the tick whose period its time falls in), and within it the first topic in name order
and the first field in the message's order; a channel that ends early (or goes on) differs at the
tick of its first missing message.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from typing import Any

from teleop.app.record.reader import RawRecord, decoder

#: JSON fields that are the recording host's wall clock or a CPU time, not the run's state
NOT_STATE = ("wall_time_s", "tick_us")
_MISSING = object()


@dataclass(frozen=True)
class Difference:
    """Where two records first differ: ``tick`` (its time ``t_s``, s), ``topic``, ``field`` (a
    dotted path, ``[k]`` for an item; "" for a missing message), the ``recorded`` and ``replayed``
    values (reprs)."""

    tick: int
    t_s: float
    topic: str
    field: str
    recorded: str
    replayed: str

    def text(self) -> str:
        where = f"{self.topic} {self.field}" if self.field else self.topic
        return f"tick {self.tick} (t = {self.t_s:.6g} s): {where}: recorded {self.recorded}, replayed {self.replayed}"


def _tick(topic: str, item: tuple, dt_ns: int) -> int:
    log_ns, seq, _ = item
    if topic.endswith("/can"):  # a frame in (i dt, (i + 1) dt] is tick i's
        return max(0, -(-log_ns // dt_ns) - 1)
    return int(seq)


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return struct.pack("<d", a) == struct.pack("<d", b)
    return type(a) is type(b) and a == b


def _leaves(x: Any, path: str = ""):
    """(path, value) of every leaf of a decoded message, in its order."""
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _leaves(v, f"{path}.{k}" if path else str(k))
    elif isinstance(x, (list, tuple)):
        for k, v in enumerate(x):
            yield from _leaves(v, f"{path}[{k}]")
    elif hasattr(x, "__slots__") and not isinstance(x, (str, bytes, int, float, bool)):
        for k in x.__slots__:
            yield from _leaves(getattr(x, k), f"{path}.{k}" if path else k)
    else:
        yield path, x


def _state(msg: dict) -> dict:
    return {k: v for k, v in msg.items() if k not in NOT_STATE}


def _field(a: Any, b: Any) -> tuple[str, str, str]:
    """The first leaf where decoded messages ``a`` and ``b`` differ: (path, repr a, repr b)."""
    la, lb = dict(_leaves(a)), dict(_leaves(b))
    for k, v in la.items():
        w = lb.get(k, _MISSING)
        if w is _MISSING or not _same(v, w):
            return k, repr(v), "absent" if w is _MISSING else repr(w)
    for k, w in lb.items():
        if k not in la:
            return k, "absent", repr(w)
    return "", "(the same values, other bytes)", ""


def _first_in(topic: str, a: list, b: list, raw_a: RawRecord, raw_b: RawRecord, dt_ns: int) -> Difference | None:
    """The first difference on one topic, or None."""
    json_topic = raw_a.encodings[topic] == "json"
    dec = None
    for k in range(min(len(a), len(b))):
        da, db = a[k][2], b[k][2]
        if json_topic:
            ma, mb = _state(json.loads(da)), _state(json.loads(db))
            if a[k][0] == b[k][0] and ma.keys() == mb.keys() and all(_same_tree(ma[x], mb[x]) for x in ma):
                continue
            path, ra, rb = _field(ma, mb) if a[k][0] == b[k][0] else ("log_time", str(a[k][0]), str(b[k][0]))
        else:
            if da == db and a[k][0] == b[k][0]:
                continue
            if a[k][0] != b[k][0]:
                path, ra, rb = "log_time", str(a[k][0]), str(b[k][0])
            else:
                dec = dec or decoder(raw_a, topic)
                path, ra, rb = _field(dec(da), dec(db)) if dec is not None else ("", "bytes", "other bytes")
        tick = _tick(topic, a[k], dt_ns)
        return Difference(tick, tick * dt_ns * 1e-9, topic, path, ra, rb)
    if len(a) == len(b):
        return None
    k = min(len(a), len(b))
    item = (a if len(a) > k else b)[k]
    tick = _tick(topic, item, dt_ns)
    ra, rb = ("a message", "none (the replay ended)") if len(a) > k else ("none (the run ended)", "a message")
    return Difference(tick, tick * dt_ns * 1e-9, topic, "", ra, rb)


def _same_tree(a: Any, b: Any) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same_tree(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(_same_tree(x, y) for x, y in zip(a, b))
    return _same(a, b)


def first_difference(recorded: RawRecord, replayed: RawRecord, topics: list[str], dt_s: float) -> Difference | None:
    """The first difference between two records on ``topics`` (see the module docstring), or
    None when every message is the same. A topic one record lacks differs at its first message."""
    dt_ns = max(1, round(dt_s * 1e9))
    found: list[tuple[int, str, Difference]] = []
    for topic in sorted(topics):
        a, b = recorded.messages.get(topic, []), replayed.messages.get(topic, [])
        if topic not in replayed.encodings and a:
            tick = _tick(topic, a[0], dt_ns)
            d = Difference(tick, tick * dt_s, topic, "", "a channel", "none (not in the replay)")
        elif topic not in recorded.encodings and b:
            tick = _tick(topic, b[0], dt_ns)
            d = Difference(tick, tick * dt_s, topic, "", "none (not in the record)", "a channel")
        elif not a and not b:
            continue
        else:
            d = _first_in(topic, a, b, recorded, replayed, dt_ns)
        if d is not None:
            found.append((d.tick, topic, d))
    return min(found, key=lambda x: (x[0], x[1]))[2] if found else None


def count_messages(raw: RawRecord, topics: list[str]) -> int:
    """Messages of ``topics`` in ``raw``."""
    return sum(len(raw.messages.get(t, [])) for t in topics)


__all__ = ["NOT_STATE", "Difference", "count_messages", "first_difference"]
