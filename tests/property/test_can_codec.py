"""The compiled frame codec agrees with cantools on every frame of the DBC (hypothesis): the same
payload bytes, the same decoded values and types, the same strict range verdicts; its CRC-32 is
crccheck's; no frame tied to a SYNC passes when replayed whole counter wraps later."""

import math

import cantools
import numpy as np
import pytest
from crccheck.crc import Crc32
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop.master.cobot import frame_kernels as FK
from teleop.master.cobot.codec import MessageCodec, compile_layout
from teleop.master.cobot.database import Decoded, FrameDatabase, Rejected
from teleop.util.crc32 import crc32_continue
from teleop.util.errors import CanError

DB = FrameDatabase()
#: layouts the shipped protocol does not use: big-endian integers and floats (compiled), bit fields
#: (cantools' codec), a value table with a value outside the range
OTHER_DBC = """VERSION ""
NS_ :
BS_:
BU_: A B
BO_ 256 BIG: 16 A
 SG_ BigI16 : 7|16@0- (0.01,0) [-300|300] "" B
 SG_ BigU8 : 23|8@0+ (1,0) [0|200] "" B
 SG_ BigF32 : 31|32@0- (1,0) [-1000|1000] "" B
 SG_ BigF64 : 63|64@0- (0.5,1) [-1e6|1e6] "" B
BO_ 257 BITS: 8 A
 SG_ Nib : 0|4@1+ (1,0) [0|15] "" B
 SG_ Rest : 4|12@1- (0.5,0) [-1000|1000] "" B
BO_ 258 CHOICE: 2 A
 SG_ Mode : 0|8@1+ (1,0) [0|3] "" B
 SG_ Other : 8|8@1+ (1,0) [0|255] "" B
SIG_VALTYPE_ 256 BigF32 : 1;
SIG_VALTYPE_ 256 BigF64 : 2;
VAL_ 258 Mode 0 "off" 1 "on" 255 "fault" ;
"""
OTHER = cantools.database.load_string(OTHER_DBC, "dbc")
MESSAGES = list(DB.db.messages) + list(OTHER.messages)
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


def test_every_protocol_message_compiles_to_the_codec_tables():
    for msg in DB.db.messages:
        assert compile_layout(msg) is not None and MessageCodec(msg).compiled, msg.name
    assert MessageCodec(OTHER.get_message_by_name("BIG")).compiled
    assert MessageCodec(OTHER.get_message_by_name("CHOICE")).compiled
    assert not MessageCodec(OTHER.get_message_by_name("BITS")).compiled  # bit fields: cantools' codec


def test_a_value_table_value_outside_the_range_encodes_as_cantools_strict():
    msg = OTHER.get_message_by_name("CHOICE")
    codec = MessageCodec(msg)
    assert codec.encode({"Mode": 255, "Other": 7}) == msg.encode({"Mode": 255, "Other": 7}, strict=True)
    with pytest.raises(CanError, match="Mode"):
        codec.encode({"Mode": 254, "Other": 7})


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=64), st.integers(0, 2**32 - 1))
def test_compiled_crc_is_crccheck_continued(data, start):
    """crc32_continue(CRC of a, b) = CRC of a + b, against crccheck (the wire's definition)."""
    head = start.to_bytes(4, "little")
    assert crc32_continue(Crc32.calc(head), data, len(data)) == Crc32.calc(head + data)


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
            same = out[k] == v or (isinstance(v, float) and math.isnan(v) and math.isnan(out[k]))  # a float's NaN
            assert same and type(out[k]) is type(v), k

    check()


@pytest.fixture(scope="module")
def other_db(tmp_path_factory):
    path = tmp_path_factory.mktemp("dbc") / "other.dbc"
    path.write_text(OTHER_DBC)
    return FrameDatabase(path)


@pytest.mark.parametrize("msg", MESSAGES, ids=IDS)
def test_database_roundtrip_is_on_the_grid(msg, other_db):
    """encode -> decode through the database (checksums included) returns cantools' quantization,
    on the compiled layouts and on cantools' own (a bit-field message)."""
    db = DB if msg.name in DB.by_name else other_db

    @settings(max_examples=60, deadline=None)
    @given(physical_values(msg))
    def check(values):
        values = {k: v for k, v in values.items() if not k.endswith("Checksum")}
        fid, data, fd = db.encode(msg.name, values)
        out = db.decode(fid, data, is_fd=fd)
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


