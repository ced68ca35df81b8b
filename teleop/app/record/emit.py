"""What the rows become: the writer process's side of the record (:mod:`teleop.app.record.serve`).

A side's capture fills rows of numbers laid out by a :class:`~teleop.app.rows.RowLayout`
(:mod:`teleop.app.recorders`, handed over by :mod:`teleop.app.record.hooks`);
here each batch of rows becomes the side's messages: the ROS 2 ones laid out by
:mod:`teleop.app.record.cdr`, the JSON ones by a :class:`JsonTemplate`, all added through the
``mcap`` package's writer (:class:`McapOut`), which closes and flushes a chunk whenever it holds
``flush_s`` of the run's time or has been open ``flush_s`` of the wall clock.
"""

from __future__ import annotations

import json
import math
import struct
import time
from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from teleop.app.record import schemas
from teleop.app.record.cdr import (
    Layout,
    joint_state,
    pose_stamped,
    quat_xyzw,
    stamp,
    tf_message,
    wrench_stamped,
)
from teleop.app.rows import RowLayout

#: one CAN frame in its ring: bus time (s), id, rx, fd, error, dlc, payload length, payload
CAN_ROW = struct.Struct("<dIBBBBB64s")


_JB = ("false", "true")


class _Null:
    def __repr__(self) -> str:
        return "null"


_NULL = _Null()


class JsonTemplate:
    """A JSON object with a fixed set of keys, rendered from a row of numbers by one %-format.
    ``num``, ``integer``, ``boolean``, ``vec`` and ``string`` (a status code into ``names``) take
    their value from column(s) of the row; ``open``/``close`` nest an object, ``null`` writes a
    key whose value is null. Values that are not finite are written as null."""

    def __init__(self) -> None:
        self._parts: list[str] = []
        self._cols: list[int] = []
        self._kinds: list[str] = []
        self._first = True

    def _key(self, key: str) -> None:
        self._parts.append((("" if self._first else ",") + json.dumps(key) + ":").replace("%", "%%"))
        self._first = False

    def _one(self, key: str, col: int, fmt: str, kind: str) -> JsonTemplate:
        self._key(key)
        self._parts.append(fmt)
        self._cols.append(col)
        self._kinds.append(kind)
        return self

    def num(self, key: str, col: int) -> JsonTemplate:
        return self._one(key, col, "%r", "f")

    def integer(self, key: str, col: int) -> JsonTemplate:
        return self._one(key, col, "%s", "i")

    def boolean(self, key: str, col: int) -> JsonTemplate:
        return self._one(key, col, "%s", "b")

    def string(self, key: str, col: int) -> JsonTemplate:
        return self._one(key, col, "%s", "s")

    def vec(self, key: str, cols: slice) -> JsonTemplate:
        self._key(key)
        n = cols.stop - cols.start
        self._parts.append("[" + ",".join(["%r"] * n) + "]")
        self._cols.extend(range(cols.start, cols.stop))
        self._kinds.extend("f" * n)
        return self

    def open(self, key: str | None = None) -> JsonTemplate:
        if key is not None:
            self._key(key)
        self._parts.append("{")
        self._first = True
        return self

    def close(self) -> JsonTemplate:
        self._parts.append("}")
        self._first = False
        return self

    def null(self, key: str) -> JsonTemplate:
        self._key(key)
        self._parts.append("null")
        return self

    def compile(self) -> JsonTemplate:
        self.fmt = "".join(self._parts)
        self.index = np.array(self._cols, dtype=np.intp)
        self.ints = [k for k, c in enumerate(self._kinds) if c == "i"]
        self.bools = [k for k, c in enumerate(self._kinds) if c == "b"]
        self.strs = [k for k, c in enumerate(self._kinds) if c == "s"]
        return self

    def render(self, rows: np.ndarray, names: dict) -> list[bytes]:
        """One JSON text per row of ``rows`` (k, width); ``names`` the status strings by code."""
        vals = rows[:, self.index]
        finite = np.isfinite(vals).all(axis=1)
        out = []
        ints, bools, strs, fmt = self.ints, self.bools, self.strs, self.fmt
        for k, row in enumerate(vals.tolist()):
            if not finite[k]:
                row = [x if math.isfinite(x) else _NULL for x in row]
            for j in ints:
                if row[j] is not _NULL:
                    row[j] = int(row[j])
            for j in bools:
                row[j] = "null" if row[j] is _NULL else "true" if row[j] else "false"
            for j in strs:
                row[j] = "null" if row[j] is _NULL else json.dumps(names.get(int(row[j]), f"?{int(row[j])}"))
            out.append((fmt % tuple(row)).encode())
        return out


