"""A side's ticks as rows of numbers: the one capture its log, its metrics and its record read.

Each tick, a side's capture hook (:mod:`teleop.app.recorders`) joins what the tick left (its
scalars, packed, and its arrays' bytes) into the next row of a :class:`TickRows`: one copy of
the tick, in the tick. Everything else reads that row, out of the tick: the run's ``log.npz``
and metrics at the end (:mod:`teleop.app.metrics`), and the MCAP record
(:mod:`teleop.app.record.hooks`), which hands the row's bytes to its writer as they are. A
:class:`RowLayout` names the rows' column ranges; the record's writer process lays out its
messages by the same names.

numpy only: the record's writer process imports this and nothing of the tick.
"""

from __future__ import annotations

import struct

import numpy as np

#: ticks reserved at first and added each time the rows fill (they grow, never preallocated for a
#: run of unknown length)
ROW_CHUNK = 16_384
_JOIN = b"".join
#: what joining a part that is not a contiguous buffer of the row's size raises (the row is then
#: filled with numpy's casting)
_COPY_ERRORS = (BufferError, ValueError, TypeError, IndexError, struct.error)


class RowLayout:
    """Named column ranges of a row of float64s: ``add(name, n)`` appends n columns (0 allowed)."""

    def __init__(self, at: dict | None = None) -> None:
        self.at: dict[str, tuple[int, int]] = {k: (int(a), int(b)) for k, (a, b) in (at or {}).items()}
        self.width = max((b for _, b in self.at.values()), default=0)

    def add(self, name: str, n: int = 1) -> None:
        if name in self.at:
            raise ValueError(f"row layout: column {name!r} twice")
        self.at[name] = (self.width, self.width + int(n))
        self.width += int(n)

    def __getitem__(self, name: str) -> slice:
        a, b = self.at[name]
        return slice(a, b)

    def __contains__(self, name: object) -> bool:
        return name in self.at

    def col(self, name: str) -> int:
        return self.at[name][0]


class TickRows:
    """Row i is tick i (float64 columns laid out by ``layout``), kept in blocks: the first of
    ``expected`` rows (at most :data:`ROW_CHUNK`), then blocks of :data:`ROW_CHUNK` added as the
    ticks come, so the rows never move and a long run never stops to copy them. :meth:`put`
    fills a row in one copy; :meth:`column` reads a column range back, :meth:`segments` the raw
    bytes of a run of rows; :meth:`code` numbers a status string (``names``: the strings by
    number, in the order first seen)."""

    def __init__(self, layout: RowLayout, expected: int = ROW_CHUNK) -> None:
        self.layout = layout
        self.width = layout.width
        self.row_bytes = 8 * self.width
        first = max(1, min(int(expected), ROW_CHUNK))
        self.blocks: list[np.ndarray] = [np.zeros((first, self.width))]
        self.starts: list[int] = [0]
        self.n = 0  # rows put: one past the highest
        self.codes: dict[str, int] = {}
        self.names: list[str] = []
        self._typed = False  # the first row's parts checked (see put)
        self._lo, self._hi = 0, first  # the block rows are put into: its first row and one past its last
        self._raw = memoryview(self.blocks[0]).cast("B")

    @property
    def capacity(self) -> int:
        """Rows the blocks hold now."""
        return self.starts[-1] + len(self.blocks[-1])

    def _block(self, i: int) -> int:
        """The block holding row ``i`` (blocks added up to it)."""
        while i >= self.capacity:
            self.starts.append(self.capacity)
            self.blocks.append(np.zeros((ROW_CHUNK, self.width)))
        k = len(self.starts) - 1
        while self.starts[k] > i:
            k -= 1
        return k

    def at(self, i: int) -> np.ndarray:
        """Row ``i`` (a view; blocks added up to it)."""
        k = self._block(i)
        return self.blocks[k][i - self.starts[k]]

    def code(self, status: str) -> int:
        """``status``'s number (a new one is numbered next)."""
        c = self.codes.get(status)
        if c is None:
            c = self.codes[status] = len(self.names)
            self.names.append(status)
        return c

    def put(self, i: int, parts: tuple) -> None:
        """Row ``i`` from ``parts``: packed float64 bytes, then arrays, in the layout's order. In
        the tick: their bytes joined into the row in one copy. A part that is not a contiguous
        float64 buffer of its size is cast by numpy instead (the first row checks every part's
        type, since an int64 buffer of the right size would join as bytes)."""
        if not self._lo <= i < self._hi:
            k = self._block(i)
            self._lo, self._hi = self.starts[k], self.starts[k] + len(self.blocks[k])
            self._raw = memoryview(self.blocks[k]).cast("B")
        rb = self.row_bytes
        o = (i - self._lo) * rb
        try:
            if not self._typed:
                self._check(parts)
            self._raw[o:o + rb] = _JOIN(parts)
        except _COPY_ERRORS:
            self._cast(i, parts)
        if i >= self.n:
            self.n = i + 1

    def _check(self, parts: tuple) -> None:
        for a in parts[1:]:
            if not (isinstance(a, np.ndarray) and a.dtype == np.float64):
                raise TypeError("row part not float64")
        self._typed = True

    def _cast(self, i: int, parts: tuple) -> None:
        pieces = [np.frombuffer(parts[0], np.float64)] + [np.ravel(np.asarray(a, dtype=float)) for a in parts[1:]]
        if sum(p.size for p in pieces) != self.width:
            raise ValueError(f"tick rows: row {i} has {sum(p.size for p in pieces)} numbers, the layout "
                             f"{self.width}")
        np.concatenate(pieces, out=self.at(i))

    def segments(self, a: int, b: int) -> list[memoryview]:
        """Rows [a, b)'s bytes as they are, one view per block they span (valid while the rows
        live: blocks never move)."""
        out = []
        rb = self.row_bytes
        while a < b:
            k = self._block(a)
            lo, blk = self.starts[k], self.blocks[k]
            end = min(b, lo + len(blk))
            out.append(memoryview(blk).cast("B")[(a - lo) * rb:(end - lo) * rb])
            a = end
        return out

    def column(self, name: str, n: int | None = None, shape: tuple = ()) -> np.ndarray:
        """The first ``n`` rows (default: all put) of column range ``name``, as an (n, *shape)
        array of its own (``shape`` () for one column; default: the range's width)."""
        n = self.n if n is None else int(n)
        a, b = self.layout.at[name]
        parts = [blk[: max(0, min(len(blk), n - lo)), a:b] for lo, blk in zip(self.starts, self.blocks) if lo < n]
        out = np.concatenate(parts) if parts else np.zeros((0, b - a))
        if shape == () and b - a == 1:
            return out.reshape(n)
        return out.reshape(n, *shape) if shape else out
