"""Every DBC frame round-trips encode -> decode across its signals' ranges (hypothesis)."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop.master.cobot.database import Decoded, FrameDatabase

DB = FrameDatabase()
MESSAGES = [m for m in DB.db.messages]


def signal_values(msg):
    fields = {}
    for s in msg.signals:
        if s.name.endswith("Checksum"):
            continue
        lo, hi = s.minimum, s.maximum
        if s.scale == 1 and s.offset == 0:
            fields[s.name] = st.integers(int(lo), int(hi))
        else:  # on the device grid, inside the range
            k_lo, k_hi = math.ceil(lo / s.scale), math.floor(hi / s.scale)
            fields[s.name] = st.integers(k_lo, k_hi).map(lambda k, sc=s.scale: k * sc)
    return st.fixed_dictionaries(fields)


@pytest.mark.parametrize("msg", MESSAGES, ids=[m.name for m in MESSAGES])
def test_roundtrip(msg):
    @settings(max_examples=60, deadline=None)
    @given(signal_values(msg))
    def check(values):
        fid, data, fd = DB.encode(msg.name, values)
        assert fid == msg.frame_id and len(data) == msg.length and fd
        out = DB.decode(fid, data)
        assert isinstance(out, Decoded), out
        for k, v in values.items():
            sig = msg.get_signal_by_name(k)
            assert out.signals[k] == pytest.approx(v, abs=sig.scale * 0.5 + 1e-12)

    check()