TIED = [m for m in DB.db.messages if m.name in DB.counter]  # HOST_CMD, DEV_JOINTS, DEV_WRENCH


def count_and_wraps():
    """(k, count): k whole counter wraps (1 .. 2^23, up to 2^31 SYNCs) and a full count that a
    receiver k wraps on can still hold (< 2^32)."""
    return st.integers(1, 2**23).flatmap(lambda k: st.tuples(st.just(k), st.integers(0, 2**32 - 1 - 256 * k - 128)))


def test_every_tied_message_carries_a_counter():
    assert sorted(m.name for m in TIED) == ["DEV_JOINTS", "DEV_WRENCH", "HOST_CMD"]


@pytest.mark.parametrize("msg", TIED, ids=[m.name for m in TIED])
def test_any_replay_whole_counter_wraps_later_is_refused(msg):
    """A frame of any values answering SYNC ``count`` decodes at a receiver within half a wrap of
    that count, and is refused at one k * 256 SYNCs later (within half a wrap of it), for any k:
    the counts differ only in the CRC's four implicit bytes, a burst CRC-32 always detects.
    Stale while k <= STALE_WRAPS, a checksum failure beyond."""
    ctr = DB.codecs[msg.name].names[DB.counter[msg.name]]

    @settings(max_examples=200, deadline=None)
    @given(physical_values(msg), count_and_wraps(), st.integers(-128, 127), st.integers(-128, 127))
    def check(values, k_count, at, later):
        k, count = k_count
        values = {n: v for n, v in values.items() if not n.endswith("Checksum")}
        values[ctr] = count % 256
        try:
            fid, data, _ = DB.encode(msg.name, values, sync_count=count)
        except CanError:  # a value too wide for its bits: not a frame (test_encode_matches_cantools)
            return
        fresh = DB.decode(fid, data, sync_ref=count + at)
        assert isinstance(fresh, Decoded) and fresh.count == count
        replayed = DB.decode(fid, data, sync_ref=count + 256 * k + later)
        assert isinstance(replayed, Rejected) and replayed.reason == ("stale" if k <= FK.STALE_WRAPS else "checksum")

    check()


@pytest.mark.parametrize("name", ["DEV_JOINTS", "DEV_WRENCH"])
def test_the_host_never_applies_a_device_frame_replayed_whole_wraps_later(name):
    """The host's receive kernel: a device frame applied at its SYNC, replayed k * 256 SYNCs
    later (plus up to half a wrap), is refused (stale or checksum) and changes nothing."""
    msg = DB.message(name)
    ctr = DB.codecs[name].names[DB.counter[name]]

    @settings(max_examples=100, deadline=None)
    @given(physical_values(msg), count_and_wraps(), st.integers(0, 127))
    def check(values, k_count, later):
        k, count = k_count
        values = {n: v for n, v in values.items() if not n.endswith("Checksum")}
        values[ctr] = count % 256
        try:
            fid, data, _ = DB.encode(name, values, sync_count=count)
        except CanError:
            return
        ds = np.zeros(1, FK.DRIVER_STATE)
        ds["rows"] = DB.row["DEV_JOINTS"], DB.row["DEV_WRENCH"]
        ds["jc"] = ds["wc"] = ds["jf"] = ds["wf"] = -1
        ds["step_max"] = ds["wslew"] = -1.0  # the value checks off: freshness alone refuses
        vals = np.empty(DB.tables[0]["sig_f"].shape[1])
        verdict, _ = FK.rx_period_frame(DB.tables, ds, count + 1, fid, False, True, data, vals)
        assert verdict == FK.APPLIED
        before = ds.copy()
        verdict, _ = FK.rx_period_frame(DB.tables, ds, count + 256 * k + later + 1, fid, False, True, data, vals)
        assert verdict in (FK.STALE, FK.CHECKSUM)
        assert ds.tobytes() == before.tobytes()

    check()
