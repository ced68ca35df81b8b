"""Reading a record back: :func:`read_record` gives each channel as arrays.

The file is read front to back with ``mcap``'s stream reader (no seeking, no summary needed), so
a record whose process was killed reads up to its last whole chunk: the truncated tail is
reported in :attr:`Record.error`, not raised. The ROS 2 messages are decoded by
``mcap-ros2-support``'s decoder (the maintained one, from the schemas the file carries), the JSON
ones by :mod:`json`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from teleop.app.record import schemas
from teleop.app.record.cdr import rotation


@dataclass
class Channel:
    """One channel's messages in log-time order: ``t_ns`` log times (ns), ``t_s`` the same in s,
    ``seq`` sequence numbers (the tick's index), ``fields`` the values as arrays (per schema:
    PoseStamped ``p`` (n, 3), ``q`` (n, 4: x, y, z, w), ``R`` (n, 3, 3); TwistStamped ``v``,
    ``w``; WrenchStamped ``force``, ``torque``, ``W`` (n, 6); JointState ``position``,
    ``velocity``; JSON every key, nested ones dotted (``guard.W_J``), numbers as arrays, the rest
    as lists); ``frames`` for TFMessage: child -> {"parent", "p", "q", "R"}; ``names`` a
    JointState's joint names; ``messages`` the decoded messages (JSON: dicts)."""

    topic: str
    schema: str
    encoding: str
    t_ns: np.ndarray
    seq: np.ndarray
    fields: dict = field(default_factory=dict)
    frames: dict = field(default_factory=dict)
    names: list = field(default_factory=list)
    messages: list = field(default_factory=list)

    @property
    def t_s(self) -> np.ndarray:
        return self.t_ns * 1e-9

    def __len__(self) -> int:
        return len(self.t_ns)

    def __getitem__(self, key: str) -> Any:
        return self.fields[key]


@dataclass
class Record:
    """A record read back: ``channels`` by topic, the file's ``metadata`` records by name, its
    ``attachments`` (name -> bytes), ``complete`` (the file ended with its footer: closed
    properly), ``error`` why reading stopped short (a truncated file), or None."""

    channels: dict
    metadata: dict
    complete: bool
    error: str | None = None
    attachments: dict = field(default_factory=dict)

    def __getitem__(self, topic: str) -> Channel:
        return self.channels[topic]

    def __contains__(self, topic: str) -> bool:
        return topic in self.channels

    @property
    def topics(self) -> list[str]:
        return sorted(self.channels)


def _vec(msgs: list, get) -> np.ndarray:
    return np.array([get(m) for m in msgs], dtype=float).reshape(len(msgs), -1)


def _xyz(v) -> tuple[float, float, float]:
    return (v.x, v.y, v.z)


def _xyzw(v) -> tuple[float, float, float, float]:
    return (v.x, v.y, v.z, v.w)


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[prefix + k] = v
    return out


def _columns(dicts: list[dict]) -> dict:
    flat = [_flatten(d) for d in dicts]
    keys: list[str] = []
    for f in flat:
        keys.extend(k for k in f if k not in keys)
    out: dict = {}
    for k in keys:
        vals = [f.get(k) for f in flat]
        present = [v for v in vals if v is not None]
        numeric = present and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present)
        numlists = present and all(isinstance(v, list) and all(isinstance(x, (int, float)) for x in v) for v in present)
        if numeric:
            out[k] = np.array([np.nan if v is None else v for v in vals], dtype=float)
        elif present and all(isinstance(v, bool) for v in present) and len(present) == len(vals):
            out[k] = np.array(vals, dtype=bool)
        elif numlists and len(present) == len(vals) and len({len(v) for v in present}) == 1:
            out[k] = np.array(vals, dtype=float)
        else:
            out[k] = vals
    return out


