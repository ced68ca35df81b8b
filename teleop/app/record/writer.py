"""The record's writer: an MCAP file written by a process of its own, fed by bounded rings.

Three ways to run it, for three kinds of run (measured on this 2-core machine, see the report of
``tools/record_bench.py`` and the two-process figures in the record's tests):

* ``RecordWriter(path)``: a process of its own writes the MCAP file as the run goes. For a run in
  one process (its loop uses one core; the writer, some 10 % of the other).
* ``RecordWriter(path, spool=True)`` (the default with ``realtime=True``): the process only
  appends the rows to ``<path>.spool`` while the run goes (0.6 % of a core) and writes the MCAP
  file after it (some 0.15 ms a tick: 1 s for a 7 s cut). For runs paced to the wall clock: the
  two-process run pins each side to a core and spins on it, and a writer doing its MCAP work
  beside them made some 10x more late ticks; one in-process real-time run of two with a live
  writer had 382 late ticks against 36 without; spooling made none more in either.
* ``RecordWriter(path, mode="thread")``: the same writer as a thread of the run's process.

The tick never serialises or writes. A side's hook (:mod:`teleop.app.record.hooks`) copies the
rows its side's capture holds (:mod:`teleop.app.rows`), every 10 ms of the run, as they are into
the next rows of a preallocated ring (:class:`Source`, one per side) in memory shared with the
writer process (:mod:`teleop.app.record.serve`), and publishes them by advancing a counter
there; the writer process takes the published rows in batches, lays out their messages with
numpy and adds them to the file through the ``mcap`` package's writer
(:mod:`teleop.app.record.emit`). The writer's work (some 50-100 us a tick a side, most of it
inside ``mcap``'s own Python) runs on another core, not under the tick's GIL: as a thread it
shares the tick's interpreter lock (a run faster than real time never releases it, and a thread
that waits for it forces a switch in mid-tick every 5 ms).

Rings: each is single-producer single-consumer, its counters ``w`` (rows published, the tick's)
and ``r`` (rows taken, the writer's) int64s in the shared memory; a row is written before ``w``
is advanced past it (x86's store order makes that enough; no lock). When the writer falls
behind: a run paced to the wall clock (``realtime=True``) never waits for it, and a ring that
fills (16384 ticks, 16 s at 1 kHz) drops the ticks it has no room for and counts them (the
record's ``ticks_dropped``); a run on the simulated clock (the default) loses nothing: a ring
that holds ``high_water`` unwritten ticks makes its hook wait (sleeping) until the writer is back
under ``low_water``, at most ``block_s`` at once. Status strings, the sides' static facts and
link events go over the writer's stdin as pickles (rare: once per new status).

Crash safety: the writer process lives in its own process group (a Ctrl-C or a signal to the
run's group does not reach it) and watches its stdin: when the run's process ends,
however it ends (SIGKILL included), the writer takes every row the run published and finishes
the file, summary and all. When the writer itself is killed, the file keeps every chunk it
closed: a chunk is closed and flushed to the operating system whenever it holds ``flush_s`` of
the run's time or has been open ``flush_s`` of the wall clock (0.05 s), and
:func:`teleop.app.record.reader.read_record` reads such a file to its last whole chunk
(:func:`~teleop.app.record.reader.recover` finishes a copy). A spooling writer appends to its
spool every 10 ms, and ``recover`` makes the file of a killed one's spool.

Timestamps: each message's log time (and publish time, and a ROS 2 header's stamp) is the run's
simulated time ``t_s`` of its tick, in ns from the run's start (tick 0 at 0); the wall clock of
the recording host is in the JSON records (``wall_time_s``, Unix time).
"""

from __future__ import annotations

import atexit
import importlib.util
import json
import mmap
import os
import pickle
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any, Self

from teleop.app.record.emit import CAN_ROW
from teleop.app.rows import RowLayout