class McapOut:
    """The ``mcap`` writer of one record (only the writer process touches it): schemas and
    channels registered once, messages added tick by tick, chunks closed and flushed by time."""

    def __init__(self, path: str, metadata: dict, flush_s: float, chunk_bytes: int, compression: str) -> None:
        from mcap.writer import CompressionType, Writer

        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[compression]
        self.file = open(path, "wb")  # open until finish()
        self.mcap = Writer(self.file, chunk_size=int(chunk_bytes), compression=comp)
        self.mcap.start(profile="", library="teleop.app.record")
        self.mcap.add_metadata("teleop", {str(k): str(v) for k, v in metadata.items()})
        self.flush_s = float(flush_s)
        self._schemas: dict[tuple[str, str], int] = {}
        self._channels: dict[str, int] = {}
        self._static: set[tuple[str, str]] = set()
        self.messages = self.chunks = 0
        self._unflushed = 0
        self._flush_wall = time.monotonic()
        self._flush_log: int | None = None
        self._last_log = 0
        self.flush()

    def schema(self, name: str, encoding: str, data: bytes) -> int:
        key = (name, encoding)
        sid = self._schemas.get(key)
        if sid is None:
            sid = self._schemas[key] = self.mcap.register_schema(name, encoding, data)
        return sid

    def ros_channel(self, topic: str, datatype: str) -> int:
        return self._channel(topic, "cdr", self.schema(datatype, "ros2msg", schemas.msgdef(datatype).encode()))

    def json_channel(self, topic: str, schema: dict) -> int:
        return self._channel(topic, "json", self.schema(schema["title"], "jsonschema", schemas.json_schema(schema)))

    def _channel(self, topic: str, encoding: str, sid: int) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            cid = self._channels[topic] = self.mcap.register_channel(topic, encoding, sid)
        return cid

    def _count(self, n: int, first: int, last: int) -> None:
        self.messages += n
        self._unflushed += n
        self._last_log = max(self._last_log, last)
        if self._flush_log is None:
            self._flush_log = first

    def add_ticks(self, log_ns: np.ndarray, seq: np.ndarray, channels: list[tuple[int, list[bytes]]]) -> None:
        """A batch of ticks: their log times (ns), sequence numbers (the ticks' indices) and, per
        channel, one message per tick; added tick by tick."""
        add = self.mcap.add_message
        for k, (t, s) in enumerate(zip(log_ns.tolist(), seq.tolist())):
            s &= 0xFFFFFFFF
            for cid, data in channels:
                add(cid, t, data[k], t, s)
        if len(log_ns):
            self._count(len(log_ns) * len(channels), int(log_ns[0]), int(log_ns[-1]))

    def add_one(self, channel: int, log_ns: int, data: bytes, seq: int = 0) -> None:
        self.mcap.add_message(channel, log_ns, data, log_ns, seq & 0xFFFFFFFF)
        self._count(1, log_ns, log_ns)

    def static_tf(self, parent: str, child: str, p: Any, R: Any) -> None:
        """A transform on ``/tf_static`` (once per (parent, child)), at log time 0."""
        if (parent, child) in self._static:
            return
        self._static.add((parent, child))
        lay: Layout = tf_message([(parent, child)])
        _, sec, nsec = stamp(np.zeros(1))
        data = lay.encode(1, {"sec": sec, "nanosec": nsec, "p0": np.asarray(p, float)[None],
                              "q0": quat_xyzw(np.asarray(R, float)[None])})
        self.add_one(self.ros_channel("/tf_static", schemas.TF), 0, data[0])

    def maybe_flush(self, force: bool = False) -> None:
        if not self._unflushed:
            return
        now = time.monotonic()
        if force or now - self._flush_wall >= self.flush_s or \
                self._last_log - (self._flush_log or 0) >= self.flush_s * 1e9:
            self.flush()

    def flush(self) -> None:
        """Close the chunk in progress and hand the file's bytes to the operating system."""
        self.mcap.flush()
        self.chunks += self._unflushed > 0
        self._unflushed = 0
        self._flush_wall = time.monotonic()
        self._flush_log = None

    def finish(self, stats: dict) -> None:
        self.flush()
        self.mcap.add_metadata("teleop.record", {k: str(v) for k, v in stats.items()})
        self.mcap.finish()
        self.file.close()


