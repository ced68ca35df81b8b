"""Compiled CAN frame codec (numba): the checks, the decoding and the encoding of a frame over the
layout tables :mod:`.codec` derives from the DBC, and the driver's per-period frames applied in
one call.

A frame's bytes go to the math through one compiled call: id lookup, id type, FD flag, length,
the CRC-32 (the frame id's two bytes, little-endian, then the payload before the CRC; continued
from the id's CRC; for a frame tied to a SYNC, then the full 32-bit SYNC count it answers, four
bytes little-endian, never sent: see :func:`check_frame`), each signal unpacked, scaled (``raw *
scale + offset``) and checked against its DBC range. Encoding is the inverse (``raw = (v - offset)
/ scale``, rounded half to even for an integer signal, as cantools and Python's ``round`` do),
strict, then sealed with the CRC.

The layout tables (built by :func:`.codec.layout_tables`), the fields of one record ``tab`` (a
numpy structured array of shape (1,), so that a kernel call passes one argument for all five):

* ``msgs`` int64 (n_msgs, MSG_COLS): frame id, extended id, FD, length, the CRC of the id alone
  (-1: unprotected), number of signals, big-endian, compiled (0: a layout the tables cannot hold;
  the caller uses cantools), the byte of the 8-bit counter of a frame tied to a SYNC (its CRC
  covers the full SYNC count; -1: a frame tied to none);
* ``sig_i`` int64 (n_msgs, max_signals, SIG_I_COLS): first byte, bytes, kind (unsigned, signed,
  float);
* ``sig_f`` float64 (n_msgs, max_signals, SIG_F_COLS): scale, offset, decode range (the DBC's,
  widened by half a raw step for integers: what strict encoding accepts decodes), encode range
  (cantools' strict one: widened by a millionth of the scale);
* ``ids`` int64 (n_msgs,): the frame ids sorted, ``order`` int64: their message rows.

Tested against cantools (tests/property/test_can_codec.py, random frames and payloads); the CRC is
:func:`teleop.util.crc32.crc32_continue`. Set ``NUMBA_DISABLE_JIT=1`` to run them as Python.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from teleop.util.crc32 import CRC_TABLE, crc32_continue

#: msgs columns
M_ID, M_EXT, M_FD, M_LEN, M_IDCRC, M_NSIG, M_BIG, M_COMPILED, M_CTR = range(9)
MSG_COLS = 9
#: sig_i columns and kinds
S_BYTE, S_NBYTES, S_KIND = range(3)
SIG_I_COLS = 3
KIND_UNSIGNED, KIND_SIGNED, KIND_FLOAT = range(3)
#: sig_f columns
S_SCALE, S_OFFSET, S_DLO, S_DHI, S_ELO, S_EHI = range(6)
SIG_F_COLS = 6
#: bytes of the CRC at the end of a protected frame
CRC_BYTES = 4

#: check_frame's verdicts; RANGE + i: signal i outside its range (its value left in ``vals[i]``);
#: STALE: a frame tied to a SYNC whose CRC holds for a count whole counter wraps (256 SYNCs) older
#: than the one its counter names now (a recorded frame replayed)
OK, UNKNOWN_ID, ID_TYPE, FD_FLAG, LENGTH, CHECKSUM, NOT_COMPILED, STALE = 0, -1, -2, -3, -4, -5, -6, -9
RANGE = 1000
#: rx_period_frame's verdicts beyond check_frame's: applied, late (an old counter), another valid
#: message (values in ``vals``), a counter the host has not sent, an encoder jump (fault latched),
#: a load-cell reading that changed faster than the load cell can (refused, the last one kept)
APPLIED, LATE, OTHER, FUTURE, ENCODER_JUMP, WRENCH_JUMP = 1, 2, 3, -7, -8, -10
#: how many counter wraps back (256 SYNCs each) a failed CRC is tried against before it is called
#: corruption (``checksum``) rather than a replay (``stale``): bounded work on the failure path only
#: (four table steps a wrap), 4.1 s of SYNCs at 1 kHz
STALE_WRAPS = 16
#: the full counts are 32-bit (the SYNC's SyncCounter): they wrap after 2^32 SYNCs, 49.7 days at 1 kHz
COUNT_MOD = 1 << 32


@njit(cache=True)
def _read_raw(data, first, nbytes, big):
    """The unsigned integer of bytes [first, first + nbytes) in the given byte order."""
    r = np.uint64(0)
    for b in range(nbytes):
        byte = data[first + b] if big else data[first + nbytes - 1 - b]
        r = (r << np.uint64(8)) | np.uint64(byte)
    return r


@njit(cache=True)
def _write_raw(out, first, nbytes, big, r):
    for b in range(nbytes):
        byte = (r >> np.uint64(8 * b)) & np.uint64(0xFF)
        out[first + nbytes - 1 - b if big else first + b] = np.uint8(byte)


@njit(cache=True)
def crc32_count(crc, count):
    """``crc`` continued over the four bytes of ``count`` (mod 2^32), little-endian: the implicit
    freshness value of a frame tied to a SYNC (``crc32_continue(crc, count.to_bytes(4, "little"),
    4)`` without the bytes)."""
    c = np.uint32(crc) ^ np.uint32(0xFFFFFFFF)
    v = np.uint32(np.int64(count) & np.int64(0xFFFFFFFF))
    for _ in range(4):
        c = CRC_TABLE[(c ^ v) & np.uint32(0xFF)] ^ (c >> np.uint32(8))
        v = v >> np.uint32(8)
    return np.int64(c ^ np.uint32(0xFFFFFFFF))


@njit(cache=True)
def full_count(low, ref):
    """The full SYNC count whose low byte is ``low`` nearest the receiver's ``ref`` (its latest
    full count): the one in [ref - 127, ref + 128]."""
    d = (np.int64(low) - np.int64(ref)) % 256
    if d > 128:
        d -= 256
    return np.int64(ref) + d


@njit(cache=True)
def _signal_value(data, si, sf, big):
    """The physical value of one signal (sig_i row si, sig_f row sf) of a payload."""
    first, nbytes, kind = si[S_BYTE], si[S_NBYTES], si[S_KIND]
    r = _read_raw(data, first, nbytes, big)
    if kind == KIND_FLOAT:
        if nbytes == 4:
            raw = float(np.array([np.uint32(r)]).view(np.float32)[0])
        else:
            raw = np.array([r]).view(np.float64)[0]
    elif kind == KIND_SIGNED:
        bits = 8 * nbytes
        v = np.int64(r)
        if bits < 64 and v >= np.int64(1) << np.int64(bits - 1):
            v -= np.int64(1) << np.int64(bits)
        raw = float(v)
    else:
        raw = float(r)
    return raw * sf[S_SCALE] + sf[S_OFFSET]


@njit(cache=True)
def find_message(ids, order, frame_id):
    """The message row of ``frame_id``, or -1."""
    k = np.searchsorted(ids, frame_id)
    if k < ids.shape[0] and ids[k] == frame_id:
        return order[k]
    return -1


@njit(cache=True)
def unpack_values(tab, mi, data, vals):
    """Every signal of message row mi's payload ``data`` (of its length) into ``vals``, SI."""
    t = tab[0]
    msgs, sig_i, sig_f = t["msgs"], t["sig_i"], t["sig_f"]
    big = msgs[mi, M_BIG] != 0
    for i in range(msgs[mi, M_NSIG]):
        vals[i] = _signal_value(data, sig_i[mi, i], sig_f[mi, i], big)