#: the chunk in progress is closed and flushed once it holds this much of the run's time, or has
#: been open this long on the wall clock (s)
FLUSH_S = 0.05
#: a chunk also closes when it reaches this many bytes (uncompressed)
CHUNK_BYTES = 1024 * 1024
#: ticks a side's ring holds (a run on the simulated clock; one paced to the wall clock); CAN
#: frames the bus's ring holds
CAPACITY = 4096
REALTIME_CAPACITY = 16384
CAN_CAPACITY = 16384
#: unwritten ticks in a ring at which its hook waits for the writer, and down to which it waits
HIGH_WATER, LOW_WATER = 2048, 512
#: the longest a hook waits for the writer at once (s)
BLOCK_S = 1.0
#: the memory shared with the writer (bytes; pages are only used as the rings fill them)
REGION_BYTES = 64 * 1024 * 1024
#: the writer process's niceness: where it shares a core, the tick comes first
WRITER_NICE = 5
#: how long close() waits for the writer to finish the file (s)
CLOSE_TIMEOUT_S = 120.0
_HEADER = 128  # a ring's header: w at byte 0, r at byte 64 (their own cache lines)
_LEN = struct.Struct("<I")


class RecordError(RuntimeError):
    """The record could not be written (the writer process failed or could not start)."""


def _shared_fd(size: int) -> int:
    """A file descriptor of ``size`` bytes of memory with no name (memfd; else an unlinked temporary
    file, in /dev/shm where there is one)."""
    if hasattr(os, "memfd_create"):
        fd = os.memfd_create("teleop-record", 0)
    else:  # pragma: no cover - not Linux
        f = tempfile.TemporaryFile(dir="/dev/shm" if os.path.isdir("/dev/shm") else None)
        fd = os.dup(f.fileno())
        f.close()
    os.ftruncate(fd, size)
    return fd


class _Ring:
    """A ring's place in the shared memory: its header's int64 0 is w, its int64 8 is r."""

    def __init__(self, writer: RecordWriter, row_bytes: int, capacity: int) -> None:
        self.writer, self.cap, self.row_bytes = writer, int(capacity), int(row_bytes)
        size = _HEADER + self.row_bytes * self.cap
        self.offset = writer._alloc(size)
        writer._region[self.offset:self.offset + size] = bytes(size)  # its pages now, not one per few ticks
        self.hdr = memoryview(writer._region)[self.offset:self.offset + _HEADER].cast("q")
        self.data = self.offset + _HEADER
        self.w = 0
        self.r = 0  # the writer's r as last read: it only grows, so an old one errs on the safe side
        self.dropped = 0

    def room(self, n: int = 1) -> bool:
        """Whether n more rows fit (the writer's r read again only when they seem not to)."""
        if self.w - self.r + n <= self.cap:
            return True
        self.r = self.hdr[8]
        return self.w - self.r + n <= self.cap