def _R(rows: np.ndarray, cols: slice) -> np.ndarray:
    return rows[:, cols].reshape(-1, 3, 3)


def _eye_q(n: int) -> np.ndarray:
    q = np.zeros((n, 4))
    q[:, 3] = 1.0
    return q


class Emitter(ABC):
    """A side's rows into its channels; ``meta`` is what its hook said at its first tick."""

    def __init__(self, out: McapOut, meta: dict) -> None:
        self.out, self.meta = out, meta
        self.cols = RowLayout(meta["cols"])
        self.prefix = meta["prefix"]
        self.names: dict[int, str] = {}
        reg = meta.get("registration")
        if reg is not None:
            out.static_tf("patient", "master", *reg)

    @abstractmethod
    def emit(self, rows: np.ndarray) -> None:
        """A batch of rows (one per tick, the layout's columns) as the side's messages."""


class MasterEmitter(Emitter):
    def __init__(self, out: McapOut, meta: dict) -> None:
        super().__init__(out, meta)
        p, c, w = self.prefix, self.cols, self.cols.width
        self.nj, self.guarded = meta["nj"], meta["guarded"]
        self.ch = {k: out.ros_channel(f"{p}/{k}", dt) for k, dt in (
            ("tool_pose", schemas.POSE), ("hand_wrench", schemas.WRENCH), ("felt_wrench", schemas.WRENCH),
            ("tf", schemas.TF))}
        if self.nj:
            self.ch["joints"] = out.ros_channel(f"{p}/joints", schemas.JOINTS)
            self.lay_joints = joint_state(meta["joint_names"], velocity=False)
        self.ch["state"] = out.json_channel(f"{p}/state", schemas.MASTER_STATE)
        self.lay_pose, self.lay_wrench = pose_stamped("master"), wrench_stamped("reference_tool_M")
        frames = [("master", "reference_tool"), ("master", "reference_tool_M")]
        if self.nj:
            frames.append(("master", "device"))
        self.lay_tf = tf_message(frames)
        j = JsonTemplate().open()
        j.integer("tick", c.col("i")).num("t_s", c.col("t")).num("wall_time_s", c.col("wall"))
        j.string("status", c.col("status")).num("gain", c.col("gain")).boolean("heartbeat_lost", c.col("lost"))
        j.boolean("peer_lost", c.col("peer_lost")).num("tick_us", w + 0).integer("command_errors", c.col("cmd_err"))
        j.num("hand_force_N", w + 1).num("felt_force_N", w + 2)
        j.vec("tool_twist", c["V"]).vec("feedback_wrench", c["fb"])
        if self.guarded:
            j.open("guard").vec("W_J", c["gW"]).vec("E_diss_J", c["gE"]).vec("alpha", c["gA"]).close()
        else:
            j.null("guard")
        self.json = j.close().compile()

    def emit(self, rows: np.ndarray) -> None:
        c, n = self.cols, len(rows)
        ns, sec, nsec = stamp(rows[:, c.col("t")])
        seq = rows[:, c.col("i")].astype(np.int64)
        h = {"sec": sec, "nanosec": nsec}
        p, q = rows[:, c["p"]], quat_xyzw(_R(rows, c["R"]))
        hand, felt = rows[:, c["hand"]], rows[:, c["felt"]]
        tf = {**h, "p0": p, "q0": q, "p1": p, "q1": _eye_q(n)}
        chans = [(self.ch["tool_pose"], self.lay_pose.encode(n, {**h, "p": p, "q": q})),
                 (self.ch["hand_wrench"], self.lay_wrench.encode(n, {**h, "f": hand[:, :3], "tau": hand[:, 3:]})),
                 (self.ch["felt_wrench"], self.lay_wrench.encode(n, {**h, "f": felt[:, :3], "tau": felt[:, 3:]}))]
        if self.nj:
            tf.update(p2=rows[:, c["dev_p"]], q2=quat_xyzw(_R(rows, c["dev_R"])))
            chans.append((self.ch["joints"], self.lay_joints.encode(n, {**h, "position": rows[:, c["joints"]]})))
        chans.append((self.ch["tf"], self.lay_tf.encode(n, tf)))
        derived = np.stack((rows[:, c.col("tick_ns")] * 1e-3, np.linalg.norm(hand[:, :3], axis=1),
                            np.linalg.norm(felt[:, :3], axis=1)), 1)
        chans.append((self.ch["state"], self.json.render(np.concatenate((rows, derived), 1), self.names)))
        self.out.add_ticks(ns, seq, chans)

    def emit_can(self, frames: np.ndarray) -> None:
        """CAN frames (rows of :data:`CAN_ROW` bytes) on ``<prefix>/can``, at the run's time."""
        out = self.out
        cid = out.json_channel(f"{self.prefix}/can", schemas.CAN_FRAME)
        t0 = float(self.meta.get("can_t0") or 0.0)
        for raw in frames:
            t, fid, rx, fd, err, dlc, ln, data = CAN_ROW.unpack(raw.tobytes())
            ts = t - t0
            text = (f'{{"t_s":{ts!r},"bus_t_s":{t!r},"id":{fid},"rx":{_JB[bool(rx)]},"fd":{_JB[bool(fd)]},'
                    f'"error":{_JB[bool(err)]},"dlc":{dlc},"data":"{data[:ln].hex()}"}}')
            out.add_one(cid, max(0, round(ts * 1e9)), text.encode())


