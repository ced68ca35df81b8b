"""The writer process of a record: ``python -m teleop.app.record.serve FD SIZE PARENT_PID``,
started by :class:`teleop.app.record.writer.RecordWriter` and fed by it: the shared memory
``FD`` (``SIZE`` bytes) holds the sides' rings, stdin brings length-prefixed pickles ("open",
"source", "name", "meta", "event", "attach", "close"). It ends when told to close or when its parent is gone
(stdin at its end, or another parent): either way it takes every row published, finishes the file
and prints its counts as one JSON line. It ignores SIGINT (a Ctrl-C is the run's to handle) and
finishes on SIGTERM as on a close.
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
#: ticks a side taken at once; between two such slices the writer yields its core (a run pinned to
#: it gets it back within a slice, some 0.5 ms)
SLICE_ROWS = 8
_HEADER = 128
_LEN = struct.Struct("<I")


class _Reader:
    """The rows of one ring, as the writer sees them."""

    def __init__(self, region: mmap.mmap, offset: int, cap: int, width: int | None, row_bytes: int) -> None:
        self.hdr = np.frombuffer(region, np.int64, count=_HEADER // 8, offset=offset)
        self.cap, self.r = cap, 0
        self.rows: np.ndarray
        if width is not None:
            self.rows = np.frombuffer(region, np.float64, count=cap * width, offset=offset + _HEADER).reshape(cap, width)
        else:
            self.rows = np.frombuffer(region, np.uint8, count=cap * row_bytes,
                                      offset=offset + _HEADER).reshape(cap, row_bytes)

    def take(self, w: int) -> np.ndarray | None:
        w = min(w, self.r + SLICE_ROWS) if self.rows.dtype == np.float64 else w
        if w <= self.r:
            return None
        idx = np.arange(self.r, w) % self.cap
        out = self.rows[idx]  # a copy
        self.r = w
        self.hdr[8] = w
        return out


class _Side:
    def __init__(self, out: McapOut, region: mmap.mmap, kind: str, offset: int, cap: int, width: int, meta: dict,
                 can_offset: int | None) -> None:
        from teleop.app.record.writer import CAN_CAPACITY

        self.emitter = EMITTERS[kind](out, meta)
        self.ring = _Reader(region, offset, cap, width, 8 * width)
        self.can = None if can_offset is None else _Reader(region, can_offset, CAN_CAPACITY, None, CAN_ROW.size)

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


def main(argv: list[str]) -> int:
    fd, size, parent = int(argv[1]), int(argv[2]), int(argv[3])
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
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
    out: McapOut | None = None
    sides: dict[int, _Side] = {}
    events: list[tuple] = []
    closing, parent_stats, eof = False, {}, False
    while True:
        # the counters first, then the pipe: every name and side a published row needs is in it
        ws = {sid: (int(s.ring.hdr[0]), int(s.can.hdr[0]) if s.can is not None else 0) for sid, s in sides.items()}
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
            kind = msg[0]
            if kind == "open":
                _, path, metadata, opts = msg
                out = McapOut(path, metadata, opts["flush_s"], opts["chunk_bytes"], opts["compression"])
            elif kind == "source":
                assert out is not None
                _, sid, side_kind, offset, cap, width, meta, can_offset = msg
                sides[sid] = _Side(out, region, side_kind, offset, cap, width, meta, can_offset)
            elif kind == "name":
                _, sid, code, name = msg
                sides[sid].emitter.names[code] = name
            elif kind == "meta":
                _, sid, more = msg
                sides[sid].emitter.meta.update(more)
            elif kind == "event":
                events.append(msg[1:])
            elif kind == "attach":
                assert out is not None
                _, name, data, media_type = msg
                out.mcap.add_attachment(create_time=time.time_ns(), log_time=0, name=name, media_type=media_type,
                                        data=data)
            elif kind == "close":
                closing, parent_stats = True, msg[1]
        if eof or stop or os.getppid() != parent:
            closing = True
        if out is None:
            if closing:
                return 0
            time.sleep(POLL_S)
            continue
        if closing:  # the run has stopped writing: everything it published
            ws = {sid: (int(s.ring.hdr[0]), int(s.can.hdr[0]) if s.can is not None else 0)
                  for sid, s in sides.items()}
        busy = False
        while True:  # slice by slice, every side in turn, yielding the core between slices
            more = False
            for sid, (w, wc) in ws.items():
                more |= sides[sid].drain(w, wc)
            busy |= more
            if not more:
                break
            os.sched_yield()
        if events:
            cid = out.json_channel("/link/events", _link_schema())
            for t_s, wall, side, kind, seq, detail in events:
                text = json.dumps({"t_s": t_s, "wall_time_s": wall, "side": side, "kind": kind, "seq": seq,
                                   "detail": detail}, default=str)
                out.add_one(cid, max(0, round(t_s * 1e9)), text.encode())
            events.clear()
            busy = True
        out.maybe_flush()
        if closing:
            out.flush()
            stats = {**parent_stats, "messages": out.messages, "chunks": out.chunks,
                     "closed_by": "close" if parent_stats else "end of the run's process"}
            out.finish(stats)
            try:  # to the run, if it is still there to read it
                os.write(sys.stdout.fileno(), (json.dumps(stats) + "\n").encode())
            except OSError:
                pass
            return 0
        if not busy:
            time.sleep(POLL_S)


def _link_schema() -> dict:
    from teleop.app.record.schemas import LINK_EVENT

    return LINK_EVENT


if __name__ == "__main__":
    try:
        sys.exit(main(sys.argv))
    except Exception:  # noqa: BLE001 - told on stderr; the run sees the exit code at close()
        traceback.print_exc()
        sys.exit(1)