class Source:
    """One side's ring: ``capacity`` rows of ``cols.width`` float64s in the memory shared with the
    writer process, written by the tick's thread (:meth:`next_row` gives the next row's byte offset
    in :attr:`region`, then :meth:`publish`; or rows copied in and ``ring.w`` advanced, as the
    side hooks' hand-over does). ``kind`` names
    the writer's emitter ("master", "slave"); ``meta`` (picklable) is what the emitter needs."""

    def __init__(self, writer: RecordWriter, kind: str, cols: RowLayout, meta: dict, can: bool = False) -> None:
        self.writer, self.cols, self.kind = writer, cols, kind
        cap = writer.capacity
        self.ring = ring = _Ring(writer, 8 * cols.width, cap)
        self.region = writer._region
        self.high, self.low, self.realtime = writer.high_water, writer.low_water, writer.realtime
        self.waits = 0
        self.waited_s = 0.0
        self._stalled = False
        self.told = 0  # status names told to the writer (tell)
        self.live = writer.live
        self.can = _Ring(writer, CAN_ROW.size, CAN_CAPACITY) if can else None
        self.can_frames: list[tuple] = []
        self.sid = writer._add(self)
        writer._send(("source", self.sid, kind, ring.offset, cap, cols.width, dict(meta, cols=cols.at),
                      None if self.can is None else self.can.offset))

    @property
    def w(self) -> int:
        return self.ring.w

    @property
    def dropped(self) -> int:
        return self.ring.dropped

    def tell(self, names: list[str]) -> None:
        """The status strings by code (a capture's :attr:`~teleop.app.rows.TickRows.names`) that
        the writer has not been told yet, told (before a row with their code is published)."""
        for c in range(self.told, len(names)):
            self.writer._send(("name", self.sid, c, names[c]))
        self.told = len(names)

    def next_row(self) -> int:
        """The byte offset in :attr:`region` of the next row to fill, or -1 (the ring is full: the
        tick is dropped and counted)."""
        ring = self.ring
        if ring.room():
            return ring.data + (ring.w % ring.cap) * ring.row_bytes
        ring.dropped += 1
        return -1

    def publish(self) -> None:
        """The next row is filled: hand it to the writer."""
        ring = self.ring
        ring.w += 1
        ring.hdr[0] = ring.w
        if self.can_frames:
            self._publish_can()
        if ring.w - ring.r >= self.high and not self.realtime:
            self.high_water()

    def high_water(self) -> None:
        """The ring seems to hold ``high`` unwritten rows (by the writer's count as last read): read
        it again, and wait for the writer if they are there."""
        ring = self.ring
        ring.r = ring.hdr[8]
        if ring.w - ring.r >= self.high:
            self._wait()

    def _publish_can(self) -> None:
        ring, region, pack, size = self.can, self.region, CAN_ROW.pack, CAN_ROW.size
        assert ring is not None
        for fr in self.can_frames:
            if not ring.room():
                ring.dropped += 1
                continue
            at = ring.data + (ring.w % ring.cap) * size
            region[at:at + size] = pack(*fr)
            ring.w += 1
        ring.hdr[0] = ring.w
        self.can_frames.clear()

    def _wait(self) -> None:
        ring = self.ring
        if self._stalled:  # the last wait timed out: no more waiting until the writer catches up
            if ring.w - ring.hdr[8] <= self.low:
                self._stalled = False
            return
        wr = self.writer
        t0 = time.perf_counter()
        end = t0 + wr.block_s
        while ring.w - ring.hdr[8] > self.low:
            if not wr._alive():  # the writer is gone: stop recording
                wr._dead()
                break
            if time.perf_counter() > end:
                self._stalled = True
                break
            time.sleep(1e-4)
        ring.r = ring.hdr[8]
        self.waits += 1
        self.waited_s += time.perf_counter() - t0

    def finalize(self) -> None:
        """Called once by :meth:`RecordWriter.close`, before the writer is told to finish."""