@njit(cache=True)
def check_frame(tab, frame_id, extended, fd, data, vals, ref):
    """Check and decode one received frame into ``vals`` (SI, in the layout's signal order).
    Returns (verdict, message row, full count): the verdict OK, one of the rejections
    (UNKNOWN_ID, ID_TYPE, FD_FLAG, LENGTH, CHECKSUM, STALE, RANGE + i), or NOT_COMPILED (the
    caller decodes with cantools).

    A frame tied to a SYNC (``msgs[row, M_CTR] >= 0``) carries only the low byte of the SYNC count
    it answers; its CRC covers the full 32-bit count (AUTOSAR SecOC's freshness value: implicit,
    after the payload). The receiver takes the count nearest its own latest one ``ref`` (the host:
    the last SYNC it sent; the device: the last SYNC it took) with that low byte
    (:func:`full_count`) and checks the CRC with it, so a frame recorded 256 (512, ...) SYNCs
    earlier and replayed fails: the two counts differ in four consecutive bytes, a burst of at
    most 32 bits, which CRC-32 always detects. On that failure path only, the CRC is tried with
    the count STALE_WRAPS wraps back at most: a match is STALE (the count it held returned), else
    CHECKSUM. The full count is -1 for a frame tied to no SYNC."""
    t = tab[0]
    msgs, sig_f = t["msgs"], t["sig_f"]
    count = np.int64(-1)
    mi = find_message(t["ids"], t["order"], frame_id)
    if mi < 0:
        return UNKNOWN_ID, mi, count
    m = msgs[mi]
    if (m[M_EXT] != 0) != extended:
        return ID_TYPE, mi, count
    if (m[M_FD] != 0) != fd:
        return FD_FLAG, mi, count
    n = len(data)
    if n != m[M_LEN]:
        return LENGTH, mi, count
    if m[M_IDCRC] >= 0:
        got = np.int64(_read_raw(data, n - CRC_BYTES, CRC_BYTES, False))
        crc = crc32_continue(m[M_IDCRC], data, n - CRC_BYTES)
        if m[M_CTR] >= 0:
            count = full_count(data[m[M_CTR]], ref)
            if crc32_count(crc, count) != got:
                for k in range(1, STALE_WRAPS + 1):
                    old = count - 256 * k
                    if old < 0:
                        break
                    if crc32_count(crc, old) == got:
                        return STALE, mi, old
                return CHECKSUM, mi, count
        elif crc != got:
            return CHECKSUM, mi, count
    if m[M_COMPILED] == 0:
        return NOT_COMPILED, mi, count
    unpack_values(tab, mi, data, vals)
    for i in range(m[M_NSIG]):
        if not (sig_f[mi, i, S_DLO] <= vals[i] <= sig_f[mi, i, S_DHI]):  # NaN fails too
            return RANGE + i, mi, count
    return OK, mi, count


