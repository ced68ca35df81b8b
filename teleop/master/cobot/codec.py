"""Per-message codecs compiled once from the cantools database.

cantools encodes and decodes through Python loops over its signal objects, with dict plumbing and
strict checks on every call (≈ 10 µs to encode a 16-byte frame). A :class:`MessageCodec` reads the
same message's layout from the DBC once (start bit, length, byte order, signedness, float-ness,
scale, offset, range, value table) and, when every signal fills whole bytes in one byte order,
compiles it into a single :class:`struct.Struct`; any other layout keeps cantools' own bit codec.
Either way the values are those of cantools: raw -> physical is ``raw * scale + offset`` and
physical -> raw is the signal conversion's own ``numeric_scaled_to_raw``, and the range check is
cantools' strict one (tests/property/test_can_codec.py compares both on random frames).

Values are SI (the DBC's units); raw values are the integers on the wire.
"""

from __future__ import annotations

import math
import operator
import struct

from cantools.database.conversion import IdentityConversion, LinearConversion

from teleop.errors import CanError

_INT_CODES = {8: "b", 16: "h", 32: "i", 64: "q"}  # upper case: unsigned
_FLOAT_CODES = {16: "e", 32: "f", 64: "d"}


def _field(signal) -> tuple[int, str] | None:
    """(first byte, struct code) of a signal that fills whole bytes, or None."""
    if signal.is_float:
        code = _FLOAT_CODES.get(signal.length)
    else:
        code = _INT_CODES.get(signal.length)
        code = code if code is None or signal.is_signed else code.upper()
    if code is None:
        return None
    # cantools numbers a little-endian signal by its LSB, a big-endian one by its MSB (bit 7 of
    # its first byte in the DBC's sawtooth numbering)
    aligned = signal.start % 8 == (0 if signal.byte_order == "little_endian" else 7)
    return (signal.start // 8, code) if aligned else None


def compile_struct(message) -> tuple[struct.Struct, tuple] | None:
    """(struct, signals in field order) of a byte-aligned, single-byte-order message without
    multiplexing, with unused bytes as zero padding; None for any other layout."""
    signals = sorted(message.signals, key=lambda s: s.start // 8)
    orders = {s.byte_order for s in signals}
    if not signals or len(orders) != 1 or any(s.is_multiplexer or s.multiplexer_ids for s in signals):
        return None
    fmt, pos = ["<" if orders == {"little_endian"} else ">"], 0
    for s in signals:
        f = _field(s)
        if f is None or f[0] < pos:  # not byte-aligned, or overlapping
            return None
        fmt.append("x" * (f[0] - pos) + f[1])
        pos = f[0] + s.length // 8
    if pos > message.length:
        return None
    fmt.append("x" * (message.length - pos))
    return struct.Struct("".join(fmt)), tuple(signals)


class MessageCodec:
    """Encode and decode one message (a cantools ``Message``) in physical units."""

    def __init__(self, message):
        self.message = message
        self.name, self.frame_id, self.length = message.name, message.frame_id, message.length
        compiled = compile_struct(message)
        self.struct, signals = compiled if compiled is not None else (None, tuple(message.signals))
        self.signals = signals
        self.names = tuple(s.name for s in signals)
        self._scale_offset = tuple((s.conversion.scale, s.conversion.offset) for s in signals)
        self._scales = tuple(sc for sc, _ in self._scale_offset)
        self._offsets = tuple(off for _, off in self._scale_offset)
        self._to_raw = tuple(s.conversion.numeric_scaled_to_raw for s in signals)
        # cantools' identity and linear conversions are raw = (v - offset) / scale, rounded for an
        # integer signal: computed inline for those (no call per value); any other conversion
        # (integer scale and offset, value tables) calls cantools' own
        self._inline = all(type(s.conversion) in (IdentityConversion, LinearConversion) for s in signals)
        self._round = tuple(not s.is_float for s in signals)
        self._all_int = all(self._round)
        # cantools' strict encode: the range widened by a millionth of the scale, except for raw
        # values of the signal's value table
        self._encode_range = tuple(
            (-math.inf if s.minimum is None else s.minimum - abs(s.conversion.scale) * 1e-6,
             math.inf if s.maximum is None else s.maximum + abs(s.conversion.scale) * 1e-6,
             frozenset(s.conversion.choices or ()))
            for s in signals)
        self._lo = tuple(lo for lo, _, _ in self._encode_range)
        self._hi = tuple(hi for _, hi, _ in self._encode_range)

    def encode(self, values) -> bytes:
        """Payload of ``values`` (a mapping with every signal, physical units); strict like
        cantools: a missing, unknown, non-finite or out-of-range value raises :class:`CanError`."""
        if len(values) != len(self.names) or not all(n in values for n in self.names):
            missing = sorted(set(self.names) - set(values))
            unknown = sorted(set(values) - set(self.names))
            raise CanError(f"can encode {self.name}: missing signals {missing}, unknown signals {unknown}")
        return self.encode_ordered([values[n] for n in self.names])

    def encode_ordered(self, values) -> bytes:
        """:meth:`encode` for values given in the order of :attr:`names` (no mapping to build)."""
        if len(values) != len(self.names):
            raise CanError(f"can encode {self.name}: expected {len(self.names)} values, got {len(values)}")
        try:  # every value in range (the loops in C); NaN fails here too
            ok = all(map(operator.le, self._lo, values)) and all(map(operator.le, values, self._hi))
        except TypeError:
            ok = False
        if not ok:
            self._check_each(values)  # raises, unless a value outside the range is in the value table
        if self._inline and self._all_int:  # the loops in C
            raw = list(map(round, map(operator.truediv, map(operator.sub, values, self._offsets), self._scales)))
        elif self._inline:
            raw = [round((v - off) / sc) if rnd else (v - off) / sc
                   for v, off, sc, rnd in zip(values, self._offsets, self._scales, self._round)]
        else:
            raw = [to_raw(v) for to_raw, v in zip(self._to_raw, values)]
        if self.struct is None:
            return self.message.encode(dict(zip(self.names, raw)), scaling=False, strict=False)
        try:
            return self.struct.pack(*raw)
        except struct.error as e:  # a raw value that does not fit its bits
            raise CanError(f"can encode {self.name}: {e}") from None

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

    def decode(self, data: bytes) -> tuple:
        """Physical values of a payload of the right length, in the order of :attr:`names`."""
        if self.struct is None:
            raw = self.message.decode(data, decode_choices=False, scaling=False)
            return tuple(raw[n] * sc + off for n, (sc, off) in zip(self.names, self._scale_offset))
        # raw * scale + offset per signal, the loop in C
        return tuple(map(operator.add, map(operator.mul, self.struct.unpack(data), self._scales), self._offsets))
