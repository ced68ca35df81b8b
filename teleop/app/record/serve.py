"""The writer of a record: :class:`Server` takes the rows the hooks publish and writes them. It
runs either as a process of its own (the default: ``python -m teleop.app.record.serve FD SIZE
PARENT_PID``, started by :class:`teleop.app.record.writer.RecordWriter`: the shared memory ``FD``
of ``SIZE`` bytes holds the rings, stdin brings length-prefixed pickles) or as a thread of the
run's process (``RecordWriter(mode="thread")``: the messages come through a queue).

Messages: ("open", path, metadata, options), ("source", sid, kind, offset, capacity, width, meta,
can_offset), ("name", sid, code, status), ("meta", sid, {...}), ("event", ...), ("attach", name,
data, media_type), ("json", topic, schema, log_ns, data, seq), ("metadata", name, values), ("close",
stats). The process ends when told to close or when its parent is gone (stdin at its end, or
another parent): either way it takes every row published, finishes the file and prints its
counts as one JSON line. It ignores SIGINT (a Ctrl-C is the run's to handle)
and finishes on SIGTERM or SIGHUP as on a close.
"""

from __future__ import annotations

import json
import mmap
import os
import pickle
import signal
import struct
import sys
import time
import traceback

import numpy as np

from teleop.app.record.emit import CAN_ROW, EMITTERS, McapOut

POLL_S = 0.01  # the sleep when nothing is pending (s): batches of ~10 ticks at 1 kHz
#: ticks a side taken at once, in a process of its own and in a thread of the run; between two
#: slices the writer sleeps YIELD_S, giving its core (and, as a thread, the GIL) back, so a tick
#: waits for it at most a slice. A sleep, not sched_yield: on Linux 6.18 (EEVDF) a writer that
#: yielded beside two pinned sides spinning on sched_yield was left runnable and unscheduled for
#: seconds (its /proc/PID/schedstat run time frozen).
SLICE_ROWS = {"process": 8, "thread": 2}
YIELD_S = 2e-4
_HEADER = 128
_LEN = struct.Struct("<I")