@njit(cache=True)
def pack_frame(tab, mi, values, out, seal, count):
    """Encode ``values`` (SI, layout order) of message row mi into ``out`` (its length). ``seal``:
    the frame's CRC goes into its last four bytes (the checksum signal's value is not read), for a
    frame tied to a SYNC continued over the full SYNC ``count`` (the caller puts its low byte in
    the counter); else every value is encoded as given. Returns -1, or the index of the first
    value outside its encode range or its bits (nothing is then promised of ``out``)."""
    t = tab[0]
    sig_i, sig_f = t["sig_i"], t["sig_f"]
    m = t["msgs"][mi]
    big = m[M_BIG] != 0
    n = m[M_LEN]
    for b in range(n):
        out[b] = 0
    sealed = seal and m[M_IDCRC] >= 0
    crc_first = n - CRC_BYTES if sealed else n
    for i in range(m[M_NSIG]):
        si, sf = sig_i[mi, i], sig_f[mi, i]
        first, nbytes, kind = si[S_BYTE], si[S_NBYTES], si[S_KIND]
        if first >= crc_first:  # the checksum's bytes: written by the seal
            continue
        v = values[i]
        if not (sf[S_ELO] <= v <= sf[S_EHI]):
            return i
        raw = (v - sf[S_OFFSET]) / sf[S_SCALE]
        if kind == KIND_FLOAT:
            if nbytes == 4:
                r = np.uint64(np.array([np.float32(raw)]).view(np.uint32)[0])
            else:
                r = np.array([raw]).view(np.uint64)[0]
        else:
            ri = np.rint(raw)  # half to even, as Python's round
            bits = 8 * nbytes
            if kind == KIND_SIGNED:
                half = 2.0 ** (bits - 1)
                if not (-half <= ri < half):
                    return i
                r = np.uint64(np.int64(ri)) if bits == 64 else \
                    np.uint64(np.int64(ri) & ((np.int64(1) << np.int64(bits)) - np.int64(1)))
            else:
                if not (0.0 <= ri < 2.0 ** bits):
                    return i
                r = np.uint64(ri)
        _write_raw(out, first, nbytes, big, r)
    if sealed:
        crc = crc32_continue(m[M_IDCRC], out, n - CRC_BYTES)
        if m[M_CTR] >= 0:
            crc = crc32_count(crc, count)
        _write_raw(out, n - CRC_BYTES, CRC_BYTES, False, np.uint64(crc))
    return -1


