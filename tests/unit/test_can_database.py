"""The frame database: strict encoding, checked decoding, checksums."""

import pytest

from teleop.master.cobot.database import Decoded, FrameDatabase, Rejected, compute_crc8
from teleop.errors import CanError


@pytest.fixture(scope="module")
def db():
    return FrameDatabase()


def joints(**kw):
    sig = dict(PosX=0.1, PosY=-0.2, PosZ=0.05, AngA=3.0, AngB=1.5, AngC=-2.0, DevState=2, JointsCounter=7)
    sig.update(kw)
    return sig


def test_encode_decode_si_values(db):
    fid, data, fd = db.encode("DEV_JOINTS", joints())
    assert fid == 0x180 and fd and len(data) == 16
    out = db.decode(fid, data, 1.5)
    assert isinstance(out, Decoded) and out.timestamp == 1.5
    assert out.signals["PosX"] == pytest.approx(0.1, abs=12.5e-6)
    assert out.signals["AngA"] == pytest.approx(3.0, abs=2.5e-4)
    assert out.signals["JointsCounter"] == 7


def test_strict_encode_rejects_out_of_range_and_nonfinite(db):
    with pytest.raises(CanError, match="DEV_JOINTS"):
        db.encode("DEV_JOINTS", joints(PosX=0.9))
    with pytest.raises(CanError, match="PosY"):
        db.encode("DEV_JOINTS", joints(PosY=float("nan")))
    with pytest.raises(CanError, match="unknown message"):
        db.encode("NOPE", {})


def test_corrupted_frame_fails_checksum(db):
    fid, data, _ = db.encode("DEV_WRENCH", dict(ForceX=1, ForceY=2, ForceZ=-35, TorqueX=0, TorqueY=0.1,
                                                  TorqueZ=0, WrenchCounter=3))
    for bit in range(8 * len(data)):
        bad = bytearray(data)
        bad[bit // 8] ^= 1 << (bit % 8)
        out = db.decode(fid, bytes(bad))
        assert isinstance(out, Rejected) and out.reason == "checksum", bit


def test_unknown_id_wrong_length_and_out_of_range_are_rejected(db):
    assert db.decode(0x555, bytes(8)).reason == "unknown_id"
    assert db.decode(0x180, bytes(8)).reason == "length"
    raw = bytearray(16)
    raw[0:2] = (32767).to_bytes(2, "little", signed=True)  # PosX = 0.819 m > 0.8 m range
    raw[15] = compute_crc8(bytes(raw[:15]))
    out = db.decode(0x180, bytes(raw))
    assert isinstance(out, Rejected) and out.reason == "range:PosX"
