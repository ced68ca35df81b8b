"""The frame database: strict encoding, checked decoding, CRC-32, id type and FD flag."""

import numpy as np
import pytest
from crccheck.crc import Crc32

from teleop.master.cobot.database import Decoded, FrameDatabase, Rejected, compute_crc32
from teleop.util.errors import CanError


@pytest.fixture(scope="module")
def db():
    return FrameDatabase()


def joints(**kw):
    sig = dict(PosX=0.1, PosY=-0.2, PosZ=0.05, AngA=3.0, AngB=1.5, AngC=-2.0, DevState=2, JointsCounter=7)
    sig.update(kw)
    return sig


def test_encode_decode_si_values(db):
    fid, data, fd = db.encode("DEV_JOINTS", joints())
    assert fid == 0x040 and fd and len(data) == 20
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
    assert db.decode(0x040, bytes(8)).reason == "length"
    raw = bytearray(20)
    raw[0:2] = (32767).to_bytes(2, "little", signed=True)  # PosX = 0.819 m > 0.8 m range
    # crccheck, not ours: id, payload, the full SYNC count (JointsCounter 0: SYNC 0)
    raw[16:20] = Crc32.calc(b"\x40\x00" + bytes(raw[:16]) + bytes(4)).to_bytes(4, "little")
    out = db.decode(0x040, bytes(raw))
    assert isinstance(out, Rejected) and out.reason == "range:PosX"


def test_crc_is_crccheck_crc32_over_the_frame_id_and_payload(db):
    """The wire CRC (teleop.util.crc32 in the hot path) equals crccheck's CRC-32/ISO-HDLC of id (2 bytes LE) +
    payload, on random payloads of every length the protocol uses."""
    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 4, 16, 60):
        for _ in range(50):
            fid, body = int(rng.integers(0, 0x800)), rng.bytes(n)
            assert compute_crc32(fid, body) == Crc32.calc(fid.to_bytes(2, "little") + body)
    fid, data, _ = db.encode("SYNC", {"SyncCounter": 9})
    assert int.from_bytes(data[-4:], "little") == Crc32.calc(b"\x20\x00" + data[:-4])


def test_a_frame_under_another_id_fails_its_crc(db):
    """The frame id is in the CRC (E2E data id): DEV_JOINTS' payload sent as DEV_WRENCH fails."""
    _fid, data, _ = db.encode("DEV_JOINTS", joints())
    assert db.decode(0x041, data).reason == "checksum"


def test_id_type_and_fd_flag_are_checked(db):
    fid, data, _ = db.encode("DEV_JOINTS", joints())
    assert isinstance(db.decode(fid, data, 0.0, is_extended_id=False, is_fd=True), Decoded)
    assert db.decode(fid, data, 0.0, is_extended_id=True, is_fd=True).reason == "id_type"
    assert db.decode(fid, data, 0.0, is_extended_id=False, is_fd=False).reason == "fd_flag"


def test_no_random_frame_passes(db):
    """10^5 random payloads on the known ids, with the right flags and lengths: CRC-32 lets each
    through with p = 2^-32, so the expected count is 2.3e-5 and none may pass. 5000 of the same
    frames checked with an 8-bit CRC (crccheck's CRC-8 SAE J1850, the old check) let ~1/256
    through: the draw is random enough to show a weak check (tools/can_residual.py: 10^6 frames)."""
    from crccheck.crc import Crc8SaeJ1850
    rng = np.random.default_rng(1)
    n, passed, weak = 100_000, 0, 0
    for m in db.db.messages:
        block = rng.integers(0, 256, (n // len(db.db.messages), m.length), dtype=np.uint8)
        rows = [r.tobytes() for r in block]
        passed += sum(isinstance(db.decode(m.frame_id, r), Decoded) for r in rows)
        weak += sum(Crc8SaeJ1850.calc(r[:-1]) == r[-1] for r in rows[:5000 // len(db.db.messages)])
    assert passed == 0
    assert 6 <= weak <= 34  # 4998 frames: 19.5 expected, +-3.3 sigma (binomial)


def wrench(**kw):
    sig = dict(ForceX=1.0, ForceY=2.0, ForceZ=-35.0, TorqueX=0.0, TorqueY=0.1, TorqueZ=0.0, WrenchCounter=3)
    sig.update(kw)
    return sig


def test_a_frame_tied_to_a_sync_carries_its_full_count_in_the_crc(db):
    """DEV_WRENCH answering SYNC 70 000: on the wire the counter is the count's low byte (112);
    the CRC (crccheck's) runs over the frame id, the payload and the full count, 4 bytes LE. SYNC
    carries its full count itself and is tied to none."""
    count = 70_000
    fid, data, _ = db.encode("DEV_WRENCH", wrench(WrenchCounter=count % 256), sync_count=count)
    assert data[13] == count % 256
    assert int.from_bytes(data[-4:], "little") == Crc32.calc(b"\x41\x00" + data[:-4] + count.to_bytes(4, "little"))
    assert int.from_bytes(data[-4:], "little") == compute_crc32(fid, data[:-4], count)
    out = db.decode(fid, data, sync_ref=count + 100)  # the receiver's latest count, 100 SYNCs on
    assert isinstance(out, Decoded) and out.count == count
    fid, data, _ = db.encode("SYNC", {"SyncCounter": count})
    assert len(data) == 8 and int.from_bytes(data[:4], "little") == count
    assert int.from_bytes(data[-4:], "little") == Crc32.calc(b"\x20\x00" + data[:-4])
    assert db.decode(fid, data, sync_ref=5).count == -1


def test_the_count_and_its_counter_must_agree(db):
    with pytest.raises(CanError, match="low byte"):
        db.encode("DEV_WRENCH", wrench(WrenchCounter=4), sync_count=70_000)
    with pytest.raises(CanError, match="2\\^32"):
        db.encode("DEV_WRENCH", wrench(WrenchCounter=0), sync_count=2**32)
    with pytest.raises(CanError, match="SyncCounter"):
        db.encode("SYNC", {"SyncCounter": 2**32})


@pytest.mark.parametrize("wraps, reason", [(1, "stale"), (2, "stale"), (16, "stale"), (17, "checksum")])
def test_a_replay_whole_wraps_later_fails_the_crc(db, wraps, reason):
    """Recorded at SYNC 1000 and checked by a receiver 256 k SYNCs on: refused, as stale while
    the CRC is tried that far back (STALE_WRAPS = 16), as a checksum failure beyond."""
    fid, data, _ = db.encode("DEV_WRENCH", wrench(WrenchCounter=1000 % 256), sync_count=1000)
    assert db.decode(fid, data, sync_ref=1000).count == 1000
    for offset in (0, -128, 127):  # the receiver then rebuilds the count 256 k after the recorded one
        assert db.decode(fid, data, sync_ref=1000 + 256 * wraps + offset).reason == reason