def _fill(ch: Channel, msgs: list) -> None:
    s = ch.schema
    if ch.encoding == "json":
        ch.fields = _columns(msgs)
    elif s == schemas.POSE:
        ch.fields["p"] = _vec(msgs, lambda m: _xyz(m.pose.position))
        ch.fields["q"] = _vec(msgs, lambda m: _xyzw(m.pose.orientation))
        ch.fields["R"] = rotation(ch.fields["q"])
    elif s == schemas.TWIST:
        ch.fields["v"] = _vec(msgs, lambda m: _xyz(m.twist.linear))
        ch.fields["w"] = _vec(msgs, lambda m: _xyz(m.twist.angular))
    elif s == schemas.WRENCH:
        ch.fields["force"] = _vec(msgs, lambda m: _xyz(m.wrench.force))
        ch.fields["torque"] = _vec(msgs, lambda m: _xyz(m.wrench.torque))
        ch.fields["W"] = np.concatenate((ch.fields["force"], ch.fields["torque"]), 1)
    elif s == schemas.JOINTS:
        ch.names = list(msgs[0].name) if msgs else []
        ch.fields["position"] = _vec(msgs, lambda m: m.position)
        ch.fields["velocity"] = _vec(msgs, lambda m: m.velocity)
    elif s == schemas.TF:
        frames: dict = {}
        for k, m in enumerate(msgs):
            for tr in m.transforms:
                f = frames.setdefault(tr.child_frame_id, {"parent": tr.header.frame_id, "k": [], "p": [], "q": []})
                f["k"].append(k)
                f["p"].append(_xyz(tr.transform.translation))
                f["q"].append(_xyzw(tr.transform.rotation))
        for f in frames.values():
            f["p"], f["q"] = np.array(f["p"], float), np.array(f["q"], float)
            f["R"] = rotation(f["q"])
            f["t_ns"] = ch.t_ns[np.array(f.pop("k"), dtype=np.intp)]
        ch.frames = frames


@dataclass
class RawRecord:
    """A record's messages as stored, not decoded: ``messages`` by topic, in log-time order, each
    (log time ns, sequence, bytes); ``schemas`` by topic (name, encoding, data), ``encodings`` the
    topics' message encodings; ``metadata``, ``attachments``, ``complete`` and ``error`` as in
    :class:`Record`."""

    messages: dict
    schemas: dict
    encodings: dict
    metadata: dict
    attachments: dict
    complete: bool
    error: str | None = None


def scan_record(path: str | Path, topics=None) -> RawRecord:
    """The record at ``path`` read front to back, its messages left as bytes (see
    :class:`RawRecord`; only ``topics`` if given). A file cut short reads up to its last whole
    record, the reason in ``error``."""
    from mcap.records import Attachment, Footer, Message, Metadata, Schema
    from mcap.records import Channel as McapChannel
    from mcap.stream_reader import StreamReader

    wanted = None if topics is None else set([topics] if isinstance(topics, str) else topics)
    sch: dict[int, Schema] = {}
    chans: dict[int, McapChannel] = {}
    raw: dict[int, list] = {}
    metadata: dict = {}
    attachments: dict = {}
    complete, error = False, None
    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f, record_size_limit=None).records:
                if isinstance(rec, Schema):
                    sch[rec.id] = rec
                elif isinstance(rec, McapChannel):
                    chans[rec.id] = rec
                elif isinstance(rec, Message):
                    c = chans.get(rec.channel_id)
                    if c is None or (wanted is not None and c.topic not in wanted):
                        continue
                    raw.setdefault(rec.channel_id, []).append((rec.log_time, rec.sequence, rec.data))
                elif isinstance(rec, Metadata):
                    metadata[rec.name] = dict(rec.metadata)
                elif isinstance(rec, Attachment):
                    attachments[rec.name] = bytes(rec.data)
                elif isinstance(rec, Footer):
                    complete = True
        except Exception as e:  # a truncated tail: keep what came before it
            error = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
    messages, schemas_, encodings = {}, {}, {}
    for cid, items in raw.items():
        c = chans[cid]
        items.sort(key=lambda x: x[0])
        messages[c.topic] = items
        s = sch.get(c.schema_id)
        schemas_[c.topic] = (s.name, s.encoding, bytes(s.data)) if s is not None else ("", "", b"")
        encodings[c.topic] = c.message_encoding
    return RawRecord(messages, schemas_, encodings, metadata, attachments, complete, error)


