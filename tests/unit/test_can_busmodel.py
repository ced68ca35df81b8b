"""Bus timing: worst-case stuffing, arbitration, the 1 kHz budget."""

import pytest

from teleop.can.busmodel import (
    BusModel,
    BusTiming,
    compute_classic_bits,
    compute_cycle_load_pct,
    compute_fd_bits,
    compute_frame_time_s,
)
from teleop.util.errors import ConfigError

CLASSIC = BusTiming(1e6, 1e6, fd=False)
FD = BusTiming(1e6, 5e6, fd=True)


def test_classic_worst_case_bits():
    assert compute_classic_bits(8) == 135  # 47 + 64 + 24 stuff bits
    assert compute_classic_bits(0) == 55
    assert compute_frame_time_s(CLASSIC, 8, False) == pytest.approx(135e-6)
    with pytest.raises(ConfigError):
        compute_classic_bits(9)


def test_fd_bits_and_time():
    nominal, data = compute_fd_bits(16)
    assert nominal == 34 and data == 5 + 128 + 4 + 17 + 6 + 33
    assert compute_frame_time_s(FD, 16, True) == pytest.approx(34e-6 + data / 5e6)
    with pytest.raises(ConfigError):
        compute_fd_bits(10)
    with pytest.raises(ConfigError):
        compute_frame_time_s(CLASSIC, 16, True)


def test_one_khz_cycle_fits_fd_but_not_classic():
    # classic: SYNC + 6 frames of 8 bytes (4 feedback, 2 command) for 18 16-bit values
    classic = compute_cycle_load_pct(CLASSIC, [(1, False, 1)] + [(8, False, 1)] * 6, 1e-3)
    assert classic > 60.0
    fd = compute_cycle_load_pct(FD, [(2, True, 1), (16, True, 1), (16, True, 1), (16, True, 1),
                                      (3, True, 10), (4, True, 10)], 1e-3)
    print(f"\nbus load at 1 kHz: classic {classic:.1f} %, CAN FD 1/5 Mbit/s {fd:.1f} %")
    assert fd <= 60.0


def test_arbitration_lowest_id_first_and_load():
    bus = BusModel(FD)
    bus.submit(0.0, 0x181, 16, True, "wrench")
    bus.submit(0.0, 0x180, 16, True, "joints")
    bus.submit(0.0, 0x010, 8, True, "emcy")
    order = []
    while (r := bus.next_done(1.0)) is not None:
        order.append(r)
    assert [item for _, item in order] == ["emcy", "joints", "wrench"]
    assert order[0][0] < order[1][0] < order[2][0]  # serialised on the wire
    assert bus.load_pct(1e-3) == pytest.approx(100 * order[-1][0] / 1e-3)


def test_frames_do_not_start_after_the_horizon():
    bus = BusModel(FD)
    bus.submit(0.002, 0x100, 16, True, "late")
    assert bus.next_done(0.001) is None
    assert bus.next_done(0.003)[1] == "late"


def test_timing_validation():
    with pytest.raises(ConfigError, match="bitrate_bps"):
        BusTiming(-1.0)
    with pytest.raises(ConfigError, match="data_bitrate_bps"):
        BusTiming(1e6, 5e5, True)
