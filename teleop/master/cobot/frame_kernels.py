"""Compiled CAN frame codec (numba): the checks, the decoding and the encoding of a frame over the
layout tables :mod:`.codec` derives from the DBC, and the driver's per-period frames applied in
one call.

A frame's bytes go to the math through one compiled call: id lookup, id type, FD flag, length,
the CRC-32 (the frame id's two bytes, little-endian, then the payload before the CRC; continued
from the id's CRC), each signal unpacked, scaled (``raw * scale + offset``) and checked against
its DBC range. Encoding is the inverse (``raw = (v - offset) / scale``, rounded half to even for
an integer signal, as cantools and Python's ``round`` do), strict, then sealed with the CRC.

The layout tables (built by :func:`.codec.layout_tables`), the fields of one record ``tab`` (a
numpy structured array of shape (1,), so that a kernel call passes one argument for all five):

* ``msgs`` int64 (n_msgs, MSG_COLS): frame id, extended id, FD, length, the CRC of the id alone
  (-1: unprotected), number of signals, big-endian, compiled (0: a layout the tables cannot hold;
  the caller uses cantools);
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

from teleop.util.crc32 import crc32_continue

#: msgs columns
M_ID, M_EXT, M_FD, M_LEN, M_IDCRC, M_NSIG, M_BIG, M_COMPILED = range(8)
MSG_COLS = 8
#: sig_i columns and kinds
S_BYTE, S_NBYTES, S_KIND = range(3)
SIG_I_COLS = 3
KIND_UNSIGNED, KIND_SIGNED, KIND_FLOAT = range(3)
#: sig_f columns
S_SCALE, S_OFFSET, S_DLO, S_DHI, S_ELO, S_EHI = range(6)
SIG_F_COLS = 6
#: bytes of the CRC at the end of a protected frame
CRC_BYTES = 4

#: check_frame's verdicts; RANGE + i: signal i outside its range (its value left in ``vals[i]``)
OK, UNKNOWN_ID, ID_TYPE, FD_FLAG, LENGTH, CHECKSUM, NOT_COMPILED = 0, -1, -2, -3, -4, -5, -6
RANGE = 1000
#: rx_period_frame's verdicts beyond check_frame's: applied, late (an old counter), another valid
#: message (values in ``vals``), a counter the host has not sent, an encoder jump (fault latched)
APPLIED, LATE, OTHER, FUTURE, ENCODER_JUMP = 1, 2, 3, -7, -8


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
def check_frame(tab, frame_id, extended, fd, data, vals):
    """Check and decode one received frame into ``vals`` (SI, in the layout's signal order).
    Returns (verdict, message row): OK, one of the rejections (UNKNOWN_ID, ID_TYPE, FD_FLAG,
    LENGTH, CHECKSUM, RANGE + i), or NOT_COMPILED (the caller decodes with cantools)."""
    t = tab[0]
    msgs, sig_f = t["msgs"], t["sig_f"]
    mi = find_message(t["ids"], t["order"], frame_id)
    if mi < 0:
        return UNKNOWN_ID, mi
    m = msgs[mi]
    if (m[M_EXT] != 0) != extended:
        return ID_TYPE, mi
    if (m[M_FD] != 0) != fd:
        return FD_FLAG, mi
    n = len(data)
    if n != m[M_LEN]:
        return LENGTH, mi
    if m[M_IDCRC] >= 0:
        got = np.int64(_read_raw(data, n - CRC_BYTES, CRC_BYTES, False))
        if crc32_continue(m[M_IDCRC], data, n - CRC_BYTES) != got:
            return CHECKSUM, mi
    if m[M_COMPILED] == 0:
        return NOT_COMPILED, mi
    unpack_values(tab, mi, data, vals)
    for i in range(m[M_NSIG]):
        if not (sig_f[mi, i, S_DLO] <= vals[i] <= sig_f[mi, i, S_DHI]):  # NaN fails too
            return RANGE + i, mi
    return OK, mi


@njit(cache=True)
def pack_frame(tab, mi, values, out, seal):
    """Encode ``values`` (SI, layout order) of message row mi into ``out`` (its length). ``seal``:
    the frame's CRC goes into its last four bytes (the checksum signal's value is not read); else
    every value is encoded as given. Returns -1, or the index of the first value outside its
    encode range or its bits (nothing is then promised of ``out``)."""
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
        _write_raw(out, n - CRC_BYTES, CRC_BYTES, False, np.uint64(crc32_continue(m[M_IDCRC], out, n - CRC_BYTES)))
    return -1


# -- the driver's per-period frames ------------------------------------------------------------------

#: the driver's receive state, one record (a numpy structured array of shape (1,)) the kernel below
#: updates in place: joints (m x3, rad x3, the wrist unwrapped), wrench (N, N*m, load-cell frame),
#: the message rows of DEV_JOINTS and DEV_WRENCH in the codec's tables (``rows``), the last applied
#: counters (-1: none yet), fresh flags and cycles since the last fresh reading,
#: device state, late frames, the encoder check's limits (6,: m, rad per SYNC; negative:
#: off) and, after an encoder jump, its joint, size and gap in SYNCs (``jump``).
DRIVER_STATE = np.dtype([
    ("rows", "i8", 2), ("joints", "f8", 6), ("wrench", "f8", 6), ("jc", "i8"), ("wc", "i8"), ("fresh_j", "i8"),
    ("fresh_w", "i8"), ("since_j", "i8"), ("since_w", "i8"), ("dev_state", "i8"), ("late", "i8"),
    ("step_max", "f8", 6), ("jump", "f8", 3)])


@njit(cache=True)
def _newer(counter, last):
    return last < 0 or 0 < (counter - last) % 256 < 128


@njit(cache=True)
def rx_period_frame(tab, ds, syncs, frame_id, extended, fd, data, vals):
    """One received frame through :func:`check_frame` and, for the period's two device frames, into
    the driver state ``ds`` (:data:`DRIVER_STATE`): DEV_JOINTS (row ``ds.rows[0]``: six joints, the
    device state, the counter) and DEV_WRENCH (``ds.rows[1]``: six wrench values, the counter). A
    counter the host has not sent yet (``syncs``: the SYNCs sent so far) is rejected (FUTURE), an
    older one than the last applied is LATE; the wrist angles are unwrapped next to the previous
    reading; a joint that moved more than ``step_max`` times the SYNCs between readings is an
    ENCODER_JUMP (``ds.jump`` says which, how far, over how many). Returns (verdict, message row);
    any other valid message is OTHER with its values in ``vals``."""
    verdict, mi = check_frame(tab, frame_id, extended, fd, data, vals)
    if verdict != OK:
        return verdict, mi
    r = ds[0]
    if mi != r["rows"][0] and mi != r["rows"][1]:
        return OTHER, mi
    is_joints = mi == r["rows"][0]
    counter = np.int64(vals[7] if is_joints else vals[6])
    if syncs == 0 or (syncs - 1 - counter) % 256 >= 128:  # a SYNC not sent yet: corrupted or foreign
        return FUTURE, mi
    if not is_joints:
        if not _newer(counter, r["wc"]):
            r["late"] += 1
            return LATE, mi
        r["wrench"][:] = vals[:6]
        r["wc"] = counter
        r["fresh_w"] = 1
        r["since_w"] = 0
        return APPLIED, mi
    if not _newer(counter, r["jc"]):
        r["late"] += 1
        return LATE, mi
    prev, step_max = r["joints"], r["step_max"]
    meas = vals[:6]  # the scratch values, unwrapped in place (no allocation in the tick)
    for i in range(3, 6):  # unwrap the wrist angles next to the previous reading
        meas[i] = prev[i] + (meas[i] - prev[i] + math.pi) % (2.0 * math.pi) - math.pi
    if step_max[0] >= 0.0 and r["jc"] >= 0:
        gap = (counter - r["jc"]) % 256
        worst, k = 0.0, -1
        for i in range(6):
            jump = abs(meas[i] - prev[i]) - gap * step_max[i]
            if jump > worst:
                worst, k = jump, i
        if k >= 0:
            r["jump"][0], r["jump"][1], r["jump"][2] = k, abs(meas[k] - prev[k]), gap
            return ENCODER_JUMP, mi
    prev[:] = meas
    r["jc"] = counter
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
def pack_command(tab, mi, qd, limits, run, counter, values, out):
    """HOST_CMD (row mi: six joint rates, the mode, the counter) into ``out``: the rates (6,: m/s
    x3, rad/s x3) clipped to ``limits`` (6,), mode 1; zero rates and mode 0 when not ``run`` or a
    rate is not finite. Returns whether the command ran (mode 1), or -1 if a value did not encode."""
    ok = run
    for i in range(6):
        ok = ok and math.isfinite(qd[i])
    for i in range(6):
        values[i] = min(max(qd[i], -limits[i]), limits[i]) if ok else 0.0
    values[6] = 1.0 if ok else 0.0
    values[7] = counter % 256
    if pack_frame(tab, mi, values, out, True) >= 0:
        return -1
    return 1 if ok else 0
