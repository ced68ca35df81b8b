"""The compiled per-message codecs agree with cantools on every frame of the DBC (hypothesis):
the same payload bytes, the same decoded values, the same strict range verdicts."""

import math

import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop.master.cobot.codec import MessageCodec, compile_struct
from teleop.master.cobot.database import FrameDatabase
from teleop.errors import CanError

DB = FrameDatabase()
MESSAGES = list(DB.db.messages)
IDS = [m.name for m in MESSAGES]


def physical_values(msg, margin: float = 0.0):
    """Any float (ints for scale-1 signals) within [min - margin*span, max + margin*span]."""
    fields = {}
    for s in msg.signals:
        lo, hi = s.minimum, s.maximum
        pad = margin * (hi - lo)
        if s.conversion.scale == 1 and s.conversion.offset == 0:
            fields[s.name] = st.integers(int(lo - pad), int(hi + pad))
        else:
            fields[s.name] = st.floats(lo - pad, hi + pad, allow_nan=False)
    return st.fixed_dictionaries(fields)


def test_every_protocol_message_compiles_to_a_struct():
    for msg in MESSAGES:
        assert compile_struct(msg) is not None, msg.name


@pytest.mark.parametrize("msg", MESSAGES, ids=IDS)
def test_encode_matches_cantools(msg):
    codec = MessageCodec(msg)

    @settings(max_examples=150, deadline=None)
    @given(physical_values(msg, margin=0.01))
    def check(values):
        try:
            ref = msg.encode(values, strict=True, scaling=True)
        except cantools.database.EncodeError:
            ref = None
        if ref is None:
            with pytest.raises(CanError):
                codec.encode(values)
        else:
            assert codec.encode(values) == ref

    check()


@pytest.mark.parametrize("msg", MESSAGES, ids=IDS)
def test_decode_matches_cantools_on_any_payload(msg):
    codec = MessageCodec(msg)

    @settings(max_examples=150, deadline=None)
    @given(st.binary(min_size=msg.length, max_size=msg.length))
    def check(data):
        ref = msg.decode(data, decode_choices=False, scaling=True)
        out = dict(zip(codec.names, codec.decode(data)))
        assert out.keys() == ref.keys()
        for k, v in ref.items():
            assert out[k] == v and type(out[k]) is type(v), k

    check()


@pytest.mark.parametrize("msg", MESSAGES, ids=IDS)
def test_database_roundtrip_is_on_the_grid(msg):
    """encode -> decode through the database (checksums included) returns cantools' quantization."""

    @settings(max_examples=60, deadline=None)
    @given(physical_values(msg))
    def check(values):
        values = {k: v for k, v in values.items() if not k.endswith("Checksum")}
        fid, data, _ = DB.encode(msg.name, values)
        out = DB.decode(fid, data)
        for k, v in values.items():
            sig = msg.get_signal_by_name(k)
            assert out.signals[k] == sig.conversion.raw_to_scaled(sig.conversion.numeric_scaled_to_raw(v), False)

    check()


def test_codec_rejects_like_strict_cantools():
    codec = DB.codecs["HOST_CMD"]
    ok = dict(CmdVelX=0.1, CmdVelY=0.0, CmdVelZ=0.0, CmdRateA=0.0, CmdRateB=0.0, CmdRateC=0.0, CmdMode=1,
              CmdCounter=0, CmdChecksum=0)
    for bad, match in ((dict(ok, CmdVelX=math.nan), "non-finite"), (dict(ok, CmdRateA=16.5), "range"),
                       (dict(ok, Extra=1), "unknown"), ({k: v for k, v in ok.items() if k != "CmdMode"}, "missing"),
                       (dict(ok, CmdMode="run"), "number")):
        with pytest.raises(CanError, match=match):
            codec.encode(bad)
