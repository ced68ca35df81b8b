"""Per-message codecs: each message's layout read once from the cantools database into the tables
of the compiled frame codec (:mod:`.frame_kernels`).

cantools encodes and decodes through Python loops over its signal objects, with dict plumbing and
strict checks on every call (≈ 10 µs to encode a 16-byte frame). :func:`compile_layout` reads a
message's layout from the DBC (start bit, length, byte order, signedness, float-ness, scale,
offset, range) and, when every signal fills whole bytes in one byte order with a linear
conversion, :func:`layout_tables` writes it into the compiled codec's tables; any other layout
(bit fields, multiplexing, integer-scale conversions) keeps cantools' own codec.
Either way the values are those of cantools: raw -> physical is ``raw * scale + offset``,
physical -> raw is ``(v - offset) / scale`` rounded half to even for an integer signal (cantools'
``numeric_scaled_to_raw``), and the range check is cantools' strict one
(tests/property/test_can_codec.py compares both on random frames).

Values are SI (the DBC's units); raw values are the integers on the wire.
"""

from __future__ import annotations

import math

import numpy as np
from cantools.database.conversion import (
    BaseConversion,
    IdentityConversion,
    LinearConversion,
    LinearIntegerConversion,
)

from teleop.master.cobot import frame_kernels as FK
from teleop.util.crc32 import crc32_continue
from teleop.util.errors import CanError

_INT_BYTES = (1, 2, 4, 8)
_FLOAT_BYTES = (4, 8)


