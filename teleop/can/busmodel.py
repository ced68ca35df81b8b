"""Bus time on a CAN wire: frame durations with worst-case bit stuffing, arbitration by id, load.

python-can's virtual bus delivers instantly and has no bandwidth, so the simulator asks this model
when each frame would finish on a real wire.

Worst-case bit counts (11-bit identifiers), n = payload bytes:

* classic CAN: 47 + 8n fixed bits, plus up to floor((34 + 8n - 1) / 4) stuff bits over the
  34 + 8n stuffed bits (SOF to CRC); 8 bytes -> 111 + 24 = 135 bits.
* CAN FD with bit-rate switch: at the nominal rate SOF, id, r1, IDE, FDF, res, BRS (17 bits, up
  to 4 stuff bits), CRC delimiter, ACK, ACK delimiter, EOF and IFS (13 bits); at the data rate ESI
  and DLC (5), the payload (8n), the stuff count (4), CRC-17 (n <= 16) or CRC-21, the fixed stuff
  bits of the CRC field (one per 4 bits) and up to floor((5 + 8n - 1) / 4) dynamic stuff bits.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

from teleop.util.errors import ConfigError

FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


@dataclass(frozen=True)
class BusTiming:
    """Nominal (arbitration) bit rate and, for CAN FD with BRS, the data-phase bit rate (bit/s)."""

    bitrate_bps: float = 1_000_000.0
    data_bitrate_bps: float = 5_000_000.0
    fd: bool = True

    def __post_init__(self):
        for key in ("bitrate_bps", "data_bitrate_bps"):
            v = float(getattr(self, key))
            if not v > 0 or v > 20e6:
                raise ConfigError(f"can.{key}: expected a bit rate in (0, 20e6] bit/s, got {v}")
            object.__setattr__(self, key, v)
        if self.fd and self.data_bitrate_bps < self.bitrate_bps:
            raise ConfigError("can.data_bitrate_bps: the CAN FD data rate must be >= the nominal rate")


def compute_classic_bits(n_bytes: int) -> int:
    """Worst-case bits of a classic base-format frame with ``n_bytes`` (0..8) of data."""
    if not 0 <= n_bytes <= 8:
        raise ConfigError(f"can frame: classic CAN carries 0..8 bytes, got {n_bytes}")
    stuffed = 34 + 8 * n_bytes
    return 47 + 8 * n_bytes + (stuffed - 1) // 4


def compute_fd_bits(n_bytes: int) -> tuple[int, int]:
    """Worst-case (nominal-rate bits, data-rate bits) of a base-format CAN FD frame with BRS."""
    if n_bytes not in FD_LENGTHS:
        raise ConfigError(f"can frame: CAN FD lengths are {FD_LENGTHS}, got {n_bytes}")
    nominal = 17 + (17 - 1) // 4 + 13
    crc = 17 if n_bytes <= 16 else 21
    fixed_stuff = -(-(4 + crc) // 4)
    data = 5 + 8 * n_bytes + 4 + crc + fixed_stuff + (5 + 8 * n_bytes - 1) // 4
    return nominal, data


def compute_frame_time_s(timing: BusTiming, n_bytes: int, fd_frame: bool) -> float:
    """Worst-case duration (s) of one frame on the wire."""
    if fd_frame:
        if not timing.fd:
            raise ConfigError("can frame: a CAN FD frame on a classic bus")
        nominal, data = compute_fd_bits(n_bytes)
        return nominal / timing.bitrate_bps + data / timing.data_bitrate_bps
    return compute_classic_bits(n_bytes) / timing.bitrate_bps


def compute_cycle_load_pct(timing: BusTiming, frames, period_s: float) -> float:
    """Bus load (%) of ``frames`` = [(n_bytes, fd_frame, every_n_periods), ...] sent each period."""
    busy = sum(compute_frame_time_s(timing, n, fd) / every for n, fd, every in frames)
    return 100.0 * busy / period_s


class BusModel:
    """One wire: frames wait until the bus is idle; among the waiting, the lowest id wins.

    ``submit`` queues a frame ready at a time (s); ``next_done(t_end)`` returns the next frame to
    finish among those that start before ``t_end``, as (done_s, item), or None.
    """

    def __init__(self, timing: BusTiming):
        self.timing = timing
        self.busy_until = 0.0
        self.busy_s = 0.0
        self.frames = 0
        self._pending: list = []  # heap of (ready_s, seq, frame_id, duration_s, item)
        self._seq = 0

    def submit(self, ready_s: float, frame_id: int, n_bytes: int, fd_frame: bool, item) -> None:
        duration = compute_frame_time_s(self.timing, n_bytes, fd_frame)
        heapq.heappush(self._pending, (ready_s, self._seq, frame_id, duration, item))
        self._seq += 1

    def next_done(self, t_end: float):
        if not self._pending:
            return None
        start = max(self.busy_until, self._pending[0][0])
        if start >= t_end:
            return None
        ready = [e for e in self._pending if e[0] <= start]
        win = min(ready, key=lambda e: (e[2], e[1]))  # arbitration: lowest id, then first queued
        self._pending.remove(win)
        heapq.heapify(self._pending)
        done = start + win[3]
        self.busy_until = done
        self.busy_s += win[3]
        self.frames += 1
        return done, win[4]

    def load_pct(self, elapsed_s: float) -> float:
        """Share of ``elapsed_s`` the wire was busy (%)."""
        return 100.0 * self.busy_s / elapsed_s if elapsed_s > 0 else 0.0
