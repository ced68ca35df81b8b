"""Traffic capture to python-can log formats: ``.log`` (candump -L), ``.asc``, ``.blf``, ``.csv``.

Timestamps are the frames' end-of-frame times on the modelled wire (s). A ``.log`` capture reads
back with ``python -m can.player`` and ``python -m cantools decode protocol.dbc < capture.log``.
The capture is the host's view of the wire: its own frames are marked transmitted (``is_rx``
False: ``Tx`` in ``.asc``, ``T`` in candump's ``.log``), the device's received.
"""

from __future__ import annotations

from pathlib import Path

import can

from teleop.util.errors import CanError


class Capture:
    """Writes frames through ``can.Logger`` (format chosen by suffix); ``close`` is safe twice."""

    def __init__(self, path: str | Path, channel: str = "vcan0"):
        self.path, self.channel = Path(path), channel
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self.writer = can.Logger(str(self.path))
        except ValueError as e:
            raise CanError(f"capture_path {self.path}: {e}") from None
        self.frames = 0

    def write(self, msg: can.Message, t_s: float, is_rx: bool = True) -> None:
        """Record ``msg`` at ``t_s`` (s); ``is_rx`` False for a frame the capturing node sent."""
        m = can.Message(timestamp=t_s, arbitration_id=msg.arbitration_id, data=msg.data,
                        is_extended_id=msg.is_extended_id, is_fd=msg.is_fd, bitrate_switch=msg.bitrate_switch,
                        is_error_frame=msg.is_error_frame, channel=self.channel, dlc=msg.dlc, is_rx=is_rx)
        self.writer.on_message_received(m)
        self.frames += 1

    def close(self) -> None:
        if self.writer is not None:
            self.writer.stop()
            self.writer = None