class RecordWriter:
    """An MCAP record at ``path`` (its folder made), written by a process started here; see the
    module docstring. ``metadata`` (str -> str) goes in the file's "teleop" metadata record.
    ``realtime``: the run is paced to the wall clock: its ticks never wait for the writer (a full
    ring drops ticks, counted), the rings are 4 times longer, and the writer spools unless told
    otherwise (``spool=False``). ``mode``: "process" (a process of
    its own, on any core: for runs in one process, which leave the other core free) or "thread"
    (a thread of the run's process, working while the tick waits for its next period: for a side
    pinned to a core that it spins on, as in the two-process run, where a process of its own
    either steals that core mid-tick or, in a session of its own, was starved). ``spool``: write
    the MCAP file after the run: during it the writer only appends the rows to ``<path>.spool`` (a
    few us of its CPU a tick, for runs with no core to spare: two sides pinned to a 2-core
    machine); ``close()`` converts it (the run's process ended otherwise: the writer process
    converts it all the same); a spool left by a killed writer: :func:`~teleop.app.record.recover`.
    ``close()`` (or leaving a ``with`` block, or the interpreter's exit) has the writer write
    what is left and the summary section, and waits for it. Sides attach with
    :class:`~teleop.app.record.hooks.MasterRecorderMcap` and
    :class:`~teleop.app.record.hooks.SlaveRecorderMcap` (or the in-process loop's
    :class:`~teleop.app.record.hooks.LoopRecorderMcap`); link events come through
    :meth:`link_event`."""

    def __init__(self, path: str | Path, metadata: dict | None = None, flush_s: float = FLUSH_S,
                 chunk_bytes: int = CHUNK_BYTES, compression: str = "zstd", realtime: bool = False,
                 capacity: int | None = None, high_water: int = HIGH_WATER, low_water: int = LOW_WATER,
                 block_s: float = BLOCK_S, region_bytes: int = REGION_BYTES, mode: str = "process",
                 spool: bool | None = None) -> None:
        self.path = Path(path)
        if mode not in ("process", "thread"):
            raise ValueError(f"record: mode must be process or thread, got {mode!r}")
        self.mode, self.spool = mode, bool(realtime if spool is None else spool)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.realtime = bool(realtime)
        self.capacity = int(capacity if capacity is not None else REALTIME_CAPACITY if realtime else CAPACITY)
        self.block_s = float(block_s)
        self.high_water, self.low_water = int(high_water), int(low_water)
        if not 0 < self.low_water < self.high_water <= self.capacity:
            raise ValueError(f"record: need 0 < low_water < high_water <= capacity, got {self.low_water}, "
                             f"{self.high_water}, {self.capacity}")
        if importlib.util.find_spec("mcap") is None:
            raise RecordError("record: the mcap package is not installed (pip install mcap)")
        if compression not in ("zstd", "lz4", "none"):
            raise ValueError(f"record: compression must be zstd, lz4 or none, got {compression!r}")
        self.live = True
        self.closed = False
        self.result: dict = {}
        self._sources: list[Source] = []
        self._size, self._used = int(region_bytes), 0
        self._lock = threading.Lock()
        self._proc: subprocess.Popen | None = None
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        if mode == "thread":
            self._region = mmap.mmap(-1, self._size)
            self._queue: deque = deque()
            self._thread = threading.Thread(target=self._serve, name="teleop-record", daemon=True)
            self._thread.start()
        else:
            fd = _shared_fd(self._size)
            try:
                self._region = mmap.mmap(fd, self._size)
                # its own process group (a Ctrl-C or a signal to the run's group does not reach it) but
                # not its own session: a session of its own is a scheduling group of its own
                # (autogroup), which Linux 6.18 left unscheduled for seconds beside pinned sides
                self._proc = subprocess.Popen(
                    [sys.executable, "-m", "teleop.app.record.serve", str(fd), str(self._size), str(os.getpid()),
                     *(["--spool"] if self.spool else [])],
                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, pass_fds=(fd,), process_group=0,
                    env=_child_env())
            finally:
                os.close(fd)
        self._send(("open", str(self.path), {"log_time": "the run's simulated time, ns from tick 0 (t_s = i * dt)",
                                             "wall_time": "JSON wall_time_s: Unix time on the recording host",
                                             **{str(k): str(v) for k, v in (metadata or {}).items()}},
                    {"flush_s": float(flush_s), "chunk_bytes": int(chunk_bytes), "compression": compression}))
        atexit.register(self.close)

    @property
    def pid(self) -> int:
        """The writer process's id (this process's, for a thread)."""
        return self._proc.pid if self._proc is not None else os.getpid()

    def _alive(self) -> bool:
        if self._proc is not None:
            return self._proc.poll() is None
        return self._thread is not None and self._thread.is_alive()

    def _serve(self) -> None:
        """The writer as a thread of this process (mode "thread")."""
        from teleop.app.record.serve import POLL_S, Server, Spooler

        srv: Server | Spooler = Spooler(self._region) if self.spool else Server(self._region, "thread")
        q = self._queue
        try:
            while True:
                ws = srv.counters()  # the counters first, then the messages
                while q:
                    srv.handle(q.popleft())
                if srv.out is None and srv.closing:
                    return
                busy = srv.step(ws)
                if srv.closing:
                    self.result = srv.finish("close")
                    return
                if not busy:
                    time.sleep(POLL_S)
        except BaseException as e:  # raised by close()
            self._error = e
            self._dead()

    @property
    def dropped(self) -> int:
        return sum(s.dropped for s in self._sources)

    def stats(self) -> dict:
        """The hooks' side of the record: ticks dropped (a full ring), times they waited for the
        writer; after close() also the writer's (``messages``, ``chunks``)."""
        out = {"path": str(self.path), "ticks_dropped": self.dropped,
               "can_frames_dropped": sum(s.can.dropped for s in self._sources if s.can is not None),
               "hook_waits": sum(s.waits for s in self._sources),
               "hook_waited_s": round(sum(s.waited_s for s in self._sources), 6)}
        out.update({k: v for k, v in self.result.items() if k not in out})
        return out

    def link_event(self, t_s: float, side: str, kind: str, seq: int | None = None, detail: Any = None) -> None:
        """A link event (sent, delivered, lost, refused, ...) at the run's time ``t_s`` (s), seen by
        ``side``; written to ``/link/events`` (JSON). A pickle down a pipe (a few us): meant for
        events, not for every message of every tick."""
        self._send(("event", float(t_s), time.time(), str(side), str(kind), seq, detail))

    def message(self, topic: str, schema: dict, t_s: float, body: dict, seq: int = 0) -> None:
        """One JSON message on ``topic`` (its JSON Schema ``schema``, see
        :mod:`~teleop.app.record.schemas`) at the run's time ``t_s`` (s): a pickle down a pipe (a
        few us), for what comes now and then (a key typed), not every tick."""
        self._send(("json", str(topic), schema, max(0, round(float(t_s) * 1e9)), json.dumps(body).encode(), int(seq)))

    def metadata_record(self, name: str, values: dict) -> None:
        """An MCAP metadata record ``name`` of str -> str ``values`` (what a replay needs, say)."""
        self._send(("metadata", str(name), {str(k): str(v) for k, v in values.items()}))

    def attach(self, name: str, data: bytes | str, media_type: str = "text/plain") -> None:
        """A file carried in the record (an MCAP attachment: the scene as run, say), at log time 0."""
        self._send(("attach", str(name), data.encode() if isinstance(data, str) else bytes(data), str(media_type)))

    def close(self) -> None:
        """Have the writer write what is left and the summary section, and wait for it
        (idempotent). Raises :class:`RecordError` if the writer failed."""
        if self.closed:
            return
        self.closed = True
        atexit.unregister(self.close)
        for s in list(self._sources):
            s.finalize()
        self._send(("close", {k: v for k, v in self.stats().items() if k != "path"}))
        if self._thread is not None:
            self._thread.join(CLOSE_TIMEOUT_S)
            self.live = False
            for s in self._sources:
                s.live = False
            if self._error is not None or self._thread.is_alive() or not self.result:
                raise RecordError(f"record {self.path}: the writer failed: {self._error!r}") from self._error
            return
        assert self._proc is not None
        try:
            out, _ = self._proc.communicate(timeout=CLOSE_TIMEOUT_S)  # closes its stdin too
        except subprocess.TimeoutExpired:
            self._proc.kill()
            out, _ = self._proc.communicate()
            raise RecordError(f"record {self.path}: the writer did not finish within {CLOSE_TIMEOUT_S:g} s") from None
        finally:
            self.live = False
            for s in self._sources:
                s.live = False
        lines = out.decode(errors="replace").strip().splitlines() if out else []
        if self._proc.returncode != 0 or not lines:
            raise RecordError(f"record {self.path}: the writer failed (exit {self._proc.returncode}; its "
                              f"error is on stderr)")
        self.result = json.loads(lines[-1])

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the sides' ------------------------------------------------------------------------------
    def _alloc(self, nbytes: int) -> int:
        at = (self._used + 63) // 64 * 64
        if at + nbytes > self._size:
            raise RecordError(f"record: the shared memory ({self._size} bytes) is full: raise region_bytes")
        self._used = at + nbytes
        return at

    def _add(self, source: Source) -> int:
        self._sources.append(source)
        return len(self._sources) - 1

    def _send(self, msg: tuple) -> None:
        if not self.live and msg[0] != "close":
            return
        if self._thread is not None:
            self._queue.append(msg)
            return
        assert self._proc is not None
        data = pickle.dumps(msg, protocol=pickle.HIGHEST_PROTOCOL)
        try:
            with self._lock:
                stdin = self._proc.stdin
                assert stdin is not None
                stdin.write(_LEN.pack(len(data)) + data)
                stdin.flush()
        except (OSError, ValueError):  # the writer is gone (close() says why)
            self._dead()

    def _dead(self) -> None:
        self.live = False
        for s in self._sources:
            s.live = False


def _child_env() -> dict:
    """The writer's environment: this process's, with the folder this ``teleop`` was imported from
    first on its path (a checkout that is not installed works too)."""
    import teleop

    env = dict(os.environ)
    root = str(Path(teleop.__file__).resolve().parent.parent)
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env