def decoder(raw: RawRecord, topic: str):
    """A function decoding one message of ``topic`` (JSON: a dict; ROS 2: mcap-ros2-support's
    decoded message), or None when there is none for its encoding."""
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory

    if raw.encodings[topic] == "json":
        return json.loads
    name, encoding, data = raw.schemas[topic]
    return DecoderFactory().decoder_for(raw.encodings[topic], Schema(id=1, name=name, encoding=encoding, data=data))


def read_record(path: str | Path, topics=None, keep_messages: bool = False) -> Record:
    """The record at ``path`` (see :class:`Record`), only ``topics`` if given. Reads a file cut
    short (a killed process) up to its last whole record. ``keep_messages``: keep the decoded
    messages in each :attr:`Channel.messages`."""
    raw = scan_record(path, topics)
    out: dict = {}
    for topic, items in raw.messages.items():
        dec = decoder(raw, topic)
        msgs = [dec(d) for _, _, d in items] if dec is not None else [d for _, _, d in items]
        ch = Channel(topic, raw.schemas[topic][0], raw.encodings[topic],
                     np.array([x[0] for x in items], dtype=np.int64), np.array([x[1] for x in items], dtype=np.int64))
        _fill(ch, msgs)
        if keep_messages:
            ch.messages = msgs
        out[topic] = ch
    return Record(out, raw.metadata, raw.complete, raw.error, raw.attachments)


def recover(path: str | Path, out: str | Path | None = None) -> tuple[Path, int]:
    """A finished copy of the record at ``path`` that was cut short (its writer killed): every
    schema, channel, message, metadata record and attachment up to its last whole record, written
    again by ``mcap``'s writer with a summary section, so that any reader (``mcap``'s seeking
    reader, which reads the footer first, or Foxglove's) opens it. ``out`` defaults to
    ``<name>.recovered.mcap`` beside it. A record written with ``spool=True`` whose writer was
    killed left ``<path>.spool`` (``path`` may name either): it becomes the MCAP file ``out``
    (default: ``path``). Returns (the file's path, messages written)."""
    spool = Path(path) if str(path).endswith(".spool") else Path(str(path) + ".spool")
    if spool.exists():
        from teleop.app.record.serve import convert

        target = Path(out) if out is not None else Path(str(spool)[: -len(".spool")])
        return target, int(convert(str(spool), str(target)).get("messages", 0))
    from mcap.records import Attachment, Message, Metadata, Schema
    from mcap.records import Channel as McapChannel
    from mcap.stream_reader import StreamReader
    from mcap.writer import Writer

    src = Path(path)
    dst = Path(out) if out is not None else src.with_name(src.stem + ".recovered.mcap")
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    n = 0
    with open(src, "rb") as f, open(dst, "wb") as g:
        w = Writer(g)
        w.start(profile="", library="teleop.app.record.recover")
        try:
            for rec in StreamReader(f, record_size_limit=None).records:
                if isinstance(rec, Schema):
                    schema_ids[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
                elif isinstance(rec, McapChannel):
                    channel_ids[rec.id] = w.register_channel(rec.topic, rec.message_encoding,
                                                             schema_ids.get(rec.schema_id, 0), dict(rec.metadata))
                elif isinstance(rec, Message) and rec.channel_id in channel_ids:
                    w.add_message(channel_ids[rec.channel_id], rec.log_time, rec.data, rec.publish_time, rec.sequence)
                    n += 1
                elif isinstance(rec, Metadata):
                    w.add_metadata(rec.name, dict(rec.metadata))
                elif isinstance(rec, Attachment):
                    w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
        except Exception:  # the cut: everything before it is copied
            pass
        w.finish()
    return dst, n