def _field(signal) -> tuple[int, int, int] | None:
    """(first byte, bytes, kind) of a signal that fills whole bytes, or None."""
    if signal.length % 8 or signal.length // 8 not in (_FLOAT_BYTES if signal.is_float else _INT_BYTES):
        return None
    kind = FK.KIND_FLOAT if signal.is_float else FK.KIND_SIGNED if signal.is_signed else FK.KIND_UNSIGNED
    # cantools numbers a little-endian signal by its LSB, a big-endian one by its MSB (bit 7 of
    # its first byte in the DBC's sawtooth numbering)
    aligned = signal.start % 8 == (0 if signal.byte_order == "little_endian" else 7)
    return (signal.start // 8, signal.length // 8, kind) if aligned else None


def _base_conversion(signal) -> type:
    """The type of a signal's numeric conversion (a value table's wraps one: cantools builds it by
    the same factory from the scale and offset)."""
    c = signal.conversion
    return type(BaseConversion.factory(scale=c.scale, offset=c.offset, is_float=signal.is_float))


def compile_layout(message) -> tuple[tuple, tuple] | None:
    """(fields (first byte, bytes, kind) per signal, signals) in byte order of a byte-aligned,
    single-byte-order message without multiplexing whose conversions are cantools' identity or
    linear ones (with or without a value table); None for any other layout."""
    signals = tuple(sorted(message.signals, key=lambda s: s.start // 8))
    orders = {s.byte_order for s in signals}
    if not signals or len(orders) != 1 or any(s.is_multiplexer or s.multiplexer_ids for s in signals):
        return None
    if any(_base_conversion(s) not in (IdentityConversion, LinearConversion) for s in signals):
        return None
    fields, pos = [], 0
    for s in signals:
        f = _field(s)
        if f is None or f[0] < pos:  # not byte-aligned, or overlapping
            return None
        fields.append(f)
        pos = f[0] + f[1]
    return (tuple(fields), signals) if pos <= message.length else None


def _decode_slack(signal) -> float:
    """Tolerance (physical units) of a decoded value against the DBC range: half a raw step for
    integer signals, round-off for floats. The DBC writes its limits at physical resolution
    (0.99996 for raw 32767 x 2^-15), so whatever strict encoding accepts, decoding does."""
    return 1e-9 + (0.0 if signal.is_float else 0.5 * abs(signal.conversion.scale))


#: the DBC message attribute that ties a message to a SYNC: 1 = its CRC covers the full SYNC count
#: its 8-bit ``*Counter`` names (:func:`.frame_kernels.check_frame`)
SYNC_FRESHNESS = "SyncFreshness"


def sync_counter(message):
    """The 8-bit counter signal of a message tied to a SYNC (its DBC attribute ``SyncFreshness``
    is 1), or None for a message tied to none. The counter must be the message's one ``*Counter``
    signal: unsigned, 8 bits in one byte, identity conversion (its raw value is the count's low
    byte); anything else raises :class:`CanError`."""
    attrs = message.dbc.attributes if message.dbc is not None else {}
    attr = attrs.get(SYNC_FRESHNESS)
    if attr is None or not attr.value:
        return None
    counters = [s for s in message.signals if s.name.endswith("Counter")]
    s = counters[0] if len(counters) == 1 else None
    aligned = s is not None and s.start % 8 == (0 if s.byte_order == "little_endian" else 7)
    if not (aligned and s.length == 8 and not s.is_signed and not s.is_float and s.conversion.scale == 1
            and s.conversion.offset == 0):
        raise CanError(f"can database: {message.name} has {SYNC_FRESHNESS} 1 and must carry one *Counter signal "
                       f"of 8 unsigned bits in one byte, scale 1, offset 0")
    return s


def _signal_order(message) -> tuple:
    compiled = compile_layout(message)
    return compiled[1] if compiled is not None else tuple(message.signals)


def layout_tables(messages, crc_of_id=None) -> np.ndarray:
    """The compiled codec's tables (a record with fields msgs, sig_i, sig_f, ids, order; see
    :mod:`.frame_kernels`) of
    ``messages`` (cantools ``Message`` objects), signals in :func:`compile_layout`'s order (the
    DBC's for a layout it cannot compile). ``crc_of_id(frame_id)``: the CRC of a protected
    message's id (a message with a ``*Checksum`` signal), None: no message is protected; a
    protected message tied to a SYNC (:func:`sync_counter`) gets its counter's byte in M_CTR."""
    messages = list(messages)
    n_sig = max([len(m.signals) for m in messages] + [1])
    msgs = np.zeros((len(messages), FK.MSG_COLS), np.int64)
    sig_i = np.zeros((len(messages), n_sig, FK.SIG_I_COLS), np.int64)
    sig_f = np.zeros((len(messages), n_sig, FK.SIG_F_COLS))
    for row, m in enumerate(messages):
        compiled = compile_layout(m)
        signals = compiled[1] if compiled is not None else tuple(m.signals)
        protected = crc_of_id is not None and any(s.name.endswith("Checksum") for s in signals)
        ctr = sync_counter(m) if protected else None
        msgs[row] = (m.frame_id, m.is_extended_frame, m.is_fd, m.length,
                     crc_of_id(m.frame_id) if protected else -1, len(signals),
                     bool(signals) and signals[0].byte_order == "big_endian", compiled is not None,
                     -1 if ctr is None else ctr.start // 8)
        for i, s in enumerate(signals):
            if compiled is not None:
                sig_i[row, i] = compiled[0][i]
            scale = s.conversion.scale
            checked = not s.name.endswith("Checksum")  # a checksum's check is the CRC
            sig_f[row, i] = (
                scale, s.conversion.offset,
                s.minimum - _decode_slack(s) if checked and s.minimum is not None else -math.inf,
                s.maximum + _decode_slack(s) if checked and s.maximum is not None else math.inf,
                # cantools' strict encode: the range widened by a millionth of the scale
                -math.inf if s.minimum is None else s.minimum - abs(scale) * 1e-6,
                math.inf if s.maximum is None else s.maximum + abs(scale) * 1e-6)
    ids = msgs[:, FK.M_ID]
    order = np.argsort(ids, kind="stable")
    n = len(messages)
    tab = np.zeros(1, np.dtype([("msgs", "i8", msgs.shape), ("sig_i", "i8", sig_i.shape), ("sig_f", "f8", sig_f.shape),
                                ("ids", "i8", (n,)), ("order", "i8", (n,))]))
    tab["msgs"], tab["sig_i"], tab["sig_f"], tab["ids"], tab["order"] = msgs, sig_i, sig_f, ids[order], order
    return tab


class MessageCodec:
    """Encode and decode one message's payload (a cantools ``Message``) in physical units; the
    checksum signal, if any, is a value like the others here (the database seals and checks)."""

    def __init__(self, message):
        self.message = message
        self.name, self.frame_id, self.length = message.name, message.frame_id, message.length
        self.signals = _signal_order(message)
        self.names = tuple(s.name for s in self.signals)
        self.tables = layout_tables([message])
        self.compiled = bool(self.tables[0]["msgs"][0, FK.M_COMPILED])
        # cantools gives an int for an integer signal with an integer conversion, else a float
        self._int = tuple(_base_conversion(s) in (IdentityConversion, LinearIntegerConversion) and not s.is_float
                          for s in self.signals)
        self._ints = any(self._int)
        self._scale_offset = tuple((s.conversion.scale, s.conversion.offset) for s in self.signals)
        self._to_raw = tuple(s.conversion.numeric_scaled_to_raw for s in self.signals)
        self._encode_range = tuple(
            (-math.inf if s.minimum is None else s.minimum - abs(s.conversion.scale) * 1e-6,
             math.inf if s.maximum is None else s.maximum + abs(s.conversion.scale) * 1e-6,
             frozenset(s.conversion.choices or ()))
            for s in self.signals)
        self._values = np.empty(len(self.names))

    def encode(self, values) -> bytes:
        """Payload of ``values`` (a mapping with every signal, physical units); strict like
        cantools: a missing, unknown, non-finite or out-of-range value raises :class:`CanError`."""
        if len(values) != len(self.names) or not all(n in values for n in self.names):
            missing = sorted(set(self.names) - set(values))
            unknown = sorted(set(values) - set(self.names))
            raise CanError(f"can encode {self.name}: missing signals {missing}, unknown signals {unknown}")
        return self.encode_ordered([values[n] for n in self.names])

    def encode_ordered(self, values, seal: bool = False, tables=None, row: int = 0, count: int = -1) -> bytes:
        """:meth:`encode` for values given in the order of :attr:`names` (no mapping to build).
        ``seal``: put the frame's CRC-32 (of the id in ``tables``' message ``row``, the database's;
        for a message tied to a SYNC continued over the full SYNC ``count``) in its last four bytes
        instead of the checksum signal's value."""
        if len(values) != len(self.names):
            raise CanError(f"can encode {self.name}: expected {len(self.names)} values, got {len(values)}")
        tab = self.tables if tables is None else tables
        msgs, sig_i = tab[0]["msgs"], tab[0]["sig_i"]
        if self.compiled:
            buf = self._values
            try:
                buf[:] = values
            except (TypeError, ValueError):
                self._check_each(values)  # raises: a value that is not a number
                raise
            out = bytearray(self.length)
            bad = FK.pack_frame(tab, row, buf, out, seal, count)
            if bad < 0:
                return bytes(out)
            self._check_each(values)  # raises, unless the value is in the signal's value table
            lo, hi, _ = self._encode_range[bad]
            if lo <= values[bad] <= hi:  # in range, yet too wide for its bits
                raise CanError(f"can encode {self.name}.{self.names[bad]}: {values[bad]} does not fit its "
                               f"{8 * int(sig_i[row, bad, FK.S_NBYTES])} bits")
        else:  # cantools' codec for this layout
            self._check_each(values)
        raw = [to_raw(v) for to_raw, v in zip(self._to_raw, values)]
        data = self.message.encode(dict(zip(self.names, raw)), scaling=False, strict=False)
        idcrc = int(msgs[row, FK.M_IDCRC])
        if not seal or idcrc < 0:
            return data
        body = bytes(data[:-FK.CRC_BYTES])
        crc = crc32_continue(idcrc, body, len(body))
        if msgs[row, FK.M_CTR] >= 0:
            crc = FK.crc32_count(crc, count)
        return body + int(crc).to_bytes(FK.CRC_BYTES, "little")

    def _check_each(self, values) -> None:
        """The range check value by value, raising :class:`CanError` for the first bad one."""
        for name, v, (lo, hi, choices) in zip(self.names, values, self._encode_range):
            try:
                if not lo <= v <= hi:  # NaN fails here too
                    self._reject(name, v, lo, hi, choices)
            except TypeError:
                raise CanError(f"can encode {self.name}.{name}: expected a number, got {v!r}") from None

    def _reject(self, name, v, lo, hi, choices) -> None:
        if not math.isfinite(v):
            raise CanError(f"can encode {self.name}.{name}: non-finite value {v}")
        if self._to_raw[self.names.index(name)](v) not in choices:
            raise CanError(f"can encode {self.name}.{name}: {v} outside the DBC range [{lo}, {hi}]")

    def values_from(self, vals: np.ndarray) -> tuple:
        """The decoded values ``vals`` (n,) as cantools gives them: an int for an integer signal with
        the identity conversion, else a float."""
        out = vals[: len(self.names)].tolist()
        if self._ints:
            out = [int(v) if i else v for v, i in zip(out, self._int)]
        return tuple(out)

    def decode(self, data: bytes) -> tuple:
        """Physical values of a payload of the right length, in the order of :attr:`names`."""
        if self.compiled:
            FK.unpack_values(self.tables, 0, bytes(data), self._values)
            return self.values_from(self._values)
        raw = self.message.decode(data, decode_choices=False, scaling=False)
        return tuple(raw[n] * sc + off for n, (sc, off) in zip(self.names, self._scale_offset))