class SlaveEmitter(Emitter):
    def __init__(self, out: McapOut, meta: dict) -> None:
        super().__init__(out, meta)
        p, c, w = self.prefix, self.cols, self.cols.width
        self.guarded = meta["guarded"]
        self.ch = {k: out.ros_channel(f"{p}/{k}", dt) for k, dt in (
            ("tool_pose", schemas.POSE), ("target_pose", schemas.POSE), ("contact", schemas.WRENCH),
            ("joints", schemas.JOINTS), ("tf", schemas.TF))}
        self.ch["state"] = out.json_channel(f"{p}/state", schemas.SLAVE_STATE)
        self.lay_pose, self.lay_wrench = pose_stamped("patient"), wrench_stamped("blade_tip")
        self.lay_joints = joint_state(meta["joint_names"])
        self.lay_tf = tf_message([("patient", "slave_tool"), ("patient", "slave_target"), ("patient", "blade_tip")])
        j = JsonTemplate().open()
        j.integer("tick", c.col("i")).num("t_s", c.col("t")).num("wall_time_s", c.col("wall"))
        j.string("status", c.col("status")).boolean("heartbeat_lost", c.col("lost")).num("tick_us", w + 0)
        j.integer("last_command_seq", c.col("last_seq")).integer("ticks_without_command", c.col("without"))
        j.integer("commands_skipped", c.col("skipped"))
        j.num("tracking_error_m", w + 1).num("tracking_error_rad", w + 2).num("contact_force_N", w + 3)
        j.vec("tool_twist", slice(c.col("v"), c.col("v") + 6))
        if self.guarded:
            j.open("guard").vec("W_J", c["gW"]).vec("E_diss_J", c["gE"]).vec("drift_M", c["gD"]).close()
        else:
            j.null("guard")
        self.json = j.close().compile()

    def emit(self, rows: np.ndarray) -> None:
        c, n = self.cols, len(rows)
        ns, sec, nsec = stamp(rows[:, c.col("t")])
        seq = rows[:, c.col("i")].astype(np.int64)
        h = {"sec": sec, "nanosec": nsec}
        R, R_t = _R(rows, c["R"]), _R(rows, c["R_t"])
        p, p_t, tip, F = rows[:, c["p"]], rows[:, c["p_t"]], rows[:, c["tip"]], rows[:, c["contact"]]
        q, q_t = quat_xyzw(R), quat_xyzw(R_t)
        chans = [
            (self.ch["tool_pose"], self.lay_pose.encode(n, {**h, "p": p, "q": q})),
            (self.ch["target_pose"], self.lay_pose.encode(n, {**h, "p": p_t, "q": q_t})),
            (self.ch["contact"], self.lay_wrench.encode(n, {**h, "f": F[:, :3], "tau": F[:, 3:]})),
            (self.ch["joints"], self.lay_joints.encode(n, {**h, "position": rows[:, c["q"]],
                                                           "velocity": rows[:, c["qd"]]})),
            (self.ch["tf"], self.lay_tf.encode(n, {**h, "p0": p, "q0": q, "p1": p_t, "q1": q_t, "p2": tip,
                                                   "q2": _eye_q(n)})),
        ]
        cos = (np.einsum("kij,kij->k", R_t, R) - 1.0) / 2.0  # trace(R_t^T R) = sum of the products
        derived = np.stack((rows[:, c.col("tick_ns")] * 1e-3, np.linalg.norm(p - p_t, axis=1),
                            np.arccos(np.clip(cos, -1.0, 1.0)), np.linalg.norm(F[:, :3], axis=1)), 1)
        chans.append((self.ch["state"], self.json.render(np.concatenate((rows, derived), 1), self.names)))
        self.out.add_ticks(ns, seq, chans)


class LinkEmitter(Emitter):
    """A side's link, tick by tick, on ``<prefix>/link`` (JSON): its delivery schedule and stamps
    (:mod:`teleop.link.schedule`)."""

    def __init__(self, out: McapOut, meta: dict) -> None:
        super().__init__(out, meta)
        c = self.cols
        self.ch = out.json_channel(f"{self.prefix}/link", schemas.LINK_TICK)
        j = JsonTemplate().open()
        j.integer("tick", c.col("i")).num("t_s", c.col("t")).integer("seq", c.col("seq"))
        j.boolean("hello", c.col("hello")).num("clock_s", c.col("clock_s")).num("heard_s", c.col("heard_s"))
        j.num("sent_s", c.col("sent_s")).vec("chain_s", c["chain"])
        self.json = j.close().compile()

    def emit(self, rows: np.ndarray) -> None:
        ns, _, _ = stamp(rows[:, self.cols.col("t")])
        self.out.add_ticks(ns, rows[:, self.cols.col("i")].astype(np.int64),
                           [(self.ch, self.json.render(rows, self.names))])


EMITTERS = {"master": MasterEmitter, "slave": SlaveEmitter, "link": LinkEmitter}