class _Reader:
    """The rows of one ring, as the writer sees them."""

    def __init__(self, region: mmap.mmap, offset: int, cap: int, width: int | None, row_bytes: int,
                 slice_rows: int | None) -> None:
        self.hdr = np.frombuffer(region, np.int64, count=_HEADER // 8, offset=offset)
        self.cap, self.r, self.slice = cap, 0, slice_rows
        self.rows: np.ndarray
        if width is not None:
            self.rows = np.frombuffer(region, np.float64, count=cap * width, offset=offset + _HEADER).reshape(
                cap, width
            )
        else:
            self.rows = np.frombuffer(region, np.uint8, count=cap * row_bytes,
                                      offset=offset + _HEADER).reshape(cap, row_bytes)

    def take(self, w: int) -> np.ndarray | None:
        if self.slice is not None:
            w = min(w, self.r + self.slice)
        if w <= self.r:
            return None
        idx = np.arange(self.r, w) % self.cap
        out = self.rows[idx]  # a copy
        self.r = w
        self.hdr[8] = w
        return out


def _readers(region: mmap.mmap, offset: int, cap: int, width: int, can_offset: int | None,
             slice_rows: int | None) -> tuple[_Reader, _Reader | None]:
    from teleop.app.record.writer import CAN_CAPACITY

    can = None if can_offset is None else _Reader(region, can_offset, CAN_CAPACITY, None, CAN_ROW.size, None)
    return _Reader(region, offset, cap, width, 8 * width, slice_rows), can


class _Side:
    def __init__(self, out: McapOut, region: mmap.mmap | None, kind: str, offset: int, cap: int, width: int,
                 meta: dict, can_offset: int | None, slice_rows: int) -> None:
        self.emitter = EMITTERS[kind](out, meta)
        self.width = width
        if region is not None:
            self.ring, self.can = _readers(region, offset, cap, width, can_offset, slice_rows)

    def drain(self, w: int, w_can: int) -> bool:
        busy = False
        rows = self.ring.take(w)
        if rows is not None:
            self.emitter.emit(rows)
            busy = True
        if self.can is not None:
            frames = self.can.take(w_can)
            if frames is not None:
                self.emitter.emit_can(frames)  # type: ignore[attr-defined]
                busy = True
        return busy


class Server:
    """One record's writer over the rings in ``region``; ``mode`` "process" or "thread" (the
    slice it takes at once). The loop that drives it: :meth:`counters` first, then every message
    that came (:meth:`handle`: each name and side a published row needs came before the row),
    then :meth:`step` up to those counters; :meth:`finish` once ``closing``."""

    def __init__(self, region: mmap.mmap | None, mode: str = "process") -> None:
        self.region, self.slice = region, SLICE_ROWS[mode]
        self.out: McapOut | None = None
        self.sides: dict[int, _Side] = {}
        self.events: list[tuple] = []
        self.closing = False
        self.parent_stats: dict = {}

    def counters(self) -> dict[int, tuple[int, int]]:
        return {sid: (int(s.ring.hdr[0]), int(s.can.hdr[0]) if s.can is not None else 0)
                for sid, s in self.sides.items()}

    def handle(self, msg: tuple) -> None:
        kind = msg[0]
        if kind == "open":
            _, path, metadata, opts = msg
            self.out = McapOut(path, metadata, opts["flush_s"], opts["chunk_bytes"], opts["compression"])
            return
        if kind == "close":
            self.closing, self.parent_stats = True, msg[1]
            return
        out = self.out
        assert out is not None, f"record: {kind!r} before 'open'"
        if kind == "source":
            _, sid, side_kind, offset, cap, width, meta, can_offset = msg
            self.sides[sid] = _Side(out, self.region, side_kind, offset, cap, width, meta, can_offset, self.slice)
        elif kind == "name":
            _, sid, code, name = msg
            self.sides[sid].emitter.names[code] = name
        elif kind == "meta":
            _, sid, more = msg
            self.sides[sid].emitter.meta.update(more)
        elif kind == "event":
            self.events.append(msg[1:])
        elif kind == "json":
            _, topic, schema, log_ns, data, seq = msg
            out.add_one(out.json_channel(topic, schema), log_ns, data, seq)
        elif kind == "metadata":
            out.mcap.add_metadata(msg[1], msg[2])
        elif kind == "attach":
            _, name, data, media_type = msg
            out.mcap.add_attachment(create_time=time.time_ns(), log_time=0, name=name, media_type=media_type,
                                    data=data)

    def step(self, ws: dict[int, tuple[int, int]]) -> bool:
        """Write every side's rows up to ``ws``, a slice at a time; the link events; flush when it
        is time. Returns whether there was anything."""
        out = self.out
        if out is None:
            return False
        if self.closing:  # the run has stopped writing: everything it published
            ws = self.counters()
        busy = False
        while True:  # slice by slice, every side in turn, giving the core back between slices
            more = False
            for sid, (w, wc) in ws.items():
                more |= self.sides[sid].drain(w, wc)
            busy |= more
            if not more:
                break
            time.sleep(YIELD_S)
        if self.events:
            from teleop.app.record.schemas import LINK_EVENT

            cid = out.json_channel("/link/events", LINK_EVENT)
            for t_s, wall, side, kind, seq, detail in self.events:
                text = json.dumps({"t_s": t_s, "wall_time_s": wall, "side": side, "kind": kind, "seq": seq,
                                   "detail": detail}, default=str)
                out.add_one(cid, max(0, round(t_s * 1e9)), text.encode())
            self.events.clear()
            busy = True
        out.maybe_flush()
        return busy

    def finish(self, closed_by: str) -> dict:
        """The summary section written and the file closed; returns the counts."""
        out = self.out
        if out is None:
            return {}
        out.flush()
        stats = {**self.parent_stats, "messages": out.messages, "chunks": out.chunks, "closed_by": closed_by}
        out.finish(stats)
        return stats


class Spooler:
    """A writer that, during the run, only appends every message and every batch of rows to
    ``<path>.spool`` (frames: a 4-byte length, then a pickle), a few us of its CPU a tick; at the
    end (:meth:`finish`) the spool becomes the MCAP file (:func:`convert`) and is removed. For runs
    with no core to spare. A spool left by a killed writer: :func:`teleop.app.record.recover`."""

    def __init__(self, region: mmap.mmap, mode: str = "process") -> None:
        self.region = region
        self.readers: dict[int, tuple[_Reader, _Reader | None]] = {}
        self.closing = False
        self.parent_stats: dict = {}
        self.path: str | None = None
        self.fd = -1
        self.out = None

    def counters(self) -> dict[int, tuple[int, int]]:
        return {sid: (int(r.hdr[0]), int(c.hdr[0]) if c is not None else 0) for sid, (r, c) in self.readers.items()}

    def _frame(self, obj: tuple) -> None:
        data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
        os.write(self.fd, _LEN.pack(len(data)) + data)

    def handle(self, msg: tuple) -> None:
        kind = msg[0]
        if kind == "close":
            self.closing, self.parent_stats = True, msg[1]
            return
        if kind == "open":
            self.path = msg[1]
            self.fd = os.open(self.path + ".spool", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            self.out = True  # type: ignore[assignment]
        elif kind == "source":
            _, sid, _, offset, cap, width, _, can_offset = msg
            self.readers[sid] = _readers(self.region, offset, cap, width, can_offset, None)
        self._frame(("msg", msg))

    def step(self, ws: dict[int, tuple[int, int]]) -> bool:
        if self.fd < 0:
            return False
        if self.closing:
            ws = self.counters()
        busy = False
        for sid, (w, wc) in ws.items():
            ring, can = self.readers[sid]
            rows = ring.take(w)
            if rows is not None:
                self._frame(("rows", sid, rows.tobytes()))
                busy = True
            frames = can.take(wc) if can is not None else None
            if frames is not None:
                self._frame(("can", sid, frames.tobytes()))
                busy = True
        return busy

    def finish(self, closed_by: str) -> dict:
        if self.fd < 0 or self.path is None:
            return {}
        os.close(self.fd)
        self.fd = -1
        spool = self.path + ".spool"
        stats = convert(spool, self.path, self.parent_stats, closed_by)
        os.unlink(spool)
        return stats


def convert(spool: str, path: str, extra: dict | None = None, closed_by: str = "recovered from its spool") -> dict:
    """The MCAP file at ``path`` from the spool ``spool`` (up to its last whole frame)."""
    srv = Server(None, "process")
    with open(spool, "rb") as f:
        data = f.read()
    at, n = 0, len(data)
    while at + 4 <= n:
        size = _LEN.unpack_from(data, at)[0]
        if at + 4 + size > n:
            break  # a frame cut short: the writer was killed writing it
        try:
            frame = pickle.loads(data[at + 4:at + 4 + size])
        except Exception:  # told on stderr; the run sees the exit code at close()  # a torn frame ends the spool
            break
        at += 4 + size
        if frame[0] == "msg":
            msg = frame[1]
            if msg[0] == "open":
                msg = (msg[0], str(path), *msg[2:])
            srv.handle(msg)
        elif frame[0] == "rows":
            side = srv.sides[frame[1]]
            side.emitter.emit(np.frombuffer(frame[2], np.float64).reshape(-1, side.width))
            assert srv.out is not None
            srv.out.maybe_flush()
        elif frame[0] == "can":
            srv.sides[frame[1]].emitter.emit_can(  # type: ignore[attr-defined]
                np.frombuffer(frame[2], np.uint8).reshape(-1, CAN_ROW.size))
    srv.step({})  # the link events
    srv.parent_stats = dict(extra or {})
    return srv.finish(closed_by)


def main(argv: list[str]) -> int:
    fd, size, parent = int(argv[1]), int(argv[2]), int(argv[3])  # then --spool, if so
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    stop: list[int] = []
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, lambda *_: stop.append(1))
    try:
        os.nice(int(os.environ.get("TELEOP_RECORD_NICE", "5")))
    except OSError:
        pass
    try:  # not the core the run pinned itself to: any the machine lets it have
        os.sched_setaffinity(0, range(os.cpu_count() or 1))
    except (OSError, AttributeError):
        pass
    region = mmap.mmap(fd, size)
    os.close(fd)
    ctl = sys.stdin.buffer.fileno()
    os.set_blocking(ctl, False)
    buf = bytearray()
    srv: Server | Spooler = Spooler(region) if "--spool" in argv else Server(region, "process")
    eof = False
    while True:
        ws = srv.counters()  # the counters first, then the pipe
        while not eof:
            try:
                chunk = os.read(ctl, 1 << 16)
            except BlockingIOError:
                break
            if not chunk:
                eof = True
            buf += chunk
        while len(buf) >= 4:
            n = _LEN.unpack_from(buf)[0]
            if len(buf) < 4 + n:
                break
            msg = pickle.loads(bytes(buf[4:4 + n]))
            del buf[:4 + n]
            srv.handle(msg)
        told = srv.closing
        if eof or stop or os.getppid() != parent:
            srv.closing = True
        if srv.out is None and srv.closing:
            return 0
        busy = srv.step(ws)
        if srv.closing:
            stats = srv.finish("close" if told else "end of the run's process")
            try:  # to the run, if it is still there to read it
                os.write(sys.stdout.fileno(), (json.dumps(stats) + "\n").encode())
            except OSError:
                pass
            return 0
        if not busy:
            time.sleep(POLL_S)


if __name__ == "__main__":
    try:
        sys.exit(main(sys.argv))
    except Exception:
        traceback.print_exc()
        sys.exit(1)