# -- the driver's per-period frames ------------------------------------------------------------------

#: the driver's receive state, one record (a numpy structured array of shape (1,)) the kernel below
#: updates in place: joints (m x3, rad x3, the wrist unwrapped), wrench (N, N*m, load-cell frame),
#: the message rows of DEV_JOINTS and DEV_WRENCH in the codec's tables (``rows``), the last applied
#: counters (the low byte the host's history is indexed by, ``jc``, ``wc``, and the full SYNC
#: counts, ``jf``, ``wf``; -1: none yet), fresh flags and cycles since the last fresh reading,
#: device state, late frames, the encoder check's limits (6,: m, rad per SYNC; negative: off) and,
#: after an encoder jump, its joint, size and gap in SYNCs (``jump``); the load-cell check's limits
#: (``wslew`` 6,: N x3, N*m x3 per SYNC; negative: off), after a refused reading its axis, size and
#: gap in SYNCs (``wjump``), and the readings refused since the last applied one (``wrefused``).
DRIVER_STATE = np.dtype([
    ("rows", "i8", 2), ("joints", "f8", 6), ("wrench", "f8", 6), ("jc", "i8"), ("wc", "i8"), ("fresh_j", "i8"),
    ("fresh_w", "i8"), ("since_j", "i8"), ("since_w", "i8"), ("dev_state", "i8"), ("late", "i8"),
    ("step_max", "f8", 6), ("jump", "f8", 3), ("jf", "i8"), ("wf", "i8"), ("wslew", "f8", 6), ("wjump", "f8", 3),
    ("wrefused", "i8")])


@njit(cache=True)
def _beyond(meas, prev, limit, gap, out):
    """The component whose change |meas - prev| most exceeds ``gap`` times its ``limit`` (6,):
    -1 when none does; else its index, with (index, change, gap) in ``out``."""
    worst, k = 0.0, -1
    for i in range(6):
        excess = abs(meas[i] - prev[i]) - gap * limit[i]
        if excess > worst:
            worst, k = excess, i
    if k >= 0:
        out[0], out[1], out[2] = k, abs(meas[k] - prev[k]), gap
    return k


