"""The rows a side's tick is captured into (teleop.app.rows): what is put is read back exactly,
across the blocks the rows grow in, whatever the parts' layout; a run of rows' bytes, handed over
as they are, is the rows."""

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop.app import rows as rows_mod
from teleop.app.rows import RowLayout, TickRows

_HEAD = struct.Struct("<2d")


def _layout():
    c = RowLayout()
    c.add("i")
    c.add("t")
    c.add("p", 3)
    c.add("R", 9)
    c.add("none", 0)
    return c


def _parts(i, rng):
    p, R = rng.normal(size=3), rng.normal(size=(3, 3))
    return (_HEAD.pack(i, 0.001 * i), p, R, np.zeros(0)), (p, R)


@settings(max_examples=40, deadline=None)
@given(expected=st.integers(1, 40), n=st.integers(0, 130), chunk=st.integers(1, 17), seed=st.integers(0, 2**16))
def test_rows_read_back_what_was_put_across_blocks(expected, n, chunk, seed):
    with pytest.MonkeyPatch.context() as mp:  # blocks of ``chunk`` rows: many of them
        mp.setattr(rows_mod, "ROW_CHUNK", chunk)
        _read_back(expected, n, chunk, seed)


def _read_back(expected, n, chunk, seed):
    rng = np.random.default_rng(seed)
    rows, held = TickRows(_layout(), expected), []
    for i in range(n):
        parts, (p, R) = _parts(i, rng)
        rows.put(i, parts)
        held.append((p, R))
    assert rows.n == n and rows.capacity >= n
    assert np.array_equal(rows.column("i"), np.arange(n, dtype=float))
    assert np.array_equal(rows.column("p"), np.reshape([h[0] for h in held], (n, 3)))
    assert np.array_equal(rows.column("R", shape=(3, 3)), np.reshape([h[1] for h in held], (n, 3, 3)))
    assert rows.column("none").shape == (n, 0)
    if n:
        a = int(rng.integers(0, n))
        b = int(rng.integers(a, n + 1))
        joined = b"".join(bytes(s) for s in rows.segments(a, b))
        assert joined == b"".join(rows.at(k).tobytes() for k in range(a, b))
        assert len(rows.segments(a, b)) <= 1 + (b - a) // max(1, min(chunk, expected)) + 1


def test_parts_of_any_layout_are_cast_alike():
    """A transposed rotation, float32, a list: numpy's casting, the same numbers; an int64 array
    on the first row is cast too (its bytes are not float64's)."""
    rng = np.random.default_rng(1)
    rows = TickRows(_layout(), 8)
    p, R = rng.normal(size=3), rng.normal(size=(3, 3))
    rows.put(0, (_HEAD.pack(0, 0.0), np.array([1, 2, 3]), R, np.zeros(0)))
    rows.put(1, (_HEAD.pack(1, 0.0), list(p), np.asfortranarray(R), np.zeros(0)))
    rows.put(2, (_HEAD.pack(2, 0.0), p.astype(np.float32), R.T.copy().T, np.zeros(0)))
    assert np.array_equal(rows.column("p")[0], [1.0, 2.0, 3.0])
    assert np.array_equal(rows.column("p")[1], p) and np.array_equal(rows.column("p")[2], p.astype(np.float32))
    assert np.array_equal(rows.column("R", shape=(3, 3)), [R, R, R])
    with pytest.raises(ValueError, match="row 3 has 15 numbers, the layout 14"):
        rows.put(3, (_HEAD.pack(3, 0.0), p, R, np.zeros(1)))


def test_statuses_are_numbered_in_the_order_first_seen():
    rows = TickRows(_layout())
    assert [rows.code(s) for s in ("ok", "link_lost", "ok", "saturated")] == [0, 1, 0, 2]
    assert rows.names == ["ok", "link_lost", "saturated"]