@njit(cache=True)
def rx_period_frame(tab, ds, syncs, frame_id, extended, fd, data, vals):
    """One received frame through :func:`check_frame` and, for the period's two device frames, into
    the driver state ``ds`` (:data:`DRIVER_STATE`): DEV_JOINTS (row ``ds.rows[0]``: six joints, the
    device state, the counter) and DEV_WRENCH (``ds.rows[1]``: six wrench values, the counter).

    ``syncs``: the SYNCs sent so far; the full count of a frame is the one nearest the last SYNC
    sent (:func:`check_frame`: a recorded frame replayed whole counter wraps later is STALE). A
    count the host has not sent yet is rejected (FUTURE), one no newer than the last applied is
    LATE (a duplicate too). The wrist angles are unwrapped next to the previous reading; a joint
    that moved more than ``step_max`` times the SYNCs between the two readings is an ENCODER_JUMP
    (``ds.jump`` says which, how far, over how many). A wrench component that changed more than
    ``wslew`` times the SYNCs since the last applied reading is a WRENCH_JUMP (``ds.wjump``): the
    reading is refused and the last one kept, so the allowance grows with each SYNC until a real
    step fits. Returns (verdict, message row); any other valid message is OTHER with its values in
    ``vals``."""
    ref = syncs - 1
    verdict, mi, count = check_frame(tab, frame_id, extended, fd, data, vals, ref)
    if verdict != OK:
        return verdict, mi
    r = ds[0]
    if mi != r["rows"][0] and mi != r["rows"][1]:
        return OTHER, mi
    is_joints = mi == r["rows"][0]
    if count < 0 or count > ref:  # a SYNC not sent yet: corrupted or foreign
        return FUTURE, mi
    if not is_joints:
        if count <= r["wf"]:
            r["late"] += 1
            return LATE, mi
        if r["wslew"][0] >= 0.0 and r["wf"] >= 0 and _beyond(vals, r["wrench"], r["wslew"], count - r["wf"],
                                                             r["wjump"]) >= 0:
            r["wrefused"] += 1
            return WRENCH_JUMP, mi
        r["wrench"][:] = vals[:6]
        r["wc"] = count % 256
        r["wf"] = count
        r["fresh_w"] = 1
        r["since_w"] = 0
        r["wrefused"] = 0
        return APPLIED, mi
    if count <= r["jf"]:
        r["late"] += 1
        return LATE, mi
    prev = r["joints"]
    meas = vals[:6]  # the scratch values, unwrapped in place (no allocation in the tick)
    for i in range(3, 6):  # unwrap the wrist angles next to the previous reading
        meas[i] = prev[i] + (meas[i] - prev[i] + math.pi) % (2.0 * math.pi) - math.pi
    if r["step_max"][0] >= 0.0 and r["jf"] >= 0 and _beyond(meas, prev, r["step_max"], count - r["jf"],
                                                            r["jump"]) >= 0:
        return ENCODER_JUMP, mi
    prev[:] = meas
    r["jc"] = count % 256
    r["jf"] = count
    r["dev_state"] = np.int64(vals[6])
    r["fresh_j"] = 1
    r["since_j"] = 0
    return APPLIED, mi


@njit(cache=True)
def end_cycle_counts(ds, stale_cycles):
    """Age the feedback by one cycle: the cycles since a fresh reading, the fresh flags cleared.
    Returns whether either reading is ``stale_cycles`` old."""
    r = ds[0]
    if r["fresh_j"] == 0:
        r["since_j"] += 1
    if r["fresh_w"] == 0:
        r["since_w"] += 1
    r["fresh_j"] = r["fresh_w"] = 0
    return max(r["since_j"], r["since_w"]) >= stale_cycles


@njit(cache=True)
def pack_command(tab, mi, qd, limits, run, count, values, out):
    """HOST_CMD (row mi: six joint rates, the mode, the counter) into ``out``: the rates (6,: m/s
    x3, rad/s x3) clipped to ``limits`` (6,), mode 1; zero rates and mode 0 when not ``run`` or a
    rate is not finite; the counter the low byte of ``count``, the full SYNC count of the cycle
    (in the CRC). Returns whether the command ran (mode 1), or -1 if a value did not encode."""
    ok = run
    for i in range(6):
        ok = ok and math.isfinite(qd[i])
    for i in range(6):
        values[i] = min(max(qd[i], -limits[i]), limits[i]) if ok else 0.0
    values[6] = 1.0 if ok else 0.0
    values[7] = count % 256
    if pack_frame(tab, mi, values, out, True, count) >= 0:
        return -1
    return 1 if ok else 0
